"""The built-in controller's lost-edge count against the Hall code (no plant: captured edges only)."""

from __future__ import annotations

import numpy as np

from bldc.contract import Fault, Strategy
from bldc.hall import SENSOR_POSITION_DEG_E, hall_state
from hil.controller.virtual import VirtualController
from plant_models import paper_bench

MOTOR = paper_bench().motor
SECTOR_S = 714e-6  #: one sector at 7000 rpm on the paper bench's two pole pairs (60 deg e / (7000 * 2 * 6 deg e/s))


def _edge(angle_deg_e: float, t_s: float) -> dict:
    """The ideal capture of the Hall edge at ``angle_deg_e`` (a multiple of 60)."""
    before, after = hall_state(angle_deg_e - 1.0), hall_state(angle_deg_e + 1.0)
    sensor = int(np.flatnonzero(before != after)[0])
    assert np.isclose((angle_deg_e - SENSOR_POSITION_DEG_E[sensor]) % 180.0, 0.0)
    return {"t_capture_s": t_s, "now_s": t_s, "sensor": sensor, "rising": bool(after[sensor])}


def test_a_too_short_first_interval_does_not_make_every_later_sector_lost_edges():
    """A start-up edge moved 40 deg e late (1.94 deg e/A of armature reaction at 20 A: the drawn set of
    REQ-ROB-001 at --hil-seed 1 had 32 A) left a first interval of a third of a sector as the lost-edge
    reference. Every later sector, three of it, then counted two lost edges although the Hall code
    stepped one sector each time: the edge count ran three per edge and the pole corrections went to
    the wrong poles (+-12.6 deg e). The Hall code bounds what can have been lost to whole electrical
    periods: after the reference is replaced, each edge advances the count by exactly one."""
    c = VirtualController(MOTOR, strategy=Strategy.CORRECTED, speed_setpoint_rpm=7000.0)
    times = [0.0, SECTOR_S / 3.0] + [SECTOR_S / 3.0 + SECTOR_S * k for k in range(1, 40)]
    counts = []
    for k, t in enumerate(times):
        c.capture(_edge(60.0 * k, t))
        counts.append(c._logic._edge_index)
    # the third edge (the Hall state known only from it) may read as lost edges against the short
    # reference, and the count restarts after a period of normal steps (resync); from then on each
    # edge is one sector
    assert np.all(np.diff(counts[-20:]) == 1), counts
    ref_s, _ratio = c._reference_interval_s()
    assert abs(ref_s - SECTOR_S) < 1e-9 * SECTOR_S, ref_s
    # the timing monitor's verdict stands (a lost edge cannot be told from a wrong reference by time)
    assert [code for _, code in c.faults] == [Fault.MISSING_EDGE]


def test_a_slow_sector_the_hall_code_steps_one_is_no_lost_edge():
    """A sector 1.4 times the same sector one mechanical turn earlier (a start-up sector shortened by
    its current's armature lag, as the reference firmware met at REQ-ROB-001's --hil-seed 1) exceeds
    the same-sector ratio of 1.3, but the Hall code stepped one sector and the time reads no whole
    electrical period more: no edge was lost. It raised a false MISSING_EDGE and restarted the edge
    count, the references and the pole alignment; now it is a measured sector."""
    c = VirtualController(MOTOR, strategy=Strategy.CORRECTED, speed_setpoint_rpm=7000.0)
    turn = 6 * MOTOR.pole_pairs
    intervals = [SECTOR_S] * (2 * turn) + [1.4 * SECTOR_S] + [SECTOR_S] * (2 * turn)
    times = np.concatenate([[0.0], np.cumsum(intervals)])
    counts = []
    for k, t in enumerate(times):
        c.capture(_edge(60.0 * k, float(t)))
        counts.append(c._logic._edge_index)
    assert c.faults == []
    assert np.all(np.diff(counts) == 1), counts  # one edge each: no lost edges counted, no restart
    assert c._logic._pole_shift is not None  # the alignment learned once stays
