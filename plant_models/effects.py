"""The effect library: every deviation the plant can show, one typed, bounded object each.

Each effect is a frozen dataclass whose fields carry units in their names and physical bounds
(:func:`bldc.params.bounded`). Defaults are neutral: an effect built with its defaults
changes nothing. Each effect is declared once, here, with everything the rest of the house asks
of it: how it writes itself into the compiled plant (:meth:`Effect.contribute`), its draw for
hypothesis (:meth:`Effect.strategy`), its fingerprint and knob text for the gap diagnosis
(:attr:`Effect.fingerprint`, :attr:`Effect.knob_record`, :attr:`Effect.knob_shows`,
:attr:`Effect.pair_knobs`), its linear edge-angle signature if the diagnosis fits it
(:meth:`Effect.edge_signature`), and its random draw and parameter vector for the diagnosis's
validation (:meth:`Effect.unit_draw`, :attr:`Effect.validation`, :meth:`Effect.fit_error`).
Registered in :data:`EFFECTS`, an effect is simulated, listed, diagnosed and validated.

Sign convention (paper Section 2): a positive angular deviation means the captured edge trails
the ideal one in forward rotation. Installation and pole offsets are spatial displacements, so
in reverse rotation they lead; hysteresis, conditioning delay and armature reaction always lag.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from bldc.contract import MAX_CONDITIONING_DELAY_S
from bldc.params import ConfigError, bounded, from_mapping, strategy_for, validate

from .compiled import CompiledPlant
from .sensor import ARMATURE_SHIFT_LIMIT_DEG_E


@dataclass(frozen=True)
class EdgeSignature:
    """How the gap diagnosis (``hil.gap``) fits an effect's mean edge-angle signature: a linear block
    over the residual cells.

    ``columns`` maps the cells' features to an (n_cells, k) design block in deg_e per unit
    coefficient. The features (``hil.gap.diagnose.build_cells``) are arrays with one value per
    cell: ``sensor`` (0-2), ``rising`` (1/0), ``pole`` (0 .. 2p-1), ``direction`` (+1/-1), ``w_e``
    (deg_e/s), ``current`` (A, mean |i|), ``load``, ``segment``; and the int ``pole_pairs``.
    ``params`` maps the k fitted coefficients to the effect's parameters (its own units and sign),
    ``physical`` (coefficients, standard errors) says whether a fit is inside the effect's bounds,
    ``param_stderr`` gives the parameters' standard errors where they are not linear in the
    coefficients (None: ``params(stderr)``)."""

    columns: Callable[[Mapping[str, Any]], np.ndarray]
    params: Callable[[np.ndarray], dict]
    physical: Callable[[np.ndarray, np.ndarray], bool]
    param_stderr: Callable[[np.ndarray, np.ndarray], dict] | None = None
    #: invisible in relative errors (a recording referenced to the turn, no encoder): a common
    #: shift or a lag equal on every edge
    needs_encoder: bool = False


@dataclass(frozen=True)
class OrdinarySignature:
    """How the gap diagnosis of an ordinary run (``hil.gap.ordinary``: capture times alone, no
    encoder) fits an effect: the column set of the calibration's joint fit it switches on
    (a flag of ``hil.calibration.ordinary.Effects``), and how its fitted coefficients are reported."""

    #: the ``Effects`` flag: "install", "switching", "delay", "ripple", or "pole_pairs" (a candidate
    #: only when the pole count is stated or found)
    columns: str
    coefficients: str  #: the fit's coefficient names start with this (``scalar``: are this)
    key: str  #: the name its parameters are reported under
    meaning: str  #: what the parameters describe (the JSON rows' ``meaning``)
    scalar: bool = False  #: one coefficient, reported as a number
    #: the ordinary run's own experiment against another candidate (by name; the pair in this
    #: order), where capture times alone make it a speed sweep
    knobs: Mapping[str, str] = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class SampleSignature:
    """How the gap diagnosis fits an effect with no edge-angle signature to a sampled signal's
    residual (``hil.gap.samples``): a block of columns, linear given a shape parameter (a grid
    is profiled), and the floor of practical relevance it is judged against.

    ``columns(rows, shape, motor)`` gives per-row columns (n_rows, k) per unit coefficient from the
    residual's rows; the engine averages them into the residual's cells. In the ``voltage``
    domain a column is a line-to-line voltage (V), from the rows ``i`` (line current), ``e`` (line
    back-EMF), ``i0x``, ``i1x``, ``i0y``, ``i1y`` (the phase currents of the pair at an interval's
    two ends) and ``h`` (its length, s); in the ``speed`` domain it is a torque (N m), from
    ``theta_m`` (mechanical angle, rad) and ``t`` (s), which the engine turns into the speed it
    takes away exactly as the residual was made. ``motor`` is the nominal motor (resistance_ohm,
    inductance_h, ke_v_s_per_rad, pole_pairs, ...). ``params(coef, shape, motor)`` maps the
    coefficients to the effect's parameters, ``physical(coef, stderr, motor)`` says whether a fit
    is inside the effect's bounds, ``grid(motor, limits)`` the shape parameters to profile
    (``limits``: what the domain resolves, ``max_periods_per_rev``)."""

    domain: str  #: "voltage" or "speed"
    columns: Callable[[Mapping[str, np.ndarray], Any, Any], np.ndarray]
    params: Callable[[np.ndarray, Any, Any], dict]
    physical: Callable[[np.ndarray, np.ndarray, Any], bool]
    #: practical relevance (``hil.gap.relevance``): the budget the effect disturbs (a key of
    #: ``BUDGETS``), what it disturbs in words, and how much (params, motor, operating envelope)
    budget: str
    disturbs: str
    disturbance: Callable[[Mapping[str, Any], Any, Any], float]
    grid: Callable[[Any, Mapping[str, float]], tuple] = lambda motor, limits: (None,)
    n_coef: int = 1  #: fitted coefficients (0: the column enters with coefficient 1, only its shape is fitted)
    refine: bool = False  #: the shape parameter refined by a bounded search around the best grid point
    constants: tuple[str, ...] = ()  #: parameters stated, not fitted (no standard error)


def bounds_of(cls: type, field_name: str) -> tuple[float | None, float | None]:
    """(low, high) of an effect field, as its ``bounded`` metadata states them."""
    for f in dataclasses.fields(cls):
        if f.name == field_name:
            return f.metadata.get("low"), f.metadata.get("high")
    raise KeyError(f"{cls.__name__} has no field {field_name!r}")


def magnitude_within(cls: type, field_name: str) -> Callable[[np.ndarray, np.ndarray], bool]:
    """Fitted coefficients plausible when each |value| is at most the field's high bound plus three
    standard errors (a field bounded symmetrically about 0)."""
    high = bounds_of(cls, field_name)[1]
    return lambda c, se: bool(np.all(np.abs(c) <= high + 3 * se))


def not_below(cls: type, field_name: str) -> Callable[[np.ndarray, np.ndarray], bool]:
    """Fitted coefficients plausible when none is below the field's low bound by three standard errors."""
    low = bounds_of(cls, field_name)[0]
    return lambda c, se: bool(np.all(c >= low - 3 * se))


#: validation scaling laws (``hil.gap.validate``): how a unit draw becomes an effect at a given
#: signal-to-noise ratio
VALIDATION_LAWS = (
    "edge",      #: every magnitude of the unit draw alike, to the RMS of its edge-angle signature
    "tick",      #: a capture timer's tick from its quantisation noise (the signature is a variance too)
    "jitter",    #: an extra edge jitter component (a variance effect)
    "sampled",   #: ``magnitude_field`` alone, linear, to the RMS of its sampled-signal signature
    "knee",      #: ``magnitude_field`` is a knee the signature falls with: secant steps in log-log
)


@dataclass(frozen=True)
class Effect:
    name: ClassVar[str] = ""
    #: where the effect acts: "sensor" (edge angle), "timing" (edge time), "electrical", "mechanical"
    layer: ClassVar[str] = ""
    #: fingerprint for the gap diagnosis (docs/gap.md, Fingerprints)
    fingerprint: ClassVar[Mapping[str, str]] = {}
    #: the two halves of the gap diagnosis's knob sentence (``hil.gap.diagnose.knob``): what to
    #: record to expose the effect, and how it shows there (None: "more operating points", "has its
    #: own fingerprint")
    knob_record: ClassVar[str | None] = None
    knob_shows: ClassVar[str | None] = None
    #: the sentence that separates it from one other effect (by that effect's name), where the two
    #: halves would not say it; a pair's sentence sits on one of its two effects
    pair_knobs: ClassVar[Mapping[str, str]] = {}
    #: how the diagnosis's validation scales a unit draw to a signal-to-noise ratio (one of
    #: VALIDATION_LAWS); None: the validation does not draw it
    validation: ClassVar[str | None] = None
    #: the field the "sampled" and "knee" laws scale
    magnitude_field: ClassVar[str] = ""
    #: the parameters the validation compares, fitted against injected (:meth:`params_vector`)
    vector_fields: ClassVar[tuple[str, ...]] = ()
    #: its part in the diagnosis of an ordinary run (capture times alone); None: not a candidate there
    ordinary: ClassVar[OrdinarySignature | None] = None
    #: why the recorded signals (hil-recording/1) hold no trace of it, where none do
    no_trace: ClassVar[str | None] = None
    #: why capture times cannot tell it: a twin made from a Hall capture (``hil.twin.capture``) takes
    #: it from its base plant as it is, and says so. The electrical and mechanical ones are taken from
    #: the base too (with the motor); the others are measured, or show in what the twin measures
    capture_blind: ClassVar[str | None] = None

    def contribute(self, plant: CompiledPlant) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def check(self, pole_pairs: int, prefix: str) -> None:
        """Checks that need the motor (for example a per-pole length)."""
        validate(self, prefix)

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        """Hypothesis strategy drawing this effect inside its documented bounds."""
        return strategy_for(cls)

    @classmethod
    def edge_signature(cls) -> EdgeSignature | None:
        """Its mean edge-angle signature as the gap diagnosis fits it; None: it leaves none (or is
        diagnosed elsewhere: edge jitter as a variance, the electrical ones from the samples)."""
        return None

    @classmethod
    def sample_signature(cls) -> SampleSignature | None:
        """How the gap diagnosis fits it to a sampled signal (voltage equation, speed); None: it
        leaves no trace there (or a mean edge-angle one)."""
        return None

    @classmethod
    def from_base_in_twin(cls) -> bool:
        """Whether a twin made from a Hall capture takes it from its base plant (see ``capture_blind``)."""
        return cls.capture_blind is not None or cls.layer in ("electrical", "mechanical")

    @classmethod
    def unit_draw(cls, rng: np.random.Generator, pole_pairs: int) -> "Effect":
        """A random direction in the effect's parameter space for the validation, scaled to the
        signal-to-noise ratio by its ``validation`` law."""
        raise NotImplementedError(f"effect {cls.name!r} has no validation draw (validation = {cls.validation!r})")

    @classmethod
    def params_vector(cls, params: Mapping[str, Any]) -> np.ndarray:
        """The compared parameters (``vector_fields``) of ``params`` as one vector."""
        if not cls.vector_fields:
            raise KeyError(f"effect {cls.name!r} declares no vector_fields to compare")
        out: list[float] = []
        for k in cls.vector_fields:
            v = params[k]
            out.extend(v if isinstance(v, (list, tuple)) else [v])
        return np.asarray(out, dtype=float)

    def fit_error(self, params: Mapping[str, Any]) -> float:
        """Relative error of fitted ``params`` against this (injected) effect's."""
        t, f = self.params_vector(dataclasses.asdict(self)), self.params_vector(params)
        return float(np.linalg.norm(f - t) / max(np.linalg.norm(t), 1e-12))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


@dataclass(frozen=True)
class InstallationOffset(Effect):
    """Each Hall sensor sits a little off its nominal 0/120/240 deg electrical position.

    Physics: PCB placement tolerance moves sensor X by ``offset_deg_e[X]`` along the air gap,
    so both its edges occur that much later (forward rotation) at every pole.
    Fingerprint: per-sensor constant, rising and falling alike, independent of speed and load.
    """

    name: ClassVar[str] = "installation_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-sensor constant, both edges alike",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "-",
    }
    knob_record: ClassVar[str] = "a segment in reverse"
    knob_shows: ClassVar[str] = (
        "an installation offset is a fixed place on the stator, so each sensor's error changes sign in the "
        "trailing frame when the rotor turns the other way"
    )
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("offset_deg_e",)
    ordinary: ClassVar[OrdinarySignature] = OrdinarySignature(
        "install", "inst_", "relative_offset_contrasts_deg_e", "per sensor, sum zero"
    )
    offset_deg_e: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-10.0, high=10.0, unit="deg_e", length=3,
        doc="offset of sensors A, B, C; positive = edges trail",
    )

    @classmethod
    def edge_signature(cls):
        return EdgeSignature(
            lambda c: np.column_stack([c["direction"] * (c["sensor"] == x) for x in range(3)]),
            lambda k: {"offset_deg_e": [float(v) for v in k]},
            magnitude_within(cls, "offset_deg_e"),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(tuple(rng.uniform(-1, 1, 3)))

    def contribute(self, plant):
        plant.sensor_offset_deg_e += np.asarray(self.offset_deg_e, dtype=float)


@dataclass(frozen=True)
class PoleOffset(Effect):
    """Magnet pole boundaries off their nominal 180 deg electrical pitch.

    Physics: uneven magnetisation or pole-piece placement shifts the boundary that starts pole j
    (order in which poles pass sensor A from the reference zero; pole 0 = N1) by
    ``offset_deg_e[j]``; every sensor sees the same boundary shifted alike.
    Fingerprint: a pattern repeating every mechanical turn, all sensors alike per pole.
    """

    name: ClassVar[str] = "pole_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-pole pattern repeating every mechanical turn, all sensors alike",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "6p-edge block analysis",
    }
    knob_record: ClassVar[str] = "at least 30 mechanical turns per operating point"
    knob_shows: ClassVar[str] = "a pole offset is any per-pole pattern repeating every mechanical turn"
    pair_knobs: ClassVar[Mapping[str, str]] = {
        "eccentricity": (
            "Record more mechanical turns per operating point (30 or more): an eccentricity is a first-order "
            "sinusoid over the turn (two parameters), a pole offset any per-pole pattern; only the pattern's "
            "departure from a sinusoid, resolved by more turns, separates them, and while they are equal within "
            "noise the eccentricity is kept for having fewer parameters."
        ),
    }
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("offset_deg_e",)
    ordinary: ClassVar[OrdinarySignature] = OrdinarySignature(
        "pole_pairs", "pole_", "pole_offset_contrasts_deg_e", "per pole boundary, sum zero"
    )
    offset_deg_e: tuple[float, ...] = bounded(
        (0.0, 0.0, 0.0, 0.0), low=-5.0, high=5.0, unit="deg_e",
        doc="shift of the boundary starting each magnet pole; length 2 * pole_pairs",
    )

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        if len(self.offset_deg_e) != 2 * pole_pairs:
            raise ConfigError(
                f"{prefix}offset_deg_e",
                f"expected {2 * pole_pairs} values (one per magnet pole), got {len(self.offset_deg_e)}",
            )

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        one = st.floats(-5.0, 5.0, allow_nan=False)
        return st.builds(cls, offset_deg_e=st.tuples(*([one] * (2 * pole_pairs))))

    @classmethod
    def edge_signature(cls):
        def columns(c):
            return np.column_stack([c["direction"] * (c["pole"] == j) for j in range(2 * c["pole_pairs"])])

        return EdgeSignature(columns, lambda k: {"offset_deg_e": [float(v) for v in k]},
                             magnitude_within(cls, "offset_deg_e"))

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(tuple(rng.uniform(-1, 1, 2 * pole_pairs)))

    def fit_error(self, params):
        # the common part is shared with installation offsets: only the pattern about its mean counts
        t, f = self.params_vector(dataclasses.asdict(self)), self.params_vector(params)
        t, f = t - t.mean(), f - f.mean()
        return float(np.linalg.norm(f - t) / max(np.linalg.norm(t), 1e-12))

    def contribute(self, plant):
        plant.pole_offset_deg_e += np.asarray(self.offset_deg_e, dtype=float)


@dataclass(frozen=True)
class SensorPoleOffset(Effect):
    """Each sensor sees each magnet pole boundary at its own offset (beyond the per-pole table).

    Physics: the pole offsets shift a boundary alike for every sensor; a sensor that switches
    away from the field's zero (B_op != 0) crosses a weaker or stronger pole's boundary at a
    different angle, and sensors at different gaps see the magnetisation's shape differently, so
    the offset of boundary j at sensor X is ``offset_deg_e[X * 2p + j]`` (spatial, as pole
    offsets: it leads in reverse). Real captures show such a pattern, constant in speed, in
    what the per-pole table leaves (docs/twin.md).
    Fingerprint: a pattern of 6p edges repeating every mechanical turn, different per sensor.
    """

    name: ClassVar[str] = "sensor_pole_offset"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "per-sensor, per-pole pattern repeating every mechanical turn",
        "scales_with": "nothing (constant in angle); flips sign with direction",
        "knob": "6p-edge block analysis per sensor",
    }
    offset_deg_e: tuple[float, ...] = bounded(
        (), low=-5.0, high=5.0, unit="deg_e",
        doc="shift of boundary j at sensor X, index X * 2p + j (sensors A, B, C); length 6 * pole_pairs",
    )

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        if self.offset_deg_e and len(self.offset_deg_e) != 6 * pole_pairs:
            raise ConfigError(
                f"{prefix}offset_deg_e",
                f"expected {6 * pole_pairs} values (3 sensors x {2 * pole_pairs} poles), got {len(self.offset_deg_e)}",
            )

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        one = st.floats(-5.0, 5.0, allow_nan=False)
        return st.builds(cls, offset_deg_e=st.tuples(*([one] * (6 * pole_pairs))))

    def contribute(self, plant):
        if self.offset_deg_e:
            table = np.asarray(self.offset_deg_e, dtype=float).reshape(3, 2 * plant.pole_pairs)
            plant.switch_offset_deg_e = plant.switch_offset_deg_e + table[:, :, None]


@dataclass(frozen=True)
class ConditioningCircuit:
    """The paper's Hall conditioning circuit (Fig. 3a), open-drain sensor.

    Topology: pull-up R2 from Vcc to the sensor output node; the sensor pulls that node to
    ground through its output impedance R1; limiter R3 from that node to the MCU node, which
    carries filter capacitor C1 and R4 (divider and MCU input) to ground. Exact Thevenin
    equivalents give the time constants; with R4 >> R2 they reduce to the paper's
    tau_rise = R2*C1 and tau_fall = (R1+R3)*C1. The MCU captures when the capacitor voltage
    crosses ``v_ih`` (rising) or ``v_il`` (falling). The capacitor settles between edges at any
    speed the pump reaches (tau << an edge interval), so the delays are constant in time.
    """

    r1_ohm: float = bounded(50.0, low=0.0, high=1e4, unit="ohm", doc="sensor output impedance")
    r2_ohm: float = bounded(4.7e3, low=0.0, high=1e6, unit="ohm", low_open=True, doc="pull-up")
    r3_ohm: float = bounded(1e3, low=0.0, high=1e6, unit="ohm", doc="limiter")
    r4_ohm: float = bounded(47e3, low=0.0, high=1e7, unit="ohm", low_open=True, doc="divider / MCU input")
    c1_f: float = bounded(1e-9, low=0.0, high=1e-6, unit="F", doc="filter capacitor")
    vcc_v: float = bounded(5.0, low=0.0, high=30.0, unit="V", low_open=True, doc="pull-up supply")
    v_ih_v: float = bounded(3.25, low=0.0, high=30.0, unit="V", doc="MCU rising threshold (0.65 VDD)")
    v_il_v: float = bounded(1.75, low=0.0, high=30.0, unit="V", doc="MCU falling threshold (0.35 VDD)")

    def levels(self) -> tuple[float, float, float, float]:
        """(v_high, tau_rise_s, v_low, tau_fall_s) of the capacitor node."""
        par = lambda a, b: a * b / (a + b)  # noqa: E731
        v_high = self.vcc_v * self.r4_ohm / (self.r2_ohm + self.r3_ohm + self.r4_ohm)
        tau_rise = par(self.r2_ohm + self.r3_ohm, self.r4_ohm) * self.c1_f
        v_node = self.vcc_v * self.r1_ohm / (self.r1_ohm + self.r2_ohm)
        r_node = par(self.r1_ohm, self.r2_ohm) if self.r1_ohm > 0 else 0.0
        v_low = v_node * self.r4_ohm / (r_node + self.r3_ohm + self.r4_ohm)
        tau_fall = par(r_node + self.r3_ohm, self.r4_ohm) * self.c1_f
        return v_high, tau_rise, v_low, tau_fall

    def delays_s(self) -> tuple[float, float]:
        """(rise, fall) delay from the raw sensor edge to the MCU threshold crossing."""
        v_high, tau_rise, v_low, tau_fall = self.levels()
        if not (v_low < self.v_il_v < self.v_ih_v < v_high):
            raise ConfigError(
                "conditioning_delay.v_ih_v",
                f"thresholds must satisfy v_low ({v_low:.3g} V) < v_il < v_ih < v_high ({v_high:.3g} V)",
            )
        rise = tau_rise * math.log((v_high - v_low) / (v_high - self.v_ih_v))
        fall = tau_fall * math.log((v_high - v_low) / (self.v_il_v - v_low))
        return rise, fall


#: the ranges a search draws conditioning delays from (s): "library", the stated range of the
#: acceptance search (REQ-ROB-001: the paper's circuit class, 1 nF into a few kOhm, up to 50 us);
#: "real-wiring", open-collector Hall outputs with pull-up, filter and cable as real motors show
#: them (134 and 276 us rise minus fall on the shipped captures): up to 300 us
DRAW_DELAY_S = {"library": 50e-6, "real-wiring": 300e-6}


@dataclass(frozen=True)
class ConditioningDelay(Effect):
    """Delay of the Hall conditioning circuit (paper Section 2.5), rising and falling apart.

    Physics: the RC filter charges through the pull-up (slow) and discharges through the sensor
    (fast), so captured rising edges lag more than falling ones; the delay is constant in
    time, hence the angle error grows linearly with speed. Build it from component values with
    :meth:`from_circuit`, or give the two delays directly.
    Fingerprint: lag, rising != falling (electrical order 3), growing with speed.
    """

    name: ClassVar[str] = "conditioning_delay"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "lag, rising and falling edges differ (order 3)",
        "scales_with": "speed (constant in time)",
        "knob": "speed sweep",
    }
    knob_record: ClassVar[str] = "three or more speeds at one load"
    knob_shows: ClassVar[str] = (
        "a delay constant in time grows in angle with speed, and rising and falling edges differ"
    )
    pair_knobs: ClassVar[Mapping[str, str]] = {
        "armature_reaction": (
            "Record two loads at the same speed (throttle or brake the pump): a conditioning delay follows the "
            "speed and stays, armature reaction follows the phase current and moves; under a pump load alone speed "
            "and current rise together."
        ),
        "timer_quantization": (
            "Record with the capture timer's tick in meta.json (or at a finer timer resolution) and compare rising "
            "with falling edges: the timer makes every edge lead by half a tick alike, a conditioning delay lags "
            "and differs between the edges."
        ),
    }
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("rise_delay_s", "fall_delay_s")
    ordinary: ClassVar[OrdinarySignature] = OrdinarySignature(
        "delay", "delay_diff_s", "rise_minus_fall_delay_s",
        "rising edges' delay minus falling edges' delay, constant in time", scalar=True,
        knobs={
            "hysteresis": "a speed sweep: a delay grows with speed, asymmetric switching points do not",
            "torque_ripple": "a speed sweep at another load: the ripple falls with 1/speed^2",
        },
    )
    rise_delay_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S, unit="s", doc="delay of captured rising edges"
    )
    fall_delay_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S, unit="s", doc="delay of captured falling edges"
    )

    @classmethod
    def strategy(cls, pole_pairs: int = 2, max_delay_s: float | None = None):
        """Both delays drawn from [0, ``max_delay_s``]: by default the stated range of the acceptance
        search (``DRAW_DELAY_S['library']``, a paper-bench-like circuit), or a real-wiring range."""
        from hypothesis import strategies as st

        high = DRAW_DELAY_S["library"] if max_delay_s is None else float(max_delay_s)
        if not 0.0 < high <= MAX_CONDITIONING_DELAY_S:
            raise ConfigError(
                "conditioning_delay.max_delay_s", f"must be in (0, {MAX_CONDITIONING_DELAY_S}] s, got {high!r}"
            )
        one = st.floats(0.0, high, allow_nan=False)
        return st.builds(cls, rise_delay_s=one, fall_delay_s=one)

    @classmethod
    def from_circuit(cls, circuit: ConditioningCircuit) -> "ConditioningDelay":
        validate(circuit, "conditioning_delay.")
        rise, fall = circuit.delays_s()
        return cls(rise_delay_s=rise, fall_delay_s=fall)

    @classmethod
    def edge_signature(cls):
        return EdgeSignature(
            lambda c: np.column_stack([c["w_e"] * c["rising"], c["w_e"] * (1 - c["rising"])]),
            lambda k: {"rise_delay_s": float(k[0]), "fall_delay_s": float(k[1])},
            not_below(cls, "rise_delay_s"),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        rise = rng.uniform(0.3, 1.0)
        return cls(rise * 1e-5, rng.uniform(0.0, 1.0) * rise * 1e-5)

    def contribute(self, plant):
        plant.rise_delay_s += self.rise_delay_s
        plant.fall_delay_s += self.fall_delay_s


@dataclass(frozen=True)
class ArmatureReaction(Effect):
    """Armature field shifts the air-gap field the Hall sensors see (paper Section 2.4).

    Physics: the stator MMF adds to the magnet field and moves its zero crossings by an angle
    that grows with the phase current; linear (``slope_deg_e_per_a``) by default, or a table of
    (mean phase current, offset) points interpolated linearly (clamped at its ends). Either
    saturates at ``ARMATURE_SHIFT_LIMIT_DEG_E`` (30 deg e): the field the sensor sees turns
    towards the armature's, never past it. The current is the mean of |i| over the three phases
    at the edge.
    Fingerprint: lag growing with phase current (load), both edges alike.
    """

    name: ClassVar[str] = "armature_reaction"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "lag, both edges alike",
        "scales_with": "phase current (load)",
        "knob": "load sweep at fixed speed",
    }
    knob_record: ClassVar[str] = "two loads (pump load and throttled or braked) at one speed"
    knob_shows: ClassVar[str] = "armature reaction follows the phase current, not the speed"
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("slope_deg_e_per_a",)
    capture_blind: ClassVar[str] = "needs phase currents and a reference angle"
    slope_deg_e_per_a: float = bounded(0.0, low=-2.0, high=2.0, unit="deg_e/A", doc="edge lag per ampere")
    table_current_a: tuple[float, ...] = bounded((), low=0.0, high=1e3, unit="A", doc="table currents")
    table_offset_deg_e: tuple[float, ...] = bounded(
        (), low=-ARMATURE_SHIFT_LIMIT_DEG_E, high=ARMATURE_SHIFT_LIMIT_DEG_E, unit="deg_e", doc="table offsets"
    )

    def check(self, pole_pairs, prefix):
        super().check(pole_pairs, prefix)
        n = len(self.table_current_a)
        if n != len(self.table_offset_deg_e):
            raise ConfigError(f"{prefix}table_offset_deg_e", f"expected {n} values to match table_current_a")
        if n == 1 or (n and np.any(np.diff(self.table_current_a) <= 0)):
            raise ConfigError(f"{prefix}table_current_a", "needs >= 2 strictly increasing currents")
        if n and self.slope_deg_e_per_a != 0.0:
            raise ConfigError(f"{prefix}slope_deg_e_per_a", "give either a slope or a table, not both")

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        return st.builds(cls, slope_deg_e_per_a=st.floats(-2.0, 2.0, allow_nan=False))

    def offset_deg_e(self, current_a: np.ndarray) -> np.ndarray:
        if self.table_current_a:
            return np.interp(current_a, self.table_current_a, self.table_offset_deg_e)
        shift = self.slope_deg_e_per_a * np.asarray(current_a, dtype=float)
        return np.clip(shift, -ARMATURE_SHIFT_LIMIT_DEG_E, ARMATURE_SHIFT_LIMIT_DEG_E)  # as the plant's sensors

    @classmethod
    def edge_signature(cls):
        return EdgeSignature(
            lambda c: c["current"][:, None],
            lambda k: {"slope_deg_e_per_a": float(k[0])},
            magnitude_within(cls, "slope_deg_e_per_a"),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(float(rng.choice([-1, 1]) * rng.uniform(0.5, 1.0)))

    def contribute(self, plant):
        if self.table_current_a:
            plant.armature_table_current_a = np.asarray(self.table_current_a, dtype=float)
            plant.armature_table_offset_deg_e = np.asarray(self.table_offset_deg_e, dtype=float)
        else:
            plant.armature_slope_deg_e_per_a += self.slope_deg_e_per_a


@dataclass(frozen=True)
class Hysteresis(Effect):
    """Magnetic hysteresis of the Hall switch (operate vs release point).

    Physics: the sensor switches only after the field has passed zero by B_op, i.e. a constant
    angle after the ideal crossing, in whichever direction the rotor turns.
    Fingerprint: common lag, rising and falling alike, constant in angle; in the forward-angle
    frame it flips sign with direction (installation offsets do not).
    """

    name: ClassVar[str] = "hysteresis"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "common lag, rise and fall alike, in either direction of rotation",
        "scales_with": "nothing (constant in angle)",
        "knob": "a segment in reverse (hysteresis lags both ways; an installation offset flips)",
    }
    knob_record: ClassVar[str] = "a segment in reverse"
    knob_shows: ClassVar[str] = (
        "hysteresis lags the switching in either direction of rotation, alike for every sensor"
    )
    pair_knobs: ClassVar[Mapping[str, str]] = {
        "installation_offset": (
            "Record a segment in reverse: hysteresis lags in either direction of rotation, while an installation "
            "offset is a fixed place on the stator and changes sign in the trailing frame when the rotor reverses."
        ),
    }
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("lag_deg_e",)
    #: capture times alone cannot see a lag common to every edge: what an ordinary run fits under this
    #: name is each sensor's rise minus fall, constant in angle (its asymmetric switching points)
    ordinary: ClassVar[OrdinarySignature] = OrdinarySignature(
        "switching", "switch_", "rise_minus_fall_deg_e", "per sensor and direction, rise minus fall, constant in angle",
        knobs={"torque_ripple": "a speed sweep: the ripple falls with 1/speed^2, switching points stay"},
    )
    capture_blind: ClassVar[str] = "a lag common to every edge is invisible without an encoder"
    lag_deg_e: float = bounded(0.0, low=0.0, high=5.0, unit="deg_e", doc="switching lag after the field zero")

    @classmethod
    def edge_signature(cls):
        return EdgeSignature(
            lambda c: np.ones((c["sensor"].size, 1)),
            lambda k: {"lag_deg_e": float(k[0])},
            not_below(cls, "lag_deg_e"),
            needs_encoder=True,
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(1.0)

    def contribute(self, plant):
        plant.hysteresis_deg_e += self.lag_deg_e


@dataclass(frozen=True)
class SwitchingAsymmetry(Effect):
    """Rising and falling edges of a sensor apart by a constant angle (its switching points).

    Physics: a Hall switch turns on at its operate point B_op on a rising field and off at its
    release point B_rp on a falling one; when |B_op| != |B_rp| (or the open-collector output's
    threshold is off centre) the rising edge trails the field's zero crossing by a different
    angle than the falling edge, in either direction of rotation. ``rise_minus_fall_deg_e[X]``:
    sensor X's rising edges trail by half of it, its falling edges lead by half (the common part
    is hysteresis). Spatially this is an N/S-alternating shift of the boundaries the sensor sees.
    Fingerprint: rise minus fall constant in angle (a delay grows with speed), any direction.
    """

    name: ClassVar[str] = "switching_asymmetry"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "rising and falling edges of a sensor apart by a constant angle",
        "scales_with": "nothing (constant in angle); the same in either direction",
        "knob": "speed sweep (tells it from a conditioning delay)",
    }
    rise_minus_fall_deg_e: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-10.0, high=10.0, unit="deg_e", length=3,
        doc="rising minus falling edge lag of sensors A, B, C",
    )

    def contribute(self, plant):
        # boundary k of pole k: rising edges at even k forward, at odd k in reverse; a spatial
        # +a/2 on even boundaries and -a/2 on odd ones makes rising trail and falling lead both ways
        half = 0.5 * np.asarray(self.rise_minus_fall_deg_e, dtype=float)
        parity = np.where(np.arange(2 * plant.pole_pairs) % 2 == 0, 1.0, -1.0)
        plant.switch_offset_deg_e = plant.switch_offset_deg_e + half[:, None, None] * parity[None, :, None]


@dataclass(frozen=True)
class EdgeJitter(Effect):
    """Random edge-time disturbance (paper's type III interference).

    Physics: noise on the Hall signal near the MCU threshold (time domain) or magnetic noise
    and vibration (angle domain). White when ``correlation`` is 0; otherwise AR(1) over
    successive captured edges with that lag-1 coefficient, stationary RMS as given.
    Fingerprint: white (or AR(1)) scatter, zero mean; in angle or in time.
    """

    name: ClassVar[str] = "edge_jitter"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "zero-mean scatter, white or coloured",
        "scales_with": "nothing in angle (angle jitter) or speed (time jitter)",
        "knob": "-",
    }
    knob_record: ClassVar[str] = "a run at a second speed"
    knob_shows: ClassVar[str] = "jitter in time grows in angle with speed while jitter in angle does not"
    validation: ClassVar[str] = "jitter"
    vector_fields: ClassVar[tuple[str, ...]] = ("time_rms_s",)
    #: three RMS inside the half sector that bounds a conditioning delay (MAX_CONDITIONING_DELAY_S: the
    #: slowest-commutating motor, a many-pole hub motor at its top speed, whose slow field ramps
    #: through the threshold make the largest time jitter)
    time_rms_s: float = bounded(
        0.0, low=0.0, high=MAX_CONDITIONING_DELAY_S / 3.0, unit="s", doc="RMS of the time-domain jitter"
    )
    #: up to 10 deg e: three RMS stay inside half a sector (30 deg e), beyond which edges would
    #: reorder; a many-pole hub motor's rotor vibration reaches several deg e (0.5 deg mechanical
    #: at 15 pole pairs is 7.5 deg e)
    angle_rms_deg_e: float = bounded(0.0, low=0.0, high=10.0, unit="deg_e", doc="RMS of the angle-domain jitter")
    correlation: float = bounded(0.0, low=0.0, high=0.95, unit="1", doc="AR(1) coefficient across edges")

    def contribute(self, plant):
        plant.jitter_time_rms_s = math.hypot(plant.jitter_time_rms_s, self.time_rms_s)
        plant.jitter_angle_rms_deg_e = math.hypot(plant.jitter_angle_rms_deg_e, self.angle_rms_deg_e)
        plant.jitter_correlation = self.correlation


@dataclass(frozen=True)
class TimerQuantization(Effect):
    """The capture timer latches a free-running counter: t_captured = floor(t / tick) * tick.

    Fingerprint: white, uniform on [-tick, 0] (mean -tick/2); sector times show lag-1
    autocorrelation of -0.5.
    """

    name: ClassVar[str] = "timer_quantization"
    layer: ClassVar[str] = "timing"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "white, uniform over one tick",
        "scales_with": "constant in time",
        "knob": "lag-1 autocorrelation -0.5 of sector times",
    }
    knob_record: ClassVar[str] = (
        "the capture timer's tick in meta.json, or a run at a finer timer resolution"
    )
    knob_shows: ClassVar[str] = "a capture timer makes every edge lead by half a tick, rising and falling alike"
    validation: ClassVar[str] = "tick"
    vector_fields: ClassVar[tuple[str, ...]] = ("tick_s",)
    #: up to 100 us: an MCU capture timer ticks in ns, a logic analyser samples at 10 kHz or faster
    #: (the shipped real captures: 30 kHz, 33.3 us)
    tick_s: float = bounded(0.0, low=0.0, high=1e-4, unit="s", doc="capture timer resolution (0 = none)")

    @classmethod
    def edge_signature(cls):
        return EdgeSignature(
            lambda c: (-0.5 * c["w_e"])[:, None],  # the timer floors: mean lag -tick/2 in time
            lambda k: {"tick_s": float(k[0])},
            not_below(cls, "tick_s"),
            needs_encoder=True,
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(1e-6)

    def contribute(self, plant):
        plant.timer_tick_s = max(plant.timer_tick_s, self.tick_s)


@dataclass(frozen=True)
class Eccentricity(Effect):
    """Dynamic rotor eccentricity: the air gap at each boundary varies once per mechanical turn.

    Physics: a rotor-fixed eccentricity tilts the field at every pole boundary by an amount
    that depends on where the boundary sits on the rotor, so boundary k is shifted by
    ``amplitude_deg_e * sin(2 pi k / (2p) + phase_rad)``, alike for all sensors.
    Fingerprint: first mechanical order across the poles (a two-parameter special case of
    the pole-offset pattern).
    """

    name: ClassVar[str] = "eccentricity"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "sinusoid of first mechanical order across poles, all sensors alike",
        "scales_with": "nothing (constant in angle)",
        "knob": "6p-edge block analysis (order 1 of the mechanical turn)",
    }
    knob_record: ClassVar[str] = "at least 30 mechanical turns per operating point"
    knob_shows: ClassVar[str] = (
        "an eccentricity is a first-order sinusoid over the mechanical turn, whose two parameters the per-pole "
        "pattern must match"
    )
    validation: ClassVar[str] = "edge"
    vector_fields: ClassVar[tuple[str, ...]] = ("amplitude_deg_e",)
    amplitude_deg_e: float = bounded(0.0, low=0.0, high=3.0, unit="deg_e", doc="peak boundary shift")
    phase_rad: float = bounded(0.0, low=0.0, high=2 * math.pi, unit="rad", doc="phase of the gap minimum")

    @classmethod
    def edge_signature(cls):
        high = bounds_of(cls, "amplitude_deg_e")[1]

        def columns(c):
            ang = 2 * np.pi * c["pole"] / (2 * c["pole_pairs"])
            return np.column_stack([c["direction"] * np.sin(ang), c["direction"] * np.cos(ang)])

        def param_stderr(k, se):
            """First-order propagation of the sine and cosine coefficients' errors to amplitude and phase."""
            amp = max(float(np.hypot(*k)), 1e-300)
            return {
                "amplitude_deg_e": float(np.hypot(k[0] * se[0], k[1] * se[1]) / amp),
                "phase_rad": float(np.hypot(k[1] * se[0], k[0] * se[1]) / amp**2),
            }

        return EdgeSignature(
            columns,
            lambda k: {
                "amplitude_deg_e": float(np.hypot(*k)),
                "phase_rad": float(np.mod(np.arctan2(k[1], k[0]), 2 * np.pi)),
            },
            lambda c, se: bool(np.hypot(*c) <= high + 3 * np.hypot(*se)),
            param_stderr,
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(1.0, float(rng.uniform(0, 2 * math.pi)))

    def contribute(self, plant):
        k = np.arange(2 * plant.pole_pairs)
        pole_angle_rad = 2 * np.pi * k / (2 * plant.pole_pairs)
        plant.pole_offset_deg_e += self.amplitude_deg_e * np.sin(pole_angle_rad + self.phase_rad)


@dataclass(frozen=True)
class CoggingTorque(Effect):
    """Reluctance torque between magnets and stator teeth.

    T_cog = amplitude_n_m * sin(periods_per_rev * theta_m + phase_rad); 12 periods for a
    6-slot, 4-pole motor (lcm of slots and poles).
    Fingerprint: no edge signature (aliases to order 0 in sector times); speed and current
    ripple, largest at low speed.
    """

    name: ClassVar[str] = "cogging_torque"
    layer: ClassVar[str] = "mechanical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current ripple at periods_per_rev; none in edge angles",
        "scales_with": "largest at low speed",
        "knob": "low-speed run",
    }
    knob_record: ClassVar[str] = "the lowest speed the pump holds, with the reference encoder"
    knob_shows: ClassVar[str] = (
        "cogging's speed ripple grows as the speed falls and sits at a fixed number of periods per turn"
    )
    validation: ClassVar[str] = "sampled"
    magnitude_field: ClassVar[str] = "amplitude_n_m"
    amplitude_n_m: float = bounded(0.0, low=0.0, high=0.1, unit="N m", doc="peak cogging torque")
    periods_per_rev: int = bounded(12, low=1, high=96, unit="1/rev", integer=True, doc="cogging periods per turn")
    phase_rad: float = bounded(0.0, low=0.0, high=2 * math.pi, unit="rad", doc="phase")

    @staticmethod
    def possible_orders(pole_pairs: int, max_order: int) -> tuple[int, ...]:
        """Cogging periods per turn a three-phase motor with ``2 p`` poles can have.

        The cogging fundamental is lcm(slots, poles) per turn; magnet and slot imperfections add
        harmonics at multiples of the pole count and of the slot count, and a three-phase stator's
        slot count is a multiple of 3. Other orders (for example p, the electrical frequency) are
        ripple of another cause: an offset of a current sensor makes a torque error at exactly the
        electrical frequency in the speed residual."""
        return tuple(n for n in range(1, max_order + 1) if n % (2 * pole_pairs) == 0 or n % 3 == 0)

    @classmethod
    def sample_signature(cls):
        high = bounds_of(cls, "amplitude_n_m")[1]

        def columns(rows, order, motor):
            th = rows["theta_m"]  # A sin(n theta + phi) = a sin(n theta) + b cos(n theta)
            return np.column_stack([np.sin(order * th), np.cos(order * th)])

        return SampleSignature(
            "speed",
            columns,
            lambda c, n, m: {
                "amplitude_n_m": float(np.hypot(*c)),
                "periods_per_rev": int(n),
                "phase_rad": float(np.mod(np.arctan2(c[1], c[0]), 2 * np.pi)),
            },
            lambda c, se, m: bool(np.hypot(*c) <= high + 3 * np.hypot(*se)),
            budget="torque",
            disturbs="peak cogging torque",
            disturbance=lambda params, motor, env: float(params["amplitude_n_m"]),
            grid=lambda motor, limits: cls.possible_orders(motor.pole_pairs, int(limits["max_periods_per_rev"])),
            n_coef=2,
            constants=("phase_rad",),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(0.01, int(rng.choice([6, 8, 12, 18, 24])), float(rng.uniform(0, 2 * math.pi)))

    @classmethod
    def params_vector(cls, params):
        a, ph = params["amplitude_n_m"], params["phase_rad"]  # amplitude and phase as one phasor
        return np.array([a * math.cos(ph), a * math.sin(ph)])

    def fit_error(self, params):
        if params["periods_per_rev"] != self.periods_per_rev:
            return float("inf")  # the wrong order: no magnitude is right
        return super().fit_error(params)

    def contribute(self, plant):
        plant.cogging_amplitude_n_m = self.amplitude_n_m
        plant.cogging_periods_per_rev = int(self.periods_per_rev)
        plant.cogging_phase_rad = self.phase_rad


@dataclass(frozen=True)
class WindingTemperature(Effect):
    """Copper heats up: R = R_nominal * (1 + alpha_cu * temperature_rise_k), alpha_cu = 0.00393/K.

    Fingerprint: no edge signature; more current and less speed for the same duty, growing
    with run time (heat soak).
    """

    name: ClassVar[str] = "winding_temperature"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current versus duty; none in edge angles",
        "scales_with": "run time (heat soak)",
        "knob": "heat soak",
    }
    knob_record: ClassVar[str] = "two loads at one speed"
    knob_shows: ClassVar[str] = "a resistance change shows in proportion to the current"
    pair_knobs: ClassVar[Mapping[str, str]] = {
        "magnet_temperature": (
            "Record two loads at one speed: a resistance change (winding temperature) follows the current, a "
            "back-EMF change (magnet temperature) follows the speed; under a pump load alone current and speed "
            "move together."
        ),
    }
    validation: ClassVar[str] = "sampled"
    magnitude_field: ClassVar[str] = "temperature_rise_k"
    vector_fields: ClassVar[tuple[str, ...]] = ("temperature_rise_k",)
    temperature_rise_k: float = bounded(0.0, low=-40.0, high=150.0, unit="K", doc="above the reference temperature")
    alpha_per_k: float = bounded(0.00393, low=0.0, high=0.01, unit="1/K", doc="resistance temperature coefficient")

    @classmethod
    def sample_signature(cls):
        alpha = cls().alpha_per_k  # the library's copper coefficient: the fit gives dR, the rise follows
        low, high = bounds_of(cls, "temperature_rise_k")

        def physical(c, se, m):
            k = m.resistance_ohm * alpha
            return bool(low - 3 * se[0] / k <= c[0] / k <= high + 3 * se[0] / k)

        def disturbance(params, motor, env):
            # at a fixed duty, u = 2 R I + 2 k_e w: a resistance change dR moves the speed by dR I / k_e
            return float(np.max(np.abs(params["resistance_delta_ohm"]) * env.current_a
                                / (motor.ke_v_s_per_rad * np.maximum(env.speed_rad_s, 1e-9))))

        return SampleSignature(
            "voltage",
            lambda rows, _, m: rows["i"][:, None],  # dR times the line current
            lambda c, _, m: {
                "temperature_rise_k": float(c[0] / (m.resistance_ohm * alpha)),
                "alpha_per_k": alpha,
                "resistance_delta_ohm": float(c[0]),
            },
            physical,
            budget="speed",
            disturbs="relative speed change at a fixed duty (most sensitive operating point)",
            disturbance=disturbance,
            constants=("alpha_per_k",),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(10.0)  # a heat soak: the -40 K bound would cap a cold draw near SNR 1

    def contribute(self, plant):
        plant.phase_resistance_ohm *= 1.0 + self.alpha_per_k * self.temperature_rise_k


@dataclass(frozen=True)
class MagnetTemperature(Effect):
    """Magnets weaken when hot: k_e = k_e_nominal * (1 + alpha_br * temperature_rise_k).

    alpha_br = -0.0012/K for NdFeB. Fingerprint: no edge signature; higher speed per duty and
    more current per torque.
    """

    name: ClassVar[str] = "magnet_temperature"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed and current versus duty; none in edge angles",
        "scales_with": "run time (heat soak)",
        "knob": "heat soak",
    }
    knob_record: ClassVar[str] = "two speeds at one load"
    knob_shows: ClassVar[str] = "a back-EMF change shows in proportion to the speed"
    validation: ClassVar[str] = "sampled"
    magnitude_field: ClassVar[str] = "temperature_rise_k"
    vector_fields: ClassVar[tuple[str, ...]] = ("temperature_rise_k",)
    temperature_rise_k: float = bounded(0.0, low=-40.0, high=150.0, unit="K", doc="above the reference temperature")
    alpha_br_per_k: float = bounded(-0.0012, low=-0.005, high=0.0, unit="1/K", doc="remanence temperature coefficient")

    @classmethod
    def sample_signature(cls):
        alpha = cls().alpha_br_per_k  # the library's NdFeB coefficient: the fit gives dk_e / k_e
        low, high = bounds_of(cls, "temperature_rise_k")
        return SampleSignature(
            "voltage",
            lambda rows, _, m: rows["e"][:, None],  # the relative k_e change times the line back-EMF
            lambda c, _, m: {
                "temperature_rise_k": float(c[0] / alpha),
                "alpha_br_per_k": alpha,
                "ke_delta_v_s_per_rad": float(c[0] * m.ke_v_s_per_rad),
            },
            lambda c, se, m: bool(low - 3 * se[0] / abs(alpha) <= c[0] / alpha <= high + 3 * se[0] / abs(alpha)),
            budget="speed",
            disturbs="relative speed change at a fixed duty",
            # speed per duty goes as 1 / k_e
            disturbance=lambda params, motor, env: abs(params["ke_delta_v_s_per_rad"]) / motor.ke_v_s_per_rad,
            constants=("alpha_br_per_k",),
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(float(rng.choice([-1, 1]) * 10.0))

    def contribute(self, plant):
        plant.ke_v_s_per_rad *= 1.0 + self.alpha_br_per_k * self.temperature_rise_k


@dataclass(frozen=True)
class DeadTime(Effect):
    """Inverter dead time: the PWM leg loses ``dead_time_s * f_pwm`` of duty per period.

    During the dead time a positive phase current freewheels through the lower diode, so the
    averaged terminal voltage of the PWM phase drops by dead_time_s * f_pwm * V_dc (rises when
    the current is negative). Fingerprint: no edge signature; a speed deficit at low duty.
    """

    name: ClassVar[str] = "dead_time"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "speed versus duty offset; none in edge angles",
        "scales_with": "PWM frequency and supply voltage",
        "knob": "f_pwm, V_dc",
    }
    no_trace: ClassVar[str] = (
        "no trace in the recorded signals: the terminal voltages already carry the dead-time loss and the duty "
        "is not in hil-recording/1; record the duty (or V_dc and f_pwm changes) to see it"
    )
    dead_time_s: float = bounded(0.0, low=0.0, high=5e-6, unit="s", doc="dead time per switching event")

    def contribute(self, plant):
        plant.dead_time_s += self.dead_time_s


@dataclass(frozen=True)
class Saturation(Effect):
    """Iron saturation: the phase inductance falls with current.

    L(i) = L * max(min_inductance_fraction, 1 / (1 + (|i| / saturation_current_a)^2)).
    Fingerprint: no edge signature; faster current rise and commutation above the knee.
    """

    name: ClassVar[str] = "saturation"
    layer: ClassVar[str] = "electrical"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "current waveform above a threshold; none in edge angles",
        "scales_with": "phase current above the knee",
        "knob": "current threshold (load)",
    }
    knob_record: ClassVar[str] = "one operating point at high load"
    knob_shows: ClassVar[str] = "saturation shows only above its knee current"
    validation: ClassVar[str] = "knee"
    magnitude_field: ClassVar[str] = "saturation_current_a"
    vector_fields: ClassVar[tuple[str, ...]] = ("saturation_current_a",)
    saturation_current_a: float = bounded(20.0, low=0.1, high=1e3, unit="A", doc="knee current")
    min_inductance_fraction: float = bounded(1.0, low=0.1, high=1.0, unit="1", doc="floor of L(i)/L (1 = none)")

    @staticmethod
    def flux_deficit(i: np.ndarray, inductance_h: float, knee_a: float, floor: float) -> np.ndarray:
        """Psi(i) - L i for L(i) = L max(floor, 1 / (1 + (i / knee)^2)) (Psi = integral of L(i) di)."""
        i_floor = knee_a * math.sqrt(1.0 / floor - 1.0)
        a = np.abs(i)
        psi = np.where(
            a <= i_floor, knee_a * np.arctan(a / knee_a), knee_a * math.atan(i_floor / knee_a) + floor * (a - i_floor)
        )
        return inductance_h * (np.sign(i) * psi - i)

    @classmethod
    def sample_signature(cls):
        # the knee is fitted over the library's range with L(i)/L floored at its lower bound
        floor = bounds_of(cls, "min_inductance_fraction")[0]
        knee_low, knee_high = bounds_of(cls, "saturation_current_a")

        def columns(rows, knee_a, m):
            def deficit(i):
                return cls.flux_deficit(i, m.inductance_h, knee_a, floor)

            # the line pair's flux deficit change over the interval, as a voltage
            d = deficit(rows["i1x"]) - deficit(rows["i0x"]) - deficit(rows["i1y"]) + deficit(rows["i0y"])
            return (d / rows["h"])[:, None]

        def disturbance(params, motor, env):
            knee, fl = params["saturation_current_a"], params["min_inductance_fraction"]
            return 1.0 - max(fl, 1.0 / (1.0 + (env.max_current_a / knee) ** 2))

        return SampleSignature(
            "voltage",
            columns,
            lambda c, knee, m: {"saturation_current_a": float(knee), "min_inductance_fraction": floor},
            lambda c, se, m: True,
            budget="inductance",
            disturbs="inductance drop at the largest measured current",
            disturbance=disturbance,
            grid=lambda motor, limits: tuple(np.geomspace(knee_low, knee_high, 41)),
            n_coef=0,
            refine=True,
        )

    @classmethod
    def unit_draw(cls, rng, pole_pairs):
        return cls(10.0, 0.1)  # the knee law's first step; the floor at the library's lower bound

    def contribute(self, plant):
        plant.saturation_current_a = self.saturation_current_a
        plant.min_inductance_fraction = self.min_inductance_fraction


#: the registry: an effect listed here is simulated, listed by ``hil effects``, read from TOML, and, by
#: its declaration, diagnosed and validated; its order is the order the gap diagnosis tries them in
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        InstallationOffset,
        PoleOffset,
        SensorPoleOffset,
        Eccentricity,
        Hysteresis,
        ConditioningDelay,
        ArmatureReaction,
        SwitchingAsymmetry,
        EdgeJitter,
        TimerQuantization,
        CoggingTorque,
        WindingTemperature,
        MagnetTemperature,
        DeadTime,
        Saturation,
    )
}

_CIRCUIT_KEYS = {f.name for f in dataclasses.fields(ConditioningCircuit)}


def effect_from_mapping(data: Mapping[str, Any], prefix: str = "effects[0].") -> Effect:
    """Build an effect from a TOML table ``{name = "...", <params>}``; errors name the field."""
    data = dict(data)
    name = data.pop("name", None)
    if name is None:
        raise ConfigError(f"{prefix}name", "missing effect name")
    cls = EFFECTS.get(name)
    if cls is None:
        raise ConfigError(f"{prefix}name", f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
    if cls is ConditioningDelay and set(data) & _CIRCUIT_KEYS:
        circuit = from_mapping(ConditioningCircuit, data, prefix)
        return ConditioningDelay.from_circuit(circuit)
    if hasattr(cls, "from_mapping"):  # an effect with nested tables (hall_field)
        return cls.from_mapping(data, prefix)
    return from_mapping(cls, data, prefix)


def effects_strategy(pole_pairs: int = 2, names: tuple[str, ...] | None = None, min_size: int = 0):
    """Hypothesis strategy for a composed effect set (each effect at most once)."""
    from hypothesis import strategies as st

    names = tuple(names or EFFECTS)
    return st.lists(st.sampled_from(names), min_size=min_size, max_size=len(names), unique=True).flatmap(
        lambda chosen: st.tuples(*[EFFECTS[n].strategy(pole_pairs) for n in chosen])
    )
