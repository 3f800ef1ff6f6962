"""Smooth progress for long work on stderr: one line redrawn in place on a terminal (count,
share, elapsed, time left), a line every 10 % when stderr is a file or a pipe."""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, what: str, stream=None, min_interval_s: float = 0.25):
        self.what, self.stream, self.min_interval_s = what, stream or sys.stderr, min_interval_s
        self.t0 = time.monotonic()
        self._last_draw = 0.0
        self._last_decile = -1
        self._drawn = False
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def line(self, done: int, total: int) -> str:
        elapsed = time.monotonic() - self.t0
        left = elapsed / done * (total - done) if done else float("nan")
        eta = f", about {_duration(left)} left" if done and done < total else ""
        return f"  {done}/{total} {self.what} ({done / total:.0%}), {_duration(elapsed)} elapsed{eta}"

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if self.tty:
            if done == total or now - self._last_draw >= self.min_interval_s:
                self.stream.write("\r" + self.line(done, total).ljust(78))
                self.stream.flush()
                self._last_draw, self._drawn = now, True
            return
        decile = (10 * done) // total
        if decile != self._last_decile:
            self._last_decile = decile
            print(self.line(done, total), file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    if seconds != seconds:  # NaN
        return "?"
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min"
