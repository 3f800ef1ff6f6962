"""Shared pieces of the acceptance suite.

The suite never knows which controller it talks to (``hil_link`` / ``hil_bench``); the plant
knows the true rotor angle of every commutation, and every figure is scored against it.
"""

import pytest

from hil.calibration.campaign import station_corrections
from hil.verdicts.progress import note


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
