"""Imported by a process that others are forked from (``hil qualify``'s warm process,
``hil.qualify.forked.PRELOAD``): the plant's and the controller's numba code loaded from its cache
once, there, for every process forked after (``hil.compile_ahead.load_compiled``, which compiles
what the cache lacks and never raises; the plugin's own call in a forked run then has nothing left
to do). An entry point of its own, since only entry points load the compiled code."""

from hil.compile_ahead import load_compiled

load_compiled()
