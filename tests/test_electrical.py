"""The electrical plant against analytic truth: torque and power balance, Line-BEMF, inverter."""

import dataclasses
import math

import numpy as np
import pytest

from bldc.motor import steady_speed_rpm, steady_state
from hil.calibration.linebemf import falling_zero_crossings, line_bemf
from plant_models import OracleCommutation, RawHallCommutation, Simulation, paper_bench
from plant_models import effects as fx

BASE = paper_bench()
P = BASE.motor.pole_pairs


def settle(config, duty, speed_rpm, t_settle, t_measure, source=None, **kw):
    sim = Simulation(config, source or OracleCommutation(), duty=duty, initial_speed_rpm=speed_rpm, **kw)
    sim.run_until(t_settle)
    e0 = sim.energy()
    sim.run_until(t_settle + t_measure)
    return sim, e0


def test_steady_speed_matches_analytic_torque_balance_small_inductance():
    """With L -> 0 the six-step torque balance is closed-form: ke (d Vdc - 2 ke w) / R = M w^2 + f w."""
    motor = dataclasses.replace(BASE.motor, phase_inductance_h=0.5e-6)
    config = dataclasses.replace(BASE, motor=motor)
    duty = 0.45
    expected = steady_speed_rpm(motor, duty)
    sim, _ = settle(config, duty, expected * 0.98, 1.5, 0.05, max_step_s=2e-6, sample_rate_hz=20e3)
    s = sim.samples()
    measured = s.speed_rpm[s.t_s > 1.5].mean()
    assert measured == pytest.approx(expected, rel=0.005)


def test_mean_torque_balances_fan_load_at_steady_speed():
    """At steady speed the mean electromagnetic torque equals M w^2 + f w (paper Eq. 8, dw/dt = 0)."""
    duty = steady_state(BASE.motor, 10000)["duty"]
    sim, _ = settle(BASE, duty, 10000, 6.0, 0.06)  # 10 mechanical turns at ~10,000 rpm
    s = sim.samples()
    win = s.t_s > 6.0
    w = s.speed_rpm[win] * 2 * math.pi / 60
    load = BASE.motor.fan_coefficient_n_m_s2 * w**2 + BASE.motor.friction_n_m_s_per_rad * w
    # steady: the inertial torque J dw/dt is below 0.05 % of the load
    assert abs(np.polyfit(s.t_s[win], w, 1)[0] * BASE.motor.inertia_kg_m2) < 5e-4 * load.mean()
    assert s.torque_n_m[win].mean() == pytest.approx(load.mean(), rel=0.005)


@pytest.mark.parametrize("source", [OracleCommutation(), RawHallCommutation()], ids=["oracle", "raw"])
def test_power_balance_over_a_steady_turn(source):
    """Electrical in = mechanical out + copper loss (magnetic energy returns over a full turn)."""
    config = BASE.with_effects(fx.InstallationOffset((3.0, -2.0, 1.0)), fx.ConditioningDelay(8e-6, 1e-6))
    duty = steady_state(BASE.motor, 8000)["duty"]
    sim = Simulation(config, source, duty=duty, initial_speed_rpm=8000)
    sim.run_until(0.3)
    # integrate over exactly whole mechanical turns: from one A-rise of pole 0 to a later one
    sim.run_until(0.31)
    e = sim.edges()
    marks = e.t_raw_s[(e.sensor == 0) & (e.pole == 0) & e.rising & (e.t_raw_s > 0.3)]
    sim2 = Simulation(config, source, duty=duty, initial_speed_rpm=8000)
    sim2.run_until(marks[0])
    a = sim2.energy()
    sim2.run_until(marks[0] + 1 * 60 / 8000 * 1.0)  # one turn (the speed is steady within 0.1 %)
    b = sim2.energy()
    e_in = b.electrical_in_j - a.electrical_in_j
    e_out = (b.mechanical_j - a.mechanical_j) + (b.copper_loss_j - a.copper_loss_j)
    assert e_in > 0.5
    assert abs(e_in - e_out) / e_in < 0.01


def test_line_bemf_zero_crossings_match_true_back_emf():
    """Eq. 3 on sampled terminal voltages and currents crosses zero where e_B - e_C does."""
    speed = 1107.0  # one of the paper's calibration speeds
    duty = steady_state(BASE.motor, speed)["duty"]
    config = BASE.with_effects(fx.InstallationOffset((2.5, 2.5, 2.5)))  # commutation off the crossing
    sim = Simulation(config, RawHallCommutation(), duty=duty, initial_speed_rpm=speed, sample_rate_hz=100e3)
    sim.run_until(0.2)
    s = sim.samples()
    m = BASE.motor
    est = line_bemf(s.t_s, s.u_v, s.i_true_a, m.phase_resistance_ohm, m.phase_inductance_h)["BC"]
    true = s.bemf_v[:, 1] - s.bemf_v[:, 2]
    w_e = speed * 6 * P  # deg/s
    window, guard = 20.0 / w_e, 2.0 / w_e
    t_est = falling_zero_crossings(s.t_s, est, window, guard)
    t_true = falling_zero_crossings(s.t_s, true, window, 0.0)
    assert len(t_true) >= 6 and len(t_est) == len(t_true)
    err_deg = (t_est - t_true) * w_e
    assert np.max(np.abs(err_deg)) < 0.1
    # and the true crossing is the ideal A rising edge (theta_e = 0 mod 360)
    theta = np.interp(t_true, s.t_s, s.theta_e_deg)
    assert np.max(np.abs((theta + 180) % 360 - 180)) < 0.05


def test_floating_phase_shows_neutral_plus_own_bemf():
    duty = steady_state(BASE.motor, 9000)["duty"]
    sim = Simulation(BASE, OracleCommutation(), duty=duty, initial_speed_rpm=9000)
    sim.run_until(0.05)
    s = sim.samples()
    from bldc.hall import SECTOR_PHASES

    hi, lo = SECTOR_PHASES[s.sector, 0], SECTOR_PHASES[s.sector, 1]
    fl = 3 - hi - lo
    rows = np.arange(s.t_s.size)
    open_ = np.abs(s.i_true_a[rows, fl]) == 0.0
    assert open_.mean() > 0.5
    r = rows[open_]
    u_n = (s.u_v[r, hi[open_]] + s.u_v[r, lo[open_]] - s.bemf_v[r, hi[open_]] - s.bemf_v[r, lo[open_]]) / 2
    np.testing.assert_allclose(s.u_v[r, fl[open_]], u_n + s.bemf_v[r, fl[open_]], atol=1e-9)
    # right after a commutation the outgoing phase freewheels through a diode: 0 V or V_dc
    clamped = ~open_
    vals = s.u_v[rows[clamped], fl[clamped]]
    assert np.all(np.isclose(vals, 0.0) | np.isclose(vals, BASE.motor.supply_v))
    np.testing.assert_allclose(s.i_true_a.sum(axis=1), 0.0, atol=1e-9)


def test_current_sensor_gain_offset_noise():
    from plant_models import CurrentSensorParameters

    cs = CurrentSensorParameters(gain_error=(0.0065, -0.0065, 0.0), offset_a=(0.05, 0.0, -0.05), noise_rms_a=0.02)
    config = dataclasses.replace(BASE, current_sensor=cs)
    sim = Simulation(config, OracleCommutation(), duty=0.5, initial_speed_rpm=9000, seed=9)
    sim.run_until(0.05)
    s = sim.samples()
    for x in range(3):
        slope, icpt = np.polyfit(s.i_true_a[:, x], s.i_meas_a[:, x], 1)
        assert slope == pytest.approx(1 + cs.gain_error[x], abs=0.002)
        assert icpt == pytest.approx(cs.offset_a[x], abs=0.005)
    resid = s.i_meas_a - (s.i_true_a * (1 + np.asarray(cs.gain_error)) + np.asarray(cs.offset_a))
    assert resid.std() == pytest.approx(0.02, rel=0.05)


@pytest.mark.parametrize(
    "effect, motor_change",
    [
        (
            fx.WindingTemperature(temperature_rise_k=100.0),
            {"phase_resistance_ohm": BASE.motor.phase_resistance_ohm * 1.393},
        ),
        (fx.MagnetTemperature(temperature_rise_k=100.0), {"ke_v_s_per_rad": BASE.motor.ke_v_s_per_rad * 0.88}),
        (fx.DeadTime(dead_time_s=2e-6), None),
    ],
    ids=["winding_temperature", "magnet_temperature", "dead_time"],
)
def test_electrical_effects_move_the_operating_point(effect, motor_change):
    """Each no-edge-signature effect moves the steady speed as the analytic balance predicts."""
    duty = steady_state(BASE.motor, 6000)["duty"]
    base, _ = settle(BASE, duty, 6000, 3.0, 0.01)
    moved, _ = settle(BASE.with_effects(effect), duty, 6000, 3.0, 0.01)
    if motor_change is None:
        # dead time: the PWM phase (positive current) loses t_d * f_pwm of duty; the analytic
        # L -> 0 balance overstates the duty sensitivity, so compare with the plant itself
        # (both start near the new equilibrium: while braking from above it the current turns
        # negative and dead time then adds duty, so the transients differ but not the end point)
        moved, _ = settle(BASE.with_effects(effect), duty, 5300, 4.0, 0.01)
        reduced, _ = settle(BASE, duty - 2e-6 * BASE.inverter.pwm_frequency_hz, 5300, 4.0, 0.01)
        assert moved.speed_rpm - base.speed_rpm == pytest.approx(reduced.speed_rpm - base.speed_rpm, rel=0.01)
        assert reduced.speed_rpm < base.speed_rpm - 300
        return
    else:
        predicted = steady_speed_rpm(dataclasses.replace(BASE.motor, **motor_change), duty) - steady_speed_rpm(
            BASE.motor, duty
        )
    assert moved.speed_rpm - base.speed_rpm == pytest.approx(predicted, rel=0.2)


def test_cogging_torque_shows_as_speed_ripple_at_its_order():
    eff = fx.CoggingTorque(amplitude_n_m=0.05, periods_per_rev=12)
    duty = steady_state(BASE.motor, 1500)["duty"]
    sim, _ = settle(BASE.with_effects(eff), duty, 1500, 0.4, 0.4, sample_rate_hz=20e3)
    s = sim.samples()
    win = s.t_s > 0.4
    theta = np.radians(s.theta_m_deg[win])
    v = s.speed_rpm[win] - s.speed_rpm[win].mean()
    # projection of the speed ripple on the cogging order vs a neighbouring order
    amp = lambda n: abs(np.mean(v * np.exp(-1j * n * theta)))  # noqa: E731
    assert amp(12) > 5 * amp(7)


def test_saturation_speeds_up_current_rise():
    duty = 0.9
    lin = Simulation(BASE, OracleCommutation(), duty=duty, initial_speed_rpm=500)
    sat = Simulation(
        BASE.with_effects(fx.Saturation(saturation_current_a=5.0, min_inductance_fraction=0.3)),
        OracleCommutation(),
        duty=duty,
        initial_speed_rpm=500,
    )
    for sim in (lin, sat):
        sim.run_until(200e-6)
    i_lin = np.abs(lin.samples().i_true_a).max()
    i_sat = np.abs(sat.samples().i_true_a).max()
    assert i_sat > 1.2 * i_lin


def test_commutation_log_scores_against_true_angle():
    """Oracle commutations sit on the ideal angle; raw-Hall ones trail by the sensor error."""
    duty = steady_state(BASE.motor, 8000)["duty"]
    oracle = Simulation(BASE, OracleCommutation(), duty=duty, initial_speed_rpm=8000)
    oracle.run_until(0.05)
    c = oracle.commutations()
    assert len(c) >= 79  # 8000 rpm * 12 commutations per turn * 0.05 s
    assert np.max(np.abs(c.error_deg_e)) < 1e-6
    late = BASE.with_effects(fx.InstallationOffset((2.0, 2.0, 2.0)))
    raw = Simulation(late, RawHallCommutation(), duty=duty, initial_speed_rpm=8000)
    raw.run_until(0.05)
    np.testing.assert_allclose(raw.commutations().error_deg_e, 2.0, atol=1e-6)


@pytest.mark.parametrize("source", [RawHallCommutation(), OracleCommutation()], ids=["raw-hall", "oracle"])
@pytest.mark.parametrize("sample_rate_hz", [20e3, 100e3])
@pytest.mark.parametrize("direction", [1, -1], ids=["forward", "reverse"])
def test_edge_is_emitted_at_its_own_angle_whatever_the_step(source, sample_rate_hz, direction):
    """Ground truth: at a captured edge (no delay, no jitter) the rotor sits on the switching
    angle. A step cut back to an edge once ended a few nano-degrees short of it, and the edge was
    then committed one whole step late: 4.5 deg_e at 8000 rpm with 50 us steps."""
    sim = Simulation(
        BASE,
        source,
        duty=steady_state(BASE.motor, 8000.0)["duty"],
        initial_speed_rpm=8000.0,
        sample_rate_hz=sample_rate_hz,
        direction=direction,
        initial_angle_deg_m=7.0,
    )
    sim.run_until(0.1)
    assert direction * sim.speed_rpm > 7000.0  # the initial speed is a magnitude, turning the driven way
    e = sim.edges()
    assert len(e) > 100
    assert np.max(np.abs(e.theta_e_capture_deg - e.theta_e_switch_deg)) < 1e-6


def test_a_capture_jittered_before_the_switch_carries_the_angle_at_capture():
    """Jitter can place a capture before the physical switch; the edge is emitted at the switch,
    but its true angle is the rotor's at the capture time (it was the angle at emission)."""
    config = BASE.with_effects(fx.EdgeJitter(time_rms_s=5e-6))
    sim = Simulation(
        config,
        OracleCommutation(),
        duty=steady_state(BASE.motor, 8000.0)["duty"],
        initial_speed_rpm=8000.0,
        sample_rate_hz=100e3,
        initial_angle_deg_m=7.0,
    )
    sim.run_until(0.1)
    e = sim.edges()
    w_e = e.speed_rpm * 6.0 * P
    expected = e.theta_e_switch_deg + w_e * (e.t_conditioned_s - e.t_raw_s)
    early = e.t_conditioned_s < e.t_raw_s
    assert early.sum() > 30
    assert np.max(np.abs(e.theta_e_capture_deg - expected)) < 1e-3


def test_parameter_vector_table_fills_every_slot_once_from_the_plant():
    """The kernel's parameter vector is declared once (PLANT_PARAMS + RUN_PARAMS): every slot
    exactly once, and Simulation packs each from the field the table names."""
    from plant_models import layout as L

    slots = [index for index, _ in L.PLANT_PARAMS + L.RUN_PARAMS]
    assert sorted(slots) == list(range(L.N_PARAMS))
    config = BASE.with_effects(fx.Hysteresis(0.4), fx.ConditioningDelay(6e-6, 1e-6), fx.CoggingTorque(0.004, 12, 0.3))
    sim = Simulation(config, RawHallCommutation(latency_s=7e-6), sample_rate_hz=50e3, max_step_s=3e-6)
    for index, name in L.PLANT_PARAMS:
        assert sim.p[index] == getattr(sim.plant, name), name
    assert (sim.p[L.P_SAMPLE], sim.p[L.P_HMAX], sim.p[L.P_LATENCY]) == (1.0 / 50e3, 3e-6, 7e-6)


def test_kernel_interp_is_numpy_interp_bit_for_bit():
    """The kernel's allocation-free interpolation (armature-reaction tables) against NumPy's:
    ends clamped, table points exact, interior points the same double."""
    from plant_models.sensor import _interp

    rng = np.random.default_rng(17)  # seed recorded: the points are reproducible
    xp = np.array([0.0, 0.5, 2.0, 2.5, 8.0, 64.0])
    fp = np.array([0.0, 0.3, 1.1, 1.1, 2.9, -4.0])
    x = np.concatenate([xp, rng.uniform(-5.0, 80.0, 2000), [-1e-300, 64.0 + 1e-12]])
    got = np.array([_interp(v, xp, fp) for v in x])
    np.testing.assert_array_equal(got, np.interp(x, xp, fp))


def test_results_do_not_depend_on_buffer_capacity_or_run_chunks():
    """Output buffers are handed over or copied out as they fill; a run in many short calls
    (ending on sample instants) with small buffers gives the very same edges, samples and
    commutations as one long call."""
    config = BASE.with_effects(fx.Hysteresis(0.3), fx.EdgeJitter(1e-6, 0.05, 0.2), fx.ArmatureReaction(0.3))
    duty = steady_state(BASE.motor, 12000.0)["duty"]
    one = Simulation(config, RawHallCommutation(), duty=duty, initial_speed_rpm=12000.0, seed=3)
    one.run_until(0.02)
    many = Simulation(config, RawHallCommutation(), duty=duty, initial_speed_rpm=12000.0, seed=3, capacity=97)
    for k in range(70, 2001, 70):  # chunk ends on sample instants, so the steps are the same
        many.run_until(k * many.sample_period_s)
    many.run_until(0.02)
    a, b = one.samples(), many.samples()
    assert a.t_s.size == 2001
    for name in ("t_s", "i_true_a", "u_v", "theta_m_deg", "sector", "torque_n_m"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    ea, eb = one.edges(), many.edges()
    assert len(ea) > 40  # 400 Hz electrical x 6 edges x 20 ms
    np.testing.assert_array_equal(ea.t_capture_s, eb.t_capture_s)
    np.testing.assert_array_equal(ea.theta_e_switch_deg, eb.theta_e_switch_deg)
    np.testing.assert_array_equal(one.commutations().t_s, many.commutations().t_s)


def test_the_adc_ring_holds_the_current_of_an_instant_before_the_present():
    """Simulation.adc_conversions_at (the controller's ADC window, from which it reads an edge's
    current one conditioning delay before the capture) against the plant's own 1 MHz samples of
    the true currents, up to the 50 us of the effect library's longest delay."""

    sim = Simulation(BASE, RawHallCommutation(), sample_rate_hz=1e6, max_step_s=2e-6, initial_speed_rpm=6000.0)
    worst, compared = 0.0, 0
    for stop in np.arange(0.0101, 0.0125, 0.00013):  # instants all over the commutation cycle
        sim.run_until(stop)
        s = sim.samples()
        for lookback_s in (0.0, 4e-6, 12.5e-6, 25e-6, 37e-6, 50e-6):
            at = sim.t_s - lookback_s
            j = int(np.argmin(np.abs(s.t_s - at)))
            if abs(s.t_s[j] - at) > 1e-9:
                continue  # between two samples of the 1 us grid
            truth = float(np.mean(np.abs(s.i_true_a[j])))
            converted = float(np.mean(np.abs(sim.adc_conversions_at(np.array([at]))[0])))
            worst = max(worst, abs(converted - truth))
            compared += 1
    assert compared >= 40 and worst < 0.02  # A; the current moves by amperes within the 50 us after a commutation


def test_the_adc_window_mean_spans_buffer_flushes():
    """The conversions the controller's ADC accumulates over a cycle (``sensed_samples_since``) are
    every sample of its window through the sensors, also when the sample buffer was flushed inside
    the window (a small buffer here, flushed every 97 samples; a lockstep run flushes at the end of
    each run_until)."""
    config = dataclasses.replace(BASE, current_sensor=dataclasses.replace(
        BASE.current_sensor, gain_error=(0.02, -0.01, 0.0), offset_a=(0.05, 0.0, -0.03)))
    duty = steady_state(BASE.motor, 8000.0)["duty"]
    sim = Simulation(config, OracleCommutation(), duty=duty, initial_speed_rpm=8000.0, capacity=97)
    sim.run_until(0.001)
    first = sim.samples_taken
    sim.run_until(0.0013)  # a short call: a flush at its end
    sim.run_until(0.004)  # 300 samples at 100 kHz: more flushes inside the window
    got = float(np.mean(np.abs(sim.sensed_samples_since(first, math.inf))))
    i = sim.samples().i_true_a[first:] * (1.0 + np.array([0.02, -0.01, 0.0])) + np.array([0.05, 0.0, -0.03])
    assert sim.samples_taken == sim.samples().t_s.size and i.shape[0] == 300
    assert got == pytest.approx(float(np.mean(np.abs(i))), rel=1e-12)
    assert sim.sensed_samples_since(sim.samples_taken, math.inf).shape == (0, 3)
