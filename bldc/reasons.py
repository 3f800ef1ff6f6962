"""Why a figure is not given, refused or bounded: a ``Reason`` is a numbered code with its numbers,
and ``words`` is the one place that turns it into the sentence a reader sees.

The results keep the code and the numbers (a program can test ``reason.code`` and read
``reason.numbers["bound_us"]`` instead of searching a sentence); the JSON, the command line and
the twin's notes show ``words(reason)``. The wording of every code is in ``WORDING``, here once, so
a sentence is changed in one place and a saved file, which holds the sentence, still reads: a plain
string read back is a ``Reason`` of the code ``FREE_TEXT`` (``Reason.from_json``).

This module is in ``bldc`` (the vocabulary every group may import) because the correction table
(``hil.calibration.corrections``, which imports nothing else of ours) holds reasons too.

A template is ``str.format`` text over the numbers' names (units in the names: ``_us``,
``_deg_e``, ``_hz_e``); ``words`` formats a list number item by item and a dict number as
``key value`` pairs, each with the field's format spec, joined by ", ", and a nested ``Reason``
by its own words.
"""

from __future__ import annotations

import string
from dataclasses import dataclass, field
from typing import Any

#: the code of a sentence read back from a saved file (its only number: ``text``)
FREE_TEXT = "TXT-000"

#: code -> wording template: the only table of reasons (CAL: calibration, GAP: gap diagnosis, TWIN: twin)
WORDING: dict[str, str] = {
    FREE_TEXT: "{text}",
    # refusals: a fitted value beyond its physical bound (hil.calibration.refusals)
    "CAL-001": "pole(s) {poles} at {offsets_deg_e:+.1f} deg e, beyond the controller's bound +-{bound_deg_e:.0f} "
    "deg e (a pole count that is not the motor's, or a speed change inside a segment taken as steady); the table "
    "is not written",
    "CAL-002": "{offsets_deg_e:+.1f} deg e beyond +-{bound_deg_e:.0f}: a wiring or channel-mapping error, not an "
    "offset",
    "CAL-003": "{value_us:.1f} us is beyond the bound {bound_us:.0f} us ({bound_why})",
    # where the conditioning-delay bound comes from
    "CAL-010": "stated maximum {bound_us:.0f} us",
    "CAL-011": "3 RC of the stated circuit (R {pullup_ohm:.3g} Ohm, C {filter_farad:.3g} F)",
    "CAL-012": "default {bound_us:.0f} us (open-collector Hall outputs with pull-up and filter capacitor; state the "
    "circuit to narrow it)",
    "CAL-013": "half a sector at the top speed {top_hz_e:.0f} Hz electrical ({sector_us:.0f} us per sector)",
    # where the pole-pair count comes from
    "CAL-020": "stated in the recording (motor.pole_pairs)",
    "CAL-021": "no pole pattern stands out (no pole count is assumed; pole offsets not determined)",
    "CAL-022": "{pole_pairs} pole pairs assumed: the pole-offset pattern that explains the capture best (BIC gain "
    "{bic_gain:.0f}); give motor.pole_pairs to state it",
    # an ordinary run's figures not given
    "CAL-030": "no static offsets fitted",
    "CAL-031": "the capture spans {low_hz_e:.1f}-{high_hz_e:.1f} Hz electrical (ratio {speed_ratio:.2f} < "
    "{min_speed_ratio}): a delay (grows with speed) and a constant angle cannot be told apart; record a speed ramp",
    # what capture times cannot give, whatever the capture (the ordinary-run route)
    "CAL-040": "capture times give only the rise-minus-fall difference (rise_fall_delay_difference_s); the common "
    "part needs an encoder or the raw Hall line beside the conditioned one. The table holds the difference on the "
    "later polarity and 0 on the other",
    "CAL-041": "needs a reference angle and phase currents",
    "CAL-042": "a lag common to every edge is invisible without an encoder",
    "CAL-043": "only relative offsets (sum zero) from capture times; the absolute reference needs an encoder or "
    "terminal voltages (Line-BEMF)",
    # what a segments recording with an encoder could not determine (hil.calibration.fit)
    "CAL-050": "edges of only {poles_seen} of {poles} poles; record whole mechanical turns",
    "CAL-051": "needs segments at several speeds (spread >= {min_spread:.0%} of the highest); got {speeds} speed(s), "
    "spread {spread:.0%}: a constant delay is indistinguishable from an offset",
    "CAL-052": "mean phase current varies by only {current_spread_a:.3g} A across segments; add loaded operating "
    "points",
    "CAL-053": "current moves together with speed (linearly), so armature reaction and conditioning delay cannot be "
    "told apart; add a load change at a fixed speed",
    # the paper's route from capture times (no encoder)
    "CAL-060": "needs a reference angle (ref_angle_mech_deg); the paper uses a magneto-electric position sensor for "
    "it",
    "CAL-061": "only relative deviations (Eq. 2, sum zero) could be determined: the absolute reference needs "
    "ref_angle_mech_deg or samples with u_a..u_c and i_a..i_c (Line-BEMF, Eq. 3-5)",
    "CAL-062": "needs a reference angle (encoder) at several speeds, or the raw sensor channel beside the conditioned "
    "one; capture times alone see only rise-fall differences",
    # GAP: the gap diagnosis (hil.gap). What an effect's fitted magnitude is judged by (Relevance.meaning)
    "GAP-001": "RMS commutation-angle shift over the recording's edges; floor {fraction:.0%} of the "
    "{budget_deg_e} deg_e budget",
    "GAP-002": "RMS commutation-angle jitter over the recording's edges; floor {fraction:.0%} of the "
    "{budget_deg_e} deg_e budget",
    "GAP-003": "{disturbs}; floor {fraction:.0%} of a {budget_share:.0%} {budget}",
    # what a diagnosis does not assess (Diagnosis.not_assessed)
    "GAP-010": "{effect}: {no_trace}",
    "GAP-011": "{effect}: needs samples.csv with phase currents and terminal voltages (speed and the reference "
    "encoder for cogging)",
    "GAP-012": "a lag common to every edge (the common part of hysteresis and of the conditioning delays, armature "
    "reaction at a load that follows speed): invisible in capture times; needs an encoder",
    "GAP-013": "the absolute installation offset (only offsets relative to each other, summing to zero): needs an "
    "encoder or terminal voltages (Line-BEMF)",
    "GAP-014": "armature_reaction, winding and magnet temperature, dead time, saturation: need phase currents or "
    "voltages",
    "GAP-015": "cogging torque and eccentricity: move the rotor, not the sensors; with capture times alone they are "
    "part of the speed trajectory (a once-per-turn pattern shows as pole offsets)",
    "GAP-016": "pole_offset: {pole_note}",
    "GAP-017": "--model: not used for an ordinary run (capture times only): the model is an ideal motor with ideal "
    "sensors on a smooth speed trajectory",
    "GAP-018": "candidates: an ordinary run has its own list (the effects capture times can see)",
    # where a diagnosis's pole-pair count comes from (found: CAL-021, CAL-022)
    "GAP-020": "stated in the recording",
    # how the held-out gap was measured, or why not (HeldOut)
    "GAP-030": "no effect accepted",
    "GAP-031": "held-out shrink cannot be measured: the recording has a single segment",
    "GAP-032": "every detected edge effect is below practical relevance",
    "GAP-033": "every detected effect is below practical relevance",
    "GAP-034": "the gap is in the noise only: shrink of the excess noise (RMS, deg_e) on held-out segments",
    "GAP-035": "held-out shrink cannot be measured: no operating point is predicted from the others",
    "GAP-036": "held-out shrink cannot be measured: {error}",
    "GAP-037": "the training stretches alone chose no effect",
    "GAP-038": "leave-one-operating-point-out over {segments} segments: the gap test, the effect choice and the fit "
    "see only the other segments; interval: 5-95 % bootstrap over segments",
    "GAP-039": "leave-one-operating-point-out over {segments} segments: the gap test, the effect choice, shape "
    "parameters and fit see only the other segments; interval: 5-95 % bootstrap over segments",
    "GAP-040": "{held_out}; on {segments_choosing_nothing} of them the other segments chose no effect",
    "GAP-041": "{stretches} equal stretches of the run (by edge count): on the odd ones alone the gap test, the knot "
    "spacing ({knot_cycles:g} electrical cycles), the pole pairs ({pole_pairs}), the effects ({effects}) and their "
    "values were chosen; they are judged on the even ones with only the speed trajectory refitted there; gap there "
    "before {gap_before_deg_e:.3g} deg e; interval: 5-95 % bootstrap over the {held_out_stretches} held-out "
    "stretches",
    "GAP-042": "{held_out}; the chosen effects do not hold on the held-out stretches (the gap grew): treat them as "
    "not established by this capture",
    # TWIN: a twin made from a Hall capture (hil.twin.capture): what it measured, what it assumed, its notes
    "TWIN-001": "{pole_pairs} ({source})",
    "TWIN-002": "{pole_pairs} from the base: the capture shows no pole pattern",
    "TWIN-003": "{offsets_deg_e:+.3f} deg e",
    "TWIN-004": "{mean_deg_e:+.3f} deg e from the base ({base}); capture times give only differences (an encoder or "
    "Line-BEMF gives the rest)",
    "TWIN-005": "no pole offsets: {why}",
    "TWIN-006": "no pole offsets: refused by the calibration",
    "TWIN-007": "{poles} poles, within +-{max_deg_e:.2f} deg e (sum zero per polarity: pole 0 is where the capture "
    "starts)",
    "TWIN-008": "a pattern of {edges_per_turn} edges per mechanical turn in the residuals, constant in angle, "
    "{rms_deg_e:.2f} deg e RMS (chi-square p-value {p_value:.1g}); measured in the capture's direction, applied in "
    "both",
    "TWIN-009": "{asymmetry_deg_e:+.3f} deg e (common part {common_deg_e:+.3f})",
    "TWIN-010": "rise-minus-fall delay not determined ({why}): the twin has none beyond the base's",
    "TWIN-011": "{delay_us:+.1f} us",
    "TWIN-012": "{common_us:.1f} us from the base ({base}): a lag of every edge is a time shift of the trajectory, "
    "invisible without an encoder",
    "TWIN-013": "{kind}: time {time_rms_us:.2f} us RMS, angle {angle_rms_deg_e:.3f} deg e RMS, AR(1) coefficient "
    "{correlation:.3f} (residuals less the timer's quantisation)",
    "TWIN-014": "{tick_us:.4g} us (the capture's sampling, kept in the plant: the controller sees edges this coarse)",
    "TWIN-015": "{tick_us:.4g} us: `hil twin check` samples the twin at it; not the controller's capture timer, so "
    "not a plant effect here (`--capture-tick-in-plant` keeps it)",
    "TWIN-016": "the capture states no timer tick",
    "TWIN-017": "from the base: {capture_blind}",
    "TWIN-018": "none (the base has none): {capture_blind}",
    "TWIN-019": "the capture spans {low_hz_e:.0f}-{high_hz_e:.0f} Hz electrical (5-95 %); beyond it the twin "
    "extrapolates (a delay grows with speed, the jitter model holds)",
    "TWIN-020": "{top_speed_rpm:.0f} (the capture's top speed, 95th percentile; --top-speed-rpm states the motor's "
    "own)",
    "TWIN-021": "{top_speed_rpm:.0f} (given)",
    "TWIN-022": "from the base ({base}): capture times say nothing of them",
    "TWIN-023": "the base's ({base}, top {base_top_rpm:.0f} rpm) rewound for a {top_speed_rpm:.0f} rpm top on "
    "{pole_pairs} pole pairs: ke x {ke_factor:.3g}, J and friction x {j_factor:.3g}, fan load x {fan_factor:.3g}, "
    "L x {l_factor:.3g} (per unit of its top speed, supply and current the base motor: its duty, current and "
    "dynamics at its top are the twin's at its own); R, supply as the base: capture times say nothing of them",
    "TWIN-024": "measured but NOT in this plant: {effect} (no calibration table holds it; `{option}` adds it, and "
    "`hil twin check` names it as a difference the twin lacks)",
    "TWIN-025": "measured but NOT in this plant: {effect} beyond {held_part} (no calibration table holds it; "
    "`{option}` adds it, and `hil twin check` names it as a difference the twin lacks)",
    "TWIN-026": "the acceptance suite runs at the paper pump's speeds as fractions of this motor's top, "
    "{top_speed_rpm:.0f} rpm ({top_hz_e:.0f} Hz electrical), each window holding as many electrical periods; there "
    "the {delay_us:.0f} us delay is {delay_sectors:.2f} of a sector",
    "TWIN-027": "the top speed is {top_ratio:.1f} times the capture's: the suite judges the twin where the capture "
    "never ran it",
    "TWIN-028": "the delay is beyond half a sector at the top speed (the physical limit): the suite cannot judge "
    "this twin there; state a lower --top-speed-rpm (docs/twin.md)",
    "TWIN-029": "{what}: {value:.4g} clipped to the effect library's bound [{low:g}, {high:g}]",
    # the twin's TOML: its comment lines
    "TWIN-030": "Plant twin of the Hall capture {source}, written by `hil twin from-capture`.",
    "TWIN-031": "Base (what the capture cannot tell): {base}.",
    "TWIN-032": "MEASURED from the capture:",
    "TWIN-033": "ASSUMED (from the base; a capture of Hall times alone cannot tell them):",
    "TWIN-034": "MEASURED BUT LEFT OUT (no calibration table holds them; the option adds them):",
    "TWIN-035": "{effect} ({option}): {params!r}",
    "TWIN-036": "{effect} ({option}), the plant holds {held_part}: {params!r}",
    "TWIN-037": "NOTES:",
    "TWIN-038": "assumed: from the base",
    "TWIN-039": "measured",
    # why a capture's sensor-pole pattern is not kept (CaptureAnalysis.extra)
    "TWIN-040": "no pole count: no mechanical turn to fold the residuals over",
    "TWIN-041": "p-value {p_value:.2g}: not beyond the noise",
    "TWIN-042": "the faster half shows {slope:.2f} times the slower half's pattern: it changes with speed (the rotor's "
    "motion, not the sensors)",
}

#: code -> the names of the numbers its wording uses
NUMBERS_OF: dict[str, frozenset[str]] = {
    code: frozenset(name for _, name, _, _ in string.Formatter().parse(template) if name)
    for code, template in WORDING.items()
}


@dataclass(frozen=True)
class Reason:
    """A code of ``WORDING`` and the numbers its wording needs (exactly those)."""

    code: str
    numbers: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.code not in WORDING:
            raise KeyError(f"reason code {self.code!r} is not in bldc.reasons.WORDING")
        if set(self.numbers) != NUMBERS_OF[self.code]:
            raise ValueError(f"reason {self.code}: numbers {sorted(self.numbers)}, its wording needs "
                             f"{sorted(NUMBERS_OF[self.code])}")

    @classmethod
    def from_json(cls, saved: str) -> "Reason":
        """A reason as a saved file holds it (its sentence): free text, worded as it was."""
        return cls(FREE_TEXT, {"text": saved})


class _Renderer(string.Formatter):
    def format_field(self, value: Any, format_spec: str) -> str:
        if isinstance(value, Reason):
            return words(value)
        if isinstance(value, dict):
            return ", ".join(f"{k} {self.format_field(v, format_spec)}" for k, v in value.items())
        if isinstance(value, (list, tuple)):
            return ", ".join(self.format_field(v, format_spec) for v in value)
        return format(value, format_spec)


_RENDERER = _Renderer()


def words(reason: Reason) -> str:
    """The sentence of ``reason``: its code's wording with its numbers."""
    return _RENDERER.vformat(WORDING[reason.code], (), reason.numbers)
