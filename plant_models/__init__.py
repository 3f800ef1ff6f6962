"""Plant models: BLDC motor, six-step inverter, Hall sensors with conditioning, and the effect library."""

from .effects import EFFECTS, ConditioningCircuit, Effect, effect_from_mapping, effects_strategy
from .edgelog import EdgeLog
from .hall_field import HallField
from .params import ConfigError
from .plant import (
    PRESETS,
    CompiledPlant,
    CurrentSensorParameters,
    InverterParameters,
    MotorParameters,
    PlantConfig,
    paper_bench,
)
from .simulation import Command, OracleCommutation, RawHallCommutation, Simulation, simulate

__all__ = [
    "EFFECTS",
    "ConditioningCircuit",
    "Effect",
    "effect_from_mapping",
    "effects_strategy",
    "EdgeLog",
    "ConfigError",
    "HallField",
    "PRESETS",
    "CompiledPlant",
    "CurrentSensorParameters",
    "InverterParameters",
    "MotorParameters",
    "PlantConfig",
    "paper_bench",
    "Command",
    "OracleCommutation",
    "RawHallCommutation",
    "Simulation",
    "simulate",
]
