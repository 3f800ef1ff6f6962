"""The ``hil-recording/1`` format (docs/recording-format.md): a recording in memory
(:class:`Recording`, its :class:`Segment` list) and its writer. ``reader`` reads it back, strictly.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import RecordingError

FORMAT = "hil-recording/1"
SENSOR_NAMES = ("A", "B", "C")
EDGE_NAMES = ("fall", "rise")
EDGE_COLUMNS = ("t_s", "sensor", "edge", "segment")
EDGE_OPTIONAL = ("ref_angle_mech_deg",)
SAMPLE_REQUIRED = ("t_s", "segment")
SAMPLE_OPTIONAL = ("i_a", "i_b", "i_c", "u_a", "u_b", "u_c", "speed_rpm")
DIRECTIONS = ("forward", "reverse")
#: the segment column of an ordinary run: empty in every row (read as segment -1)
ORDINARY_SEGMENT = {"": -1}
TRUTH_COLUMNS = ("t_ideal_s", "t_raw_s", "t_conditioned_s", "true_angle_mech_deg", "pole", "mean_abs_current_a")



@dataclass
class Segment:
    id: str
    t_start_s: float
    t_end_s: float
    direction: str
    speed_rpm: float
    mean_phase_current_a: float
    load_scale: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def direction_sign(self) -> int:
        return 1 if self.direction == "forward" else -1


@dataclass
class Recording:
    motor: dict[str, Any]
    segments: list[Segment]
    t_s: np.ndarray                 #: capture times
    sensor: np.ndarray              #: 0, 1, 2
    rising: np.ndarray              #: bool
    segment: np.ndarray             #: index into segments
    ref_angle_mech_deg: np.ndarray | None = None
    timer_tick_s: float | None = None
    samples: dict[str, np.ndarray] | None = None  #: columns; "segment" holds indices
    truth: dict[str, np.ndarray] | None = None    #: simulator ground truth per edge (optional)
    meta_extra: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    @property
    def pole_pairs(self) -> int:
        if "pole_pairs" not in self.motor:
            raise RecordingError(
                (self.path or Path("recording")) / "meta.json",
                None,
                "motor.pole_pairs",
                "not stated; this step needs the motor's pole pairs (an ordinary run may leave them out)",
            )
        return int(self.motor["pole_pairs"])

    @property
    def stated_pole_pairs(self) -> int | None:
        """The pole pairs if meta.json states them (an ordinary run may not)."""
        return int(self.motor["pole_pairs"]) if "pole_pairs" in self.motor else None

    @property
    def ordinary(self) -> bool:
        """One ordinary run (no segments): speed, direction and reversals come from the edges."""
        return not self.segments

    @property
    def segment_ids(self) -> list[str]:
        return [s.id for s in self.segments]

    def __len__(self) -> int:
        return int(self.t_s.size)


# --- writing --------------------------------------------------------------------------------

def _fmt(x: float) -> str:
    return repr(float(x))


def write_recording(rec: Recording, directory: str | Path) -> Path:
    """Write ``rec`` as a hil-recording/1 directory; floats are written round-trip exact."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    if rec.t_s.size > 1 and np.any(np.diff(rec.t_s) <= 0):
        n = int(np.nonzero(np.diff(rec.t_s) <= 0)[0][0])
        raise RecordingError(
            d / "edges.csv",
            n + 3,
            "t_s",
            "capture times must increase; refusing to write a recording our own reader would refuse",
        )
    meta = {
        "format": FORMAT,
        "motor": rec.motor,
        "timer_tick_s": rec.timer_tick_s if rec.timer_tick_s is not None else 0,
        **({} if rec.ordinary else {"segments": [
            {
                "id": s.id,
                "t_start_s": s.t_start_s,
                "t_end_s": s.t_end_s,
                "direction": s.direction,
                "speed_rpm": s.speed_rpm,
                "mean_phase_current_a": s.mean_phase_current_a,
                "load_scale": s.load_scale,
                **s.extra,
            }
            for s in rec.segments
        ]}),
        **rec.meta_extra,
    }
    (d / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    ids = rec.segment_ids
    with open(d / "edges.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        # an ordinary run has no segment column (the format allows it absent)
        cols = list(EDGE_COLUMNS if not rec.ordinary else EDGE_COLUMNS[:3])
        cols += ["ref_angle_mech_deg"] if rec.ref_angle_mech_deg is not None else []
        w.writerow(cols)
        for n in range(rec.t_s.size):
            row = [_fmt(rec.t_s[n]), SENSOR_NAMES[rec.sensor[n]], EDGE_NAMES[int(rec.rising[n])]]
            row += [] if rec.ordinary else [ids[rec.segment[n]]]
            if rec.ref_angle_mech_deg is not None:
                row.append(_fmt(rec.ref_angle_mech_deg[n]))
            w.writerow(row)
    if rec.samples is not None:
        cols = ["t_s", "segment"] + [c for c in SAMPLE_OPTIONAL if c in rec.samples]
        with open(d / "samples.csv", "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(cols)
            seg = rec.samples["segment"]
            data = [rec.samples[c] for c in cols[2:]]
            for n in range(rec.samples["t_s"].size):
                sid = ids[seg[n]] if seg[n] >= 0 else ""
                w.writerow([_fmt(rec.samples["t_s"][n]), sid] + [_fmt(a[n]) for a in data])
    if rec.truth is not None:
        with open(d / "ground_truth.csv", "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            cols = [c for c in TRUTH_COLUMNS if c in rec.truth]
            w.writerow(cols)
            for n in range(rec.t_s.size):
                w.writerow([_fmt(rec.truth[c][n]) for c in cols])
    return d

