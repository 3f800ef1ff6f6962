"""REQ-PRED-002's pooled design: the power per profile its evidence states (test_cases/test_sage_husa.py)."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _suite_module():
    spec = importlib.util.spec_from_file_location("acceptance_sage_husa", ROOT / "test_cases" / "test_sage_husa.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("profile", ["paper", "low", "high"])
def test_a_profile_scaled_to_its_stated_ratio_brings_the_pooled_ratio_to_the_limit(profile):
    m = _suite_module()
    runs = [("paper", 0, 0.070, 0.067), ("paper", 1, 0.068, 0.064), ("low", 0, 0.062, 0.068),
            ("low", 1, 0.055, 0.066), ("high", 0, 0.096, 0.088), ("high", 1, 0.090, 0.084)]
    at = m.pooled_fails_at(runs, profile, 1.05)
    mine = [r for r in runs if r[0] == profile]
    scale = at / (sum(r[2] for r in mine) / sum(r[3] for r in mine))
    scaled = [(p, s, sh * (scale if p == profile else 1.0), kf) for p, s, sh, kf in runs]
    assert sum(r[2] for r in scaled) / sum(r[3] for r in scaled) == pytest.approx(1.05)
    # a pooled verdict lets a profile alone go past the limit where the others are ahead (here the paper and high
    # profiles: 1.19), and holds one that is far ahead to far less (the low one: 1.006)
    assert at == pytest.approx({"paper": 1.190, "low": 1.006, "high": 1.185}[profile], abs=0.002)
