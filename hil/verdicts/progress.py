"""Progress of long work, the one mechanism for every command (issue 40).

``Meter``: counted work on stderr (campaign points, gap validation recordings, signal export
chunks): one line redrawn in place on a terminal, and redrawn between results too, so the
elapsed time and the time left never sit still; a line per tenth of the work into a log file or
a pipe::

      45/100 campaign points (45%), 3.61/s, 12 s elapsed, about 15 s left

The pytest plugin (``-p hil.verdicts.progress``; ``hil acceptance`` loads it): instead of pytest's dots,
each finished test prints one line with its count, the elapsed time, its outcome and a short
label::

    [ 3/56  0:21] passed   calibration removes the deviation · virtual-canopen-installation  (16.2 s)

and a test may say what it is doing while it works (``note("calibration campaign: ...")``),
printed at once, so that a long test is never silent. Under pytest-xdist the lines come from
the controlling process as the workers report, a worker's notes with the test's report.
"""

from __future__ import annotations

import contextlib
import sys
import time

import pytest

from .report import OUTCOME_ORDER, PROPERTY_PREFIX
from .report_html import short_label

#: a terminal's line is redrawn at most this often, and at least this often while work goes on
REDRAW_S = 0.5


class Meter:
    """Counted work on ``stream`` (stderr): ``advance()`` as each piece ends, ``tick()`` while
    waiting (a terminal's line moves between results), ``close()`` at the end; or call it with
    ``(done, total)`` where only the worker knows the total."""

    def __init__(self, what: str, total: int | None = None, *, stream=None, enabled: bool = True,
                 redraw_s: float = REDRAW_S):
        self.what, self.total, self.enabled, self.redraw_s = what, total, enabled, redraw_s
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.done = 0
        self.t0 = time.monotonic()
        self._last_draw = -float("inf")
        self._last_decile = -1
        self._drawn = False

    def line(self) -> str:
        done, total = self.done, self.total or 0
        elapsed = time.monotonic() - self.t0
        share = f" ({done / total:.0%})" if total else ""
        rate = f", {done / elapsed:.3g}/s" if done and elapsed > 0 else ""
        left = f", about {_duration(elapsed / done * (total - done))} left" if done and done < total else ""
        return f"  {done}/{total or '?'} {self.what}{share}{rate}, {_duration(elapsed)} elapsed{left}"

    def advance(self, n: int = 1) -> None:
        self.done += n
        self._draw()

    def __call__(self, done: int, total: int) -> None:
        self.done, self.total = done, total
        self._draw()

    def tick(self) -> None:
        """While waiting for the next result: a terminal's line shows the time going on."""
        if self.enabled and self.tty and self._drawn and time.monotonic() - self._last_draw >= self.redraw_s:
            self._write_in_place()

    def _draw(self) -> None:
        if not self.enabled or not self.total:
            return
        if self.tty:
            if self.done >= self.total or time.monotonic() - self._last_draw >= self.redraw_s:
                self._write_in_place()
            return
        decile = (10 * self.done) // self.total
        if decile != self._last_decile:  # a log gets a line per tenth, not a flood
            self._last_decile = decile
            print(self.line(), file=self.stream, flush=True)

    def _write_in_place(self) -> None:
        self.stream.write("\r" + self.line().ljust(78))
        self.stream.flush()
        self._last_draw, self._drawn = time.monotonic(), True

    def close(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min"


_active: "Progress | None" = None


_worker_item = None  #: under xdist, in a worker: the test running there (its notes travel on its reports)
NOTE_PROPERTY = PROPERTY_PREFIX + "note"


def note(text: str) -> None:
    """Say what the running test is doing (a no-op unless the progress plugin is active here; in an
    xdist worker the note goes with the test's report and is printed when the test ends)."""
    if _active is not None:
        _active.note(text)
    elif _worker_item is not None:
        _worker_item.user_properties.append((NOTE_PROPERTY, str(text)))


class Progress:
    def __init__(self, config):
        self.config = config
        self.started = time.monotonic()
        self.total: int | None = None
        self.done = 0
        self.pending: dict[str, list] = {}
        self.running: str | None = None  #: the test whose notes have not been headed yet

    @property
    def terminal(self):
        return self.config.pluginmanager.get_plugin("terminalreporter")

    def elapsed(self) -> str:
        s = int(time.monotonic() - self.started)
        return f"{s // 60}:{s % 60:02d}"

    def count(self, k: int) -> str:
        return f"[{k:>{len(str(self.total or '?'))}}/{self.total or '?'} {self.elapsed():>5}]"

    def note(self, text: str) -> None:
        tr = self.terminal
        if tr is None:
            return
        capture = self.config.pluginmanager.get_plugin("capturemanager")
        with (
            capture.global_and_fixture_disabled() if capture else contextlib.nullcontext()
        ):  # a test's output is captured
            if self.running is not None:  # the first note of a test names it
                tr.write_line(f"{self.count(self.done + 1)} running  {short_label(self.running)}")
                self.running = None
            tr.write_line(f"{'':>{len(self.count(0))}}   ... {text}", cyan=True)

    def pytest_runtest_logstart(self, nodeid, location):
        self.running = nodeid

    @pytest.hookimpl(trylast=True)
    def pytest_collection_finish(self, session):
        self.total = len(session.items)

    @pytest.hookimpl(optionalhook=True)
    def pytest_xdist_node_collection_finished(self, node, ids):  # under xdist the controller collects nothing itself
        self.total = len(ids)

    @pytest.hookimpl(wrapper=True)
    def pytest_report_teststatus(self, report, config):
        # keep pytest's category and word (its summary counts them), drop the per-test letter:
        # the line below replaces it
        result = yield
        if result and isinstance(result, tuple) and len(result) == 3:
            return result[0], "", result[2]
        return result

    def pytest_runtest_logreport(self, report):
        self.pending.setdefault(report.nodeid, []).append(report)
        if report.when != "teardown":
            return
        reports = self.pending.pop(report.nodeid)
        notes = [v for k, v in getattr(report, "user_properties", ()) if str(k) == NOTE_PROPERTY]
        if notes:  # an xdist worker's notes, printed as the test ends
            self.running = report.nodeid
            for text in notes:
                self.note(text)
            self.running = None
        self.done += 1
        outcome = _outcome(reports)
        if any(
            str(k) == PROPERTY_PREFIX + "waived_failure" for r in reports for k, _ in getattr(r, "user_properties", ())
        ):
            outcome = "waived"  # a failure a waiver in the budgets covers (pytest counts it as a skip)
        duration = sum(getattr(r, "duration", 0.0) for r in reports)
        colour = {
            "passed": {"green": True},
            "failed": {"red": True},
            "error": {"red": True},
            "xpassed": {"red": True},
            "skipped": {"yellow": True},
            "xfailed": {"yellow": True},
            "waived": {"purple": True},
        }.get(outcome, {})
        tr = self.terminal
        if tr is not None:
            tr.write_line(
                f"{self.count(self.done)} {outcome:<8} {short_label(report.nodeid)}  ({duration:.1f} s)", **colour
            )


def _outcome(reports) -> str:
    """One word for a test from its phase reports: the worst phase wins."""
    order = OUTCOME_ORDER  # the report's order: a test's outcome is the worst of its phases
    worst = "passed"
    for r in reports:
        if hasattr(r, "wasxfail"):
            word = "xfailed" if r.skipped else "xpassed"
        elif r.failed:
            word = "failed" if r.when == "call" else "error"
        elif r.skipped:
            word = "skipped"
        else:
            word = "passed"
        if order.index(word) < order.index(worst):
            worst = word
    return worst


class _WorkerNotes:
    """In an xdist worker: which test is running, so that its notes go with its reports."""

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        global _worker_item
        _worker_item = item
        try:
            return (yield)
        finally:
            _worker_item = None


def pytest_configure(config):
    global _active
    if not hasattr(config, "workerinput"):  # an xdist worker has no terminal of its own
        _active = Progress(config)
        config.pluginmanager.register(_active, "hil-progress")
    else:
        config.pluginmanager.register(_WorkerNotes(), "hil-progress-worker")


def pytest_unconfigure(config):
    global _active
    if _active is not None and _active.config is config:
        config.pluginmanager.unregister(_active)
        _active = None
