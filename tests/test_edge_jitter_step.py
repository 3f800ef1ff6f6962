"""The plant's edge jitter stepped in mid-run (``Simulation.set_edge_jitter``): what the requirements
on what Sage-Husa learns inject (test_cases/test_sage_husa_learning.py)."""

import numpy as np
import pytest

from bldc.motor import steady_state
from plant_models import ConfigError, OracleCommutation, Simulation, paper_bench
from plant_models import effects as fx


def test_a_jitter_step_changes_the_edges_jitter_from_the_next_edge_on():
    config = paper_bench().with_effects(fx.EdgeJitter(time_rms_s=3e-6))
    rpm = 8000.0
    sim = Simulation(config, OracleCommutation(), duty=steady_state(config.motor, rpm)["duty"],
                     initial_speed_rpm=rpm, seed=3)
    sim.run_until(0.2)
    assert sim.edge_jitter_s == pytest.approx(3e-6)
    sim.set_edge_jitter(9e-6)
    step_s = sim.t_s
    sim.run_until(0.4)
    e = sim.edges()
    jitter = np.asarray(e.t_conditioned_s) - np.asarray(e.t_raw_s)  # no conditioning delay in this plant
    before, after = jitter[np.asarray(e.t_raw_s) < step_s], jitter[np.asarray(e.t_raw_s) > step_s]
    assert before.size > 200 and after.size > 200
    # RMS within 10 % of the truth on each side (a standard error of about 3 % from 300 edges)
    assert np.std(before) == pytest.approx(3e-6, rel=0.1) and np.std(after) == pytest.approx(9e-6, rel=0.1)
    with pytest.raises(ConfigError, match="edge jitter"):
        sim.set_edge_jitter(200e-6)  # beyond the effect library's bound (a third of the delay bound)


def test_the_edge_count_is_the_logs_length_at_every_poll():
    """What the learning run polls every 5 ms (``Simulation.edge_count``): the edges logged so far,
    flushed or not, without building the log each time."""
    config = paper_bench()
    rpm = 8000.0
    sim = Simulation(config, OracleCommutation(), duty=steady_state(config.motor, rpm)["duty"],
                     initial_speed_rpm=rpm, seed=3)
    counts = []
    for k in range(1, 8):
        sim.run_until(0.005 * k)
        assert sim.edge_count() == len(sim.edges())
        counts.append(sim.edge_count())
    assert counts[0] > 0 and np.all(np.diff(counts) > 0)
