"""docs/real-captures.md and docs/gap.md: ``hil gap diagnose`` on each shipped real capture."""

from __future__ import annotations

import json
from pathlib import Path

from ..model import Figure, Group, Run
from .common import ALL_CAPTURES, CAPTURE_LABELS, HIL, import_capture, inputs, run_hil


def produce_gap_captures(work: Path) -> Run:
    """docs/real-captures.md and docs/gap.md: ``hil gap diagnose`` on each shipped real capture."""
    run = Run()
    rows = [["capture", "gap", "accepted (in order)", "confounded",
             "held-out gap, shrink (90 % interval)", "split-half `D`"]]
    for stem, label in CAPTURE_LABELS.items():
        rec = import_capture(run, work, f"{stem}.vcd")
        out = work / f"{stem}-gap.json"
        run_hil(run, work, "gap", "diagnose", str(rec), "--json", str(out))
        g = json.loads(out.read_text())
        key = stem.split("-", 1)[1].replace("-", "_")
        run.figures[f"{key}.gap_deg_e"] = Figure(g["gap_before"], "deg e", "{:.2f}", tolerance_abs=0.02)
        accepted = [a["effect"] for a in g.get("accepted", [])]
        run.figures[f"{key}.accepted"] = Figure(", ".join(accepted) or "none")
        heldout = "-"
        if g.get("gap_after_heldout") is not None:
            shrink, (lo, hi) = g["heldout_shrink"], g["heldout_interval"]
            run.figures[f"{key}.heldout_shrink_pct"] = Figure(100 * shrink, "%", "{:.1f}", tolerance_abs=1.0)
            heldout = (f"{g['gap_after_heldout']:.3g} deg e, {100 * shrink:.1f} % ({100 * lo:.1f}-{100 * hi:.1f} %)"
                       + (": not established" if lo <= 0 else ""))
        rep = g.get("repeatability") or {}
        split = "-"
        if rep.get("rise_fall_delay_difference_s"):
            a, b = (1e6 * v for v in rep["rise_fall_delay_difference_s"])
            split = f"{a:.1f} / {b:.1f} us (z {rep['delay_difference_z']:.1f})"
        rows.append([label, f"{g['gap_before']:.2f} deg e",
                     ", ".join(accepted) or "none", "; ".join("/".join(c) for c in g.get("confounded", [])) or "none",
                     heldout, split])
    run.tables["captures"] = rows
    return run


GROUPS = (
    Group("gap_captures", "docs/real-captures.md, docs/gap.md: hil gap diagnose on each shipped capture", False,
          produce_gap_captures, inputs(__file__, *HIL, ALL_CAPTURES)),
)
