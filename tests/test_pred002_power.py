"""REQ-PRED-002's per-profile design (test_cases/test_sage_husa.py): each operating profile is its own
verdict, its limit derived for the commutations it judged (hil/verdicts/budget_sources.py), so a profile where
Sage-Husa is far ahead can no longer carry one where it is behind, as the pooled ratio did."""

import importlib.util
import math
from pathlib import Path

import pytest

from hil.verdicts.budget_sources import sage_husa_over_kf_limit_for
from hil.verdicts.budgets import Budgets

ROOT = Path(__file__).resolve().parents[1]
#: (profile, seed, Sage-Husa RMS, KF RMS, Sage-Husa commutations, KF commutations): the shape of
#: the built-in controller's runs before the friction was in its model (docs/sage-husa.md)
RUNS = [("paper", 0, 0.0750, 0.0714, 3273, 3273), ("paper", 1, 0.0728, 0.0700, 3273, 3273),
        ("low", 0, 0.0634, 0.0716, 1118, 1118), ("low", 1, 0.0620, 0.0700, 1118, 1118),
        ("high", 0, 0.0940, 0.0869, 2934, 2934), ("high", 1, 0.0930, 0.0850, 2934, 2934)]


def _suite_module():
    spec = importlib.util.spec_from_file_location("acceptance_sage_husa", ROOT / "test_cases" / "test_sage_husa.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _verdicts(runs) -> dict[str, str]:
    budgets = Budgets.defaults()
    return {p: budgets.check("sage_husa_over_kf_angle_rms", ratio, sage_husa_over_kf_limit_for(n)).verdict
            for p, (ratio, n) in _suite_module().profile_ratios(runs).items()}


def test_each_profile_is_its_own_verdict_where_the_pooled_ratio_passed():
    ratios = _suite_module().profile_ratios(RUNS)
    assert ratios["paper"][0] == pytest.approx(((0.0750 + 0.0728) / 2) / ((0.0714 + 0.0700) / 2))
    assert ratios["low"][1] == 2 * 1118  # the commutations each filter's RMS stands on
    pooled = sum(r[2] for r in RUNS) / sum(r[3] for r in RUNS)
    assert pooled < 1.05  # the old pooled verdict (limit 1.05) passed these runs
    assert _verdicts(RUNS) == {"paper": "fail", "low": "pass", "high": "fail"}


@pytest.mark.parametrize("profile", ["paper", "low", "high"])
def test_the_smallest_loss_a_profile_fails_is_its_sampling_error(profile):
    """The per-profile design's power: a Sage-Husa behind the KF on one profile by more than that
    profile's sampling error (z / sqrt(n), n its commutations) fails it, whatever the others show."""
    n = _suite_module().profile_ratios(RUNS)[profile][1]
    allowance = sage_husa_over_kf_limit_for(n).limit - 1.0
    assert allowance == pytest.approx(2.8070338 / math.sqrt(n), rel=1e-6)
    for over, verdict in ((0.999, "marginal"), (1.001, "fail")):
        runs = [(p, s, kf * (1.0 + over * allowance if p == profile else 0.9), kf, a, b) for p, s, _, kf, a, b in RUNS]
        assert _verdicts(runs) == {p: verdict if p == profile else "pass" for p in ("paper", "low", "high")}
