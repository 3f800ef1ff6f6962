"""The typed result of a calibration: ``Calibration``, whichever route made it, and its parts.

Every figure is a field with its unit in its name; the JSON that ``hil calibrate --json`` writes
(the keys of docs/calibration.md, saved files included) is made in one place, ``to_json()``, from
these fields: the sentences a reader sees beside the numbers (the direction, the steadiness, a
stationarity statement) are written there from the typed values, not carried as data.

``ordinary`` and ``route`` build these; this module imports neither.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bldc.edges import HallSteps
from bldc.reasons import Reason, words

from .corrections import Corrections

#: an ``ordinary.Fit`` (not imported: ``ordinary`` builds results of this module)
Fit = Any

ROUTES = ("segments", "ordinary")
#: the method of the ordinary-run route, as its JSON's ``info`` states it
ORDINARY_METHOD = "ordinary run: trajectory splines and edge offsets by joint weighted least squares"
#: what the method cross-check is (an honest label: the same edges, the same model)
CROSS_CHECK_METHOD = (
    "method cross-check, not an independent measurement: the same edges and the same two-parameter "
    "model (delay and constant asymmetry) read from sector widths alone, half the fall-to-rise minus "
    "rise-to-fall width vs speed (linregress; errors from a delete-a-stretch jackknife)"
)


@dataclass(frozen=True)
class Refusal:
    """A fitted value beyond its physical bound: never written as a table entry (neutral there)."""

    field: str  #: the JSON key (with ``.rise``/``.fall`` for a delay polarity)
    reason: Reason  #: the value, the bound and what a value beyond it means

    def to_json(self) -> dict:
        return {"field": self.field, "reason": words(self.reason)}


@dataclass
class Estimate:
    """A figure with its standard error, or why it is not given."""

    value: float | None
    stderr: float | None
    reason: Reason | None = None  #: why ``value`` is None
    fitted: float | None = None  #: refused: the value the fit gave (never in the table)
    stderr_stationary: float | None = None  #: widened for drift: the standard error before

    def to_json(self) -> dict:
        out: dict = {"value": self.value, "stderr": self.stderr}
        if self.reason is not None:
            out["reason"] = words(self.reason)
        if self.fitted is not None:
            out["fitted"] = self.fitted
        if self.stderr_stationary is not None:
            out["stderr_stationary"] = self.stderr_stationary
        return out


@dataclass(frozen=True)
class Halves:
    """One figure fitted on each half of the used edges alone."""

    value_halves: tuple[float, float]  #: in the figure's own unit
    stderr_halves: tuple[float, float]
    z: float  #: |a - b| / hypot(se_a, se_b)
    widen_by: float  #: half the halves' difference where z is beyond the bound, else 0

    def to_json(self) -> dict:
        return {"halves": list(self.value_halves), "stderr": list(self.stderr_halves), "z": self.z,
                "widen_by": self.widen_by}


@dataclass
class Stationarity:
    """Whether each figure held through the capture (``ordinary._stationarity``)."""

    z_bound: float  #: halves differing by more standard errors than this: not stationary
    figures: dict[str, Halves] = field(default_factory=dict)
    not_checked: str | None = None  #: why the halves could not be fitted alone

    @property
    def stationary(self) -> bool:
        return not any(h.widen_by for h in self.figures.values())

    def statement(self) -> str:
        if self.not_checked is not None:
            return f"not checked: a half could not be fitted alone ({self.not_checked})"
        worst = sorted(((h.z, key, *h.value_halves, h.widen_by) for key, h in self.figures.items() if h.widen_by),
                       reverse=True)
        if not worst:
            return "the halves agree within their errors"
        return "NOT stationary: " + "; ".join(
            f"{key} halves {a:.4g} / {b:.4g} (z = {z:.1f}), its standard error widened by {w:.3g}"
            for z, key, a, b, w in worst
        )

    def to_json(self) -> dict:
        return {
            "method": "the whole capture's model on each half of the used edges alone (by edge count); "
            f"a figure is not stationary where its halves differ by z > {self.z_bound:g}",
            "figures": {key: h.to_json() for key, h in self.figures.items()},
            "stationary": self.stationary,
            "statement": self.statement(),
        }


@dataclass
class IndependentDelay:
    """The method cross-check: the rise-minus-fall delay from sector widths alone (no trajectory
    model). It reads the same edges with the same two-parameter model (delay and constant
    asymmetry), so it checks the trajectory fit's method, not the data. Per window of
    seven edges starting at a rising edge, half the difference of the mean fall-to-rise and
    rise-to-fall sector widths in angle, regressed on the window's speed: slope = D, intercept =
    the constant asymmetry. Weights 1/2, 1, 1, 1/2 on the four rise-to-fall sectors cancel a
    linear change of speed inside the window."""

    delay_diff_s: float
    stderr_s: float
    asymmetry_deg_e: float
    asymmetry_stderr_deg_e: float
    windows: int
    speed_range_hz_e: tuple[float, float]

    def to_json(self) -> dict:
        return {
            "method": CROSS_CHECK_METHOD,
            "rise_fall_delay_difference_s": Estimate(self.delay_diff_s, self.stderr_s).to_json(),
            "rise_fall_angle_asymmetry_deg_e": Estimate(self.asymmetry_deg_e, self.asymmetry_stderr_deg_e).to_json(),
            "windows": self.windows,
        }


@dataclass
class OrdinaryAssumptions:
    """What an ordinary-run calibration assumed or found about the capture."""

    pole_pairs: int | None
    pole_pairs_source: Reason  #: stated, found (with its BIC gain) or not found, and why
    timer_tick_s: float | None
    forward_edges: int  #: used edges turning forward
    reverse_edges: int
    edges: int
    edges_used: int
    runs: int
    reversals: int
    stalls_split: int
    glitches_removed: int
    invalid_states_dropped: int
    short_runs_dropped: int
    outlier_edges: int
    speed_range_hz_e: tuple[float, float]  #: 5-95 % electrical speed
    speed_ratio: float
    min_speed_ratio: float  #: below it a delay and a constant angle cannot be told apart
    knot_cycles: float  #: electrical cycles between trajectory knots (chosen by BIC)
    ripple_modelled: bool  #: the sector-locked speed ripple was modelled
    trajectory_residual_rms_deg_e: float
    delay_bound_s: float
    delay_bound_why: Reason  #: where the delay bound comes from (the circuit, or half a sector)
    pole_offset_bound_deg_e: float

    @property
    def speed_range_sufficient(self) -> bool:
        """Wide enough to tell a delay (grows with speed) from a constant angle."""
        return bool(self.speed_ratio >= self.min_speed_ratio)

    def sector_locked_speed_ripple(self) -> str:
        if self.ripple_modelled:
            return ("modelled (an angle per sector boundary falling with 1/speed^2: the rotor's commutation torque "
                    "ripple; not a sensor deviation, not in the tables)")
        return "not modelled: not seen (BIC), or not separable from the delay over this speed range"

    def steadiness(self) -> str:
        return (f"not assumed: the trajectory is a cubic spline with a knot every {self.knot_cycles} electrical "
                "cycles (chosen by BIC), fitted jointly with the offsets")

    def direction(self) -> str:
        if self.reverse_edges == 0:
            return "forward (Hall sequence A, B, C)"
        if self.forward_edges == 0:
            return "reverse (Hall sequence A, C, B)"
        return f"both: {self.forward_edges} forward and {self.reverse_edges} reverse edges"

    def to_json(self) -> dict:
        return {
            "pole_pairs": self.pole_pairs,
            "pole_pairs_source": words(self.pole_pairs_source),
            "timer_tick_s": self.timer_tick_s,
            "direction": self.direction(),
            "edges": self.edges,
            "edges_used": self.edges_used,
            "runs": self.runs,
            "reversals": self.reversals,
            "stalls_split": self.stalls_split,
            "glitches_removed": self.glitches_removed,
            "invalid_states_dropped": self.invalid_states_dropped,
            "short_runs_dropped": self.short_runs_dropped,
            "outlier_edges": self.outlier_edges,
            "speed_range_hz_e": list(self.speed_range_hz_e),
            "speed_ratio": self.speed_ratio,
            "speed_range_sufficient": self.speed_range_sufficient,
            "steadiness": self.steadiness(),
            "knot_cycles": self.knot_cycles,
            "sector_locked_speed_ripple": self.sector_locked_speed_ripple(),
            "trajectory_residual_rms_deg_e": self.trajectory_residual_rms_deg_e,
            "delay_bound_s": self.delay_bound_s,
            "delay_bound": words(self.delay_bound_why),
            "pole_offset_bound_deg_e": self.pole_offset_bound_deg_e,
            "bounds_note": (
                "these bounds judge a calibration; the acceptance suite's fault draws (REQ-ROB-001) keep the "
                "effect library's own ranges"
            ),
        }


@dataclass
class OrdinaryFindings:
    """What an ordinary run gives beside the table: the figures capture times determine, their
    errors, whether they held through the capture, and what was assumed."""

    rise_fall_delay_difference_s: Estimate
    rise_fall_angle_asymmetry_deg_e: Estimate
    fit_stderr_method: str  #: how the fit's standard errors were obtained (``uncertainty``)
    stationarity: Stationarity
    cross_check: IndependentDelay | None
    assumptions: OrdinaryAssumptions
    source: str

    def stderr_method(self) -> str:
        drift = "; widened where the capture's halves disagree (stationarity)"
        return self.fit_stderr_method + ("" if self.stationarity.stationary else drift)


@dataclass
class Calibration:
    """One calibration of a recording, whichever route made it (``route.calibrate``)."""

    route: str  #: one of ``ROUTES``
    corrections: Corrections  #: the table the controller applies (refused entries neutral)
    refused: list[Refusal] = field(default_factory=list)
    ordinary: OrdinaryFindings | None = None  #: ordinary run: the figures beside the table
    steps: HallSteps | None = None  #: ordinary run: the decoded edges
    fit: Fit | None = None  #: ordinary run: the joint fit the figures come from
    table_fit: Fit | None = None  #: ordinary run: the fit of the effects the table holds

    @property
    def undetermined(self) -> dict[str, Reason]:
        """What the data could not determine, with the reason (left neutral in the table)."""
        return self.corrections.undetermined

    def to_json(self) -> dict:
        """The JSON ``hil calibrate --json`` writes (docs/calibration.md)."""
        refused = [r.to_json() for r in self.refused]
        if self.ordinary is None:
            return {**self.corrections.to_json_dict(), "refused": refused}
        c, o = self.corrections, self.ordinary
        cross_check = None if o.cross_check is None else o.cross_check.to_json()
        return {
            "installation_offset_deg_e": dict(c.installation_offset_deg_e),
            "pole_offset_deg_e": list(c.pole_offset_deg_e),
            "conditioning_delay_s": dict(c.conditioning_delay_s),
            "armature_reaction_deg_e_per_a": c.armature_reaction_deg_e_per_a,
            "rise_fall_delay_difference_s": o.rise_fall_delay_difference_s.to_json(),
            "rise_fall_angle_asymmetry_deg_e": o.rise_fall_angle_asymmetry_deg_e.to_json(),
            "refused": refused,
            "undetermined": c.undetermined_words(),
            "uncertainty": c.uncertainty,
            "stderr_method": o.stderr_method(),
            "stationarity": o.stationarity.to_json(),
            "conditioning_delay_table": c.delay_table,
            "method_cross_check": cross_check,
            "independent_estimate": cross_check,  # the same object under its former name (an alias)
            "assumptions": o.assumptions.to_json(),
            "info": c.info,
        }

    #: the former name of ``to_json`` (callers and docs use both)
    to_json_dict = to_json
