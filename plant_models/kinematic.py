"""Edge-only kinematic mode: Hall edges of a prescribed speed profile, vectorised.

No electrical model: each operating point prescribes speed (constant or a linear ramp), mean
phase current (for armature reaction) and direction; the rotor angle is an exact quadratic in
time, so every edge is an exact root. The sensor layer is the same as in the electrical plant
(the compiled effects of :class:`~plant_models.plant.PlantConfig`), so the two modes agree edge
for edge on the same trajectory. Segments are assumed to turn one way throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from bldc.hall import SENSOR_POSITION_DEG_E
from bldc.params import ConfigError
from bldc.units import deg_e_per_s_to_rpm, rpm_to_deg_e_per_s

from .edgelog import EdgeLog
from .plant import PlantConfig


@dataclass(frozen=True)
class OperatingPoint:
    """A steady (or linearly ramping) stretch of operation."""

    duration_s: float
    speed_rpm: float
    mean_phase_current_a: float = 0.0
    direction: int = 1
    end_speed_rpm: float | None = None
    load_scale: float = 1.0
    id: str = ""

    def check(self, index: int) -> None:
        prefix = f"profile[{index}]."
        for name in ("duration_s", "speed_rpm", "mean_phase_current_a", "load_scale"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(prefix + name, f"must be a finite number, got {v!r}")
        if self.duration_s <= 0:
            raise ConfigError(prefix + "duration_s", f"must be > 0 s, got {self.duration_s!r}")
        if self.speed_rpm < 0 or (self.end_speed_rpm is not None and self.end_speed_rpm < 0):
            raise ConfigError(prefix + "speed_rpm", "speeds are magnitudes (>= 0); use direction for reverse")
        if self.direction not in (1, -1):
            raise ConfigError(prefix + "direction", f"must be +1 or -1, got {self.direction!r}")


def simulate_edges(
    config: PlantConfig,
    profile: list[OperatingPoint],
    seed: int = 0,
    start_angle_deg_e: float = 0.0,
    start_time_s: float = 0.0,
) -> EdgeLog:
    """Captured edges (with ground truth) of ``profile`` run back to back."""
    cp = config.compile()
    for index, op in enumerate(profile):
        op.check(index)
    if not profile:
        return EdgeLog.empty()
    if cp.jitter_angle_rms_deg_e == 0 and cp.jitter_time_rms_s == 0:
        # no random draws: every segment at once (a twin replays a capture as one segment per
        # edge interval, tens of thousands; one by one they cost some 0.2 ms each)
        log = _segments_at_once(cp, profile, float(start_angle_deg_e), float(start_time_s))
    else:
        log = _segments_one_by_one(cp, profile, seed, float(start_angle_deg_e), float(start_time_s))
    return _in_time_order(log)


def _segments_one_by_one(cp, profile: list[OperatingPoint], seed: int, theta0: float, t0: float) -> EdgeLog:
    """The segments in turn, the jitter drawn segment by segment (its random stream in that order)."""
    table = cp.switch_table_deg_e()
    rng = np.random.default_rng(seed)
    p = cp.pole_pairs
    n_poles = 2 * p
    logs = []
    # the coloured jitter runs on across segment seams (AR(1) over successive captured edges,
    # not restarted at each operating point: a trajectory of many short segments keeps its colour)
    jitter_state = {"angle": None, "time": None}
    for index, op in enumerate(profile):
        d = op.direction
        w0 = rpm_to_deg_e_per_s(op.speed_rpm, p)  # deg_e / s
        w1 = rpm_to_deg_e_per_s(op.end_speed_rpm if op.end_speed_rpm is not None else op.speed_rpm, p)
        acc = (w1 - w0) / op.duration_s
        travel = w0 * op.duration_s + 0.5 * acc * op.duration_s**2  # deg_e, >= 0
        theta1 = theta0 + d * travel
        lo, hi = min(theta0, theta1), max(theta0, theta1)
        shift = d * (cp.hysteresis_deg_e + float(cp.armature_offset_deg_e(op.mean_phase_current_a)))
        parts = []
        for x in range(3):
            base = SENSOR_POSITION_DEG_E[x] + cp.sensor_offset_deg_e[x]
            # deterministic switching angles decide membership; jitter is added afterwards
            k = np.arange(math.floor((lo - base - 60.0) / 180.0), math.ceil((hi - base + 60.0) / 180.0) + 1)
            switch = 180.0 * k + SENSOR_POSITION_DEG_E[x] + table[x, k % n_poles, 0 if d > 0 else 1] + shift
            inside = (d * (switch - theta0) >= 0) & (d * (switch - theta1) < 0)
            k, switch = k[inside], switch[inside]
            parts.append((np.full(k.size, x), k, switch))
        sensor = np.concatenate([q[0] for q in parts]).astype(np.int64, copy=False)
        boundary = np.concatenate([q[1] for q in parts]).astype(np.int64, copy=False)
        switch = np.concatenate([q[2] for q in parts])
        if cp.jitter_angle_rms_deg_e > 0:
            order = np.argsort(d * switch, kind="stable")
            jit = _ar1(rng, order.size, cp.jitter_correlation, jitter_state, "angle")
            switch[order] += cp.jitter_angle_rms_deg_e * jit
        tau_raw = _time_at(d * (switch - theta0), w0, acc)
        ideal = 180.0 * boundary + SENSOR_POSITION_DEG_E[sensor]
        tau_ideal = _time_at(d * (ideal - theta0), w0, acc)
        rising = ((boundary if d > 0 else boundary - 1) % 2) == 0
        order = np.argsort(tau_raw, kind="stable")
        sensor, boundary, switch, tau_raw, tau_ideal, rising = (
            a[order] for a in (sensor, boundary, switch, tau_raw, tau_ideal, rising)
        )
        delay = np.where(rising, cp.rise_delay_s, cp.fall_delay_s)
        tau_cond = tau_raw + delay
        if cp.jitter_time_rms_s > 0:
            tau_cond = tau_cond + cp.jitter_time_rms_s * _ar1(
                rng, tau_cond.size, cp.jitter_correlation, jitter_state, "time"
            )
        t_cond = t0 + tau_cond
        t_cap = np.floor(t_cond / cp.timer_tick_s) * cp.timer_tick_s if cp.timer_tick_s > 0 else t_cond.copy()
        theta_cap = theta0 + d * (w0 * tau_cond + 0.5 * acc * tau_cond**2)
        n = sensor.size
        logs.append(
            EdgeLog(
                t_capture_s=t_cap,
                t_conditioned_s=t_cond,
                t_raw_s=t0 + tau_raw,
                t_ideal_s=t0 + tau_ideal,
                sensor=sensor,
                rising=rising,
                boundary=boundary,
                pole=boundary % n_poles,
                direction=np.full(n, d, dtype=np.int64),
                theta_e_switch_deg=switch,
                theta_e_capture_deg=theta_cap,
                speed_rpm=deg_e_per_s_to_rpm(w0 + acc * tau_cond, p),
                mean_abs_current_a=np.full(n, op.mean_phase_current_a),
                segment=np.full(n, index, dtype=np.int64),
            )
        )
        theta0, t0 = theta1, t0 + op.duration_s
    return logs[0] if len(logs) == 1 else EdgeLog.concatenate(logs)


def _in_time_order(log: EdgeLog) -> EdgeLog:
    # a conditioned edge may overtake its neighbour across a segment seam; keep time order
    # (checked first: reordering copies every column, and almost always nothing overtakes)
    if np.all(log.t_conditioned_s[1:] >= log.t_conditioned_s[:-1]):
        return log
    return log.take(np.argsort(log.t_conditioned_s, kind="stable"))


def _segments_at_once(cp, profile: list[OperatingPoint], theta_start: float, t_start: float) -> EdgeLog:
    """The segments without jitter, all in one set of array operations: the same arithmetic,
    element by element, as ``_segments_one_by_one`` (the same edges, bit for bit, in its order)."""
    table = cp.switch_table_deg_e()
    p = cp.pole_pairs
    n_poles = 2 * p
    dur = np.array([op.duration_s for op in profile], dtype=float)
    d = np.array([op.direction for op in profile], dtype=np.int64)
    rpm0 = np.array([op.speed_rpm for op in profile], dtype=float)
    rpm1 = np.array([op.speed_rpm if op.end_speed_rpm is None else op.end_speed_rpm for op in profile], dtype=float)
    current = np.array([op.mean_phase_current_a for op in profile], dtype=float)
    w0, w1 = rpm_to_deg_e_per_s(rpm0, p), rpm_to_deg_e_per_s(rpm1, p)
    acc = (w1 - w0) / dur
    travel = w0 * dur + 0.5 * acc * dur**2
    # each segment starts where the one before ended: a running sum, added in the loop's order
    theta0 = np.add.accumulate(np.concatenate(([theta_start], d * travel)))[:-1]
    t0 = np.add.accumulate(np.concatenate(([t_start], dur)))[:-1]
    theta1 = theta0 + d * travel
    lo, hi = np.minimum(theta0, theta1), np.maximum(theta0, theta1)
    shift = d * (cp.hysteresis_deg_e + cp.armature_offset_deg_e(current))
    seg, sensor, boundary, switch = [], [], [], []
    for x in range(3):
        base = SENSOR_POSITION_DEG_E[x] + cp.sensor_offset_deg_e[x]
        k_lo = np.floor((lo - base - 60.0) / 180.0).astype(np.int64)
        count = np.ceil((hi - base + 60.0) / 180.0).astype(np.int64) + 1 - k_lo  # np.arange(k_lo, that)
        i = np.repeat(np.arange(dur.size), count)
        k = k_lo[i] + (np.arange(i.size) - np.repeat(np.cumsum(count) - count, count))
        sw = 180.0 * k + SENSOR_POSITION_DEG_E[x] + table[x, k % n_poles, np.where(d[i] > 0, 0, 1)] + shift[i]
        inside = (d[i] * (sw - theta0[i]) >= 0) & (d[i] * (sw - theta1[i]) < 0)
        seg.append(i[inside])
        sensor.append(np.full(int(inside.sum()), x, dtype=np.int64))
        boundary.append(k[inside])
        switch.append(sw[inside])
    seg, sensor, boundary, switch = map(np.concatenate, (seg, sensor, boundary, switch))
    dd, ww, aa = d[seg], w0[seg], acc[seg]
    tau_raw = _time_at(dd * (switch - theta0[seg]), ww, aa)
    ideal = 180.0 * boundary + SENSOR_POSITION_DEG_E[sensor]
    tau_ideal = _time_at(dd * (ideal - theta0[seg]), ww, aa)
    # the loop's order: segment by segment, by raw time, ties by sensor then boundary (its
    # stable sort of sensor A's edges, then B's, then C's)
    order = np.lexsort((boundary, sensor, tau_raw, seg))
    seg, sensor, boundary, switch, tau_raw, tau_ideal, dd, ww, aa = (
        a[order] for a in (seg, sensor, boundary, switch, tau_raw, tau_ideal, dd, ww, aa)
    )
    rising = (np.where(dd > 0, boundary, boundary - 1) % 2) == 0
    tau_cond = tau_raw + np.where(rising, cp.rise_delay_s, cp.fall_delay_s)
    t_cond = t0[seg] + tau_cond
    t_cap = np.floor(t_cond / cp.timer_tick_s) * cp.timer_tick_s if cp.timer_tick_s > 0 else t_cond.copy()
    return EdgeLog(
        t_capture_s=t_cap,
        t_conditioned_s=t_cond,
        t_raw_s=t0[seg] + tau_raw,
        t_ideal_s=t0[seg] + tau_ideal,
        sensor=sensor,
        rising=rising,
        boundary=boundary,
        pole=boundary % n_poles,
        direction=dd,
        theta_e_switch_deg=switch,
        theta_e_capture_deg=theta0[seg] + dd * (ww * tau_cond + 0.5 * aa * tau_cond**2),
        speed_rpm=deg_e_per_s_to_rpm(ww + aa * tau_cond, p),
        mean_abs_current_a=current[seg],
        segment=seg.astype(np.int64, copy=False),
    )


def _time_at(travel_deg: np.ndarray, w0, acc) -> np.ndarray:
    """Time at which w0 t + acc t^2 / 2 = travel (stable root; w0, travel >= 0); ``w0`` and ``acc``
    one segment's, or each edge's own (its segment's)."""
    with np.errstate(all="ignore"):  # both roots are computed for every edge, each kept where it holds
        steady = travel_deg / w0
        disc = np.maximum(w0 * w0 + 2.0 * acc * travel_deg, 0.0)
        ramp = 2.0 * travel_deg / (w0 + np.sqrt(disc))
    return np.where(acc == 0.0, steady, ramp)


def _ar1(rng: np.random.Generator, n: int, rho: float, state: dict | None = None, key: str = "") -> np.ndarray:
    """Unit-RMS stationary AR(1) sequence (white when rho = 0); with ``state``, it continues from
    ``state[key]``, the last value of the previous call (a stationary start when None)."""
    w = rng.standard_normal(n)
    if rho == 0.0 or n == 0:
        return w
    x0 = state.get(key) if state is not None else None
    if x0 is None:
        x0 = rng.standard_normal()
    y, _ = lfilter([math.sqrt(1 - rho * rho)], [1.0, -rho], w, zi=[rho * x0])
    if state is not None:
        state[key] = float(y[-1])
    return y
