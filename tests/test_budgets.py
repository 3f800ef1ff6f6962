"""Budgets: verdicts, messages, TOML validation, and the plugin's fixture with JUnit properties."""

import math

import pytest

from pathlib import Path

from hil.verdicts.budgets import Budget, BudgetExceeded, Budgets
from hil.verdicts.requirements import DOCS, GENERATED, REQUIREMENTS, rendered
from plant_models import ConfigError

SUITE = Path(__file__).resolve().parents[1] / "test_cases"


def test_verdicts_and_margins():
    b = Budgets.defaults()
    assert b.check("commutation_angle_p99", 0.3).verdict == "pass"
    v = b.check("commutation_angle_p99", 0.55)  # limit 0.6 (hil/verdicts/budget_sources.py), marginal beyond 0.4
    assert v.verdict == "marginal" and v.margin == pytest.approx(0.05)
    v = b.check("commutation_angle_p99", 0.72)
    assert v.verdict == "fail" and v.margin == pytest.approx(-0.12)
    assert b.check("commutation_angle_p99", math.nan).verdict == "fail"
    # "never" (a settling that never came) fails and is recorded as such, not as nan
    never = b.check("edge_noise_tracking_edges", math.inf)
    assert never.verdict == "fail" and never.measured == math.inf and "measured inf edges" in never.message()


def test_failure_message_names_budget_requirement_value_and_limit():
    with pytest.raises(BudgetExceeded) as info:
        Budgets.defaults().require("commutation_angle_p99", 0.72)
    msg = str(info.value)
    assert msg == ("commutation_angle_p99 (REQ-COMM-001): measured 0.72 deg_e exceeds the limit of at most 0.6 deg_e "
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


BOUNDARY_BUDGETS = (
    '[err_max]\nrequirement = "REQ-B-001"\nunit = "deg_e"\nlimit = 0.5\nmarginal = 0.4\n\n'
    '[share_min]\nrequirement = "REQ-B-002"\nunit = "fraction"\nlimit = 0.9\nmarginal = 0.95\nkind = "min"\n'
)


@pytest.mark.parametrize(
    "name, measured, verdict, margin",
    [
        # "at most 0.5, marginal beyond 0.4"
        ("err_max", 0.5, "marginal", 0.0),  # exactly at the limit: inside it
        ("err_max", math.nextafter(0.5, math.inf), "fail", None),  # the least step beyond it
        ("err_max", 0.4, "pass", 0.1),  # exactly at the marginal bound: a plain pass
        ("err_max", math.nextafter(0.4, math.inf), "marginal", None),
        # "at least 0.9, marginal below 0.95"
        ("share_min", 0.9, "marginal", 0.0),
        ("share_min", math.nextafter(0.9, -math.inf), "fail", None),
        ("share_min", 0.95, "pass", 0.05),
        ("share_min", math.nextafter(0.95, -math.inf), "marginal", None),
    ],
)
def test_verdicts_exactly_at_the_limit_and_at_the_marginal_bound(tmp_path, name, measured, verdict, margin):
    path = tmp_path / "b.toml"
    path.write_text(BOUNDARY_BUDGETS)
    v = Budgets.from_toml(path).check(name, measured)
    assert v.verdict == verdict
    if margin is not None:
        assert v.margin == pytest.approx(margin, abs=1e-15)
    else:
        assert (v.margin < 0) == (verdict == "fail")


def test_a_budget_without_marginal_bound_passes_at_its_limit():
    b = Budgets.defaults()
    b.budgets["bare"] = type(b["commutation_angle_p99"])("bare", "REQ-B-003", "A", 2.0)
    assert b.check("bare", 2.0).verdict == "pass" and b.check("bare", math.nextafter(2.0, 3.0)).verdict == "fail"


@pytest.mark.parametrize(
    "text, field, words",
    [
        ('[x]\nrequirement = "R"\nunit = "A"\nlimit = -0.1\n', "[x].limit", "must be >= 0"),
        ("[commutation_angle_p99]\nlimit = -0.5\nmarginal = -0.6\n", "[commutation_angle_p99].limit", "must be >= 0"),
        ("[commutation_angle_p99]\nlimit = 0.3\nmarginal = 0.35\n", "[commutation_angle_p99].marginal", "passing side"),
        ("[commutation_angle_p99]\nmarginal = -0.1\n", "[commutation_angle_p99].marginal", "passing side"),
        ("[calibrated_fraction_removed]\nmarginal = 0.85\n", "[calibrated_fraction_removed].marginal", "passing side"),
        (
            '[x]\nrequirement = "R"\nunit = "A"\nlimit = 1.0\nkind = "min"\nmarginal = 0.5\n',
            "[x].marginal",
            "at or above the limit",
        ),
    ],
)
def test_inconsistent_budgets_are_refused_naming_file_and_key(tmp_path, text, field, words):
    path = tmp_path / "b.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Budgets.from_toml(path)
    assert f"{path}: {field}" in str(info.value) and words in str(info.value)


def test_the_defaults_are_consistent():
    b = Budgets.defaults()
    assert b.source == "defaults" and len(b.budgets) >= 14
    for budget in b.budgets.values():
        assert budget.limit >= 0 and budget.requirement.startswith("REQ-")


def test_the_defaults_are_the_registrys_budgets_each_under_its_requirement():
    defaults = Budgets.defaults()
    declared = [(b.name, rid) for rid, r in REQUIREMENTS.items() for b in r.budgets]
    assert len({name for name, _ in declared}) == len(declared), "a budget name declared twice in the registry"
    assert {n: b.requirement for n, b in defaults.budgets.items()} == dict(declared)
    assert defaults.waivers == ()  # a built-in default never waives: waivers are the user's, in a budgets file
    titles = defaults.requirement_titles()
    assert all(titles[rid] == r.statement for rid, r in REQUIREMENTS.items())


def test_every_default_budget_takes_limit_and_source_from_its_derivation():
    """One place (hil/verdicts/budget_sources.py): each default's limit, marginal bound and source are its
    derivation's; the arithmetic itself is recomputed in tests/test_budget_sources.py."""
    from hil.verdicts.budget_sources import DERIVATIONS

    defaults = Budgets.defaults().budgets
    assert set(defaults) == set(DERIVATIONS), "a default budget without a derivation, or one without a budget"
    for name, budget in defaults.items():
        d = DERIVATIONS[name]
        assert (budget.limit, budget.marginal, budget.limit_source) == (d.limit, d.marginal, d.source), name


def test_a_limit_of_a_budgets_file_drops_the_defaults_marginal_bound_and_source(tmp_path):
    base = Budgets({"x": Budget("x", "REQ-X-001", "deg_e", 1.0, marginal=0.8, limit_source="spec 4.2")})
    path = tmp_path / "b.toml"
    path.write_text('[x]\nunit = "rad"\n')
    kept = Budgets.from_toml(path, base=base)["x"]
    assert (kept.unit, kept.marginal, kept.limit_source) == ("rad", 0.8, "spec 4.2")
    path.write_text("[x]\nlimit = 2.0\n")
    changed = Budgets.from_toml(path, base=base)["x"]
    assert (changed.limit, changed.marginal, changed.limit_source) == (2.0, None, "")
    path.write_text('[x]\nlimit = 2.0\nlimit_source = "our datasheet, table 3"\n')
    assert Budgets.from_toml(path, base=base)["x"].limit_source == "our datasheet, table 3"


def _traced_in_the_suite() -> dict[str, list[str]]:
    """Requirement ID -> the test files of test_cases/ that name it (a marker or a parameter)."""
    import ast
    import re

    out: dict[str, list[str]] = {}
    for path in sorted(SUITE.glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and re.fullmatch(
                r"REQ-[A-Z]+-\d{3}", node.value
            ):
                out.setdefault(node.value, []).append(path.name)
    return out


def test_every_requirement_has_a_test_and_every_traced_id_is_a_requirement():
    """Adding a requirement is one registry entry and its test: neither goes without the other."""
    traced = _traced_in_the_suite()
    untested, unknown = set(REQUIREMENTS) - set(traced), set(traced) - set(REQUIREMENTS)
    assert not untested, f"no test in test_cases/ traces to {sorted(untested)}"
    assert not unknown, f"test_cases/ traces to IDs the registry lacks: {sorted(unknown)}"
    for rid, r in REQUIREMENTS.items():  # the test file the registry names is one that traces to it
        named = {f for f in traced[rid] if f"`{f}" in r.tested_by}
        assert named, f"{rid}: tested_by names none of {traced[rid]}"


def _github_anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation other than - and _ dropped, spaces to -."""
    import re

    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_requirements_doc_anchor_is_a_heading_of_its_page():
    for rid, r in REQUIREMENTS.items():
        page, _, anchor = r.doc.partition("#")
        headings = [line.lstrip("#") for line in (DOCS / page).read_text().splitlines() if line.startswith("#")]
        assert anchor in {_github_anchor(h) for h in headings}, f"{rid}: no heading of docs/{page} is #{anchor}"


@pytest.mark.parametrize("page", sorted(GENERATED))
def test_the_docs_tables_are_the_registrys(page):
    """docs/acceptance.md's requirement table and docs/budgets.md's defaults are generated from the
    registry (``python -m hil.verdicts.requirements`` rewrites them)."""
    text = (DOCS / page).read_text()
    assert rendered(page, text) == text, (
        f"docs/{page} differs from the registry: run python -m hil.verdicts.requirements")


WAIVER = '[[waiver]]\nrequirement = "REQ-ROB-002"\nreason = "recovery needs 80 ms"\nowner = "controls team"\n'


def test_waivers_load_with_their_reason_owner_scope_and_expiry(tmp_path):
    import datetime

    path = tmp_path / "b.toml"
    path.write_text(
        WAIVER + 'tests = ["test_fault_sequences"]\nexpires = 2027-06-30\n\n' + WAIVER.replace("ROB-002", "ROB-001")
    )
    b = Budgets.from_toml(path, base=Budgets({}), today=datetime.date(2027, 6, 30))  # still valid on its last day
    w = b.waivers[0]
    assert (w.requirement, w.reason, w.owner, w.tests, w.expires) == (
        "REQ-ROB-002",
        "recovery needs 80 ms",
        "controls team",
        ("test_fault_sequences",),
        datetime.date(2027, 6, 30),
    )
    assert w.covers("test_cases/x.py::test_fault_sequences[virtual]") and not w.covers("test_cases/x.py::test_other")
    assert b.waivers[1].covers("anything") and f"{path}: [[waiver]][1]" == b.waivers[1].source
    layered = tmp_path / "more.toml"
    layered.write_text(WAIVER.replace("ROB-002", "CAL-001"))
    assert [w.requirement for w in Budgets.from_toml(layered, base=b).waivers] == [
        "REQ-ROB-002",
        "REQ-ROB-001",
        "REQ-CAL-001",
    ]


@pytest.mark.parametrize(
    "text, field, words",
    [
        (WAIVER.replace('reason = "recovery needs 80 ms"\n', ""), "[[waiver]][0].reason", "required"),
        (WAIVER.replace('"controls team"', '"  "'), "[[waiver]][0].owner", "required"),
        (WAIVER + 'expires = "2001-01-31"\n', "[[waiver]][0].expires", "expired on 2001-01-31"),
        (WAIVER + 'expires = "next year"\n', "[[waiver]][0].expires", "ISO date"),
        (WAIVER + 'tests = "test_x"\n', "[[waiver]][0].tests", "list"),
        (WAIVER + 'because = "x"\n', "[[waiver]][0].because", "unknown key"),
        ('[waiver]\nrequirement = "REQ-ROB-002"\n', "waiver", "[[waiver]]"),
    ],
)
def test_bad_waivers_are_refused_naming_file_and_key(tmp_path, text, field, words):
    path = tmp_path / "b.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Budgets.from_toml(path)
    assert f"{path}: {field}" in str(info.value) and words in str(info.value)


@pytest.mark.parametrize(
    "text, field",
    [
        ('[x]\nunit = "A"\nlimit = 1.0\n', "[x].requirement"),
        ('[x]\nrequirement = "R"\nunit = "A"\nlimit = nan\n', "[x].limit"),
        ("[commutation_angle_p99]\nlimt = 1.0\n", "[commutation_angle_p99].limt"),
        ('[commutation_angle_p99]\nkind = "avg"\n', "[commutation_angle_p99].kind"),
        ("[commutation_angle_p99]\nmarginal = 0.9\n", "[commutation_angle_p99].marginal"),
    ],
)
def test_bad_budget_files_name_the_field(tmp_path, text, field):
    path = tmp_path / "b.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Budgets.from_toml(path)
    assert field in str(info.value) and str(path) in str(info.value)


def test_plugin_fixture_records_verdicts_as_junit_properties(pytester):
    pytester.makefile(".toml", budgets="[commutation_angle_p99]\nlimit = 0.3\n")
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
    result.stdout.fnmatch_lines(
        ["*commutation_angle_p99 (REQ-COMM-001): measured 0.42 deg_e exceeds the limit of at most 0.3 deg_e*FAIL*"]
    )
    xml = (pytester.path / "out.xml").read_text()
    assert 'name="budget:commutation_angle_p99"' in xml and 'name="requirement" value="REQ-COMM-001"' in xml
