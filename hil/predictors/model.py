"""The commutation-cycle state model of paper Eq. 7-10.

State X_k = [w_k, theta_k, I_k]: electrical speed (rad/s, mean over commutation cycle k),
electrical angle (rad, re-referenced to the corrected edge that ends each cycle) and mean
phase current (A, mean of |i| over the three phases in the cycle). Paper Eq. 9 with the
sampling interval dT = one commutation cycle:

    w_{k+1}     = w_k + (p K_T(n) / J) dT I_k - dT p (M(n) w_m^2 + B w_m) / J
    theta_{k+1} = theta_k + dT w_k + (p K_T(n) / 2J) dT^2 I_k - (dT^2 / 2) p (M(n) w_m^2 + B w_m) / J
    I_{k+1}     = I_k

(the factor p turns the mechanical equation of motion, Eq. 8, into electrical speed; w_m is the
mechanical speed w / p, the paper's mean speed w-bar over the cycle). B is the bearings' viscous
friction. The paper's Eq. 8 has no friction term, but its M(n) is regressed on the fan-loaded
motor's measured current and speed (Section 4.4), so the load it predicts holds the friction at
each speed; a model built from stated motor parameters (``from_plant``) states it separately.
Left out, it is an acceleration the model always over-predicts (p B w_m / J: 3-5 rad/s^2 e at
5000-9500 rpm on the paper bench), which a filter with little process noise follows with a lag.
Eq. 10 observes speed and current: Z_k = H X_k + V_k, H = [[1, 0, 0], [0, 0, 1]].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bldc.units import rad_e_per_s_to_rpm


@dataclass(frozen=True)
class MotorModel:
    """J, K_T(n) and M(n) as the filter uses them; K_T and M may be tables over speed (rpm)."""

    pole_pairs: int
    inertia_kg_m2: float
    #: torque per ampere of mean |i| over the three phases (N m / A); constant or a table
    torque_coefficient_n_m_per_a: tuple[float, ...] = (0.0648,)
    #: fan coefficient M in T_L = M w_m^2 (N m s^2); constant or a table
    fan_coefficient_n_m_s2: tuple[float, ...] = (1.5e-7,)
    #: speeds (rpm) of the table entries; empty for constants
    table_speed_rpm: tuple[float, ...] = field(default=())
    #: viscous friction B in T_f = B w_m (N m s/rad), beside the fan load
    friction_n_m_s_per_rad: float = 0.0

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        speeds = np.asarray(self.table_speed_rpm or (0.0,), dtype=float)
        kt = np.asarray(self.torque_coefficient_n_m_per_a, dtype=float)
        m = np.asarray(self.fan_coefficient_n_m_s2, dtype=float)
        if not (speeds.size == kt.size == m.size):
            raise ValueError(
                "table_speed_rpm, torque_coefficient_n_m_per_a and fan_coefficient_n_m_s2 must have equal lengths"
            )
        return speeds, kt, m

    def acceleration_rad_s2(self, w_e: float, current_a: float) -> float:
        """Electrical angular acceleration of Eq. 8, with the friction (module docstring)."""
        speeds, kt, m = self.arrays()
        n_rpm = rad_e_per_s_to_rpm(w_e, self.pole_pairs)
        k = np.interp(n_rpm, speeds, kt)
        mm = np.interp(n_rpm, speeds, m)
        w_m = w_e / self.pole_pairs
        load = mm * w_m * w_m + self.friction_n_m_s_per_rad * w_m
        return self.pole_pairs * (k * current_a - load) / self.inertia_kg_m2

    @classmethod
    def from_plant(cls, motor) -> "MotorModel":
        """The nominal model of a plant's MotorParameters (two conducting phases: T = 2 ke I_c,
        mean |i| over three phases = 2/3 I_c, so K_T = 3 ke per ampere of mean |i|), with its friction."""
        return cls(
            int(motor.pole_pairs), motor.inertia_kg_m2, (3.0 * motor.ke_v_s_per_rad,), (motor.fan_coefficient_n_m_s2,),
            friction_n_m_s_per_rad=float(motor.friction_n_m_s_per_rad),
        )


SECTOR_RAD = math.pi / 3.0
