"""Sim-to-real gap diagnosis (docs/gap.md): ``diagnose(recording)`` chooses its route."""

from __future__ import annotations

from bldc.reasons import Reason
from hil.recording.format import Recording

from .diagnose import Diagnosis, diagnose_segments
from .ordinary import diagnose_ordinary

__all__ = ["Diagnosis", "diagnose"]


def diagnose(rec: Recording, model=None, candidates: list[str] | None = None) -> Diagnosis:
    """Diagnose ``rec``: the route follows the recording. With operating points (segments), against
    ``model`` (a PlantConfig; None = the nominal motor, no effects); an ordinary run (capture
    times only) against an ideal motor on a smooth trajectory (``model`` and ``candidates`` do not
    apply and are named in ``not_assessed`` when given)."""
    if not rec.ordinary:
        return diagnose_segments(rec, model, candidates)
    from hil.calibration.ordinary import hall_steps

    notes = []
    if model is not None:
        notes.append(Reason("GAP-017"))
    if candidates is not None:
        notes.append(Reason("GAP-018"))
    return diagnose_ordinary(rec, hall_steps(rec.t_s, rec.sensor, rec.rising), notes)
