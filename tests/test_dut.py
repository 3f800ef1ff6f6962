"""The virtual controller and the in-process link through the lockstep bench (ground truth scoring)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bldc.contract import (
    ADC_LSB_A,
    ADC_PERIOD_S,
    MAX_ADC_SAMPLES,
    Command,
    CommandMessage,
    EdgeMessage,
    Fault,
    Strategy,
    commands_as_received,
    edge_as_received,
    edge_epoch,
    encode_reply,
)
from bldc.motor import steady_state
from hil.bench.lockstep import LinkSource, LockstepBench
from hil.calibration.campaign import station_corrections
from hil.calibration.corrections import Corrections
from hil.controller.adc import edge_currents
from hil.controller.commutation import HallCommutation, SpeedPI
from hil.controller.virtual import VirtualController
from hil.dut.in_process import InProcessLink
from hil.dut.link import LinkError
from plant_models import Simulation, paper_bench

CONFIG = paper_bench(with_deviations=True)


@pytest.fixture(scope="module")
def corrections():
    return station_corrections(CONFIG, seed=0)


def bench(strategy, corrections, speed=6000.0):
    vc = VirtualController(CONFIG.motor, strategy=strategy, speed_setpoint_rpm=speed)
    link = InProcessLink(vc)
    link.download_calibration(corrections)
    b = LockstepBench(CONFIG, link, initial_speed_rpm=speed, duty=steady_state(CONFIG.motor, speed)["duty"])
    return b, link, vc


def test_in_process_bench_matches_the_controller_logic_within_the_message_scaling(corrections):
    """The link carries 100 ns ticks, 2 mA ADC counts and a 16-bit duty: the same commutation
    decisions as the float logic called directly on the same ADC window, each instant within a
    few ticks."""
    b, link, _ = bench(Strategy.CORRECTED, corrections)
    b.run_setpoints([6000.0], hold_s=0.3, settle_s=0.1)
    direct = HallCommutation(
        2,
        SpeedPI(6000.0, kp_per_rpm=1e-4, ki_per_rpm_s=2e-3, feedforward=steady_state(CONFIG.motor, 6000.0)["duty"]),
        corrections,
        current_limit_a=15.0,
        motor=CONFIG.motor,
    )
    class Unquantised(LinkSource):
        """The same ADC window and edge currents, in floats, straight into the logic (no message)."""

        def on_edge(self, edge, sim):
            self.with_adc(edge, sim)
            cycle = edge["adc_cycle_phase_currents_a"]
            edge["adc_cycle_sums_a"], edge["adc_cycle_conversions"] = cycle.sum(axis=0), cycle.shape[0]
            delay = corrections.conditioning_delay_s["rise" if edge["rising"] else "fall"]
            return direct.on_edge(edge_currents(edge, delay))

    sim = Simulation(
        CONFIG,
        Unquantised(None),
        duty=steady_state(CONFIG.motor, 6000.0)["duty"],
        initial_speed_rpm=6000.0,
        sample_rate_hz=50e3,
        capacity=1 << 18,
    )
    sim.run_until(b.sim.t_s)
    a, c = b.sim.commutations(), sim.commutations()
    assert len(a) > 400 and len(a) == len(c)
    np.testing.assert_array_equal(a.sector, c.sector)
    assert np.max(np.abs(a.t_s - c.t_s)) < 1e-6


@pytest.mark.parametrize(
    "strategy, p99_max",
    [(Strategy.CORRECTED, 0.5), (Strategy.KF, 0.5), (Strategy.SAGE_HUSA, 0.5), (Strategy.RAW, 99.0)],
)
def test_each_strategy_commutates_and_reports(corrections, strategy, p99_max):
    b, link, vc = bench(strategy, corrections)
    steps = b.run_setpoints([6000.0, 6500.0], hold_s=0.4, settle_s=0.2)
    c = b.sim.commutations()
    steady = (c.t_s > 0.3) & (c.t_s < steps[1])
    assert np.percentile(np.abs(c.error_deg_e[steady]), 99) <= p99_max  # constant speed
    step = c.t_s >= steps[1]
    assert np.percentile(np.abs(c.error_deg_e[step]), 99) <= max(2.0, p99_max)  # a set-point step keeps sync
    if strategy is Strategy.RAW:
        assert np.sqrt(np.mean(c.error_deg_e[steady] ** 2)) > 2.0  # the paper-sized deviations are uncorrected
    st = link.status()
    assert st["strategy"] == int(strategy)
    assert abs(st["estimated_speed_rpm"] - b.sim.speed_rpm) < 0.02 * b.sim.speed_rpm
    assert not any(code in (Fault.MISSING_EDGE, Fault.ILLEGAL_HALL_CODE) for _, code in st["faults"])
    if strategy in (Strategy.KF, Strategy.SAGE_HUSA):
        assert len(st["q_diag"]) == 3 and len(st["r_diag"]) == 2 and math.isfinite(st["last_predicted_commutation_s"])


def edge(t, sensor, rising):
    return {"t_capture_s": t, "sensor": sensor, "rising": rising, "now_s": t, "current_a": 1.0}


def feed(vc, sequence, t0=0.0, dt=1e-3):
    for k, (sensor, rising) in enumerate(sequence):
        vc.capture(edge(t0 + k * dt, sensor, rising))


FORWARD = [(0, True), (2, False), (1, True), (0, False), (2, True), (1, False)]


def test_illegal_hall_code_and_missing_edge_are_faults():
    motor = paper_bench().motor
    vc = VirtualController(motor, strategy=Strategy.RAW)
    feed(vc, FORWARD * 2)
    assert vc.faults == [] and vc.error_register == 0
    # after B falls the code is 001; C falling instead of A rising gives 000
    feed(vc, [(2, False)], t0=vc._last_t + 1e-3)
    assert [c for _, c in vc.faults] == [Fault.ILLEGAL_HALL_CODE]
    assert vc.error_register & 0x01 and vc.error_register & 0x80
    vc.clear_faults()
    assert vc.error_register == 0
    # a step against the direction of rotation: B rises from 001 (sector 5 -> 4)
    vc2 = VirtualController(motor, strategy=Strategy.RAW)
    feed(vc2, FORWARD * 2)
    feed(vc2, [(1, True)], t0=vc2._last_t + 1e-3)
    assert [c for _, c in vc2.faults] == [Fault.MISSING_EDGE]
    # a lost edge in timing: the next edge comes after two sector times
    vc3 = VirtualController(motor, strategy=Strategy.RAW)
    feed(vc3, FORWARD * 2)
    feed(vc3, [(0, True)], t0=vc3._last_t + 2.2e-3)
    assert [c for _, c in vc3.faults] == [Fault.MISSING_EDGE]


def test_invalid_calibration_table_is_refused_and_raises_a_fault(corrections):
    vc = VirtualController(CONFIG.motor)
    link = InProcessLink(vc)
    bad = Corrections.from_json_dict(corrections.to_json_dict())
    bad.pole_offset_deg_e = bad.pole_offset_deg_e[:3]
    with pytest.raises(LinkError, match="pole_offset_deg_e"):
        link.download_calibration(bad)
    assert any(c == Fault.INVALID_CALIBRATION for _, c in vc.faults)
    nan = Corrections.from_json_dict(corrections.to_json_dict())
    nan.conditioning_delay_s["rise"] = float("nan")
    with pytest.raises(LinkError, match="conditioning_delay_s.rise"):
        link.download_calibration(nan)


def test_filter_guard_trip_is_a_fault(corrections):
    from hil.predictors import FilterSettings

    # the textbook filter from Q0 x100 loses positive definiteness; the variance match (on by
    # default) sets R from the edges and keeps it from doing so, so it is off here
    vc = VirtualController(
        CONFIG.motor,
        strategy=Strategy.SAGE_HUSA,
        speed_setpoint_rpm=6000.0,
        filter_settings=FilterSettings(q0_diag=(10.0, 1e-7, 1e-4), adapt_mask=7, r_match_horizon_s=0.0),
    )
    link = InProcessLink(vc)
    link.download_calibration(corrections)
    b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
    b.run_setpoints([6000.0], hold_s=0.3, settle_s=0.1)
    st = link.status()
    assert st["guard_trips"] > 0
    assert [c for _, c in st["faults"]].count(Fault.FILTER_GUARD_TRIP) == 1  # latched, reported once


# --- the in-process link's quantisation equals the 8-byte messages of the protocol links -----


_times = st.floats(0.0, 2000.0, allow_nan=False)  # beyond the 429 s wrap of the capture timer


def _same_edge(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@settings(max_examples=3000, deadline=None, derandomize=True, database=None)
@given(
    t=_times,
    sensor=st.integers(0, 2),
    rising=st.booleans(),
    at_capture=st.tuples(*[st.floats(-80.0, 80.0, allow_nan=False)] * 3),
    window=st.lists(st.tuples(*[st.floats(-80.0, 80.0, allow_nan=False)] * 3), max_size=MAX_ADC_SAMPLES - 1),
    cycle=st.lists(st.tuples(*[st.floats(-60.0, 60.0, allow_nan=False)] * 3), max_size=300),
    age_s=st.floats(0.0, ADC_PERIOD_S),
    seq=st.integers(0, 127),
    offsets=st.lists(
        st.tuples(st.floats(-1e-3, 5e-3), st.integers(0, 5) | st.none(), st.floats(-0.5, 1.5) | st.none()), max_size=3
    ),
)
def test_in_process_fast_path_equals_the_byte_round_trip(
    t, sensor, rising, at_capture, window, cycle, age_s, seq, offsets
):
    adc_t = t - age_s - ADC_PERIOD_S * np.arange(len(window))[::-1]
    edge = {"t_capture_s": t, "sensor": sensor, "rising": rising, "adc_t_s": adc_t,
            "capture_phase_currents_a": at_capture,
            "adc_phase_currents_a": np.asarray(window, dtype=float).reshape(-1, 3),
            "adc_cycle_phase_currents_a": np.asarray(cycle, dtype=float).reshape(-1, 3)}
    epoch = edge_epoch(t)
    message = EdgeMessage.from_edge(edge, seq)
    received = edge_as_received(edge, epoch)
    _same_edge(received, EdgeMessage.unpack(message.pack()).to_edge(epoch))
    _same_edge(received, EdgeMessage.from_frames(message.header(), message.data_frames()).to_edge(epoch))
    # the ADC window arrives within half a count and a tick, the capture's conversion last; beyond
    # +-65.5 A a conversion saturates, as an ADC does
    sent = np.clip(np.vstack([np.reshape(window, (-1, 3)), at_capture]), -32768 * ADC_LSB_A, 32767 * ADC_LSB_A)
    assert np.max(np.abs(received["adc_phase_currents_a"] - sent)) <= ADC_LSB_A / 2 + 1e-9
    shift = received["t_capture_s"] - t  # the capture timer's epoch and tick
    assert np.max(np.abs(received["adc_t_s"] - np.append(adc_t, t) - shift)) <= 1.5e-7
    assert received["adc_cycle_conversions"] == len(cycle)
    summed = np.sum(np.clip(np.reshape(cycle, (-1, 3)), -32768 * ADC_LSB_A, 32767 * ADC_LSB_A), axis=0)
    assert np.all(np.abs(received["adc_cycle_sums_a"] - summed) <= len(cycle) * ADC_LSB_A / 2 + 1e-6)
    commands = [Command(at_s=max(t + dt, 0.0), sector=s, duty=d) for dt, s, d in offsets]
    via_bytes = [
        f.to_command(epoch)
        for f in (CommandMessage.unpack(m.pack()) for m in encode_reply(commands, seq))
        if not f.keeps_everything
    ]
    assert commands_as_received(commands, epoch) == via_bytes


def test_device_epoch_advances_on_a_timer_wrap_and_not_on_a_bad_stamp():
    """Both protocol faces unwrap the 32-bit capture stamp with next_epoch: a step back by more
    than half the range is a wrap (one epoch more), a small step back is a bad stamp (none)."""
    from bldc.contract import WRAP, next_epoch

    assert next_epoch(0, None, 5) == 0
    assert next_epoch(0, WRAP - 10, 3) == WRAP
    assert next_epoch(WRAP, 1000, 990) == WRAP
    assert next_epoch(0, WRAP // 2, 0) == 0  # exactly half the range back: not past the half, no wrap
    assert next_epoch(0, WRAP // 2 + 1, 0) == WRAP


def test_the_window_reaches_what_the_profile_declares_else_the_downloaded_table_else_the_bound(corrections):
    """How far back an edge's ADC window reaches (docs/controller.md, "The bus")."""
    import dataclasses
    from types import SimpleNamespace

    from bldc.contract import MAX_CONDITIONING_DELAY_S
    from hil.bench.lockstep import adc_reach_s
    from hil.dut.profile import shipped

    profile = shipped("modbus")
    link = SimpleNamespace(profile=profile, applied_calibration=None)
    assert adc_reach_s(link) == MAX_CONDITIONING_DELAY_S  # a table the framework did not download: any delay
    link.applied_calibration = corrections
    assert adc_reach_s(link) == max(corrections.conditioning_delay_s.values()) > 0
    link.profile = dataclasses.replace(profile, edge_hook=dataclasses.replace(profile.edge_hook, adc_reach_s=30e-6))
    assert adc_reach_s(link) == 30e-6


def test_a_set_points_edge_jitter_is_the_plants_from_that_set_point_on(corrections):
    """REQ-PRED-002's noisy profile changes the edges' jitter with each set point: the edges of the
    second hold carry the second jitter (plant truth: each edge's stamp error, edge to edge within
    its class), the first hold's none."""
    b, _, _ = bench(Strategy.CORRECTED, corrections)
    with pytest.raises(ValueError, match="1 values for 2 set points"):
        b.run_setpoints([6000.0, 6000.0], hold_s=0.1, edge_jitter_s=[0.0])
    jitter_s = 20e-6
    steps = b.run_setpoints([6000.0, 6000.0], hold_s=0.15, settle_s=0.1, edge_jitter_s=[0.0, jitter_s])
    assert b.sim.edge_jitter_s == jitter_s
    e = b.sim.edges()
    pp = CONFIG.motor.pole_pairs
    w_e_rad_s = 6000.0 / 60.0 * 2.0 * np.pi * pp
    noise_s = [math.sqrt(e.take((e.t_capture_s >= lo) & (e.t_capture_s < hi)).stamp_noise_variance_rad2(pp)) / w_e_rad_s
               for lo, hi in ((steps[0], steps[1]), (steps[1] + 0.01, np.inf))]
    assert noise_s[0] < 0.2 * jitter_s  # before: the plant's own (none configured beyond the timer's)
    assert noise_s[1] == pytest.approx(jitter_s, rel=0.25)  # after: the set point's
