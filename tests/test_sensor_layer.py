"""Each Hall effect produces exactly its predicted per-edge signature (analytic truth)."""

import math
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from plant_models import EFFECTS, OracleCommutation, RawHallCommutation, Simulation, paper_bench
from plant_models import effects as fx
from plant_models.edgelog import EdgeLog
from plant_models.kinematic import OperatingPoint, simulate_edges

BASE = paper_bench()
P = BASE.motor.pole_pairs


def kin(*effects, speed_rpm=3000.0, current_a=2.0, direction=1, duration_s=0.2, seed=0):
    return simulate_edges(
        BASE.with_effects(*effects), [OperatingPoint(duration_s, speed_rpm, current_a, direction)], seed=seed
    )


def w_e_deg_s(speed_rpm):
    return speed_rpm * 6.0 * P


# --- no effects ------------------------------------------------------------------------------


@pytest.mark.parametrize("direction", [1, -1])
def test_kinematic_no_effects_edges_are_ideal(direction):
    e = kin(direction=direction)
    assert len(e) == pytest.approx(3000 / 60 * 12 * 0.2, abs=2)
    assert np.max(np.abs(e.capture_error_deg_e)) < 1e-6
    assert np.max(np.abs(e.t_capture_s - e.t_ideal_s)) * w_e_deg_s(3000) < 1e-6


def test_kinematic_edge_sequence_matches_format_spec():
    e = kin(speed_rpm=600, duration_s=0.1)
    # forward: A rises at 0, C falls at 60, B rises at 120, A falls at 180, C rises at 240, B falls at 300
    first = [
        ("ABC"[s], "rise" if r else "fall", a % 360)
        for s, r, a in zip(e.sensor[:6], e.rising[:6], e.ideal_angle_deg_e[:6])
    ]
    assert first == [
        ("A", "rise", 0),
        ("C", "fall", 60),
        ("B", "rise", 120),
        ("A", "fall", 180),
        ("C", "rise", 240),
        ("B", "fall", 300),
    ]
    r = kin(speed_rpm=600, duration_s=0.1, direction=-1)
    a = r.sensor == 0
    # reverse: A falls at 0 and rises at 180
    assert set(zip(r.rising[a], np.mod(r.ideal_angle_deg_e[a], 360))) == {(False, 0.0), (True, 180.0)}


@pytest.mark.parametrize("source", [OracleCommutation(), RawHallCommutation()], ids=["oracle", "raw"])
def test_electrical_no_effects_edges_are_ideal(source):
    sim = Simulation(BASE, source, duty=0.45, initial_speed_rpm=8000, seed=3)
    sim.run_until(0.05)
    e = sim.edges()
    assert len(e) > 70
    assert np.max(np.abs(e.switch_error_deg_e)) < 1e-6
    assert np.max(np.abs(e.capture_error_deg_e)) < 1e-6
    # ideal edge time from the independent ideal-sensor crossing, converted to angle
    assert np.max(np.abs(e.t_raw_s - e.t_ideal_s) * e.speed_rpm * 6 * P) < 1e-6


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_effect_defaults_are_neutral(name):
    """An effect built with its defaults changes nothing (the library's default is 'absent')."""
    eff = EFFECTS[name]()
    a = Simulation(BASE, OracleCommutation(), duty=0.4, initial_speed_rpm=6000, seed=1)
    b = Simulation(BASE.with_effects(eff), OracleCommutation(), duty=0.4, initial_speed_rpm=6000, seed=1)
    a.run_until(0.01)
    b.run_until(0.01)
    ea, eb = a.edges(), b.edges()
    np.testing.assert_array_equal(ea.t_capture_s, eb.t_capture_s)
    np.testing.assert_array_equal(a.samples().i_true_a, b.samples().i_true_a)


# --- one effect at a time ------------------------------------------------------------------


@given(fx.InstallationOffset.strategy())
def test_installation_offset_is_per_sensor_constant(eff):
    e = kin(eff)
    err = e.switch_error_deg_e
    for x in range(3):
        np.testing.assert_allclose(err[e.sensor == x], eff.offset_deg_e[x], atol=1e-9)


@given(fx.PoleOffset.strategy(P))
def test_pole_offset_repeats_every_mechanical_turn_alike_for_all_sensors(eff):
    e = kin(eff)
    err = e.switch_error_deg_e
    for pole in range(2 * P):
        np.testing.assert_allclose(err[e.pole == pole], eff.offset_deg_e[pole], atol=1e-9)
    # the pattern repeats every 6p edges (one mechanical turn)
    np.testing.assert_allclose(err[6 * P :], err[: -6 * P], atol=1e-9)


def rc_crossing_time(v0, v_final, tau, threshold):
    """Independent check of the RC formula: root of the exponential charge curve."""
    return brentq(lambda t: v_final + (v0 - v_final) * math.exp(-t / tau) - threshold, 0.0, 50 * tau)


def test_conditioning_delay_matches_rc_circuit():
    circuit = fx.ConditioningCircuit()
    v_high, tau_r, v_low, tau_f = circuit.levels()
    # Thevenin levels from first principles (node equations solved by numpy)
    g = np.array(
        [
            [1 / circuit.r2_ohm + 1 / circuit.r3_ohm, -1 / circuit.r3_ohm],
            [-1 / circuit.r3_ohm, 1 / circuit.r3_ohm + 1 / circuit.r4_ohm],
        ]
    )
    v_off = np.linalg.solve(g, [circuit.vcc_v / circuit.r2_ohm, 0.0])
    g_on = g.copy()
    g_on[0, 0] += 1 / circuit.r1_ohm
    v_on = np.linalg.solve(g_on, [circuit.vcc_v / circuit.r2_ohm, 0.0])
    assert v_high == pytest.approx(v_off[1], rel=1e-12)
    assert v_low == pytest.approx(v_on[1], rel=1e-12)
    rise, fall = circuit.delays_s()
    assert rise == pytest.approx(rc_crossing_time(v_low, v_high, tau_r, circuit.v_ih_v), rel=1e-9)
    assert fall == pytest.approx(rc_crossing_time(v_high, v_low, tau_f, circuit.v_il_v), rel=1e-9)
    assert rise > 3 * fall  # pull-up charging is the slow edge (paper Section 2.5)
    # paper's approximations hold when R4 >> R2
    assert tau_r == pytest.approx(circuit.r2_ohm * circuit.c1_f, rel=0.2)
    assert tau_f == pytest.approx((circuit.r1_ohm + circuit.r3_ohm) * circuit.c1_f, rel=0.05)


@given(fx.ConditioningDelay.strategy(), st.sampled_from([1000.0, 5000.0, 10000.0, 15000.0]))
def test_conditioning_delay_constant_in_time_growing_in_angle(eff, speed):
    e = kin(eff, speed_rpm=speed, duration_s=0.02)
    dt = e.t_conditioned_s - e.t_raw_s
    np.testing.assert_allclose(dt[e.rising], eff.rise_delay_s, atol=1e-12)
    np.testing.assert_allclose(dt[~e.rising], eff.fall_delay_s, atol=1e-12)
    ang = e.capture_error_deg_e
    np.testing.assert_allclose(ang[e.rising], eff.rise_delay_s * w_e_deg_s(speed), atol=1e-7)
    np.testing.assert_allclose(ang[~e.rising], eff.fall_delay_s * w_e_deg_s(speed), atol=1e-7)


@given(fx.ArmatureReaction.strategy(), st.floats(0.0, 20.0))
def test_armature_reaction_is_k_times_current(eff, current):
    e = kin(eff, current_a=current)
    np.testing.assert_allclose(e.switch_error_deg_e, eff.slope_deg_e_per_a * current, atol=1e-9)


def test_armature_table_interpolates():
    eff = fx.ArmatureReaction(table_current_a=(0.0, 5.0, 10.0), table_offset_deg_e=(0.0, 1.0, 1.5))
    assert kin(eff, current_a=7.5).switch_error_deg_e == pytest.approx(1.25)


def test_armature_reaction_in_electrical_plant_follows_instantaneous_current():
    eff = fx.ArmatureReaction(slope_deg_e_per_a=0.4)
    sim = Simulation(BASE.with_effects(eff), OracleCommutation(), duty=0.6, initial_speed_rpm=9000, seed=2)
    sim.run_until(0.05)
    e = sim.edges()
    assert e.mean_abs_current_a.min() > 1.0
    np.testing.assert_allclose(e.switch_error_deg_e, 0.4 * e.mean_abs_current_a, atol=1e-6)


@given(fx.Hysteresis.strategy())
def test_hysteresis_lags_in_both_directions(eff):
    fwd = kin(eff)
    rev = kin(eff, direction=-1)
    # "trails" in the direction of motion in both cases
    np.testing.assert_allclose(fwd.switch_error_deg_e, eff.lag_deg_e, atol=1e-9)
    np.testing.assert_allclose(rev.switch_error_deg_e, eff.lag_deg_e, atol=1e-9)
    # in the forward-angle frame it flips sign with direction; installation offsets do not
    inst = fx.InstallationOffset((1.0, 1.0, 1.0))
    assert np.allclose(kin(inst, direction=-1).switch_error_deg_e, -1.0)


def test_eccentricity_first_mechanical_order():
    eff = fx.Eccentricity(amplitude_deg_e=1.0, phase_rad=0.3)
    e = kin(eff)
    expected = np.sin(2 * np.pi * e.pole / (2 * P) + 0.3)
    np.testing.assert_allclose(e.switch_error_deg_e, expected, atol=1e-9)


@given(st.floats(0.2e-6, 10e-6), st.floats(0.0, 0.9))
def test_time_jitter_rms_and_correlation(rms, rho):
    e = kin(fx.EdgeJitter(time_rms_s=rms, correlation=rho), speed_rpm=10000, duration_s=2.0, seed=7)
    j = e.t_conditioned_s - e.t_raw_s
    n = j.size
    assert n > 3000
    assert np.std(j) == pytest.approx(rms, rel=5 / math.sqrt(n) * (1 + 3 * rho))
    lag1 = np.corrcoef(j[:-1], j[1:])[0, 1]
    assert lag1 == pytest.approx(rho, abs=0.08)


def test_angle_jitter_rms():
    e = kin(fx.EdgeJitter(angle_rms_deg_e=0.5), speed_rpm=10000, duration_s=2.0)
    assert np.std(e.switch_error_deg_e) == pytest.approx(0.5, rel=0.05)
    assert abs(np.mean(e.switch_error_deg_e)) < 0.02


@given(st.sampled_from([1e-8, 1e-7, 1e-6, 5e-6]))
def test_timer_quantization_floors_to_tick(tick):
    e = kin(fx.TimerQuantization(tick_s=tick), fx.EdgeJitter(time_rms_s=0.3e-6), seed=5)
    np.testing.assert_allclose(e.t_capture_s / tick, np.round(e.t_capture_s / tick), atol=1e-6)
    q = e.t_capture_s - e.t_conditioned_s
    assert q.max() <= 1e-15 and q.min() > -tick * (1 + 1e-9)
    assert q.mean() == pytest.approx(-tick / 2, abs=tick * 0.1)


# --- composition and the two modes agree ----------------------------------------------------


@given(
    fx.InstallationOffset.strategy(),
    fx.PoleOffset.strategy(P),
    fx.ConditioningDelay.strategy(),
    fx.Hysteresis.strategy(),
    fx.Eccentricity.strategy(),
)
def test_effects_compose_additively(inst, pole, cond, hyst, ecc):
    e = kin(inst, pole, cond, hyst, ecc, speed_rpm=5000)
    w = w_e_deg_s(5000)
    expected = (
        np.asarray(inst.offset_deg_e)[e.sensor]
        + np.asarray(pole.offset_deg_e)[e.pole]
        + hyst.lag_deg_e
        + ecc.amplitude_deg_e * np.sin(2 * np.pi * e.pole / (2 * P) + ecc.phase_rad)
        + np.where(e.rising, cond.rise_delay_s, cond.fall_delay_s) * w
    )
    np.testing.assert_allclose(e.capture_error_deg_e, expected, atol=1e-7)


def test_electrical_and_kinematic_modes_agree_on_sensor_layer():
    effects = (
        fx.InstallationOffset((1.5, -0.7, 0.3)),
        fx.PoleOffset((0.0, 0.8, -0.4, 0.2)),
        fx.Hysteresis(0.6),
        fx.ConditioningDelay(6e-6, 1e-6),
    )
    sim = Simulation(BASE.with_effects(*effects), RawHallCommutation(), duty=0.5, initial_speed_rpm=9000, seed=4)
    sim.run_until(0.05)
    e = sim.edges()
    k = kin(*effects)
    # same per-(sensor, pole, polarity) switching error; the time delay maps to angle through speed
    for x in range(3):
        for pole in range(2 * P):
            a = e.switch_error_deg_e[(e.sensor == x) & (e.pole == pole)]
            b = k.switch_error_deg_e[(k.sensor == x) & (k.pole == pole)]
            np.testing.assert_allclose(a, b[0], atol=1e-9)
    dt = e.t_conditioned_s - e.t_raw_s
    np.testing.assert_allclose(dt[e.rising], 6e-6, atol=1e-12)
    np.testing.assert_allclose(dt[~e.rising], 1e-6, atol=1e-12)


# --- the Hall chatter defect (issue 15): each cause pinned on the electrical plant ---------------


def _steady_raw_hall(effects, speed_rpm, duration_s=0.05, seed=0):
    from bldc.motor import steady_state

    sim = Simulation(
        BASE.with_effects(*effects),
        RawHallCommutation(),
        duty=steady_state(BASE.motor, speed_rpm)["duty"],
        initial_speed_rpm=speed_rpm,
        seed=seed,
        max_step_s=2e-6,
    )
    sim.run_until(duration_s)
    return sim


def assert_no_chatter(sim, max_current_a=10.0):
    """One forward Hall step per 60 deg e of rotor travel, each sensor alternating, and the phase
    currents at their steady size (a chattering plant ran away to hundreds of amperes)."""
    e, s = sim.edges(), sim.samples()
    assert np.all(e.direction == 1)
    assert abs(len(e) - (s.theta_e_deg[-1] - s.theta_e_deg[0]) / 60.0) <= 1.0, len(e)
    for x in range(3):
        r = e.rising[e.sensor == x]
        assert np.all(r[1:] != r[:-1])
    assert np.abs(s.i_true_a).max() < max_current_a


@pytest.mark.parametrize("slope", [-2.0, -0.5, 2.0])
def test_armature_reaction_of_either_sign_keeps_raw_hall_commutation(slope):
    """A leading armature shift (negative slope) used to act as a negative hysteresis band: the
    sensor flipped back on the step after each edge, and raw-Hall commutation ran away (tens of
    amperes). Now every edge is one forward Hall step, one per 60 deg e of rotor travel."""
    sim = _steady_raw_hall([fx.ArmatureReaction(slope)], 10000.0)
    assert_no_chatter(sim)  # about 2 A in steady state at 10,000 rpm
    e = sim.edges()
    np.testing.assert_allclose(e.switch_error_deg_e, slope * e.mean_abs_current_a, atol=1e-6)


def test_angle_jitter_does_not_flip_a_sensor_back():
    """The boundary a sensor has just crossed keeps the jitter it was crossed with: a fresh draw
    behind the rotor put the way back ahead of it half the time (76 edges where 36 were due)."""
    cfg = BASE.with_effects(fx.EdgeJitter(angle_rms_deg_e=1.0, time_rms_s=1e-6), fx.TimerQuantization(1e-6))
    sim = Simulation(cfg, OracleCommutation(), duty=0.4, initial_speed_rpm=6000, seed=5, max_step_s=2e-6)
    sim.run_until(0.03)
    assert_no_chatter(sim, max_current_a=100.0)  # commutated on the true angle; accelerating at 0.4 duty


def _swinging_rotor(rise_s, fall_s):
    """A light rotor released 4 deg e from a cogging rest on Hall C's boundary (moved 2 deg e by
    its installation offset), unpowered: it swings about the rest with a slowly decaying
    amplitude, so C's pulses past its boundary shrink through every width down to zero."""
    import dataclasses

    motor = dataclasses.replace(
        BASE.motor, inertia_kg_m2=1e-8, friction_n_m_s_per_rad=1.5e-7, fan_coefficient_n_m_s2=0.0
    )
    cfg = dataclasses.replace(BASE, motor=motor).with_effects(
        fx.ConditioningDelay(rise_delay_s=rise_s, fall_delay_s=fall_s),
        fx.InstallationOffset((0.0, 0.0, 2.0)),
        fx.CoggingTorque(amplitude_n_m=0.1, periods_per_rev=12, phase_rad=0.0),
    )

    class Unpowered:
        def on_edge(self, edge, sim):
            return []

    from bldc.contract import Command

    sim = Simulation(
        cfg, Unpowered(), duty=0.0, initial_speed_rpm=0.0, initial_angle_deg_m=28.0, seed=0, max_step_s=1e-6
    )
    sim.schedule(Command(0.0, sector=-1))
    sim.run_until(0.12)
    return sim.edges()


def test_a_pulse_shorter_than_the_conditioning_delay_never_reaches_the_mcu():
    """The conditioning circuit is a state (its capacitor), not a delay per edge: a raw pulse that
    ends before the capacitor reached the MCU threshold is not seen, nor is its end. Delayed one
    by one, a short low pulse's rising end (2 us) overtook its falling start (40 us), and the MCU
    saw the same level twice, then the wrong one until the next edge."""
    fast = _swinging_rotor(2e-6, 2e-6)
    slow = _swinging_rotor(2e-6, 40e-6)
    assert len(fast) > 300 and np.all(fast.sensor == 2)
    # the same swing, less the pulses too short for the 40 us fall (their two edges each)
    swallowed = len(fast) - len(slow)
    assert swallowed > 0 and swallowed % 2 == 0
    r, t = slow.rising, slow.t_capture_s
    assert np.all(r[1:] != r[:-1]) and np.all(np.diff(t) > 0)
    low = np.nonzero(~r[:-1])[0]  # every low pulse the MCU saw lasted at least its leading (fall) delay
    assert np.all(slow.t_raw_s[low + 1] - slow.t_raw_s[low] >= 40e-6)


def test_edge_current_is_the_current_at_the_crossing():
    """The armature shift follows the current within the plant step: an edge's current (and so
    its lag) is the current at its own instant. Taken at the step start it was up to a step of
    commutation transient stale (0.6 A on a finding), which cost 2 deg e of commutation there."""
    from bldc.motor import steady_state

    # commutation on the true angle, edges 1 deg e later: each edge falls in a commutation transient
    cfg = BASE.with_effects(fx.ArmatureReaction(1.0), fx.InstallationOffset((1.0, 1.0, 1.0)))
    duty = steady_state(BASE.motor, 9000.0)["duty"] + 0.1  # driven hard: tens of amperes, fast transients

    def run(sample_rate_hz):
        sim = Simulation(
            cfg,
            OracleCommutation(),
            duty=duty,
            initial_speed_rpm=9000.0,
            seed=0,
            max_step_s=2e-6,
            sample_rate_hz=sample_rate_hz,
        )
        sim.run_until(0.02)
        return sim

    e = run(100e3).edges()  # plant steps of 2 us
    f = run(20e6).samples()  # the same run seen every 50 ns
    mean_abs = np.abs(f.i_true_a).mean(axis=1)
    at_crossing = np.interp(e.t_raw_s, f.t_s, mean_abs)
    step_start = np.interp(np.floor(e.t_raw_s / 2e-6) * 2e-6, f.t_s, mean_abs)
    assert np.max(np.abs(step_start - at_crossing)) > 0.03  # the step start is stale here
    np.testing.assert_allclose(e.mean_abs_current_a, at_crossing, atol=0.003)
    np.testing.assert_allclose(e.switch_error_deg_e, 1.0 + 1.0 * e.mean_abs_current_a, atol=1e-6)


# --- many segments at once: the same edges as one segment at a time --------------------------


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(
    segments=st.lists(
        st.tuples(st.floats(1e-4, 0.02), st.floats(0.0, 12000.0), st.floats(0.0, 12000.0) | st.none(),
                  st.floats(0.0, 8.0), st.sampled_from([1, -1])),
        min_size=1, max_size=60,
    ),
    start_deg_e=st.floats(-720.0, 720.0),
    start_s=st.floats(0.0, 10.0),
    pole=st.tuples(*[st.floats(-2.0, 2.0)] * 4),
    tick_s=st.sampled_from([0.0, 1e-7, 33.3e-6]),
)
def test_the_segments_at_once_are_the_segments_one_by_one_bit_for_bit(segments, start_deg_e, start_s, pole, tick_s):
    """Without jitter (no random draws) every segment is computed at once (a twin replays a capture
    as tens of thousands of one-interval segments); with installation, pole, conditioning-delay,
    armature (a current per segment), hysteresis and timer effects, ramps and reversals, its edges
    are the one-by-one loop's, field by field and in the same order."""
    from plant_models.kinematic import _in_time_order, _segments_at_once, _segments_one_by_one

    config = BASE.with_effects(
        fx.InstallationOffset((0.7, -0.4, -0.3)), fx.PoleOffset((pole[0], pole[1], -pole[0], -pole[1])),
        fx.ConditioningDelay(rise_delay_s=40e-6, fall_delay_s=25e-6), fx.ArmatureReaction(slope_deg_e_per_a=0.3),
        fx.Hysteresis(lag_deg_e=0.5), fx.TimerQuantization(tick_s),
    )
    profile = [OperatingPoint(dur, rpm, cur, d, end) for dur, rpm, end, cur, d in segments]
    cp = config.compile()
    assert cp.jitter_angle_rms_deg_e == 0 and cp.jitter_time_rms_s == 0
    at_once = _segments_at_once(cp, profile, start_deg_e, start_s)
    one_by_one = _segments_one_by_one(cp, profile, 0, start_deg_e, start_s)
    for f in fields(EdgeLog):
        a, b = getattr(at_once, f.name), getattr(one_by_one, f.name)
        assert a.dtype == b.dtype and a.shape == b.shape, f.name
        np.testing.assert_array_equal(a, b, err_msg=f.name)
    np.testing.assert_array_equal(simulate_edges(config, profile, 0, start_deg_e, start_s).t_capture_s,
                                  _in_time_order(one_by_one).t_capture_s)
