"""README: the default acceptance run's verdict and run time."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from ..model import Figure, Group, Run
from .common import SUITE, find, inputs, run_hil


def produce_acceptance(work: Path) -> Run:
    """The README's first command, timed (wall and CPU time of the whole run)."""
    run = Run()
    t0, c0 = time.perf_counter(), _children_cpu_s()
    report_dir = work / "acceptance"
    try:
        run_hil(run, work, "acceptance", "-o", str(report_dir))
    except RuntimeError:
        pass  # the verdict below says what happened
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    report = json.loads((report_dir / "hil-report.json").read_text())
    run.commands[-1] = "python -m hil acceptance"
    run.figures = {
        "verdict": Figure(str(find(report, "verdict"))),
        "wall_s": Figure(wall, "s", "{:.0f}", reproducible=False),
        "cpu_s": Figure(cpu, "s", "{:.0f}", reproducible=False),
    }
    return run


def _children_cpu_s() -> float:
    t = os.times()
    return t.children_user + t.children_system


GROUPS = (
    Group("acceptance", "README: the default acceptance run's verdict and run time", False, produce_acceptance,
          inputs(__file__, *SUITE)),
)
