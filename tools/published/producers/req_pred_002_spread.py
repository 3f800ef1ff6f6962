"""docs/sage-husa.md, REQ-PRED-002: Sage-Husa over the KF per operating profile, held-out seeds."""

from __future__ import annotations

import re
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_tool


def produce_req_pred_002_spread(work: Path) -> Run:
    """docs/sage-husa.md, REQ-PRED-002: the controller's defaults, Sage-Husa over the KF per operating
    profile over ten held-out seeds, in-process (``tools/req_pred_002_spread.py``)."""
    run = Run(seeds=list(range(10)))
    out = run_tool(run, "req_pred_002_spread.py").stdout
    profiles = re.findall(r"\n(\w+) ([\d,\- ]+rpm[^\n]*?), acceptance plant.*?\nSH/KF of the mean RMS ([\d.]+); "
                          r"per seed ([\d.]+)-([\d.]+) .*?SH ahead on (\d+) of (\d+)", out, re.S)
    pooled = re.search(r"pooled SH/KF over (\d+) runs: ([\d.]+); per run ([\d.]+)-([\d.]+); leaving one seed out "
                       r"([\d.]+)-([\d.]+)", out)
    if not profiles or not pooled:
        raise RuntimeError(f"tools/req_pred_002_spread.py printed no summary:\n{out[-1500:]}")
    rows = [["profile", "Sage-Husa / KF (pooled)", "per seed", "Sage-Husa ahead"]]
    ratio = dict(tolerance_abs=0.01, fmt="{:.3f}")
    ahead_total = 0
    for name, rpm, r, lo, hi, ahead, n in profiles:
        run.figures[f"{name}.ratio"] = Figure(float(r), "", **ratio)
        run.figures[f"{name}.ahead"] = Figure(int(ahead), "", "{:d}", tolerance_abs=2)
        ahead_total += int(ahead)
        rows.append([f"{name}, {rpm}", r, f"{lo}-{hi}", f"{ahead} of {n}"])
    n_runs, r, lo, hi, loo_lo, loo_hi = pooled.groups()
    rows.append([f"all {n_runs} runs", f"**{r}**", f"{lo}-{hi}", f"{ahead_total} of {n_runs}"])
    run.figures["pooled_ratio"] = Figure(float(r), "", **ratio)
    run.figures["leave_one_out_low"] = Figure(float(loo_lo), "", **ratio)
    run.figures["leave_one_out_high"] = Figure(float(loo_hi), "", **ratio)
    for name in ("paper", "high"):  # "N % behind the KF" in the prose
        if f"{name}.ratio" in run.figures:
            run.figures[f"{name}.behind_pct"] = Figure(100 * (run.figures[f"{name}.ratio"].value - 1), "%",
                                                       "{:.1f}", tolerance_abs=1.0)
    run.tables["profiles"] = rows
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("req_pred_002_spread", "docs/sage-husa.md: REQ-PRED-002 per operating profile, held-out seeds", False,
          produce_req_pred_002_spread, inputs(__file__, *HIL, "tools/req_pred_002_spread.py")),
)
