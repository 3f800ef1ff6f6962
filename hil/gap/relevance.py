"""Practical significance: an effect is accepted only if what it does matters.

A statistically significant fit can be physically irrelevant: with enough edges or samples, a
pattern a thousandth of the commutation budget is detected. Each effect therefore has a floor,
stated against a budget of the quantity it disturbs (docs/gap.md, "Practical significance"):

- **edge effects** (installation, pole offset, eccentricity, hysteresis, conditioning delay,
  armature reaction, timer quantisation, edge jitter) disturb the commutation angle: the RMS
  over the recording's edges of the angle shift the effect predicts (the jitter's RMS for
  edge_jitter) must reach ``FRACTION`` of the commutation-angle budget (``commutation_angle_p99``,
  0.5 deg_e by default).
- **winding and magnet temperature** disturb the speed a duty gives: the relative speed change at
  a fixed duty, at the recording's most sensitive operating point, must reach ``FRACTION`` of a
  1 % speed budget (a pump's flow follows its speed).
- **saturation** disturbs the current waveform: the drop of the inductance at the largest measured
  current must reach ``FRACTION`` of a 10 % inductance tolerance.
- **cogging torque** disturbs the torque: its peak must reach ``FRACTION`` of a 10 % torque-ripple
  budget of the largest load torque in the recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from bldc.reasons import Reason, words
from plant_models.effects import SampleSignature

FRACTION = 0.1                    #: share of a budget an effect must reach to matter
COMMUTATION_ANGLE_BUDGET_DEG_E = 0.5  #: hil.verdicts.budgets default commutation_angle_p99
SPEED_BUDGET = 0.01               #: relative speed at a fixed duty
INDUCTANCE_TOLERANCE = 0.10       #: relative inductance
TORQUE_RIPPLE_BUDGET = 0.10       #: peak ripple / load torque


@dataclass(frozen=True)
class Relevance:
    """What an effect's fitted magnitude does, against its floor (same unit)."""

    value: float
    floor: float
    unit: str
    meaning: Reason  #: what the value is and what its floor is a share of (worded by bldc.reasons)

    @property
    def relevant(self) -> bool:
        return bool(self.value >= self.floor)

    def to_json(self) -> dict:
        return {"value": float(self.value), "floor": float(self.floor), "unit": self.unit,
                "meaning": words(self.meaning)}


def angle_floor_deg_e() -> float:
    return FRACTION * COMMUTATION_ANGLE_BUDGET_DEG_E


def edge_relevance(shift_deg_e: np.ndarray, weight: np.ndarray) -> Relevance:
    """RMS (weighted by edges) of the commutation-angle shift an edge effect predicts."""
    rms = float(math.sqrt(np.sum(weight * shift_deg_e**2) / max(np.sum(weight), 1e-300)))
    return Relevance(
        rms,
        angle_floor_deg_e(),
        "deg_e",
        Reason("GAP-001", {"fraction": FRACTION, "budget_deg_e": COMMUTATION_ANGLE_BUDGET_DEG_E}),
    )


def jitter_relevance(time_rms_s: float, angle_rms_deg_e: float, w_e_deg_s: np.ndarray, weight: np.ndarray) -> Relevance:
    var = (w_e_deg_s * time_rms_s) ** 2 + angle_rms_deg_e**2
    return Relevance(
        float(math.sqrt(np.sum(weight * var) / max(np.sum(weight), 1e-300))),
        angle_floor_deg_e(),
        "deg_e",
        Reason("GAP-002", {"fraction": FRACTION, "budget_deg_e": COMMUTATION_ANGLE_BUDGET_DEG_E}),
    )


@dataclass(frozen=True)
class OperatingEnvelope:
    """What the sampled-signal floors need from the recording: per operating point, the mean
    |phase current| (A), the mechanical speed (rad/s) and the load torque (N m)."""

    current_a: np.ndarray
    speed_rad_s: np.ndarray
    load_torque_n_m: np.ndarray
    max_current_a: float


@dataclass(frozen=True)
class Budget:
    """A budget a sampled-signal effect disturbs (``SampleSignature.budget`` names it): its share
    of a reference (1, or a figure of the recording's operating envelope), in ``unit``."""

    share: float
    unit: str
    name: str  #: the budget as the floor's meaning names it, after its share
    reference: Callable[[OperatingEnvelope], float] | None = None  #: None: the share is the budget


def _largest_load_torque(env: OperatingEnvelope) -> float:
    return float(np.max(env.load_torque_n_m)) if env.load_torque_n_m.size else 0.0


BUDGETS = {
    "speed": Budget(SPEED_BUDGET, "1", "speed budget"),
    "inductance": Budget(INDUCTANCE_TOLERANCE, "1", "inductance tolerance"),
    "torque": Budget(TORQUE_RIPPLE_BUDGET, "N m", "torque-ripple budget of the largest load torque",
                     _largest_load_torque),
}


def sample_relevance(sig: SampleSignature, params: dict, motor, env: OperatingEnvelope) -> Relevance:
    """Floor test of a sampled-signal effect's fitted parameters (``motor``: NominalMotor): what its
    declaration says it disturbs, against ``FRACTION`` of that budget."""
    budget = BUDGETS[sig.budget]
    floor = FRACTION * budget.share
    if budget.reference is not None:
        floor = floor * budget.reference(env)
    return Relevance(
        float(sig.disturbance(params, motor, env)),
        floor,
        budget.unit,
        Reason("GAP-003", {"disturbs": sig.disturbs, "fraction": FRACTION, "budget_share": budget.share,
                           "budget": budget.name}),
    )
