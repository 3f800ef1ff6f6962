"""The virtual controller: the reference device under test, firmware-like and deterministic.

It captures Hall edges (time stamp from its capture timer, phase current from its ADC), applies
the downloaded correction tables, predicts commutation with the selected strategy, closes a PI
speed loop on the duty with a current limit, and raises faults the way a CiA 301 device
reports them (error code, error register, a history of codes). The protocol faces (CANopen,
Modbus) and the in-process link all drive this one object.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field
from typing import ClassVar, Mapping

import numpy as np

from bldc.contract import (
    FILTER_COUNTERS,
    GUARD_TRIPS,
    MAX_CONDITIONING_DELAY_S,
    MAX_POLE_TABLE_OFFSET_DEG_E,
    CalibrationTableError,
    Command,
    Fault,
    Strategy,
)
from bldc.hall import sector_of_levels
from bldc.motor import MotorParameters, speed_loop_gain_scale, steady_state
from bldc.units import rad_e_per_s_to_rpm

from ..calibration.corrections import SENSORS, Corrections
from ..predictors import FilterSettings, KalmanPredictor, MotorModel, SageHusaPredictor
from ..predictors.registry import for_strategy, pump_defaults
from .adc import edge_currents
from .commutation import HallCommutation, SpeedPI


@dataclass(frozen=True)
class Identity:
    vendor_id: int = 0x00000B1D
    product_code: int = 0x00480001
    revision: int = 0x00010000
    serial: int = 0x00000001
    device_type: int = 0x00000192  # CiA 402-like drive profile number, informative
    firmware: str = "vc-0.1.0"


def validate_corrections(c: Corrections, pole_pairs: int) -> None:
    """Refuse a calibration table that is not finite, out of the library's bounds or the wrong size."""
    for s in SENSORS:
        v = c.installation_offset_deg_e.get(s)
        if v is None or not math.isfinite(v) or abs(v) > 30.0:
            raise CalibrationTableError(
                f"installation_offset_deg_e.{s}", f"must be finite and within +-30 deg_e, got {v!r}"
            )
    if len(c.pole_offset_deg_e) != 2 * pole_pairs:
        raise CalibrationTableError(
            "pole_offset_deg_e", f"needs {2 * pole_pairs} entries, got {len(c.pole_offset_deg_e)}"
        )
    for j, v in enumerate(c.pole_offset_deg_e):
        if not math.isfinite(v) or abs(v) > MAX_POLE_TABLE_OFFSET_DEG_E:  # its physics: bldc/contract.py
            raise CalibrationTableError(
                f"pole_offset_deg_e[{j}]",
                f"must be finite and within +-{MAX_POLE_TABLE_OFFSET_DEG_E:g} deg_e, got {v!r}",
            )
    for k in ("rise", "fall"):
        v = c.conditioning_delay_s.get(k)
        # the bound's physics (half a sector at the top speed of a many-pole hub motor): bldc/contract.py
        if v is None or not math.isfinite(v) or not 0.0 <= v <= MAX_CONDITIONING_DELAY_S:
            raise CalibrationTableError(
                f"conditioning_delay_s.{k}", f"must be within [0, {MAX_CONDITIONING_DELAY_S:g}] s, got {v!r}"
            )
    v = c.armature_reaction_deg_e_per_a
    if not math.isfinite(v) or abs(v) > 5.0:
        raise CalibrationTableError(
            "armature_reaction_deg_e_per_a", f"must be finite and within +-5 deg_e/A, got {v!r}"
        )


def warm_up() -> None:
    """Compile the filters' numba code before a device announces itself: a first edge must not
    wait seconds for a compiler (what a fresh machine with a cold numba cache would do)."""
    t = np.arange(8) * 1e-3
    for cls in (KalmanPredictor, SageHusaPredictor):
        p = cls(MotorModel(2, 0.0039), FilterSettings(q0_diag=(0.1, 1e-9, 1e-6), r0_diag=(1e-5, 1.0)))
        for k in range(t.size):
            p.update(float(t[k]), 1.0)


@dataclass
class VirtualController:
    motor: MotorParameters
    identity: Identity = field(default_factory=Identity)
    strategy: Strategy = Strategy.SAGE_HUSA
    speed_setpoint_rpm: float = 5000.0
    corrections: Corrections | None = None
    #: Sage-Husa settings: the paper's P0, q0, r0 and R0_theta = 0; R and Q_i adapt by Eq. 12, Q_w is
    #: steered by innovation whiteness and R_i never goes below its R0 (``compare.SH_DESIGN``).
    #: Nominal Q0, R0_i, b and b_R from the tuning on training pumps 2000-2007 (pumps drawn around
    #: this bench, none of them this controller's plant or any scenario seed it is judged on):
    #: ``python tools/predictor_tuning.py`` writes hil/predictors/peer_settings.py, read here and
    #: rounded to two digits (``registry.pump_defaults``; docs/sage-husa.md, "Peers")
    filter_settings: FilterSettings = field(default_factory=lambda: pump_defaults()[0])
    #: the fixed-noise Kalman strategy's Q, R and gate, from the same tuning with the same budget
    kf_settings: FilterSettings = field(default_factory=lambda: pump_defaults()[1])
    model: MotorModel | None = None
    current_limit_a: float = 15.0
    #: the pump turns one way: a Hall step against it means edges were lost
    direction: int = 1
    #: an edge interval longer than this multiple of the mean interval so far means an edge was
    #: lost (the first mechanical turn, before each sector has a reference of its own)
    missing_edge_interval_ratio: float = 1.8
    #: ... than this multiple of the same sector's interval one mechanical turn earlier
    same_sector_interval_ratio: float = 1.3
    #: speed loop gains, duty per rpm of error (and per rpm s): None = the reference tuning on the
    #: paper pump (1e-4, 2e-3) times ``bldc.motor.speed_loop_gain_scale`` of this motor (the same
    #: loop on a motor wound for another speed)
    kp_per_rpm: float | None = None
    ki_per_rpm_s: float | None = None

    #: the field holding the settings of a predictor the controller configures itself (bus-written,
    #: tuned by ``hil.experiments.controller_tuning``); any other predictor a strategy runs takes
    #: the shipped tuning (``peer_settings.TUNED``)
    SETTINGS_FIELDS: ClassVar[Mapping[str, str]] = {"sage_husa": "filter_settings", "kf": "kf_settings"}

    def predictor_settings(self, name: str) -> dict:
        """The settings the controller runs predictor ``name`` with (as the registry's ``make`` reads them)."""
        attr = self.SETTINGS_FIELDS.get(name)
        if attr is None:
            from ..predictors.peer_settings import TUNED

            return TUNED[name]
        return dataclasses.asdict(getattr(self, attr))

    def __post_init__(self):
        scale = speed_loop_gain_scale(self.motor)
        if self.kp_per_rpm is None:
            self.kp_per_rpm = 1e-4 * scale
        if self.ki_per_rpm_s is None:
            self.ki_per_rpm_s = 2e-3 * scale
        self.faults: list[tuple[float, int]] = []
        self.error_register = 0
        self._fault_listeners = []
        self.reset()

    # --- configuration (what SDO writes or holding registers set) ---------------------------
    def download_calibration(self, corrections: Corrections) -> None:
        try:
            validate_corrections(corrections, self.motor.pole_pairs)
        except CalibrationTableError:
            self.raise_fault(Fault.INVALID_CALIBRATION, 0.0)
            raise
        self.corrections = corrections
        self.reset()

    def set_strategy(self, strategy: int) -> None:
        self.strategy = Strategy(int(strategy))
        self.reset()

    def set_speed(self, rpm: float) -> None:
        if not math.isfinite(rpm) or not 0.0 <= rpm <= 30000.0:
            raise ValueError(f"speed set point must be within [0, 30000] rpm, got {rpm!r}")
        self.speed_setpoint_rpm = float(rpm)
        self._logic.speed.setpoint_rpm = float(rpm)
        self._logic.speed.feedforward = steady_state(self.motor, rpm)["duty"]

    def _build_logic(self, speed_loop: SpeedPI) -> None:
        # the registry names the predictor each strategy runs (none: RAW and CORRECTED commutate at the edges)
        entry = for_strategy(self.strategy.name)
        predictor = None
        if entry is not None:
            model = self.model or MotorModel.from_plant(self.motor)
            predictor = entry.make(self.predictor_settings(entry.name), model, False)
        corrections = (
            None
            if self.strategy is Strategy.RAW
            else (self.corrections or Corrections(pole_offset_deg_e=[0.0] * 2 * self.motor.pole_pairs))
        )
        self._logic = HallCommutation(
            self.motor.pole_pairs,
            speed_loop,
            corrections,
            current_limit_a=self.current_limit_a,
            motor=self.motor,
            predictor=predictor,
        )
        self._predictor = predictor
        self._guards_seen = 0

    def reset(self) -> None:
        """(Re)start the control logic with the present configuration (NMT reset application)."""
        self._build_logic(
            SpeedPI(
                self.speed_setpoint_rpm,
                kp_per_rpm=self.kp_per_rpm,
                ki_per_rpm_s=self.ki_per_rpm_s,
                feedforward=steady_state(self.motor, self.speed_setpoint_rpm)["duty"],
            )
        )
        self._sector = None
        self._sensors_seen: set[int] = set()
        self._bits = [0, 0, 0]
        self._edges_since_motion = 0
        self._normal_steps = 6  # Hall steps in a row since the last lost edge
        self._resync_pending = False
        self._last_t: float | None = None
        self._last_current_a = 0.0  #: the current at the last motion edge
        #: the last mechanical turn's sector intervals, oldest first (the missing-edge references), each
        #: with whether it was measured (False: a reference put in place of an interval that spanned
        #: lost edges, or of a glitch)
        self._intervals: deque[tuple[float, bool]] = deque(maxlen=6 * self.motor.pole_pairs)

    # --- run time -------------------------------------------------------------------------------
    def raise_fault(self, code: int, t_s: float) -> None:
        """Latch a fault: reported (EMCY) once per code until the faults are cleared."""
        if any(c == int(code) for _, c in self.faults):
            return
        self.faults.append((t_s, int(code)))
        self.error_register |= 0x01 | 0x80  # generic + manufacturer specific
        for listener in self._fault_listeners:
            listener(int(code), t_s)

    def on_fault(self, listener) -> None:
        self._fault_listeners.append(listener)

    def clear_faults(self) -> None:
        self.faults.clear()
        self.error_register = 0

    def capture(self, edge: dict) -> list[Command]:
        """A captured edge (``EdgeMessage.to_edge``): t_capture_s, sensor (0..2), rising, now_s and
        the ADC window before the capture. Returns commands."""
        t = float(edge["t_capture_s"])
        if not math.isfinite(t) or (self._last_t is not None and t <= self._last_t):
            self.raise_fault(Fault.CAPTURE_TIMING, t if math.isfinite(t) else 0.0)
            return []  # a capture stamp that does not increase cannot be an edge of this rotor
        edge_currents(edge, self._applied_delay_s(bool(edge["rising"])))
        self._bits[int(edge["sensor"])] = 1 if edge["rising"] else 0
        sector = sector_of_levels(self._bits)
        self._sensors_seen.add(int(edge["sensor"]))
        rotor_motion = True
        one_step = False  # the Hall code stepped one sector forward from a known state
        if len(self._sensors_seen) == 3:  # the Hall state is known once every sensor has switched
            if sector < 0:
                self.raise_fault(Fault.ILLEGAL_HALL_CODE, t)
                rotor_motion = False
            elif sector == self._sector:
                rotor_motion = False  # back where the last valid edge left it: a spike or a bounce, not motion
            elif self._sector is not None and (sector - self._sector) % 6 != (1 if self.direction > 0 else 5):
                self._edge_lost(t)  # a skipped sector, or a step against the direction of rotation
            elif self._sector is not None:
                self._normal_steps += 1
                one_step = True
            self._sector = sector if sector >= 0 else self._sector
        self._edges_since_motion += 1
        if rotor_motion:
            if self._last_t is not None:
                dt, measured = t - self._last_t, True
                ref, ratio = self._reference_interval_s()
                if ref is not None and dt > ratio * ref:
                    self._edge_lost(t)  # an interval of two or more sectors
                    sectors = round(dt / ref)
                    if one_step:
                        # the Hall code stepped one sector: edges lost in between can only be whole
                        # electrical periods (each sensor's two edges), 1 + 6 k sectors, and the time
                        # picks k. Read as round(dt / ref) instead, a reference too short (a start-up
                        # edge moved 63 deg e by 32 A of armature reaction left one of 20 deg e) had
                        # every later sector counted as three, the edge count ran 3 per edge and the
                        # pole corrections went to the wrong poles (+-12.6 deg e) for good
                        sectors = 1 + 6 * max(round((dt / ref - 1.0) / 6.0), 0)
                    # keep the edge count (and the pole assignment) right: sectors that passed
                    # minus the edges that did arrive
                    self._logic.count_lost_edges(max(sectors - self._edges_since_motion, 0))
                    if sectors > 1:
                        dt, measured = ref, False  # the interval of one sector stays the reference (not measured)
                    # else the interval is one sector, measured: it replaces the reference it exceeded
                    # (which, put back in its own place unmeasured, would never have been corrected)
                elif ref is not None and dt * ratio < ref:
                    # far shorter than its reference (the rotor cannot speed up that much in one
                    # sector): a glitch that read as a step, e.g. a spike on a Hall state left
                    # wrong by a lost edge. Taken as the reference, it made every later sector
                    # read as lost edges, the edge count ran away and the corrections with it
                    dt, measured = ref, False
                    self._intervals.clear()  # a step that was not a sector: the history is out of line
                if max(edge.get("current_a", 0.0), self._last_current_a) > self.current_limit_a:
                    # an edge of it saw more current than the speed loop's limit (a start-up's late
                    # commutations): its time moved by an armature lag the motor under control never
                    # has, so the interval is no measurement of its sector for the next turn (a
                    # start-up sector shortened by 22 A, the same-sector reference a turn later, read
                    # a normal sector as a lost edge in the reference firmware: a false MISSING_EDGE,
                    # REQ-ROB-001 at --hil-seed 1)
                    measured = False
                self._intervals.append((dt, measured))
            self._last_t = t
            self._last_current_a = edge.get("current_a", 0.0)
            self._edges_since_motion = 0
        if self._resync_pending and self._normal_steps >= 6:
            # a full electrical period of normal Hall steps after lost edges: the edge count is
            # trusted again from here
            self._logic.resync()
            self._resync_pending = False
        commands = self._logic.on_edge(edge)
        if self._predictor is not None:
            # guards firing while P settles from P0 during the warm-up are expected, not faults
            trips = self._predictor.covariance_repairs
            if self._predictor.steps <= self._predictor.settings.warmup:
                self._guards_seen = trips
            elif trips > self._guards_seen:
                self._guards_seen = trips
                self.raise_fault(Fault.FILTER_GUARD_TRIP, t)
        return commands

    def _reference_interval_s(self) -> tuple[float | None, float]:
        """What a sector interval is compared with to tell a lost edge (or a glitch), and the ratio
        that tells it. Sectors are uneven by their installation, pole and delay deviations (up to
        about 80/40 deg e within the effect library's bounds, beyond the ratio of 1.8 between
        neighbours that once read as lost edges every turn); the same sector one mechanical turn
        earlier has the same deviations, so it is the reference once a turn has been seen, with
        ``same_sector_interval_ratio`` (two sectors are at least 1.4 of one). Before that: the mean
        interval so far, with ``missing_edge_interval_ratio``."""
        if not self._intervals:
            return None, self.missing_edge_interval_ratio
        if len(self._intervals) == self._intervals.maxlen and self._intervals[0][1]:
            # (a reference put in place of an interval is no measurement of this sector: a long
            # sector of a many-pole rotor, once read as a lost edge, would read as one every turn)
            return self._intervals[0][0], self.same_sector_interval_ratio
        return sum(dt for dt, _ in self._intervals) / len(self._intervals), self.missing_edge_interval_ratio
    def _applied_delay_s(self, rising: bool) -> float:
        """The conditioning delay of the applied table for this polarity: the edge's current is read
        that long before the capture, where the armature field that moved the edge acted (0 before
        a calibration is applied, and under raw commutation)."""
        table = self._logic.corrections
        return table.conditioning_delay_s["rise" if rising else "fall"] if table is not None else 0.0

    def _edge_lost(self, t_s: float) -> None:
        self.raise_fault(Fault.MISSING_EDGE, t_s)
        # the history no longer lines up with the sectors (one turn back is another sector now):
        # the references start again from the mean interval
        self._intervals.clear()
        self._normal_steps, self._resync_pending = 0, True

    # --- read-backs -------------------------------------------------------------------------------
    def status(self) -> dict:
        p = self._predictor
        # without a filter: the mean over the last mechanical turn, where edge deviations cancel
        turn = [v for _, v in self._logic.speed_estimates_rpm[-6 * self.motor.pole_pairs :]]
        est = len(turn) / sum(1.0 / v for v in turn) if turn else float("nan")
        return {
            "strategy": int(self.strategy),
            "speed_setpoint_rpm": self.speed_setpoint_rpm,
            "estimated_speed_rpm": float(rad_e_per_s_to_rpm(p.speed_rad_s, self.motor.pole_pairs))
            if p is not None and p.state[0]
            else float(est),
            "q_diag": [float(v) for v in np.diag(p.q_matrix)] if p is not None else [0.0, 0.0, 0.0],
            "r_diag": [float(v) for v in np.diag(p.r_matrix)] if p is not None else [0.0, 0.0],
            GUARD_TRIPS: int(sum(p.guards.values())) if p is not None else 0,
            **(p.counters if p is not None else dict.fromkeys(FILTER_COUNTERS, 0)),
            "last_predicted_commutation_s": float(self._logic.last_prediction_s),
            "error_register": self.error_register,
            "faults": list(self.faults),
        }
