"""Recordings made on the plant: simulated edges (and samples) written as ``hil-recording/1``
recordings, ground truth kept, for the tests, the demo and the validation of every reader."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from bldc.motor import steady_state
from plant_models import RawHallCommutation, Simulation
from plant_models.edgelog import EdgeLog
from plant_models.kinematic import simulate_edges

from .format import SAMPLE_OPTIONAL, Recording, Segment


def recording_from_edges(
    motor: dict,
    edges,
    segments: list[Segment],
    *,
    timer_tick_s: float | None = None,
    samples: dict[str, np.ndarray] | None = None,
    reference_angle: bool = True,
) -> Recording:
    """A Recording of simulated edges (a :class:`plant_models.EdgeLog`), with ground truth kept."""
    pp = int(motor["pole_pairs"])
    keep = edges.segment >= 0
    e = edges.take(keep)
    # true angle at the timer's capture instant (the reference encoder's view)
    theta_cap = e.theta_e_stamp_deg(pp)
    angle_mech = np.mod(theta_cap / pp, 360.0)
    angle_mech[angle_mech >= 360.0] = 0.0
    truth = {
        "t_ideal_s": e.t_ideal_s,
        "t_raw_s": e.t_raw_s,
        "t_conditioned_s": e.t_conditioned_s,
        "true_angle_mech_deg": angle_mech,
        "pole": e.pole,
        "mean_abs_current_a": e.mean_abs_current_a,
    }
    return Recording(
        motor=dict(motor),
        segments=segments,
        t_s=e.t_capture_s,
        sensor=e.sensor,
        rising=e.rising,
        segment=e.segment,
        ref_angle_mech_deg=angle_mech if reference_angle else None,
        timer_tick_s=timer_tick_s,
        samples=samples,
        truth=truth,
    )


def motor_meta(config) -> dict[str, Any]:
    """The meta.json ``motor`` block of a PlantConfig's nominal motor."""
    m = config.motor
    return {
        "pole_pairs": int(m.pole_pairs),
        "phase_resistance_ohm": m.phase_resistance_ohm,
        "phase_inductance_h": m.phase_inductance_h,
        "ke_v_s_per_rad": m.ke_v_s_per_rad,
        "inertia_kg_m2": m.inertia_kg_m2,
        "fan_coefficient_n_m_s2": m.fan_coefficient_n_m_s2,
        "supply_v": m.supply_v,
        "friction_n_m_s_per_rad": m.friction_n_m_s_per_rad,
        "flat_top_deg_e": m.flat_top_deg_e,
    }


def record_kinematic(config, profile, seed: int = 0, reference_angle: bool = True) -> Recording:
    """Simulate ``profile`` (OperatingPoints) in the kinematic mode and return it as a Recording."""
    edges = simulate_edges(config, profile, seed=seed)
    segments, t = [], 0.0
    for i, op in enumerate(profile):
        segments.append(
            Segment(
                op.id or f"op{i + 1:02d}",
                t,
                t + op.duration_s,
                "forward" if op.direction > 0 else "reverse",
                float(op.speed_rpm),
                float(op.mean_phase_current_a),
                float(op.load_scale),
            )
        )
        t += op.duration_s
    tick = config.compile().timer_tick_s or None
    return recording_from_edges(motor_meta(config), edges, segments, timer_tick_s=tick, reference_angle=reference_angle)


def record_electrical(
    config,
    profile,
    seed: int = 0,
    *,
    sample_rate_hz: float = 20e3,
    settle_s: float = 0.05,
    voltage_noise_v: float = 0.0,
    speed_noise_rpm: float = 0.0,
    reference_angle: bool = True,
) -> Recording:
    """Simulate ``profile`` (OperatingPoints) on the electrical plant, commutating on the raw Hall
    edges at the duty that holds each set speed (a speed loop's steady state, computed from the
    plant's true resistance, back-EMF constant and dead time), and return edges plus samples
    (currents through the current sensors; terminal voltages and speed with the given white
    measurement noise) as a Recording. Each segment's ``mean_phase_current_a`` is the measured
    mean |i| over the three phases, as the format defines it."""

    cp = config.compile()
    true_motor = dataclasses.replace(
        config.motor, phase_resistance_ohm=cp.phase_resistance_ohm, ke_v_s_per_rad=cp.ke_v_s_per_rad
    )
    noise = np.random.default_rng(seed + 7919)
    logs, segments = [], []
    samples: dict[str, list] = {k: [] for k in ("t_s", "segment", *SAMPLE_OPTIONAL)}
    t_offset = 0.0
    for index, op in enumerate(profile):
        duty = (
            steady_state(true_motor, op.speed_rpm, op.load_scale)["duty"]
            + cp.dead_time_s * config.inverter.pwm_frequency_hz
        )
        sim = Simulation(
            config,
            RawHallCommutation(),
            duty=min(duty, 1.0),
            initial_speed_rpm=op.speed_rpm,
            direction=op.direction,
            seed=seed + index,
            sample_rate_hz=sample_rate_hz,
        )
        sim.run_until(settle_s)
        sim.mark_segment(index)
        sim.run_until(settle_s + op.duration_s)
        e = sim.edges()
        e = e.take(e.segment == index)
        s = sim.samples()
        keep = s.t_s >= settle_s
        shift = t_offset - settle_s
        for name in ("t_capture_s", "t_conditioned_s", "t_raw_s", "t_ideal_s"):
            setattr(e, name, getattr(e, name) + shift)
        logs.append(e)
        n = int(keep.sum())
        samples["t_s"].append(s.t_s[keep] + shift)
        samples["segment"].append(np.full(n, index, dtype=np.int64))
        for j, c in enumerate("abc"):
            samples[f"i_{c}"].append(s.i_meas_a[keep, j])
            samples[f"u_{c}"].append(s.u_v[keep, j] + voltage_noise_v * noise.standard_normal(n))
        samples["speed_rpm"].append(s.speed_rpm[keep] + speed_noise_rpm * noise.standard_normal(n))
        t_end = t_offset + op.duration_s
        segments.append(
            Segment(
                op.id or f"op{index + 1:02d}",
                t_offset,
                t_end,
                "forward" if op.direction > 0 else "reverse",
                float(op.speed_rpm),
                float(np.abs(s.i_meas_a[keep]).mean()),
                float(op.load_scale),
            )
        )
        t_offset = t_end + 1e-3
    return recording_from_edges(
        motor_meta(config),
        EdgeLog.concatenate(logs),
        segments,
        timer_tick_s=cp.timer_tick_s or None,
        samples={k: np.concatenate(v) for k, v in samples.items()},
        reference_angle=reference_angle,
    )
