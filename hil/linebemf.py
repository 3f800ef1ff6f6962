"""Line back-EMF from terminal voltages and phase currents (paper Eq. 3) and its zero crossings."""

from __future__ import annotations

import numpy as np

PAIRS = {"AB": (0, 1), "BC": (1, 2), "CA": (2, 0)}


def line_bemf(t_s: np.ndarray, u_v: np.ndarray, i_a: np.ndarray, resistance_ohm: float, inductance_h: float) -> dict[str, np.ndarray]:
    """Paper Eq. 3: e_XY = (u_X - u_Y) - R (i_X - i_Y) - L_M p (i_X - i_Y), with equal phases.

    ``u_v`` and ``i_a`` are (n, 3) arrays of terminal voltages to ground and phase currents;
    the derivative p is a second-order finite difference on the (possibly uneven) time grid.
    """
    di = np.gradient(i_a, t_s, axis=0)
    out = {}
    for name, (x, y) in PAIRS.items():
        out[name] = (u_v[:, x] - u_v[:, y]) - resistance_ohm * (i_a[:, x] - i_a[:, y]) - inductance_h * (di[:, x] - di[:, y])
    return out


def falling_zero_crossings(t_s: np.ndarray, signal: np.ndarray, fit_window_s: float, guard_s: float) -> np.ndarray:
    """Times where ``signal`` crosses zero going down, each refined by a straight-line fit.

    Commutation makes p(i) jump, so samples within ``guard_s`` of the coarse crossing are left
    out; a line is fitted to the samples within ``fit_window_s`` on both sides (the Line-BEMF
    is a straight ramp there) and its root is the crossing.
    """
    s = np.sign(signal)
    coarse = np.nonzero((s[:-1] > 0) & (s[1:] <= 0))[0]
    out = []
    for k in coarse:
        tc = t_s[k]
        sel = (np.abs(t_s - tc) <= fit_window_s) & (np.abs(t_s - tc) >= guard_s)
        if sel.sum() < 4:
            continue
        slope, intercept = np.polyfit(t_s[sel] - tc, signal[sel], 1)
        if slope >= 0:
            continue
        out.append(tc - intercept / slope)
    return np.asarray(out)
