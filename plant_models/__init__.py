"""Plant models: BLDC motor, six-step inverter, Hall sensors with conditioning, and the effect library."""

from bldc.contract import Command
from bldc.params import ConfigError
from plant_models.simulation import OracleCommutation, RawHallCommutation, Simulation, simulate

from .edgelog import EdgeLog
from .effects import EFFECTS, ConditioningCircuit, Effect, effect_from_mapping, effects_strategy
from .hall_field import HallField
from .plant import (
    PRESETS,
    CompiledPlant,
    CurrentSensorParameters,
    InverterParameters,
    MotorParameters,
    PlantConfig,
    paper_bench,
)

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
