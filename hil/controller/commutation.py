"""Controller-side commutation strategies that drive the plant through its command interface.

These are the reference behaviours the virtual controller will wrap: commutate on raw Hall
edges, or on edges corrected by the calibration tables (the paper's "pre-calibration"
strategy), each with the same PI speed loop on the PWM duty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bldc.contract import Command
from bldc.hall import SENSOR_POSITION_DEG_E, hall_state, sector_of_levels
from bldc.units import deg_e_per_s_to_rpm, rpm_to_rad_per_s

from ..calibration.corrections import Corrections


@dataclass
class SpeedPI:
    """PI speed loop on the duty (paper Section 4.1 regulates speed by PID on the duty)."""

    setpoint_rpm: float
    kp_per_rpm: float = 2e-5
    ki_per_rpm_s: float = 2e-3
    feedforward: float = 0.0
    integral: float = 0.0
    #: anti-windup: integrate only while the error is within this fraction of the set point (wide
    #: enough for the per-sector speed noise of raw edges, about +-8 % with paper-sized deviations)
    integrate_within: float = 0.10

    def update(self, speed_rpm: float, dt_s: float, low: float = 0.0, high: float = 1.0) -> float:
        """The duty within ``low``..``high`` (the current limit's bounds at this speed). The
        integral stops while the duty is held at a bound the error pushes against (clamping
        anti-windup): integrating on through a current-limited acceleration overshot a 500 rpm
        step by 83 %."""
        error = self.setpoint_rpm - speed_rpm
        unclamped = self.feedforward + self.kp_per_rpm * error + self.ki_per_rpm_s * self.integral
        pushing = (unclamped >= high and error > 0.0) or (unclamped <= low and error < 0.0)
        if abs(error) <= self.integrate_within * self.setpoint_rpm and not pushing:
            self.integral += error * dt_s
        return min(max(self.feedforward + self.kp_per_rpm * error + self.ki_per_rpm_s * self.integral, low), high)


@dataclass
class HallCommutation:
    """Commutate from captured Hall edges, raw (``corrections=None``) or corrected (Fig. 4).

    Corrected: each edge is moved back by its calibrated deviation at the present speed and
    current estimate; the commutation it marks is made at once if that instant has passed, and
    the next one is scheduled 60 deg electrical after the corrected edge. The pole causing an
    edge is tracked from the Hall sequence (each edge advances 60 deg electrical; the first
    edge's sensor and polarity fix its angle within the electrical period); which electrical
    period holds the calibration's pole N1 is found after the first mechanical turn by the
    alignment whose corrections make the sector times most even.
    """

    pole_pairs: int
    speed: SpeedPI
    corrections: Corrections | None = None
    #: current for the armature-reaction correction when no measurement is available
    current_estimate_a: float = 0.0
    #: read the phase currents at each edge (the controller's ADC) for the armature correction
    use_measured_current: bool = True
    #: current limit enforced on the duty through the motor model: |d V_dc - 2 ke w| <= 2 R I_max
    current_limit_a: float | None = None
    motor: object | None = None
    #: a commutation predictor (KF or Sage-Husa, ``update(t_corrected, current) -> next instant``);
    #: None = the pre-calibration rule
    predictor: object | None = None
    last_prediction_s: float = float("nan")
    _last_t: float | None = None
    _last_corr_t: float | None = None
    _seen: list[int] = field(default_factory=lambda: [0, 0, 0])
    _edge_index: int = -1
    _first_angle_deg_e: float = 0.0
    _history: list[tuple[float, int, bool, int]] = field(default_factory=list)
    _pole_shift: int | None = None
    _scheduled: dict[int, float] = field(default_factory=dict)
    _last_sector: int = -1
    _index_at_last_sector: int = -1
    speed_estimates_rpm: list[tuple[float, float]] = field(default_factory=list)

    def _sync_poles(self) -> None:
        """Pick the pole alignment whose corrections make one mechanical turn most even."""
        n = 6 * self.pole_pairs
        if self._pole_shift is not None or len(self._history) < 2 * n + 1:
            return
        t, sensor, rising, count, current = (np.array(v) for v in zip(*self._history[-(n + 1):]))
        if self.current_limit_a is not None and np.max(current) > self.current_limit_a:
            # a turn whose edges saw more current than the speed loop's limit is no turn of the
            # motor under control (a start-up's late commutations run to tens of amperes): there the
            # linear armature correction is extrapolated past where it holds (the library's steepest
            # 2 deg e/A reaches the sensors' 30 deg e saturation at 15 A), errs by tens of degrees
            # and outweighs pole offsets a few degrees apart. The reference firmware scored such a
            # turn (edges at tens of amperes) and took the wrong electrical period for good (REQ-ROB-001
            # at --hil-seed 3). The alignment waits for a turn within the limit
            return
        best, best_var = 0, math.inf
        # the edges as corrected for everything the table holds: a real delay left in (133 us on a
        # spindle) makes the sectors far less even than a small pole table does, and so does the
        # armature lag of a start-up's changing current (2 deg e/A at 3-10 A against pole offsets a
        # degree apart from one alignment to the next), and the choice is noise. Then the sector
        # times about their straight line: a speed that changes over the turn (a speed step, or the
        # loop pulled by a fault) is a trend in them, which a once-per-turn pole pattern (a many-pole
        # rotor's eccentricity) resembles
        index = np.arange(n, dtype=float)
        delay_s = np.where(rising, self.corrections.conditioning_delay_s["rise"],
                           self.corrections.conditioning_delay_s["fall"])
        w = 360.0 * self.pole_pairs / (t[-1] - t[0])
        for shift in range(0, 2 * self.pole_pairs, 2):  # whole electrical periods
            pole = (count + shift) % (2 * self.pole_pairs)
            armature = self.corrections.armature_reaction_deg_e_per_a * current
            corr = self.corrections.static_deg_e(sensor, pole) + armature
            sector_s = np.diff(t - corr / w - delay_s)
            var = np.var(sector_s - np.polyval(np.polyfit(index, sector_s, 1), index))
            if var < best_var:
                best, best_var = shift, var
        self._pole_shift = best

    def _duty_bounds(self, speed_rpm: float) -> tuple[float, float]:
        """The duty that keeps the conducting-pair current within the limit (steady-state voltage
        equation: |d V_dc - 2 ke w| <= 2 R I_max), within 0..1."""
        if self.current_limit_a is None or self.motor is None:
            return 0.0, 1.0
        m = self.motor
        bemf = 2.0 * m.ke_v_s_per_rad * rpm_to_rad_per_s(speed_rpm)
        span = 2.0 * m.phase_resistance_ohm * self.current_limit_a
        return max((bemf - span) / m.supply_v, 0.0), min((bemf + span) / m.supply_v, 1.0)

    def resync(self) -> None:
        """Count edges afresh from the next one and learn the pole alignment again (one mechanical
        turn of uncorrected commutation, as at start-up): after edges were lost the count, and with
        it every pole assignment, may be off."""
        self._edge_index = -1
        self._history.clear()
        self._pole_shift = None
        self._scheduled = {}
        self._last_sector = self._index_at_last_sector = -1
        if self.predictor is not None:
            self.predictor.reset()  # its angle counted the lost sectors as one

    def count_lost_edges(self, lost: int) -> None:
        """Edges the controller knows were lost (their time passed without a capture): counted,
        so the edge count, and with it every pole assignment, stays right."""
        self._edge_index += int(lost)

    def on_edge(self, edge: dict, sim=None) -> list[Command]:
        """``edge``: t_capture_s, sensor, rising; now_s (the controller's clock at the interrupt),
        current_a (its ADC's mean |i| at the edge) and cycle_current_a (mean |i| over the cycle
        the edge ends) when available."""
        t = edge["t_capture_s"]
        x = edge["sensor"]
        rising = edge["rising"]
        self._seen[x] = 1 if rising else 0
        self._edge_index += 1
        if self._edge_index == 0:
            self._first_angle_deg_e = SENSOR_POSITION_DEG_E[x] + (0.0 if rising else 180.0)
            if self._last_t is None:
                # start-up: only this sensor's level is known from an edge; the other two follow
                # from which edge it was (the rotor turns forward), so the first commutation is
                # right and not one built from two assumed-low sensors (a sector 60 deg e ahead)
                self._seen = [int(b) for b in hall_state(self._first_angle_deg_e + 30.0)]
        # magnet boundary of this edge, from its place in the edge sequence (forward rotation)
        angle = self._first_angle_deg_e + 60.0 * self._edge_index
        boundary = int(round((angle - SENSOR_POSITION_DEG_E[x]) / 180.0))
        # the current the armature correction reads at this edge, kept for the pole alignment too
        edge_current_a = float(edge.get("current_a", self.current_estimate_a) if self.use_measured_current
                               else self.current_estimate_a)
        self._history.append((t, x, rising, boundary, edge_current_a))
        # two mechanical turns and an edge: the pole alignment compares one whole turn, and the speed
        # that turns corrections into time is measured over one (a fixed 64 edges held only 5 pole pairs)
        keep = 2 * 6 * self.pole_pairs + 2
        if len(self._history) > keep:
            del self._history[:-keep]
        sector = sector_of_levels(self._seen)
        if sector < 0:
            return []
        if sector == self._last_sector:
            # back in the sector of the last valid edge: the edges since were a glitch (a spike
            # through an illegal code, or a bounce), not rotor motion; forget them
            del self._history[len(self._history) - (self._edge_index - self._index_at_last_sector):]
            self._edge_index = self._index_at_last_sector
            return []
        self._last_sector, self._index_at_last_sector = sector, self._edge_index
        commands: list[Command] = []
        t_corr = t
        if self.corrections is not None and self._last_t is not None:
            self._sync_poles()
            # speed to turn the correction angle into time: over the last mechanical turn (the
            # same sensor's same edge one turn back), so no deviation distorts it
            n = 6 * self.pole_pairs
            if len(self._history) > n:
                w_e = 360.0 * self.pole_pairs / max(t - self._history[-n - 1][0], 1e-9)
            else:
                w_e = 60.0 / max(t - self._last_t, 1e-9)
            speed_rpm = deg_e_per_s_to_rpm(w_e, self.pole_pairs)
            if self._pole_shift is not None:
                pole = (boundary + self._pole_shift) % (2 * self.pole_pairs)
                t_corr = t - self.corrections.correction_one_deg_e(x, rising, pole, speed_rpm, edge_current_a) / w_e
            else:
                # the pole alignment is learned over the first turns; until then every correction
                # but the pole's applies, with the poles' mean for it (the installation offset,
                # the delays and above all the armature lag, which left uncorrected grows with
                # the current it causes)
                offsets = self.corrections.pole_offset_deg_e
                static = self.corrections.correction_one_deg_e(x, rising, 0, speed_rpm, edge_current_a) - offsets[0]
                t_corr = t - (static + sum(offsets) / len(offsets)) / w_e
        # speed from the (corrected) sector time, as a simple controller measures it
        duty = None
        if self._last_corr_t is not None and t_corr > self._last_corr_t:
            if self.corrections is not None and self._pole_shift is None:
                # before the pole alignment is known the edges are uncorrected, and one sector's
                # time carries the whole installation, pole and delay deviation (tens of percent
                # at the effect library's bounds); the current limit turns that speed error into
                # a duty far off the back-EMF, hence tens of amperes, which the armature reaction
                # turns into more lag. Whole electrical periods (same sensor, same edge) cancel
                # the installation offsets and delays; until one has passed the duty is kept.
                periods = min(len(self._history) - 1, 6 * self.pole_pairs) // 6
                speed_rpm = (
                    60.0 * periods / self.pole_pairs / (t - self._history[-6 * periods - 1][0]) if periods else 0.0
                )
            else:
                speed_rpm = deg_e_per_s_to_rpm(60.0 / (t_corr - self._last_corr_t), self.pole_pairs)
            if speed_rpm > 0.0:
                self.speed_estimates_rpm.append((t, speed_rpm))
                duty = self.speed.update(speed_rpm, t - self._last_t, *self._duty_bounds(speed_rpm))
        now = edge.get("now_s", t)
        if self.corrections is None or self._last_corr_t is None:
            commands.append(Command(at_s=now, sector=sector, duty=duty))
        else:
            due = self._scheduled.get(sector)
            if due is None or due <= now:
                commands.append(Command(at_s=now, sector=sector, duty=duty))
            elif duty is not None:
                commands.append(Command(at_s=now, duty=duty))
            nxt = (sector + 1) % 6
            # the predictor's K_T is per ampere of the cycle mean (Eq. 8): the edge message's
            # cycle-mean current when the plant sends it, else the current at the edge
            current = edge.get("cycle_current_a")
            if current is None:
                current = edge.get("current_a", self.current_estimate_a)
            predicted = self.predictor.update(t_corr, current) if self.predictor is not None else None
            if predicted is not None and math.isfinite(predicted):
                self.last_prediction_s = predicted
            else:  # pre-calibration: 60 deg electrical after the corrected edge, at the last cycle's speed
                w_e = 60.0 / max(t_corr - self._last_corr_t, 1e-9)
                predicted = t_corr + 60.0 / w_e
                self.last_prediction_s = predicted
            at = max(predicted, now)
            self._scheduled = {nxt: at}
            commands.append(Command(at_s=at, sector=nxt))
        self._last_t, self._last_corr_t = t, t_corr
        return commands
