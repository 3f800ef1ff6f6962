"""Where an edge's time goes through one link, run on demand:
``python benchmarks/profile_link.py virtual:canopen [--hold-s 4] [--top 25] [--sort tottime]``.

A lockstep run at 6000 rpm (Sage-Husa, the campaign's calibration downloaded) through the DUT
``--hil-dut`` names, after a short warm-up through the same link; prints the edges, wall and
process CPU time per edge, then a cProfile of every thread that ran (the bench's, a device's
notifier or event loop), so a hand-over between threads shows as time waiting in a lock or a
poll. Profiling slows Python code about twofold: the per-edge figure of a run without
``--profile`` is the one to compare (the same command on the base revision, in the same session;
docs/controller.md, "Throughput").
"""

from __future__ import annotations

import argparse
import cProfile
import io
import logging
import pstats
import resource
import threading
import time


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dut", help="virtual:canopen, virtual:modbus or virtual:in-process")
    ap.add_argument("--hold-s", type=float, default=4.0, help="plant seconds of the measured run")
    ap.add_argument("--profile", action="store_true", help="profile every thread (slower)")
    ap.add_argument("--top", type=int, default=25, help="functions listed per thread")
    ap.add_argument("--sort", default="tottime", help="pstats sort key (tottime, cumulative)")
    args = ap.parse_args()

    from bldc.contract import Strategy
    from bldc.motor import steady_state
    from hil.bench.lockstep import LockstepBench
    from hil.calibration.campaign import CalibrationCampaign
    from hil.calibration.fit import fit_corrections
    from hil.controller.virtual import VirtualController
    from hil.dut.spec import open_dut
    from plant_models import paper_bench

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    config = paper_bench(with_deviations=True)
    corrections = fit_corrections(CalibrationCampaign().run(config, seed=0))
    threads: list[tuple[str, cProfile.Profile]] = []
    if args.profile:  # every thread started from here on profiles itself from its first call

        def start(*_):
            profile = cProfile.Profile()
            threads.append((threading.current_thread().name, profile))
            profile.enable()

        threading.setprofile(start)
    controller = VirtualController(config.motor, strategy=Strategy.SAGE_HUSA)
    with open_dut(args.dut, config.motor, controller) as dut:

        def run(hold_s: float) -> LockstepBench:
            dut.link.reset()
            dut.link.download_calibration(corrections)
            bench = LockstepBench(config, dut.link, initial_speed_rpm=6000.0,
                                  duty=steady_state(config.motor, 6000.0)["duty"])
            bench.run_setpoints([6000.0], hold_s=hold_s, settle_s=0.0)
            return bench

        run(0.05)  # numba caches, sockets, interpreter caches warm
        main_profile = cProfile.Profile()
        wall, cpu = time.perf_counter(), _cpu_s()
        if args.profile:
            main_profile.enable()
        edges = run(args.hold_s).source.edges
        if args.profile:
            main_profile.disable()
        wall, cpu = time.perf_counter() - wall, _cpu_s() - cpu
    threading.setprofile(None)
    print(f"{args.dut}: {edges} edges, {wall:.2f} s wall, {cpu:.2f} s CPU (process, all threads): "
          f"{1e6 * wall / edges:.0f} us wall, {1e6 * cpu / edges:.0f} us CPU per edge"
          + (" (profiled)" if args.profile else ""))
    for name, profile in [("bench (main)", main_profile), *threads] if args.profile else []:
        profile.disable()
        out = io.StringIO()
        stats = pstats.Stats(profile, stream=out)
        if stats.total_tt < 0.01:  # a heartbeat task's thread: nothing to see
            continue
        stats.sort_stats(args.sort).print_stats(args.top)
        print(f"==== thread {name}: {stats.total_tt:.2f} s")
        print(out.getvalue())


if __name__ == "__main__":
    main()
