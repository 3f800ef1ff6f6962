"""Device profiles (``hil-device-profile/1``): a controller's own object dictionary or register map,
as configuration (docs/device-profiles.md has the format for users).

A profile maps each framework role (strategy, set point, calibration, filter settings, read-backs,
faults, ...) to the device's own objects (a CANopen index and sub-index, or a Modbus table and
address) with their type, scale, offset, unit, word order, enumeration or action value; it says
how the device reports faults and where the edge messages go (a mailbox, PDOs, or nowhere). The
messages' layout is the framework's (``bldc.contract``): a profile only says where they go.

Parsing is strict: an unknown key, a wrong type or a missing field is a ``ProfileError`` naming the
file, the table and the key. ``Profile.bind`` then resolves what the parse cannot know on its
own (the motor's pole pairs, CANopen types from an EDS, ``$NODEID`` in COB-IDs).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

from bldc.contract import FAULT_NAMES, FILTER_COUNTERS, GUARD_TRIPS, MAX_CONDITIONING_DELAY_S, STRATEGY_NAMES
from bldc.tomlfile import load_toml

FORMAT = "hil-device-profile/1"
PROFILES_DIR = Path(__file__).with_name("profiles")
#: the profiles of the built-in virtual controller's own maps (shipped as package data)
SHIPPED = {"canopen": PROFILES_DIR / "virtual-canopen.toml", "modbus": PROFILES_DIR / "virtual-modbus.toml"}
#: the framework's edge/command message versions a profile may name (``[edge_hook] layout``);
#: absent means the current one, documented in docs/controller.md
#: the edge and command message versions the framework speaks (hil-edge/1, whose 8-byte edge
#: message carried currents the bench computed, is withdrawn; hil-edge/2 carried a fixed 100 us ADC
#: window whatever the table needed, hil-edge/3 one as long as the controller's table reaches)
EDGE_LAYOUTS = ("hil-edge/3",)

# type -> (struct code, bytes); Modbus packs big-endian bytes in each register, CANopen little-endian
TYPES = {
    "bool": ("?", 1),
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "float32": ("f", 4),
    "float64": ("d", 8),
}
#: types a Modbus register holds (bytes inside a register are big-endian, per the Modbus spec)
MODBUS_TYPES = ("bool", "int16", "uint16", "int32", "uint32", "float32", "float64")
#: CiA 301 data type codes (EDS DataType=) of the types above
CANOPEN_TYPE_CODES = {0x01: "bool", 0x02: "int8", 0x03: "int16", 0x04: "int32", 0x05: "uint8", 0x06: "uint16",
                      0x07: "uint32", 0x08: "float32", 0x11: "float64"}
MODBUS_TABLES = ("holding", "input", "coil", "discrete")

#: unit -> (dimension, factor to the dimension's base unit; a string names a pole-pair rule)
UNITS = {
    "deg_e": ("angle", 1.0),
    "deg_m": ("angle", "pole_pairs"),  # one mechanical degree is pole_pairs electrical degrees
    "rad_e": ("angle", 180.0 / math.pi),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "rpm": ("speed", 1.0),
    "rad_s": ("speed", 60.0 / (2.0 * math.pi)),  # mechanical rad/s
    "hz_e": ("speed", "per_pole_pair"),  # electrical Hz: rpm = hz_e * 60 / pole_pairs
    "deg_e_per_a": ("slope", 1.0),
    "a": ("current", 1.0),
    "ma": ("current", 1e-3),
    "none": ("none", 1.0),
}



@dataclass(frozen=True)
class Role:
    name: str
    unit: str  #: the framework's unit ("enum" for strategy, "action" for a fixed write)
    access: str  #: r, rw or w
    count: int | str = 1  #: an int, "2pp" (two per pole pair) or "n" (any)
    what: str = ""


def _roles() -> dict[str, Role]:
    rows = [
        *(Role(f"identity_{k}", "none", "r", 1, "identity") for k in ("vendor", "product", "revision", "serial")),
        Role("strategy", "enum", "rw", 1, "commutation strategy"),
        Role("speed_setpoint", "rpm", "rw", 1, "speed set point"),
        Role("speed_actual", "rpm", "r", 1, "the controller's speed estimate"),
        Role("installation_offset", "deg_e", "rw", 3, "calibration (staged): sensors A, B, C"),
        Role("pole_offset", "deg_e", "rw", "2pp", "calibration (staged): one per magnet pole"),
        Role("conditioning_delay_rise", "s", "rw", 1, "calibration (staged)"),
        Role("conditioning_delay_fall", "s", "rw", 1, "calibration (staged)"),
        Role("armature_slope", "deg_e_per_a", "rw", 1, "calibration (staged)"),
        Role("calibration_apply", "action", "w", 1, "makes the staged calibration active"),
        Role("reset", "action", "w", 1, "restart the control logic with the present configuration"),
        Role("clear_faults", "action", "w", 1, "clear the latched faults"),
        Role("filter_forgetting", "none", "rw", 1, "filter setting b"),
        Role("filter_q0", "none", "rw", 3, "filter setting Q0 diagonal"),
        Role("filter_r0", "none", "rw", 2, "filter setting R0 diagonal"),
        Role("filter_p0", "none", "rw", 3, "filter setting P0 diagonal"),
        Role("filter_q_diag", "none", "r", 3, "the filter's present Q diagonal"),
        Role("filter_r_diag", "none", "r", 2, "the filter's present R diagonal"),
        *(Role(k, "none", "r", 1, "filter counter") for k in COUNTERS),
        Role("last_predicted_commutation", "s", "r", 1, "the last predicted commutation instant"),
        Role("error_register", "none", "r", 1, "CiA 301 error register bits"),
        Role("fault_count", "none", "r", 1, "number of latched faults"),
        Role("fault_code", "none", "r", "n", "latched fault codes, newest first"),
        Role("heartbeat_period", "ms", "rw", 1, "producer heartbeat time"),
    ]
    for staged in CALIBRATION_ROLES:
        s = next(r for r in rows if r.name == staged)
        rows.append(Role(f"calibration_applied_{staged}", s.unit, "r", s.count, f"read-back of the active {staged}"))
    return {r.name: r for r in rows}


COUNTERS = (GUARD_TRIPS, *FILTER_COUNTERS)
#: the staged calibration roles in the order of ``Corrections.as_vector``
CALIBRATION_ROLES = ("installation_offset", "pole_offset", "conditioning_delay_rise", "conditioning_delay_fall",
                     "armature_slope")
#: the filter-settings roles in the order of ``bldc.contract.filter_vector``
FILTER_ROLES = ("filter_forgetting", "filter_q0", "filter_r0", "filter_p0")
ROLES = _roles()
#: the read-only roles a controller reports in ``status()``, each with its key there (the same in
#: ``VirtualController.status`` and every ``ControllerLink.status``): a new reading is a row of
#: ROLES, an entry here and its object in each profile, and both faces serve it
STATUS_ROLES = {
    "speed_actual": "estimated_speed_rpm",
    "filter_q_diag": "q_diag",
    "filter_r_diag": "r_diag",
    **{counter: counter for counter in COUNTERS},
    "last_predicted_commutation": "last_predicted_commutation_s",
}
#: CiA 301 objects a CANopen role defaults to when the profile does not list it
CANOPEN_DEFAULTS = {
    "identity_vendor": (0x1018, 1, "uint32"),
    "identity_product": (0x1018, 2, "uint32"),
    "identity_revision": (0x1018, 3, "uint32"),
    "identity_serial": (0x1018, 4, "uint32"),
    "error_register": (0x1001, 0, "uint8"),
    "heartbeat_period": (0x1017, 0, "uint16"),
}
#: CiA 301's pre-defined error field: sub 0 the number of errors in the history (written with 0 to
#: clear it), subs 1.. the codes, newest first
ERROR_FIELD = 0x1003
#: roles that are protocol services on CANopen when not listed (NMT reset node: reset application)
CANOPEN_SERVICES = ("reset",)


class ProfileError(ValueError):
    """A profile that cannot be used; the message names the file, the table and the key."""

    def __init__(self, where: str, message: str):
        self.where = where
        super().__init__(f"{where}: {message}")


class ProfileValueError(ValueError):
    """An engineering value the object cannot carry (out of its type's range after scaling)."""


@dataclass(frozen=True)
class DeviceObject:
    """One mapped object (an array role: ``count`` consecutive elements)."""

    role: str
    where: str  #: "file: [objects.ROLE]" for messages
    type: str | None = None
    table: str | None = None  #: Modbus
    address: int | None = None
    index: int | None = None  #: CANopen
    subindex: int = 0
    scale: float = 1.0
    offset: float = 0.0
    unit: str = "none"
    count: int = 1
    word_order: str = "big"
    values: dict | None = None  #: enumeration: framework name -> device value
    write: int | float | None = None  #: action: the fixed value written
    default: bool = False  #: a CiA 301 default, not listed in the file

    # --- where ------------------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Bytes of one element."""
        return TYPES[self.type][1]

    @property
    def registers(self) -> int:
        """Modbus registers (or bits, for coils and discrete inputs) of one element."""
        return 1 if self.table in ("coil", "discrete") or self.type == "bool" else max(1, self.size // 2)

    def address_of(self, k: int = 0) -> int:
        return self.address + k * self.registers

    @property
    def end(self) -> int:
        """The first Modbus address after the object."""
        return self.address + self.count * self.registers

    def subindex_of(self, k: int = 0) -> int:
        return self.subindex + k

    def label(self, k: int = 0) -> str:
        if self.index is not None:
            return f"0x{self.index:04X}:{self.subindex_of(k):02X}"
        return f"{self.table} {self.address_of(k)}"

    @property
    def readable(self) -> bool:
        return ROLES[self.role].access != "w" if self.role in ROLES else True

    @property
    def is_action(self) -> bool:
        return self.write is not None

    def cells(self) -> tuple:
        """The registers (table, address) or sub-indices (index, sub-index) the object takes."""
        if self.index is None:
            return tuple((self.table, a) for a in range(self.address, self.end))
        return tuple((self.index, self.subindex_of(k)) for k in range(self.count))

    # --- values -----------------------------------------------------------------------------------
    def _unit_factor(self, unit: str, pole_pairs: int) -> float:
        f = UNITS[unit][1]
        if f == "pole_pairs":
            return float(pole_pairs)
        if f == "per_pole_pair":
            return 60.0 / pole_pairs
        return f

    def to_raw(self, value, pole_pairs: int = 2, saturate: bool = False):
        """The device's raw value of one element given in the role's framework unit; out of the
        type's range it is refused, or with ``saturate`` held at the nearest end (what a device
        does with a reading it cannot represent)."""
        if self.values is not None:
            names = {v: k for k, v in STRATEGY_NAMES.items()}
            name = names.get(int(value))
            if name not in self.values:
                raise ProfileValueError(f"{self.where}: the device has no value for {name or value!r}")
            return self.values[name]
        role_unit = ROLES[self.role].unit if self.role in ROLES else "none"
        base = float(value) * (self._unit_factor(role_unit, pole_pairs) if role_unit in UNITS else 1.0)
        u = base / self._unit_factor(self.unit, pole_pairs)
        raw = (u - self.offset) / self.scale
        if self.type in ("float32", "float64"):
            return raw
        if self.type == "bool":
            return bool(round(raw))
        if not math.isfinite(raw):
            raise ProfileValueError(f"{self.where}: {value!r} is not a finite number")
        r = int(round(raw))
        lo, hi = int_range(self.type)
        if saturate:
            return min(max(r, lo), hi)
        if not lo <= r <= hi:
            raise ProfileValueError(f"{self.where}: {value!r} is raw {r}, outside {self.type} ({lo}..{hi})")
        return r

    def from_raw(self, raw, pole_pairs: int = 2):
        """One element's value in the role's framework unit (an enumeration: the framework's code)."""
        if self.values is not None:
            names = {v: k for k, v in self.values.items()}
            name = names.get(int(raw))
            return int(STRATEGY_NAMES[name]) if name is not None else None
        if self.type not in ("float32", "float64") and (self.scale, self.offset, self.unit) == (1.0, 0.0, "none"):
            return int(raw)  # a count, a code, an identity: an integer stays one
        u = float(raw) * self.scale + self.offset
        role_unit = ROLES[self.role].unit if self.role in ROLES else "none"
        v = u * self._unit_factor(self.unit, pole_pairs)
        return v / self._unit_factor(role_unit, pole_pairs) if role_unit in UNITS else v

    def resolution(self, pole_pairs: int = 2) -> float:
        """One raw step in the framework unit (0 for floating-point types)."""
        if self.type in ("float32", "float64") or self.values is not None:
            return 0.0
        return abs(self.from_raw(1, pole_pairs) - self.from_raw(0, pole_pairs))

    # --- bytes and registers ------------------------------------------------------------------------
    def pack_le(self, raw) -> bytes:
        """CANopen: little-endian bytes of one element."""
        return struct.pack("<" + TYPES[self.type][0], raw)

    def unpack_le(self, data: bytes):
        n = self.size
        if len(data) < n:
            raise ProfileValueError(f"{self.where}: {len(data)} bytes for a {self.type}")
        return struct.unpack("<" + TYPES[self.type][0], bytes(data[:n]))[0]

    def to_registers(self, raw) -> list[int]:
        """Modbus: one element's registers (bytes big-endian inside each, words in ``word_order``)."""
        if self.table in ("coil", "discrete"):
            return [int(bool(raw))]
        if self.type == "bool":
            return [int(bool(raw))]
        data = struct.pack(">" + TYPES[self.type][0], raw)
        words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
        return words[::-1] if self.word_order == "little" else words

    def from_registers(self, regs) -> float | int:
        if self.table in ("coil", "discrete") or self.type == "bool":
            return bool(regs[0])
        words = list(regs)[: self.registers]
        if self.word_order == "little":
            words = words[::-1]
        return struct.unpack(">" + TYPES[self.type][0], b"".join(w.to_bytes(2, "big") for w in words))[0]


def int_range(type_: str) -> tuple[int, int]:
    bits = TYPES[type_][1] * 8
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if type_.startswith("int") else (0, (1 << bits) - 1)


@dataclass(frozen=True)
class EdgeHook:
    kind: str  #: mailbox, pdo or none
    request_address: int | None = None
    reply_address: int | None = None
    rx_cob_ids: tuple = ()  #: ints or "$NODEID+0x..." strings until bound
    tx_cob_id: int | str | None = None
    layout: str = EDGE_LAYOUTS[-1]
    #: how far before a capture the device reads its ADC (its calibration table's delay bound),
    #: when it says so; None: as far as the largest delay of the table the framework downloaded
    adc_reach_s: float | None = None


@dataclass(frozen=True)
class Profile:
    path: str
    name: str
    protocol: str
    objects: dict[str, DeviceObject]  #: role (or x_NAME) -> object
    fault_sources: tuple[str, ...] = ()
    fault_map: dict[int, int] = field(default_factory=dict)  #: device code -> framework Fault code
    edge_hook: EdgeHook = EdgeHook("none")
    word_order: str = "big"
    pole_pairs: int | None = None  #: set by bind

    def has(self, role: str) -> bool:
        return role in self.objects or (self.protocol == "canopen" and role in CANOPEN_SERVICES)

    def get(self, role: str) -> DeviceObject | None:
        return self.objects.get(role)

    def cell_map(self) -> tuple[dict, dict]:
        """Each register (table, address) or sub-index (index, sub-index) -> (object, the cell's
        position in its ``cells()``), as read and as written: one object, except where a role only
        read and an action share one (CiA 301's 0x1003:00: the number of errors, and 0 written
        clears them), which is read as the role and written as the action."""
        reads, writes = {}, {}
        for o in self.objects.values():
            for i, cell in enumerate(o.cells()):
                (writes if o.is_action else reads)[cell] = (o, i)
                (reads if o.is_action else writes).setdefault(cell, (o, i))
        return reads, writes

    def action_on(self, obj: DeviceObject) -> DeviceObject | None:
        """The action that shares ``obj``'s object, if one does (a write of the object is that
        action: CiA 301's 0x1003:00, read as fault_count, written with 0 as clear_faults)."""
        return next((o for o in self.objects.values() if o.is_action and o is not obj and o.cells() == obj.cells()),
                    None)

    def framework_fault(self, device_code: int) -> int:
        """The framework's fault code of a device code (an unmapped code is kept as the device gives it)."""
        return self.fault_map.get(int(device_code), int(device_code))

    def device_fault(self, framework_code: int) -> int:
        """The device's code of a framework fault (the virtual controller served under this profile)."""
        inverse = {v: k for k, v in self.fault_map.items()}
        return inverse.get(int(framework_code), int(framework_code))

    def bind(self, pole_pairs: int | None = None, node_id: int | None = None, eds=None) -> "Profile":
        """The profile resolved for one device: array counts checked against the motor, CANopen
        types from the device's EDS (``eds``: its dictionary, ``hil.dut.eds.read_eds``) where the
        profile leaves them out, ``$NODEID`` in COB-IDs replaced."""
        objects = dict(self.objects)
        od = eds if self.protocol == "canopen" else None
        for role, obj in objects.items():
            if self.protocol == "canopen":
                from_eds = _eds_type(od, obj) if od is not None else None
                if obj.type is None and from_eds is None:
                    raise ProfileError(
                        f"{obj.where}.type",
                        "required (no EDS given" + (")" if od is None else f" holds no typed object {obj.label()})"),
                    )
                if obj.type is not None and from_eds is not None and from_eds != obj.type and not obj.default:
                    raise ProfileError(f"{obj.where}.type", f"{obj.type!r}, but the EDS says {from_eds!r}")
                if obj.type is None or (obj.default and from_eds is not None):
                    objects[role] = obj = replace(obj, type=from_eds)
            if pole_pairs is not None and role in ROLES and ROLES[role].count == "2pp" and obj.count != 2 * pole_pairs:
                raise ProfileError(
                    f"{obj.where}.count",
                    f"{obj.count}, but the motor has {pole_pairs} pole pairs ({2 * pole_pairs} pole offsets)",
                )
        hook = self.edge_hook
        if hook.kind == "pdo":
            hook = replace(
                hook,
                rx_cob_ids=tuple(cob_id(c, node_id, self.path) for c in hook.rx_cob_ids),
                tx_cob_id=cob_id(hook.tx_cob_id, node_id, self.path),
            )
        return replace(self, objects=objects, edge_hook=hook, pole_pairs=pole_pairs)


def cob_id(value, node_id: int | None, where: str) -> int:
    """A COB-ID: an int, or ``"$NODEID+0x200"`` as in an EDS."""
    if isinstance(value, int):
        return value
    text = str(value).replace(" ", "")
    if text.upper().startswith("$NODEID+"):
        if node_id is None:
            raise ProfileError(f"{where}: [edge_hook]", f"{value!r} needs the node id")
        return node_id + int(text[8:], 0)
    return int(text, 0)


def _eds_type(od, obj: DeviceObject) -> str | None:
    import canopen

    if obj.index not in od:
        return None
    o = od[obj.index]
    var = o if isinstance(o, canopen.objectdictionary.ODVariable) else o.subindices.get(obj.subindex)
    return CANOPEN_TYPE_CODES.get(var.data_type) if var is not None else None


# --- parsing ----------------------------------------------------------------------------------------
_TOP = {"format", "name", "protocol", "modbus", "objects", "faults", "edge_hook"}
_OBJECT_KEYS = {"table", "address", "index", "subindex", "type", "scale", "offset", "unit", "count", "word_order",
                "values", "write"}
_HOOK_KEYS = {"kind", "request_address", "reply_address", "layout", "rx_cob_ids", "tx_cob_id", "adc_reach_s"}


def _int(v, where: str, lo: int = 0, hi: int = 0xFFFF) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ProfileError(where, f"must be an integer {lo}..{hi}, got {v!r}")
    return v


def _num(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ProfileError(where, f"must be a finite number, got {v!r}")
    return float(v)


def _choice(v, where: str, choices) -> str:
    if v not in choices:
        raise ProfileError(where, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
    return v


def load_profile(path: str | Path) -> Profile:
    """Parse a profile file strictly: ``ProfileError`` (``TomlError`` for the file itself) names file, table and key."""
    return parse_profile(load_toml(path), str(path))  # parse_profile checks every key


def parse_profile(data: dict, where: str) -> Profile:
    for key in data:
        if key not in _TOP:
            raise ProfileError(f"{where}: {key}", f"unknown top-level key (known: {', '.join(sorted(_TOP))})")
    if data.get("format") != FORMAT:
        raise ProfileError(f"{where}: format", f"must be {FORMAT!r}, got {data.get('format')!r}")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ProfileError(f"{where}: name", "required: a non-empty string")
    protocol = _choice(data.get("protocol"), f"{where}: protocol", ("modbus", "canopen"))
    word_order = "big"
    if "modbus" in data:
        if protocol != "modbus":
            raise ProfileError(f"{where}: [modbus]", "only a Modbus profile has a [modbus] table")
        m = _table(data["modbus"], f"{where}: [modbus]")
        for key in m:
            if key != "word_order":
                raise ProfileError(f"{where}: [modbus].{key}", "unknown key (known: word_order)")
        word_order = _choice(m.get("word_order", "big"), f"{where}: [modbus].word_order", ("big", "little"))
    objects_table = _table(data.get("objects", {}), f"{where}: [objects]")
    objects = {}
    for role, table in objects_table.items():
        objects[role] = _object(role, table, f"{where}: [objects.{role}]", protocol, word_order)
    if protocol == "canopen":
        for role, (index, sub, type_) in CANOPEN_DEFAULTS.items():
            if role not in objects:
                objects[role] = DeviceObject(role, f"{where}: CiA 301 default of {role}", type_, index=index,
                                             subindex=sub, unit="ms" if role == "heartbeat_period" else "none",
                                             default=True)
    _check_overlaps(objects, where)
    sources, fault_map = _faults(data.get("faults"), f"{where}: [faults]", protocol, objects)
    hook = _edge_hook(data.get("edge_hook", {"kind": "none"}), f"{where}: [edge_hook]", protocol)
    if hook.kind == "mailbox":
        _check_mailbox(hook, objects, f"{where}: [edge_hook]")
    return Profile(where, name.strip(), protocol, objects, sources, fault_map, hook, word_order)


def _table(v, where: str) -> dict:
    if not isinstance(v, dict):
        raise ProfileError(where, f"must be a table, got {type(v).__name__}")
    return v


def _object(role: str, table, where: str, protocol: str, word_order: str) -> DeviceObject:
    table = _table(table, where)
    if role not in ROLES and not role.startswith("x_"):
        raise ProfileError(where, f"unknown role {role!r} (a device's own object is named x_NAME; roles: "
                           f"{', '.join(ROLES)})")
    for key in table:
        if key not in _OBJECT_KEYS:
            raise ProfileError(f"{where}.{key}", f"unknown key (known: {', '.join(sorted(_OBJECT_KEYS))})")
    r = ROLES.get(role)
    kw: dict = {}
    if protocol == "modbus":
        for key in ("index", "subindex"):
            if key in table:
                raise ProfileError(f"{where}.{key}", "a Modbus object has a table and an address, not an index")
        kw["table"] = _choice(table.get("table"), f"{where}.table", MODBUS_TABLES)
        if "address" not in table:
            raise ProfileError(f"{where}.address", "required")
        kw["address"] = _int(table["address"], f"{where}.address")
        kw["word_order"] = _choice(table.get("word_order", word_order), f"{where}.word_order", ("big", "little"))
        if r is not None and "w" in r.access and kw["table"] in ("input", "discrete"):
            raise ProfileError(f"{where}.table", f"{role} is written, and a {kw['table']} table is read-only")
    else:
        for key in ("table", "address", "word_order"):
            if key in table:
                raise ProfileError(f"{where}.{key}", "a CANopen object has an index and a sub-index")
        if "index" not in table:
            raise ProfileError(f"{where}.index", "required")
        kw["index"] = _int(table["index"], f"{where}.index", 0x1000, 0xFFFF)
        kw["subindex"] = _int(table.get("subindex", 0), f"{where}.subindex", 0, 0xFF)
    if "type" in table:
        choices = MODBUS_TYPES if protocol == "modbus" else tuple(TYPES)
        kw["type"] = _choice(table["type"], f"{where}.type", choices)
    elif protocol == "modbus":
        raise ProfileError(f"{where}.type", "required")
    if kw.get("table") in ("coil", "discrete") and kw.get("type", "bool") != "bool":
        raise ProfileError(f"{where}.type", f"a {kw['table']} holds a bool, got {kw['type']!r}")
    kw["scale"] = _num(table.get("scale", 1.0), f"{where}.scale")
    if kw["scale"] == 0:
        raise ProfileError(f"{where}.scale", "must not be 0")
    kw["offset"] = _num(table.get("offset", 0.0), f"{where}.offset")
    unit = _choice(table.get("unit", r.unit if r and r.unit in UNITS else "none"), f"{where}.unit", tuple(UNITS))
    if r is not None and r.unit in UNITS and UNITS[unit][0] != UNITS[r.unit][0]:
        raise ProfileError(f"{where}.unit", f"{unit!r} does not measure what {role} is ({r.unit})")
    kw["unit"] = unit
    count = _int(table.get("count", 1), f"{where}.count", 1, 255)
    if r is not None and isinstance(r.count, int) and count != r.count:
        raise ProfileError(f"{where}.count", f"{role} has {r.count} element(s), got {count}")
    kw["count"] = count
    if "values" in table:
        if role != "strategy":
            raise ProfileError(f"{where}.values", "only the strategy role is an enumeration")
        values = _table(table["values"], f"{where}.values")
        for k, v in values.items():
            _choice(k, f"{where}.values.{k}", tuple(STRATEGY_NAMES))
            _int(v, f"{where}.values.{k}", -(1 << 31), (1 << 32) - 1)
        if len(set(values.values())) != len(values):
            raise ProfileError(f"{where}.values", "two names share one device value")
        kw["values"] = dict(values)
    elif role == "strategy":
        raise ProfileError(f"{where}.values", "required: the device's value of each strategy it has")
    if "write" in table:
        if r is not None and r.unit != "action":
            raise ProfileError(f"{where}.write", f"{role} is not an action")
        w = table["write"]
        if isinstance(w, bool):  # a coil's action: write = true
            w = int(w)
        kw["write"] = _int(w, f"{where}.write", -(1 << 31), (1 << 32) - 1) if not isinstance(w, float) else w
    elif r is not None and r.unit == "action":
        raise ProfileError(f"{where}.write", f"required: {role} is an action (the value written)")
    return DeviceObject(role, where, **kw)


def _kind(o: DeviceObject) -> str:
    """What a role does with its object: "read" (only read; a device's own x_ object too), "action"
    (a fixed value written) or "read-write"."""
    if o.is_action:
        return "action"
    return "read" if o.role not in ROLES or ROLES[o.role].access == "r" else "read-write"


def _check_overlaps(objects: dict[str, DeviceObject], where: str) -> None:
    """Two roles on one register (or one sub-index) are a typo in a map, never intended, except
    a role only read and an action on the very same object, where the device's standard or manual
    gives the object a meaning each way: CiA 301's 0x1003:00 is read for the number of errors in
    the history and written with 0 to clear it. Two read roles, or two written ones (an action,
    a read-write role), on one object stay refused."""
    seen: dict = {}
    for o in objects.values():
        if o.is_action and (o.index, o.subindex) == (ERROR_FIELD, 0) and (o.role, o.write) != ("clear_faults", 0):
            raise ProfileError(o.where, "CiA 301's 0x1003:00 is written with 0 to clear the error history: only "
                                        "clear_faults with write = 0 goes there")
        for key in o.cells():
            prev = seen.setdefault(key, o)
            if prev is o:
                continue
            kinds = {_kind(prev), _kind(o)}
            here = f"{o.label()} overlaps [objects.{prev.role}]"
            if kinds != {"read", "action"}:
                what = "written" if "action" in kinds else "read"
                raise ProfileError(o.where, f"{here}: two {what} roles on one object (only a role that is only read "
                                            f"and an action may share one, as CiA 301's 0x1003:00)")
            if o.cells() != prev.cells() or o.type != prev.type and None not in (o.type, prev.type):
                raise ProfileError(o.where, f"{here}, and a role and an action share an object only whole: the same "
                                            f"{'index, sub-index' if o.index is not None else 'table, address'}, "
                                            f"type and count")


#: the framework's mailbox (hil-edge/2, docs/controller.md): the edge message's header takes the
#: first EDGE_HEADER_WORDS registers at the request address; the reply is a frame count and four
#: command messages at the reply address. The message's rest (accumulators and ADC window, up to
#: 163 registers) follows the header as far as the mailbox has room, and is written ahead of it in
#: parts where it has not (hil.dut.modbus_device), so a profile that leaves little room still works.
EDGE_HEADER_WORDS, REPLY_WORDS = 4, 17
#: the most registers one write of the header and the rest takes (read/write multiple registers)
MAILBOX_MAX_WORDS = 121
#: the least room a mailbox must have: the header and one register of the rest
MAILBOX_MIN_WORDS = EDGE_HEADER_WORDS + 1


def mailbox_words(profile) -> int:
    """The registers of the request block: from the request address up to the next register taken
    (the reply block or a mapped holding register), at most MAILBOX_MAX_WORDS."""
    return _request_room(profile.edge_hook, profile.objects)


def _request_room(hook: EdgeHook, objects: dict[str, DeviceObject]) -> int:
    start = hook.request_address
    taken = [hook.reply_address] if hook.reply_address >= start else []
    taken += [o.address for o in objects.values() if o.table == "holding" and o.address >= start]
    # a mapped register inside the request block's first registers starts before it: _check_mailbox
    return min([MAILBOX_MAX_WORDS, 0x10000 - start] + [a - start for a in taken])


def _check_mailbox(hook: EdgeHook, objects: dict[str, DeviceObject], where: str) -> None:
    """The request block needs room for the header and some of the rest; the reply block must not
    overlap it or a mapped holding register."""
    room = _request_room(hook, objects)
    if room < MAILBOX_MIN_WORDS:
        raise ProfileError(
            f"{where}.request_address",
            f"the mailbox has room for {max(room, 0)} registers before the next register taken; the edge "
            f"message needs at least {MAILBOX_MIN_WORDS}",
        )
    reply = range(hook.reply_address, hook.reply_address + REPLY_WORDS)
    if hook.request_address in reply:
        raise ProfileError(f"{where}.reply_address", "the reply block overlaps the request block")
    for o in objects.values():
        if o.table == "holding" and o.address < reply.stop and reply.start < o.end:
            raise ProfileError(f"{where}.reply_address", f"the mailbox ({REPLY_WORDS} registers) overlaps {o.where}")
        if o.table == "holding" and o.address < hook.request_address < o.end:
            raise ProfileError(f"{where}.request_address", f"the mailbox starts inside {o.where}")
    if reply.stop > 0x10000:
        raise ProfileError(f"{where}.reply_address", f"the mailbox ({REPLY_WORDS} registers) runs past register 65535")


def _faults(table, where: str, protocol: str, objects) -> tuple[tuple[str, ...], dict[int, int]]:
    if table is None:
        return (("emcy",) if protocol == "canopen" else ()), {}
    table = _table(table, where)
    for key in table:
        if key not in ("source", "map"):
            raise ProfileError(f"{where}.{key}", "unknown key (known: map, source)")
    sources = table.get("source", [])
    if isinstance(sources, str):
        sources = [sources]
    if not isinstance(sources, list):
        raise ProfileError(f"{where}.source", f"must be a list, got {sources!r}")
    for s in sources:
        _choice(s, f"{where}.source", ("emcy", "register"))
    if "emcy" in sources and protocol != "canopen":
        raise ProfileError(f"{where}.source", "EMCY is a CANopen service; a Modbus device reports by register")
    if "register" in sources and "fault_code" not in objects:
        raise ProfileError(f"{where}.source", "'register' needs the fault_code role in [objects]")
    fault_map = {}
    for code, name in _table(table.get("map", {}), f"{where}.map").items():
        try:
            device = int(str(code), 0)
        except ValueError:
            raise ProfileError(f"{where}.map.{code}", "a key is a device code (0x3101 or 12545)") from None
        fault_map[device] = FAULT_NAMES[_choice(name, f"{where}.map.{code}", tuple(FAULT_NAMES))]
    return tuple(sources), fault_map


def _edge_hook(table, where: str, protocol: str) -> EdgeHook:
    table = _table(table, where)
    for key in table:
        if key not in _HOOK_KEYS:
            raise ProfileError(f"{where}.{key}", f"unknown key (known: {', '.join(sorted(_HOOK_KEYS))})")
    kind = _choice(table.get("kind"), f"{where}.kind", ("mailbox", "pdo", "none"))
    layout = _choice(table.get("layout", EDGE_LAYOUTS[-1]), f"{where}.layout", EDGE_LAYOUTS)
    reach = _adc_reach(table.get("adc_reach_s"), f"{where}.adc_reach_s")
    if kind == "none":
        extra = set(table) - {"kind"}
        if extra:
            raise ProfileError(f"{where}.{sorted(extra)[0]}", "kind = 'none' takes no other key")
        return EdgeHook("none")
    if kind == "mailbox":
        if protocol != "modbus":
            raise ProfileError(f"{where}.kind", "a mailbox is a Modbus register block; a CANopen device takes PDOs")
        for key in ("rx_cob_ids", "tx_cob_id"):
            if key in table:
                raise ProfileError(f"{where}.{key}", "a mailbox has request_address and reply_address")
        req = _int(table.get("request_address"), f"{where}.request_address")
        rep = _int(table.get("reply_address"), f"{where}.reply_address")
        return EdgeHook("mailbox", req, rep, layout=layout, adc_reach_s=reach)
    if protocol != "canopen":
        raise ProfileError(f"{where}.kind", "PDOs are CANopen; a Modbus device takes a mailbox")
    for key in ("request_address", "reply_address"):
        if key in table:
            raise ProfileError(f"{where}.{key}", "PDOs have rx_cob_ids and tx_cob_id")
    rx = table.get("rx_cob_ids")
    if not isinstance(rx, list) or not rx:
        raise ProfileError(f"{where}.rx_cob_ids", "required: a list of COB-IDs (an int or \"$NODEID+0x200\")")
    for k, c in enumerate([*rx, table.get("tx_cob_id")]):
        key = f"rx_cob_ids[{k}]" if k < len(rx) else "tx_cob_id"
        try:
            cob_id(c, 1, where) if c is not None else None
        except (ValueError, TypeError):
            raise ProfileError(f"{where}.{key}", f"not a COB-ID: {c!r}") from None
    if table.get("tx_cob_id") is None:
        raise ProfileError(f"{where}.tx_cob_id", "required")
    return EdgeHook("pdo", rx_cob_ids=tuple(rx), tx_cob_id=table["tx_cob_id"], layout=layout, adc_reach_s=reach)


def _adc_reach(value, where: str) -> float | None:
    """``[edge_hook] adc_reach_s``: seconds, 0 to the edge message's bound (bldc.contract)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_CONDITIONING_DELAY_S:
        raise ProfileError(where, f"seconds within [0, {MAX_CONDITIONING_DELAY_S:g}] (the edge message's ADC window "
                                  f"bound, docs/controller.md), got {value!r}")
    return float(value)


def shipped(protocol: str) -> Profile:
    """The built-in virtual controller's own map for ``protocol`` (canopen or modbus)."""
    return load_profile(SHIPPED[protocol])


def bound_profile(protocol: str, profile: "Profile | str | Path | None", pole_pairs: int, node_id: int | None = None,
                  eds=None) -> Profile:
    """A ``protocol`` profile bound for one device (default: the virtual controller's own map);
    a profile of the other protocol is a ``ProfileError``."""
    if profile is None or isinstance(profile, (str, Path)):
        profile = load_profile(profile) if profile is not None else shipped(protocol)
    if profile.protocol != protocol:
        raise ProfileError(profile.path, f"a {profile.protocol} profile on a {PROTOCOL_NAMES[protocol]} device")
    return profile.bind(pole_pairs, node_id, eds)


PROTOCOL_NAMES = {"canopen": "CANopen", "modbus": "Modbus"}
