"""docs/real-captures.md: a shipped real capture calibrated (``hil calibrate``), one group per capture."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from ..model import Figure, Group, Run
from .common import HIL, HOVERBOARD, SPINDLE, capture, find, import_capture, inputs, run_hil


def _calibration_figures(corrections: dict) -> dict[str, Figure]:
    """The ordinary-run calibration's headline figures with their standard errors."""
    figures: dict[str, Figure] = {}
    for key, name, scale, unit, fmt in (
        ("rise_fall_delay_difference_s", "delay_difference_us", 1e6, "us", "{:.1f}"),
        ("rise_fall_angle_asymmetry_deg_e", "asymmetry_deg_e", 1.0, "deg e", "{:.2f}"),
    ):
        item = corrections.get(key)
        if not isinstance(item, dict) or item.get("value") is None:
            continue
        value, stderr = item["value"] * scale, (item.get("stderr") or 0.0) * scale
        # a recomputation must agree within the figure's own stated uncertainty
        figures[name] = Figure(value, unit, fmt, tolerance_abs=max(stderr, 1e-3 * abs(value)))
        figures[name + "_stderr"] = Figure(stderr, unit, "{:.1f}" if unit == "us" else "{:.2f}",
                                           tolerance_abs=max(0.25 * stderr, 1e-6))
    check = (corrections.get("method_cross_check") or {}).get("rise_fall_delay_difference_s")
    if isinstance(check, dict) and check.get("value") is not None:
        figures["cross_check_delay_difference_us"] = Figure(
            check["value"] * 1e6, "us", "{:.1f}", tolerance_abs=max((check.get("stderr") or 0) * 1e6, 0.1)
        )
        check_stderr_us = (check.get("stderr") or 0) * 1e6
        figures["cross_check_delay_difference_us_stderr"] = Figure(
            check_stderr_us, "us", "{:.1f}", tolerance_abs=max(0.25 * check_stderr_us, 0.05)
        )
    pp = find(corrections, "pole_pairs")
    if isinstance(pp, (int, float)):
        figures["pole_pairs"] = Figure(int(pp), "", "{:d}")
    return figures


def _produce_real_calibration(vcd: str) -> Callable[[Path], Run]:
    def produce(work: Path) -> Run:
        run = Run()
        rec = import_capture(run, work, vcd)
        out = work / f"{rec.name}-corrections.json"
        run_hil(run, work, "calibrate", str(rec), "--json", str(out))
        run.figures = _calibration_figures(json.loads(out.read_text()))
        if not run.figures:
            raise RuntimeError(f"hil calibrate {rec}: no rise-fall figures in {out}")
        return run

    return produce


GROUPS = (
    Group("spindle_calibration", "docs/real-captures.md: the spindle capture calibrated", True,
          _produce_real_calibration(SPINDLE), inputs(__file__, *HIL, capture(SPINDLE))),
    Group("hoverboard_calibration", "docs/real-captures.md: the hoverboard speed cycles calibrated", False,
          _produce_real_calibration(HOVERBOARD), inputs(__file__, *HIL, capture(HOVERBOARD)), rotation=True),
)
