"""The typed parts of a gap diagnosis (issue 40): figures with their units in their names, effect
names, no sentences. The JSON a diagnosis writes (docs/recording-format.md) is built by each
part's ``to_json`` alone; the sentences of the JSON and of the reports (a confounded pair's knob,
the pattern an ordinary run's parameters describe, a split-half figure's caveat) are made here
from those values, so the JSON and the renderers (hil.gap.report) say the same."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from bldc.reasons import Reason, words
from plant_models.effects import EFFECTS

from .candidates import ORDINARY_CANDIDATES
from .relevance import Relevance

#: a parameter's value: a number, one per sensor or pole, or named contrasts
ParamValue = float | list[float] | dict[str, float]

ORDINARY_ROUTE = "ordinary run"
#: where a diagnosis's pole-pair count comes from when the recording states it
STATED_IN_RECORDING = Reason("GAP-020")

def ordinary_meaning(name: str) -> str | None:
    """What the parameters of an effect an ordinary run fits describe (its JSON rows' ``meaning``)."""
    sig = ORDINARY_CANDIDATES.get(name)
    return sig.meaning if sig else None


def ordinary_knob(a: str, b: str) -> str | None:
    """An ordinary run's own knob for the pair (capture times alone: the experiment is a speed sweep)."""
    sig = ORDINARY_CANDIDATES.get(a)
    return sig.knobs.get(b) if sig else None


@dataclass(frozen=True)
class HeldOut:
    """How the held-out gap (``heldout_shrink``) was measured, or why it was not: a kind and the
    figures that go with it; ``text()`` words it for the reports (the JSON's ``heldout_note``)."""

    #: "" (not reached), "no effect accepted", "single segment", "below relevance", "noise only",
    #: "unpredicted", "leave one out", "not measurable", "training chose none", "stretches"
    kind: str = ""
    domain: str = "edges"  #: "edges" or "samples" (whose choice includes shape parameters)
    segments: int | None = None  #: leave one out: the segments held out in turn
    segments_choosing_nothing: int = 0  #: leave one out: those where the others chose no effect
    reason: str = ""  #: not measurable: why (the run's own error)
    stretches: int | None = None  #: an ordinary run's equal stretches (odd: training, even: judged)
    knot_cycles: float | None = None  #: the training stretches' knot spacing, electrical cycles
    pole_pairs: int | None = None  #: the training stretches' pole pairs (None: none found)
    chosen: tuple[str, ...] = ()  #: the effects the training stretches chose
    gap_before_deg_e: float | None = None  #: the gap on the held-out stretches before the effects
    shrink: float | None = None  #: the held-out shrink (a gap that grew is said so)

    def as_reason(self) -> Reason | None:
        """The held-out method or why there is none, as a reason (None: not reached)."""
        samples = self.domain != "edges"
        plain = {"no effect accepted": "GAP-030", "single segment": "GAP-031",
                 "below relevance": "GAP-033" if samples else "GAP-032", "noise only": "GAP-034",
                 "unpredicted": "GAP-035", "training chose none": "GAP-037"}
        k = self.kind
        if k in plain:
            return Reason(plain[k])
        if k == "not measurable":
            return Reason("GAP-036", {"error": self.reason})
        if k == "leave one out":
            held = Reason("GAP-039" if samples else "GAP-038", {"segments": self.segments})
            if self.segments_choosing_nothing:
                held = Reason("GAP-040", {"held_out": held,
                                          "segments_choosing_nothing": self.segments_choosing_nothing})
            return held
        if k == "stretches":
            held = Reason("GAP-041", {
                "stretches": self.stretches, "knot_cycles": self.knot_cycles, "pole_pairs": self.pole_pairs or "none",
                "effects": list(self.chosen), "gap_before_deg_e": self.gap_before_deg_e,
                "held_out_stretches": self.segments,
            })
            if self.shrink is not None and self.shrink <= 0:
                held = Reason("GAP-042", {"held_out": held})
            return held
        return None

    def text(self) -> str:
        """The reason worded (the JSON's ``heldout_note``; "" when not reached)."""
        why = self.as_reason()
        return words(why) if why else ""


def gap_metric(route: str, sampled: tuple[str, str] | None = None) -> str:
    """What the gap figures measure, as the reports word it: the edges' systematic angle residual
    (against the encoder, or on an ordinary run against an ideal motor on a smooth trajectory), or
    a sampled signal's, ``sampled`` = (domain, unit), when that signal's gap is the headline."""
    if sampled is not None:
        domain, unit = sampled
        return f"RMS over samples of the systematic {domain} residual (cell means), {unit}"
    if route == ORDINARY_ROUTE:
        return ("RMS over edges of the systematic edge-angle residual against an ideal motor on a smooth speed "
                "trajectory (cell means per stretch, direction, sensor boundary and speed band, noise removed), "
                "deg electrical")
    return "RMS over edges of the systematic edge-angle residual (cell means), deg electrical"


def knob(a: str, b: str) -> str:
    """The experiment that separates ``a`` from ``b``, as a full sentence: what to record and
    why it tells them apart (each effect's declaration holds its halves and its pair sentences)."""
    ca, cb = EFFECTS.get(a), EFFECTS.get(b)
    pair = (ca.pair_knobs.get(b) if ca else None) or (cb.pair_knobs.get(a) if cb else None)
    if pair:
        return pair
    rec_a = (ca.knob_record if ca else None) or "more operating points"
    rec_b = (cb.knob_record if cb else None) or "more operating points"
    record = rec_a if rec_a == rec_b else f"{rec_a} and {rec_b}"
    shows_a = (ca.knob_shows if ca else None) or f"{a} has its own fingerprint"
    shows_b = (cb.knob_shows if cb else None) or f"{b} has its own fingerprint"
    return f"Record {record}: {shows_a}, while {shows_b}."


@dataclass(frozen=True)
class Confounded:
    """Two effects the recording cannot tell apart (the JSON's ``confounded`` pair and its knob)."""

    names: list[str]  #: as the result lists them
    #: the order the knob sentence names them in when it is not ``names``' (a tie at selection:
    #: the effect kept first, its rival second)
    knob_order: tuple[str, str] | None = None

    def knob(self, route: str) -> str:
        """The experiment that separates them (an ordinary run has its own for some pairs)."""
        own = ordinary_knob(*self.names) if route == ORDINARY_ROUTE else None
        return own or knob(*(self.knob_order or self.names))


@dataclass
class FittedEffect:
    """An effect fitted to the recording: its named parameters (units in the names), their
    standard errors (a searched shape parameter has none), and what it does against its floor."""

    effect: str
    params: dict[str, ParamValue]
    stderr: dict[str, ParamValue] | None = None  #: None: the fit gives none (the edge jitter's)
    relevance: Relevance | None = None  #: None: no operating envelope to judge it against

    @property
    def relevant(self) -> bool:
        return self.relevance is None or self.relevance.relevant

    def to_json(self, route: str = "segments") -> dict:
        out: dict = {"effect": self.effect, "params": self.params}
        if self.stderr is not None:
            out["stderr"] = self.stderr
        meaning = ordinary_meaning(self.effect) if route == ORDINARY_ROUTE else None
        if meaning:
            out["meaning"] = meaning
        if self.relevance is not None:
            out["relevance"] = self.relevance.to_json()
        return out


@dataclass(frozen=True)
class NoiseGap:
    """The per-edge noise against the model's (a variance effect: the edge jitter): the pooled
    chi-square test of the excess and its held-out shrink over segments."""

    p_value: float
    significant: bool
    before_deg_e: float  #: RMS over edges of measured minus expected noise RMS
    after_heldout_deg_e: float | None  #: None: a single segment
    heldout_shrink: float | None

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RegionResidual:
    """The edge residual of one operating point (segment)."""

    segment: int  #: index into the recording's segments
    speed_rpm: float
    current_a: float
    load_scale: float
    direction: int  #: +1 forward, -1 reverse
    mean_deg_e: float
    rms_deg_e: float

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class OrderSpectrum:
    """Amplitude of the turn-averaged residual per mechanical order (0 .. 3 p for edges)."""

    amplitude: list[float]  #: in the unit of the residual it is the spectrum of (``unit``)
    unit: str = "deg_e"

    @property
    def mechanical_order(self) -> list[int]:
        return list(range(len(self.amplitude)))

    def to_json(self) -> dict:
        return {"mechanical_order": self.mechanical_order, f"amplitude_{self.unit}": self.amplitude}


@dataclass(frozen=True)
class EdgeLocalisation:
    """Where the mean edge residual (deg e, + = trails) of a recording with segments sits."""

    per_sensor_deg_e: dict[str, float]  #: "A", "B", "C"
    per_polarity_deg_e: dict[str, float]  #: "rise", "fall"
    per_pole_deg_e: dict[int, float]  #: magnet pole index
    per_region: list[RegionResidual]
    order_spectrum: OrderSpectrum | None = None  #: None: no segment holds a whole mechanical turn

    def to_json(self) -> dict:
        out: dict = {
            "per_sensor": self.per_sensor_deg_e,
            "per_polarity": self.per_polarity_deg_e,
            "per_pole": {str(k): v for k, v in self.per_pole_deg_e.items()},
            "per_region": [g.to_json() for g in self.per_region],
        }
        if self.order_spectrum is not None:
            out["order_spectrum"] = self.order_spectrum.to_json()
        return out


@dataclass(frozen=True)
class SensorPolarityMean:
    sensor: str  #: "A", "B", "C"
    polarity: str  #: "rise", "fall"
    mean_deg_e: float | None  #: None: no inlying edge of this sensor and polarity


@dataclass(frozen=True)
class OrdinaryLocalisation:
    """An ordinary run's mean angle residual of the trajectory-only fit per sensor and polarity."""

    by_sensor_and_polarity: list[SensorPolarityMean]

    def to_json(self) -> dict:
        return {
            "by_sensor_and_polarity": {
                f"{m.sensor}_{m.polarity}_mean_deg_e": m.mean_deg_e for m in self.by_sensor_and_polarity
            }
        }


@dataclass(frozen=True)
class SplitHalf:
    """An ordinary run's model fitted on the first and on the second half of its used edges alone:
    how far the estimates repeat on the same motor."""

    failure: str | None = None  #: why a half could not be fitted (then no figure)
    delay_diff_s: tuple[float, float] | None = None  #: rise-minus-fall delay difference of each half
    delay_diff_stderr_s: tuple[float, float] | None = None
    static_rms_difference_deg_e: float | None = None  #: the other parameters' RMS difference of the halves
    static_rms_deg_e: float | None = None  #: their RMS (the mean of the halves)

    @property
    def delay_relative_difference(self) -> float:
        a, b = self.delay_diff_s
        return abs(a - b) / max(abs(a + b) / 2, 1e-12)

    @property
    def delay_difference_z(self) -> float:
        (a, b), (sa, sb) = self.delay_diff_s, self.delay_diff_stderr_s
        return abs(a - b) / max(math.hypot(sa, sb), 1e-300)

    def to_json(self) -> dict:
        if self.failure is not None:
            return {"note": f"no split-half figure: {self.failure}"}
        out: dict = {"halves": "first and second half of the used edges, each fitted alone"}
        if self.delay_diff_s is not None:
            out["rise_fall_delay_difference_s"] = list(self.delay_diff_s)
            out["rise_fall_delay_difference_stderr_s"] = list(self.delay_diff_stderr_s)
            out["delay_relative_difference"] = self.delay_relative_difference
            out["delay_difference_z"] = self.delay_difference_z
        if self.static_rms_difference_deg_e is not None:
            out["static_parameters_rms_difference_deg_e"] = self.static_rms_difference_deg_e
            out["static_parameters_rms_deg_e"] = self.static_rms_deg_e
        return out


@dataclass(frozen=True)
class SegmentResidual:
    """A sampled signal's systematic residual on one operating point (in the domain's unit)."""

    segment_id: str
    rms: float
    cells: int


@dataclass(frozen=True)
class SampleLocalisation:
    """Where a sampled signal's residual sits: per segment, and over the mechanical turn (speed:
    its order spectrum, where cogging shows) or the electrical turn (voltage)."""

    per_segment: list[SegmentResidual]
    order_spectrum: OrderSpectrum | None = None  #: the speed residual's
    per_electrical_angle_v: dict[int, float] = field(default_factory=dict)  #: the voltage residual's, by deg e

    def to_json(self) -> dict:
        out: dict = {"per_segment": {g.segment_id: {"rms": g.rms, "cells": g.cells} for g in self.per_segment}}
        if self.order_spectrum is not None:
            out["order_spectrum"] = self.order_spectrum.to_json()
        if self.per_electrical_angle_v:
            out["per_electrical_angle_v"] = {str(k): v for k, v in self.per_electrical_angle_v.items()}
        return out
