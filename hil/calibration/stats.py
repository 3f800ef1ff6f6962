"""The statistical rules every fit of the project shares: one outlier cut, one BIC rule, one
chi-square test. The calibration, the twin and the gap diagnosis read residuals of their own
fits; that an edge 6 robust standard deviations out is a bump, that an effect must earn 10 BIC
units, and how a pattern is tested against its standard errors are decided here once, so the
rooms cannot drift apart (the twin had restated the cut and run its own chi-square test).

Light: numpy at import, scipy on the first chi-square test (``docs/architecture.md``: vocabulary,
importable by every room).
"""

from __future__ import annotations

import math

import numpy as np

#: residuals beyond this many robust standard deviations are outliers (a missed edge, a bump)
OUTLIER_SD = 6.0
#: minimum BIC improvement (chi-square drop less k ln n) for an effect to earn its place
BIC_MIN = 10.0


def inliers(resid: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Residuals within ``OUTLIER_SD`` robust standard deviations."""
    return np.abs(resid / sigma) < OUTLIER_SD


def bic_gain(chi2_drop: float, k_new: int, n_obs: int, search_penalty: float = 0.0) -> float:
    """BIC improvement of adding ``k_new`` parameters that lower the chi-square by ``chi2_drop``
    over ``n_obs`` observations (a searched shape parameter adds ``search_penalty``)."""
    return float(chi2_drop - k_new * math.log(max(n_obs, 2)) - search_penalty)


def chi2_p_value(chi2: float, dof: float) -> float:
    """The probability that white noise of ``dof`` degrees of freedom gives a chi-square at least ``chi2``."""
    from scipy import stats

    return float(stats.chi2.sf(chi2, dof))


def chi2_test(means: np.ndarray, stderr: np.ndarray) -> tuple[float, float]:
    """Whether ``means`` stand out of their standard errors: their chi-square (an infinite standard
    error, a mean not measured, adds 0) and its p-value over as many degrees of freedom as means."""
    chi2 = float(np.sum((np.asarray(means) / np.asarray(stderr)) ** 2))
    return chi2, chi2_p_value(chi2, int(np.size(means)))
