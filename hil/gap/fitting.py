"""Fitting pieces shared by the edge and the sampled-signal diagnosis: weighted least squares on
cell means and the weighted RMS of cell means (the gap metric). The held-out shrink and its
interval are the selection engine's (hil.gap.selection)."""

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
