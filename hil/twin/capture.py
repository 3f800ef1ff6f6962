"""A plant built from a Hall capture: what the project's calibration of the capture found, as
effects of the effect library, and what the capture cannot tell, from a base plant.

The calibration (``hil.calibration.ordinary``) fits the rotor's trajectory and the deviations
jointly; here its figures become the twin's effects:

* ``installation_offset``: the relative offsets (sum zero) plus the base's mean (the absolute
  reference is not in capture times);
* ``pole_offset``: the pole table (sum zero per polarity) when a pole count is stated or found;
* ``switching_asymmetry``: each sensor's rise-minus-fall angle, constant in angle;
* ``conditioning_delay``: the rise-minus-fall delay difference on the later polarity over the
  base's common part;
* ``edge_jitter``: the residuals of the full fit (trajectory, offsets, poles, delay, the rotor's
  sector-locked ripple) less the timer's quantisation, as white time jitter plus AR(1) angle
  jitter: the variance per speed band gives the two RMS values (time jitter is constant in time,
  angle jitter grows in time as the speed falls), the lag-1 autocovariance of the angle residuals
  gives the colour;
* ``timer_quantization``: the capture's tick.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize

from bldc.motor import rewound
from bldc.params import ConfigError, validate
from bldc.reasons import Reason, words
from bldc.tomlfile import load_toml
from plant_models import PRESETS, PlantConfig
from plant_models.plant import OperatingRange
from plant_models import effects as fx

from ..calibration.corrections import SENSORS
from ..calibration.ordinary import (
    RISE_LABELS,
    SENSOR_LABELS,
    Effects,
    Fit,
    HallSteps,
    sum_zero_basis,
    fit_ordinary,
    hall_steps,
    ordinary_calibration,
)
from ..calibration.result import Calibration
from ..calibration.stats import OUTLIER_SD, chi2_test, inliers
from ..recording.format import Recording
from ..recording.load import load_recording

#: residual lags whose autocorrelation the twin check compares
ACF_LAGS = 12
#: the base plant when none is given
DEFAULT_BASE = "paper-bench"
#: the reference electrical speed of the calibration's ripple columns (ordinary.effect_columns)
RIPPLE_REF_HZ_E = 10.0


def load_base(base: str | None) -> PlantConfig:
    """A preset name or a plant TOML file."""
    base = base or DEFAULT_BASE
    if base in PRESETS:
        return PRESETS[base]()
    return PlantConfig.from_toml(base)


@dataclass
class NoiseModel:
    """Edge noise beyond the timer's quantisation, from the full fit's residuals."""

    time_rms_s: float
    angle_rms_deg_e: float
    correlation: float
    acf: list[float]  #: autocorrelation of the angle residuals, lags 1..ACF_LAGS
    band_speed_hz_e: list[float]
    band_excess_var_s2: list[float]
    kind: str = ""

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class CaptureAnalysis:
    """The capture as the project's calibration sees it, and the full fit behind it."""

    rec: Recording
    steps: HallSteps
    calibration: Calibration  #: the capture's ordinary-run calibration (``to_json()``: what ``hil calibrate`` writes)
    fit: Fit  #: trajectory, offsets, poles, delay and (where the capture shows it) the ripple
    pole_pairs: int | None
    tick_s: float | None
    ripple: bool
    asymmetry_deg_e: dict[str, tuple[float, float]]  #: per sensor rise minus fall (value, stderr)
    noise: NoiseModel
    extra: dict = field(default_factory=dict)


def analyse(rec: Recording, pole_pairs: int | None = None, source: str = "") -> CaptureAnalysis:
    """Calibrate the capture (``hil calibrate``'s ordinary-run route) and fit the full model."""
    steps = hall_steps(rec.t_s, rec.sensor, rec.rising)
    tick = rec.timer_tick_s
    cal = ordinary_calibration(
        steps, tick_s=tick, pole_pairs=pole_pairs or rec.stated_pole_pairs, source=source or str(rec.path or "")
    )
    a = cal.ordinary.assumptions
    p = a.pole_pairs if cal.corrections.pole_offset_deg_e else None
    ripple = a.ripple_modelled
    fit = fit_ordinary(steps, Effects(pole_pairs=p, ripple=ripple), tick_s=tick, knot_cycles=a.knot_cycles)
    table, resid, test = sensor_pole_pattern(fit, steps, p)
    an = CaptureAnalysis(
        rec, steps, cal, fit, a.pole_pairs, tick, ripple, sensor_asymmetry(fit),
        noise_model(fit, steps, tick, resid),
    )
    an.extra["sensor_pole_offset"] = {"table_deg_e": None if table is None else [float(v) for v in table], **test}
    return an


#: the per-sensor, per-pole pattern is kept when its chi-square over the 6p positions has a
#: p-value below this (white residuals would give such a pattern once in ten thousand captures)
PATTERN_P_VALUE = 1e-4
#: ... and when the faster half of the edges shows it as the slower half does (the amplitude ratio
#: in this range; a speed ripple locked to the rotor's position would fall with speed squared)
PATTERN_SLOPE = (0.5, 2.0)


def sensor_pole_pattern(fit: Fit, steps: HallSteps, p: int | None) -> tuple[np.ndarray | None, np.ndarray, dict]:
    """The residuals' mean per position in the mechanical turn (6p edges: each sensor at each pole
    boundary), as a spatial table [sensor * 2p + pole], and the residuals without it. Kept only
    when it stands out of the noise (chi-square of the position means against their standard
    errors); the least-squares residual is already free of the per-pole, per-sensor and
    rise-minus-fall parts, so this is what they leave."""
    from ..calibration.ordinary import SENSOR_OF_BOUNDARY, pole_of_boundary

    r = fit.residual_s
    if not p:
        return None, r, {"kept": False, "reason": Reason("TWIN-040")}
    tau = fit.tau_s_per_deg
    keep = inliers(r, fit.sigma_s)
    m = steps.boundary[fit.index]
    d = steps.direction[fit.index].astype(float)
    pos = np.mod(m, 6 * p)
    ang = r / tau  # deg e, trailing positive
    means, ses = np.zeros(6 * p), np.full(6 * p, np.inf)
    for j in range(6 * p):
        sel = keep & (pos == j)
        if sel.sum() >= 5:
            means[j] = float(np.mean(d[sel] * ang[sel]))  # spatial: a trail in reverse is a lead
            ses[j] = float(np.std(ang[sel]) / np.sqrt(sel.sum()))
    chi2, p_value = chi2_test(means, ses)
    # constant in angle, or the rotor's motion? The pattern of the slower and of the faster half of
    # the edges: a sensor's offset is the same in both (slope 1), a position-locked speed ripple
    # (cogging) falls with speed squared
    fast = 1.0 / tau > np.median(1.0 / tau)
    half, half_var = np.zeros((2, 6 * p)), np.zeros((2, 6 * p))
    for h, sel_h in enumerate((~fast, fast)):
        for j in range(6 * p):
            sel = keep & sel_h & (pos == j)
            half[h, j] = float(np.mean(d[sel] * ang[sel])) if sel.sum() >= 3 else np.nan
            half_var[h, j] = float(np.var(ang[sel]) / sel.sum()) if sel.sum() >= 3 else np.nan
    ok = np.isfinite(half).all(axis=0)
    # the amplitude ratio of the two halves' patterns, each half's power less what its noise adds
    # (a regression on a noisy half would be biased towards 0)
    power = [float(np.mean(half[h, ok] ** 2) - np.mean(half_var[h, ok])) for h in (0, 1)]
    same_sign = float(np.dot(half[0, ok], half[1, ok])) > 0
    slope = (math.sqrt(power[1] / power[0]) * (1.0 if same_sign else -1.0)
             if ok.sum() > 2 and min(power) > 0 else float("nan"))
    test = {"chi2": chi2, "positions": 6 * p, "p_value": p_value, "rms_deg_e": float(np.sqrt(np.mean(means**2))),
            "fast_over_slow_slope": slope}
    if p_value >= PATTERN_P_VALUE:
        return None, r, {"kept": False, "reason": Reason("TWIN-041", {"p_value": p_value}), **test}
    if not PATTERN_SLOPE[0] <= slope <= PATTERN_SLOPE[1]:  # (nan: not seen in one half)
        return None, r, {"kept": False, "reason": Reason("TWIN-042", {"slope": slope}), **test}
    probe = np.arange(6 * p)
    where = SENSOR_OF_BOUNDARY[probe % 3] * 2 * p + pole_of_boundary(probe, p)
    grid = np.zeros(6 * p)
    grid[where] = means
    # what the calibration's tables already hold is taken out (within each polarity of the poles:
    # the per-sensor mean is an installation offset or switching asymmetry, the per-pole mean a
    # pole offset), so the twin does not count it twice
    grid = grid.reshape(3, 2 * p)
    for parity in (0, 1):
        block = grid[:, parity::2]
        grid[:, parity::2] = block - block.mean(axis=1, keepdims=True) - block.mean(axis=0) + block.mean()
    table = grid.reshape(-1)
    return table, r - d * table[where][pos] * tau, {"kept": True, **test}


def _label_combination(fit: Fit, sgn: int, weights: np.ndarray, prefix: str = "static") -> tuple[float, float] | None:
    """A combination of the six per-label offsets (sum-zero basis) of one direction."""
    dname = "fwd" if sgn > 0 else "rev"
    keys = [f"{prefix}_{dname}_{j}" for j in range(5)]
    if keys[0] not in fit.names:
        return None
    z = sum_zero_basis(6)
    return fit.combination(dict(zip(keys, weights @ z)))


def _inverse_variance(vals: list[tuple[float, float]]) -> tuple[float, float]:
    v = np.array([a for a, _ in vals])
    w = 1.0 / np.maximum(np.array([b for _, b in vals]), 1e-12) ** 2
    return float(np.sum(w * v) / np.sum(w)), float(1.0 / np.sqrt(np.sum(w)))


def sensor_asymmetry(fit: Fit) -> dict[str, tuple[float, float]]:
    """Each sensor's rise-minus-fall trail (deg e, constant in angle), both directions combined."""
    out = {}
    for x, name in enumerate(SENSORS):
        vals = []
        for sgn in (1, -1):
            rise = [j for j in SENSOR_LABELS[x] if j in RISE_LABELS[sgn]]
            fall = [j for j in SENSOR_LABELS[x] if j not in RISE_LABELS[sgn]]
            w = np.zeros(6)
            w[rise], w[fall] = sgn, -sgn  # static offsets are spatial: they trail by sgn * offset
            r = _label_combination(fit, sgn, w)
            if r is not None:
                vals.append(r)
        out[name] = _inverse_variance(vals) if vals else (0.0, float("nan"))
    return out


def ripple_pattern_deg_e(fit: Fit, sgn: int) -> np.ndarray | None:
    """The sector-locked ripple's angle per boundary label at RIPPLE_REF_HZ_E (scales as 1/speed^2)."""
    dname = "fwd" if sgn > 0 else "rev"
    keys = [f"ripple_{dname}_{j}" for j in range(5)]
    if keys[0] not in fit.names:
        return None
    c = np.array([fit.coef[fit.names.index(k)] for k in keys])
    return sum_zero_basis(6) @ c


def residual_acf(x: np.ndarray, lags: int = ACF_LAGS) -> list[float]:
    x = x - x.mean()
    d = float(np.dot(x, x)) or 1.0
    return [float(np.dot(x[:-k], x[k:]) / d) for k in range(1, lags + 1)]


def noise_model(
    fit: Fit, steps: HallSteps, tick_s: float | None, residual_s: np.ndarray | None = None
) -> NoiseModel:
    """White time jitter plus AR(1) angle jitter from the residuals, quantisation taken off.

    Per speed decile, the residuals' variance within 4.5 robust standard deviations of their
    median (a rare bump of a slow rotor does not set the level the other edges see; a Gaussian or
    the uniform quantisation loses nothing there, so the parts still add) less the
    quantisation's tick^2 / 12 is
    ``sigma_t^2 + sigma_theta^2 tau^2``; both are fitted by non-negative least squares, each decile
    weighted by its total variance (the standard error of a variance is proportional to it).
    The colour: the lag-1 autocorrelation of
    the residuals standardised per decile, over neighbouring edges of a run, divided by the share
    of the angle jitter in their variance (quantisation and time jitter are white)."""
    r = fit.residual_s if residual_s is None else residual_s
    tau = fit.tau_s_per_deg
    q_var = (tick_s or 0.0) ** 2 / 12.0
    edges = np.quantile(tau, np.linspace(0, 1, 11))
    band = np.clip(np.searchsorted(edges, tau, side="right") - 1, 0, 9)
    sd = np.ones_like(r)
    tau_b, var_b = [], []
    for b in range(10):
        sel = band == b
        if sel.sum() < 20:
            continue
        dev = np.abs(r[sel] - np.median(r[sel]))
        mad = 1.4826 * float(np.median(dev))
        var = float(np.var(r[sel][dev < 4.5 * mad])) if mad > 0 else 0.0
        sd[sel] = max(math.sqrt(var), 1e-12)
        tau_b.append(float(np.median(tau[sel])))
        var_b.append(max(var - q_var, 0.0))
    tau_b, var_b = np.array(tau_b), np.array(var_b)
    design = np.column_stack([np.ones_like(tau_b), tau_b**2])
    rel = 1.0 / (var_b + q_var + 1e-30)  # a band variance's standard error is proportional to its total
    scale = np.array([1.0, float(np.median(tau_b)) ** 2])
    sol, _ = optimize.nnls(design * rel[:, None] / scale, var_b * rel)
    sol = sol / scale
    time_rms, angle_rms = math.sqrt(sol[0]), math.sqrt(sol[1])
    z = np.clip(r / sd, -OUTLIER_SD, OUTLIER_SD)  # an outlier weighs no more than the cut
    same_run = np.diff(steps.run[fit.index]) == 0
    acf1 = float(np.mean(z[1:][same_run] * z[:-1][same_run]) / np.mean(z**2)) if same_run.any() else 0.0
    share = float(np.mean(sol[1] * tau**2 / (sol[0] + sol[1] * tau**2 + q_var))) if sol[1] > 0 else 0.0
    rho = min(max(acf1 / share, 0.0), 0.95) if share > 0 else 0.0
    kind = (
        ("coloured AR(1)" if rho > 0.05 else "white")
        + (" angle jitter" if angle_rms > 0 else "")
        + (" and white time jitter" if time_rms > 0 else "")
    )
    return NoiseModel(
        time_rms_s=time_rms,
        angle_rms_deg_e=angle_rms,
        correlation=rho,
        acf=residual_acf(z),
        band_speed_hz_e=[float(1.0 / (360.0 * t)) for t in tau_b],
        band_excess_var_s2=[float(v) for v in var_b],
        kind=kind.strip(),
    )


@dataclass
class Twin:
    config: PlantConfig
    measured: list[tuple[str, Reason]]  #: (what, from the capture)
    assumed: list[tuple[str, Reason]]  #: (what, from the base and why)
    notes: list[Reason]
    analysis: CaptureAnalysis
    #: measured effects no calibration table holds, left out of the plant (UNCALIBRATABLE)
    left_out: list[fx.Effect] = field(default_factory=list)
    #: the effects taken from the base as they are (the rest are measured)
    from_base: list[str] = field(default_factory=list)


def _clip(v: float, lo: float, hi: float, what: str, notes: list[Reason]) -> float:
    if v < lo or v > hi:
        notes.append(Reason("TWIN-029", {"what": what, "value": v, "low": lo, "high": hi}))
    return min(max(v, lo), hi)


#: what a capture shows that no calibration table holds, each with the option that adds it to the
#: plant (docs/twin.md, "Why the default twin is what a table holds")
UNCALIBRATABLE = {"sensor_pole_offset": "--with-sensor-pole-pattern", "switching_asymmetry": "--with-sensor-asymmetry",
                  "edge_jitter": "--with-edge-noise"}
#: ... of which the default plant holds a part: the switching asymmetry common to the three sensors
#: (the pole table's two polarities hold it; the per-sensor rest no table of the built-in controller
#: holds: installation per sensor, offset per pole, delay per polarity)
PARTLY_HELD = {"switching_asymmetry": "the part common to the three sensors"}
#: what a twin takes of the base's motor and drive (the key of its assumed line)
MOTOR_ASSUMED = "motor (R, L, ke, J, friction, fan load, supply), inverter, current sensors"


def common_switching_asymmetry(an: CaptureAnalysis) -> fx.SwitchingAsymmetry:
    """The rise-minus-fall angle common to the three sensors, what a calibration table holds of it."""
    mean = float(np.mean([an.asymmetry_deg_e[s][0] for s in SENSORS]))
    return fx.SwitchingAsymmetry(rise_minus_fall_deg_e=(mean, mean, mean))


def uncalibratable_effects(an: CaptureAnalysis, pole_pairs: int,
                           notes: list[Reason] | None = None) -> dict[str, fx.Effect]:
    """The capture's deviations no calibration table holds (UNCALIBRATABLE), as effects: its
    residual pattern per sensor and pole (where it stands out) and its edge noise."""
    notes = [] if notes is None else notes
    out: dict[str, fx.Effect] = {}
    pattern = an.extra.get("sensor_pole_offset", {})
    if pattern.get("kept") and len(pattern["table_deg_e"]) == 6 * pole_pairs:
        lim = fx.bounds_of(fx.SensorPoleOffset, "offset_deg_e")[1]
        out["sensor_pole_offset"] = fx.SensorPoleOffset(offset_deg_e=tuple(
            _clip(v, -lim, lim, f"sensor_pole_offset_deg_e[{j}]", notes) for j, v in enumerate(pattern["table_deg_e"])))
    out["switching_asymmetry"] = fx.SwitchingAsymmetry(
        rise_minus_fall_deg_e=tuple(an.asymmetry_deg_e[s][0] for s in SENSORS))
    nm = an.noise
    lim_t = fx.bounds_of(fx.EdgeJitter, "time_rms_s")[1]
    lim_a = fx.bounds_of(fx.EdgeJitter, "angle_rms_deg_e")[1]
    out["edge_jitter"] = fx.EdgeJitter(
        time_rms_s=_clip(nm.time_rms_s, 0.0, lim_t, "edge_jitter.time_rms_s", notes),
        angle_rms_deg_e=_clip(nm.angle_rms_deg_e, 0.0, lim_a, "edge_jitter.angle_rms_deg_e", notes),
        correlation=nm.correlation)
    return out


def suite_speed_notes(pole_pairs: int, delay_s: float, top_speed_rpm: float,
                      capture_top_hz_e: float) -> list[Reason]:
    """Where the acceptance suite runs on this twin (the paper pump's speeds as fractions of the
    twin's top speed, ``PlantConfig.suite_speed_rpm``): its top electrical speed against the capture's,
    and the delay there against half a sector (beyond it an edge is captured after the middle of
    the next sector, and no table can place it)."""
    top_hz_e = top_speed_rpm / 60.0 * pole_pairs
    half_sector_s = 0.5 / (6.0 * top_hz_e)
    notes = [Reason("TWIN-026", {"top_speed_rpm": top_speed_rpm, "top_hz_e": top_hz_e, "delay_us": abs(delay_s) * 1e6,
                                 "delay_sectors": abs(delay_s) / (2 * half_sector_s)})]
    if top_hz_e > 1.5 * capture_top_hz_e:
        notes.append(Reason("TWIN-027", {"top_ratio": top_hz_e / capture_top_hz_e}))
    if abs(delay_s) > half_sector_s:
        notes.append(Reason("TWIN-028"))
    return notes


@dataclass
class _Making:
    """A twin in the making: its effects and what it says of each (measured, assumed, notes)."""

    base: PlantConfig
    base_name: str
    effects: list[fx.Effect] = field(default_factory=list)
    measured: list[tuple[str, Reason]] = field(default_factory=list)
    assumed: list[tuple[str, Reason]] = field(default_factory=list)
    notes: list[Reason] = field(default_factory=list)
    from_base: list[str] = field(default_factory=list)  #: the effects taken from the base as they are

    def take(self, effect: fx.Effect) -> None:
        self.effects.append(effect)
        self.from_base.append(effect.name)


def _pole_pairs(an: CaptureAnalysis, m: _Making) -> int:
    """The capture's pole pairs, or the base's when it shows no pole pattern."""
    p = an.pole_pairs or m.base.motor.pole_pairs
    if an.pole_pairs:
        m.measured.append(("motor.pole_pairs", Reason("TWIN-001", {
            "pole_pairs": p, "source": an.calibration.ordinary.assumptions.pole_pairs_source})))
    else:
        m.assumed.append(("motor.pole_pairs", Reason("TWIN-002", {"pole_pairs": p})))
    return int(p)


def _installation_offset(an: CaptureAnalysis, m: _Making) -> None:
    """The capture's relative offsets around the base's mean (capture times give only differences)."""
    base_inst = m.base.effect("installation_offset")
    mean_abs = float(np.mean(base_inst.offset_deg_e)) if base_inst else 0.0
    rel = an.calibration.corrections.installation_offset_deg_e
    lim = fx.bounds_of(fx.InstallationOffset, "offset_deg_e")[1]
    inst = tuple(_clip(rel[s] + mean_abs, -lim, lim, f"installation_offset_deg_e.{s}", m.notes) for s in SENSORS)
    m.effects.append(fx.InstallationOffset(offset_deg_e=inst))
    m.measured.append(("installation_offset (relative)",
                       Reason("TWIN-003", {"offsets_deg_e": {s: rel[s] for s in SENSORS}})))
    m.assumed.append(("installation_offset (absolute: the mean)",
                      Reason("TWIN-004", {"mean_deg_e": mean_abs, "base": m.base_name})))


def _pole_offset(an: CaptureAnalysis, p: int, m: _Making) -> None:
    """The calibration's pole table, when it holds one for ``p`` pole pairs."""
    cal = an.calibration
    poles = cal.corrections.pole_offset_deg_e
    if not (poles and len(poles) == 2 * p):
        why = cal.undetermined.get("pole_offset_deg_e")
        m.notes.append(Reason("TWIN-005", {"why": why}) if why else Reason("TWIN-006"))
        return
    lim = fx.bounds_of(fx.PoleOffset, "offset_deg_e")[1]
    m.effects.append(fx.PoleOffset(offset_deg_e=tuple(_clip(v, -lim, lim, f"pole_offset_deg_e[{j}]", m.notes)
                                                      for j, v in enumerate(poles))))
    m.measured.append(("pole_offset", Reason("TWIN-007", {"poles": len(poles),
                                                          "max_deg_e": max(abs(v) for v in poles)})))


def _beyond_table(an: CaptureAnalysis, p: int, m: _Making) -> dict[str, fx.Effect]:
    """The sensor-pole pattern (where it stands out) and the switching asymmetry, as effects; returns
    every measured deviation no table holds (the edge noise's is added by ``_edge_jitter``)."""
    beyond_table = uncalibratable_effects(an, p, m.notes)
    if "sensor_pole_offset" in beyond_table:
        pattern = an.extra.get("sensor_pole_offset", {})
        m.effects.append(beyond_table["sensor_pole_offset"])
        m.measured.append(("sensor_pole_offset", Reason("TWIN-008", {
            "edges_per_turn": 6 * p, "rms_deg_e": pattern["rms_deg_e"], "p_value": pattern["p_value"]})))
    asym = {s: an.asymmetry_deg_e[s][0] for s in SENSORS}
    m.effects.append(beyond_table["switching_asymmetry"])
    m.measured.append(("switching_asymmetry (rise minus fall, constant in angle)", Reason("TWIN-009", {
        "asymmetry_deg_e": asym, "common_deg_e": common_switching_asymmetry(an).rise_minus_fall_deg_e[0]})))
    return beyond_table


def _conditioning_delay(an: CaptureAnalysis, m: _Making) -> float:
    """The rise-minus-fall delay on the later polarity over the base's common part; returns the difference (s)."""
    d = an.calibration.ordinary.rise_fall_delay_difference_s
    d_value = d.value if d.value is not None else 0.0
    if d.value is None:
        m.notes.append(Reason("TWIN-010", {"why": d.reason}))
    base_delay = m.base.effect("conditioning_delay")
    common = min(base_delay.rise_delay_s, base_delay.fall_delay_s) if base_delay else 0.0
    rise, fall = common + max(d_value, 0.0), common + max(-d_value, 0.0)
    m.effects.append(fx.ConditioningDelay(rise_delay_s=rise, fall_delay_s=fall))
    m.measured.append(("conditioning_delay (rise minus fall)", Reason("TWIN-011", {"delay_us": d_value * 1e6})))
    m.assumed.append(("conditioning_delay (common part)",
                      Reason("TWIN-012", {"common_us": common * 1e6, "base": m.base_name})))
    return d_value


def _edge_jitter(an: CaptureAnalysis, beyond_table: dict[str, fx.Effect], m: _Making) -> None:
    nm = an.noise
    m.effects.append(beyond_table["edge_jitter"])
    m.measured.append(("edge_jitter", Reason("TWIN-013", {
        "kind": nm.kind, "time_rms_us": nm.time_rms_s * 1e6, "angle_rms_deg_e": nm.angle_rms_deg_e,
        "correlation": nm.correlation})))


def _timer(an: CaptureAnalysis, capture_tick_in_plant: bool, m: _Making) -> None:
    """The capture's tick in the plant when asked; else the base's timer (the capture's is the instrument's)."""
    if an.tick_s and capture_tick_in_plant:
        m.effects.append(fx.TimerQuantization(tick_s=an.tick_s))
        m.measured.append(("timer_quantization", Reason("TWIN-014", {"tick_us": an.tick_s * 1e6})))
    elif an.tick_s:
        base_tick = m.base.effect("timer_quantization")
        if base_tick:
            m.take(base_tick)
        m.measured.append(("capture timer tick (the instrument's)", Reason("TWIN-015", {"tick_us": an.tick_s * 1e6})))
    else:
        m.notes.append(Reason("TWIN-016"))


def _capture_blind(m: _Making) -> None:
    """What capture times cannot tell, from the base as it is: each effect that declares so
    (``Effect.from_base_in_twin``); those with a declared reason are named, present or not."""
    for cls in fx.EFFECTS.values():
        if cls.capture_blind is None:
            continue
        e = m.base.effect(cls.name)
        m.assumed.append((cls.name, Reason("TWIN-017" if e else "TWIN-018", {"capture_blind": cls.capture_blind})))
    for e in m.base.effects:
        if e.from_base_in_twin() and e.name not in {x.name for x in m.effects}:
            m.take(e)


def _top_speed(an: CaptureAnalysis, p: int, top_speed_rpm: float | None, m: _Making) -> float:
    """Where the suite's speeds end: the given top speed, or the capture's own (95th percentile)."""
    speeds = an.calibration.ordinary.assumptions.speed_range_hz_e
    m.notes.append(Reason("TWIN-019", {"low_hz_e": speeds[0], "high_hz_e": speeds[1]}))
    if top_speed_rpm is None:
        top_speed_rpm = speeds[1] / p * 60.0
        m.measured.append(("operating.top_speed_rpm", Reason("TWIN-020", {"top_speed_rpm": top_speed_rpm})))
    else:
        m.measured.append(("operating.top_speed_rpm", Reason("TWIN-021", {"top_speed_rpm": top_speed_rpm})))
    return top_speed_rpm


def _motor(p: int, top_speed_rpm: float, rewind_base: bool, m: _Making):
    """The base motor on ``p`` pole pairs, rewound for ``top_speed_rpm`` when the base is a stand-in."""
    base = m.base
    if not rewind_base:
        m.assumed.append((MOTOR_ASSUMED, Reason("TWIN-022", {"base": m.base_name})))
        return dataclasses.replace(base.motor, pole_pairs=p)
    k = base.operating.top_speed_rpm / top_speed_rpm
    m.assumed.append((MOTOR_ASSUMED, Reason("TWIN-023", {
        "base": m.base_name, "base_top_rpm": base.operating.top_speed_rpm, "top_speed_rpm": top_speed_rpm,
        "pole_pairs": p, "ke_factor": k, "j_factor": k * k, "fan_factor": k ** 3,
        "l_factor": k * base.motor.pole_pairs / p})))
    return rewound(base.motor, k, p)


def _leave_out(an: CaptureAnalysis, with_: tuple[str, ...], m: _Making) -> list[fx.Effect]:
    """Take the measured deviations no table holds out of the plant unless ``with_`` names them (the
    switching asymmetry's common part stays); returns those left out."""
    left_out = [e for e in m.effects if e.name in UNCALIBRATABLE and e.name not in with_]
    held = {"switching_asymmetry": common_switching_asymmetry(an)}
    m.effects = [e if e.name not in UNCALIBRATABLE or e.name in with_ else held[e.name]
                 for e in m.effects if e.name not in UNCALIBRATABLE or e.name in with_ or e.name in held]
    for e in left_out:
        m.notes.append(Reason("TWIN-025", {"effect": e.name, "held_part": PARTLY_HELD[e.name],
                                           "option": UNCALIBRATABLE[e.name]}) if e.name in PARTLY_HELD
                       else Reason("TWIN-024", {"effect": e.name, "option": UNCALIBRATABLE[e.name]}))
    return left_out


def twin_from_capture(an: CaptureAnalysis, base: PlantConfig, base_name: str,
                      capture_tick_in_plant: bool = False, with_: tuple[str, ...] = (),
                      top_speed_rpm: float | None = None, rewind_base: bool = False) -> Twin:
    """The twin plant: the capture's calibration as effects, the rest from ``base``; its top speed
    (where the acceptance suite's speeds end, ``OperatingRange``) is ``top_speed_rpm`` or else the
    capture's own top (95th percentile): the suite then judges the twin where it was measured. With
    ``rewind_base`` (a preset base: a stand-in, not this motor) the base motor is rewound for that top
    speed (``bldc.motor.rewound``): the base pump's duty, current and dynamics at its top speed are
    the twin's at its own, where a pump motor run at 3 % of its speed would idle at 1 % duty. By default
    only the deviations a calibration table can hold; ``with_`` names the measured deviations no
    table holds (UNCALIBRATABLE) that the plant carries too. Each one left out is listed in
    ``Twin.left_out`` (and in the TOML), and ``hil twin check`` names it as a difference."""
    unknown = set(with_) - set(UNCALIBRATABLE)
    if unknown:
        raise ValueError(f"unknown addition(s) {', '.join(sorted(unknown))} (known: {', '.join(UNCALIBRATABLE)})")
    m = _Making(base, base_name)
    p = _pole_pairs(an, m)
    _installation_offset(an, m)
    _pole_offset(an, p, m)
    beyond_table = _beyond_table(an, p, m)
    d_value = _conditioning_delay(an, m)
    _edge_jitter(an, beyond_table, m)
    _timer(an, capture_tick_in_plant, m)
    _capture_blind(m)
    top_speed_rpm = _top_speed(an, p, top_speed_rpm, m)
    motor = _motor(p, top_speed_rpm, rewind_base, m)
    m.notes += suite_speed_notes(p, d_value, top_speed_rpm, an.calibration.ordinary.assumptions.speed_range_hz_e[1])
    left_out = _leave_out(an, with_, m)
    name = f"twin of {Path(str(an.rec.path or 'capture')).name}"
    config = PlantConfig(motor=motor, inverter=base.inverter, current_sensor=base.current_sensor,
                         effects=tuple(m.effects), name=name, operating=OperatingRange(top_speed_rpm=top_speed_rpm))
    return Twin(config, m.measured, m.assumed, m.notes, an, left_out=left_out, from_base=m.from_base)


# --- TOML ------------------------------------------------------------------------------------


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, float):
        return repr(float(v)) if math.isfinite(v) else "nan"
    return str(v)


def _left_out_line(e: fx.Effect) -> Reason:
    """A measured effect the plant leaves out, as the TOML's comment names it: the option that adds it, its values."""
    if e.name in PARTLY_HELD:
        return Reason("TWIN-036", {"effect": e.name, "option": UNCALIBRATABLE[e.name], "held_part": PARTLY_HELD[e.name],
                                   "params": e.to_dict()})
    return Reason("TWIN-035", {"effect": e.name, "option": UNCALIBRATABLE[e.name], "params": e.to_dict()})


def twin_toml(twin: Twin, source: str, base_name: str) -> str:
    """The plant TOML of ``twin``, with what was measured and what was assumed as comments."""
    c = twin.config
    lines = [f"# {words(Reason('TWIN-030', {'source': source}))}",
             f"# {words(Reason('TWIN-031', {'base': base_name}))}", "#", f"# {words(Reason('TWIN-032'))}"]
    lines += [f"#   {what}: {words(how)}" for what, how in twin.measured]
    lines += ["#", f"# {words(Reason('TWIN-033'))}"]
    lines += [f"#   {what}: {words(how)}" for what, how in twin.assumed]
    if twin.left_out:
        lines += ["#", f"# {words(Reason('TWIN-034'))}"]
        lines += [f"#   {words(_left_out_line(e))}" for e in twin.left_out]
    if twin.notes:
        lines += ["#", f"# {words(Reason('TWIN-037'))}"] + [f"#   {words(n)}" for n in twin.notes]
    lines += ["", f"name = {_toml_value(c.name)}", "", "[motor]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(c.motor).items()]
    lines += ["", "[inverter]"] + [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(c.inverter).items()]
    lines += ["", "[current_sensor]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(c.current_sensor).items()]
    lines += ["", "[operating]"] + [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(c.operating).items()]
    for e in c.effects:
        d = e.to_dict()
        tag = Reason("TWIN-038") if e.name in twin.from_base else Reason("TWIN-039")
        lines += ["", f"[[effects]]  # {words(tag)}"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in d.items()]
    return "\n".join(lines) + "\n"


def from_capture(recording: str | Path, base: str | None = None, pole_pairs: int | None = None,
                 capture_tick_in_plant: bool = False, with_: tuple[str, ...] = (),
                 top_speed_rpm: float | None = None) -> tuple[Twin, str]:
    """The twin of a capture and its TOML text."""
    if top_speed_rpm is not None:  # the plant's own bound on it, named as the option that gave it
        try:
            validate(OperatingRange(top_speed_rpm=float(top_speed_rpm)))
        except ConfigError as exc:
            raise ConfigError("--top-speed-rpm", str(exc).split(": ", 1)[1]) from None
    rec = load_recording(recording, pole_pairs)
    base_name = base or DEFAULT_BASE
    base_config = load_base(base)
    if top_speed_rpm is None and base_name not in PRESETS and "operating" in load_toml(Path(base_name)):
        top_speed_rpm = base_config.operating.top_speed_rpm  # the user's motor states its own top speed
    twin = twin_from_capture(analyse(rec, pole_pairs, source=str(recording)), base_config, base_name,
                             capture_tick_in_plant, with_, top_speed_rpm, rewind_base=base_name in PRESETS)
    text = twin_toml(twin, Path(str(recording)).name, base_name)
    return twin, text
