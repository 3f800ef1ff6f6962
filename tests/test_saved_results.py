"""Saved result files keep working: each file in tests/data/results/ was written by the code
before the results became typed (issue 40); the same command today writes the same keys and the
same values (numbers to rounding), the legacy alias keys included."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import gap_cases
from saved_json import differences, key_paths, saved_file

ROOT = Path(__file__).resolve().parents[1]


def test_the_comparison_sees_a_renamed_key_and_a_changed_value():
    """A guard on the guard."""
    saved = {"a": {"value": 1.0, "reason": "x"}, "b": [1, 2], "c": None}
    assert differences(saved, json.loads(json.dumps(saved))) == []
    assert differences(saved, {"a": {"val": 1.0, "reason": "x"}, "b": [1, 2], "c": None})
    assert differences(saved, {"a": {"value": 1.1, "reason": "x"}, "b": [1, 2], "c": None})
    assert differences(saved, {"a": {"value": 1.0, "reason": "y"}, "b": [1], "c": None})
    assert differences(saved, {"a": {"value": 1.0, "reason": "x"}, "b": [1, 2], "c": 0.0})
    assert key_paths({"a": [{"x": 1}, {"y": 2}]}) == {"/a", "/a[]/x", "/a[]/y"}


@pytest.mark.parametrize(
    "name, capture, circuit",
    [
        ("calibration-ordinary-new-slow.json", "20250615-new-slow.vcd", {}),
        ("calibration-ordinary-back-and-forth-refused.json", "20250616-back-and-forth.vcd", {"delay_max_s": 1e-5}),
    ],
)
def test_an_ordinary_run_calibration_writes_the_saved_json(name, capture, circuit):
    from hil.calibration import calibrate
    from hil.calibration.refusals import Circuit
    from hil.recording.load import load_recording

    source = f"tests/data/real-hall/{capture}"
    cal = calibrate(load_recording(ROOT / source), circuit=Circuit(**circuit), source=source)
    now = json.loads(json.dumps(cal.to_json()))
    assert cal.to_json_dict() == cal.to_json()  # the former name, kept
    assert differences(saved_file(name), now) == []
    assert now["independent_estimate"] == now["method_cross_check"]  # the legacy alias key


def test_a_campaign_calibration_writes_the_saved_json():
    from hil.calibration import calibrate
    from hil.calibration.campaign import CalibrationCampaign
    from hil.calibration.refusals import Circuit
    from plant_models import PRESETS

    rec = CalibrationCampaign(turns_per_point=40).run(PRESETS["paper-bench+deviations"](), seed=3)
    cal = calibrate(rec, circuit=Circuit(delay_max_s=1e-6))
    now = json.loads(json.dumps(cal.to_json()))
    assert differences(saved_file("calibration-segments-campaign-refused.json"), now) == []


def test_a_gap_diagnosis_writes_the_saved_json():
    """``hil gap diagnose tests/data/real-hall/20250615-new-slow.vcd --json``: the ordinary-run route."""
    from hil.gap import diagnose
    from hil.recording.load import load_recording

    d = diagnose(load_recording(ROOT / "tests" / "data" / "real-hall" / "20250615-new-slow.vcd"), None)
    now = json.loads(json.dumps(d.to_json()))
    assert differences(saved_file("gap-diagnosis-ordinary-new-slow.json"), now) == []


def _sampled_confounded():
    return gap_cases.temperatures_confounded(), "known"


def _below_relevance():
    return gap_cases.tiny_installation_offset(), "paper_bench"


def _edge_confounded():
    return gap_cases.armature_lag_confounded(), None


@pytest.mark.parametrize(
    "name, case",
    [
        ("gap-diagnosis-segments-sampled-confounded.json", _sampled_confounded),
        ("gap-diagnosis-segments-below-relevance.json", _below_relevance),
        ("gap-diagnosis-segments-edge-confounded.json", _edge_confounded),
    ],
)
def test_a_segments_gap_diagnosis_writes_the_saved_json(name, case):
    """The segments route, written by ``hil.gap.diagnose`` on the simulated recording of ``case``."""
    from hil.gap import diagnose
    from hil.gap.synthetic import KNOWN_MODEL
    from plant_models import paper_bench

    rec, model = case()
    d = diagnose(rec, {"known": KNOWN_MODEL, "paper_bench": paper_bench(), None: None}[model])
    now = json.loads(json.dumps(d.to_json()))
    assert differences(saved_file(name), now) == []


#: the runs of the saved qualify result (tests/data/results/qualify-canned-runs.json), canned: a
#: control that PASSes, a defect caught by a budget, one that errored, one that survived
def _canned_runs():
    from hil.qualify.run import Run

    test = "test_cases/test_calibration_recovery.py::test_x"
    return {
        None: Run("control", "the built-in controller as shipped", "PASS", False, None, [], [], 12.5, "rep/control", "",
                  [], [{"requirement": "REQ-COMM-001", "budget": "commutation_angle_p99", "verdict": "PASS",
                        "margin": 0.4, "test": test}], "", ["REQ-COMM-001", "REQ-SPD-001"]),
        "pole-table-one-pole-off": Run(
            "pole-table-one-pole-off", "d1", "FAIL", True, "budget", ["REQ-COMM-001"], [test], 20.0, "rep/p", "",
            [{"requirement": "REQ-COMM-001", "by": "budget commutation_angle_p99", "margin": -0.3, "test": test}],
            [{"requirement": "REQ-COMM-001", "budget": "commutation_angle_p99", "verdict": "FAIL", "margin": -0.3,
              "test": test}], "table", ["REQ-COMM-001"]),
        "never-resynchronises": Run("never-resynchronises", "d2", "FAIL", False, "error", [],
                                    ["test_cases/test_faults.py::test_y"], 8.0, "rep/n", "raised KeyError", [], [],
                                    "fault-handling", ["REQ-FAULT-001"]),
        "current-limit-not-enforced": Run(
            "current-limit-not-enforced", "d3", "PASS", False, None, [], [], 30.0, "rep/c", "", [],
            [{"requirement": "REQ-CUR-001", "budget": "peak_current", "verdict": "PASS", "margin": 0.05,
              "test": "test_cases/test_current.py::test_z"}], "current", ["REQ-CUR-001"]),
    }


def test_a_qualify_result_writes_the_saved_json(tmp_path, monkeypatch):
    """``hil qualify`` with its runs canned (the suite is not run): the result today writes the same
    keys and values as the saved one (its duration aside), and its typed figures agree with them."""
    from types import SimpleNamespace

    from hil.qualify import run as R

    runs = _canned_runs()
    monkeypatch.setattr(R, "_run", lambda name, description, defect, args: runs[defect])
    args = SimpleNamespace(defects=None, only=[n for n in runs if n], dut="virtual:modbus", budgets=None,
                           report_dir=str(tmp_path), workers=1, seed=0)
    result = R.qualify(args, progress=lambda line: None)
    now = json.loads(json.dumps(result.to_json()))
    saved = saved_file("qualify-canned-runs.json")
    # keys a later version added, and only those: the defects of one kind of DUT (the part's, on pil:;
    # docs/qualify.md); a reader of the saved file does without them
    later = ("not_this_kind", "expected", "kinds", "by_design")
    changed = differences({**saved, "duration_s": 0.0}, {**now, "duration_s": 0.0})
    assert [d for d in changed if not (d.endswith(": added") and d[:-len(": added")].rsplit("/", 1)[-1] in later)] == []
    assert result.survivors == saved["survivors"] and result.errored == saved["errored"]
    assert result.requirements() == saved["requirements"]
    assert result.detection_ratio == saved["detection"]["ratio"]
