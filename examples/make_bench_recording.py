"""Write examples/bench-recording: a small hil-recording/1 as a bench would record it.

The paper's hydrogen-pump bench with deviations of the size the paper reports (installation,
magnet poles, conditioning delay, armature reaction, jitter), run in the kinematic mode at three
speeds forward and two in reverse, with the phase current growing with speed as under the fan
load. The plant's ground truth is not written: a bench has none. Run from the repository root:

    python examples/make_bench_recording.py
"""

from pathlib import Path

from hil.recording.drivers import record_kinematic
from hil.recording.format import write_recording
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint

#: (duration s, speed rpm, mean phase current A, direction): forward and reverse, so that the
#: diagnosis can tell spatial offsets (they flip with direction) from delays (they do not)
PROFILE = [
    (0.24, 1500.0, 1.0, 1),
    (0.12, 4000.0, 3.0, 1),
    (0.08, 8000.0, 6.0, 1),
    (0.12, 4000.0, 3.0, -1),
    (0.08, 8000.0, 6.0, -1),
]
SEED = 7


def write(out: Path) -> Path:
    profile = [OperatingPoint(d, rpm, amps, direction=direction) for d, rpm, amps, direction in PROFILE]
    rec = record_kinematic(paper_bench(with_deviations=True), profile, seed=SEED)
    write_recording(rec, out)
    (Path(out) / "ground_truth.csv").unlink(missing_ok=True)  # a bench has no ground truth
    return Path(out)


if __name__ == "__main__":
    print(f"wrote {write(Path(__file__).resolve().parent / 'bench-recording')}")
