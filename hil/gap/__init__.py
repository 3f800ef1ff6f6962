"""Sim-to-real gap diagnosis (docs/gap.md)."""

from .diagnose import Diagnosis
from .route import diagnose

__all__ = ["Diagnosis", "diagnose"]
