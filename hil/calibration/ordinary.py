"""Calibration from an ordinary run: Hall capture times only, no set point, no encoder.

A logic analyser on the three Hall lines records ramps, speed cycles and reversals, not steady
operating points. Here the rotor's trajectory is modelled instead of assumed steady: within each
run of constant direction the capture time is a smooth function of the travelled electrical
angle (a cubic B-spline with a knot every few electrical cycles), fitted jointly with the
per-edge deviations by linear least squares:

    t_k = T_run(psi_k) + tau_k * dir * offset[label_k] + tau_k * dir * pole[b_k] + (+-D/2)

``psi_k`` is the ideal travelled angle of edge k (60 deg e steps), ``tau_k = dT/dpsi`` the time per
electrical degree there (from the previous pass: the model is linear once it is known; two passes
settle it), ``label_k`` which sensor boundary it is (A, C, B, A, C, B over an electrical turn),
``b_k`` the magnet pole, and ``D`` the rise-minus-fall delay difference (a time). The static
offsets trail in angle whatever the speed; the delay trails by ``D * speed``: the two are told
apart by how the rise-fall asymmetry grows with speed, which needs the run to span a speed range.

What capture times cannot give (a common lag of all edges, the absolute installation offset, the
common part of the two delays, armature reaction) is listed as not determined, never guessed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import interpolate, linalg, sparse, stats
from scipy.sparse import linalg as sparse_linalg

from bldc import edges
from bldc.reasons import Reason

from .corrections import SENSORS, Corrections
from .result import (
    ORDINARY_METHOD,
    Calibration,
    Estimate,
    Halves,
    IndependentDelay,
    OrdinaryAssumptions,
    OrdinaryFindings,
    Refusal,
    Stationarity,
)
from .stats import BIC_MIN, bic_gain, inliers
from .refusals import (
    POLE_OFFSET_BOUND_DEG_E,
    Circuit,
    delay_bound_s,
    delay_refusal,
    installation_refusal,
    pole_table_refusal,
)
from .uncertainty import (
    MODEL_WEIGHT_IGNORED,
    bic_weight,
    block_starts,
    robust_fit,
    stretch_jackknife_stderr,
    with_model_choice,
)

#: the edge decoding (bit order, glitches, invalid states, stalls, reversals) is ``bldc.edges``
SENSOR_OF_BOUNDARY = edges.SENSOR_OF_BOUNDARY
HallSteps = edges.HallSteps
pole_of_boundary = edges.pole_of_boundary
#: runs shorter than this (edges) are not fitted: four electrical cycles
MIN_RUN_EDGES = edges.MIN_RUN_EDGES
#: spline knot spacing, electrical cycles: wide enough that the 6-edge pattern of the sensors is
#: not absorbed by the trajectory (its knots are 4 pattern periods apart), narrow enough to follow
#: a speed cycle of the captures (the speed changes by a few percent per knot interval)
KNOT_CYCLES = 4
#: the speed range (highest over lowest 5-95 % electrical speed) below which a delay (growing
#: with speed) and a constant angle cannot be told apart
MIN_SPEED_RATIO = 1.5


class OrdinaryRunError(ValueError):
    """The capture cannot be analysed; the message says why."""


def hall_steps(t_s: np.ndarray, sensor: np.ndarray, rising: np.ndarray) -> HallSteps:
    """The capture's edges decoded by ``bldc.edges.decode_edges`` (runs of four electrical cycles
    or more kept); a capture that cannot be read raises ``OrdinaryRunError``."""
    try:
        return edges.decode_edges(t_s, sensor, rising, min_run_edges=MIN_RUN_EDGES)
    except edges.HallEdgeError as e:
        raise OrdinaryRunError(f"{e} (four electrical cycles)" if "edges:" in str(e) else str(e)) from None


def sum_zero_basis(k: int) -> np.ndarray:
    """k x (k - 1) columns spanning the vectors that sum to zero (Helmert-like)."""
    q, _ = np.linalg.qr(np.column_stack([np.ones(k), np.eye(k)[:, : k - 1]]))
    return q[:, 1:k]


@dataclass
class Fit:
    """One joint fit: the named effect parameters with their covariance, and the per-edge parts."""

    names: list[str]
    coef: np.ndarray
    cov: np.ndarray
    residual_s: np.ndarray  #: per used edge, time
    tau_s_per_deg: np.ndarray  #: per used edge
    index: np.ndarray  #: edge indices used
    sigma_s: np.ndarray  #: per used edge, the noise sd the weights assumed
    trail_deg_e: np.ndarray  #: per used edge, the angle the effects trail by (model)
    outliers: int = 0
    #: per used edge, the part of ``trail_deg_e`` that the sensors cause (the rotor's own speed
    #: ripple left out: a calibration corrects sensors, not the rotor)
    sensor_trail_deg_e: np.ndarray | None = None
    #: per contiguous stretch of the used edges (``uncertainty.block_starts``), its share of the
    #: effects' normal equations: the score (effect columns, splines projected out, times the
    #: weighted residuals; rows sum to about zero) and the information (those columns' cross
    #: product; they sum to ``information``): what a block covariance is built from
    block_score: np.ndarray | None = None
    block_information: np.ndarray | None = None
    information: np.ndarray | None = None
    #: how ``cov`` was obtained (``uncertainty.robust_fit`` replaces the least-squares one)
    stderr_method: str = "weighted least squares (white residuals)"

    def get(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.coef[i]), float(np.sqrt(self.cov[i, i]))

    def combination(self, weights: dict[str, float]) -> tuple[float, float]:
        w = np.zeros(len(self.names))
        for n, v in weights.items():
            w[self.names.index(n)] = v
        return float(w @ self.coef), float(np.sqrt(max(w @ self.cov @ w, 0.0)))


@dataclass
class Effects:
    """Which effect columns a fit carries."""

    static: bool = True  #: an offset per sensor boundary and direction (sum zero)
    delay: bool = True  #: the rise-minus-fall delay difference
    pole_pairs: int | None = None  #: pole offsets (two sum-zero sets: N and S boundaries)
    #: the static offsets split as the gap diagnosis names them (used instead of ``static``):
    install: bool = False  #: per sensor, both polarities alike (installation offset)
    switching: bool = False  #: per sensor, rise minus fall, constant in angle (switching points, hysteresis)
    #: a speed ripple locked to the sectors (six-step commutation torque ripple): the angle at each
    #: sector boundary moves by a torque pattern over J w^2, i.e. per boundary times (w_ref / w)^2
    ripple: bool = False


def knot_spacing_edges(pole_pairs: int | None, knot_cycles: float = KNOT_CYCLES) -> float:
    """Edges between trajectory knots (the same with pole offsets: the joint fit keeps the pole
    pattern apart from the trajectory; what the spline could absorb shows in the standard errors)."""
    del pole_pairs
    return 6.0 * knot_cycles


def _knots(x: np.ndarray, spacing: float) -> np.ndarray:
    """Cubic spline knots over [x0, x1] at about ``spacing``, clamped at the ends."""
    lo, hi = float(x.min()), float(x.max())
    n_int = max(int(round((hi - lo) / spacing)), 1)
    inner = np.linspace(lo, hi, n_int + 1)
    return np.concatenate([[lo] * 3, inner, [hi] * 3])


def effect_columns(steps: HallSteps, idx: np.ndarray, tau: np.ndarray, eff: Effects) -> tuple[np.ndarray, list[str]]:
    """The effect columns (time per unit parameter) of edges ``idx``."""
    d = steps.direction[idx].astype(float)
    lab = steps.label[idx]
    cols, names = [], []
    if eff.static:
        for sgn, dname in ((1, "fwd"), (-1, "rev")):
            here = steps.direction[idx] == sgn
            if not here.any():
                continue
            z = sum_zero_basis(6)
            cols.append((np.eye(6)[lab] @ z) * (tau * d * here)[:, None])
            names += [f"static_{dname}_{j}" for j in range(5)]
    sensor = SENSOR_OF_BOUNDARY[np.mod(lab, 3)]
    for sgn, dname in ((1, "fwd"), (-1, "rev")):
        here = steps.direction[idx] == sgn
        if not here.any():
            continue
        if eff.install and not eff.static:
            cols.append((np.eye(3)[sensor] @ sum_zero_basis(3)) * (tau * d * here)[:, None])
            names += [f"inst_{dname}_{j}" for j in range(2)]
        if eff.switching and not eff.static:
            half = np.where(steps.rising[idx], 0.5, -0.5)  # trails on rising edges, leads on falling
            cols.append(np.eye(3)[sensor] * (tau * half * here)[:, None])
            names += [f"switch_{dname}_{SENSORS[x]}" for x in range(3)]
    if eff.ripple:
        for sgn, dname in ((1, "fwd"), (-1, "rev")):
            here = steps.direction[idx] == sgn
            if here.any():
                # (w_ref / w)^2 with w_ref = 10 Hz electrical: the coefficient is the angle at 10 Hz
                scale = (10.0 * 360.0 * tau) ** 2
                cols.append((np.eye(6)[lab] @ sum_zero_basis(6)) * (tau * scale * here)[:, None])
                names += [f"ripple_{dname}_{j}" for j in range(5)]
    if eff.delay:
        cols.append(np.where(steps.rising[idx], 0.5, -0.5)[:, None])
        names.append("delay_diff_s")
    if eff.pole_pairs:
        p = eff.pole_pairs
        b = pole_of_boundary(steps.boundary[idx], p)
        z = sum_zero_basis(p)
        for parity in (0, 1):
            ind = np.zeros((idx.size, p))
            sel = np.mod(b, 2) == parity
            ind[sel, b[sel] // 2] = 1.0
            cols.append((ind @ z) * (tau * d)[:, None])
            names += [f"pole_{parity}_{j}" for j in range(p - 1)]
    if not cols:
        return np.zeros((idx.size, 0)), []
    return np.column_stack(cols), names


def fit_ordinary(
    steps: HallSteps,
    eff: Effects,
    *,
    select: np.ndarray | None = None,
    fixed: dict[str, float] | None = None,
    fixed_from: Fit | None = None,
    tick_s: float | None = None,
    knot_cycles: float = KNOT_CYCLES,
    spacing_edges: float | None = None,
    passes: int = 3,
) -> Fit:
    """Joint weighted least squares of the trajectory splines and the effects on the edges of
    ``select`` (a boolean mask; default all used edges). With ``fixed_from``, the effect part of
    that earlier fit is subtracted first and only the trajectories are fitted (a held-out check)."""
    use = steps.used() if select is None else (steps.used() & select)
    idx = np.nonzero(use)[0]
    runs = [r for r in np.unique(steps.run[idx]) if np.sum(steps.run[idx] == r) >= MIN_RUN_EDGES]
    idx = idx[np.isin(steps.run[idx], runs)]
    if idx.size < MIN_RUN_EDGES:
        raise OrdinaryRunError(f"only {idx.size} usable edges in runs of {MIN_RUN_EDGES} or more")
    spacing = spacing_edges or knot_spacing_edges(eff.pole_pairs, knot_cycles)
    t = steps.t_s[idx]
    t0 = t.min()
    # spline design, block diagonal over runs; x = travelled angle in sectors (60 deg e)
    blocks = []
    x_all = np.empty(idx.size)
    for r in runs:
        sel = steps.run[idx] == r
        x = steps.direction[idx][sel] * steps.boundary[idx][sel].astype(float)
        x = x - x.min()
        x_all[sel] = x
        # a short run gets a single cubic (no interior knot beyond what its length allows)
        knots = _knots(x, min(spacing, max(x.max(), 1.0)))
        blocks.append((sel, knots))
    n_spline = sum(k.size - 4 for _, k in blocks)
    tau = np.full(idx.size, np.nan)
    # first guess of tau: the local sector time (mean of the two sectors around each edge) / 60 deg
    for sel, _ in blocks:
        tau[sel] = 1.0 / (360.0 * edges.electrical_speed_hz(t[sel], window_sectors=2))
    tau_data = tau.copy()
    sigma = np.ones(idx.size)
    fixed_part = np.zeros(idx.size)
    keep = np.ones(idx.size, dtype=bool)
    outliers = 0
    coef = np.zeros(0)
    names: list[str] = []
    cov = np.zeros((0, 0))
    resid = np.zeros(idx.size)
    for it in range(passes):
        e_cols, names = effect_columns(steps, idx, tau, eff) if fixed_from is None else (np.zeros((idx.size, 0)), [])
        if fixed_from is not None:
            f_cols, f_names = effect_columns(steps, idx, tau, eff)
            fixed_part = f_cols @ np.array(
                [fixed_from.coef[fixed_from.names.index(n)] if n in fixed_from.names else 0.0 for n in f_names]
            )
        s_mat = sparse.block_diag(
            [interpolate.BSpline.design_matrix(x_all[sel], knots, 3) for sel, knots in blocks], format="csr"
        )
        y = (t - t0) - fixed_part
        w = keep / sigma
        sol = _solve(s_mat, e_cols, y, w)
        resid = y - s_mat @ sol[:n_spline] - e_cols @ sol[n_spline:]
        solved = (s_mat, e_cols, w, resid)
        # noise per speed band: quantisation and jitter grow differently with speed
        sigma = _band_sigma(resid, tau, keep, tick_s)
        # outliers (a missed edge, a bump): beyond the project's cut (hil.calibration.stats), left out of the next pass
        new_keep = inliers(resid, sigma)
        outliers = int(np.sum(~new_keep))
        keep = new_keep
        # the trajectory's slope at each edge (the deviations move edges along it)
        col = 0
        for sel, knots in blocks:
            nb = knots.size - 4
            spl = interpolate.BSpline(knots, sol[col : col + nb], 3)
            # where the spline's slope strays from the sector times (a run's ragged end), the
            # sector times are the better guess of the local speed
            local = tau_data[sel]
            tau[sel] = np.clip(spl.derivative()(x_all[sel]) / 60.0, 0.5 * local, 2.0 * local)
            col += nb
        coef = sol[n_spline:]
        w = keep / sigma
        dof = max(int(keep.sum()) - n_spline - e_cols.shape[1], 1)
        s2 = float(np.sum((resid * w) ** 2)) / dof
        cov = s2 * _effect_precision_inv(s_mat, e_cols, w)
    # residuals are shrunk by the parameters fitted (a spline coefficient every few cycles): the
    # same degrees-of-freedom factor as the least-squares variance
    blocks = _block_parts(*solved, np.sqrt(float(keep.sum()) / dof))
    e_cols, _ = effect_columns(steps, idx, tau, eff)
    trail_s = e_cols @ coef if fixed_from is None else fixed_part
    sensor = np.array([not n.startswith("ripple_") for n in names], dtype=bool)
    sensor_s = e_cols[:, sensor] @ coef[sensor] if fixed_from is None and names else trail_s
    return Fit(names, coef, cov, resid, tau, idx, sigma, trail_s / tau, outliers, sensor_s / tau, *blocks)


def _schur(s_mat, e_cols: np.ndarray, w: np.ndarray):
    """The weighted normal equations with the spline block eliminated (it is banded: a sparse
    LU of it costs little even for a million edges)."""
    sw = sparse.diags(w) @ s_mat
    ew = e_cols * w[:, None]
    a = (sw.T @ sw).tocsc()
    a = a + sparse.identity(a.shape[0], format="csc") * (1e-12 * float(a.diagonal().max() or 1.0))
    lu = sparse_linalg.splu(a)
    b = np.asarray(sw.T @ ew)
    z_b = lu.solve(b) if b.size else np.zeros_like(b)
    m = ew.T @ ew - b.T @ z_b
    return sw, ew, lu, b, z_b, m


def _solve(s_mat, e_cols: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares of ``y`` on [splines | effects]: the spline coefficients, then the effects."""
    sw, ew, lu, b, z_b, m = _schur(s_mat, e_cols, w)
    yw = y * w
    z_y = lu.solve(np.asarray(sw.T @ yw))
    if e_cols.shape[1]:
        coef = linalg.solve(m, ew.T @ yw - b.T @ z_y, assume_a="sym")
        return np.concatenate([z_y - z_b @ coef, coef])
    return z_y


def _effect_precision_inv(s_mat, e_cols: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(X' W X)^-1 restricted to the effects: the inverse of their Schur complement."""
    if not e_cols.shape[1]:
        return np.zeros((0, 0))
    *_, m = _schur(s_mat, e_cols, w)
    return linalg.pinvh(m)


def _block_parts(s_mat, e_cols: np.ndarray, w: np.ndarray, resid: np.ndarray, resid_scale: float):
    """Per contiguous stretch of the edges: the effects' score and information (the effect columns
    weighted, with the splines projected out), and the whole information."""
    p = e_cols.shape[1]
    starts = block_starts(resid.size)
    if not p or starts.size < 2:
        return None, None, None
    sw, ew, _, _, z_b, m = _schur(s_mat, e_cols, w)
    projected = ew - np.asarray(sw @ z_b)
    score = np.add.reduceat(projected * (resid_scale * w * resid)[:, None], starts, axis=0)
    info = np.stack([a.T @ a for a in np.split(projected, starts[1:])])
    return score, info, m


def _band_sigma(resid: np.ndarray, tau: np.ndarray, keep: np.ndarray, tick_s: float | None) -> np.ndarray:
    """Robust noise sd per decile of tau (speed), floored at the timer's quantisation."""
    out = np.empty(resid.size)
    edges = np.quantile(tau, np.linspace(0, 1, 11))
    band = np.clip(np.searchsorted(edges, tau, side="right") - 1, 0, 9)
    floor = (tick_s or 0.0) / np.sqrt(12.0)
    for b in range(10):
        sel = band == b
        good = sel & keep
        r = resid[good] if good.sum() > 5 else resid[sel]
        mad = 1.4826 * np.median(np.abs(r - np.median(r))) if r.size else 0.0
        out[sel] = max(mad, floor, 1e-12)
    return out


# --- what a capture gives ------------------------------------------------------------------


def speed_hz_e(steps: HallSteps) -> np.ndarray:
    """Electrical speed (Hz) at each used edge, from its neighbours (for reporting)."""
    return edges.electrical_speed_hz(steps.t_s, window_sectors=2, run=steps.run)


def independent_delay(steps: HallSteps) -> IndependentDelay | None:
    """The method cross-check (``result.IndependentDelay``), or None with fewer than ten windows."""
    ws, hs = [], []
    for r in np.unique(steps.run[steps.run >= 0]):
        idx = np.nonzero(steps.run == r)[0]
        t = steps.t_s[idx]
        rise = steps.rising[idx]
        widths = np.diff(t)
        starts = np.nonzero(rise[:-7])[0] if idx.size > 8 else np.array([], dtype=int)
        for s in starts:
            w = widths[s : s + 7]
            if w.size < 7:
                continue
            rf = (0.5 * w[0] + w[2] + w[4] + 0.5 * w[6]) / 3.0  # rise-to-fall sectors
            fr = (w[1] + w[3] + w[5]) / 3.0  # fall-to-rise sectors
            sector = (rf + fr) / 2.0
            if max(w) > 2.0 * min(w) * 1.5:  # a jerky window (cogging, a bump): not smooth motion
                continue
            omega = 60.0 / sector  # deg e per second
            ws.append(omega)
            hs.append((fr - rf) / 2.0 * omega)  # half the width difference, deg e
    if len(ws) < 10:
        return None
    ws, hs = np.array(ws), np.array(hs)
    res = stats.linregress(ws, hs)
    f = ws / 360.0
    # overlapping windows of correlated edges: the errors from a delete-a-stretch jackknife
    def slope_and_intercept(keep: np.ndarray) -> tuple[float, float]:
        r = stats.linregress(ws[keep], hs[keep])
        return r.slope, r.intercept

    jackknife = stretch_jackknife_stderr(slope_and_intercept, ws.size)
    slope_se, intercept_se = (res.stderr, res.intercept_stderr) if jackknife is None else jackknife
    return IndependentDelay(
        float(res.slope),
        float(slope_se),
        float(res.intercept),
        float(intercept_se),
        int(ws.size),
        (float(np.percentile(f, 5)), float(np.percentile(f, 95))),
    )


def choose_pole_pairs(
    steps: HallSteps,
    tick_s: float | None,
    base: Fit,
    knot_cycles: float,
    max_pole_pairs: int = 24,
    ripple: bool = False,
) -> tuple[int | None, Reason]:
    """The pole-pair count whose pole-offset pattern the capture shows best (BIC), if any.

    A magnet's pole boundaries repeat every mechanical turn (6 p edges); without the motor's
    pole count, each candidate p is fitted on the same trajectory splines as ``base`` and the
    smallest BIC kept, provided it beats the model without pole offsets by a clear margin
    (``hil.calibration.stats.BIC_MIN``, with the noise of ``base``)."""
    n_edges = int(steps.used().sum())
    best: tuple[int | None, float] = (None, 0.0)
    for p in range(2, max_pole_pairs + 1):
        if n_edges < 6 * p * 6:  # six mechanical turns at least
            break
        try:
            f = fit_ordinary(steps, Effects(pole_pairs=p, ripple=ripple), tick_s=tick_s, knot_cycles=knot_cycles)
        except OrdinaryRunError:
            break
        gain = bic_gain(-_chi2(f, base), len(f.names) - len(base.names), n_edges)
        if gain > max(best[1], BIC_MIN):
            best = (p, gain)
    if best[0] is None:
        return None, Reason("CAL-021")
    return best[0], Reason("CAL-022", {"pole_pairs": best[0], "bic_gain": float(best[1])})


def _chi2(f: Fit, noise: Fit) -> float:
    """Weighted residual sum of squares of ``f`` minus that of ``noise`` (same edges, the noise of
    ``noise``), over the edges neither fit left out as outliers."""
    sigma = noise.sigma_s
    keep = inliers(noise.residual_s, sigma) & inliers(f.residual_s, f.sigma_s)
    return float(np.sum((f.residual_s[keep] / sigma[keep]) ** 2) - np.sum((noise.residual_s[keep] / sigma[keep]) ** 2))


#: the sector-locked speed ripple is modelled only if the delay's standard error grows less than this
RIPPLE_SE_GROWTH = 1.5
#: trajectory knot spacings tried (electrical cycles between knots); the smallest BIC is kept
KNOT_CYCLE_CHOICES = (2, 3, 4, 6, 8)
#: beyond half a sector an "installation offset" is a wiring or labelling error, not an offset
RISE_LABELS = {1: (0, 2, 4), -1: (1, 3, 5)}  #: which boundaries a sensor crosses rising, per direction
SENSOR_LABELS = {0: (0, 3), 1: (2, 5), 2: (1, 4)}  #: A, B, C


def choose_knots(steps: HallSteps, tick_s: float | None, eff: Effects | None = None) -> tuple[float, Fit]:
    """The trajectory knot spacing (electrical cycles) with the smallest BIC, and its fit: the
    speed of a capture may change slowly (a ramp) or within a second (a speed cycle)."""
    best = None
    for kc in KNOT_CYCLE_CHOICES:
        try:
            f = fit_ordinary(steps, eff or Effects(), tick_s=tick_s, knot_cycles=kc)
        except OrdinaryRunError:
            continue
        n_spline = _n_spline(steps, kc)
        keep = inliers(f.residual_s, f.sigma_s)
        n = int(keep.sum())
        rss = float(np.sum(f.residual_s[keep] ** 2 / f.tau_s_per_deg[keep] ** 2))  # in angle: speed-fair
        bic = n * np.log(max(rss / max(n, 1), 1e-30)) + (n_spline + len(f.names)) * np.log(max(n, 2))
        if best is None or bic < best[0]:
            best = (bic, kc, f)
    if best is None:
        raise OrdinaryRunError(f"no run of {MIN_RUN_EDGES} or more edges could be fitted")
    return best[1], best[2]


def _n_spline(steps: HallSteps, knot_cycles: float) -> int:
    n = 0
    for r in np.unique(steps.run[steps.run >= 0]):
        edges = int(np.sum(steps.run == r))
        n += max(int(round(edges / (6.0 * knot_cycles))), 1) + 3
    return n


def _by_direction(fit: Fit, steps: HallSteps, make) -> tuple[float, float] | None:
    """A quantity measured in each direction present, combined by inverse variance."""
    vals = []
    for sgn, dname in ((1, "fwd"), (-1, "rev")):
        keys = [f"static_{dname}_{j}" for j in range(5)]
        if keys[0] not in fit.names:
            continue
        z = sum_zero_basis(6)
        vals.append(fit.combination(dict(zip(keys, make(sgn, z)))))
    if not vals:
        return None
    v = np.array([a for a, _ in vals])
    s = np.array([b for _, b in vals])
    w = 1.0 / np.maximum(s, 1e-12) ** 2
    mean = float(np.sum(w * v) / np.sum(w))
    # the two directions measure one sensor: where they disagree beyond their errors (a misfit that
    # depends on the direction), the error is scaled up by the Birge ratio (the PDG's scale factor)
    birge = np.sqrt(max(1.0, float(np.sum(w * (v - mean) ** 2)) / max(v.size - 1, 1)))
    return mean, float(birge / np.sqrt(np.sum(w)))


#: halves of a capture that disagree by more than this many standard errors: it is not stationary
STATIONARITY_Z = 3.0


def _stationarity(steps: HallSteps, eff: Effects, tick_s: float | None, kc: float,
                  pole_pairs: int | None) -> Stationarity:
    """Each figure fitted on the first and on the second half of the used edges alone (the whole
    capture's model and knot spacing). A figure whose halves differ by z = |a - b| / hypot(se_a, se_b)
    above ``STATIONARITY_Z`` was not constant through the capture (a delay that drifts with
    temperature, a speed ripple the model lacks at low speed): its standard error is widened by
    half the halves' difference (in quadrature), so the stated interval holds both halves, and the
    result says by how much."""
    used = np.nonzero(steps.used())[0]
    out = Stationarity(STATIONARITY_Z)
    halves = []
    for sel_idx in (used[: used.size // 2], used[used.size // 2:]):
        sel = np.zeros(steps.t_s.size, dtype=bool)
        sel[sel_idx] = True
        try:
            hf = robust_fit(fit_ordinary(steps, eff, select=sel, tick_s=tick_s, knot_cycles=kc))
            pf = (robust_fit(fit_ordinary(steps, Effects(pole_pairs=pole_pairs, ripple=eff.ripple), select=sel,
                                          tick_s=tick_s, knot_cycles=kc)) if pole_pairs else None)
        except (OrdinaryRunError, np.linalg.LinAlgError, ValueError) as exc:
            out.not_checked = str(exc)
            return out
        figs = {}
        if "delay_diff_s" in hf.names:
            figs["rise_fall_delay_difference_s"] = hf.get("delay_diff_s")
        asym = _by_direction(
            hf, steps, lambda sgn, z: sgn * (z[list(RISE_LABELS[sgn])].mean(0) - z[list(RISE_LABELS[-sgn])].mean(0))
        )
        if asym:
            figs["rise_fall_angle_asymmetry_deg_e"] = asym
        for x, name in enumerate(SENSORS):
            r = _by_direction(hf, steps, lambda sgn, z, labels=list(SENSOR_LABELS[x]): z[labels].mean(0))
            if r:
                figs[f"installation_offset_deg_e.{name}"] = r
        if pf is not None:
            z = sum_zero_basis(pole_pairs)
            for parity in (0, 1):
                keys = [f"pole_{parity}_{j}" for j in range(pole_pairs - 1)]
                for i in range(pole_pairs):
                    figs[f"pole_offset_deg_e.{2 * i + parity}"] = pf.combination(dict(zip(keys, z[i])))
        halves.append(figs)
    for key in halves[0].keys() & halves[1].keys():
        (a, sa), (b, sb) = halves[0][key], halves[1][key]
        if None in (a, sa, b, sb):
            continue
        z = float(abs(a - b) / max(np.hypot(sa, sb), 1e-300))
        widen = float(abs(a - b) / 2) if z > STATIONARITY_Z else 0.0
        out.figures[key] = Halves((float(a), float(b)), (float(sa), float(sb)), z, widen)
    return out


@dataclass
class _RippleChoice:
    """Whether the run's model carries the sector-locked speed ripple, and the fit it chose."""

    fit: Fit
    ripple: bool
    other_weight: float  #: the weight of the model not taken (uncertainty.with_model_choice)
    other_what: str


def _choose_ripple(steps: HallSteps, tick_s: float | None, kc: float, fit: Fit) -> _RippleChoice:
    """The rotor's speed ripple locked to the sectors (commutation torque ripple, largest at low
    speed) would bias the static offsets by its mean over the run: modelled when the capture shows
    it (BIC) and where the run can tell it (1/speed^2) from the delay (speed) and the constant angle
    (their standard errors may grow by half at most), never written as a correction."""
    ripple_fit = fit_ordinary(steps, Effects(ripple=True), tick_s=tick_s, knot_cycles=kc)
    n_used = int(steps.used().sum())
    ripple_gain = bic_gain(-_chi2(ripple_fit, fit), len(ripple_fit.names) - len(fit.names), n_used)
    ripple = ripple_gain > BIC_MIN
    ripple = ripple and ripple_fit.get("delay_diff_s")[1] <= RIPPLE_SE_GROWTH * fit.get("delay_diff_s")[1]
    # standard errors that hold under correlated residuals, and under the ripple model not taken
    # where the data do not rule it out (uncertainty.py)
    ripple_weight = bic_weight(ripple_gain)
    other_weight = 1.0 - ripple_weight if ripple else ripple_weight
    other_what = (
        "not modelling the sector-locked speed ripple" if ripple else "modelling the sector-locked speed ripple"
    )
    fit, other = (ripple_fit, fit) if ripple else (fit, ripple_fit)
    return _RippleChoice(with_model_choice(robust_fit(fit), other, other_weight, other_what), bool(ripple),
                         other_weight, other_what)


def _rise_fall(fit: Fit, steps: HallSteps, lo: float, hi: float, ratio: float) -> tuple[Estimate, Estimate]:
    """The rise-minus-fall asymmetry as a delay (time) and as a constant angle; neither where the
    run's speed range cannot tell them apart."""
    d_val, d_se = fit.get("delay_diff_s")
    asym = _by_direction(
        fit, steps, lambda sgn, z: sgn * (z[list(RISE_LABELS[sgn])].mean(0) - z[list(RISE_LABELS[-sgn])].mean(0))
    )
    delay = Estimate(d_val, d_se)
    angle = Estimate(*asym) if asym else Estimate(None, None, reason=Reason("CAL-030"))
    if ratio < MIN_SPEED_RATIO:
        why = Reason("CAL-031", {"low_hz_e": lo, "high_hz_e": hi, "speed_ratio": ratio,
                                 "min_speed_ratio": MIN_SPEED_RATIO})
        delay = Estimate(None, None, reason=why)
        angle = Estimate(None, None, reason=why)
    return delay, angle


def _installation(fit: Fit, steps: HallSteps) -> tuple[dict[str, float], dict[str, float | None]]:
    """Installation offsets (relative: sum zero), both edges of a sensor alike, and their errors."""
    inst, inst_se = {}, {}
    for x, name in enumerate(SENSORS):
        labels = list(SENSOR_LABELS[x])
        r = _by_direction(fit, steps, lambda sgn, z, labels=labels: z[labels].mean(0))
        inst[name], inst_se[name] = r if r else (0.0, None)
    return inst, inst_se


def _pole_table(steps: HallSteps, tick_s: float | None, kc: float, pole_pairs: int,
                choice: _RippleChoice) -> tuple[list[float], list[float], Fit]:
    """The pole offsets (two sum-zero sets: N and S boundaries), their errors, and their fit."""
    ripple = choice.ripple
    pf = robust_fit(fit_ordinary(steps, Effects(pole_pairs=pole_pairs, ripple=ripple), tick_s=tick_s, knot_cycles=kc))
    if choice.other_weight >= MODEL_WEIGHT_IGNORED:
        pf_other = fit_ordinary(steps, Effects(pole_pairs=pole_pairs, ripple=not ripple), tick_s=tick_s, knot_cycles=kc)
        pf = with_model_choice(pf, pf_other, choice.other_weight, choice.other_what)
    z = sum_zero_basis(pole_pairs)
    table = np.zeros(2 * pole_pairs)
    se = np.zeros(2 * pole_pairs)
    for parity in (0, 1):
        keys = [f"pole_{parity}_{j}" for j in range(pole_pairs - 1)]
        for i in range(pole_pairs):
            table[2 * i + parity], se[2 * i + parity] = pf.combination(dict(zip(keys, z[i])))
    return [float(v) for v in table], [float(v) for v in se], pf


def _widen(stationarity: Stationarity, delay: Estimate, angle: Estimate, inst_se: dict, poles_se: list) -> None:
    """Widen the errors of the figures whose halves disagree beyond their errors (they drifted
    during the capture), in place (docs/real-captures.md)."""
    for key, item in (("rise_fall_delay_difference_s", delay), ("rise_fall_angle_asymmetry_deg_e", angle)):
        drift = stationarity.figures.get(key)
        if drift and drift.widen_by and item.stderr is not None:
            item.stderr_stationary = item.stderr
            item.stderr = float(np.hypot(item.stderr, drift.widen_by))
    for x in SENSORS:
        drift = stationarity.figures.get(f"installation_offset_deg_e.{x}")
        if drift and drift.widen_by and inst_se.get(x) is not None:
            inst_se[x] = float(np.hypot(inst_se[x], drift.widen_by))
    for j in range(len(poles_se)):
        drift = stationarity.figures.get(f"pole_offset_deg_e.{j}")
        if drift and drift.widen_by:
            poles_se[j] = float(np.hypot(poles_se[j], drift.widen_by))


#: what capture times cannot give, whatever the capture
UNDETERMINED = {
    "conditioning_delay_s": Reason("CAL-040"),
    "armature_reaction_deg_e_per_a": Reason("CAL-041"),
    "hysteresis_common_lag": Reason("CAL-042"),
}
INSTALLATION_UNDETERMINED = Reason("CAL-043")
#: the pole-pair count's source when the recording states it
STATED_POLE_PAIRS = Reason("CAL-020")


def ordinary_calibration(
    steps: HallSteps,
    *,
    tick_s: float | None = None,
    pole_pairs: int | None = None,
    circuit: Circuit | None = None,
    source: str = "",
) -> Calibration:
    """The calibration of an ordinary run: its table, refusals and figures, with the fit they come
    from and the fit whose effects the table holds (with the pole offsets, when they were
    determined and not refused); ``to_json()`` is what ``hil calibrate`` writes (docs/calibration.md)."""
    circuit = circuit or Circuit()
    refused: list[Refusal] = []
    undetermined: dict[str, Reason] = {}
    kc, fit0 = choose_knots(steps, tick_s)
    choice = _choose_ripple(steps, tick_s, kc, fit0)
    fit, ripple = choice.fit, choice.ripple
    used = steps.used()
    f_hz = speed_hz_e(steps)
    lo, hi = (float(v) for v in np.percentile(f_hz[used], [5, 95]))
    top = float(np.percentile(f_hz[used], 99))
    ratio = hi / lo if lo > 0 else float("inf")
    delay, angle = _rise_fall(fit, steps, lo, hi, ratio)
    bound_s, bound_why = delay_bound_s(circuit, top)
    refusal = delay_refusal("rise_fall_delay_difference_s", delay.value, bound_s, bound_why)
    if refusal:
        refused.append(refusal)
        delay = Estimate(None, None, reason=refusal.reason, fitted=delay.value)
    inst, inst_se = _installation(fit, steps)
    refusal = installation_refusal(inst)
    if refusal:
        refused.append(refusal)
        inst = dict.fromkeys(SENSORS, 0.0)
    undetermined["installation_offset_deg_e"] = INSTALLATION_UNDETERMINED
    # pole offsets: the pole count, stated or found
    p_source = STATED_POLE_PAIRS
    if not pole_pairs:
        pole_pairs, p_source = choose_pole_pairs(steps, tick_s, fit, kc, ripple=ripple)
    poles: list[float] = []
    poles_se: list[float] = []
    table_fit = fit
    if pole_pairs:
        poles, poles_se, pf = _pole_table(steps, tick_s, kc, pole_pairs, choice)
        refusal = pole_table_refusal(poles)
        if refusal:
            refused.append(refusal)
            poles, poles_se = [], []
        else:
            table_fit = pf
    else:
        undetermined["pole_offset_deg_e"] = p_source
    # stationarity: the same model on each half of the used edges
    stationarity = _stationarity(steps, Effects(ripple=ripple), tick_s, kc, pole_pairs if poles else None)
    _widen(stationarity, delay, angle, inst_se, poles_se)
    undetermined.update(UNDETERMINED)
    d_table = delay.value or 0.0
    n_fwd, n_rev = int(np.sum(steps.direction[used] > 0)), int(np.sum(steps.direction[used] < 0))
    assumptions = OrdinaryAssumptions(
        pole_pairs=pole_pairs,
        pole_pairs_source=p_source,
        timer_tick_s=tick_s,
        forward_edges=n_fwd,
        reverse_edges=n_rev,
        edges=int(steps.t_s.size),
        edges_used=int(used.sum()),
        runs=int(steps.run.max() + 1) if used.any() else 0,
        reversals=steps.reversals,
        stalls_split=steps.stalls,
        glitches_removed=steps.glitches,
        invalid_states_dropped=steps.invalid_states,
        short_runs_dropped=steps.short_runs_dropped,
        outlier_edges=fit.outliers,
        speed_range_hz_e=(lo, hi),
        speed_ratio=ratio,
        min_speed_ratio=MIN_SPEED_RATIO,
        knot_cycles=kc,
        ripple_modelled=bool(ripple),
        trajectory_residual_rms_deg_e=float(np.sqrt(np.median((fit.residual_s / fit.tau_s_per_deg) ** 2) / 0.4549)),
        delay_bound_s=bound_s,
        delay_bound_why=bound_why,
        pole_offset_bound_deg_e=POLE_OFFSET_BOUND_DEG_E,
    )
    table = Corrections(
        installation_offset_deg_e=inst,
        pole_offset_deg_e=poles,
        conditioning_delay_s={"rise": max(d_table, 0.0), "fall": max(-d_table, 0.0)},
        armature_reaction_deg_e_per_a=0.0,
        undetermined=undetermined,
        uncertainty={"installation_offset_deg_e": inst_se, "pole_offset_deg_e": poles_se},
        delay_table={},
        info={"method": ORDINARY_METHOD, "source": source, "edges": int(steps.t_s.size)},
    )
    findings = OrdinaryFindings(
        rise_fall_delay_difference_s=delay,
        rise_fall_angle_asymmetry_deg_e=angle,
        fit_stderr_method=fit.stderr_method,
        stationarity=stationarity,
        cross_check=independent_delay(steps),
        assumptions=assumptions,
        source=source,
    )
    return Calibration("ordinary", table, refused, findings, steps, fit, table_fit)


def edge_corrections_s(cal: Calibration, steps: HallSteps, idx: np.ndarray) -> np.ndarray:
    """Ordinary run: how late each edge ``idx`` of ``steps`` (decoded like the calibration's
    edges, the same boundary numbering) is captured by the sensor effects the table holds
    (refused ones left out; the rotor's own sector-locked speed ripple is not a sensor
    effect). Subtract it from the capture times for the corrected instants. The time per
    degree at each edge is the electrical turn around it (six sectors, so the deviations
    themselves average out)."""
    if cal.route != "ordinary" or cal.table_fit is None:
        raise ValueError("edge corrections from capture times need the ordinary-run route")
    f = cal.table_fit
    eff = Effects(
        static=any(n.startswith("static_") for n in f.names),
        delay="delay_diff_s" in f.names,
        pole_pairs=sum(n.startswith("pole_0_") for n in f.names) + 1 if "pole_0_0" in f.names else None,
    )
    hz = edges.electrical_speed_hz(steps.t_s, window_sectors=6, run=steps.run)[idx]
    tau = 1.0 / (360.0 * hz)
    cols, names = effect_columns(steps, idx, tau, eff)
    refused = {r.field for r in cal.refused}
    coef = np.array(
        [
            0.0
            if (n == "delay_diff_s" and "rise_fall_delay_difference_s" in refused)
            or (n.startswith("static_") and "installation_offset_deg_e" in refused)
            or n not in f.names
            else f.coef[f.names.index(n)]
            for n in names
        ]
    )
    return cols @ coef if names else np.zeros(idx.size)
