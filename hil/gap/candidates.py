"""Candidate explanations: each effect of the library that leaves a mean edge-angle signature,
as a linear design block over the residual cells, and the map from fitted coefficients back to
the effect's parameters (in the library's own units and sign convention)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from plant_models.effects import EFFECTS


@dataclass(frozen=True)
class Candidate:
    name: str
    columns: Callable[[dict], np.ndarray]            #: cells -> (n_cells, k)
    params: Callable[[np.ndarray], dict]             #: coefficients -> effect parameters
    physical: Callable[[np.ndarray, np.ndarray], bool]  #: (coef, stderr) -> plausible?

    @property
    def fingerprint(self) -> dict:
        return dict(EFFECTS[self.name].fingerprint)


def _not_below(lo: float) -> Callable[[np.ndarray, np.ndarray], bool]:
    return lambda c, se: bool(np.all(c >= lo - 3 * se))


def _installation(c):
    return np.column_stack([c["direction"] * (c["sensor"] == x) for x in range(3)])


def _pole(c):
    n = 2 * c["pole_pairs"]
    return np.column_stack([c["direction"] * (c["pole"] == j) for j in range(n)])


def _eccentricity(c):
    n = 2 * c["pole_pairs"]
    ang = 2 * np.pi * c["pole"] / n
    return np.column_stack([c["direction"] * np.sin(ang), c["direction"] * np.cos(ang)])


def _delay(c):
    return np.column_stack([c["w_e"] * c["rising"], c["w_e"] * (1 - c["rising"])])


def _quantization(c):
    return (-0.5 * c["w_e"])[:, None]  # the timer floors: mean lag -tick/2 in time


CANDIDATES: dict[str, Candidate] = {
    "installation_offset": Candidate(
        "installation_offset",
        _installation,
        lambda k: {"offset_deg_e": [float(v) for v in k]},
        lambda c, se: bool(np.all(np.abs(c) <= 10 + 3 * se)),
    ),
    "pole_offset": Candidate(
        "pole_offset",
        _pole,
        lambda k: {"offset_deg_e": [float(v) for v in k]},
        lambda c, se: bool(np.all(np.abs(c) <= 5 + 3 * se)),
    ),
    "eccentricity": Candidate(
        "eccentricity",
        _eccentricity,
        lambda k: {
            "amplitude_deg_e": float(np.hypot(*k)),
            "phase_rad": float(np.mod(np.arctan2(k[1], k[0]), 2 * np.pi)),
        },
        lambda c, se: bool(np.hypot(*c) <= 3 + 3 * np.hypot(*se)),
    ),
    "hysteresis": Candidate(
        "hysteresis", lambda c: np.ones((c["sensor"].size, 1)), lambda k: {"lag_deg_e": float(k[0])}, _not_below(0.0)
    ),
    "conditioning_delay": Candidate(
        "conditioning_delay",
        _delay,
        lambda k: {"rise_delay_s": float(k[0]), "fall_delay_s": float(k[1])},
        _not_below(0.0),
    ),
    "armature_reaction": Candidate(
        "armature_reaction",
        lambda c: c["current"][:, None],
        lambda k: {"slope_deg_e_per_a": float(k[0])},
        lambda c, se: bool(np.all(np.abs(c) <= 2 + 3 * se)),
    ),
    "timer_quantization": Candidate(
        "timer_quantization", _quantization, lambda k: {"tick_s": float(k[0])}, _not_below(0.0)
    ),
}

#: Library effects with no mean edge-angle signature are diagnosed elsewhere: edge_jitter as a
#: variance effect (diagnose._noise_gap), the electrical and mechanical ones from the sampled
#: signals (samples.py); dead_time leaves no trace in the format's signals (samples.NO_TRACE).
