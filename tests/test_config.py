"""Bad plant configuration is refused with a message naming the field."""

import math

import pytest

from plant_models import ConfigError, MotorParameters, PlantConfig, effect_from_mapping
from plant_models import effects as fx


def refuse(data, field):
    with pytest.raises(ConfigError) as info:
        PlantConfig.from_dict(data)
    assert info.value.field == field, str(info.value)
    assert field in str(info.value)
    return str(info.value)


def test_unknown_effect_is_named():
    msg = refuse({"effects": [{"name": "installation_offset"}, {"name": "flux_capacitor"}]}, "effects[1].name")
    assert "flux_capacitor" in msg and "installation_offset" in msg  # lists the known ones


def test_negative_resistance_is_refused():
    msg = refuse({"motor": {"phase_resistance_ohm": -0.1}}, "motor.phase_resistance_ohm")
    assert "> 0.0 ohm" in msg


def test_nan_is_refused():
    refuse({"motor": {"inertia_kg_m2": math.nan}}, "motor.inertia_kg_m2")
    refuse({"effects": [{"name": "hysteresis", "lag_deg_e": math.nan}]}, "effects[0].lag_deg_e")


@pytest.mark.parametrize("bad", [0, -2, 2.5, "2", True])
def test_pole_pairs_must_be_positive_integer(bad):
    refuse({"motor": {"pole_pairs": bad}}, "motor.pole_pairs")


def test_unknown_parameter_and_section():
    refuse({"motor": {"resistance": 1.0}}, "motor.resistance")
    refuse({"motr": {}}, "motr")
    refuse({"effects": [{"name": "hysteresis", "lag_deg": 1.0}]}, "effects[0].lag_deg")


def test_out_of_bounds_effect_parameter():
    msg = refuse(
        {"effects": [{"name": "installation_offset", "offset_deg_e": [0.0, 11.0, 0.0]}]}, "effects[0].offset_deg_e[1]"
    )
    assert "<= 10.0" in msg


def test_pole_offset_length_must_match_pole_pairs():
    refuse(
        {"motor": {"pole_pairs": 3}, "effects": [{"name": "pole_offset", "offset_deg_e": [0, 1, 2, 3]}]},
        "effects[0].offset_deg_e",
    )


def test_duplicate_effect_refused():
    with pytest.raises(ConfigError, match="given twice"):
        PlantConfig(effects=(fx.Hysteresis(1.0), fx.Hysteresis(0.5)))


def test_toml_file_errors_name_file_and_field(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text('preset = "paper-bench"\n[motor]\nphase_resistance_ohm = -1.0\n')
    with pytest.raises(ConfigError) as info:
        PlantConfig.from_toml(path)
    assert str(path) in str(info.value) and "motor.phase_resistance_ohm" in str(info.value)
    path.write_text("[motor\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        PlantConfig.from_toml(path)


def test_toml_round_trip_with_circuit(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text(
        'preset = "paper-bench"\n'
        "[motor]\npole_pairs = 2\n"
        '[[effects]]\nname = "conditioning_delay"\nr2_ohm = 10000.0\nc1_f = 1e-9\n'
        '[[effects]]\nname = "installation_offset"\noffset_deg_e = [1.0, -0.5, 0.25]\n'
    )
    config = PlantConfig.from_toml(path)
    delay = config.effect("conditioning_delay")
    assert delay.rise_delay_s > delay.fall_delay_s > 0
    assert config.effect("installation_offset").offset_deg_e == (1.0, -0.5, 0.25)
    assert (
        PlantConfig.from_dict(
            config.to_dict() | {"effects": [{k: v for k, v in e.to_dict().items()} for e in config.effects]}
        ).config_hash()
        == config.config_hash()
    )


def test_circuit_thresholds_checked():
    with pytest.raises(ConfigError, match="v_ih_v"):
        effect_from_mapping({"name": "conditioning_delay", "v_ih_v": 4.9}, "effects[0].")


def test_defaults_are_valid():
    PlantConfig()
    MotorParameters()


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"duty": math.nan}, "Simulation.duty"),
        ({"duty": 1.5}, "Simulation.duty"),
        ({"initial_speed_rpm": -5.0}, "Simulation.initial_speed_rpm"),
        ({"sample_rate_hz": 0.0}, "Simulation.sample_rate_hz"),
        ({"direction": 0}, "Simulation.direction"),
    ],
)
def test_simulation_arguments_are_checked(kwargs, field):
    from plant_models import Simulation

    with pytest.raises(ConfigError) as info:
        Simulation(PlantConfig(), **kwargs)
    assert info.value.field == field


def test_kinematic_profile_is_checked():
    from plant_models.kinematic import OperatingPoint, simulate_edges

    with pytest.raises(ConfigError, match=r"profile\[1\].duration_s"):
        simulate_edges(PlantConfig(), [OperatingPoint(0.1, 1000.0), OperatingPoint(-1.0, 1000.0)])
    with pytest.raises(ConfigError, match=r"profile\[0\].speed_rpm"):
        simulate_edges(PlantConfig(), [OperatingPoint(0.1, math.inf)])


from hypothesis import given  # noqa: E402

from plant_models import effects_strategy  # noqa: E402


@given(effects_strategy(pole_pairs=2))
def test_drawn_effect_sets_stay_inside_bounds_and_build(effects):
    """Every strategy draws valid effects; any composition builds a plant (no duplicates)."""
    config = PlantConfig(effects=tuple(effects))  # validates each effect against its bounds
    compiled = config.compile()
    assert compiled.pole_offset_deg_e.shape == (4,)
    assert len({e.name for e in effects}) == len(effects)


@given(effects_strategy(pole_pairs=3, names=("pole_offset", "eccentricity")))
def test_pole_strategies_follow_pole_count(effects):
    from plant_models import MotorParameters

    PlantConfig(motor=MotorParameters(pole_pairs=3), effects=tuple(effects))


def test_the_strict_toml_loader_names_file_line_table_and_key(tmp_path):
    """bldc.tomlfile.load_toml: one error type for every TOML file, saying where in TOML's own notation."""
    from bldc.tomlfile import ANY_KEY, TomlError, load_toml

    path = tmp_path / "f.toml"
    schema = {"top": {"inner": {"x"}}, "w": [{"a", "b"}], ANY_KEY: {"limit"}}
    cases = [
        ("[top.inner]\ny = 1\n", "[top.inner]", "y", "unknown key (known: x)"),
        ("[[w]]\na = 1\n[[w]]\nc = 2\n", "[[w]][1]", "c", "unknown key (known: a, b)"),
        ("[w]\na = 1\n", None, "w", "an array of tables: write [[w]]"),
        ("[anything]\nlimt = 1\n", "[anything]", "limt", "unknown key (known: limit)"),
        ("top = 3\n", None, "top", "must be a table ([top]), got 3"),
    ]
    for text, table, key, words in cases:
        path.write_text(text)
        with pytest.raises(TomlError) as info:
            load_toml(path, schema)
        e = info.value
        assert (e.file, e.table, e.key) == (str(path), table, key) and words in str(e), str(e)
        assert str(e).startswith(f"{path}: {table + '.' if table else ''}{key}: "), str(e)
    path.write_text('a = 1\n\n[b\n')
    with pytest.raises(TomlError, match="not valid TOML") as info:
        load_toml(path)
    assert info.value.line == 3 and isinstance(info.value, ConfigError)
    path.write_bytes("\ufeffa = 'é'\n".encode())  # a byte-order mark is tolerated, the text is UTF-8
    assert load_toml(path, {"a"}) == {"a": "é"}
    path.write_bytes(b"a = '\xe9'\n")
    with pytest.raises(TomlError, match="not UTF-8"):
        load_toml(path)
    with pytest.raises(TomlError, match="cannot read"):
        load_toml(tmp_path / "missing.toml")
