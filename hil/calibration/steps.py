"""The paper's calibration steps (Section 2 and 4.2), one function each.

Angles are electrical degrees; a positive deviation means the edge trails the ideal one.
"""

from __future__ import annotations

import numpy as np

from bldc.units import rpm_to_deg_e_per_s
from hil.calibration.linebemf import falling_zero_crossings, line_bemf

#: paper Section 4.2: weights of the three calibration speeds, in the order of Tables 2-4
PAPER_SPEED_WEIGHTS = (0.5, 0.3, 0.2)


def wrap180(angle_deg):
    return np.mod(np.asarray(angle_deg, dtype=float) + 180.0, 360.0) - 180.0


def relative_deviation(theta_a_r: float, theta_b_r: float, theta_c_r: float) -> np.ndarray:
    """Relative deviation of the three sensors' rising edges by minimum squared deviation (Eq. 1-2).

    phi_minA = (2 th_A - th_B - th_C) / 3, phi_minB = (2 th_B - th_A - th_C - 2 pi) / 3,
    phi_minC = (2 th_C - th_A - th_B + 2 pi) / 3, with 2 pi = 360 deg electrical.
    Eq. 2 as printed holds for angles measured in (-180, 180] from A's rising edge, i.e. B near
    +120 and C near -120 (Eq. 1: theta'_A - theta'_C = 2 pi / 3); the inputs are wrapped to that
    convention first. The three deviations sum to zero: a common shift is not observable here
    (Eq. 5 adds it).
    """
    a = theta_a_r
    b = a + float(wrap180(theta_b_r - a))
    c = a + float(wrap180(theta_c_r - a))
    return np.array([(2 * a - b - c) / 3.0, (2 * b - a - c - 360.0) / 3.0, (2 * c - a - b + 360.0) / 3.0])


def absolute_deviation(phi_min: np.ndarray, phi_pos_a_r: float) -> np.ndarray:
    """Installation deviation of every sensor's rising edge from that of A (Eq. 5).

    phi_PosA-r = theta_A-r - theta_LEMF (measured), phi_PosX-r = phi_minX + phi_PosA-r - phi_minA.
    """
    phi_min = np.asarray(phi_min, dtype=float)
    return phi_min + phi_pos_a_r - phi_min[0]


def pole_offsets(theta_edges_deg_m: np.ndarray, pole_pairs: int) -> np.ndarray:
    """Magnet pole offsets from one sensor's edges over one mechanical turn (Eq. 6).

    ``theta_edges_deg_m``: mechanical angles of the 2p consecutive edges of one sensor starting
    with the reference pole N1's edge. Eq. 6 gives phi_j = j * 180/p + theta_N1 - theta_j
    (ideal minus actual, mechanical); we return the deviation in our sign convention (actual
    minus ideal, positive = trails) in electrical degrees, with pole N1 = 0 by definition.
    """
    th = np.asarray(theta_edges_deg_m, dtype=float)
    j = np.arange(2 * pole_pairs)
    phi_eq6 = j * 180.0 / pole_pairs + th[0] - th  # Eq. 6, mechanical degrees
    return -phi_eq6 * pole_pairs


def weighted_over_speeds(values_by_speed: np.ndarray, weights=PAPER_SPEED_WEIGHTS) -> np.ndarray:
    """Speed-weighted average over the calibration speeds (paper Section 2.6 and Tables 2-4).

    The lowest speed, least disturbed by load, weighs most (0.5 / 0.3 / 0.2)."""
    v = np.asarray(values_by_speed, dtype=float)
    w = np.asarray(weights, dtype=float)[: v.shape[0]]
    return np.tensordot(w / w.sum(), v, axes=(0, 0))


def edge_angles_per_turn(
    t_s: np.ndarray, sensor: np.ndarray, rising: np.ndarray, pole_pairs: int, start: int = 0
) -> np.ndarray:
    """Electrical angle of each edge within its mechanical turn, from capture times only.

    The turn starts at an A rising edge (``start``-th of the recording, taken as pole N1: with no
    index pulse, which pole is N1 is a convention) and the speed is the mean over that
    turn, measured between the same sensor's same edge one mechanical turn apart, so pole
    offsets cancel from the speed (paper Section 2.1 keeps the 0th and 1st order only).
    Returns an array (turns, 6p) of angles in edge order, NaN where a turn is incomplete.
    """
    n_per_turn = 6 * pole_pairs
    a_rise = np.nonzero((sensor == 0) & rising)[0]
    starts = a_rise[start::pole_pairs]
    out = []
    for s0, s1 in zip(starts[:-1], starts[1:]):
        if s1 - s0 != n_per_turn:
            continue  # a missing or extra edge: skip this turn
        period = t_s[s1] - t_s[s0]
        out.append(360.0 * pole_pairs * (t_s[s0:s1] - t_s[s0]) / period)
    return np.array(out) if out else np.zeros((0, n_per_turn))


def line_bemf_absolute_deviation(
    t_s: np.ndarray,
    u_v: np.ndarray,
    i_a: np.ndarray,
    a_rise_t_s: np.ndarray,
    resistance_ohm: float,
    inductance_h: float,
    speed_rpm: float,
    pole_pairs: int,
) -> np.ndarray:
    """Deviation of A's rising edges from the falling zero crossing of e_BC (Eq. 3-5).

    The Line-BEMF of Eq. 3 is computed from sampled terminal voltages and phase currents; for
    each captured A rising edge the nearest falling e_BC crossing is the ideal commutation
    instant, and phi_PosA-r = theta_A-r - theta_LEMF = w_e (t_A-r - t_LEMF).
    """
    w_e = rpm_to_deg_e_per_s(speed_rpm, pole_pairs)
    e_bc = line_bemf(t_s, u_v, i_a, resistance_ohm, inductance_h)["BC"]
    crossings = falling_zero_crossings(t_s, e_bc, 20.0 / w_e, 2.0 / w_e)
    if crossings.size == 0:
        return np.zeros(0)
    idx = np.clip(np.searchsorted(crossings, a_rise_t_s), 1, crossings.size - 1)
    nearest = np.where(
        np.abs(crossings[idx] - a_rise_t_s) < np.abs(crossings[idx - 1] - a_rise_t_s),
        crossings[idx],
        crossings[idx - 1],
    )
    ok = np.abs(nearest - a_rise_t_s) * w_e < 30.0
    return w_e * (a_rise_t_s[ok] - nearest[ok])


def conditioning_delay_table(
    speed_rpm: np.ndarray, t_raw_s: np.ndarray, t_conditioned_s: np.ndarray, rising: np.ndarray, pole_pairs: int
) -> dict[str, list[float]]:
    """Delay of the conditioning circuit versus speed, by comparing raw and conditioned edges.

    Returns {"speed_rpm": [...], "rise_deg_e": [...], "fall_deg_e": [...], "rise_s": [...],
    "fall_s": [...]}: the mean delay per speed, to be interpolated (paper Fig. 7a).
    """
    speeds = np.unique(np.round(speed_rpm, 0))
    table: dict[str, list[float]] = {"speed_rpm": [], "rise_s": [], "fall_s": [], "rise_deg_e": [], "fall_deg_e": []}
    for s in speeds:
        sel = np.abs(np.round(speed_rpm, 0) - s) < 0.5
        d = t_conditioned_s[sel] - t_raw_s[sel]
        r = rising[sel]
        if r.any() and (~r).any():
            table["speed_rpm"].append(float(s))
            table["rise_s"].append(float(d[r].mean()))
            table["fall_s"].append(float(d[~r].mean()))
            table["rise_deg_e"].append(float(d[r].mean() * s * 6 * pole_pairs))
            table["fall_deg_e"].append(float(d[~r].mean() * s * 6 * pole_pairs))
    return table
