"""The one effect-selection engine of the gap diagnosis (docs/gap.md, "Which" and "How far").

Every route (edge cells of a recording with segments, the sampled signals' cells, the spline fit
of an ordinary run) states its candidates as fits it can make; this module decides with one set
of rules:

- one significance level (``ALPHA``) for the gap, the remainder and the stop of the selection;
- one BIC rule (``hil.calibration.stats.bic_gain`` >= ``BIC_MIN``) and one physical-bounds check (the route's);
- one parsimony rule: candidates whose explained chi-square is equal within noise to the best
  one are tied, and the tie goes to the fewest new parameters;
- one confounding rule with its refit check: a rival that alone explains at least
  ``CONFOUND_RATIO`` as much as an accepted effect and earns nothing once the accepted set is in;
- one outlier cut (``hil.calibration.stats.inliers``: ``OUTLIER_SD`` robust standard deviations, the
  calibration's and the twin's too);
- one held-out shrink with its interval from a bootstrap over blocks (operating points or
  stretches of time): residuals correlated inside a block stay together, so the interval holds
  under correlated noise where a bootstrap over edges or cells would be too narrow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

# the outlier cut and the BIC rule are the project's (hil.calibration.stats), shared with the calibration and the twin
from ..calibration.stats import BIC_MIN, bic_gain

#: significance of a gap against its noise floor, of a remainder after the accepted effects, and
#: the selection's stop. 1e-3: a diagnosis tests dozens to hundreds of cells per recording and a
#: user runs it on many recordings; at 1e-3 a null recording raises a false gap once in a
#: thousand (0 of 100 on the validation), while a real effect at SNR 3 gives p far below it.
ALPHA = 1e-3
#: a rival that alone explains at least this share of what an accepted effect explains alone
CONFOUND_RATIO = 0.9
#: only a substantial accepted effect has confounded rivals: alone it explains at least this share
#: of what the best candidate explains alone (a small effect kept after a large one would pair
#: with every rival the large one already explains)
CONFOUND_MIN_SHARE = 0.1
#: bootstrap draws of the held-out shrink and its interval (5-95 %)
N_BOOT = 300
INTERVAL_PERCENT = (5.0, 95.0)


def explained_noise_sd(gain: float, k: int) -> float:
    """Standard deviation of an explained chi-square: under noise it is non-central chi-square
    with k degrees of freedom and non-centrality about ``gain``, variance 2 (k + 2 gain)."""
    return math.sqrt(2.0 * (k + 2.0 * max(gain, 0.0)))


def equal_within_noise(gain_a: float, k_a: int, gain_b: float, k_b: int) -> bool:
    """Two candidates explain the same within noise: their explained chi-squares differ by less
    than twice the larger one's standard deviation."""
    return abs(gain_a - gain_b) <= 2.0 * max(explained_noise_sd(gain_a, k_a), explained_noise_sd(gain_b, k_b))


@dataclass
class Trial:
    """One candidate fitted after a set of effects: the remainder chi-square, the parameters it
    adds, whether its fitted values are physical, and the route's own fit (``fit``)."""

    name: str
    chi2: float
    k: int
    physical: bool
    search_penalty: float = 0.0
    fit: object = None
    gain: float = 0.0  #: chi-square it removes from the set before it
    delta_bic: float = 0.0


#: the route's fit of the set ``fitted`` plus one candidate; None when it adds nothing
TryAdd = Callable[[list[str], str], "Trial | None"]


@dataclass
class Selection:
    fitted: list[str]  #: the effects kept, in the order chosen
    steps: list[Trial]  #: the chosen trial of each step
    first: dict[str, Trial]  #: every candidate fitted alone (the ranking)
    ties: list[list[str]]  #: (chosen, rival) equal within noise; the chosen has fewer parameters
    chi2_0: float
    chi2_end: float
    n_obs: int

    def share_alone(self, name: str) -> float:
        """Share of the excess chi-square (chi2_0 - n) that ``name`` removes alone: the ranking
        score. Each share is the candidate on its own, so the shares of rivals that explain the
        same pattern overlap and need not add up to 1."""
        t = self.first.get(name)
        excess = self.chi2_0 - self.n_obs
        if t is None or excess <= 0:
            return 0.0
        return float(max(min(t.gain / excess, 1.0), 0.0))


def forward_select(
    names: list[str],
    try_add: TryAdd,
    chi2_0: float,
    n_obs: int,
    remainder_p: Callable[[list[str], Trial], float],
    start: list[str] | None = None,
) -> Selection:
    """Forward selection: each step fits every remaining candidate after the effects kept; among
    the physical ones that gain at least ``BIC_MIN``, those equal within noise to the largest
    gain are tied and the tie goes to the fewest new parameters (then the larger gain). BIC's own
    penalty separates only gains a few units apart, while at a high SNR the noise of a gain of
    thousands is tens of units. Stops when nothing earns its place or the remainder is no longer
    significant (``remainder_p`` > ``ALPHA``). ``start``: nuisance effects every fit carries."""
    fitted = list(start or [])
    steps: list[Trial] = []
    first: dict[str, Trial] = {}
    ties: list[list[str]] = []
    chi2_now = chi2_0
    while True:
        rows = []
        for name in names:
            if name in fitted:
                continue
            t = try_add(fitted, name)
            if t is None:
                continue
            t.gain = chi2_now - t.chi2
            t.delta_bic = bic_gain(t.gain, t.k, n_obs, t.search_penalty)
            if not steps:
                first[name] = t
            rows.append(t)
        eligible = [t for t in rows if t.physical and t.delta_bic >= BIC_MIN]
        if not eligible:
            break
        top = max(eligible, key=lambda t: t.gain)
        tied = [t for t in eligible if equal_within_noise(top.gain, top.k, t.gain, t.k)]
        best = min(tied, key=lambda t: (t.k, -t.gain))
        for t in tied:
            if t is not best and t.k > best.k:
                ties.append([best.name, t.name])
        fitted.append(best.name)
        steps.append(best)
        chi2_now = best.chi2
        if remainder_p(fitted, best) > ALPHA:
            break
    return Selection(fitted, steps, first, ties, chi2_0, chi2_now, n_obs)


def confounded_rivals(
    sel: Selection,
    accepted: list[str],
    names: list[str],
    refit_chi2: Callable[[str], float],
    alone: dict[str, float] | None = None,
) -> list[list[str]]:
    """Rivals the data cannot tell from a substantial accepted effect (``CONFOUND_MIN_SHARE``):
    alone they explain at least ``CONFOUND_RATIO`` as much (and physically), and refitted after
    the kept set they lower the chi-square by less than ``BIC_MIN`` (``refit_chi2(m)``: the
    remainder with ``m`` added). ``alone``: what each candidate explains alone in the route's own
    measure (default: the chi-square it removes alone)."""
    alone = alone if alone is not None else {n: t.gain for n, t in sel.first.items()}
    pairs: list[list[str]] = []
    g_best = max(alone.values(), default=0.0)
    for n in accepted:
        g_n = alone.get(n, 0.0)
        if g_n <= 0 or g_n < CONFOUND_MIN_SHARE * g_best:
            continue
        for m in names:
            if m == n or m in sel.fitted or m not in sel.first:
                continue
            if alone.get(m, 0.0) < CONFOUND_RATIO * g_n or not sel.first[m].physical:
                continue
            if sel.chi2_end - refit_chi2(m) < BIC_MIN:
                pair = sorted([n, m])
                if pair not in pairs:
                    pairs.append(pair)
    return pairs


# --- held-out shrink -------------------------------------------------------------------------


@dataclass
class BlockSums:
    """Per block (operating point or stretch of time): the sum over its cells of n (m^2 - v)
    (the systematic part of the squared cell means, their noise ``v`` removed where known) and
    the sum of n. The gap of a set of blocks is sqrt(sum of the first / sum of the second)."""

    block: np.ndarray
    sq: np.ndarray
    n: np.ndarray

    @classmethod
    def of(cls, block: np.ndarray, n: np.ndarray, mean: np.ndarray, var_of_mean: np.ndarray | None = None):
        ids = np.unique(block)
        inv = np.searchsorted(ids, block)
        part = n * (mean**2 - (0.0 if var_of_mean is None else var_of_mean))
        return cls(ids, np.bincount(inv, part, minlength=ids.size), np.bincount(inv, n, minlength=ids.size))

    def gap(self, counts: np.ndarray | None = None) -> float:
        c = np.ones(self.block.size) if counts is None else counts
        den = float(np.sum(c * self.n))
        return float(math.sqrt(max(float(np.sum(c * self.sq)), 0.0) / den)) if den > 0 else 0.0


@dataclass
class Shrink:
    shrink: float | None
    before: float
    after: float | None
    interval: list[float] | None
    blocks: int
    draws: list[float] = field(default_factory=list)


def heldout_shrink(before: BlockSums, after: BlockSums, n_boot: int = N_BOOT, seed: int = 0) -> Shrink:
    """Shrink ``1 - after / before`` of the gap on held-out blocks, with its 5-95 % interval from a
    bootstrap over the blocks (both gaps over the same resampled blocks). ``before`` and
    ``after`` are the held-out cells without and with the effects chosen and fitted on the other
    blocks. No interval with fewer than two blocks."""
    common = np.intersect1d(before.block, after.block)
    b_idx, a_idx = np.searchsorted(before.block, common), np.searchsorted(after.block, common)
    b = BlockSums(common, before.sq[b_idx], before.n[b_idx])
    a = BlockSums(common, after.sq[a_idx], after.n[a_idx])
    g0, g1 = b.gap(), a.gap()
    shrink = 1.0 - g1 / g0 if g0 > 0 else None
    if common.size < 2 or shrink is None:
        return Shrink(shrink, g0, g1, None, int(common.size))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(n_boot):
        counts = np.bincount(rng.integers(0, common.size, common.size), minlength=common.size).astype(float)
        d0 = b.gap(counts)
        if d0 > 0:
            draws.append(1.0 - a.gap(counts) / d0)
    interval = [float(np.percentile(draws, INTERVAL_PERCENT[0])), float(np.percentile(draws, INTERVAL_PERCENT[1]))]
    return Shrink(float(shrink), g0, g1, interval if draws else None, int(common.size), draws)
