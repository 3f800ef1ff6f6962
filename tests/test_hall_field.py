"""Field-level Hall sensor model: the switching angles its geometry implies, in both generators.

Every figure is checked against first-order physics computed here from the physical parameters
(not against the model's own tables): the ring's centre off its axis by e shifts what a sensor
at radius R_s sees by e / R_s (mechanical), a switching point b in mT lags by b over the field's
slope, a delay is the RC crossing time of the output circuit.
"""

import math

import numpy as np
import pytest

from bldc.hall import SENSOR_POSITION_DEG_E
from plant_models import ConfigError, PlantConfig, RawHallCommutation, Simulation, paper_bench
from plant_models import effects as fx
from plant_models.hall_field import FIELD_CAUSES, HallField, HallSwitches, MagnetRing, StatorCoupling
from plant_models.kinematic import OperatingPoint, simulate_edges

P = 2
BASE = paper_bench()
OPS = [OperatingPoint(0.03, 3000.0, 1.0), OperatingPoint(0.03, 3000.0, 1.0, direction=-1)]


def errors(hf: HallField, ops=OPS):
    e = simulate_edges(BASE.with_effects(hf), ops, seed=0)
    return e, e.direction * (e.theta_e_capture_deg - e.ideal_angle_deg_e)


def slope_mt_per_deg_e(hf: HallField = HallField(), x: int = 0) -> float:
    """The ring field's slope at sensor A's first zero crossing, by a central difference."""
    b = hf.model(P).field_mt(x, np.array([-1e-3, 1e-3]))
    return (b[1] - b[0]) / 2e-3


def test_ideal_ring_is_positive_over_the_even_poles_and_switches_on_the_ideal_edges():
    m = HallField().model(P)
    th = np.array([10.0, 170.0, 190.0, 350.0])
    b = m.field_mt(0, th)
    assert b[0] > 0 and b[1] > 0 and b[2] < 0 and b[3] < 0  # pole 0 (even) makes A high: A rises at 0
    ring = HallField(ring=MagnetRing(pole_remanence=(1.0,) * 4))  # not the default object, the same physics
    _, err = errors(ring)
    assert np.max(np.abs(err)) < 1e-6


def test_dynamic_eccentricity_is_a_first_order_sinusoid_of_amplitude_p_e_over_r():
    e_mm, beta = 0.1, 40.0
    hf = HallField(ring=MagnetRing(eccentricity_mm=e_mm, eccentricity_angle_deg=beta))
    e, err = errors(hf)
    r_s = hf.ring.radius_mm + hf.sensors.air_gap_mm
    amp = math.degrees(P * e_mm / r_s)
    for d in (1, -1):
        sel = e.direction == d
        per_pole = np.array([err[sel & (e.pole == j)].mean() for j in range(2 * P)])
        # alike for all sensors
        for x in range(3):
            np.testing.assert_allclose(
                [err[sel & (e.pole == j) & (e.sensor == x)].mean() for j in range(2 * P)], per_pole, atol=2e-3
            )
        spectrum = np.fft.rfft(per_pole) / (2 * P) * 2
        assert abs(spectrum[1]) == pytest.approx(amp, rel=0.02)
        assert abs(spectrum[0]) < 0.01 * amp and abs(spectrum[2]) < 0.02 * amp
        if d > 0:
            forward = per_pole
    np.testing.assert_allclose(per_pole, -forward, atol=2e-3)  # a place on the rotor: leads in reverse (trailing frame)


def test_static_eccentricity_moves_each_sensor_by_p_e_over_r_sin():
    e_mm, gamma = 0.15, 75.0
    hf = HallField(ring=MagnetRing(static_offset_mm=e_mm, static_offset_angle_deg=gamma))
    e, err = errors(hf)
    r_s = hf.ring.radius_mm + hf.sensors.air_gap_mm
    for x in range(3):
        phi = math.radians(SENSOR_POSITION_DEG_E[x] / P)
        expected = math.degrees(P * e_mm / r_s * math.sin(phi - math.radians(gamma)))
        fwd = err[(e.sensor == x) & (e.direction > 0)]
        assert fwd.mean() == pytest.approx(expected, abs=0.02 * abs(expected) + 1e-3)
        assert np.ptp(fwd) < 1e-3


@pytest.mark.parametrize("temperature_rise_k", [0.0, 60.0])
def test_hysteresis_band_lags_both_ways_by_half_band_over_slope_with_temperature(temperature_rise_k):
    b, tc = 8.0, -0.001
    hf = HallField(
        sensors=HallSwitches(operate_mt=(b / 2,) * 3, release_mt=(-b / 2,) * 3, threshold_tc_per_k=tc),
        temperature_rise_k=temperature_rise_k,
    )
    e, err = errors(hf)
    alpha = hf.ring.alpha_br_per_k
    expected = (b / 2) * (1 + tc * temperature_rise_k) / (slope_mt_per_deg_e() * (1 + alpha * temperature_rise_k))
    for d in (1, -1):
        assert err[e.direction == d].mean() == pytest.approx(expected, rel=0.03)


def test_stator_field_lag_grows_with_current():
    kappa = 3.0
    hf = HallField(stator=StatorCoupling(kappa))
    lags = []
    for current in (0.0, 1.0, 2.0):
        _, err = errors(hf, [OperatingPoint(0.03, 3000.0, current)])
        lags.append(err.mean())
    assert lags[0] == pytest.approx(0.0, abs=1e-9)
    # sensor X on phase X's axis sees 1.5 kappa i_x, i_x = -+I at its edges, I = 1.5 mean |i|
    expected = 2.25 * kappa / slope_mt_per_deg_e()
    assert lags[1] == pytest.approx(expected, rel=0.05)
    assert lags[2] == pytest.approx(2 * expected, rel=0.05)


def test_open_collector_delays_come_from_the_circuit():
    circuit = fx.ConditioningCircuit(r2_ohm=6.8e3, c1_f=2.2e-9)
    e = simulate_edges(BASE.with_effects(HallField(output=circuit)), OPS, seed=0)
    v_high, tau_r, v_low, tau_f = circuit.levels()
    rise = tau_r * math.log((v_high - v_low) / (v_high - circuit.v_ih_v))  # RC charge to v_ih through the pull-up
    fall = tau_f * math.log((v_high - v_low) / (circuit.v_il_v - v_low))
    delay = e.t_conditioned_s - e.t_raw_s
    np.testing.assert_allclose(delay[e.rising], rise, rtol=1e-9)
    np.testing.assert_allclose(delay[~e.rising], fall, rtol=1e-9)
    assert rise > fall > 0


def test_each_field_cause_is_declared_once_with_the_effect_and_magnitude_first_order_physics_implies():
    """The declarations ``hil gap validate --generator field`` iterates: one per cause, each drawing a
    field model whose implied magnitude is the library effect it names; two magnitudes against the
    first-order formulas computed here (ring centre e: p e / R_s; stator coupling k: 2.25 k / slope)."""
    assert len({c.name for c in FIELD_CAUSES}) == len(FIELD_CAUSES) == 6
    implied = {}
    for cause in FIELD_CAUSES:
        assert cause.parameter and fx.EFFECTS[cause.explained_by.name] is cause.explained_by
        hf = cause.draw(np.random.default_rng(0), P)(1.0)
        assert hf != HallField(), cause.name  # the unit size is a deviation
        implied[cause.name] = effect = cause.implied(hf, P)
        assert type(effect) is cause.explained_by
        effect.check(P, cause.name)  # within the effect's own bounds
    r_s = HallField().ring.radius_mm + HallField().sensors.air_gap_mm
    assert implied["dynamic_eccentricity"].amplitude_deg_e == pytest.approx(math.degrees(P * 0.05 / r_s), rel=1e-12)
    coupling = abs(implied["stator_field"].slope_deg_e_per_a)
    assert coupling == pytest.approx(2.25 * 1.0 / abs(slope_mt_per_deg_e()), rel=0.01)


def test_electrical_plant_switches_where_the_kinematic_generator_does():
    hf = HallField(
        ring=MagnetRing(eccentricity_mm=0.08, eccentricity_angle_deg=10.0, pole_remanence=(1.0, 1.05, 0.97, 1.0)),
        sensors=HallSwitches(operate_mt=(3.0, 4.0, 2.0), release_mt=(-3.0, -2.0, -4.0)),
    )
    cfg = BASE.with_effects(hf)
    sim = Simulation(cfg, RawHallCommutation(), duty=0.2, initial_speed_rpm=3000, seed=1)
    sim.run_until(0.03)
    el = sim.edges()
    kin = simulate_edges(cfg, [OperatingPoint(0.03, 3000.0)], seed=0)
    for x in range(3):
        for j in range(2 * P):
            a = el.switch_error_deg_e[(el.sensor == x) & (el.pole == j)]
            b = kin.switch_error_deg_e[(kin.sensor == x) & (kin.pole == j)]
            assert a.size and b.size
            np.testing.assert_allclose(a, b.mean(), atol=1e-6)


def test_toml_nested_tables_and_errors_name_the_field(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text(
        '[[effects]]\nname = "hall_field"\ntemperature_rise_k = 20.0\n'
        "ring = { eccentricity_mm = 0.05, eccentricity_angle_deg = 30.0 }\n"
        "sensors = { operate_mt = [2.5, 2.5, 2.5], release_mt = [-2.5, -2.5, -2.5] }\n"
        "output = { c1_f = 1e-9 }\n"
    )
    cfg = PlantConfig.from_toml(path)
    hf = cfg.effect("hall_field")
    assert hf.ring.eccentricity_mm == 0.05 and hf.output.c1_f == 1e-9
    cfg.config_hash()  # nested parts serialise
    path.write_text('[[effects]]\nname = "hall_field"\nring = { eccentricity_mm = 0.05, bogus = 1 }\n')
    with pytest.raises(ConfigError, match=r"effects\[0\]\.ring\.bogus"):
        PlantConfig.from_toml(path)
    with pytest.raises(ConfigError, match=r"ring\.pole_remanence"):
        PlantConfig(effects=(HallField(ring=MagnetRing(pole_remanence=(1.0, 1.0))),))
    with pytest.raises(ConfigError, match=r"air_gap_mm"):
        PlantConfig(effects=(HallField(ring=MagnetRing(eccentricity_mm=0.5), sensors=HallSwitches(air_gap_mm=0.5)),))
