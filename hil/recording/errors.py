"""The errors of reading bench files: each says which file (and where in it) is wrong.

``RecordingError`` for a recording or a trace (file, line, column), ``SignalError`` for a capture,
a stimulus, a mapping or truth input (the signals package raises it too).
"""

from __future__ import annotations

from pathlib import Path


class SignalError(ValueError):
    """Bad stimulus, capture, mapping or truth input; ``where`` names the file, line or field."""

    def __init__(self, where: str, message: str):
        self.where = where
        super().__init__(f"{where}: {message}")


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
