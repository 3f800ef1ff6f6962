"""README's acceptance run, as a user runs it: ``python -m hil acceptance`` (test_cases/ against the
built-in controller over CANopen, on pytest-xdist workers). This is the test suite's one run of
test_cases/: its verdict must be PASS with every requirement answered, and what it prints must
read well (no warning, one progress line per test). The run itself is ``default_acceptance``
(tests/conftest.py); tests/test_browser.py lays out and prints the same report."""

from __future__ import annotations

import json
import re


def test_the_default_acceptance_passes_every_requirement(default_acceptance):
    run, reports = default_acceptance
    content = json.loads((reports / "hil-report.json").read_text())
    traced = {r["id"]: r["verdict"] for r in content["traceability"] if r["traced"]}
    from hil.verdicts.requirements import not_applicable

    # the requirements of a part (its interrupts, its stack) mean nothing for the virtual controller:
    # those, and only those, are "not applicable"
    elsewhere = set(not_applicable(traced, "virtual"))
    failing = {rid: v for rid, v in traced.items()
               if v not in ("pass", "marginal") and not (v == "not applicable" and rid in elsewhere)}
    problems = [f"{t['nodeid']}: {t['outcome']}: {t['message'][:400]}" for t in content["tests"]
                if t["outcome"] not in ("passed", "skipped")]
    assert not failing and content["verdict"] == "PASS", (
        f"verdict {content['verdict']} ({content['verdict_reasons']}); requirements {failing}; tests:\n"
        + "\n".join(problems)
    )
    assert run.returncode == 0, f"PASS, yet hil acceptance exited {run.returncode}"
    from hil.verdicts.requirements import REQUIREMENTS

    # every requirement of the catalogue is answered over CANopen (none silently left out)
    assert set(traced) == set(REQUIREMENTS), sorted(set(REQUIREMENTS) ^ set(traced))
    assert content["complete"] and content["session"]["seed"] is not None


def test_every_listed_budget_is_measured(default_acceptance):
    """A compliance report lists no budget it never judged: every default budget of every requirement
    the run answered has at least one measurement in the report (a budget no test passes to
    ``hil_budget`` fails here, named with its requirement)."""
    _, reports = default_acceptance
    content = json.loads((reports / "hil-report.json").read_text())
    from hil.verdicts.requirements import REQUIREMENTS

    measured = {m["budget"] for t in content["tests"] for m in t["measurements"]}
    answered = {r["id"] for r in content["traceability"] if r["traced"] and r["verdict"] != "not applicable"}
    never = sorted(f"{b.name} ({rid})" for rid in answered for b in REQUIREMENTS[rid].budgets if b.name not in measured)
    assert not never, f"listed and never measured: {', '.join(never)}"


def test_default_acceptance_prints_no_warning_and_shows_progress(default_acceptance):
    run, reports = default_acceptance
    output = run.stdout + run.stderr
    # pytest's warnings summary, or any Python warning category (PytestAssertRewriteWarning, ...)
    assert not re.search(r"warnings summary|\b\w*Warning\b", output), (
        f"hil acceptance printed a warning:\n{output[-4000:]}"
    )
    n = len(json.loads((reports / "hil-report.json").read_text())["tests"])
    progress = re.findall(
        rf"^\[ *(\d+)/{n} +\d+:\d\d\] (passed|failed|skipped|xfailed|xpassed|error|waived) +\S", run.stdout, re.M
    )
    assert [int(k) for k, _ in progress] == list(range(1, n + 1)), (
        f"expected one progress line per test, 1 to {n}:\n{run.stdout[:3000]}"
    )
    assert re.search(r"^ +\.\.\. calibration campaign", run.stdout, re.M), (
        "the calibration campaign does not say what it does"
    )
