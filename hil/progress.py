"""Progress lines for long HIL runs (pytest plugin: ``-p hil.progress``; ``hil acceptance`` loads it).

Instead of pytest's dots, each finished test prints one line with its count, the elapsed time,
its outcome and a short label::

    [ 3/56  0:21] passed   calibration removes the deviation · virtual-canopen-installation  (16.2 s)

and a test may say what it is doing while it works (``note("calibration campaign: ...")``),
printed at once, so that a long test is never silent. Under pytest-xdist the lines come from
the controlling process as the workers report, a worker's notes with the test's report.
"""

from __future__ import annotations

import contextlib
import time

import pytest

from .report import OUTCOME_ORDER, PROPERTY_PREFIX
from .report_html import short_label

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
