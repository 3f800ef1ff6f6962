"""Sim-to-real gap diagnosis (docs/gap.md)."""

from .diagnose import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
