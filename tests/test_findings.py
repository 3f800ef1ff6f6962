"""Open defects found by the acceptance suite's property search, kept as replayable stimuli.

Each is a strict xfail: when the defect is fixed the test passes, the xfail turns into a
failure, and the acceptance search bounds (test_cases/test_fault_injection.py) can be widened.
"""

from pathlib import Path

import pytest

from hil.budgets import Budgets
from hil.dut import InProcessLink, VirtualController
from hil.stimulus import Stimulus, run

DATA = Path(__file__).parent / "data"


@pytest.mark.xfail(strict=True, reason="open defect: Hall edges chatter every plant step soon after start-up with large "
                                       "pole/installation offsets or rise/fall delays far apart; commutation is lost")
@pytest.mark.parametrize("name", ["finding-start-chatter.json", "finding-pole-offset-chatter.json", "finding-fault-sequence-recovery.json"])
def test_finding_replays_within_budget(name):
    stim = Stimulus.load(DATA / name)
    outcome = run(stim, InProcessLink(VirtualController(stim.plant_config().motor)), Budgets.defaults())
    assert outcome.ok, outcome.message
