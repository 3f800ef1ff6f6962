"""The campaign SPEC (TOML): what is swept, what stays fixed, which budgets judge each point.

    [campaign]
    name = "offset-by-speed"
    seed = 7                      # every point's seed is drawn from it (see grid.point_seed)
    kind = "deviations"           # or "fault_sequence"
    plant = "paper-bench"         # a preset, or a plant TOML file (relative to the SPEC)
    budgets_file = "limits.toml"  # optional: budgets over the defaults (relative to the SPEC)
    run_s = 0.1                   # judged hold after the 0.1 s settle (deviations)
    repeats = 1                   # seeds per grid cell

    [campaign.budgets]            # budget name = metric it judges (hil.bench.stimulus.METRICS)
    commutation_angle_p99 = "angle_p99"

    [fixed]                       # what every point shares
    speed_rpm = 6000.0
    load_scale = 1.0
    strategy = "corrected"       # raw, corrected, kf, sage_husa
    effects = [{ name = "conditioning_delay", rise_delay_s = 6.6e-6, fall_delay_s = 2.0e-6 }]

    [[axis]]
    name = "installation_offset.offset_deg_e"   # an effect parameter ...
    linspace = [0.0, 8.0, 9]                    # ... or values = [...]
    pattern = [1.0, -0.6, 0.3]                  # list parameters: the point's value times this

    [[axis]]
    name = "speed_rpm"                          # or load_scale, strategy, fault_hold_s, fault.<param>
    values = [2000.0, 6000.0, 10000.0]

    [map]
    x = "installation_offset.offset_deg_e"
    y = "speed_rpm"
    budget = "commutation_angle_p99"            # default: the first budget

Every error names the file and the key (``spec.toml: axis[1].linspace: ...``; an unknown key, as
every TOML file's, in TOML's notation: ``spec.toml: [[axis]][1].step: unknown key ...``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bldc.contract import strategy_named
from bldc.params import ConfigError
from bldc.tomlfile import ANY_KEY, load_toml
from plant_models import PRESETS, PlantConfig
from plant_models.effects import EFFECTS, effect_from_mapping

from ..bench.stimulus import DEFAULT_BUDGETS, METRICS
from ..dut.faults import WIRING_FAULTS, wiring_fault_from_dict
from ..verdicts.budgets import Budgets

#: operating-point axes (not effect parameters)
OPERATING_AXES = ("speed_rpm", "load_scale", "strategy", "fault_hold_s")
#: what a point runs: a deviation set judged on its commutation, or a wiring fault switched on and off
KINDS = ("deviations", "fault_sequence")


@dataclass(frozen=True)
class Axis:
    name: str
    values: tuple                          #: the swept values (numbers, or strategy names)
    pattern: tuple[float, ...] | None = None  #: list parameters: value * pattern

    @property
    def effect(self) -> str | None:
        """The effect this axis sweeps a parameter of (None for operating-point axes)."""
        head, _, _ = self.name.partition(".")
        return None if self.name in OPERATING_AXES or head == "fault" else head

    @property
    def categorical(self) -> bool:
        return any(isinstance(v, str) for v in self.values)


@dataclass(frozen=True)
class MapSpec:
    x: str
    y: str
    budget: str


@dataclass(frozen=True)
class CampaignSpec:
    path: str
    name: str
    seed: int
    kind: str
    plant: PlantConfig
    budgets: Budgets
    checked: dict[str, str]                 #: budget name -> metric
    fixed_speed_rpm: float
    fixed_load_scale: float
    fixed_strategy: str
    fixed_effects: tuple[dict, ...]         #: effect tables (name + parameters)
    fixed_fault: dict | None
    fixed_fault_hold_s: float
    axes: tuple[Axis, ...]
    map: MapSpec | None
    run_s: float = 0.1
    repeats: int = 1
    budgets_file: str | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @property
    def size(self) -> int:
        return math.prod(len(a.values) for a in self.axes) * self.repeats


def _number(where: str, v: Any, low: float = -math.inf, high: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not low <= v <= high:
        bounds = f" within [{low:g}, {high:g}]" if math.isfinite(low) or math.isfinite(high) else ""
        raise ConfigError(where, f"must be a finite number{bounds}, got {v!r}")
    return float(v)


def _table(where: str, v: Any) -> dict:
    if not isinstance(v, dict):
        raise ConfigError(where, "must be a table")
    return v


#: the keys a SPEC may hold (bldc.tomlfile): ``[campaign.budgets]`` names any budget
SCHEMA = {
    "campaign": {"name": None, "seed": None, "kind": None, "plant": None, "budgets_file": None, "run_s": None,
                 "repeats": None, "budgets": {ANY_KEY: None}},
    "fixed": {"speed_rpm", "load_scale", "strategy", "effects", "fault", "fault_hold_s"},
    "axis": [{"name", "values", "linspace", "pattern"}],
    "map": {"x", "y", "budget"},
}


def _strategy(where: str, v: Any) -> str:
    """The strategy's name as bldc.contract spells it (``sage-husa`` is read as ``sage_husa``)."""
    try:
        return strategy_named(v).name.lower()
    except ValueError as exc:
        raise ConfigError(where, str(exc)) from None


def _axis(where: str, t: dict, kind: str) -> Axis:
    """One ``[[axis]]``: what it sweeps, its values (numbers within the axis's bounds, or strategy
    names) and, for a list parameter of an effect, its pattern."""
    name = t.get("name")
    if not isinstance(name, str) or not name:
        raise ConfigError(
            f"{where}.name",
            "required (an effect parameter such as installation_offset.offset_deg_e, or one of "
            f"{', '.join(OPERATING_AXES)}, or fault.<param>)",
        )
    values = _axis_values(where, t, name)
    if name.startswith("fault") and kind != "fault_sequence":
        raise ConfigError(f"{where}.name", f'{name!r} sweeps a wiring fault: set [campaign] kind = "fault_sequence"')
    pattern = None
    if "pattern" in t:
        p = t["pattern"]
        if not isinstance(p, list) or not p:
            raise ConfigError(f"{where}.pattern", "must be a non-empty list of numbers")
        pattern = tuple(_number(f"{where}.pattern[{i}]", v) for i, v in enumerate(p))
    axis = Axis(name, values, pattern)
    if axis.effect is not None:
        _check_effect_parameter(where, name, pattern)
    elif pattern is not None:
        raise ConfigError(f"{where}.pattern", f"{name} is not a list parameter: no pattern")
    return axis


def _axis_values(where: str, t: dict, name: str) -> tuple:
    """An axis's ``values`` or ``linspace``: distinct, within the bounds of the operating axes."""
    if ("values" in t) == ("linspace" in t):
        raise ConfigError(where, "give exactly one of 'values' or 'linspace'")
    if "linspace" in t:
        ls = t["linspace"]
        if (
            not isinstance(ls, list)
            or len(ls) != 3
            or isinstance(ls[2], bool)
            or not isinstance(ls[2], int)
            or ls[2] < 1
        ):
            raise ConfigError(f"{where}.linspace", f"must be [start, stop, count >= 1], got {ls!r}")
        a, b = _number(f"{where}.linspace[0]", ls[0]), _number(f"{where}.linspace[1]", ls[1])
        n = ls[2]
        values = tuple(a + (b - a) * i / (n - 1) if n > 1 else a for i in range(n))
    else:
        vs = t["values"]
        if not isinstance(vs, list) or not vs:
            raise ConfigError(f"{where}.values", "must be a non-empty list")
        if name == "strategy":
            values = tuple(_strategy(f"{where}.values[{i}]", v) for i, v in enumerate(vs))
        else:
            values = tuple(_number(f"{where}.values[{i}]", v) for i, v in enumerate(vs))
    if len(set(values)) != len(values):
        raise ConfigError(where, "repeated values (use [campaign] repeats for more seeds per point)")
    if name == "strategy" and "linspace" in t:
        raise ConfigError(f"{where}.linspace", "strategy takes values = [names]")
    if name == "speed_rpm":
        for i, v in enumerate(values):
            _number(f"{where}.values[{i}]", v, 100.0, 30000.0)
    if name in ("load_scale",):
        for i, v in enumerate(values):
            _number(f"{where}.values[{i}]", v, 0.0, 10.0)
    return values


def _check_effect_parameter(where: str, name: str, pattern: tuple[float, ...] | None) -> None:
    """``effect.param`` names a parameter of a known effect; a list parameter has a pattern, a number none."""
    effect, _, param = name.partition(".")
    cls = EFFECTS.get(effect)
    if cls is None:
        raise ConfigError(
            f"{where}.name",
            f"unknown effect {effect!r} (known: {', '.join(EFFECTS)}) and not an operating axis "
            f"({', '.join(OPERATING_AXES)})",
        )
    fields = {f.name: f for f in dataclasses.fields(cls)}
    if param not in fields:
        raise ConfigError(
            f"{where}.name", f"effect {effect!r} has no parameter {param!r} (has: {', '.join(fields)})"
        )
    is_list = "tuple" in str(fields[param].type)
    if is_list and pattern is None:
        raise ConfigError(
            f"{where}.pattern", f"{name} is a list parameter: give pattern = [...] (the point's value times it)"
        )
    if not is_list and pattern is not None:
        raise ConfigError(f"{where}.pattern", f"{name} is a single number: no pattern")


def load_spec(path: str | Path) -> CampaignSpec:
    path = Path(path)
    data = load_toml(path, SCHEMA)
    try:
        return parse_spec(data, path)
    except ConfigError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ConfigError(f"{path}: {exc.field}", str(exc)[len(exc.field) + 2 :]) from None


def parse_spec(data: dict, path: Path) -> CampaignSpec:
    """Validate the values of a SPEC whose keys ``load_toml`` checked against ``SCHEMA``; errors
    name the key (``load_spec`` prefixes the file)."""
    campaign = _campaign(_table("campaign", data.get("campaign", {})), path)
    fixed = _fixed(_table("fixed", data.get("fixed", {})), campaign["kind"], campaign["plant"])
    axes = _axes(data.get("axis", []), campaign["kind"])
    spec = CampaignSpec(
        path=str(path), **campaign, **fixed, axes=axes, map=_map(data.get("map"), axes, campaign["checked"]), raw=data
    )
    _check_axis_values(spec)
    return spec


def _campaign(c: dict, path: Path) -> dict[str, Any]:
    """``[campaign]``: the SPEC's name, seed, kind, plant, budgets and run length (CampaignSpec's fields)."""
    name = c.get("name", path.stem)
    if not isinstance(name, str):
        raise ConfigError("campaign.name", "must be a string")
    seed = c.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError("campaign.seed", f"must be a non-negative integer, got {seed!r}")
    kind = c.get("kind", "deviations")
    if kind not in KINDS:
        raise ConfigError("campaign.kind", f"must be one of {', '.join(KINDS)}, got {kind!r}")
    plant = _plant(c.get("plant", "paper-bench"), path)
    budgets_file, budgets = _budgets(c.get("budgets_file"), path)
    checked = _checked_budgets(c.get("budgets", DEFAULT_BUDGETS[kind]), kind, budgets)
    run_s = _number("campaign.run_s", c.get("run_s", 0.1), 0.06, 10.0)
    repeats = c.get("repeats", 1)
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ConfigError("campaign.repeats", f"must be an integer >= 1, got {repeats!r}")
    return dict(name=name, seed=seed, kind=kind, plant=plant, budgets=budgets, checked=dict(checked), run_s=run_s,
                repeats=repeats, budgets_file=budgets_file)


def _plant(ref: Any, path: Path) -> PlantConfig:
    """``campaign.plant``: a preset's name, or a plant TOML file relative to the SPEC."""
    if not isinstance(ref, str):
        raise ConfigError("campaign.plant", "must be a preset name or a plant TOML path")
    if ref in PRESETS:
        return PRESETS[ref]()
    plant_path = path.parent / ref
    if not plant_path.is_file():
        raise ConfigError("campaign.plant", f"neither a preset ({', '.join(PRESETS)}) nor a file: {plant_path}")
    return PlantConfig.from_toml(plant_path)


def _budgets(budgets_file: Any, path: Path) -> tuple[str | None, Budgets]:
    """``campaign.budgets_file`` (relative to the SPEC) as a path, and the budgets: its own over the
    defaults, or the defaults."""
    if budgets_file is None:
        return None, Budgets.defaults()
    if not isinstance(budgets_file, str) or not (path.parent / budgets_file).is_file():
        raise ConfigError("campaign.budgets_file", f"no such file: {path.parent / str(budgets_file)}")
    budgets_file = str(path.parent / budgets_file)
    return budgets_file, Budgets.from_toml(budgets_file)


def _checked_budgets(checked: Any, kind: str, budgets: Budgets) -> dict:
    """``[campaign.budgets]``: budget name -> the metric of the kind it judges; each a known budget."""
    _table("campaign.budgets", checked)
    if not checked:
        raise ConfigError("campaign.budgets", "name at least one budget")
    for b, metric in checked.items():
        if b not in budgets:
            raise ConfigError(f"campaign.budgets.{b}", f"no such budget (have: {', '.join(sorted(budgets.budgets))})")
        if metric not in METRICS[kind]:
            raise ConfigError(
                f"campaign.budgets.{b}",
                f"metric must be one of {', '.join(METRICS[kind])} for kind {kind!r}, got {metric!r}",
            )
    return checked


def _fixed(f: dict, kind: str, plant: PlantConfig) -> dict[str, Any]:
    """``[fixed]``: what every point shares (CampaignSpec's ``fixed_*`` fields)."""
    return dict(
        fixed_speed_rpm=_number("fixed.speed_rpm", f.get("speed_rpm", 6000.0), 100.0, 30000.0),
        fixed_load_scale=_number("fixed.load_scale", f.get("load_scale", 1.0), 0.0, 10.0),
        fixed_strategy=_strategy("fixed.strategy", f.get("strategy", "corrected")),
        fixed_effects=_fixed_effects(f.get("effects", []), plant),
        fixed_fault=_fixed_fault(f.get("fault"), kind),
        fixed_fault_hold_s=_number("fixed.fault_hold_s", f.get("fault_hold_s", 0.02), 0.0, 10.0),
    )


def _fixed_effects(effects: Any, plant: PlantConfig) -> tuple[dict, ...]:
    """``fixed.effects``: effect tables, each valid on the plant, no effect twice."""
    if not isinstance(effects, list):
        raise ConfigError("fixed.effects", "must be a list of effect tables")
    for i, e in enumerate(effects):
        effect_from_mapping(_table(f"fixed.effects[{i}]", e), f"fixed.effects[{i}].").check(
            plant.motor.pole_pairs, f"fixed.effects[{i}]."
        )
    names = [e["name"] for e in effects]
    if len(set(names)) != len(names):
        raise ConfigError("fixed.effects", "an effect appears twice")
    return tuple(effects)


def _fixed_fault(fault: Any, kind: str) -> dict | None:
    """``fixed.fault``: the wiring fault a ``fault_sequence`` campaign switches (a name or a table),
    and none otherwise."""
    if fault is None:
        if kind == "fault_sequence":
            raise ConfigError(
                "fixed.fault", 'a fault_sequence campaign names its fault, e.g. fault = { name = "hall_spike" }'
            )
        return None
    if kind != "fault_sequence":
        raise ConfigError("fixed.fault", 'a wiring fault needs [campaign] kind = "fault_sequence"')
    if isinstance(fault, str):
        fault = {"name": fault}
    try:
        wiring_fault_from_dict(_table("fixed.fault", fault))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError("fixed.fault", f"not a wiring fault: {exc}") from None
    return fault


def _axes(raw_axes: Any, kind: str) -> tuple[Axis, ...]:
    """``[[axis]]``: at least one, none swept twice."""
    if not isinstance(raw_axes, list) or not raw_axes:
        raise ConfigError("axis", "at least one [[axis]] table")
    axes = tuple(_axis(f"axis[{i}]", _table(f"axis[{i}]", t), kind) for i, t in enumerate(raw_axes))
    seen = [a.name for a in axes]
    for i, n in enumerate(seen):
        if n in seen[:i]:
            raise ConfigError(f"axis[{i}].name", f"{n!r} is swept twice")
    return axes


def _map(m: Any, axes: tuple[Axis, ...], checked: dict) -> MapSpec | None:
    """``[map]``: two swept axes and a checked budget; without it, the first two axes and the first
    budget (none for one axis)."""
    seen = [a.name for a in axes]
    if m is None:
        return MapSpec(axes[0].name, axes[1].name, next(iter(checked))) if len(axes) >= 2 else None
    _table("map", m)
    for key in ("x", "y"):
        if m.get(key) not in seen:
            raise ConfigError(f"map.{key}", f"must name a swept axis ({', '.join(seen)}), got {m.get(key)!r}")
    if m["x"] == m["y"]:
        raise ConfigError("map.y", "x and y must differ")
    mb = m.get("budget", next(iter(checked)))
    if mb not in checked:
        raise ConfigError("map.budget", f"must be one of the checked budgets ({', '.join(checked)}), got {mb!r}")
    return MapSpec(m["x"], m["y"], mb)


def _check_axis_values(spec: CampaignSpec) -> None:
    """Every axis value must give a valid plant or fault: out-of-bounds values fail here, naming the axis."""
    for i, a in enumerate(spec.axes):
        if a.name.startswith("fault."):
            for j, v in enumerate(a.values):
                try:
                    wiring_fault_from_dict(point_fault(spec, {a.name: v}))
                except (KeyError, TypeError, ValueError) as exc:
                    raise ConfigError(
                        f"axis[{i}].name",
                        f"{a.name} = {v:g} is not a parameter of fault {spec.fixed_fault['name']!r}: {exc}",
                    ) from None
        if a.effect is not None:
            for j, v in enumerate(a.values):
                try:
                    point_plant(spec, {a.name: v})
                except ConfigError as exc:
                    raise ConfigError(f"axis[{i}].values[{j}]", f"{a.name} = {v:g}: {exc}") from None


def _effect_tables(spec: CampaignSpec, coords: dict) -> list[dict]:
    tables = {e["name"]: dict(e) for e in spec.fixed_effects}
    for a in spec.axes:
        if a.effect is None or a.name not in coords:
            continue
        param = a.name.partition(".")[2]
        v = coords[a.name]
        table = tables.setdefault(a.effect, {"name": a.effect})
        table[param] = [v * p for p in a.pattern] if a.pattern is not None else v
    return list(tables.values())


def point_plant(spec: CampaignSpec, coords: dict) -> PlantConfig:
    """The point's plant: the campaign plant with its pump load scaled and the effects applied."""
    load = coords.get("load_scale", spec.fixed_load_scale)
    base = spec.plant
    if load != 1.0:
        base = dataclasses.replace(
            base, motor=dataclasses.replace(base.motor, fan_coefficient_n_m_s2=base.motor.fan_coefficient_n_m_s2 * load)
        )
    effects = [effect_from_mapping(t, f"effects.{t['name']}.") for t in _effect_tables(spec, coords)]
    config = base.with_effects(*effects)
    for e in config.effects:
        e.check(config.motor.pole_pairs, f"effects.{e.name}.")
    return config


def point_fault(spec: CampaignSpec, coords: dict) -> dict:
    """The point's wiring fault (a table for ``wiring_fault_from_dict``)."""
    fault = dict(spec.fixed_fault or {})
    fields = {f.name: f for f in dataclasses.fields(WIRING_FAULTS[fault["name"]])}
    for a in spec.axes:
        if a.name.startswith("fault.") and a.name in coords:
            param = a.name.partition(".")[2]
            if param not in fields:
                raise KeyError(f"no parameter {param!r} (has: {', '.join(fields) or 'none'})")
            fault[param] = int(coords[a.name]) if isinstance(fields[param].default, int) else coords[a.name]
    return fault
