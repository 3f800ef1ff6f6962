"""docs/gap.md, "Validation": ``hil gap validate`` at its default size."""

from __future__ import annotations

import json
from pathlib import Path

from ..model import Figure, Group, Run
from .common import HIL, inputs, run_hil


def produce_gap_validation(work: Path) -> Run:
    """docs/gap.md, "Validation": ``hil gap validate`` at its default size, the figures at SNR >= 3
    against their bars."""
    run = Run(seeds=[0])
    out = work / "validate.json"
    run_hil(run, work, "gap", "validate", "--no-progress", "--json", str(out), timeout_s=7200)
    s = json.loads(out.read_text())["summary_snr_ge_3"]

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f} %"

    for key in ("top1_rate", "top3_rate", "false_alarm_rate", "no_trace_alarm_rate", "unexplained_rate",
                "param_within_20pct_rate", "median_param_error", "median_heldout_shrink",
                "two_effect_both_found_rate"):
        run.figures[key] = Figure(None if s.get(key) is None else 100 * s[key], "%", "{:.1f}", tolerance_abs=2.0)
    electrical = s.get("top1_rate_by_generator", {}).get("electrical")
    run.tables["snr3"] = [
        ["at SNR >= 3", "measured", "bar"],
        ["top-1 identification", f"{pct(s['top1_rate'])} ({s['single_cases']} cases; {pct(electrical)} on the "
                                 "electrical plant)", ">= 90 %"],
        ["top-3 identification", pct(s["top3_rate"]), ">= 98 %"],
        ["false alarms on null recordings", f"{pct(s['false_alarm_rate'])} ({s['null_cases']})", "<= 5 %"],
        ["dead time withheld, flagged", f"{pct(s['no_trace_alarm_rate'])} ({s['no_trace_cases']})", "(no trace)"],
        ["out-of-library called unexplained", f"{pct(s['unexplained_rate'])} ({s['out_of_library_cases']})",
         ">= 90 %"],
        ["fitted magnitudes within 20 %", f"{pct(s['param_within_20pct_rate'])} (median error "
                                          f"{pct(s['median_param_error'])})", "within 20 %"],
        ["median held-out shrink", pct(s["median_heldout_shrink"]), ">= 80 %"],
        ["both of two withheld effects found", f"{pct(s['two_effect_both_found_rate'])} ({s['two_effect_cases']})",
         "(reported)"],
    ]
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("gap_validation", "docs/gap.md: hil gap validate at its default size", False, produce_gap_validation,
          inputs(__file__, *HIL)),
)
