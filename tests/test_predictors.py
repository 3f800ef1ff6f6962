"""Commutation predictors: equations, guards, robustness over drawn conditions, Table 5 scenario."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from hil.predictors import FilterSettings, KalmanPredictor, MotorModel, PrecalibrationPredictor, SageHusaPredictor
from hil.predictors.compare import SH_ADAPT
from hil.predictors import filters as F
from plant_models import paper_bench
from plant_models import effects as fx
from plant_models.kinematic import OperatingPoint, simulate_edges

BASE = paper_bench()
MODEL = MotorModel.from_plant(BASE.motor)
NOMINAL_Q = (0.1, 1e-9, 1e-6)


def consistent_current(profile, load_scale, motor=BASE.motor):
    """Mean |i| that makes the filter's own equation of motion true for this profile."""
    out = []
    for op in profile:
        w_m = op.speed_rpm * 2 * math.pi / 60
        acc = ((op.end_speed_rpm or op.speed_rpm) - op.speed_rpm) * 2 * math.pi / 60 / op.duration_s
        torque = motor.inertia_kg_m2 * acc + load_scale * motor.fan_coefficient_n_m_s2 * w_m * w_m
        out.append(max(torque, 0.0) / (3 * motor.ke_v_s_per_rad))
    return out


def edges_and_currents(profile, jitter_s, angle_jitter_deg, load_scale, seed):
    currents = consistent_current(profile, load_scale)
    ops = [OperatingPoint(op.duration_s, op.speed_rpm, c, end_speed_rpm=op.end_speed_rpm) for op, c in zip(profile, currents)]
    config = BASE.with_effects(fx.EdgeJitter(time_rms_s=jitter_s, angle_rms_deg_e=angle_jitter_deg))
    e = simulate_edges(config, ops, seed=seed)
    return e, e.mean_abs_current_a


def angle_error_deg(e, pred, skip=150):
    k = np.arange(skip, len(e) - 1)
    return (pred[k] - e.t_ideal_s[k + 1]) * e.speed_rpm[k + 1] * 6 * MODEL.pole_pairs


def test_prediction_follows_eq7_at_constant_speed_without_noise():
    e, cur = edges_and_currents([OperatingPoint(0.3, 6000.0)], 0.0, 0.0, 1.0, 0)
    for predictor in (SageHusaPredictor(MODEL), KalmanPredictor(MODEL, FilterSettings(r0_diag=(1e-8, 0.02))), PrecalibrationPredictor()):
        err = angle_error_deg(e, predictor.run(e.t_conditioned_s, cur).pred_t_s)
        assert np.max(np.abs(err)) < 0.01, type(predictor).__name__


def test_filters_beat_the_last_edge_under_jitter():
    """Angle filtering: a Kalman filter averages edge jitter the pre-calibration predictor passes on."""
    e, cur = edges_and_currents([OperatingPoint(1.0, 8000.0)], 3e-6, 0.0, 1.0, 1)
    pre = np.sqrt(np.mean(angle_error_deg(e, PrecalibrationPredictor().run(e.t_conditioned_s, cur).pred_t_s) ** 2))
    kf = np.sqrt(np.mean(angle_error_deg(e, KalmanPredictor(MODEL, FilterSettings(q0_diag=(0.01, 1e-9, 1e-6), r0_diag=(2.5e-5, 1.0))).run(e.t_conditioned_s, cur).pred_t_s) ** 2))
    sh = np.sqrt(np.mean(angle_error_deg(e, SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q, adapt_mask=7)).run(e.t_conditioned_s, cur).pred_t_s) ** 2))
    # t_k + (t_k - t_k-1) - t_k+1 carries the jitter 2 d_k - d_k-1 - d_k+1: sqrt(6) sigma
    assert pre == pytest.approx(math.sqrt(6) * 3e-6 * 8000 * 12, rel=0.1)
    assert kf < 0.5 * pre and sh < 0.6 * pre


def test_sage_husa_learns_edge_noise_from_the_papers_r0():
    """Starting from R0 = diag(0, 0.02), the interval adaptation recovers the edge-angle variance."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 8000.0)], 3e-6, 0.0, 1.0, 2)
    sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q, adapt_mask=7))
    sh.run(e.t_conditioned_s, cur)
    true_r = (3e-6 * 8000 / 60 * 2 * 2 * math.pi) ** 2
    # was within 30 % when the first estimate came from innovations of the R0 = 0 filter
    assert sh.r_matrix[0, 0] == pytest.approx(true_r, rel=0.1)


def test_divergence_guard_recovers_a_filter_locked_on_a_wrong_speed():
    """Drawn condition that diverged (7 deg_e RMS against the KF's 0.2): after the warm-up on
    R0 = 0 the filter's P claimed a speed known to 0.04 rad/s while it was 35 rad/s off, so
    every later edge was gated and the error grew by 0.8 deg_e per cycle."""
    e, cur = edges_and_currents([OperatingPoint(0.4, 11825.9)], 3.98e-6, 0.177, 0.514, 688)
    q0 = tuple(q * 10 ** -1.788 for q in NOMINAL_Q)
    kf = KalmanPredictor(MODEL, FilterSettings(q0_diag=q0, r0_diag=(1e-5, 1.0))).run(e.t_conditioned_s, cur)
    kf_rms = np.sqrt(np.mean(angle_error_deg(e, kf.pred_t_s) ** 2))
    rms = {}
    for run_length in (0, 2):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=q0, adapt_mask=SH_ADAPT, divergence_run=run_length))
        run = sh.run(e.t_conditioned_s, cur)
        rms[run_length] = np.sqrt(np.mean(angle_error_deg(e, run.pred_t_s) ** 2))
        assert (run.guards["divergence"] > 0) == (run_length > 0)
    assert rms[0] > 5 * kf_rms          # the failure the guard exists for
    assert rms[2] < 1.5 * kf_rms, rms   # faded P: re-converged


@pytest.mark.parametrize("end_rpm, q_log10", [(9000.0, -2), (None, 2)])
def test_whiteness_option_steers_q_where_the_eq12_recursion_does_not(end_rpm, q_log10):
    """Q_w barely moves a one-step innovation (dt^2 Q_w << R), so the Eq. 12 recursion drifts
    to its band edge; lag-1 innovation whiteness does see a lagging or noise-chasing gain."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 6000.0, end_speed_rpm=end_rpm)], 3e-6, 0.0, 1.0, 7)
    q0 = tuple(q * 10 ** q_log10 for q in NOMINAL_Q)
    rms, q_w = {}, {}
    for mask in (SH_ADAPT, F.ADAPT_Q_WHITE | F.ADAPT_R):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=q0, adapt_mask=mask, q_band_factor=1e4))
        rms[mask] = np.sqrt(np.mean(angle_error_deg(e, sh.run(e.t_conditioned_s, cur).pred_t_s) ** 2))
        q_w[mask] = sh.q_matrix[0, 0]
    white = F.ADAPT_Q_WHITE | F.ADAPT_R
    assert rms[white] < 0.7 * rms[SH_ADAPT], rms
    assert 1e-4 < q_w[white] < 0.1, q_w


def test_guards_fire_and_are_visible_when_q_starts_100x_too_large():
    """design notes section 5: the textbook update loses positive definiteness from Q0 x 100."""
    e, cur = edges_and_currents([OperatingPoint(1.0, 7000.0)], 2e-6, 0.0, 1.0, 3)
    sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=tuple(100 * q for q in NOMINAL_Q)))
    run = sh.run(e.t_conditioned_s, cur)
    assert sum(run.guards.values()) > 0
    assert set(run.guards) == {"innovation_gate", "q_not_pd", "q_band", "r_not_pd", "p_not_pd", "divergence"}
    for m in (sh.p_matrix, sh.q_matrix, sh.r_matrix):
        assert np.allclose(m, m.T) and np.all(np.linalg.eigvalsh(m) > 0)


def test_online_and_batch_modes_agree():
    e, cur = edges_and_currents([OperatingPoint(0.2, 5000.0, end_speed_rpm=6000.0)], 2e-6, 0.0, 1.0, 4)
    batch = SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q)).run(e.t_conditioned_s, cur).pred_t_s
    online = SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q))
    preds = [online.update(t, c) for t, c in zip(e.t_conditioned_s, cur)]
    np.testing.assert_allclose(np.array(preds[1:], dtype=float), batch[1:], rtol=0, atol=1e-12)


def test_bad_settings_and_inputs_refused():
    with pytest.raises(ValueError, match="forgetting_b"):
        SageHusaPredictor(MODEL, FilterSettings(forgetting_b=1.0))
    with pytest.raises(ValueError, match="q0_diag"):
        KalmanPredictor(MODEL, FilterSettings(q0_diag=(math.nan, 1e-9, 1e-6)))
    with pytest.raises(ValueError, match="edge times must increase"):
        SageHusaPredictor(MODEL).run(np.array([0.0, 1e-3, 0.5e-3]), np.ones(3))


# --- robustness over drawn conditions ------------------------------------------------------

conditions = st.fixed_dictionaries({
    "jitter_s": st.floats(0.2e-6, 10e-6),
    "angle_jitter_deg": st.floats(0.0, 0.2),
    "q_factor_log10": st.floats(-2.0, 2.0),
    "start_rpm": st.floats(2000.0, 12000.0),
    "end_rpm": st.floats(2000.0, 12000.0) | st.none(),
    "load_scale": st.floats(0.3, 2.0),
    "seed": st.integers(0, 2**16),
})
RESULTS: list[dict] = []


@settings(max_examples=1000, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(conditions)
def _run_condition(c):
    profile = [OperatingPoint(0.4, c["start_rpm"], end_speed_rpm=c["end_rpm"])]
    e, cur = edges_and_currents(profile, c["jitter_s"], c["angle_jitter_deg"], c["load_scale"], c["seed"])
    q0 = tuple(q * 10 ** c["q_factor_log10"] for q in NOMINAL_Q)
    out = dict(c)
    for name, cls, s in (("kf", KalmanPredictor, FilterSettings(q0_diag=q0, r0_diag=(1e-5, 1.0))),
                         ("sh", SageHusaPredictor, FilterSettings(q0_diag=q0, adapt_mask=SH_ADAPT))):
        f = cls(MODEL, s)
        run = f.run(e.t_conditioned_s, cur)
        err = angle_error_deg(e, run.pred_t_s)
        out[name] = float(np.sqrt(np.mean(err**2)))
        out[name + "_finite"] = bool(np.all(np.isfinite(run.pred_t_s[1:])) and np.all(np.isfinite(f.state)))
        out[name + "_pd"] = all(np.allclose(m, m.T) and np.all(np.linalg.eigvalsh(m) > 0) for m in (f.p_matrix, f.q_matrix, f.r_matrix))
    RESULTS.append(out)


@pytest.fixture(scope="module")
def robustness_results():
    RESULTS.clear()
    _run_condition()
    return list(RESULTS)


def test_covariances_stay_positive_definite_over_1000_drawn_conditions(robustness_results):
    assert len(robustness_results) >= 1000
    broken = [r for r in robustness_results if not (r["kf_finite"] and r["sh_finite"] and r["kf_pd"] and r["sh_pd"])]
    assert not broken, f"covariance lost positive definiteness or estimate not finite in: {broken[:3]}"


@pytest.mark.xfail(strict=True, reason="issue 4 blocked: Sage-Husa is within 5 % of the KF's commutation RMS in 50 % of drawn conditions (docs/sage-husa.md)")
def test_sage_husa_no_worse_than_kf_in_99_percent(robustness_results):
    worse = [r for r in robustness_results if r["sh"] > 1.05 * r["kf"]]
    rate = 1 - len(worse) / len(robustness_results)
    detail = "\n".join(f"  SH {r['sh']:.3f} vs KF {r['kf']:.3f} deg_e: " + ", ".join(f"{k}={r[k]:.4g}" for k in ("jitter_s", "angle_jitter_deg", "q_factor_log10", "start_rpm", "load_scale")) + f", end_rpm={r['end_rpm']}, seed={r['seed']}" for r in worse[:10])
    assert rate >= 0.99, f"Sage-Husa within 5 % of KF in only {rate:.1%} of {len(robustness_results)} conditions; worse in:\n{detail}"


# --- the paper scenario (Table 5) -------------------------------------------------------------

@pytest.fixture(scope="module")
def table():
    from hil.predictors.compare import table5

    return table5()


def test_table5_scenario_scored_against_ground_truth(table):
    tab, run = table
    rows = {r.name: r for r in tab.rows}
    assert set(rows) == {"pre-calibration", "KF", "Sage-Husa"}
    assert len(tab.per_run) == len(tab.eval_seeds) == 3 and not set(tab.eval_seeds) & set(tab.train_seeds)
    # seven set points, each regulation stage ends inside its hold; the ideal instants are exact
    assert len(run.step_times_s) == 7 and np.all(np.isfinite(run.edges.t_ideal_s))
    # both filters average the edge jitter the pre-calibration predictor passes on: a tenth of
    # a degree electrical is the budget a commutation predictor should meet on this bench
    for name in ("KF", "Sage-Husa"):
        assert rows[name].angle_rms_deg_e < 0.1, tab.format()
        assert rows[name].angle_rms_deg_e < 0.2 * rows["pre-calibration"].angle_rms_deg_e, tab.format()
        assert rows[name].angle_p99_deg_e < 0.3, tab.format()
    assert rows["Sage-Husa"].guards and all(v >= 0 for v in rows["Sage-Husa"].guards.values())


def test_scenario_corrects_edges_with_the_current_at_the_edge(table):
    """The armature correction must use the current the calibration was fitted against: the
    ADC's mean |i| at the capture. With the commutation cycle's mean instead (30 % larger on
    this bench) every corrected edge carried a common bias of about -0.55 deg e at 5 A, which no
    predictor can see (a common offset does not change the edge intervals)."""
    _, run = table
    w = run.true_speed_rad_s
    error_deg = np.degrees((run.t_corrected_s - run.edges.t_ideal_s) * w)[300:]
    assert abs(float(np.mean(error_deg))) < 0.05, f"corrected edges biased by {np.mean(error_deg):.3f} deg_e"
    # and the bias does not grow with current either
    slope = np.polyfit(run.mean_current_a[300:], error_deg, 1)[0]
    assert abs(slope) < 0.02, f"corrected-edge error moves {slope:.3f} deg_e per ampere"


@pytest.mark.xfail(strict=True, reason="issue 4 blocked: tuned alike, Sage-Husa does not beat the KF; an oracle bounds any noise adaptation to ~1 % here (docs/sage-husa.md, tools/table5_headroom.py)")
def test_sage_husa_beats_kf_on_every_table5_metric(table):
    tab, _ = table
    improvement = tab.improvement()
    assert all(v > 0 for v in improvement), tab.format()
