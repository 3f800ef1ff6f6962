"""Bench recordings in the ``hil-recording/1`` format (docs/recording-format.md), read strictly.

A recording that breaks the format is refused with :class:`RecordingError`, which names the
file, the line and the column (for meta.json: the JSON line and the key path). Nothing is
guessed. Files the format does not define (our simulator's ``ground_truth.csv``) are ignored by
the reader unless asked for.
"""

from __future__ import annotations

import csv
import json
import math
from array import array
from pathlib import Path

import numpy as np

from .errors import RecordingError
from .format import (
    DIRECTIONS,
    EDGE_COLUMNS,
    FORMAT,
    ORDINARY_SEGMENT,
    SAMPLE_OPTIONAL,
    SAMPLE_REQUIRED,
    TRUTH_COLUMNS,
    Recording,
    Segment,
)

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

