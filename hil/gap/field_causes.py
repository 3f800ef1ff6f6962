"""``hil gap validate --generator field``: withheld causes drawn from the field-level Hall model.

The library's validation withholds effects drawn from the formulas the candidates fit. Here each
withheld cause is a physical parameter of :class:`plant_models.hall_field.HallField` (a ring
off its axis, uneven pole magnetisation, a hysteresis band in mT at a temperature, the stator's
field at the sensors, an open-collector output's RC filter), the edges come out of the field
geometry, and each cause is scored against the library effect that should explain it, with the
magnitude its physical parameter implies by first-order physics (docs/gap.md, "Causes and the
effects that explain them"). Each cause is declared once, in
:data:`plant_models.hall_field.FIELD_CAUSES` (parameter, library effect, how a case draws it,
its implied magnitude); this module only iterates the declarations.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hil.recording.drivers import record_kinematic
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx
from plant_models.hall_field import FIELD_CAUSES, HallField, HallSwitches, MagnetRing, StatorCoupling

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

#: the field causes by name, in their declared order (the case plans and seeds depend on it)
CAUSES_BY_NAME = {c.name: c for c in FIELD_CAUSES}
CAUSES = tuple(CAUSES_BY_NAME)


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
        cause = CAUSES_BY_NAME[name]
        make = cause.draw(rng, p)
        sig = signature_rms(base, [make(1.0)], ops, seed)
        hf = make(snr * noise / max(sig, 1e-12))
        got = signature_rms(base, [hf], ops, seed)
        fields.append(hf)
        implied.append(cause.implied(hf, p))
        achieved.append(got / noise)
    hf = combine(fields)
    config = base.with_effects(
        fx.EdgeJitter(time_rms_s=JITTER_S), fx.TimerQuantization(TICK_S), *([hf] if causes else [])
    )
    rec = record_electrical_case(config, ops, seed) if electrical else record_kinematic(config, ops, seed=seed)
    rec.meta_extra["validation_snr"] = min(achieved) if achieved else snr
    return rec, implied, hf


def plan_field_cases(rng: np.random.Generator, per_cause: int, null: int, two: int,
                     snr_range: tuple[float, float]) -> list[tuple]:
    """(index, kind, causes, snr, seed, electrical) for every case, the SNR drawn uniformly from
    ``snr_range``: a quarter of the single causes on the electrical plant (speed ripple, real
    commutation, the edge currents of six-step)."""
    plan = []
    for name in CAUSES:
        plan += [("single", [name])] * per_cause
    plan += [("null", [])] * null
    for _ in range(two):
        a, b = rng.choice(CAUSES, 2, replace=False)
        plan.append(("two", [str(a), str(b)]))
    return [
        (i, kind, names, float(rng.uniform(*snr_range)), int(rng.integers(0, 2**31)), (i % 4 == 3) and kind != "two")
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
