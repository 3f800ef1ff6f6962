"""Bench traces other than hil-recording/1: MDF4 (asammdf), CSV and Parquet, through a column mapping.

A trace is either a **level trace** (the three Hall signals sampled at a fixed rate, as a
logger or scope records them: edges are the transitions, placed midway between the two samples
that straddle the threshold, so the timing is unbiased) or an **edge table** (one row per
captured edge, under any column names). Segments and the motor come from a meta.json in the
hil-recording/1 form. The mapping is a TOML table (docs/gap.md):

    kind = "levels"                  # or "edges"
    time = "t"                       # time channel / column
    time_scale = 1e-6                # multiply to get seconds (here: microseconds)
    hall = ["HallA", "HallB", "HallC"]
    threshold = 2.5                  # level above which a Hall signal is high
    ref_angle_mech_deg = "Encoder"   # optional: encoder angle in degrees [0, 360)
    # edge tables: sensor = "ch", edge = "pol", sensor_values = {A = "1", B = "2", C = "3"},
    #              edge_values = {rise = "R", fall = "F"}
"""

from __future__ import annotations

import csv
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bldc.tomlfile import load_toml

from .errors import RecordingError
from .format import Recording, write_recording
from .formats import open_trace
from .reader import read_meta_file
from .tables import TraceTable


@dataclass(frozen=True)
class TraceMapping:
    kind: str = "levels"
    time: str = "t_s"
    time_scale: float = 1.0
    hall: tuple[str, str, str] = ("hall_a", "hall_b", "hall_c")
    threshold: float = 0.5
    ref_angle_mech_deg: str | None = None
    sensor: str = "sensor"
    edge: str = "edge"
    sensor_values: dict[str, str] = field(default_factory=lambda: {"A": "A", "B": "B", "C": "C"})
    edge_values: dict[str, str] = field(default_factory=lambda: {"rise": "rise", "fall": "fall"})

    @classmethod
    def from_toml(cls, path: str | Path) -> "TraceMapping":
        data = load_toml(path, set(cls.__dataclass_fields__))
        if "hall" in data:
            data["hall"] = tuple(data["hall"])
            if len(data["hall"]) != 3:
                raise RecordingError(path, None, "hall", "needs three channel names (A, B, C)")
        m = cls(**data)
        if m.kind not in ("levels", "edges"):
            raise RecordingError(path, None, "kind", f"must be 'levels' or 'edges', got {m.kind!r}")
        return m


def _edges_from_levels(table: TraceTable, m: TraceMapping):
    times, sensors, rising = [], [], []
    t_shared = None if table.signals is not None else table.channel(m.time)[0] * m.time_scale
    for x, name in enumerate(m.hall):
        level, stamps = table.channel(name)
        t = stamps * m.time_scale if stamps is not None else t_shared
        if t.size > 1 and np.any(np.diff(t) <= 0):
            k = int(np.nonzero(np.diff(t) <= 0)[0][0]) + 1
            raise RecordingError(table.path, k + 2 if table.signals is None else None, m.time, "times must increase")
        high = level > m.threshold
        k = np.nonzero(high[1:] != high[:-1])[0]
        times.append(0.5 * (t[k] + t[k + 1]))  # midway: unbiased within one sample period
        sensors.append(np.full(k.size, x))
        rising.append(high[k + 1])
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(sensors)[order], np.concatenate(rising)[order]


def _edges_from_table(table: TraceTable, m: TraceMapping):
    t = table.channel(m.time)[0] * m.time_scale
    sensor_raw = table.channel(m.sensor, numeric=False)[0]
    edge_raw = table.channel(m.edge, numeric=False)[0]
    s_map = {str(v): k for k, v in zip("ABC", (m.sensor_values["A"], m.sensor_values["B"], m.sensor_values["C"]))}
    e_map = {str(m.edge_values["rise"]): True, str(m.edge_values["fall"]): False}
    sensor = np.empty(t.size, dtype=np.int64)
    rising = np.empty(t.size, dtype=bool)
    for i in range(t.size):
        sv, ev = str(sensor_raw[i]).strip(), str(edge_raw[i]).strip()
        if sv not in s_map:
            raise RecordingError(table.path, i + 2, m.sensor, f"unknown sensor {sv!r} (mapped: {', '.join(s_map)})")
        if ev not in e_map:
            raise RecordingError(table.path, i + 2, m.edge, f"unknown edge {ev!r} (mapped: {', '.join(e_map)})")
        sensor[i] = "ABC".index(s_map[sv])
        rising[i] = e_map[ev]
    if t.size > 1 and np.any(np.diff(t) <= 0):
        k = int(np.nonzero(np.diff(t) <= 0)[0][0]) + 1
        raise RecordingError(table.path, k + 2, m.time, "times must increase")
    return t, sensor, rising


def read_trace(path: str | Path, mapping: TraceMapping, meta_path: str | Path) -> Recording:
    """A Recording from a trace file plus a meta.json (motor, segments); edges are assigned to the
    segment whose time span holds them, edges outside every segment are dropped."""
    path = Path(path)
    meta_path = Path(meta_path)
    motor, segments, tick, extra = read_meta_file(meta_path)
    table = open_trace(path)
    t, sensor, rising = (_edges_from_levels if mapping.kind == "levels" else _edges_from_table)(table, mapping)
    ref = None
    if mapping.ref_angle_mech_deg:
        angle, stamps = table.channel(mapping.ref_angle_mech_deg)
        t_angle = (stamps if stamps is not None else table.channel(mapping.time)[0]) * mapping.time_scale
        if np.any((angle < 0) | (angle >= 360)):
            k = int(np.nonzero((angle < 0) | (angle >= 360))[0][0])
            raise RecordingError(
                path,
                k + 2 if table.signals is None else None,
                mapping.ref_angle_mech_deg,
                f"{angle[k]!r} outside [0, 360)",
            )
        # angle at each edge time, interpolated on the unwrapped encoder angle
        unwrapped = np.degrees(np.unwrap(np.radians(angle)))
        ref = np.mod(np.interp(t, t_angle, unwrapped), 360.0)
    segment = np.full(t.size, -1, dtype=np.int64)
    for i, s in enumerate(segments):
        segment[(t >= s.t_start_s) & (t < s.t_end_s)] = i
    keep = segment >= 0
    if not keep.any():
        raise RecordingError(path, None, mapping.time, "no edge falls inside any segment of the meta.json")
    return Recording(
        motor=motor,
        segments=segments,
        t_s=t[keep],
        sensor=sensor[keep],
        rising=rising[keep],
        segment=segment[keep],
        ref_angle_mech_deg=None if ref is None else ref[keep],
        timer_tick_s=None,
        meta_extra=extra,
        path=path,
    )


def write_level_trace(
    rec: Recording,
    path: str | Path,
    sample_rate_hz: float,
    hall_names=("hall_a", "hall_b", "hall_c"),
    angle_name: str | None = "encoder_deg",
    time_name: str = "t_s",
) -> Path:
    """Sample a recording's Hall levels (and encoder angle) as a logger would, to CSV, Parquet
    or MDF4 by extension: the reverse of read_trace, used to check the readers."""
    path = Path(path)
    t = np.arange(rec.t_s[0] - 1e-4, rec.t_s[-1] + 1e-4, 1.0 / sample_rate_hz)
    levels = []
    for x in range(3):
        sel = rec.sensor == x
        te, up = rec.t_s[sel], rec.rising[sel]
        idx = np.searchsorted(te, t, side="right") - 1
        state = np.where(idx >= 0, up[np.clip(idx, 0, None)], ~up[0])
        levels.append(state.astype(float) * 5.0)
    cols = {time_name: t, hall_names[0]: levels[0], hall_names[1]: levels[1], hall_names[2]: levels[2]}
    if angle_name and rec.ref_angle_mech_deg is not None:
        unwrapped = np.degrees(np.unwrap(np.radians(rec.ref_angle_mech_deg)))
        cols[angle_name] = np.mod(np.interp(t, rec.t_s, unwrapped), 360.0)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(list(cols))
            for row in zip(*cols.values()):
                w.writerow([repr(float(v)) for v in row])
    elif suffix == ".parquet":
        import pandas as pd

        pd.DataFrame(cols).to_parquet(path)
    elif suffix == ".mf4":
        from asammdf import MDF, Signal

        mdf = MDF()
        mdf.append([Signal(v, t, name=k) for k, v in cols.items() if k != time_name])
        mdf.save(str(path), overwrite=True)
    else:
        raise ValueError(f"unknown trace format {suffix!r}")
    return path


def write_meta(rec: Recording, path: str | Path) -> Path:
    with tempfile.TemporaryDirectory() as tmp:
        write_recording(
            Recording(
                motor=rec.motor,
                segments=rec.segments,
                t_s=rec.t_s[:2],
                sensor=rec.sensor[:2],
                rising=rec.rising[:2],
                segment=rec.segment[:2],
                timer_tick_s=None,
            ),
            tmp,
        )
        text = (Path(tmp) / "meta.json").read_text()
    Path(path).write_text(text)
    return Path(path)
