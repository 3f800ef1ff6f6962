"""Commutation predictors that motor firmware ships for Hall sensors, and the variational-Bayes
adaptive Kalman filter: the peers the KF and Sage-Husa are compared with (docs/sage-husa.md).

Every peer has the interface of ``predictors.py``: ``run(t_corrected_s, mean_current_a)`` takes
the corrected edge times (calibration applied) and returns a :class:`PredictionRun` whose
``pred_t_s[k]`` is the predicted instant of edge k + 1 and ``speed_rad_s[k]`` the speed estimate
after edge k (electrical). ``settings`` gives what was set, for the comparison's JSON.

* ``sector_hold`` (VESC ``foc_correct_hall``): at each edge the angle snaps to the edge's
  calibrated angle (the midpoint of the two sector centres the table holds) and is extrapolated
  at 60 deg e over the last sector time: the next edge one last-sector-time later. It is the
  paper's pre-calibration baseline, :class:`PrecalibrationPredictor`, and is not written twice.
* ``moving_average`` (ST MCSDK ``hall_speed_pos_fdbk.c``): speed from the mean of a FIFO of the
  last ``fifo_edges`` edge periods (one electrical period = 6), the angle set to the edge's at
  each edge and integrated between edges at that speed.
* ``pll`` (ODrive ``Encoder::update``, moteus ``motor_position.h``): a second-order phase-locked
  loop on the calibrated edge positions with kp = 2 bw, ki = kp^2 / 4 (a critically damped double
  pole at -bw). A Hall sensor gives a position only at its edges, so the loop's phase detector
  is sampled there: the loop is the edge-sampled form of that PLL with both poles at
  z = exp(-bw dt) over the last edge interval dt (alpha = 1 - z^2, beta = (1 - z)^2, which
  tend to kp dt and ki dt^2 at small bw dt). Option ``two_edge`` (moteus): the loop takes the
  midpoint of the last two edges (one rising, one falling: the sequence alternates), which
  cancels a rise/fall delay asymmetry to first order.
* ``vb_akf``: Huang, Zhang, Wu, Chambers, "A Novel Adaptive Kalman Filter With Inaccurate
  Process and Measurement Noise Covariance Matrices", IEEE TAC 63(2), 2018,
  DOI 10.1109/TAC.2017.2730480, Algorithm 1, on the paper's model (Eq. 9 transition, Eq. 10
  observation of the edge angle and the cycle's mean current).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import filters as F
from .model import SECTOR_RAD, MotorModel
from .predictors import FilterSettings, PrecalibrationPredictor, PredictionRun


def _checked(t_corrected_s, mean_current_a=None) -> tuple[np.ndarray, np.ndarray]:
    t = np.ascontiguousarray(t_corrected_s, dtype=float)
    cur = np.zeros(t.size) if mean_current_a is None else np.ascontiguousarray(mean_current_a, dtype=float)
    if t.size != cur.size:
        raise ValueError("one mean current per edge is needed")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        k = int(np.nonzero(np.diff(t) <= 0)[0][0]) + 1
        raise ValueError(f"edge times must increase (edge {k}: {t[k]!r} after {t[k - 1]!r})")
    return t, cur


class SectorHoldPredictor(PrecalibrationPredictor):
    """VESC's hall interpolation: next edge one last-sector-time after this one (no setting)."""

    name = "sector_hold"

    @property
    def settings(self) -> dict:
        return {}


@njit(cache=True)
def _moving_average(t, n_fifo, pred, w):
    acc, n = 0.0, 0
    for k in range(1, t.size):
        acc += t[k] - t[k - 1]
        n += 1
        if n > n_fifo:
            acc -= t[k - n_fifo] - t[k - n_fifo - 1]
            n = n_fifo
        period = acc / n                       # mean of the FIFO of the last n edge periods
        pred[k] = t[k] + period
        w[k] = SECTOR_RAD / period



class MovingAveragePredictor:
    """MCSDK's hall speed: the mean over a FIFO of the last ``fifo_edges`` edge periods."""

    name = "moving_average"

    def __init__(self, fifo_edges: int = 6):
        if not (isinstance(fifo_edges, (int, np.integer)) and fifo_edges >= 1):
            raise ValueError(f"fifo_edges must be an integer >= 1, got {fifo_edges!r}")
        self.fifo_edges = int(fifo_edges)

    @property
    def settings(self) -> dict:
        return {"fifo_edges": self.fifo_edges}

    def run(self, t_corrected_s, mean_current_a=None) -> PredictionRun:
        t, _ = _checked(t_corrected_s, mean_current_a)
        pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
        _moving_average(t, self.fifo_edges, pred, w)
        return PredictionRun(pred, w, {})


@njit(cache=True)
def _pll(t, bw, two_edge, pred, w_out):
    # position in rad e counted from edge 0 (edge k at k pi / 3); the loop's own clock t_m is the
    # instant its measurement refers to (the edge, or the midpoint of the last two edges)
    theta, w, t_m = 0.0, 0.0, t[0]
    for k in range(1, t.size):
        if two_edge and k >= 2:
            z_t, z = 0.5 * (t[k] + t[k - 1]), (k - 0.5) * SECTOR_RAD
        else:
            z_t, z = t[k], k * SECTOR_RAD
        if k == 1 or (two_edge and k == 2):
            # start-up: the loop starts locked to the first measured interval
            w = SECTOR_RAD / (t[k] - t[k - 1])
            theta, t_m = z, z_t
        else:
            dt = z_t - t_m
            theta += w * dt                            # integrate between measurements
            e = z - theta                              # phase detector
            p = math.exp(-bw * dt)                     # both poles at exp(-bw dt)
            theta += (1.0 - p * p) * e                 # alpha = 1 - p^2  (-> kp dt = 2 bw dt)
            w += (1.0 - p) * (1.0 - p) / dt * e        # beta / dt, beta = (1 - p)^2 (-> ki dt^2)
            t_m = z_t
        w_out[k] = w
        ahead = (k + 1) * SECTOR_RAD - theta        # angle to the next edge
        pred[k] = t_m + max(ahead, 0.0) / max(w, 1e-9)


class PllPredictor:
    """Second-order PLL on the calibrated edge positions (ODrive, moteus); ``bandwidth_rad_s`` is
    the user's knob; ``two_edge`` the moteus rise+fall option."""

    name = "pll"

    def __init__(self, bandwidth_rad_s: float = 300.0, two_edge: bool = False):
        if not (math.isfinite(bandwidth_rad_s) and bandwidth_rad_s > 0):
            raise ValueError(f"bandwidth_rad_s must be positive and finite, got {bandwidth_rad_s!r}")
        self.bandwidth_rad_s, self.two_edge = float(bandwidth_rad_s), bool(two_edge)

    @property
    def settings(self) -> dict:
        bw = self.bandwidth_rad_s
        return {"bandwidth_rad_s": bw, "kp_per_s": 2.0 * bw, "ki_per_s2": bw * bw, "two_edge": self.two_edge}

    def run(self, t_corrected_s, mean_current_a=None) -> PredictionRun:
        t, _ = _checked(t_corrected_s, mean_current_a)
        pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
        if t.size > 1:
            _pll(t, self.bandwidth_rad_s, self.two_edge, pred, w)
        return PredictionRun(pred, w, {})


# --- VB-AKF (Huang et al. 2018, Algorithm 1) ------------------------------------------------------

@njit(cache=True, inline="always")
def _inv_small(s, m, out):
    """out = s^-1 for the 1 x 1 or 2 x 2 innovation covariance."""
    if m == 1:
        out[0, 0] = 1.0 / s[0, 0]
        return
    det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
    out[0, 0], out[1, 1] = s[1, 1] / det, s[0, 0] / det
    out[0, 1], out[1, 0] = -s[0, 1] / det, -s[1, 0] / det


@njit(cache=True)
def _vb_akf(t, cur, fp, tables, q0, r0, p0, tau, rho, n_iter, m, pred, w_out, guards, r_out):
    """Algorithm 1 of Huang et al. 2018 per commutation cycle on the paper's Eq. 9 model.

    State x = [w, theta, I] (theta from the last edge, as in ``filters.step``); measurement
    z = [pi / 3, I_meas] with H = [[0, 1, 0], [0, 0, 1]], or z = pi / 3 alone (m = 1: the
    kinematic run, no current). q0: nominal Q (3 x 3); r0: the prior's nominal R (m x m).
    H selects state entries 1 .. m, so H M H^T is M[1:1+m, 1:1+m] and M H^T is M[:, 1:1+m]; the
    work arrays are allocated once (a step allocates nothing)."""
    n = 3
    x, x_pred, xi, dx = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    P, Phi, tmp, P_pred, T_pr = p0.copy(), np.eye(n), np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    Pi, P_t, IKH = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    K = np.zeros((n, m))
    z, innov, r = np.zeros(m), np.zeros(m), np.zeros(m)
    U_pr, U_i, R_t, S, S_inv = (np.zeros((m, m)), np.zeros((m, m)), np.zeros((m, m)), np.zeros((m, m)),
                                np.zeros((m, m)))
    # prior of R: inverse Wishart with u_0 dof and scale U_0 = (u_0 - m - 1) R_0 (its mean R_0)
    u = tau + m + 1.0
    U = (u - m - 1.0) * r0
    st = np.zeros(F.N_STATE)                     # only X is read by filters.predict_next_s
    for k in range(1, t.size):
        dt = t[k] - t[k - 1]
        if k == 1:
            x[0], x[1], x[2] = SECTOR_RAD / dt, 0.0, cur[k]
        else:
            a, dl = F.coefficients(x[0], fp, tables)
            Phi[0, 2], Phi[1, 0], Phi[1, 2] = a * dt, dt, 0.5 * a * dt * dt
            # Step 1: x_k|k-1 = F x_k-1|k-1 (+ the load input of Eq. 9)
            x_pred[0] = x[0] + Phi[0, 2] * x[2] - dt * dl
            x_pred[1] = dt * x[0] + x[1] + Phi[1, 2] * x[2] - 0.5 * dt * dt * dl
            x_pred[2] = x[2]
            # Step 2: P~_k|k-1 = F P_k-1|k-1 F^T + Q~_k-1 (Q~: the nominal, inaccurate Q)
            for i in range(n):
                for j in range(n):
                    tmp[i, j] = Phi[i, 0] * P[0, j] + Phi[i, 1] * P[1, j] + Phi[i, 2] * P[2, j]
            for i in range(n):
                for j in range(n):
                    P_pred[i, j] = tmp[i, 0] * Phi[j, 0] + tmp[i, 1] * Phi[j, 1] + tmp[i, 2] * Phi[j, 2] + q0[i, j]
            z[0] = SECTOR_RAD
            if m == 2:
                z[1] = cur[k]
            for i in range(m):
                innov[i] = z[i] - x_pred[1 + i]      # z - H x_k|k-1
            # Step 3: t_k|k-1 = n + tau + 1, T_k|k-1 = tau P~_k|k-1;
            #         u_k|k-1 = rho (u_k-1|k-1 - m - 1) + m + 1, U_k|k-1 = rho U_k-1|k-1
            t_pr = n + tau + 1.0
            u_pr = rho * (u - m - 1.0) + m + 1.0
            for i in range(n):
                xi[i] = x_pred[i]
                for j in range(n):
                    T_pr[i, j] = tau * P_pred[i, j]
                    Pi[i, j] = P_pred[i, j]
            for i in range(m):
                for j in range(m):
                    U_pr[i, j] = rho * U[i, j]
            # Step 5 and 7: t^(i+1) = t_k|k-1 + 1, u^(i+1) = u_k|k-1 + 1 (the same every iteration)
            t_i, u_i = t_pr + 1.0, u_pr + 1.0
            for _ in range(n_iter):
                for i in range(n):
                    dx[i] = xi[i] - x_pred[i]
                for i in range(m):
                    r[i] = z[i] - xi[1 + i]
                # Step 4: A = P^(i) + (x^(i) - x_k|k-1)(x^(i) - x_k|k-1)^T; Step 5: T^(i+1) = A + T_k|k-1;
                # Step 8: E[P_k|k-1^-1] = (t - n - 1) T^-1; Step 9: P~^(i+1) = E[P^-1]^-1
                for i in range(n):
                    for j in range(n):
                        P_t[i, j] = (Pi[i, j] + dx[i] * dx[j] + T_pr[i, j]) / (t_i - n - 1.0)
                # Step 6: B = (z - H x^(i))(z - H x^(i))^T + H P^(i) H^T; Step 7: U^(i+1) = B + U_k|k-1;
                # Step 8: E[R^-1] = (u - m - 1) U^-1; Step 9: R~^(i+1) = E[R^-1]^-1
                for i in range(m):
                    for j in range(m):
                        U_i[i, j] = r[i] * r[j] + Pi[1 + i, 1 + j] + U_pr[i, j]
                        R_t[i, j] = U_i[i, j] / (u_i - m - 1.0)
                        S[i, j] = P_t[1 + i, 1 + j] + R_t[i, j]
                # Step 10: K = P~ H^T (H P~ H^T + R~)^-1
                _inv_small(S, m, S_inv)
                for i in range(n):
                    for j in range(m):
                        v = 0.0
                        for q in range(m):
                            v += P_t[i, 1 + q] * S_inv[q, j]
                        K[i, j] = v
                # Step 11: x^(i+1) = x_k|k-1 + K (z - H x_k|k-1)
                for i in range(n):
                    v = x_pred[i]
                    for q in range(m):
                        v += K[i, q] * innov[q]
                    xi[i] = v
                # Step 12: P^(i+1) = P~ - K H P~, in Joseph form (the same in exact arithmetic):
                # (I - K H) P~ (I - K H)^T + K R~ K^T
                for i in range(n):
                    for j in range(n):
                        IKH[i, j] = 1.0 if i == j else 0.0
                    for q in range(m):
                        IKH[i, 1 + q] -= K[i, q]
                for i in range(n):
                    for j in range(n):
                        tmp[i, j] = IKH[i, 0] * P_t[0, j] + IKH[i, 1] * P_t[1, j] + IKH[i, 2] * P_t[2, j]
                for i in range(n):
                    for j in range(i, n):
                        v = tmp[i, 0] * IKH[j, 0] + tmp[i, 1] * IKH[j, 1] + tmp[i, 2] * IKH[j, 2]
                        for p_ in range(m):
                            for q in range(m):
                                v += K[i, p_] * R_t[p_, q] * K[j, q]
                        Pi[i, j] = v
                        Pi[j, i] = v
            # Step 13: x_k|k = x^(N), P_k|k = P^(N), u_k|k = u^(N), U_k|k = U^(N)
            for i in range(n):
                x[i] = xi[i]
                for j in range(n):
                    P[i, j] = Pi[i, j]
            u = u_i
            for i in range(m):
                for j in range(m):
                    U[i, j] = U_i[i, j]
            x[1] -= SECTOR_RAD                       # re-reference: this edge is the new zero
            if not np.all(np.isfinite(x)) or F.lost_lock(x[0], innov[0]):
                # lost (filters.lost_lock): restart from the last interval, R from its prior: the
                # residuals that raised R were the lost state's error, not the edges' noise (Step 6
                # adds them to B, R grew, the gain on the edges fell and the state ran a sector
                # ahead: 40-60 deg e RMS on every real capture before this restart)
                guards[0] += 1
                x[0], x[1], x[2] = SECTOR_RAD / dt, 0.0, cur[k]
                P[:, :] = p0
                u = tau + m + 1.0
                for i in range(m):
                    for j in range(m):
                        U[i, j] = (u - m - 1.0) * r0[i, j]
        a, dl = F.coefficients(x[0], fp, tables)
        st[F.ST.X], st[F.ST.X + 1], st[F.ST.X + 2] = x[0], x[1], x[2]
        pred[k] = t[k] + F.predict_next_s(st, a, dl)
        w_out[k] = x[0]
    r_out[:, :] = U / (u - m - 1.0)                 # R's posterior mean E[R] at the last edge


class VbAkfPredictor:
    """Variational-Bayes adaptive KF (Huang et al. 2018, Algorithm 1) on the paper's model.

    ``q0_diag``: the nominal Q~ (per cycle: (rad/s)^2, rad^2, A^2); ``r0_diag``: the mean of R's
    inverse-Wishart prior (angle rad^2, current A^2); ``tau`` the tuning parameter of P's prior,
    ``rho`` R's forgetting factor, ``iterations`` the variational iterations N. With
    ``use_current`` False the current is not observed (m = 1)."""

    name = "vb_akf"

    def __init__(self, model: MotorModel, q0_diag=(1e-2, 1e-9, 1e-3), r0_diag=(1e-4, 1.0), tau: float = 3.0,
                 rho: float = 1.0 - math.exp(-4.0), iterations: int = 10, p0_diag=(5e4, 5e4, 5e4),
                 use_current: bool = True):
        if not tau > 0:
            raise ValueError(f"tau must be > 0, got {tau!r}")
        if not 0.0 < rho <= 1.0:
            raise ValueError(f"rho must be in (0, 1], got {rho!r}")
        if not (isinstance(iterations, (int, np.integer)) and iterations >= 1):
            raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
        for name, v in (("q0_diag", q0_diag), ("r0_diag", r0_diag), ("p0_diag", p0_diag)):
            if any(not (math.isfinite(x) and x > 0) for x in v):
                raise ValueError(f"{name} must be positive and finite, got {v!r}")
        self.model = model
        self.q0_diag, self.r0_diag, self.p0_diag = tuple(map(float, q0_diag)), tuple(map(float, r0_diag)), p0_diag
        self.tau, self.rho, self.iterations, self.use_current = float(tau), float(rho), int(iterations), use_current
        self.fp = FilterSettings().params(False, model.pole_pairs, model.inertia_kg_m2, model.friction_n_m_s_per_rad)
        speed, kt, m = model.arrays()
        self.tables = np.ascontiguousarray(np.vstack((speed, kt, m)), dtype=float)

    @property
    def settings(self) -> dict:
        return {"q0_diag": list(self.q0_diag), "r0_diag": list(self.r0_diag), "tau": self.tau, "rho": self.rho,
                "iterations": self.iterations, "p0_diag": list(self.p0_diag), "use_current": self.use_current}

    def run(self, t_corrected_s, mean_current_a=None) -> PredictionRun:
        t, cur = _checked(t_corrected_s, mean_current_a)
        m = 2 if self.use_current else 1
        pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
        guards = np.zeros(1, dtype=np.int64)
        r_learned = np.diag(self.r0_diag[:m])
        if t.size > 1:
            _vb_akf(t, cur, self.fp, self.tables, np.diag(self.q0_diag), np.diag(self.r0_diag[:m]),
                    np.diag(np.asarray(self.p0_diag, dtype=float)), self.tau, self.rho, self.iterations, m,
                    pred, w, guards, r_learned)
        #: R's posterior mean after the last edge (rad^2 for the angle; A^2 for the current)
        self.r_learned = r_learned
        return PredictionRun(pred, w, {"restarts": int(guards[0])})
