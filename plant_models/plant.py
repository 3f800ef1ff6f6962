"""Plant configuration: nominal motor, inverter and current sensors, plus a list of effects."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from bldc.motor import MotorParameters
from bldc.params import ConfigError, bounded, from_mapping, validate
from bldc.tomlfile import load_toml

from . import effects as fx
from .compiled import CompiledPlant
from .effects import ConditioningCircuit, Effect, effect_from_mapping


@dataclass(frozen=True)
class InverterParameters:
    """Six-step (two-phase, 120 deg) inverter, H_PWM-L_ON with synchronous rectification.

    Averaged over a PWM period: the PWM phase sits at duty * V_dc, the low phase at 0, and the
    floating phase freewheels through its diodes (0 V for positive current, V_dc for negative)
    until its current dies, then shows the neutral voltage plus its own back-EMF.
    """

    pwm_frequency_hz: float = bounded(20e3, low=0.0, high=1e6, unit="Hz", low_open=True, doc="PWM carrier")
    #: the paper bench's switches are Infineon IPB200N25N3 G (paper Section 4.1): 64 A continuous drain
    #: current at 25 C case (Infineon datasheet IPB200N25N3 G, rev. 2.x, "I_D")
    switch_current_rating_a: float = bounded(
        64.0, low=0.0, high=1e4, unit="A", low_open=True, doc="continuous current rating of the inverter's switches"
    )


@dataclass(frozen=True)
class CurrentSensorParameters:
    """Phase current transducers (LA25-P: accuracy +-0.65 %); applied to the sampled currents."""

    gain_error: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-0.05, high=0.05, unit="1", length=3, doc="relative gain error A, B, C"
    )
    offset_a: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-1.0, high=1.0, unit="A", length=3, doc="offset A, B, C"
    )
    noise_rms_a: float = bounded(0.0, low=0.0, high=1.0, unit="A", doc="white noise RMS per sample")
    #: the paper bench's LA25-P measures 0-25 A (paper Table 1)
    range_a: float = bounded(25.0, low=0.0, high=1e4, unit="A", low_open=True,
                             doc="measurement range: a current beyond it is not seen by the controller")


#: The deviations a calibration table holds (paper Sections 2.1-2.4).
CALIBRATED_DEVIATIONS = ("installation_offset", "pole_offset", "conditioning_delay", "armature_reaction")

#: Mechanical turns every settling window holds (``PlantConfig.suite_settle_s``): two to learn the
#: pole alignment (one whole turn compared, after one to fill it) and one of aligned commutation.
SETTLE_MECHANICAL_TURNS = 3.0

#: The paper pump's service range tops out at 10,000 rpm (Section 4.1: 5000-10,000 rpm) on its
#: 2 pole pairs. The acceptance suite and the calibration campaign are written at its speeds.
PAPER_TOP_SPEED_RPM = 10000.0
PAPER_POLE_PAIRS = 2


@dataclass(frozen=True)
class OperatingRange:
    """Where this motor runs in service. The acceptance suite and the calibration campaign name the
    paper pump's speeds; on another motor they run at the same fractions of its top speed, and each
    window holds at least the electrical periods it holds on the paper pump (``PlantConfig.suite_speed_rpm``,
    ``suite_duration_s``). A twin of a capture tops out at the capture's own top speed unless told."""

    top_speed_rpm: float = bounded(
        PAPER_TOP_SPEED_RPM, low=0.0, high=200_000.0, unit="rpm", low_open=True,
        doc="the fastest the motor runs in service",
    )


@dataclass(frozen=True)
class PlantConfig:
    motor: MotorParameters = field(default_factory=MotorParameters)
    inverter: InverterParameters = field(default_factory=InverterParameters)
    current_sensor: CurrentSensorParameters = field(default_factory=CurrentSensorParameters)
    effects: tuple[Effect, ...] = ()
    name: str = "custom"
    operating: OperatingRange = field(default_factory=OperatingRange)

    def __post_init__(self):
        validate(self.motor, "motor.")
        validate(self.inverter, "inverter.")
        validate(self.current_sensor, "current_sensor.")
        validate(self.operating, "operating.")
        seen: set[str] = set()
        for i, eff in enumerate(self.effects):
            prefix = f"effects[{i}]."
            if not isinstance(eff, Effect):
                raise ConfigError(f"effects[{i}]", f"not an effect: {eff!r}")
            if eff.name in seen:
                raise ConfigError(f"{prefix}name", f"effect {eff.name!r} given twice; combine its parameters")
            seen.add(eff.name)
            eff.check(self.motor.pole_pairs, prefix)

    def with_effects(self, *effects: Effect) -> "PlantConfig":
        """A copy with ``effects`` added (replacing any effect of the same name)."""
        names = {e.name for e in effects}
        kept = tuple(e for e in self.effects if e.name not in names)
        return dataclasses.replace(self, effects=kept + tuple(effects))

    def effect(self, name: str) -> Effect | None:
        return next((e for e in self.effects if e.name == name), None)

    @property
    def top_electrical_hz(self) -> float:
        return self.operating.top_speed_rpm / 60.0 * self.motor.pole_pairs

    def suite_speed_rpm(self, paper_rpm: float) -> float:
        """The speed at which a step written at the paper pump's ``paper_rpm`` runs on this motor: the
        same fraction of the top speed (identity on the paper pump)."""
        return paper_rpm * (self.operating.top_speed_rpm / PAPER_TOP_SPEED_RPM)

    @property
    def suite_time_scale(self) -> float:
        """How much longer a window must be on this motor than on the paper pump to hold as many
        electrical periods (edges): the paper pump's top electrical frequency over this motor's, never
        below 1."""
        paper_top_hz = PAPER_TOP_SPEED_RPM / 60.0 * PAPER_POLE_PAIRS
        return max(1.0, paper_top_hz / self.top_electrical_hz)

    def suite_duration_s(self, paper_s: float) -> float:
        """A window written for the paper pump, stretched by ``suite_time_scale``; never shortened."""
        return paper_s * self.suite_time_scale

    def suite_settle_s(self, paper_s: float, speed_rpm: float) -> float:
        """A settling window written for the paper pump (before anything is judged, from a start or
        a resynchronisation), as ``suite_duration_s`` stretches it, and at least
        ``SETTLE_MECHANICAL_TURNS`` turns at ``speed_rpm``: a controller that reads only Hall edges
        learns which electrical period holds its calibration's pole N1 over whole mechanical turns,
        and a rotor of many pole pairs turns those slowly (the paper pump's windows all hold more)."""
        return max(self.suite_duration_s(paper_s), SETTLE_MECHANICAL_TURNS * 60.0 / speed_rpm)

    def suite_deviations(self, effects) -> tuple[Effect, ...]:
        """The acceptance suite's deviations (written for the paper pump) as they stand on this motor.

        A deviation a calibration table holds that this motor carries itself (a twin's measured
        installation and pole tables, its real delay) is the motor's: the suite's of that name is left
        out, so the plant's own stays in force. A pole table written for another pole count repeats
        around this rotor (``paper_pole_offsets_deg_e``'s rule). A time jitter stretches like a window
        (``suite_duration_s``), so that it is the same angle at the same fraction of the top speed.
        Every other effect passes unchanged."""
        kept = []
        for eff in effects:
            if eff.name in CALIBRATED_DEVIATIONS and self._carries(eff.name):
                continue
            if isinstance(eff, fx.EdgeJitter) and eff.time_rms_s > 0.0:
                eff = dataclasses.replace(eff, time_rms_s=self.suite_duration_s(eff.time_rms_s))
            if isinstance(eff, fx.PoleOffset) and len(eff.offset_deg_e) != 2 * self.motor.pole_pairs:
                eff = dataclasses.replace(eff, offset_deg_e=around_the_rotor(eff.offset_deg_e, self.motor.pole_pairs))
            kept.append(eff)
        return tuple(kept)

    def _carries(self, name: str) -> bool:
        """The motor carries a deviation of this name that is not all zeros."""
        own = self.effect(name)
        if own is None:
            return False
        values = [v for k, v in own.to_dict().items() if k != "name"]
        return bool(np.any(np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in values]) != 0.0))

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "motor": dataclasses.asdict(self.motor),
            "inverter": dataclasses.asdict(self.inverter),
            "current_sensor": {
                k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self.current_sensor).items()
            },
            "effects": [e.to_dict() for e in self.effects],
            "operating": dataclasses.asdict(self.operating),
        }

    def config_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "PlantConfig":
        known = {"name", "motor", "inverter", "current_sensor", "effects", "preset", "operating"}
        for key in data:
            if key not in known:
                raise ConfigError(key, f"unknown section (known: {', '.join(sorted(known))})")
        if "preset" in data and data["preset"] not in PRESETS:
            raise ConfigError("preset", f"unknown preset {data['preset']!r} (known: {', '.join(PRESETS)})")
        base = PRESETS[data["preset"]]() if "preset" in data else cls()

        def merged(section: str, current):
            table = data.get(section, {})
            if not isinstance(table, Mapping):
                raise ConfigError(section, "expected a table")
            return from_mapping(type(current), {**dataclasses.asdict(current), **table}, f"{section}.")

        effects = data.get("effects", None)
        if effects is None:
            eff = base.effects
        else:
            if not isinstance(effects, list):
                raise ConfigError("effects", "expected an array of tables [[effects]]")
            eff = tuple(effect_from_mapping(e, f"effects[{i}].") for i, e in enumerate(effects))
        return cls(
            motor=merged("motor", base.motor),
            inverter=merged("inverter", base.inverter),
            current_sensor=merged("current_sensor", base.current_sensor),
            effects=eff,
            name=str(data.get("name", base.name)),
            operating=merged("operating", base.operating),
        )

    @classmethod
    def from_toml(cls, path: str | Path) -> "PlantConfig":
        path = Path(path)
        data = load_toml(path)  # from_dict knows the sections and parameters
        try:
            return cls.from_dict(data)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc.field}", str(exc).split(": ", 1)[1]) from None

    def compile(self) -> CompiledPlant:
        """The flat numeric view the kernels read, with every effect folded in."""
        m, inv = self.motor, self.inverter
        plant = CompiledPlant(
            pole_pairs=int(m.pole_pairs),
            phase_resistance_ohm=m.phase_resistance_ohm,
            phase_inductance_h=m.phase_inductance_h,
            ke_v_s_per_rad=m.ke_v_s_per_rad,
            flat_top_deg_e=m.flat_top_deg_e,
            inertia_kg_m2=m.inertia_kg_m2,
            friction_n_m_s_per_rad=m.friction_n_m_s_per_rad,
            fan_coefficient_n_m_s2=m.fan_coefficient_n_m_s2,
            supply_v=m.supply_v,
            pwm_frequency_hz=inv.pwm_frequency_hz,
            sensor_offset_deg_e=np.zeros(3),
            pole_offset_deg_e=np.zeros(2 * int(m.pole_pairs)),
            switch_offset_deg_e=np.zeros((3, 2 * int(m.pole_pairs), 2)),
        )
        for eff in self.effects:
            eff.contribute(plant)
        return plant


# --- presets -------------------------------------------------------------------------------

#: Component values of the paper-bench conditioning circuit (paper Fig. 3a leaves them open).
PAPER_BENCH_CIRCUIT = ConditioningCircuit()


def paper_bench(with_deviations: bool = False) -> PlantConfig:
    """The paper's hydrogen circulation pump bench (Section 4.1), values documented in docs/plant.md.

    80 V, 2 pole pairs, rated 15,000 rpm, J = 0.0039 kg m^2, fan load; R = 65.5 mOhm (the
    paper's "65.5 ohm" cannot carry the measured ~4-10 A at 80 V). With ``with_deviations``
    the Hall deviations are of the size the paper reports (Tables 2-4) plus its conditioning
    circuit and a LA25-P-like current sensor.
    """
    config = PlantConfig(name="paper-bench")
    if not with_deviations:
        return config
    return dataclasses.replace(
        config,
        name="paper-bench+deviations",
        current_sensor=CurrentSensorParameters(
            gain_error=(0.004, -0.003, 0.002), offset_a=(0.02, -0.015, 0.01), noise_rms_a=0.02
        ),
        effects=(
            fx.InstallationOffset(offset_deg_e=paper_installation_offsets_deg_e()),
            fx.PoleOffset(offset_deg_e=paper_pole_offsets_deg_e()),
            fx.ConditioningDelay.from_circuit(PAPER_BENCH_CIRCUIT),
            fx.ArmatureReaction(slope_deg_e_per_a=0.35),
            fx.EdgeJitter(time_rms_s=1e-6),
            fx.TimerQuantization(tick_s=1e-7),
        ),
    )


#: The paper prints Tables 2 and 4 as percentages without naming the base; we read them as
#: percent of one commutation interval (60 deg electrical), the quantity the controller times.
PAPER_PERCENT_BASE_DEG_E = 60.0
#: Table 3, weighted sum: relative deviations phi_min of the rising edges A1, B1, C1 (Eq. 2).
PAPER_TABLE3_RELATIVE_DEG_E = (-0.930, 0.021, 0.908)
#: Table 4, weighted sum: A rising edge trails the falling e_BC zero crossing by this percentage.
PAPER_TABLE4_ABSOLUTE_PERCENT = 4.22
#: Table 2, weighted sum: phi_N1-f, phi_N2-r, phi_N2-f of Eq. 6 (ideal minus actual, so
#: positive = the edge leads).
PAPER_TABLE2_POLE_PERCENT = (1.59, 0.03, 0.22)


def paper_installation_offsets_deg_e() -> tuple[float, float, float]:
    """Installation offsets consistent with Tables 3 and 4 through Eq. 5."""
    absolute_a = PAPER_TABLE4_ABSOLUTE_PERCENT / 100.0 * PAPER_PERCENT_BASE_DEG_E
    rel = PAPER_TABLE3_RELATIVE_DEG_E
    return tuple(absolute_a + rel[x] - rel[0] for x in range(3))  # Eq. 5


def paper_pole_offsets_deg_e(pole_pairs: int = PAPER_POLE_PAIRS) -> tuple[float, ...]:
    """Pole offsets of Table 2 in our convention (positive = trails; pole N1 = 0), one per magnet pole.

    On a rotor with more poles than the paper's four, its four-pole pattern repeats around the
    rotor (the last repetition cut short), so every pole carries a deviation of the paper's size."""
    paper = (0.0,) + tuple(-pct / 100.0 * PAPER_PERCENT_BASE_DEG_E for pct in PAPER_TABLE2_POLE_PERCENT)
    return around_the_rotor(paper, pole_pairs)


def around_the_rotor(pole_offsets_deg_e, pole_pairs: int) -> tuple[float, ...]:
    """A pole table written for another pole count, on a rotor of ``pole_pairs``: its pattern repeats
    around the rotor, the last repetition cut short (one entry per magnet pole)."""
    n = len(pole_offsets_deg_e)
    return tuple(float(pole_offsets_deg_e[k % n]) for k in range(2 * int(pole_pairs)))


PRESETS = {"paper-bench": paper_bench, "paper-bench+deviations": lambda: paper_bench(True)}
