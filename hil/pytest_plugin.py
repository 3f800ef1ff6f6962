"""pytest plugin (entry point ``pytest11: hil``): options and fixtures for HIL tests.

Options: ``--hil-plant`` (plant TOML; default: the paper-bench preset) and ``--hil-seed``;
both also readable as ini keys ``hil_plant`` / ``hil_seed`` (pytest.ini or pyproject.toml).
"""

from __future__ import annotations

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("hil", "BLDC pump controller HIL")
    group.addoption("--hil-plant", default=None, help="plant TOML (motor, circuit, effects); default: paper-bench preset")
    group.addoption("--hil-seed", type=int, default=None, help="base seed for plant randomness (default 0)")
    group.addoption("--hil-budgets", default=None, help="budgets TOML (named limits traced to requirements); default: built-in")
    parser.addini("hil_plant", "plant TOML used when --hil-plant is not given", default="")
    parser.addini("hil_budgets", "budgets TOML used when --hil-budgets is not given", default="")
    parser.addini("hil_seed", "base seed used when --hil-seed is not given", default="0")


def _option(config, name):
    value = config.getoption(f"--hil-{name}")
    if value is None or value == "":
        value = config.getini(f"hil_{name}") or None
    return value


def pytest_report_header(config):
    return f"hil: plant={_option(config, 'plant') or 'paper-bench (preset)'} seed={_option(config, 'seed')}"


@pytest.fixture(scope="session")
def hil_seed(pytestconfig) -> int:
    """Base seed for everything random in a HIL run (recorded in reports)."""
    return int(_option(pytestconfig, "seed") or 0)


@pytest.fixture(scope="session")
def hil_plant_config(pytestconfig):
    """The nominal plant: --hil-plant TOML if given, else the paper-bench preset."""
    from plant_models import PlantConfig, paper_bench

    path = _option(pytestconfig, "plant")
    return PlantConfig.from_toml(path) if path else paper_bench()


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


@pytest.fixture(scope="session")
def hil_budgets(pytestconfig):
    """The accuracy budgets: --hil-budgets TOML over the built-in defaults."""
    from hil.budgets import Budgets

    path = _option(pytestconfig, "budgets")
    return Budgets.from_toml(path) if path else Budgets.defaults()


@pytest.fixture
def hil_budget(hil_budgets, record_property):
    """``hil_budget(name, measured)``: check a measurement against its budget, record the verdict
    (a JUnit property ``budget:<name>`` and ``requirement``), and fail the test on a fail."""
    import json

    def check(name: str, measured: float):
        v = hil_budgets.check(name, measured)
        record_property(f"budget:{name}", json.dumps(v.as_dict()))
        record_property("requirement", v.requirement)
        if v.verdict == "fail":
            from hil.budgets import BudgetExceeded

            raise BudgetExceeded(v)
        return v

    return check
