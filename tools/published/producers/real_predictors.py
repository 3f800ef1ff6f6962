"""docs/sage-husa.md: every predictor on a shipped real capture (``hil predictors compare``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from ..model import Figure, Group, Run
from .common import HIL, SPINDLE, capture, import_capture, inputs, run_hil


def _produce_real_predictors(vcd: str) -> Callable[[Path], Run]:
    def produce(work: Path) -> Run:
        run = Run()
        rec = import_capture(run, work, vcd)
        out = work / f"{rec.name}-predictors.json"
        run_hil(run, work, "predictors", "compare", str(rec), "--json", str(out))
        result = json.loads(out.read_text())
        rows = [["predictor", "RMS deg e", "p99 deg e", "max deg e", "edges scored"]]
        for p in result["predictors"]:
            run.figures[f"{p['name']}.rms_deg_e"] = Figure(
                p["angle_rms_deg_e"], "deg e", "{:.2f}", tolerance_abs=0.02, tolerance_rel=0.02
            )
            rows.append(
                [
                    p["name"],
                    f"{p['angle_rms_deg_e']:.2f}",
                    f"{p['angle_p99_deg_e']:.2f}",
                    f"{p['angle_max_deg_e']:.2f}",
                    f"{p['edges_scored']:d}",
                ]
            )
        best = min(result["predictors"], key=lambda p: p["angle_rms_deg_e"])
        run.figures["best"] = Figure(best["name"])
        run.tables["predictors"] = rows
        return run

    return produce


GROUPS = (
    Group("spindle_predictors", "docs/sage-husa.md: every predictor on the spindle capture", True,
          _produce_real_predictors(SPINDLE), inputs(__file__, *HIL, capture(SPINDLE))),
)
