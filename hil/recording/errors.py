"""The one error type of the signals package: says which file (and where in it) is wrong."""

from __future__ import annotations


class SignalError(ValueError):
    """Bad stimulus, capture, mapping or truth input; ``where`` names the file, line or field."""

    def __init__(self, where: str, message: str):
        self.where = where
        super().__init__(f"{where}: {message}")
