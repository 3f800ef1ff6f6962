import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# Explicit profile: no deadlines (numba compiles on first call), derandomised so CI is repeatable;
# failing examples print their reproduction blob.
settings.register_profile(
    "hil-ci", deadline=None, derandomize=True, print_blob=True, max_examples=25,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("hil-ci")


#: the spindle capture the twin tests build their twin from (tests/test_twin.py, tests/test_saved_results.py)
SPINDLE = Path(__file__).parent / "data" / "real-hall" / "20260618-spindle-hw.vcd"


@pytest.fixture(scope="session")
def spindle_twin(tmp_path_factory):
    """The spindle capture's twin plant, as ``hil twin from-capture`` writes it (made once a session)."""
    from hil.cli import main

    out = tmp_path_factory.mktemp("twin") / "spindle.toml"
    assert main(["twin", "from-capture", str(SPINDLE), "-o", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def spindle_check(spindle_twin):
    """``twin_check`` of the spindle capture against its twin (run once a session), as its JSON."""
    from hil.twin.check import twin_check

    return twin_check(SPINDLE, spindle_twin, log=lambda m: None).to_json()


ROOT = Path(__file__).resolve().parent.parent


#: the directory the session's processes (the xdist controller and its workers) share: the default
#: acceptance run's claim, process id, report, output and exit code
RUN_DIR_ENV = "HIL_TEST_RUN_DIR"
#: the session's compile ahead (in the first process), closed when the session ends
_AHEAD = pytest.StashKey()
_ACCEPTANCE_TIMEOUT_S = 1800
#: the run in the background: its output, and its exit code once it has ended (written last)
_WRAPPER = ("import pathlib, subprocess, sys\n"
            "d = pathlib.Path(sys.argv[1])\n"
            "with open(d / 'stdout', 'w') as out, open(d / 'stderr', 'w') as err:\n"
            "    rc = subprocess.run(sys.argv[2:], stdout=out, stderr=err).returncode\n"
            "(d / 'rc.part').write_text(str(rc))\n"
            "(d / 'rc.part').rename(d / 'rc')\n")


def _is_worker(config) -> bool:
    return hasattr(config, "workerinput")


def pytest_configure(config):
    """In the session's first process (the xdist controller, or the one process): the run directory,
    and the numba code compiled once, ahead, in two processes (hil/compile_ahead.py), for every
    worker and for the default acceptance run; the workers (spawned later) inherit both. Every run
    the tests start is recorded in a results history of this session's own (docs/history.md), never
    in the user's or a team's."""
    if not _is_worker(config):
        os.environ["HIL_HISTORY"] = str(Path(tempfile.mkdtemp(prefix="hil-test-history-")) / "history.sqlite")
    if _is_worker(config) or config.option.collectonly:
        return
    from hil.compile_ahead import CompileAhead

    os.environ[RUN_DIR_ENV] = tempfile.mkdtemp(prefix="hil-test-run-")
    ahead = CompileAhead(dict(os.environ)).start()
    os.environ.update(ahead.env())
    config.stash[_AHEAD] = ahead


@pytest.hookimpl(wrapper=True)
def pytest_runtestloop(session):
    """Each worker waits for the compile ahead, then loads the compiled code, before its first test
    (the plugin does the same for a session that uses its fixtures; most of these tests drive the
    plant directly)."""
    from hil.compile_ahead import LOCK_ENV, load_compiled, wait_for_compile_ahead

    if os.environ.get(LOCK_ENV) and not session.config.option.collectonly:
        wait_for_compile_ahead()
        load_compiled()
    return (yield)


def pytest_unconfigure(config):
    """The session has ended (every worker too): a default acceptance run still going is stopped
    (the session stopped before it needed it), the compile ahead closed, the run directory gone."""
    if _is_worker(config):
        return
    folder = os.environ.pop(RUN_DIR_ENV, None)
    if folder:
        pid = Path(folder, "pid")
        if pid.exists() and not Path(folder, "rc").exists():
            try:
                os.killpg(int(pid.read_text()), signal.SIGKILL)
            except (ProcessLookupError, PermissionError, ValueError):
                pass
        shutil.rmtree(folder, ignore_errors=True)
    ahead = config.stash.get(_AHEAD, None)
    if ahead is not None:
        from hil.compile_ahead import LOCK_ENV

        os.environ.pop(LOCK_ENV, None)
        ahead.close()


def _run_dir() -> Path:
    folder = os.environ.get(RUN_DIR_ENV)
    if not folder:  # a process the controller's pytest_configure did not run in: a directory of its own
        folder = os.environ[RUN_DIR_ENV] = tempfile.mkdtemp(prefix="hil-test-run-")
    return Path(folder)


def _start_default_acceptance() -> None:
    """README's ``python -m hil acceptance``, started once per session, whichever worker claims it
    first (an atomic mkdir): each worker collects every test, and each started a run of its own."""
    folder = _run_dir()
    try:
        (folder / "claimed").mkdir()
    except FileExistsError:
        return
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    # in one process (-j 0): beside the session's own tests a second worker only doubles the
    # imports and the calibration campaign, it finds no idle core
    cmd = [sys.executable, "-m", "hil", "acceptance", "-j", "0", "-o", str(folder / "reports")]
    proc = subprocess.Popen([sys.executable, "-c", _WRAPPER, str(folder), *cmd], cwd=ROOT, env=env,
                            start_new_session=True, stdin=subprocess.DEVNULL)
    (folder / "pid").write_text(str(proc.pid))


def pytest_collection_modifyitems(session, config, items):
    """The tests of the default acceptance run go last, and the run starts now, beside the other
    tests: it keeps both cores busy where most of the suite keeps one (it ran alone, in series,
    before: a minute of the suite's ten)."""
    users = [item for item in items if "default_acceptance" in getattr(item, "fixturenames", ())]
    if not users:
        return
    items[:] = [item for item in items if item not in users] + users
    if not config.option.collectonly:
        _start_default_acceptance()


@pytest.fixture(scope="session")
def default_acceptance():
    """README's ``python -m hil acceptance`` (the acceptance suite, test_cases/, against the
    built-in controller over CANopen), run once a session from the repository, in one process and
    in the background from the end of collection: the completed process and its report directory.
    This is the test suite's one run of test_cases/ (tests/test_acceptance_run.py holds its
    verdict; tests/test_browser.py lays out and prints its report)."""
    _start_default_acceptance()  # collected by a plugin that bypassed the hook: start it here
    folder = _run_dir()
    deadline = time.monotonic() + _ACCEPTANCE_TIMEOUT_S
    while not (folder / "rc").exists():
        assert time.monotonic() < deadline, f"hil acceptance gave no exit code in {_ACCEPTANCE_TIMEOUT_S} s"
        time.sleep(0.5)
    text = {name: (folder / name).read_text() for name in ("stdout", "stderr")}
    run = subprocess.CompletedProcess(["python", "-m", "hil", "acceptance"], int((folder / "rc").read_text()),
                                      stdout=text["stdout"], stderr=text["stderr"])
    reports = folder / "reports"
    assert (reports / "hil-report.json").is_file(), (
        f"hil acceptance wrote no report (exit {run.returncode}):\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    )
    return run, reports
