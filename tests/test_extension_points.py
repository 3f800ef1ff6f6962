"""Each extension point is one place (docs/architecture.md, "Where a new thing goes"): a toy effect,
a toy predictor and a toy capture format, each registered in its one table and nowhere else, are
diagnosed, compared and read by the code that never heard of them. The toy effect goes through
every route an effect has: diagnosed by the gap engine on a recording that carries it, made by a
twin, swept by a campaign, listed by ``hil effects`` and documented from its declaration."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Mapping

import numpy as np
import pytest

from bldc.params import bounded
from bldc.reasons import words
from plant_models import effects as fx
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint


# --- a toy effect: every falling edge trails by a constant angle, rising edges untouched ---------------

@dataclass(frozen=True)
class FallingLag(fx.Effect):
    """Falling edges trail by ``lag_deg_e`` in either direction of rotation; rising ones do not move."""

    name: ClassVar[str] = "falling_lag"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "falling edges trail, rising edges do not",
        "scales_with": "nothing (constant in angle)",
        "knob": "-",
    }
    knob_record: ClassVar[str] = "a segment in reverse"
    knob_shows: ClassVar[str] = "a falling lag moves the falling edges alone, in either direction"
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("lag_deg_e",)
    #: a toy's twin takes it from its base (what the twin measures is the library's effects)
    capture_blind: ClassVar[str] = "a toy the twin does not measure"
    lag_deg_e: float = bounded(0.0, low=0.0, high=10.0, unit="deg_e", doc="lag of every falling edge")

    @classmethod
    def edge_signature(cls):
        return fx.EdgeSignature(
            lambda c: (1.0 - np.asarray(c["rising"], dtype=float))[:, None],
            lambda k: {"lag_deg_e": float(k[0])},
            fx.not_below(cls, "lag_deg_e"),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(1.0)

    def contribute(self, plant):
        # a hysteresis of half the lag (every edge trails by it, both ways) and a switching asymmetry
        # of minus the lag (rising edges lead by half, falling trail by half, both ways): falling edges
        # trail by all of it, rising ones stay (the plants' hysteresis is a band: never negative)
        half = 0.5 * self.lag_deg_e
        parity = np.where(np.arange(2 * plant.pole_pairs) % 2 == 0, 1.0, -1.0)
        plant.switch_offset_deg_e = plant.switch_offset_deg_e - half * parity[None, :, None]
        plant.hysteresis_deg_e += half


def test_a_toy_effect_registered_in_the_library_alone_is_drawn_and_diagnosed(monkeypatch):
    from hil.gap.candidates import CANDIDATES
    from hil.gap.diagnose import diagnose_segments, knob
    from hil.gap.synthetic import KNOWN_MODEL, param_error
    from hil.gap.validate import effect_names, make_case

    assert "falling_lag" not in CANDIDATES
    monkeypatch.setitem(fx.EFFECTS, FallingLag.name, FallingLag)
    assert "falling_lag" in CANDIDATES and "falling_lag" in effect_names()  # diagnosed, and validated
    rec, truth = make_case(["falling_lag"], 8.0, seed=3)  # the validation's own draw and scaling
    assert isinstance(truth[0], FallingLag) and truth[0].lag_deg_e > 0
    d = diagnose_segments(rec, KNOWN_MODEL)
    assert d.significant and d.accepted[0].effect == "falling_lag", d.ranking
    assert param_error(truth[0], d.accepted[0]) < 0.2
    assert "a falling lag moves the falling edges alone" in knob("falling_lag", "conditioning_delay")


@pytest.fixture
def toy_effect(monkeypatch):
    monkeypatch.setitem(fx.EFFECTS, FallingLag.name, FallingLag)
    return FallingLag


def test_a_toy_effect_is_made_by_a_twin_from_its_declaration(toy_effect, tmp_path):
    """A twin from a Hall capture takes from its base what its declaration says capture times cannot
    tell: the toy is in the twin's plant, as the base has it, named as assumed, and its TOML reads back."""
    from hil.twin.capture import analyse, twin_from_capture, twin_toml
    from plant_models import PlantConfig

    from hil.recording.drivers import record_kinematic

    # a speed ramp, as a twin's capture is (the calibration tells a delay from a constant angle by it)
    config = paper_bench().with_effects(fx.InstallationOffset((1.0, -0.5, 0.3)), fx.EdgeJitter(time_rms_s=1e-6))
    rec = record_kinematic(config, [OperatingPoint(0.4, 2000.0, 1.0, end_speed_rpm=8000.0, id="ramp")], seed=5)
    base = paper_bench().with_effects(FallingLag(2.5))
    twin = twin_from_capture(analyse(rec, pole_pairs=2), base, "toy base")
    assert twin.config.effect("falling_lag") == FallingLag(2.5) and "falling_lag" in twin.from_base
    assert ("falling_lag", "from the base: a toy the twin does not measure") in [(what, words(how)) for what, how in
                                                                             twin.assumed]
    text = twin_toml(twin, "bench.toy", "toy base")
    assert '[[effects]]  # assumed: from the base\nname = "falling_lag"\nlag_deg_e = 2.5' in text
    (tmp_path / "twin.toml").write_text(text)
    assert PlantConfig.from_toml(tmp_path / "twin.toml").effect("falling_lag") == FallingLag(2.5)


def test_a_toy_effect_is_swept_by_a_campaign(toy_effect, tmp_path):
    """A campaign axis on the toy's parameter: with raw Hall commutation the commutation lands on the
    sensor's edge, so the worst commutation error against the plant's true angle is the lag itself."""
    from hil.campaign import load_spec, read_table, run_campaign

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text('''
[campaign]
name = "toy"
seed = 1
run_s = 0.06
[campaign.budgets]
commutation_angle_p99 = "angle_p99"
[fixed]
strategy = "raw"
speed_rpm = 4000.0
[[axis]]
name = "falling_lag.lag_deg_e"
values = [0.5, 2.0]
''')
    result = run_campaign(load_spec(spec_path), tmp_path / "out", scheduler="serial", progress=False)
    table = read_table(result.paths["table"])
    assert list(table["falling_lag.lag_deg_e"]) == [0.5, 2.0]
    for _, row in table.iterrows():
        assert abs(row["angle_p99_deg_e"] - row["falling_lag.lag_deg_e"]) < 0.05, row


def test_a_toy_effect_is_listed_and_documented_from_its_declaration(toy_effect, capsys):
    from hil.cli import effects_markdown, main

    assert main(["effects"]) == 0
    listed = capsys.readouterr().out
    assert "falling_lag  [sensor]  falling edges trail, rising edges do not" in listed
    assert "lag_deg_e" in listed and "lag of every falling edge" in listed
    doc = effects_markdown()
    section = doc[doc.index("## `falling_lag` (sensor)"):]
    assert "Falling edges trail by ``lag_deg_e``" in section
    assert "| `lag_deg_e` | deg_e | [0.0, 10.0] | `0.0` | lag of every falling edge |" in section
    routes = section[section.index("Routes: "):].splitlines()[0]
    for route in ("diagnosed from its mean edge-angle signature", "validated by the 'edge' law",
                  "a twin from a Hall capture takes it from its base plant: a toy the twin does not measure",
                  "swept by a campaign axis `falling_lag.<parameter>`"):
        assert route in routes, routes
    assert "capture times alone" not in routes and "sampled signals" not in routes  # it declares neither


# --- a toy capture format: a text file of "time levels" lines, levels as three 0/1 characters ----------

_TOY_CHANNELS = ["hall_a", "hall_b", "hall_c"]


def _toy_rows(path):
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    return np.array([float(t) for t, _ in rows]), [levels for _, levels in rows]


def _toy_read(cap, chunk):
    t, levels = _toy_rows(cap.path)
    bits = [_TOY_CHANNELS.index(cap.mapping.channels[s]) for s in cap.mapping.signals]
    state = np.array([sum(int(lv[b]) << j for j, b in enumerate(bits)) for lv in levels], dtype=np.int64)
    cap.end_s = float(t[-1])
    yield t, state


def _toy_time_base(cap, t_s):
    from hil.recording.capture import time_step

    return time_step(t_s, 1e-9), "the greatest common step of the toy file's times (printed in ns)"


def _write_toy(path, t_s, sensor, rising):
    """The Hall levels after every edge, and before the first (each line low before its first rise)."""
    level = [0 if rising[sensor == x][0] else 1 for x in range(3)]
    lines = [f"{t_s[0] - 1e-3:.9f} {''.join(map(str, level))}"]
    for t, x, up in zip(t_s, sensor, rising):
        level[x] = int(up)
        lines.append(f"{t:.9f} {''.join(map(str, level))}")
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def toy_format(monkeypatch):
    from hil.recording.capture import CaptureFormat
    from hil.recording.formats import FORMATS, FileFormat

    fmt = CaptureFormat("toy", "toy text", _toy_read, lambda path, time_column: list(_TOY_CHANNELS), _toy_time_base)
    monkeypatch.setitem(FORMATS, ".toy", FileFormat(capture=fmt))
    return fmt


@pytest.fixture
def kinematic_run():
    from hil.recording.drivers import record_kinematic

    # the capture timer ticks in whole microseconds: the time base the import finds
    config = paper_bench().with_effects(fx.InstallationOffset((1.0, -0.5, 0.3)), fx.EdgeJitter(time_rms_s=1e-6),
                                        fx.TimerQuantization(tick_s=1e-6))
    return record_kinematic(config, [OperatingPoint(0.4, 6000.0, 1.0, id="run")], seed=5)


def test_a_toy_capture_format_registered_in_the_table_alone_is_read_by_the_recording_import(
    tmp_path, toy_format, kinematic_run
):
    from hil.cli import main
    from hil.recording.load import load_recording
    from hil.recording.reader import read_recording

    rec = kinematic_run
    path = tmp_path / "bench.toy"
    _write_toy(path, rec.t_s, rec.sensor, rec.rising)
    assert main(["recording", "import", str(path), "--pole-pairs", "2", "-o", str(tmp_path / "imported")]) == 0
    imported = read_recording(tmp_path / "imported")
    assert len(imported) == len(rec) and imported.timer_tick_s == pytest.approx(1e-6, rel=1e-6)
    got = load_recording(path, pole_pairs=2)  # every command's RECORDING argument
    assert len(got) == len(rec)
    assert np.array_equal(got.sensor, rec.sensor) and np.array_equal(got.rising, rec.rising)
    assert np.max(np.abs(got.t_s - rec.t_s)) < 1e-9


def test_an_unregistered_suffix_is_refused_with_the_registered_ones(tmp_path):
    from hil.recording.errors import SignalError
    from hil.recording.formats import open_capture

    path = tmp_path / "bench.toy"
    path.write_text("0.0 000\n")
    with pytest.raises(SignalError, match=r"unknown capture format '\.toy' \(VCD \.vcd, .*CSV \.csv/\.txt\)"):
        open_capture(path)


# --- a toy predictor: the next edge one mean of the last two sector times after this one ---------------

class TwoSectorPredictor:
    """Next edge one mean of the last two sector times after this one (no setting)."""

    name = "two_sector"
    settings: ClassVar[dict] = {}

    def run(self, t_corrected_s, mean_current_a=None):
        from hil.predictors.model import SECTOR_RAD
        from hil.predictors.predictors import PredictionRun

        t = np.asarray(t_corrected_s, dtype=float)
        pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
        dt = (t[2:] - t[:-2]) / 2.0
        pred[2:] = t[2:] + dt
        w[2:] = SECTOR_RAD / dt
        return PredictionRun(pred, w)


#: the recording's calibration (an ordinary run, hil calibrate's) fits a trajectory with more knots than a
#: short steady run resolves; its solver says so, and the comparison is unaffected
@pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning")
def test_a_toy_predictor_registered_in_the_registry_alone_is_compared(monkeypatch, kinematic_run):
    from hil.experiments import peers
    from hil.predictors import registry

    entry = registry.PredictorEntry("two_sector", TwoSectorPredictor, lambda s, m, k: TwoSectorPredictor(), False,
                                    None, registry.TuningSpace(lambda p, o: {}))
    monkeypatch.setitem(registry.PREDICTORS, entry.name, entry)
    rec = dataclasses.replace(kinematic_run, motor={"pole_pairs": 2})
    result = peers.compare_recording(rec, "toy run")
    rows = {r["name"]: r for r in result["predictors"]}
    assert set(rows) == set(registry.PREDICTORS)
    toy, hold = rows["two_sector"], rows["sector_hold"]
    # on a steady run with white edge jitter, averaging two sectors halves the interval's noise
    assert 0 < toy["angle_rms_deg_e"] < hold["angle_rms_deg_e"]
    assert "two_sector" in peers.format_result(result)


def test_the_controller_runs_the_predictor_the_registry_names_for_its_strategy(monkeypatch):
    from bldc.contract import Strategy
    from hil.controller.virtual import VirtualController
    from hil.predictors import registry

    c = VirtualController(paper_bench().motor, strategy=Strategy.KF)
    assert type(c._predictor) is registry.PREDICTORS["kf"].cls
    entry = dataclasses.replace(registry.PREDICTORS["sage_husa"], strategy="KF")  # KF now runs Sage-Husa's entry
    monkeypatch.setitem(registry.PREDICTORS, "kf", dataclasses.replace(registry.PREDICTORS["kf"], strategy=None))
    monkeypatch.setitem(registry.PREDICTORS, "sage_husa", entry)
    c.reset()
    assert type(c._predictor) is entry.cls


# --- the declarations themselves ------------------------------------------------------------------

def test_every_pair_knob_names_a_registered_effect_and_sits_on_one_side_only():
    for name, cls in fx.EFFECTS.items():
        for other, sentence in cls.pair_knobs.items():
            assert other in fx.EFFECTS and other != name, (name, other)
            assert name not in fx.EFFECTS[other].pair_knobs, f"{name}/{other}: declared on both effects"
            assert sentence.startswith("Record ") and sentence.endswith("."), (name, other)


def test_the_tuning_searches_each_registered_space_as_data():
    """``peers.search`` knows no predictor: it reads the entry's axes, grids and options. On a
    known objective it finds the known optimum of an exhaustive space (moving average) and of a
    refined one with an option (PLL)."""
    import math

    from hil.experiments.peers import search
    from hil.predictors.registry import KINEMATIC_MODEL, PREDICTORS

    value, p = search(PREDICTORS["moving_average"], lambda p: (p.fifo_edges - 30) ** 2, KINEMATIC_MODEL)
    assert (value, p.fifo_edges) == (0, 30)

    def pll_objective(p):
        return (math.log(p.bandwidth_rad_s / 365.0)) ** 2 + (0.0 if p.two_edge else 1.0)

    value, p = search(PREDICTORS["pll"], pll_objective, KINEMATIC_MODEL)
    assert p.two_edge and p.bandwidth_rad_s == pytest.approx(365.0, rel=0.02)
    for name, entry in PREDICTORS.items():  # every grid corner of every option set builds its predictor
        space = entry.tuning_space
        for opts in space.option_sets():
            for corner in (min, max):
                point = {k: corner(a.grid) for k, a in space.axes.items()}
                assert type(entry.make(space.settings(point, opts), KINEMATIC_MODEL, False)) is entry.cls, name
