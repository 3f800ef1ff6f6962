import os
import subprocess
import sys
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


@pytest.fixture(scope="session")
def default_acceptance(tmp_path_factory):
    """README's ``python -m hil acceptance`` (the acceptance suite, test_cases/, against the
    built-in controller over CANopen on pytest-xdist workers), run once a session from the
    repository: the completed process and its report directory. This is the test suite's one run
    of test_cases/ (tests/test_acceptance_run.py holds its verdict; tests/test_browser.py lays out
    and prints its report)."""
    reports = tmp_path_factory.mktemp("acceptance")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    run = subprocess.run([sys.executable, "-m", "hil", "acceptance", "-o", str(reports)],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=1800)
    assert (reports / "hil-report.json").is_file(), (
        f"hil acceptance wrote no report (exit {run.returncode}):\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    )
    return run, reports
