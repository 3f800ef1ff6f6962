"""Phase currents of the stimulus, from the electrical plant.

For each speed of a grid spanning the profile, the electrical plant (with the plant file's
effects) runs at the duty that holds that speed against the pump load, commutated ideally
(the oracle: the current shape a correct controller would draw), until the winding currents
have settled; one mechanical turn of its three phase currents is tabulated against the
mechanical angle. That duty is the plant's own torque balance, found by iteration (zero mean
acceleration over the tabulated turn), not the analytic L -> 0 steady state: the winding
inductance delays each commutation's current, so the analytic duty leaves the plant short of
torque (at 6000 rpm on the paper bench 0.2 % of duty is 40 % of the current, and the currents
exported at it were those of a motor decelerating at 6.5 rad/s^2, which a controller's
torque model reads as a deceleration that never happens). At export time the current at any
instant is the table of the true mechanical angle, interpolated linearly between the two nearest grid speeds. This is
quasi-static: the extra torque current of an acceleration is not included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.motor import steady_state
from bldc.units import rpm_to_rad_per_s
from plant_models import OracleCommutation, PlantConfig, Simulation

#: table resolution over one mechanical turn
TABLE_POINTS = 1440
#: grid spacing of the tabulated speeds
SPEED_STEP_RPM = 500.0
#: below this speed the motor is taken as standing (no current)
MIN_SPEED_RPM = 30.0
#: torque balance: the residual mean acceleration accepted, as a fraction of the load torque / J
BALANCE_TOLERANCE = 1e-3
BALANCE_MAX_ITERATIONS = 8


@dataclass
class CurrentTables:
    speeds_rpm: np.ndarray      #: (k,) grid speeds, increasing
    tables_a: np.ndarray        #: (k, 3, TABLE_POINTS) phase currents against mechanical angle
    duty: np.ndarray            #: (k,) duty that held each speed
    #: (k,) mean acceleration left at that duty over the tabulated turn (rad/s^2, mechanical)
    residual_accel_rad_s2: np.ndarray | None = None

    def currents_a(self, theta_m_deg: np.ndarray, speed_rpm: np.ndarray) -> np.ndarray:
        """(3, n) phase currents at mechanical angles and speeds."""
        pos = np.mod(theta_m_deg, 360.0) * (TABLE_POINTS / 360.0)
        j0 = np.floor(pos).astype(np.int64) % TABLE_POINTS
        j1 = (j0 + 1) % TABLE_POINTS
        fa = pos - np.floor(pos)
        k = np.clip(np.searchsorted(self.speeds_rpm, speed_rpm, side="right") - 1, 0, max(self.speeds_rpm.size - 2, 0))
        if self.speeds_rpm.size == 1:
            tab = self.tables_a[0]
            return tab[:, j0] * (1 - fa) + tab[:, j1] * fa
        s0, s1 = self.speeds_rpm[k], self.speeds_rpm[k + 1]
        fs = np.clip((speed_rpm - s0) / (s1 - s0), 0.0, 1.0)
        out = np.empty((3, theta_m_deg.size))
        for x in range(3):
            lo = self.tables_a[k, x, j0] * (1 - fa) + self.tables_a[k, x, j1] * fa
            hi = self.tables_a[k + 1, x, j0] * (1 - fa) + self.tables_a[k + 1, x, j1] * fa
            out[x] = lo * (1 - fs) + hi * fs
        return out

    def mean_abs_current_a(self, speed_rpm: float) -> float:
        """Mean |i| over phases and one turn at ``speed_rpm`` (the armature-reaction current)."""
        i = np.mean(np.abs(self.tables_a), axis=(1, 2))
        return float(np.interp(speed_rpm, self.speeds_rpm, i))


def speed_grid(speeds_rpm) -> np.ndarray:
    lo, hi = float(np.min(speeds_rpm)), float(np.max(speeds_rpm))
    n = max(int(np.ceil((hi - lo) / SPEED_STEP_RPM)), 0) + 1
    return np.unique(np.concatenate([np.linspace(lo, hi, n), np.asarray(speeds_rpm, dtype=float)]))


@dataclass
class _Turn:
    duty: float
    accel_rad_s2: float     #: mean mechanical acceleration over the turn
    samples: object
    keep: np.ndarray
    theta_deg: np.ndarray   #: mechanical angle from the turn's start


def _one_turn(config: PlantConfig, rpm: float, duty: float, seed: int) -> _Turn:
    """The plant at ``duty`` from ``rpm``, ideally commutated: the turn after the currents settled."""
    turn_s = 60.0 / rpm
    rate = max(200e3, 4.0 * TABLE_POINTS / turn_s)
    motor = config.motor
    settle_s = max(20.0 * motor.phase_inductance_h / motor.phase_resistance_ohm, 3.0 * turn_s / motor.pole_pairs, 0.01)
    sim = Simulation(config, OracleCommutation(), duty=duty, initial_speed_rpm=rpm, sample_rate_hz=rate,
                     max_step_s=min(2e-6, 1.0 / rate), seed=seed)
    sim.run_until(settle_s + 1.05 * turn_s)
    s = sim.samples()
    keep = s.t_s >= settle_s
    theta = s.theta_m_deg[keep] - s.theta_m_deg[keep][0]
    # speed at the same angle one turn apart: the torque ripple's periods cancel
    t, w = s.t_s[keep], rpm_to_rad_per_s(s.speed_rpm[keep])
    accel = (np.interp(360.0, theta, w) - w[0]) / (np.interp(360.0, theta, t) - t[0])
    return _Turn(duty, float(accel), s, keep, theta)


def balanced_turn(config: PlantConfig, rpm: float, seed: int = 0) -> _Turn:
    """The turn at the duty whose mean torque balances the load at ``rpm`` (secant on the duty
    from the analytic steady state; its first step uses the analytic slope dT/dduty = ke V / R)."""
    m = config.motor
    load_accel = steady_state(m, rpm)["torque_n_m"] / m.inertia_kg_m2
    tol = BALANCE_TOLERANCE * max(load_accel, 1e-9)
    duty = min(steady_state(m, rpm)["duty"], 1.0)
    turn = _one_turn(config, rpm, duty, seed)
    slope = m.ke_v_s_per_rad * m.supply_v / m.phase_resistance_ohm / m.inertia_kg_m2  # d accel / d duty
    for _ in range(BALANCE_MAX_ITERATIONS):
        if abs(turn.accel_rad_s2) <= tol:
            break
        nxt = min(max(turn.duty - turn.accel_rad_s2 / slope, 0.0), 1.0)
        if nxt == turn.duty:
            break
        new = _one_turn(config, rpm, nxt, seed)
        if new.accel_rad_s2 != turn.accel_rad_s2:
            slope = (new.accel_rad_s2 - turn.accel_rad_s2) / (new.duty - turn.duty)
        turn = new
    return turn


def tabulate(config: PlantConfig, speeds_rpm, seed: int = 0) -> CurrentTables:
    grid = speed_grid(speeds_rpm)
    tables = np.zeros((grid.size, 3, TABLE_POINTS))
    duties = np.zeros(grid.size)
    residual = np.zeros(grid.size)
    angles = (np.arange(TABLE_POINTS) + 0.0) * 360.0 / TABLE_POINTS
    for k, rpm in enumerate(grid):
        if rpm < MIN_SPEED_RPM:
            continue
        turn = balanced_turn(config, rpm, seed)
        s, keep, theta = turn.samples, turn.keep, turn.theta_deg
        for x in range(3):
            # one turn against the angle relative to where the turn started, then placed absolutely
            base = s.theta_m_deg[keep][0]
            tables[k, x] = np.interp(
                np.mod(angles - base, 360.0), theta[theta < 360.0], s.i_true_a[keep][theta < 360.0, x], period=360.0
            )
        duties[k], residual[k] = turn.duty, turn.accel_rad_s2
    return CurrentTables(grid, tables, duties, residual)
