"""``calibrate(recording)``: the project's calibration of a recording, one entry point, one result.

It chooses the route itself:

* **segments** (a calibration campaign: steady set points, an encoder or the paper's route from
  capture times, ``fit.fit_corrections``);
* **ordinary run** (a capture of the Hall lines alone: no segments, or no forward segment without
  an encoder; ``ordinary.ordinary_calibration``).

Both routes apply the same bounds and refusals (``refusals``: ``pole_table_refusal``,
``installation_refusal``, ``delay_refusal`` with ``delay_bound_s``): a value beyond its physical
bound is refused with the reason and never written as a table entry. Both return a
typed ``Calibration`` (``result``), whose ``to_json()`` is what ``hil calibrate --json`` writes (the
keys of docs/calibration.md).
"""

from __future__ import annotations

from .corrections import SENSORS
from .fit import fit_corrections
from .ordinary import hall_steps, ordinary_calibration
from .refusals import Circuit, delay_bound_s, delay_refusal, installation_refusal, pole_table_refusal
from .result import ROUTES, Calibration, Refusal

__all__ = ["ROUTES", "Calibration", "Circuit", "calibrate"]


def calibrate(rec, *, circuit: Circuit | None = None, source: str = "") -> Calibration:
    """The project's calibration of ``rec`` (a ``hil.recording.format.Recording``), by the route its
    content allows (module docstring)."""
    circuit = circuit or Circuit()
    source = source or str(rec.path or "recording")
    if rec.ordinary or _no_forward_without_encoder(rec):
        steps = hall_steps(rec.t_s, rec.sensor, rec.rising)
        return ordinary_calibration(
            steps, tick_s=rec.timer_tick_s, pole_pairs=rec.stated_pole_pairs, circuit=circuit, source=source
        )
    corr = fit_corrections(rec)
    refused: list[Refusal] = []
    refusal = pole_table_refusal(corr.pole_offset_deg_e)
    if refusal:
        refused.append(refusal)
        corr.pole_offset_deg_e = []
    refusal = installation_refusal(corr.installation_offset_deg_e)
    if refusal:
        refused.append(refusal)
        corr.installation_offset_deg_e = dict.fromkeys(SENSORS, 0.0)
    top_hz_e = max(s.speed_rpm for s in rec.segments) / 60.0 * rec.pole_pairs
    bound_s, bound_why = delay_bound_s(circuit, top_hz_e) if top_hz_e > 0 else circuit.bound_s()
    for polarity in ("rise", "fall"):
        delay_s = corr.conditioning_delay_s[polarity]
        refusal = delay_refusal(f"conditioning_delay_s.{polarity}", delay_s, bound_s, bound_why)
        if refusal:
            refused.append(refusal)
            corr.conditioning_delay_s[polarity] = 0.0
    return Calibration("segments", corr, refused)


def _no_forward_without_encoder(rec) -> bool:
    """Steady segments without an encoder, none of them forward: the paper's route (Eq. 2, 6 on
    forward turns) has nothing to read; the ordinary-run model reads either direction."""
    return rec.ref_angle_mech_deg is None and all(s.direction != "forward" for s in rec.segments)
