"""Commutation prediction: paper Section 3 (state model, Sage-Husa), its baselines and the firmware peers."""

from .model import MotorModel
from .peers import MovingAveragePredictor, PllPredictor, SectorHoldPredictor, VbAkfPredictor
from .predictors import FilterSettings, KalmanPredictor, PrecalibrationPredictor, PredictionRun, SageHusaPredictor

__all__ = [
    "MotorModel",
    "FilterSettings",
    "KalmanPredictor",
    "PrecalibrationPredictor",
    "PredictionRun",
    "SageHusaPredictor",
    "SectorHoldPredictor",
    "MovingAveragePredictor",
    "PllPredictor",
    "VbAkfPredictor",
]
