"""docs/sage-husa.md: every predictor in a simulated scenario (``hil predictors compare --scenario``):
the held-out pumps and the paper's speed step."""

from __future__ import annotations

import json
import re
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_hil


def _predictor_table(run: Run, result: dict, columns, tol_abs: float) -> list[list[str]]:
    """One row per predictor of ``hil predictors compare --json``; each cell also a figure."""
    rows = [["predictor"] + [label for _, label in columns]]
    for p in result["predictors"]:
        for key, _ in columns:
            if p.get(key) is not None:
                run.figures[f"{p['name']}.{key}"] = Figure(
                    p[key], "deg e", "{:.3f}", tolerance_abs=tol_abs, tolerance_rel=0.03
                )
        rows.append([p["name"]] + [f"{p[k]:.3f}" if p.get(k) is not None else "n/a" for k, _ in columns])
    return rows


def _scenario_seeds(result: dict) -> list[int]:
    """The seeds a scenario's ``source`` line names ("seeds 1000-1023" or "seeds [0, 1, ...]")."""
    text = result["source"].split("seeds", 1)[1]
    m = re.match(r"\s*(\d+)-(\d+)", text)
    if m:
        return list(range(int(m[1]), int(m[2]) + 1))
    return [int(x) for x in re.findall(r"\d+", text.split("]")[0])]


def _compare(work: Path, scenario: str) -> tuple[Run, dict]:
    """``hil predictors compare --scenario SCENARIO``: the run (its command and seeds) and its JSON."""
    run = Run()
    out = work / f"{scenario}.json"
    run_hil(run, work, "predictors", "compare", "--scenario", scenario, "--json", str(out))
    result = json.loads(out.read_text())
    run.seeds = _scenario_seeds(result)
    return run, result


def produce_pump_predictors(work: Path) -> Run:
    run, result = _compare(work, "pumps")
    columns = (("angle_rms_deg_e", "mean RMS"), ("angle_rms_median_deg_e", "median RMS"),
               ("angle_p99_deg_e", "mean p99"), ("angle_max_deg_e", "max"))
    run.tables["predictors"] = _predictor_table(run, result, columns, 0.005)
    run.figures["sage_husa_over_kf_median_rms"] = Figure(
        result["sage_husa_over_kf_median_rms"], "", "{:.3f}", tolerance_abs=0.01
    )
    # pump by pump: how often Sage-Husa is ahead of the KF, and the pump the KF does worst on
    by_pump = [{r["name"]: r["angle_rms_deg_e"] for r in pump["predictors"]} for pump in result["pumps"]]
    ratios = [p["sage_husa"] / p["kf"] for p in by_pump]
    run.figures["pumps"] = Figure(len(by_pump), "", "{:d}")
    run.figures["sage_husa_ahead_of_kf_pumps"] = Figure(sum(r < 1.0 for r in ratios), "", "{:d}", tolerance_abs=2)
    run.figures["sage_husa_over_kf_min"] = Figure(min(ratios), "", "{:.2f}", tolerance_abs=0.05)
    run.figures["sage_husa_over_kf_max"] = Figure(max(ratios), "", "{:.2f}", tolerance_abs=0.05)
    worst = max(range(len(by_pump)), key=lambda j: by_pump[j]["kf"])
    run.figures["kf_worst_pump_seed"] = Figure(run.seeds[worst] if run.seeds else worst, "", "{:d}")
    for name in ("kf", "sage_husa", "vb_akf", "pll"):
        run.figures[f"kf_worst_pump.{name}_rms_deg_e"] = Figure(
            by_pump[worst][name], "deg e", "{:.2f}", tolerance_abs=0.01, tolerance_rel=0.05
        )
    return run


def produce_paper_predictors(work: Path) -> Run:
    run, result = _compare(work, "paper")
    columns = (("angle_rms_deg_e", "RMS"), ("angle_p99_deg_e", "p99"), ("angle_max_deg_e", "max"))
    run.tables["predictors"] = _predictor_table(run, result, columns, 0.003)
    return run


GROUPS = (
    Group("pump_predictors", "docs/sage-husa.md: every predictor on the held-out pumps", False,
          produce_pump_predictors, inputs(__file__, *HIL), rotation=True),
    Group("paper_predictors", "docs/sage-husa.md: every predictor in the paper's speed-step scenario", False,
          produce_paper_predictors, inputs(__file__, *HIL), rotation=True),
)
