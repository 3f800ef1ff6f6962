"""The campaign's HTML report: one self-contained file (the envelope map inlined)."""

from __future__ import annotations

import base64
import math
from pathlib import Path

from jinja2 import Environment, select_autoescape

from ..verdicts.report import atomic_write

#: at most this many failing points are listed (the table has them all)
MAX_LISTED = 200

#: the HTML lives in hil/templates (package data), beside the compliance report's
TEMPLATES = Path(__file__).resolve().parent.parent / "templates"
TEMPLATE = (TEMPLATES / "campaign.html.j2").read_text(encoding="utf-8")


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) and math.isfinite(v) else str(v)


def write_report(result, path: str | Path) -> Path:
    path = Path(path)
    env = Environment(autoescape=select_autoescape(default=True))
    png = result.paths.get("envelope")
    envelope = base64.b64encode(Path(png).read_bytes()).decode() if png else None
    html = env.from_string(TEMPLATE).render(
        s=result.summary(),
        envelope=envelope,
        axes=[a.name for a in result.spec.axes],
        fmt=_fmt,
        failing=[r for r in result.rows if r["verdict"] == "fail"][:MAX_LISTED],
        errors=[r for r in result.rows if r["verdict"] == "error"],
        budgets_file=result.spec.budgets_file,
    )
    atomic_write(path, html)
    return path
