"""docs/calibration.md: raw versus corrected commutation (``hil compare-correction``)."""

from __future__ import annotations

import re
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_hil


def produce_compare_correction(work: Path) -> Run:
    """docs/calibration.md, "Raw versus corrected commutation": ``hil compare-correction``."""
    run = Run(seeds=[0])
    done = run_hil(run, work, "compare-correction", "--plot", str(work / "headline.png"))
    rows = [["strategy", "speed fluctuation MSE", "mean phase current", "commutation error RMS", "p99"]]
    labels = {"raw": "raw Hall edges", "corrected": "corrected edges"}
    found = re.findall(r"^(raw Hall edges|corrected edges)\s+([\d.e+\-]+) rpm2\s+[\d.e+\-]+ rpm2\s+"
                       r"([\d.]+) A\s+([\d.]+) de\s+([\d.]+) de", done.stdout, re.M)
    red = re.search(r"speed MSE ([\d.\-]+)% .*mean phase current ([\d.\-]+)%", done.stdout)
    if len(found) != 2 or not red:
        raise RuntimeError(f"hil compare-correction printed no table:\n{done.stdout[-1500:]}")
    for name, mse, cur, rms_, p99 in found:
        key = "raw" if "raw" in name.lower() else "corrected"
        rows.append([labels[key], f"{float(mse):.2g} rpm^2", f"{float(cur):.4f} A", f"{float(rms_):.2f} deg e",
                     f"{float(p99):.2f} deg e"])
        run.figures[f"{key}.rms_deg_e"] = Figure(float(rms_), "deg e", "{:.2f}", tolerance_abs=0.02)
    run.figures["speed_mse_reduction_pct"] = Figure(float(red[1]), "%", "{:.1f}", tolerance_abs=1.0)
    run.figures["mean_current_reduction_pct"] = Figure(float(red[2]), "%", "{:.1f}", tolerance_abs=0.5)
    run.tables["strategies"] = rows
    return run


GROUPS = (
    Group("compare_correction", "docs/calibration.md: raw versus corrected commutation (paper Section 4.3)", False,
          produce_compare_correction, inputs(__file__, *HIL), rotation=True),
)
