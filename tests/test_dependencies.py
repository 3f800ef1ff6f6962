"""Every package a test imports is installed by README's test command (``pip install -e ".[test]"``).

A package installed by hand on the developer's machine once made CI green and a user's first run red
(filterpy, imported by a test, was only in the ``bench`` extra). This test reads the import statements
of every test module (function-level imports included) and checks each third-party top-level module
against the distributions the core dependencies and the ``test`` extra name in pyproject.toml.
"""

from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
from pathlib import Path

from bldc.tomlfile import load_toml

ROOT = Path(__file__).resolve().parents[1]
TEST_DIRS = ("tests", "test_cases")
#: the project's own top-level packages and the test directories' own modules (a test may import
#: a helper from another test module)
OWN = {"bldc", "hil", "plant_models"} | {p.stem for d in TEST_DIRS for p in (ROOT / d).glob("*.py")}


def _distribution_name(requirement: str) -> str:
    """``dask[distributed]>=2024.8`` -> ``dask`` (PEP 503 normalised)."""
    name = re.match(r"[A-Za-z0-9._-]+", requirement).group(0)
    return re.sub(r"[-_.]+", "-", name).lower()


def declared_distributions() -> set[str]:
    project = load_toml(ROOT / "pyproject.toml")["project"]
    requirements = project["dependencies"] + project["optional-dependencies"]["test"]
    declared = {_distribution_name(r) for r in requirements}
    # extras pull further distributions in: dask[distributed] brings distributed
    for requirement in requirements:
        for extra in re.findall(r"\[([^\]]+)\]", requirement):
            declared.update(_distribution_name(e) for e in extra.split(","))
    return declared


def imported_top_level_modules() -> dict[str, str]:
    """Top-level module -> the first test file that imports it."""
    found: dict[str, str] = {}
    for directory in TEST_DIRS:
        for path in sorted((ROOT / directory).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split(".")[0], str(path.relative_to(ROOT)))
    return found


def test_every_module_a_test_imports_is_declared_in_the_core_or_test_extra():
    declared = declared_distributions()
    providers = importlib.metadata.packages_distributions()
    missing = []
    for module, where in sorted(imported_top_level_modules().items()):
        if module in OWN or module in sys.stdlib_module_names:
            continue
        distributions = {_distribution_name(d) for d in providers.get(module, [module])}
        if not distributions & declared:
            missing.append(f"{module} (imported by {where}; distribution {', '.join(sorted(distributions))})")
    assert not missing, "imported by tests but not in pyproject's dependencies or test extra: " + "; ".join(missing)


def test_the_check_sees_a_module_nobody_declared():
    # the check itself must be able to fail: a module no distribution provides is reported
    assert "no_such_module_xyz" not in importlib.metadata.packages_distributions()
    declared = declared_distributions()
    assert "filterpy" in declared and "no-such-module-xyz" not in declared
