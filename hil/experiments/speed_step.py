"""REQ-SPD-001's figures: a speed set-point step small enough that the current limit never acts,
judged on the plant's true speed (averaged over each mechanical turn) and true currents.

A speed loop is judged on what it alone decides. A 10 % step (REQ-CUR-001's) is an acceleration
at the current limit: every loop, well tuned or not, ramps at the same current-limited rate and
settles at the same instant, so such a step cannot tell a speed loop's gains apart. A 2 % step
(5000 to 5100 rpm on the paper pump) asks the reference loop for about 0.016 of duty, 10 A of
transient current on its 0.131 ohm conducting pair at 80 V, within its 15 A limit: the response is
the loop's own. Four figures (docs/controller.md, "The speed loop"):

* the overshoot, over the step;
* the decay ratio: the second overshoot over the first (same direction, one period of ringing
  later), the quarter-amplitude decay of Ziegler and Nichols as its bound;
* the settling time into a band of +-10 % of the step (inside the overshoot limit);
* the mean phase current while holding the new set point, over the current the load needs there
  (physics: the fan and friction torque at the set point over the torque constant 2 ke, two
  phases of three conducting: a mean |i| per phase of 2/3 of it); a loop whose duty chatters on
  the speed measurement's noise drives current the load does not need.

Two more figures judge what a small step cannot show (``run_load_step`` and REQ-CUR-001's
current-limited step):

* the overshoot of the current-limited 10 % step: once the limit releases, a loop whose integral
  wound up through the ramp overshoots by most of the step (anti-windup missing);
* the recovery from a load step at a held set point (the pump's load torque half as large again,
  a valve opening): the time until the speed is back within the settling band's width (10 % of
  the 2 % step, 0.2 % of the set point) for good. A loop without integral action settles off the
  set point, by the load change over its proportional gain, and never recovers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.motor import steady_state

#: the paper pump's step (the acceptance suite's plant scales it to the same fraction of its top speed)
STEP_FROM_RPM, STEP_TO_RPM = 5000.0, 5100.0
#: how long the new set point is held (settling is judged within it), and the closing window in
#: which the holding current is measured
HOLD_S, HOLDING_WINDOW_S = 1.5, 0.3
#: the settling band, of the step
SETTLING_BAND = 0.10
#: excursions of the turn-averaged speed smaller than this fraction of the step are noise, not ringing
DEADBAND = 0.05
#: the load step at a held set point: the pump's load torque this many times its own (a valve
#: opening), the band the speed must return to (the settling band's width: 10 % of the 2 % step,
#: as a fraction of the set point), and how long the new load is held
LOAD_STEP_SCALE = 1.5
LOAD_STEP_BAND = SETTLING_BAND * (STEP_TO_RPM - STEP_FROM_RPM) / STEP_FROM_RPM
LOAD_HOLD_S = 1.5


@dataclass(frozen=True)
class StepResponse:
    overshoot: float  #: the first overshoot, over the step (0 when the speed never passes the set point)
    decay_ratio: float  #: the second overshoot over the first (0 without a second one beyond the deadband)
    settling_s: float  #: into +-SETTLING_BAND of the step, for good (inf: still outside at the end)
    excursions: tuple[float, ...]  #: the signed peaks about the set point after it was first reached, over the step


def turn_average(t_s: np.ndarray, speed_rpm: np.ndarray, rpm: float) -> tuple[np.ndarray, np.ndarray]:
    """The speed averaged over one mechanical turn at ``rpm`` (a running mean): the per-sector ripple of
    the Hall deviations and the commutation, which repeat every turn, cancel."""
    dt = float(np.median(np.diff(t_s)))
    n = max(int(round(60.0 / rpm / dt)), 1)
    return t_s[n - 1:], np.convolve(speed_rpm, np.ones(n) / n, mode="valid")


def time_into_band(t_s: np.ndarray, error: np.ndarray, band: float) -> float:
    """The first instant from which ``|error|`` stays within ``band`` for good (0: never outside;
    inf: still outside at the end)."""
    outside = np.nonzero(np.abs(error) > band)[0]
    if outside.size == 0:
        return 0.0
    return float("inf") if outside[-1] == error.size - 1 else float(t_s[outside[-1] + 1])


def since(bench, t0_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bench's true time (from ``t0_s``), speed and |i| of each phase since ``t0_s``."""
    s = bench.sim.samples()
    t = np.asarray(s.t_s)
    keep = t >= t0_s
    return t[keep] - t0_s, np.asarray(s.speed_rpm)[keep], np.abs(np.asarray(s.i_true_a))[keep]


def step_response(t_s: np.ndarray, speed_rpm: np.ndarray, step_from_rpm: float, step_to_rpm: float,
                  band: float = SETTLING_BAND, deadband: float = DEADBAND) -> StepResponse:
    """The figures of a step from ``step_from_rpm`` to ``step_to_rpm`` at t = 0 (``t_s`` from the
    step, ``speed_rpm`` already averaged over a turn)."""
    step = step_to_rpm - step_from_rpm
    e = (np.asarray(speed_rpm, dtype=float) - step_to_rpm) / step  # the error, over the step
    t = np.asarray(t_s, dtype=float)
    settling = time_into_band(t, e, band)
    reached = np.nonzero(e >= 0.0)[0]
    excursions: list[float] = []
    if reached.size:
        sign, peak = 1.0, 0.0
        for v in e[reached[0]:]:
            if sign * v >= 0.0:
                peak = max(peak, sign * v)
            elif -sign * v > deadband:  # the speed crossed to the other side, beyond the noise
                excursions.append(sign * peak)
                sign, peak = -sign, -sign * v
        excursions.append(sign * peak)
    overshoot = max(excursions[0], 0.0) if excursions else 0.0
    second = excursions[2] if len(excursions) > 2 else 0.0
    decay = second / overshoot if overshoot > deadband and second > deadband else 0.0
    return StepResponse(overshoot, decay, settling, tuple(excursions))


def load_mean_phase_current_a(motor, rpm: float) -> float:
    """The mean |i| per phase the load needs at ``rpm`` (``bldc.motor.steady_state``: the fan and
    friction torque over 2 ke), with two phases of three conducting at a time."""
    return 2.0 / 3.0 * steady_state(motor, rpm)["current_a"]


def run_step(bench, plant, step_from_rpm: float, step_to_rpm: float, settle_s: float, hold_s: float = HOLD_S):
    """Step the controller's set point on ``bench`` (already built at ``step_from_rpm``); returns
    (StepResponse, holding current over the load's need, peak |i| A, the turn-averaged trace from the step)."""
    (step_s,) = bench.run_setpoints([step_from_rpm], hold_s=0.0, settle_s=settle_s)
    bench.link.set_speed(step_to_rpm)
    bench.sim.run_until(step_s + hold_s)
    t, speed, current = since(bench, step_s)
    ts, averaged = turn_average(t, speed, step_to_rpm)
    response = step_response(ts, averaged, step_from_rpm, step_to_rpm)
    holding = current[t >= t[-1] - plant.suite_duration_s(HOLDING_WINDOW_S)].mean()
    need = load_mean_phase_current_a(bench.config.motor, step_to_rpm)
    return response, float(holding / need), float(current.max()), (ts, averaged)


@dataclass(frozen=True)
class LoadStepResponse:
    recovery_s: float  #: back within +-LOAD_STEP_BAND of the set point for good (inf: still outside at the end)
    dip: float  #: the largest excursion below the set point, over the set point
    final_offset: float  #: the mean error over the last turn-averaged tenth of the hold, over the set point


def load_step_response(t_s: np.ndarray, speed_rpm: np.ndarray, rpm: float,
                       band: float = LOAD_STEP_BAND) -> LoadStepResponse:
    """The figures of a load step at t = 0 (``t_s`` from the step, ``speed_rpm`` turn-averaged)."""
    e = (np.asarray(speed_rpm, dtype=float) - rpm) / rpm
    t = np.asarray(t_s, dtype=float)
    recovery = time_into_band(t, e, band)
    tail = e[t >= t[-1] - 0.1 * (t[-1] - t[0])]
    return LoadStepResponse(recovery, float(max(-e.min(), 0.0)), float(tail.mean()))


def run_load_step(bench, rpm: float, settle_s: float, hold_s: float = LOAD_HOLD_S,
                  scale: float = LOAD_STEP_SCALE):
    """Hold ``rpm`` on ``bench`` (already built there), then step the plant's load to ``scale``
    times its own; returns (LoadStepResponse, the turn-averaged trace from the step)."""
    (step_s,) = bench.run_setpoints([rpm], hold_s=0.0, settle_s=settle_s)
    bench.sim.set_load_scale(scale)
    bench.sim.run_until(step_s + hold_s)
    t, speed, _ = since(bench, step_s)
    ts, averaged = turn_average(t, speed, rpm)
    return load_step_response(ts, averaged, rpm), (ts, averaged)
