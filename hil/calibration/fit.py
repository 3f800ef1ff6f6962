"""Compute the correction tables from a recording (``hil calibrate``).

With a reference encoder angle (``ref_angle_mech_deg``) every captured edge gives its own angle
error, and one linear least-squares fit of the issue's model

    error = installation[X] + pole[j] + w_e * delay[polarity] + armature * I + noise

recovers all four quantities at once, with standard errors. Each quantity is fitted only when
the segments can determine it (several speeds for the delays, current moving independently of
speed for the armature reaction); otherwise it is reported as undetermined with the reason,
and the others are still computed. Without an encoder, the paper's own route is taken:
relative deviations (Eq. 2) and pole offsets (Eq. 6) from capture times, and the absolute
deviation from the Line-BEMF (Eq. 3-5) when terminal voltages and currents were sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.hall import SENSOR_POSITION_DEG_E
from bldc.reasons import Reason
from bldc.units import deg_e_per_s_to_rpm, rpm_to_deg_e_per_s
from hil.recording.format import Recording

from .corrections import SENSORS, Corrections
from .steps import (
    absolute_deviation,
    edge_angles_per_turn,
    line_bemf_absolute_deviation,
    pole_offsets,
    relative_deviation,
    weighted_over_speeds,
    wrap180,
)


class CalibrationError(ValueError):
    """The recording cannot give a required quantity; the message says which and why."""


def _check_data(rec: Recording) -> None:
    if len(rec) < 6 * rec.pole_pairs:
        raise CalibrationError(
            f"{rec.path or 'recording'}: only {len(rec)} edges; calibration needs at least one mechanical turn "
            f"({6 * rec.pole_pairs} edges)"
        )


def segment_speed_deg_e_s(rec: Recording) -> np.ndarray:
    """Mean electrical speed (deg/s) of each segment from the encoder (or the set speed)."""
    p = rec.pole_pairs
    out = np.zeros(len(rec.segments))
    for i, seg in enumerate(rec.segments):
        sel = rec.segment == i
        if rec.ref_angle_mech_deg is not None and sel.sum() > 6 * p:
            ang = np.unwrap(np.radians(rec.ref_angle_mech_deg[sel]))
            t = rec.t_s[sel]
            out[i] = abs(np.degrees(ang[-1] - ang[0]) / (t[-1] - t[0])) * p
        else:
            out[i] = rpm_to_deg_e_per_s(seg.speed_rpm, p)
    return out


def edge_errors_from_encoder(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Per-edge angle error (deg e, + = trails) and magnet pole, from the reference angle."""
    p = rec.pole_pairs
    theta_e = p * rec.ref_angle_mech_deg
    direction = np.array([s.direction_sign for s in rec.segments])[rec.segment]
    # ideal angle of each edge (format document): forward A rises at 0, falls at 180; reverse swapped
    ideal = SENSOR_POSITION_DEG_E[rec.sensor] + np.where(rec.rising == (direction > 0), 0.0, 180.0)
    err = direction * wrap180(theta_e - ideal)
    boundary = np.round((theta_e - direction * err - SENSOR_POSITION_DEG_E[rec.sensor]) / 180.0).astype(np.int64)
    pole = np.mod(boundary, 2 * p)
    return err, pole


@dataclass
class DesignMatrix:
    """The joint model of the edge errors (paper Eq. 1-6 with the armature term): one column per
    identifiable deviation, and for each one the recording cannot determine, the reason."""

    columns: np.ndarray  #: (edges, parameters)
    names: list[tuple[str, int]]  #: (kind, index) of each column: inst / pole / rise / fall / arm
    undetermined: dict[str, Reason]


def design_matrix(
    rec: Recording, w: np.ndarray, w_seg: np.ndarray, min_speed_spread: float, pole: np.ndarray
) -> DesignMatrix:
    """Columns for the deviations this recording can separate (``w``: each edge's electrical
    speed, ``w_seg``: each segment's, deg e/s; ``pole``: the pole causing each edge). Signed by
    the direction, since every deviation lags the rotor the way it turns."""
    n_poles = 2 * rec.pole_pairs
    direction = np.array([s.direction_sign for s in rec.segments])[rec.segment].astype(float)
    current = np.array([s.mean_phase_current_a for s in rec.segments])[rec.segment]
    undetermined: dict[str, Reason] = {}
    cols, names = [], []
    for x, name in enumerate(SENSORS):
        if not np.any(rec.sensor == x):
            raise CalibrationError(f"installation_offset_deg_e: no edges of sensor {name} in the recording")
        cols.append(direction * (rec.sensor == x))
        names.append(("inst", x))
    poles_seen = np.unique(pole)
    if poles_seen.size < n_poles:
        undetermined["pole_offset_deg_e"] = Reason("CAL-050", {"poles_seen": int(poles_seen.size), "poles": n_poles})
    else:
        for j in range(1, n_poles):
            cols.append(direction * (pole == j))
            names.append(("pole", j))
    # conditioning delays need several speeds (the delay is the slope of error vs speed)
    speeds = np.unique(np.round(w_seg[np.unique(rec.segment)], 3))
    spread = (speeds.max() - speeds.min()) / speeds.max() if speeds.size else 0.0
    if speeds.size < 2 or spread < min_speed_spread:
        undetermined["conditioning_delay_s"] = Reason(
            "CAL-051", {"min_spread": min_speed_spread, "speeds": int(speeds.size), "spread": float(spread)}
        )
    else:
        cols += [w * rec.rising, w * ~rec.rising]
        names += [("rise", 0), ("fall", 0)]
    # armature reaction needs current that does not just follow speed
    seg_used = np.unique(rec.segment)
    i_seg = np.array([rec.segments[k].mean_phase_current_a for k in seg_used])
    w_used = w_seg[seg_used]
    reason: Reason | None = None
    if np.ptp(i_seg) < 0.1:
        reason = Reason("CAL-052", {"current_spread_a": float(np.ptp(i_seg))})
    elif "conditioning_delay_s" not in undetermined:
        basis = np.column_stack([np.ones_like(w_used), w_used])
        coef, *_ = np.linalg.lstsq(basis, i_seg, rcond=None)
        resid = i_seg - basis @ coef
        if np.sqrt(np.mean(resid**2)) < 0.02 * np.ptp(i_seg):
            reason = Reason("CAL-053")
    if reason:
        undetermined["armature_reaction_deg_e_per_a"] = reason
    else:
        cols.append(current)
        names.append(("arm", 0))
    return DesignMatrix(np.column_stack(cols).astype(float), names, undetermined)


@dataclass
class WeightedFit:
    coef: np.ndarray
    standard_error: np.ndarray
    residual: np.ndarray  #: unweighted, deg e per edge


def weighted_least_squares(a: np.ndarray, err: np.ndarray, segment: np.ndarray, n_segments: int) -> WeightedFit:
    """Two-pass weighted least squares: time jitter makes the angle noise grow with speed, so
    each segment is weighted by the inverse of its own residual variance from a first pass."""
    coef, *_ = np.linalg.lstsq(a, err, rcond=None)
    resid = err - a @ coef
    var_seg = np.array(
        [max(np.var(resid[segment == k]), 1e-12) if np.any(segment == k) else 1.0 for k in range(n_segments)]
    )
    wt = 1.0 / np.sqrt(var_seg[segment])
    coef, *_ = np.linalg.lstsq(a * wt[:, None], err * wt, rcond=None)
    resid = err - a @ coef
    dof = max(a.shape[0] - a.shape[1], 1)
    aw = a * wt[:, None]
    sigma2 = float(((resid * wt) @ (resid * wt))) / dof
    cov = sigma2 * np.linalg.pinv(aw.T @ aw)
    return WeightedFit(coef, np.sqrt(np.diag(cov)), resid)


def unpack(design: DesignMatrix, fit: WeightedFit, n_poles: int) -> Corrections:
    """The fitted coefficients as a correction table, with their standard errors."""
    out = Corrections(pole_offset_deg_e=[0.0] * n_poles, undetermined=design.undetermined)
    unc: dict = {"installation_offset_deg_e": {}, "pole_offset_deg_e": [0.0] * n_poles}
    for (kind, k), c, s in zip(design.names, fit.coef, fit.standard_error):
        if kind == "inst":
            out.installation_offset_deg_e[SENSORS[k]] = float(c)
            unc["installation_offset_deg_e"][SENSORS[k]] = float(s)
        elif kind == "pole":
            out.pole_offset_deg_e[k] = float(c)
            unc["pole_offset_deg_e"][k] = float(s)
        elif kind in ("rise", "fall"):
            # a delay cannot be negative, and a controller rightly refuses a table that says so: a
            # negative fit is projected onto the physical range (0), and a clearly negative one (beyond
            # 3 standard errors: something the model lacks grows with speed, such as an armature
            # reaction the segments' currents could not determine) is named in the table's info
            if c < -max(3 * s, 1e-12):
                out.info.setdefault("clipped_to_zero", {})[f"conditioning_delay_s.{kind}"] = (
                    f"fitted {c * 1e6:+.3g} us (standard error {s * 1e6:.2g} us): a delay cannot be negative"
                )
            out.conditioning_delay_s[kind] = max(float(c), 0.0)
            unc.setdefault("conditioning_delay_s", {})[kind] = float(s)
        else:
            out.armature_reaction_deg_e_per_a = float(c)
            unc["armature_reaction_deg_e_per_a"] = float(s)
    out.uncertainty = unc
    return out


def _delay_table(rec: Recording, static: np.ndarray, err: np.ndarray, w_seg: np.ndarray) -> dict:
    """The delay versus speed as an interpolation table (paper Fig. 7a), from the fitted residuals:
    per segment, the mean edge error left once the static deviations are removed."""
    table: dict[str, list[float]] = {"speed_rpm": [], "rise_deg_e": [], "fall_deg_e": []}
    for k in np.unique(rec.segment):
        sel = rec.segment == k
        table["speed_rpm"].append(float(deg_e_per_s_to_rpm(w_seg[k], rec.pole_pairs)))
        for pol, key in ((True, "rise_deg_e"), (False, "fall_deg_e")):
            s = sel & (rec.rising == pol)
            table[key].append(float(np.mean(err[s] - static[s])) if s.any() else float("nan"))
    return table


def fit_corrections(rec: Recording, min_speed_spread: float = 0.3) -> Corrections:
    """Every deviation at once from reference-encoder edge errors (joint weighted least squares);
    without an encoder, the paper's route from capture times (``fit_from_times``)."""
    _check_data(rec)
    if rec.ref_angle_mech_deg is None:
        return fit_from_times(rec)
    err, pole = edge_errors_from_encoder(rec)
    w_seg = segment_speed_deg_e_s(rec)
    w = w_seg[rec.segment]
    if rec.timer_tick_s:
        err = err + w * rec.timer_tick_s / 2.0  # the capture timer floors: undo its mean lag
    design = design_matrix(rec, w, w_seg, min_speed_spread, pole)
    fit = weighted_least_squares(design.columns, err, rec.segment, len(rec.segments))
    out = unpack(design, fit, 2 * rec.pole_pairs)
    if "conditioning_delay_s" not in design.undetermined:
        static = design.columns @ fit.coef - (
            w * np.where(rec.rising, out.conditioning_delay_s["rise"], out.conditioning_delay_s["fall"])
        )
        out.delay_table = _delay_table(rec, static, err, w_seg)
    out.info = {
        "method": "joint least squares on reference-encoder edge errors",
        "edges": int(len(rec)),
        "segments": [rec.segments[k].id for k in np.unique(rec.segment)],
        "residual_rms_deg_e": float(np.sqrt(np.mean(fit.residual**2))),
        **out.info,  # what unpack projected onto the physical range
    }
    return out


def fit_from_times(rec: Recording) -> Corrections:
    """The paper's route without an encoder: Eq. 2 and Eq. 6 from capture times, Eq. 3-5 from samples."""
    p = rec.pole_pairs
    undetermined = {"armature_reaction_deg_e_per_a": Reason("CAL-060")}
    fwd = [k for k, s in enumerate(rec.segments) if s.direction == "forward"]
    order = sorted(fwd, key=lambda k: rec.segments[k].speed_rpm)
    rel_by_speed, pole_by_speed, abs_by_speed, speeds = [], [], [], []
    for k in order:
        sel = rec.segment == k
        # no index pulse: pole N1 is the first segment's first A rise; later segments are
        # aligned to it by the electrical period whose Eq. 6 pattern matches best
        candidates = []
        for start in range(p):
            turns = edge_angles_per_turn(rec.t_s[sel], rec.sensor[sel], rec.rising[sel], p, start)
            if turns.shape[0]:
                mean = turns.mean(axis=0)  # edge order: A-r, C-f, B-r, A-f, C-r, B-f, ... per electrical period
                candidates.append((start, mean, pole_offsets(mean[0::3][: 2 * p] / p, p)))
        if not candidates:
            continue
        if pole_by_speed:
            start, mean, poles = min(candidates, key=lambda c: float(np.sum((c[2] - pole_by_speed[0]) ** 2)))
        else:
            start, mean, poles = candidates[0]
        rel = np.mean([relative_deviation(mean[6 * e], mean[6 * e + 2], mean[6 * e + 4]) for e in range(p)], axis=0)
        rel_by_speed.append(rel)
        pole_by_speed.append(poles)
        speeds.append(rec.segments[k].speed_rpm)
        if rec.samples is not None and all(c in rec.samples for c in ("u_a", "u_b", "u_c", "i_a", "i_b", "i_c")):
            m = rec.motor
            ss = rec.samples["segment"] == k
            if ss.sum() > 100 and "phase_resistance_ohm" in m and "phase_inductance_h" in m:
                u = np.column_stack([rec.samples[c][ss] for c in ("u_a", "u_b", "u_c")])
                i = np.column_stack([rec.samples[c][ss] for c in ("i_a", "i_b", "i_c")])
                a_rise = rec.t_s[sel & (rec.sensor == 0) & rec.rising][start::p]  # the reference pole N1's edges
                dev = line_bemf_absolute_deviation(
                    rec.samples["t_s"][ss],
                    u,
                    i,
                    a_rise,
                    m["phase_resistance_ohm"],
                    m["phase_inductance_h"],
                    rec.segments[k].speed_rpm,
                    p,
                )
                if dev.size:
                    abs_by_speed.append(float(np.mean(dev)))
    if not rel_by_speed:
        raise CalibrationError("installation_offset_deg_e: no complete mechanical turn in any forward segment")
    rel = weighted_over_speeds(np.array(rel_by_speed[:3]))
    poles = weighted_over_speeds(np.array(pole_by_speed[:3]))
    out = Corrections(pole_offset_deg_e=[float(v) for v in poles], undetermined=undetermined)
    if abs_by_speed:
        inst = absolute_deviation(rel, float(weighted_over_speeds(np.array(abs_by_speed[:3]))))
        method = "paper route: Eq. 2 and Eq. 6 from capture times, Eq. 3-5 Line-BEMF from samples"
    else:
        inst = rel
        undetermined["installation_offset_deg_e"] = Reason("CAL-061")
        method = "paper route: Eq. 2 and Eq. 6 from capture times"
    out.installation_offset_deg_e = dict(zip(SENSORS, map(float, inst)))
    undetermined["conditioning_delay_s"] = Reason("CAL-062")
    out.info = {"method": method, "speeds_rpm": speeds[:3], "edges": int(len(rec))}
    return out
