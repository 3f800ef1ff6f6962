"""``hil gap validate``: the diagnosis checks itself on data whose effect was withheld.

For each effect that leaves a mean edge-angle signature, and random magnitudes (signal-to-noise
1-10) and seeds: simulate a recording with that effect, withhold it from the model (the model is
the nominal motor with the known noise), diagnose, score. Also null recordings, recordings with
two effects withheld, and recordings with an effect outside the candidate list (one sensor's own
conditioning delay, or a lag growing with the square of speed), which must come out
"unexplained". SNR = RMS of the effect's per-edge signature / RMS of the per-edge noise.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from hil.recording import Recording, record_kinematic
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx
from plant_models.kinematic import OperatingPoint
from plant_models.plant import steady_state

from .candidates import CANDIDATES
from .diagnose import diagnose

EFFECT_NAMES = tuple(CANDIDATES) + ("edge_jitter",)
JITTER_S = 1e-6
TICK_S = 1e-7
#: what the model knows: the nominal motor and the bench's base edge jitter
KNOWN_MODEL = paper_bench().with_effects(fx.EdgeJitter(time_rms_s=JITTER_S))


def profile(config: PlantConfig, turns: int = 30) -> list[OperatingPoint]:
    """The operating points a bench would record: three speeds, no load and pump load, and a
    reverse run (the knobs that separate confounded effects)."""
    m = config.motor
    ops = []
    for rpm in (2000.0, 5000.0, 8000.0):
        for load in (0.0, 1.0):
            ops.append(OperatingPoint(turns * 60 / rpm, rpm, steady_state(m, rpm, load)["current_a"] * 2 / 3, load_scale=load,
                                      id=f"{'load' if load else 'noload'}_{rpm:.0f}"))
    ops.append(OperatingPoint(turns * 60 / 5000.0, 5000.0, steady_state(m, 5000.0, 1.0)["current_a"] * 2 / 3, direction=-1, load_scale=1.0, id="reverse_5000"))
    return ops


def _unit_effect(name: str, rng: np.random.Generator, pole_pairs: int) -> fx.Effect:
    """A random direction in the effect's parameter space (scaled to the SNR afterwards)."""
    if name == "installation_offset":
        return fx.InstallationOffset(tuple(rng.uniform(-1, 1, 3)))
    if name == "pole_offset":
        return fx.PoleOffset(tuple(rng.uniform(-1, 1, 2 * pole_pairs)))
    if name == "eccentricity":
        return fx.Eccentricity(1.0, float(rng.uniform(0, 2 * math.pi)))
    if name == "hysteresis":
        return fx.Hysteresis(1.0)
    if name == "conditioning_delay":
        rise = rng.uniform(0.3, 1.0)
        return fx.ConditioningDelay(rise * 1e-5, rng.uniform(0.0, 1.0) * rise * 1e-5)
    if name == "armature_reaction":
        return fx.ArmatureReaction(float(rng.choice([-1, 1]) * rng.uniform(0.5, 1.0)))
    if name == "timer_quantization":
        return fx.TimerQuantization(1e-6)
    raise KeyError(name)


def _scale(effect: fx.Effect, factor: float) -> fx.Effect:
    changes = {}
    for f in dataclasses.fields(effect):
        v = getattr(effect, f.name)
        if f.name == "phase_rad":
            continue
        meta = f.metadata
        lo, hi = meta.get("low"), meta.get("high")
        if isinstance(v, tuple):
            changes[f.name] = tuple(float(np.clip(x * factor, lo, hi)) for x in v)
        elif isinstance(v, float):
            changes[f.name] = float(np.clip(v * factor, lo, hi))
    return dataclasses.replace(effect, **changes)


def _signature_rms(config: PlantConfig, effects, ops, seed: int) -> float:
    e = _truth_error(config.with_effects(*effects), ops, seed)
    return float(np.sqrt(np.mean(e**2)))


def _truth_error(config, ops, seed):
    from plant_models.kinematic import simulate_edges

    e = simulate_edges(config, ops, seed=seed)
    return e.direction * (e.theta_e_capture_deg - e.ideal_angle_deg_e) if len(e) else np.zeros(0)


def _noise_rms(ops, pole_pairs):
    w = np.array([op.speed_rpm * 6 * pole_pairs for op in ops])
    n = np.array([op.duration_s * op.speed_rpm / 60 * 6 * pole_pairs for op in ops])
    per = (w * JITTER_S) ** 2 + (w * TICK_S) ** 2 / 12
    return float(np.sqrt(np.sum(n * per) / np.sum(n)))


def make_case(effects_withheld: list[str], snr: float, seed: int, base: PlantConfig | None = None, ool: str | None = None):
    """A recording with ``effects_withheld`` at signal-to-noise ``snr`` (and an out-of-library
    effect ``ool``); returns (recording, list of true effects)."""
    base = base or paper_bench()
    rng = np.random.default_rng(seed)
    noise = [fx.EdgeJitter(time_rms_s=JITTER_S)]
    ops = profile(base)
    p = base.motor.pole_pairs
    truth = []
    for name in effects_withheld:
        if name == "edge_jitter":  # an extra jitter component the model does not know
            extra = snr * JITTER_S
            noise = [fx.EdgeJitter(time_rms_s=math.hypot(JITTER_S, extra))]
            truth.append(fx.EdgeJitter(time_rms_s=extra))
            continue
        unit = _unit_effect(name, rng, p)
        if name == "timer_quantization":
            eff = fx.TimerQuantization(min(1e-5, 2 * snr * _noise_rms(ops, p) / (np.mean([op.speed_rpm for op in ops]) * 6 * p) * math.sqrt(3)))
        else:
            sig = _signature_rms(base, [unit], ops, seed)
            eff = _scale(unit, snr * _noise_rms(ops, p) / max(sig, 1e-12))
        truth.append(eff)
    known_tick = not any(e.name == "timer_quantization" for e in truth)
    injected = [t for t in truth if t.name != "edge_jitter"]  # withheld jitter is already in ``noise``
    config = base.with_effects(*noise, *injected, *([fx.TimerQuantization(TICK_S)] if known_tick else []))
    rec = record_kinematic(config, ops, seed=seed)
    if not known_tick:
        rec.timer_tick_s = None  # withheld: the model does not know the capture timer
    if ool:
        _inject_out_of_library(rec, ool, snr * _noise_rms(ops, p), rng)
    return rec, truth


def _inject_out_of_library(rec: Recording, kind: str, target_rms_deg: float, rng) -> None:
    """Effects no candidate describes: one sensor's own RC delay, or a lag growing with speed^2."""
    p = rec.pole_pairs
    w = np.array([s.speed_rpm * 6 * p for s in rec.segments])[rec.segment]
    if kind == "sensor_delay":
        x = int(rng.integers(0, 3))
        shift_deg = np.where(rec.sensor == x, w, 0.0)
    else:  # speed_squared
        shift_deg = (w / w.max()) ** 2 * w.max()
    shift_deg = shift_deg * (target_rms_deg / max(np.sqrt(np.mean(shift_deg**2)), 1e-12))
    dt = shift_deg / w
    rec.t_s = rec.t_s + dt
    rec.ref_angle_mech_deg = np.mod(rec.ref_angle_mech_deg + np.array([s.direction_sign for s in rec.segments])[rec.segment] * shift_deg / p, 360.0)
    order = np.argsort(rec.t_s, kind="stable")
    for name in ("t_s", "sensor", "rising", "segment", "ref_angle_mech_deg"):
        setattr(rec, name, getattr(rec, name)[order])
    if rec.truth is not None:
        rec.truth = {k: v[order] for k, v in rec.truth.items()}


def _param_error(truth: fx.Effect, accepted: dict) -> float:
    """Relative error of the fitted magnitude against the injected one."""
    t = _params_vector(truth.name, dataclasses.asdict(truth))
    f = _params_vector(truth.name, accepted["params"])
    if truth.name == "pole_offset":  # the common part is shared with installation offsets
        t, f = t - t.mean(), f - f.mean()
    return float(np.linalg.norm(f - t) / max(np.linalg.norm(t), 1e-12))


def _params_vector(name, params) -> np.ndarray:
    keys = {"edge_jitter": ["time_rms_s"], "installation_offset": ["offset_deg_e"], "pole_offset": ["offset_deg_e"], "eccentricity": ["amplitude_deg_e"],
            "hysteresis": ["lag_deg_e"], "conditioning_delay": ["rise_delay_s", "fall_delay_s"],
            "armature_reaction": ["slope_deg_e_per_a"], "timer_quantization": ["tick_s"]}[name]
    out = []
    for k in keys:
        v = params[k]
        out.extend(v if isinstance(v, (list, tuple)) else [v])
    return np.asarray(out, dtype=float)


@dataclass
class ValidationReport:
    cases: list[dict] = field(default_factory=list)

    def summary(self, min_snr: float = 3.0) -> dict:
        single = [c for c in self.cases if c["kind"] == "single" and c["snr"] >= min_snr]
        null = [c for c in self.cases if c["kind"] == "null"]
        two = [c for c in self.cases if c["kind"] == "two" and c["snr"] >= min_snr]
        ool = [c for c in self.cases if c["kind"] == "out_of_library" and c["snr"] >= min_snr]
        conf: dict[str, dict[str, int]] = {}
        for c in single:
            row = conf.setdefault(c["truth"][0], {})
            row[c["top1"]] = row.get(c["top1"], 0) + 1
        shrink = [c["heldout_shrink"] for c in single if c["heldout_shrink"] is not None]
        shrink_by_effect = {}
        for c in single:
            if c["heldout_shrink"] is not None:
                shrink_by_effect.setdefault(c["truth"][0], []).append(c["heldout_shrink"])
        perr = [c["param_error"] for c in single if c["param_error"] is not None]
        return {
            "min_snr": min_snr,
            "single_cases": len(single),
            "top1_rate": float(np.mean([c["top1"] == c["truth"][0] for c in single])) if single else None,
            "top3_rate": float(np.mean([c["truth"][0] in c["top3"] for c in single])) if single else None,
            "null_cases": len(null),
            "false_alarm_rate": float(np.mean([c["significant"] for c in null])) if null else None,
            "two_effect_cases": len(two),
            "two_effect_both_found_rate": float(np.mean([set(c["truth"]) <= set(c["accepted"]) for c in two])) if two else None,
            "out_of_library_cases": len(ool),
            "unexplained_rate": float(np.mean([c["unexplained"] for c in ool])) if ool else None,
            "param_within_20pct_rate": float(np.mean(np.array(perr) <= 0.2)) if perr else None,
            "median_param_error": float(np.median(perr)) if perr else None,
            "median_heldout_shrink": float(np.median(shrink)) if shrink else None,
            "confusion": conf,
            "median_heldout_shrink_by_effect": {k: float(np.median(v)) for k, v in shrink_by_effect.items()},
        }


def run_validation(per_effect: int = 12, null: int = 24, two: int = 14, out_of_library: int = 24, seed: int = 0, progress=None) -> ValidationReport:
    rng = np.random.default_rng(seed)
    report = ValidationReport()
    jobs = []
    for name in EFFECT_NAMES:
        for _ in range(per_effect):
            jobs.append(("single", [name], None))
    jobs += [("null", [], None)] * null
    for _ in range(two):
        a, b = rng.choice(EFFECT_NAMES, 2, replace=False)
        jobs.append(("two", [str(a), str(b)], None))
    jobs += [("out_of_library", [], "sensor_delay" if i % 2 == 0 else "speed_squared") for i in range(out_of_library)]
    for i, (kind, names, ool) in enumerate(jobs):
        snr = float(rng.uniform(1.0, 10.0))
        case_seed = int(rng.integers(0, 2**31))
        rec, truth = make_case(names, snr, case_seed, ool=ool)
        d = diagnose(rec, KNOWN_MODEL)
        top = [r["effect"] for r in d.ranking] if d.significant else ["none"]
        accepted = [a["effect"] for a in d.accepted]
        perr = None
        if kind == "single":
            hit = next((a for a in d.accepted if a["effect"] == truth[0].name), None)
            perr = _param_error(truth[0], hit) if hit else None
        report.cases.append({
            "kind": kind, "truth": [t.name for t in truth] or ([ool] if ool else []), "snr": snr, "seed": case_seed,
            "significant": d.significant, "top1": accepted[0] if accepted else "none", "top3": top[:3], "accepted": accepted,
            "unexplained": d.unexplained, "param_error": perr,
            "heldout_shrink": d.noise_gap.get("heldout_shrink") if truth and truth[0].name == "edge_jitter" and kind == "single" else d.heldout_shrink,
        })
        if progress:
            progress(i + 1, len(jobs))
    return report
