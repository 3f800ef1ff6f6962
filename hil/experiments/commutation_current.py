"""The commutation's effect on current, with the speed loop taken out (REQ-CUR-002).

A controller's mean phase current at a speed depends on two things: where it commutates (a
commutation off the ideal angle needs more current for the same torque) and how its speed loop
holds the speed (a loop fed by uneven Hall sectors drives current it does not need). The paper's
comparison (Section 4.3: the mean phase current fell to 37.2 % once calibrated) measures both at
once, each strategy on its own speed measurement. To judge the commutation alone, the bench runs
every strategy under one speed loop of its own, on the plant's true speed (an instrument, not a
controller under test), at the same set point:

- the **ideal floor**: commutation at the true rotor angle (the plant's oracle);
- **raw Hall commutation**: commutation on the plant's own Hall edges, as they reach the
  controller (the paper's "before calibration");
- the **controller under test, replayed**: commutation at the true angle plus the commutation
  errors the controller made in its own run, in the order it made them (``AngleReplay``).

The share of raw Hall commutation's excess current (over the floor) that the controller's
commutation removes is then the commutation's doing alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bldc.contract import Command
from bldc.motor import speed_loop_gain_scale, steady_state
from plant_models import OracleCommutation, RawHallCommutation, Simulation
from plant_models.layout import S_OMEGA_M, S_THETA_M

from ..bench.lockstep import acceptance_max_step_s


@dataclass(frozen=True)
class BenchSpeedLoop:
    """The bench's own PI on the duty, on the plant's true speed, updated every ``period_s`` (the
    same loop for every strategy; on a motor wound for another speed the error is scaled by
    ``speed_loop_gain_scale``)."""

    period_s: float = 1e-3
    #: settled within 0.2 s of a start at the steady-state duty on the paper pump (mean |i| within
    #: 0.1 % of its value a second later), inside the suite's 0.4 s settling time; ten times gentler
    #: gains still swing by 5 % after 0.4 s and would compare transients, not commutations
    kp_per_rpm: float = 2e-3
    ki_per_rpm_s: float = 5e-2
    #: commutations are planned this many times per loop period, from the true angle and speed
    plans_per_period: int = 4


class AngleReplay:
    """Commutate at the true electrical angle ``60 k + error[k]`` (deg e): the ``k``-th boundary
    after the start takes the ``k``-th error of a controller's own run (cycled when the replay
    runs longer). Each instant is planned a fraction of a loop period ahead from the plant's true
    angle and speed, so it lands within a few thousandths of a degree."""

    latency_s = 0.0  # the errors already hold the controller's latency

    def __init__(self, errors_deg_e: np.ndarray):
        errors = np.asarray(errors_deg_e, dtype=float)
        if errors.size == 0 or not np.all(np.isfinite(errors)):
            raise ValueError("AngleReplay needs the finite commutation errors of a controller's run")
        self.errors_deg_e = errors
        self._next_boundary: int | None = None
        self._replayed = 0

    def on_edge(self, edge: dict, sim) -> tuple:
        return ()  # the replay follows the rotor, not the sensors

    def plan(self, sim: Simulation, horizon_s: float) -> list[Command]:
        pole_pairs = sim.plant.pole_pairs
        theta_deg_e = pole_pairs * math.degrees(sim.st[S_THETA_M])
        omega_deg_e_per_s = pole_pairs * math.degrees(sim.st[S_OMEGA_M])
        commands = []
        if self._next_boundary is None:
            # the sector the rotor is in, at once: the start is the oracle's, whatever the sensors say
            self._next_boundary = math.floor(theta_deg_e / 60.0) + 1
            commands.append(Command(at_s=sim.t_s, sector=(self._next_boundary - 1) % 6))
        while True:
            k = self._next_boundary
            target_deg_e = 60.0 * k + self.errors_deg_e[self._replayed % self.errors_deg_e.size]
            due_s = (target_deg_e - theta_deg_e) / omega_deg_e_per_s
            if due_s > horizon_s:
                return commands
            commands.append(Command(at_s=sim.t_s + max(due_s, 0.0), sector=k % 6))
            self._next_boundary += 1
            self._replayed += 1


@dataclass(frozen=True)
class BenchRun:
    """Mean |i| (over the three phases) and mean speed over the judged window, and the commutation
    errors the plant recorded there (positive: late)."""

    mean_current_a: float
    mean_speed_rpm: float
    commutation_error_deg_e: np.ndarray

    @property
    def commutation_rms_deg_e(self) -> float:
        return float(np.sqrt(np.mean(self.commutation_error_deg_e**2)))


def bench_run(config, source, rpm: float, seed: int, settle_s: float, window_s: float,
              loop: BenchSpeedLoop = BenchSpeedLoop()) -> BenchRun:
    """``source`` (``OracleCommutation``, ``RawHallCommutation`` or ``AngleReplay``) commutating the
    plant while the bench's loop holds ``rpm`` on the true speed."""
    gain_scale = speed_loop_gain_scale(config.motor)
    duty0 = steady_state(config.motor, rpm)["duty"]
    sim = Simulation(config, source, duty=duty0, initial_speed_rpm=rpm, seed=seed,
                     max_step_s=acceptance_max_step_s(config))
    plan = getattr(source, "plan", None)
    integral = 0.0
    while sim.t_s < settle_s + window_s - 1e-9:
        for _ in range(loop.plans_per_period):
            step_s = loop.period_s / loop.plans_per_period
            if plan is not None:
                for command in plan(sim, 1.01 * step_s):
                    sim.schedule(command)
            sim.run_until(sim.t_s + step_s)
        error = (rpm - sim.speed_rpm) * gain_scale
        integral += error * loop.period_s
        sim.set_duty(min(max(duty0 + loop.kp_per_rpm * error + loop.ki_per_rpm_s * integral, 0.0), 1.0))
    s, c = sim.samples(), sim.commutations()
    keep = np.asarray(s.t_s) >= settle_s
    return BenchRun(
        mean_current_a=float(np.abs(np.asarray(s.i_true_a))[keep].mean()),
        mean_speed_rpm=float(np.asarray(s.speed_rpm)[keep].mean()),
        commutation_error_deg_e=np.asarray(c.error_deg_e)[np.asarray(c.t_s) >= settle_s],
    )


@dataclass(frozen=True)
class CommutationCurrent:
    """One operating point: the floor, raw Hall commutation and the controller's commutation, each
    under the bench's loop; ``excess_removed`` is the share of raw Hall commutation's excess
    current over the floor that the controller's commutation removes."""

    floor: BenchRun
    raw_hall: BenchRun
    controller: BenchRun

    @property
    def excess_removed(self) -> float:
        raw_excess_a = self.raw_hall.mean_current_a - self.floor.mean_current_a
        return (self.raw_hall.mean_current_a - self.controller.mean_current_a) / raw_excess_a


def commutation_current(config, controller_errors_deg_e: np.ndarray, rpm: float, seed: int, settle_s: float,
                        window_s: float, floor: BenchRun | None = None) -> CommutationCurrent:
    """The three strategies of the module docstring at ``rpm``, on the same plant and seed. ``floor``:
    the ideal commutation's run at ``rpm`` when already made (it draws nothing from the seed but
    rounding: the oracle commutates on the true angle, and the seed moves only what the sensors see)."""
    return CommutationCurrent(
        floor=floor or bench_run(config, OracleCommutation(), rpm, seed, settle_s, window_s),
        raw_hall=bench_run(config, RawHallCommutation(), rpm, seed, settle_s, window_s),
        controller=bench_run(config, AngleReplay(controller_errors_deg_e), rpm, seed, settle_s, window_s),
    )
