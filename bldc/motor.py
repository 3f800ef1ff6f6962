"""The motor as both sides know it: its nameplate and the analytic steady state it implies.

The plant simulates this motor; the controller is configured with the same nameplate (as firmware
is configured with its motor's data sheet) and uses the steady state for its start-up duty. Neither
side owns it, so it lives here, below both (``docs/architecture.md``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from bldc.params import bounded

from .units import rad_per_s_to_rpm, rpm_to_rad_per_s


@dataclass(frozen=True)
class MotorParameters:
    """Star-connected three-phase BLDC motor with trapezoidal back-EMF and a fan (pump) load.

    ``ke_v_s_per_rad`` is the flat-top phase back-EMF per mechanical rad/s, so the torque of a
    two-phase conduction at current I is 2 * ke * I. ``phase_inductance_h`` is L - M.
    Load torque: T_L = fan_coefficient * w_m^2 + friction * w_m (w_m in mechanical rad/s).
    """

    pole_pairs: int = bounded(2, low=1, high=64, unit="1", integer=True, doc="pole pairs")
    phase_resistance_ohm: float = bounded(0.0655, low=0.0, high=100.0, unit="ohm", low_open=True, doc="per phase")
    phase_inductance_h: float = bounded(60e-6, low=0.0, high=1.0, unit="H", low_open=True, doc="L - M per phase")
    ke_v_s_per_rad: float = bounded(
        0.0216, low=0.0, high=10.0, unit="V s/rad", low_open=True, doc="phase BEMF constant (mechanical)"
    )
    flat_top_deg_e: float = bounded(120.0, low=0.0, high=180.0, unit="deg_e", low_open=True, doc="BEMF flat top width")
    inertia_kg_m2: float = bounded(
        0.0039, low=0.0, high=100.0, unit="kg m^2", low_open=True, doc="rotor + pump inertia"
    )
    friction_n_m_s_per_rad: float = bounded(1e-5, low=0.0, high=10.0, unit="N m s/rad", doc="viscous friction")
    fan_coefficient_n_m_s2: float = bounded(1.5e-7, low=0.0, high=1.0, unit="N m s^2/rad^2", doc="pump load T = M w^2")
    supply_v: float = bounded(80.0, low=0.0, high=1000.0, unit="V", low_open=True, doc="DC link voltage")


def steady_state(motor: MotorParameters, speed_rpm: float, load_scale: float = 1.0) -> dict[str, float]:
    """Torque balance of ideal six-step commutation with L -> 0 (analytic).

    Two phases conduct on their flat tops: T_e = 2 ke I, and duty * V_dc = 2 R I + 2 ke w_m.
    Returns the current and duty that hold ``speed_rpm`` against the fan load and friction.
    """
    w = rpm_to_rad_per_s(speed_rpm)
    torque = load_scale * motor.fan_coefficient_n_m_s2 * w * w + motor.friction_n_m_s_per_rad * w
    current = torque / (2 * motor.ke_v_s_per_rad)
    duty = (2 * motor.phase_resistance_ohm * current + 2 * motor.ke_v_s_per_rad * w) / motor.supply_v
    return {"torque_n_m": torque, "current_a": current, "duty": duty}


def steady_speed_rpm(motor: MotorParameters, duty: float, load_scale: float = 1.0) -> float:
    """Inverse of :func:`steady_state`: the speed at which ``duty`` balances the load (L -> 0)."""
    ke, r = motor.ke_v_s_per_rad, motor.phase_resistance_ohm
    a = load_scale * motor.fan_coefficient_n_m_s2
    b = motor.friction_n_m_s_per_rad + 2 * ke * ke / r
    c = -ke * duty * motor.supply_v / r
    w = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a) if a > 0 else -c / b
    return rad_per_s_to_rpm(w)


def speed_loop_gain_scale(motor: MotorParameters) -> float:
    """How much more duty this motor needs per rpm than the paper pump's (``MotorParameters()``):
    its back-EMF per rpm over its supply, 2 ke / V_dc, against the paper pump's. A speed loop tuned
    in duty per rpm on the paper pump is the same loop on this motor with its gains times this
    (its mechanical time constant J R / (2 ke^2) the same; exactly 1 on the paper pump)."""
    paper = MotorParameters()
    return (motor.ke_v_s_per_rad / motor.supply_v) / (paper.ke_v_s_per_rad / paper.supply_v)


def rewound(motor: MotorParameters, speed_ratio: float, pole_pairs: int | None = None) -> MotorParameters:
    """``motor`` for a top speed ``speed_ratio`` times lower (and ``pole_pairs``), the same motor per
    unit of its top speed, supply voltage and current: the back-EMF, duty and phase current at the
    new top speed are the old ones at the old top, and so are the electrical and mechanical time
    constants per period. ke scales by the ratio k; the load torque at the top speed (fan M w^2,
    friction f w) by k, so M by k^3 and f by k^2; the inertia by k^2 (J w / T the same); L by the
    ratio of the top electrical frequencies (the same reactance at the top); R and the supply stay."""
    k = float(speed_ratio)
    p = int(motor.pole_pairs if pole_pairs is None else pole_pairs)
    return dataclasses.replace(
        motor,
        pole_pairs=p,
        phase_inductance_h=motor.phase_inductance_h * k * motor.pole_pairs / p,
        ke_v_s_per_rad=motor.ke_v_s_per_rad * k,
        inertia_kg_m2=motor.inertia_kg_m2 * k * k,
        friction_n_m_s_per_rad=motor.friction_n_m_s_per_rad * k * k,
        fan_coefficient_n_m_s2=motor.fan_coefficient_n_m_s2 * k**3,
    )
