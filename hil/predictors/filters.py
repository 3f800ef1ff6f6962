"""Sage-Husa adaptive Kalman filter (paper Eq. 11-12) and the fixed-noise Kalman baseline.

One numba step function serves both: with ``adaptive`` off it is the plain Kalman filter
(Eq. 11 with fixed Q, R). The filter state lives in flat float64 arrays so that the same code
runs online (one call per commutation) and in batch (a whole edge sequence in one call).

Guards (shared/design.md section 5), each counted in ``guards``:
  GUARD_GATE     innovation failed the chi-square gate: no adaptation from this step;
  GUARD_Q_PD     the Q update was not positive definite: eigenvalues floored;
  GUARD_Q_BAND   a diagonal of Q left its band around nominal (band_factor) and was clamped;
  GUARD_R_PD     the R update (residual form) was not positive definite: eigenvalues floored;
  GUARD_P_PD     P lost positive definiteness after the Joseph update: eigenvalues floored.
Q adapts every step after a warm-up; r, R and q at intervals (paper: every 120 commutations),
from the mean of their Eq. 12 terms over the interval.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# parameter vector
F_B, F_INTERVAL, F_WARMUP, F_GATE, F_BAND, F_FLOOR, F_ADAPTIVE, F_POLE_PAIRS, F_J, F_THETA_VAR = range(10)
N_FPARAMS = 10
# state vector layout
X0, P0, Q0, R0, QN0, SMALLQ0, SMALLR0, ACC_R0, ACC_RR0, ACC_Q0 = 0, 3, 12, 21, 25, 34, 37, 39, 43, 46
K_STEP, K_INTERVAL, N_ACC, INITIALISED, LAST_NIS = 49, 50, 51, 52, 53
N_STATE = 54
GUARD_GATE, GUARD_Q_PD, GUARD_Q_BAND, GUARD_R_PD, GUARD_P_PD = range(5)
#: which Eq. 12 estimates adapt (F_ADAPTIVE holds the mask; 0 = plain Kalman filter)
ADAPT_Q, ADAPT_R, ADAPT_SMALL_R, ADAPT_SMALL_Q = 1, 2, 4, 8
ADAPT_ALL = 15
N_GUARDS = 5
CHI2_2DOF_999 = 13.815510557964274  # 99.9 % quantile, 2 degrees of freedom


def new_state(q0: np.ndarray, r0_diag: tuple[float, float] = (0.0, 0.02), p0_diag=(5e4, 5e4, 5e4),
              x0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Initial filter state with the paper's values: q0 = 0, r0 = 0, R0 = diag(0, 0.02), P0 = diag(5e4, ...)."""
    s = np.zeros(N_STATE)
    s[X0:X0 + 3] = x0
    s[P0:P0 + 9] = np.diag(p0_diag).ravel()
    s[Q0:Q0 + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[QN0:QN0 + 9] = np.asarray(q0, dtype=float).reshape(9)
    s[R0:R0 + 4] = np.diag(r0_diag).ravel()
    return s


@njit(cache=True)
def _sym_pd_floor(m, n, floor):
    """Symmetrise the n x n matrix stored row-major in m; floor its eigenvalues; True if it had to."""
    a = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            a[i, j] = 0.5 * (m[i * n + j] + m[j * n + i])
    # cheap positive-definiteness check (Cholesky) before an eigen-decomposition
    ok = True
    lo = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= lo[i, k] * lo[j, k]
            if i == j:
                if s <= floor:
                    ok = False
                    break
                lo[i, i] = math.sqrt(s)
            else:
                lo[i, j] = s / lo[j, j]
        if not ok:
            break
    if ok:
        for i in range(n * n):
            m[i] = a.ravel()[i]
        return False
    w, v = np.linalg.eigh(a)
    for i in range(n):
        if w[i] < floor:
            w[i] = floor
    b = (v * w) @ v.T
    for i in range(n):
        for j in range(n):
            m[i * n + j] = 0.5 * (b[i, j] + b[j, i])
    return True


@njit(cache=True)
def _adapt_interval(s, fp, guards, k, z_theta, z_i, hx0, hx1, innov0, innov1, p_pred, x_new, phi, x, u):
    """Eq. 12 for r, R and q: terms accumulated each cycle, applied every interval (paper: every
    120 commutations) and once at the end of the warm-up, so that R has an estimate before Q
    starts to adapt (Q adapted against R0 = 0 would absorb the edge noise)."""
    mask = int(fp[F_ADAPTIVE])
    b = fp[F_B]
    s[ACC_R0] += z_theta - hx0                                      # Z - H X_k,k-1
    s[ACC_R0 + 1] += z_i - hx1
    s[ACC_RR0] += innov0 * innov0 - p_pred[1, 1]                    # Z~ Z~^T - H P_k,k-1 H^T
    s[ACC_RR0 + 1] += innov0 * innov1 - p_pred[1, 2]
    s[ACC_RR0 + 2] += innov1 * innov0 - p_pred[2, 1]
    s[ACC_RR0 + 3] += innov1 * innov1 - p_pred[2, 2]
    dq = x_new - (phi @ x + u)                                      # X_k - Phi X_k-1
    for i in range(3):
        s[ACC_Q0 + i] += dq[i]
    s[N_ACC] += 1.0
    if s[N_ACC] >= fp[F_INTERVAL] or k + 1.0 == fp[F_WARMUP]:
        n = s[N_ACC]
        j = s[K_INTERVAL]
        dj = (1.0 - b) / (1.0 - b ** (j + 1.0))
        for i in range(2):
            if mask & ADAPT_SMALL_R:
                s[SMALLR0 + i] = (1.0 - dj) * s[SMALLR0 + i] + dj * s[ACC_R0 + i] / n
        rn = np.empty(4)
        for i in range(4):
            rn[i] = (1.0 - dj) * s[R0 + i] + dj * s[ACC_RR0 + i] / n
        if _sym_pd_floor(rn, 2, fp[F_FLOOR]):
            guards[GUARD_R_PD] += 1
        if mask & ADAPT_R:
            s[R0:R0 + 4] = rn
        for i in range(3):
            if mask & ADAPT_SMALL_Q:
                s[SMALLQ0 + i] = (1.0 - dj) * s[SMALLQ0 + i] + dj * s[ACC_Q0 + i] / n
        s[ACC_R0:ACC_Q0 + 3] = 0.0
        s[N_ACC] = 0.0
        s[K_INTERVAL] = j + 1.0


@njit(cache=True)
def step(s, fp, guards, z_theta, z_i, dt, accel_per_amp, decel_load):
    """One commutation cycle: predict with Eq. 9, update with Eq. 11, adapt with Eq. 12.

    The angle is kept relative to the last corrected edge: that edge is at 0, so the edge that
    ends this cycle is measured at z_theta = pi / 3 (Eq. 10, observing angle and current);
    dt is the measured cycle duration; accel_per_amp = p K_T(n) / J and decel_load =
    p M(n) w_m^2 / J are evaluated at the previous estimate. Returns the normalised innovation
    squared."""
    # --- Eq. 9: transition and input -------------------------------------------------------
    phi = np.array([[1.0, 0.0, accel_per_amp * dt], [dt, 1.0, 0.5 * accel_per_amp * dt * dt], [0.0, 0.0, 1.0]])
    u = np.array([-dt * decel_load, -0.5 * dt * dt * decel_load, 0.0])
    x = s[X0:X0 + 3].copy()
    p = s[P0:P0 + 9].reshape(3, 3).copy()
    q_mat = s[Q0:Q0 + 9].reshape(3, 3)
    q_bias = s[SMALLQ0:SMALLQ0 + 3]
    r_mat = s[R0:R0 + 4].reshape(2, 2)
    r_bias = s[SMALLR0:SMALLR0 + 2]
    # --- Eq. 11: prediction ------------------------------------------------------------------
    x_pred = phi @ x + u + q_bias                                   # X_k,k-1 = Phi X_k-1 + q_k-1
    p_pred = phi @ p @ phi.T + q_mat                                # P_k,k-1 = Phi P Phi^T + Q_k-1
    # H = [[0,1,0],[0,0,1]] (Eq. 10 as we read it: the edge measures the angle): rows 1 and 2
    hx0 = x_pred[1]
    hx1 = x_pred[2]
    innov0 = z_theta - hx0 - r_bias[0]                              # Z~ = Z - H X_k,k-1 - r
    innov1 = z_i - hx1 - r_bias[1]
    s00 = p_pred[1, 1] + r_mat[0, 0]
    s01 = p_pred[1, 2] + r_mat[0, 1]
    s10 = p_pred[2, 1] + r_mat[1, 0]
    s11 = p_pred[2, 2] + r_mat[1, 1]
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    nis = innov0 * (i00 * innov0 + i01 * innov1) + innov1 * (i10 * innov0 + i11 * innov1)
    gain = np.empty((3, 2))                                         # K = P H^T (H P H^T + R)^-1
    for i in range(3):
        a0 = p_pred[i, 1]
        a1 = p_pred[i, 2]
        gain[i, 0] = a0 * i00 + a1 * i10
        gain[i, 1] = a0 * i01 + a1 * i11
    x_new = x_pred.copy()
    for i in range(3):
        x_new[i] += gain[i, 0] * innov0 + gain[i, 1] * innov1       # X_k = X_k,k-1 + K Z~
    # Joseph form of P_k = (I - K H) P_k,k-1 (keeps P symmetric positive semi-definite)
    ikh = np.eye(3)
    for i in range(3):
        ikh[i, 1] -= gain[i, 0]
        ikh[i, 2] -= gain[i, 1]
    p_new = ikh @ p_pred @ ikh.T + gain @ r_mat @ gain.T
    pn = p_new.ravel().copy()
    if _sym_pd_floor(pn, 3, 1e-12):
        guards[GUARD_P_PD] += 1
    s[X0:X0 + 3] = x_new
    s[X0 + 1] -= math.pi / 3.0  # re-reference: the edge just measured is the new angle zero
    s[P0:P0 + 9] = pn
    s[LAST_NIS] = nis
    k = s[K_STEP]
    s[K_STEP] = k + 1.0
    if fp[F_ADAPTIVE] == 0.0:
        return nis
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
    kz0 = gain[:, 0] * innov0 + gain[:, 1] * innov1
    term = np.outer(kz0, kz0) + p_new - phi @ p @ phi.T             # K Z~ Z~^T K^T + P_k - Phi P_k-1 Phi^T
    # Q keeps its physical structure: process noise enters speed and current (theta follows
    # from w through Eq. 9), so only those diagonal entries adapt; the angle entry stays at its
    # nominal value and cross terms at zero. Unconstrained, Q absorbs the edge noise whenever R
    # starts too small (R0 = 0 here) and R is then never learned.
    mask = int(fp[F_ADAPTIVE])
    qn = np.zeros(9)
    qn[4] = s[QN0 + 4]
    band = fp[F_BAND]
    clamped = False
    for i in (0, 2):
        v = (1.0 - d) * q_mat[i, i] + d * term[i, i]
        nominal = s[QN0 + 4 * i]
        lo, hi = nominal / band, nominal * band
        if not v > 0.0:
            guards[GUARD_Q_PD] += 1
            v = lo
        if v < lo:
            v = lo
            clamped = True
        elif v > hi:
            v = hi
            clamped = True
        qn[4 * i] = v
    if clamped:
        guards[GUARD_Q_BAND] += 1
    if mask & ADAPT_Q:
        s[Q0:Q0 + 9] = qn
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
            step(s, fp, guards, math.pi / 3.0, current[k], dt, a, dl)
            w_now = s[X0]
        n_rpm = w_now / pp * 60.0 / (2.0 * math.pi)
        w_m = w_now / pp
        out_pred_t[k] = t_edges[k] + predict_next_s(s, pp * np.interp(n_rpm, speed_tab, kt_tab) / j_inertia,
                                                     pp * np.interp(n_rpm, speed_tab, m_tab) * w_m * w_m / j_inertia)
        out_w[k] = w_now
    return n - 1
