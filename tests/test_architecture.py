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

#: module prefix -> group, the longest prefix wins (the rows of the table in docs/architecture.md);
#: a group with a folder of its own under hil/ is that folder's prefix
GROUP_OF_PREFIX = {
    "bldc": "vocabulary",
    "hil.cli_grammar": "vocabulary",
    "plant_models": "plant",
    "hil.predictors": "predictors",
    "hil.calibration.corrections": "corrections",
    "hil.controller": "controller",
    "hil.dut.link": "link",
    "hil.dut": "dut",  # the wiring faults (hil.dut.faults) too: they act on the way to the device
    "hil.sil": "dut",  # a firmware in the loop is one more kind of DUT
    "hil.pil": "dut",  # and a processor in the loop
    "hil.recording": "recording",
    "hil.calibration": "calibration",
    "hil.bench": "bench",
    "hil.verdicts": "verdicts",
    "hil.history.compare": "verdicts",  # a figure against its past runs: plain arithmetic the report draws
    "hil.history": "entry",  # the results store: a run's records, written and read by the commands
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
                "calibration"}
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
    "bench": _BELOW_BENCH,
    "verdicts": {"vocabulary"},
    "experiments": _BELOW_BESIDE,
    "gap": _BELOW_BESIDE | {"campaign"},
    "signals": _BELOW_BESIDE,
    "campaign": _BELOW_BESIDE,
    "qualify": _BELOW_BESIDE,
    "entry": set(GROUP_OF_PREFIX.values()),
}
#: the modules that stay loose in hil/ (entry points and the command line's words): every other
#: module lives in the folder of its group
MAX_LOOSE_MODULES = 8


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


def test_the_folders_show_the_groups():
    """A group of more than one module is a folder under hil/: few modules stay loose beside them."""
    loose = sorted(p.name for p in (ROOT / "hil").glob("*.py"))
    assert len(loose) <= MAX_LOOSE_MODULES, f"{len(loose)} loose modules in hil/: {', '.join(loose)}"
    # each folder-group's prefix is a folder (the table above names no module that has moved out)
    for prefix in GROUP_OF_PREFIX:
        path = ROOT / Path(*prefix.split("."))
        assert path.is_dir() or path.with_suffix(".py").is_file(), f"{prefix} is neither a folder nor a module"


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
    assert "\nfrom .canopen_link" not in source  # hil.dut.spec loads the CANopen stack on use only
    assert "hil.dut.canopen_link" in {t for t, _ in GRAPH["hil.dut.spec"]}


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


def _tomllib_uses(path: Path) -> list[int]:
    """Lines of ``path`` that import tomllib or call it (an alias or ``from tomllib import loads`` included)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] in ("tomllib", "tomli") for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in ("tomllib", "tomli"):
            lines.append(node.lineno)
    return lines


def test_toml_files_are_read_only_through_the_strict_loader():
    """bldc.tomlfile.load_toml is the one reader of TOML (one error type naming file, table and key;
    unknown keys refused): no other module of the project, tests and tools included, uses tomllib."""
    helper = ROOT / "bldc" / "tomlfile.py"
    sources = [p for p in ROOT.rglob("*.py") if not any(part.startswith(".") for part in p.relative_to(ROOT).parts)]
    assert helper in sources and _tomllib_uses(helper)  # the rule sees the one module that may
    wrong = [f"{p.relative_to(ROOT)}:{line}" for p in sources if p != helper for line in _tomllib_uses(p)]
    assert not wrong, "tomllib used outside bldc/tomlfile.py (read with load_toml): " + ", ".join(wrong)


#: names bldc.contract defines once (strategies, filter counters, faults): no other module lists them.
#: family -> (its names, names one of which a list must hold to be a copy, whether dict keys count):
#: the predictors' own names (kf, sage_husa beside precal, pll, ...) are another list, and a
#: figure's style by run label is no list of strategies
_CONTRACT_NAME_FAMILIES = {
    "strategies": ({"raw", "corrected", "kf", "sage_husa", "sage-husa"}, {"raw", "corrected"}, False),
    "filter counters": ({"guard_trips", "gated_edges", "covariance_repairs", "divergence_fades", "band_projections"},
                        None, True),
    "faults": ({"illegal_hall_code", "missing_edge", "filter_guard_trip", "invalid_calibration", "capture_timing",
                "internal_error"}, None, True),
}


def _name_lists(path: Path) -> list[tuple[int, str]]:
    """(line, family) of each tuple, list or set literal (or dict's keys) in ``path`` that spells two
    or more names of a family the contract owns: a second copy of the list, which drifts."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            items, keys = node.elts, False
        elif isinstance(node, ast.Dict):
            items, keys = [k for k in node.keys if k is not None], True
        else:
            continue
        words = {e.value for e in items if isinstance(e, ast.Constant) and isinstance(e.value, str)}
        for family, (names, marks, dict_keys) in _CONTRACT_NAME_FAMILIES.items():
            # a list of the family (most of its words are the family's), not a table of other things
            # that names a few of them among many (the draft's phrases per profile role)
            mostly = 2 * len(words & names) >= len(words)
            if len(words & names) >= 2 and mostly and (marks is None or words & marks) and (dict_keys or not keys):
                found.append((node.lineno, family))
    return found


def test_strategy_counter_and_fault_names_are_listed_only_in_the_contract():
    contract = MODULES["bldc.contract"]
    assert {f for _, f in _name_lists(contract)} >= {"filter counters"}  # the rule sees the list where it belongs
    wrong = [f"{p.relative_to(ROOT)}:{line}: {family}" for m, p in MODULES.items() if p != contract
             for line, family in _name_lists(p)]
    assert not wrong, "import these names from bldc.contract: " + ", ".join(wrong)


def test_the_contract_states_no_device_address():
    """Where a device keeps the strategy or the filter settings is its profile's business (a copy in
    the contract's text drifted: it said 0x2010 and register 10 for what sits at 0x2000 and 0)."""
    import re

    text = MODULES["bldc.contract"].read_text()
    assert not re.findall(r"0x2[0-9A-Fa-f]{3}|(?:Modbus|holding) registers? \d", text)


#: the modules the private-name rule reads: the packages and the tools (tools/published's modules too)
_PRIVATE_RULE_MODULES = {**MODULES, **{
    ".".join(("tools", *p.relative_to(ROOT / "tools").with_suffix("").parts)).removesuffix(".__init__"): p
    for p in sorted((ROOT / "tools").rglob("*.py"))}}


def room(module: str) -> str:
    """A module's room: the directory right under ``hil/`` it lives in (``hil.calibration``,
    ``hil.twin``), ``hil`` for the modules beside them, the top-level package otherwise."""
    parts = module.split(".")
    if parts[0] == "hil" and len(parts) > 1 and (ROOT / "hil" / parts[1]).is_dir():
        return ".".join(parts[:2])
    return parts[0]


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _foreign_private_names(module: str, path: Path, source: str | None = None) -> list[tuple[int, str]]:
    """(line, what) for each private name of another room that ``module`` (at ``path``; its text
    ``source``, read from the file if None) reaches: ``from X import _name``, ``import X._name``,
    or ``X._name`` where X is a module of ours bound by an import."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text() if source is None else source, str(path))
    bound: dict[str, str] = {}  # local name -> module of ours it is bound to
    found = []

    def home(name: str) -> str | None:
        """The module of ours that ``name`` (dotted) is, or whose attribute it is."""
        while name and name not in MODULES:
            if "." not in name:
                return None
            name = name.rpartition(".")[0]
        return name or None

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                target = home(a.name)
                if target is None:
                    continue
                if a.asname:
                    bound[a.asname] = a.name
                else:
                    bound[a.name.split(".")[0]] = a.name.split(".")[0]
                if any(_private(p) for p in a.name.split(".")) and room(target) != room(module):
                    found.append((node.lineno, f"import {a.name}"))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            target = home(base)
            if target is None:
                continue
            for a in node.names:
                full = f"{base}.{a.name}"
                if full in MODULES:
                    bound[a.asname or a.name] = full
                where = home(full) if full in MODULES else target
                if (_private(a.name) or any(_private(p) for p in base.split("."))) and room(where) != room(module):
                    found.append((node.lineno, f"from {base} import {a.name}"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            chain, value = [node.attr], node.value
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if not isinstance(value, ast.Name) or value.id not in bound:
                continue
            owner = ".".join([bound[value.id], *reversed(chain[1:])])
            target = home(owner)
            if target is not None and room(target) != room(module):
                found.append((node.lineno, f"{owner}.{node.attr}"))
    return found


def test_the_private_name_rule_sees_each_form():
    """A guard on the guard: each form of reaching another room's private name is seen, and a
    room's own private names and public names of another room are not."""
    cases = {
        "from hil.calibration.ordinary import _chi2": 1,
        "from ..calibration.ordinary import _chi2, fit_ordinary": 1,
        "from ..calibration import ordinary\nordinary._chi2(a, b)": 1,
        "import hil.calibration.ordinary as o\no._chi2(a, b)": 1,
        "import hil.calibration.ordinary\nhil.calibration.ordinary._chi2(a, b)": 1,
        "from plant_models import _kernel": 1,
        "from .capture import _something": 0,  # the twin's own
        "from ..calibration.ordinary import fit_ordinary": 0,
        "from ..calibration import ordinary\nordinary.__doc__": 0,
    }
    probe = ROOT / "hil" / "twin" / "probe.py"  # a module of the twin's room (not written)
    for source, n in cases.items():
        got = _foreign_private_names("hil.twin.probe", probe, source)
        assert len(got) == n, (source, got)


def test_no_module_reaches_another_rooms_private_names():
    """A name starting with ``_`` is its room's business: a module of another room that needs it
    needs it public (or in a shared module), so the room can change it without breaking a caller
    it cannot see."""
    wrong = [
        f"{path.relative_to(ROOT)}:{line}: {what}"
        for module, path in _PRIVATE_RULE_MODULES.items()
        for line, what in _foreign_private_names(module, path)
    ]
    assert not wrong, "private names of another room:\n" + "\n".join(wrong)
