"""The virtual controller seen through the framework's roles: what a face serves under a profile.

Each role reads and writes in its framework unit (hil.dut.profile.ROLES); the faces encode them
into whatever objects or registers the profile gives. Refusals are ``ValueError`` (a
``CalibrationTableError`` for a table the controller refuses): the face answers them with its
protocol's "value out of range" (SDO abort 0x06090030, Modbus exception 03).
"""

from __future__ import annotations

import math

from bldc.contract import filter_vector, with_filter_vector

from ..calibration.corrections import Corrections
from ..controller.virtual import VirtualController
from .profile import CALIBRATION_ROLES, COUNTERS, FILTER_ROLES, ROLES, STATUS_ROLES, STRATEGY_NAMES, Profile

SPEED_RANGE_RPM = (0.0, 30000.0)  #: the set points the virtual controller accepts
HISTORY = 8  #: latched fault codes kept, newest first


def _slices(counts: dict[str, int], order) -> dict[str, slice]:
    out, start = {}, 0
    for role in order:
        out[role] = slice(start, start + counts[role])
        start += counts[role]
    return out


class VirtualRoles:
    """One virtual controller's roles. ``history`` holds the latched fault codes (framework codes)."""

    def __init__(self, controller: VirtualController, profile: Profile):
        self.c, self.profile = controller, profile
        pp = controller.motor.pole_pairs
        counts = {"installation_offset": 3, "pole_offset": 2 * pp, "conditioning_delay_rise": 1,
                  "conditioning_delay_fall": 1, "armature_slope": 1}
        self.cal = _slices(counts, CALIBRATION_ROLES)
        self.filt = _slices({"filter_forgetting": 1, "filter_q0": 3, "filter_r0": 2, "filter_p0": 3}, FILTER_ROLES)
        self.staged = list((controller.corrections or Corrections()).as_float32().as_vector())
        self.history: list[int] = []
        self.heartbeat_ms = 100
        controller.on_fault(self._on_fault)

    def _on_fault(self, code: int, t_s: float) -> None:
        self.history.insert(0, code)
        del self.history[HISTORY:]

    # --- reads ------------------------------------------------------------------------------------
    def read(self, role: str, count: int = 1) -> list:
        """``count`` values of ``role`` in its framework unit (an action, or an x_ object: zeros)."""
        c = self.c
        r = ROLES.get(role)
        if r is None or r.unit == "action":
            return [0] * count
        if role.startswith("identity_"):
            i = c.identity
            return [{"vendor": i.vendor_id, "product": i.product_code, "revision": i.revision,
                     "serial": i.serial}[role.removeprefix("identity_")]]
        if role == "strategy":
            return [int(c.strategy)]
        if role == "speed_setpoint":
            return [c.speed_setpoint_rpm]
        if role in self.cal:
            return self.staged[self.cal[role]]
        if role.startswith("calibration_applied_"):
            applied = (c.corrections or Corrections()).as_vector()
            return list(applied)[self.cal[role.removeprefix("calibration_applied_")]]
        if role in self.filt:
            return filter_vector(c.filter_settings)[self.filt[role]]
        if role == "error_register":
            return [c.error_register]
        if role == "fault_count":
            return [len(self.history)]
        if role == "fault_code":
            return ([self.profile.device_fault(code) for code in self.history] + [0] * count)[:count]
        if role == "heartbeat_period":
            return [self.heartbeat_ms]
        if role in STATUS_ROLES:
            value = c.status()[STATUS_ROLES[role]]
            values = list(value) if isinstance(value, (list, tuple)) else [value]
            # a count stays an integer; a reading the controller does not have yet (NaN) reads 0
            return [int(v) if role in COUNTERS else (v if math.isfinite(v) else 0.0) for v in values]
        raise KeyError(role)

    # --- writes -----------------------------------------------------------------------------------
    def write(self, role: str, values: list) -> None:
        """Write ``role`` (all its elements, framework unit); ValueError refuses the value."""
        c = self.c
        if any(v is None or (isinstance(v, float) and not math.isfinite(v)) for v in values):
            raise ValueError(f"{role}: {values!r} is not a value the device has")
        if role == "strategy":
            if int(values[0]) not in STRATEGY_NAMES.values():
                raise ValueError(f"strategy {values[0]!r}")
            c.set_strategy(int(values[0]))
        elif role == "speed_setpoint":
            lo, hi = SPEED_RANGE_RPM
            if not lo <= float(values[0]) <= hi:
                raise ValueError(f"speed set point {values[0]!r} rpm outside {lo}..{hi}")
            c.set_speed(float(values[0]))
        elif role in self.cal:
            self.staged[self.cal[role]] = [float(v) for v in values]
        elif role in self.filt:
            vector = filter_vector(c.filter_settings)
            vector[self.filt[role]] = [float(v) for v in values]
            # takes effect at the next strategy write or reset, as the filter restarts then
            c.filter_settings = with_filter_vector(c.filter_settings, vector)
        elif role == "heartbeat_period":
            if not 0 <= int(values[0]) <= 0xFFFF:
                raise ValueError(f"heartbeat {values[0]!r} ms")
            self.heartbeat_ms = int(values[0])
        elif role == "calibration_apply":
            c.download_calibration(Corrections.from_vector(self.staged))
        elif role == "reset":  # as NMT reset node: the latched faults go with the restart
            c.clear_faults()
            self.history.clear()
            c.reset()
        elif role == "clear_faults":
            c.clear_faults()
            self.history.clear()
        elif role == "fault_count":  # CiA 301 0x1003 sub 0: writing 0 clears the history, nothing else
            if int(values[0]) != 0:
                raise ValueError(f"fault_count takes 0 (clear the history), got {values[0]!r}")
            self.history.clear()
        else:
            raise ValueError(f"{role} is read-only")
