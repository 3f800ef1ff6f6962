"""The campaign's HTML report: one self-contained file (the envelope map inlined)."""

from __future__ import annotations

import base64
import math
from pathlib import Path

from jinja2 import Environment, select_autoescape

from ..report import _atomic_write

#: at most this many failing points are listed (the table has them all)
MAX_LISTED = 200

TEMPLATE = """<!doctype html>
<html><head><meta charset="utf-8"><title>Campaign {{ s.campaign }}</title>
<style>body{font-family:sans-serif;margin:2em;max-width:1150px}table{border-collapse:collapse;font-size:90%}
td,th{border:1px solid #ccc;padding:3px 8px}.fail,.error{color:#b00}.pass{color:#070}.marginal{color:#a60}img{max-width:100%}
pre{background:#f6f6f6;padding:6px;overflow-x:auto;font-size:80%}</style></head><body>
<h1>Campaign <code>{{ s.campaign }}</code></h1>
<p>SPEC <code>{{ s.spec }}</code>, seed {{ s.seed }}, kind {{ s.kind }}: {{ s.points_done }} of {{ s.points_planned }} points
{% if not s.complete %}<b class="fail">(incomplete: {{ "interrupted" if s.interrupted else "points missing" }})</b>{% endif %}.
<span class="pass">{{ s["pass"] }} pass</span>, <span class="marginal">{{ s.marginal }} marginal</span>,
<span class="fail">{{ s.fail }} fail</span>, <span class="error">{{ s.error }} error</span>.</p>
<p>Scheduler <code>{{ s.scheduler }}</code>{% if s.scheduler_address %} ({{ s.scheduler_address }}){% endif %},
{{ s.workers_used }} worker(s) used, {{ "%.1f"|format(s.elapsed_s) }} s{% if s.points_per_s %}, {{ "%.2f"|format(s.points_per_s) }} points/s{% endif %}.</p>
<h2>Budgets</h2>
<table><tr><th>budget</th><th>requirement</th><th>metric</th><th>limit</th><th>marginal</th><th>unit</th><th>description</th></tr>
{% for name, b in s.budgets.items() %}<tr><td>{{ name }}</td><td>{{ b.requirement }}</td><td>{{ b.metric }}</td><td>{{ b.kind }} {{ b.limit }}</td>
<td>{{ b.marginal if b.marginal is not none else "-" }}</td><td>{{ b.unit }}</td><td>{{ b.description }}</td></tr>{% endfor %}</table>
<h2>Axes</h2>
<table><tr><th>axis</th><th>values</th></tr>{% for name, vals in s.axes.items() %}<tr><td>{{ name }}</td><td>{{ vals|join(", ") }}</td></tr>{% endfor %}</table>
{% if envelope %}<h2>Envelope map</h2><img src="data:image/png;base64,{{ envelope }}" alt="envelope map">{% endif %}
<h2>Failing points ({{ failing|length }}{% if s.fail > failing|length %} of {{ s.fail }}{% endif %})</h2>
{% if failing %}<table><tr><th>point</th>{% for a in axes %}<th>{{ a }}</th>{% endfor %}<th>seed</th><th>result</th><th>replay</th></tr>
{% for r in failing %}<tr><td>{{ r.index }}</td>{% for a in axes %}<td>{{ fmt(r[a]) }}</td>{% endfor %}<td>{{ r.seed }}</td>
<td>{{ r.message }}</td><td><code>hil replay {{ r.replay }}{% if budgets_file %} --budgets {{ budgets_file }}{% endif %}</code></td></tr>{% endfor %}</table>
{% else %}<p>None.</p>{% endif %}
<h2>Errors ({{ errors|length }})</h2>
{% for r in errors %}<details><summary>point {{ r.index }}: {{ r.message }}</summary><pre>{{ r.error }}</pre></details>{% else %}<p>None.</p>{% endfor %}
</body></html>
"""


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) and math.isfinite(v) else str(v)


def write_report(result, path: str | Path) -> Path:
    path = Path(path)
    env = Environment(autoescape=select_autoescape(default=True))
    png = result.paths.get("envelope")
    envelope = base64.b64encode(Path(png).read_bytes()).decode() if png else None
    html = env.from_string(TEMPLATE).render(
        s=result.summary(), envelope=envelope, axes=[a.name for a in result.spec.axes], fmt=_fmt,
        failing=[r for r in result.rows if r["verdict"] == "fail"][:MAX_LISTED], errors=[r for r in result.rows if r["verdict"] == "error"],
        budgets_file=result.spec.budgets_file)
    _atomic_write(path, html)
    return path
