"""Processor in the loop per interrupt, in one run: the reference firmware's Hall and control
interrupts on emulated cores (instructions, cycles, microseconds at the clock) and the wall time of
one call, beside the same calls into its SIL build (the peer: the same C compiled for the PC).

``python benchmarks/bench_pil_isr.py [--cpu cortex-m4f --cpu cortex-m0plus] [--turns 20]``

The drive is the one tests/test_pil_core.py uses: reset, then Hall edges of a forward rotation
(2500 timer ticks apart at 10 MHz) with four control interrupts after each. The wall figures are
ratios to the SIL call in the same run, never pass/fail.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def drive(fw, turns: int) -> None:
    fw.reset(0b001)
    sequence = (0b011, 0b010, 0b110, 0b100, 0b101, 0b001) * turns
    count = 1000
    for k, levels in enumerate(sequence):
        count += 2500
        pin = [b for b in range(3) if (levels ^ sequence[k - 1]) >> b & 1][0] if k else 1
        fw.adc[0], fw.adc[1], fw.adc[2] = 120, -60, -60
        fw.hall_isr(count, pin, levels, fw.adc)
        fw.gates(), fw.duty()
        for c in range(1, 5):
            fw.control_isr(count + 500 * c, fw.adc)
            fw.gates(), fw.duty()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cpu", action="append", help="cores (default cortex-m4f and cortex-m0plus)")
    p.add_argument("--turns", type=int, default=20, help="electrical turns of Hall edges (6 edges each)")
    args = p.parse_args()
    from hil.pil.build import build_elf
    from hil.pil.firmware import PilFirmware
    from hil.pil.target import read_target
    from hil.sil.build import build, read_build_spec
    from hil.sil.firmware import Firmware

    spec = read_build_spec(ROOT / "firmware" / "reference")
    sil = Firmware(str(build(spec).library))
    t0 = time.perf_counter()
    drive(sil, args.turns)
    sil_s = time.perf_counter() - t0
    calls = 6 * args.turns * 5
    out = {"sil_us_per_interrupt": sil_s / calls * 1e6}
    for cpu in args.cpu or ["cortex-m4f", "cortex-m0plus"]:
        target = read_target({"cpu": cpu, "clock_hz": 168_000_000 if cpu != "cortex-m0plus" else 64_000_000,
                              "flash_bytes": 1 << 20, "ram_bytes": 196608, "stack_bytes": 4096}, "bench")
        fw = PilFirmware(build_elf(spec, target).elf, target)
        core = fw.core
        i0 = core.instructions
        t0 = time.perf_counter()
        drive(fw, args.turns)
        wall = time.perf_counter() - t0
        stats = fw.stats()
        pil = {"wall_us_per_interrupt": wall / calls * 1e6,
               "ratio_to_sil": wall / sil_s,
               "instructions_per_interrupt": (core.instructions - i0) / calls,
               "interrupts": stats["interrupts"], "stack": stats["stack"], "flash": stats["flash"],
               "ram": stats["ram"], "translated_blocks": len(core._blocks)}
        out[cpu] = pil
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
