"""The correction tables a controller applies at run time (paper Fig. 4), and their JSON form."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bldc.reasons import Reason, words
from bldc.units import deg_e_per_s_to_rpm, rpm_to_deg_e_per_s

SENSORS = ("A", "B", "C")


@dataclass
class Corrections:
    """Calibrated deviations, positive = the captured edge trails the ideal one.

    Per captured edge of sensor X caused by pole j at electrical speed w_e and mean phase
    current I, the edge trails its ideal position by
        installation_offset[X] + pole_offset[j] + w_e * conditioning_delay[polarity] + armature * I
    and the controller subtracts that angle (:meth:`correction_deg_e`).
    """

    installation_offset_deg_e: dict[str, float] = field(default_factory=lambda: dict.fromkeys(SENSORS, 0.0))
    pole_offset_deg_e: list[float] = field(default_factory=lambda: [0.0] * 4)
    conditioning_delay_s: dict[str, float] = field(default_factory=lambda: {"rise": 0.0, "fall": 0.0})
    armature_reaction_deg_e_per_a: float = 0.0
    #: quantities the data could not determine, with the reason (left at 0 in the tables)
    undetermined: dict[str, Reason] = field(default_factory=dict)
    #: one-sigma uncertainties of the fitted quantities (same keys as the JSON)
    uncertainty: dict[str, Any] = field(default_factory=dict)
    #: conditioning delay angle versus speed, per polarity, for interpolation (paper Fig. 7a)
    delay_table: dict[str, list[float]] = field(default_factory=dict)
    #: extra information (method, residual RMS, segments used)
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def pole_pairs(self) -> int:
        return len(self.pole_offset_deg_e) // 2

    def static_deg_e(self, sensor: np.ndarray, pole: np.ndarray) -> np.ndarray:
        inst = np.array([self.installation_offset_deg_e[s] for s in SENSORS])
        return inst[np.asarray(sensor)] + np.asarray(self.pole_offset_deg_e)[np.asarray(pole)]

    def correction_deg_e(self, sensor, rising, pole, speed_rpm, current_a) -> np.ndarray:
        """Angle by which each captured edge trails its ideal position (Fig. 4 integration)."""
        rising = np.asarray(rising, dtype=bool)
        w_e_deg_s = rpm_to_deg_e_per_s(np.asarray(speed_rpm, dtype=float), self.pole_pairs)
        delay = np.where(rising, self.conditioning_delay_s["rise"], self.conditioning_delay_s["fall"])
        return (
            self.static_deg_e(sensor, pole)
            + w_e_deg_s * delay
            + self.armature_reaction_deg_e_per_a * np.asarray(current_a, dtype=float)
        )

    def correction_one_deg_e(self, sensor: int, rising: bool, pole: int, speed_rpm: float, current_a: float) -> float:
        """``correction_deg_e`` for one edge in plain floats (the controller's per-edge path)."""
        delay = self.conditioning_delay_s["rise" if rising else "fall"]
        return (
            self.installation_offset_deg_e[SENSORS[sensor]]
            + self.pole_offset_deg_e[pole]
            + speed_rpm * 6.0 * self.pole_pairs * delay
            + self.armature_reaction_deg_e_per_a * current_a
        )

    def undetermined_words(self) -> dict[str, str]:
        """``undetermined`` as the JSON holds it: quantity -> the reason's sentence."""
        return {quantity: words(why) for quantity, why in self.undetermined.items()}

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "installation_offset_deg_e": dict(self.installation_offset_deg_e),
            "pole_offset_deg_e": list(self.pole_offset_deg_e),
            "conditioning_delay_s": dict(self.conditioning_delay_s),
            "armature_reaction_deg_e_per_a": self.armature_reaction_deg_e_per_a,
            "undetermined": self.undetermined_words(),
            "uncertainty": self.uncertainty,
            "conditioning_delay_table": self.delay_table,
            "info": self.info,
        }

    def write_json(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json_dict(), indent=2) + "\n")
        return path

    @classmethod
    def from_json_dict(cls, data: dict[str, Any]) -> "Corrections":
        return cls(
            installation_offset_deg_e={s: float(data["installation_offset_deg_e"][s]) for s in SENSORS},
            pole_offset_deg_e=[float(v) for v in data["pole_offset_deg_e"]],
            conditioning_delay_s={k: float(data["conditioning_delay_s"][k]) for k in ("rise", "fall")},
            armature_reaction_deg_e_per_a=float(data["armature_reaction_deg_e_per_a"]),
            undetermined={q: Reason.from_json(why) for q, why in data.get("undetermined", {}).items()},
            uncertainty=dict(data.get("uncertainty", {})),
            delay_table=dict(data.get("conditioning_delay_table", {})),
            info=dict(data.get("info", {})),
        )

    def as_vector(self) -> list[float]:
        """The ten table values in protocol order: installation A/B/C, poles 0-3, rise, fall, armature."""
        return (
            [self.installation_offset_deg_e[s] for s in SENSORS]
            + list(self.pole_offset_deg_e)
            + [self.conditioning_delay_s["rise"], self.conditioning_delay_s["fall"], self.armature_reaction_deg_e_per_a]
        )

    @classmethod
    def from_vector(cls, v: list[float]) -> "Corrections":
        """Inverse of :meth:`as_vector` (four pole offsets: two pole pairs)."""
        return cls(
            installation_offset_deg_e=dict(zip(SENSORS, v[:3])),
            pole_offset_deg_e=list(v[3:7]),
            conditioning_delay_s={"rise": v[7], "fall": v[8]},
            armature_reaction_deg_e_per_a=v[9],
        )

    def as_float32(self) -> "Corrections":
        """The table as every controller link stores it (IEEE single precision): the declared scaling."""
        f32 = lambda v: float(np.float32(v))  # noqa: E731
        return Corrections(
            installation_offset_deg_e={s: f32(self.installation_offset_deg_e[s]) for s in SENSORS},
            pole_offset_deg_e=[f32(v) for v in self.pole_offset_deg_e],
            conditioning_delay_s={k: f32(self.conditioning_delay_s[k]) for k in ("rise", "fall")},
            armature_reaction_deg_e_per_a=f32(self.armature_reaction_deg_e_per_a),
        )

    @classmethod
    def from_plant(cls, config) -> "Corrections":
        """The true corrections of a plant configuration (for scoring; pole 0 taken as reference)."""
        cp = config.compile()
        pole = np.asarray(cp.pole_offset_deg_e, dtype=float)
        inst = np.asarray(cp.sensor_offset_deg_e, dtype=float) + pole[0]
        return cls(
            installation_offset_deg_e=dict(zip(SENSORS, map(float, inst))),
            pole_offset_deg_e=list(map(float, pole - pole[0])),
            conditioning_delay_s={"rise": cp.rise_delay_s, "fall": cp.fall_delay_s},
            armature_reaction_deg_e_per_a=cp.armature_slope_deg_e_per_a,
        )


def corrected_edge_times(
    t_s: np.ndarray,
    sensor: np.ndarray,
    rising: np.ndarray,
    pole: np.ndarray,
    corrections: Corrections,
    current_a: np.ndarray,
    pole_pairs: int,
) -> np.ndarray:
    """Each captured edge moved back by its calibrated deviation (paper Fig. 4), vectorised.

    The angle is turned into time with the speed over the preceding mechanical turn (the same
    sensor's same edge 6p edges back), which no installation or pole offset distorts; the
    first turn uses the first turn's mean speed."""
    t = np.asarray(t_s, dtype=float)
    n = 6 * pole_pairs
    w_e = np.empty(t.size)
    if t.size > n:
        w_e[n:] = 360.0 * pole_pairs / (t[n:] - t[:-n])
        w_e[:n] = w_e[n]
    else:
        w_e[:] = 60.0 * (t.size - 1) / (t[-1] - t[0])
    speed_rpm = deg_e_per_s_to_rpm(w_e, pole_pairs)
    return t - corrections.correction_deg_e(sensor, rising, pole, speed_rpm, current_a) / w_e
