"""The layout of docs/architecture.md, held: no import cycle, no import the page does not allow.

The import graph is read from the source (every ``import`` statement, those inside functions and
under ``TYPE_CHECKING`` included), not from what happens to be loaded, so an import that only
runs on some path is judged too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bldc", "hil", "plant_models")

#: module prefix -> group, the longest prefix wins (the rows of the table in docs/architecture.md)
GROUP_OF_PREFIX = {
    "bldc": "vocabulary",
    "plant_models": "plant",
    "hil.predictors": "predictors",
    "hil.calibration.corrections": "corrections",
    "hil.controller": "controller",
    "hil.dut.link": "link",
    "hil.dut": "dut",
    "hil.recording": "recording",
    "hil.traces": "recording",
    "hil.linebemf": "recording",
    "hil.calibration": "calibration",
    "hil.faults": "faults",
    "hil.bench": "bench",
    "hil.stimulus": "bench",
    "hil.budgets": "verdicts",
    "hil.report": "verdicts",
    "hil.report_html": "verdicts",
    "hil.progress": "verdicts",
    "hil.plots": "verdicts",
    "hil.experiments": "experiments",
    "hil.gap": "gap",
    "hil.signals": "signals",
    "hil.campaign": "campaign",
    "hil.qualify": "qualify",
    "hil.cli": "entry",
    "hil.pytest_plugin": "entry",
    "hil.demo": "entry",
    "hil.__main__": "entry",
    "hil": "entry",
}
_BELOW_BENCH = {"vocabulary", "plant", "predictors", "corrections", "controller", "link", "dut", "recording",
                "calibration", "faults"}
_BELOW_BESIDE = _BELOW_BENCH | {"bench", "verdicts"}
#: group -> the groups it may import (besides itself)
MAY_IMPORT = {
    "vocabulary": set(),
    "plant": {"vocabulary"},
    "predictors": {"vocabulary"},
    "corrections": {"vocabulary"},
    "controller": {"vocabulary", "corrections", "predictors"},
    "link": {"vocabulary", "corrections"},
    "dut": {"vocabulary", "plant", "predictors", "corrections", "controller", "link"},
    "recording": {"vocabulary", "plant"},
    "calibration": {"vocabulary", "corrections", "recording", "plant"},
    "faults": {"vocabulary"},
    "bench": _BELOW_BENCH,
    "verdicts": {"vocabulary"},
    "experiments": _BELOW_BESIDE,
    "gap": _BELOW_BESIDE | {"campaign"},
    "signals": _BELOW_BESIDE,
    "campaign": _BELOW_BESIDE,
    "qualify": _BELOW_BESIDE,
    "entry": set(GROUP_OF_PREFIX.values()),
}


def group(module: str) -> str:
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in GROUP_OF_PREFIX:
            return GROUP_OF_PREFIX[".".join(parts[:n])]
    raise KeyError(f"{module} is in no group of docs/architecture.md")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _modules()


def _imports(module: str, path: Path) -> list[tuple[str, int]]:
    """(imported module of ours, line) for every import statement in ``path``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            # "from pkg import mod" imports the module pkg.mod
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in MODULES and "." in name:
                name = name.rpartition(".")[0]
            if name in MODULES and name != module:
                found.append((name, node.lineno))
    return found


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def test_the_top_level_packages_import_downwards_only():
    """bldc imports neither of the others, plant_models never imports hil."""
    wrong = [
        f"{module} imports {target}"
        for module, imports in GRAPH.items()
        for target, _ in imports
        if (module.split(".")[0], target.split(".")[0]) in {("bldc", "hil"), ("bldc", "plant_models"),
                                                            ("plant_models", "hil")}
    ]
    assert not wrong, wrong


def test_every_module_has_a_room():
    for module in MODULES:
        assert group(module) in MAY_IMPORT, module


def test_no_import_goes_where_the_architecture_page_does_not_allow():
    wrong = []
    for module, imports in GRAPH.items():
        g = group(module)
        for target, line in imports:
            t = group(target)
            if t != g and t not in MAY_IMPORT[g]:
                wrong.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {module} ({g}) imports {target} ({t})")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycle_between_modules():
    # Tarjan's strongly connected components over the module graph
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w, _ in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in MODULES:
        if module not in index:
            visit(module)
    assert not cycles, cycles


def test_the_graph_reader_sees_function_level_imports():
    """A guard on the guard: the reader must see an import made inside a function."""
    source = MODULES["hil.dut.spec"].read_text()
    assert "\nfrom .canopen_face" not in source  # hil.dut.spec loads the CANopen stack on use only
    assert "hil.dut.canopen_face" in {t for t, _ in GRAPH["hil.dut.spec"]}


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print('\\n'.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return set(out.stdout.split())


@pytest.mark.parametrize(
    "statement, never",
    [
        ("import hil.dut.link", ("numba", "canopen", "can", "pymodbus", "plant_models", "hil.controller")),
        ("import bldc.contract", ("numba", "plant_models", "hil.predictors", "hil.controller")),
        ("import hil.controller.virtual", ("plant_models",)),
    ],
)
def test_light_modules_stay_light_when_imported(statement, never):
    loaded = _loaded_after(statement)
    heavy = sorted(m for m in loaded if m.split(".")[0] in never or any(m.startswith(n + ".") or m == n for n in never))
    assert not heavy, f"{statement} loads {heavy}"


def test_the_hall_geometry_is_written_once():
    """Sensor positions and back-EMF zero crossings appear as numbers only in bldc/hall.py."""
    literals = ("0.0, 120.0, 240.0", "0, 120, 240", "90.0, 210.0, 330.0", "90, 210, 330")
    found = [
        f"{path.relative_to(ROOT)}: {lit}"
        for path in MODULES.values()
        if path.name != "hall.py" or path.parent.name != "bldc"
        for lit in literals
        if lit in path.read_text()
    ]
    assert not found, found


def _hand_assembled_hall_codes(tree: ast.AST) -> list[int]:
    """Lines that build a 3-bit Hall code by hand: a sum or bitwise or whose terms weigh lines by
    4 and 2 (``a * 4 + b * 2 + c``, ``(a << 2) | (b << 1) | c``), or that index ``SECTOR_OF_CODE``
    or a sector table of their own."""

    def weights(node: ast.AST) -> set[int]:
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.BitOr)):
            return weights(node.left) | weights(node.right)
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Mult, ast.LShift)):
            for c in (node.left, node.right):
                if isinstance(c, ast.Constant) and isinstance(c.value, int):
                    return {c.value if isinstance(node.op, ast.Mult) else 1 << c.value}
        return set()

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.BitOr)) and {4, 2} <= weights(node):
            lines.append(node.lineno)
        elif isinstance(node, (ast.Name, ast.Attribute)) and (
            getattr(node, "id", None) or getattr(node, "attr", "")
        ) in ("SECTOR_OF_CODE", "SECTOR_STATES", "_SECTOR_OF_STATE"):
            lines.append(node.lineno)
    return sorted(set(lines))


def test_no_module_outside_the_core_decodes_hall_codes():
    """Issue 31: Hall codes are decoded in ``bldc`` only (``bldc.hall.sector_of_levels`` for one
    edge at a time, ``bldc.edges.decode_edges`` for captured edges); nothing under ``hil/``
    assembles a code or reads a code table. The check itself is checked on the forms it replaced."""
    for form in ("s = T[a * 4 + b * 2 + c]", "s = (a << 2) | (b << 1) | c", "s = SECTOR_OF_CODE[x]"):
        assert _hand_assembled_hall_codes(ast.parse(form)), form
    assert not _hand_assembled_hall_codes(ast.parse("n = 1 << 20; m = 2 * k + 1"))
    found = [
        f"{path.relative_to(ROOT)}:{line}"
        for module, path in MODULES.items()
        if module.startswith("hil")
        for line in _hand_assembled_hall_codes(ast.parse(path.read_text()))
    ]
    assert not found, f"Hall codes decoded outside bldc: {found}"
