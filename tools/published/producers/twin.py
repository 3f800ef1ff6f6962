"""docs/twin.md: a shipped capture's twin, checked against the capture and put through the suite."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

from ..model import Figure, Group, Run
from .common import HOVERBOARD, REAL_CAPTURES, SPINDLE, SUITE, capture, inputs, run_hil


def _produce_twin(vcd: str) -> Callable[[Path], Run]:
    """docs/twin.md: the capture's twin (``hil twin from-capture``), checked against the capture
    (``hil twin check``) and put through the acceptance suite in-process (``hil acceptance --plant``)."""

    def produce(work: Path) -> Run:
        run = Run(seeds=[0])
        twin = work / f"{Path(vcd).stem}-twin.toml"
        run_hil(run, work, "twin", "from-capture", str(REAL_CAPTURES / vcd), "-o", str(twin))
        check = work / f"{Path(vcd).stem}-twin-check.json"
        run_hil(run, work, "twin", "check", str(REAL_CAPTURES / vcd), str(twin), "--json", str(check))
        result = json.loads(check.read_text())
        delay = {side: result["calibration"][side]["rise_fall_delay_difference_s"] for side in ("real", "twin")}
        for side, d in delay.items():
            run.figures[f"delay_{side}_us"] = Figure(d["value"] * 1e6, "us", "{:.1f}", tolerance_abs=0.5)
            run.figures[f"delay_{side}_stderr_us"] = Figure(d["stderr"] * 1e6, "us", "{:.1f}", tolerance_abs=0.5)
        rows = [["predictor", "real RMS deg e", "twin RMS deg e", "twin / real"]]
        for p in result["predictors"]:
            run.figures[f"ratio.{p['name']}"] = Figure(p["ratio"], "", "{:.2f}", tolerance_abs=0.03)
            rows.append([p["name"], f"{p['real_rms_deg_e']:.2f}", f"{p['twin_rms_deg_e']:.2f}", f"{p['ratio']:.2f}"])
        run.tables["predictors"] = rows
        report_dir = work / f"{Path(vcd).stem}-acceptance"
        t0 = time.perf_counter()
        try:
            run_hil(run, work, "acceptance", "--plant", str(twin), "--dut", "virtual:in-process", "-o",
                 str(report_dir))
        except RuntimeError:
            pass  # a FAIL verdict exits 1; the report says what happened
        run.figures["acceptance_wall_s"] = Figure(time.perf_counter() - t0, "s", "{:.0f}", reproducible=False)
        report = json.loads((report_dir / "hil-report.json").read_text())
        run.figures["acceptance_verdict"] = Figure(str(report["verdict"]))
        for outcome in ("passed", "failed", "error", "skipped"):
            run.figures[f"acceptance_{outcome}"] = Figure(int(report["counts"].get(outcome, 0)), "", "{:d}")
        rows = [["requirement", "verdict", "worst budget measured (limit)"]]
        for req in report["traceability"]:
            if not req["traced"]:
                continue
            run.figures[f"verdict.{req['id']}"] = Figure(str(req["verdict"]))
            # every budget its tests judged (a calibration test judges REQ-COMM-001's angle budget too),
            # the worst by its margin over its limit
            measured = [m for t in req["tests"] for m in t["measurements"]]
            worst = min(measured, key=lambda m: m["margin"] / max(abs(m["limit"]), 1e-12)) if measured else None
            bound = "-" if worst is None else "<=" if worst["limit_kind"] == "max" else ">="
            rows.append([req["id"], req["verdict"],
                         f"{worst['budget']} {worst['measured']:.3g} {worst['unit']} ({bound} {worst['limit']:g})"
                         if worst else "-"])
        run.tables["acceptance"] = rows
        return run

    return produce


GROUPS = (
    Group("spindle_twin", "docs/twin.md: the spindle's twin, checked and put through the suite", False,
          _produce_twin(SPINDLE), inputs(__file__, *SUITE, capture(SPINDLE))),
    Group("hoverboard_twin", "docs/twin.md: the hoverboard's twin, checked and put through the suite", False,
          _produce_twin(HOVERBOARD), inputs(__file__, *SUITE, capture(HOVERBOARD))),
)
