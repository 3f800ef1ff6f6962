"""Every default budget's limit recomputed by hand from the inputs its derivation states
(hil/verdicts/budget_sources.py, docs/budgets.md "Sources"): the arithmetic, not the words."""

from __future__ import annotations

import math

import pytest

from hil.verdicts import budget_sources as bs
from hil.verdicts.budgets import Budgets

#: budget -> the limit recomputed here from the paper's printed values and the stated parameters
#: (written out again, not imported, so a changed input or formula in the module shows here)
BY_HAND = {
    # example: a 1 % torque-ripple allowance, a dip of delta / 60 deg e
    "commutation_angle_p99": 60 * 0.01,
    # paper Table 3, C1 at 960 / 1107 / 1330 rpm
    "installation_offset_error": 0.953 - 0.875,
    # paper Table 2, HallAF1, percent of the 60 deg e interval
    "pole_offset_error": (1.67 - 1.46) / 100 * 60,
    # Table 3's 0.078 deg e at 10,000 rpm, 2 pole pairs
    "conditioning_delay_error": 0.078 / (10_000 / 60 * 360 * 2),
    # Table 3's 0.078 deg e over 0.35 deg e/A x the mean |i| at 10,000 rpm: fan 1.5e-7 w^2 + friction 1e-5 w
    # over 2 ke (0.0216), two of three phases conducting
    "armature_slope_error": 0.078 / (0.35 * 2 / 3 * (1.5e-7 * (10_000 * math.pi / 30) ** 2
                                                     + 1e-5 * 10_000 * math.pi / 30) / (2 * 0.0216)),
    # Table 5, Sage-Husa 0.0066 of 60 deg e, Gaussian RMS and p99
    "sage_husa_commutation_angle_rms": 0.0066 * 60 * math.sqrt(math.pi / 2),
    "sage_husa_commutation_angle_p99": 2.5758293 * 0.0066 * 60 * math.sqrt(math.pi / 2),
    "sage_husa_commutation_time_mape": 0.66,
    "commutation_time_mape": 0.66,
    # Table 5: Sage-Husa no worse than the KF (0.0066 < 0.0077), plus the ratio's sampling error over the paper
    # profile's commutations by design (6 seeds x 0.4 s at each of 5000, 5833, ..., 10,000 rpm, 12 edges per turn):
    # one-sided z at 1 % / 4 profiles over sqrt(n)
    "sage_husa_over_kf_angle_rms": 1 + 2.8070338 / math.sqrt(6 * sum(rpm / 60 * 12 * 0.4 for rpm in
                                                                   (5000, 5833.333, 6666.667, 7500, 8333.333,
                                                                    9166.667, 10_000))),
    # Section 4.4: 120 commutation cycles; three relative standard errors sqrt(2 / n)
    "edge_noise_estimate_low": math.exp(-3 * math.sqrt(2 / 120)),
    "edge_noise_estimate_high": math.exp(3 * math.sqrt(2 / 120)),
    "edge_noise_estimate_log_scatter": math.sqrt(2 / 120),
    "edge_noise_tracking_edges": 2 * 120,
    "learned_edge_noise_ratio": 1 / 4,
    "heartbeat_period_error": (1.1 - 1) / 2,
    # REQ-COMM-001's 1 % torque ripple, for any calibrated deviation set and after a recovery
    "any_deviations_commutation_angle_p99": 60 * 0.01,
    "recovered_commutation_angle_p99": 60 * 0.01,
    # the paper bench's LA25-P range (Table 1) and IPB200N25N3 G rating (Infineon datasheet): min(25, 64)
    "phase_current_peak_a": min(25.0, 64.0),
    # example: half of raw Hall commutation's excess current (the paper's 37.2 % is its whole controller's)
    "raw_excess_current_removed": 1 / 2,
    # example: Ziegler and Nichols (1942), quarter-amplitude decay
    "speed_step_overshoot": math.sqrt(1 / 4),
    "speed_step_decay_ratio": 1 / 4,
    "speed_step_settling_s": 1.0,
    "speed_limited_step_overshoot": math.sqrt(1 / 4),
    "speed_load_step_recovery_s": 1.0,
    "speed_hold_current_over_load": 1 + 0.25,
    # REQ-CAL-001..004: REQ-COMM-001's limit on each deviation alone
    "installation_corrected_angle_p99": 60 * 0.01,
    "pole_corrected_angle_p99": 60 * 0.01,
    "conditioning_delay_corrected_angle_p99": 60 * 0.01,
    "armature_reaction_corrected_angle_p99": 60 * 0.01,
    "learned_edge_noise_ratio_high": 1 / 0.25,
    # 640 edges of a steady 0.4 s phase at 8000 rpm, 2 pole pairs; half the scatter, to 3 places
    "edge_noise_estimate_log_scatter_low": round(math.sqrt(2 / (8000 / 60 * 12 * 0.4)) / 2, 3),
    # Table 5, regulation stage: speed MAPE 0.37 % over 0.75 %, to 2 places
    "sage_husa_over_precalibration_regulation_rms": round(0.37 / 0.75, 2),
    # processor in the loop: the shortest Hall interval at 10,000 rpm, 2 pole pairs, six edges a turn
    "hall_isr_response_s": 60 / (10_000 * 2 * 6),
    "compare_isr_response_s": 60 / (10_000 * 2 * 6),
    "control_isr_response_over_period": 1.0,
    "interrupt_overruns": 0.0,
    # Liu and Layland (1973), Theorem 5, three tasks
    "cpu_load_worst": 3 * (2 ** (1 / 3) - 1),
    "stack_high_water_fraction": 1.0,
    "flash_used_fraction": 1.0,
    "ram_used_fraction": 1.0,
}


def _raw_rms_by_hand() -> float:
    """Tables 2-4 through Eq. 5-6: installation offsets (absolute 4.22 % of 60 deg e on A, the
    relative corrections -0.930, 0.021, 0.908 deg) plus each pole's offset (0, -1.59, -0.03, -0.22 %)."""
    absolute = 4.22 / 100 * 60
    install = [absolute + r + 0.930 for r in (-0.930, 0.021, 0.908)]
    poles = [0.0, -1.59 / 100 * 60, -0.03 / 100 * 60, -0.22 / 100 * 60]
    edges = [i + p for p in poles for i in install]
    return math.sqrt(sum(e * e for e in edges) / len(edges))


BY_HAND["calibrated_fraction_removed"] = 1 - (0.6 / 2.5758293) / _raw_rms_by_hand()


def test_every_default_budget_is_recomputed_here():
    assert set(BY_HAND) == set(Budgets.defaults().budgets) == set(bs.DERIVATIONS)


@pytest.mark.parametrize("name", sorted(BY_HAND))
def test_the_default_limit_is_its_arithmetic(name):
    assert Budgets.defaults()[name].limit == pytest.approx(BY_HAND[name], rel=1e-6), bs.DERIVATIONS[name].source


def test_the_stated_inputs_are_the_papers_printed_values():
    """The module's tables are the paper's (the copy a reviewer reads): a typo in an input shows."""
    assert bs.PAPER_TABLE3_DEG["C1"] == (0.875, 0.933, 0.953)
    assert bs.PAPER_TABLE3_WEIGHTED_DEG == (-0.930, 0.021, 0.908)
    assert bs.PAPER_TABLE2_PERCENT["AF1"] == (1.67, 1.54, 1.46)
    assert bs.PAPER_TABLE2_WEIGHTED_PERCENT == (1.59, 0.03, 0.22)
    assert bs.PAPER_TABLE4_WEIGHTED_PERCENT == 4.22
    assert bs.PAPER_TABLE5_TIME_MAPE == {"pre-calibration": 0.0087, "kf": 0.0077, "sage_husa": 0.0066}
    assert bs.PAPER_TABLE5_REGULATION_SPEED_MAPE == {"pre-calibration": 0.0075, "sage_husa": 0.0037}
    assert (bs.PAPER_SEC43_CURRENT_RATIO, bs.PAPER_NOISE_INTERVAL_EDGES, bs.PAPER_LA25P_RANGE_A) == (0.372, 120, 25.0)
    assert (bs.PAPER_POLE_PAIRS, bs.PAPER_TOP_SPEED_RPM) == (2, 10_000.0)


def test_the_stated_bench_parameters_are_the_paper_benchs():
    """The physics inputs that are bench parameters are the plant's (docs/plant.md), not free numbers."""
    from plant_models import plant

    assert bs.PAPER_POLE_PAIRS == plant.PAPER_POLE_PAIRS and bs.PAPER_TOP_SPEED_RPM == plant.PAPER_TOP_SPEED_RPM
    assert bs.PAPER_TABLE3_WEIGHTED_DEG == plant.PAPER_TABLE3_RELATIVE_DEG_E
    assert bs.PAPER_TABLE2_WEIGHTED_PERCENT == plant.PAPER_TABLE2_POLE_PERCENT
    assert bs.PAPER_TABLE4_WEIGHTED_PERCENT == plant.PAPER_TABLE4_ABSOLUTE_PERCENT
    assert bs.PAPER_PERCENT_BASE_DEG_E == plant.PAPER_PERCENT_BASE_DEG_E


def test_every_source_is_outside_the_project_or_says_it_is_an_example():
    for d in bs.DERIVATIONS.values():
        assert d.kind in bs.KINDS, d.budget
        assert d.source.startswith(("paper: ", "standard: ", "physics: ", "example for your own specification: "))
        assert "spec S" not in d.source.replace("earlier spec S", ""), f"{d.budget} cites the retired S1-S6"
        if d.kind == "paper":
            assert any(w in d.cite for w in ("Table", "Section", "Figure")), d.budget


def test_the_current_limit_is_the_plants_own_ratings():
    """The default is the paper bench's ratings, and they are the plant's defaults (one set of numbers)."""
    from plant_models.plant import CurrentSensorParameters, InverterParameters

    d = bs.DERIVATIONS["phase_current_peak_a"]
    assert d.inputs == {"sensor_range_a": CurrentSensorParameters().range_a,
                        "switch_rating_a": InverterParameters().switch_current_rating_a}
    assert bs.current_limit_for(10.0, 64.0).limit == 10.0 and bs.current_limit_for(25.0, 20.0).limit == 20.0


def test_the_share_removed_is_derived_for_the_scenarios_own_raw_error():
    """REQ-CAL-005: a scenario with less to remove may remove a smaller share and still meet the
    commutation limit (sigma = 0.6 / 2.576 deg e of residual RMS)."""
    sigma = 0.6 / 2.5758293
    for raw in (0.45, 1.0, 3.3, 10.0):
        assert bs.fraction_removed_for(raw).limit == pytest.approx(1 - sigma / raw, rel=1e-6)
    assert bs.fraction_removed_for(0.1).limit == 0.0  # less raw error than the residual allowed: nothing to remove


def test_req_pred_002s_limit_is_derived_for_the_commutations_each_profile_judged():
    """No worse than the KF (Table 5), beyond the sampling error of a ratio of two RMS values over n
    commutations each: z / sqrt(n), z one-sided at a 1 % false fail shared by four profiles."""
    assert bs.PAPER_TABLE5_TIME_MAPE["sage_husa"] < bs.PAPER_TABLE5_TIME_MAPE["kf"]
    for n in (6708, 17604, 19638, 25200):
        assert bs.sage_husa_over_kf_limit_for(n).limit == pytest.approx(1 + 2.8070338 / math.sqrt(n), rel=1e-6)
    assert bs.sage_husa_over_kf_limit_for(25200).marginal == 1.0  # behind the KF at all: a warning


def test_a_scenario_limit_applies_to_the_default_and_never_over_a_users_own(tmp_path):
    derived_for = bs.fraction_removed_for(0.45)
    v = Budgets.defaults().check("calibrated_fraction_removed", 0.6, derived_for)
    assert v.verdict != "fail" and v.limit == pytest.approx(derived_for.limit)
    assert Budgets.defaults().check("calibrated_fraction_removed", 0.6).verdict == "fail"  # the paper's 0.929
    own = tmp_path / "budgets.toml"
    own.write_text("[calibrated_fraction_removed]\nlimit = 0.7\n")
    mine = Budgets.from_toml(own)
    assert mine.check("calibrated_fraction_removed", 0.6, derived_for).limit == 0.7


def test_every_marginal_bound_lies_on_the_passing_side():
    for name, b in Budgets.defaults().budgets.items():
        if b.marginal is not None:
            assert (b.marginal <= b.limit) if b.kind == "max" else (b.marginal >= b.limit), name
