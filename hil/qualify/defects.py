"""Seeded firmware defects of the built-in controller: what the acceptance suite must catch.

Each defect is a realistic firmware bug, written as a subclass of the built-in controller that
changes only what the bug changes (the table the firmware applies, not the one it reads back;
the instant its ADC is read; its filter; its fault handling). ``hil qualify`` runs the acceptance
suite against each; a defect no requirement fails is a finding about the suite.

Add your own in a Python file and pass it with ``--defects FILE``::

    from hil.qualify.defects import defect
    from hil.controller.virtual import VirtualController

    @defect("speed-loop-gain-x10", "the speed PI's proportional gain ten times too high")
    class FastSpeedLoop(VirtualController):
        kp_per_rpm: float = 1e-3
"""

from __future__ import annotations

import dataclasses
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bldc.contract import Fault, Strategy

from ..calibration.corrections import SENSORS, Corrections
from ..controller.commutation import SpeedPI
from ..controller.virtual import VirtualController
from ..predictors import KalmanPredictor, MotorModel
from ..predictors import filters as F


@dataclass(frozen=True)
class Defect:
    name: str
    description: str
    controller: type[VirtualController]
    #: the defect class (hil.verdicts.requirements.DEFECT_CLASSES): the requirements that name it must catch it
    defect_class: str = ""


CATALOGUE: dict[str, Defect] = {}


def defect(name: str, description: str, defect_class: str = ""):
    """Register a controller class as the seeded defect ``name`` (a VirtualController subclass) of
    ``defect_class`` (one of hil.verdicts.requirements.DEFECT_CLASSES; a user's defect may leave it empty)."""
    from ..verdicts.requirements import DEFECT_CLASSES

    if defect_class and defect_class not in DEFECT_CLASSES:
        raise ValueError(f"defect {name!r}: unknown defect class {defect_class!r}; known: {', '.join(DEFECT_CLASSES)}")

    def register(cls):
        if not (isinstance(cls, type) and issubclass(cls, VirtualController)):
            raise TypeError(f"defect {name!r}: {cls!r} is not a VirtualController subclass")
        if name in CATALOGUE:
            raise ValueError(f"defect {name!r} is registered twice ({CATALOGUE[name].controller.__qualname__}, "
                             f"{cls.__qualname__})")
        CATALOGUE[name] = Defect(name, description, dataclasses.dataclass(cls) if "__dataclass_fields__" not in
                                 cls.__dict__ else cls, defect_class)
        return cls

    return register


#: the defects files imported in this process, by resolved path, and the names each registered
_LOADED: dict[Path, list[str]] = {}


def load_defects(path: str | Path) -> list[str]:
    """Import a user's defects file (its ``@defect`` classes join the catalogue); their names. A file
    already imported is not imported again (``hil qualify --defects`` loads it for its list and its
    runs in one process)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"defects file {path} does not exist")
    if path.resolve() in _LOADED and all(n in CATALOGUE for n in _LOADED[path.resolve()]):
        return list(_LOADED[path.resolve()])
    before = set(CATALOGUE)
    spec = importlib.util.spec_from_file_location(f"hil_user_defects_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    added = [n for n in CATALOGUE if n not in before]
    _LOADED[path.resolve()] = added
    if not added:
        raise ValueError(f"defects file {path} registers no defect (decorate VirtualController subclasses "
                         "with @defect)")
    return added


class _WrongTable(VirtualController):
    """Firmware that stores and reads back the downloaded table but applies a wrong one."""

    def applied(self, table: Corrections) -> Corrections:
        raise NotImplementedError

    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        if self._logic.corrections is not None and self.corrections is not None:
            self._logic.corrections = self.applied(self.corrections)


@defect("pole-table-one-pole-off", "the pole offsets applied one magnet pole late (table index off by one)",
        "calibration-table")
class PoleTableOneOff(_WrongTable):
    def applied(self, table):
        return dataclasses.replace(table, pole_offset_deg_e=list(np.roll(table.pole_offset_deg_e, 1)))


@defect("rise-fall-delays-swapped", "the rising edges corrected with the falling-edge delay and vice versa",
        "calibration-table")
class DelaysSwapped(_WrongTable):
    def applied(self, table):
        d = table.conditioning_delay_s
        return dataclasses.replace(table, conditioning_delay_s={"rise": d["fall"], "fall": d["rise"]})


@defect("installation-on-wrong-sensor", "sensor A's installation offset applied to B, B's to C, C's to A",
        "calibration-table")
class InstallationRotated(_WrongTable):
    def applied(self, table):
        off = table.installation_offset_deg_e
        rotated = {s: off[SENSORS[k - 1]] for k, s in enumerate(SENSORS)}
        return dataclasses.replace(table, installation_offset_deg_e=rotated)


@defect("armature-sign-inverted", "the armature-reaction correction applied with the wrong sign", "calibration-table")
class ArmatureSign(_WrongTable):
    def applied(self, table):
        return dataclasses.replace(table, armature_reaction_deg_e_per_a=-table.armature_reaction_deg_e_per_a)


@defect("delay-applied-at-90-percent", "the conditioning delays applied at 90 % (a timer prescaler rounded)",
        "calibration-table")
class DelayNinety(_WrongTable):
    def applied(self, table):
        delays = {k: 0.9 * v for k, v in table.conditioning_delay_s.items()}
        return dataclasses.replace(table, conditioning_delay_s=delays)


@defect("table-never-applied", "the table is accepted and read back, but the commutation runs on an empty one",
        "calibration-table")
class TableNeverApplied(_WrongTable):
    def applied(self, table):
        return Corrections(pole_offset_deg_e=[0.0] * len(table.pole_offset_deg_e))


@defect("current-sampled-at-capture", "the edge's current read from the ADC at the capture interrupt, not one "
        "conditioning delay before it where the armature field moved the edge", "edge-current")
class CurrentAtCapture(VirtualController):
    def _applied_delay_s(self, rising: bool) -> float:
        return 0.0


class _InMilliamps:
    """A predictor whose current input is scaled to mA on the way in."""

    def __init__(self, predictor):
        self._predictor = predictor

    def update(self, t_s, current_a):
        return self._predictor.update(t_s, current_a * 1000.0)

    def __getattr__(self, name):
        return getattr(self._predictor, name)


@defect("predictor-fed-milliamperes", "the predictor's current input in mA where Eq. 8 wants A", "model-input")
class PredictorMilliamps(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        if self._logic.predictor is not None:
            self._logic.predictor = _InMilliamps(self._logic.predictor)


class CycleCurrentScaled(VirtualController):
    """Eq. 8's cycle-mean current input ``scale`` times what the controller's ADC measured (the
    model-input class's magnitude: ``tools/power_defects.py`` sweeps it)."""

    scale: float = 1.0

    def capture(self, edge):
        if edge.get("adc_cycle_conversions"):
            edge = {**edge, "adc_cycle_sums_a": self.scale * np.asarray(edge["adc_cycle_sums_a"], dtype=float)}
        return super().capture(edge)


@defect("predictor-current-phase-sum", "the predictor's current input (Eq. 8's cycle mean |i|) computed as the sum "
        "of the three phases' mean |i|, not their mean (three times the current K_T is defined for)", "model-input")
class PredictorCurrentPhaseSum(CycleCurrentScaled):
    # the cycle accumulators summed over the phases and divided by the conversions alone
    # (hil.controller.adc.cycle_mean_current_a divides by three times them)
    scale: float = 3.0


@defect("predictor-current-signed-sum", "the predictor's current input (Eq. 8's cycle mean |i|) computed from the "
        "signed sum of the three phases' accumulators, |sum(i)|, not the sum of their magnitudes, sum(|i|): about "
        "0 A in a star winding (the phase currents sum to zero), so Eq. 8 sees no current", "model-input")
class PredictorCurrentSignedSum(VirtualController):
    def capture(self, edge):
        # abs(sum(sums_a)) where hil.controller.adc.cycle_mean_current_a takes sum(abs(sums_a)): the
        # accumulators handed on as their signed sum in one phase, the other two empty
        if edge.get("adc_cycle_conversions"):
            sums = np.asarray(edge["adc_cycle_sums_a"], dtype=float)
            edge = {**edge, "adc_cycle_sums_a": np.array([sums.sum(), 0.0, 0.0])}
        return super().capture(edge)


class GateLatency(VirtualController):
    """Commands ``latency_s`` late (the commutation-timing class's magnitude: ``tools/power_defects.py``)."""

    latency_s: float = 0.0

    def capture(self, edge):
        # commands leave the interrupt late by the gate driver's uncompensated latency
        return [dataclasses.replace(c, at_s=c.at_s + self.latency_s) for c in super().capture(edge)]


@defect("gate-latency-5us", "5 us of gate-driver latency not compensated", "commutation-timing")
class GateLatency5(GateLatency):
    latency_s: float = 5e-6


@defect("gate-latency-25us", "25 us of gate-driver latency not compensated", "commutation-timing")
class GateLatency25(GateLatency):
    latency_s: float = 25e-6


@defect("sage-husa-runs-kf", "the Sage-Husa strategy selects the fixed-noise Kalman filter", "predictor-model")
class SageHusaIsKf(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        if self.strategy is Strategy.SAGE_HUSA:
            model = self.model or MotorModel.from_plant(self.motor)
            self._predictor = self._logic.predictor = KalmanPredictor(model, self.kf_settings)


@defect("sage-husa-without-adaptation", "Sage-Husa with its noise adaptation (Eq. 12) switched off", "noise-learning")
class NoAdaptation(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        self.filter_settings = dataclasses.replace(self.filter_settings, adapt_mask=0)
        super()._build_logic(speed_loop)


class _UnreportedFault(VirtualController):
    """The controller handles the faults ``unreported`` (the edge dropped, the covariance
    repaired) but never latches or sends their codes: a missing case in the firmware's fault
    switch."""

    unreported: tuple[Fault, ...]

    def raise_fault(self, code, t_s):
        if int(code) not in self.unreported:
            super().raise_fault(code, t_s)


@defect("no-missing-edge-fault", "a lost edge is counted but never reported (no 0xFF02)", "fault-handling")
class NoMissingEdgeFault(_UnreportedFault):
    unreported = (Fault.MISSING_EDGE,)


@defect("no-illegal-code-fault", "an illegal Hall code (000/111) is dropped as a glitch but never reported (no "
        "0xFF01)", "fault-handling")
class NoIllegalCodeFault(_UnreportedFault):
    unreported = (Fault.ILLEGAL_HALL_CODE,)


@defect("no-hall-fault-reports", "the Hall faults are handled but none is reported (no 0xFF01, no 0xFF02): a sensor "
        "that drops out goes unseen", "fault-handling")
class NoHallFaultReports(_UnreportedFault):
    unreported = (Fault.ILLEGAL_HALL_CODE, Fault.MISSING_EDGE)


@defect("no-guard-trip-fault", "a filter guard repairs the covariance but the trip is never reported (no 0xFF03)",
        "fault-handling")
class NoGuardTripFault(_UnreportedFault):
    unreported = (Fault.FILTER_GUARD_TRIP,)


@defect("no-table-validation", "a calibration table is applied without checking it (NaN, out of range, wrong size)",
        "table-validation")
class NoTableValidation(VirtualController):
    def download_calibration(self, corrections):
        self.corrections = corrections
        self.reset()


@defect("current-limit-not-enforced", "the speed loop's duty is clamped to 0..1 but never limited to keep the "
        "phase current within the limit", "current-limit")
class NoCurrentLimit(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        self._logic._duty_bounds = lambda speed_rpm: (0.0, 1.0)


@defect("never-resynchronises", "after lost edges the edge count (and the pole table) is never resynchronised",
        "fault-handling")
class NeverResyncs(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        self._logic.resync = lambda: None


@defect("lost-edge-against-last-sector", "a lost edge told from the last sector's interval (x1.8), so uneven "
        "calibrated sectors read as lost edges", "fault-handling")
class LostEdgeAgainstLastSector(VirtualController):
    def _reference_interval_s(self):
        if not self._intervals:
            return None, self.missing_edge_interval_ratio
        last_s, _measured = self._intervals[-1]  # the references are (interval, measured) pairs
        return last_s, self.missing_edge_interval_ratio


class _SpeedGains(VirtualController):
    """A speed loop commissioned with a gain off by ``kp_factor`` / ``ki_factor`` (a gain entered in
    the wrong unit, a scale left from another motor)."""

    kp_factor: float = 1.0
    ki_factor: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        self.kp_per_rpm *= self.kp_factor
        self.ki_per_rpm_s *= self.ki_factor
        self.reset()


@defect("speed-loop-integral-x10", "the speed PI's integral gain ten times the commissioned one", "speed-loop")
class SpeedIntegralX10(_SpeedGains):
    ki_factor: float = 10.0


@defect("speed-loop-integral-x20", "the speed PI's integral gain twenty times the commissioned one", "speed-loop")
class SpeedIntegralX20(_SpeedGains):
    ki_factor: float = 20.0


@defect("speed-loop-integral-x100", "the speed PI's integral gain a hundred times the commissioned one",
        "speed-loop")
class SpeedIntegralX100(_SpeedGains):
    ki_factor: float = 100.0


@defect("speed-loop-proportional-x10", "the speed PI's proportional gain ten times the commissioned one",
        "speed-loop")
class SpeedProportionalX10(_SpeedGains):
    kp_factor: float = 10.0


@defect("speed-loop-proportional-x0.1", "the speed PI's proportional gain a tenth of the commissioned one",
        "speed-loop")
class SpeedProportionalTenth(_SpeedGains):
    kp_factor: float = 0.1


@defect("speed-loop-integral-zero", "the speed PI's integral gain left at zero (a proportional loop on the "
        "feedforward: it holds a set point only at the load the feedforward assumes)", "speed-loop")
class SpeedIntegralZero(_SpeedGains):
    ki_factor: float = 0.0


@defect("speed-loop-no-anti-windup", "the speed PI integrates on while the duty is held at the current limit's "
        "bound (anti-windup left out)", "speed-loop")
class SpeedNoAntiWindup(VirtualController):
    def _build_logic(self, speed_loop: SpeedPI) -> None:
        super()._build_logic(_WindingUp(**dataclasses.asdict(speed_loop)))


@dataclass
class _WindingUp(SpeedPI):
    def update(self, speed_rpm: float, dt_s: float, low: float = 0.0, high: float = 1.0) -> float:
        error = self.setpoint_rpm - speed_rpm
        self.integral += error * dt_s
        return min(max(self.feedforward + self.kp_per_rpm * error + self.ki_per_rpm_s * self.integral, low), high)


@defect("sage-husa-noise-without-memory", "Sage-Husa's noise estimates with almost no memory: R's forgetting "
        "factor near 0 over an interval of 2 edges, Q's near 0 every edge (each estimate is the last edges' alone)",
        "noise-learning")
class NoiseWithoutMemory(VirtualController):
    def _build_logic(self, speed_loop) -> None:
        self.filter_settings = dataclasses.replace(self.filter_settings, r_forgetting_b=1e-3, r_interval=2,
                                                   forgetting_b=1e-3, adapt_interval=1)
        super()._build_logic(speed_loop)


class _EdgeNoiseUpdate:
    """A Sage-Husa predictor whose update of the edge-angle noise variance R_theta is wrong:
    ``wrong(before, after)`` is what the firmware stores where the filter computed ``after``."""

    def __init__(self, predictor, wrong):
        self._predictor, self._wrong = predictor, wrong

    def update(self, t_s, current_a):
        state = self._predictor.state
        before = float(state[F.ST.R])
        predicted = self._predictor.update(t_s, current_a)
        after = float(state[F.ST.R])
        if after != before:
            state[F.ST.R] = self._wrong(before, after)
        return predicted

    def __getattr__(self, name):
        return getattr(self._predictor, name)


class _WrongEdgeNoiseUpdate(VirtualController):
    def wrong(self, before: float, after: float) -> float:
        raise NotImplementedError

    def _build_logic(self, speed_loop) -> None:
        super()._build_logic(speed_loop)
        if self.strategy is Strategy.SAGE_HUSA:
            self._predictor = self._logic.predictor = _EdgeNoiseUpdate(self._logic.predictor, self.wrong)


@defect("sage-husa-r-frozen", "Sage-Husa's edge-noise variance R set once (its first estimate) and never updated "
        "after (each later update written to a copy the filter does not use)", "noise-learning")
class EdgeNoiseFrozen(_WrongEdgeNoiseUpdate):
    def wrong(self, before, after):
        return before if before > 0.0 else after


@defect("sage-husa-r-update-wrong-sign", "Sage-Husa's edge-noise variance R updated with the wrong sign (the "
        "step R_new - R_old subtracted; R floored at 0)", "noise-learning")
class EdgeNoiseWrongSign(_WrongEdgeNoiseUpdate):
    def wrong(self, before, after):
        return max(before - (after - before), 0.0)


@defect("sage-husa-r-update-wrong-scale", "Sage-Husa's edge-noise variance R stored at a quarter of each update "
        "(a fixed-point scale 2 bits off)", "noise-learning")
class EdgeNoiseWrongScale(_WrongEdgeNoiseUpdate):
    def wrong(self, before, after):
        return 0.25 * after


@defect("sage-husa-r-runaway", "Sage-Husa's edge-noise variance R updated without the (1 - d) factor on the old "
        "estimate (R = R + d term, not (1 - d) R + d term): it accumulates every interval's noise and runs away",
        "noise-learning")
class EdgeNoiseRunaway(_WrongEdgeNoiseUpdate):
    def wrong(self, before, after):
        # after = (1 - d) before + d term, d = 1 - b_R once the interval count has grown: the old
        # estimate kept whole is after + d before
        return after + (1.0 - self.filter_settings.r_forgetting_b) * before
