"""The ordinary-run calibration's error bars are checked, not trusted: coverage on synthetic captures
with correlated jitter and known truth, and agreement of the halves of the shipped real captures
(docs/real-captures.md, "Are the error bars honest?"; the full study: tools/calibration_coverage.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.calibration import uncertainty
from hil.calibration.ordinary import Effects, fit_ordinary, hall_steps
from hil.experiments.calibration_coverage import Z, correlated_capture, coverage_study, half_split
from hil.recording.hall import read_hall_capture

DATA = Path(__file__).parent / "data" / "real-hall"
#: the reduced coverage study: 60 captures from this seed (some 10 s of CPU)
COVERAGE_SEED = 7
COVERAGE_CAPTURES = 60


@pytest.fixture(scope="module")
def coverage():
    rows, info = coverage_study(COVERAGE_CAPTURES, COVERAGE_SEED)
    return {r.figure: r for r in rows}, info


@pytest.mark.parametrize("figure", ["delay_difference", "asymmetry", "installation", "pole"])
def test_intervals_hold_the_truth_about_95_percent_of_the_time(coverage, figure):
    rows, info = coverage
    row = rows[figure]
    assert row.n >= COVERAGE_CAPTURES * (0.9 if figure in ("delay_difference", "asymmetry") else 2.9), row
    # 95 % intervals: at least 85 % over this reduced set (seed 7) ...
    assert row.coverage >= 0.85, (row, info)
    # ... and no wider than the errors need: the stated errors match the real ones (RMS of
    # |value - truth| / stderr near 1; white-noise errors give 0.5 for the delay here, too wide)
    assert 0.7 <= row.rms_z <= 1.4, (row, info)


def test_the_generator_has_correlated_jitter_and_a_speed_range():
    cap = correlated_capture(3)
    s = cap.settings
    assert 0.5 <= s["jitter_lag1"] <= 0.85 and s["speed_hz_e"][1] / s["speed_hz_e"][0] >= 3.0
    assert np.all(np.diff(cap.t_s) > 0) and abs(cap.installation_deg_e.sum()) < 1e-12
    for parity in (0, 1):
        assert abs(cap.pole_deg_e[parity::2].sum()) < 1e-12


def test_the_jackknife_sees_correlated_noise_that_least_squares_misses():
    """Edge jitter correlated over about 20 edges (AR(1), lag-1 0.95). The pole pattern repeats every
    6 p = 24 edges, where the AR(1) spectrum, 1 / (1 + rho^2 - 2 rho cos(2 pi / 24)), is 1.44 times
    its mean: the pole offsets' errors are some 1.2 times what white noise of the same variance
    gives. The white-noise figure misses that; the stretch jackknife does not."""
    cap = correlated_capture(11, jitter_correlation=(0.95, 0.95), jitter_rms_s=(20e-6, 20e-6))
    steps = hall_steps(cap.t_s, cap.sensor, cap.rising)
    fit = fit_ordinary(steps, Effects(pole_pairs=cap.pole_pairs), tick_s=33_333e-9)
    robust = uncertainty.robust_fit(fit)
    poles = [i for i, n in enumerate(fit.names) if n.startswith("pole_")]
    ratio = np.sqrt(np.diag(robust.cov)[poles] / np.diag(fit.cov)[poles])
    assert np.median(ratio) > 1.1, ratio
    assert "jackknife" in robust.stderr_method


# --- halves of the shipped real captures ------------------------------------------------------

#: pole pairs as the whole captures give them (tests/test_real_hall.py, docs/real-captures.md)
HALVES = [("20260618-spindle-hw.vcd", 2), ("20250616-hboard-cycle.vcd", 15)]


@pytest.mark.parametrize("name,pole_pairs", HALVES, ids=["spindle", "hboard-cycle"])
def test_halves_of_a_real_capture_agree_within_their_errors(name, pole_pairs):
    cap = read_hall_capture(DATA / name)
    rows, cals = half_split(cap.t_s, cap.sensor, cap.rising, cap.timer_tick_s, pole_pairs)
    figures = {r["figure"] for r in rows}
    assert {"delay_difference", "asymmetry", "installation A"} <= figures
    assert sum(f.startswith("pole") for f in figures) == 2 * pole_pairs
    worst = max(rows, key=lambda r: r["z"])
    assert worst["z"] <= 3.0, worst
    assert all("jackknife" in c.ordinary.stderr_method() for c in cals)


@pytest.mark.parametrize(
    "name", ["20250616-back-and-forth.vcd", "20250615-new-slow.vcd"], ids=["back-and-forth", "slow"]
)
def test_halves_of_the_low_speed_captures_agree_on_the_delay(name):
    """The delay difference of each half (reversals, stalls, 6-40 Hz electrical) within the errors;
    the figures whose halves still disagree are listed in docs/real-captures.md."""
    cap = read_hall_capture(DATA / name)
    rows, _ = half_split(cap.t_s, cap.sensor, cap.rising, cap.timer_tick_s, None)
    delay = next(r for r in rows if r["figure"] == "delay_difference")
    assert delay["z"] <= 3.0, delay


#: the figures whose halves disagree on the low-speed captures (docs/real-captures.md, "Halves")
LOW_SPEED_DRIFT = {
    "20250616-back-and-forth.vcd": ["rise_fall_angle_asymmetry_deg_e"],
    "20250615-new-slow.vcd": ["pole_offset_deg_e.0", "pole_offset_deg_e.2"],
}


def _whole(cal, key: str) -> tuple[float, float]:
    """A figure of a calibration and its standard error: a table entry (``TABLE.ITEM``) or a figure."""
    if "." in key:
        table, item = key.split(".")
        values, errors = getattr(cal.corrections, table), cal.corrections.uncertainty[table]
        index = int(item) if item.isdigit() else item
        return values[index], errors[index]
    figure = getattr(cal.ordinary, key)
    return figure.value, figure.stderr


@pytest.mark.parametrize("name", sorted(LOW_SPEED_DRIFT), ids=["slow", "back-and-forth"])
def test_a_capture_whose_halves_disagree_says_so_and_its_interval_holds_both(name):
    """Issue 39: the halves of a low-speed capture disagree by more than their errors allow. The
    calibration of the whole capture fits each half alone, says the capture is not stationary and
    by how much, and widens the figure's error by half the halves' difference: the stated interval
    (value +- 1.96 stderr) then holds both halves' values."""
    from hil.calibration.ordinary import STATIONARITY_Z, ordinary_calibration

    cap = read_hall_capture(DATA / name)
    cal = ordinary_calibration(hall_steps(cap.t_s, cap.sensor, cap.rising), tick_s=cap.timer_tick_s)
    st = cal.ordinary.stationarity
    assert st.stationary is False and st.statement().startswith("NOT stationary")
    for key in LOW_SPEED_DRIFT[name]:
        f = st.figures[key]
        assert f.z > STATIONARITY_Z and key in st.statement(), f
        value, stderr = _whole(cal, key)
        assert stderr >= f.widen_by > 0
        for half in f.value_halves:
            assert abs(half - value) <= Z * stderr, (key, half, value, stderr)
    assert "widened" in cal.ordinary.stderr_method()


def test_a_stationary_capture_keeps_its_errors():
    """The hoverboard's speed cycles: its halves agree, nothing is widened."""
    cap = read_hall_capture(DATA / "20250616-hboard-cycle.vcd")
    from hil.calibration.ordinary import ordinary_calibration

    cal = ordinary_calibration(hall_steps(cap.t_s, cap.sensor, cap.rising), tick_s=cap.timer_tick_s, pole_pairs=15)
    st = cal.ordinary.stationarity
    assert st.stationary is True and all(not f.widen_by for f in st.figures.values()), st.statement()
    assert cal.ordinary.rise_fall_delay_difference_s.stderr_stationary is None


def test_interval_quantile_is_the_normal_one():
    assert Z == pytest.approx(1.96, abs=0.001)
    assert uncertainty.t_over_normal(20) == pytest.approx(2.093 / 1.960, rel=1e-3)
