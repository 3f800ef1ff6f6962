"""Real-bench signals: stimulus an instrument can play (VCD, CSV) and gate captures scored against truth."""

from ..recording.errors import SignalError

__all__ = ["SignalError"]
