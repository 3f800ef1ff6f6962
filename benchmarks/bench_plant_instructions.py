"""The plant's cost in instructions per simulated second, this checkout against a base revision in the
same run: ``python benchmarks/bench_plant_instructions.py [--base REV]`` (needs valgrind).

Wall and CPU time on a shared machine move with its load (the CPU time too: two hyperthreads of
one core slow each other); an instruction count does not. valgrind's callgrind counts every
instruction executed inside numba's ``call_cfunc`` (the compiled plant and the unboxing of its
arguments), repeatable to a few dozen instructions in a hundred million. valgrind knows no
AVX-512, so both checkouts are compiled for one fixed target (``haswell``, its features listed
below) into a numba cache of their own, natively first, then loaded under valgrind: the figures
compare source with source, not this processor's code with another's.

Cases as ``bench_plant.py``: one simulated second at 15,000 rpm with 100 kHz outputs, oracle
commutation, and raw Hall with all Hall effects (plus a 1 ms warm-up run, the same in both).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from _against_base import PYTHON, ROOT, arguments, base_checkout

TARGET_CPU = "haswell"
TARGET_FEATURES = ("+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+cx8,+f16c,+fma,+fxsr,+lzcnt,+mmx,+movbe,+popcnt,"
                   "+sahf,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave,+aes,+pclmul")
CASES = ("oracle", "raw")


def child(case: str, sim_s: float) -> None:
    """One run of the plant of the checkout on PYTHONPATH (no timing: valgrind counts)."""
    from bldc.motor import steady_state
    from plant_models import OracleCommutation, RawHallCommutation, Simulation, paper_bench

    # after the checkout's own plant_models is imported: bench_plant puts its checkout first on sys.path
    from bench_plant import ALL_HALL_EFFECTS

    source = OracleCommutation() if case == "oracle" else RawHallCommutation()
    config = paper_bench().with_effects(*(ALL_HALL_EFFECTS if case == "raw" else ()))
    speed = 15000.0
    duty = steady_state(config.motor, speed)["duty"]
    Simulation(config, source, duty=duty, initial_speed_rpm=speed).run_until(1e-3)
    sim = Simulation(config, source, duty=duty, initial_speed_rpm=speed, sample_rate_hz=100e3, capacity=1 << 17)
    sim.run_until(sim_s)
    print(len(sim.edges()))


def count(checkout: Path, tag: str, case: str, sim_s: float = 1.0) -> tuple[int, int]:
    """(instructions inside the compiled plant, edges) of one run of ``checkout``'s plant."""
    work = Path(tempfile.gettempdir()) / "hil-bench-instructions"
    work.mkdir(exist_ok=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(checkout), str(Path(__file__).parent)]),
           "NUMBA_CPU_NAME": TARGET_CPU, "NUMBA_CPU_FEATURES": TARGET_FEATURES, "NUMBA_NUM_THREADS": "1",
           "NUMBA_CACHE_DIR": str(work / f"numba-{tag}"), "PYTHONHASHSEED": "0"}
    me = [PYTHON, str(Path(__file__).resolve()), "--child", case]
    subprocess.run([*me, "0.001"], cwd=checkout, env=env, check=True, capture_output=True)  # compile natively
    out = work / f"callgrind.{tag}.{case}"
    proc = subprocess.run(["valgrind", "--tool=callgrind", "--collect-atstart=no", "--toggle-collect=call_cfunc*",
                           f"--callgrind-out-file={out}", *me, str(sim_s)], cwd=checkout, env=env,
                          capture_output=True, text=True, check=True)
    collected = [ln for ln in proc.stderr.splitlines() if "Collected :" in ln]
    return int(collected[-1].split()[-1]), int(proc.stdout.split()[-1])


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--child":
        child(sys.argv[2], float(sys.argv[3]))
        return
    args = arguments(__doc__).parse_args()
    for case in CASES:
        head, edges = count(ROOT, "head", case)
        line = f"{case:6s} this checkout: {head / 1e6:8.2f} M instructions per simulated second ({edges} edges)"
        if not args.no_base:
            base, base_edges = count(base_checkout(args.base), args.base, case)
            line += (f"; {args.base}: {base / 1e6:8.2f} M ({base_edges} edges); "
                     f"ratio {head / base:.4f}")
        print(line, flush=True)


if __name__ == "__main__":
    main()
