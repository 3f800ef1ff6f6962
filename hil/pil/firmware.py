"""The ``hil-sil/1`` exports of an ELF on an emulated Cortex-M core, with the interface of
``hil.sil.firmware.Firmware``: what drives a library drives this (``hil.sil.peripherals``).

The interrupts run as interrupts (exception entry and return charged, their cycles in
``stats()``); ``describe``, ``reset`` and the object dictionary run as thread-mode calls; the
outputs the framework reads after every interrupt (``gates``, ``duty``, ``compare``, ``emcy``) are
what the hardware's registers would show, so their cycles are given back (they take no time of the
firmware's). They are read in one emulated call, not four: a few lines of Thumb of the framework's
own (``_outputs_code``) call the four exports in turn and leave their answers in the scratch
region; the answers stand until firmware code runs again (``Core.firmware_runs``), and an EMCY code
that call popped is handed out first by ``emcy()``. ``core`` is the emulated core, for a scheduler
that preempts (``Core.begin``/``run``).
"""

from __future__ import annotations

import array
import struct
from pathlib import Path

import numpy as np

from hil.sil.firmware import FirmwareInfo, SilInterfaceError, check_exports, check_info

from .core import ADC_BASE, FRAMEWORK_CODE, MAGIC_RETURN, SCRATCH_BASE, SCRATCH_BYTES, Core
from .target import Target

#: hil_sil_info as the AAPCS lays it out on a 32-bit ARM (docs/firmware-in-the-loop.md)
_INFO = struct.Struct("<IIIB3xIfB3x")
#: interrupt kinds, as ``stats()`` names them
KINDS = ("hall", "compare", "control")
#: where the output read leaves its answers (the last 32 bytes of the scratch region): the return
#: values of hil_sil_gates, _duty, _compare, _emcy, then the count _compare wrote and the code _emcy wrote
OUTPUTS = SCRATCH_BASE + SCRATCH_BYTES - 32
_OUTPUTS = struct.Struct("<IIIIIH")
#: the framework's output read, as ``Core.load_framework_code`` names it
OUTPUTS_SYMBOL = "hil_pil_outputs"


def _outputs_code(getters: list[tuple[int, int | None]]) -> bytes:
    """Thumb code (ARMv6-M's subset, so every core runs it) that calls each ``(address, argument)`` in
    turn (r0 = argument when there is one) and stores its r0 at OUTPUTS + 4 k:

        push {r4, lr}; ldr r4, =OUTPUTS
        [ldr r0, =argument]; ldr r3, =address | 1; blx r3; str r0, [r4, #4k]   (per getter)
        pop {r4, pc}
        literals
    """
    literals: list[int] = [OUTPUTS]
    body: list[tuple[str, int]] = [("ldr r4", 0)]
    for k, (address, argument) in enumerate(getters):
        if argument is not None:
            body.append(("ldr r0", len(literals)))
            literals.append(argument)
        body += [("ldr r3", len(literals)), ("blx r3", 0), ("str", k)]
        literals.append(address | 1)
    n = 1 + len(body) + 1  # push, the body, pop: halfwords
    pool = (2 * n + 3) // 4 * 4  # the literal pool, word aligned after the code
    out = [0xB510]  # push {r4, lr}
    for i, (op, arg) in enumerate(body):
        at = 2 * (1 + i)
        if op.startswith("ldr"):
            offset = pool + 4 * arg - ((at + 4) & ~3)  # LDR (literal): Align(PC, 4) + imm8 * 4
            out.append({"ldr r0": 0x4800, "ldr r3": 0x4B00, "ldr r4": 0x4C00}[op] | offset // 4)
        elif op == "blx r3":
            out.append(0x4798)
        else:  # str r0, [r4, #4k]
            out.append(0x6020 | arg << 6)
    out.append(0xBD10)  # pop {r4, pc}
    code = struct.pack(f"<{len(out)}H", *out)
    return code.ljust(pool, b"\0") + struct.pack(f"<{len(literals)}I", *literals)


def _tail_code(read: int) -> bytes:
    """Thumb code an interrupt returns into (its LR, ``Core.begin(then=...)``): the output read at
    ``read``, then the end of the emulated call (MAGIC_RETURN), so that an interrupt and the read of
    what it left are one call, not two (word aligned; ARMv6-M's subset):

        ldr r3, =read | 1; blx r3; ldr r3, =MAGIC_RETURN | 1; bx r3; literals
    """
    return struct.pack("<4H2I", 0x4B01, 0x4798, 0x4B01, 0x4718, read | 1, MAGIC_RETURN | 1)


class PilFirmware:
    """The exports of ``elf`` on a fresh core of ``target``."""

    def __init__(self, elf: str | Path, target: Target, *, budget_cycles: int | None = None, hooks: str = "native"):
        self.path = str(elf)
        self.target = target
        self.core = core = Core(elf, target, hooks=hooks,
                                **({"budget_cycles": budget_cycles} if budget_cycles else {}))
        has = check_exports(self.path, core.has)
        self.has_compare, self.has_emcy = has["hil_sil_compare"], has["hil_sil_emcy"]
        self.compare_isr = self._compare_isr if self.has_compare else None
        self.adc = array.array("h", [0, 0, 0])  #: the ADC's result registers, written before every interrupt
        self.last_cycles = 0  #: cycles of the last call, exception entry and return included for an interrupt
        getters = [(core.symbol("hil_sil_gates"), None), (core.symbol("hil_sil_duty"), None)]
        getters += [(core.symbol("hil_sil_compare"), OUTPUTS + 16)] if self.has_compare else []
        getters += [(core.symbol("hil_sil_emcy"), OUTPUTS + 20)] if self.has_emcy else []
        read = _outputs_code(getters)
        tail_at = (len(read) + 3) // 4 * 4
        core.load_framework_code(OUTPUTS_SYMBOL, read.ljust(tail_at, b"\0") + _tail_code(FRAMEWORK_CODE))
        #: where an interrupt the scheduler starts returns to (``Core.begin(then=...)``): the output read
        self.isr_tail = FRAMEWORK_CODE + tail_at
        self._outputs: tuple | None = None
        self._outputs_at = -1  #: core.firmware_runs when the outputs were read
        self._emcy_popped: list[int] = []  #: EMCY codes the output read popped, not handed out yet
        #: core.firmware_runs when the EMCY queue was last found empty: it stays empty until firmware code
        #: runs again (the output read after every interrupt finds it so; no second call to ask again)
        self._emcy_empty_at = -1
        self._constructors()

    def _constructors(self) -> None:
        """C++ static constructors (``.init_array``), run once as a start-up routine would."""
        section = self.core._elffile.get_section_by_name(".init_array")
        if section is None or section["sh_size"] == 0:
            return
        for pointer in struct.unpack(f"<{section['sh_size'] // 4}I", section.data()):
            name = self.core.function_at(pointer & ~1)
            if name is not None:
                self._run(name)

    def _run(self, symbol: str, *args, interrupt: bool = False, label: str | None = None) -> int:
        value = self.core.call(symbol, *args, interrupt=interrupt, label=label)
        self.last_cycles = self.core.last_cycles
        return value

    def _read(self, symbol: str, *args) -> int:
        """An output register read (no time of the firmware's)."""
        return self.core.call(symbol, *args, charge=False)

    def load_adc(self) -> int:
        """``adc`` into the ADC's result registers; their address, the interrupts' ``adc`` argument
        (a scheduler that starts an interrupt with ``core.begin`` passes it)."""
        self.core.write(ADC_BASE, self.adc.tobytes())
        return ADC_BASE

    # --- hil-sil/1 ---------------------------------------------------------------------------------
    def describe(self) -> FirmwareInfo:
        self.core.write(SCRATCH_BASE, bytes(_INFO.size))
        self._run("hil_sil_describe", SCRATCH_BASE)
        abi, name, timer_hz, bits, control_hz, amps, pole_pairs = _INFO.unpack(self.core.read(SCRATCH_BASE,
                                                                                             _INFO.size))
        info = FirmwareInfo(abi, self.core.read_cstring(name) if name else "", timer_hz, bits, control_hz,
                            float(amps), pole_pairs, self.has_compare, self.has_emcy)
        check_info(self.path, info)
        return info

    def reset(self, levels: int) -> None:
        self._run("hil_sil_reset", levels & 0xFF)

    def hall_isr(self, count: int, pin: int, levels: int, adc=None) -> None:
        self._run("hil_sil_hall_isr", count, pin & 0xFF, levels & 0xFF, self.load_adc(), interrupt=True, label="hall")

    def control_isr(self, count: int, adc=None) -> None:
        self._run("hil_sil_control_isr", count, self.load_adc(), interrupt=True, label="control")

    def _compare_isr(self, count: int) -> None:
        self._run("hil_sil_compare_isr", count, interrupt=True, label="compare")

    def _read_outputs(self) -> tuple:
        """gates, duty, compare's answer, emcy's answer, the compare count, the EMCY code: read in one
        call unless no firmware code ran since the last read."""
        if self._outputs_at != self.core.firmware_runs:
            if self.core.outputs_ran_at != self.core.firmware_runs:  # not read at the interrupt's return
                self.core.call(OUTPUTS_SYMBOL, charge=False)
            out = _OUTPUTS.unpack(self.core.read(OUTPUTS, _OUTPUTS.size))
            if not self.has_compare:  # the slots shift: compare's were never called
                out = (out[0], out[1], 0, out[2], 0, out[5])
            if self.has_emcy and out[3]:
                self._emcy_popped.append(out[5])
            elif self.has_emcy:
                self._emcy_empty_at = self.core.firmware_runs
            self._outputs, self._outputs_at = out, self.core.firmware_runs
        return self._outputs

    def gates(self) -> int:
        return self._read_outputs()[0] & 0xFF

    def duty(self) -> int:
        return self._read_outputs()[1] & 0xFFFF

    def compare(self) -> int | None:
        """The armed compare count, or None."""
        out = self._read_outputs()
        return out[4] if out[2] else None

    def emcy(self) -> int | None:
        """One EMCY code popped from the firmware's queue (the output read's first), or None (no call
        when the queue was found empty and no firmware code ran since)."""
        if not self.has_emcy:
            return None
        self._read_outputs()  # the first code after firmware code ran comes with the outputs
        if self._emcy_popped:
            return self._emcy_popped.pop(0)
        if self._emcy_empty_at == self.core.firmware_runs:
            return None
        if not self._read("hil_sil_emcy", SCRATCH_BASE) & 0xFFFFFFFF:
            self._emcy_empty_at = self.core.firmware_runs
            return None
        return struct.unpack("<H", self.core.read(SCRATCH_BASE, 2))[0]

    def od_read(self, index: int, sub: int, size: int) -> bytes | int:
        """The object's bytes, or the (negative) SDO abort code."""
        if size > SCRATCH_BYTES:
            raise ValueError(f"an object-dictionary read of {size} bytes (at most {SCRATCH_BYTES})")
        self.core.write(SCRATCH_BASE, bytes(max(size, 1)))
        n = _signed(self._run("hil_sil_od_read", index & 0xFFFF, sub & 0xFF, SCRATCH_BASE, size))
        if n < 0:
            return n
        if n > size:
            raise SilInterfaceError(f"hil_sil_od_read(0x{index:04X}, {sub}) returned {n} bytes into a buffer of {size}")
        return self.core.read(SCRATCH_BASE, n)

    def od_write(self, index: int, sub: int, data: bytes) -> int:
        if len(data) > SCRATCH_BYTES:
            raise ValueError(f"an object-dictionary write of {len(data)} bytes (at most {SCRATCH_BYTES})")
        self.core.write(SCRATCH_BASE, bytes(data))
        return _signed(self._run("hil_sil_od_write", index & 0xFFFF, sub & 0xFF, SCRATCH_BASE, len(data)))

    # --- what the core measured --------------------------------------------------------------------------
    def stats(self) -> dict:
        """Per interrupt kind: calls, cycles (median, p99, max, and in microseconds at clock_hz), the
        soft floating-point routines it called by name, its stack high-water mark; and the firmware's
        flash and RAM, the stack's high-water mark against stack_bytes."""
        core, clock = self.core, self.target.clock_hz
        kinds = {}
        for kind in KINDS:
            s = core.stats.get(kind)
            if s is None or not s.calls:
                continue
            c = np.asarray(s.cycles, dtype=float)
            figures = {"median": float(np.median(c)), "p99": float(np.percentile(c, 99)), "max": float(c.max())}
            kinds[kind] = {"calls": s.calls, "cycles": figures, "instructions_median": float(np.median(s.instructions)),
                           "us": {k: v / clock * 1e6 for k, v in figures.items()},
                           "soft_float": dict(sorted(s.soft_float.items())), "stack_bytes": s.stack_bytes}
        t = self.target
        return {"cpu": t.cpu, "clock_hz": clock, "interrupts": kinds,
                "stack": {"high_water_bytes": core.stack_high_water, "stack_bytes": t.stack_bytes},
                "flash": {"used_bytes": core.flash_used, "flash_bytes": t.flash_bytes},
                "ram": {"used_bytes": core.ram_used, "ram_bytes": t.ram_bytes},
                "cycles": core.cycles, "instructions": core.instructions}


def _signed(value: int) -> int:
    return value - (1 << 32) if value & 0x8000_0000 else value
