"""The twin run along a capture's own trajectory (kinematic mode, at the capture's tick).

The calibration's fit gives the time at which the real rotor passed each ideal sector boundary
(the trajectory spline at 60 m deg e, without the deviations and the noise). The twin's rotor
passes the same boundaries at the same times, at constant speed in between
(``plant_models.kinematic.simulate_edges``, one operating point per sector), and its Hall layer
(the twin's effects) makes the edges. With ``ripple`` the rotor also carries the sector-locked
speed ripple the calibration found (an angle per boundary falling with 1/speed^2): the rotor's
motion, not a sensor property, so it is part of the trajectory, not of the plant file.
"""

from __future__ import annotations

import numpy as np

from bldc.units import deg_e_per_s_to_rpm
from plant_models import PlantConfig
from plant_models.edgelog import EdgeLog
from plant_models.kinematic import OperatingPoint, simulate_edges

from ..recording.format import Recording
from .capture import CaptureAnalysis


def boundary_times(an: CaptureAnalysis, ripple: bool) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Per run: (direction, boundary index m, time the rotor passed 60 m deg e)."""
    fit, steps = an.fit, an.steps
    idx = fit.index
    tau = fit.tau_s_per_deg
    # t = T(psi) + effects + residual; the rotor's own ripple stays with the rotor when asked
    keep_deg = fit.sensor_trail_deg_e if ripple else fit.trail_deg_e
    node_t = steps.t_s[idx] - keep_deg * tau - fit.residual_s
    out = []
    for r in np.unique(steps.run[idx]):
        sel = steps.run[idx] == r
        m = steps.boundary[idx][sel]
        t = node_t[sel]
        order = np.argsort(t, kind="stable")
        m, t = m[order], t[order]
        ok = np.concatenate(([True], np.diff(t) > 0))  # a spline that turned back (never seen) is skipped
        out.append((int(steps.direction[idx][sel][0]), m[ok], t[ok]))
    return out


def twin_edges(config: PlantConfig, an: CaptureAnalysis, seed: int = 0, ripple: bool = False) -> EdgeLog:
    """The twin's edges along the capture's trajectory (each run of the capture in turn)."""
    p = config.motor.pole_pairs
    logs = []
    for k, (d, m, t) in enumerate(boundary_times(an, ripple)):
        dt = np.diff(t)
        profile = [
            OperatingPoint(float(h), float(deg_e_per_s_to_rpm(60.0 / h, p)), direction=d) for h in dt
        ]
        if not profile:
            continue
        logs.append(simulate_edges(config, profile, seed=seed + 7919 * k, start_angle_deg_e=60.0 * float(m[0]),
                                   start_time_s=float(t[0])))
    if not logs:
        raise ValueError("the capture has no run the twin can follow")
    return logs[0] if len(logs) == 1 else EdgeLog.concatenate(logs)


def twin_recording(config: PlantConfig, an: CaptureAnalysis, seed: int = 0, ripple: bool = False) -> Recording:
    """The twin's capture as an ordinary-run recording (what the logic analyser would have shown):
    sampled at the capture's tick (the instrument's, where the twin does not carry it already)."""
    if an.tick_s and not config.effect("timer_quantization"):
        from plant_models import effects as fx

        config = config.with_effects(fx.TimerQuantization(tick_s=an.tick_s))
    e = twin_edges(config, an, seed, ripple)
    order = np.argsort(e.t_capture_s, kind="stable")
    tick = an.tick_s
    return Recording(
        motor={"pole_pairs": int(config.motor.pole_pairs)},
        segments=[],
        t_s=e.t_capture_s[order],
        sensor=e.sensor[order],
        rising=e.rising[order],
        segment=np.full(order.size, -1, dtype=np.int64),
        timer_tick_s=tick,
        truth={"t_ideal_s": e.t_ideal_s[order], "t_conditioned_s": e.t_conditioned_s[order]},
    )
