"""``hil acceptance`` on a fresh numba cache against a warm one, against the base revision (issue 40, item 5).

``python benchmarks/bench_first_run.py [--base REV [--base-dir DIR] | --no-base] [--full] [-k EXPR]``

Each checkout runs ``hil acceptance`` twice from its own directory with ``NUMBA_CACHE_DIR``
pointed at a new empty directory: the first run compiles (a fresh clone's first run), the second
loads the cache. By default the suite is cut to the eight "calibration removes the deviation"
tests (``-k``), which use the plant, the filters and both links on both workers: the compile is
the part that differs, and this keeps a measurement to minutes on a shared machine; ``--full``
runs the whole default suite. Each figure: wall and CPU seconds of the command and everything it
started, the load before and after, and the time to the first test's result.
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from _against_base import PYTHON, ROOT, arguments, base_checkout, timed

FIRST = re.compile(r"^\[\s*\d+/\d+\s+(\d+):(\d+)\]", re.M)


def _runs(cwd: Path, select: str | None) -> list[tuple[str, dict]]:
    cache = tempfile.mkdtemp(prefix="bench-first-run-numba-")
    out = []
    for what in ("fresh cache", "warm cache"):
        reports = tempfile.mkdtemp(prefix="bench-first-run-")
        cmd = [PYTHON, "-m", "hil", "acceptance", "--report-dir", reports]  # the spelling both revisions know
        if select:
            cmd += ["--", "-k", select]
        os.environ["NUMBA_CACHE_DIR"] = cache  # timed() passes this environment on
        try:
            r = timed(cmd, cwd)
        finally:
            del os.environ["NUMBA_CACHE_DIR"]
        m = FIRST.search(r["stdout"])
        r["first_s"] = int(m.group(1)) * 60 + int(m.group(2)) if m else None
        out.append((what, r))
    return out


def _line(label: str, what: str, r: dict) -> str:
    first = f"{r['first_s']} s" if r["first_s"] is not None else "-"
    return (f"{label}, {what}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU, first result at {first}, exit "
            f"{r['returncode']}, load {r['load'][0]:.1f} -> {r['load'][1]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    parser = arguments(__doc__)
    parser.add_argument("--base-dir", help="an existing checkout of the base revision (instead of a git worktree)")
    parser.add_argument("--full", action="store_true", help="the whole default suite")
    parser.add_argument("-k", default="removes_the_deviation", help="pytest -k of the cut suite")
    args = parser.parse_args()
    select = None if args.full else args.k
    checkouts = [("this checkout", ROOT)]
    if not args.no_base:
        checkouts.append((args.base, Path(args.base_dir) if args.base_dir else base_checkout(args.base)))
    for label, cwd in checkouts:
        for what, r in _runs(cwd, select):
            print(_line(label, what, r), flush=True)
