"""The one report of a diagnosis, for every route: the terminal summary (``format_text``) and the
HTML page (``write_html``): ranking, accepted effects as tables of named parameters with units,
rounded values, standard errors and relevance, the held-out shrink, and the route's figures (edge
pattern, order spectrum, operating regions and before/after for a recording with segments; the
sector widths and split-half repeatability for an ordinary run)."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
from jinja2 import Environment, select_autoescape
from markupsafe import Markup

from bldc.reasons import words

from ..verdicts.plots import pyplot
from .candidates import CANDIDATES
from .diagnose import Diagnosis, _design, build_cells
from .fitting import wls as _wls
from .residuals import model_prediction, residuals
from .result import ORDINARY_ROUTE, FittedEffect, SplitHalf, ordinary_meaning

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


#: unit suffixes of parameter names (longest first) -> (unit shown, scale to it)
_UNITS = (
    ("_deg_e_per_a", "deg e/A", 1.0),
    ("_v_s_per_rad", "V s/rad", 1.0),
    ("_deg_e", "deg e", 1.0),
    ("_per_k", "1/K", 1.0),
    ("_ohm", "ohm", 1.0),
    ("_n_m", "N m", 1.0),
    ("_rad", "rad", 1.0),
    ("_s", "us", 1e6),
    ("_a", "A", 1.0),
    ("_k", "K", 1.0),
)
_SENSORS = "ABC"


def _unit(name: str) -> tuple[str, str, float]:
    """(label without the unit, unit, scale) of a parameter name that carries its unit."""
    for suffix, unit, scale in _UNITS:
        if name.endswith(suffix):
            return name[: -len(suffix)].replace("_", " "), unit, scale
    if name == "periods_per_rev":
        return "periods", "per turn", 1.0
    return name.replace("_", " "), "", 1.0


def param_rows(a: FittedEffect) -> list[dict]:
    """An accepted (or below-floor) effect's parameters as rows: parameter, value, standard error
    and unit, rounded (4 significant digits, the error 2). A list is one row per sensor (three
    entries) or per pole; a dict of contrasts one row per named contrast."""
    rows = []
    stderr = a.stderr or {}
    for key, value in a.params.items():
        label, unit, scale = _unit(key)
        err = stderr.get(key)
        if isinstance(value, dict):
            items = [(f"{label} [{k}]", v, (err or {}).get(k)) for k, v in value.items()]
        elif isinstance(value, (list, tuple)):
            names = _SENSORS if len(value) == 3 and a.effect == "installation_offset" else range(len(value))
            items = [(f"{label} [{n}]", v, err[i] if err else None) for i, (n, v) in enumerate(zip(names, value))]
        else:
            items = [(label, value, err)]
        for name, v, e in items:
            num = isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
            rows.append(
                {
                    "parameter": name,
                    "value": sig(v * scale if num else v),
                    "stderr": sig(e * scale, 2) if e is not None and num else "",
                    "unit": unit,
                }
            )
    return rows


def format_params(a: FittedEffect) -> str:
    """One line: ``name = value +- error unit`` per parameter."""
    parts = []
    for r in param_rows(a):
        err = f" +- {r['stderr']}" if r["stderr"] else ""
        parts.append(f"{r['parameter']} = {r['value']}{err}{' ' + r['unit'] if r['unit'] else ''}")
    return "; ".join(parts)


def format_text(d: Diagnosis, name: str) -> str:
    """The terminal summary of a diagnosis (every route)."""
    lines = []
    what = "ordinary run, " if d.route == ORDINARY_ROUTE else ""
    lines.append(
        f"{name}: {what}gap {d.gap_before:.4g} ({d.gap_metric}), "
        f"{'SIGNIFICANT' if d.significant else 'within the noise floor'} (p = {d.p_value:.2g})"
    )
    if d.route == ORDINARY_ROUTE:
        lines.append(f"  pole pairs: {words(d.pole_pairs_source)}")
    for dname, dom in d.samples.items():
        measured = dom.heldout_shrink is not None and dom.accepted
        shrink = f", held-out shrink {dom.heldout_shrink:.1%}" if measured else ""
        lines.append(
            f"  sampled {dname}: gap {dom.gap_before:.3g} {dom.unit}, p = {dom.p_value:.2g}"
            f"{', unexplained remainder' if dom.unexplained else ''}{shrink}"
        )
    accepted = {a.effect for a in d.accepted}
    lines.append("  ranking (share alone: each effect fitted on its own; share added: in the order chosen)")
    for i, r in enumerate(d.ranking[:6], 1):
        verdict = "accepted" if r.effect in accepted else ("below relevance" if r.below_relevance else "")
        added = f"  added {r.share_added:.3f}" if r.share_added is not None else ""
        lines.append(f"  {i}. {r.effect:<22} share alone {r.score:.3f}{added}   {verdict}".rstrip())
    for a in d.accepted:
        lines.append(f"  accepted {a.effect}: {format_params(a)}")
    for b in d.below_relevance:
        rel = b.relevance  # below relevance: judged against its floor, so it has one
        lines.append(
            f"  detected, below practical relevance: {b.effect} ({rel.value:.3g} < floor {rel.floor:.3g} {rel.unit}: "
            f"{words(rel.meaning)})"
        )
    for c in d.confounded:
        lines.append(f"  confounded: {' / '.join(c.names)}; knob: {c.knob(d.route)}")
    lines.append(f"  unexplained remainder: {'yes' if d.unexplained else 'no'}")
    if d.heldout_shrink is not None and d.gap_after_heldout is not None:
        lo, hi = d.heldout_interval or (float("nan"), float("nan"))
        lines.append(
            f"  held-out: gap {d.gap_after_heldout:.4g}, shrink {d.heldout_shrink:.1%} (interval {lo:.1%} to "
            f"{hi:.1%}); {d.heldout_note}"
        )
    else:
        lines.append(f"  held-out: {d.heldout_note}")
    rep = d.repeatability
    if rep is not None:
        parts = []
        if rep.delay_diff_s is not None:
            a, b = rep.delay_diff_s
            apart = f"{rep.delay_relative_difference:.1%} apart"
            parts.append(f"delay difference {a * 1e6:.1f} / {b * 1e6:.1f} us ({apart})")
        if rep.static_rms_difference_deg_e is not None:
            parts.append(
                f"other parameters differ by {rep.static_rms_difference_deg_e:.3g} deg e RMS (their "
                f"RMS {rep.static_rms_deg_e:.3g})"
            )
        failed = f"no split-half figure: {rep.failure}" if rep.failure else "no figure"
        lines.append(f"  split-half repeatability: {'; '.join(parts) or failed}")
    lines += [f"  not assessed: {words(n)}" for n in d.not_assessed]
    return "\n".join(lines)


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
    spec = diagnosis.localisation.order_spectrum
    if spec:
        out.append(("Order spectrum", _bars(spec.mechanical_order, spec.amplitude, "amplitude [deg e]")))
    regions = diagnosis.localisation.per_region
    fig, ax = plt.subplots(figsize=(6, 3.5))
    sc = ax.scatter(
        [g.speed_rpm for g in regions],
        [g.current_a for g in regions],
        c=[g.mean_deg_e for g in regions],
        s=120,
        marker="o",
        cmap="coolwarm",
        edgecolors=["k" if g.direction > 0 else "r" for g in regions],
    )
    fig.colorbar(sc, ax=ax, label="mean residual [deg e]")
    ax.set_xlabel("speed [rpm]")
    ax.set_ylabel("mean phase current [A]")
    ax.set_title("operating regions (red edge: reverse)", fontsize=9)
    out.append(("Operating-region map", _png(fig)))

    names = [a.effect for a in diagnosis.accepted if a.effect in CANDIDATES]  # the mean edge effects
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
    speed = diagnosis.samples["speed"].localisation.order_spectrum if "speed" in diagnosis.samples else None
    if speed:
        out.append(
            (
                "Speed residual: order spectrum (cogging shows at its periods per turn)",
                _bars(speed.mechanical_order, speed.amplitude, "speed residual [rad/s]"),
            )
        )
    volt = diagnosis.samples["voltage"].localisation.per_electrical_angle_v if "voltage" in diagnosis.samples else {}
    if volt:
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot([float(k) for k in volt], list(volt.values()), "o-")
        ax.set_xlabel("electrical angle [deg]")
        ax.set_ylabel("voltage residual [V]")
        out.append(("Voltage-equation residual over the electrical turn", _png(fig)))
    return out


def repeatability_rows(rep: SplitHalf | None) -> list[dict]:
    """An ordinary run's split-half figures as rows (first half, second half, unit); ``key`` is
    the figure's key in the JSON."""
    if rep is None:
        return []
    rows = []
    if rep.delay_diff_s is not None:
        (a, b), (sa, sb) = rep.delay_diff_s, rep.delay_diff_stderr_s
        rows.append(
            {
                "figure": "rise-minus-fall delay difference",
                "key": "rise_fall_delay_difference_s",
                "value": f"{sig(a * 1e6)} +- {sig(sa * 1e6, 2)} / {sig(b * 1e6)} +- {sig(sb * 1e6, 2)}",
                "unit": "us",
            }
        )
        rows.append(
            {
                "figure": "halves apart (relative; in standard errors)",
                "key": "delay_relative_difference",
                "value": f"{100 * rep.delay_relative_difference:.2g} %; z = {sig(rep.delay_difference_z, 2)}",
                "unit": "",
            }
        )
    if rep.static_rms_difference_deg_e is not None:
        rows.append(
            {
                "figure": "other parameters: RMS difference of the halves (their RMS)",
                "key": "static_parameters_rms_difference_deg_e",
                "value": f"{sig(rep.static_rms_difference_deg_e, 3)} ({sig(rep.static_rms_deg_e, 3)})",
                "unit": "deg e",
            }
        )
    if rep.failure is not None:
        rows.append({"figure": "note", "key": "note", "value": f"no split-half figure: {rep.failure}", "unit": ""})
    return rows


def _ordinary_figures(rec, d: Diagnosis) -> list[tuple[str, str]]:
    from .ordinary import report_fit, sector_width_figure

    steps, fit = report_fit(rec, d)
    return [("Sector width against speed", _png(sector_width_figure(steps, fit, "")))]


def write_html(path, name, rec, diagnosis: Diagnosis, model=None) -> Path:
    """The HTML report of ``diagnosis`` of ``rec`` (either route)."""
    env = Environment(autoescape=select_autoescape(default=True))
    env.filters["sig"] = sig
    env.filters["words"] = words
    params = env.from_string(PARAMS_TEMPLATE)
    loc = diagnosis.localisation
    spectrum = []
    ordinary = diagnosis.route == ORDINARY_ROUTE
    if ordinary:
        figs = _ordinary_figures(rec, diagnosis)
    else:
        pred = model_prediction(model, rec) if model is not None else None
        r = residuals(rec, pred)
        figs = figures(r, build_cells(r), diagnosis)
        if loc.order_spectrum:
            spec = loc.order_spectrum
            spectrum = sorted(sorted(zip(spec.mechanical_order, spec.amplitude), key=lambda oa: -oa[1])[:8])
    html = env.from_string(TEMPLATE).render(
        name=name,
        d=diagnosis,
        accepted=[a.effect for a in diagnosis.accepted],
        below=[a.effect for a in diagnosis.below_relevance],
        figures=figs,
        loc=loc,
        localisation_tables=[] if ordinary else [
            ("Per sensor", "sensor", loc.per_sensor_deg_e),
            ("Per edge polarity", "edge", loc.per_polarity_deg_e),
            ("Per magnet pole", "pole", loc.per_pole_deg_e),
        ],
        spectrum=spectrum,
        segment_ids=rec.segment_ids,
        repeatability=repeatability_rows(diagnosis.repeatability),
        params_table=lambda a: Markup(
            params.render(a=a, meaning=ordinary_meaning(a.effect) if ordinary else None, rows=param_rows(a))
        ),
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html, encoding="utf-8")
    return path
