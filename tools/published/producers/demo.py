"""README's tour, step 1: the paper-bench demo's captured-edge error and its printout."""

from __future__ import annotations

import re
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_hil


def produce_demo(work: Path) -> Run:
    run = Run(seeds=[0])
    done = run_hil(run, work, "paper", "demo", "-o", str(work / "demo"))
    m = re.search(r"all edges: mean ([\d.\-]+), RMS ([\d.]+), max \|err\| ([\d.]+)", done.stdout)
    if not m:
        raise RuntimeError(f"hil paper demo printed no summary line:\n{done.stdout[-1500:]}")
    mean, rms, worst = (float(g) for g in m.groups())
    tol = dict(tolerance_abs=0.01, unit="deg e", fmt="{:.3f}")
    run.figures = {
        "mean_deg_e": Figure(mean, **tol),
        "rms_deg_e": Figure(rms, **tol),
        "max_deg_e": Figure(worst, **tol),
    }
    # the table as printed, without the last line (where the recording was written)
    run.blocks["output"] = "".join(line + "\n" for line in done.stdout.splitlines() if " written to " not in line)
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("demo", "README tour step 1: the paper-bench demo's captured-edge error", True, produce_demo,
          inputs(__file__, *HIL)),
)
