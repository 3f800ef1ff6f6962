"""A command's RECORDING argument, read by the one loader (docs/cli.md): a ``hil-recording/1``
directory, a capture file (read as ``hil recording import`` reads it) or, for a command that takes
traces (``hil gap diagnose``), a trace with its meta.json. The formats are ``formats.FORMATS``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bldc.params import ConfigError

from .format import Recording
from .formats import capture_suffixes, is_capture_file, known_formats, trace_suffixes
from .hall import capture_recording, read_hall_capture
from .reader import read_recording
from .traces import TraceMapping, read_trace


@dataclass(frozen=True)
class TraceFiles:
    """What a trace needs beside its file (``--meta``, ``--mapping``). A command that passes one
    takes traces: there a suffix that both a capture and a trace format read (.csv, .txt) is a
    trace, as is any file when a meta.json is given, for the trace's segments."""

    meta: str | Path | None = None
    mapping: str | Path | None = None


def load_recording(path: str | Path, pole_pairs: int | None = None, traces: TraceFiles | None = None) -> Recording:
    """The recording ``path`` names; ``pole_pairs`` for a capture, ``traces`` where traces are taken."""
    given, path = path, Path(path)
    captures_only = [s for s in capture_suffixes() if s not in trace_suffixes()]
    if traces is not None and not path.is_dir() and (path.suffix.lower() not in captures_only or traces.meta):
        return _load_trace(given, traces, captures_only)
    if is_capture_file(path):
        rec = capture_recording(read_hall_capture(path), pole_pairs, source=path.name)
        rec.path = path
        return rec
    if not path.exists():
        raise ConfigError(str(path), f"no such recording directory or capture file ({known_formats()})")
    return read_recording(path)


def _load_trace(given: str | Path, traces: TraceFiles, captures_only: list[str]) -> Recording:
    path = Path(given)
    if not path.exists():
        raise ValueError(f"{path}: no such file or directory")
    if path.suffix.lower() not in trace_suffixes():
        raise ValueError(
            f"{path}: not a recording or a trace file (a hil-recording/1 directory, a Hall capture "
            f"{' or '.join(captures_only)}, or a trace: {', '.join(trace_suffixes())})"
        )
    if not traces.meta:
        raise ValueError(
            f"{given}: a trace file needs --meta META.json (motor and segments) and usually --mapping MAP.toml"
        )
    mapping = TraceMapping.from_toml(traces.mapping) if traces.mapping else TraceMapping()
    return read_trace(given, mapping, traces.meta)
