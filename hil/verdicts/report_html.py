"""The HTML compliance report: what a reviewer reads first, and how each test is named.

``html(content, directory)`` renders the report's content (``ReportWriter.content()``, the same
data as the JSON report) through ``templates/report.html.j2``. This module adds only
presentation: short test labels (the full node id stays in the evidence card and on hover),
the summary block (verdict, requirements by verdict, worst margins, controllers), and the
rows of the traceability matrix with their row spans. Verdicts are read from the content as
they are; nothing here judges.
"""

from __future__ import annotations

import base64
import hashlib
import math
import re
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported on use: the plugin loads this module in every pytest run
    import markupsafe

#: a message longer than this folds into <details> with its first line as the summary
FOLD_CHARS = 240


def short_label(nodeid: str, dut: str = "") -> str:
    """A short human label for a node id: the test function in words and its parameters.

    ``test_cases/test_faults.py::test_wiring_fault_gives_the_promised_fault[virtual-canopen-missing-edge]``
    reads ``wiring fault gives the promised fault · virtual-canopen-missing-edge``; with ``dut``
    given (a DUT column beside it) ``wiring fault gives the promised fault · missing-edge``."""
    path, _, name = nodeid.rpartition("::")
    name = name or path
    func, bracket, params = name.partition("[")
    words = func.removeprefix("test_").replace("_", " ").strip() or func
    params = params.removesuffix("]") if bracket else ""
    if dut and (params == dut or params.startswith(dut + "-")):
        params = params[len(dut) + 1:]
    return f"{words} · {printable(params)}" if params else words


def module_label(nodeid: str) -> str:
    """The test file a node id belongs to, without directory and ``test_`` prefix."""
    path = nodeid.split("::", 1)[0]
    return Path(path).stem.removeprefix("test_").replace("_", " ")


def printable(text: str) -> str:
    """Text with control and escaped raw bytes shown as hex (``\\x03\\xff`` -> ``03 ff``), never as an id."""
    text = re.sub(
        r"(?:\\x[0-9a-fA-F]{2})+",
        lambda m: " ".join(m.group(0)[i + 2 : i + 4] for i in range(0, len(m.group(0)), 4)),
        text,
    )
    return "".join(c if c.isprintable() else f"{ord(c):02x}" for c in text)


def reason(text: str, limit: int = 220) -> markupsafe.Markup:
    """A verdict reason for the summary: a leading node id becomes its label (the node id on
    hover), the rest is cut at ``limit`` characters (the whole text is in the JSON report)."""
    import markupsafe

    found = re.match(r"(\S+::\S+?): (.*)", text, re.S)
    rest = found.group(2) if found else text
    rest = rest if len(rest) <= limit else rest[:limit].rstrip() + " …"
    if not found:
        return markupsafe.escape(printable(rest))
    return markupsafe.Markup('<span title="{}">{}</span>: {}').format(
        found.group(1), short_label(found.group(1)), printable(rest)
    )


def anchor(nodeid: str) -> str:
    """An HTML id for a test's evidence card (stable, unique per node id)."""
    return "t-" + hashlib.sha1(nodeid.encode()).hexdigest()[:10]


def relative_margin(m: dict) -> float:
    """A measurement's margin as a share of its limit (negative: outside), comparable across units."""
    margin, limit = m.get("margin"), m.get("limit")
    if not isinstance(margin, (int, float)) or not math.isfinite(margin):
        return -math.inf
    scale = abs(limit) if isinstance(limit, (int, float)) and limit else 1.0
    return margin / scale


def summary(content: dict, verdicts: tuple[str, ...], worst: int = 5) -> dict:
    """The summary block: requirements by verdict (in the order of ``verdicts``, the bad news
    first), the worst margins, the test outcome counts."""
    by_verdict = Counter(r.get("verdict", "not tested") for r in content["traceability"])
    ordered = [(v, by_verdict[v]) for v in verdicts if by_verdict.get(v)]
    ordered += [(v, n) for v, n in by_verdict.items() if v not in verdicts]
    # one entry per (budget, DUT): the worst measurement of each, then the worst of those
    seen: dict[tuple, dict] = {}
    for t in content["tests"]:
        for m in t.get("measurements", []):
            key = (m["budget"], t.get("dut", ""))
            entry = {
                **m,
                "dut": t.get("dut", ""),
                "nodeid": t["nodeid"],
                "label": short_label(t["nodeid"]),
                "anchor": anchor(t["nodeid"]),
                "relative": relative_margin(m),
            }
            if key not in seen or entry["relative"] < seen[key]["relative"]:
                seen[key] = entry
    margins = sorted(seen.values(), key=lambda e: e["relative"])[:worst]
    return {"requirements": ordered, "requirement_count": len(content["traceability"]), "worst_margins": margins}


def matrix_rows(content: dict) -> list[dict]:
    """The traceability matrix as table rows: a requirement spans its tests, a test its measurements."""
    rows = []
    for req in content["traceability"]:
        tests = req.get("tests") or []
        span = sum(max(1, len(t.get("measurements") or [])) for t in tests) or 1
        if not tests:
            rows.append({"req": req, "req_span": 1, "test": None, "test_span": 1, "m": None})
            continue
        first_req = True
        # the same test on each controller side by side
        for t in sorted(tests, key=lambda t: (short_label(t["nodeid"], t.get("dut", "")), t.get("dut", ""))):
            ms = t.get("measurements") or [None]
            for i, m in enumerate(ms):
                rows.append(
                    {
                        "req": req if first_req else None,
                        "req_span": span,
                        "test": t if i == 0 else None,
                        "test_span": len(ms),
                        "m": m,
                        "label": short_label(t["nodeid"], t.get("dut", "")),
                        "nodeid": t["nodeid"],
                        "test_dut": t.get("dut", ""),
                        "anchor": anchor(t["nodeid"]),
                    }
                )
                first_req = False
    return rows


def _data_uri(directory: Path, relpath: str) -> str:
    try:
        data = (directory / relpath).read_bytes()
    except OSError:
        return ""
    return "data:image/png;base64," + base64.b64encode(data).decode()


def _num(v) -> str:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return str(v)
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return f"{v:.4g}"


def trend_cell(history: dict | None, dut: str, m: dict, nodeid: str) -> markupsafe.Markup:
    """A measurement's small trend: the same figure over the device's last runs (hil.history), this
    run's as the dot (red when it is a regression); its runs and figures on hover."""
    import markupsafe

    from ..history.compare import sparkline, trend_key

    if not history:
        return markupsafe.Markup("")
    past = history.get("trends", {}).get(trend_key(dut, m["budget"], nodeid), [])
    alarm = any(r["test"] == nodeid and r["budget"] == m["budget"] and r["dut"] == dut
                for r in history.get("regressions", []))
    svg = sparkline([p["measured"] for p in past] + [m.get("measured")], alarm=alarm)
    if not svg:
        return markupsafe.Markup('<span class="muted">first run</span>' if not past else "")
    title = "; ".join(f"run {p['run']} ({p['build'] or '-'}): {_num(p['measured'])}" for p in past)
    return markupsafe.Markup('<span title="{}">{}</span>').format(f"{title}; this run: {_num(m.get('measured'))}",
                                                                  markupsafe.Markup(svg))


def html(content: dict, directory: Path, verdicts: tuple[str, ...]) -> str:
    import jinja2
    import markupsafe

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("hil", "templates"), autoescape=True, undefined=jinja2.StrictUndefined
    )
    env.filters["data_uri"] = lambda rel: _data_uri(Path(directory), rel)
    env.filters["num"] = _num
    env.filters["hex"] = lambda v: f"0x{v:08X}" if isinstance(v, int) else ("-" if v is None else str(v))
    env.filters["label"] = short_label
    env.filters["module"] = module_label
    env.filters["anchor"] = anchor
    env.filters["printable"] = printable
    env.filters["reason"] = reason
    env.filters["cls"] = lambda v: re.sub(r"[^a-z]", "", str(v).lower())
    # identifiers may break after an underscore or a dot, nowhere else
    env.filters["soft"] = lambda v: markupsafe.Markup("<wbr>").join(re.split(r"(?<=[_.])", str(v)))
    env.globals["FOLD_CHARS"] = FOLD_CHARS
    env.globals["trend"] = lambda dut, m, nodeid: trend_cell(content.get("history"), dut, m, nodeid)
    return env.get_template("report.html.j2").render(
        **content, summary=summary(content, verdicts), rows=matrix_rows(content)
    )
