"""REQ-CUR-002's instrument (hil.experiments.commutation_current): the bench's own speed loop on
the true speed, and a controller's commutation errors replayed against the true rotor angle."""

import numpy as np
import pytest

from hil.experiments.commutation_current import AngleReplay, bench_run, commutation_current
from hil.experiments.table5 import scenario_plant
from plant_models import OracleCommutation, paper_bench

RPM, SETTLE_S, WINDOW_S = 5000.0, 0.3, 0.2


@pytest.fixture(scope="module")
def deviated():
    base = paper_bench()
    return base.with_effects(*base.suite_deviations(scenario_plant().effects))


def test_a_replay_of_zero_errors_is_the_oracle_and_a_replayed_error_is_where_the_plant_commutates(deviated):
    oracle = bench_run(deviated, OracleCommutation(), RPM, 0, SETTLE_S, WINDOW_S)
    zero = bench_run(deviated, AngleReplay(np.zeros(1)), RPM, 0, SETTLE_S, WINDOW_S)
    assert zero.mean_current_a == pytest.approx(oracle.mean_current_a, rel=1e-6)
    pattern = np.array([1.5, -0.5, 0.25, 2.0, -1.0, 0.0, 0.75])
    replayed = bench_run(deviated, AngleReplay(pattern), RPM, 0, SETTLE_S, WINDOW_S)
    errors = replayed.commutation_error_deg_e
    # the plant's own record of where it commutated: the pattern, in order, within a millidegree
    start = int(np.argmin([np.abs(np.roll(pattern, -k)[: 7] - errors[:7]).max() for k in range(pattern.size)]))
    expected = np.resize(np.roll(pattern, -start), errors.size)
    assert np.abs(errors - expected).max() < 1e-3
    # the bench's loop holds the set point whatever the commutation
    for run in (oracle, zero, replayed):
        assert abs(run.mean_speed_rpm - RPM) < 1e-3 * RPM


def test_raw_hall_commutation_costs_current_that_late_commutation_costs_too(deviated):
    """At paper-sized deviations raw Hall commutation draws more than the ideal floor, and a
    commutation replayed 4 deg e late (about raw's RMS) removes none of that excess (its share is
    at or below zero), where a perfect one removes all of it."""
    late = commutation_current(deviated, np.full(1, 4.0), RPM, 0, SETTLE_S, WINDOW_S)
    assert late.raw_hall.mean_current_a > late.floor.mean_current_a * 1.001
    assert late.excess_removed < 0.2
    perfect = commutation_current(deviated, np.zeros(1), RPM, 0, SETTLE_S, WINDOW_S)
    assert perfect.excess_removed == pytest.approx(1.0, abs=1e-6)


def test_a_replay_refuses_an_empty_or_broken_error_record():
    with pytest.raises(ValueError, match="finite commutation errors"):
        AngleReplay(np.array([]))
    with pytest.raises(ValueError, match="finite commutation errors"):
        AngleReplay(np.array([0.1, np.nan]))


def test_the_floor_draws_nothing_from_the_seed(deviated):
    """REQ-CUR-002 runs the ideal commutation once per speed for all its seeds: the oracle
    commutates on the true angle, and the seed moves only what the sensors see."""
    runs = [bench_run(deviated, OracleCommutation(), RPM, seed, SETTLE_S, WINDOW_S) for seed in (0, 7)]
    # equal but for rounding: the sensors' edges still cut the plant's steps at other instants
    assert runs[0].mean_current_a == pytest.approx(runs[1].mean_current_a, rel=1e-9)
