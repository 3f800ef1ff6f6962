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
