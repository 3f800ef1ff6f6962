"""Reaching the device under test, one file per thing it holds:

- client links: ``link`` (the interface every link gives, and its errors), ``in_process``,
  ``canopen_link``, ``modbus_link``, and ``role_link`` (the interface in terms of a profile's roles,
  which both protocol links share);
- the simulated device (the virtual controller behind a protocol): ``canopen_device``,
  ``modbus_device``, ``virtual_roles`` (its roles, which both serve), ``serve`` (``hil dut serve``),
  ``socketcand`` and ``tcp`` (its servers);
- device profiles: ``profile`` (parsing, and each object's value encoding), ``eds`` (EDS files
  written from a profile's dictionary, and read as real tools write them), ``draft`` (a profile
  drafted from an EDS);
- protocol codecs both sides share: ``canopen_codec`` (CiA 301 codes), ``modbus_codec`` (the edge
  mailbox's words, function codes, exception rules);
- ``kinds`` (the DUT kinds, one declaration each), ``spec`` (``--dut`` specifications, parsed and
  opened by their kind) and ``can_interfaces``.

Import the module you need; this package imports nothing, so ``hil.dut.link`` stays light.
"""
