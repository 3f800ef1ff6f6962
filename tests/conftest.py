import os
import subprocess
import sys
import tempfile
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


#: README's ``python -m hil acceptance``, started in the background once the session has collected
#: a test that needs it (``pytest_collection_modifyitems``): the process and its report directory
_DEFAULT_ACCEPTANCE: dict = {}
_ACCEPTANCE_TIMEOUT_S = 1800


def _start_default_acceptance() -> None:
    reports = Path(tempfile.mkdtemp(prefix="hil-default-acceptance-"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    # files, not pipes: a pipe would fill and stall the run while nobody reads it
    out, err = tempfile.TemporaryFile(mode="w+"), tempfile.TemporaryFile(mode="w+")
    # in one process (-j 0): beside the session's own tests a second worker only doubles the
    # imports and the calibration campaign, it finds no idle core
    proc = subprocess.Popen([sys.executable, "-m", "hil", "acceptance", "-j", "0", "-o", str(reports)], cwd=ROOT,
                            env=env, stdout=out, stderr=err, text=True)
    _DEFAULT_ACCEPTANCE.update(proc=proc, reports=reports, out=out, err=err)


def pytest_collection_modifyitems(session, config, items):
    """The tests of the default acceptance run go last, and the run starts now, beside the other
    tests: it keeps both cores busy where most of the suite keeps one (it ran alone, in series,
    before: a minute of the suite's ten)."""
    users = [item for item in items if "default_acceptance" in getattr(item, "fixturenames", ())]
    if not users:
        return
    items[:] = [item for item in items if item not in users] + users
    if not _DEFAULT_ACCEPTANCE and not config.option.collectonly:
        _start_default_acceptance()


def pytest_sessionfinish(session, exitstatus):
    proc = _DEFAULT_ACCEPTANCE.get("proc")
    if proc is not None and proc.poll() is None:  # the session stopped before it needed the run
        proc.kill()
        proc.wait()


@pytest.fixture(scope="session")
def default_acceptance():
    """README's ``python -m hil acceptance`` (the acceptance suite, test_cases/, against the
    built-in controller over CANopen), run once a session from the repository, in one process and
    in the background from the end of collection: the completed process and its report directory.
    This is the test suite's one run of test_cases/ (tests/test_acceptance_run.py holds its
    verdict; tests/test_browser.py lays out and prints its report)."""
    if not _DEFAULT_ACCEPTANCE:  # collected by a plugin that bypassed the hook: start it here
        _start_default_acceptance()
    proc, reports = _DEFAULT_ACCEPTANCE["proc"], _DEFAULT_ACCEPTANCE["reports"]
    try:
        proc.wait(timeout=_ACCEPTANCE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    out, err = (_DEFAULT_ACCEPTANCE[k] for k in ("out", "err"))
    out.seek(0)
    err.seek(0)
    run = subprocess.CompletedProcess(proc.args, proc.returncode, stdout=out.read(), stderr=err.read())
    assert (reports / "hil-report.json").is_file(), (
        f"hil acceptance wrote no report (exit {run.returncode}):\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    )
    return run, reports
