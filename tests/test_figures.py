"""Published figures come from code: every marked number and table in README.md and docs/ equals
docs/figures.json, and the quick subset recomputed at HEAD stays within each figure's tolerance
(tools/figures.py)."""

from __future__ import annotations

import copy
import importlib.util
import json
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _figures_module():
    spec = importlib.util.spec_from_file_location("hil_figures_tool", ROOT / "tools" / "figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up while the tool is being loaded
    spec.loader.exec_module(mod)
    return mod


figures = _figures_module()


#: the groups tools/figures.py is computing while this suite runs inside its measurement
COMPUTING = frozenset(filter(None, os.environ.get("HIL_FIGURES_RUNNING", "").split(",")))


def test_every_published_figure_agrees_with_the_figures_file():
    assert figures.disagreements(figures.load(), COMPUTING) == []


def test_the_docs_mark_the_figures_they_publish():
    """The file is used: at least the README's demo block and a figure per quick group are marked."""
    data = figures.load()
    marked = set()
    for path in figures.PUBLISHED:
        text = path.read_text()
        marked |= {m["key"].partition(".")[0] for m in figures.FIG_MARK.finditer(text)}
        marked |= {m["name"].partition("-")[0] for m in figures.TABLE_MARK.finditer(text)}
    quick = {name for name, g in data["groups"].items() if g["provenance"]["quick"]}
    assert quick and quick <= marked, f"quick groups with no marked figure in the docs: {sorted(quick - marked)}"


def test_a_hand_edited_figure_is_caught(tmp_path, monkeypatch):
    data = figures.load()
    group = next(iter(data["groups"]))
    name, fig = next(iter(data["groups"][group]["figures"].items()))
    shown = figures.Figure(**fig).text()
    doc = tmp_path / "doc.md"
    doc.write_text(f"the figure is <!-- fig:{group}.{name} -->{shown}<!-- /fig --> here\n")
    monkeypatch.setattr(figures, "PUBLISHED", [doc])
    monkeypatch.setattr(figures, "ROOT", tmp_path)
    assert figures.disagreements(data) == []
    doc.write_text(f"the figure is <!-- fig:{group}.{name} -->{shown}1<!-- /fig --> here\n")
    (bad,) = figures.disagreements(data)
    assert f"{group}.{name}" in bad and "doc.md:1" in bad
    doc.write_text("<!-- fig:nosuch.figure -->1<!-- /fig -->\n")
    (bad,) = figures.disagreements(data)
    assert "no figure 'nosuch.figure'" in bad


def test_drift_beyond_tolerance_is_reported():
    f = figures.Figure(1.0, "deg e", tolerance_abs=0.01, tolerance_rel=0.02)
    assert f.drift(figures.Figure(1.019)) is None
    assert "tolerance" in f.drift(figures.Figure(1.03))
    assert figures.Figure("pass").drift(figures.Figure("fail")) == "'pass' -> 'fail'"


def test_every_figure_states_its_provenance():
    for name, g in figures.load()["groups"].items():
        prov = g["provenance"]
        assert prov["commands"] and prov["date"] and prov["duration_s"] >= 0, name
    note = figures.history_note()
    if note:  # a clone without history: said, never passed silently
        pytest.skip(note)
    assert figures.provenance_problems(figures.load()) == []


def _forged(mutate) -> dict:
    data = copy.deepcopy(figures.load())
    mutate(data)
    return data


def _needs_history():
    if figures.history_note():
        pytest.skip(figures.history_note())


def test_a_figure_changed_by_hand_in_the_figures_file_fails_the_check():
    """The pumps' Sage-Husa figure set to 0.120, the docs rendered from the edited file: the docs
    agree with it, the group's digest does not."""
    def edit(data):
        data["groups"]["pump_predictors"]["figures"]["sage_husa.angle_rms_deg_e"]["value"] = 0.120

    data = _forged(edit)
    bad = figures.provenance_problems(data)
    assert any("pump_predictors" in b and "digest" in b for b in bad), bad


def test_a_table_cell_changed_by_hand_in_the_figures_file_fails_the_check():
    def edit(data):
        data["groups"]["pump_predictors"]["tables"]["predictors"][5][1] = "0.120"

    bad = figures.provenance_problems(_forged(edit))
    assert any("pump_predictors" in b and "digest" in b for b in bad), bad


def test_a_provenance_commit_of_zeros_fails_the_check_even_with_its_digest_rewritten():
    _needs_history()

    def edit(data):
        g = data["groups"]["pump_predictors"]
        g["provenance"]["commit"] = "0" * 40
        g["digest"] = figures.digest(g)  # a forger who knows the tool

    bad = figures.provenance_problems(_forged(edit))
    assert bad == ["figures.json: group pump_predictors: provenance commit 000000000000 is no commit of this "
                   "repository"], bad


def test_a_provenance_commit_that_is_not_an_ancestor_of_head_fails_the_check(tmp_path):
    _needs_history()
    head = figures._git("rev-parse", "HEAD").stdout.strip()
    # a commit of this repository that HEAD does not contain: HEAD's tree with HEAD as parent
    child = figures._git("commit-tree", f"{head}^{{tree}}", "-p", head, "-m", "not an ancestor").stdout.strip()
    assert child

    def edit(data):
        g = data["groups"]["demo"]
        g["provenance"]["commit"] = child
        g["digest"] = figures.digest(g)

    bad = figures.provenance_problems(_forged(edit))
    assert bad == [f"figures.json: group demo: provenance commit {child[:12]} is not an ancestor of HEAD"], bad


def test_uncommitted_provenance_fails_the_check():
    def edit(data):
        g = data["groups"]["demo"]
        g["provenance"]["commit"] += "+uncommitted"
        g["digest"] = figures.digest(g)

    bad = figures.provenance_problems(_forged(edit))
    assert len(bad) == 1 and "not a commit" in bad[0], bad


def test_a_clone_without_history_is_told_so(monkeypatch):
    monkeypatch.setattr(figures, "history_note", lambda: "provenance NOT checked: this clone has no history")

    def edit(data):
        g = data["groups"]["demo"]
        g["provenance"]["commit"] = "0" * 40
        g["digest"] = figures.digest(g)

    assert figures.provenance_problems(_forged(edit)) == []  # commits unseen: the note says so
    assert "NOT checked" in figures.history_note()


def test_a_number_changed_by_hand_in_a_rendered_doc_fails_the_check(tmp_path, monkeypatch):
    """1.023 -> 0.923 in the REQ-PRED-002 table of a rendered page: the page disagrees with the file."""
    data = figures.load()
    page = "<!-- figtable:req_pred_002_spread-profiles -->\n<!-- /figtable -->\n"
    doc = tmp_path / "doc.md"
    doc.write_text(figures.render_text(page, data))
    monkeypatch.setattr(figures, "PUBLISHED", [doc])
    monkeypatch.setattr(figures, "ROOT", tmp_path)
    assert figures.disagreements(data) == []
    pooled = figures.figure(data, "req_pred_002_spread.pooled_ratio").text()
    doc.write_text(doc.read_text().replace(f"**{pooled}**", "**0.923**"))
    (bad,) = figures.disagreements(data)
    assert "req_pred_002_spread-profiles differs" in bad


def test_a_recomputed_table_cell_is_compared():
    stored = {"groups": {"g": {"figures": {}, "tables": {"t": [["name", "RMS"], ["kf", "0.130"]]}, "blocks": {}}}}

    def fresh(cell):
        return {"g": {"figures": {}, "tables": {"t": [["name", "RMS"], ["kf", cell]]}, "blocks": {}}}

    assert figures.drift(stored, fresh("0.130")) == []
    assert figures.drift(stored, fresh("0.131")) == []  # one unit of the last printed digit
    assert figures.drift(stored, fresh("0.120")) == ["g-t: row 1 column 1: '0.130' -> '0.120'"]
    assert figures.drift(stored, fresh("0.130 (bad)")) != []
    stored["groups"]["g"]["blocks"] = {"out": "mean 1.00\n"}
    (bad,) = figures.drift(stored, {"g": {"figures": {}, "tables": stored["groups"]["g"]["tables"],
                                          "blocks": {"out": "mean 1.50\n"}}})
    assert bad.startswith("g-out: row 0")


def test_the_release_check_record_is_shown_and_cannot_be_edited():
    data = figures.load()
    readme = (figures.ROOT / "README.md").read_text()
    assert f"<!-- figcheck -->{figures.release_check_text(data)}<!-- /figcheck -->" in readme
    record = {"date": "2026-11-27T22:00:00Z", "commit": "a" * 40, "groups": ["demo"], "duration_s": 1.0,
              "result": "every figure and table cell within tolerance"}
    record["digest"] = figures._release_digest(record)
    forged = _forged(lambda d: d.__setitem__("release_check", {**record, "date": "2027-01-01T00:00:00Z"}))
    assert any("release_check" in b for b in figures.disagreements(forged))


def test_no_page_gains_numbers_outside_the_markers():
    """Every decimal of README.md and docs/ outside a figure marker is counted against a ledger
    that only shrinks (python tools/figures.py --unmarked lists them)."""
    assert figures.unmarked_growth(figures.load()) == []


@pytest.mark.skipif(bool(COMPUTING), reason="tools/figures.py is running this suite (it recomputes the figures itself)")
def test_the_quick_figures_reproduce_at_head():
    """The CI subset: recompute every quick group (the demo, the spindle's calibration and its
    predictors) and hold each figure to its tolerance. The shipped tuned settings' training score is
    held by tests/test_predictor_peers.py."""
    data = figures.load()
    quick = [g for g in figures.GROUPS if g.quick]
    fresh = figures.compute(quick)
    assert figures.drift(data, fresh) == [], json.dumps(figures.drift(data, fresh), indent=1)
