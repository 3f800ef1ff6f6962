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
    #: (coef, stderr) -> standard errors of the parameters; None: the parameters are linear in the
    #: coefficients, so they are ``params(stderr)``
    param_stderr: Callable[[np.ndarray, np.ndarray], dict] | None = None

    def stderr(self, coef: np.ndarray, se: np.ndarray) -> dict:
        """Standard errors of ``params(coef)`` (model-based: from the weighted fit of the cells)."""
        if self.param_stderr is not None:
            return self.param_stderr(coef, se)
        return {k: (np.abs(v).tolist() if isinstance(v, list) else abs(v)) for k, v in self.params(se).items()}

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


def _eccentricity_stderr(k, se):
    """First-order propagation of the sine and cosine coefficients' errors to amplitude and phase."""
    amp = max(float(np.hypot(*k)), 1e-300)
    return {
        "amplitude_deg_e": float(np.hypot(k[0] * se[0], k[1] * se[1]) / amp),
        "phase_rad": float(np.hypot(k[1] * se[0], k[0] * se[1]) / amp**2),
    }


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
        _eccentricity_stderr,
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
