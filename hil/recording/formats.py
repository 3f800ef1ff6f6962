"""Every file format a recording is read from, by suffix: the one table (``FORMATS``).

A suffix reads as a logic-analyser capture (``capture``: a ``capture.CaptureFormat``, the Hall or gate
lines as level changes, no mapping), as a logger trace (``trace``: a ``tables`` opener, whose columns
a ``traces.TraceMapping`` names and whose segments a meta.json gives), or as both (CSV, text). A new
format is one entry here, with its reader; ``load.load_recording`` chooses between the readings.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .capture import CSV, SIGROK, VCD, Capture, CaptureFormat, GateMapping
from .errors import RecordingError, SignalError
from .reader import MAX_TABLE_BYTES, _checked_size
from .tables import TraceTable, open_csv, open_mdf, open_parquet


@dataclass(frozen=True)
class FileFormat:
    """What a file of one suffix can be read as."""

    capture: CaptureFormat | None = None  #: read as logic levels (``hil recording import``, gate captures)
    trace: Callable[[Path], TraceTable] | None = None  #: opened as a trace table (through a mapping)


#: every format by file suffix (lower case): the one place a format is registered
FORMATS: dict[str, FileFormat] = {
    ".mf4": FileFormat(trace=open_mdf), ".mdf": FileFormat(trace=open_mdf), ".dat": FileFormat(trace=open_mdf),
    ".parquet": FileFormat(trace=open_parquet), ".pq": FileFormat(trace=open_parquet),
    ".vcd": FileFormat(capture=VCD),
    ".sr": FileFormat(capture=SIGROK),
    ".csv": FileFormat(capture=CSV, trace=open_csv), ".txt": FileFormat(capture=CSV, trace=open_csv),
}


def capture_suffixes() -> list[str]:
    return [s for s, f in FORMATS.items() if f.capture is not None]


def trace_suffixes() -> list[str]:
    return [s for s, f in FORMATS.items() if f.trace is not None]


def known_formats() -> str:
    """The capture formats as messages name them: "VCD .vcd, sigrok session .sr, CSV .csv/.txt"."""
    by_label: dict[str, list[str]] = {}
    for suffix in capture_suffixes():
        by_label.setdefault(FORMATS[suffix].capture.label, []).append(suffix)
    return ", ".join(f"{label} {'/'.join(suffixes)}" for label, suffixes in by_label.items())


def capture_format(path: Path) -> CaptureFormat:
    """The capture format of a file, by its suffix; unknown suffixes are refused with the known ones."""
    suffix = path.suffix.lower()
    fmt = FORMATS.get(suffix, FileFormat()).capture
    if fmt is None:
        raise SignalError(str(path), f"unknown capture format {suffix!r} ({known_formats()})")
    return fmt


def is_capture_file(path: Path) -> bool:
    """A file whose suffix a capture format reads."""
    return path.is_file() and path.suffix.lower() in capture_suffixes()


def open_capture(path: str | Path, mapping: GateMapping | None = None) -> Capture:
    """A capture file, read in the format of its suffix."""
    if not Path(path).is_file():
        raise SignalError(str(path), "missing capture file")
    return Capture(path, capture_format(Path(path)), mapping)


def open_trace(path: Path) -> TraceTable:
    """A trace file as a table, opened in the format of its suffix."""
    suffix = path.suffix.lower()
    if not path.is_file():
        raise RecordingError(path, None, None, "missing file")
    _checked_size(path, MAX_TABLE_BYTES)
    opener = FORMATS.get(suffix, FileFormat()).trace
    if opener is None:
        raise RecordingError(
            path, None, None, f"unknown trace format {suffix!r} (MDF4 .mf4, Parquet .parquet, CSV .csv)"
        )
    return opener(path)
