"""The C block hook (hil.pil.native) against the Python one it replaces (the reference): the same
calls give the same cycles, instructions, stack high-water marks, soft-float counts and findings.

The reference firmware runs a fixed input sequence on each core twice, once per hook: Hall edges of a
forward rotation with four control interrupts after each, and on every third edge a control
interrupt that preempts the Hall interrupt part-way (nesting, the 26-word FP frame and lazy FP
stacking on the M4F, the taken-branch state saved across the preemption). Every figure the core
measured must be equal, not close.
"""

from __future__ import annotations

from dataclasses import astuple

import pytest
from test_pil_core import REFERENCE, _target, m0plus, m4f, snippet_folder  # noqa: F401  (fixtures)

from hil.pil import native
from hil.pil.build import build_elf
from hil.pil.core import RAM_BASE, Core, ProcessorFinding
from hil.pil.firmware import PilFirmware
from hil.sil.build import read_build_spec

HOOKS = ("python", "native")


def test_the_native_hook_builds_for_this_host():
    """The figures below compare two implementations only if the C one is there (it is built with the
    compiler ``sil:`` uses; ziglang is a dependency, so every host has one)."""
    assert native.library() is not None


def _drive(fw: PilFirmware, turns: int) -> dict:
    """The fixed input sequence; what the firmware answered and what the core measured."""
    core = fw.core
    fw.reset(0b001)
    sequence = (0b011, 0b010, 0b110, 0b100, 0b101, 0b001) * turns
    answers, preempted, count = [], 0, 1000
    for k, levels in enumerate(sequence):
        count += 2500
        pin = [b for b in range(3) if (levels ^ sequence[k - 1]) >> b & 1][0] if k else 1
        fw.adc[0], fw.adc[1], fw.adc[2] = 120 + k, -60, -60 - k
        if k % 3 == 2:
            core.begin("hil_sil_hall_isr", (count, pin, levels, fw.load_adc()), interrupt=True, label="hall")
            if not core.run(until_cycle=core.cycles + 300 + 7 * k):  # paused part-way: preempt it
                preempted += 1
                core.begin("hil_sil_control_isr", (count + 100, fw.load_adc()), interrupt=True, label="control")
                assert core.run()
                answers.append(("nested", core.last_cycles, core.active))
                assert core.run()
        else:
            fw.hall_isr(count, pin, levels, fw.adc)
        answers.append((fw.gates(), fw.duty(), core.last_cycles))
        for c in range(1, 5):
            fw.control_isr(count + 500 * c, fw.adc)
            answers.append((fw.gates(), fw.duty(), core.last_cycles))
    raw = {label: (s.calls, s.cycles, s.instructions, dict(s.soft_float), s.stack_bytes)
           for label, s in core.stats.items()}
    return {"answers": answers, "preempted": preempted, "stats": fw.stats(), "raw": raw,
            "cycles": core.cycles, "instructions": core.instructions, "stack": core.stack_high_water}


@pytest.mark.parametrize("cpu", ["cortex-m4f", "cortex-m0plus"])
def test_native_and_python_hooks_measure_the_reference_firmware_alike(cpu):
    spec = read_build_spec(REFERENCE)
    target = _target(cpu, flash_bytes=1 << 20, ram_bytes=196608, stack_bytes=4096)
    elf = build_elf(spec, target).elf
    runs = {}
    for hooks in HOOKS:
        fw = PilFirmware(elf, target, hooks=hooks)
        assert fw.core.hooks == hooks
        runs[hooks] = _drive(fw, turns=1)
    python, fast = runs["python"], runs["native"]
    assert fast["preempted"] >= 1  # the nesting path ran
    for key in ("answers", "raw", "stats", "cycles", "instructions", "stack"):
        assert fast[key] == python[key], key
    interrupts = fast["stats"]["interrupts"]
    assert interrupts["hall"]["calls"] == 6 and interrupts["control"]["calls"] == 24 + fast["preempted"]
    assert fast["stack"] > 0 and any(s["soft_float"] for s in interrupts.values())


@pytest.mark.parametrize("function, args", [
    ("bus_fault", ()), ("load64", (RAM_BASE + 2,)), ("divide", (7, 0)), ("trap", ()), ("deep", (1000,)),
    ("spin", ()),
])
def test_native_and_python_hooks_report_the_same_finding(m4f, function, args):  # noqa: F811
    """A fault, a stack overflow and a hang: the same finding, at the same cycle, from either hook;
    and the calls before it counted alike."""
    said = {}
    for hooks in HOOKS:
        core = Core(m4f, _target("cortex-m4f"), budget_cycles=20_000, hooks=hooks)
        before = [core.call("count_to", 37), core.call("lib_op", 0), core.call("deep", 6)]
        with pytest.raises(ProcessorFinding) as info:
            core.call(function, *args, interrupt=True, label="control")
        said[hooks] = (before, str(info.value), core.cycles, core.instructions, core.stack_high_water)
    assert said["native"] == said["python"]


@pytest.mark.parametrize("cpu", ["cortex-m4f", "cortex-m0plus"])
def test_a_block_summed_from_the_sweep_is_the_block_decoded_in_full(cpu):
    """The native path's first sight of a block sums the cost rows of the ELF's sweep; blocks
    starting at every fifth instruction of the reference firmware, one to six instructions long,
    come out field for field as the full decode makes them."""
    from hil.pil.cycles import _known_rows, decode_block

    target = _target(cpu, flash_bytes=1 << 20, ram_bytes=196608, stack_bytes=4096)
    core = Core(build_elf(read_build_spec(REFERENCE), target).elf, target)
    rows = core._rows
    starts = sorted(rows)
    compared = summed_from_rows = 0
    for i in range(0, len(starts) - 6, 5):
        a, last = starts[i], starts[i + i % 6]  # one to six instructions
        code = core.read(a, last + rows[last][1] - a)
        full = decode_block(core.md, code, a, core.table, core.spec.hard_float)
        summed = decode_block(core.md, code, a, core.table, core.spec.hard_float, rows)
        assert astuple(summed) == astuple(full), hex(a)
        compared += 1
        summed_from_rows += _known_rows(core.md, code, a, rows) is not None
    assert compared > 1000 and summed_from_rows > 0.9 * compared  # the rows were used, not the fallback
