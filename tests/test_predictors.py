"""Commutation predictors: equations, guards, robustness over drawn conditions, Table 5 scenario."""

import json
import math

import numpy as np
import pytest

from hil.experiments import compare
from hil.experiments.compare import SH_ADAPT
from hil.experiments.robustness import MODEL, angle_error_deg, edges_and_currents
from hil.experiments.robustness import NOMINAL_Q0 as NOMINAL_Q
from hil.predictors import FilterSettings, KalmanPredictor, PrecalibrationPredictor, SageHusaPredictor
from hil.predictors import filters as F
from bldc.units import rpm_to_rad_per_s
from plant_models.kinematic import OperatingPoint


def test_prediction_follows_eq7_at_constant_speed_without_noise():
    e, cur = edges_and_currents([OperatingPoint(0.3, 6000.0)], 0.0, 0.0, 1.0, 0)
    for predictor in (
        SageHusaPredictor(MODEL),
        KalmanPredictor(MODEL, FilterSettings(r0_diag=(1e-8, 0.02))),
        PrecalibrationPredictor(),
    ):
        err = angle_error_deg(e, predictor.run(e.t_conditioned_s, cur).pred_t_s)
        assert np.max(np.abs(err)) < 0.01, type(predictor).__name__


def test_filters_beat_the_last_edge_under_jitter():
    """Angle filtering: a Kalman filter averages edge jitter the pre-calibration predictor passes on."""
    e, cur = edges_and_currents([OperatingPoint(1.0, 8000.0)], 3e-6, 0.0, 1.0, 1)
    pre = np.sqrt(np.mean(angle_error_deg(e, PrecalibrationPredictor().run(e.t_conditioned_s, cur).pred_t_s) ** 2))
    kf = np.sqrt(
        np.mean(
            angle_error_deg(
                e,
                KalmanPredictor(MODEL, FilterSettings(q0_diag=(0.01, 1e-9, 1e-6), r0_diag=(2.5e-5, 1.0)))
                .run(e.t_conditioned_s, cur)
                .pred_t_s,
            )
            ** 2
        )
    )
    sh = np.sqrt(
        np.mean(
            angle_error_deg(
                e,
                SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q, adapt_mask=7))
                .run(e.t_conditioned_s, cur)
                .pred_t_s,
            )
            ** 2
        )
    )
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


def test_warm_up_leaves_p_consistent_with_the_first_r():
    """Drawn condition that diverged (7 deg_e RMS against the KF's 0.37): the warm-up ran on the
    paper's R0 = 0, so the speed estimate was the last two edges' difference (35 rad/s off) while
    P claimed it known to 0.04 rad/s; when R got its first estimate the gain on the speed fell to
    1e-6 and every later edge was gated. P is now re-based on that first R (``filters._rebase_p``:
    the covariance of a two-edge estimate), and the filter converges without any guard."""
    e, cur = edges_and_currents([OperatingPoint(0.4, 11825.9)], 3.98e-6, 0.177, 0.514, 688)
    q0 = tuple(q * 10**-1.788 for q in NOMINAL_Q)
    kf = KalmanPredictor(MODEL, FilterSettings(q0_diag=q0, r0_diag=(1e-5, 1.0))).run(e.t_conditioned_s, cur)
    kf_rms = np.sqrt(np.mean(angle_error_deg(e, kf.pred_t_s) ** 2))
    for match_horizon_s in (0.0, 1000.0):  # with and without the variance match (it hid the lock)
        sh = SageHusaPredictor(
            MODEL, FilterSettings(q0_diag=q0, adapt_mask=SH_ADAPT, r_match_horizon_s=match_horizon_s)
        )
        run = sh.run(e.t_conditioned_s, cur)
        rms = np.sqrt(np.mean(angle_error_deg(e, run.pred_t_s) ** 2))
        # measured 0.25 against the KF's 0.37 (1.37 with the variance match, 7 without, before)
        assert rms < kf_rms and run.guards["divergence"] == 0, (match_horizon_s, rms, kf_rms, run.guards)


def _knocked_case(knock: float):
    """A converged filter whose speed estimate is knocked off by ``knock`` (a glitch in firmware
    memory, a missed edge): with Q0 at 1/60 nominal P is small, the gain on the speed tiny, and
    every later edge is gated. Angle RMS from the knock on, for no fade and the default run."""
    e, cur = edges_and_currents([OperatingPoint(1.0, 11825.9)], 3.98e-6, 0.177, 0.514, 688)
    q0 = tuple(q * 10**-1.788 for q in NOMINAL_Q)
    knock_at = 400

    def rms(f):
        pred = np.full(len(e), np.nan)
        for k, (t, c) in enumerate(zip(e.t_conditioned_s, cur)):
            if k == knock_at:
                f.state[F.ST.X] *= 1.0 + knock
            p = f.update(float(t), float(c))
            pred[k] = np.nan if p is None else p
        return float(np.sqrt(np.mean(angle_error_deg(e, pred, skip=knock_at) ** 2)))

    kf_rms = rms(KalmanPredictor(MODEL, FilterSettings(q0_diag=q0, r0_diag=(1e-5, 1.0))))
    out = {}
    for run_length in (0, FilterSettings().divergence_run):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=q0, **{**compare.SH_DESIGN, "divergence_run": run_length}))
        out[run_length] = rms(sh)
        assert (sh.guards["divergence"] > 0) == (run_length > 0), sh.guards
    return out, kf_rms


@pytest.mark.parametrize("knock", [0.01, 0.03, 0.1])
def test_divergence_guard_brings_a_locked_filter_back_to_the_kf(knock):
    rms, kf_rms = _knocked_case(knock)
    # the failure the fade exists for: locked. Without the fade only the lost-lock restart acts
    # (filters.lost_lock: each time the state is a sector off), measured 8.5 / 4.7 / 2.7 deg e
    # against the KF's 0.43 / 0.45 / 0.62 (above 20x the KF before that restart existed)
    assert rms[0] > 4 * kf_rms, (rms, kf_rms)
    # measured 0.31 / 0.35 / 0.65 against the KF's 0.43 / 0.45 / 0.62 deg e
    assert rms[FilterSettings().divergence_run] < 1.5 * kf_rms, (rms, kf_rms)


@pytest.mark.parametrize("end_rpm, q_log10", [(9000.0, -2), (None, 2)])
def test_whiteness_option_steers_q_where_the_eq12_recursion_does_not(end_rpm, q_log10):
    """Q_w barely moves a one-step innovation (dt^2 Q_w << R), so the Eq. 12 recursion drifts
    to its band edge; lag-1 innovation whiteness does see a lagging or noise-chasing gain."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 6000.0, end_speed_rpm=end_rpm)], 3e-6, 0.0, 1.0, 7)
    q0 = tuple(q * 10**q_log10 for q in NOMINAL_Q)
    rms, q_w = {}, {}
    for mask in (SH_ADAPT, F.ADAPT_Q_WHITE | F.ADAPT_R):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=q0, adapt_mask=mask, q_band_factor=1e4))
        rms[mask] = np.sqrt(np.mean(angle_error_deg(e, sh.run(e.t_conditioned_s, cur).pred_t_s) ** 2))
        q_w[mask] = sh.q_matrix[0, 0]
    white = F.ADAPT_Q_WHITE | F.ADAPT_R
    assert rms[white] < rms[SH_ADAPT], rms
    assert 1e-4 < q_w[white] < 0.1, q_w


def test_guards_fire_and_are_visible_when_q_starts_100x_too_large():
    """docs/sage-husa.md, What adapts, and the guards: the textbook update loses positive definiteness from Q0 x 100."""
    e, cur = edges_and_currents([OperatingPoint(1.0, 7000.0)], 2e-6, 0.0, 1.0, 3)
    sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=tuple(100 * q for q in NOMINAL_Q)))
    run = sh.run(e.t_conditioned_s, cur)
    assert sum(run.guards.values()) > 0
    assert set(run.guards) == {"innovation_gate", "q_not_pd", "q_band", "r_not_pd", "p_not_pd", "divergence",
                               "lost_lock"}
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


# --- layout, cross-check against filterpy, the repairs of issue 14 --------------------------------


def test_state_layout_is_generated_from_one_table():
    at = 0
    for name, size, _ in F.STATE_TABLE:
        assert getattr(F.ST, name) == at, name
        at += size
    assert F.ST.SIZE == F.N_STATE == at
    assert [getattr(F.FP, name) for name, _ in F.PARAM_TABLE] == list(
        range(len(F.PARAM_TABLE))
    ) and F.FP.SIZE == F.N_FPARAMS


def test_fixed_noise_step_equals_filterpy_step_by_step():
    """Eq. 9 predict and Eq. 11 update (Joseph form) with adaptation and gate off, against
    filterpy 2's KalmanFilter on the same model, edges and currents: every state and covariance
    entry to 1e-12 relative, after every step. A sign flipped in the Joseph form fails it."""
    from filterpy.kalman import KalmanFilter

    e, cur = edges_and_currents([OperatingPoint(0.15, 6000.0, end_speed_rpm=7000.0)], 3e-6, 0.0, 1.0, 11)
    settings = FilterSettings(
        q0_diag=(0.01, 1e-9, 1e-4), r0_diag=(2e-5, 0.5), p0_diag=(50.0, 1e-3, 1.0), gate_state_update=False
    )
    ours = KalmanPredictor(MODEL, settings)
    kf = KalmanFilter(dim_x=3, dim_z=2)
    kf.Q, kf.R = np.diag(settings.q0_diag), np.diag(settings.r0_diag)
    kf.H = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    t = e.t_conditioned_s
    ours.update(t[0], cur[0])
    ours.update(t[1], cur[1])  # initialises speed and current from the first cycle
    kf.x = ours.state[F.ST.X : F.ST.X + 3].copy()
    kf.P = np.diag(settings.p0_diag)
    np.testing.assert_array_equal(ours.p_matrix, kf.P)
    for k in range(2, len(t)):
        w = float(kf.x[0])
        a, dl = F.coefficients(w, ours.fp, ours.tables)
        dt = t[k] - t[k - 1]
        kf.F = np.array([[1.0, 0.0, a * dt], [dt, 1.0, 0.5 * a * dt * dt], [0.0, 0.0, 1.0]])  # Eq. 9
        kf.predict()
        kf.x = kf.x + np.array([-dt * dl, -0.5 * dt * dt * dl, 0.0])  # input of Eq. 9
        kf.update(np.array([math.pi / 3.0, cur[k]]))
        kf.x[1] -= math.pi / 3.0  # the edge just measured is the new angle zero
        ours.update(t[k], cur[k])
        np.testing.assert_allclose(
            ours.state[F.ST.X : F.ST.X + 3],
            kf.x,
            rtol=1e-12,
            atol=1e-12 * np.max(np.abs(kf.x)),
            err_msg=f"x at step {k}",
        )
        np.testing.assert_allclose(
            ours.p_matrix, kf.P, rtol=1e-12, atol=1e-12 * np.max(np.abs(kf.P)), err_msg=f"P at step {k}"
        )


def _burst_edges(seed=5):
    """8000 rpm for 2 s with 3 us jitter, and 30 us of edge-time noise from 1.0 to 1.4 s."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 8000.0)], 3e-6, 0.0, 1.0, seed)
    t = e.t_conditioned_s.copy()
    burst = (t > 1.0) & (t < 1.4)
    t[burst] += 30e-6 * np.random.default_rng(seed).standard_normal(int(burst.sum()))
    return e, t, cur, burst


def test_gated_edges_still_teach_r_with_a_huber_weight():
    """A burst of edge noise is gated (the state keeps its prediction), yet R must learn it: R is
    adapted from every innovation with a Huber weight. When gated edges skipped the R update, R
    never saw the burst and the whole burst was gated."""
    e, t, cur, burst = _burst_edges()
    # the divergence fade off: the test isolates how R learns a burst
    sh = SageHusaPredictor(
        MODEL,
        FilterSettings(q0_diag=NOMINAL_Q, adapt_mask=SH_ADAPT, r_interval=30, r_forgetting_b=0.7, divergence_run=0),
    )
    r_theta = []
    for tk, ck in zip(t, cur):
        sh.update(tk, ck)
        r_theta.append(sh.r_matrix[0, 0])
    r_theta = np.array(r_theta)
    quiet = r_theta[np.nonzero(burst)[0][0] - 1]
    in_burst = r_theta[np.nonzero(burst)[0][-1]]
    true_ratio = (30.0 / 3.0) ** 2
    assert in_burst > 0.3 * true_ratio * quiet, (quiet, in_burst)
    assert sh.guards["innovation_gate"] < 0.3 * burst.sum(), sh.guards  # the gate let the burst in once R knew it
    # the state does not take a gated edge: its NIS was beyond the gate and x stayed at the prediction
    g = SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q, adapt_mask=SH_ADAPT))
    g.run(t[:400], cur[:400])
    s, x_pred = g.state.copy(), None
    a, dl = F.coefficients(s[F.ST.X], g.fp, g.tables)
    before = g.guard_counts[F.GUARD_GATE]
    dt = t[400] - t[399] + 200e-6  # a wild edge
    F.step(g.state, g.fp, g.guard_counts, math.pi / 3.0, cur[400], dt, a, dl, np.empty(F.N_WORK))
    assert g.guard_counts[F.GUARD_GATE] == before + 1
    x_pred = s[F.ST.X] - dt * dl + a * dt * s[F.ST.X + 2]
    assert g.state[F.ST.X] == pytest.approx(x_pred, rel=1e-12)


def test_r_has_its_own_forgetting_factor_and_interval():
    e, t, cur, _ = _burst_edges()
    runs = {}
    for r_interval, r_b in ((30, 0.7), (120, 0.7), (30, 0.98)):
        sh = SageHusaPredictor(
            MODEL,
            FilterSettings(
                q0_diag=NOMINAL_Q,
                adapt_mask=SH_ADAPT,
                forgetting_b=0.98,
                adapt_interval=120,
                r_interval=r_interval,
                r_forgetting_b=r_b,
                cusum_h=0.0,  # the change detector restarts the interval at a burst's edges
            ),
        )
        sh.run(t, cur)
        runs[(r_interval, r_b)] = (int(sh.state[F.ST.K_INTERVAL_R]), sh.r_matrix[0, 0], sh.q_matrix[0, 0])
    steps = len(t) - 2
    assert runs[(30, 0.7)][0] == 1 + (steps - 120) // 30  # R every 30 edges after the warm-up
    assert runs[(120, 0.7)][0] == 1 + (steps - 120) // 120
    assert runs[(30, 0.7)][1] != runs[(30, 0.98)][1]  # b_R acts on R
    assert runs[(30, 0.7)][1] != runs[(120, 0.7)][1]


def test_divergence_run_makes_a_chance_trigger_rarer_than_once_per_1000_s():
    """A one-signed run of n gated edges starts on an edge with p (p / 2)^(n - 1), p the
    probability of a gated edge. With consistent innovations p = exp(-gate / 2) = 1e-3 and n = 3
    would do; inside a burst of edge noise R has not learned, every edge is gated (p = 1) and only
    the sign test is left: at 12,000 rpm with 2 pole pairs (2400 edges/s), 2.4e6 / 2^(n - 1) < 1
    needs n = 23 (n = 22 gives 1.1 chance triggers per 1000 s)."""
    p = math.exp(-F.CHI2_2DOF_999 / 2)
    assert p == pytest.approx(1e-3)
    rate = 12000 / 60 * 6 * MODEL.pole_pairs
    assert rate == F.MAX_EDGE_RATE_HZ
    assert rate * 1000 * p * (p / 2) >= 1.0 > rate * 1000 * p * (p / 2) ** 2
    assert F.divergence_run_for(F.CHI2_2DOF_999, rate) == 3
    assert rate * 1000 * 0.5**21 >= 1.0 > rate * 1000 * 0.5**22
    assert F.divergence_run_for(F.CHI2_2DOF_999, rate) == FilterSettings().divergence_run
    assert F.divergence_run_for(F.CHI2_2DOF_999, rate, p_gated=1.0) == 23 == compare.BURSTS_SH["divergence_run"]
    # the formula against a Monte-Carlo draw of consistent Gaussian innovations at a looser gate
    rng = np.random.default_rng(3)
    gate = 4.0
    nis = rng.chisquare(2, 2_000_000)
    sign = rng.random(nis.size) < 0.5
    gated = nis > gate
    starts = gated[1:] & gated[:-1] & (sign[1:] == sign[:-1])
    expected = math.exp(-gate / 2) * (math.exp(-gate / 2) / 2)
    assert starts.mean() == pytest.approx(expected, rel=0.05)


def test_divergence_fade_does_not_fire_inside_a_burst_of_edge_noise():
    """Inside a burst R has not learned yet, most edges are gated and their signs are random: a
    run of 3 (the bound for consistent innovations) fired there by chance and took burst edges
    at full gain; the bursts protocol's run (23, derived for p_gated = 1) does not. The variance match
    and the change detector are off: the test isolates the fade while R is still learning the burst."""
    e, t, cur, burst = _burst_edges()
    fades = {}
    for run_length in (3, compare.BURSTS_SH["divergence_run"]):
        sh = SageHusaPredictor(
            MODEL,
            FilterSettings(
                q0_diag=NOMINAL_Q,
                **{**compare.BURSTS_SH, "divergence_run": run_length, "r_match_horizon_s": 0.0, "cusum_h": 0.0},
            ),
        )
        fades[run_length] = sh.run(t, cur).guards["divergence"]
    assert fades[3] > 0 and fades[23] == 0, fades


def test_variance_match_bounds_hold_chance_crossings_below_once_per_1000_s():
    """The edge noise of an R interval is measured from second differences of white edge noise,
    n_k - 2 n_k-1 + n_k-2 (variance 6 sigma^2, correlated over two lags): their sample variance
    is close to chi-square with (n - 1) / 1.944 dof. Each bound may be crossed with probability
    interval / (2 x 2400 edges/s x 1000 s) per interval; a Monte-Carlo draw checks the
    approximation at a looser horizon, where crossings are frequent enough to count."""
    hi, lo = F.variance_match_bounds(30)
    assert lo < 1.0 < hi
    rng = np.random.default_rng(11)
    noise = rng.standard_normal((400_000, 32))
    x2 = noise[:, 2:] - 2 * noise[:, 1:-1] + noise[:, :-2]
    ratio = x2.var(axis=1, ddof=1) / 6.0
    alpha = 0.5 * 30 / (F.MAX_EDGE_RATE_HZ * 1000.0)
    assert np.mean(ratio > hi) < 5 * alpha and np.mean(ratio < lo) < 5 * alpha
    hi1, lo1 = F.variance_match_bounds(30, horizon_s=0.1)
    alpha1 = 0.5 * 30 / (F.MAX_EDGE_RATE_HZ * 0.1)
    assert np.mean(ratio > hi1) == pytest.approx(alpha1, rel=0.3) and np.mean(ratio < lo1) == pytest.approx(
        alpha1, rel=0.3
    )
    # treating the second differences as independent (n - 1 dof) would put the bounds too close
    from scipy.stats import chi2

    assert np.mean(ratio > chi2.isf(alpha1, 29) / 29) > 2 * alpha1


def test_variance_match_follows_a_burst_in_and_out_within_two_r_intervals():
    """The Eq. 12 recursion blends a burst into R over 1 / d_j intervals with each edge capped by
    the Huber weight: R_theta reached a fraction of the burst variance only after the burst had
    half passed, and stayed high long after it. The variance match replaces R_theta as soon as an
    interval's innovations are inconsistent with it."""
    e, t, cur, burst = _burst_edges()
    first, last = np.nonzero(burst)[0][[0, -1]]
    w = 8000 / 60 * 2 * math.pi * MODEL.pole_pairs
    burst_var = (30e-6 * w) ** 2
    r = {}
    for horizon in (0.0, 1000.0):
        sh = SageHusaPredictor(
            MODEL,
            FilterSettings(q0_diag=NOMINAL_Q, **{**compare.BURSTS_SH, "r_match_horizon_s": horizon, "cusum_h": 0.0}),
        )
        r_theta = []
        for tk, ck in zip(t, cur):
            sh.update(tk, ck)
            r_theta.append(sh.r_matrix[0, 0])
        r[horizon] = np.array(r_theta)
    quiet = r[1000.0][first - 1]
    for horizon, ok in ((1000.0, True), (0.0, False)):
        into = r[horizon][first + 2 * 30 + 1] > 0.3 * burst_var
        out = r[horizon][last + 2 * 30 + 1] < 3 * quiet
        assert (into and out) == ok, (horizon, r[horizon][first + 61] / burst_var, r[horizon][last + 61] / quiet)


def test_change_detector_follows_a_burst_within_a_few_edges():
    """Page's CUSUM on the edges' own noise measure sets R_theta within a few edges of a burst's
    onset and end; the interval's variance match alone waits for the end of its R interval."""
    e, t, cur, burst = _burst_edges()
    first, last = np.nonzero(burst)[0][[0, -1]]
    w = 8000 / 60 * 2 * math.pi * MODEL.pole_pairs
    burst_var = (30e-6 * w) ** 2
    lag = {}
    for h in (0.0, F.CUSUM_H_1000S):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=NOMINAL_Q, **{**compare.BURSTS_SH, "cusum_h": h}))
        r_theta = []
        for tk, ck in zip(t, cur):
            sh.update(tk, ck)
            r_theta.append(sh.r_matrix[0, 0])
        r_theta = np.array(r_theta)
        quiet = r_theta[first - 1]
        into = np.nonzero(r_theta[first:] > 0.3 * burst_var)[0]
        out = np.nonzero(r_theta[last + 1:] < 3 * quiet)[0]
        lag[h] = (int(into[0]) if into.size else None, int(out[0]) if out.size else None)
    # measured: 14 and 23 edges with the detector, 21 and 40 without (the R interval is 30 edges)
    assert lag[F.CUSUM_H_1000S][0] <= 16 and lag[F.CUSUM_H_1000S][1] <= 25, lag
    assert lag[0.0][0] > 16 and lag[0.0][1] > 25, lag


def test_change_detector_chance_alarms_rarer_than_once_per_1000_s():
    """White Gaussian edge noise at the top edge rate (2400 edges/s): fewer than one chance
    alarm per 1000 s, i.e. at most 10 in 2.4e7 edges (measured 7 at the default threshold; the
    filter's own detector runs on the second differences, correlated over two lags)."""
    from numba import njit

    @njit(cache=False)
    def alarms(n, h, seed):
        np.random.seed(seed)
        s = np.zeros(F.N_STATE)
        fp = np.zeros(F.N_FPARAMS)
        fp[F.FP.CUSUM_H] = h
        a, b, count = np.random.standard_normal(), np.random.standard_normal(), 0
        for _ in range(n):
            s[F.ST.R] = 1.0
            c = np.random.standard_normal()
            if F._change_detect(s, fp, c - 2.0 * b + a):
                count += 1
            a, b = b, c
        return count

    n = 24_000_000
    assert alarms(n, F.CUSUM_H_1000S, 7) <= 10
    assert alarms(n, 20.0, 7) > 10  # the test can fail: a lower threshold alarms by chance


def test_q_current_option_adapts_q_i_and_leaves_q_w_at_nominal():
    """dt^2 Q_w is about 1/200 of R_theta, so a one-step innovation says almost nothing about Q_w:
    on edges whose speed model is exact (the current makes the equation of motion true, no
    process noise at all) the Eq. 12 recursion still moves Q_w by a factor of 5 (to 1/5 with the
    variance match on, to 10x without). With ADAPT_Q_CURRENT only Q_i adapts."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 6000.0)], 3e-6, 0.0, 1.0, 7)
    q0 = (1e-4, 1e-9, 0.1)
    q = {}
    for mask in (SH_ADAPT, F.ADAPT_R | F.ADAPT_Q_CURRENT):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=q0, adapt_mask=mask))
        sh.run(e.t_conditioned_s, cur)
        q[mask] = (sh.q_matrix[0, 0], sh.q_matrix[2, 2])
    assert not q0[0] / 4 < q[SH_ADAPT][0] < 4 * q0[0], q  # Eq. 12 on Q_w: drifts
    assert q[F.ADAPT_R | F.ADAPT_Q_CURRENT][0] == q0[0], q
    assert q[F.ADAPT_R | F.ADAPT_Q_CURRENT][1] < 0.1 * q0[2], q  # Q_i learns the exact current



def test_r_current_floor_option_keeps_r_i_at_or_above_r0_and_still_learns_r_theta():
    """With ADAPT_R_CURRENT_FLOOR, R's current entry never falls below its R0 (it stands for the
    acceleration input's error too, not only the sensor's noise, which is all Eq. 12 sees), while
    R_theta is still learned from the edges: the variance of 3 us of jitter at 6000 rpm (rad^2)."""
    e, cur = edges_and_currents([OperatingPoint(2.0, 6000.0)], 3e-6, 0.0, 1.0, 7)
    r0 = (0.0, 1.6)
    r = {}
    for mask in (F.ADAPT_Q | F.ADAPT_R, F.ADAPT_Q | F.ADAPT_R | F.ADAPT_R_CURRENT_FLOOR):
        sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=(1e-5, 1e-9, 1e-3), r0_diag=r0, adapt_mask=mask))
        sh.run(e.t_conditioned_s, cur)
        r[mask] = (sh.r_matrix[0, 0], sh.r_matrix[1, 1])
    injected_rad2 = (3e-6 * rpm_to_rad_per_s(6000.0) * MODEL.pole_pairs) ** 2
    held = r[F.ADAPT_Q | F.ADAPT_R | F.ADAPT_R_CURRENT_FLOOR]
    assert held[1] >= r0[1], r
    assert r[F.ADAPT_Q | F.ADAPT_R][1] < 0.5 * r0[1], r  # without the option Eq. 12 lowers it
    assert 0.5 * injected_rad2 < held[0] < 2.0 * injected_rad2, (held, injected_rad2)


def test_a_negative_r_i_estimate_is_a_repair_even_under_the_floor():
    """The floor raises R_i after the textbook failure is counted: with Q's current entry 1 A^2
    (a thousand times too large) the Eq. 12 term of R_i, innovation^2 - H P H^T, goes negative,
    and the guards must say so (the controller raises EMCY 0xFF03 on it, REQ-FLT-004) before R_i
    is raised back to its R0."""
    e, cur = edges_and_currents([OperatingPoint(0.4, 6000.0)], 3e-6, 0.0, 1.0, 7)
    mask = F.ADAPT_Q_CURRENT | F.ADAPT_R | F.ADAPT_R_CURRENT_FLOOR
    sh = SageHusaPredictor(MODEL, FilterSettings(q0_diag=(10.0, 1e-7, 1.0), r0_diag=(0.0, 1.8), adapt_mask=mask))
    sh.run(e.t_conditioned_s, cur)
    assert sh.counters["covariance_repairs"] > 0, sh.counters
    assert sh.r_matrix[1, 1] >= 1.8


# --- robustness over drawn conditions ------------------------------------------------------

ROBUSTNESS_CONDITIONS = 1000  # the full draw: about 30 s with the batch path
ROBUSTNESS_SEED = 0


@pytest.fixture(scope="module")
def robustness_results():
    from hil.experiments.robustness import draw_conditions, run_condition

    return [run_condition(c) for c in draw_conditions(ROBUSTNESS_CONDITIONS, ROBUSTNESS_SEED)]


def _worst(results, n=8):
    return "\n".join(
        f"  SH {r['sh']:.3f} vs KF {r['kf']:.3f} deg_e: jitter {r['jitter_s'] * 1e6:.2f} us, Q0 "
        f"x10^{r['q_factor_log10']:.2f}, "
        f"{r['start_rpm']:.0f}->{r['end_rpm'] or r['start_rpm']:.0f} rpm, load x{r['load_scale']:.2f}, seed {r['seed']}"
        for r in sorted(results, key=lambda r: r["sh"] / r["kf"], reverse=True)[:n]
    )


def test_robustness_runs_are_long_enough_and_covariances_stay_positive_definite(robustness_results):
    from hil.experiments.robustness import summarise

    s = summarise(robustness_results)
    assert s["conditions"] >= 1000 and s["min_duration_s"] >= 1.0 and s["min_scored_edges"] >= 500, s
    broken = [r for r in robustness_results if not (r["kf_finite"] and r["sh_finite"] and r["kf_pd"] and r["sh_pd"])]
    assert not broken, f"covariance lost positive definiteness or estimate not finite in: {broken[:3]}"


def test_sage_husa_under_twice_the_kf_in_every_condition(robustness_results):
    """Measured: 100 % (worst 1.39x) of the 1000 drawn conditions; 94.5 % (worst 10.9x) before P
    was re-based on the first R at the end of the warm-up."""
    worse = [r for r in robustness_results if not r["sh"] < 2.0 * r["kf"]]
    assert not worse, (
        f"Sage-Husa at 2x the KF or worse in {len(worse)} of {len(robustness_results)} conditions:\n{_worst(worse)}"
    )


def test_sage_husa_no_worse_than_kf_in_95_percent(robustness_results):
    """Measured: 95.9 % (95.8 % on the draw of seed 1), the issue's bar 95 %; 79.6 % before the
    warm-up's P re-base, Q adapting only once the gate acts, Q_w steered by innovation
    whiteness instead of the Eq. 12 recursion and R kept diagonal (docs/sage-husa.md,
    Robustness)."""
    ok = [r["sh"] <= 1.05 * r["kf"] + 0.01 for r in robustness_results]
    rate = float(np.mean(ok))
    assert rate >= 0.95, (
        f"Sage-Husa within 5 % + 0.01 deg e of the KF in only {rate:.1%}; worst:\n{_worst(robustness_results)}"
    )


# --- the paper scenario (Table 5) -------------------------------------------------------------


@pytest.fixture(scope="module")
def scenario_run():
    from hil.experiments.table5 import run_scenario

    return run_scenario(seed=0)


def test_the_oracle_is_the_kf_with_its_r_theta_following_the_true_speed(scenario_run):
    """The oracle row (published beside the tuned protocols, compare.Oracle) is the fixed-Q KF with
    R_theta(k) = r_theta (w_k / W_REF)^2: with r_theta about 0 it predicts as the KF with R_theta 0
    does, and with a real r_theta it does not predict as the KF with that R_theta held constant
    (the profile runs 5000-10,000 rpm, W_REF 7500)."""
    from hil.experiments.table5 import score

    run = scenario_run

    def kf_rms(r_theta):
        kf = KalmanPredictor(MODEL, FilterSettings(q0_diag=(1e3, 1e-9, 1e-2), r0_diag=(r_theta, 1e-2),
                                                   gate_state_update=False))
        r = kf.run(run.t_corrected_s, run.mean_current_a)
        return score(run, "kf", r.pred_t_s, r.speed_rad_s).angle_rms_deg_e

    def oracle_rms(r_theta):
        return compare.Oracle((1e3, 1e-2, r_theta, 1e-2)).row(run, MODEL, None, 0.0).angle_rms_deg_e

    assert oracle_rms(1e-30) == pytest.approx(kf_rms(1e-30), rel=1e-9)
    assert abs(oracle_rms(1e-4) - kf_rms(1e-4)) > 1e-3 * kf_rms(1e-4)


@pytest.fixture(scope="module")
def tuned():
    # the oracle's headroom row is a reference this test judges nothing on (the figures publish it)
    return compare.run_protocol("tuned", eval_seeds=(0, 3, 4), oracle=False)


def test_tuned_protocol_scored_against_ground_truth(tuned):
    assert set(tuned.rows) == {"sage_husa", "kf", "precal"} and len(tuned.rows["kf"]) == 3
    m = {name: tuned.metrics(name) for name in tuned.rows}
    # both filters average the edge jitter the pre-calibration predictor passes on: a tenth of
    # a degree electrical is the budget a commutation predictor should meet on this bench
    for name in ("kf", "sage_husa"):
        assert m[name]["angle_rms_deg_e"] < 0.1, tuned.format()
        assert m[name]["angle_rms_deg_e"] < 0.2 * m["precal"]["angle_rms_deg_e"], tuned.format()
    # judged: tuned alike, Sage-Husa no worse than -5 % on angle RMS and commutation-time MAPE
    imp = tuned.improvement_pct()
    assert imp["angle_rms_deg_e"] >= -5.0 and imp["commutation_time_mape_pct"] >= -5.0, tuned.format()
    assert all(len(line) <= 100 for line in tuned.format().splitlines()), tuned.format()


def test_scenario_corrects_edges_with_the_current_at_the_edge(scenario_run):
    """The armature correction must use the current the calibration was fitted against: the
    ADC's mean |i| at the capture. With the commutation cycle's mean instead (30 % larger on
    this bench) every corrected edge carried a common bias of about -0.55 deg e at 5 A, which no
    predictor can see (a common offset does not change the edge intervals)."""
    run = scenario_run
    w = run.true_speed_rad_s
    error_deg = np.degrees((run.t_corrected_s - run.edges.t_ideal_s) * w)[300:]
    assert abs(float(np.mean(error_deg))) < 0.05, f"corrected edges biased by {np.mean(error_deg):.3f} deg_e"
    # and the bias does not grow with current either
    slope = np.polyfit(run.mean_current_a[300:], error_deg, 1)[0]
    assert abs(slope) < 0.02, f"corrected-edge error moves {slope:.3f} deg_e per ampere"


def test_table5_cli_writes_exactly_the_documented_json_keys(tmp_path, capsys):
    from hil.cli import main

    out = tmp_path / "paper.json"
    assert main(["paper", "table5", "--protocol", "paper", "--seeds", "0", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert all(len(line) <= 100 for line in printed.splitlines()), printed
    assert "mean signed error" in printed and "constant-stage edges" in printed and "Q0 x100" in printed
    data = json.loads(out.read_text())
    assert set(data) == {"protocol", "seeds_evaluated", "metrics", "improvement_pct", "sh_wins_fraction"}
    assert data["protocol"] == "paper" and data["seeds_evaluated"] == [0]
    assert set(data["metrics"]) == {"sage_husa", "kf", "precal"}
    keys = {
        "speed_mape_regulation_pct",
        "max_overshoot_pct",
        "speed_mape_constant_pct",
        "commutation_time_mape_pct",
        "angle_rms_deg_e",
    }
    for block in (*data["metrics"].values(), data["improvement_pct"], data["sh_wins_fraction"]):
        assert set(block) == keys
    m = data["metrics"]
    assert data["improvement_pct"]["angle_rms_deg_e"] == pytest.approx(
        100 * (m["kf"]["angle_rms_deg_e"] - m["sage_husa"]["angle_rms_deg_e"]) / m["kf"]["angle_rms_deg_e"]
    )


def test_equation_table_points_at_the_code():
    """docs/sage-husa.md maps Eq. 7-12 to a function and a line; each named line holds the text."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    rows = re.findall(
        r"^\| (\d+) \|[^|]*\| `(\w+)` \| `([\w/.]+):(\d+)` \| `([^`]+)` \|$",
        (root / "docs/sage-husa.md").read_text(),
        re.M,
    )
    assert {int(r[0]) for r in rows} == {7, 8, 9, 10, 11, 12}, rows
    for eq, function, path, line, text in rows:
        lines = (root / path).read_text().splitlines()
        assert text in lines[int(line) - 1], f"Eq. {eq}: {path}:{line} does not say {text!r}: {lines[int(line) - 1]!r}"
        above = [ln for ln in lines[: int(line)] if ln.startswith("def ")]
        assert above and above[-1].startswith(f"def {function}("), f"Eq. {eq}: {path}:{line} is not in {function}"


def test_r_stays_diagonal_under_bursts(scenario_run):
    """Edge instants and current come from different sensors: R is diagonal. Its Eq. 12 cross
    term (the innovations' cross-correlation, which the state's errors make) is not estimated."""
    from hil.experiments.identify import identify
    from hil.experiments.table5 import Bursts

    run, _ = Bursts().apply(scenario_run, 0)
    settings = {**compare.BURSTS_SH, "q0_diag": (8.28e-05, 1e-09, 4.14), "forgetting_b": 0.9991, "r_forgetting_b": 0.05}
    sh = SageHusaPredictor(identify(run.config, seed=1).model, FilterSettings(**settings))
    sh.run(run.t_corrected_s, run.mean_current_a)
    assert sh.r_matrix[0, 1] == sh.r_matrix[1, 0] == 0.0 and sh.r_matrix[0, 0] > 0.0, sh.r_matrix
