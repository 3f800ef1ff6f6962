"""Line back-EMF from terminal voltages and phase currents (paper Eq. 3) and its zero crossings."""

from __future__ import annotations

import numpy as np
from scipy.stats import siegelslopes

PAIRS = {"AB": (0, 1), "BC": (1, 2), "CA": (2, 0)}


def line_bemf(
    t_s: np.ndarray, u_v: np.ndarray, i_a: np.ndarray, resistance_ohm: float, inductance_h: float
) -> dict[str, np.ndarray]:
    """Paper Eq. 3: e_XY = (u_X - u_Y) - R (i_X - i_Y) - L_M p (i_X - i_Y), with equal phases.

    ``u_v`` and ``i_a`` are (n, 3) arrays of terminal voltages to ground and phase currents;
    the derivative p is a second-order finite difference on the (possibly uneven) time grid.
    """
    di = np.gradient(i_a, t_s, axis=0)
    out = {}
    for name, (x, y) in PAIRS.items():
        out[name] = (
            (u_v[:, x] - u_v[:, y]) - resistance_ohm * (i_a[:, x] - i_a[:, y]) - inductance_h * (di[:, x] - di[:, y])
        )
    return out


def falling_zero_crossings(t_s: np.ndarray, signal: np.ndarray, fit_window_s: float, guard_s: float) -> np.ndarray:
    """Times where ``signal`` crosses zero going down, each refined by a straight-line fit.

    Commutation makes p(i) jump, so samples within ``guard_s`` of the coarse crossing are left
    out; a robust line is fitted to the samples within ``fit_window_s`` on both sides (the
    Line-BEMF of trapezoidal phases is a straight ramp +-60 deg electrical around its crossing)
    and its root is the crossing.
    """
    s = np.sign(signal)
    coarse = np.nonzero((s[:-1] > 0) & (s[1:] <= 0))[0]
    out: list[float] = []
    for k in coarse:
        tc = t_s[k]
        if out and tc - out[-1] < fit_window_s:
            continue  # a commutation spike or noise near a crossing already found
        sel = (np.abs(t_s - tc) <= fit_window_s) & (np.abs(t_s - tc) >= guard_s)
        before, after = sel & (t_s < tc), sel & (t_s > tc)
        if before.sum() < 2 or after.sum() < 2:
            continue
        # a true crossing has the ramp's sign on both sides, not just a spike through zero
        if np.median(signal[before]) <= 0 or np.median(signal[after]) >= 0:
            continue
        x, y = t_s[sel] - tc, signal[sel]
        # repeated-median line first: commutation transients inside the window (diode
        # freewheeling makes p(i) jump) are outliers, not data; then least squares on inliers
        slope, intercept = siegelslopes(y, x)
        resid = y - (slope * x + intercept)
        scale = 1.4826 * np.median(np.abs(resid)) + 1e-12 * np.abs(y).max()
        inlier = np.abs(resid) <= 5 * scale
        if inlier.sum() >= 4:
            slope, intercept = np.polyfit(x[inlier], y[inlier], 1)
        root = tc - intercept / slope
        if slope < 0 and abs(root - tc) <= max(guard_s, 2 * np.median(np.diff(t_s))):
            out.append(root)
    return np.asarray(out)
