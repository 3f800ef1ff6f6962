"""A recording, and every file a recording is read from:

- ``format`` the ``hil-recording/1`` format (``Recording``, ``Segment``, ``write_recording``),
  ``reader`` its strict reader (``read_recording``), ``errors`` the reading errors;
- ``capture`` logic-analyser captures (VCD through ``vcd``, sigrok session, CSV), ``hall`` the
  Hall lines of a capture as a recording, ``traces`` logger traces (MDF4, Parquet, CSV) through a
  column mapping;
- ``formats`` the one table of file formats by suffix, ``load`` the one loader of a command's
  RECORDING argument (a recording directory, a capture, or a trace);
- ``drivers`` recordings made on the plant.

Import the module you need; this package imports nothing.
"""
