"""CANopen EDS files (CiA 306): the object dictionary a device profile describes, written as an EDS,
and EDS files read as real tools write them.

The profile is the single source of a CANopen map: ``object_dictionary`` builds the dictionary a
device with that profile has (every mapped object, with the CiA 301 objects a device needs), the
virtual device serves it, and ``eds_text`` writes it as an EDS through the canopen library's own
writer. The virtual controller's shipped EDS (``SHIPPED_EDS``) is ``eds_text`` of its shipped
profile; a test holds the two equal. Regenerate it with
``python -m hil.dut.eds hil/dut/profiles/virtual-canopen.toml -o hil/dut/profiles/virtual-canopen.eds``.

``read_eds`` reads a device's EDS: fields CiA 306 lets a tool leave empty (CANopenNode's
reference ``DS301_profile.eds`` has an empty ``VendorNumber``, which canopen 2.4.1's reader
refuses with ``invalid literal for int() with base 0: ''``: canopen issues #313 and #385) are
taken as absent; any other value the reader cannot use is an ``EdsError`` naming the file, the
section and the key.
"""

from __future__ import annotations

import configparser
import io
import re
from dataclasses import dataclass
from pathlib import Path

from .profile import CANOPEN_TYPE_CODES, ERROR_FIELD, PROFILES_DIR, ROLES, Profile, cob_id

#: the virtual controller's EDS, generated from its shipped profile (profiles/virtual-canopen.toml)
SHIPPED_EDS = PROFILES_DIR / "virtual-canopen.eds"
#: the framework's type names as CiA 301 data type codes
TYPE_CODES = {name: code for code, name in CANOPEN_TYPE_CODES.items()}
VISIBLE_STRING = 0x09
#: names of the CiA 301 objects a dictionary built here holds (their sub-indices are named by role)
CIA301_NAMES = {
    0x1000: "Device type",
    0x1001: "Error register",
    0x1003: "Pre-defined error field",
    0x100A: "Manufacturer software version",
    0x1014: "COB-ID EMCY",
    0x1017: "Producer heartbeat time",
    0x1018: "Identity object",
}


class EdsError(ValueError):
    """An EDS that cannot be used; the message names the file, the section and the key."""


@dataclass(frozen=True)
class DeviceIdentity:
    """What a device's dictionary says of itself beyond its profile (0x1000, 0x100A, [DeviceInfo])."""

    vendor_name: str = ""
    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0
    serial: int = 0
    device_type: int = 0
    firmware: str = ""


def _variable(name: str, index: int, sub: int, type_code: int, access: str, default, raw: str | None = None):
    import canopen

    var = canopen.objectdictionary.ODVariable(name, index, sub)
    var.data_type, var.access_type, var.default = type_code, access, default
    if raw is not None:  # as the EDS gives it ($NODEID+...), resolved in ``default``
        var.default_raw, var.relative = raw, "$NODEID" in raw
    return var


def object_dictionary(profile: Profile, node_id: int = 1, identity: DeviceIdentity | None = None):
    """The CiA 301 dictionary of a device with ``profile``: every object it maps (named by its
    role; an object with sub-indices is a RECORD with its highest sub-index at 0 unless a role maps
    sub 0), 0x1000, 0x1014 when it sends EMCY,
    and 0x100A when ``identity`` gives a firmware version. Defaults: the identity's values, else 0.
    An enumeration's EDS limits are its lowest and highest device values."""
    import canopen

    identity = identity or DeviceIdentity()
    od = canopen.ObjectDictionary()
    info = od.device_information
    info.vendor_name, info.vendor_number = identity.vendor_name, identity.vendor_id
    info.product_name, info.product_number = profile.name, identity.product_code
    info.revision_number = identity.revision
    info.allowed_baudrates = {rate * 1000 for rate in (10, 20, 50, 125, 250, 500, 800, 1000)}
    info.simple_boot_up_slave, info.granularity = True, 0
    # the edge hook's PDOs carry the framework's messages (docs/controller.md), whose frames no
    # CiA 301 mapping of objects describes: the dictionary lists no PDO parameters
    info.nr_of_RXPDO = info.nr_of_TXPDO = 0
    identity_defaults = {"identity_vendor": identity.vendor_id, "identity_product": identity.product_code,
                         "identity_revision": identity.revision, "identity_serial": identity.serial}

    def mapped(o, k: int):
        access = {"r": "ro", "rw": "rw", "w": "wo"}[ROLES[o.role].access if o.role in ROLES else "r"]
        if (o.index, o.subindex_of(k)) == (ERROR_FIELD, 0):
            access = "rw"  # CiA 301: writing 0 to the number of errors clears the history
        zero = False if o.type == "bool" else (0.0 if o.type.startswith("float") else 0)
        default = identity_defaults.get(o.role, zero)
        var = _variable(f"{o.role}[{k}]" if o.count > 1 else o.role, o.index, o.subindex_of(k), TYPE_CODES[o.type],
                        access, default)
        if o.values is not None:
            var.min, var.max = min(o.values.values()), max(o.values.values())
        return var

    by_index: dict[int, dict[int, object]] = {}
    reads, writes = profile.cell_map()
    for (index, sub), (o, k) in reads.items():
        var = mapped(o, k)
        if writes[(index, sub)][0] is not o:  # a role read and an action written on one object (named by the role)
            var.access_type = "rw"
        by_index.setdefault(index, {})[sub] = var
    fixed = {0x1000: _variable(CIA301_NAMES[0x1000], 0x1000, 0, TYPE_CODES["uint32"], "ro", identity.device_type)}
    if identity.firmware:
        fixed[0x100A] = _variable(CIA301_NAMES[0x100A], 0x100A, 0, VISIBLE_STRING, "const", identity.firmware)
    if "emcy" in profile.fault_sources:
        fixed[0x1014] = _variable(CIA301_NAMES[0x1014], 0x1014, 0, TYPE_CODES["uint32"], "ro",
                                  cob_id("$NODEID+0x80", node_id, profile.path), "$NODEID+0x80")
    for index, var in fixed.items():
        if index not in by_index:
            od.add_object(var)
    for index, subs in sorted(by_index.items()):
        if list(subs) == [0]:
            var = subs[0]
            var.name = CIA301_NAMES.get(index, var.name)
            od.add_object(var)
            continue
        first = subs[min(subs)].name.partition("[")[0]
        record = canopen.objectdictionary.ODRecord(CIA301_NAMES.get(index, f"{first} record"), index)
        if 0 not in subs:
            record.add_member(_variable("Highest sub-index supported", index, 0, TYPE_CODES["uint8"], "const",
                                        max(subs)))
        for _, var in sorted(subs.items()):
            record.add_member(var)
        od.add_object(record)
    return od


def eds_text(profile: Profile, identity: DeviceIdentity | None = None, file_name: str = "device.eds") -> str:
    """The EDS of ``object_dictionary(profile)``, written by canopen's own EDS writer (its dates
    fixed, so the text is a function of the profile alone)."""
    from canopen.objectdictionary.eds import export_eds

    od = object_dictionary(profile, 1, identity)
    setattr(od, "__edsFileInfo", {})  # what the writer takes as an imported file's [FileInfo]: none
    out = io.StringIO()
    file_info = {"FileName": file_name, "FileVersion": 1, "FileRevision": 0, "EDSVersion": "4.0",
                 "Description": profile.name, "CreatedBy": "bldc-hil (hil.dut.eds)",
                 "CreationDate": "01-01-2026", "CreationTime": "12:00AM",
                 "ModificationDate": "01-01-2026", "ModificationTime": "12:00AM"}
    export_eds(od, out, file_info=file_info)
    return "\n".join(line.rstrip() for line in out.getvalue().splitlines()) + "\n"


def virtual_identity() -> DeviceIdentity:
    """The built-in virtual controller's identity, as its dictionary states it."""
    from ..controller.virtual import Identity

    i = Identity()
    return DeviceIdentity("bldc-hil", i.vendor_id, i.product_code, i.revision, i.serial, i.device_type, i.firmware)


def shipped_eds_text() -> str:
    """What ``SHIPPED_EDS`` must hold: the EDS of the virtual controller's shipped CANopen profile."""
    from .profile import shipped

    return eds_text(shipped("canopen"), virtual_identity(), SHIPPED_EDS.name)


# --- reading ------------------------------------------------------------------------------------------
#: [DeviceInfo] keys read as numbers; CiA 306 lets a tool leave them empty (absent)
_DEVICE_INFO_NUMBERS = ("VendorNumber", "ProductNumber", "RevisionNumber", "SimpleBootUpMaster", "SimpleBootUpSlave",
                        "Granularity", "DynamicChannelsSupported", "GroupMessaging", "NrOfRXPDO", "NrOfTXPDO",
                        "LSS_Supported", "CompactPDO")
#: an object's keys a tool may leave empty (absent: no default, no limit, no value, not mappable)
_OPTIONAL_OBJECT_KEYS = ("DefaultValue", "LowLimit", "HighLimit", "ParameterValue", "PDOMapping", "ObjectType",
                         "StorageLocation", "Factor", "Description", "Unit")
#: an object's keys read as integers
_OBJECT_INTEGERS = ("ObjectType", "DataType", "PDOMapping", "SubNumber", "CompactSubObj", "NrOfEntries")


def _integer(text: str) -> int:
    """An EDS integer: decimal, 0x hex, or $NODEID+n (resolved with node 0)."""
    t = text.strip().upper().replace("$NODEID", "0").replace(" ", "")
    return sum(int(part, 0) for part in t.split("+") if part)


def read_eds(path: str | Path, node_id: int = 1):
    """A device's EDS as a canopen ``ObjectDictionary``; ``EdsError`` names file, section and key."""
    from canopen.objectdictionary.eds import import_eds

    where = str(path)
    eds = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    eds.optionxform = str  # keys keep their case, as canopen's reader reads them
    try:
        with open(path) as fp:
            eds.read_file(fp)
    except OSError as exc:
        raise EdsError(f"{where}: cannot read: {exc.strerror}") from None
    except (configparser.DuplicateSectionError, configparser.DuplicateOptionError) as exc:
        key = f".{exc.option}" if getattr(exc, "option", None) else ""
        raise EdsError(f"{where}: [{exc.section}]{key}: given twice (line {exc.lineno})") from None
    except configparser.Error as exc:
        raise EdsError(f"{where}: not an EDS (CiA 306 INI): {' '.join(str(exc).split())}") from None
    _tolerate_empty(eds, where)
    text = io.StringIO()
    eds.write(text)
    text.seek(0)
    try:
        return import_eds(text, node_id)
    except Exception as exc:  # what the checks above did not foresee: still name the file
        raise EdsError(f"{where}: canopen's EDS reader refused it: {type(exc).__name__}: {exc}") from None


def _tolerate_empty(eds: configparser.RawConfigParser, where: str) -> None:
    """Drop the empty fields CiA 306 tolerates; refuse any other value the reader cannot use."""
    if eds.has_section("DeviceInfo"):
        for key in _DEVICE_INFO_NUMBERS + tuple(k for k in eds.options("DeviceInfo") if k.startswith("BaudRate_")):
            if eds.has_option("DeviceInfo", key):
                _number_or_drop(eds, "DeviceInfo", key, where)
    if eds.has_section("Comments") and eds.has_option("Comments", "Lines"):
        _number_or_drop(eds, "Comments", "Lines", where)
    for section in eds.sections():
        if not _is_object(section):
            continue
        for key in _OPTIONAL_OBJECT_KEYS:
            if eds.has_option(section, key) and not eds.get(section, key).strip():
                eds.remove_option(section, key)
        for key in _OBJECT_INTEGERS:
            if eds.has_option(section, key):
                _number(eds, section, key, where)
        var = not eds.has_option(section, "ObjectType") or _integer(eds.get(section, "ObjectType")) in (0x7, 0x2)
        compact = eds.has_option(section, "CompactSubObj")
        required = ("ParameterName",) + (("DataType", "AccessType") if var or compact else ())
        for key in required:
            if not eds.has_option(section, key) or not eds.get(section, key).strip():
                raise EdsError(f"{where}: [{section}].{key}: required (CiA 306), "
                               + ("empty" if eds.has_option(section, key) else "missing"))


def _is_object(section: str) -> bool:
    return re.fullmatch(r"[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]+)?", section) is not None


def _number(eds, section: str, key: str, where: str) -> None:
    value = eds.get(section, key)
    try:
        _integer(value)
    except ValueError:
        raise EdsError(f"{where}: [{section}].{key}: {value!r} is not a number") from None


def _number_or_drop(eds, section: str, key: str, where: str) -> None:
    if not eds.get(section, key).strip():
        eds.remove_option(section, key)
    else:
        _number(eds, section, key, where)


def main(argv: list[str] | None = None) -> int:
    """``python -m hil.dut.eds PROFILE [-o FILE]``: the EDS of a CANopen profile's dictionary."""
    import argparse

    from .profile import load_profile

    parser = argparse.ArgumentParser(prog="python -m hil.dut.eds", description=main.__doc__)
    parser.add_argument("profile", help="a CANopen device profile (hil-device-profile/1)")
    from .. import cli_grammar as grammar

    grammar.add_out(parser, "write the EDS here (default: standard output)")
    grammar.add_deprecated(parser, "--output", dest="out", new="-o/--out")
    args = parser.parse_args(argv)
    profile = load_profile(args.profile)
    if profile.protocol != "canopen":
        parser.error(f"{args.profile} is a {profile.protocol} profile; an EDS describes a CANopen device")
    own = Path(args.profile).resolve() == (PROFILES_DIR / "virtual-canopen.toml").resolve()
    name = Path(args.out).name if args.out else "device.eds"
    text = eds_text(profile, virtual_identity() if own else None, name)
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
