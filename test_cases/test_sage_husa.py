"""The Sage-Husa commutation predictor in the paper's experiment (Section 4.4), through the link.

Speed stepped from 5000 to 10,000 rpm in seven set points under the controller's own speed
loop, with the pump load, paper-sized deviations (calibrated and downloaded) and random
type III edge disturbances (3 us RMS jitter). The controller commutates with its Sage-Husa
predictor, then with its fixed-noise Kalman filter and with the pre-calibration rule, on the
same plant and seed; every commutation is scored against the true rotor angle. On another motor
(a twin) the speeds are the same fractions of its top speed, the windows hold as many electrical
periods, and the motor's own calibrated deviations stand in for the paper's.
"""

import numpy as np
import pytest

from bldc.contract import FILTER_COUNTERS, Strategy
from hil.bench.lockstep import p99_abs, rms
from hil.controller.virtual import VirtualController
from hil.experiments.closed_loop import commutation_time_mape_pct
from hil.experiments.table5 import SETPOINTS_RPM, scenario_plant
from hil.verdicts.plots import commutation_error_figure
from hil.predictors import FilterSettings

HOLD_S = 0.4
JITTER_S = 3e-6
SCENARIO_PLANT = scenario_plant(jitter_time_rms_s=JITTER_S)
SCENARIO_EFFECTS = SCENARIO_PLANT.effects
#: the Sage-Husa settings under test, written to the controller (it keeps whatever an earlier
#: test wrote; a link carries b, Q0, R0 and P0): the reference controller's, the paper's P0 with
#: Q0, R0's current entry and b tuned on its closed loop (docs/sage-husa.md, "Tuned on the closed loop")
SH_SETTINGS = VirtualController(SCENARIO_PLANT.motor).filter_settings


def run_scenario(hil_bench, plant, corrections, strategy, filter_settings=SH_SETTINGS, setpoints_rpm=SETPOINTS_RPM,
                 seed=None, edge_jitter_s=None):
    """The scenario on ``plant`` (the run's plant): ``setpoints_rpm`` are the paper pump's."""
    setpoints_rpm = [plant.suite_speed_rpm(rpm) for rpm in setpoints_rpm]
    bench = hil_bench(
        strategy,
        corrections=corrections,
        effects=plant.suite_deviations(SCENARIO_EFFECTS),
        speed_rpm=setpoints_rpm[0],
        filter_settings=filter_settings,
        seed=seed,
    )
    steps = bench.run_setpoints(setpoints_rpm, hold_s=plant.suite_duration_s(HOLD_S),
                                settle_s=plant.suite_settle_s(0.3, setpoints_rpm[0]),
                                edge_jitter_s=None if edge_jitter_s is None else
                                [plant.suite_duration_s(j) for j in edge_jitter_s])
    c = bench.sim.commutations()
    keep = c.t_s >= steps[0]
    err = c.error_deg_e[keep]
    # commutation time error over the ideal commutation interval: (err / w) / (60 deg / w), at any speed
    return bench, (c.t_s, c.error_deg_e), steps[0], err, commutation_time_mape_pct(err)


def current_at_commutations_a(bench, t_s: np.ndarray) -> np.ndarray:
    """The plant's true mean phase |i| at each commutation instant (its edges' record, interpolated)."""
    e = bench.sim.edges()
    return np.interp(t_s, e.t_capture_s, e.mean_abs_current_a)


#: the paper scenario's runs per controller link and strategies, shared by REQ-PRED-001's and
#: REQ-PRED-006's tests (each still requests the link)
_STRATEGY_RUNS: dict = {}


def run_strategies(calibrate, hil_bench, hil_link, plant, strategies):
    """Each strategy on the same plant and seed: its row of figures, its error trace (start-up
    included), the instant the judged window starts and the controller's filter counters read
    back right after its run."""
    key = (id(hil_link), id(plant), tuple(strategies))
    if key not in _STRATEGY_RUNS:
        _STRATEGY_RUNS[key] = _run_strategies(calibrate, hil_bench, hil_link, plant, strategies)
    return _STRATEGY_RUNS[key]


def _run_strategies(calibrate, hil_bench, hil_link, plant, strategies):
    corrections = calibrate(plant.suite_deviations(SCENARIO_EFFECTS))
    rows, traces, counters, currents = {}, {}, {}, {}
    for strategy in strategies:
        bench, trace, judged_from_s, err, mape = run_scenario(hil_bench, plant, corrections, strategy)
        rows[strategy] = [strategy.name, err.size, rms(err), p99_abs(err), float(np.max(np.abs(err))), mape]
        traces[strategy.name] = trace
        currents[strategy.name] = current_at_commutations_a(bench, trace[0])
        counters[strategy] = {k: hil_link.status()[k] for k in FILTER_COUNTERS}
    return rows, traces, judged_from_s, counters, currents


ROW_COLUMNS = ["strategy", "commutations", "RMS deg e", "p99 deg e", "max deg e", "commutation time MAPE %"]


@pytest.mark.requirement("REQ-PRED-001")
def test_sage_husa_meets_its_budgets(calibrate, hil_bench, hil_link, hil_plant_config, hil_budget, hil_budgets,
                                     hil_evidence):
    rows, traces, judged_from_s, counters, _ = run_strategies(
        calibrate, hil_bench, hil_link, hil_plant_config, (Strategy.SAGE_HUSA, Strategy.CORRECTED)
    )
    hil_evidence.table(
        "paper scenario: commutation error against the true rotor angle", ROW_COLUMNS, list(rows.values())
    )
    hil_evidence.figure(
        "commutation error through the seven set points",
        commutation_error_figure(
            traces,
            "paper scenario, 5000 to 10,000 rpm",
            judged_from_s=judged_from_s,
            budget_deg_e=hil_budgets["sage_husa_commutation_angle_p99"].limit,
            budget_label="Sage-Husa p99 budget",
        ),
    )
    hil_evidence.table(
        "Sage-Husa filter counters read back from the controller",
        ["counter", "count"],
        [[k, v] for k, v in counters[Strategy.SAGE_HUSA].items()],
    )
    sh = rows[Strategy.SAGE_HUSA]
    hil_budget("sage_husa_commutation_angle_rms", sh[2])
    hil_budget("sage_husa_commutation_angle_p99", sh[3])
    hil_budget("commutation_time_mape", sh[5])


#: REQ-PRED-006's windows: this long after each set-point step of the paper scenario (its
#: regulation stage: the acceleration at the current limit, where Eq. 8's K_T I term drives the rotor)
REGULATION_WINDOW_S = 0.12


def regulation_windows(t_s: np.ndarray, first_step_s: float, plant) -> np.ndarray:
    """The commutations within ``REGULATION_WINDOW_S`` after each set-point step but the first (the
    steps follow each other every ``HOLD_S``, ``run_scenario``)."""
    hold, window = plant.suite_duration_s(HOLD_S), plant.suite_duration_s(REGULATION_WINDOW_S)
    steps = first_step_s + hold * np.arange(1, len(SETPOINTS_RPM))
    return np.any([(t_s >= s) & (t_s < s + window) for s in steps], axis=0)


#: REQ-PRED-001's back-to-back check runs the paper scenario on this many seeds (the run's and the next)
BACK_TO_BACK_SEEDS = 3


@pytest.mark.requirement("REQ-PRED-001")
def test_sage_husa_is_the_papers_method_back_to_back_with_the_reference(calibrate, hil_bench, hil_link,
                                                                         hil_plant_config, hil_seed, hil_judge,
                                                                         hil_evidence):
    """Power beside compliance: a controller that declares the paper's method (its strategy role
    offers Sage-Husa) commutates in the paper scenario as the reference implementation does (the
    built-in controller as shipped, in-process), on the same plant, calibration, settings, seeds
    and set points. The tolerance is what the seed alone moves one run's RMS, measured here; the
    budgets (Table 5) sit several times above what the method reaches on this bench, so a wrong
    model input that triples the error passes them and fails this."""
    from hil.verdicts.budget_sources import BAND_STANDARD_ERRORS
    from hil.pytest_plugin import bench_factory, declares_the_papers_method, reference_link

    if not declares_the_papers_method(hil_link):
        pytest.skip("the controller does not declare the paper's method (no sage_husa strategy): no back-to-back")
    plant = hil_plant_config
    rows, _, _, _, _ = run_strategies(calibrate, hil_bench, hil_link, plant, (Strategy.SAGE_HUSA, Strategy.CORRECTED))
    corrections = calibrate(plant.suite_deviations(SCENARIO_EFFECTS))
    seeds = list(range(hil_seed, hil_seed + BACK_TO_BACK_SEEDS))
    dut = [rows[Strategy.SAGE_HUSA][2]]  # the run's seed: REQ-PRED-001's own run
    for seed in seeds[1:]:
        dut.append(rms(run_scenario(hil_bench, plant, corrections, Strategy.SAGE_HUSA, seed=seed)[3]))
    reference = bench_factory(reference_link(plant.motor), plant, hil_seed)
    ref = [rms(run_scenario(reference, plant, corrections, Strategy.SAGE_HUSA, seed=seed)[3]) for seed in seeds]
    spread = float(np.sqrt((np.var(dut, ddof=1) + np.var(ref, ddof=1)) / 2.0))  # pooled, one run's
    hil_evidence.table("Sage-Husa commutation angle RMS, paper scenario: the controller and the reference",
                       ["seed", "controller deg e", "reference deg e", "difference deg e"],
                       [[s, d, r, d - r] for s, d, r in zip(seeds, dut, ref)])
    hil_evidence.value("seed-to-seed standard deviation of one run's RMS, pooled", spread, "deg_e")
    hil_judge("sage_husa_rms_against_reference", abs(float(np.mean(dut) - np.mean(ref))),
              BAND_STANDARD_ERRORS * spread)


def error_growth_with_current_deg_e(err_deg_e: np.ndarray, current_a: np.ndarray) -> tuple[float, float]:
    """How far the signed error moves with the current: the least-squares slope (deg e per A) times
    the current's span between its 5th and 95th percentile; (growth deg e, slope deg e/A)."""
    slope = float(np.polyfit(current_a, err_deg_e, 1)[0])
    span = float(np.percentile(current_a, 95) - np.percentile(current_a, 5))
    return slope * span, slope


@pytest.mark.requirement("REQ-PRED-006")
def test_sage_husa_beats_the_constant_speed_rule_through_the_speed_steps(calibrate, hil_bench, hil_link,
                                                                         hil_plant_config, hil_budget, hil_judge,
                                                                         hil_evidence):
    """Through the set-point steps the rotor accelerates by Eq. 8's current term: a predictor whose
    model gets its current input wrong (a scale, a window) predicts the wrong acceleration, and
    falls back towards the constant-speed rule of pre-calibration (60 deg e at the last sector's
    speed). Judged on REQ-PRED-001's runs, the 0.12 s after each step. Physics beside the budget:
    the error of a correct predictor does not move with the phase current (the armature term
    removes the current's shift of the edges, Eq. 8's current term the acceleration)."""
    from hil.verdicts.budget_sources import table3_repeatability_deg_e

    _, traces, judged_from_s, _, currents = run_strategies(
        calibrate, hil_bench, hil_link, hil_plant_config, (Strategy.SAGE_HUSA, Strategy.CORRECTED)
    )
    rows = []
    for strategy in (Strategy.SAGE_HUSA, Strategy.CORRECTED):
        t, err = (np.asarray(v) for v in traces[strategy.name])
        keep = regulation_windows(t, judged_from_s, hil_plant_config)
        rows.append([strategy.name, int(keep.sum()), rms(err[keep]), p99_abs(err[keep])])
    hil_evidence.table("commutation error in the 0.12 s after each set-point step (the regulation stage)",
                       ["strategy", "commutations", "RMS deg e", "p99 deg e"], rows)
    hil_budget("sage_husa_over_precalibration_regulation_rms", rows[0][2] / rows[1][2])
    t, err = (np.asarray(v) for v in traces[Strategy.SAGE_HUSA.name])
    judged = t >= judged_from_s
    growth, slope = error_growth_with_current_deg_e(err[judged], currents[Strategy.SAGE_HUSA.name][judged])
    hil_evidence.value("Sage-Husa's signed error against the phase current, slope", slope, "deg_e/A")
    hil_judge("commutation_error_growth_with_current", abs(growth), table3_repeatability_deg_e())


#: REQ-PRED-002 is judged over this many seeds (from the run's seed on) on each operating profile
#: of ``controller_tuning.PROFILES``, with the controller's own motor: on each profile Sage-Husa's
#: angle RMS over the KF's (means over the seeds), each profile its own verdict. The controller's
#: filters were tuned on training pumps, none of these; the evidence states every run and each
#: profile's ratio with each seed left out in turn
REQ_PRED_002_SEEDS = 6
#: the profiles, each a test of its own: ``controller_tuning.PROFILES``'s, in its order, by their first
#: word (that module is imported in the test, not here: its import takes seconds of every collection)
REQ_PRED_002_PROFILES = ("paper", "low", "high", "noisy")


def profile_ratios(runs) -> dict[str, tuple[float, int]]:
    """Per profile of ``runs`` ((profile, seed, Sage-Husa RMS, KF RMS, Sage-Husa commutations, KF
    commutations) each): Sage-Husa's mean RMS over the KF's, and the commutations each filter's
    RMS stands on (the fewer of the two), which set the profile's limit
    (``budget_sources.sage_husa_over_kf_limit_for``)."""
    out = {}
    for profile in dict.fromkeys(r[0] for r in runs):
        mine = [r for r in runs if r[0] == profile]
        ratio = float(np.mean([r[2] for r in mine]) / np.mean([r[3] for r in mine]))
        out[profile] = (ratio, min(sum(r[4] for r in mine), sum(r[5] for r in mine)))
    return out


@pytest.mark.requirement("REQ-PRED-002")
@pytest.mark.parametrize("profile", REQ_PRED_002_PROFILES)
def test_sage_husa_is_no_worse_than_the_tuned_kf(profile, calibrate, hil_bench, hil_plant_config, hil_seed,
                                                 hil_budget, hil_evidence):
    """Against the controller's fixed-noise Kalman filter, both from the same tuning on training
    pumps (docs/sage-husa.md, "Peers"), over held-out seeds on each of four operating profiles (the
    fourth, noisy, with an edge noise that changes from set point to set point: where a filter must
    learn R, and one whose R is stuck falls behind); each profile is a verdict (and a test) of its
    own (a pooled ratio would let a profile where Sage-Husa is far ahead carry one where it is behind;
    as tests of their own they run side by side on the suite's workers), its limit derived for the
    commutations it judged."""
    from hil.experiments.controller_tuning import PROFILES
    from hil.verdicts.budget_sources import PRED_002_PROFILES, sage_husa_over_kf_limit_for

    name, operating = list(PROFILES.items())[REQ_PRED_002_PROFILES.index(profile)]
    assert name.split()[0] == profile, f"REQ_PRED_002_PROFILES is not controller_tuning.PROFILES: {name!r}"
    assert len(PROFILES) == PRED_002_PROFILES, "the limit's false-fail share is not split over every profile"
    corrections = calibrate(hil_plant_config.suite_deviations(SCENARIO_EFFECTS))
    runs, traces, judged_from_s = [], {}, None
    for seed in range(hil_seed, hil_seed + REQ_PRED_002_SEEDS):
        pair = {}
        for strategy in (Strategy.SAGE_HUSA, Strategy.KF):
            _, trace, t0, err, _ = run_scenario(hil_bench, hil_plant_config, corrections, strategy,
                                                setpoints_rpm=operating.setpoints_rpm, seed=seed,
                                                edge_jitter_s=operating.edge_jitter_s)
            pair[strategy] = (rms(err), err.size)
            if seed == hil_seed and profile == "paper":
                traces[strategy.name], judged_from_s = trace, t0
        (sh, n_sh), (kf, n_kf) = pair[Strategy.SAGE_HUSA], pair[Strategy.KF]
        runs.append((name, seed, sh, kf, n_sh, n_kf))

    hil_evidence.table(
        "Sage-Husa against the tuned Kalman filter, per seed, on this operating profile",
        ["profile", "seed", "Sage-Husa RMS deg e", "KF RMS deg e", "ratio", "commutations"],
        [[p, s, sh, kf, sh / kf, n] for p, s, sh, kf, n, _ in runs],
    )
    seeds = range(hil_seed, hil_seed + REQ_PRED_002_SEEDS)
    rows, verdicts = [], []
    for profile, (ratio, n) in profile_ratios(runs).items():
        scenario = sage_husa_over_kf_limit_for(n, f"the {profile} profile's, {REQ_PRED_002_SEEDS} seeds")
        left_out = [profile_ratios([r for r in runs if r[0] == profile and r[1] != s])[profile][0] for s in seeds]
        rows.append([profile, ratio, n, scenario.limit, min(left_out), max(left_out)])
        verdicts.append((ratio, scenario))
    hil_evidence.table(
        "each profile's verdict: Sage-Husa's mean RMS over the KF's, its limit (no worse than the KF, paper "
        "Table 5, beyond the ratio's sampling error over its commutations) and its range with one seed left out",
        ["profile", "ratio", "commutations", "limit", "one seed left out, lowest", "highest"], rows)
    if traces:  # the paper's profile
        hil_evidence.figure(
            "commutation error: Sage-Husa and Kalman filter",
            commutation_error_figure(traces, "paper scenario, 5000 to 10,000 rpm", judged_from_s=judged_from_s),
        )
    for ratio, scenario in verdicts:
        hil_budget("sage_husa_over_kf_angle_rms", ratio, scenario)


@pytest.mark.requirement("REQ-PRED-003")
def test_sage_husa_learns_the_edge_noise_it_was_not_told(calibrate, hil_bench, hil_link, hil_plant_config, hil_budget,
                                                         hil_evidence):
    """Started with R0 of the paper (edge-angle variance 0) and Q0 a hundred times too large (the
    controller keeps Q_w at that nominal and Q_i within its band, so the start is wrong
    throughout), the filter must learn an edge-angle noise variance of the size the plant
    actually injects (3 us jitter at the running speed), where a filter that adapts nothing keeps R0."""
    plant = hil_plant_config
    effects = plant.suite_deviations(SCENARIO_EFFECTS)
    speed_rpm = plant.suite_speed_rpm(8000.0)
    corrections = calibrate(effects)
    nominal = FilterSettings(q0_diag=(0.1, 1e-9, 1e-6))
    wrong = FilterSettings(
        q0_diag=tuple(100.0 * q for q in nominal.q0_diag), r0_diag=(0.0, 0.02), forgetting_b=0.995, q_band_factor=10.0
    )
    bench = hil_bench(
        Strategy.SAGE_HUSA, corrections=corrections, effects=effects, speed_rpm=speed_rpm, filter_settings=wrong
    )
    bench.run_setpoints([speed_rpm], hold_s=plant.suite_duration_s(0.5), settle_s=plant.suite_settle_s(0.2, speed_rpm))
    st = hil_link.status()
    w_e = speed_rpm / 60.0 * 2 * np.pi * bench.config.motor.pole_pairs
    injected_rad2 = (plant.suite_duration_s(JITTER_S) * w_e) ** 2  # the suite's jitter on this motor
    learned = st["r_diag"][0]
    hil_evidence.table(
        "noise statistics read back from the controller",
        ["quantity", "start (R0 / Q0)", "read back", "plant truth"],
        [
            ["R theta (rad^2)", wrong.r0_diag[0], learned, injected_rad2],
            ["Q w ((rad/s)^2)", wrong.q0_diag[0], st["q_diag"][0], ""],
        ],
    )
    err = bench.angle_errors_deg_e(plant.suite_settle_s(0.4, speed_rpm))
    hil_evidence.value("commutation RMS with the wrong start", rms(err), "deg_e")
    hil_budget("learned_edge_noise_ratio", learned / injected_rad2)
    hil_budget("learned_edge_noise_ratio_high", learned / injected_rad2)  # a runaway estimate
    hil_budget("sage_husa_commutation_angle_rms", rms(err))


@pytest.mark.requirement("REQ-PRED-001")
def test_sage_husa_commutation_instants_against_the_plants_ideal_instants(
    calibrate, hil_link, hil_plant_config, hil_seed, hil_budget, hil_evidence
):
    """The controller's Sage-Husa on the paper scenario, each commutation judged against the plant's
    ideal commutation instant (ground truth, never a replay of the same filter): the commutation
    time error over the ideal commutation interval (paper Table 5's last column), and no
    covariance repair read back from the controller."""
    from hil.experiments.closed_loop import record_link

    from hil.experiments.closed_loop import HOLD_S as SCENARIO_HOLD_S
    from hil.experiments.closed_loop import SETTLE_S as SCENARIO_SETTLE_S

    plant = hil_plant_config
    effects = plant.suite_deviations(SCENARIO_EFFECTS)
    corrections = calibrate(effects)
    setpoints_rpm = [plant.suite_speed_rpm(rpm) for rpm in SETPOINTS_RPM]
    r = record_link(
        hil_link,
        plant.with_effects(*effects),
        corrections,
        seed=hil_seed,
        filter_settings=SH_SETTINGS,
        setpoints_rpm=setpoints_rpm,
        hold_s=plant.suite_duration_s(SCENARIO_HOLD_S),
        settle_s=plant.suite_settle_s(SCENARIO_SETTLE_S, setpoints_rpm[0]),
    )
    err = r.closed_loop_error_deg_e
    mape = commutation_time_mape_pct(err)
    hil_evidence.table(
        "closed loop against the plant's ideal commutation instants",
        ["quantity", "value"],
        [
            ["commutations judged", int(err.size)],
            ["angle error RMS deg e", rms(err)],
            ["angle error p99 deg e", p99_abs(err)],
            ["commutation time MAPE % of the ideal interval", mape],
            *[[k, v] for k, v in r.counters.items()],
        ],
    )
    hil_budget("sage_husa_commutation_time_mape", mape)
    assert r.counters["covariance_repairs"] == 0, (
        f"{r.counters['covariance_repairs']} covariance repairs read back from the controller ({r.counters})"
    )
