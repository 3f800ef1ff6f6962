"""``hil --help``, wall and CPU time, against the base revision (goal, issue 40: under 0.3 s).

``python benchmarks/bench_cli_help.py [--repeat N] [--nice N] [--base REV [--base-dir DIR] | --no-base]``:
each checkout runs ``python -m hil --help`` N times (default 10) from its own directory; the figure is the median
and the fastest run (the fastest is the one the machine's other work disturbed least). A second
figure is what ``import hil.cli`` loads (modules and the heavy ones among them). The test suite
holds only the imports (tests/test_cli_grammar.py); the time is this figure, not a test.
"""

from __future__ import annotations

import os
import statistics
import subprocess

from _against_base import PYTHON, ROOT, arguments, base_checkout, timed

HEAVY = ("numpy", "numba", "scipy", "plant_models")


def _runs(cwd, repeat: int, nice: int = 0) -> list[dict]:
    def raise_priority():
        os.nice(nice)

    kwargs = {"preexec_fn": raise_priority} if nice else {}
    return [timed([PYTHON, "-m", "hil", "--help"], cwd, **kwargs) for _ in range(repeat)]


def _summary(what: str, runs: list[dict]) -> str:
    wall = sorted(r["wall_s"] for r in runs)
    cpu = sorted(r["cpu_s"] for r in runs)
    load = runs[0]["load"][0], runs[-1]["load"][1]
    return (f"{what}: hil --help median {statistics.median(wall):.3f} s wall (fastest {wall[0]:.3f} s), "
            f"median {statistics.median(cpu):.3f} s CPU; {len(runs)} runs, load {load[0]:.1f} -> {load[1]:.1f}")


def _imports(cwd) -> str:
    code = ("import sys; n = len(sys.modules); import hil.cli; hil.cli.build_parser(); "
            f"print(len(sys.modules) - n, sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))")
    out = subprocess.run([PYTHON, "-c", code], cwd=cwd, capture_output=True, text=True,
                         env={"PYTHONPATH": str(cwd), "PATH": ""}).stdout.split(maxsplit=1)
    return f"{out[0]} modules, heavy: {out[1].strip()}" if out else "(import failed)"


if __name__ == "__main__":
    parser = arguments(__doc__)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--base-dir", help="an existing checkout of the base revision (instead of a git worktree)")
    parser.add_argument("--nice", type=int, default=0,
                        help="run each hil --help at this niceness (-20 as root: ahead of a loaded machine's work)")
    args = parser.parse_args()
    head = _runs(ROOT, args.repeat, args.nice)
    print(_summary("this checkout", head) + "; import hil.cli loads " + _imports(ROOT), flush=True)
    if not args.no_base:
        from pathlib import Path

        base_dir = Path(args.base_dir) if args.base_dir else base_checkout(args.base)
        base = _runs(base_dir, args.repeat, args.nice)
        print(_summary(args.base, base) + "; import hil.cli loads " + _imports(base_dir))
        ratio = statistics.median(r["wall_s"] for r in head) / statistics.median(r["wall_s"] for r in base)
        print(f"hil --help: {ratio:.2f} x the median wall time of {args.base}")
