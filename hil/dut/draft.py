"""``hil dut profile --from-eds``: a first draft of a CANopen device profile from the device's EDS.

Roles are guessed from each object's ParameterName (keywords below) and counted over consecutive
sub-indices; types come from the EDS. Every guess is marked ``# GUESS`` for the user to check:
the draft is a start, never a finished profile. Manufacturer objects no keyword matches are
listed as ``x_`` objects (read by ``hil dut check``, otherwise ignored).
"""

from __future__ import annotations

import re

from .profile import CANOPEN_DEFAULTS, CANOPEN_TYPE_CODES, FORMAT, ROLES

#: (role, words all present in the lower-case name, words none of which may be present)
KEYWORDS = [
    ("strategy", ("strategy",), ()),
    ("speed_setpoint", ("speed",), ("actual", "estimat", "measur")),
    ("speed_actual", ("speed",), ()),
    ("installation_offset", ("install",), ()),
    ("pole_offset", ("pole",), ()),
    ("conditioning_delay_rise", ("rise",), ()),
    ("conditioning_delay_fall", ("fall",), ()),
    ("armature_slope", ("armature",), ()),
    ("calibration_apply", ("apply",), ()),
    ("filter_forgetting", ("forgetting",), ()),
    ("filter_q0", ("q0",), ()),
    ("filter_r0", ("r0",), ()),
    ("filter_p0", ("p0",), ()),
    ("guard_trips", ("guard",), ()),
    ("gated_edges", ("gated",), ()),
    ("covariance_repairs", ("covariance",), ()),
    ("divergence_fades", ("divergence",), ()),
    ("band_projections", ("band",), ()),
    ("last_predicted_commutation", ("predicted",), ()),
    ("filter_q_diag", ("q ",), ()),
    ("filter_r_diag", ("r ",), ()),
]


def _guess(name: str, applied: bool) -> str | None:
    low = f"{name.lower()} "
    for role, words, never in KEYWORDS:
        if all(w in low for w in words) and not any(w in low for w in never):
            calibration = role in ("installation_offset", "pole_offset", "conditioning_delay_rise",
                                   "conditioning_delay_fall", "armature_slope")
            return f"calibration_applied_{role}" if applied and calibration else role
    return None


def draft_from_eds(path: str) -> str:
    import canopen

    od = canopen.import_od(str(path), 1)
    found: dict[str, dict] = {}
    extra: list[dict] = []
    for obj in od.values():
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            variables, parent = [obj], obj.name
        else:
            variables, parent = [v for v in obj.values() if v.subindex > 0], obj.name
        applied = bool(re.search(r"applied|active|read.?back", parent, re.I))
        for var in variables:
            type_ = CANOPEN_TYPE_CODES.get(var.data_type)
            if type_ is None or var.index < 0x2000 and var.index != 0x1003:
                continue
            sub = var.subindex if not isinstance(obj, canopen.objectdictionary.ODVariable) else 0
            role = _guess(var.name, applied) if var.index >= 0x2000 else None
            if var.index == 0x1003:
                role = "fault_code" if sub >= 1 else None
            if role is None:
                if var.index >= 0x2000:
                    extra.append({"name": var.name, "index": var.index, "sub": sub, "type": type_})
                continue
            entry = found.get(role)
            if entry is not None and entry["index"] == var.index and entry["sub"] + entry["count"] == sub:
                entry["count"] += 1  # the next sub-index of an array role
            elif entry is None:
                found[role] = {"name": var.name, "index": var.index, "sub": sub, "type": type_, "count": 1,
                               "access": var.access_type}
    out = [
        f"# Drafted by `hil dut profile --from-eds {path}`: every line marked GUESS was guessed",
        "# from an object's name; check each against the device's manual before you rely on it.",
        f'format = "{FORMAT}"',
        f'name = "{od.device_information.product_name or "my controller"} (draft)"',
        'protocol = "canopen"',
        "",
        "# identity (0x1018), error register (0x1001), heartbeat (0x1017) and reset (NMT) default to CiA 301",
    ]
    for role, e in found.items():
        if role in CANOPEN_DEFAULTS:
            continue
        out += ["", f"[objects.{role}]  # GUESS from {e['name']!r}", f"index = 0x{e['index']:04X}"]
        if e["sub"]:
            out.append(f"subindex = {e['sub']}")
        out.append(f'type = "{e["type"]}"')
        unit = ROLES[role].unit
        if unit not in ("enum", "action", "none"):
            out.append(f'unit = "{unit}"  # GUESS: the framework\'s unit; scale and offset 1, 0')
        if e["count"] > 1:
            out.append(f"count = {e['count']}")
        if role == "strategy":
            out.append("values = { raw = 0, corrected = 1, kf = 2, sage_husa = 3 }  # GUESS: the device's numbers")
        if unit == "action":
            out.append("write = 1  # GUESS: the value that triggers it")
    if "fault_code" in found:
        out += ["", "[objects.fault_count]  # GUESS: the pre-defined error field's count", "index = 0x1003",
                "subindex = 0", 'type = "uint8"']
    for e in extra:
        key = re.sub(r"[^a-z0-9]+", "_", e["name"].lower()).strip("_")[:40] or f"{e['index']:04x}"
        out += ["", f"[objects.x_{key}_{e['index']:04x}_{e['sub']}]  # no role guessed: read by hil dut check only",
                f"index = 0x{e['index']:04X}", f"subindex = {e['sub']}", f'type = "{e["type"]}"']
    out += ["", "[faults]", 'source = ["emcy"]  # GUESS: add "register" if fault_code is right',
            "map = {}  # GUESS: device code -> framework fault (docs/device-profiles.md)", "",
            "[edge_hook]", 'kind = "none"  # GUESS: "pdo" with rx_cob_ids and tx_cob_id if the device takes edges'
            " by PDO", ""]
    return "\n".join(out)
