"""Findings of the acceptance suite's property search, kept as replayable stimuli and regression tests.

The three ``finding-*.json`` stimuli came from the plant, not from the controller: Hall edges that
chattered every plant step soon after start-up (a leading armature shift acted as a negative
hysteresis band; a fresh angle-noise draw behind the rotor; independent delays per edge that
let a short pulse's end overtake its start), and an armature shift taken from the current at the
step start rather than at the edge. With the plant fixed they exposed three start-up and glitch
defects of the virtual controller (commutation from an unknown Hall state, a speed from one
uncorrected sector that the current limit turned into tens of amperes, a glitch interval taken
as the missing-edge reference). Each replay must now meet its budget.

The two ``finding-armature-current-*.json`` stimuli found a limit of the controller, not of the
plant: it corrected the armature lag with the current read at the capture interrupt, while the
lag was set by the current at the Hall switch, one conditioning delay earlier. With 1.5 deg e/A
and 16/30 us delays at 7000 rpm the two are about 1 A apart after a commutation (3.0 deg e p99
of commutation against 1); with 1.4 deg e/A, early sensors and 4.6/14.8 us at 10,000 rpm the
commutation falls on the Hall switch itself, where the current turns fastest (6.5 deg e). The
controller now reads the current at the edge's own instant from its own ADC window, one applied
conditioning delay before the capture (hil.controller.adc; the edge message carries the
conversions, bldc.contract.EdgeMessage).

``finding-uneven-sectors-read-as-lost-edges.json`` came from the search at 100 examples (it had run
8): installation offsets of +2.4/+1.8/-9.0 deg e, pole offsets to -4.8 deg e and 14/50 us delays,
calibrated exactly, at 7000 rpm. Two neighbouring sectors then differ by more than the ratio of
1.8 that told a lost edge, so every turn one sector read as a lost edge, the edge count moved by
one and every pole correction with it (16.5 deg e p99; one MISSING_EDGE, latched, so the later
false alarms were silent). The controller now compares a sector with the same sector one
mechanical turn earlier (VirtualController._reference_interval_s).
"""

from pathlib import Path

import pytest
from test_sensor_layer import assert_no_chatter

from bldc.motor import steady_state
from hil.verdicts.budgets import Budgets
from hil.controller.commutation import HallCommutation, SpeedPI
from hil.controller.virtual import VirtualController
from hil.dut.in_process import InProcessLink
from hil.dut.spec import open_dut
from hil.bench.stimulus import Stimulus, run
from plant_models import RawHallCommutation, Simulation

DATA = Path(__file__).parent / "data"
#: the findings whose cause was in the plant (its Hall edges chattered), then the controller's
PLANT_FINDINGS = [
    "finding-start-chatter.json",
    "finding-pole-offset-chatter.json",
    "finding-fault-sequence-recovery.json",
]
FINDINGS = PLANT_FINDINGS + [
    "finding-armature-current-at-capture.json",
    "finding-armature-current-at-commutation.json",
    "finding-uneven-sectors-read-as-lost-edges.json",
    # REQ-ROB-001's search at seed 1 (9.8 deg e p99) and at seed 0 once its draws changed (178 deg
    # e): at 10,000 rpm the start-up current's armature lag (2 deg e/A) outweighed the pole table
    # in the pole alignment, which took the wrong electrical period; and the plant's linear
    # armature lag, carried to 1000 deg e by a stalled commutation's 500 A, ran away (it
    # saturates at ARMATURE_SHIFT_LIMIT_DEG_E now)
    "finding-pole-alignment-under-startup-current.json",
    "finding-startup-armature-runaway.json",
    # REQ-ROB-001's search at seed 1 (12.6 deg e p99): a start-up edge 63 deg e late (32 A at 1.94 deg
    # e/A) left a first interval of a third of a sector as the lost-edge reference, and every later
    # sector read as two lost edges although the Hall code stepped one: the edge count ran three per
    # edge and the pole corrections went to the wrong poles. A one-sector Hall step now counts 1 + 6k
    # sectors, and the interval then replaces the reference (tests/test_controller_lost_edges.py)
    "finding-startup-interval-as-lost-edge-reference.json",
]
#: REQ-ROB-001's search through sil:firmware/reference (each the search's shrunk draw; reproduce with
#: ``hil replay FILE --dut sil:firmware/reference``), replayed on both controllers
FIRMWARE_FINDINGS = [
    # --hil-seed 2 (7.34 deg e p99): the start-up bounce guard measured the armature-corrected interval,
    # which 26 A at 1.9 deg e/A shortened below half a sector at the top set point; the commutation the
    # correction said was due waited for the next (late) edge, the current ran to 130 A and the pole
    # alignment learned in it took the wrong electrical period. The guard reads the captured interval
    "finding-firmware-startup-guard-on-corrected-interval.json",
    # --hil-seed 3 (6.13 deg e p99 once the guard was fixed): the pole alignment scored a turn with
    # edges at tens of amperes, far past the current limit, where the linear armature correction does
    # not hold. It waits for a turn within the limit (both controllers)
    "finding-firmware-pole-alignment-over-current-limit.json",
    # --hil-seed 1 (0.609 deg e p99 and a MISSING_EDGE at start-up): a start-up sector shortened by
    # 22 A of armature lag was the same-sector reference a turn later, and a normal sector read 1.4
    # times it as a lost edge (an interval with an edge beyond the current limit is no reference now,
    # both controllers); and the edge current read through a 13 us commutation transient at 10,000
    # rpm, 0.49 A high
    "finding-firmware-slow-sector-read-as-lost-edge.json",
]
FIRMWARE = Path(__file__).parent.parent / "firmware" / "reference"


@pytest.mark.parametrize("name", FINDINGS + FIRMWARE_FINDINGS)
def test_finding_replays_within_budget(name):
    stim = Stimulus.load(DATA / name)
    outcome = run(stim, InProcessLink(VirtualController(stim.plant_config().motor)), Budgets.defaults())
    assert outcome.ok, outcome.message


@pytest.mark.parametrize("name", FIRMWARE_FINDINGS)
def test_firmware_finding_replays_within_budget_without_a_fault_code(name):
    """Through the reference firmware: within the budget, and no fault code (nothing is injected in a
    deviation run: any code is a false alarm, REQ-FLT-005)."""
    stim = Stimulus.load(DATA / name)
    with open_dut(f"sil:{FIRMWARE}", stim.plant_config().motor) as dut:
        outcome = run(stim, dut.link, Budgets.defaults())
        codes = dut.link.faults()
    assert outcome.ok, outcome.message
    assert codes == [], [hex(c) for c in codes]


@pytest.mark.parametrize("name", [n for n in PLANT_FINDINGS if Stimulus.load(DATA / n).kind == "deviations"])
def test_finding_plant_does_not_chatter_under_raw_hall_commutation(name):
    """The finding's plant, driven by its own Hall sensors (no controller to blame)."""
    stim = Stimulus.load(DATA / name)
    config = stim.plant_config()
    sim = Simulation(config, RawHallCommutation(), duty=steady_state(config.motor, stim.speed_rpm)["duty"],
                     initial_speed_rpm=stim.speed_rpm, seed=stim.seed, max_step_s=2e-6)
    sim.run_until(0.05)
    assert_no_chatter(sim)


def test_first_commutation_follows_the_first_edge():
    """At start-up only the switching sensor's level is known; the Hall state after the edge
    follows from which edge it was (the pump turns forward), not from two assumed-low sensors."""
    from bldc.hall import SECTOR_OF_CODE, hall_code, hall_state

    for sensor, rising, angle in [
        (0, True, 0.0),
        (2, False, 60.0),
        (1, True, 120.0),
        (0, False, 180.0),
        (2, True, 240.0),
        (1, False, 300.0),
    ]:
        logic = HallCommutation(2, SpeedPI(6000.0))
        (command,) = logic.on_edge({"t_capture_s": 1e-3, "sensor": sensor, "rising": rising})
        assert command.sector == SECTOR_OF_CODE[int(hall_code(hall_state(angle + 30.0)))] == angle // 60


def test_a_glitch_step_does_not_become_the_missing_edge_reference():
    """A spike on a Hall state left wrong by a lost edge can read as a step a microsecond long.
    Taken as the sector reference it made every later edge read as a run of lost edges (a
    MISSING_EDGE each, the edge count off by ~120 each, the pole corrections with it)."""
    vc = VirtualController(Stimulus.load(DATA / FINDINGS[0]).plant_config().motor)
    vc.set_strategy(1)
    sector_s = 1e-3 / 1.2  # 6000 rpm, 2 pole pairs
    t = 0.0
    order = [(0, True), (2, False), (1, True), (0, False), (2, True), (1, False)]
    for k in range(24):
        t += sector_s
        vc.capture({"t_capture_s": t, "sensor": order[k % 6][0], "rising": order[k % 6][1]})
    assert not vc.faults
    # a step 1 us after the last edge (a glitch that passed for a sector), then the rotor goes on
    vc.capture({"t_capture_s": t + 1e-6, "sensor": 0, "rising": True})
    edges_before = vc._logic._edge_index
    for k in range(25, 37):
        t += sector_s
        vc.capture({"t_capture_s": t, "sensor": order[k % 6][0], "rising": order[k % 6][1]})
    assert vc._reference_interval_s()[0] == pytest.approx(sector_s, rel=0.01)  # a sector, not the glitch's 1 us
    assert vc._logic._edge_index - edges_before <= 13  # twelve sectors passed; not hundreds of "lost" edges


class _CurrentAtCapture(VirtualController):
    """The classic firmware defect: the edge's current read from the ADC at the capture interrupt,
    not one applied conditioning delay before it, where the armature field that moved the edge
    acted."""

    def _applied_delay_s(self, rising: bool) -> float:
        return 0.0


@pytest.mark.parametrize(
    "name, p99_deg_e",
    [("finding-armature-current-at-capture.json", 3.0), ("finding-armature-current-at-commutation.json", 6.5)],
)
def test_the_armature_correction_gets_the_current_at_the_edges_instant(name, p99_deg_e):
    """The armature findings meet their budget because each edge's current is read at the edge's
    own instant (one applied conditioning delay before the capture): at the capture they fail it
    by the figure the search found."""
    stim = Stimulus.load(DATA / name)
    budgets = Budgets.defaults()
    limit = budgets["any_deviations_commutation_angle_p99"].limit
    motor = stim.plant_config().motor
    at_edge = run(stim, InProcessLink(VirtualController(motor)), budgets).values["commutation_angle_p99_deg_e"]
    at_capture = run(stim, InProcessLink(_CurrentAtCapture(motor)), budgets).values["commutation_angle_p99_deg_e"]
    # the controller's own ADC (a conversion every 2 us and one at the capture): well within the
    # budget (0.014 and 0.019 deg e when the bench handed it the plant's exact current); reading it
    # at the capture fails the budget by half again and more (3.0 and 6.5 deg e when the search found them,
    # 2.2 and 5.1 with the speed loop's anti-windup and the pump-tuned filter defaults)
    assert at_edge < 0.4 * limit
    assert at_capture > 1.5 * limit and at_capture > 0.6 * p99_deg_e

