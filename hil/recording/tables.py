"""A logger's trace as a table of columns (MDF4 through asammdf, Parquet and CSV through pandas),
with the file named in every error: what ``traces`` reads a mapping's channels from. Each format's
opener is declared by its suffixes in ``formats.FORMATS``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .errors import RecordingError
from .reader import MAX_TABLE_BYTES, _lines


class TraceTable:
    """Column access with the file named in every error."""

    def __init__(self, path: Path, columns: dict[str, np.ndarray] | None = None, signals: Any = None):
        self.path, self.columns, self.signals = path, columns, signals

    def channel(self, name: str, numeric: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """(values, own timestamps or None)."""
        if self.signals is not None:  # MDF4: each channel has its own time base
            try:
                sig = self.signals.get(name)
            except Exception:  # asammdf raises MdfException for unknown channels
                raise RecordingError(self.path, None, name, "channel not found in the MDF file") from None
            values, stamps = np.asarray(sig.samples), np.asarray(sig.timestamps, dtype=float)
        else:
            if name not in self.columns:
                raise RecordingError(self.path, 1, name, f"missing column (have: {', '.join(self.columns)})")
            values, stamps = self.columns[name], None
        if numeric:
            try:
                values = values.astype(float)
            except (TypeError, ValueError):
                raise RecordingError(self.path, None, name, "not numeric") from None
            bad = np.nonzero(~np.isfinite(values))[0]
            if bad.size:
                raise RecordingError(self.path, int(bad[0]) + 2 if self.signals is None else None, name,
                                     f"non-finite value at row {int(bad[0])}")
        return values, stamps


def open_mdf(path: Path) -> TraceTable:
    from asammdf import MDF

    return TraceTable(path, signals=MDF(str(path)))


def open_parquet(path: Path) -> TraceTable:
    import pandas as pd

    frame = pd.read_parquet(path)
    return TraceTable(path, columns={c: frame[c].to_numpy() for c in frame.columns})


def open_csv(path: Path) -> TraceTable:
    import pandas as pd

    for _ in _lines(path, MAX_TABLE_BYTES):  # line length, NUL bytes, UTF-8: refused at their line
        pass
    try:
        frame = pd.read_csv(path, skipinitialspace=True, encoding="utf-8-sig")
    except (pd.errors.ParserError, ValueError) as exc:
        raise RecordingError(path, None, None, f"not a readable CSV: {' '.join(str(exc).split())[:200]}") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return TraceTable(path, columns={c: frame[c].to_numpy() for c in frame.columns})
