"""The synthetic bench the gap validation records on: its operating points, its noise floor, its
known model, and the yardsticks (signature RMS against the noise, fitted-magnitude error).

Shared by the library-effect validation (``validate``) and the field-model validation
(``field_causes``), which both import it and not each other.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bldc.motor import steady_state
from bldc.units import edges_per_s, rpm_to_deg_e_per_s
from hil.recording.drivers import record_electrical
from hil.recording.format import Recording
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx
from plant_models.kinematic import OperatingPoint, simulate_edges

from .result import FittedEffect

JITTER_S = 1e-6
TICK_S = 1e-7
#: the sampled signals' measurement noise in the electrical recordings (white, per sample)
CURRENT_NOISE_A = 0.002
VOLTAGE_NOISE_V = 0.005
SPEED_NOISE_RPM = 0.002
SAMPLE_RATE_HZ = 20e3
#: what the model knows: the nominal motor and the bench's base edge jitter
KNOWN_MODEL = paper_bench().with_effects(fx.EdgeJitter(time_rms_s=JITTER_S))


def profile(config: PlantConfig, turns: int = 30) -> list[OperatingPoint]:
    """The operating points a bench would record: three speeds, no load and pump load, and a
    reverse run (the knobs that separate confounded effects)."""
    m = config.motor
    ops = []
    for rpm in (2000.0, 5000.0, 8000.0):
        for load in (0.0, 1.0):
            ops.append(
                OperatingPoint(
                    turns * 60 / rpm,
                    rpm,
                    steady_state(m, rpm, load)["current_a"] * 2 / 3,
                    load_scale=load,
                    id=f"{'load' if load else 'noload'}_{rpm:.0f}",
                )
            )
    ops.append(
        OperatingPoint(
            turns * 60 / 5000.0,
            5000.0,
            steady_state(m, 5000.0, 1.0)["current_a"] * 2 / 3,
            direction=-1,
            load_scale=1.0,
            id="reverse_5000",
        )
    )
    return ops


def signature_rms(config: PlantConfig, effects, ops, seed: int) -> float:
    e = truth_error(config.with_effects(*effects), ops, seed)
    return float(np.sqrt(np.mean(e**2)))


def truth_error(config, ops, seed):
    e = simulate_edges(config, ops, seed=seed)
    return e.direction * (e.theta_e_capture_deg - e.ideal_angle_deg_e) if len(e) else np.zeros(0)


def noise_rms(ops, pole_pairs):
    w = np.array([rpm_to_deg_e_per_s(op.speed_rpm, pole_pairs) for op in ops])
    n = np.array([op.duration_s * edges_per_s(op.speed_rpm, pole_pairs) for op in ops])
    per = (w * JITTER_S) ** 2 + (w * TICK_S) ** 2 / 12
    return float(np.sqrt(np.sum(n * per) / np.sum(n)))


def record_electrical_case(config: PlantConfig, ops, seed: int, noisy: bool = True) -> Recording:
    if noisy:
        config = dataclasses.replace(
            config, current_sensor=dataclasses.replace(config.current_sensor, noise_rms_a=CURRENT_NOISE_A)
        )
    return record_electrical(
        config,
        ops,
        seed=seed,
        sample_rate_hz=SAMPLE_RATE_HZ,
        voltage_noise_v=VOLTAGE_NOISE_V if noisy else 0.0,
        speed_noise_rpm=SPEED_NOISE_RPM if noisy else 0.0,
    )


def param_error(truth: fx.Effect, accepted: FittedEffect) -> float:
    """Relative error of the fitted magnitude against the injected one (the effect's declaration
    says which parameters count: ``Effect.fit_error``)."""
    return truth.fit_error(accepted.params)

