"""docs/real-captures.md: each shipped capture calibrated whole and in halves."""

from __future__ import annotations

import json
from pathlib import Path

from ..model import Figure, Group, Run
from .common import ALL_CAPTURES, CAPTURE_LABELS, HIL, inputs, run_tool


def _pm_text(value: float | None, stderr: float | None, scale: float, fmt: str) -> str:
    if value is None or stderr is None:
        return "-"
    return f"{fmt.format(value * scale)} +- {stderr * scale:.2g}"


def produce_capture_halves(work: Path) -> Run:
    """docs/real-captures.md: each shipped capture calibrated whole, and its halves calibrated alone
    (``tools/calibration_coverage.py --captures 0 --halves``)."""
    run = Run()
    out = work / "halves.json"
    run_tool(run, "calibration_coverage.py", "--captures", "0", "--halves", "--json", str(out))
    result = json.loads(out.read_text())["halves"]
    halves = [["capture", "delay difference, halves", "z", "asymmetry z", "installation z (A, B, C)",
               "pole offsets: largest z"]]
    whole = [["capture", "rise-minus-fall delay `D`", "method cross-check: `D` (constant asymmetry)",
              "constant asymmetry", "pole pairs found"]]
    for stem, label in CAPTURE_LABELS.items():
        h = result[stem]
        rows = {r["figure"]: r for r in h["rows"]}
        key = stem.split("-", 1)[1].replace("-", "_")
        d = rows["delay_difference"]
        z = dict(tolerance_abs=0.3, fmt="{:.1f}")
        run.figures[f"{key}.delay_z"] = Figure(d["z"], "", **z)
        run.figures[f"{key}.asymmetry_z"] = Figure(rows["asymmetry"]["z"], "", **z)
        poles = [r["z"] for name, r in rows.items() if name.startswith("pole ")]
        if poles:
            run.figures[f"{key}.pole_z_max"] = Figure(max(poles), "", **z)
        for i, part in enumerate(("first", "second")):
            run.figures[f"{key}.delay_{part}_half_us"] = Figure(d["halves"][i] * 1e6, "us", "{:.1f}",
                                                                tolerance_abs=max(0.5, 0.25 * d["stderr"][i] * 1e6))
            run.figures[f"{key}.delay_{part}_half_stderr_us"] = Figure(d["stderr"][i] * 1e6, "us", "{:.2g}",
                                                                       tolerance_rel=0.25)
        halves.append([
            label,
            " / ".join(_pm_text(a, s_, 1e6, "{:+.4g}") for a, s_ in zip(d["halves"], d["stderr"])) + " us",
            f"{d['z']:.1f}", f"{rows['asymmetry']['z']:.1f}",
            ", ".join(f"{rows[f'installation {x}']['z']:.1f}" for x in "ABC" if f"installation {x}" in rows),
            f"{max(poles):.1f} ({len(poles)} poles)" if poles else "(no pole count)",
        ])
        w = h["whole"]
        cc = w.get("method_cross_check") or {}
        dd, aa = w["rise_fall_delay_difference_s"], w["rise_fall_angle_asymmetry_deg_e"]
        ccd, cca = cc.get("rise_fall_delay_difference_s") or {}, cc.get("rise_fall_angle_asymmetry_deg_e") or {}
        whole.append([
            label,
            _pm_text(dd.get("value"), dd.get("stderr"), 1e6, "{:+.4g}") + " us",
            _pm_text(ccd.get("value"), ccd.get("stderr"), 1e6, "{:+.4g}") + " us ("
            + _pm_text(cca.get("value"), cca.get("stderr"), 1.0, "{:+.3g}") + " deg e)",
            _pm_text(aa.get("value"), aa.get("stderr"), 1.0, "{:+.3g}") + " deg e",
            str(h["pole_pairs"] or "none stands out"),
        ])
    run.tables["halves"] = halves
    run.tables["whole"] = whole
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("capture_halves", "docs/real-captures.md: each shipped capture whole and in halves", False,
          produce_capture_halves, inputs(__file__, *HIL, "tools/calibration_coverage.py", ALL_CAPTURES)),
)
