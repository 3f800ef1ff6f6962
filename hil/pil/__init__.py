"""Processor in the loop (``hil-pil/1``): the same ``hil-sil/1`` firmware, built for the Cortex-M
part it ships on and run instruction by instruction on an emulated core, with each interrupt's
cycles, its stack and its faults (docs/processor-in-the-loop.md).

- ``hil.pil.target``: the ``[target]`` table and the cores (ISA, FPU, compiler flags, cycle table);
- ``hil.pil.build``: a ``sil.toml`` folder built into an ELF for the core with Zig's clang;
- ``hil.pil.core``: one emulated core (Unicorn) with cycle counting, nesting and fault findings;
- ``hil.pil.firmware``: the ``hil-sil/1`` exports on that core, as ``hil.sil.firmware.Firmware``.
"""
