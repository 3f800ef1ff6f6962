"""``hil gap validate``: the diagnosis checks itself on data whose effect was withheld.

For each effect that leaves a trace in the recorded signals, and random magnitudes
(signal-to-noise 1-10) and seeds: simulate a recording with that effect, withhold it from the
model (the model is the nominal motor with the known noise), diagnose, score. Also null
recordings, recordings with two effects withheld, and recordings with an effect outside the
candidate list, which must come out "unexplained".

Edge effects are simulated in the kinematic mode (edges only); effects seen in the sampled
signals on the electrical plant (edges plus samples through noisy sensors). SNR = RMS of the
effect's per-row signature / RMS of the per-row noise, per edge for edge effects, per sample
interval of the voltage equation or per speed sample for the sampled ones. Out of the library:
one sensor's own conditioning delay or a lag growing with speed^2 (edges); a current-sensor
offset on one phase or a gain error on one phase (samples).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from bldc.units import rpm_to_deg_e_per_s
from hil.campaign.scheduler import TaskError, dispatch
from hil.recording.format import Recording
from hil.recording.drivers import record_kinematic
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx

from .candidates import CANDIDATES
from .diagnose import diagnose_segments
from .field_causes import plan_field_cases, run_field_case
from .samples import (
    EFFECT_DOMAIN,
    NominalMotor,
    _angles,
    _speed_rad_s,
    speed_residuals,
    voltage_residuals,
)
from .synthetic import (
    JITTER_S,
    KNOWN_MODEL,
    TICK_S,
    noise_rms,
    param_error,
    profile,
    record_electrical_case,
    signature_rms,
)

def edge_effects() -> tuple[str, ...]:
    """The edge effects the validation withholds: every candidate of the diagnosis, then the
    library's edge-noise effects (their declared validation law is "jitter"); read from the
    registry when asked."""
    return tuple(CANDIDATES) + tuple(n for n, c in fx.EFFECTS.items() if c.validation == "jitter")


def effect_names() -> tuple[str, ...]:
    """Every effect the validation withholds: the edge effects, then the sampled-signal ones."""
    return edge_effects() + tuple(EFFECT_DOMAIN)


SAMPLE_OUT_OF_LIBRARY = ("current_offset", "current_gain")


def _unit_effect(name: str, rng: np.random.Generator, pole_pairs: int) -> fx.Effect:
    """A random direction in the effect's parameter space (scaled to the SNR afterwards): the
    effect's declared draw."""
    return fx.EFFECTS[name].unit_draw(rng, pole_pairs)


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


def make_case(
    effects_withheld: list[str],
    snr: float,
    seed: int,
    base: PlantConfig | None = None,
    ool: str | None = None,
    electrical: bool | None = None,
):
    """A recording with ``effects_withheld`` at signal-to-noise ``snr`` (and an out-of-library
    effect ``ool``); returns (recording, list of true effects). Electrical (edges and samples)
    when an effect or ``ool`` needs the sampled signals, or when ``electrical`` asks for it."""
    base = base or paper_bench()
    if electrical is None:
        electrical = any(n in EFFECT_DOMAIN for n in effects_withheld) or ool in SAMPLE_OUT_OF_LIBRARY
    rng = np.random.default_rng(seed)
    noise = [fx.EdgeJitter(time_rms_s=JITTER_S)]
    ops = profile(base)
    p = base.motor.pole_pairs
    truth = []
    snr_achieved = snr
    for name in effects_withheld:
        law = fx.EFFECTS[name].validation
        if law == "jitter":  # an extra jitter component the model does not know
            extra = snr * JITTER_S
            noise = [fx.EdgeJitter(time_rms_s=math.hypot(JITTER_S, extra))]
            truth.append(fx.EdgeJitter(time_rms_s=extra))
            continue
        if law in ("sampled", "knee"):
            eff, achieved = _sample_effect(name, snr, seed, base, ops, rng)
            truth.append(eff)
            snr_achieved = min(snr_achieved, achieved)
            continue
        unit = _unit_effect(name, rng, p)
        if law == "tick":  # the bench's capture timer, coarser: its quantisation noise is the signature
            mean_w_deg_e_s = rpm_to_deg_e_per_s(np.mean([op.speed_rpm for op in ops]), p)
            eff = dataclasses.replace(
                unit, tick_s=min(1e-5, 2 * snr * noise_rms(ops, p) / mean_w_deg_e_s * math.sqrt(3))
            )
        elif law == "edge":
            sig = signature_rms(base, [unit], ops, seed)
            eff = _scale(unit, snr * noise_rms(ops, p) / max(sig, 1e-12))
        else:
            raise ValueError(f"effect {name!r}: validation law {law!r} is not one of {', '.join(fx.VALIDATION_LAWS)}")
        truth.append(eff)
    known_tick = not any(isinstance(e, fx.TimerQuantization) for e in truth)
    # withheld jitter is already in ``noise``
    injected = [t for t in truth if not isinstance(t, fx.EdgeJitter)]
    config = base.with_effects(*noise, *injected, *([fx.TimerQuantization(TICK_S)] if known_tick else []))
    if electrical:
        if ool in SAMPLE_OUT_OF_LIBRARY:
            config = _sensor_fault(config, ool, snr, seed, ops, rng)
        rec = record_electrical_case(config, ops, seed)
    else:
        rec = record_kinematic(config, ops, seed=seed)
    if not known_tick:
        rec.timer_tick_s = None  # withheld: the model does not know the capture timer
    if ool and ool not in SAMPLE_OUT_OF_LIBRARY:
        _inject_out_of_library(rec, ool, snr * noise_rms(ops, p), rng)
    rec.meta_extra["validation_snr"] = snr_achieved  # below the drawn SNR when a magnitude hit its bound
    return rec, truth


def _sample_rows(rec: Recording, domain: str) -> np.ndarray:
    """Per-row residual of one sampled domain against the nominal motor (the SNR's yardstick)."""
    motor = NominalMotor.of(rec)
    th_e, th_m, _ = _angles(rec)
    w = _speed_rad_s(rec, th_m)
    r = voltage_residuals(rec, motor, th_e, w) if domain == "voltage" else speed_residuals(rec, motor, th_e, th_m, w)
    return r.y


def _signature(config: PlantConfig, ops, seed: int, domain: str) -> float:
    """RMS per row of the effects' signature (noise-free recording), in the domain's unit."""
    return float(np.sqrt(np.mean(_sample_rows(record_electrical_case(config, ops, seed, noisy=False), domain) ** 2)))


def _noise(config: PlantConfig, ops, seed: int, domain: str) -> float:
    """RMS per row of the measurement noise (noisy recording of the nominal motor)."""
    nominal = record_electrical_case(dataclasses.replace(config, effects=()), ops, seed)
    return float(np.sqrt(np.mean(_sample_rows(nominal, domain) ** 2)))


def _sample_effect(name: str, snr: float, seed: int, base: PlantConfig, ops, rng) -> tuple[fx.Effect, float]:
    """A sampled-signal effect scaled to ``snr`` by its declared law, from its declared unit draw
    (a knee by bisection in log), within the library's bounds; returns it with the SNR it
    actually has."""
    cls = fx.EFFECTS[name]
    domain = EFFECT_DOMAIN[name]
    noise = _noise(base, ops, seed, domain)
    unit = cls.unit_draw(rng, base.motor.pole_pairs)
    key = cls.magnitude_field
    low, high = fx.bounds_of(cls, key)
    if cls.validation == "knee":
        # the signature falls roughly as knee^-2: secant steps in log-log from the unit draw's knee
        target = snr * noise
        log_k, log_s = [math.log(getattr(unit, key))], []
        for _ in range(5):
            sig = _signature(base.with_effects(dataclasses.replace(unit, **{key: math.exp(log_k[-1])})), ops, seed,
                             domain)
            log_s.append(math.log(max(sig, 1e-30)))
            if abs(log_s[-1] - math.log(target)) < 0.01:
                break
            slope = (
                (log_s[-1] - log_s[-2]) / (log_k[-1] - log_k[-2]) if len(log_s) > 1 and log_k[-1] != log_k[-2] else -2.0
            )
            slope = min(slope, -0.2)  # keep the step finite where the signature flattens
            log_k.append(
                float(np.clip(log_k[-1] + (math.log(target) - log_s[-1]) / slope, math.log(low), math.log(high)))
            )
        eff = dataclasses.replace(unit, **{key: float(math.exp(log_k[len(log_s) - 1]))})
        return eff, math.exp(log_s[-1]) / noise
    sig = _signature(base.with_effects(unit), ops, seed, domain)
    wanted = getattr(unit, key) * snr * noise / max(sig, 1e-30)
    got = float(np.clip(wanted, low, high))
    # the signatures are linear in the magnitude: a clipped magnitude has a proportionally lower SNR
    return dataclasses.replace(unit, **{key: got}), snr * got / wanted


def _sensor_fault(config: PlantConfig, kind: str, snr: float, seed: int, ops, rng) -> PlantConfig:
    """A current-sensor fault on one phase, scaled to ``snr`` in the voltage residual."""
    x = int(rng.integers(0, 3))

    def faulty(size: float) -> PlantConfig:
        cs = config.current_sensor
        if kind == "current_offset":
            return dataclasses.replace(
                config,
                current_sensor=dataclasses.replace(cs, offset_a=tuple(size if k == x else 0.0 for k in range(3))),
            )
        return dataclasses.replace(
            config, current_sensor=dataclasses.replace(cs, gain_error=tuple(size if k == x else 0.0 for k in range(3)))
        )

    unit = 0.01
    sig, noise = _signature(faulty(unit), ops, seed, "voltage"), _noise(config, ops, seed, "voltage")
    size = float(
        np.clip(
            unit * snr * noise / max(sig, 1e-30),
            -0.05 if kind == "current_gain" else -1.0,
            0.05 if kind == "current_gain" else 1.0,
        )
    )
    return faulty(size)


def _inject_out_of_library(rec: Recording, kind: str, target_rms_deg: float, rng) -> None:
    """Effects no candidate describes: one sensor's own RC delay, or a lag growing with speed^2."""
    p = rec.pole_pairs
    w = np.array([rpm_to_deg_e_per_s(s.speed_rpm, p) for s in rec.segments])[rec.segment]
    if kind == "sensor_delay":
        x = int(rng.integers(0, 3))
        shift_deg = np.where(rec.sensor == x, w, 0.0)
    else:  # speed_squared
        shift_deg = (w / w.max()) ** 2 * w.max()
    shift_deg = shift_deg * (target_rms_deg / max(np.sqrt(np.mean(shift_deg**2)), 1e-12))
    dt = shift_deg / w
    rec.t_s = rec.t_s + dt
    rec.ref_angle_mech_deg = np.mod(
        rec.ref_angle_mech_deg + np.array([s.direction_sign for s in rec.segments])[rec.segment] * shift_deg / p, 360.0
    )
    order = np.argsort(rec.t_s, kind="stable")
    for name in ("t_s", "sensor", "rising", "segment", "ref_angle_mech_deg"):
        setattr(rec, name, getattr(rec, name)[order])
    if rec.truth is not None:
        rec.truth = {k: v[order] for k, v in rec.truth.items()}


@dataclass
class ValidationReport:
    cases: list[dict] = field(default_factory=list)
    dispatch: dict = field(default_factory=dict)  #: where the cases ran (scheduler, workers_used, ...)
    errors: list[dict] = field(default_factory=list)  #: cases that raised: never scored, always reported

    def summary(self, min_snr: float = 3.0) -> dict:
        single = [c for c in self.cases if c["kind"] == "single" and c["snr"] >= min_snr]
        null = [c for c in self.cases if c["kind"] == "null"]
        no_trace = [c for c in self.cases if c["kind"] == "no_trace"]
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
            "false_alarm_rate_electrical": float(np.mean([c["significant"] for c in null if c["electrical"]]))
            if any(c["electrical"] for c in null)
            else None,
            "no_trace_cases": len(no_trace),
            "no_trace_alarm_rate": float(np.mean([c["significant"] for c in no_trace])) if no_trace else None,
            "two_effect_cases": len(two),
            "two_effect_both_found_rate": float(np.mean([set(c["truth"]) <= set(c["accepted"]) for c in two]))
            if two
            else None,
            "out_of_library_cases": len(ool),
            "unexplained_rate": float(np.mean([c["unexplained"] for c in ool])) if ool else None,
            "param_within_20pct_rate": float(np.mean(np.array(perr) <= 0.2)) if perr else None,
            "median_param_error": float(np.median(perr)) if perr else None,
            "median_heldout_shrink": float(np.median(shrink)) if shrink else None,
            "confusion": conf,
            "median_heldout_shrink_by_effect": {k: float(np.median(v)) for k, v in shrink_by_effect.items()},
            "top1_rate_by_generator": {
                gen: float(
                    np.mean([c["top1"] == c["truth"][0] for c in single if c["electrical"] == (gen == "electrical")])
                )
                for gen in ("kinematic", "electrical")
                if any(c["electrical"] == (gen == "electrical") for c in single)
            },
            "edge_effects_on_electrical_plant": {
                "cases": len(edge_el := [c for c in single if c["electrical"] and c["truth"][0] in edge_effects()]),
                "top1_rate": float(np.mean([c["top1"] == c["truth"][0] for c in edge_el])) if edge_el else None,
            },
        }


GENERATORS = ("library", "field")
#: the signal-to-noise ratios the cases are drawn from, uniformly (each case's effect scaled to its draw)
SNR_RANGE = (1.0, 10.0)


def run_validation(
    per_effect: int = 12,
    null: int = 24,
    two: int = 14,
    out_of_library: int = 24,
    seed: int = 0,
    progress: bool = False,
    jobs: int = 1,
    generator: str = "library",
    scheduler: str | None = None,
    snr_range: tuple[float, float] = SNR_RANGE,
) -> ValidationReport:
    """Draw the cases (all randomness from ``seed``), diagnose each: in this process (``jobs`` 1),
    on a local Dask cluster of ``jobs`` workers, or on the Dask ``scheduler`` at an address
    (hil.campaign.scheduler); ``progress``: the count of recordings diagnosed on stderr.

    ``generator``: "library" withholds the library's effects (kinematic and electrical plant);
    "field" withholds physical causes of the field-level Hall model (hil.gap.field_causes),
    ``per_effect`` cases per cause (there is no out-of-library set).

    ``snr_range``: the SNRs drawn. A check of the rates at SNR >= 3 alone draws from (3, 10): the
    cases distributed as the default's share at SNR >= 3 (a uniform draw conditioned on >= 3 is uniform
    on [3, 10]), none drawn only to be left out of the rates."""
    if generator not in GENERATORS:
        raise ValueError(f"unknown generator {generator!r} (known: {', '.join(GENERATORS)})")
    if not (len(snr_range) == 2 and 0.0 < snr_range[0] <= snr_range[1] and math.isfinite(snr_range[1])):
        raise ValueError(f"snr_range: (lowest, highest) with 0 < lowest <= highest, got {snr_range!r}")
    rng = np.random.default_rng(seed)
    if generator == "field":
        return _run(plan_field_cases(rng, per_effect, null, two, snr_range), run_field_case, progress, jobs, scheduler)
    plan = []
    names = effect_names()
    for name in names:
        plan += [("single", [name], None)] * per_effect
    plan += [("null", [], None)] * null
    for _ in range(two):
        a, b = rng.choice(names, 2, replace=False)
        plan.append(("two", [str(a), str(b)], None))
    ool_kinds = ("sensor_delay", "speed_squared") + SAMPLE_OUT_OF_LIBRARY
    plan += [("out_of_library", [], ool_kinds[i % len(ool_kinds)]) for i in range(out_of_library)]
    # dead time leaves no trace in the format's signals: withheld, it must not raise a gap
    plan += [("no_trace", ["dead_time"], None)] * max(null // 4, 1)
    cases = [
        (i, kind, names, ool, float(rng.uniform(*snr_range)), int(rng.integers(0, 2**31)))
        for i, (kind, names, ool) in enumerate(plan)
    ]
    return _run(cases, _run_case, progress, jobs, scheduler)


def _run(cases: list, run_case, progress: bool, jobs: int, scheduler: str | None) -> ValidationReport:
    """Diagnose every case (see run_validation for where), kept in plan order, reporting each as it ends."""
    report = ValidationReport()
    # one task per case, results kept in case order: the report is the same on any scheduler

    results: dict[int, dict] = {}

    def on_result(i: int, case) -> None:
        if isinstance(case, TaskError):  # kept out of the rates, reported with its traceback
            report.errors.append(
                {"index": i, "case": list(cases[i]), "message": case.message, "traceback": case.traceback}
            )
        else:
            results[i] = case

    report.dispatch = dispatch(
        run_case,
        cases,
        on_result,
        scheduler=scheduler or ("serial" if jobs <= 1 else "local"),
        workers=jobs,
        label="recordings diagnosed",
        progress=progress,
    ).as_dict()
    report.cases = [results[i] for i in sorted(results)]
    report.errors.sort(key=lambda e: e["index"])
    return report


def _run_case(job) -> dict:
    i, kind, names, ool, snr, case_seed = job
    if kind == "no_trace":
        dead = fx.DeadTime(float(np.random.default_rng(case_seed).uniform(0.5e-6, 3e-6)))
        config = paper_bench().with_effects(fx.EdgeJitter(time_rms_s=JITTER_S), fx.TimerQuantization(TICK_S), dead)
        rec, truth = record_electrical_case(config, profile(config), case_seed), []
    else:
        # half of the null recordings are electrical (false alarms in the sampled signals count
        # too), and a quarter of the edge-effect draws: the edges of the full electrical plant
        # (speed ripple, real commutation) check that the diagnosis is not tuned to the
        # kinematic generator's constant speed
        electrical = (kind == "null" and i % 2 == 1) or (kind == "single" and i % 4 == 3)
        rec, truth = make_case(names, snr, case_seed, ool=ool, electrical=electrical or None)
    d = diagnose_segments(rec, KNOWN_MODEL)
    top = [r.effect for r in d.ranking] if d.significant else ["none"]
    accepted = [a.effect for a in d.accepted]
    perr = None
    shrink = d.heldout_shrink
    if kind == "single":
        hit = next((a for a in d.accepted if a.effect == truth[0].name), None)
        perr = param_error(truth[0], hit) if hit else None
        if type(truth[0]).validation == "jitter":
            shrink = d.noise_gap.heldout_shrink
        elif truth[0].name in EFFECT_DOMAIN:
            domain = d.samples.get(EFFECT_DOMAIN[truth[0].name])
            shrink = domain.heldout_shrink if domain else None
    return {
        "kind": kind,
        "truth": [t.name for t in truth] or ([ool] if ool else names),
        "seed": case_seed,
        "snr_drawn": snr,
        "snr": float(rec.meta_extra.get("validation_snr", snr)),
        "electrical": rec.samples is not None,
        "significant": d.significant,
        "top1": accepted[0] if accepted else "none",
        "top3": top[:3],
        "accepted": accepted,
        "unexplained": d.unexplained,
        "param_error": perr,
        "heldout_shrink": shrink,
    }
