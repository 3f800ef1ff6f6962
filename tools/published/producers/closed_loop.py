"""docs/sage-husa.md, "Closed loop": Sage-Husa through the controller against its offline replay."""

from __future__ import annotations

import re
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_hil


def produce_closed_loop(work: Path) -> Run:
    """docs/sage-husa.md, "Closed loop": ``hil table5 --closed-loop`` (seed 0), Sage-Husa through the
    controller on every link against its offline replay, and the filter's counters."""
    run = Run(seeds=[0])
    done = run_hil(run, work, "table5", "--closed-loop", "--json", str(work / "closed-loop.json"))
    found = re.findall(r"^(in-process|canopen|modbus)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)\s+"
                       r"(\d+)\s+(\d+)\s+(\d+)\s*$", done.stdout, re.M)
    if len(found) != 3:
        raise RuntimeError(f"hil table5 --closed-loop printed no table:\n{done.stdout[-1500:]}")
    rows = [["link", "commutations", "closed loop RMS deg e", "offline RMS deg e", "ratio", "gated edges",
             "covariance repairs", "divergence fades", "band projections"]]
    for link, n, cl, off, ratio, gated, repairs, fades, band in found:
        rows.append([link, n, cl, off, ratio, gated, repairs, fades, band])
        key = link.replace("-", "_")
        run.figures[f"{key}.ratio"] = Figure(float(ratio), "", "{:.3f}", tolerance_abs=0.01)
        run.figures[f"{key}.closed_loop_rms_deg_e"] = Figure(float(cl), "deg e", "{:.4f}", tolerance_rel=0.03)
        run.figures[f"{key}.repairs"] = Figure(int(repairs), "", "{:d}")
    run.tables["links"] = rows
    return run


GROUPS = (
    Group("closed_loop", "docs/sage-husa.md: Sage-Husa through the controller against its offline replay", False,
          produce_closed_loop, inputs(__file__, *HIL), rotation=True),
)
