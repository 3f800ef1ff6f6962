"""Recordings more than one test file diagnoses (tests/test_gap.py holds what the diagnosis finds in
them, tests/test_saved_results.py that a saved diagnosis of each still reads key for key)."""

from __future__ import annotations

from bldc.motor import steady_state
from plant_models import effects as fx
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint


def temperatures_confounded():
    """Pump load over a narrow speed range, the winding 80 K warm: a resistance change (follows
    current) and a back-EMF change (follows speed) explain nearly the same. A sampled recording."""
    from hil.recording.drivers import record_electrical

    config = paper_bench().with_effects(
        fx.EdgeJitter(time_rms_s=1e-6), fx.TimerQuantization(1e-7), fx.WindingTemperature(80.0)
    )
    ops = [OperatingPoint(0.3, rpm, load_scale=1.0, id=f"pump_{rpm:.0f}") for rpm in (7000.0, 7500.0, 8000.0)]
    return record_electrical(config, ops, seed=1, voltage_noise_v=0.005)


def tiny_installation_offset():
    """0.02 deg e of installation offset through 100 turns at a 0.1 us timer, no jitter."""
    from hil.recording.drivers import record_kinematic

    config = paper_bench().with_effects(fx.InstallationOffset((0.02, -0.02, 0.0)), fx.TimerQuantization(1e-7))
    ops = [OperatingPoint(100 * 60 / rpm, rpm, direction=d) for rpm in (2000.0, 4000.0) for d in (1, -1)]
    return record_kinematic(config, ops, seed=1)


def armature_lag_confounded():
    """Forward only, the current tied to speed by the pump load over a narrow speed range, an
    armature lag of 0.2 deg e/A: the lag (~ w^2) and a conditioning delay (~ w) are then alike."""
    from hil.recording.drivers import record_kinematic

    m = paper_bench().motor
    ops = [
        OperatingPoint(30 * 60 / rpm, rpm, steady_state(m, rpm)["current_a"] * 2 / 3)
        for rpm in (8000.0, 8500.0, 9000.0)
    ]
    config = paper_bench().with_effects(
        fx.ArmatureReaction(0.2), fx.EdgeJitter(time_rms_s=1e-6), fx.TimerQuantization(1e-7)
    )
    return record_kinematic(config, ops, seed=2)
