"""Runs compared: requirement verdicts that changed, figures that moved beyond their spread, and the
regressions a report names (pure Python over the rows ``hil.history.store`` reads).

**Spread.** A figure moved when the change is larger than its own run-to-run spread:

* both runs give the figure's interval (a report's ``interval`` of a measurement): the intervals do
  not overlap (the change exceeds the sum of the half-widths); one gives it: twice its half-width;
* otherwise the spread is twice the standard deviation of the same figure (device, budget, test)
  over the earlier runs recorded (three at least; for a regression, the runs up to the last PASS,
  so a regression that persists does not widen its own yardstick);
* with neither the spread is unknown: the change is shown, and nothing is claimed about it.

**Worse** is toward the limit: up for an upper limit (``max``), down for a lower one (``min``).

**A regression** is a figure of this run worse than the same figure in the last run of the same
device whose verdict was PASS, beyond the spread. It is named by requirement, budget (and the test,
where several tests measure that budget) and carries the run and build where it started: the
earliest run after that PASS from which every run was worse beyond the spread.
"""

from __future__ import annotations

import math
import re
import statistics

#: a figure's trend in a report: this many earlier runs beside it
TREND_RUNS = 10
#: the fewest earlier figures a spread is estimated from
MIN_SPREAD_RUNS = 3


def half_width(m: dict) -> float | None:
    lo, hi = m.get("interval_low"), m.get("interval_high")
    if lo is None or hi is None or not all(map(math.isfinite, (lo, hi))):
        return None
    return abs(hi - lo) / 2


def history_spread(values: list) -> float | None:
    """Twice the standard deviation of the earlier figures (None with fewer than ``MIN_SPREAD_RUNS``)."""
    xs = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    if len(xs) < MIN_SPREAD_RUNS:
        return None
    return 2 * statistics.stdev(xs)


def spread(a: dict, b: dict, earlier: list | None = None) -> tuple[float | None, str]:
    """(the spread a change from ``a`` to ``b`` is judged against, where it comes from)."""
    ha, hb = half_width(a), half_width(b)
    if ha is not None and hb is not None:
        return ha + hb, "intervals"
    if ha is not None or hb is not None:
        return 2 * (ha if ha is not None else hb), "interval"
    s = history_spread(earlier or [])
    if s is not None:
        return s, f"2 sd of {len(earlier)} runs"
    return None, "unknown"


def worse_by(a: dict, b: dict) -> float | None:
    """How much worse ``b``'s figure is than ``a``'s (negative: better), toward the limit."""
    x, y = a.get("measured"), b.get("measured")
    if x is None or y is None:
        return None
    return (y - x) if (b.get("limit_kind") or a.get("limit_kind") or "max") == "max" else (x - y)


def _floor(a: dict, b: dict) -> float:
    """Below this a change is rounding (a deterministic figure's spread is 0)."""
    scale = max(abs(a.get("measured") or 0.0), abs(b.get("measured") or 0.0), abs(b.get("limit_value") or 0.0))
    return 1e-9 * scale


def comparable_test(test: str, dut: str | None) -> str:
    """A test's node id with its DUT's id taken out of the parameters: the same test on another
    spec of the same device (a second station) compares."""
    if dut and "[" in test:
        head, _, params = test.partition("[")
        params = re.sub(rf"(^|-){re.escape(dut)}(-|\]$)", lambda m: m.group(1) + "DUT" + m.group(2), params)
        return f"{head}[{params}"
    return test


def diff(a: dict, b: dict, spreads: dict | None = None) -> dict:
    """Run ``b`` against run ``a`` (each ``Store.run``): the requirements whose verdict changed, and
    every figure of both, with its change, its spread and whether it moved beyond it. ``spreads``:
    (budget, test key) -> the earlier figures of that budget (``history_spread``)."""
    ra = {r["requirement"]: r["verdict"] for r in a["requirements"]}
    rb = {r["requirement"]: r["verdict"] for r in b["requirements"]}
    requirements = [{"requirement": rid, "a": ra.get(rid), "b": rb.get(rid), "changed": ra.get(rid) != rb.get(rid)}
                    for rid in sorted(set(ra) | set(rb))]
    ma = {(m["budget"], comparable_test(m["test"], m["dut"])): m for m in a["measurements"]}
    mb = {(m["budget"], comparable_test(m["test"], m["dut"])): m for m in b["measurements"]}
    figures = []
    for key in sorted(set(ma) | set(mb)):
        x, y = ma.get(key), mb.get(key)
        row = {"budget": key[0], "test": key[1], "requirement": (y or x)["requirement"], "unit": (y or x)["unit"],
               "a": x and x["measured"], "b": y and y["measured"], "margin_a": x and x["margin"],
               "margin_b": y and y["margin"], "verdict_a": x and x["verdict"], "verdict_b": y and y["verdict"],
               "limit": (y or x)["limit_value"], "change": None, "worse_by": None, "spread": None,
               "spread_from": "", "moved": None}
        if x and y and x["measured"] is not None and y["measured"] is not None:
            s, source = spread(x, y, (spreads or {}).get(key))
            w = worse_by(x, y)
            row.update(change=y["measured"] - x["measured"], worse_by=w, spread=s, spread_from=source,
                       moved=None if s is None else abs(w) > max(s, _floor(x, y)))
        figures.append(row)
    return {"a": a["id"], "b": b["id"], "requirements": requirements, "figures": figures,
            "verdicts_changed": [r for r in requirements if r["changed"]],
            "moved": [f for f in figures if f["moved"]]}


def _short(test: str) -> str:
    return test.rpartition("::")[2] or test


def look_back(content: dict, rows: list[dict], identities: dict[str, str]) -> dict:
    """A report's history: for each figure of this run (``content``, a report's), the trend of the
    same figure over the device's earlier runs (``rows``: ``Store.history_of``, oldest first), and
    the regressions (module docstring). ``identities``: DUT id -> identity key."""
    earlier: dict[tuple, list] = {}
    for r in rows:
        earlier.setdefault((r["identity_key"], r["budget"], r["test"]), []).append(r)
    measured_by: dict[tuple, set] = {}
    for t in content.get("tests", []):
        for m in t.get("measurements", []):
            measured_by.setdefault((t.get("dut", ""), m["budget"]), set()).add(t["nodeid"])
    trends: dict[str, list] = {}
    regressions = []
    for t in content.get("tests", []):
        dut = t.get("dut", "")
        ident = identities.get(dut)
        for m in t.get("measurements", []):
            now = {"measured": m.get("measured"), "limit_value": m.get("limit"), "limit_kind": m.get("limit_kind"),
                   "interval_low": (m.get("interval") or [None, None])[0],
                   "interval_high": (m.get("interval") or [None, None])[1]}
            past = earlier.get((ident, m["budget"], t["nodeid"]), []) if ident else []
            key = trend_key(dut, m["budget"], t["nodeid"])
            trends[key] = [{"run": p["run"], "build": p["build"], "measured": p["measured"], "verdict": p["verdict"],
                            "run_verdict": p["run_verdict"]} for p in past[-TREND_RUNS:]]
            passes = [i for i, p in enumerate(past) if p["run_verdict"] == "PASS"]
            if not passes or now["measured"] is None:
                continue
            lp = past[passes[-1]]
            s, source = spread(lp, now, [p["measured"] for p in past[: passes[-1] + 1]])
            w = worse_by(lp, now)
            if s is None or w is None or w <= max(s, _floor(lp, now)):
                continue
            start = None  # the earliest run after the PASS from which every run was worse beyond the spread
            for p in reversed(past[passes[-1] + 1:]):
                pw = worse_by(lp, p)
                if pw is None or pw <= max(s, _floor(lp, p)):
                    break
                start = p
            several = len(measured_by.get((dut, m["budget"]), ())) > 1
            name = f"{m['requirement']} {m['budget']}" + (f" ({_short(t['nodeid'])})" if several else "")
            unit = m.get("unit", "").replace("_", " ")
            above = "above" if (m.get("limit_kind") or "max") == "max" else "below"
            began = (f"started in run {start['run']} (build {start['build'] or '-'})" if start
                     else "started in this run")
            regressions.append({
                "name": name, "requirement": m["requirement"], "budget": m["budget"], "test": t["nodeid"],
                "dut": dut, "identity": ident, "measured": now["measured"], "unit": m.get("unit", ""),
                "worse_by": w, "spread": s, "spread_from": source,
                "last_pass": {"run": lp["run"], "build": lp["build"], "measured": lp["measured"]},
                "started": {"run": start["run"], "build": start["build"]} if start else None,
                "line": (f"{name} {now['measured']:.3g} {unit}, {w:.2g} {above} build {lp['build'] or '-'}'s run "
                         f"{lp['run']} (the last PASS; spread {s:.2g}, {source}); {began}"),
            })
    return {"trends": trends, "regressions": regressions}


def trend_key(dut: str, budget: str, test: str) -> str:
    return f"{dut}|{budget}|{test}"


def sparkline(values: list, *, width: int = 84, height: int = 20, alarm: bool = False) -> str:
    """An inline SVG of ``values`` (oldest first; the last is this run's, drawn as a dot): the shape
    of a trend, scaled to its own range."""
    xs = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    if len(xs) < 2:
        return ""
    lo, hi = min(xs), max(xs)
    span = (hi - lo) or 1.0
    step = (width - 6) / (len(values) - 1)
    points = []
    for i, v in enumerate(values):
        if isinstance(v, (int, float)) and math.isfinite(v):
            points.append((3 + i * step, height - 3 - (v - lo) / span * (height - 6)))
    line = " ".join(f"{x:.1f},{y:.1f}" for x, y in points)
    cx, cy = points[-1]
    colour = "#cf222e" if alarm else "#0a58ca"
    return (f'<svg class="spark" width="{width}" height="{height}" viewBox="0 0 {width} {height}" role="img">'
            f'<polyline fill="none" stroke="#8c959f" stroke-width="1.2" points="{line}"/>'
            f'<circle cx="{cx:.1f}" cy="{cy:.1f}" r="2.4" fill="{colour}"/></svg>')
