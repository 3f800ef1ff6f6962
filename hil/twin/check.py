"""``hil twin check``: the twin along the capture's own trajectory, put through the capture's analysis.

Both the capture and the twin's capture go through the same steps: the ordinary-run calibration
(each figure with its standard error), the sector widths against speed per edge slot, the
residuals' autocorrelation, and every predictor of ``hil predictors compare`` scored on the second
half. Where a figure differs beyond its uncertainty, the candidates the capture's own calibration
names (the rotor's sector-locked speed ripple, which it fits as a nuisance) are added to the twin
one at a time, and a difference the addition closes is marked ``explained_by_adding``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from plant_models import PlantConfig

from ..calibration.corrections import SENSORS
from ..calibration.ordinary import speed_hz_e
from ..calibration.result import Estimate
from ..experiments import peers
from ..recording.load import load_recording
from .capture import UNCALIBRATABLE, CaptureAnalysis, analyse, uncalibratable_effects
from .replay import twin_recording
from .result import (
    RATIO_BAND,
    AutocorrelationDifference,
    Comparison,
    Difference,
    FigureComparison,
    FigureDifference,
    LeftOutDifference,
    PredictorDifference,
    PredictorRatio,
    SectorWidths,
    TwinCheck,
    Variant,
    WidthDifference,
)

#: speed bins of the sector-width comparison (over the capture's 5-95 % speed range)
WIDTH_BINS = 8
#: what the twin can take on, and what it is
CANDIDATES = {
    "sector_locked_speed_ripple": "the rotor's speed ripple locked to the sectors (commutation torque ripple: an "
    "angle per sector boundary falling with 1/speed^2), which the capture's calibration fitted as a nuisance",
}


def predictor_rows(rec, source: str) -> dict:
    """Commutation-error RMS (deg e) per predictor, as ``hil predictors compare RECORDING`` scores it
    (calibrated on the first half, scored on the second). The one place the twin check calls the
    predictors: a registry of predictors replaces this adapter when there is one."""
    try:
        result = peers.compare_recording(rec, source)
    except ValueError as exc:  # a capture the comparison refuses (too few edges, a correction that reorders)
        return {"error": str(exc)}
    return {r["name"]: r["angle_rms_deg_e"] for r in result["predictors"]}


def _vs(value, stderr) -> dict:
    return {"value": None if value is None else float(value),
            "stderr": None if stderr is None or not math.isfinite(stderr) else float(stderr)}


def calibration_figures(an: CaptureAnalysis) -> dict:
    cal, o = an.calibration.corrections, an.calibration.ordinary
    unc = cal.uncertainty
    delay, angle = o.rise_fall_delay_difference_s, o.rise_fall_angle_asymmetry_deg_e
    # the method cross-check's delay as the calibration writes it (no stderr filtering: a copy)
    ind = None if o.cross_check is None else Estimate(o.cross_check.delay_diff_s, o.cross_check.stderr_s).to_json()
    return {
        "rise_fall_delay_difference_s": _vs(delay.value, delay.stderr),
        "rise_fall_angle_asymmetry_deg_e": _vs(angle.value, angle.stderr),
        "independent_rise_fall_delay_difference_s": ind,
        **{f"installation_offset_deg_e.{s}": _vs(cal.installation_offset_deg_e[s],
                                                 unc["installation_offset_deg_e"].get(s)) for s in SENSORS},
        **{f"switching_asymmetry_deg_e.{s}": _vs(*an.asymmetry_deg_e[s]) for s in SENSORS},
        **{f"pole_offset_deg_e[{j}]": _vs(v, s) for j, (v, s) in
           enumerate(zip(cal.pole_offset_deg_e, unc["pole_offset_deg_e"]))},
        "trajectory_residual_rms_deg_e": _vs(o.assumptions.trajectory_residual_rms_deg_e, None),
        "edge_jitter_angle_rms_deg_e": _vs(an.noise.angle_rms_deg_e, None),
        "edge_jitter_time_rms_s": _vs(an.noise.time_rms_s, None),
        "edge_jitter_correlation": _vs(an.noise.correlation, None),
        "sector_locked_speed_ripple": o.assumptions.sector_locked_speed_ripple(),
        "edges_used": o.assumptions.edges_used,
    }


def sector_widths(an: CaptureAnalysis, bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean sector width (deg e) per edge slot (the label of the edge opening the sector, and its
    polarity) and speed bin, and its standard error."""
    steps = an.steps
    f = speed_hz_e(steps)
    used = np.nonzero(steps.used())[0]
    k = used[:-1][(steps.run[used[1:]] == steps.run[used[:-1]])]
    width = 360.0 * 0.5 * (f[k] + f[k + 1]) * (steps.t_s[k + 1] - steps.t_s[k])
    speed = 0.5 * (f[k] + f[k + 1])
    label = np.mod(steps.boundary[k], 6)
    b = np.digitize(speed, bins) - 1
    mean = np.full((6, bins.size - 1), np.nan)
    se = np.full((6, bins.size - 1), np.nan)
    for s in range(6):
        for j in range(bins.size - 1):
            sel = (label == s) & (b == j)
            if sel.sum() >= 5:
                mean[s, j] = float(np.mean(width[sel]))
                se[s, j] = float(np.std(width[sel]) / math.sqrt(sel.sum()))
    return mean, se


def _analyse_twin(config: PlantConfig, real: CaptureAnalysis, seed: int, ripple: bool, name: str):
    rec = twin_recording(config, real, seed=seed, ripple=ripple)
    an = analyse(rec, real.pole_pairs, source=name)
    return an, predictor_rows(rec, name)


def _beyond_table_figure(an: CaptureAnalysis, name: str) -> float:
    """What a capture shows of an effect no table holds: the RMS (deg e) of its residual pattern per
    sensor and pole, or of its edge noise's angle jitter."""
    if name == "sensor_pole_offset":
        return float(an.extra.get("sensor_pole_offset", {}).get("rms_deg_e", 0.0))
    if name == "switching_asymmetry":  # its per-sensor part: what the common part leaves
        a = np.array([an.asymmetry_deg_e[s][0] for s in SENSORS])
        return float(np.sqrt(np.mean((a - a.mean()) ** 2)))
    return float(an.noise.angle_rms_deg_e)


def _left_out_differences(real: CaptureAnalysis, twin: CaptureAnalysis, with_them: CaptureAnalysis,
                          left_out: list[str]) -> list[Difference]:
    """Each measured effect the twin leaves out (no table holds it) is a difference the twin lacks;
    adding it explains it when the twin's capture then shows it as the real one does."""
    out = []
    for name in left_out:
        d = LeftOutDifference(name, *(_beyond_table_figure(a, name) for a in (real, twin, with_them)))
        d.explained_by_adding, d.added = d.closed, name if d.closed else None
        out.append(d)
    return out


def _figure_differences(real: dict, twin: dict) -> dict[str, FigureComparison]:
    """The figures both captures give with a standard error, side by side."""
    out = {}
    for k, r in real.items():
        t = twin.get(k)
        if not isinstance(r, dict) or not isinstance(t, dict) or r.get("value") is None or t.get("value") is None:
            continue
        if r.get("stderr") is None or t.get("stderr") is None:
            continue
        out[k] = FigureComparison(r["value"], t["value"], math.hypot(r["stderr"], t["stderr"]))
    return out


def _ratios(real_rows: dict, twin_rows: dict) -> list[PredictorRatio]:
    out = [PredictorRatio("all", None, None, error=f"{side}: {rows['error']}")
           for side, rows in (("real", real_rows), ("twin", twin_rows)) if "error" in rows]
    names = [n for n in (real_rows if "error" not in real_rows else twin_rows) if n != "error"]
    return out + [PredictorRatio(name, real_rows.get(name), twin_rows.get(name)) for name in names]


def _compare(real: CaptureAnalysis, real_fig: dict, real_rows: dict, twin: CaptureAnalysis, twin_rows: dict,
             bins: np.ndarray) -> Comparison:
    """One twin run against the capture: every figure side by side and what differs."""
    twin_fig = calibration_figures(twin)
    (real_w, real_se), (twin_w, twin_se) = sector_widths(real, bins), sector_widths(twin, bins)
    widths = SectorWidths([float(v) for v in bins], real_w, twin_w, real_se, twin_se)
    acf_se = 1.0 / math.sqrt(max(real.fit.index.size, 1))  # an autocorrelation estimate of white noise
    figs = _figure_differences(real_fig, twin_fig)
    preds = _ratios(real_rows, twin_rows)
    return Comparison(
        int(real.rec.t_s.size), int(twin.rec.t_s.size), real_fig, twin_fig, figs, real.noise, twin.noise, acf_se,
        widths, preds, _differences(figs, preds, widths, np.array(real.noise.acf), np.array(twin.noise.acf), acf_se,
                                    real.pole_pairs),
    )


def twin_check(recording: str | Path, plant: str | Path, seed: int = 0, take_on: tuple[str, ...] | None = None,
               log=print) -> TwinCheck:
    """The comparison of a capture and its twin (JSON contract in docs/twin.md). ``take_on``: the
    additions the twin runs with; None takes on what the capture's own calibration modelled (the
    rotor's sector-locked ripple, part of the trajectory the twin follows). The twin without them
    is compared too, and its differences say which addition closes them."""
    config = PlantConfig.from_toml(plant)
    for c in take_on or ():
        if c not in CANDIDATES and c not in UNCALIBRATABLE:
            raise ValueError(f"--take-on: unknown addition {c!r} (known: {', '.join([*CANDIDATES, *UNCALIBRATABLE])})")
    rec = load_recording(recording, config.motor.pole_pairs)
    log(f"{recording}: calibrating the capture ({len(rec)} edges)")
    real = analyse(rec, config.motor.pole_pairs, source=str(recording))
    if real.pole_pairs is not None and real.pole_pairs != config.motor.pole_pairs:
        raise ValueError(f"{plant}: motor.pole_pairs {config.motor.pole_pairs}, the capture's {real.pole_pairs}")
    # what the capture shows and no calibration table holds, left out of the twin's plant (docs/twin.md)
    beyond = uncalibratable_effects(real, config.motor.pole_pairs)
    left_out = [n for n in beyond if config.effect(n) != beyond[n] and _beyond_table_figure(real, n) > 0]
    if take_on is None:  # the capture's own ripple and what the plant leaves out: the motor as measured
        take_on = (("sector_locked_speed_ripple",) if real.ripple else ()) + tuple(left_out)
    real_rows = predictor_rows(rec, str(recording))
    real_fig = calibration_figures(real)
    lo, hi = real.calibration.ordinary.assumptions.speed_range_hz_e
    bins = np.linspace(lo, hi, WIDTH_BINS + 1)
    log("running the twin along the capture's trajectory")
    plain, plain_rows = _analyse_twin(config, real, seed, False, f"twin of {recording}")
    bare = _compare(real, real_fig, real_rows, plain, plain_rows, bins)
    main, main_an = bare, plain
    variants = {}
    ripple_possible = real.ripple and ripple_pattern_available(real)
    if ripple_possible and ("sector_locked_speed_ripple" in take_on or bare.differences):
        log("adding the capture's sector-locked speed ripple to the twin's trajectory")
        tw2, rows2 = _analyse_twin(config, real, seed, True, f"twin of {recording} with ripple")
        with_ripple = _compare(real, real_fig, real_rows, tw2, rows2, bins)
        remaining = {d.what for d in with_ripple.differences}
        for d in bare.differences:
            d.explained_by_adding = d.what not in remaining
            if d.explained_by_adding:
                d.added = "sector_locked_speed_ripple"
        if "sector_locked_speed_ripple" in take_on:
            main, main_an = with_ripple, tw2
            variants["without_additions"] = Variant(bare)
        else:
            variants["sector_locked_speed_ripple"] = Variant(
                with_ripple, CANDIDATES["sector_locked_speed_ripple"],
                f"hil twin check {recording} {plant} --take-on sector_locked_speed_ripple")
    else:
        for d in bare.differences:
            d.explained_by_adding = False
    _not_closed_unless_found(main.differences)
    # what the plant leaves out: named as differences of the plant as written; the twin run with them
    # added says which other differences they explain, and is the headline when taken on
    written = main
    added = [n for n in left_out if n in take_on]
    adding = added or left_out  # what --take-on asked for, else (for the comparison) all of it
    if left_out:
        log(f"adding what the twin leaves out ({', '.join(adding)}) to the twin")
        ripple_on = main is not bare
        tw3, rows3 = _analyse_twin(config.with_effects(*(beyond[n] for n in adding)), real, seed, ripple_on,
                                   f"twin of {recording} with {', '.join(adding)}")
        with_left = _compare(real, real_fig, real_rows, tw3, rows3, bins)
        remaining = {d.what for d in with_left.differences}
        for d in written.differences:
            if not d.explained_by_adding and d.what not in remaining:
                d.explained_by_adding, d.added = True, ", ".join(adding)
        lacking = _left_out_differences(real, main_an, tw3, left_out)
        written.differences += lacking  # in place: the twin as written lacks them wherever it is shown
        as_written = Variant(written, "the plant as written (what `hil acceptance --plant` runs), without "
                             + ", ".join(left_out))
        if added:
            _not_closed_unless_found(with_left.differences)
            main = dataclasses.replace(with_left, differences=with_left.differences + [d for d in lacking
                                                                                      if d.explained_by_adding])
            variants["as_written"] = as_written
        else:
            variants["measured_but_left_out"] = Variant(
                with_left, "the twin with what the capture shows and no calibration table holds: " + ", ".join(adding),
                f"hil twin check {recording} {plant}" + "".join(f" --take-on {n}" for n in left_out))
    taken_on = (["sector_locked_speed_ripple"] if ripple_possible and "sector_locked_speed_ripple" in take_on
                else []) + added
    return TwinCheck(str(recording), str(plant), seed, taken_on, left_out, real.tick_s, main, bare.differences,
                     variants)


def _not_closed_unless_found(differences: list[Difference]) -> None:
    """The headline's differences say whether an addition closed them: not, where none was found to."""
    for d in differences:
        if d.explained_by_adding is None:
            d.explained_by_adding = False


def ripple_pattern_available(an: CaptureAnalysis) -> bool:
    return any(n.startswith("ripple_") for n in an.fit.names)


def _differences(figs: dict[str, FigureComparison], preds: list[PredictorRatio], widths: SectorWidths,
                 acf_real, acf_twin, acf_se, pole_pairs=None) -> list[Difference]:
    out: list[Difference] = [FigureDifference(k, f) for k, f in figs.items() if f.beyond]
    out += [PredictorDifference(p) for p in preds if p.error or not p.within_band]
    diff = widths.difference_deg_e
    se = widths.combined_stderr_deg_e
    z = np.abs(diff) / np.where(se > 0, se, np.nan)
    if np.nanmax(z, initial=0.0) > 5.0:
        s, j = np.unravel_index(np.nanargmax(z), z.shape)
        out.append(WidthDifference(int(s), int(j), float(diff[s, j]), float(z[s, j])))
    lag = int(np.argmax(np.abs(acf_twin - acf_real)))
    if abs(acf_twin[lag] - acf_real[lag]) > 4.0 * acf_se:
        out.append(AutocorrelationDifference(lag + 1, float(acf_real[lag]), float(acf_twin[lag]), acf_se, pole_pairs))
    return out


def format_check(result: dict) -> str:
    """A twin check's JSON (``TwinCheck.to_json()``, or a saved file) for the reader."""
    c = result["calibration"]
    lines = [f"{result['recording']} against its twin {result['twin']}"]
    for k in ("rise_fall_delay_difference_s", "rise_fall_angle_asymmetry_deg_e", "trajectory_residual_rms_deg_e",
              "edge_jitter_angle_rms_deg_e", "edge_jitter_correlation"):
        r, t = c["real"].get(k) or {}, c["twin"].get(k) or {}
        scale, unit = (1e6, "us") if k.endswith("_s") else (1.0, "")

        def f(d):
            if d.get("value") is None:
                return "-"
            se = d.get("stderr")
            return f"{d['value'] * scale:.4g}" + (f" +- {se * scale:.2g}" if se is not None else "")

        lines.append(f"  {k:<34} real {f(r):>18}  twin {f(t):>18} {unit}")
    widest = result["sector_widths"]["max_abs_difference_deg_e"]
    lines.append(f"  sector widths: largest twin - real difference {widest:.2f} deg e")
    lines.append(f"  {'predictor':<16}{'real RMS':>10}{'twin RMS':>10}{'ratio':>8}")
    for p in result["predictors"]:
        fmt = lambda v: "-" if v is None else (f"{v:.3f}" if abs(v) < 1e4 else f"{v:.2e}")  # noqa: E731
        lines.append(f"  {p['name']:<16}{fmt(p['real_rms_deg_e']):>10}{fmt(p['twin_rms_deg_e']):>10}"
                     f"{fmt(p['ratio']):>8}{'' if p['within_band'] else '  outside ' + str(RATIO_BAND)}")
    for d in result["differences"]:
        lines.append(f"  differs: {d['what']}: {d['effect']}"
                     + ("; closed by adding " + d["added"] if d.get("explained_by_adding") else ""))
    return "\n".join(lines)
