"""``hil dut profile --from-eds``: a first draft of a CANopen device profile from the device's EDS.

A role is guessed from an object's ParameterName only on a real match of meaning: the name is
the role's own (as ``python -m hil.dut.eds`` writes them), or its words (not substrings: "Max
user temperature" holds no "r", "Lifeguard" no "guard") hold every part of one of the role's
phrases below, and the object's access allows the role's (a set point must be writable, a
read-back readable). Array roles are counted over consecutive sub-indices; types come from the
EDS. Every guess is marked ``# GUESS`` for the user to check: the draft is a start, never a
finished profile. Manufacturer objects no role matches are listed as ``x_`` objects (read by
``hil dut check``, otherwise ignored).
"""

from __future__ import annotations

import re

from .profile import CALIBRATION_ROLES, CANOPEN_DEFAULTS, CANOPEN_TYPE_CODES, ERROR_FIELD, FORMAT, ROLES

_SPEED, _SET = ("speed", "velocity"), ("setpoint", "target", "demand", "reference", "command", "commanded")
#: role -> phrases; a phrase is a tuple of parts, a part a tuple of words any one of which is that part
PHRASES: dict[str, tuple[tuple[tuple[str, ...], ...], ...]] = {
    "strategy": ((("strategy",),), (("commutation",), ("strategy", "predictor"))),
    "speed_setpoint": ((_SPEED, _SET),),
    "speed_actual": ((_SPEED, ("actual", "estimated", "estimate", "measured")),),
    "installation_offset": ((("installation", "mounting"), ("offset", "offsets")),),
    "pole_offset": ((("pole", "poles"), ("offset", "offsets")),),
    "conditioning_delay_rise": ((("rise", "rising"), ("delay",)),),
    "conditioning_delay_fall": ((("fall", "falling"), ("delay",)),),
    "armature_slope": ((("armature",), ("slope", "reaction")),),
    "calibration_apply": ((("apply", "activate"), ("calibration",)),),
    "filter_forgetting": ((("forgetting",),),),
    "filter_q0": ((("q0",),),),
    "filter_r0": ((("r0",),),),
    "filter_p0": ((("p0",),),),
    "filter_q_diag": ((("q",), ("diagonal", "diag")),),
    "filter_r_diag": ((("r",), ("diagonal", "diag")),),
    "guard_trips": ((("guard",), ("trip", "trips")),),
    "gated_edges": ((("gated",), ("edge", "edges")),),
    "covariance_repairs": ((("covariance",), ("repair", "repairs")),),
    "divergence_fades": ((("divergence",), ("fade", "fades")),),
    "band_projections": ((("band",), ("projection", "projections")),),
    "last_predicted_commutation": ((("predicted",), ("commutation",)),),
}
#: words of a record's (or an object's) name that make a calibration role its read-back
_APPLIED = ("applied", "active", "readback")


def words(name: str) -> list[str]:
    """An object name's words: lower case, split at every character that is not a letter or a
    digit and at camelCase; "set point" and "read back" are one word each."""
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", name)
    text = " ".join(re.findall(r"[a-z0-9]+", spaced.lower()))
    return re.sub(r"\bset point\b", "setpoint", re.sub(r"\bread back\b", "readback", text)).split()


def _own_role(name: str) -> str | None:
    """The role an object named as the framework names it holds ("speed_setpoint", "pole_offset[2]")."""
    bare = re.sub(r"\[\d+\]$", "", name.strip())
    return bare if bare in ROLES or bare.startswith("x_") else None


def _guess(name: str, applied: bool) -> str | None:
    own = _own_role(name)
    if own is not None:
        return own
    found = set(words(name))
    for role, phrases in PHRASES.items():
        if any(all(found & set(part) for part in phrase) for phrase in phrases):
            read_back = applied or bool(found & set(_APPLIED))
            return f"calibration_applied_{role}" if read_back and role in CALIBRATION_ROLES else role
    return None


def _access_allows(role: str, access: str) -> bool:
    """The object can do what the role needs (an x_ object: anything readable)."""
    need = ROLES[role].access if role in ROLES else "r"
    return ("r" not in need or access in ("ro", "rw", "rwr", "rww", "const")) and (
        "w" not in need or access in ("rw", "wo", "rwr", "rww")
    )


def draft_from_eds(path: str) -> str:
    import canopen

    from .eds import read_eds

    od = read_eds(path, 1)
    found: dict[str, dict] = {}
    extra: list[dict] = []
    for obj in od.values():
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            variables, parent = [obj], obj.name
        else:
            variables, parent = [v for v in obj.values() if v.subindex > 0], obj.name
        applied = bool(set(words(parent)) & set(_APPLIED))
        for var in variables:
            type_ = CANOPEN_TYPE_CODES.get(var.data_type)
            if type_ is None or var.index < 0x2000 and var.index != ERROR_FIELD:
                continue
            sub = var.subindex if not isinstance(obj, canopen.objectdictionary.ODVariable) else 0
            role = _guess(var.name, applied) if var.index >= 0x2000 else None
            if var.index == ERROR_FIELD:
                role = "fault_code" if sub >= 1 else None
            if role is not None and (role.startswith("x_") or not _access_allows(role, var.access_type)):
                role = None
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
            elif var.index >= 0x2000:  # a second candidate for a role taken: listed, for the user to choose
                extra.append({"name": var.name, "index": var.index, "sub": sub, "type": type_, "also": role})
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
        out += ["", "[objects.fault_count]  # GUESS: the pre-defined error field's count",
                f"index = 0x{ERROR_FIELD:04X}", "subindex = 0", 'type = "uint8"']
        count = getattr(od[ERROR_FIELD], "subindices", {}).get(0)
        if "clear_faults" not in found and count is not None and _access_allows("clear_faults", count.access_type):
            # the same object, as CiA 301 defines it: written with 0, it clears the history
            out += ["", "[objects.clear_faults]  # GUESS: CiA 301 clears the error history on 0 written to 0x1003:00",
                    f"index = 0x{ERROR_FIELD:04X}", "subindex = 0", 'type = "uint8"', "write = 0"]
    for e in extra:
        key = re.sub(r"[^a-z0-9]+", "_", e["name"].lower()).strip("_")[:40] or f"{e['index']:04x}"
        why = f"also matches {e['also']} (taken above)" if "also" in e else "no role guessed"
        out += ["", f"[objects.x_{key}_{e['index']:04x}_{e['sub']}]  # {why}: read by hil dut check only",
                f"index = 0x{e['index']:04X}", f"subindex = {e['sub']}", f'type = "{e["type"]}"']
    out += ["", "[faults]", 'source = ["emcy"]  # GUESS: add "register" if fault_code is right',
            "map = {}  # GUESS: device code -> framework fault (docs/device-profiles.md)", "",
            "[edge_hook]", 'kind = "none"  # GUESS: "pdo" with rx_cob_ids and tx_cob_id if the device takes edges'
            " by PDO", ""]
    return "\n".join(out)
