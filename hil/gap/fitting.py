"""Fitting pieces shared by the edge and the sampled-signal diagnosis: weighted least squares on
cell means, the weighted RMS of cell means (the gap metric), and the leave-one-operating-point-out
shrink with its bootstrap interval over segments."""

from __future__ import annotations

import math

import numpy as np


def wls(x: np.ndarray, y: np.ndarray, w: np.ndarray):
    """Weighted least squares: (coefficients, their standard errors, chi-square of the rest)."""
    if x.shape[1] == 0:
        return np.zeros(0), np.zeros(0), float(np.sum(w * y * y))
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=None)
    resid = y - x @ coef
    cov = np.linalg.pinv((x * w[:, None]).T @ x)
    return coef, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(np.sum(w * resid * resid))


def cell_rms(cell_mean: np.ndarray, weight: np.ndarray) -> float:
    """Weighted RMS of cell means: the systematic residual (the noise left in a cell mean is not
    subtracted, so a shrink measured with it is conservative)."""
    return float(math.sqrt(np.sum(weight * cell_mean**2) / np.sum(weight)))


def heldout_shrink(cell_mean: np.ndarray, heldout_resid: np.ndarray, weight: np.ndarray, segment: np.ndarray,
                   n_boot: int = 200, seed: int = 0):
    """Shrink of the gap on held-out cells: ``heldout_resid`` is each cell's residual predicted
    from the other segments; cells with zero ``weight`` could not be predicted. Returns
    (shrink, gap after, 5-95 % bootstrap interval over segments, note)."""
    usable = np.unique(segment[weight > 0])

    def gaps(wts):
        return cell_rms(cell_mean, wts), cell_rms(np.where(weight > 0, heldout_resid, 0.0), wts)

    before, after = gaps(weight)
    rng = np.random.default_rng(seed)
    boots = []
    for _ in range(n_boot):
        pick = rng.choice(usable, usable.size, replace=True)
        wts = np.zeros_like(weight)
        for s in pick:
            wts = wts + weight * (segment == s)
        b, a = gaps(wts)
        boots.append(1 - a / b if b > 0 else 0.0)
    shrink = 1 - after / before if before > 0 else 0.0
    note = f"leave-one-operating-point-out over {usable.size} segments; interval: 5-95 % bootstrap over segments"
    return float(shrink), float(after), [float(np.percentile(boots, 5)), float(np.percentile(boots, 95))], note
