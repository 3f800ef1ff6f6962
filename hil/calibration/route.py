"""``calibrate(recording)``: the project's calibration of a recording, one entry point, one result.

It chooses the route itself:

* **segments** (a calibration campaign: steady set points, an encoder or the paper's route from
  capture times, ``fit.fit_corrections``);
* **ordinary run** (a capture of the Hall lines alone: no segments, or no forward segment without
  an encoder; ``ordinary.ordinary_calibration``).

Both routes apply the same bounds and refusals (``ordinary``'s ``pole_table_refusal``,
``installation_refusal``, ``delay_refusal`` with ``delay_bound_s``): a value beyond its physical
bound is refused with the reason and never written as a table entry. Both return a
``Calibration``, whose ``to_json_dict`` is what ``hil calibrate --json`` writes (the keys of
docs/calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.edges import HallSteps, electrical_speed_hz

from .corrections import SENSORS, Corrections
from .fit import fit_corrections
from .ordinary import (
    Circuit,
    Effects,
    Fit,
    delay_bound_s,
    delay_refusal,
    effect_columns,
    hall_steps,
    installation_refusal,
    ordinary_calibration,
    pole_table_refusal,
)

ROUTES = ("segments", "ordinary")


@dataclass
class Calibration:
    """One calibration of a recording, whichever route made it."""

    route: str  #: "segments" or "ordinary"
    corrections: Corrections  #: the table the controller applies (refused entries neutral)
    json: dict  #: the JSON form (``to_json_dict``)
    steps: HallSteps | None = None  #: ordinary run: the decoded edges
    fit: Fit | None = None  #: ordinary run: the joint fit the figures come from
    table_fit: Fit | None = None  #: ordinary run: the fit of the effects the table holds

    @property
    def refused(self) -> list[dict]:
        return self.json["refused"]

    @property
    def undetermined(self) -> dict[str, str]:
        return self.json["undetermined"]

    def to_json_dict(self) -> dict:
        return self.json

    def edge_corrections_s(self, steps: HallSteps, idx: np.ndarray) -> np.ndarray:
        """Ordinary run: how late each edge ``idx`` of ``steps`` (decoded like the calibration's
        edges, the same boundary numbering) is captured by the sensor effects the table holds
        (refused ones left out; the rotor's own sector-locked speed ripple is not a sensor
        effect). Subtract it from the capture times for the corrected instants. The time per
        degree at each edge is the electrical turn around it (six sectors, so the deviations
        themselves average out)."""
        if self.route != "ordinary" or self.table_fit is None:
            raise ValueError("edge corrections from capture times need the ordinary-run route")
        f = self.table_fit
        eff = Effects(
            static=any(n.startswith("static_") for n in f.names),
            delay="delay_diff_s" in f.names,
            pole_pairs=sum(n.startswith("pole_0_") for n in f.names) + 1 if "pole_0_0" in f.names else None,
        )
        hz = electrical_speed_hz(steps.t_s, window_sectors=6, run=steps.run)[idx]
        tau = 1.0 / (360.0 * hz)
        cols, names = effect_columns(steps, idx, tau, eff)
        refused = {r["field"] for r in self.refused}
        coef = np.array(
            [
                0.0
                if (n == "delay_diff_s" and "rise_fall_delay_difference_s" in refused)
                or (n.startswith("static_") and "installation_offset_deg_e" in refused)
                or n not in f.names
                else f.coef[f.names.index(n)]
                for n in names
            ]
        )
        return cols @ coef if names else np.zeros(idx.size)


def calibrate(rec, *, circuit: Circuit | None = None, source: str = "") -> Calibration:
    """The project's calibration of ``rec`` (a ``hil.recording.Recording``), by the route its
    content allows (module docstring)."""
    circuit = circuit or Circuit()
    source = source or str(rec.path or "recording")
    if rec.ordinary or _no_forward_without_encoder(rec):
        steps = hall_steps(rec.t_s, rec.sensor, rec.rising)
        out, fit, table_fit = ordinary_calibration(
            steps, tick_s=rec.timer_tick_s, pole_pairs=rec.stated_pole_pairs, circuit=circuit, source=source
        )
        corr = Corrections.from_json_dict(out)
        return Calibration("ordinary", corr, out, steps, fit, table_fit)
    corr = fit_corrections(rec)
    refused = []
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
    return Calibration("segments", corr, {**corr.to_json_dict(), "refused": refused})


def _no_forward_without_encoder(rec) -> bool:
    """Steady segments without an encoder, none of them forward: the paper's route (Eq. 2, 6 on
    forward turns) has nothing to read; the ordinary-run model reads either direction."""
    return rec.ref_angle_mech_deg is None and all(s.direction != "forward" for s in rec.segments)
