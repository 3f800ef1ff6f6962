"""Closed-loop check of the reference firmware on the SIL harness, outside pytest: the paper
bench with the combined deviations, calibrated by the station, one run per strategy; prints the
commutation angle error against the plant's true rotor angle, the speed and the faults.

    python firmware/reference/tools/closed_loop.py [sil:firmware/reference] [strategies] [seconds]
"""

import sys
import time

import numpy as np

from bldc.contract import Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import acceptance_max_step_s, make_bench
from hil.dut.spec import open_dut
from plant_models import effects as fx
from plant_models import paper_bench
from plant_models.plant import paper_installation_offsets_deg_e, paper_pole_offsets_deg_e

dut = sys.argv[1] if len(sys.argv) > 1 else "sil:firmware/reference"
strategies = (sys.argv[2] if len(sys.argv) > 2 else "raw,corrected,kf,sage_husa").split(",")
hold_s = float(sys.argv[3]) if len(sys.argv) > 3 else 0.25
speed = 8000.0
effects = (fx.InstallationOffset(paper_installation_offsets_deg_e()), fx.PoleOffset(paper_pole_offsets_deg_e()),
           fx.ConditioningDelay(rise_delay_s=6.6e-6, fall_delay_s=1.0e-6), fx.ArmatureReaction(slope_deg_e_per_a=0.35))
config = paper_bench().with_effects(*effects)
from hil.calibration.campaign import station_corrections  # noqa: E402

corrections = station_corrections(config, seed=0)
link = open_dut(dut, config.motor).link
for name in strategies:
    t0 = time.monotonic()
    link.reset()
    link.download_calibration(corrections)
    link.set_strategy(int(Strategy[name.upper()]))
    bench = make_bench(config, link, initial_speed_rpm=speed, duty=steady_state(config.motor, speed)["duty"], seed=0,
                       sim_options={"max_step_s": acceptance_max_step_s(config)})
    bench.run_setpoints([speed], hold_s=hold_s, settle_s=0.1)
    err = bench.angle_errors_deg_e(0.15)
    st = link.status()
    print(f"{name:10s} n={err.size:5d} mean={err.mean():+.3f} rms={np.sqrt(np.mean(err**2)):.3f} "
          f"p99={np.percentile(np.abs(err), 99):.3f} deg_e  plant {bench.sim.speed_rpm:.0f} rpm  "
          f"fw {st.get('estimated_speed_rpm', float('nan')):.0f} rpm  faults {link.faults()}  "
          f"R {st.get('r_diag')} guards {st.get('guard_trips')}  ({time.monotonic() - t0:.0f} s)", flush=True)
link.close()
