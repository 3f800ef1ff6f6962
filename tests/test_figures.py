"""Published figures come from code: every marked number and table in README.md and docs/ equals
docs/figures.json, and the quick subset recomputed at HEAD stays within each figure's tolerance
(tools/figures.py)."""

from __future__ import annotations

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
        assert len(prov["commit"]) >= 40, name
        assert prov["commands"] and prov["date"] and prov["duration_s"] >= 0, name


@pytest.mark.skipif(bool(COMPUTING), reason="tools/figures.py is running this suite (it recomputes the figures itself)")
def test_the_quick_figures_reproduce_at_head():
    """The CI subset: recompute every quick group (the demo, the spindle's calibration and its
    predictors) and hold each figure to its tolerance. The shipped tuned settings' training score is
    held by tests/test_predictor_peers.py."""
    data = figures.load()
    quick = [g for g in figures.GROUPS if g.quick]
    fresh = figures.compute(quick)
    assert figures.drift(data, fresh) == [], json.dumps(figures.drift(data, fresh), indent=1)
