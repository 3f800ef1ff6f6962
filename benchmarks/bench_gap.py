"""Gap diagnosis speed, run on demand: ``python benchmarks/bench_gap.py``.

A recording of 60 s at 10,000 rpm (about 120,000 edges) in four segments is written, read back
(strict hil-recording/1 parsing) and diagnosed; the bar is 30 s on one core. The same minute
is then recorded on the electrical plant with samples.csv at 20 kHz (1.2 million rows of currents,
voltages and speed) and a warm winding withheld, and timed the same way. The default-size
``hil gap validate`` is timed too (bar 10 minutes; it uses one worker per core).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bldc.motor import steady_state
from hil.gap import diagnose
from hil.recording.drivers import record_electrical, record_kinematic
from hil.recording.format import write_recording
from hil.recording.reader import read_recording
from plant_models import effects as fx
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint


def _read_and_diagnose(rec, label: str):
    """Write ``rec``, then time the strict read and the diagnosis (what the bar covers)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = write_recording(rec, Path(tmp) / "rec")
        t0 = time.perf_counter()
        back = read_recording(path)
        t1 = time.perf_counter()
        d = diagnose(back)
        t2 = time.perf_counter()
    samples = f", {back.samples['t_s'].size:,} samples" if back.samples is not None else ""
    print(f"{label}: {len(back):,} edges, {len(back.segments)} segments{samples}")
    print(f"  read (strict parse): {t1 - t0:6.2f} s")
    print(f"  diagnose:            {t2 - t1:6.2f} s   (read + diagnose {t2 - t0:.2f} s; bar 30 s)")
    print(f"  accepted: {[a['effect'] for a in d.accepted]}, shrink {d.heldout_shrink}")


def main():
    config = paper_bench().with_effects(fx.ConditioningDelay(6e-6, 1e-6), fx.InstallationOffset((0.4, -0.2, 0.1)),
                                        fx.EdgeJitter(time_rms_s=1e-6), fx.TimerQuantization(1e-7))
    m = config.motor
    ops = [OperatingPoint(15.0, rpm, steady_state(m, rpm, load)["current_a"] * 2 / 3, load_scale=load, id=f"op{i}")
           for i, (rpm, load) in enumerate(((10000.0, 1.0), (9800.0, 0.5), (10200.0, 1.0), (10000.0, 0.0)))]
    _read_and_diagnose(record_kinematic(config, ops, seed=1), "edges only")
    warm = config.with_effects(fx.WindingTemperature(60.0))
    _read_and_diagnose(
        record_electrical(warm, ops, seed=1, sample_rate_hz=20e3, voltage_noise_v=0.005, speed_noise_rpm=0.002),
        "electrical plant, samples at 20 kHz, a warm winding withheld",
    )
    t = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "hil",
            "gap",
            "validate",
            "--json",
            str(Path(tempfile.gettempdir()) / "gap-validate.json"),
        ],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    print(f"hil gap validate (default size): {time.perf_counter() - t:6.1f} s   (bar 600 s)")


if __name__ == "__main__":
    main()
