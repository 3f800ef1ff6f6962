"""Per-edge residuals of a recording against a model, and the features that localise them.

Edges are samples in rotor angle: each captured edge has a measured angle error (against the
reference encoder when recorded, otherwise against the same-sensor, same-edge speed over each
mechanical turn) from which the model's own prediction is subtracted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.hall import SENSOR_POSITION_DEG_E
from hil.calibration.fit import edge_errors_from_encoder, segment_speed_deg_e_s
from hil.calibration.steps import wrap180
from hil.recording.format import Recording


@dataclass
class EdgeResiduals:
    """One row per captured edge."""

    residual_deg_e: np.ndarray   #: measured error minus model prediction, + = trails
    sensor: np.ndarray
    rising: np.ndarray
    pole: np.ndarray
    direction: np.ndarray        #: +1 / -1
    w_e_deg_s: np.ndarray        #: segment electrical speed
    current_a: np.ndarray        #: segment mean phase current
    load_scale: np.ndarray
    segment: np.ndarray
    turn: np.ndarray             #: mechanical turn index within the segment
    reference: str               #: "encoder" or "turn" (relative errors only)
    pole_pairs: int
    edge_index: np.ndarray | None = None  #: row of the recording's edge table


    def __len__(self) -> int:
        return int(self.residual_deg_e.size)

    def take(self, index) -> "EdgeResiduals":
        return EdgeResiduals(**{k: (v[index] if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()})

    def cell_index(self) -> np.ndarray:
        """Cells whose mean is the systematic part: segment x sensor x polarity x pole."""
        n_poles = 2 * self.pole_pairs
        return ((self.segment * 3 + self.sensor) * 2 + self.rising) * n_poles + self.pole


def turn_errors(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Without an encoder: each edge's angle within its mechanical turn, from the speed between
    the same sensor's same edge one turn apart, minus its ideal angle; a common shift per turn
    (the turn's reference) is removed, so only relative errors remain."""
    p = rec.pole_pairs
    n = 6 * p
    err = np.full(len(rec), np.nan)
    pole = np.zeros(len(rec), dtype=np.int64)
    turn = np.zeros(len(rec), dtype=np.int64)
    for k, seg in enumerate(rec.segments):
        idx = np.nonzero(rec.segment == k)[0]
        if idx.size < 2 * n:
            continue
        t = rec.t_s[idx]
        d = seg.direction_sign
        a_first = np.nonzero((rec.sensor[idx] == 0) & (rec.rising[idx] == (d > 0)))[0]
        start = a_first[0] if a_first.size else 0
        # angle of each edge relative to its turn's start edge, at that turn's mean speed
        theta = np.full(idx.size, np.nan)
        j = np.arange(start, idx.size - n)
        s0 = start + ((j - start) // n) * n
        theta[j] = 360.0 * p * (t[j] - t[s0]) / (t[s0 + n] - t[s0])
        seq = np.arange(idx.size) - start
        e = wrap180(theta - 60.0 * np.mod(seq, n))
        turn_id = np.where(seq >= 0, seq // n, -1)
        # remove each turn's mean: the reference edge itself is not known to be ideal
        ok = np.isfinite(e)
        ids, inv = np.unique(turn_id[ok], return_inverse=True)
        e[ok] -= (np.bincount(inv, e[ok]) / np.bincount(inv))[inv]
        err[idx] = e
        pole[idx] = np.mod(
            np.round(
                (np.mod(seq, n) * 60.0 + SENSOR_POSITION_DEG_E[0] - SENSOR_POSITION_DEG_E[rec.sensor[idx]]) / 180.0
            ),
            2 * p,
        ).astype(np.int64)
        turn[idx] = turn_id
    return err, pole, turn


def edge_currents_a(rec: Recording) -> np.ndarray:
    """Mean |i| over the phases at each edge: the last sample at or before the capture when
    samples.csv has the phase currents (armature reaction follows the current at the edge,
    which under six-step commutation differs from the segment mean), else the segment's
    ``mean_phase_current_a``."""
    current = np.array([s.mean_phase_current_a for s in rec.segments])[rec.segment].astype(float)
    s = rec.samples
    if s is None or not all(c in s for c in ("i_a", "i_b", "i_c")):
        return current
    mean_abs = (np.abs(s["i_a"]) + np.abs(s["i_b"]) + np.abs(s["i_c"])) / 3.0
    for k in range(len(rec.segments)):
        e_sel = np.nonzero(rec.segment == k)[0]
        s_sel = np.nonzero(s["segment"] == k)[0]
        if e_sel.size == 0 or s_sel.size == 0:
            continue
        j = np.searchsorted(s["t_s"][s_sel], rec.t_s[e_sel], side="right") - 1
        inside = j >= 0
        current[e_sel[inside]] = mean_abs[s_sel[j[inside]]]
    return current


def residuals(rec: Recording, model_prediction_deg_e: np.ndarray | None = None) -> EdgeResiduals:
    p = rec.pole_pairs
    if rec.ref_angle_mech_deg is not None:
        err, pole = edge_errors_from_encoder(rec)
        reference = "encoder"
        turn = np.zeros(len(rec), dtype=np.int64)
        for k in range(len(rec.segments)):
            idx = np.nonzero(rec.segment == k)[0]
            turn[idx] = np.arange(idx.size) // (6 * p)
    else:
        err, pole, turn = turn_errors(rec)
        reference = "turn"
    w = segment_speed_deg_e_s(rec)[rec.segment]
    if rec.timer_tick_s and reference == "encoder":
        err = err + w * rec.timer_tick_s / 2.0  # the known timer is part of the model
    if model_prediction_deg_e is not None:
        err = err - model_prediction_deg_e
    seg = rec.segments
    keep = np.isfinite(err)
    out = EdgeResiduals(
        residual_deg_e=err,
        sensor=rec.sensor.astype(np.int64),
        rising=rec.rising.astype(np.int64),
        pole=pole.astype(np.int64),
        direction=np.array([s.direction_sign for s in seg])[rec.segment],
        w_e_deg_s=w,
        current_a=edge_currents_a(rec),
        load_scale=np.array([s.load_scale for s in seg])[rec.segment],
        segment=rec.segment.astype(np.int64),
        turn=turn,
        reference=reference,
        pole_pairs=p,
        edge_index=np.arange(len(rec)),
    )
    return out.take(keep)


def model_prediction(config, rec: Recording) -> np.ndarray:
    """Per-edge angle error the model itself predicts (its sensor-layer effects), + = trails.

    The timer is taken from meta.json (timer_tick_s), not from the model."""
    cp = config.compile()
    if cp.pole_pairs != rec.pole_pairs:
        raise ValueError(f"model has {cp.pole_pairs} pole pairs, the recording {rec.pole_pairs}")
    if rec.ref_angle_mech_deg is not None:
        _, pole = edge_errors_from_encoder(rec)
    else:
        _, pole, _ = turn_errors(rec)
    direction = np.array([s.direction_sign for s in rec.segments])[rec.segment]
    w = segment_speed_deg_e_s(rec)[rec.segment]
    current = edge_currents_a(rec)
    delay = np.where(rec.rising, cp.rise_delay_s, cp.fall_delay_s)
    offsets = cp.switch_table_deg_e()[rec.sensor, pole, np.where(direction > 0, 0, 1)]
    return direction * offsets + cp.hysteresis_deg_e + cp.armature_offset_deg_e(current) + w * delay
