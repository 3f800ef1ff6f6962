"""Imported by the process ``hil qualify`` forks its runs from (``hil.qualify.forked.PRELOAD``):
the plant's and the controller's numba code loaded from its cache once, there, for every run
(``hil.compile_ahead.load_compiled``, which compiles what the cache lacks and never raises)."""

from hil.compile_ahead import load_compiled

load_compiled()
