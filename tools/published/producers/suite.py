"""README: the test command's run time (the group ``test_suite``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from ..model import ROOT, Figure, Group, Run
from .common import inputs


def produce_test_suite(work: Path) -> Run:
    """The README's second command (pytest only; the install is timed apart by CI)."""
    run = Run(commands=["python -m pytest -q"])
    t0 = time.perf_counter()
    env = {**os.environ, "HIL_FIGURES_RUNNING": "test_suite"}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=ROOT,
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    m = re.search(r"(\d+) passed", done.stdout)
    failed = [line for line in done.stdout.splitlines() if line.startswith(("FAILED ", "ERROR "))]
    if failed:  # what made the exit status, kept with the figures
        run.blocks["failures"] = "\n".join(failed) + "\n"
    run.figures = {
        "wall_s": Figure(wall, "s", "{:.0f}", reproducible=False),
        "passed": Figure(int(m.group(1)) if m else 0, "", "{:d}", reproducible=False),
        "exit_status": Figure(done.returncode, "", "{:d}"),
    }
    return run


GROUPS = (
    # everything the suite reads but the figures' own output: each figures commit rewrites the file and
    # the pages, and the suite's tests of them (tests/test_figures.py, tests/test_readme.py) run in CI on
    # every commit anyway, as the whole suite does
    Group("test_suite", "README: the test command's run time", False, produce_test_suite,
          inputs(__file__, "**", "!docs/figures.json", "!docs/*.md", "!README.md")),
)
