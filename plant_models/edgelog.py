"""Captured Hall edges with their ground truth, as columns (one row per captured edge)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from bldc.hall import ideal_edge_angle_deg_e
from bldc.units import rpm_to_deg_e_per_s


@dataclass
class EdgeLog:
    t_capture_s: np.ndarray        #: as the controller's timer saw it (conditioned, jittered, quantised)
    t_conditioned_s: np.ndarray    #: after the conditioning circuit and jitter, before quantisation
    t_raw_s: np.ndarray            #: sensor output switched (a scope on the raw sensor pin)
    t_ideal_s: np.ndarray          #: perfect sensor, perfect magnet (NaN if the rotor never got there)
    sensor: np.ndarray             #: 0, 1, 2 for A, B, C
    rising: np.ndarray             #: bool
    boundary: np.ndarray           #: unwrapped magnet-boundary index
    pole: np.ndarray               #: magnet pole whose leading boundary caused the edge (0 = N1)
    direction: np.ndarray          #: +1 forward, -1 reverse
    theta_e_switch_deg: np.ndarray  #: true electrical angle at the raw switching instant (unwrapped)
    theta_e_capture_deg: np.ndarray  #: true electrical angle at the conditioned capture instant (unwrapped)
    speed_rpm: np.ndarray          #: true mechanical speed at capture
    mean_abs_current_a: np.ndarray  #: mean |i| over the phases at the switching instant
    segment: np.ndarray            #: index of the operating segment (-1 if none)

    def __len__(self) -> int:
        return int(self.t_capture_s.size)

    @property
    def ideal_angle_deg_e(self) -> np.ndarray:
        return ideal_edge_angle_deg_e(self.sensor, self.boundary)

    @property
    def switch_error_deg_e(self) -> np.ndarray:
        """Sensor-layer angle error, positive = trails the ideal edge in the direction of motion."""
        return self.direction * (self.theta_e_switch_deg - self.ideal_angle_deg_e)

    @property
    def capture_error_deg_e(self) -> np.ndarray:
        """Angle error of the conditioned edge (before timer quantisation), positive = trails."""
        return self.direction * (self.theta_e_capture_deg - self.ideal_angle_deg_e)

    def theta_e_stamp_deg(self, pole_pairs: int) -> np.ndarray:
        """True electrical angle (unwrapped) at the instant the controller's timer stamped the edge:
        the conditioned instant's angle moved on by the quantisation, at the speed there (its
        magnitude in the direction of motion: the electrical plant logs signed speed, the
        kinematic one magnitudes)."""
        w_e_deg_s = rpm_to_deg_e_per_s(np.abs(self.speed_rpm), pole_pairs)
        return self.theta_e_capture_deg - self.direction * w_e_deg_s * (self.t_conditioned_s - self.t_capture_s)

    def stamp_error_deg_e(self, pole_pairs: int) -> np.ndarray:
        """Angle error of the edge as the controller's timer stamped it, positive = trails."""
        return self.direction * (self.theta_e_stamp_deg(pole_pairs) - self.ideal_angle_deg_e)

    def stamp_noise_variance_rad2(self, pole_pairs: int) -> float:
        """The variance of the captured edges' angle noise (rad^2, plant truth): each edge's angle
        error at the instant the timer stamped it, within its class (sensor, polarity, pole), as half
        the variance of the differences between consecutive edges of the class (a drift of the
        class's mean over the run, a slowly changing current's lag, is not noise); NaN with fewer
        than two differences."""
        error_rad = np.radians(self.stamp_error_deg_e(pole_pairs))
        classes = self.sensor * 4 * pole_pairs + self.rising * 2 * pole_pairs + self.pole
        diffs = [np.diff(error_rad[classes == k]) for k in np.unique(classes)]
        diffs = np.concatenate([d for d in diffs if d.size]) if diffs else np.array([])
        return float(np.var(diffs) / 2.0) if diffs.size > 1 else float("nan")

    def take(self, index) -> "EdgeLog":
        return EdgeLog(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    @classmethod
    def concatenate(cls, logs: list["EdgeLog"]) -> "EdgeLog":
        return cls(**{f.name: np.concatenate([getattr(log, f.name) for log in logs]) for f in fields(cls)})

    @classmethod
    def empty(cls) -> "EdgeLog":
        return cls(**{f.name: np.zeros(0) for f in fields(cls)})


def join_ideal(boundary_sensor_dir: np.ndarray, t_emit: np.ndarray, ideal: np.ndarray) -> np.ndarray:
    """Ideal time of each captured edge: the ideal crossing of the same boundary, sensor and
    direction nearest in time (rows of ``ideal``: t, sensor, boundary, direction)."""
    out = np.full(t_emit.size, np.nan)
    if ideal.size == 0 or t_emit.size == 0:
        return out
    key_edges = _key(boundary_sensor_dir[:, 0], boundary_sensor_dir[:, 1], boundary_sensor_dir[:, 2])
    key_ideal = _key(ideal[:, 2], ideal[:, 1], ideal[:, 3])
    order = np.lexsort((ideal[:, 0], key_ideal))
    k_sorted = key_ideal[order]
    t_sorted = ideal[order, 0]
    lo = np.searchsorted(k_sorted, key_edges, side="left")
    hi = np.searchsorted(k_sorted, key_edges, side="right")
    for n in np.nonzero(hi > lo)[0]:
        ts = t_sorted[lo[n]:hi[n]]
        out[n] = ts[np.argmin(np.abs(ts - t_emit[n]))]
    return out


def _key(boundary, sensor, direction):
    return (np.asarray(boundary, dtype=np.int64) * 3 + np.asarray(sensor, dtype=np.int64)) * 2 + (
        np.asarray(direction) > 0
    )
