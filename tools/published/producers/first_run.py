"""docs/acceptance.md: the default acceptance on fresh clones, compile included, then warm."""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from ..model import ROOT, Figure, Group, Run
from .common import SUITE, inputs


#: fresh clones measured by ``first_run``: its wall time varies by ten seconds and more from run to
#: run on a shared machine, so the figure is the median, and the slowest is published beside it
FIRST_RUN_CLONES = 3


def produce_first_run(work: Path) -> Run:
    """README's first command on fresh clones of HEAD (each numba cache empty: the compile
    included), then once more on the last one's warm cache: wall times and the first result's
    instant."""
    run = Run(commands=["git clone <repository> fresh && cd fresh", "python -m hil acceptance",
                        "python -m hil acceptance"])
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}

    def acceptance(clone: Path, out: Path) -> tuple[float, int | None, str]:
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "hil", "acceptance", "-o", str(out)], cwd=clone, env=env,
                              capture_output=True, text=True, timeout=1800)
        wall = time.perf_counter() - t0
        # the progress lines: "[ 1/37  0:18] passed   <test>" (count, elapsed m:ss, outcome)
        first = re.search(r"^\[\s*\d+/\d+\s+(\d+):(\d\d)\] (?:passed|failed|skipped|error)", done.stdout, re.M)
        verdict = re.search(r"hil acceptance: (\w+)", done.stdout)
        return wall, 60 * int(first[1]) + int(first[2]) if first else None, (
            verdict[1] if verdict else f"exit {done.returncode}")

    fresh = []
    for k in range(FIRST_RUN_CLONES):
        clone = work / f"fresh{k}"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        fresh.append(acceptance(clone, work / f"fresh{k}-report"))
    warm = acceptance(clone, work / "warm-report")
    walls = sorted(w for w, _, _ in fresh)
    firsts = sorted(f for _, f, _ in fresh if f is not None)
    verdicts = sorted({v for _, _, v in fresh} | {warm[2]})
    run.figures = {
        "fresh_wall_s": Figure(float(statistics.median(walls)), "s", "{:.0f}", reproducible=False),
        "fresh_wall_max_s": Figure(walls[-1], "s", "{:.0f}", reproducible=False),
        "fresh_clones": Figure(FIRST_RUN_CLONES, "", "{:d}"),
        "fresh_first_result_s": Figure(float(statistics.median(firsts)) if firsts else None, "s", "{:.0f}",
                                       reproducible=False),
        "warm_wall_s": Figure(warm[0], "s", "{:.0f}", reproducible=False),
        "verdict": Figure(", ".join(verdicts), fmt="{}"),
    }
    return run


GROUPS = (
    Group("first_run", "docs/acceptance.md: the default acceptance on a fresh clone, compile included, then warm",
          False, produce_first_run, inputs(__file__, *SUITE)),
)
