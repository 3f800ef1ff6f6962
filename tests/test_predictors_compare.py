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
from hil.recording.format import Recording, Segment, write_recording
from hil.recording.reader import read_recording
from hil.recording.vcd import VcdReader

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
    from hil.predictors.peer_settings import PROVENANCE

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


@pytest.fixture(scope="module")
def spindle(tmp_path_factory):
    return vcd_recording(SPINDLE, tmp_path_factory.mktemp("rec") / "spindle")


@pytest.fixture(scope="module")
def spindle_compared(spindle):
    edges = peers.recording_edges(spindle)
    return peers.compare_recording(spindle, "spindle", edges), edges


def test_real_capture_all_six_finite_and_a_model_filter_no_worse_than_sector_hold(spindle_compared):
    """Held-out real capture (no tuning saw any real capture): the judged bound of issue 26."""
    out, _ = spindle_compared
    rows = {r["name"]: r for r in out["predictors"]}
    assert set(rows) == set(peers.PREDICTORS)
    for r in rows.values():
        assert all(k in r for k in CONTRACT)
        assert all(math.isfinite(r[k]) for k in ("angle_rms_deg_e", "angle_p99_deg_e", "angle_max_deg_e"))
    best = min(rows[n]["angle_rms_deg_e"] for n in ("kf", "sage_husa", "vb_akf"))
    assert best <= rows["sector_hold"]["angle_rms_deg_e"]
    assert "kinematic" in out["model"] and "corrected" in out["reference"]


def test_real_capture_scored_against_the_calibrations_corrected_instants(spindle, spindle_compared):
    """Issue 31: the comparison calibrates the capture with the project's calibration (the delay
    included) and scores against those instants. An independent computation of sector hold (plain
    numpy on the calibration's corrected times: predict edge k+1 one sector after edge k at the
    last sector's duration, the error in deg e at the two-sector speed around edge k+1) agrees
    within 25 %, and the best predictor reaches 2.0 deg e RMS (issue figures: sector hold 3.21,
    PLL 1.74; measured 3.17 and 1.71)."""
    out, e = spindle_compared
    # the rise-minus-fall delay is taken off: the shift of each edge is +-D/2 (rising later) plus
    # an angle per edge slot (sensor and polarity) times the time per degree
    pick = np.searchsorted(spindle.t_s, e.t_s)
    rising, slot = spindle.rising[pick].astype(bool), 2 * spindle.sensor[pick] + spindle.rising[pick]
    tau = np.gradient(e.t_s) / 60.0
    cols = np.column_stack([np.where(rising, 0.5, -0.5), np.eye(6)[slot] * tau[:, None]])
    delay_taken_off = np.linalg.lstsq(cols, e.t_s - e.t_corrected_s, rcond=None)[0][0]
    delay = out["calibration"]["rise_fall_delay_difference_s"]["value"]
    assert 100e-6 < delay < 170e-6  # the spindle's 134 us (docs/real-captures.md)
    assert delay_taken_off == pytest.approx(delay, rel=0.05)
    tc, k = e.t_corrected_s, np.arange(e.first_scored, e.t_corrected_s.size - 2)
    predicted = tc[k] + (tc[k] - tc[k - 1])
    err_deg = (predicted - tc[k + 1]) * 120.0 / (tc[k + 2] - tc[k])
    independent = float(np.sqrt(np.mean(err_deg**2)))
    rows = {r["name"]: r["angle_rms_deg_e"] for r in out["predictors"]}
    assert abs(rows["sector_hold"] / independent - 1.0) < 0.25, (rows["sector_hold"], independent)
    assert min(rows.values()) <= 2.0, rows


def test_cli_writes_the_contract(spindle, tmp_path):
    out = tmp_path / "cmp.json"
    assert hil_main(["predictors", "compare", str(spindle.path), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"source", "reference", "predictors"} <= set(data)
    assert [r["name"] for r in data["predictors"]] == list(peers.PREDICTORS)


def test_cli_refuses_a_recording_and_a_scenario(spindle, capsys):
    assert hil_main(["predictors", "compare", str(spindle.path), "--scenario", "pumps"]) == 2
    assert "not both" in capsys.readouterr().err


def test_pumps_contract_on_two_held_out_pumps():
    out = peers.compare_pumps(seeds=peers.HELD_OUT_PUMP_SEEDS[:2])
    assert len(out["pumps"]) == 2
    for pump in out["pumps"]:
        assert "pole_pairs" in pump["params"]
        assert [r["name"] for r in pump["predictors"]] == list(peers.PREDICTORS)
        assert all(math.isfinite(r["angle_rms_deg_e"]) for r in pump["predictors"])
    assert out["settings_provenance"]["train_pump_seeds"]


def test_the_controller_defaults_are_the_training_pump_tuning():
    """Issue 26: the controller's filters come from the training pumps, not from the scenario
    REQ-PRED-002 judges (a hand edit of either side fails here)."""
    from hil.controller.virtual import VirtualController
    from hil.predictors.registry import pump_defaults
    from hil.experiments.table5 import scenario_plant

    controller = VirtualController(scenario_plant().motor)
    assert (controller.filter_settings, controller.kf_settings) == pump_defaults()


def test_paper_scenario_contract_and_the_model_filters_beat_sector_hold():
    """One seed of the paper scenario (ground truth from the plant): all six finite, and the
    filters with the paper's model (Eq. 8 predicts the acceleration from the measured current)
    better than sector hold, which predicts none (measured 0.07 against 0.6 deg e)."""
    out = peers.compare_paper(seeds=(0,), hold_s=0.5)
    rows = {r["name"]: r for r in out["predictors"]}
    assert list(rows) == list(peers.PREDICTORS)
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

    from hil.recording.drivers import record_electrical

    rec = record_electrical(paper_bench(with_deviations=True), [OperatingPoint(1.0, 7000.0)], seed=3)
    write_recording(rec, tmp_path / "r")
    out = peers.compare_recording(read_recording(tmp_path / "r"), "electrical")
    assert "paper's model" in out["model"]
    rows = {r["name"]: r for r in out["predictors"]}
    assert all(math.isfinite(r["angle_rms_deg_e"]) for r in rows.values())
    for name in ("kf", "sage_husa", "vb_akf"):
        assert rows[name]["angle_rms_deg_e"] < rows["sector_hold"]["angle_rms_deg_e"]
