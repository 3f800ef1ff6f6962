"""``hil gap validate --generator field``: withheld causes drawn from the field-level Hall model.

The library's validation withholds effects drawn from the formulas the candidates fit. Here each
withheld cause is a physical parameter of :class:`plant_models.hall_field.HallField` (a ring
off its axis, uneven pole magnetisation, a hysteresis band in mT at a temperature, the stator's
field at the sensors, an open-collector output's RC filter), the edges come out of the field
geometry, and each cause is scored against the library effect that should explain it, with the
magnitude its physical parameter implies by first-order physics (docs/gap.md, "Causes and the
effects that explain them"):

| cause | parameter | library effect | implied magnitude |
|---|---|---|---|
| dynamic_eccentricity | ring centre off the axis, e (mm) | eccentricity | amplitude p e / R_s (rad -> deg_e) |
| static_eccentricity | rotation axis off the stator centre, e (mm), towards gamma | installation_offset | p (e / R_s) sin(phi_x - gamma) per sensor |
| pole_magnetisation | per-pole remanence and boundary placement | pole_offset | the ring field's zero crossings (field geometry) |
| hysteresis_band | B_op = -B_rp = b / 2 (mT) at a temperature | hysteresis | (b / 2) (1 + tc dT) / (dB/dtheta (1 + alpha_Br dT)) |
| stator_field | coupling (mT/A) | armature_reaction | 2.25 coupling / (dB/dtheta) per A of mean abs(i) |
| output_filter | pull-up and filter capacitor | conditioning_delay | the RC crossing times of the circuit |

R_s is the sensor radius (ring radius plus air gap); dB/dtheta the ring field's slope at its
zero crossings (mT per deg_e), phi_x the sensor's stator angle.
"""  # noqa: E501 (a Markdown table cannot wrap)

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from bldc.hall import SENSOR_POSITION_DEG_E
from hil.recording.drivers import record_kinematic
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx
from plant_models.hall_field import HallField, HallSwitches, MagnetRing, StatorCoupling

from .diagnose import diagnose_segments
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

#: cause -> the library effect that should explain it
CAUSE_EFFECT = {
    "dynamic_eccentricity": "eccentricity",
    "static_eccentricity": "installation_offset",
    "pole_magnetisation": "pole_offset",
    "hysteresis_band": "hysteresis",
    "stator_field": "armature_reaction",
    "output_filter": "conditioning_delay",
}
CAUSES = tuple(CAUSE_EFFECT)
#: temperature coefficient of the Hall switching points drawn with a hysteresis band (an
#: uncompensated CMOS Hall latch drifts by about -0.1 %/K)
THRESHOLD_TC_PER_K = -0.001


def _unit_cause(name: str, rng: np.random.Generator, pole_pairs: int) -> tuple[HallField, Callable[[float], HallField]]:
    """A field model with the cause at a unit size, and how to rescale it (factor -> HallField)."""
    if name == "dynamic_eccentricity":
        angle = float(rng.uniform(0.0, 360.0))

        def make(s):
            return HallField(
                ring=MagnetRing(eccentricity_mm=float(np.clip(0.05 * s, 0.0, 0.5)), eccentricity_angle_deg=angle)
            )
    elif name == "static_eccentricity":
        angle = float(rng.uniform(0.0, 360.0))

        def make(s):
            return HallField(
                ring=MagnetRing(static_offset_mm=float(np.clip(0.05 * s, 0.0, 0.5)), static_offset_angle_deg=angle)
            )
    elif name == "pole_magnetisation":
        rem = rng.uniform(-1.0, 1.0, 2 * pole_pairs)
        err = rng.uniform(-1.0, 1.0, 2 * pole_pairs)

        def make(s):
            return HallField(
                ring=MagnetRing(
                    pole_remanence=tuple(float(np.clip(1.0 + 0.02 * s * r, 0.8, 1.2)) for r in rem),
                    boundary_error_deg_m=tuple(float(np.clip(0.05 * s * e, -2.0, 2.0)) for e in err),
                )
            )
    elif name == "hysteresis_band":
        dt = float(rng.uniform(-20.0, 80.0))

        def make(s):
            b = float(np.clip(2.0 * s, 0.0, 100.0))
            return HallField(
                sensors=HallSwitches(
                    operate_mt=(b / 2,) * 3, release_mt=(-b / 2,) * 3, threshold_tc_per_k=THRESHOLD_TC_PER_K
                ),
                temperature_rise_k=dt,
            )
    elif name == "stator_field":
        sign = float(rng.choice([-1.0, 1.0]))  # a sensor on the phase axis's far side sees the field reversed: it leads

        def make(s):
            return HallField(stator=StatorCoupling(float(np.clip(sign * s, -20.0, 20.0))))
    elif name == "output_filter":
        r2 = float(rng.uniform(2.2e3, 10e3))
        ratio = float(rng.uniform(0.3, 1.0))

        def make(s):
            c1 = float(np.clip(1e-9 * s, 1e-12, 1e-6))
            return HallField(output=fx.ConditioningCircuit(r2_ohm=r2, r1_ohm=ratio * 50.0, c1_f=c1))
    else:
        raise KeyError(name)
    return make(1.0), make


def implied_effect(name: str, hf: HallField, pole_pairs: int) -> fx.Effect:
    """The library effect, with the magnitude the cause's physical parameter implies."""
    ring, sen = hf.ring, hf.sensors
    r_s = ring.radius_mm + sen.air_gap_mm
    if name == "dynamic_eccentricity":
        return fx.Eccentricity(math.degrees(pole_pairs * ring.eccentricity_mm / r_s), 0.0)
    if name == "static_eccentricity":
        phi = np.radians(SENSOR_POSITION_DEG_E / pole_pairs)
        gamma = math.radians(ring.static_offset_angle_deg)
        return fx.InstallationOffset(
            tuple(float(v) for v in np.degrees(pole_pairs * ring.static_offset_mm / r_s * np.sin(phi - gamma)))
        )
    if name == "pole_magnetisation":
        # where the ring's own field crosses zero, per pole boundary (all sensors alike)
        zero = HallField(ring=ring).model(pole_pairs).switch_table_deg_e()[:, :, 0].mean(axis=0)
        return fx.PoleOffset(tuple(float(v) for v in zero))
    nominal = HallField().model(pole_pairs).slope_mt_per_deg_e()
    if name == "hysteresis_band":
        b_half = 0.5 * (sen.operate_mt[0] - sen.release_mt[0]) * (1 + sen.threshold_tc_per_k * hf.temperature_rise_k)
        return fx.Hysteresis(b_half / (nominal * (1 + ring.alpha_br_per_k * hf.temperature_rise_k)))
    if name == "stator_field":
        return fx.ArmatureReaction(2.25 * hf.stator.coupling_mt_per_a / nominal)
    if name == "output_filter":
        rise, fall = hf.output.delays_s()
        return fx.ConditioningDelay(rise, fall)
    raise KeyError(name)


def combine(fields: list[HallField]) -> HallField:
    """One field model holding every drawn cause (each sets different parts)."""
    out = HallField()
    for hf in fields:
        ring = {
            f.name: getattr(hf.ring, f.name)
            for f in dataclasses.fields(MagnetRing)
            if getattr(hf.ring, f.name) != getattr(MagnetRing(), f.name)
        }
        sens = {
            f.name: getattr(hf.sensors, f.name)
            for f in dataclasses.fields(HallSwitches)
            if getattr(hf.sensors, f.name) != getattr(HallSwitches(), f.name)
        }
        out = dataclasses.replace(
            out,
            ring=dataclasses.replace(out.ring, **ring),
            sensors=dataclasses.replace(out.sensors, **sens),
            stator=hf.stator if hf.stator != StatorCoupling() else out.stator,
            output=hf.output or out.output,
            temperature_rise_k=hf.temperature_rise_k or out.temperature_rise_k,
        )
    return out


def make_field_case(
    causes: list[str], snr: float, seed: int, electrical: bool = False, base: PlantConfig | None = None
):
    """A recording whose edges come from the field model with ``causes`` at signal-to-noise
    ``snr`` (each cause scaled alone to it, within its bounds); returns (recording, implied
    library effects, the field model)."""
    base = base or paper_bench()
    rng = np.random.default_rng(seed)
    ops = profile(base)
    p = base.motor.pole_pairs
    noise = noise_rms(ops, p)
    fields, implied, achieved = [], [], []
    for name in causes:
        unit, make = _unit_cause(name, rng, p)
        sig = signature_rms(base, [unit], ops, seed)
        hf = make(snr * noise / max(sig, 1e-12))
        got = signature_rms(base, [hf], ops, seed)
        fields.append(hf)
        implied.append(implied_effect(name, hf, p))
        achieved.append(got / noise)
    hf = combine(fields)
    config = base.with_effects(
        fx.EdgeJitter(time_rms_s=JITTER_S), fx.TimerQuantization(TICK_S), *([hf] if causes else [])
    )
    rec = record_electrical_case(config, ops, seed) if electrical else record_kinematic(config, ops, seed=seed)
    rec.meta_extra["validation_snr"] = min(achieved) if achieved else snr
    return rec, implied, hf


def plan_field_cases(rng: np.random.Generator, per_cause: int, null: int, two: int) -> list[tuple]:
    """(index, kind, causes, snr, seed, electrical) for every case: a quarter of the single
    causes on the electrical plant (speed ripple, real commutation, the edge currents of six-step)."""
    plan = []
    for name in CAUSES:
        plan += [("single", [name])] * per_cause
    plan += [("null", [])] * null
    for _ in range(two):
        a, b = rng.choice(CAUSES, 2, replace=False)
        plan.append(("two", [str(a), str(b)]))
    return [
        (i, kind, names, float(rng.uniform(1.0, 10.0)), int(rng.integers(0, 2**31)), (i % 4 == 3) and kind != "two")
        for i, (kind, names) in enumerate(plan)
    ]


def run_field_case(job) -> dict:
    i, kind, names, snr, seed, electrical = job
    rec, implied, _ = make_field_case(names, snr, seed, electrical=electrical)
    d = diagnose_segments(rec, KNOWN_MODEL)
    top = [r.effect for r in d.ranking] if d.significant else ["none"]
    accepted = [a.effect for a in d.accepted]
    perr = None
    if kind == "single":
        hit = next((a for a in d.accepted if a.effect == implied[0].name), None)
        perr = param_error(implied[0], hit) if hit else None
    return {
        "kind": kind,
        "cause": names,
        "truth": [e.name for e in implied],
        "seed": seed,
        "snr_drawn": snr,
        "snr": float(rec.meta_extra.get("validation_snr", snr)),
        "electrical": electrical,
        "significant": d.significant,
        "top1": accepted[0] if accepted else "none",
        "top3": top[:3],
        "accepted": accepted,
        "below_relevance": [b.effect for b in d.below_relevance],
        "confounded": [c.names for c in d.confounded],
        "unexplained": d.unexplained,
        "param_error": perr,
        "heldout_shrink": d.heldout_shrink,
        "implied": [e.to_dict() for e in implied],
    }
