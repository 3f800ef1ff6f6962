"""The ControllerLink operations in terms of a device profile's roles, for every protocol link.

A protocol link (CANopen, Modbus) gives ``read_raw`` / ``write_raw`` of one profile object; this
class turns roles into the link interface: the framework's values are converted to the device's
raw values (type, scale, offset, unit, enumeration) on the way out and back on the way in, so no
link knows an index or an address.
"""

from __future__ import annotations

from .link import LinkError, verify_calibration
from .profile import (
    CALIBRATION_ROLES,
    COUNTERS,
    FILTER_ROLES,
    ROLES,
    STATUS_ROLES,
    DeviceObject,
    Profile,
    ProfileValueError,
)


class RoleLink:
    """Mixin: ``profile`` (bound), ``where``, ``read_raw(obj)`` and ``write_raw(obj, raws)`` given."""

    profile: Profile
    where: str

    def read_raw(self, obj: DeviceObject) -> list: ...
    def write_raw(self, obj: DeviceObject, raws: list) -> None: ...

    def object(self, role: str) -> DeviceObject:
        obj = self.profile.get(role)
        if obj is None:
            raise LinkError(f"{self.where}: the profile {self.profile.path} maps no {role}")
        return obj

    def read_role(self, role: str) -> list:
        """Every element of ``role`` in its framework unit (an enumeration: the framework's code,
        None for a device value the profile does not name)."""
        obj = self.object(role)
        return [obj.from_raw(r, self.profile.pole_pairs) for r in self.read_raw(obj)]

    def _raws(self, obj: DeviceObject, values) -> list:
        try:
            return [obj.to_raw(v, self.profile.pole_pairs) for v in values]
        except ProfileValueError as exc:
            raise LinkError(f"{self.where}: {exc}") from None

    def write_role(self, role: str, values) -> None:
        obj = self.object(role)
        values = list(values)
        if len(values) != obj.count:
            raise ValueError(f"{role} has {obj.count} element(s), got {len(values)}")
        self.write_raw(obj, self._raws(obj, values))

    def act(self, role: str) -> None:
        """Write an action role's fixed value."""
        obj = self.object(role)
        self.write_raw(obj, [obj.write])

    def quantized(self, role: str, values) -> list[float]:
        """``values`` as the device will hold them: through its raw type and back."""
        obj = self.object(role)
        return [obj.from_raw(obj.unpack_le(obj.pack_le(r)), self.profile.pole_pairs) for r in self._raws(obj, values)]

    # --- ControllerLink ---------------------------------------------------------------------------
    def identity(self) -> dict:
        ident = {
            f"{k}": (self.read_raw(self.object(f"identity_{r}"))[0] if self.profile.has(f"identity_{r}") else None)
            for k, r in (("vendor_id", "vendor"), ("product_code", "product"), ("revision", "revision"),
                         ("serial", "serial"))
        }
        return {**ident, "device_type": None, "firmware": None}

    def reset(self) -> None:
        """Clear the latched faults (when the device has the action), then restart the control logic."""
        if self.profile.has("clear_faults"):
            self.act("clear_faults")
        if self.profile.has("reset"):
            self.act("reset")

    def set_strategy(self, strategy: int) -> None:
        self.write_role("strategy", [int(strategy)])

    def set_speed(self, rpm: float) -> None:
        self.write_role("speed_setpoint", [float(rpm)])

    def set_filter_settings(self, settings) -> None:
        from bldc.contract import filter_vector

        vector, start = filter_vector(settings), 0
        for role in FILTER_ROLES:
            n = self.object(role).count
            self.write_role(role, vector[start : start + n])
            start += n
        self.write_role("strategy", self.read_role("strategy"))  # the filter restarts with its new settings

    def download_calibration(self, corrections) -> None:
        """Stage every calibration role, apply, read back the ones the profile maps (within one raw
        step of each object: a scaled integer holds the table to its resolution)."""
        from ..calibration.corrections import Corrections

        vector, start = corrections.as_vector(), 0
        written, tolerance = [], {"deg_e": 1e-9, "s": 1e-15, "deg_e_per_a": 1e-9}
        units = {"installation_offset": "deg_e", "pole_offset": "deg_e", "conditioning_delay_rise": "s",
                 "conditioning_delay_fall": "s", "armature_slope": "deg_e_per_a"}
        slices = {}
        for role in CALIBRATION_ROLES:
            n = self.object(role).count
            slices[role] = slice(start, start + n)
            part = vector[start : start + n]
            start += n
            q = self.quantized(role, part)
            written += q
            self.write_role(role, part)
            for r in (role, f"calibration_applied_{role}"):
                if self.profile.has(r):
                    u = units[role]
                    tolerance[u] = max(tolerance[u], self.object(r).resolution(self.profile.pole_pairs) * 0.5 + 1e-12)
        self.act("calibration_apply")
        back = list(written)
        for role in CALIBRATION_ROLES:
            if self.profile.has(f"calibration_applied_{role}"):
                back[slices[role]] = self.read_role(f"calibration_applied_{role}")
        table, read_back = Corrections.from_vector(written), Corrections.from_vector(back)
        verify_calibration(table, read_back, tolerance)
        self.applied_calibration = read_back

    def faults(self) -> list[int]:
        """The latched fault codes, newest first, as framework codes (the profile's fault map)."""
        if not self.profile.has("fault_code"):
            return []
        codes = self.read_role("fault_code")
        if self.profile.has("fault_count"):
            codes = codes[: int(self.read_role("fault_count")[0])]
        else:
            codes = [c for c in codes if c]
        return [self.profile.framework_fault(int(c)) for c in codes]

    def status(self) -> dict:
        """What the device reports; a role the profile does not map is None."""

        def get(role, n=None):
            if not self.profile.has(role):
                return None
            v = self.read_role(role)
            return v if n is None else v[0]

        out = {}
        for role, key in STATUS_ROLES.items():  # a one-element reading is a scalar, a count an int
            v = get(role, None if ROLES[role].count != 1 else 0)
            out[key] = int(v) if v is not None and role in COUNTERS else v
        out.update(
            strategy=get("strategy", 0),
            speed_setpoint_rpm=get("speed_setpoint", 0),
            error_register=(int(v) if (v := get("error_register", 0)) is not None else None),
            faults=[(0.0, code) for code in self.faults()],
        )
        return out
