"""Bench recordings in the ``hil-recording/1`` format (shared/recording-format.md), read strictly.

A recording that breaks the format is refused with :class:`RecordingError`, which names the
file, the line and the column (for meta.json: the JSON line and the key path). Nothing is
guessed. Files the format does not define (our simulator's ``ground_truth.csv``) are ignored by
the reader unless asked for.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "hil-recording/1"
SENSOR_NAMES = ("A", "B", "C")
EDGE_NAMES = ("fall", "rise")
EDGE_COLUMNS = ("t_s", "sensor", "edge", "segment")
EDGE_OPTIONAL = ("ref_angle_mech_deg",)
SAMPLE_REQUIRED = ("t_s", "segment")
SAMPLE_OPTIONAL = ("i_a", "i_b", "i_c", "u_a", "u_b", "u_c", "speed_rpm")
DIRECTIONS = ("forward", "reverse")
TRUTH_COLUMNS = ("t_ideal_s", "t_raw_s", "t_conditioned_s", "true_angle_mech_deg", "pole", "mean_abs_current_a")


class RecordingError(ValueError):
    """The recording breaks the format. ``file``, ``line`` (1-based) and ``column`` say where."""

    def __init__(self, file: str | Path, line: int | None, column: str | None, message: str):
        self.file, self.line, self.column = str(file), line, column
        where = str(file)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column {column}"
        super().__init__(f"{where}: {message}")


@dataclass
class Segment:
    id: str
    t_start_s: float
    t_end_s: float
    direction: str
    speed_rpm: float
    mean_phase_current_a: float
    load_scale: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def direction_sign(self) -> int:
        return 1 if self.direction == "forward" else -1


@dataclass
class Recording:
    motor: dict[str, Any]
    segments: list[Segment]
    t_s: np.ndarray                 #: capture times
    sensor: np.ndarray              #: 0, 1, 2
    rising: np.ndarray              #: bool
    segment: np.ndarray             #: index into segments
    ref_angle_mech_deg: np.ndarray | None = None
    timer_tick_s: float | None = None
    samples: dict[str, np.ndarray] | None = None  #: columns; "segment" holds indices
    truth: dict[str, np.ndarray] | None = None    #: simulator ground truth per edge (optional)
    meta_extra: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    @property
    def pole_pairs(self) -> int:
        return int(self.motor["pole_pairs"])

    @property
    def segment_ids(self) -> list[str]:
        return [s.id for s in self.segments]

    def __len__(self) -> int:
        return int(self.t_s.size)


# --- writing --------------------------------------------------------------------------------

def _fmt(x: float) -> str:
    return repr(float(x))


def write_recording(rec: Recording, directory: str | Path) -> Path:
    """Write ``rec`` as a hil-recording/1 directory; floats are written round-trip exact."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    if rec.t_s.size > 1 and np.any(np.diff(rec.t_s) <= 0):
        n = int(np.nonzero(np.diff(rec.t_s) <= 0)[0][0])
        raise RecordingError(d / "edges.csv", n + 3, "t_s", "capture times must increase; refusing to write a recording our own reader would refuse")
    meta = {
        "format": FORMAT,
        "motor": rec.motor,
        "timer_tick_s": rec.timer_tick_s if rec.timer_tick_s is not None else 0,
        "segments": [
            {"id": s.id, "t_start_s": s.t_start_s, "t_end_s": s.t_end_s, "direction": s.direction,
             "speed_rpm": s.speed_rpm, "mean_phase_current_a": s.mean_phase_current_a, "load_scale": s.load_scale, **s.extra}
            for s in rec.segments
        ],
        **rec.meta_extra,
    }
    (d / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    ids = rec.segment_ids
    with open(d / "edges.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        cols = list(EDGE_COLUMNS) + (["ref_angle_mech_deg"] if rec.ref_angle_mech_deg is not None else [])
        w.writerow(cols)
        for n in range(rec.t_s.size):
            row = [_fmt(rec.t_s[n]), SENSOR_NAMES[rec.sensor[n]], EDGE_NAMES[int(rec.rising[n])], ids[rec.segment[n]]]
            if rec.ref_angle_mech_deg is not None:
                row.append(_fmt(rec.ref_angle_mech_deg[n]))
            w.writerow(row)
    if rec.samples is not None:
        cols = ["t_s", "segment"] + [c for c in SAMPLE_OPTIONAL if c in rec.samples]
        with open(d / "samples.csv", "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(cols)
            seg = rec.samples["segment"]
            data = [rec.samples[c] for c in cols[2:]]
            for n in range(rec.samples["t_s"].size):
                w.writerow([_fmt(rec.samples["t_s"][n]), ids[seg[n]]] + [_fmt(a[n]) for a in data])
    if rec.truth is not None:
        with open(d / "ground_truth.csv", "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            cols = [c for c in TRUTH_COLUMNS if c in rec.truth]
            w.writerow(cols)
            for n in range(rec.t_s.size):
                w.writerow([_fmt(rec.truth[c][n]) for c in cols])
    return d


# --- reading --------------------------------------------------------------------------------

def _json_line(text: str, needle: str, nth: int = 0) -> int | None:
    pos = -1
    for _ in range(nth + 1):
        pos = text.find(needle, pos + 1)
        if pos < 0:
            return None
    return text.count("\n", 0, pos) + 1


def _read_meta(d: Path) -> tuple[dict, list[Segment], float | None, dict]:
    path = d / "meta.json"
    if not path.is_file():
        raise RecordingError(path, None, None, "missing file (a recording needs meta.json and edges.csv)")
    text = path.read_text()
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(path, exc.lineno, f"{exc.colno} (character)", f"not valid JSON: {exc.msg}") from None
    if not isinstance(meta, dict):
        raise RecordingError(path, 1, None, "top level must be a JSON object")

    def err(key_path: str, key: str, message: str, nth: int = 0):
        # line of the key; for a missing key, the line of the object that should hold it
        line = _json_line(text, f'"{key}"', nth)
        if line is None:
            parent = key_path.rsplit(".", 1)[0].split("[")[0] if "." in key_path else None
            line = _json_line(text, f'"{parent}"') if parent else 1
        raise RecordingError(path, line, key_path, message)

    if meta.get("format") != FORMAT:
        err("format", "format", f"expected \"{FORMAT}\", got {meta.get('format')!r}")
    motor = meta.get("motor")
    if not isinstance(motor, dict):
        err("motor", "motor", "missing or not an object")
    pp = motor.get("pole_pairs")
    if isinstance(pp, bool) or not isinstance(pp, (int, float)) or not float(pp).is_integer() or pp < 1:
        err("motor.pole_pairs", "pole_pairs", f"must be a positive integer, got {pp!r}")
    for key, value in motor.items():
        if key != "pole_pairs" and isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isfinite(value):
            err(f"motor.{key}", key, "must be finite")
    tick = meta.get("timer_tick_s")
    if tick is not None:
        if isinstance(tick, bool) or not isinstance(tick, (int, float)) or not math.isfinite(tick) or tick < 0:
            err("timer_tick_s", "timer_tick_s", f"must be a finite number >= 0, got {tick!r}")
        tick = float(tick) or None
    segs = meta.get("segments")
    if not isinstance(segs, list) or not segs:
        err("segments", "segments", "missing or empty (at least one segment is needed)")
    segments: list[Segment] = []
    seen: set[str] = set()
    numeric = ("t_start_s", "t_end_s", "speed_rpm", "mean_phase_current_a", "load_scale")
    for i, s in enumerate(segs):
        if not isinstance(s, dict):
            err(f"segments[{i}]", "segments", "must be an object")
        sid = s.get("id")
        if not isinstance(sid, str) or not sid:
            err(f"segments[{i}].id", "id", f"must be a non-empty string, got {sid!r}", i)
        if sid in seen:
            err(f"segments[{i}].id", "id", f"duplicate segment id {sid!r}", i)
        seen.add(sid)
        vals = {}
        for key in numeric:
            v = s.get(key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                err(f"segments[{i}].{key}", key, f"must be a finite number, got {v!r}", i)
            vals[key] = float(v)
        if vals["t_end_s"] <= vals["t_start_s"]:
            err(f"segments[{i}].t_end_s", "t_end_s", "must be after t_start_s", i)
        direction = s.get("direction")
        if direction not in DIRECTIONS:
            err(f"segments[{i}].direction", "direction", f"must be 'forward' or 'reverse', got {direction!r}", i)
        extra = {k: v for k, v in s.items() if k not in numeric + ("id", "direction")}
        segments.append(Segment(sid, direction=direction, extra=extra, **vals))
    order = sorted(range(len(segments)), key=lambda i: segments[i].t_start_s)
    for a, b in zip(order, order[1:]):
        if segments[b].t_start_s < segments[a].t_end_s:
            err(f"segments[{b}].t_start_s", "t_start_s", f"segments {segments[a].id!r} and {segments[b].id!r} overlap in time (they must be disjoint)", b)
    extra = {k: v for k, v in meta.items() if k not in ("format", "motor", "timer_tick_s", "segments")}
    return motor, segments, tick, extra


def _read_table(path: Path, required: tuple[str, ...], optional: tuple[str, ...]):
    """Rows of a CSV with a header; returns (columns present, list of (line, row))."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise RecordingError(path, 1, None, "empty file (a header line is required)") from None
        header = [h.strip() for h in header]
        for col in required:
            if col not in header:
                raise RecordingError(path, 1, col, f"missing column (header has: {', '.join(header)})")
        if len(set(header)) != len(header):
            dup = next(h for h in header if header.count(h) > 1)
            raise RecordingError(path, 1, dup, "duplicate column")
        rows = []
        for row in reader:
            line = reader.line_num
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            if len(row) != len(header):
                raise RecordingError(path, line, None, f"expected {len(header)} fields, found {len(row)}")
            rows.append((line, row))
    return header, rows


def _floats(path: Path, header: list[str], rows, column: str, low=None, high_open=None) -> np.ndarray:
    j = header.index(column)
    try:  # fast path: numpy parses with float()'s grammar; on failure find the offending line
        out = np.array([row[j] for _, row in rows], dtype=float)
    except ValueError:
        for line, row in rows:
            try:
                float(row[j])
            except ValueError:
                raise RecordingError(path, line, column, f"not a number: {row[j].strip()!r}") from None
        raise
    bad = ~np.isfinite(out)
    if low is not None:
        bad |= (out < low) | (out >= high_open)
    if bad.any():
        n = int(np.argmax(bad))
        line, text, v = rows[n][0], rows[n][1][j].strip(), out[n]
        if not math.isfinite(v):
            raise RecordingError(path, line, column, f"not finite: {text!r}")
        raise RecordingError(path, line, column, f"{v!r} outside [{low}, {high_open})")
    return out


def _increasing(path: Path, rows, t: np.ndarray):
    if t.size > 1:
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if bad.size:
            n = int(bad[0]) + 1
            raise RecordingError(path, rows[n][0], "t_s", f"times must increase: {t[n]!r} after {t[n - 1]!r}")


def _choice(path: Path, header, rows, column: str, choices: dict[str, int], what: str) -> np.ndarray:
    j = header.index(column)
    out = np.empty(len(rows), dtype=np.int64)
    for n, (line, row) in enumerate(rows):
        v = row[j].strip()
        if v not in choices:
            raise RecordingError(path, line, column, f"unknown {what} {v!r} (expected one of: {', '.join(choices)})")
        out[n] = choices[v]
    return out


def _read_samples_fast(path: Path, seg_index: dict[str, int]) -> dict[str, np.ndarray] | None:
    """samples.csv through pandas' C parser (a million rows in about a second, against some
    fifteen for the row-by-row reader). Every check of the strict reader is made on the whole
    columns; on any doubt this returns None and the strict reader runs, so a bad file is still
    refused with its file, line and column."""
    try:
        import pandas as pd
    except ImportError:
        return None
    with open(path, newline="") as fh:
        header = [h.strip() for h in next(csv.reader(fh), [])]
    if not all(c in header for c in SAMPLE_REQUIRED) or len(set(header)) != len(header):
        return None
    numeric = [c for c in header if c != "segment"]
    try:
        df = pd.read_csv(path, header=0, names=header, dtype={**{c: "float64" for c in numeric}, "segment": object},
                         skipinitialspace=True, engine="c", keep_default_na=False, na_filter=False)
    except (ValueError, pd.errors.ParserError):
        return None
    out = {c: df[c].to_numpy(dtype=float) for c in numeric if c in SAMPLE_REQUIRED or c in SAMPLE_OPTIONAL}
    if any(not np.all(np.isfinite(v)) for v in out.values()) or (out["t_s"].size > 1 and np.any(np.diff(out["t_s"]) <= 0)):
        return None
    segment = df["segment"].str.strip().map(seg_index)
    if segment.isna().any():
        return None
    out["segment"] = segment.to_numpy(dtype=np.int64)
    return out


def read_recording(directory: str | Path, *, with_truth: bool = True) -> Recording:
    d = Path(directory)
    if not d.is_dir():
        raise RecordingError(d, None, None, "not a directory (a recording is a directory with meta.json and edges.csv)")
    motor, segments, tick, extra = _read_meta(d)
    seg_index = {s.id: i for i, s in enumerate(segments)}
    path = d / "edges.csv"
    if not path.is_file():
        raise RecordingError(path, None, None, "missing file")
    header, rows = _read_table(path, EDGE_COLUMNS, EDGE_OPTIONAL)
    t = _floats(path, header, rows, "t_s")
    _increasing(path, rows, t)
    sensor = _choice(path, header, rows, "sensor", {"A": 0, "B": 1, "C": 2}, "sensor")
    rising = _choice(path, header, rows, "edge", {"fall": 0, "rise": 1}, "edge").astype(bool)
    segment = _choice(path, header, rows, "segment", seg_index, "segment")
    ref = _floats(path, header, rows, "ref_angle_mech_deg", 0.0, 360.0) if "ref_angle_mech_deg" in header else None
    samples = None
    spath = d / "samples.csv"
    if spath.is_file():
        samples = _read_samples_fast(spath, seg_index)
    if spath.is_file() and samples is None:
        sh, srows = _read_table(spath, SAMPLE_REQUIRED, SAMPLE_OPTIONAL)
        samples = {"t_s": _floats(spath, sh, srows, "t_s")}
        _increasing(spath, srows, samples["t_s"])
        samples["segment"] = _choice(spath, sh, srows, "segment", seg_index, "segment")
        for c in SAMPLE_OPTIONAL:
            if c in sh:
                samples[c] = _floats(spath, sh, srows, c)
    truth = None
    tpath = d / "ground_truth.csv"
    if with_truth and tpath.is_file():
        th, trows = _read_table(tpath, (), TRUTH_COLUMNS)
        if len(trows) != t.size:
            raise RecordingError(tpath, None, None, f"{len(trows)} rows for {t.size} edges")
        truth = {c: _floats(tpath, th, trows, c) for c in th if c in TRUTH_COLUMNS}
        if "pole" in truth:
            truth["pole"] = truth["pole"].astype(np.int64)
    return Recording(motor=motor, segments=segments, t_s=t, sensor=sensor, rising=rising, segment=segment,
                     ref_angle_mech_deg=ref, timer_tick_s=tick, samples=samples, truth=truth, meta_extra=extra, path=d)


def recording_from_edges(motor: dict, edges, segments: list[Segment], *, timer_tick_s: float | None = None,
                         samples: dict[str, np.ndarray] | None = None, reference_angle: bool = True) -> Recording:
    """A Recording of simulated edges (a :class:`plant_models.EdgeLog`), with ground truth kept."""
    pp = int(motor["pole_pairs"])
    keep = edges.segment >= 0
    e = edges.take(keep)
    # true angle at the timer's capture instant (the reference encoder's view)
    w_e_deg_s = np.abs(e.speed_rpm) * 6.0 * pp  # the electrical plant logs signed speed, the kinematic one magnitudes
    theta_cap = e.theta_e_capture_deg - e.direction * w_e_deg_s * (e.t_conditioned_s - e.t_capture_s)
    angle_mech = np.mod(theta_cap / pp, 360.0)
    angle_mech[angle_mech >= 360.0] = 0.0
    truth = {
        "t_ideal_s": e.t_ideal_s, "t_raw_s": e.t_raw_s, "t_conditioned_s": e.t_conditioned_s,
        "true_angle_mech_deg": angle_mech, "pole": e.pole, "mean_abs_current_a": e.mean_abs_current_a,
    }
    return Recording(motor=dict(motor), segments=segments, t_s=e.t_capture_s, sensor=e.sensor, rising=e.rising,
                     segment=e.segment, ref_angle_mech_deg=angle_mech if reference_angle else None,
                     timer_tick_s=timer_tick_s, samples=samples, truth=truth)


def motor_meta(config) -> dict[str, Any]:
    """The meta.json ``motor`` block of a PlantConfig's nominal motor."""
    m = config.motor
    return {
        "pole_pairs": int(m.pole_pairs), "phase_resistance_ohm": m.phase_resistance_ohm,
        "phase_inductance_h": m.phase_inductance_h, "ke_v_s_per_rad": m.ke_v_s_per_rad,
        "inertia_kg_m2": m.inertia_kg_m2, "fan_coefficient_n_m_s2": m.fan_coefficient_n_m_s2,
        "supply_v": m.supply_v, "friction_n_m_s_per_rad": m.friction_n_m_s_per_rad, "flat_top_deg_e": m.flat_top_deg_e,
    }


def record_kinematic(config, profile, seed: int = 0, reference_angle: bool = True) -> Recording:
    """Simulate ``profile`` (OperatingPoints) in the kinematic mode and return it as a Recording."""
    from plant_models.kinematic import simulate_edges

    edges = simulate_edges(config, profile, seed=seed)
    segments, t = [], 0.0
    for i, op in enumerate(profile):
        segments.append(Segment(op.id or f"op{i + 1:02d}", t, t + op.duration_s, "forward" if op.direction > 0 else "reverse",
                                float(op.speed_rpm), float(op.mean_phase_current_a), float(op.load_scale)))
        t += op.duration_s
    tick = config.compile().timer_tick_s or None
    return recording_from_edges(motor_meta(config), edges, segments, timer_tick_s=tick, reference_angle=reference_angle)


def record_electrical(config, profile, seed: int = 0, *, sample_rate_hz: float = 20e3, settle_s: float = 0.05,
                      voltage_noise_v: float = 0.0, speed_noise_rpm: float = 0.0, reference_angle: bool = True) -> Recording:
    """Simulate ``profile`` (OperatingPoints) on the electrical plant, commutating on the raw Hall
    edges at the duty that holds each set speed (a speed loop's steady state, computed from the
    plant's true resistance, back-EMF constant and dead time), and return edges plus samples
    (currents through the current sensors; terminal voltages and speed with the given white
    measurement noise) as a Recording. Each segment's ``mean_phase_current_a`` is the measured
    mean |i| over the three phases, as the format defines it."""
    import dataclasses

    from plant_models import RawHallCommutation, Simulation
    from plant_models.edgelog import EdgeLog
    from plant_models.plant import steady_state

    cp = config.compile()
    true_motor = dataclasses.replace(config.motor, phase_resistance_ohm=cp.phase_resistance_ohm, ke_v_s_per_rad=cp.ke_v_s_per_rad)
    noise = np.random.default_rng(seed + 7919)
    logs, segments = [], []
    samples: dict[str, list] = {k: [] for k in ("t_s", "segment", *SAMPLE_OPTIONAL)}
    t_offset = 0.0
    for index, op in enumerate(profile):
        duty = steady_state(true_motor, op.speed_rpm, op.load_scale)["duty"] + cp.dead_time_s * config.inverter.pwm_frequency_hz
        sim = Simulation(config, RawHallCommutation(), duty=min(duty, 1.0), initial_speed_rpm=op.speed_rpm, direction=op.direction,
                         seed=seed + index, sample_rate_hz=sample_rate_hz)
        sim.run_until(settle_s)
        sim.mark_segment(index)
        sim.run_until(settle_s + op.duration_s)
        e = sim.edges()
        e = e.take(e.segment == index)
        s = sim.samples()
        keep = s.t_s >= settle_s
        shift = t_offset - settle_s
        for name in ("t_capture_s", "t_conditioned_s", "t_raw_s", "t_ideal_s"):
            setattr(e, name, getattr(e, name) + shift)
        logs.append(e)
        n = int(keep.sum())
        samples["t_s"].append(s.t_s[keep] + shift)
        samples["segment"].append(np.full(n, index, dtype=np.int64))
        for j, c in enumerate("abc"):
            samples[f"i_{c}"].append(s.i_meas_a[keep, j])
            samples[f"u_{c}"].append(s.u_v[keep, j] + voltage_noise_v * noise.standard_normal(n))
        samples["speed_rpm"].append(s.speed_rpm[keep] + speed_noise_rpm * noise.standard_normal(n))
        t_end = t_offset + op.duration_s
        segments.append(Segment(op.id or f"op{index + 1:02d}", t_offset, t_end, "forward" if op.direction > 0 else "reverse",
                                float(op.speed_rpm), float(np.abs(s.i_meas_a[keep]).mean()), float(op.load_scale)))
        t_offset = t_end + 1e-3
    return recording_from_edges(motor_meta(config), EdgeLog.concatenate(logs), segments, timer_tick_s=cp.timer_tick_s or None,
                                samples={k: np.concatenate(v) for k, v in samples.items()}, reference_angle=reference_angle)
