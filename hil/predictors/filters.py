"""Sage-Husa adaptive Kalman filter (paper Eq. 11-12) and the fixed-noise Kalman baseline.

One numba step function serves both: with adaptation off it is the plain Kalman filter (Eq. 11
with fixed Q, R). The filter state lives in one flat float64 array whose named layout is
generated from ``STATE_TABLE`` (``ST.P`` is the offset of P, and so on), so the same code runs
online (one call per commutation) and in batch (a whole edge sequence in one call), and each
update line reads like its equation.

Guards (design of the filter: docs/sage-husa.md), each counted in ``guards``:
  GUARD_GATE        innovation beyond the chi-square gate: the state keeps its prediction (the
                    edge still teaches R, with a Huber weight);
  GUARD_Q_PD        the unclamped Eq. 12 Q recursion was not positive (the filter uses the band);
  GUARD_Q_BAND      a diagonal of Q was projected onto its band around nominal (band_factor);
  GUARD_R_PD        the R estimate was not positive definite: eigenvalues floored (a repair);
  GUARD_P_PD        P lost positive definiteness after the Joseph update: eigenvalues floored;
  GUARD_DIVERGENCE  innovations beyond the gate and of one sign on ``divergence_run``
                    consecutive cycles: the state, not the edge, is wrong; P is faded by NIS / 2;
  GUARD_LOST_LOCK   the state lost count of the sectors (``lost_lock``: speed not positive, or
                    an angle innovation beyond a sector): it is restarted from the last interval.
                    This check does not depend on the gate, which a tuned KF may have off.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

#: the filter state, in order: (name, size, meaning); offsets are generated from this table
STATE_TABLE = (
    ("X", 3, "state estimate [w (rad/s), theta (rad, from the last corrected edge), I (A)]"),
    ("P", 9, "state covariance, row-major"),
    ("Q", 9, "process-noise covariance in use (Eq. 12 projected onto its band)"),
    ("R", 4, "measurement-noise covariance [angle, current], row-major"),
    ("Q_NOMINAL", 9, "nominal Q0, centre of the band"),
    ("SMALL_Q", 3, "process-noise mean q (Eq. 12)"),
    ("SMALL_R", 2, "measurement-noise mean r (Eq. 12)"),
    ("ACC_SMALL_R", 2, "r interval accumulator: sum of Z - H X_k,k-1"),
    ("ACC_SMALL_Q", 3, "q interval accumulator: sum of X_k - Phi X_k-1"),
    ("N_ACC", 1, "cycles in the r, q interval"),
    ("K_INTERVAL", 1, "r, q intervals completed (j of d_j)"),
    ("ACC_R", 2, "R interval accumulator, diagonal: sum of Huber-weighted Z~^2 / kappa - H P H^T"),
    ("ACC_R_MEAN", 2, "R interval accumulator: sum of sqrt(weight) Z~ (the innovations' mean is taken out)"),
    ("N_ACC_R", 1, "cycles in the R interval"),
    ("K_INTERVAL_R", 1, "R intervals completed"),
    ("Q_RAW", 2, "unclamped Eq. 12 recursion of Q_w and Q_i"),
    ("K_STEP", 1, "filter steps taken"),
    ("INITIALISED", 1, "1 once the first cycle set speed and current"),
    ("LAST_NIS", 1, "normalised innovation squared of the last step"),
    ("GATED_RUN", 1, "signed count of consecutive gated innovations of one sign"),
    ("DT_PREV", 1, "last cycle duration (s), edge-noise analysis"),
    ("ACC_Z0", 3, "R interval, angle channel, unweighted: sum of Z~, sum of Z~^2, sum of H P_k,k-1 H^T"),
    ("ACC_EDGE", 3, "edge-noise analysis over the R interval: n, sum, sum of squares"),
    ("EDGE_STATS", 3, "warm-up edge-noise analysis: n, sum, sum of squares"),
    ("PREV_INNOV", 1, "last angle innovation (whiteness option)"),
    ("ACC_WHITE", 2, "whiteness option: sum of lag-1 products, sum of squares"),
    ("COEF", 2, "Eq. 8 coefficients at the present speed estimate (the next step's, too)"),
    ("CUSUM", 6, "edge-noise change detector, up and down: statistic, sum of x2^2 / 6, count since it left 0"),
    ("CHANGED", 2, "after a detected change, until the R interval ends: sum of x2^2 / 6 and count since the change"),
)
#: the parameter vector, in order: (name, meaning)
PARAM_TABLE = (
    ("B", "Q forgetting factor b (Eq. 12, d_k per step)"),
    ("INTERVAL", "r and q adaptation interval (cycles)"),
    ("WARMUP", "cycles before Q adapts and the gate acts"),
    ("GATE", "chi-square gate on the NIS"),
    ("BAND", "Q band factor around nominal"),
    ("FLOOR", "eigenvalue floor of R"),
    ("ADAPTIVE", "mask of adapted estimates (0 = plain Kalman filter)"),
    ("POLE_PAIRS", "pole pairs"),
    ("J", "inertia (kg m^2)"),
    ("DIVERGENCE_RUN", "one-signed gated run taken as divergence (0 = never)"),
    ("R_B", "R forgetting factor (per R interval)"),
    ("R_INTERVAL", "R adaptation interval (cycles)"),
    ("HUBER_C", "Huber threshold on sqrt(NIS)"),
    ("HUBER_KAPPA", "consistency factor E[w NIS] / 2 of the Huber weight"),
    ("GATE_STATE", "1: a gated innovation leaves the state at its prediction"),
    ("R_I_FLOOR", "floor of the current variance in R (A^2): the current measurement's quantisation, "
                  "or R0's current entry with ADAPT_R_CURRENT_FLOOR"),
    ("R_MATCH_HI", "variance match: interval variance / S of the angle above this replaces R_theta (0 = off)"),
    ("R_MATCH_LO", "variance match: interval variance / S of the angle below this replaces R_theta"),
    ("CUSUM_H", "edge-noise change detector threshold (0 = off)"),
    ("FRICTION", "viscous friction B (N m s/rad): Eq. 8's load is M(n) w_m^2 + B w_m"),
)


def _layout(name: str, table) -> tuple:
    offsets, at = [], 0
    for row in table:
        offsets.append(at)
        at += row[1] if len(row) == 3 else 1
    return namedtuple(name, [row[0] for row in table] + ["SIZE"])(*offsets, at)


ST = _layout("StateLayout", STATE_TABLE)
FP = _layout("ParamLayout", PARAM_TABLE)
N_STATE, N_FPARAMS = ST.SIZE, FP.SIZE

GUARD_GATE, GUARD_Q_PD, GUARD_Q_BAND, GUARD_R_PD, GUARD_P_PD, GUARD_DIVERGENCE, GUARD_LOST_LOCK = range(7)
N_GUARDS = 7
#: which Eq. 12 estimates adapt (FP.ADAPTIVE holds the mask; 0 = plain Kalman filter)
ADAPT_Q, ADAPT_R, ADAPT_SMALL_R, ADAPT_SMALL_Q = 1, 2, 4, 8
ADAPT_ALL = 15
#: option, not the paper's: the speed entry of Q steered by innovation whiteness (Mehra 1970)
#: instead of the Eq. 12 recursion, see docs/sage-husa.md
ADAPT_Q_WHITE = 16
#: option: only the current entry of Q by Eq. 12; Q_w stays at nominal (dt^2 Q_w is about 1/200 of
#: R_theta, so a one-step innovation carries almost nothing about Q_w and its recursion drifts)
ADAPT_Q_CURRENT = 32
#: option: R's current entry never below its R0 (Eq. 12 may raise it, not lower it). The measured
#: current drives the model's acceleration (K_T i), so R_i stands for what that input misses (load
#: and torque-constant error) as much as for the sensor's noise; Eq. 12 learns only the latter from
#: the current's innovations (about 0.04 A^2 against the 1.6 A^2 a KF tuned on the closed loop
#: needs), and a filter that trusts the current that much follows the model's error. R0's current
#: entry is then a stated floor, as the quantisation's is (``FP.R_I_FLOOR``)
ADAPT_R_CURRENT_FLOOR = 64
#: log-step of Q_w per unit of lag-1 innovation correlation, applied once per interval
WHITENESS_GAIN = 4.0
CHI2_2DOF_999 = 13.815510557964274  # 99.9 % quantile, 2 degrees of freedom: P(NIS > gate) = 1e-3
HUBER_C_95 = math.sqrt(-2.0 * math.log(0.05))  # sqrt of the 95 % quantile of chi-square, 2 dof
#: the fastest edges the chance-trigger bounds are stated for: 12,000 rpm, 2 pole pairs, 6 edges
#: per electrical revolution
MAX_EDGE_RATE_HZ = 2400.0


#: sum over lags of the squared autocorrelation of the edge second difference n_k - 2 n_k-1 +
#: n_k-2 of white edge noise: autocovariance (6, -4, 1) sigma^2, so (36 + 2 16 + 2 1) / 36
EDGE_DIFF_RHO2_SUM = 70.0 / 36.0


def variance_match_bounds(
    interval: int, edge_rate_hz: float = MAX_EDGE_RATE_HZ, horizon_s: float = 1000.0
) -> tuple[float, float]:
    """Bounds on the ratio of an R interval's measured edge-noise variance (sample variance of the
    edge second differences / 6) to the R_theta in use, beyond which the edge noise changed.
    For white Gaussian edge noise the sample variance of n second differences is close to
    chi-square with nu = (n - 1) / EDGE_DIFF_RHO2_SUM degrees of freedom (they are correlated
    over two lags; Bartlett's variance of a sample variance, 2 sigma^4 sum(rho^2) / n), and each
    bound is crossed by chance less than once per ``horizon_s`` of edges at ``edge_rate_hz``
    (half the budget on each side)."""
    from scipy.stats import chi2

    dof = (interval - 1) / EDGE_DIFF_RHO2_SUM
    if interval < 3:
        return 0.0, 0.0
    alpha = 0.5 * interval / (edge_rate_hz * horizon_s)
    return float(chi2.isf(alpha, dof)) / dof, float(chi2.ppf(alpha, dof)) / dof


def huber_kappa(c: float) -> float:
    """E[w(m) m^2] / 2 for m^2 ~ chi-square(2) and the Huber weight w = min(1, c / m): the factor
    that makes the weighted outer product Z~ Z~^T an unbiased estimate of S = H P H^T + R when
    the innovations are Gaussian. With the Rayleigh density of m:
    E = int_0^c m^3 e^(-m^2/2) dm + c int_c^inf m^2 e^(-m^2/2) dm
      = 2 - 2 e^(-c^2/2) + c sqrt(2 pi) (1 - Phi(c))."""
    if not c > 0:
        return 1.0
    tail = 0.5 * math.erfc(c / math.sqrt(2.0))
    return (2.0 - 2.0 * math.exp(-0.5 * c * c) + c * math.sqrt(2.0 * math.pi) * tail) / 2.0


def divergence_run_for(
    gate: float, edge_rate_hz: float, horizon_s: float = 1000.0, p_gated: float | None = None
) -> int:
    """Shortest run of one-signed gated innovations that chance produces less than once per
    ``horizon_s`` of edges. An edge is gated with probability p and its sign is even, so a given
    edge starts a one-signed run of n with probability p (p / 2)^(n - 1); the expected number
    over the horizon is edge_rate_hz horizon_s p (p / 2)^(n - 1), which must stay below 1.

    With consistent Gaussian innovations p = exp(-gate / 2) (chi-square, 2 dof; the default).
    Inside a burst of edge noise that R has not learned yet, every edge is gated: p_gated = 1,
    and only the sign test is left, which holds whatever the noise's scale (zero-mean noise of
    any variance gives either sign with probability 1/2)."""
    p = math.exp(-0.5 * gate) if p_gated is None else p_gated
    n = 1
    while edge_rate_hz * horizon_s * p * (0.5 * p) ** (n - 1) >= 1.0:
        n += 1
    return n


def new_state(q0: np.ndarray, r0_diag: tuple[float, float] = (0.0, 0.02), p0_diag=(5e4, 5e4, 5e4),
              x0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Initial filter state with the paper's values: q0 = 0, r0 = 0, R0 = diag(0, 0.02), P0 = diag(5e4, ...)."""
    s = np.zeros(N_STATE)
    s[ST.X:ST.X + 3] = x0
    s[ST.P:ST.P + 9] = np.diag(p0_diag).ravel()
    s[ST.Q:ST.Q + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[ST.Q_NOMINAL:ST.Q_NOMINAL + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[ST.Q_RAW], s[ST.Q_RAW + 1] = s[ST.Q], s[ST.Q + 8]
    s[ST.R:ST.R + 4] = np.diag(r0_diag).ravel()
    return s


@njit(cache=True)
def _sym_pd_floor(m, n, floor):
    """Symmetrise the n x n matrix stored row-major in m; floor its eigenvalues; True if it was
    indefinite (a repair).

    The common case (already positive definite) is a scalar Cholesky test with no allocation;
    only a failing matrix goes through an eigen-decomposition."""
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (m[i * n + j] + m[j * n + i])
            m[i * n + j] = v
            m[j * n + i] = v
    if n == 2:
        a, b, d = m[0], m[1], m[3]
        ok = a > floor and d - b * b / a > floor
    else:
        a, b, c, d, e, f = m[0], m[1], m[2], m[4], m[5], m[8]
        ok = False
        if a > floor:
            l10 = b / math.sqrt(a)
            l20 = c / math.sqrt(a)
            d1 = d - l10 * l10
            if d1 > floor:
                l21 = (e - l20 * l10) / math.sqrt(d1)
                ok = f - l20 * l20 - l21 * l21 > floor
    if ok:
        return False
    mat = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            mat[i, j] = m[i * n + j]
    w, v = np.linalg.eigh(mat)
    # a repair only if the matrix was indefinite beyond rounding: an exactly singular P (the
    # paper's R_theta = 0 leaves no angle uncertainty after an update) is positive semi-definite,
    # a valid covariance, and lifting its zero eigenvalue to the floor is not a repair
    repaired = w[0] < -1e-12 * max(abs(w[n - 1]), 1.0)
    for i in range(n):
        if w[i] < floor:
            w[i] = floor
    bm = (v * w) @ v.T
    for i in range(n):
        for j in range(n):
            m[i * n + j] = 0.5 * (bm[i, j] + bm[j, i])
    return repaired


@njit(cache=True, inline="always")
def _mm3(a, b, out):
    """out = a @ b for 3 x 3 matrices stored row-major in flat arrays."""
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j]


@njit(cache=True, inline="always")
def _mm3t(a, b, out):
    """out = a @ b.T for 3 x 3 matrices stored row-major in flat arrays."""
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] + a[3 * i + 2] * b[3 * j + 2]


@njit(cache=True)
def _adapt_small_rq(s, fp, k, z_theta, z_i, hx0, hx1, x_new, phi, x, u):
    """Eq. 12 for the noise means r and q: terms accumulated each (ungated) cycle, applied every
    interval (paper: every 120 commutations) from their mean."""
    mask = int(fp[FP.ADAPTIVE])
    s[ST.ACC_SMALL_R] += z_theta - hx0                              # Z - H X_k,k-1
    s[ST.ACC_SMALL_R + 1] += z_i - hx1
    for i in range(3):                                              # X_k - Phi X_k-1
        s[ST.ACC_SMALL_Q + i] += x_new[i] - (phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i])
    s[ST.N_ACC] += 1.0
    if s[ST.N_ACC] >= fp[FP.INTERVAL] or k + 1.0 == fp[FP.WARMUP]:
        n = s[ST.N_ACC]
        b = fp[FP.B]
        j = s[ST.K_INTERVAL]
        dj = (1.0 - b) / (1.0 - b ** (j + 1.0))                       # d_j = (1 - b) / (1 - b^(j+1))
        if mask & ADAPT_SMALL_R:
            for i in range(2):                                      # r = (1 - d) r + d mean(Z - H X_k,k-1)
                s[ST.SMALL_R + i] = (1.0 - dj) * s[ST.SMALL_R + i] + dj * s[ST.ACC_SMALL_R + i] / n
        if mask & ADAPT_SMALL_Q:
            for i in range(3):                                      # q = (1 - d) q + d mean(X_k - Phi X_k-1)
                s[ST.SMALL_Q + i] = (1.0 - dj) * s[ST.SMALL_Q + i] + dj * s[ST.ACC_SMALL_Q + i] / n
        for i in range(2):
            s[ST.ACC_SMALL_R + i] = 0.0
        for i in range(3):
            s[ST.ACC_SMALL_Q + i] = 0.0
        s[ST.N_ACC] = 0.0
        s[ST.K_INTERVAL] = j + 1.0


@njit(cache=True)
def _rebase_p(s, r_warm, r_new, dt):
    """P made consistent with the first R estimate, at the end of the warm-up.

    The warm-up ran on R_warm (the paper's R_theta = 0): with R_warm = 0 the gain on the angle is
    1, the speed estimate is the last two edges' difference, and P says that estimate is exact.
    Its true error is that of a two-point estimate with the edge noise now learned: var(theta) = R,
    var(w) = 2 R / dt^2, cov(w, theta) = R / dt. Left as it is, P locks the speed where the last
    noisy difference put it (a gain of 1e-6 on the speed at 12,000 rpm), and the state drifts a
    few degrees per edge until the gate's divergence run fades it. With 0 < R_warm < R_new the
    warm-up P is scaled by R_new / R_warm, never past the two-point covariance."""
    if not (r_new > r_warm and dt > 0.0):
        return
    two_ww, two_wt, two_tt = 2.0 * r_new / (dt * dt), r_new / dt, r_new
    scale = r_new / r_warm if r_warm > 0.0 else math.inf
    if s[ST.P] * scale >= two_ww:
        s[ST.P], s[ST.P + 1], s[ST.P + 3], s[ST.P + 4] = two_ww, two_wt, two_wt, two_tt
        for i in (2, 5, 6, 7):                                      # the current decorrelated
            s[ST.P + i] = 0.0
    else:
        for i in (0, 1, 3, 4):
            s[ST.P + i] *= scale


@njit(cache=True, inline="always")
def _restart_r_interval(s):
    """Empty the R interval's accumulators: a new interval starts with the next edge."""
    for i in range(2):
        s[ST.ACC_R + i] = 0.0
        s[ST.ACC_R_MEAN + i] = 0.0
    for i in range(3):
        s[ST.ACC_EDGE + i] = 0.0
        s[ST.ACC_Z0 + i] = 0.0
    s[ST.N_ACC_R] = 0.0


@njit(cache=True, inline="always")
def _accumulate_r(s, fp, innov0, innov1, nis, p_pred):
    """The R interval's terms of one edge: the Eq. 12 term of each diagonal entry, Huber-weighted
    (an outlier moves R by c sqrt(S) at most instead of its full square, and a burst of edge
    noise still raises R: it is the edge noise R stands for; kappa, ``huber_kappa``, makes the
    weight unbiased for Gaussian innovations), the weighted innovations' sum (their mean is taken
    out) and, unweighted, the angle innovations' sum, sum of squares and H P H^T for the
    variance match."""
    c = fp[FP.HUBER_C]
    m = math.sqrt(nis) if nis > 0.0 else 0.0
    w = 1.0 if m <= c else c / m
    g = w / fp[FP.HUBER_KAPPA]
    s[ST.ACC_R] += g * innov0 * innov0 - p_pred[4]                  # w Z~^2 / kappa - H P_k,k-1 H^T (diagonal)
    s[ST.ACC_R + 1] += g * innov1 * innov1 - p_pred[8]
    sg = math.sqrt(g)
    s[ST.ACC_R_MEAN] += sg * innov0
    s[ST.ACC_R_MEAN + 1] += sg * innov1
    s[ST.N_ACC_R] += 1.0
    s[ST.ACC_Z0] += innov0
    s[ST.ACC_Z0 + 1] += innov0 * innov0
    s[ST.ACC_Z0 + 2] += p_pred[4]


@njit(cache=True, inline="always")
def _variance_match(s, fp, n):
    """R_theta replaced at once when the edge noise changed (a burst began or ended).

    The edge noise of the interval is measured from the edges themselves (the second
    differences of ``_edge_noise``, variance 6 sigma^2 whatever the filter does), against the
    R_theta the filter will run on: beyond a bound that chance crosses less than once per
    1000 s (``variance_match_bounds``), R_theta is set now instead of being blended in over
    1 / d_j intervals with each burst edge capped by the Huber weight. The trigger is the
    edges', not the innovations': a lagging state cannot raise R (a larger R would lower the
    gain and the lag grow). Tested after the Eq. 12 blend, so a blend that a noisy interval
    pushed below the edges' measure is caught too."""
    ne = s[ST.ACC_EDGE]
    if not (fp[FP.R_MATCH_HI] > 0.0 and ne > 2.0):
        return
    mean = s[ST.ACC_EDGE + 1] / ne
    r_edge = (s[ST.ACC_EDGE + 2] - ne * mean * mean) / (ne - 1.0) / 6.0
    if not r_edge > 0.0 or fp[FP.R_MATCH_LO] * s[ST.R] <= r_edge <= fp[FP.R_MATCH_HI] * s[ST.R]:
        return
    # the new R_theta is what the innovations show beyond H P H^T over the interval (it holds
    # what the filter needs, e.g. edge noise that is not white, or a burst's edges that the gate
    # kept out of the state); the edges' own measure where the innovations show less than the
    # chance bound below it (P already explains them, or the difference of two noisy variances
    # came out near zero)
    var0 = (s[ST.ACC_Z0 + 1] - s[ST.ACC_Z0] * s[ST.ACC_Z0] / n) / (n - 1.0) if n > 1.0 else 0.0
    r_innov = var0 - s[ST.ACC_Z0 + 2] / n
    s[ST.R] = r_innov if r_innov >= fp[FP.R_MATCH_LO] * r_edge else r_edge


@njit(cache=True)
def _adapt_r(s, fp, guards, k, innov0, innov1, nis, p_pred):
    """Eq. 12 for R from every innovation, gated or not (``_accumulate_r``). R has its own
    forgetting factor and interval: it is applied every R_INTERVAL cycles from the interval's
    mean term, d_j = (1 - b_R) / (1 - b_R^(j+1)).

    R keeps its physical structure, as Q does: the edge instants and the current come from
    different sensors, so their noises are independent and R is diagonal. The Eq. 12 cross
    term is the innovations' cross-correlation, which comes from the state's errors (H P H^T
    accounts for them only on average), not a property of the sensors."""
    _accumulate_r(s, fp, innov0, innov1, nis, p_pred)
    warm = k < fp[FP.WARMUP]
    # during the warm-up R is set once, at its end (the first R_INTERVAL cycles after P0 would
    # otherwise swamp it); then every R_INTERVAL cycles
    if (warm and k + 1.0 != fp[FP.WARMUP]) or (not warm and s[ST.N_ACC_R] < fp[FP.R_INTERVAL]):
        return
    n = s[ST.N_ACC_R]
    j = s[ST.K_INTERVAL_R]
    r_before = s[ST.R]                                              # the R_theta the interval ran on
    b = fp[FP.R_B]
    dj = (1.0 - b) / (1.0 - b ** (j + 1.0))
    # the innovations' own mean over the interval is taken out (Eq. 12's Z~ - r): a state that is
    # off pushes every innovation one way, and R must not absorb that error (it would lower the
    # gain, the error would grow, and R with it); the one-signed run then fades P instead
    unbias = n / (n - 1.0) if n > 1.0 else 1.0
    for i in range(2):
        mean = s[ST.ACC_R_MEAN + i] / n
        term = unbias * (s[ST.ACC_R + i] - n * mean * mean) / n
        s[ST.R + 3 * i] = (1.0 - dj) * s[ST.R + 3 * i] + dj * term  # R = (1 - d) R + d mean(term)
    if not warm:
        _variance_match(s, fp, n)
    if j == 0.0 and s[ST.EDGE_STATS] > 2.0:
        # the first estimate of the edge-angle variance comes from the edges themselves (below),
        # not from innovations of a filter that ran on R0 = 0 and so followed every edge: those
        # innovations carry its own prediction error, not only the edge noise (R 6-10x too large)
        mean = s[ST.EDGE_STATS + 1] / s[ST.EDGE_STATS]
        s[ST.R] = max(s[ST.EDGE_STATS + 2] / s[ST.EDGE_STATS] - mean * mean, 0.0) / 6.0
        _rebase_p(s, r_before, s[ST.R], s[ST.DT_PREV])
    s[ST.R + 1] = 0.0
    s[ST.R + 2] = 0.0
    # an Eq. 12 estimate that went negative lost positive definiteness: the textbook failure
    # the guards exist for, floored and counted as a repair
    if _sym_pd_floor(s[ST.R:ST.R + 4], 2, fp[FP.FLOOR]):
        guards[GUARD_R_PD] += 1
    # an exactly repeated current would drive its variance to the eigenvalue floor, and the
    # smallest drift of the current estimate would then be gated as an outlier; no measurement
    # is finer than its quantisation (a positive variance raised to it is not a repair)
    s[ST.R + 3] = max(s[ST.R + 3], fp[FP.R_I_FLOOR])
    _restart_r_interval(s)
    s[ST.K_INTERVAL_R] = j + 1.0
    s[ST.CHANGED] = 0.0
    s[ST.CHANGED + 1] = 0.0


N_WORK = 96


@njit(cache=True, inline="always")
def _innovation_inverse(p_pred, s):
    """(H P_k,k-1 H^T + R)^-1 with H = [[0,1,0],[0,0,1]], as its four entries row-major."""
    s00 = p_pred[4] + s[ST.R]
    s01 = p_pred[5] + s[ST.R + 1]
    s10 = p_pred[7] + s[ST.R + 2]
    s11 = p_pred[8] + s[ST.R + 3]
    det = s00 * s11 - s01 * s10
    return s11 / det, -s01 / det, -s10 / det, s00 / det


@njit(cache=True, inline="always")
def _predict(s, dt, accel_per_amp, decel_load, phi, u, x, p, x_pred, p_pred, phi_p_phi, tmp):
    """Eq. 9 (transition Phi and load input over one cycle of dt) and the Eq. 11 prediction."""
    # --- Eq. 9: transition Phi and input ------------------------------------------------------
    a = accel_per_amp
    phi[0], phi[1], phi[2] = 1.0, 0.0, a * dt
    phi[3], phi[4], phi[5] = dt, 1.0, 0.5 * a * dt * dt
    phi[6], phi[7], phi[8] = 0.0, 0.0, 1.0
    u[0], u[1], u[2] = -dt * decel_load, -0.5 * dt * dt * decel_load, 0.0
    for i in range(3):
        x[i] = s[ST.X + i]
    for i in range(9):
        p[i] = s[ST.P + i]
    # --- Eq. 11: prediction ------------------------------------------------------------------
    for i in range(3):                                              # X_k,k-1 = Phi X_k-1 + q_k-1
        x_pred[i] = phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i] + s[ST.SMALL_Q + i]
    _mm3(phi, p, tmp)
    _mm3t(tmp, phi, phi_p_phi)
    for i in range(9):                                              # P_k,k-1 = Phi P Phi^T + Q_k-1
        p_pred[i] = phi_p_phi[i] + s[ST.Q + i]


@njit(cache=True, inline="always")
def _gate(s, fp, guards, k, gate_from, innov0, nis, p_pred):
    """The chi-square gate on the NIS and the divergence fade. Returns (gated, faded): a gated
    edge leaves the state at its prediction; a faded step has P_k,k-1 scaled up and takes the
    edge (the caller recomputes S^-1)."""
    if not (fp[FP.GATE_STATE] != 0.0 and k >= gate_from and nis > fp[FP.GATE]):
        s[ST.GATED_RUN] = 0.0
        return False, False
    # signed run length of gated innovations of one sign: a wrong state pushes every edge the
    # same way, a burst of edge noise scatters both ways
    run = s[ST.GATED_RUN]
    if innov0 >= 0.0:
        run = run + 1.0 if run > 0.0 else 1.0
    else:
        run = run - 1.0 if run < 0.0 else -1.0
    s[ST.GATED_RUN] = run
    if fp[FP.DIVERGENCE_RUN] > 0.0 and abs(run) >= fp[FP.DIVERGENCE_RUN]:
        # innovations persistently beyond the gate, all one way: the state is wrong, not the
        # edge. P is overconfident, so it is faded by the ratio of the observed to the expected
        # NIS (strong-tracking fading factor) and the filter takes the edge
        fade = nis / 2.0
        for i in range(9):
            p_pred[i] *= fade
        guards[GUARD_DIVERGENCE] += 1
        return False, True
    guards[GUARD_GATE] += 1
    return True, False


@njit(cache=True, inline="always")
def _update(s, guards, innov0, innov1, i00, i01, i10, i11, x_pred, p_pred, gain, x_new, p_new, ikh, tmp):
    """Eq. 11: gain, state update and the Joseph-form covariance update, with its repair."""
    for i in range(3):                                              # K = P H^T (H P H^T + R)^-1
        a0 = p_pred[3 * i + 1]
        a1 = p_pred[3 * i + 2]
        gain[2 * i] = a0 * i00 + a1 * i10
        gain[2 * i + 1] = a0 * i01 + a1 * i11
    for i in range(3):                                              # X_k = X_k,k-1 + K Z~
        x_new[i] = x_pred[i] + gain[2 * i] * innov0 + gain[2 * i + 1] * innov1
    # Joseph form of P_k = (I - K H) P_k,k-1 (I - K H)^T + K R K^T (symmetric, PSD)
    for i in range(3):
        for j in range(3):
            ikh[3 * i + j] = 1.0 if i == j else 0.0
        ikh[3 * i + 1] -= gain[2 * i]
        ikh[3 * i + 2] -= gain[2 * i + 1]
    _mm3(ikh, p_pred, tmp)
    _mm3t(tmp, ikh, p_new)
    r00, r01, r10, r11 = s[ST.R], s[ST.R + 1], s[ST.R + 2], s[ST.R + 3]
    for i in range(3):                                              # + K R K^T
        g0, g1 = gain[2 * i], gain[2 * i + 1]
        for j in range(3):
            h0, h1 = gain[2 * j], gain[2 * j + 1]
            p_new[3 * i + j] += g0 * (r00 * h0 + r01 * h1) + g1 * (r10 * h0 + r11 * h1)
    # covariance repair: only rounding can make the Joseph form indefinite; counted when it did
    if _sym_pd_floor(p_new, 3, 1e-12):
        guards[GUARD_P_PD] += 1


@njit(cache=True, inline="always")
def _adapt_q_whiteness(s, fp, k, innov0):
    """Option (ADAPT_Q_WHITE): Q_w steered by innovation whiteness (Mehra 1970). The lag-1
    correlation of the angle innovations is zero for the optimal gain, positive when the filter
    lags (Q too small), negative when it chases the noise (Q too large); once per interval Q_w
    takes a log-step of WHITENESS_GAIN per unit of correlation, within its band."""
    s[ST.ACC_WHITE] += innov0 * s[ST.PREV_INNOV]
    s[ST.ACC_WHITE + 1] += innov0 * innov0
    if s[ST.ACC_WHITE + 1] > 0.0 and (k + 1.0 - fp[FP.WARMUP]) % fp[FP.INTERVAL] == 0.0:
        c1 = s[ST.ACC_WHITE] / s[ST.ACC_WHITE + 1]
        s[ST.Q] = min(
            max(s[ST.Q] * math.exp(WHITENESS_GAIN * c1), s[ST.Q_NOMINAL] / fp[FP.BAND]),
            s[ST.Q_NOMINAL] * fp[FP.BAND],
        )
        s[ST.ACC_WHITE] = 0.0
        s[ST.ACC_WHITE + 1] = 0.0


@njit(cache=True, inline="always")
def _edge_noise(s, dt, warm):
    """Sensor analysis of the edge noise (paper 3.2: R from the sensor's own errors): with white
    edge-angle noise n_k, w (dt_k - dt_k-1) = n_k - 2 n_k-1 + n_k-2 has variance 6 sigma^2
    whatever the filter does; a steady acceleration only shifts its mean. Over the warm-up it
    gives R's first estimate; over each R interval, the variance match's."""
    x2 = math.nan
    if s[ST.DT_PREV] > 0.0:
        x2 = (math.pi / 3.0) / dt * (dt - s[ST.DT_PREV])
        at = ST.EDGE_STATS if warm else ST.ACC_EDGE
        s[at] += 1.0
        s[at + 1] += x2
        s[at + 2] += x2 * x2
    s[ST.DT_PREV] = dt
    return x2


#: variance ratios the change detector is tuned for: a tenfold rise, a tenfold fall
CUSUM_UP, CUSUM_DOWN = 10.0, 0.1
#: its threshold for chance alarms (both sides) rarer than once per 1000 s at MAX_EDGE_RATE_HZ:
#: Monte-Carlo of white Gaussian edge noise, 2e8 edges: 0.98 alarms per 2.4e6 edges at 24, 0.60
#: at 25, 0.41 at 26 (``test_change_detector_chance_alarms_rarer_than_once_per_1000_s``)
CUSUM_H_1000S = 25.0


@njit(cache=True, inline="always")
def _change_detect(s, fp, x2):
    """Page's CUSUM on the edges' own noise measure u = x2^2 / (6 R_theta), for a tenfold rise
    and a tenfold fall of the edge-angle variance: the log-likelihood ratio of one sample is
    (u / 2)(1 - 1/V) - ln(V) / 2. At the threshold the edge noise changed: the R interval
    restarts at the change point (where the statistic left zero) and, until it ends, R_theta is
    the mean x2^2 / 6 since the change point, growing sample by sample (a few samples say little
    of a variance; the interval's Eq. 12 and variance match take over at its end). Returns True
    on a change."""
    if s[ST.CHANGED + 1] > 0.0 and x2 == x2:
        s[ST.CHANGED] += x2 * x2 / 6.0
        s[ST.CHANGED + 1] += 1.0
        s[ST.R] = s[ST.CHANGED] / s[ST.CHANGED + 1]
    r = s[ST.R]
    if not (r > 0.0 and x2 == x2):
        return False
    u = x2 * x2 / (6.0 * r)
    for side in range(2):
        v = CUSUM_UP if side == 0 else CUSUM_DOWN
        at = ST.CUSUM + 3 * side
        g = s[at] + 0.5 * u * (1.0 - 1.0 / v) - 0.5 * math.log(v)
        if g <= 0.0:
            s[at], s[at + 1], s[at + 2] = 0.0, 0.0, 0.0
            continue
        s[at] = g
        s[at + 1] += x2 * x2 / 6.0
        s[at + 2] += 1.0
        if g > fp[FP.CUSUM_H]:
            s[ST.CHANGED], s[ST.CHANGED + 1] = s[at + 1], s[at + 2]
            s[ST.R] = s[at + 1] / s[at + 2]
            for i in range(6):
                s[ST.CUSUM + i] = 0.0
            _restart_r_interval(s)
            return True
    return False


@njit(cache=True, inline="always")
def _adapt_q(s, fp, guards, k, innov0, innov1, gain, p_new, phi_p_phi):
    """Eq. 12 for Q, every step: Q = (1 - d_k) Q + d_k (K Z~ Z~^T K^T + P_k - Phi P_k-1 Phi^T).

    Q keeps its physical structure: process noise enters speed and current (theta follows from
    w through Eq. 9), so only those diagonal entries adapt; the angle entry stays at its nominal
    value and cross terms at zero. Unconstrained, Q absorbs the edge noise whenever R starts too
    small (R0 = 0 here) and R is then never learned."""
    mask = int(fp[FP.ADAPTIVE])
    b = fp[FP.B]
    # d_k continues from the true step count: restarting it at 1 after the warm-up would let a
    # single noisy sample replace Q
    d = (1.0 - b) / (1.0 - b ** (k + 1.0))                          # d_k = (1 - b) / (1 - b^(k+1))
    band = fp[FP.BAND]
    clamped = False
    for i, raw in ((0, ST.Q_RAW), (2, ST.Q_RAW + 1)):
        if i == 0 and (mask & ADAPT_Q_WHITE or not mask & ADAPT_Q):
            continue
        kz = gain[2 * i] * innov0 + gain[2 * i + 1] * innov1
        term = kz * kz + p_new[4 * i] - phi_p_phi[4 * i]            # K Z~ Z~^T K^T + P_k - Phi P_k-1 Phi^T
        nominal = s[ST.Q_NOMINAL + 4 * i]
        lo, hi = nominal / band, nominal * band
        # the Eq. 12 recursion runs on its own, unclamped: truncating each step's estimate at
        # the floor and feeding it back biases Q upward (the negative half of a noisy term is
        # cut, the positive half kept). The filter uses the estimate projected onto the band.
        v = min(max((1.0 - d) * s[raw] + d * term, -hi), hi)        # Q = (1 - d) Q + d term
        s[raw] = v
        if not v > 0.0:
            guards[GUARD_Q_PD] += 1
        if v < lo:
            v = lo
            clamped = True
        elif v >= hi:
            v = hi
            clamped = True
        s[ST.Q + 4 * i] = v
    for i in (1, 2, 3, 5, 6, 7):
        s[ST.Q + i] = 0.0
    s[ST.Q + 4] = s[ST.Q_NOMINAL + 4]
    if clamped:
        guards[GUARD_Q_BAND] += 1


@njit(cache=True)
def step(s, fp, guards, z_theta, z_i, dt, accel_per_amp, decel_load, wk):
    """One commutation cycle: predict with Eq. 9, update with Eq. 11, adapt with Eq. 12.

    The angle is kept relative to the last corrected edge: that edge is at 0, so the edge that
    ends this cycle is measured at z_theta = pi / 3 (Eq. 10, observing angle and current);
    dt is the measured cycle duration; accel_per_amp = p K_T(n) / J and decel_load =
    p M(n) w_m^2 / J are evaluated at the previous estimate; wk is scratch (N_WORK), so a step
    allocates nothing. Returns the normalised innovation squared."""
    phi, u, x, p = wk[0:9], wk[9:12], wk[12:15], wk[15:24]
    x_pred, p_pred, tmp = wk[24:27], wk[27:36], wk[36:45]
    gain = wk[45:51]          # 3 x 2
    p_new, ikh, phi_p_phi, x_new = wk[51:60], wk[60:69], wk[69:78], wk[78:81]
    _predict(s, dt, accel_per_amp, decel_load, phi, u, x, p, x_pred, p_pred, phi_p_phi, tmp)
    # --- Eq. 10: H = [[0,1,0],[0,0,1]] (as we read it: the edge measures the angle) ----------
    hx0 = x_pred[1]
    hx1 = x_pred[2]
    innov0 = z_theta - hx0 - s[ST.SMALL_R]                          # Z~ = Z - H X_k,k-1 - r
    innov1 = z_i - hx1 - s[ST.SMALL_R + 1]
    i00, i01, i10, i11 = _innovation_inverse(p_pred, s)
    nis = innov0 * (i00 * innov0 + i01 * innov1) + innov1 * (i10 * innov0 + i11 * innov1)
    k = s[ST.K_STEP]
    warm = k < fp[FP.WARMUP]
    mask = int(fp[FP.ADAPTIVE])
    # the gate acts once P is consistent with R: the warm-up ran on R0 (the paper's R_theta = 0
    # claims exact edges, so P leaves it overconfident), and R's first estimate is set at its
    # end; one R interval with that R brings P in line. Gating earlier refuses every edge.
    gate_from = fp[FP.WARMUP] + (fp[FP.R_INTERVAL] if mask & ADAPT_R else 0.0)
    gated, faded = _gate(s, fp, guards, k, gate_from, innov0, nis, p_pred)
    if gated:
        # an outlier edge: the state keeps its prediction, P its predicted covariance
        for i in range(3):
            x_new[i] = x_pred[i]
        for i in range(9):
            p_new[i] = p_pred[i]
    else:
        if faded:
            i00, i01, i10, i11 = _innovation_inverse(p_pred, s)
        _update(s, guards, innov0, innov1, i00, i01, i10, i11, x_pred, p_pred, gain, x_new, p_new, ikh, tmp)
    for i in range(3):
        s[ST.X + i] = x_new[i]
    s[ST.X + 1] -= math.pi / 3.0  # re-reference: the edge just measured is the new angle zero
    for i in range(9):
        s[ST.P + i] = p_new[i]
    s[ST.LAST_NIS] = nis
    s[ST.K_STEP] = k + 1.0
    if mask == 0:
        return nis
    # --- Eq. 12 ------------------------------------------------------------------------------
    # Q adapts once the gate acts, one R interval after the warm-up: P has then converged from
    # its re-base on the first R (``_rebase_p``). Earlier, the Eq. 12 term P_k - Phi P Phi^T is
    # P's own convergence (hundreds of (rad/s)^2 per step), not process noise: it drove the
    # recursion to its lower clamp in a few steps, Q_w sat at the band floor for the rest of the
    # run and the filter could not follow a load its model had wrong (drawn conditions, Q_w by
    # Eq. 12: within 1.05 x KF + 0.01 deg e in 64 % before, 91 % after). Whiteness alike.
    q_on = k >= gate_from
    if mask & ADAPT_Q_WHITE and q_on:
        _adapt_q_whiteness(s, fp, k, innov0)
    s[ST.PREV_INNOV] = innov0
    x2 = _edge_noise(s, dt, warm)
    if fp[FP.CUSUM_H] > 0.0 and mask & ADAPT_R and not warm:
        _change_detect(s, fp, x2)
    # the first half of the warm-up lets P settle from P0 (5e4 would swamp the R estimate); a
    # faded step's innovation is the state's error, not the edge noise R stands for
    settled = k >= 0.5 * fp[FP.WARMUP]
    if mask & ADAPT_R and settled and not faded:
        _adapt_r(s, fp, guards, k, innov0, innov1, nis, p_pred)
    if gated:
        return nis
    if mask & (ADAPT_SMALL_R | ADAPT_SMALL_Q) and settled:
        _adapt_small_rq(s, fp, k, z_theta, z_i, hx0, hx1, x_new, phi, x, u)
    if q_on and mask & (ADAPT_Q | ADAPT_Q_CURRENT):
        _adapt_q(s, fp, guards, k, innov0, innov1, gain, p_new, phi_p_phi)
    return nis


@njit(cache=True)
def predict_next_s(s, accel_per_amp, decel_load):
    """Time from the last corrected edge until the predicted angle reaches the next commutation
    angle: theta + w tau + eps tau^2 / 2 = pi / 3 (Eq. 7, with eps from Eq. 8)."""
    w = s[ST.X]
    theta = s[ST.X + 1]
    eps = accel_per_amp * s[ST.X + 2] - decel_load
    d = math.pi / 3.0 - theta
    disc = w * w + 2.0 * eps * d
    if w <= 0.0 or d <= 0.0:
        return max(d, 0.0) / max(w, 1e-9)
    if disc < 0.0:
        disc = 0.0
    return 2.0 * d / (w + math.sqrt(disc))


@njit(cache=True)
def coefficients(w_e, fp, tables):
    """Eq. 8 in electrical speed at w_e: p K_T(n) / J, p M(n) w_m^2 / J (+ p B w_m / J), K_T and M
    interpolated in the identified tables (rows: speed rpm, K_T, M; clamped at their ends), B the
    friction (``model.MotorModel``)."""
    pp = fp[FP.POLE_PAIRS]
    n_rpm = w_e / pp * 60.0 / (2.0 * math.pi)
    w_m = w_e / pp
    return (pp * np.interp(n_rpm, tables[0], tables[1]) / fp[FP.J],
            pp * (np.interp(n_rpm, tables[0], tables[2]) * w_m * w_m + fp[FP.FRICTION] * w_m) / fp[FP.J])


@njit(cache=True, inline="always")
def lost_lock(w, innov_theta):
    """True when the state no longer follows the edges: a speed that is not positive (within a
    run of rotor steps the rotor turns one way: the edge decoder splits runs at reversals and
    stalls), or an angle innovation beyond one sector. Each edge is the next 60 deg e boundary,
    so a state whose predicted angle at the edge is off by more than a sector has lost count of
    the sectors; no update from there recovers what the edge sequence states. A kinematic filter
    that extrapolates a strong deceleration over a long low-speed cycle reaches a negative
    speed, and its Eq. 7 prediction is then a time without end (4e10 deg e RMS on a hoverboard
    capture); a filter whose R absorbed its own lag (VB-AKF) predicts a sector early on every
    edge. Neither is fixed by a fade of P: the state is restarted (``restart``)."""
    return not (w > 0.0 and abs(innov_theta) <= math.pi / 3.0)


@njit(cache=True)
def restart(s, dt, current):
    """The state restarted from the interval that just ended, as at the first edge: speed
    (pi / 3) / dt, angle 0 at this edge, the current measured; P the covariance of that
    two-point estimate under the edge noise in use (var(w) = 2 R / dt^2, cov(w, theta) = R / dt,
    var(theta) = R; ``_rebase_p``'s), the third state keeping its variance and decorrelated. The
    noise statistics (Q, R, r, q) are kept: they describe the sensor and the plant, not the
    lost state."""
    s[ST.X] = (math.pi / 3.0) / dt
    s[ST.X + 1] = 0.0
    s[ST.X + 2] = current
    r = s[ST.R]
    if r > 0.0:
        s[ST.P], s[ST.P + 1], s[ST.P + 3], s[ST.P + 4] = 2.0 * r / (dt * dt), r / dt, r / dt, r
        for i in (2, 5, 6, 7):
            s[ST.P + i] = 0.0
    s[ST.GATED_RUN] = 0.0


@njit(cache=True)
def edge(s, fp, guards, dt, current, tables, wk):
    """One corrected edge that ended a cycle of ``dt`` seconds with mean |i| ``current``: the
    whole online update (Eq. 8 coefficients, step, Eq. 7 prediction) in one compiled call.
    Returns the time from this edge to the predicted next commutation."""
    if s[ST.INITIALISED] == 0.0:
        # the first cycle initialises speed and current; filtering starts with the next edge
        s[ST.X] = (math.pi / 3.0) / dt
        s[ST.X + 1] = 0.0
        s[ST.X + 2] = current
        s[ST.INITIALISED] = 1.0
    else:
        # the coefficients at the previous estimate: computed for the last prediction already
        step(s, fp, guards, math.pi / 3.0, current, dt, s[ST.COEF], s[ST.COEF + 1], wk)
        if lost_lock(s[ST.X], math.pi / 3.0 - wk[25]):
            restart(s, dt, current)
            guards[GUARD_LOST_LOCK] += 1
    a, dl = coefficients(s[ST.X], fp, tables)
    s[ST.COEF] = a
    s[ST.COEF + 1] = dl
    return predict_next_s(s, a, dl)


@njit(cache=True)
def run_batch(s, fp, guards, t_edges, current, tables, out_pred_t, out_w):
    """Filter a whole sequence of corrected edge times; out_pred_t[k] predicts edge k + 1."""
    wk = np.empty(N_WORK)
    n = t_edges.size
    for k in range(1, n):
        tau = edge(s, fp, guards, t_edges[k] - t_edges[k - 1], current[k], tables, wk)
        out_pred_t[k] = t_edges[k] + tau
        out_w[k] = s[ST.X]
    return n - 1
