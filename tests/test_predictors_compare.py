"""``hil predictors compare``: the pumps drawn, a recording's calibration and scoring, and the
JSON contract, on simulated truth and on a real Hall capture (tests/data/real-hall, moteus test
data, Apache-2.0, see its README)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hil.cli import main as hil_main
from hil.experiments import peers
from hil.recording import Recording, Segment, read_recording, record_kinematic, write_recording
from hil.signals.vcd import VcdReader

SPINDLE = Path(__file__).parent / "data" / "real-hall" / "20260618-spindle-hw.vcd"
CONTRACT = ("name", "angle_rms_deg_e", "angle_p99_deg_e", "angle_max_deg_e", "us_per_edge", "settings")


def vcd_recording(path: Path, out: Path) -> Recording:
    """A hil-recording/1 of a VCD's three Hall lines (the capture's 33.3 us sample period as the
    timer tick), written and read back through hil.recording."""
    r = VcdReader(path)
    ticks, line, value = (np.concatenate(a) for a in zip(*r.changes(["hall_a", "hall_b", "hall_c"])))
    first = ticks > 0  # the initial levels at tick 0 are states, not edges
    t = ticks[first] * r.timescale.seconds
    seg = [Segment("capture", float(t[0]), float(t[-1]) + 1e-3, "reverse", 0.0, 0.0, 1.0)]
    rec = Recording({"pole_pairs": 1}, seg, t, line[first].astype(np.int64), value[first] > 0.5,
                    np.zeros(t.size, dtype=np.int64), timer_tick_s=33.333e-6)
    write_recording(rec, out)
    return read_recording(out)


def test_pumps_are_drawn_inside_the_stated_range_and_no_tuning_seed_is_held_out():
    from hil.experiments.peer_settings import PROVENANCE

    assert not set(PROVENANCE["train_pump_seeds"]) & set(peers.HELD_OUT_PUMP_SEEDS)
    assert len(peers.HELD_OUT_PUMP_SEEDS) >= 20
    r = peers.PUMP_RANGE
    drawn = [peers.draw_pump(s) for s in peers.HELD_OUT_PUMP_SEEDS]
    assert {p.params["pole_pairs"] for p in drawn} == {1, 2, 3, 4}
    for p in drawn:
        assert r["inertia_factor"][0] <= p.params["inertia_factor"] <= r["inertia_factor"][1]
        assert r["fan_factor"][0] <= p.params["fan_factor"] <= r["fan_factor"][1]
        assert r["speed_rpm"][0] <= min(p.setpoints_rpm) < max(p.setpoints_rpm) <= r["speed_rpm"][1]
    assert peers.draw_pump(1000).params == peers.draw_pump(1000).params


def test_slot_calibration_recovers_the_simulated_per_slot_deviations():
    """Edges of a rotor at constant speed with installation offsets and a rise/fall delay
    difference: each slot's deviation from capture times against the plant's truth (t_capture -
    t_ideal at the true speed), both with their mean taken out."""
    from plant_models import paper_bench
    from plant_models import effects as fx
    from plant_models.kinematic import OperatingPoint

    config = paper_bench().with_effects(fx.InstallationOffset(offset_deg_e=(2.0, -1.5, 0.5)),
                                        fx.ConditioningDelay(rise_delay_s=8e-6, fall_delay_s=1e-6),
                                        fx.EdgeJitter(time_rms_s=1e-6))
    rec = record_kinematic(config, [OperatingPoint(1.0, 6000.0)], seed=2)
    e = peers.recording_edges(rec)
    assert e.dropped == 0
    dev = peers.slot_deviation_deg_e(e.t_s, e.slot)
    w_deg_s = 6000.0 / 60.0 * 360.0 * config.motor.pole_pairs
    truth_dev = (rec.t_s - rec.truth["t_ideal_s"]) * w_deg_s
    slot = 2 * rec.sensor + rec.rising.astype(int)
    want = np.array([truth_dev[slot == s].mean() for s in range(6)])
    np.testing.assert_allclose(dev, want - want.mean(), atol=0.05)  # the effects are 0.5-2.6 deg e


@pytest.fixture(scope="module")
def spindle(tmp_path_factory):
    return vcd_recording(SPINDLE, tmp_path_factory.mktemp("rec") / "spindle")


def test_real_capture_all_six_finite_and_a_model_filter_no_worse_than_sector_hold(spindle):
    """Held-out real capture (no tuning saw any real capture): the judged bound of issue 26."""
    out = peers.compare_recording(spindle, "spindle")
    rows = {r["name"]: r for r in out["predictors"]}
    assert set(rows) == set(peers.NAMES)
    for r in rows.values():
        assert all(k in r for k in CONTRACT)
        assert all(math.isfinite(r[k]) for k in ("angle_rms_deg_e", "angle_p99_deg_e", "angle_max_deg_e"))
    best = min(rows[n]["angle_rms_deg_e"] for n in ("kf", "sage_husa", "vb_akf"))
    assert best <= rows["sector_hold"]["angle_rms_deg_e"]
    assert "kinematic" in out["model"] and "corrected" in out["reference"]


def test_cli_writes_the_contract(spindle, tmp_path):
    out = tmp_path / "cmp.json"
    assert hil_main(["predictors", "compare", str(spindle.path), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"source", "reference", "predictors"} <= set(data)
    assert [r["name"] for r in data["predictors"]] == list(peers.NAMES)


def test_cli_refuses_a_recording_and_a_scenario(spindle, capsys):
    assert hil_main(["predictors", "compare", str(spindle.path), "--scenario", "pumps"]) == 2
    assert "not both" in capsys.readouterr().err


def test_pumps_contract_on_two_held_out_pumps():
    out = peers.compare_pumps(seeds=peers.HELD_OUT_PUMP_SEEDS[:2])
    assert len(out["pumps"]) == 2
    for pump in out["pumps"]:
        assert "pole_pairs" in pump["params"]
        assert [r["name"] for r in pump["predictors"]] == list(peers.NAMES)
        assert all(math.isfinite(r["angle_rms_deg_e"]) for r in pump["predictors"])
    assert out["settings_provenance"]["train_pump_seeds"]


def test_the_controller_defaults_are_the_training_pump_tuning():
    """Issue 26: the controller's filters come from the training pumps, not from the scenario
    REQ-PRED-002 judges (a hand edit of either side fails here)."""
    from hil.controller.virtual import VirtualController
    from hil.experiments.controller_tuning import pump_defaults
    from hil.experiments.table5 import scenario_plant

    controller = VirtualController(scenario_plant().motor)
    assert (controller.filter_settings, controller.kf_settings) == pump_defaults()


def test_paper_scenario_contract_and_the_model_filters_beat_sector_hold():
    """One seed of the paper scenario (ground truth from the plant): all six finite, and the
    filters with the paper's model (Eq. 8 predicts the acceleration from the measured current)
    better than sector hold, which predicts none (measured 0.07 against 0.6 deg e)."""
    out = peers.compare_paper(seeds=(0,), hold_s=0.5)
    rows = {r["name"]: r for r in out["predictors"]}
    assert list(rows) == list(peers.NAMES)
    for r in rows.values():
        assert all(k in r for k in CONTRACT)
        assert all(math.isfinite(r[k]) for k in ("angle_rms_deg_e", "angle_p99_deg_e", "angle_max_deg_e",
                                                  "speed_mape_constant_pct", "speed_mape_regulation_pct"))
    for name in ("kf", "sage_husa", "vb_akf"):
        assert rows[name]["angle_rms_deg_e"] < 0.5 * rows["sector_hold"]["angle_rms_deg_e"]


def test_a_recording_with_currents_runs_the_model_filters(tmp_path):
    """An electrical-plant recording with phase currents and a full motor block: the model-based
    filters get the model and the cycle-mean currents (stated), all six are finite, and each model
    filter beats sector hold against the corrected edges."""
    from plant_models import paper_bench
    from plant_models.kinematic import OperatingPoint

    from hil.recording import record_electrical

    rec = record_electrical(paper_bench(with_deviations=True), [OperatingPoint(1.0, 7000.0)], seed=3)
    write_recording(rec, tmp_path / "r")
    out = peers.compare_recording(read_recording(tmp_path / "r"), "electrical")
    assert "paper's model" in out["model"]
    rows = {r["name"]: r for r in out["predictors"]}
    assert all(math.isfinite(r["angle_rms_deg_e"]) for r in rows.values())
    for name in ("kf", "sage_husa", "vb_akf"):
        assert rows[name]["angle_rms_deg_e"] < rows["sector_hold"]["angle_rms_deg_e"]
