"""The effect library: every deviation the plant can show, one typed, bounded object each.

Each effect is a frozen dataclass whose fields carry units in their names and physical bounds
(:func:`bldc.params.bounded`). Defaults are neutral: an effect built with its defaults
changes nothing. Each effect knows how to write itself into the compiled plant
(:meth:`Effect.contribute`), draws itself for hypothesis (:meth:`Effect.strategy`) and
describes its fingerprint for the gap diagnosis (:attr:`Effect.fingerprint`).

Sign convention (paper Section 2): a positive angular deviation means the captured edge trails
the ideal one in forward rotation. Installation and pole offsets are spatial displacements, so
in reverse rotation they lead; hysteresis, conditioning delay and armature reaction always lag.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np

from bldc.contract import MAX_CONDITIONING_DELAY_S
from bldc.params import ConfigError, bounded, from_mapping, strategy_for, validate

from .compiled import CompiledPlant


@dataclass(frozen=True)
class Effect:
    name: ClassVar[str] = ""
    #: where the effect acts: "sensor" (edge angle), "timing" (edge time), "electrical", "mechanical"
    layer: ClassVar[str] = ""
    #: fingerprint for the gap diagnosis (docs/gap.md, Fingerprints)
    fingerprint: ClassVar[Mapping[str, str]] = {}

    def contribute(self, plant: CompiledPlant) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def check(self, pole_pairs: int, prefix: str) -> None:
        """Checks that need the motor (for example a per-pole length)."""
        validate(self, prefix)

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        """Hypothesis strategy drawing this effect inside its documented bounds."""
        return strategy_for(cls)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


@dataclass(frozen=True)
class InstallationOffset(Effect):
    """Each Hall sensor sits a little off its nominal 0/120/240 deg electrical position.

    Physics: PCB placement tolerance moves sensor X by ``offset_deg_e[X]`` along the air gap,
    so both its edges occur that much later (forward rotation) at every pole.
    Fingerprint: per-sensor constant, rising and falling alike, independent of speed and load.
    """

    name: ClassVar[str] = "installation_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-sensor constant, both edges alike",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "-",
    }
    offset_deg_e: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-10.0, high=10.0, unit="deg_e", length=3,
        doc="offset of sensors A, B, C; positive = edges trail",
    )

    def contribute(self, plant):
        plant.sensor_offset_deg_e += np.asarray(self.offset_deg_e, dtype=float)


@dataclass(frozen=True)
class PoleOffset(Effect):
    """Magnet pole boundaries off their nominal 180 deg electrical pitch.

    Physics: uneven magnetisation or pole-piece placement shifts the boundary that starts pole j
    (order in which poles pass sensor A from the reference zero; pole 0 = N1) by
    ``offset_deg_e[j]``; every sensor sees the same boundary shifted alike.
    Fingerprint: a pattern repeating every mechanical turn, all sensors alike per pole.
    """

    name: ClassVar[str] = "pole_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-pole pattern repeating every mechanical turn, all sensors alike",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "6p-edge block analysis",
    }
    offset_deg_e: tuple[float, ...] = bounded(
        (0.0, 0.0, 0.0, 0.0), low=-5.0, high=5.0, unit="deg_e",
        doc="shift of the boundary starting each magnet pole; length 2 * pole_pairs",
    )

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        if len(self.offset_deg_e) != 2 * pole_pairs:
            raise ConfigError(
                f"{prefix}offset_deg_e",
                f"expected {2 * pole_pairs} values (one per magnet pole), got {len(self.offset_deg_e)}",
            )

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        one = st.floats(-5.0, 5.0, allow_nan=False)
        return st.builds(cls, offset_deg_e=st.tuples(*([one] * (2 * pole_pairs))))

    def contribute(self, plant):
        plant.pole_offset_deg_e += np.asarray(self.offset_deg_e, dtype=float)


@dataclass(frozen=True)
class SensorPoleOffset(Effect):
    """Each sensor sees each magnet pole boundary at its own offset (beyond the per-pole table).

    Physics: the pole offsets shift a boundary alike for every sensor; a sensor that switches
    away from the field's zero (B_op != 0) crosses a weaker or stronger pole's boundary at a
    different angle, and sensors at different gaps see the magnetisation's shape differently, so
    the offset of boundary j at sensor X is ``offset_deg_e[X * 2p + j]`` (spatial, as pole
    offsets: it leads in reverse). Real captures show such a pattern, constant in speed, in
    what the per-pole table leaves (docs/twin.md).
    Fingerprint: a pattern of 6p edges repeating every mechanical turn, different per sensor.
    """

    name: ClassVar[str] = "sensor_pole_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-sensor, per-pole pattern repeating every mechanical turn",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "6p-edge block analysis per sensor",
    }
    offset_deg_e: tuple[float, ...] = bounded(
        (), low=-5.0, high=5.0, unit="deg_e",
        doc="shift of boundary j at sensor X, index X * 2p + j (sensors A, B, C); length 6 * pole_pairs",
    )

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        if self.offset_deg_e and len(self.offset_deg_e) != 6 * pole_pairs:
            raise ConfigError(
                f"{prefix}offset_deg_e",
                f"expected {6 * pole_pairs} values (3 sensors x {2 * pole_pairs} poles), got {len(self.offset_deg_e)}",
            )

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        one = st.floats(-5.0, 5.0, allow_nan=False)
        return st.builds(cls, offset_deg_e=st.tuples(*([one] * (6 * pole_pairs))))

    def contribute(self, plant):
        if self.offset_deg_e:
            table = np.asarray(self.offset_deg_e, dtype=float).reshape(3, 2 * plant.pole_pairs)
            plant.switch_offset_deg_e = plant.switch_offset_deg_e + table[:, :, None]


@dataclass(frozen=True)
class ConditioningCircuit:
    """The paper's Hall conditioning circuit (Fig. 3a), open-drain sensor.

    Topology: pull-up R2 from Vcc to the sensor output node; the sensor pulls that node to
    ground through its output impedance R1; limiter R3 from that node to the MCU node, which
    carries filter capacitor C1 and R4 (divider and MCU input) to ground. Exact Thevenin
    equivalents give the time constants; with R4 >> R2 they reduce to the paper's
    tau_rise = R2*C1 and tau_fall = (R1+R3)*C1. The MCU captures when the capacitor voltage
    crosses ``v_ih`` (rising) or ``v_il`` (falling). The capacitor settles between edges at any
    speed the pump reaches (tau << an edge interval), so the delays are constant in time.
    """

    r1_ohm: float = bounded(50.0, low=0.0, high=1e4, unit="ohm", doc="sensor output impedance")
    r2_ohm: float = bounded(4.7e3, low=0.0, high=1e6, unit="ohm", low_open=True, doc="pull-up")
    r3_ohm: float = bounded(1e3, low=0.0, high=1e6, unit="ohm", doc="limiter")
    r4_ohm: float = bounded(47e3, low=0.0, high=1e7, unit="ohm", low_open=True, doc="divider / MCU input")
    c1_f: float = bounded(1e-9, low=0.0, high=1e-6, unit="F", doc="filter capacitor")
    vcc_v: float = bounded(5.0, low=0.0, high=30.0, unit="V", low_open=True, doc="pull-up supply")
    v_ih_v: float = bounded(3.25, low=0.0, high=30.0, unit="V", doc="MCU rising threshold (0.65 VDD)")
    v_il_v: float = bounded(1.75, low=0.0, high=30.0, unit="V", doc="MCU falling threshold (0.35 VDD)")

    def levels(self) -> tuple[float, float, float, float]:
        """(v_high, tau_rise_s, v_low, tau_fall_s) of the capacitor node."""
        par = lambda a, b: a * b / (a + b)  # noqa: E731
        v_high = self.vcc_v * self.r4_ohm / (self.r2_ohm + self.r3_ohm + self.r4_ohm)
        tau_rise = par(self.r2_ohm + self.r3_ohm, self.r4_ohm) * self.c1_f
        v_node = self.vcc_v * self.r1_ohm / (self.r1_ohm + self.r2_ohm)
        r_node = par(self.r1_ohm, self.r2_ohm) if self.r1_ohm > 0 else 0.0
        v_low = v_node * self.r4_ohm / (r_node + self.r3_ohm + self.r4_ohm)
        tau_fall = par(r_node + self.r3_ohm, self.r4_ohm) * self.c1_f
        return v_high, tau_rise, v_low, tau_fall

    def delays_s(self) -> tuple[float, float]:
        """(rise, fall) delay from the raw sensor edge to the MCU threshold crossing."""
        v_high, tau_rise, v_low, tau_fall = self.levels()
        if not (v_low < self.v_il_v < self.v_ih_v < v_high):
            raise ConfigError(
                "conditioning_delay.v_ih_v",
                f"thresholds must satisfy v_low ({v_low:.3g} V) < v_il < v_ih < v_high ({v_high:.3g} V)",
            )
        rise = tau_rise * math.log((v_high - v_low) / (v_high - self.v_ih_v))
        fall = tau_fall * math.log((v_high - v_low) / (self.v_il_v - v_low))
        return rise, fall


#: the ranges a search draws conditioning delays from (s): "library", the stated range of the
#: acceptance search (REQ-ROB-001: the paper's circuit class, 1 nF into a few kOhm, up to 50 us);
#: "real-wiring", open-collector Hall outputs with pull-up, filter and cable as real motors show
#: them (134 and 276 us rise minus fall on the shipped captures): up to 300 us
DRAW_DELAY_S = {"library": 50e-6, "real-wiring": 300e-6}


@dataclass(frozen=True)
class ConditioningDelay(Effect):
    """Delay of the Hall conditioning circuit (paper Section 2.5), rising and falling apart.

    Physics: the RC filter charges through the pull-up (slow) and discharges through the sensor
    (fast), so captured rising edges lag more than falling ones; the delay is constant in
    time, hence the angle error grows linearly with speed. Build it from component values with
    :meth:`from_circuit`, or give the two delays directly.
    Fingerprint: lag, rising != falling (electrical order 3), growing with speed.
    """

    name: ClassVar[str] = "conditioning_delay"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "lag, rising and falling edges differ (order 3)",
        "scales_with": "speed (constant in time)",
        "knob": "speed sweep",
    }
    rise_delay_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S, unit="s", doc="delay of captured rising edges"
    )
    fall_delay_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S, unit="s", doc="delay of captured falling edges"
    )

    @classmethod
    def strategy(cls, pole_pairs: int = 2, max_delay_s: float | None = None):
        """Both delays drawn from [0, ``max_delay_s``]: by default the stated range of the acceptance
        search (``DRAW_DELAY_S['library']``, a paper-bench-like circuit), or a real-wiring range."""
        from hypothesis import strategies as st

        high = DRAW_DELAY_S["library"] if max_delay_s is None else float(max_delay_s)
        if not 0.0 < high <= MAX_CONDITIONING_DELAY_S:
            raise ConfigError(
                "conditioning_delay.max_delay_s", f"must be in (0, {MAX_CONDITIONING_DELAY_S}] s, got {high!r}"
            )
        one = st.floats(0.0, high, allow_nan=False)
        return st.builds(cls, rise_delay_s=one, fall_delay_s=one)

    @classmethod
    def from_circuit(cls, circuit: ConditioningCircuit) -> "ConditioningDelay":
        validate(circuit, "conditioning_delay.")
        rise, fall = circuit.delays_s()
        return cls(rise_delay_s=rise, fall_delay_s=fall)

    def contribute(self, plant):
        plant.rise_delay_s += self.rise_delay_s
        plant.fall_delay_s += self.fall_delay_s


@dataclass(frozen=True)
class ArmatureReaction(Effect):
    """Armature field shifts the air-gap field the Hall sensors see (paper Section 2.4).

    Physics: the stator MMF adds to the magnet field and moves its zero crossings by an angle
    that grows with the phase current; linear (``slope_deg_e_per_a``) by default, or a table of
    (mean phase current, offset) points interpolated linearly (clamped at its ends).
    The current is the mean of |i| over the three phases at the edge.
    Fingerprint: lag growing with phase current (load), both edges alike.
    """

    name: ClassVar[str] = "armature_reaction"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "lag, both edges alike",
        "scales_with": "phase current (load)",
        "knob": "load sweep at fixed speed",
    }
    slope_deg_e_per_a: float = bounded(0.0, low=-2.0, high=2.0, unit="deg_e/A", doc="edge lag per ampere")
    table_current_a: tuple[float, ...] = bounded((), low=0.0, high=1e3, unit="A", doc="table currents")
    table_offset_deg_e: tuple[float, ...] = bounded((), low=-30.0, high=30.0, unit="deg_e", doc="table offsets")

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        n = len(self.table_current_a)
        if n != len(self.table_offset_deg_e):
            raise ConfigError(f"{prefix}table_offset_deg_e", f"expected {n} values to match table_current_a")
        if n == 1 or (n and np.any(np.diff(self.table_current_a) <= 0)):
            raise ConfigError(f"{prefix}table_current_a", "needs >= 2 strictly increasing currents")
        if n and self.slope_deg_e_per_a != 0.0:
            raise ConfigError(f"{prefix}slope_deg_e_per_a", "give either a slope or a table, not both")

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        return st.builds(cls, slope_deg_e_per_a=st.floats(-2.0, 2.0, allow_nan=False))

    def offset_deg_e(self, current_a: np.ndarray) -> np.ndarray:
        if self.table_current_a:
            return np.interp(current_a, self.table_current_a, self.table_offset_deg_e)
        return self.slope_deg_e_per_a * np.asarray(current_a, dtype=float)

    def contribute(self, plant):
        if self.table_current_a:
            plant.armature_table_current_a = np.asarray(self.table_current_a, dtype=float)
            plant.armature_table_offset_deg_e = np.asarray(self.table_offset_deg_e, dtype=float)
        else:
            plant.armature_slope_deg_e_per_a += self.slope_deg_e_per_a


@dataclass(frozen=True)
class Hysteresis(Effect):
    """Magnetic hysteresis of the Hall switch (operate vs release point).

    Physics: the sensor switches only after the field has passed zero by B_op, i.e. a constant
    angle after the ideal crossing, in whichever direction the rotor turns.
    Fingerprint: common lag, rising and falling alike, constant in angle; in the forward-angle
    frame it flips sign with direction (installation offsets do not).
    """

    name: ClassVar[str] = "hysteresis"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "common lag, rise and fall alike, in either direction of rotation",
        "scales_with": "nothing (constant in angle)",
        "knob": "a segment in reverse (hysteresis lags both ways; an installation offset flips)",
    }
    lag_deg_e: float = bounded(0.0, low=0.0, high=5.0, unit="deg_e", doc="switching lag after the field zero")

    def contribute(self, plant):
        plant.hysteresis_deg_e += self.lag_deg_e


@dataclass(frozen=True)
class SwitchingAsymmetry(Effect):
    """Rising and falling edges of a sensor apart by a constant angle (its switching points).

    Physics: a Hall switch turns on at its operate point B_op on a rising field and off at its
    release point B_rp on a falling one; when |B_op| != |B_rp| (or the open-collector output's
    threshold is off centre) the rising edge trails the field's zero crossing by a different
    angle than the falling edge, in either direction of rotation. ``rise_minus_fall_deg_e[X]``:
    sensor X's rising edges trail by half of it, its falling edges lead by half (the common part
    is hysteresis). Spatially this is an N/S-alternating shift of the boundaries the sensor sees.
    Fingerprint: rise minus fall constant in angle (a delay grows with speed), any direction.
    """

    name: ClassVar[str] = "switching_asymmetry"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "rising and falling edges of a sensor apart by a constant angle",
        "scales_with": "nothing (constant in angle); the same in either direction",
        "knob": "speed sweep (tells it from a conditioning delay)",
    }
    rise_minus_fall_deg_e: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-10.0, high=10.0, unit="deg_e", length=3,
        doc="rising minus falling edge lag of sensors A, B, C",
    )

    def contribute(self, plant):
        # boundary k of pole k: rising edges at even k forward, at odd k in reverse; a spatial
        # +a/2 on even boundaries and -a/2 on odd ones makes rising trail and falling lead both ways
        half = 0.5 * np.asarray(self.rise_minus_fall_deg_e, dtype=float)
        parity = np.where(np.arange(2 * plant.pole_pairs) % 2 == 0, 1.0, -1.0)
        plant.switch_offset_deg_e = plant.switch_offset_deg_e + half[:, None, None] * parity[None, :, None]


@dataclass(frozen=True)
class EdgeJitter(Effect):
    """Random edge-time disturbance (paper's type III interference).

    Physics: noise on the Hall signal near the MCU threshold (time domain) or magnetic noise
    and vibration (angle domain). White when ``correlation`` is 0; otherwise AR(1) over
    successive captured edges with that lag-1 coefficient, stationary RMS as given.
    Fingerprint: white (or AR(1)) scatter, zero mean; in angle or in time.
    """

    name: ClassVar[str] = "edge_jitter"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "zero-mean scatter, white or coloured",
        "scales_with": "nothing in angle (angle jitter) or speed (time jitter)",
        "knob": "-",
    }
    #: three RMS inside the half sector that bounds a conditioning delay (MAX_CONDITIONING_DELAY_S: the
    #: slowest-commutating motor, a many-pole hub motor at its top speed, whose slow field ramps
    #: through the threshold make the largest time jitter)
    time_rms_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S / 3.0, unit="s", doc="RMS of the time-domain jitter"
    )
    #: up to 10 deg e: three RMS stay inside half a sector (30 deg e), beyond which edges would
    #: reorder; a many-pole hub motor's rotor vibration reaches several deg e (0.5 deg mechanical
    #: at 15 pole pairs is 7.5 deg e)
    angle_rms_deg_e: float = bounded(0.0, low=0.0, high=10.0, unit="deg_e", doc="RMS of the angle-domain jitter")
    correlation: float = bounded(0.0, low=0.0, high=0.95, unit="1", doc="AR(1) coefficient across edges")

    def contribute(self, plant):
        plant.jitter_time_rms_s = math.hypot(plant.jitter_time_rms_s, self.time_rms_s)
        plant.jitter_angle_rms_deg_e = math.hypot(plant.jitter_angle_rms_deg_e, self.angle_rms_deg_e)
        plant.jitter_correlation = self.correlation


@dataclass(frozen=True)
class TimerQuantization(Effect):
    """The capture timer latches a free-running counter: t_captured = floor(t / tick) * tick.

    Fingerprint: white, uniform on [-tick, 0] (mean -tick/2); sector times show lag-1
    autocorrelation of -0.5.
    """

    name: ClassVar[str] = "timer_quantization"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "white, uniform over one tick",
        "scales_with": "constant in time",
        "knob": "lag-1 autocorrelation -0.5 of sector times",
    }
    #: up to 100 us: an MCU capture timer ticks in ns, a logic analyser samples at 10 kHz or faster
    #: (the shipped real captures: 30 kHz, 33.3 us)
    tick_s: float = bounded(0.0, low=0.0, high=1e-4, unit="s", doc="capture timer resolution (0 = none)")

    def contribute(self, plant):
        plant.timer_tick_s = max(plant.timer_tick_s, self.tick_s)


@dataclass(frozen=True)
class Eccentricity(Effect):
    """Dynamic rotor eccentricity: the air gap at each boundary varies once per mechanical turn.

    Physics: a rotor-fixed eccentricity tilts the field at every pole boundary by an amount
    that depends on where the boundary sits on the rotor, so boundary k is shifted by
    ``amplitude_deg_e * sin(2 pi k / (2p) + phase_rad)``, alike for all sensors.
    Fingerprint: first mechanical order across the poles (a two-parameter special case of
    the pole-offset pattern).
    """

    name: ClassVar[str] = "eccentricity"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "sinusoid of first mechanical order across poles, all sensors alike",
        "scales_with": "nothing (constant in angle)",
        "knob": "6p-edge block analysis (order 1 of the mechanical turn)",
    }
    amplitude_deg_e: float = bounded(0.0, low=0.0, high=3.0, unit="deg_e", doc="peak boundary shift")
    phase_rad: float = bounded(0.0, low=0.0, high=2 * math.pi, unit="rad", doc="phase of the gap minimum")

    def contribute(self, plant):
        k = np.arange(2 * plant.pole_pairs)
        pole_angle_rad = 2 * np.pi * k / (2 * plant.pole_pairs)
        plant.pole_offset_deg_e += self.amplitude_deg_e * np.sin(pole_angle_rad + self.phase_rad)


@dataclass(frozen=True)
class CoggingTorque(Effect):
    """Reluctance torque between magnets and stator teeth.

    T_cog = amplitude_n_m * sin(periods_per_rev * theta_m + phase_rad); 12 periods for a
    6-slot, 4-pole motor (lcm of slots and poles).
    Fingerprint: no edge signature (aliases to order 0 in sector times); speed and current
    ripple, largest at low speed.
    """

    name: ClassVar[str] = "cogging_torque"
    layer: ClassVar[str] = "mechanical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current ripple at periods_per_rev; none in edge angles",
        "scales_with": "largest at low speed",
        "knob": "low-speed run",
    }
    amplitude_n_m: float = bounded(0.0, low=0.0, high=0.1, unit="N m", doc="peak cogging torque")
    periods_per_rev: int = bounded(12, low=1, high=96, unit="1/rev", integer=True, doc="cogging periods per turn")
    phase_rad: float = bounded(0.0, low=0.0, high=2 * math.pi, unit="rad", doc="phase")

    def contribute(self, plant):
        plant.cogging_amplitude_n_m = self.amplitude_n_m
        plant.cogging_periods_per_rev = int(self.periods_per_rev)
        plant.cogging_phase_rad = self.phase_rad


@dataclass(frozen=True)
class WindingTemperature(Effect):
    """Copper heats up: R = R_nominal * (1 + alpha_cu * temperature_rise_k), alpha_cu = 0.00393/K.

    Fingerprint: no edge signature; more current and less speed for the same duty, growing
    with run time (heat soak).
    """

    name: ClassVar[str] = "winding_temperature"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current versus duty; none in edge angles",
        "scales_with": "run time (heat soak)",
        "knob": "heat soak",
    }
    temperature_rise_k: float = bounded(0.0, low=-40.0, high=150.0, unit="K", doc="above the reference temperature")
    alpha_per_k: float = bounded(0.00393, low=0.0, high=0.01, unit="1/K", doc="resistance temperature coefficient")

    def contribute(self, plant):
        plant.phase_resistance_ohm *= 1.0 + self.alpha_per_k * self.temperature_rise_k


@dataclass(frozen=True)
class MagnetTemperature(Effect):
    """Magnets weaken when hot: k_e = k_e_nominal * (1 + alpha_br * temperature_rise_k).

    alpha_br = -0.0012/K for NdFeB. Fingerprint: no edge signature; higher speed per duty and
    more current per torque.
    """

    name: ClassVar[str] = "magnet_temperature"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current versus duty; none in edge angles",
        "scales_with": "run time (heat soak)",
        "knob": "heat soak",
    }
    temperature_rise_k: float = bounded(0.0, low=-40.0, high=150.0, unit="K", doc="above the reference temperature")
    alpha_br_per_k: float = bounded(-0.0012, low=-0.005, high=0.0, unit="1/K", doc="remanence temperature coefficient")

    def contribute(self, plant):
        plant.ke_v_s_per_rad *= 1.0 + self.alpha_br_per_k * self.temperature_rise_k


@dataclass(frozen=True)
class DeadTime(Effect):
    """Inverter dead time: the PWM leg loses ``dead_time_s * f_pwm`` of duty per period.

    During the dead time a positive phase current freewheels through the lower diode, so the
    averaged terminal voltage of the PWM phase drops by dead_time_s * f_pwm * V_dc (rises when
    the current is negative). Fingerprint: no edge signature; a speed deficit at low duty.
    """

    name: ClassVar[str] = "dead_time"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed versus duty offset; none in edge angles",
        "scales_with": "PWM frequency and supply voltage",
        "knob": "f_pwm, V_dc",
    }
    dead_time_s: float = bounded(0.0, low=0.0, high=5e-6, unit="s", doc="dead time per switching event")

    def contribute(self, plant):
        plant.dead_time_s += self.dead_time_s


@dataclass(frozen=True)
class Saturation(Effect):
    """Iron saturation: the phase inductance falls with current.

    L(i) = L * max(min_inductance_fraction, 1 / (1 + (|i| / saturation_current_a)^2)).
    Fingerprint: no edge signature; faster current rise and commutation above the knee.
    """

    name: ClassVar[str] = "saturation"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "current waveform above a threshold; none in edge angles",
        "scales_with": "phase current above the knee",
        "knob": "current threshold (load)",
    }
    saturation_current_a: float = bounded(20.0, low=0.1, high=1e3, unit="A", doc="knee current")
    min_inductance_fraction: float = bounded(1.0, low=0.1, high=1.0, unit="1", doc="floor of L(i)/L (1 = none)")

    def contribute(self, plant):
        plant.saturation_current_a = self.saturation_current_a
        plant.min_inductance_fraction = self.min_inductance_fraction


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        InstallationOffset,
        PoleOffset,
        SensorPoleOffset,
        ConditioningDelay,
        ArmatureReaction,
        Hysteresis,
        SwitchingAsymmetry,
        EdgeJitter,
        TimerQuantization,
        Eccentricity,
        CoggingTorque,
        WindingTemperature,
        MagnetTemperature,
        DeadTime,
        Saturation,
    )
}

_CIRCUIT_KEYS = {f.name for f in dataclasses.fields(ConditioningCircuit)}


def effect_from_mapping(data: Mapping[str, Any], prefix: str = "effects[0].") -> Effect:
    """Build an effect from a TOML table ``{name = "...", <params>}``; errors name the field."""
    data = dict(data)
    name = data.pop("name", None)
    if name is None:
        raise ConfigError(f"{prefix}name", "missing effect name")
    cls = EFFECTS.get(name)
    if cls is None:
        raise ConfigError(f"{prefix}name", f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
    if cls is ConditioningDelay and set(data) & _CIRCUIT_KEYS:
        circuit = from_mapping(ConditioningCircuit, data, prefix)
        return ConditioningDelay.from_circuit(circuit)
    if hasattr(cls, "from_mapping"):  # an effect with nested tables (hall_field)
        return cls.from_mapping(data, prefix)
    return from_mapping(cls, data, prefix)


def effects_strategy(pole_pairs: int = 2, names: tuple[str, ...] | None = None, min_size: int = 0):
    """Hypothesis strategy for a composed effect set (each effect at most once)."""
    from hypothesis import strategies as st

    names = tuple(names or EFFECTS)
    return st.lists(st.sampled_from(names), min_size=min_size, max_size=len(names), unique=True).flatmap(
        lambda chosen: st.tuples(*[EFFECTS[n].strategy(pole_pairs) for n in chosen])
    )
