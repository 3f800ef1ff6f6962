"""Real-bench signals: stimulus an instrument can play (VCD, CSV) and gate captures scored against truth."""

from .errors import SignalError

__all__ = ["SignalError"]
