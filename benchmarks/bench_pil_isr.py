"""Processor in the loop per interrupt, in one run: the reference firmware's Hall and control
interrupts on emulated cores (instructions, cycles, microseconds at the clock) and the wall and CPU
time of one interrupt, beside the same calls into its SIL build (the peer: the same C compiled for
the PC), with cycles charged by the C block hook (``native``) and by the Python one it replaces
(``python``, the reference).

``python benchmarks/bench_pil_isr.py [--cpu cortex-m4f --cpu cortex-m0plus] [--turns 20]``

The drive is the one tests/test_pil_core.py uses: reset, then Hall edges of a forward rotation
(2500 timer ticks apart at 10 MHz) with four control interrupts after each, and the gates and the
duty read after every interrupt (as a scheduler reads them). The first turn is timed apart: it
decodes every block the firmware runs for the first time (Capstone, once per ELF and process); the
per-interrupt figures are the turns after it. CPU time (``time.process_time``) is given beside
wall time because a loaded machine stretches the wall. The figures are ratios to the SIL call in
the same run, never pass/fail; ``identical`` says whether both hooks measured the same cycles,
instructions, soft-float calls and stack.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def drive(fw, turns: int, first: int = 0) -> None:
    sequence = (0b011, 0b010, 0b110, 0b100, 0b101, 0b001) * (first + turns)
    if not first:
        fw.reset(0b001)
    count = 1000 + 2500 * 6 * first
    for k in range(6 * first, len(sequence)):
        levels = sequence[k]
        count += 2500
        pin = [b for b in range(3) if (levels ^ sequence[k - 1]) >> b & 1][0] if k else 1
        fw.adc[0], fw.adc[1], fw.adc[2] = 120, -60, -60
        fw.hall_isr(count, pin, levels, fw.adc)
        fw.gates(), fw.duty()
        for c in range(1, 5):
            fw.control_isr(count + 500 * c, fw.adc)
            fw.gates(), fw.duty()


def timed(fw, turns: int) -> dict:
    """The first turn, then the ``turns - 1`` after it: wall and CPU seconds of each part."""
    w0, c0 = time.perf_counter(), time.process_time()
    drive(fw, 1)
    w1, c1 = time.perf_counter(), time.process_time()
    drive(fw, turns - 1, first=1)
    w2, c2 = time.perf_counter(), time.process_time()
    return {"first_wall_s": w1 - w0, "first_cpu_s": c1 - c0, "wall_s": w2 - w1, "cpu_s": c2 - c1}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cpu", action="append", help="cores (default cortex-m4f and cortex-m0plus)")
    p.add_argument("--turns", type=int, default=20, help="electrical turns of Hall edges (6 edges each), at least 2")
    args = p.parse_args()
    from hil.pil import core as pil_core
    from hil.pil.build import build_elf
    from hil.pil.firmware import PilFirmware
    from hil.pil.target import read_target
    from hil.sil.build import build, read_build_spec
    from hil.sil.firmware import Firmware

    spec = read_build_spec(ROOT / "firmware" / "reference")
    calls = 6 * (args.turns - 1) * 5  #: interrupts timed (the first turn's apart)
    sil = timed(Firmware(str(build(spec).library)), args.turns)
    out = {"interrupts_timed": calls, "sil_wall_us_per_interrupt": sil["wall_s"] / calls * 1e6,
           "sil_cpu_us_per_interrupt": sil["cpu_s"] / calls * 1e6}
    for cpu in args.cpu or ["cortex-m4f", "cortex-m0plus"]:
        target = read_target({"cpu": cpu, "clock_hz": 168_000_000 if cpu != "cortex-m0plus" else 64_000_000,
                              "flash_bytes": 1 << 20, "ram_bytes": 196608, "stack_bytes": 4096}, "bench")
        elf = build_elf(spec, target).elf
        pil, measured = {}, {}
        for hooks in ("python", "native"):
            pil_core._DECODED.clear()  # each hook decodes its blocks itself (the cache is shared per ELF)
            fw = PilFirmware(elf, target, hooks=hooks)
            t = timed(fw, args.turns)
            stats = fw.stats()
            measured[hooks] = (stats, {k: (s.cycles, dict(s.soft_float)) for k, s in fw.core.stats.items()})
            pil[hooks] = {"hooks": fw.core.hooks, "first_turn_wall_s": t["first_wall_s"],
                          "first_turn_cpu_s": t["first_cpu_s"],
                          "wall_us_per_interrupt": t["wall_s"] / calls * 1e6,
                          "cpu_us_per_interrupt": t["cpu_s"] / calls * 1e6,
                          "ratio_to_sil_wall": t["wall_s"] / sil["wall_s"],
                          "ratio_to_sil_cpu": t["cpu_s"] / sil["cpu_s"]}
        stats = measured["native"][0]
        out[cpu] = {**pil, "native_speedup_cpu": pil["python"]["cpu_us_per_interrupt"]
                    / pil["native"]["cpu_us_per_interrupt"],
                    "identical": measured["native"] == measured["python"],
                    "instructions_per_interrupt": stats["instructions"] / (calls + 30),  # reads and reset in
                    "interrupts": stats["interrupts"], "stack": stats["stack"], "flash": stats["flash"],
                    "ram": stats["ram"], "translated_blocks": len(fw.core._blocks)}
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
