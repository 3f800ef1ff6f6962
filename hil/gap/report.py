"""HTML report of a diagnosis: edge-error pattern, order spectrum, operating-region map, before/after."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
from jinja2 import Environment, select_autoescape
from markupsafe import Markup

from ..plots import pyplot
from .candidates import CANDIDATES
from .diagnose import _design, build_cells
from .fitting import wls as _wls
from .residuals import model_prediction, residuals

#: the HTML lives in hil/templates (package data), beside the compliance report's
TEMPLATES = Path(__file__).resolve().parent.parent / "templates"
TEMPLATE = (TEMPLATES / "gap-diagnosis.html.j2").read_text(encoding="utf-8")

PARAMS_TEMPLATE = (TEMPLATES / "gap-params.html.j2").read_text(encoding="utf-8")


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
    plt = pyplot()
    out = []
    fig, ax = plt.subplots(figsize=(10, 3.2))
    first = r.segment == r.segment[0]
    idx = np.arange(first.sum())[: 6 * r.pole_pairs * 4]
    for x in range(3):
        for rising, mk in ((1, "^"), (0, "v")):
            sel = (r.sensor[first][idx] == x) & (r.rising[first][idx] == rising)
            ax.plot(
                idx[sel],
                r.residual_deg_e[first][idx][sel],
                mk,
                ls="",
                label=f"{'ABC'[x]} {'rise' if rising else 'fall'}",
            )
    ax.set_xlabel("edge index (first four mechanical turns of the first segment)")
    ax.set_ylabel("residual [deg e]")
    ax.legend(ncol=6, fontsize=7)
    out.append(("Edge-error pattern", _png(fig)))
    spec = diagnosis.localisation.get("order_spectrum")
    if spec:
        out.append(("Order spectrum", _bars(spec["mechanical_order"], spec["amplitude_deg_e"], "amplitude [deg e]")))
    regions = diagnosis.localisation["per_region"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    sc = ax.scatter(
        [g["speed_rpm"] for g in regions],
        [g["current_a"] for g in regions],
        c=[g["mean_deg_e"] for g in regions],
        s=120,
        marker="o",
        cmap="coolwarm",
        edgecolors=["k" if g["direction"] > 0 else "r" for g in regions],
    )
    fig.colorbar(sc, ax=ax, label="mean residual [deg e]")
    ax.set_xlabel("speed [rpm]")
    ax.set_ylabel("mean phase current [A]")
    ax.set_title("operating regions (red edge: reverse)", fontsize=9)
    out.append(("Operating-region map", _png(fig)))

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
        out.append(
            (
                "Speed residual: order spectrum (cogging shows at its periods per turn)",
                _bars(speed["mechanical_order"], speed["amplitude_rad_s"], "speed residual [rad/s]"),
            )
        )
    volt = diagnosis.samples.get("voltage", {}).get("localisation", {}).get("per_electrical_angle_v")
    if volt:
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot([float(k) for k in volt], list(volt.values()), "o-")
        ax.set_xlabel("electrical angle [deg]")
        ax.set_ylabel("voltage residual [V]")
        out.append(("Voltage-equation residual over the electrical turn", _png(fig)))
    return out


def write_html(path, name, rec, diagnosis, model=None) -> Path:
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
        name=name,
        d=diagnosis,
        accepted=[a["effect"] for a in diagnosis.accepted],
        below=[a["effect"] for a in diagnosis.below_relevance],
        figures=figures(r, cells, diagnosis),
        loc=diagnosis.localisation,
        spectrum=spectrum,
        segment_ids=rec.segment_ids,
        params_table=lambda a: Markup(params.render(a=a)),
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html)
    return path
