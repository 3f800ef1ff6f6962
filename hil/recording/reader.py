"""Bench recordings in the ``hil-recording/1`` format (docs/recording-format.md), read strictly.

A recording that breaks the format is refused with :class:`RecordingError`, which names the
file, the line and the column (for meta.json: the JSON line and the key path). Nothing is
guessed. Files the format does not define (our simulator's ``ground_truth.csv``) are ignored by
the reader unless asked for.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bldc.motor import steady_state
from plant_models import RawHallCommutation, Simulation
from plant_models.edgelog import EdgeLog
from plant_models.kinematic import simulate_edges

FORMAT = "hil-recording/1"
SENSOR_NAMES = ("A", "B", "C")
EDGE_NAMES = ("fall", "rise")
EDGE_COLUMNS = ("t_s", "sensor", "edge", "segment")
EDGE_OPTIONAL = ("ref_angle_mech_deg",)
SAMPLE_REQUIRED = ("t_s", "segment")
SAMPLE_OPTIONAL = ("i_a", "i_b", "i_c", "u_a", "u_b", "u_c", "speed_rpm")
DIRECTIONS = ("forward", "reverse")
#: the segment column of an ordinary run: empty in every row (read as segment -1)
ORDINARY_SEGMENT = {"": -1}
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
        if "pole_pairs" not in self.motor:
            raise RecordingError(
                (self.path or Path("recording")) / "meta.json",
                None,
                "motor.pole_pairs",
                "not stated; this step needs the motor's pole pairs (an ordinary run may leave them out)",
            )
        return int(self.motor["pole_pairs"])

    @property
    def stated_pole_pairs(self) -> int | None:
        """The pole pairs if meta.json states them (an ordinary run may not)."""
        return int(self.motor["pole_pairs"]) if "pole_pairs" in self.motor else None

    @property
    def ordinary(self) -> bool:
        """One ordinary run (no segments): speed, direction and reversals come from the edges."""
        return not self.segments

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
        raise RecordingError(
            d / "edges.csv",
            n + 3,
            "t_s",
            "capture times must increase; refusing to write a recording our own reader would refuse",
        )
    meta = {
        "format": FORMAT,
        "motor": rec.motor,
        "timer_tick_s": rec.timer_tick_s if rec.timer_tick_s is not None else 0,
        **({} if rec.ordinary else {"segments": [
            {
                "id": s.id,
                "t_start_s": s.t_start_s,
                "t_end_s": s.t_end_s,
                "direction": s.direction,
                "speed_rpm": s.speed_rpm,
                "mean_phase_current_a": s.mean_phase_current_a,
                "load_scale": s.load_scale,
                **s.extra,
            }
            for s in rec.segments
        ]}),
        **rec.meta_extra,
    }
    (d / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    ids = rec.segment_ids
    with open(d / "edges.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        # an ordinary run has no segment column (the format allows it absent)
        cols = list(EDGE_COLUMNS if not rec.ordinary else EDGE_COLUMNS[:3])
        cols += ["ref_angle_mech_deg"] if rec.ref_angle_mech_deg is not None else []
        w.writerow(cols)
        for n in range(rec.t_s.size):
            row = [_fmt(rec.t_s[n]), SENSOR_NAMES[rec.sensor[n]], EDGE_NAMES[int(rec.rising[n])]]
            row += [] if rec.ordinary else [ids[rec.segment[n]]]
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
                sid = ids[seg[n]] if seg[n] >= 0 else ""
                w.writerow([_fmt(rec.samples["t_s"][n]), sid] + [_fmt(a[n]) for a in data])
    if rec.truth is not None:
        with open(d / "ground_truth.csv", "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            cols = [c for c in TRUTH_COLUMNS if c in rec.truth]
            w.writerow(cols)
            for n in range(rec.t_s.size):
                w.writerow([_fmt(rec.truth[c][n]) for c in cols])
    return d


# --- reading --------------------------------------------------------------------------------

#: what a reader takes in; past these a file is refused with one line (memory stays bounded
#: whatever is handed in: a table's columns are held as packed arrays, some 14-22 bytes per edge)
MAX_META_BYTES = 1 << 20
MAX_TABLE_BYTES = 256 << 20
MAX_LINE_BYTES = 4096
MAX_JSON_DEPTH = 64
MAX_JSON_NUMBER_CHARS = 100
BOM = b"\xef\xbb\xbf"


def _checked_size(path: Path, limit: int) -> int:
    size = path.stat().st_size
    if size > limit:
        raise RecordingError(path, None, None, f"{size} bytes, above the reader's limit of {limit} bytes")
    return size


def _line_column(data: bytes, offset: int) -> tuple[int, int]:
    """1-based line and column (in characters of the line read as UTF-8) of a byte offset."""
    start = data.rfind(b"\n", 0, offset) + 1
    return data.count(b"\n", 0, offset) + 1, len(data[start:offset].decode("utf-8", "replace")) + 1


def _decode(path: Path, data: bytes, line: int | None = None) -> str:
    """UTF-8 text of ``data`` (a leading byte-order mark is dropped); a bad byte is named by line and column."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        offset = exc.start + (len(BOM) if data.startswith(BOM) else 0)
        row, col = _line_column(data, offset)
        raise RecordingError(
            path, line or row, f"{col} (character)", f"not valid UTF-8 (byte 0x{data[offset]:02X})"
        ) from None


def _json_limits(path: Path, text: str) -> None:
    """Nesting deeper than MAX_JSON_DEPTH or a number longer than MAX_JSON_NUMBER_CHARS is refused
    at its line and column before the JSON parser sees it (it would recurse, or convert a
    5000-digit integer, with no position in its error)."""
    depth, in_string, escape, number_start, line, line_start = 0, False, False, -1, 1, 0
    for i, ch in enumerate(text):
        if in_string:
            if escape:
                escape = False
            elif ch == "\\":
                escape = True
            elif ch == '"':
                in_string = False
            elif ch == "\n":
                line, line_start = line + 1, i + 1
            continue
        if ch in "-+.eE0123456789":
            if number_start < 0:
                number_start = i
            elif i - number_start >= MAX_JSON_NUMBER_CHARS:
                raise RecordingError(
                    path,
                    line,
                    f"{number_start - line_start + 1} (character)",
                    f"a number longer than {MAX_JSON_NUMBER_CHARS} characters",
                )
            continue
        number_start = -1
        if ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise RecordingError(
                    path, line, f"{i - line_start + 1} (character)", f"nested deeper than {MAX_JSON_DEPTH} levels"
                )
        elif ch in "]}":
            depth -= 1
        elif ch == "\n":
            line, line_start = line + 1, i + 1


def _json_line(text: str, needle: str, nth: int = 0) -> int | None:
    pos = -1
    for _ in range(nth + 1):
        pos = text.find(needle, pos + 1)
        if pos < 0:
            return None
    return text.count("\n", 0, pos) + 1


def _read_meta(d: Path) -> tuple[dict, list[Segment], float | None, dict]:
    return read_meta_file(d / "meta.json")


def read_meta_file(path: Path) -> tuple[dict, list[Segment], float | None, dict]:
    """The motor, segments, timer tick and extra keys of a hil-recording/1 meta.json."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, None, None, "missing file (a recording needs meta.json and edges.csv)")
    _checked_size(path, MAX_META_BYTES)
    text = _decode(path, path.read_bytes())
    _json_limits(path, text)
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(path, exc.lineno, f"{exc.colno} (character)", f"not valid JSON: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # after _json_limits: a safety net, never a traceback
        raise RecordingError(path, None, None, f"not readable JSON: {exc}") from None
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
        err("format", "format", f'expected "{FORMAT}", got {meta.get("format")!r}')
    segs = meta.get("segments")
    ordinary = segs is None or segs == []
    # an ordinary run (a logic analyser's capture) may know nothing of the motor
    motor = meta.get("motor", {} if ordinary else None)
    if not isinstance(motor, dict):
        err("motor", "motor", "missing or not an object")
    pp = motor.get("pole_pairs")
    if not (ordinary and pp is None) and (
        isinstance(pp, bool) or not isinstance(pp, (int, float)) or not float(pp).is_integer() or pp < 1
    ):
        err("motor.pole_pairs", "pole_pairs", f"must be a positive integer, got {pp!r}")
    for key, value in motor.items():
        if (
            key != "pole_pairs"
            and isinstance(value, (int, float))
            and not isinstance(value, bool)
            and not math.isfinite(value)
        ):
            err(f"motor.{key}", key, "must be finite")
    tick = meta.get("timer_tick_s")
    if tick is not None:
        if isinstance(tick, bool) or not isinstance(tick, (int, float)) or not math.isfinite(tick) or tick < 0:
            err("timer_tick_s", "timer_tick_s", f"must be a finite number >= 0, got {tick!r}")
        tick = float(tick) or None
    if ordinary:
        segs = []
    elif not isinstance(segs, list):
        err("segments", "segments", "must be a list of segments (or absent, or empty, for an ordinary run)")
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
            err(
                f"segments[{b}].t_start_s",
                "t_start_s",
                f"segments {segments[a].id!r} and {segments[b].id!r} overlap in time (they must be disjoint)",
                b,
            )
    extra = {k: v for k, v in meta.items() if k not in ("format", "motor", "timer_tick_s", "segments")}
    return motor, segments, tick, extra


class _Column:
    """How one column is read: ``float`` (finite, optionally within [low, high_open)) or a choice."""

    def __init__(
        self,
        name: str,
        choices: dict[str, int] | None = None,
        what: str = "",
        low: float | None = None,
        high_open: float | None = None,
        increasing: bool = False,
    ):
        self.name, self.choices, self.what, self.low, self.high_open, self.increasing = (
            name,
            choices,
            what,
            low,
            high_open,
            increasing,
        )
        self.values = array("d") if choices is None else array("q")

    def add(self, path: Path, line: int, text: str, last: float | None) -> float | None:
        v = text.strip()
        if self.choices is not None:
            if v not in self.choices and self.choices == ORDINARY_SEGMENT:
                raise RecordingError(
                    path, line, self.name, f"{v[:40]!r}, but meta.json has no segments (an ordinary run): leave it out"
                )
            if v not in self.choices:
                raise RecordingError(
                    path,
                    line,
                    self.name,
                    f"unknown {self.what} {v[:40]!r} (expected one of: {', '.join(list(self.choices)[:12])})",
                )
            self.values.append(self.choices[v])
            return None
        try:
            x = float(v)
        except ValueError:
            raise RecordingError(path, line, self.name, f"not a number: {v[:40]!r}") from None
        if not math.isfinite(x):
            raise RecordingError(path, line, self.name, f"not finite: {v[:40]!r}")
        if self.low is not None and not self.low <= x < self.high_open:
            raise RecordingError(path, line, self.name, f"{x!r} outside [{self.low}, {self.high_open})")
        if self.increasing and last is not None and not x > last:
            raise RecordingError(path, line, self.name, f"times must increase: {x!r} after {last!r}")
        self.values.append(x)
        return x


def _lines(path: Path, max_bytes: int):
    """(line number, text) of a CSV file, read line by line in binary: a line longer than
    MAX_LINE_BYTES, a NUL byte or invalid UTF-8 is refused where it is; memory is one line."""
    _checked_size(path, max_bytes)
    with open(path, "rb") as fh:
        for number, raw in enumerate(iter(lambda: fh.readline(MAX_LINE_BYTES + 1), b""), start=1):
            if len(raw) > MAX_LINE_BYTES:
                raise RecordingError(path, number, None, f"line longer than {MAX_LINE_BYTES} bytes")
            if number == 1 and raw.startswith(BOM):
                raw = raw[len(BOM) :]
            nul = raw.find(b"\0")
            if nul >= 0:
                raise RecordingError(path, number, f"{nul + 1} (byte)", "NUL byte (not a text file)")
            yield number, _decode(path, raw, number)


def _read_columns(path: Path, required: tuple[str, ...], columns: list[_Column], max_bytes: int = MAX_TABLE_BYTES):
    """Stream a CSV with a header: every value checked as it is read (the error names its line
    and column), kept in packed arrays. Returns (header, {name: numpy array}); columns the
    header lacks are left out."""
    lines = _lines(path, max_bytes)
    header_line = next(lines, None)
    if header_line is None:
        raise RecordingError(path, 1, None, "empty file (a header line is required)")
    header = [h.strip() for h in _split(path, *header_line)]
    for col in required:
        if col not in header:
            raise RecordingError(path, 1, col, f"missing column (header has: {', '.join(h[:40] for h in header[:20])})")
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise RecordingError(path, 1, dup, "duplicate column")
    wanted = [(header.index(c.name), c) for c in columns if c.name in header]
    last = {c.name: None for _, c in wanted}
    for line, text in lines:
        if not text.strip():
            continue
        row = _split(path, line, text)
        if len(row) != len(header):
            raise RecordingError(path, line, None, f"expected {len(header)} fields, found {len(row)}")
        for j, c in wanted:
            last[c.name] = c.add(path, line, row[j], last[c.name])
    out = {}
    for _, c in wanted:  # one column at a time, so the copy costs one column at most
        out[c.name] = np.array(c.values, dtype=np.float64 if c.choices is None else np.int64)
        c.values = None
    return header, out


def _split(path: Path, line: int, text: str) -> list[str]:
    try:
        return next(csv.reader([text], strict=True))
    except csv.Error as exc:
        raise RecordingError(path, line, None, f"not valid CSV: {exc}") from None


def _read_samples_fast(
    path: Path, seg_index: dict[str, int], max_bytes: int = MAX_TABLE_BYTES
) -> dict[str, np.ndarray] | None:
    """samples.csv through pandas' C parser (a million rows in about a second, against some
    fifteen for the row-by-row reader). Every check of the strict reader is made on the whole
    columns; on any doubt this returns None and the strict reader runs, so a bad file is still
    refused with its file, line and column."""
    try:
        import pandas as pd
    except ImportError:
        return None
    first = next(_lines(path, max_bytes), None)  # the header, checked like every line (BOM, UTF-8, length)
    header = [h.strip() for h in _split(path, *first)] if first else []
    if not all(c in header for c in SAMPLE_REQUIRED) or len(set(header)) != len(header):
        return None  # (an ordinary run without a segment column too: the strict reader takes it)
    numeric = [c for c in header if c != "segment"]
    try:
        df = pd.read_csv(
            path,
            header=0,
            names=header,
            dtype={**{c: "float64" for c in numeric}, "segment": object},
            encoding="utf-8-sig",
            skipinitialspace=True,
            engine="c",
            keep_default_na=False,
            na_filter=False,
        )
    except (ValueError, pd.errors.ParserError):  # UnicodeDecodeError is a ValueError
        return None
    out = {c: df[c].to_numpy(dtype=float) for c in numeric if c in SAMPLE_REQUIRED or c in SAMPLE_OPTIONAL}
    if any(not np.all(np.isfinite(v)) for v in out.values()) or (
        out["t_s"].size > 1 and np.any(np.diff(out["t_s"]) <= 0)
    ):
        return None
    segment = df["segment"].str.strip().map(seg_index)
    if segment.isna().any():
        return None
    out["segment"] = segment.to_numpy(dtype=np.int64)
    return out


def read_recording(
    directory: str | Path, *, with_truth: bool = True, max_table_bytes: int = MAX_TABLE_BYTES
) -> Recording:
    d = Path(directory)
    if not d.is_dir():
        raise RecordingError(d, None, None, "not a directory (a recording is a directory with meta.json and edges.csv)")
    motor, segments, tick, extra = _read_meta(d)
    seg_index = {s.id: i for i, s in enumerate(segments)} if segments else ORDINARY_SEGMENT
    path = d / "edges.csv"
    if not path.is_file():
        raise RecordingError(path, None, None, "missing file")
    # an ordinary run: the segment column is absent, or empty in every row
    header, cols = _read_columns(
        path,
        EDGE_COLUMNS if segments else EDGE_COLUMNS[:3],
        [
            _Column("t_s", increasing=True),
            _Column("sensor", {"A": 0, "B": 1, "C": 2}, "sensor"),
            _Column("edge", {"fall": 0, "rise": 1}, "edge"),
            _Column("segment", seg_index if segments else ORDINARY_SEGMENT, "segment"),
            _Column("ref_angle_mech_deg", low=0.0, high_open=360.0),
        ],
        max_table_bytes,
    )
    t = cols["t_s"]
    samples = None
    spath = d / "samples.csv"
    if spath.is_file():
        samples = _read_samples_fast(spath, seg_index, max_table_bytes)
    if spath.is_file() and samples is None:
        _, samples = _read_columns(
            spath,
            SAMPLE_REQUIRED if segments else SAMPLE_REQUIRED[:1],
            [_Column("t_s", increasing=True), _Column("segment", seg_index, "segment")]
            + [_Column(c) for c in SAMPLE_OPTIONAL],
            max_table_bytes,
        )
    truth = None
    tpath = d / "ground_truth.csv"
    if with_truth and tpath.is_file():
        _, truth = _read_columns(tpath, (), [_Column(c) for c in TRUTH_COLUMNS], max_table_bytes)
        n = next(iter(truth.values())).size if truth else 0
        if n != t.size:
            raise RecordingError(tpath, None, None, f"{n} rows for {t.size} edges")
        if "pole" in truth:
            truth["pole"] = truth["pole"].astype(np.int64)
    return Recording(
        motor=motor,
        segments=segments,
        t_s=t,
        sensor=cols["sensor"],
        rising=cols["edge"].astype(bool),
        segment=cols["segment"] if "segment" in cols else np.full(t.size, -1, dtype=np.int64),
        ref_angle_mech_deg=cols.get("ref_angle_mech_deg"),
        timer_tick_s=tick,
        samples=samples,
        truth=truth,
        meta_extra=extra,
        path=d,
    )


def recording_from_edges(
    motor: dict,
    edges,
    segments: list[Segment],
    *,
    timer_tick_s: float | None = None,
    samples: dict[str, np.ndarray] | None = None,
    reference_angle: bool = True,
) -> Recording:
    """A Recording of simulated edges (a :class:`plant_models.EdgeLog`), with ground truth kept."""
    pp = int(motor["pole_pairs"])
    keep = edges.segment >= 0
    e = edges.take(keep)
    # true angle at the timer's capture instant (the reference encoder's view)
    theta_cap = e.theta_e_stamp_deg(pp)
    angle_mech = np.mod(theta_cap / pp, 360.0)
    angle_mech[angle_mech >= 360.0] = 0.0
    truth = {
        "t_ideal_s": e.t_ideal_s,
        "t_raw_s": e.t_raw_s,
        "t_conditioned_s": e.t_conditioned_s,
        "true_angle_mech_deg": angle_mech,
        "pole": e.pole,
        "mean_abs_current_a": e.mean_abs_current_a,
    }
    return Recording(
        motor=dict(motor),
        segments=segments,
        t_s=e.t_capture_s,
        sensor=e.sensor,
        rising=e.rising,
        segment=e.segment,
        ref_angle_mech_deg=angle_mech if reference_angle else None,
        timer_tick_s=timer_tick_s,
        samples=samples,
        truth=truth,
    )


def motor_meta(config) -> dict[str, Any]:
    """The meta.json ``motor`` block of a PlantConfig's nominal motor."""
    m = config.motor
    return {
        "pole_pairs": int(m.pole_pairs),
        "phase_resistance_ohm": m.phase_resistance_ohm,
        "phase_inductance_h": m.phase_inductance_h,
        "ke_v_s_per_rad": m.ke_v_s_per_rad,
        "inertia_kg_m2": m.inertia_kg_m2,
        "fan_coefficient_n_m_s2": m.fan_coefficient_n_m_s2,
        "supply_v": m.supply_v,
        "friction_n_m_s_per_rad": m.friction_n_m_s_per_rad,
        "flat_top_deg_e": m.flat_top_deg_e,
    }


def record_kinematic(config, profile, seed: int = 0, reference_angle: bool = True) -> Recording:
    """Simulate ``profile`` (OperatingPoints) in the kinematic mode and return it as a Recording."""
    edges = simulate_edges(config, profile, seed=seed)
    segments, t = [], 0.0
    for i, op in enumerate(profile):
        segments.append(
            Segment(
                op.id or f"op{i + 1:02d}",
                t,
                t + op.duration_s,
                "forward" if op.direction > 0 else "reverse",
                float(op.speed_rpm),
                float(op.mean_phase_current_a),
                float(op.load_scale),
            )
        )
        t += op.duration_s
    tick = config.compile().timer_tick_s or None
    return recording_from_edges(motor_meta(config), edges, segments, timer_tick_s=tick, reference_angle=reference_angle)


def record_electrical(
    config,
    profile,
    seed: int = 0,
    *,
    sample_rate_hz: float = 20e3,
    settle_s: float = 0.05,
    voltage_noise_v: float = 0.0,
    speed_noise_rpm: float = 0.0,
    reference_angle: bool = True,
) -> Recording:
    """Simulate ``profile`` (OperatingPoints) on the electrical plant, commutating on the raw Hall
    edges at the duty that holds each set speed (a speed loop's steady state, computed from the
    plant's true resistance, back-EMF constant and dead time), and return edges plus samples
    (currents through the current sensors; terminal voltages and speed with the given white
    measurement noise) as a Recording. Each segment's ``mean_phase_current_a`` is the measured
    mean |i| over the three phases, as the format defines it."""

    cp = config.compile()
    true_motor = dataclasses.replace(
        config.motor, phase_resistance_ohm=cp.phase_resistance_ohm, ke_v_s_per_rad=cp.ke_v_s_per_rad
    )
    noise = np.random.default_rng(seed + 7919)
    logs, segments = [], []
    samples: dict[str, list] = {k: [] for k in ("t_s", "segment", *SAMPLE_OPTIONAL)}
    t_offset = 0.0
    for index, op in enumerate(profile):
        duty = (
            steady_state(true_motor, op.speed_rpm, op.load_scale)["duty"]
            + cp.dead_time_s * config.inverter.pwm_frequency_hz
        )
        sim = Simulation(
            config,
            RawHallCommutation(),
            duty=min(duty, 1.0),
            initial_speed_rpm=op.speed_rpm,
            direction=op.direction,
            seed=seed + index,
            sample_rate_hz=sample_rate_hz,
        )
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
        segments.append(
            Segment(
                op.id or f"op{index + 1:02d}",
                t_offset,
                t_end,
                "forward" if op.direction > 0 else "reverse",
                float(op.speed_rpm),
                float(np.abs(s.i_meas_a[keep]).mean()),
                float(op.load_scale),
            )
        )
        t_offset = t_end + 1e-3
    return recording_from_edges(
        motor_meta(config),
        EdgeLog.concatenate(logs),
        segments,
        timer_tick_s=cp.timer_tick_s or None,
        samples={k: np.concatenate(v) for k, v in samples.items()},
        reference_angle=reference_angle,
    )
