"""Sage-Husa adaptive Kalman filter (paper Eq. 11-12) and the fixed-noise Kalman baseline.

One numba step function serves both: with ``adaptive`` off it is the plain Kalman filter
(Eq. 11 with fixed Q, R). The filter state lives in flat float64 arrays so that the same code
runs online (one call per commutation) and in batch (a whole edge sequence in one call).

Guards (shared/design.md section 5), each counted in ``guards``:
  GUARD_GATE     innovation failed the chi-square gate: no adaptation from this step;
  GUARD_Q_PD     the Eq. 12 Q recursion was not positive: the filter uses the band's floor;
  GUARD_Q_BAND   a diagonal of Q left its band around nominal (band_factor) and was clamped;
  GUARD_R_PD     the R update (residual form) was not positive definite: eigenvalues floored;
  GUARD_P_PD     P lost positive definiteness after the Joseph update: eigenvalues floored;
  GUARD_DIVERGENCE  innovations beyond the gate and of one sign on ``divergence_run``
                 consecutive cycles: the state, not the edge, is wrong; P is faded by NIS / 2
                 (strong tracking).
The first edge-angle variance comes from the edges themselves (second differences of the edge
intervals) rather than from innovations of a filter that ran on the paper's R0 = 0.
Q adapts every step after a warm-up; r, R and q at intervals (paper: every 120 commutations),
from the mean of their Eq. 12 terms over the interval.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# parameter vector
F_B, F_INTERVAL, F_WARMUP, F_GATE, F_BAND, F_FLOOR, F_ADAPTIVE, F_POLE_PAIRS, F_J, F_DIVERGENCE_RUN = range(10)
N_FPARAMS = 10
# state vector layout
X0, P0, Q0, R0, QN0, SMALLQ0, SMALLR0, ACC_R0, ACC_RR0, ACC_Q0 = 0, 3, 12, 21, 25, 34, 37, 39, 43, 46
K_STEP, K_INTERVAL, N_ACC, INITIALISED, LAST_NIS, GATED_RUN = 49, 50, 51, 52, 53, 54
DT_PREV, EDGE_N, EDGE_SUM, EDGE_SUMSQ = 55, 56, 57, 58
Q_RAW_W, Q_RAW_I = 59, 60
PREV_INNOV, ACC_C1, ACC_C0 = 61, 62, 63
N_STATE = 64
GUARD_GATE, GUARD_Q_PD, GUARD_Q_BAND, GUARD_R_PD, GUARD_P_PD, GUARD_DIVERGENCE = range(6)
#: which Eq. 12 estimates adapt (F_ADAPTIVE holds the mask; 0 = plain Kalman filter)
ADAPT_Q, ADAPT_R, ADAPT_SMALL_R, ADAPT_SMALL_Q = 1, 2, 4, 8
ADAPT_ALL = 15
#: option, not the paper's: the speed entry of Q steered by innovation whiteness (Mehra 1970)
#: instead of the Eq. 12 recursion, see docs/sage-husa.md
ADAPT_Q_WHITE = 16
#: log-step of Q_w per unit of lag-1 innovation correlation, applied once per interval
WHITENESS_GAIN = 4.0
N_GUARDS = 6
CHI2_2DOF_999 = 13.815510557964274  # 99.9 % quantile, 2 degrees of freedom


def new_state(q0: np.ndarray, r0_diag: tuple[float, float] = (0.0, 0.02), p0_diag=(5e4, 5e4, 5e4),
              x0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Initial filter state with the paper's values: q0 = 0, r0 = 0, R0 = diag(0, 0.02), P0 = diag(5e4, ...)."""
    s = np.zeros(N_STATE)
    s[X0:X0 + 3] = x0
    s[P0:P0 + 9] = np.diag(p0_diag).ravel()
    s[Q0:Q0 + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[QN0:QN0 + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[Q_RAW_W], s[Q_RAW_I] = s[Q0], s[Q0 + 8]
    s[R0:R0 + 4] = np.diag(r0_diag).ravel()
    return s


@njit(cache=True)
def _sym_pd_floor(m, n, floor):
    """Symmetrise the n x n matrix stored row-major in m; floor its eigenvalues; True if it had to.

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
    for i in range(n):
        if w[i] < floor:
            w[i] = floor
    bm = (v * w) @ v.T
    for i in range(n):
        for j in range(n):
            m[i * n + j] = 0.5 * (bm[i, j] + bm[j, i])
    return True


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
def _adapt_interval(s, fp, guards, k, z_theta, z_i, hx0, hx1, innov0, innov1, p_pred, x_new, phi, x, u):
    """Eq. 12 for r, R and q: terms accumulated each cycle, applied every interval (paper: every
    120 commutations) and once at the end of the warm-up, so that R has an estimate before Q
    starts to adapt (Q adapted against R0 = 0 would absorb the edge noise)."""
    mask = int(fp[F_ADAPTIVE])
    b = fp[F_B]
    s[ACC_R0] += z_theta - hx0                                      # Z - H X_k,k-1
    s[ACC_R0 + 1] += z_i - hx1
    s[ACC_RR0] += innov0 * innov0 - p_pred[4]                       # Z~ Z~^T - H P_k,k-1 H^T
    s[ACC_RR0 + 1] += innov0 * innov1 - p_pred[5]
    s[ACC_RR0 + 2] += innov1 * innov0 - p_pred[7]
    s[ACC_RR0 + 3] += innov1 * innov1 - p_pred[8]
    for i in range(3):                                              # X_k - Phi X_k-1
        s[ACC_Q0 + i] += x_new[i] - (phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i])
    s[N_ACC] += 1.0
    if s[N_ACC] >= fp[F_INTERVAL] or k + 1.0 == fp[F_WARMUP]:
        n = s[N_ACC]
        j = s[K_INTERVAL]
        dj = (1.0 - b) / (1.0 - b ** (j + 1.0))
        for i in range(2):
            if mask & ADAPT_SMALL_R:
                s[SMALLR0 + i] = (1.0 - dj) * s[SMALLR0 + i] + dj * s[ACC_R0 + i] / n
        if mask & ADAPT_R:
            for i in range(4):
                s[R0 + i] = (1.0 - dj) * s[R0 + i] + dj * s[ACC_RR0 + i] / n
            if j == 0.0 and s[EDGE_N] > 2.0:
                # the first estimate of the edge-angle variance comes from the edges themselves
                # (below), not from innovations of a filter that ran on R0 = 0 and so followed
                # every edge: those innovations carry its own prediction error, not only the
                # edge noise (measured: R learned 6-10x too large)
                m = s[EDGE_SUM] / s[EDGE_N]
                s[R0] = max(s[EDGE_SUMSQ] / s[EDGE_N] - m * m, 0.0) / 6.0
                s[R0 + 1] = 0.0
                s[R0 + 2] = 0.0
            if _sym_pd_floor(s[R0:R0 + 4], 2, fp[F_FLOOR]):
                guards[GUARD_R_PD] += 1
        for i in range(3):
            if mask & ADAPT_SMALL_Q:
                s[SMALLQ0 + i] = (1.0 - dj) * s[SMALLQ0 + i] + dj * s[ACC_Q0 + i] / n
        for i in range(ACC_R0, ACC_Q0 + 3):
            s[i] = 0.0
        s[N_ACC] = 0.0
        s[K_INTERVAL] = j + 1.0


N_WORK = 96


@njit(cache=True, inline="always")
def _innovation_inverse(p_pred, s):
    """(H P_k,k-1 H^T + R)^-1 with H = [[0,1,0],[0,0,1]], as its four entries row-major."""
    s00 = p_pred[4] + s[R0]
    s01 = p_pred[5] + s[R0 + 1]
    s10 = p_pred[7] + s[R0 + 2]
    s11 = p_pred[8] + s[R0 + 3]
    det = s00 * s11 - s01 * s10
    return s11 / det, -s01 / det, -s10 / det, s00 / det


@njit(cache=True)
def step(s, fp, guards, z_theta, z_i, dt, accel_per_amp, decel_load, wk):
    """One commutation cycle: predict with Eq. 9, update with Eq. 11, adapt with Eq. 12.

    The angle is kept relative to the last corrected edge: that edge is at 0, so the edge that
    ends this cycle is measured at z_theta = pi / 3 (Eq. 10, observing angle and current);
    dt is the measured cycle duration; accel_per_amp = p K_T(n) / J and decel_load =
    p M(n) w_m^2 / J are evaluated at the previous estimate; wk is scratch (N_WORK), so a step
    allocates nothing. Returns the normalised innovation squared."""
    phi = wk[0:9]
    u = wk[9:12]
    x = wk[12:15]
    p = wk[15:24]
    x_pred = wk[24:27]
    p_pred = wk[27:36]
    tmp = wk[36:45]
    gain = wk[45:51]          # 3 x 2
    p_new = wk[51:60]
    ikh = wk[60:69]
    phi_p_phi = wk[69:78]
    x_new = wk[78:81]
    # --- Eq. 9: transition and input -------------------------------------------------------
    a = accel_per_amp
    phi[0], phi[1], phi[2] = 1.0, 0.0, a * dt
    phi[3], phi[4], phi[5] = dt, 1.0, 0.5 * a * dt * dt
    phi[6], phi[7], phi[8] = 0.0, 0.0, 1.0
    u[0], u[1], u[2] = -dt * decel_load, -0.5 * dt * dt * decel_load, 0.0
    for i in range(3):
        x[i] = s[X0 + i]
    for i in range(9):
        p[i] = s[P0 + i]
    # --- Eq. 11: prediction ------------------------------------------------------------------
    for i in range(3):                                              # X_k,k-1 = Phi X_k-1 + q_k-1
        x_pred[i] = phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i] + s[SMALLQ0 + i]
    _mm3(phi, p, tmp)
    _mm3t(tmp, phi, phi_p_phi)
    for i in range(9):                                              # P_k,k-1 = Phi P Phi^T + Q_k-1
        p_pred[i] = phi_p_phi[i] + s[Q0 + i]
    # H = [[0,1,0],[0,0,1]] (Eq. 10 as we read it: the edge measures the angle): rows 1 and 2
    hx0 = x_pred[1]
    hx1 = x_pred[2]
    innov0 = z_theta - hx0 - s[SMALLR0]                             # Z~ = Z - H X_k,k-1 - r
    innov1 = z_i - hx1 - s[SMALLR0 + 1]
    i00, i01, i10, i11 = _innovation_inverse(p_pred, s)
    nis = innov0 * (i00 * innov0 + i01 * innov1) + innov1 * (i10 * innov0 + i11 * innov1)
    k = s[K_STEP]
    if fp[F_ADAPTIVE] != 0.0 and k >= fp[F_WARMUP]:
        # signed run length of gated innovations of one sign: a wrong state pushes every edge
        # the same way, a burst of edge noise scatters both ways (and must not fade P)
        run = s[GATED_RUN]
        if nis <= fp[F_GATE]:
            run = 0.0
        elif innov0 >= 0.0:
            run = run + 1.0 if run > 0.0 else 1.0
        else:
            run = run - 1.0 if run < 0.0 else -1.0
        s[GATED_RUN] = run
        if fp[F_DIVERGENCE_RUN] > 0.0 and abs(run) >= fp[F_DIVERGENCE_RUN]:
            # innovations persistently beyond the gate, all one way: the state is wrong, not the
            # edge. P is overconfident (it claims a precision the innovations refute), so it is
            # faded by the ratio of the observed to the expected NIS (strong-tracking fading
            # factor) and the filter re-converges instead of locking onto a wrong speed
            fade = nis / 2.0
            for i in range(9):
                p_pred[i] *= fade
            guards[GUARD_DIVERGENCE] += 1
            i00, i01, i10, i11 = _innovation_inverse(p_pred, s)
    for i in range(3):                                              # K = P H^T (H P H^T + R)^-1
        a0 = p_pred[3 * i + 1]
        a1 = p_pred[3 * i + 2]
        gain[2 * i] = a0 * i00 + a1 * i10
        gain[2 * i + 1] = a0 * i01 + a1 * i11
    for i in range(3):                                              # X_k = X_k,k-1 + K Z~
        x_new[i] = x_pred[i] + gain[2 * i] * innov0 + gain[2 * i + 1] * innov1
    # Joseph form of P_k = (I - K H) P_k,k-1 (keeps P symmetric positive semi-definite)
    for i in range(3):
        for j in range(3):
            ikh[3 * i + j] = 1.0 if i == j else 0.0
        ikh[3 * i + 1] -= gain[2 * i]
        ikh[3 * i + 2] -= gain[2 * i + 1]
    _mm3(ikh, p_pred, tmp)
    _mm3t(tmp, ikh, p_new)
    r00, r01, r10, r11 = s[R0], s[R0 + 1], s[R0 + 2], s[R0 + 3]
    for i in range(3):                                              # + K R K^T
        g0, g1 = gain[2 * i], gain[2 * i + 1]
        for j in range(3):
            h0, h1 = gain[2 * j], gain[2 * j + 1]
            p_new[3 * i + j] += g0 * (r00 * h0 + r01 * h1) + g1 * (r10 * h0 + r11 * h1)
    if _sym_pd_floor(p_new, 3, 1e-12):
        guards[GUARD_P_PD] += 1
    for i in range(3):
        s[X0 + i] = x_new[i]
    s[X0 + 1] -= math.pi / 3.0  # re-reference: the edge just measured is the new angle zero
    for i in range(9):
        s[P0 + i] = p_new[i]
    s[LAST_NIS] = nis
    s[K_STEP] = k + 1.0
    if int(fp[F_ADAPTIVE]) & ADAPT_Q_WHITE and k >= fp[F_WARMUP]:
        # innovation whiteness (Mehra): lag-1 correlation of the angle innovations is zero for
        # the optimal gain, positive when the filter lags (Q too small), negative when it
        # chases the noise (Q too large)
        s[ACC_C1] += innov0 * s[PREV_INNOV]
        s[ACC_C0] += innov0 * innov0
        if s[ACC_C0] > 0.0 and (k + 1.0 - fp[F_WARMUP]) % fp[F_INTERVAL] == 0.0:
            c1 = s[ACC_C1] / s[ACC_C0]
            s[Q0] = min(max(s[Q0] * math.exp(WHITENESS_GAIN * c1), s[QN0] / fp[F_BAND]), s[QN0] * fp[F_BAND])
            s[ACC_C1] = 0.0
            s[ACC_C0] = 0.0
    s[PREV_INNOV] = innov0
    if fp[F_ADAPTIVE] == 0.0:
        return nis
    if k < fp[F_WARMUP]:
        # sensor analysis of the edge noise (paper 3.2: R from the sensor's own errors): with
        # white edge-angle noise n_k, w (dt_k - dt_k-1) = n_k - 2 n_k-1 + n_k-2 has variance
        # 6 sigma^2 whatever the filter does; a steady acceleration only shifts its mean
        if s[DT_PREV] > 0.0:
            x2 = (math.pi / 3.0) / dt * (dt - s[DT_PREV])
            s[EDGE_N] += 1.0
            s[EDGE_SUM] += x2
            s[EDGE_SUMSQ] += x2 * x2
        s[DT_PREV] = dt
    if k >= fp[F_WARMUP] and nis > fp[F_GATE]:
        guards[GUARD_GATE] += 1
        return nis
    # the first half of the warm-up lets P settle from P0 (5e4 would swamp the R estimate)
    if k >= 0.5 * fp[F_WARMUP]:
        _adapt_interval(s, fp, guards, k, z_theta, z_i, hx0, hx1, innov0, innov1, p_pred, x_new, phi, x, u)
    if k < fp[F_WARMUP]:
        return nis
    # --- Eq. 12: Q every step ----------------------------------------------------------------
    b = fp[F_B]
    # d_k continues from the true step count: restarting it at 1 after the warm-up would let a
    # single noisy sample replace Q
    d = (1.0 - b) / (1.0 - b ** (k + 1.0))                          # d_k = (1 - b) / (1 - b^(k+1))
    # Q keeps its physical structure: process noise enters speed and current (theta follows
    # from w through Eq. 9), so only those diagonal entries adapt; the angle entry stays at its
    # nominal value and cross terms at zero. Unconstrained, Q absorbs the edge noise whenever R
    # starts too small (R0 = 0 here) and R is then never learned.
    mask = int(fp[F_ADAPTIVE])
    if not mask & ADAPT_Q:
        return nis
    band = fp[F_BAND]
    clamped = False
    for i, raw in ((0, Q_RAW_W), (2, Q_RAW_I)):
        if i == 0 and mask & ADAPT_Q_WHITE:
            continue
        kz = gain[2 * i] * innov0 + gain[2 * i + 1] * innov1
        term = kz * kz + p_new[4 * i] - phi_p_phi[4 * i]            # K Z~ Z~^T K^T + P_k - Phi P_k-1 Phi^T
        nominal = s[QN0 + 4 * i]
        lo, hi = nominal / band, nominal * band
        # the Eq. 12 recursion runs on its own, unclamped: truncating each step's estimate at
        # the floor and feeding it back biases Q upward (the negative half of a noisy term is
        # cut, the positive half kept; measured: Q settled 40x above a true Q near zero).
        # The filter uses the estimate projected onto the band.
        v = min(max((1.0 - d) * s[raw] + d * term, -hi), hi)
        s[raw] = v
        if not v > 0.0:
            guards[GUARD_Q_PD] += 1
        if v < lo:
            v = lo
            clamped = True
        elif v >= hi:
            v = hi
            clamped = True
        s[Q0 + 4 * i] = v
    for i in range(9):
        if i not in (0, 4, 8):
            s[Q0 + i] = 0.0
    s[Q0 + 4] = s[QN0 + 4]
    if clamped:
        guards[GUARD_Q_BAND] += 1
    return nis


@njit(cache=True)
def predict_next_s(s, accel_per_amp, decel_load):
    """Time from the last corrected edge until the predicted angle reaches the next commutation
    angle: theta + w tau + eps tau^2 / 2 = pi / 3 (Eq. 7, with eps from Eq. 8)."""
    w = s[X0]
    theta = s[X0 + 1]
    eps = accel_per_amp * s[X0 + 2] - decel_load
    d = math.pi / 3.0 - theta
    disc = w * w + 2.0 * eps * d
    if w <= 0.0 or d <= 0.0:
        return max(d, 0.0) / max(w, 1e-9)
    if disc < 0.0:
        disc = 0.0
    return 2.0 * d / (w + math.sqrt(disc))


@njit(cache=True)
def run_batch(s, fp, guards, t_edges, current, speed_tab, kt_tab, m_tab, out_pred_t, out_w):
    """Filter a whole sequence of corrected edge times; out_pred_t[k] predicts edge k + 1."""
    wk = np.empty(N_WORK)
    pp = fp[F_POLE_PAIRS]
    j_inertia = fp[F_J]
    n = t_edges.size
    for k in range(1, n):
        dt = t_edges[k] - t_edges[k - 1]
        if s[INITIALISED] == 0.0:
            # the first cycle initialises speed and current; filtering starts with the next edge
            s[X0] = (math.pi / 3.0) / dt
            s[X0 + 1] = 0.0
            s[X0 + 2] = current[k]
            s[INITIALISED] = 1.0
            w_now = s[X0]
        else:
            w_prev = s[X0]
            n_rpm = w_prev / pp * 60.0 / (2.0 * math.pi)
            a = pp * np.interp(n_rpm, speed_tab, kt_tab) / j_inertia
            w_m = w_prev / pp
            dl = pp * np.interp(n_rpm, speed_tab, m_tab) * w_m * w_m / j_inertia
            step(s, fp, guards, math.pi / 3.0, current[k], dt, a, dl, wk)
            w_now = s[X0]
        n_rpm = w_now / pp * 60.0 / (2.0 * math.pi)
        w_m = w_now / pp
        out_pred_t[k] = t_edges[k] + predict_next_s(s, pp * np.interp(n_rpm, speed_tab, kt_tab) / j_inertia,
                                                     pp * np.interp(n_rpm, speed_tab, m_tab) * w_m * w_m / j_inertia)
        out_w[k] = w_now
    return n - 1
