"""Progress of a long run (hil.verdicts.progress) and the acceptance command's fresh pytest process."""

import re

from hil.cli import main
from hil.verdicts.report_html import printable, short_label

pytest_plugins = ["pytester"]


def test_each_finished_test_prints_count_elapsed_outcome_and_label(pytester):
    pytester.makepyfile(test_run="""
        import pytest
        from hil.verdicts.progress import note

        def test_long_one():
            note("calibration campaign: step one")
            note("lockstep bench: step two")

        @pytest.mark.parametrize("pdu", [b"\\x03\\xff"])
        def test_bytes(pdu):
            assert False

        @pytest.mark.skip(reason="not this DUT")
        def test_skipped():
            pass
    """)
    result = pytester.runpytest(
        "-p", "hil.verdicts.progress", "-q", "-o", "console_output_style=classic", "-p", "no:cacheprovider"
    )
    out = result.stdout.str()
    lines = [line for line in out.splitlines() if re.match(r"\[\d/3 +\d+:\d\d\]", line)]
    assert [re.sub(r"\[(\d)/3 +\d+:\d\d\]", r"[\1/3]", line).rsplit("  (", 1)[0] for line in lines] == [
        "[1/3] running  long one",
        "[1/3] passed   long one",
        "[2/3] failed   bytes · 03 ff",
        "[3/3] skipped  skipped",
    ], out
    assert re.search(r"^ +\.\.\. calibration campaign: step one\n +\.\.\. lockstep bench: step two$", out, re.M), out
    result.assert_outcomes(passed=1, failed=1, skipped=1)  # pytest's own summary still counts


def test_acceptance_runs_pytest_in_a_fresh_interpreter(pytester):
    """The cause of 'Module already imported so cannot be rewritten: hil' (with a regular, not
    editable, install): pytest ran inside the hil command, which had imported hil and plant_models."""
    pytester.makeconftest("")
    pytester.makepyfile(
        test_fresh="""
        import sys

        def test_fresh():
            assert "hil.cli" not in sys.modules, "pytest runs inside the hil command"
    """
    )
    assert (
        main(["acceptance", "--suite", str(pytester.path), "-o", "rep", "--dut", "virtual:in-process"]) == 0
    )


def test_labels_are_short_and_readable():
    nodeid = "test_cases/test_faults.py::test_wiring_fault_gives_the_promised_fault[virtual-canopen-missing-edge]"
    assert short_label(nodeid) == "wiring fault gives the promised fault · virtual-canopen-missing-edge"
    assert short_label(nodeid, "virtual-canopen") == "wiring fault gives the promised fault · missing-edge"
    assert short_label("t.py::test_x[\\x03\\xff\\xf0\\x00\\x01]") == "x · 03 ff f0 00 01"
    assert printable("a\x00b") == "a00b"


def test_a_waived_failure_reads_waived(pytester):
    budgets = pytester.path.parent / "waiver.toml"
    budgets.write_text('[[waiver]]\nrequirement = "REQ-X-009"\nreason = "known, fix in 2.1"\nowner = "lead"\n')
    pytester.makepyfile(
        test_w="""
        import pytest

        @pytest.mark.requirement("REQ-X-009")
        def test_known_defect():
            assert False
    """
    )
    result = pytester.runpytest(
        "-p",
        "hil.verdicts.progress",
        "-q",
        "-o",
        "console_output_style=classic",
        "-p",
        "no:cacheprovider",
        "--hil-budgets",
        str(budgets),
    )
    assert re.search(r"^\[1/1 +\d+:\d\d\] waived +known defect", result.stdout.str(), re.M), result.stdout.str()


# --- counted work: hil.verdicts.progress.Meter (campaigns, gap validation, signal export) --------------


def test_a_meter_into_a_log_prints_a_line_per_tenth():
    import io

    from hil.verdicts.progress import Meter

    out = io.StringIO()
    meter = Meter("recordings diagnosed", 100, stream=out)
    for _ in range(100):
        meter.advance()
    meter.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 11 and lines[-1].startswith("  100/100 recordings diagnosed (100%)")  # one line per 10 %
    assert "left" in lines[5] and "/s" in lines[5]


class _Terminal:
    """A stream that says it is a terminal and records what was written."""

    def __init__(self):
        self.text = ""

    def isatty(self):
        return True

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_a_meter_on_a_terminal_moves_between_results_and_ends_its_line(monkeypatch):
    """One line redrawn in place; while no result arrives, ``tick`` redraws it (elapsed and time
    left move); closing ends the line."""
    from hil.verdicts import progress

    clock = [100.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    term = _Terminal()
    meter = progress.Meter("campaign points", 4, stream=term, redraw_s=0.5)
    meter.advance()
    assert term.text.count("\r") == 1 and "1/4 campaign points (25%)" in term.text
    meter.tick()  # no time passed: nothing new
    assert term.text.count("\r") == 1
    clock[0] += 61.0
    meter.tick()  # a minute without a result: the line still moves
    assert term.text.count("\r") == 2 and term.text.rstrip().endswith("61 s elapsed, about 3.0 min left")
    for _ in range(3):
        meter.advance()  # the last one is drawn whatever the time
    assert "4/4 campaign points (100%)" in term.text.rsplit("\r", 1)[1]
    meter.close()
    assert term.text.endswith("\n") and "\n" not in term.text[:-1]


def test_dispatch_counts_its_jobs_through_the_meter(capsys):
    """The campaign scheduler's progress is the Meter's (no second mechanism); off, it is silent."""
    import math

    from hil.campaign.scheduler import dispatch

    got = {}
    dispatch(math.sqrt, [float(i) for i in range(20)], got.__setitem__, scheduler="serial", label="squares")
    lines = capsys.readouterr().err.splitlines()
    assert len(got) == 20 and len(lines) == 11 and lines[-1].startswith("  20/20 squares (100%)"), lines
    dispatch(math.sqrt, [4.0], got.__setitem__, scheduler="serial", label="squares", progress=False)
    assert capsys.readouterr().err == ""
