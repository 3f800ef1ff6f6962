"""Corrected commutation verified through the pins (signal injection, docs/signals.md).

The plant's Hall and phase-current signals, with paper-sized deviations, are exported as a
stimulus an instrument can play; the controller commutates from its pins with the
calibration downloaded; its six gate outputs, captured as a logic analyser would, are scored
against the ideal commutation instants. By default the built-in virtual controller plays the
stimulus (loopback); on a bench, ``--hil-signals-stimulus DIR --hil-signals-capture FILE``
score your controller's capture instead.
"""

import numpy as np
import pytest

from bldc.contract import Strategy
from hil.bench.lockstep import p99_abs, rms
from plant_models import effects as fx
from plant_models.plant import paper_installation_offsets_deg_e, paper_pole_offsets_deg_e

EFFECTS = (fx.InstallationOffset(paper_installation_offsets_deg_e()), fx.PoleOffset(paper_pole_offsets_deg_e()),
           fx.ConditioningDelay(rise_delay_s=6.6e-6, fall_delay_s=1.0e-6))
SPEED_RPM = 8000.0
#: the controller learns which electrical period holds pole N1 over its first mechanical turns
SETTLE_S = 0.05


@pytest.mark.requirement("REQ-COMM-001")
def test_corrected_commutation_through_the_pins(calibrate, hil_signals, hil_plant_config, hil_budget, hil_evidence):
    plant = hil_plant_config
    effects = plant.suite_deviations(EFFECTS)
    speed_rpm = plant.suite_speed_rpm(SPEED_RPM)
    settle_s = plant.suite_settle_s(SETTLE_S, speed_rpm)
    duration_s = max(plant.suite_duration_s(0.5), settle_s + plant.suite_duration_s(0.5 - SETTLE_S))
    run = hil_signals.run(
        effects=effects,
        speed_rpm=speed_rpm,
        duration_s=duration_s,
        strategy=Strategy.CORRECTED,
        corrections=calibrate(effects),
    )
    sc = run.score
    hil_evidence.text("source", f"{run.source}; stimulus {run.stimulus_dir}; gates {run.capture}")
    hil_evidence.text("score (hil signals score --json)", str(sc.to_json()))
    hil_evidence.table(
        "angle error per sector entered (deg e, + = late)",
        ["sector", "n", "mean", "RMS", "max |e|"],
        [[r["sector"], r["n"], r["mean"], r["rms"], r["max_abs"]] for r in sc.per_sector()],
    )
    assert sc.missed == 0 and sc.extra == 0, (
        f"{run.source}: {sc.missed} commutations missed, {sc.extra} extra "
        f"(at {sc.missed_t_s[:5].tolist()} / {sc.extra_t_s[:5].tolist()} s)"
    )
    err = sc.angle_error_deg_e[sc.t_ideal_s >= settle_s]
    hil_evidence.value("commutations scored after the pole alignment", err.size)
    hil_evidence.value("angle error RMS through the pins", rms(err), "deg_e")
    pole_pairs = plant.motor.pole_pairs
    hil_evidence.value("timing bound of the sampled signals", sc.sample_bound_s * speed_rpm * 6.0 * pole_pairs,
                       "deg_e")
    assert err.size > 0.8 * (duration_s - settle_s) * speed_rpm / 60.0 * 6 * pole_pairs, "too few commutations scored"
    hil_budget("commutation_angle_p99", p99_abs(err))
    assert np.isfinite(err).all()
