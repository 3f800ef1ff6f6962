"""Calibration accuracy versus edge jitter and turns per operating point (run on demand).

``python benchmarks/calibration_accuracy.py`` prints, for each (jitter, turns) cell, the worst
error over several seeds of each calibrated quantity against ground truth, with the paper-bench
deviations injected (docs/calibration.md quotes this table).
"""

from __future__ import annotations

import numpy as np

from hil.calibration.campaign import CalibrationCampaign
from hil.calibration.corrections import Corrections
from hil.calibration.fit import fit_corrections
from plant_models import effects as fx
from plant_models import paper_bench


def worst_errors(jitter_s: float, turns: int, seeds=range(5)):
    base = paper_bench(with_deviations=True).with_effects(
        fx.EdgeJitter(time_rms_s=jitter_s), fx.TimerQuantization(1e-7)
    )
    true = Corrections.from_plant(base)
    out = np.zeros(5)
    for seed in seeds:
        got = fit_corrections(CalibrationCampaign(turns_per_point=turns).run(base, seed=seed))
        inst = max(abs(got.installation_offset_deg_e[s] - true.installation_offset_deg_e[s]) for s in "ABC")
        pole = np.max(np.abs(np.subtract(got.pole_offset_deg_e, true.pole_offset_deg_e)))
        rise = abs(got.conditioning_delay_s["rise"] - true.conditioning_delay_s["rise"])
        fall = abs(got.conditioning_delay_s["fall"] - true.conditioning_delay_s["fall"])
        arm = abs(got.armature_reaction_deg_e_per_a / true.armature_reaction_deg_e_per_a - 1)
        out = np.maximum(out, [inst, pole, rise * 1e6, fall * 1e6, arm * 100])
    return out


def main():
    print(
        f"{'jitter':>8} {'turns':>6} {'inst [de]':>10} {'pole [de]':>10} {'rise [us]':>10} {'fall [us]':>10} "
        f"{'armature [%]':>13}"
    )
    for jitter in (0.5e-6, 1e-6, 2e-6, 5e-6):
        for turns in (20, 50, 200):
            e = worst_errors(jitter, turns)
            print(
                f"{jitter * 1e6:>6.1f}us {turns:>6d} {e[0]:>10.4f} {e[1]:>10.4f} {e[2]:>10.3f} {e[3]:>10.3f} "
                f"{e[4]:>13.2f}"
            )
    print("bounds of the acceptance: 0.05 de, 0.05 de, 0.5 us, 0.5 us, 5 % (1 us jitter, 200 turns)")


if __name__ == "__main__":
    main()
