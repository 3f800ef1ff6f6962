"""Shared pieces of the acceptance suite.

The suite never knows which controller it talks to (``hil_link`` / ``hil_bench``); the plant
knows the true rotor angle of every commutation, and every figure is scored against it.
"""

import pytest

from hil.calibration.campaign import station_corrections
from hil.progress import note


@pytest.fixture(scope="session")
def calibrate(hil_plant_config, hil_seed):
    """``calibrate(effects)``: the calibration station's tables for the plant with ``effects``
    (the paper's campaign, recorded with the reference encoder), cached per effect set."""
    cache = {}

    def run(effects=()):
        key = tuple(effects)
        if key not in cache:
            note(
                f"calibration campaign on the plant with {', '.join(e.name for e in effects) or 'no deviations'} "
                "(station recording, fit)"
            )
            cache[key] = station_corrections(hil_plant_config.with_effects(*effects), seed=hil_seed)
        return cache[key]

    return run


#: the suite's longest tests (REQ-PRED-002's 36 scenario runs, REQ-ROB-001's and REQ-ROB-002's
#: searches), run first: pytest-xdist's work stealing then fills the other workers around them,
#: where one started last would leave the run waiting on it alone
LONGEST_FIRST = ("test_sage_husa_is_no_worse_than_the_tuned_kf",
                 "test_any_calibrated_deviation_set_meets_the_commutation",
                 "test_fault_sequences_are_reported_and_recovered")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}

    def order(item):
        return next((k for name, k in rank.items() if item.name.startswith(name)), len(rank))

    items.sort(key=order)  # stable: the rest keep pytest's order
