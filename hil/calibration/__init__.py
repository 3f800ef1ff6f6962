"""Pre-calibration of the Hall position deviations (paper Section 2 and 4.2)."""

from .corrections import Corrections
from .fit import CalibrationError, fit_corrections

__all__ = ["Corrections", "CalibrationError", "fit_corrections"]
