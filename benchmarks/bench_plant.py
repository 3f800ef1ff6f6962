"""Plant throughput, run on demand (not a test): ``python benchmarks/bench_plant.py``.

Prints the real-time factor of the full electrical plant at 15,000 rpm with 100 kHz sampled
outputs (bar >= 50x, goal >= 100x) and the edges/s of the edge-only kinematic mode with all
Hall effects on (bar >= 10,000,000 edges/s), each with the electrical plant's own edge rate
measured in the same run as the peer. One core: numba runs single-threaded here.

Each figure is the best of a few runs, by wall clock and by the process's CPU time: on a
shared machine the wall clock also counts the time other processes held the core, the CPU
time does not (it still counts page faults on the output buffers, which are part of the cost).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
# measure the checkout this file sits in, not whichever plant_models happens to be installed
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bldc.motor import steady_state  # noqa: E402
from plant_models import OracleCommutation, RawHallCommutation, Simulation, paper_bench  # noqa: E402
from plant_models import effects as fx  # noqa: E402
from plant_models.kinematic import OperatingPoint, simulate_edges  # noqa: E402

ALL_HALL_EFFECTS = (
    fx.InstallationOffset((1.0, -0.5, 0.7)), fx.PoleOffset((0.0, 0.9, -0.3, 0.4)), fx.ConditioningDelay(6e-6, 1e-6),
    fx.ArmatureReaction(0.3), fx.Hysteresis(0.4), fx.EdgeJitter(1e-6, 0.05, 0.2), fx.TimerQuantization(1e-7),
    fx.Eccentricity(0.3, 1.0),
)


def best_of(n, fn):
    """(best wall time, best CPU time, last result) of n calls."""
    wall, cpu = [], []
    for _ in range(n):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - t)
    return min(wall), min(cpu), out


def electrical(source, sim_s=1.0, speed=15000.0, effects=()):
    config = paper_bench().with_effects(*effects)
    duty = steady_state(config.motor, speed)["duty"]

    def run():
        sim = Simulation(config, source, duty=duty, initial_speed_rpm=speed, sample_rate_hz=100e3, capacity=1 << 17)
        sim.run_until(sim_s)
        return sim

    Simulation(config, source, duty=duty, initial_speed_rpm=speed).run_until(1e-3)  # JIT warm-up
    wall, cpu, sim = best_of(5, run)
    return sim_s / wall, sim_s / cpu, len(sim.edges()) / wall, len(sim.samples().t_s)


def kinematic(seconds=60.0, speed=10000.0):
    config = paper_bench().with_effects(*ALL_HALL_EFFECTS)
    profile = [OperatingPoint(seconds, speed, 4.0)]
    simulate_edges(config, [OperatingPoint(0.01, speed, 4.0)])
    wall, cpu, edges = best_of(9, lambda: simulate_edges(config, profile, seed=1))
    return len(edges) / wall, len(edges) / cpu, len(edges)


def main():
    rows = []
    rtf_o, cpu_o, eps_o, n_o = electrical(OracleCommutation())
    rows.append(("electrical plant, oracle commutation, 15,000 rpm, 100 kHz samples",
                 f"{rtf_o:6.1f}x ({cpu_o:.1f}x CPU)", f"{eps_o:12,.0f} edges/s", ">= 50x (goal 100x)"))
    rtf_r, cpu_r, eps_r, _ = electrical(RawHallCommutation(), effects=ALL_HALL_EFFECTS)
    rows.append(("electrical plant, raw Hall, all Hall effects, 15,000 rpm, 100 kHz",
                 f"{rtf_r:6.1f}x ({cpu_r:.1f}x CPU)", f"{eps_r:12,.0f} edges/s", ">= 50x (goal 100x)"))
    eps_k, cpu_k, n_k = kinematic()
    rows.append((f"kinematic edge-only mode, all Hall effects ({n_k:,} edges)", "",
                 f"{eps_k:12,.0f} edges/s", f">= 10,000,000 edges/s ({cpu_k:,.0f}/s CPU)"))
    width = max(len(r[0]) for r in rows)
    print(f"{'case':<{width}}  {'real-time factor, wall (CPU)':>28}  {'throughput':>20}  bar")
    for r in rows:
        print(f"{r[0]:<{width}}  {r[1]:>28}  {r[2]:>20}  {r[3]}")
    print(f"\nratio kinematic / electrical (raw Hall) edge rate, same run: {eps_k / eps_r:,.0f}x")
    print(f"samples per simulated second: {n_o:,}")


if __name__ == "__main__":
    main()
