"""Standard errors of the ordinary-run calibration that hold when the residuals are not white.

The least-squares covariance of ``ordinary.fit_ordinary`` assumes independent edge noise. Real
captures break that: timer quantisation of neighbouring edges, a rotor's speed ripple the
trajectory spline does not follow and the pole pattern (where no pole offsets are fitted) leave
residuals correlated over many edges (the spindle: lag-1 autocorrelation 0.7, still 0.1 at lag
48), and the white-noise figure is wrong both ways: too small where the errors of neighbouring
edges add up, too large where they cancel (the rise-minus-fall contrast of edges whose jitter is
positively correlated).

**Delete-a-stretch jackknife.** The used edges are cut into ``BLOCKS`` contiguous stretches of
equal edge count (never shorter than ``MIN_BLOCK_EDGES``). For each stretch the effects are
re-estimated without it, to first order with the trajectory splines held (the effects' normal
equations less that stretch's information and score), and the covariance is the jackknife's
spread of those estimates, ``(G - 1) / G * sum (d_b - mean d)(d_b - mean d)'`` (the "CV3"
cluster-robust covariance; MacKinnon, Nielsen and Webb, J. Econometrics 232 (2023) 272-299).
Any correlation shorter than a stretch, and any misfit that varies from stretch to stretch,
shows in that spread; unlike the plain sandwich it does not shrink when a few stretches carry
most of the information (a capture whose high speeds, which fix the delay, last only seconds).
With G stretches it has G - 1 degrees of freedom: the standard error is scaled by Student's t
over the normal quantile, so that value +- 1.96 stderr is the 95 % interval a user reads.

Checked on synthetic captures with correlated jitter and drifting speed, and on the halves of the
real captures: ``tools/calibration_coverage.py`` and docs/real-captures.md.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy import linalg, special, stats

#: an ``ordinary.Fit`` (not imported: ``ordinary`` imports this module)
Fit = Any

#: contiguous stretches the jackknife deletes one at a time: a variance with 19 degrees of freedom
#: (its own scatter some 16 %, and t/z = 1.07), stretches of hundreds of edges on a capture of ten
#: thousand, far beyond the residuals' correlation
BLOCKS = 20
#: a stretch is at least this many edges (eight electrical cycles: the pole pattern of a motor with
#: up to 8 pole pairs repeats within two of them); a short capture gets fewer stretches
MIN_BLOCK_EDGES = 48
#: fewer stretches than this give no block covariance: the white-noise figure is reported, and said
MIN_BLOCKS = 6
#: two-sided coverage of the intervals a standard error stands for
INTERVAL_COVERAGE = 0.95


def block_starts(n_edges: int) -> np.ndarray:
    """First edge (index into the fit's used edges) of each stretch."""
    g = int(min(BLOCKS, n_edges // MIN_BLOCK_EDGES))
    return np.linspace(0, n_edges, max(g, 1) + 1).round().astype(int)[:-1]


def block_covariance(fit: Fit) -> np.ndarray | None:
    """The effects' delete-a-stretch jackknife covariance, or None with too few stretches."""
    if fit.block_score is None or fit.block_score.shape[0] < MIN_BLOCKS:
        return None
    g = fit.block_score.shape[0]
    shifts = np.empty_like(fit.block_score)
    for b in range(g):
        # the effects without stretch b, to first order: (M - M_b)^-1 times the score it carried
        shifts[b] = linalg.pinvh(fit.information - fit.block_information[b]) @ fit.block_score[b]
    shifts -= shifts.mean(axis=0)
    return (g - 1.0) / g * (shifts.T @ shifts)


def robust_fit(fit: Fit) -> Fit:
    """``fit`` with the covariance its figures are reported with (the jackknife over stretches),
    and ``stderr_method`` saying which it is."""
    block = block_covariance(fit)
    if block is None:
        return dataclasses.replace(
            fit,
            stderr_method=(
                f"weighted least squares (white residuals): fewer than {MIN_BLOCKS} stretches of "
                f"{MIN_BLOCK_EDGES} edges for a jackknife, so correlated residuals are not accounted for"
            ),
        )
    g = fit.block_score.shape[0]
    return dataclasses.replace(
        fit,
        cov=block * t_over_normal(g) ** 2,
        stderr_method=(
            f"delete-a-stretch jackknife over {g} contiguous stretches of the used edges (holds under "
            "correlated residuals and stretch-to-stretch misfit); scaled by Student's t with "
            f"{g - 1} degrees of freedom so that +-1.96 stderr is the {INTERVAL_COVERAGE:.0%} interval"
        ),
    )


def t_over_normal(blocks: int) -> float:
    """Student's t over the normal quantile of a two-sided ``INTERVAL_COVERAGE`` interval with
    ``blocks - 1`` degrees of freedom."""
    q = 0.5 + INTERVAL_COVERAGE / 2
    return float(stats.t.ppf(q, blocks - 1) / stats.norm.ppf(q))


def with_model_choice(chosen: Fit, alternative: Fit, weight: float, what: str) -> Fit:
    """``chosen`` with the spread of a model choice added: where the data do not settle between
    two nuisance models (``weight`` is the alternative's posterior weight, from BIC), each figure
    is uncertain by the change the alternative would make, ``weight * (d d')`` with ``d`` the
    change of the shared coefficients (the between-model term of a model average)."""
    if weight < MODEL_WEIGHT_IGNORED:
        return chosen
    delta = np.array(
        [
            c - alternative.coef[alternative.names.index(n)] if n in alternative.names else 0.0
            for n, c in zip(chosen.names, chosen.coef)
        ]
    )
    return dataclasses.replace(
        chosen,
        cov=chosen.cov + weight * np.outer(delta, delta),
        stderr_method=(
            f"{chosen.stderr_method}; plus the change {what} would make, weighted by its BIC weight {weight:.2g}"
        ),
    )


#: an alternative model with less posterior weight than this changes no figure's error
MODEL_WEIGHT_IGNORED = 1e-3


def bic_weight(gain: float) -> float:
    """The posterior weight of a model whose BIC is ``gain`` lower than its alternative's."""
    return float(special.expit(gain / 2.0))


def stretch_jackknife_stderr(estimate, n: int) -> np.ndarray | None:
    """Standard errors of ``estimate(keep)`` (a vector from the items of the boolean mask ``keep``,
    in order) by deleting one contiguous stretch of the ``n`` items at a time (``block_starts``),
    t-scaled as ``robust_fit``; None with too few stretches."""
    starts = block_starts(n)
    g = starts.size
    if g < MIN_BLOCKS:
        return None
    ends = np.append(starts[1:], n)
    draws = []
    for a, b in zip(starts, ends):
        keep = np.ones(n, dtype=bool)
        keep[a:b] = False
        draws.append(np.asarray(estimate(keep), dtype=float))
    draws = np.array(draws)
    spread = np.sqrt((g - 1.0) / g * np.sum((draws - draws.mean(axis=0)) ** 2, axis=0))
    return spread * t_over_normal(g)
