"""What a pump controller must keep: its phase current, and the efficiency calibration buys.

* The current limit: the controller's own speed loop stepped from 5000 to 5500 rpm with
  calibrated commutation (a speed loop asks for more torque than the limit allows: the
  acceleration is current-limited); the peak phase current, read from the plant's true
  currents, must stay within the controller's limit.
* The speed loop itself (REQ-SPD-001): a 2 % step the current limit does not bound (a 10 % step
  is a current-limited ramp, the same for every loop's gains): overshoot, decay ratio, settling
  into +-10 % of the step and the holding current over the load's need (hil.experiments.speed_step).
* The efficiency figure (the paper's headline, Section 4.3: the phase current falls to 37.2 %
  once the Hall deviations are calibrated): at the paper's operating point, 5700 rpm, and at
  5000 and 7000 rpm, over three seeds, with the pump load and paper-sized deviations, the share
  of raw Hall commutation's excess mean phase current (over the plant's ideal-commutation
  floor) that calibrated commutation removes, same plant, seed, speed and load.
Every figure comes from the plant's ground truth (true phase currents and speed), not from what
the controller reports. Speeds and windows are the paper pump's; on another motor (a twin) they
are the same fractions of its top speed and hold as many electrical periods
(``PlantConfig.suite_speed_rpm``, ``suite_duration_s``), on the deviations it carries itself.
"""

import numpy as np
import pytest

from bldc.contract import Strategy
from bldc.motor import speed_loop_gain_scale, steady_state
from hil.bench import LockstepBench, acceptance_max_step_s
from hil.controller.virtual import VirtualController
from hil.dut.in_process import InProcessLink
from hil.judging import not_judged
from hil.experiments.table5 import scenario_plant
from plant_models import OracleCommutation, Simulation

STEP_FROM_RPM, STEP_TO_RPM = 5000.0, 5500.0
STEP_HOLD_S = 1.2
EFFICIENCY_SETTLE_S, EFFICIENCY_WINDOW_S = 0.4, 0.4
#: the paper's deviations (installation, pole, RC, armature, edge jitter), as in its Section 4
PAPER_EFFECTS = scenario_plant().effects


def _true_abs_currents(bench, since_s: float):
    s = bench.sim.samples()
    keep = np.asarray(s.t_s) >= since_s
    return np.asarray(s.t_s)[keep], np.abs(np.asarray(s.i_true_a))[keep], np.asarray(s.speed_rpm)[keep]


@pytest.mark.requirement("REQ-CUR-001")
def test_a_speed_step_keeps_the_current_limit(calibrate, hil_bench, hil_budget, hil_evidence, hil_plant_config):
    plant = hil_plant_config
    effects = plant.suite_deviations(PAPER_EFFECTS)
    step_from_rpm, step_to_rpm = plant.suite_speed_rpm(STEP_FROM_RPM), plant.suite_speed_rpm(STEP_TO_RPM)
    corrections = calibrate(effects)
    bench = hil_bench(Strategy.CORRECTED, corrections=corrections, effects=effects, speed_rpm=step_from_rpm)
    (step_s,) = bench.run_setpoints([step_from_rpm], hold_s=0.0, settle_s=plant.suite_settle_s(0.3, step_from_rpm))
    bench.link.set_speed(step_to_rpm)
    bench.sim.run_until(step_s + plant.suite_duration_s(STEP_HOLD_S))
    _, current, _ = _true_abs_currents(bench, step_s)
    peak_a = float(current.max())
    hil_evidence.value("peak phase current", peak_a, "A")
    hil_evidence.value("mean |i| over the step", float(current.mean()), "A")
    hil_budget("phase_current_peak_a", peak_a)


@pytest.mark.requirement("REQ-SPD-001")
def test_the_speed_loop_settles_a_step_the_current_limit_does_not_bound(
    calibrate, hil_bench, hil_budget, hil_evidence, hil_plant_config
):
    """The controller's own speed loop stepped by 2 % (5000 to 5100 rpm on the paper pump): small
    enough that the current limit never acts, so the response is the loop's own
    (hil.experiments.speed_step). Overshoot and decay ratio (the quarter-amplitude decay), settling
    into +-10 % of the step, and the holding current over the load's need, all from the plant's
    true speed and currents."""
    from hil.experiments import speed_step as S

    plant = hil_plant_config
    effects = plant.suite_deviations(PAPER_EFFECTS)
    step_from_rpm, step_to_rpm = plant.suite_speed_rpm(S.STEP_FROM_RPM), plant.suite_speed_rpm(S.STEP_TO_RPM)
    bench = hil_bench(Strategy.CORRECTED, corrections=calibrate(effects), effects=effects, speed_rpm=step_from_rpm)
    response, holding, peak_a, (ts, averaged) = S.run_step(
        bench, plant, step_from_rpm, step_to_rpm, settle_s=plant.suite_settle_s(0.3, step_from_rpm),
        hold_s=plant.suite_duration_s(S.HOLD_S))
    hil_evidence.value("step", step_to_rpm - step_from_rpm, "rpm")
    hil_evidence.value("peak phase current (the current limit must not act)", peak_a, "A")
    hil_evidence.value("excursions about the set point, over the step",
                       " ".join(f"{x:+.3f}" for x in response.excursions) or "none")
    grid = np.linspace(0.0, ts[-1], 16)
    hil_evidence.table("true speed averaged over a turn, from the step", ["t s", "rpm"],
                       [[float(t), float(np.interp(t, ts, averaged))] for t in grid])
    hil_budget("speed_step_overshoot", response.overshoot)
    hil_budget("speed_step_decay_ratio", response.decay_ratio)
    hil_budget("speed_step_settling_s", response.settling_s)
    hil_budget("speed_hold_current_over_load", holding)


#: REQ-CUR-002's operating points: the paper's (5700 rpm, its Figures 8 and 9) and one on either
#: side within its pump's 5000-10,000 rpm range, each over this many seeds from the run's seed on
EFFICIENCY_SPEEDS_RPM = (5000.0, 5700.0, 7000.0)
EFFICIENCY_SEEDS = 3
#: the bench's own speed loop for the ideal-commutation floor (on the true speed: an instrument,
#: not a controller under test), updated every millisecond
FLOOR_LOOP_DT_S, FLOOR_KP_PER_RPM, FLOOR_KI_PER_RPM_S = 1e-3, 2e-4, 4e-3


def ideal_commutation_mean_current_a(config, rpm: float, seed: int, settle_s: float, window_s: float) -> float:
    """The physics floor: mean |i| of the same plant, seed, speed and load commutated at the true
    rotor angle (the plant's oracle), held at ``rpm`` by the bench's own PI on the duty (the same
    loop on a motor wound for another speed: ``speed_loop_gain_scale``)."""
    gain_scale = speed_loop_gain_scale(config.motor)
    d0 = steady_state(config.motor, rpm)["duty"]
    sim = Simulation(config, OracleCommutation(), duty=d0, initial_speed_rpm=rpm, seed=seed,
                     max_step_s=acceptance_max_step_s(config))
    integral = 0.0
    while sim.t_s < settle_s + window_s - 1e-9:
        sim.run_until(sim.t_s + FLOOR_LOOP_DT_S)
        error = (rpm - sim.speed_rpm) * gain_scale
        integral += error * FLOOR_LOOP_DT_S
        sim.set_duty(min(max(d0 + FLOOR_KP_PER_RPM * error + FLOOR_KI_PER_RPM_S * integral, 0.0), 1.0))
    s = sim.samples()
    return float(np.abs(np.asarray(s.i_true_a))[np.asarray(s.t_s) >= settle_s].mean())


def mean_current_a(bench, rpm: float, settle_s: float, window_s: float) -> tuple[float, float]:
    """Mean |i| and mean speed over the judged window, the controller holding ``rpm``."""
    bench.link.set_speed(rpm)
    bench.sim.run_until(settle_s + window_s)
    _, current, speed = _true_abs_currents(bench, settle_s)
    return float(current.mean()), float(speed.mean())


@pytest.mark.requirement("REQ-CUR-002")
def test_calibration_removes_the_excess_current_of_raw_commutation(
    calibrate, hil_bench, hil_plant_config, hil_seed, hil_budget, hil_evidence
):
    """Mean phase current with calibrated commutation (the controller under test) against raw Hall
    commutation and against the ideal-commutation floor of the same plant: the share of raw
    commutation's excess current (over the floor) that calibration removes, at three speeds over
    three seeds each. The judged raw baseline is the paper's setup (a speed loop on the duty,
    commutation on the Hall edges) with no current limit, run by the reference controller: a
    controller's own raw baseline is capped by its current limiter (the built-in's binds at every
    speed here: 1.6 A against 2.3-2.9 A unlimited), and a capped baseline has no excess left to
    remove. That case is reported beside it."""
    effects = hil_plant_config.suite_deviations(PAPER_EFFECTS)
    corrections = calibrate(effects)
    config = hil_plant_config.with_effects(*effects)
    rows, shares = [], []
    for paper_rpm in EFFICIENCY_SPEEDS_RPM:
        rpm = config.suite_speed_rpm(paper_rpm)
        window = (config.suite_settle_s(EFFICIENCY_SETTLE_S, rpm), config.suite_duration_s(EFFICIENCY_WINDOW_S))
        for seed in range(hil_seed, hil_seed + EFFICIENCY_SEEDS):
            raw = mean_current_a(hil_bench(Strategy.RAW, corrections=corrections, effects=effects,
                                           speed_rpm=rpm, seed=seed), rpm, *window)
            cal = mean_current_a(hil_bench(Strategy.CORRECTED, corrections=corrections, effects=effects,
                                           speed_rpm=rpm, seed=seed), rpm, *window)
            # the paper's baseline: raw Hall commutation under a speed loop with no current limit
            reference = InProcessLink(VirtualController(config.motor, strategy=Strategy.RAW, current_limit_a=None))
            unlimited = mean_current_a(
                LockstepBench(config, reference, initial_speed_rpm=rpm, duty=steady_state(config.motor, rpm)["duty"],
                              seed=seed, sim_options={"max_step_s": acceptance_max_step_s(config)}),
                rpm, *window)
            floor_a = ideal_commutation_mean_current_a(config, rpm, seed, *window)
            # the same operating point, or the comparison says nothing
            for name, (_, got) in (("raw", raw), ("calibrated", cal), ("unlimited raw", unlimited)):
                not_judged(abs(got - rpm) < 0.02 * rpm, f"{name} commutation held {got:.0f} rpm, not {rpm:.0f}: "
                           "not the same operating point (the speed loop is REQ-SPD-001's)")
            share = (raw[0] - cal[0]) / (raw[0] - floor_a)
            share_unlimited = (unlimited[0] - cal[0]) / (unlimited[0] - floor_a)
            shares.append(share_unlimited)
            rows.append([rpm, seed, raw[0], unlimited[0], cal[0], floor_a, cal[0] / raw[0], cal[0] / unlimited[0],
                         share, share_unlimited])
    hil_evidence.table(
        "mean phase current (plant truth), pump load, paper-sized deviations, same plant and seed per row",
        ["rpm", "seed", "raw A (controller under test)", "raw A (no current limit)", "calibrated A",
         "ideal commutation A", "calibrated / raw", "calibrated / unlimited raw", "excess removed",
         "excess removed (unlimited raw)"],
        rows,
    )
    paper = [r for r in rows if r[0] == config.suite_speed_rpm(5700.0)]
    hil_evidence.value("calibrated / unlimited raw at 5700 rpm, mean over seeds (the paper: 0.372)",
                       float(np.mean([r[7] for r in paper])), "ratio")
    hil_evidence.value("calibrated / raw at 5700 rpm, mean over seeds (the controller's own limiter on its raw "
                       "baseline)",
                       float(np.mean([r[6] for r in paper])), "ratio")
    hil_evidence.value("lowest excess removed against the controller's own raw baseline (its limiter caps that "
                       "baseline's excess; reported, not judged)", float(min(r[8] for r in rows)), "fraction")
    hil_budget("raw_excess_current_removed", min(shares))
