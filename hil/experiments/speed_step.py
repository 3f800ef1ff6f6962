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


def step_response(t_s: np.ndarray, speed_rpm: np.ndarray, step_from_rpm: float, step_to_rpm: float,
                  band: float = SETTLING_BAND, deadband: float = DEADBAND) -> StepResponse:
    """The figures of a step from ``step_from_rpm`` to ``step_to_rpm`` at t = 0 (``t_s`` from the
    step, ``speed_rpm`` already averaged over a turn)."""
    step = step_to_rpm - step_from_rpm
    e = (np.asarray(speed_rpm, dtype=float) - step_to_rpm) / step  # the error, over the step
    t = np.asarray(t_s, dtype=float)
    outside = np.nonzero(np.abs(e) > band)[0]
    settling = 0.0 if outside.size == 0 else (float("inf") if outside[-1] == e.size - 1 else float(t[outside[-1] + 1]))
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
    s = bench.sim.samples()
    t = np.asarray(s.t_s)
    keep = t >= step_s
    t, speed, current = t[keep] - step_s, np.asarray(s.speed_rpm)[keep], np.abs(np.asarray(s.i_true_a))[keep]
    ts, averaged = turn_average(t, speed, step_to_rpm)
    response = step_response(ts, averaged, step_from_rpm, step_to_rpm)
    holding = current[t >= t[-1] - plant.suite_duration_s(HOLDING_WINDOW_S)].mean()
    need = load_mean_phase_current_a(bench.config.motor, step_to_rpm)
    return response, float(holding / need), float(current.max()), (ts, averaged)
