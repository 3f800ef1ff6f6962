"""The twin of a Hall capture (docs/twin.md): built from the shipped real captures, checked against
them; the delay bounds from real hardware; the effects the twin needs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, seed, settings

from bldc.contract import MAX_CONDITIONING_DELAY_S, CalibrationTableError
from bldc.params import ConfigError
from bldc.tomlfile import load_toml
from hil.calibration.corrections import Corrections
from hil.cli import main
from hil.controller.virtual import validate_corrections
from plant_models import PlantConfig
from plant_models import effects as fx
from plant_models.kinematic import OperatingPoint, simulate_edges
from saved_json import differences, key_paths, saved_file, with_paths

DATA = Path(__file__).parent / "data" / "real-hall"
SPINDLE = DATA / "20260618-spindle-hw.vcd"
HBOARD = DATA / "20250616-hboard-cycle.vcd"
ROOT = Path(__file__).parent.parent
#: the judged bands (issue 34): the twin's rise-minus-fall delay within 10 % of the capture's; the
#: twin/real commutation-error ratio within 0.67-1.5 for sector hold and the PLL
DELAY_TOLERANCE = 0.10
RATIO_BAND = (0.67, 1.5)


def test_from_capture_writes_a_plant_that_plant_check_accepts(spindle_twin, capsys):
    assert main(["plant", "check", str(spindle_twin)]) == 0
    assert "valid; motor 2 pole pairs" in capsys.readouterr().out
    text = spindle_twin.read_text()
    assert "# ASSUMED" in text and "# MEASURED" in text
    for what in ("absolute: the mean", "common part", "armature_reaction", "motor (R, L, ke, J"):
        assert what in text, what
    effects = load_toml(spindle_twin)["effects"]
    names = [e["name"] for e in effects]
    # by default the plant holds what a calibration table can hold; the capture's residual pattern
    # per sensor and pole and its edge noise are measured, listed as left out, and not in the plant
    assert names == ["installation_offset", "pole_offset", "switching_asymmetry", "conditioning_delay"]
    left_out = text.split("# MEASURED BUT LEFT OUT")[1].split("# NOTES")[0]
    assert "sensor_pole_offset (--with-sensor-pole-pattern)" in left_out
    assert "switching_asymmetry (--with-sensor-asymmetry), the plant holds the part common" in left_out
    assert "edge_jitter (--with-edge-noise)" in left_out
    # the switching asymmetry the pole table's polarities hold: the three sensors' mean, -0.97 +- 0.06
    # deg e on the capture (docs/twin.md); each sensor's own (-0.94, -0.64, -1.51) is left out
    asym = next(e for e in effects if e["name"] == "switching_asymmetry")["rise_minus_fall_deg_e"]
    assert asym[0] == asym[1] == asym[2] and -1.3 < asym[0] < -0.7, asym
    delay = next(e for e in effects if e["name"] == "conditioning_delay")
    # the capture's calibration: 133.5 +- 0.7 us rise minus fall (docs/real-captures.md)
    assert abs(delay["rise_delay_s"] - delay["fall_delay_s"] - 133.5e-6) < 3e-6


def test_the_twin_reproduces_the_spindles_delay_and_predictor_errors(spindle_check):
    cal = spindle_check["calibration"]
    real = cal["real"]["rise_fall_delay_difference_s"]["value"]
    twin = cal["twin"]["rise_fall_delay_difference_s"]["value"]
    assert abs(twin - real) <= DELAY_TOLERANCE * abs(real), (real, twin)
    ratios = {p["name"]: p["ratio"] for p in spindle_check["predictors"]}
    for name in ("sector_hold", "pll"):
        assert RATIO_BAND[0] <= ratios[name] <= RATIO_BAND[1], (name, ratios[name])
    # the relative installation offsets come back to their standard errors' scale
    for s in "ABC":
        c = cal["comparison"][f"installation_offset_deg_e.{s}"]
        assert abs(c["difference"]) < 0.2, (s, c)


def test_the_check_names_what_the_default_twin_leaves_out_and_adding_it_explains_it(spindle_check):
    """The spindle's residual pattern per sensor and pole (0.95 deg e RMS, docs/twin.md) is real and
    no table holds it: the default twin's plant leaves it out, and the check must say so, not hide it.
    By default the check takes on what the plant leaves out (the motor as measured) and reports the
    plant as written beside it."""
    assert spindle_check["left_out"] == ["sensor_pole_offset", "switching_asymmetry", "edge_jitter"]
    assert spindle_check["taken_on"] == ["sector_locked_speed_ripple", *spindle_check["left_out"]]
    written = spindle_check["variants"]["as_written"]
    lacking = {d["what"]: d for d in written["differences"] if d["what"].startswith("left out of the twin")}
    pattern = lacking["left out of the twin: sensor_pole_offset"]
    assert pattern["explained_by_adding"] and "--with-sensor-pole-pattern" in pattern["effect"], pattern
    assert lacking["left out of the twin: switching_asymmetry beyond the part common to the three sensors"][
        "explained_by_adding"]
    # ... and the headline's differences name what was taken on
    assert any(d["what"] == "left out of the twin: sensor_pole_offset" and d["explained_by_adding"]
               for d in spindle_check["differences"])
    # the plant as written errs less than the capture (0.70 sector hold, 0.75 PLL when measured):
    # what is left out is a third of the real commutation error; still inside the judged band
    for row in written["predictors"]:
        if row["name"] in ("sector_hold", "pll"):
            assert RATIO_BAND[0] <= row["ratio"] < 1.0, row


def test_the_options_add_what_no_table_holds(tmp_path, capsys):
    out = tmp_path / "hboard.toml"
    assert main(["twin", "from-capture", str(HBOARD), "-o", str(out), "--with-sensor-pole-pattern",
                 "--with-sensor-asymmetry", "--with-edge-noise"]) == 0
    printed = capsys.readouterr()
    assert "left out: nothing" in printed.out
    effects = {e["name"]: e for e in load_toml(out)["effects"]}
    assert "sensor_pole_offset" in effects and "edge_jitter" in effects
    asym = effects["switching_asymmetry"]["rise_minus_fall_deg_e"]
    assert max(asym) - min(asym) > 0.05, asym  # each sensor its own
    assert "# MEASURED BUT LEFT OUT" not in out.read_text()
    # the suite runs up to the capture's own top speed (305 rpm, 76 Hz electrical), where the real
    # delay is an eighth of a sector; the twin's motor is the base pump's rewound for that top speed
    assert load_toml(out)["operating"]["top_speed_rpm"] == pytest.approx(305.0, rel=0.02)
    assert "there the 276 us delay is 0.13 of a sector" in printed.err
    assert "rewound for a 305 rpm top" in printed.out
    # a top speed where the delay spans four sectors (the paper pump's 10,000 rpm on 15 pole pairs):
    # said, not left for the acceptance run to find
    assert main(["twin", "from-capture", str(HBOARD), "-o", str(out), "--top-speed-rpm", "10000"]) == 0
    printed = capsys.readouterr()
    assert "the delay is beyond half a sector at the top speed" in printed.err
    assert "times the capture's: the suite judges the twin where the capture never ran it" in printed.err


def test_the_twin_check_json_keeps_its_contract(spindle_check, spindle_twin, tmp_path):
    for key in ("recording", "twin", "calibration", "predictors", "differences", "sector_widths", "noise"):
        assert key in spindle_check
    d = spindle_check["calibration"]["real"]["rise_fall_delay_difference_s"]
    assert set(d) == {"value", "stderr"} and d["stderr"] > 0
    row = spindle_check["predictors"][0]
    assert set(row) >= {"name", "real_rms_deg_e", "twin_rms_deg_e", "ratio"}
    for diff in spindle_check["differences"]:
        assert set(diff) >= {"what", "effect", "explained_by_adding"}
    from hil.twin.report import write_html

    write_html(spindle_check, tmp_path / "check.html")
    assert "data:image/png;base64," in (tmp_path / "check.html").read_text()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["plant", "from-capture", "no-such-capture.vcd", "-o", "x.toml"], "no-such-capture.vcd"),
        (["twin", "check", str(SPINDLE), "no-such-twin.toml", "--json", "x.json"], "no-such-twin.toml"),
        (["plant", "from-capture", str(HBOARD), "-o", "x.toml", "--top-speed-rpm", "0"],
         "--top-speed-rpm: must be > 0.0 rpm, got 0.0"),
    ],
)
def test_bad_input_is_one_line_naming_the_file(argv, expected, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err


def test_a_twin_of_another_pole_count_is_refused(spindle_twin, tmp_path, capsys):
    wrong = tmp_path / "wrong.toml"
    text = spindle_twin.read_text().replace("pole_pairs = 2", "pole_pairs = 3")
    # the per-pole tables no longer fit: plant check names the field
    wrong.write_text(text)
    assert main(["plant", "check", str(wrong)]) == 2
    assert "offset_deg_e: expected 6 values (one per magnet pole)" in capsys.readouterr().err


def test_a_capture_too_short_is_refused(tmp_path, capsys):
    vcd = tmp_path / "short.vcd"
    lines = ["$timescale 1 ns $end", "$var wire 1 a hall_a $end", "$var wire 1 b hall_b $end",
             "$var wire 1 c hall_c $end", "$enddefinitions $end", "#0", "1a", "0b", "1c"]
    state = [1, 0, 1]
    for k, x in enumerate([2, 1, 0, 2, 1, 0, 2, 1]):  # a few forward steps only
        state[x] ^= 1
        lines += [f"#{(k + 1) * 1000000}", f"{state[x]}{'abc'[x]}"]
    vcd.write_text("\n".join(lines) + "\n")
    assert main(["twin", "from-capture", str(vcd), "-o", str(tmp_path / "t.toml")]) == 2
    assert "edges" in capsys.readouterr().err
    assert not (tmp_path / "t.toml").exists()


# --- bounds from real hardware -----------------------------------------------------------------


def test_a_real_wiring_delay_is_inside_the_library_and_the_controller_table():
    # the hoverboard's 276 us rise minus fall: a plant and a table may carry it
    fx.ConditioningDelay(rise_delay_s=300e-6, fall_delay_s=0.0).check(2, "effects[0].")
    c = Corrections()
    c.pole_offset_deg_e = [0.0] * 4
    c.conditioning_delay_s = {"rise": 300e-6, "fall": 0.0}
    validate_corrections(c, 2)
    c.conditioning_delay_s = {"rise": 1.2 * MAX_CONDITIONING_DELAY_S, "fall": 0.0}
    with pytest.raises(CalibrationTableError, match="conditioning_delay_s.rise"):
        validate_corrections(c, 2)
    with pytest.raises(ConfigError, match="rise_delay_s"):
        too_long = 1.2 * MAX_CONDITIONING_DELAY_S
        PlantConfig.from_dict({"effects": [{"name": "conditioning_delay", "rise_delay_s": too_long}]})


def test_the_bound_is_half_a_sector_of_a_hub_motor_at_its_top_speed():
    pole_pairs, top_rpm = 15, 600.0
    sector_s = 60.0 / (360.0 * pole_pairs * top_rpm / 60.0)
    assert MAX_CONDITIONING_DELAY_S <= 0.5 * sector_s
    assert MAX_CONDITIONING_DELAY_S >= fx.DRAW_DELAY_S["real-wiring"] >= 300e-6


@seed(34)
@settings(max_examples=50, deadline=None, database=None)
@given(library=fx.ConditioningDelay.strategy(2),
       real=fx.ConditioningDelay.strategy(2, fx.DRAW_DELAY_S["real-wiring"]))
def test_rob_001_draws_keep_their_stated_range_and_the_option_widens_it(library, real):
    assert max(library.rise_delay_s, library.fall_delay_s) <= 50e-6
    assert max(real.rise_delay_s, real.fall_delay_s) <= 300e-6


# --- the effects a twin needs ----------------------------------------------------------------------


@pytest.mark.parametrize("direction", [1, -1])
def test_switching_asymmetry_makes_rising_edges_trail_and_falling_lead(direction):
    a = (1.0, -0.6, 2.0)
    config = PlantConfig().with_effects(fx.SwitchingAsymmetry(rise_minus_fall_deg_e=a))
    e = simulate_edges(config, [OperatingPoint(0.05, 3000.0, direction=direction)])
    ideal = 180.0 * e.boundary + np.array([0.0, 120.0, 240.0])[e.sensor]
    trail = direction * (e.theta_e_switch_deg - ideal)  # positive: later than the ideal edge
    for x in range(3):
        rise = trail[(e.sensor == x) & e.rising]
        fall = trail[(e.sensor == x) & ~e.rising]
        assert np.allclose(rise, a[x] / 2) and np.allclose(fall, -a[x] / 2), (x, rise[:3], fall[:3])


def test_sensor_pole_offset_needs_one_value_per_sensor_and_pole():
    with pytest.raises(ConfigError, match=r"effects\[0\]\.offset_deg_e.*12 values"):
        PlantConfig.from_dict({"effects": [{"name": "sensor_pole_offset", "offset_deg_e": [0.1] * 4}]})
    table = [0.1 * k for k in range(12)]
    config = PlantConfig().with_effects(fx.SensorPoleOffset(offset_deg_e=tuple(table)))
    e = simulate_edges(config, [OperatingPoint(0.05, 3000.0)])
    ideal = 180.0 * e.boundary + np.array([0.0, 120.0, 240.0])[e.sensor]
    got = e.theta_e_switch_deg - ideal
    assert np.allclose(got, np.array(table)[e.sensor * 4 + e.pole])


def test_coloured_jitter_keeps_its_colour_across_short_segments():
    rho = 0.8
    config = PlantConfig().with_effects(fx.EdgeJitter(angle_rms_deg_e=1.0, correlation=rho))
    profile = [OperatingPoint(60.0 / (360.0 * 2 * 3000.0 / 60.0), 3000.0)] * 3000  # one sector each
    e = simulate_edges(config, profile, seed=3)
    ideal = 180.0 * e.boundary + np.array([0.0, 120.0, 240.0])[e.sensor]
    x = e.theta_e_switch_deg - ideal
    lag1 = float(np.corrcoef(x[1:], x[:-1])[0, 1])
    # 3000 edges: the lag-1 estimate's standard error is about 0.01
    assert abs(lag1 - rho) < 0.05 and math.isclose(float(np.std(x)), 1.0, rel_tol=0.15)


def acceptance_on(plant: Path, out: Path, *args: str) -> tuple[dict, str]:
    """``hil acceptance`` against the built-in controller (in-process, one process) on ``plant`` with
    ``args`` after the fixed ones: its JSON report and its standard output."""
    import os
    import subprocess
    import sys

    run = subprocess.run(
        [sys.executable, "-m", "hil", "acceptance", "--plant", str(plant), "--dut", "virtual:in-process", "-j", "0",
         "-o", str(out), *args],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=900,
    )
    return json.loads((out / "hil-report.json").read_text()), run.stdout


def test_a_hub_motor_twin_runs_the_suite_with_every_calibration_requirement_passing(tmp_path):
    """The hoverboard's twin (15 pole pairs, a 276 us real delay, a 305 rpm capture top): the suite's
    calibration tests run at the same fractions of its top speed (``PlantConfig.suite_speed_rpm``),
    on its own measured tables and real delay, against the built-in controller, which downloads the
    twin's calibration; every calibration requirement passes and no test errors (issue 34). A
    controller that held too few edges to align a 30-pole table (64 once) fails REQ-CAL-002 here."""
    twin = tmp_path / "hub.toml"
    assert main(["twin", "from-capture", str(HBOARD), "-o", str(twin)]) == 0
    report, stdout = acceptance_on(twin, tmp_path / "report", "--suite", "test_cases/test_calibration_recovery.py")
    outcomes = {t["nodeid"].rpartition("::")[2]: t["outcome"] for t in report["tests"]}
    assert len(outcomes) == 5 and set(outcomes.values()) == {"passed"}, (outcomes, stdout[-3000:])
    verdicts = {r["id"]: r["verdict"] for r in report["traceability"] if r["traced"]}
    calibration = {k: v for k, v in verdicts.items() if k.startswith("REQ-CAL")}
    assert set(calibration) == {f"REQ-CAL-00{k}" for k in range(1, 6)}, verdicts
    assert set(calibration.values()) <= {"pass", "marginal"}, calibration
    # the real delay, not the paper's, is what REQ-CAL-003 judged
    delay = next(e for e in PlantConfig.from_toml(twin).effects if e.name == "conditioning_delay")
    assert delay.rise_delay_s - delay.fall_delay_s == pytest.approx(276e-6, rel=0.10)


def test_after_a_fault_a_many_pole_rotor_is_realigned_while_its_speed_recovers(tmp_path):
    """A sensor dropout on the hub motor's twin: the controller counts edges afresh and learns its
    pole alignment again while its speed loop pulls the rotor back, a speed trend across the turn it
    compares. The hub's pole pattern is once per turn (eccentricity), which such a trend mimics; the
    alignment compares the sector times about their trend, so the commutation recovers (REQ-ROB-002's
    budget); compared raw, it kept a neighbouring alignment and a 5-8 deg e error."""
    from hil.verdicts.budgets import Budgets
    from hil.controller.virtual import VirtualController
    from hil.dut.in_process import InProcessLink
    from hil.dut.faults import SensorDropout
    from hil.bench.stimulus import Stimulus, run
    from plant_models.plant import paper_bench

    # the base as a user's file: its motor taken as written (a pump motor at 3 % of its speed, whose
    # speed loop after the fault pulls hard), not rewound for the hub's top speed
    base = tmp_path / "base.toml"
    base.write_text('preset = "paper-bench"\n')
    twin = tmp_path / "hub.toml"
    assert main(["twin", "from-capture", str(HBOARD), "-o", str(twin), "--base", str(base)]) == 0
    plant = PlantConfig.from_toml(twin)
    fault = SensorDropout(sensor=1).as_dict()
    stim = Stimulus("fault_sequence",
                    effects=[e.to_dict() for e in plant.suite_deviations(paper_bench(True).effects)],
                    steps=[["on", fault], ["run", plant.suite_duration_s(0.02)], ["off", fault]],
                    speed_rpm=plant.suite_speed_rpm(Stimulus.speed_rpm), plant=plant.to_dict())
    outcome = run(stim, InProcessLink(VirtualController(plant.motor)), Budgets.defaults())
    assert outcome.values["acted"] == ["sensor_dropout"]
    assert outcome.ok, outcome.message


REPLAYS = Path(__file__).parent / "data" / "replays"


@pytest.mark.parametrize("replay, what", [
    # REQ-ROB-001's draw on the hub's twin: a long sector read once as a lost edge at the start, and
    # the interval put in its place became that sector's reference a turn later, so it read as a lost
    # edge every turn and the pole alignment never held (18.8 deg e p99)
    ("hub-twin-long-sector.json", "a substituted interval is never a same-sector reference"),
    # REQ-ROB-002's sequence on the spindle's twin: after the faults the pole alignment was chosen on
    # edges with the real 133 us delay left in, which made the choice noise (2.2 deg e p99 recovered)
    ("spindle-twin-resync.json", "the alignment compares edges corrected for the delays"),
])
def test_what_the_suite_found_on_the_twins_passes_its_replay(replay, what):
    """The stimuli the acceptance suite saved when it found two of the built-in controller's defects
    on the shipped motors' twins (docs/twin.md), replayed against the controller: each now meets its
    budget."""
    from hil.verdicts.budgets import Budgets
    from hil.controller.virtual import VirtualController
    from hil.dut.in_process import InProcessLink
    from hil.bench.stimulus import Stimulus, run

    stimulus = Stimulus.load(REPLAYS / replay)
    outcome = run(stimulus, InProcessLink(VirtualController(stimulus.plant_config().motor)), Budgets.defaults())
    assert outcome.ok, f"{what}: {outcome.message}"


def test_a_twin_check_writes_the_saved_json(spindle_check):
    """``hil twin check`` of the spindle capture against its twin: the same keys and values (the
    twin's replay is seeded), the paths aside: the saved file names the capture as the README's
    command does and the twin where it was written."""
    now = json.loads(json.dumps(spindle_check))
    saved = saved_file("twin-check-spindle.json")
    assert key_paths(now) == key_paths(saved), sorted(key_paths(now) ^ key_paths(saved))
    paths = {now["recording"]: saved["recording"], now["twin"]: saved["twin"]}
    assert differences(saved, with_paths(now, paths)) == []


@pytest.fixture(scope="module")
def spindle_twin_findings(spindle_twin, tmp_path_factory):
    """The acceptance suite's two open findings on the spindle's twin (docs/twin.md, "The spindle's
    twin"), run once: REQ-PRED-002 on its noisy profile and REQ-ROB-002's fault sequences, against
    the built-in controller; the report's tests by name."""
    report, stdout = acceptance_on(spindle_twin, tmp_path_factory.mktemp("spindle-findings"),
                                   "--", "-k", "(no_worse and noisy) or fault_sequences")
    tests = {t["nodeid"].rpartition("::")[2]: t for t in report["tests"]}
    assert len(tests) == 2, (sorted(tests), stdout[-3000:])
    return tests, {r["id"]: r["verdict"] for r in report["traceability"] if r["traced"]}


def test_a_failed_fault_sequence_is_reported_as_the_failure_it_is(spindle_twin_findings):
    """Hypothesis runs a failing example again to confirm it; the fault-sequence search
    skipped a sequence it had seen, so the repeat passed and the report said "FlakyFailure: produces
    unreliable results", as if the controller were not deterministic (its replay fails every time).
    A failing sequence now fails again: the report names the budget it missed."""
    tests, _ = spindle_twin_findings
    test = next(t for name, t in tests.items() if name.startswith("test_fault_sequences"))
    if test["outcome"] != "failed":
        pytest.skip("REQ-ROB-002 passes on the spindle's twin: no failed sequence to report")
    assert test["message"].startswith("AssertionError: recovered_commutation_angle_p99 (REQ-ROB-002)"), test["message"]
    assert "in FlakyFailure]" not in test["message"] and "errors.FlakyFailure" not in str(test["details"])


@pytest.mark.xfail(strict=True, reason=(
    "open finding (docs/twin.md): after a 5 ms sensor dropout the built-in controller's commutation on "
    "the spindle's twin is 0.63 deg e p99 in the recovery window, against REQ-ROB-002's 0.6; the same run "
    "without the fault errs as much there: the window judges the run, not the recovery"))
def test_the_built_in_controller_recovers_from_a_fault_on_the_spindles_twin(spindle_twin_findings):
    assert spindle_twin_findings[1]["REQ-ROB-002"] == "pass"


@pytest.mark.xfail(strict=True, reason=(
    "open finding (docs/twin.md): at a set point step of the noisy profile the speed loop raises the "
    "current about tenfold within two edges; Sage-Husa's chi-square gate, on angle and current together, "
    "refuses the step as an outlier edge, the divergence fade then sets the speed state 2.7 rad/s off "
    "and the edge-noise change detector takes the acceleration for noise (R_theta 60x): one seed's RMS "
    "is twice the KF's"))
def test_sage_husa_is_no_worse_than_the_kf_on_the_spindles_twin_with_a_changing_edge_noise(spindle_twin_findings):
    assert spindle_twin_findings[1]["REQ-PRED-002"] == "pass"
