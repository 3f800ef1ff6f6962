"""Budgets: verdicts, messages, TOML validation, and the plugin's fixture with JUnit properties."""

import math

import pytest

from hil.budgets import BudgetExceeded, Budgets
from plant_models import ConfigError


def test_verdicts_and_margins():
    b = Budgets.defaults()
    assert b.check("commutation_angle_p99", 0.3).verdict == "pass"
    v = b.check("commutation_angle_p99", 0.45)
    assert v.verdict == "marginal" and v.margin == pytest.approx(0.05)
    v = b.check("commutation_angle_p99", 0.62)
    assert v.verdict == "fail" and v.margin == pytest.approx(-0.12)
    assert b.check("commutation_angle_p99", math.nan).verdict == "fail"


def test_failure_message_names_budget_requirement_value_and_limit():
    with pytest.raises(BudgetExceeded) as info:
        Budgets.defaults().require("commutation_angle_p99", 0.62)
    msg = str(info.value)
    assert msg == ("commutation_angle_p99 (REQ-COMM-001): measured 0.62 deg_e exceeds the limit of at most 0.5 deg_e "
                   "(margin -0.12 deg_e): FAIL")


def test_toml_overrides_and_min_budgets(tmp_path):
    path = tmp_path / "b.toml"
    path.write_text('[commutation_angle_p99]\nlimit = 0.3\nmarginal = 0.25\n\n[gap_top1]\nrequirement = "REQ-GAP-001"\n'
                    'unit = "fraction"\nlimit = 0.9\nkind = "min"\nmarginal = 0.95\n')
    b = Budgets.from_toml(path)
    assert b.check("commutation_angle_p99", 0.35).verdict == "fail"
    assert b.check("gap_top1", 0.93).verdict == "marginal"
    assert b.check("gap_top1", 0.85).verdict == "fail"
    assert "installation_offset_error" in b  # defaults kept


@pytest.mark.parametrize("text, field", [
    ('[x]\nunit = "A"\nlimit = 1.0\n', "[x].requirement"),
    ('[x]\nrequirement = "R"\nunit = "A"\nlimit = nan\n', "[x].limit"),
    ('[commutation_angle_p99]\nlimt = 1.0\n', "[commutation_angle_p99].limt"),
    ('[commutation_angle_p99]\nkind = "avg"\n', "[commutation_angle_p99].kind"),
    ('[commutation_angle_p99]\nmarginal = 0.9\n', "[commutation_angle_p99].marginal"),
])
def test_bad_budget_files_name_the_field(tmp_path, text, field):
    path = tmp_path / "b.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Budgets.from_toml(path)
    assert field in str(info.value) and str(path) in str(info.value)


def test_plugin_fixture_records_verdicts_as_junit_properties(pytester):
    pytester.makefile(".toml", budgets='[commutation_angle_p99]\nlimit = 0.3\n')
    pytester.makepyfile(
        """
        def test_good(hil_budget):
            assert hil_budget("commutation_angle_p99", 0.1).verdict == "pass"

        def test_bad(hil_budget):
            hil_budget("commutation_angle_p99", 0.42)
        """
    )
    result = pytester.runpytest("--hil-budgets", "budgets.toml", "--junitxml", "out.xml")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*commutation_angle_p99 (REQ-COMM-001): measured 0.42 deg_e exceeds the limit of at most 0.3 deg_e*FAIL*"])
    xml = (pytester.path / "out.xml").read_text()
    assert 'name="budget:commutation_angle_p99"' in xml and 'name="requirement" value="REQ-COMM-001"' in xml
