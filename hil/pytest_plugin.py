"""pytest plugin (entry point ``pytest11: hil``): options, fixtures, the requirement marker and reports.

Options (each also an ini key ``hil_<name>`` in pytest.ini or pyproject.toml):

* ``--hil-dut SPEC`` (repeatable): the controller(s) under test, ``virtual`` by default
  (``hil/dut/spec.py`` lists the forms: CANopen, Modbus TCP/RTU, the virtual controller);
  tests that use the controller run once per DUT;
* ``--hil-plant TOML``: motor and circuit (default: the paper-bench preset);
* ``--hil-budgets TOML``: accuracy budgets over the built-in defaults;
* ``--hil-report-dir DIR``: write the HTML, JSON and JUnit reports there, test by test;
* ``--hil-seed N``: the base seed of everything random.

The plugin costs nothing until a session uses it (an option or ini key given, a test requesting
one of its fixtures or carrying a ``requirement`` marker): only then does it import the plant, the
controller links and the budgets, and print its header line. Ini paths are relative to the ini
file. ``-n`` (xdist) with a real controller is refused: every worker would open it.

Fixtures: ``hil_plant_config``, ``hil_simulation``, ``hil_kinematic``, ``hil_seed``, ``hil_dut``
(the opened controller, once per session and DUT), ``hil_link`` (the controller reset for this
test), ``hil_bench`` (a lockstep bench factory with effect injection), ``hil_budgets``,
``hil_budget`` (check a measurement and record its verdict), ``hil_evidence`` (attach values,
tables, figures and text to the current test). Marker: ``requirement("REQ-...", ...)``.
"""

from __future__ import annotations

import datetime
import json
import platform
import re
import sys
from pathlib import Path

import pytest

# the report's record format: standard library only (the plant, links and budgets load on use)
from .verdicts.record import FailedBy, Outcome, Status, TestRecord, Unanswerable, Verdict
from .verdicts.report import PROPERTY_PREFIX, ReportWriter, file_sha256, test_waiver

#: the signal-injection fixture (hil_signals) and its options live in their own plugin module
pytest_plugins = ["hil.signals.fixtures"]

VERSIONED = (
    "bldc-hil",
    "numpy",
    "scipy",
    "numba",
    "python-can",
    "canopen",
    "pymodbus",
    "hypothesis",
    "pytest",
    "pytest-xdist",
    "matplotlib",
    "jinja2",
)


def pytest_addoption(parser):
    group = parser.getgroup("hil", "BLDC pump controller HIL")
    group.addoption(
        "--hil-dut",
        action="append",
        default=None,
        metavar="SPEC",
        help="controller under test (repeatable): virtual[:canopen|modbus|in-process], "
        "canopen:interface=..,channel=..,node=.., "
        "modbus-tcp:host=..,port=..,unit=.., modbus-rtu:port=..,baud=..,unit=.. (each with profile=FILE for the "
        "device's own map: docs/device-profiles.md), or a firmware kind's KIND:FIRMWARE (every kind is one "
        "declaration of hil/dut/kinds.py; hil acceptance --help lists them); default: virtual",
    )
    group.addoption(
        "--hil-plant", default=None, help="plant TOML (motor, circuit, effects); default: paper-bench preset"
    )
    group.addoption("--hil-seed", type=int, default=None, help="base seed for plant randomness (default 0)")
    group.addoption(
        "--hil-delay-draws",
        choices=("library", "real-wiring"),
        default="library",
        help="range REQ-ROB-001 draws conditioning delays from: library (the stated 0-50 us, default) or "
        "real-wiring (0-300 us, open-collector Hall outputs with pull-up, filter and cable)",
    )
    group.addoption(
        "--hil-defect",
        default=None,
        metavar="NAME",
        help="seed this firmware defect into the built-in controller (hil qualify; virtual DUTs only)",
    )
    group.addoption(
        "--hil-defects", default=None, metavar="FILE", help="a Python file of further @defect classes (hil qualify)"
    )
    group.addoption(
        "--hil-requirements",
        default=None,
        metavar="IDS",
        help="run only the tests traced to these requirements (comma-separated; hil qualify --sensitivity)",
    )
    group.addoption(
        "--hil-first",
        default=None,
        metavar="IDS",
        help="run the tests traced to these requirements first, the rest after in their order (comma-separated; "
        "hil qualify: a defect's own requirements, so that the run stops at its catch early)",
    )
    group.addoption(
        "--hil-stop-at-catch",
        action="store_true",
        default=False,
        help="stop the session after the first test whose failure is a catch (a failed budget or judged check, a "
        "device failure, a check of a requirement without budgets); a setup check, an error or a check of a "
        "requirement with budgets does not stop it (hil qualify)",
    )
    group.addoption(
        "--hil-budgets", default=None, help="budgets TOML (named limits traced to requirements); default: built-in"
    )
    group.addoption(
        "--hil-report-dir", default=None, help="write HTML/JSON/JUnit compliance reports there, test by test"
    )
    group.addoption(
        "--hil-history",
        default=None,
        metavar="URL",
        help="record the run in this results history: an SQLite file, sqlite:///PATH, postgresql+psycopg://..., "
        "or off (default: HIL_HISTORY, else the user's history.sqlite: docs/history.md)",
    )
    group.addoption(
        "--hil-station", default=None, metavar="NAME", help="the station's name in the history (default: HIL_STATION, "
        "else the host name)"
    )
    parser.addini(
        "hil_dut", "controller spec(s), shell-separated, used when --hil-dut is not given", type="args", default=[]
    )
    parser.addini(
        "hil_plant",
        "plant TOML (relative to the ini file) used when --hil-plant is not given",
        type="paths",
        default=[],
    )
    parser.addini(
        "hil_budgets",
        "budgets TOML (relative to the ini file) used when --hil-budgets is not given",
        type="paths",
        default=[],
    )
    # read as text and parsed here: pytest's own "int" ini type names neither the key nor the file
    # when the value is not an integer (pytest 9.2: "invalid literal for int() with base 10")
    parser.addini("hil_seed", "base seed (an integer) used when --hil-seed is not given", type="string", default="0")
    parser.addini("hil_history", "results history URL or SQLite file (relative to the ini file) or off, used when "
                  "--hil-history and HIL_HISTORY are not given", type="string", default="")
    parser.addini("hil_station", "the station's name in the results history", type="string", default="")
    parser.addini(
        "hil_report_dir",
        "report directory (relative to the ini file) used when --hil-report-dir is not given",
        type="paths",
        default=[],
    )


_PATH_KEYS = ("plant", "budgets", "report_dir")
_PLANT = pytest.StashKey()  #: the parsed plant configuration (the TOML is read once per session)
_BUDGETS = pytest.StashKey()  #: the budgets in force, read once per session
_EXPLICIT = pytest.StashKey[bool]()  #: an option or ini key of the plugin was given


def _option(config, name: str):
    """A path option (``plant``, ``budgets``, ``report_dir``) as a Path, or the seed as an int:
    the command line (relative to the invocation directory) over the ini key (relative to the
    ini file); None for a path neither gives."""
    value = config.getoption(f"--hil-{name.replace('_', '-')}")
    if name == "seed":
        if value is not None:
            return int(value)
        text = config.getini("hil_seed")
        try:
            return int(text)
        except ValueError:
            raise pytest.UsageError(
                f"hil: ini key hil_seed in {config.inipath} must be an integer, got {text!r}"
            ) from None
    if value not in (None, ""):
        return config.invocation_params.dir / value
    paths = config.getini(f"hil_{name}")
    if len(paths) > 1:
        raise pytest.UsageError(
            f"hil: ini key hil_{name} in {config.inipath} takes one path, got {len(paths)}: {' '.join(map(str, paths))}"
        )
    return paths[0] if paths else None


def _dut_texts(config) -> list[str]:
    return config.getoption("--hil-dut") or config.getini("hil_dut") or ["virtual"]


def _explicit(config) -> bool:
    """Whether the run configures the plugin (any --hil-* option or hil_* ini key given)."""
    if _EXPLICIT not in config.stash:
        given = [
            config.getoption("--hil-dut"),
            config.getini("hil_dut"),
            _option(config, "seed") != 0,
            *(_option(config, name) for name in _PATH_KEYS),
        ]
        config.stash[_EXPLICIT] = any(given)
    return config.stash[_EXPLICIT]


def _uses_plugin(item) -> bool:
    """Whether a test uses the plugin: it requests one of its fixtures or carries a requirement mark."""
    names = getattr(item, "fixturenames", ())
    return any(name.startswith("hil_") for name in names) or item.get_closest_marker("requirement") is not None


def dut_specs(config) -> list:
    from .dut.spec import DutSpecError, parse_dut

    try:
        return [parse_dut(t) for t in _dut_texts(config)]
    except DutSpecError as exc:
        raise pytest.UsageError(str(exc)) from None


def _plant_config(config):
    """The plant in force (--hil-plant TOML or the paper-bench preset), parsed once per session."""
    if _PLANT not in config.stash:
        from plant_models import PlantConfig, paper_bench

        path = _option(config, "plant")
        config.stash[_PLANT] = PlantConfig.from_toml(path) if path else paper_bench()
    return config.stash[_PLANT]


def _budgets(config):
    """The budgets in force (--hil-budgets over the defaults), read once per session."""
    if _BUDGETS not in config.stash:
        from .verdicts.budgets import Budgets

        path = _option(config, "budgets")
        config.stash[_BUDGETS] = Budgets.from_toml(path) if path else Budgets.defaults()
    return config.stash[_BUDGETS]


def hil_settings(**overrides):
    """The HIL hypothesis profile (no deadline: a plant run is slow and its time says nothing;
    examples saved in the report directory's database), with per-test overrides."""
    from hypothesis import settings

    return settings(settings.get_profile("hil"), **overrides)


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "requirement(*ids): ties the test to requirement IDs (traceability matrix in the HIL report)"
    )
    config.addinivalue_line(
        "markers", "processor: the test measures the part a firmware runs on (pil:); its link's core and interrupt "
        "figures go into the report's processor section",
    )
    config.addinivalue_line(
        "markers", "dut_protocol(name): the test is a probe of that protocol only (canopen, modbus, sil: a firmware's "
        "dictionary, sil: and pil: alike); it is "
        "not collected for a DUT that speaks another",
    )
    report_dir = _option(config, "report_dir")
    if _explicit(config):
        _check_configuration(config, report_dir)
    # hypothesis is loaded by its own pytest plugin already: registering the profile costs nothing
    from hypothesis import HealthCheck, Phase, settings
    from hypothesis.database import DirectoryBasedExampleDatabase

    database = DirectoryBasedExampleDatabase(str(Path(report_dir) / "hypothesis-db")) if report_dir else None
    # no shrinking: each example is a closed-loop plant run, and a failing one is saved whole as a
    # replayable stimulus anyway (hil replay)
    settings.register_profile(
        "hil",
        deadline=None,
        print_blob=True,
        database=database,
        phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.target],
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
    )
    if not hasattr(config, "workerinput"):  # under xdist only the controlling process writes
        # without a report directory the reporter only keeps the records, for the history, until the
        # session is known to use the plugin (it then loads what it needs)
        config.pluginmanager.register(HilReporter(config, Path(report_dir) if report_dir else None), "hil-reporter")


def _history(config):
    """The run's results history (hil.history.hook; docs/history.md): ``--hil-history`` over
    ``HIL_HISTORY`` over the ini key ``hil_history`` (a path in it relative to the ini file)."""
    import os

    from .history.hook import RunHistory
    from .history.location import HISTORY_ENV, OFF

    setting = config.getoption("--hil-history")
    if not setting and not os.environ.get(HISTORY_ENV):
        setting = config.getini("hil_history").strip() or None
        if setting and "://" not in setting and setting.lower() not in OFF and config.inipath is not None:
            setting = str(config.inipath.parent / setting)
    return RunHistory(setting, config.getoption("--hil-station") or config.getini("hil_station").strip() or None)


def _check_configuration(config, report_dir) -> None:
    """A configured run: a bad --hil-dut, plant or budgets file, or -n against a real controller,
    is a usage error before anything runs."""
    controller = not hasattr(config, "workerinput")
    if report_dir and controller:
        ReportWriter.clear(Path(report_dir))  # a run refused below must not leave the last run's verdict behind
    specs = dut_specs(config)
    workers = config.getoption("numprocesses", None)
    # a firmware in the loop is opened once per worker too, each in its own process, like a virtual controller
    real = [s.text for s in specs if not s.local]
    if controller and workers and real:
        raise pytest.UsageError(
            f"hil: -n {workers} would open the controller {real[0]} once per xdist worker; "
            "a real controller serves one session: run without -n"
        )
    from bldc.params import ConfigError

    try:
        _plant_config(config)
        _budgets(config)
    except ConfigError as exc:
        raise pytest.UsageError(f"hil: {exc}") from None


def _plant_label(config) -> str:
    """The plant file as the user knows it (relative to where pytest started, when it is below)."""
    path = _option(config, "plant")
    if path is None:
        return "paper-bench (preset)"
    start = config.invocation_params.dir
    return str(path.relative_to(start)) if path.is_relative_to(start) else str(path)


def _header(config) -> str:
    specs = ", ".join(s.text for s in dut_specs(config))
    return f"hil: dut={specs} plant={_plant_label(config)} seed={_option(config, 'seed')}"


def pytest_report_header(config):
    if _explicit(config):
        return _header(config)
    return None


def pytest_report_collectionfinish(config, items):
    """The header of a run that uses the plugin without configuring it (printed after collection,
    once it is known that a test uses it)."""
    if (
        not _explicit(config)
        and not config.option.no_header
        and config.get_verbosity() >= 0
        and any(map(_uses_plugin, items))
    ):
        return _header(config)
    return None


@pytest.hookimpl(wrapper=True)
def pytest_runtestloop(session):
    """Under ``hil acceptance`` on a cold cache (a worker, or the one process): wait for the numba
    code it compiles ahead while pytest starts (hil/compile_ahead.py), then load all of it from the
    cache before the first test, so no test meets a load (or a compile) while a link's reply is
    timed. A session none of whose tests uses the plugin waits for nothing and loads nothing."""
    if "HIL_COMPILE_LOCK" in __import__("os").environ and any(map(_uses_plugin, session.items)):
        from .compile_ahead import load_compiled, wait_for_compile_ahead

        wait_for_compile_ahead()
        load_compiled()
    return (yield)


def pytest_generate_tests(metafunc):
    if "hil_dut_spec" in metafunc.fixturenames:
        specs = dut_specs(metafunc.config)
        metafunc.parametrize("hil_dut_spec", specs, ids=[s.id for s in specs], scope="session")


def _in_hypothesis_example() -> bool:
    """True inside a hypothesis example (``@given``), where a miss must raise at once."""
    control = sys.modules.get("hypothesis.control")
    return control is not None and control.currently_in_test_context()


def _missed_budgets(item) -> list:
    """The budgets ``hil_budget`` recorded as missed on ``item`` (its ``budget:`` properties, the
    record the report reads too)."""
    recorded = [Verdict.from_dict(json.loads(v)) for k, v in item.user_properties if str(k).startswith("budget:")]
    return [m for m in recorded if m.verdict == Status.FAIL]


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    """A test whose body returned after ``hil_budget`` recorded misses fails with all of them (a
    body that raised fails with its own exception; the misses are in the report either way)."""
    result = yield
    missed = _missed_budgets(item)
    if missed:
        from .verdicts.budgets import BudgetsExceeded

        raise BudgetsExceeded(missed)
    return result


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    """Outermost, so it sees pytest's xfail handling: a setup or teardown that raised under an
    xfail mark is an error (the test never judged the controller), and a skip raised while a
    controller link error was being handled is an error too (an unreachable controller is not
    "not applicable"). docs/acceptance.md, Verdicts."""
    rep = yield
    exc = call.excinfo.value if call.excinfo is not None else None
    if exc is None or not (_explicit(item.config) or _uses_plugin(item)):
        return rep
    if rep.failed and call.when == "call":
        # a judged figure that missed its bound (an assertion, a budget, pytest.fail) or a test
        # that could not judge (any other exception): only the first is evidence against the DUT
        kind = failure_kind(exc)
        rep.user_properties.append((PROPERTY_PREFIX + "failed_by", kind.value))  # plain data: xdist sends it
        if not hasattr(rep, "wasxfail"):
            _apply_waiver(item, rep, kind)
    if (
        rep.skipped
        and hasattr(rep, "wasxfail")
        and call.when != "call"
        and not isinstance(exc, (pytest.xfail.Exception, pytest.skip.Exception))
    ):
        rep.outcome = "failed"
        del rep.wasxfail
        rep.sections.append(("hil", f"{call.when} raised under an xfail mark: an error, not a known failure"))
    elif (
        rep.skipped
        and not hasattr(rep, "wasxfail")
        and isinstance(exc, pytest.skip.Exception)
        and (hidden := _unreachable(exc))
    ):
        reason = getattr(exc, "msg", "") or str(exc)
        rep.outcome = "failed"
        rep.longrepr = (
            f"skipped ({reason}) while the controller could not be reached: an error, not a skip\n"
            f"{type(hidden).__name__}: {hidden}"
        )
        rep.user_properties.append((PROPERTY_PREFIX + "unreachable", f"{type(hidden).__name__}: {hidden}"))
    return rep


def _apply_waiver(item, rep, kind: FailedBy) -> None:
    """A failure that a waiver in the budgets covers under every requirement the test traces to
    (under every requirement whose budget it missed, when it missed only budgets) becomes a skip
    whose reason is the waiver (pytest's exit status, its own JUnit and the HIL report then agree);
    the failure itself travels on to the HIL report, which shows it beside the waiver. Docs:
    docs/budgets.md, Waivers."""
    if kind == FailedBy.BUDGET:
        rids = {v.requirement for v in _missed_budgets(item)}
    else:
        rids = {str(v) for k, v in item.user_properties if k == "requirement"}
    if not rids:  # a waiver covers a test under the requirements it traces to: none, no waiver
        return
    waiver = test_waiver(_budgets(item.config).waivers, rids, item.nodeid)
    if waiver is None:
        return
    message, details = _failure_text(rep)
    rep.user_properties.append((PROPERTY_PREFIX + "waived_failure", {"message": message, "details": details}))
    path, line, _ = item.reportinfo()
    rep.outcome = "skipped"
    rep.longrepr = (str(path), (line or 0) + 1, f"WAIVED ({waiver.requirement}, owner {waiver.owner}): {waiver.reason}")


def failure_kind(exc: BaseException) -> FailedBy:
    """"budget" when only budgets were missed (``hil_budget``: each requirement the test traces to
    then has the verdict of its own budgets); "assertion" for any other assertion, pytest.fail, or
    a group of only those (a search that found several failures); "device failure" when the
    controller signalled its own failure on valid input (hil.verdicts.judging: a Modbus exception 04, an
    SDO abort 0x08000000 or 0x06060000); "not judged" for a setup check that found the scenario
    did not provoke what the test judges (hil.verdicts.judging.NotJudged); "error" for anything else."""
    from .verdicts.budgets import BudgetExceeded, BudgetsExceeded
    from .verdicts.judging import NotJudged, device_failure

    judged = (AssertionError, pytest.fail.Exception)
    budgets = (BudgetExceeded, BudgetsExceeded)
    if isinstance(exc, BaseExceptionGroup):
        if exc.split(budgets)[1] is None:
            return FailedBy.BUDGET
        if exc.split(judged)[1] is None:
            return FailedBy.ASSERTION
        return FailedBy.NOT_JUDGED if exc.split(NotJudged)[1] is None else FailedBy.ERROR
    if isinstance(exc, budgets):
        return FailedBy.BUDGET
    if isinstance(exc, judged):
        return FailedBy.ASSERTION
    if isinstance(exc, NotJudged):
        return FailedBy.NOT_JUDGED
    return FailedBy.DEVICE_FAILURE if device_failure(exc) else FailedBy.ERROR


def _unreachable(exc: BaseException):
    """The controller link, connection, CAN or serial error a skip was raised while handling, if any
    (not any OSError: a skip because an optional file is missing is a real "not applicable")."""
    # an exception of a library's type exists only if that library was imported: look, do not import
    unreachable = (
        ConnectionError,
        TimeoutError,
        *(
            getattr(sys.modules[m], name)
            for m, name in (("hil.dut.link", "LinkError"), ("can", "CanError"), ("serial", "SerialException"))
            if m in sys.modules
        ),
    )
    seen, cause = set(), exc.__cause__ or exc.__context__
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, unreachable):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return None


def traced_requirements(item) -> set[str]:
    """The requirements a collected test is traced to before it runs: its ``requirement`` marks
    (a parameter's included) and the requirement IDs among its parameters."""
    rids = {str(rid) for mark in item.iter_markers("requirement") for rid in mark.args}
    params = getattr(getattr(item, "callspec", None), "params", {})
    return rids | {v for v in params.values() if isinstance(v, str) and v.startswith("REQ-")}


def _protocol_applies(item) -> bool:
    """False for a ``dut_protocol`` probe parametrized with a DUT that speaks another protocol: a
    Modbus exception probe sent to a CANopen node is not a test that could pass or fail, so it is
    not collected (pytest counts it as deselected) rather than listed as a skip in the matrix."""
    mark = item.get_closest_marker("dut_protocol")
    spec = getattr(getattr(item, "callspec", None), "params", {}).get("hil_dut_spec")
    return mark is None or spec is None or spec.protocol == mark.args[0]


def _requirement_ids(config, option: str) -> set[str] | None:
    text = config.getoption(option, None)
    return {w.strip() for w in text.split(",") if w.strip()} if text else None


def pytest_collection_modifyitems(config, items):
    wanted = _requirement_ids(config, "--hil-requirements")
    keep, drop = [], []
    for item in items:
        applies = _protocol_applies(item) and (wanted is None or traced_requirements(item) & wanted)
        (keep if applies else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep
    first = _requirement_ids(config, "--hil-first")
    if first:  # a stable sort: the named requirements' tests ahead, each group in the suite's order
        items.sort(key=lambda item: not traced_requirements(item) & first)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    if not (_explicit(item.config) or _uses_plugin(item)):
        return
    for mark in item.iter_markers("requirement"):
        for rid in mark.args:
            item.user_properties.append(("requirement", str(rid)))
    doc = getattr(getattr(item, "obj", None), "__doc__", None)
    if doc:
        item.user_properties.append((PROPERTY_PREFIX + "doc", " ".join(doc.split())))


# --- fixtures -------------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def hil_seed(pytestconfig) -> int:
    """Base seed for everything random in a HIL run (recorded in reports)."""
    return _option(pytestconfig, "seed")


@pytest.fixture(scope="session")
def hil_plant_config(pytestconfig):
    """The nominal plant: --hil-plant TOML if given, else the paper-bench preset."""
    return _plant_config(pytestconfig)


@pytest.fixture
def hil_simulation(hil_plant_config, hil_seed):
    """Factory: ``hil_simulation(source, effects=(...), **kwargs)`` -> a ready plant Simulation."""
    from plant_models import Simulation

    def make(source=None, effects=(), **kwargs):
        kwargs.setdefault("seed", hil_seed)
        return Simulation(hil_plant_config.with_effects(*effects), source, **kwargs)

    return make


@pytest.fixture
def hil_kinematic(hil_plant_config, hil_seed):
    """Factory: ``hil_kinematic(profile, effects=(...))`` -> EdgeLog of the edge-only mode."""
    from plant_models.kinematic import simulate_edges

    def make(profile, effects=(), seed=None):
        return simulate_edges(hil_plant_config.with_effects(*effects), profile, seed=hil_seed if seed is None else seed)

    return make


def _seeded_defect(spec, motor, config):
    """The built-in controller with the firmware defect ``--hil-defect`` names, or None (no defect)."""
    name = config.getoption("--hil-defect")
    if name is None:
        return None
    from .qualify.defects import CATALOGUE, load_defects

    if config.getoption("--hil-defects"):
        try:
            load_defects(config.getoption("--hil-defects"))
        except (OSError, ValueError, TypeError) as exc:
            raise pytest.UsageError(f"hil: --hil-defects: {exc}") from None
    if name not in CATALOGUE:
        raise pytest.UsageError(f"hil: --hil-defect {name!r} is not a known defect ({', '.join(CATALOGUE)})")
    if not spec.is_virtual:
        raise pytest.UsageError(f"hil: --hil-defect seeds the built-in controller; {spec.text} is not virtual")
    return CATALOGUE[name].controller(motor)


@pytest.fixture(scope="session")
def hil_dut(hil_dut_spec, hil_plant_config, pytestconfig):
    """The controller under test, opened once per session and DUT spec (``virtual``: the built-in
    controller, served over its protocol in this process; each xdist worker has its own)."""
    from .dut.link import LinkError
    from .dut.spec import open_dut

    controller = _seeded_defect(hil_dut_spec, hil_plant_config.motor, pytestconfig)
    try:  # a controller that cannot be reached ends the session in one line, not one error per test
        dut = open_dut(hil_dut_spec, hil_plant_config.motor, controller=controller)
    except LinkError as exc:
        pytest.exit(f"hil: {exc}", returncode=3)
    try:
        dut.identity = dut.link.identity()
        from .history.record import dut_build

        # the firmware build's content hash and the profile's, for the results history
        dut.build = {"spec": hil_dut_spec.text, **dut_build(dut.link)}
        if controller is not None:  # the report names the seeded defect beside the identity
            dut.identity["seeded defect"] = pytestconfig.getoption("--hil-defect")
    except LinkError as exc:
        dut.close()
        pytest.exit(f"hil: {exc}", returncode=3)
    except Exception:
        dut.close()
        raise
    yield dut
    dut.close()


@pytest.fixture
def hil_link(hil_dut, request):
    """The controller link, reset for this test (faults cleared, control logic restarted). A test
    whose requirements need what the DUT's device profile lacks is skipped as "not testable with
    this profile" (the report's verdict, never a pass)."""
    request.node.user_properties.append(
        (PROPERTY_PREFIX + "dut", {"id": hil_dut.spec.id, "identity": hil_dut.identity,
                                   "build": getattr(hil_dut, "build", {})})
    )
    _require_applicable(request.node, hil_dut.spec.kind)
    _require_testable(request.node, hil_dut.link)
    hil_dut.link.reset()
    before = _traffic(hil_dut.link)
    yield hil_dut.link
    if request.node.get_closest_marker("processor") is not None and hasattr(hil_dut.link, "processor"):
        # what the emulated core and the interrupt schedule measured (pil:): the report's processor section
        figures = hil_dut.link.processor()
        if figures is not None:
            request.node.user_properties.append((PROPERTY_PREFIX + "processor", figures))
    if before is not None:  # what this test's edges moved on the link, summed per DUT in the report
        from .dut.traffic import traffic_delta

        request.node.user_properties.append(
            (PROPERTY_PREFIX + "traffic", traffic_delta(_traffic(hil_dut.link), before))
        )


def _traffic(link) -> dict | None:
    """The link's traffic counts so far (``hil.dut.traffic``), or None for a link without a bus."""
    traffic = getattr(link, "traffic", None)
    return traffic.as_dict() if traffic is not None else None


def _require_applicable(item, kind: str) -> None:
    """Skip ``item`` when none of its requirements applies to a DUT of ``kind`` (a requirement of
    the part, REQ-PIL-*, on anything but ``pil:``): "not applicable" in the report, never a pass.
    When only some do not apply, the test runs for the others."""
    from .verdicts.requirements import not_applicable

    rids = traced_requirements(item)
    lacking = not_applicable(rids, kind)
    if lacking:
        reason = f"not applicable to a {kind} DUT: {', '.join(lacking)} judge the part a firmware runs on (pil:)"
        item.user_properties.append((PROPERTY_PREFIX + "not_applicable", {"reason": reason, "requirements": lacking}))
        if set(lacking) >= rids:
            pytest.skip(reason)


def _require_testable(item, link) -> None:
    """Skip ``item`` when the link's profile lacks a role, the edge hook or the fault source every
    one of its requirements needs (hil.verdicts.requirements); a link without a profile has everything. When
    only some lack it, the test runs and judges the others (``item.hil_not_testable`` names the
    lacking ones, which the report lists as not testable)."""
    item.hil_not_testable = set()
    profile = getattr(link, "profile", None)
    if profile is None:
        return
    from .dut.link import edge_hook_kind
    from .verdicts.requirements import missing_needs

    rids = {str(v) for k, v in item.user_properties if k == "requirement"}
    for mark in item.iter_markers("requirement"):
        rids |= {str(a) for a in mark.args}
    params = getattr(getattr(item, "callspec", None), "params", {})
    rids |= {v for v in params.values() if isinstance(v, str) and v.startswith("REQ-")}
    hook = edge_hook_kind(link)
    missing = missing_needs(rids, profile.has, hook, profile.fault_sources)
    if missing:
        reason = f"not testable with the profile {profile.path}: it lacks {', '.join(missing)}"
        # the requirements the profile cannot show; the test's others are merely not tested by it
        lacking = sorted(r for r in rids if missing_needs([r], profile.has, hook, profile.fault_sources))
        item.user_properties.append((PROPERTY_PREFIX + "not_testable", {"reason": reason, "requirements": lacking}))
        item.hil_not_testable = set(lacking)
        if not rids or set(lacking) >= rids:
            pytest.skip(reason)


@pytest.fixture
def hil_bench(hil_link, hil_plant_config, hil_seed):
    """Factory: ``hil_bench(strategy, corrections=None, effects=(), speed_rpm=6000, filter_settings=None)``
    -> a LockstepBench of the plant (with ``effects`` injected) and the controller, configured through the link."""
    return bench_factory(hil_link, hil_plant_config, hil_seed)


def bench_factory(hil_link, hil_plant_config, hil_seed):
    """``hil_bench``'s factory for any link: a back-to-back check runs the reference implementation
    (``reference_link``) on benches made exactly as the controller's are."""
    from bldc.contract import Strategy
    from bldc.motor import steady_state

    from .bench.lockstep import acceptance_max_step_s, make_bench
    from .dut.link import link_has
    from .verdicts.progress import note
    from .verdicts.requirements import CALIBRATION

    benches = 0

    def make(
        strategy,
        corrections=None,
        effects=(),
        speed_rpm: float = 6000.0,
        filter_settings=None,
        seed: int | None = None,
        config=None,
    ):
        nonlocal benches
        config = (config or hil_plant_config).with_effects(*effects)
        # a controller without the calibration roles or the strategy role is judged with its own
        # calibration and strategy: nothing downloaded, nothing set (hil.verdicts.requirements, ``uses``)
        download = corrections is not None and link_has(hil_link, *CALIBRATION)
        set_strategy = link_has(hil_link, "strategy")
        note(
            f"lockstep bench: "
            f"{Strategy(int(strategy)).name.lower().replace('_', '-') if set_strategy else 'its own'} commutation "
            f"from {speed_rpm:.0f} rpm{', calibration downloaded' if download else ''}, effects: "
            f"{', '.join(e.name for e in effects) or 'none'}"
        )
        if benches:  # hil_link reset the controller for the first bench; each later one starts from a reset too
            hil_link.reset()
        benches += 1
        if filter_settings is not None:
            hil_link.set_filter_settings(filter_settings)
        if download:
            hil_link.download_calibration(corrections)
        if set_strategy:
            hil_link.set_strategy(int(strategy))
        # plant steps of at most 2 us: the armature reaction follows the instantaneous current, which
        # moves fast right after a commutation; a coarser step would blur it (docs/acceptance.md)
        return make_bench(
            config,
            hil_link,
            initial_speed_rpm=speed_rpm,
            duty=steady_state(config.motor, speed_rpm)["duty"],
            seed=hil_seed if seed is None else seed,
            sim_options={"max_step_s": acceptance_max_step_s(config)},
        )

    return make


def reference_link(motor):
    """The reference implementation of the paper's method for a back-to-back check: the built-in
    controller as shipped, in-process (hil.verdicts.requirements.JUDGEMENTS)."""
    from .controller.virtual import VirtualController
    from .dut.in_process import InProcessLink

    return InProcessLink(VirtualController(motor))


def declares_the_papers_method(link) -> bool:
    """Whether the controller declares the paper's method: its profile's strategy role offers the
    Sage-Husa predictor (a link without a profile, the built-in controller in-process, is it)."""
    profile = getattr(link, "profile", None)
    if profile is None:
        return True
    strategy = profile.get("strategy")
    return strategy is not None and "sage_husa" in (strategy.values or {})


@pytest.fixture(scope="session")
def hil_budgets(pytestconfig):
    """The accuracy budgets: --hil-budgets TOML over the built-in defaults."""
    return _budgets(pytestconfig)


@pytest.fixture
def hil_budget(hil_budgets, request):
    """``hil_budget(name, measured[, scenario])``: check a measurement against its budget (``scenario``:
    the budget's derivation for the test's scenario, ``Budgets.check``), record the verdict (report
    and JUnit property), and fail the test on a fail with a message naming the budget."""

    def check(name: str, measured: float, scenario=None):
        return _record_verdict(request.node, hil_budgets.check(name, measured, scenario))

    return check


def _record_verdict(node, v):
    """Record a budget's or a judged check's verdict on the test ``node`` (its report record and
    JUnit properties); a miss fails the test once its body has returned (``pytest_runtest_call``)."""
    from .verdicts.budgets import BudgetExceeded

    # plain JUnit properties, so pytest's own --junitxml carries them to CI systems too
    props = node.user_properties
    if ("requirement", v.requirement) not in props:
        # tied to the test by this budget alone: the test's other checks are not its evidence
        props.append((PROPERTY_PREFIX + "budget_only", v.requirement))
    props.append((f"budget:{v.budget}", json.dumps(v.as_dict())))
    props.append(("requirement", v.requirement))
    if v.verdict == "fail":
        if _in_hypothesis_example():
            raise BudgetExceeded(v)  # hypothesis finds and shrinks a failing example by its exception
        # the test goes on, so each requirement it traces to is judged by its own budgets and
        # checks; pytest_runtest_call fails it with every missed budget once the body returns
    return v


@pytest.fixture
def hil_judge(request):
    """``hil_judge(name, measured, bound)``: a judged check of the requirement registry
    (``hil.verdicts.requirements.JudgedCheck``: back-to-back against the reference, or physics) whose bound
    the test computed by the check's stated rule; recorded and failing as a missed budget does, and
    named by its judgement in the report and in ``hil qualify``."""

    def judge(name: str, measured: float, bound: float):
        from .verdicts.budgets import judged
        from .verdicts.requirements import JUDGED_CHECKS

        return _record_verdict(request.node, judged(JUDGED_CHECKS[name], measured, bound))

    return judge


class Evidence:
    """What a test attaches to its record in the report."""

    def __init__(self, node, figure_dir: Path, report_dir: Path | None):
        self._node, self._figure_dir, self._report_dir = node, figure_dir, report_dir

    def _add(self, item: dict) -> None:
        self._node.user_properties.append((PROPERTY_PREFIX + "evidence", item))

    def value(self, name: str, value, unit: str = "") -> None:
        self._add(
            {
                "kind": "value",
                "name": name,
                "value": float(value) if isinstance(value, (int, float)) else str(value),
                "unit": unit,
            }
        )

    def table(self, name: str, columns, rows) -> None:
        self._add(
            {
                "kind": "table",
                "name": name,
                "columns": [str(c) for c in columns],
                "rows": [[v if isinstance(v, (int, float, str)) else str(v) for v in row] for row in rows],
            }
        )

    def text(self, name: str, text: str) -> None:
        self._add({"kind": "text", "name": name, "text": str(text)})

    def figure(self, name: str, fig) -> Path:
        """Save a matplotlib figure as PNG (embedded in the HTML report) and attach it."""
        from .verdicts.plots import save

        path = save(fig, self._figure_dir / figure_file_name(self._node.nodeid, name), dpi=90)
        rel = path.relative_to(self._report_dir).as_posix() if self._report_dir else str(path)
        self._add({"kind": "figure", "name": name, "path": rel})
        return path


def figure_file_name(nodeid: str, name: str) -> str:
    """A figure's file name that reads from its start (test function, parameters, figure name;
    shortened at the end, never at the front) and is unique (a hash of node id and name)."""
    import hashlib

    func = nodeid.rpartition("::")[2].removeprefix("test_")
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{func}-{name}").strip("_")[:150]
    return f"{slug}-{hashlib.sha1(f'{nodeid}|{name}'.encode()).hexdigest()[:8]}.png"


@pytest.fixture
def hil_evidence(request, tmp_path):
    """Attach evidence to the current test: ``.value(name, v, unit)``, ``.table(name, columns, rows)``,
    ``.text(name, text)``, ``.figure(name, matplotlib_figure)``."""
    report_dir = _option(request.config, "report_dir")
    if report_dir:
        report_dir = Path(report_dir).resolve()
        return Evidence(request.node, report_dir / "figures", report_dir)
    return Evidence(request.node, tmp_path, None)


# --- reports --------------------------------------------------------------------------------------
class HilReporter:
    """Collects phase reports into one record per test and hands it to the ReportWriter; at the end
    the run is recorded in the results history (hil.history). Without a report directory nothing is
    written but the history, and only for a session that used the plugin."""

    def __init__(self, config, directory: Path | None):
        self.config = config
        self.directory = directory
        self.pending: dict[str, list] = {}
        self.history = _history(config)  #: standard library only until the run ends
        self.records: list[TestRecord] = []  #: without a report directory: the records, until the end
        self.collected: set[str] = set()
        self.used = False
        self.writer = self._writer() if directory is not None else None
        if self.writer is not None:
            self.writer.render()  # an empty report exists from the start

    def _writer(self) -> ReportWriter:
        budgets = _budgets(self.config)
        return ReportWriter(
            self.directory,
            session=self._session_info(budgets),
            requirements=budgets.requirement_titles(),
            waivers=budgets.waivers,
        )

    def _session_info(self, budgets) -> dict:
        from importlib import metadata

        config = self.config
        plant = _plant_config(config)
        versions = {"python": platform.python_version()}
        for name in VERSIONED:
            try:
                versions[name] = metadata.version(name)
            except metadata.PackageNotFoundError:
                pass
        info = {
            "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "command": _command(),
            "host": platform.node(),
            "dut": ", ".join(s.text for s in dut_specs(config)),
            "plant": _plant_label(config),
            "plant_sha256": plant.config_hash(),
            "budgets": budgets.source,
            "seed": _option(config, "seed"),
            "hypothesis_seed": config.getoption("hypothesis_seed", None),
            "xdist_workers": getattr(config.option, "numprocesses", None),
            "versions": versions,
            **self.history.session_info(),
        }
        if budgets.source != "defaults":
            info["budgets_sha256"] = file_sha256(budgets.source)
        return info

    def _add(self, record: dict) -> None:
        if self.writer is not None:
            self.writer.add(record)
        else:
            self.records.append(record)

    def pytest_collection_finish(self, session):
        self.session = session
        self.used = self.used or _explicit(self.config) or any(map(_uses_plugin, session.items))
        self.collected |= {item.nodeid for item in session.items}
        if self.writer is not None:
            self.writer.expect(item.nodeid for item in session.items)

    @pytest.hookimpl(optionalhook=True)
    def pytest_xdist_node_collection_finished(self, node, ids):
        self.collected |= set(ids)
        if self.writer is not None:
            self.writer.expect(ids)

    def pytest_runtest_logreport(self, report):
        self.pending.setdefault(report.nodeid, []).append(report)
        if report.when == "teardown" or report.when not in ("setup", "call"):
            record = self._record(report.nodeid, self.pending.pop(report.nodeid))
            self._add(record)
            self._stop_at_catch(record)

    def _stop_at_catch(self, record: dict) -> None:
        """With --hil-stop-at-catch: end the session after a test whose failure is a catch (pytest's
        -x would also stop at a setup check or at a check that counts for nothing, and the defect's
        real catch, later in the suite, would never run)."""
        session = getattr(self, "session", None)
        if session is None or record.outcome not in (Outcome.FAILED, Outcome.ERROR):
            return
        if not self.config.getoption("--hil-stop-at-catch", False):
            return
        from .qualify.run import CATCH_KINDS, what_caught

        caught_by, requirements, _, _ = what_caught({"tests": [record.to_json()]})
        if caught_by in CATCH_KINDS:
            session.shouldstop = f"--hil-stop-at-catch: {record.nodeid} caught it ({', '.join(requirements)})"

    def pytest_sessionfinish(self, session, exitstatus):
        for nodeid, reports in list(self.pending.items()):  # a test whose teardown never came (a crashed worker)
            self._add(self._record(nodeid, reports))
        self.pending.clear()
        if self.writer is None:
            # under xdist the controller collects nothing: a test that used the plugin left its trace
            traced = any(r.requirements or r.measurements or r.dut for r in self.records)
            if not (self.used or traced) or self.history.url is None:
                return
            self.writer = self._writer()
            self.writer.expect(self.collected)
            for record in self.records:
                self.writer.add(record)
        # the trends and regressions go into the last rendering of the report; the run is recorded after it
        self.writer.history = self.history.look_back(self.writer.content())
        self.writer.finish(
            {
                "finished": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
                "exit_status": int(exitstatus),
            }
        )
        self.history.record(self.writer.content(), self.directory)

    def pytest_terminal_summary(self, terminalreporter):
        if self.writer is None:
            return
        if self.directory is not None:
            content = self.writer.content()
            terminalreporter.write_sep("-", f"HIL verdict {content['verdict']}: {self.writer.paths['html']}")
            for reason in content["verdict_reasons"]:
                terminalreporter.write_line(f"  {reason}")
            for w in content["waivers"]:
                unused = "" if w["tests_waived"] else " [waives nothing in this run]"
                label = "OUT OF SCOPE" if w.get("kind") == "out of scope" else "WAIVED"
                terminalreporter.write_line(
                    f"  {label} {w['requirement']} (owner {w['owner']}): {w['reason']}{unused}")
        for line in self.history.summary_lines():
            terminalreporter.write_line(line)

    @staticmethod
    def _record(nodeid: str, reports: list) -> TestRecord:
        outcome, message, details, duration, xfail_reason = Outcome.PASSED, "", "", 0.0, ""
        failed_by = FailedBy.NOTHING
        props: list = []
        for r in reports:
            duration += getattr(r, "duration", 0.0)
            props = list(getattr(r, "user_properties", props)) or props
            own = dict((str(k), v) for k, v in getattr(r, "user_properties", ()))
            phase = None
            if hasattr(r, "wasxfail"):
                phase = Outcome.XFAILED if r.skipped else (Outcome.XPASSED if r.passed else None)
                xfail_reason = str(r.wasxfail).removeprefix("reason: ")
                message = message or xfail_reason
            if phase is None:
                if r.failed:
                    unreachable = PROPERTY_PREFIX + "unreachable" in own
                    # a setup check that found the scenario did not provoke what the test judges: no
                    # evidence either way (hil.verdicts.judging.not_judged)
                    unjudged = own.get(PROPERTY_PREFIX + "failed_by") == FailedBy.NOT_JUDGED
                    phase = Outcome.FAILED if r.when == "call" and not unreachable and not unjudged else Outcome.ERROR
                elif r.skipped:
                    phase = Outcome.SKIPPED
                else:
                    phase = Outcome.PASSED
            waived = own.get(PROPERTY_PREFIX + "waived_failure")
            if waived is not None:
                # a failure the plugin reported to pytest as a waived skip: the report keeps the failure
                phase = Outcome.FAILED
            if phase.worse_than(outcome):
                outcome = phase
                failing = phase in (Outcome.FAILED, Outcome.ERROR)
                failed_by = FailedBy(own.get(PROPERTY_PREFIX + "failed_by", FailedBy.ERROR if failing else ""))
                if waived is not None:
                    message, details = waived["message"], waived["details"]
                elif r.failed or r.skipped:
                    message, details = _failure_text(r)
        record = TestRecord(
            nodeid, outcome, round(duration, 3), message, details,
            worker=_worker_id(reports[-1]),
            xfail_reason=xfail_reason if outcome in (Outcome.XFAILED, Outcome.XPASSED) else "",
            failed_by=failed_by if outcome in (Outcome.FAILED, Outcome.ERROR) else FailedBy.NOTHING,
        )
        for key, value in props:
            key = str(key)
            if key == PROPERTY_PREFIX + "budget_only" and value not in record.budget_only:
                record.budget_only.append(value)
            elif key == "requirement" and value not in record.requirements:
                record.requirements.append(value)
            elif key.startswith("budget:"):
                record.measurements.append(Verdict.from_dict(json.loads(value)))
            if not key.startswith(PROPERTY_PREFIX):
                continue
            kind = key[len(PROPERTY_PREFIX) :]
            if kind == "evidence":
                record.evidence.append(value)
            elif kind == "dut":
                record.dut, record.dut_identity = value["id"], value["identity"]
                record.dut_build = value.get("build") or None
            elif kind == "doc":
                record.doc = value
            elif kind in ("traffic", "processor"):
                setattr(record, kind, value)
            elif kind in ("not_applicable", "not_testable"):
                # kept whatever the outcome: a test that ran for its other requirements judged
                # nothing of these (TestRecord.status), so its pass or failure is not theirs
                setattr(record, kind, Unanswerable.from_json(value))
        json.dumps(record.to_json())  # everything in a record is plain data
        return record


def _command() -> str:
    """The command that started this run: the ``hil`` command line when ``hil acceptance`` started
    it (``HIL_COMMAND``), else pytest's own (``python -m pytest`` for its ``__main__``)."""
    import os

    if os.environ.get("HIL_COMMAND"):
        return os.environ["HIL_COMMAND"]
    program = Path(sys.argv[0])
    head = f"python -m {program.parent.name}" if program.name == "__main__.py" else program.name
    return " ".join([head, *sys.argv[1:]])


def _worker_id(report) -> str:
    """The xdist worker that ran the test ("gw0", ...; xdist puts it on every report it forwards),
    or "" without xdist."""
    return getattr(report, "worker_id", "") or ""


def _failure_text(report) -> tuple[str, str]:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:  # a skip: (file, line, reason)
        return str(longrepr[2]).removeprefix("Skipped: "), ""
    crash = getattr(longrepr, "reprcrash", None)
    text = str(longrepr) if longrepr is not None else ""
    return (crash.message if crash is not None else (text.splitlines() or [""])[-1])[:2000], text[-20000:]
