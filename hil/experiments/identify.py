"""Identification of J, K_T(n) and M(n) from run data (paper Section 4.4).

K_T from the voltage equation of steady two-phase conduction (the Line-BEMF idea: the
conducting pair's terminal difference is 2 R I + 2 ke w_m, so ke, hence K_T = 3 ke per ampere
of mean |i|, follows by regression); J from an acceleration without fan load (K_T I = J dw/dt
plus friction); M(n) from steady loaded points (K_T I = M w_m^2 + f w_m), as a table over speed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from bldc.hall import SECTOR_PHASES
from bldc.motor import steady_state
from bldc.units import rpm_to_rad_per_s
from plant_models import OracleCommutation, PlantConfig, Simulation

from ..predictors.model import MotorModel


@dataclass
class IdentificationResult:
    model: MotorModel
    ke_v_s_per_rad: float
    inertia_kg_m2: float
    speeds_rpm: np.ndarray
    fan_coefficients: np.ndarray


def _steady_point(config: PlantConfig, speed_rpm: float, load_scale: float, seed: int):
    motor = dataclasses.replace(config.motor, fan_coefficient_n_m_s2=config.motor.fan_coefficient_n_m_s2 * load_scale)
    cfg = dataclasses.replace(config, motor=motor)
    duty = steady_state(motor, speed_rpm)["duty"]
    sim = Simulation(cfg, OracleCommutation(), duty=duty, initial_speed_rpm=speed_rpm, seed=seed, sample_rate_hz=50e3)
    sim.run_until(1.5)
    t0 = sim.t_s
    sim.run_until(t0 + 20 * 60.0 / speed_rpm)
    s = sim.samples()
    win = s.t_s >= t0
    return s, win


def identify(
    config: PlantConfig, speeds_rpm=(800.0, 2000.0, 4000.0, 6000.0, 8000.0, 10000.0), seed: int = 0
) -> IdentificationResult:
    """Run the identification experiments on the plant (a bench would record the same) and fit."""
    m = config.motor

    # K_T: regression of the conducting pair's voltage on current and speed over steady points
    rows, rhs, points = [], [], []
    for k, rpm in enumerate(speeds_rpm):
        s, win = _steady_point(config, rpm, 1.0, seed + k)
        hi, lo = SECTOR_PHASES[s.sector[win], 0], SECTOR_PHASES[s.sector[win], 1]
        idx = np.nonzero(win)[0]
        fl = 3 - hi - lo
        flat = np.abs(s.i_meas_a[idx, fl]) < 0.05  # only instants with the third phase open
        u_pair = s.u_v[idx, hi] - s.u_v[idx, lo]
        i_pair = 0.5 * (s.i_meas_a[idx, hi] - s.i_meas_a[idx, lo])
        w_m = rpm_to_rad_per_s(s.speed_rpm[idx])
        rows.append(np.column_stack([2 * i_pair[flat], 2 * w_m[flat]]))
        rhs.append(u_pair[flat])
        points.append((rpm, float(np.mean(np.abs(s.i_meas_a[idx]))), float(np.mean(w_m))))
    (r_est, ke), *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    kt = 3.0 * ke
    # M(n): at steady speed the mean electromagnetic torque balances the load (friction folded in)
    fan = np.array([kt * i / (w * w) for _, i, w in points])
    # J: acceleration from 500 rpm without fan load at a fixed duty

    noload = dataclasses.replace(config, motor=dataclasses.replace(m, fan_coefficient_n_m_s2=0.0))
    sim = Simulation(noload, OracleCommutation(), duty=0.15, initial_speed_rpm=500.0, seed=seed, sample_rate_hz=20e3)
    sim.run_until(0.3)
    s = sim.samples()
    w_m = rpm_to_rad_per_s(s.speed_rpm)
    # smooth over whole electrical periods before differentiating
    win = max(1, int(round(len(s.t_s) / (s.t_s[-1] - s.t_s[0]) * 60.0 / (500.0 * m.pole_pairs))))
    kernel = np.ones(win) / win
    w_s = np.convolve(w_m, kernel, mode="same")
    i_s = np.convolve(np.mean(np.abs(s.i_meas_a), axis=1), kernel, mode="same")
    acc = np.gradient(w_s, s.t_s)
    sel = slice(win, -win)
    torque = kt * i_s[sel] - m.friction_n_m_s_per_rad * w_s[sel]
    inertia = float(np.linalg.lstsq(acc[sel, None], torque, rcond=None)[0][0])
    model = MotorModel(
        m.pole_pairs, inertia, tuple([kt] * len(speeds_rpm)), tuple(fan), tuple(float(v) for v in speeds_rpm)
    )
    return IdentificationResult(model, float(ke), inertia, np.asarray(speeds_rpm, dtype=float), fan)
