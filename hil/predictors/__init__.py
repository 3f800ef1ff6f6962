"""Commutation prediction: paper Section 3 (state model, Sage-Husa) and its baselines."""

from .model import MotorModel
from .predictors import FilterSettings, KalmanPredictor, PrecalibrationPredictor, PredictionRun, SageHusaPredictor

__all__ = [
    "MotorModel",
    "FilterSettings",
    "KalmanPredictor",
    "PrecalibrationPredictor",
    "PredictionRun",
    "SageHusaPredictor",
]
