"""The compliance reports: escaping, incremental writing (a killed run keeps what it finished), xdist merge."""

import json

import pytest

pytest_plugins = ["pytester"]

SUITE = """
import os
import pytest

@pytest.mark.requirement("REQ-X-001")
@pytest.mark.parametrize("name", ["<script>alert(1)</script>", "plain"])
def test_named(name, hil_budget, hil_evidence):
    hil_evidence.value("a value <b>bold</b>", 1.5, "deg_e")
    hil_budget("commutation_angle_p99", 0.1)

def test_fails(hil_budget):
    hil_budget("commutation_angle_p99", 0.7)
"""


def report(pytester):
    return json.loads((pytester.path / "rep" / "hil-report.json").read_text())


def test_report_escapes_markup_and_traces_requirements(pytester):
    pytester.makepyfile(test_suite=SUITE)
    result = pytester.runpytest("--hil-report-dir", "rep")
    result.assert_outcomes(passed=2, failed=1)
    html = (pytester.path / "rep" / "hil-report.html").read_text()
    assert "<script>alert(1)</script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "<b>bold</b>" not in html
    content = report(pytester)
    assert content["complete"] and content["verdict"] == "FAIL" and content["counts"]["failed"] == 1
    req = {r["id"]: r for r in content["traceability"]}
    assert req["REQ-X-001"]["verdict"] == "pass" and len(req["REQ-X-001"]["tests"]) == 2
    assert req["REQ-COMM-001"]["verdict"] == "fail"
    failing = next(t for t in content["tests"] if t["nodeid"].endswith("test_fails"))
    assert "measured 0.7 deg_e exceeds the limit of at most 0.5 deg_e" in failing["message"]
    xml = (pytester.path / "rep" / "hil-report-junit.xml").read_text()
    assert 'name="requirement" value="REQ-X-001"' in xml and 'name="measurement:commutation_angle_p99"' in xml


def test_a_killed_run_keeps_every_finished_test(pytester):
    pytester.makepyfile(test_suite="""
        import os

        def test_one(hil_budget):
            hil_budget("commutation_angle_p99", 0.1)

        def test_two():
            pass

        def test_killed():
            os._exit(9)  # the process dies as under kill -9: no teardown, no session finish

        def test_never():
            pass
    """)
    pytester.runpytest_subprocess("--hil-report-dir", "rep", "-p", "no:cacheprovider")
    content = report(pytester)
    assert not content["complete"] and content["verdict"] == "INCOMPLETE"
    assert [t["nodeid"].split("::")[1] for t in content["tests"]] == ["test_one", "test_two"]
    assert "INCOMPLETE" in (pytester.path / "rep" / "hil-report.html").read_text()
    assert len((pytester.path / "rep" / "results.jsonl").read_text().splitlines()) == 2


def test_xdist_workers_merge_into_one_report(pytester):
    pytester.makepyfile(test_suite=SUITE)
    result = pytester.runpytest_subprocess("--hil-report-dir", "rep", "-n", "2", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2, failed=1)
    content = report(pytester)
    assert len(content["tests"]) == 3 and content["complete"]
    assert {t["worker"] for t in content["tests"]} <= {"gw0", "gw1"} and any(t["measurements"] for t in content["tests"])


def test_bad_dut_spec_and_bad_budgets_are_usage_errors_naming_the_cause(pytester):
    pytester.makepyfile("def test_x():\n    pass\n")
    result = pytester.runpytest("--hil-dut", "modbus-tcp:port=502")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*modbus-tcp needs host=...*"])
    pytester.makefile(".toml", budgets="[commutation_angle_p99]\nlimit = 'tight'\n")
    result = pytester.runpytest("--hil-budgets", "budgets.toml")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*budgets.toml: [[]commutation_angle_p99[]].limit*must be a finite number*"])


def test_replay_of_a_dead_controller_names_it(tmp_path, capsys):
    from hil.cli import main
    from hil.stimulus import Stimulus

    path = Stimulus("deviations").save(tmp_path / "s.json")
    assert main(["replay", str(path), "--dut", "modbus-tcp:host=127.0.0.1,port=1,timeout=0.3"]) == 3
    assert "Modbus unit 1 at 127.0.0.1:1: cannot connect within 0.3 s" in capsys.readouterr().err
