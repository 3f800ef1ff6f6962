"""HTML report of a diagnosis: edge-error pattern, order spectrum, operating-region map, before/after."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
from jinja2 import Environment, select_autoescape
from markupsafe import Markup

from ..plots import pyplot

TEMPLATE = """<!doctype html>
<html><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>Sim-to-real gap: {{ name }}</title>
<style>
*{box-sizing:border-box}
body{font-family:sans-serif;margin:2em auto;padding:0 1em;max-width:1100px;line-height:1.4;overflow-wrap:anywhere}
table{border-collapse:collapse;margin:.5em 0 1em;max-width:100%}
td,th{border:1px solid #ccc;padding:3px 8px;text-align:left;vertical-align:top}
td.pair{white-space:nowrap}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.bad{color:#b00}.ok{color:#070}.muted{color:#666}
img{max-width:100%;height:auto}
code{white-space:pre-wrap;overflow-wrap:anywhere}
.grid{display:flex;flex-wrap:wrap;gap:0 2em}
@media print{body{margin:0;max-width:none}h2{break-after:avoid}table,img{break-inside:avoid}}
</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p>Recording <code>{{ name }}</code>, reference: {{ d.reference }}. Gap ({{ d.gap_metric }}):
<b>{{ d.gap_before|sig }}</b>,
{% if d.significant %}<span class="bad">significant</span>{% else %}<span class="ok">within the noise floor</span>{% endif %}
(p = {{ "%.2g"|format(d.p_value) }}).</p>
<h2>Which effect</h2>
<table><tr><th>rank</th><th>effect</th><th>score</th><th>verdict</th></tr>
{% for r in d.ranking %}<tr><td class="num">{{ loop.index }}</td><td>{{ r.effect }}</td><td class="num">{{ "%.3f"|format(r.score) }}</td>
<td>{% if r.effect in accepted %}accepted{% elif r.effect in below %}detected, below practical relevance{% endif %}</td></tr>{% endfor %}
</table>
{% for a in d.accepted %}<h3>Accepted: {{ a.effect }}</h3>{{ params_table(a) }}{% endfor %}
{% if d.below_relevance %}<h3>Detected, below practical relevance</h3>
<p class="muted">Fitted and significant, but what they do is below the floor of their budget (docs/gap.md, "Practical significance"); not accepted.</p>
{% for a in d.below_relevance %}<h4>{{ a.effect }}</h4>{{ params_table(a) }}{% endfor %}{% endif %}
{% if d.confounded %}<h3>Confounded pairs</h3>
<table><tr><th>pair</th><th>what separates them</th></tr>
{% for pair in d.confounded %}<tr><td class="pair">{{ pair[0] }}<br>{{ pair[1] }}</td><td>{{ d.knobs[pair|join("/")] }}</td></tr>{% endfor %}</table>{% endif %}
<p>Unexplained remainder: <b>{{ "yes" if d.unexplained else "no" }}</b></p>
<h2>How far it shrinks</h2>
<p>{% if d.heldout_shrink is not none %}Held-out gap {{ (d.gap_after_heldout or 0)|sig }}, shrink <b>{{ "%.1f"|format(100 * d.heldout_shrink) }} %</b>
{% if d.heldout_interval %}(interval {{ "%.1f"|format(100 * d.heldout_interval[0]) }}-{{ "%.1f"|format(100 * d.heldout_interval[1]) }} %){% endif %}.{% endif %} {{ d.heldout_note }}</p>
{% for title, img in figures %}<h2>{{ title }}</h2><img src="data:image/png;base64,{{ img }}" alt="{{ title }}">{% endfor %}
<h2>Sampled signals</h2>
{% if d.samples %}<table><tr><th>signal</th><th>p</th><th>gap</th><th>accepted</th><th>held-out gap</th><th>shrink</th><th>unexplained</th></tr>
{% for k, v in d.samples.items() %}<tr><td>{{ k }} [{{ v.unit }}]</td><td class="num">{{ "%.2g"|format(v.p_value) }}</td><td class="num">{{ v.gap_before|sig }}</td>
<td>{% for a in v.accepted %}{{ a.effect }}{{ ", " if not loop.last }}{% endfor %}{% if v.below_relevance %} <span class="muted">(below relevance: {% for a in v.below_relevance %}{{ a.effect }}{{ ", " if not loop.last }}{% endfor %})</span>{% endif %}</td>
<td class="num">{{ v.gap_after_heldout|sig if v.gap_after_heldout is not none else "-" }}</td>
<td class="num">{{ "%.1f %%"|format(100 * v.heldout_shrink) if v.heldout_shrink is not none else "-" }}</td><td>{{ "yes" if v.unexplained else "no" }}</td></tr>{% endfor %}
</table>{% else %}<p>The recording has no samples.csv.</p>{% endif %}
<h2>Localisation</h2>
<p class="muted">Mean edge residual (deg electrical, + = trails) by where it occurs.</p>
<div class="grid">
{% for title, key, label in (("Per sensor", "per_sensor", "sensor"), ("Per edge polarity", "per_polarity", "edge"), ("Per magnet pole", "per_pole", "pole")) %}
{% if loc[key] %}<div><h3>{{ title }}</h3><table><tr><th>{{ label }}</th><th>mean [deg e]</th></tr>
{% for k, v in loc[key].items() %}<tr><td>{{ k }}</td><td class="num">{{ v|sig }}</td></tr>{% endfor %}</table></div>{% endif %}
{% endfor %}
{% if d.noise_floor_deg_e %}<div><h3>Noise floor per segment</h3><table><tr><th>segment</th><th>per-edge noise [deg e]</th></tr>
{% for k, v in d.noise_floor_deg_e.items() %}<tr><td>{{ k }}</td><td class="num">{{ v|sig }}</td></tr>{% endfor %}</table></div>{% endif %}
</div>
{% if loc.per_region %}<h3>Per operating region</h3>
<table><tr><th>segment</th><th>speed [rpm]</th><th>mean |i| [A]</th><th>load scale</th><th>direction</th><th>mean [deg e]</th><th>RMS [deg e]</th></tr>
{% for g in loc.per_region %}<tr><td>{{ segment_ids[g.segment] }}</td><td class="num">{{ g.speed_rpm|sig }}</td><td class="num">{{ g.current_a|sig }}</td>
<td class="num">{{ g.load_scale|sig }}</td><td>{{ "forward" if g.direction > 0 else "reverse" }}</td><td class="num">{{ g.mean_deg_e|sig }}</td>
<td class="num">{{ g.rms_deg_e|sig }}</td></tr>{% endfor %}</table>{% endif %}
{% if spectrum %}<h3>Order spectrum (largest orders)</h3>
<table><tr><th>mechanical order</th><th>amplitude [deg e]</th></tr>
{% for o, a in spectrum %}<tr><td class="num">{{ o }}</td><td class="num">{{ a|sig }}</td></tr>{% endfor %}</table>{% endif %}
<h2>Not assessed</h2><ul>{% for n in d.not_assessed %}<li>{{ n }}</li>{% endfor %}</ul>
</body></html>"""

PARAMS_TEMPLATE = """<table><tr><th>parameter</th><th>value</th></tr>
{% for k, v in a.params.items() %}<tr><td>{{ k }}</td><td class="num">{{ v|sig }}</td></tr>{% endfor %}
{% if a.relevance %}<tr><td>relevance ({{ a.relevance.meaning }})</td><td class="num">{{ a.relevance.value|sig }} {{ a.relevance.unit }}
(floor {{ a.relevance.floor|sig }})</td></tr>{% endif %}</table>"""


def sig(value, digits: int = 4) -> str:
    """Numbers with ``digits`` significant digits; lists element by element."""
    if isinstance(value, (list, tuple)):
        return ", ".join(sig(v, digits) for v in value)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f"{float(value):.{digits}g}"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
    pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _bars(order, amplitude, ylabel: str) -> str:
    fig, ax = pyplot().subplots(figsize=(6, 3))
    ax.bar(order, amplitude)
    ax.set_xlabel("mechanical order")
    ax.set_ylabel(ylabel)
    return _png(fig)


def figures(r, cells, diagnosis) -> list[tuple[str, str]]:
    from .diagnose import _design
    from .fitting import wls as _wls

    plt = pyplot()
    out = []
    fig, ax = plt.subplots(figsize=(10, 3.2))
    first = r.segment == r.segment[0]
    idx = np.arange(first.sum())[: 6 * r.pole_pairs * 4]
    for x in range(3):
        for rising, mk in ((1, "^"), (0, "v")):
            sel = (r.sensor[first][idx] == x) & (r.rising[first][idx] == rising)
            ax.plot(idx[sel], r.residual_deg_e[first][idx][sel], mk, ls="", label=f"{'ABC'[x]} {'rise' if rising else 'fall'}")
    ax.set_xlabel("edge index (first four mechanical turns of the first segment)")
    ax.set_ylabel("residual [deg e]")
    ax.legend(ncol=6, fontsize=7)
    out.append(("Edge-error pattern", _png(fig)))
    spec = diagnosis.localisation.get("order_spectrum")
    if spec:
        out.append(("Order spectrum", _bars(spec["mechanical_order"], spec["amplitude_deg_e"], "amplitude [deg e]")))
    regions = diagnosis.localisation["per_region"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    sc = ax.scatter([g["speed_rpm"] for g in regions], [g["current_a"] for g in regions], c=[g["mean_deg_e"] for g in regions],
                    s=120, marker="o", cmap="coolwarm", edgecolors=["k" if g["direction"] > 0 else "r" for g in regions])
    fig.colorbar(sc, ax=ax, label="mean residual [deg e]")
    ax.set_xlabel("speed [rpm]")
    ax.set_ylabel("mean phase current [A]")
    ax.set_title("operating regions (red edge: reverse)", fontsize=9)
    out.append(("Operating-region map", _png(fig)))
    from .candidates import CANDIDATES

    names = [a["effect"] for a in diagnosis.accepted if a["effect"] in CANDIDATES]  # the mean edge effects
    if names:
        x = _design(names, cells)
        coef, _, _ = _wls(x, cells.mean, cells.weight)
        fig, ax = plt.subplots(figsize=(10, 3.2))
        ax.plot(cells.mean, ".", label="before: cell means")
        ax.plot(cells.mean - x @ coef, ".", label="after: with the accepted effects")
        ax.set_xlabel("cell (segment x sensor x polarity x pole)")
        ax.set_ylabel("residual [deg e]")
        ax.legend(fontsize=8)
        out.append(("Before / after", _png(fig)))
    speed = diagnosis.samples.get("speed", {}).get("localisation", {}).get("order_spectrum")
    if speed:
        out.append(("Speed residual: order spectrum (cogging shows at its periods per turn)",
                    _bars(speed["mechanical_order"], speed["amplitude_rad_s"], "speed residual [rad/s]")))
    volt = diagnosis.samples.get("voltage", {}).get("localisation", {}).get("per_electrical_angle_v")
    if volt:
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot([float(k) for k in volt], list(volt.values()), "o-")
        ax.set_xlabel("electrical angle [deg]")
        ax.set_ylabel("voltage residual [V]")
        out.append(("Voltage-equation residual over the electrical turn", _png(fig)))
    return out


def write_html(path, name, rec, diagnosis, model=None) -> Path:
    from .diagnose import build_cells
    from .residuals import model_prediction, residuals

    pred = model_prediction(model, rec) if model is not None else None
    r = residuals(rec, pred)
    cells = build_cells(r)
    env = Environment(autoescape=select_autoescape(default=True))
    env.filters["sig"] = sig
    params = env.from_string(PARAMS_TEMPLATE)
    spec = diagnosis.localisation.get("order_spectrum")
    spectrum = []
    if spec:
        top = sorted(zip(spec["mechanical_order"], spec["amplitude_deg_e"]), key=lambda oa: -oa[1])[:8]
        spectrum = sorted(top)
    html = env.from_string(TEMPLATE).render(
        name=name, d=diagnosis, accepted=[a["effect"] for a in diagnosis.accepted], below=[a["effect"] for a in diagnosis.below_relevance],
        figures=figures(r, cells, diagnosis), loc=diagnosis.localisation, spectrum=spectrum, segment_ids=rec.segment_ids,
        params_table=lambda a: Markup(params.render(a=a)),
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html)
    return path
