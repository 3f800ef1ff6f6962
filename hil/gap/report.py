"""HTML report of a diagnosis: edge-error pattern, order spectrum, operating-region map, before/after."""

from __future__ import annotations

import base64
import io
import json
from pathlib import Path

import numpy as np
from jinja2 import Environment, select_autoescape

from ..plots import pyplot

TEMPLATE = """<!doctype html>
<html><head><meta charset="utf-8"><title>Sim-to-real gap: {{ name }}</title>
<style>body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}
.bad{color:#b00}.ok{color:#070}img{max-width:100%}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p>Recording <code>{{ name }}</code>, reference: {{ d.reference }}. Gap ({{ d.gap_metric }}):
<b>{{ "%.4g"|format(d.gap_before) }}</b>,
{% if d.significant %}<span class="bad">significant</span>{% else %}<span class="ok">within the noise floor</span>{% endif %}
(p = {{ "%.2g"|format(d.p_value) }}).</p>
<h2>Which effect</h2>
<table><tr><th>rank</th><th>effect</th><th>score</th><th>accepted</th></tr>
{% for r in d.ranking %}<tr><td>{{ loop.index }}</td><td>{{ r.effect }}</td><td>{{ "%.3f"|format(r.score) }}</td><td>{{ "yes" if r.effect in accepted else "" }}</td></tr>{% endfor %}
</table>
{% for a in d.accepted %}<p>Accepted <b>{{ a.effect }}</b>: <code>{{ a.params|tojson }}</code></p>{% endfor %}
{% if d.confounded %}<p>Confounded: {% for pair in d.confounded %}{{ pair|join(" / ") }} (knob: {{ d.knobs[pair|join("/")] }}); {% endfor %}</p>{% endif %}
<p>Unexplained remainder: <b>{{ "yes" if d.unexplained else "no" }}</b></p>
<h2>How far it shrinks</h2>
<p>{% if d.heldout_shrink is not none %}Held-out gap {{ "%.4g"|format(d.gap_after_heldout or 0) }}, shrink <b>{{ "%.1f"|format(100 * d.heldout_shrink) }} %</b>
{% if d.heldout_interval %}(interval {{ "%.1f"|format(100 * d.heldout_interval[0]) }}-{{ "%.1f"|format(100 * d.heldout_interval[1]) }} %){% endif %}.{% endif %} {{ d.heldout_note }}</p>
{% for title, img in figures %}<h2>{{ title }}</h2><img src="data:image/png;base64,{{ img }}" alt="{{ title }}">{% endfor %}
<h2>Sampled signals</h2>
{% if d.samples %}<table><tr><th>signal</th><th>p</th><th>gap</th><th>accepted</th><th>held-out gap</th><th>shrink</th><th>unexplained</th></tr>
{% for k, v in d.samples.items() %}<tr><td>{{ k }} [{{ v.unit }}]</td><td>{{ "%.2g"|format(v.p_value) }}</td><td>{{ "%.3g"|format(v.gap_before) }}</td>
<td>{% for a in v.accepted %}{{ a.effect }} <code>{{ a.params|tojson }}</code> {% endfor %}</td>
<td>{{ "%.3g"|format(v.gap_after_heldout) if v.gap_after_heldout is not none else "-" }}</td>
<td>{{ "%.1f %%"|format(100 * v.heldout_shrink) if v.heldout_shrink is not none else "-" }}</td><td>{{ "yes" if v.unexplained else "no" }}</td></tr>{% endfor %}
</table>{% else %}<p>The recording has no samples.csv.</p>{% endif %}
<h2>Localisation</h2><pre>{{ localisation }}</pre>
<h2>Not assessed</h2><ul>{% for n in d.not_assessed %}<li>{{ n }}</li>{% endfor %}</ul>
</body></html>"""


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
    html = env.from_string(TEMPLATE).render(
        name=name, d=diagnosis, accepted=[a["effect"] for a in diagnosis.accepted], figures=figures(r, cells, diagnosis),
        localisation=json.dumps({k: v for k, v in diagnosis.localisation.items() if k != "order_spectrum"}, indent=1),
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html)
    return path
