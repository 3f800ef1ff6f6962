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

import numpy as np

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
    meaning: str

    @property
    def relevant(self) -> bool:
        return bool(self.value >= self.floor)

    def to_json(self) -> dict:
        return {"value": float(self.value), "floor": float(self.floor), "unit": self.unit, "meaning": self.meaning}


def angle_floor_deg_e() -> float:
    return FRACTION * COMMUTATION_ANGLE_BUDGET_DEG_E


def edge_relevance(shift_deg_e: np.ndarray, weight: np.ndarray) -> Relevance:
    """RMS (weighted by edges) of the commutation-angle shift an edge effect predicts."""
    rms = float(math.sqrt(np.sum(weight * shift_deg_e**2) / max(np.sum(weight), 1e-300)))
    return Relevance(
        rms,
        angle_floor_deg_e(),
        "deg_e",
        f"RMS commutation-angle shift over the recording's edges; floor {FRACTION:.0%} of the "
        f"{COMMUTATION_ANGLE_BUDGET_DEG_E} deg_e budget",
    )


def jitter_relevance(time_rms_s: float, angle_rms_deg_e: float, w_e_deg_s: np.ndarray, weight: np.ndarray) -> Relevance:
    var = (w_e_deg_s * time_rms_s) ** 2 + angle_rms_deg_e**2
    return Relevance(
        float(math.sqrt(np.sum(weight * var) / max(np.sum(weight), 1e-300))),
        angle_floor_deg_e(),
        "deg_e",
        f"RMS commutation-angle jitter over the recording's edges; floor {FRACTION:.0%} of the "
        f"{COMMUTATION_ANGLE_BUDGET_DEG_E} deg_e budget",
    )


@dataclass(frozen=True)
class OperatingEnvelope:
    """What the sampled-signal floors need from the recording: per operating point, the mean
    |phase current| (A), the mechanical speed (rad/s) and the load torque (N m)."""

    current_a: np.ndarray
    speed_rad_s: np.ndarray
    load_torque_n_m: np.ndarray
    max_current_a: float


def sample_relevance(name: str, params: dict, motor, env: OperatingEnvelope) -> Relevance:
    """Floor test of a sampled-signal effect's fitted parameters (``motor``: NominalMotor)."""
    if name == "winding_temperature":
        # at a fixed duty, u = 2 R I + 2 k_e w: a resistance change dR moves the speed by dR I / k_e
        rel = float(
            np.max(
                np.abs(params["resistance_delta_ohm"])
                * env.current_a
                / (motor.ke_v_s_per_rad * np.maximum(env.speed_rad_s, 1e-9))
            )
        )
        return Relevance(
            rel,
            FRACTION * SPEED_BUDGET,
            "1",
            "relative speed change at a fixed duty (most sensitive operating point); "
            f"floor {FRACTION:.0%} of a {SPEED_BUDGET:.0%} speed budget",
        )
    if name == "magnet_temperature":
        rel = abs(params["ke_delta_v_s_per_rad"]) / motor.ke_v_s_per_rad  # speed per duty goes as 1 / k_e
        return Relevance(
            float(rel),
            FRACTION * SPEED_BUDGET,
            "1",
            f"relative speed change at a fixed duty; floor {FRACTION:.0%} of a {SPEED_BUDGET:.0%} speed budget",
        )
    if name == "saturation":
        knee, floor = params["saturation_current_a"], params["min_inductance_fraction"]
        drop = 1.0 - max(floor, 1.0 / (1.0 + (env.max_current_a / knee) ** 2))
        return Relevance(
            float(drop),
            FRACTION * INDUCTANCE_TOLERANCE,
            "1",
            "inductance drop at the largest measured current; "
            f"floor {FRACTION:.0%} of a {INDUCTANCE_TOLERANCE:.0%} inductance tolerance",
        )
    if name == "cogging_torque":
        top = float(np.max(env.load_torque_n_m)) if env.load_torque_n_m.size else 0.0
        return Relevance(
            float(params["amplitude_n_m"]),
            FRACTION * TORQUE_RIPPLE_BUDGET * top,
            "N m",
            f"peak cogging torque; floor {FRACTION:.0%} of a {TORQUE_RIPPLE_BUDGET:.0%} torque-ripple budget of the "
            "largest load torque",
        )
    raise KeyError(name)


def possible_cogging_orders(pole_pairs: int, max_order: int) -> tuple[int, ...]:
    """Cogging periods per turn a three-phase motor with ``2 p`` poles can have.

    The cogging fundamental is lcm(slots, poles) per turn; magnet and slot imperfections add
    harmonics at multiples of the pole count and of the slot count, and a three-phase stator's
    slot count is a multiple of 3. Other orders (for example p, the electrical frequency) are
    ripple of another cause: an offset of a current sensor makes a torque error at exactly the
    electrical frequency in the speed residual."""
    return tuple(n for n in range(1, max_order + 1) if n % (2 * pole_pairs) == 0 or n % 3 == 0)
