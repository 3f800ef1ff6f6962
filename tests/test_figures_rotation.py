"""One slow group of published figures recomputed per CI run, in turn (``rotation=True`` in
tools/figures.py), held cell by cell to docs/figures.json: a group edited by hand with a fresh
commit and digest is caught within as many commits as there are rotating groups. Its own file, so
that pytest-xdist runs it beside tests/test_figures.py's quick groups rather than after them."""

from __future__ import annotations

import json

import pytest
from test_figures import COMPUTING, figures


@pytest.mark.skipif(bool(COMPUTING), reason="tools/figures.py is running this suite (it recomputes the figures itself)")
def test_this_commits_rotating_group_reproduces():
    data = figures.load()
    group = figures.rotation_group()
    differ = figures.drift(data, figures.compute([group]))
    assert differ == [], f"{group.name} recomputed at HEAD:\n" + json.dumps(differ, indent=1)
