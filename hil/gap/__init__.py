"""Sim-to-real gap diagnosis (issue 7, design notes section 6)."""

from .diagnose import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
