"""EDS files as real tools write them (tests/data/eds: CANopenNode's and the canopen library's,
README there): read with CiA 306's empty fields, refused naming file, section and key when
broken, drafted into profiles without false role guesses; and EDS files generated from profiles."""

import re
from pathlib import Path

import canopen
import pytest

from hil.cli import main
from hil.dut.draft import _guess, draft_from_eds
from hil.dut.eds import EdsError, eds_text, read_eds
from hil.dut.profile import CANOPEN_TYPE_CODES, load_profile
from hil.dut.spec import DutSpecError, parse_dut

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data" / "eds"
CANOPENNODE = DATA / "CANopenNode-DS301_profile.eds"
E35 = DATA / "canopen-e35.eds"
SAMPLE = DATA / "canopen-sample.eds"
#: every role a draft may guess on each public file: a real match of meaning, nothing else
#: (e35's 0x6042 "vl target velocity" and 0x6044 "vl velocity actual value" are CiA 402's
#: velocity-mode set point and actual speed; clear_faults is 0x1003:00 written with 0, as CiA 301
#: defines it, where the EDS says the number of errors is writable)
EXPECTED_ROLES = {
    CANOPENNODE: {"fault_code", "fault_count", "clear_faults"},
    E35: {"fault_code", "fault_count", "clear_faults", "speed_setpoint", "speed_actual"},
    SAMPLE: {"fault_code", "fault_count", "clear_faults"},
}


def test_the_library_alone_refuses_an_empty_vendor_number_and_read_eds_takes_it_as_absent():
    with pytest.raises(ValueError, match="invalid literal for int"):  # canopen issues #313, #385
        canopen.import_od(str(CANOPENNODE), 1)
    od = read_eds(CANOPENNODE, 1)
    assert od.device_information.vendor_number is None and od.device_information.product_name == "New Product"
    sections = re.findall(r"^\[([0-9A-Fa-f]{4})\]$", CANOPENNODE.read_text(), re.M)
    assert len(sections) == 33 and {int(s, 16) for s in sections} <= set(od.indices)  # every object read


@pytest.mark.parametrize("path", list(EXPECTED_ROLES), ids=lambda p: p.name)
def test_a_draft_from_a_public_eds_guesses_only_real_matches_and_loads(tmp_path, path):
    text = draft_from_eds(str(path))
    draft = tmp_path / "draft.toml"
    draft.write_text(text)
    profile = load_profile(draft)  # the draft is a valid profile as it stands
    guessed = {role for role, o in profile.objects.items() if not role.startswith("x_") and not o.default}
    assert guessed == EXPECTED_ROLES[path], guessed
    # every typed object from 0x2000 is in the draft: a guessed role's element or an x_ object
    od = read_eds(path, 1)
    listed = {(o.index, o.subindex_of(k)) for o in profile.objects.values() for k in range(o.count)}
    variables = [v for obj in od.values() for v in ([obj] if isinstance(obj, canopen.objectdictionary.ODVariable)
                                                    else [v for v in obj.values() if v.subindex > 0])]
    wanted = {(v.index, v.subindex) for v in variables if v.index >= 0x2000 and v.data_type in CANOPEN_TYPE_CODES}
    assert wanted <= listed and bool(wanted) == (path != CANOPENNODE)  # DS301_profile: CiA 301 objects only


@pytest.mark.parametrize(
    "name, role",
    [
        ("Max user temperature", None),  # "r" is no word of it
        ("Lifeguard message", None),  # nor "guard"
        ("Motor pair poles", None),  # pole pairs are no pole offset
        ("Analog input velocity deadband", None),  # "band" inside "deadband"
        ("Open loop final speed", None),  # a speed, but no set point
        ("Speed set point rpm", "speed_setpoint"),
        ("MotorSpeedActual", "speed_actual"),
        ("Hall installation offset A", "installation_offset"),
        ("Pole offset 3", "pole_offset"),
        ("Applied rise delay", "calibration_applied_conditioning_delay_rise"),
        ("Filter R diagonal", "filter_r_diag"),
        ("Guard trips", "guard_trips"),
        ("pole_offset[2]", "pole_offset"),  # the framework's own name, as hil.dut.eds writes it
    ],
)
def test_a_role_is_guessed_on_whole_words_only(name, role):
    assert _guess(name, applied=False) == role


def _broken(tmp_path, old: str, new: str) -> Path:
    text = CANOPENNODE.read_text()
    assert old in text
    path = tmp_path / "broken.eds"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    "old, new, where",
    [
        ("VendorNumber=\n", "VendorNumber=acme\n", "[DeviceInfo].VendorNumber: 'acme' is not a number"),
        ("PERSIST_COMM\nDataType=0x0007\n", "PERSIST_COMM\nDataType=\n", "[1000].DataType: required (CiA 306), empty"),
        ("[1000]\nParameterName=Device type\nObjectType=0x7\n", "[1000]\nParameterName=Device type\nObjectType=VAR\n",
         "[1000].ObjectType: 'VAR' is not a number"),
        ("[1000]\nParameterName=Device type\n", "[1000]\n", "[1000].ParameterName: required (CiA 306), missing"),
        ("NrOfRXPDO=4\n", "NrOfRXPDO=4\nNrOfRXPDO=2\n", "[DeviceInfo].NrOfRXPDO: given twice"),
    ],
)
def test_a_broken_eds_is_refused_naming_file_section_and_key(tmp_path, capsys, old, new, where):
    path = _broken(tmp_path, old, new)
    with pytest.raises(EdsError) as info:
        read_eds(path)
    assert str(info.value).startswith(f"{path}: ") and where in str(info.value), str(info.value)
    assert main(["dut", "profile", "--from-eds", str(path)]) == 2  # hil dut profile --from-eds FILE
    assert f"hil: error: {path}: " in capsys.readouterr().err
    with pytest.raises(DutSpecError, match=r"eds .*" + where.split(":")[0].replace("[", r"\[").replace("]", r"\]")):
        parse_dut(f"canopen:interface=virtual,channel=x,eds={path}")  # --dut canopen:...,eds=FILE


def test_the_dut_takes_a_public_eds_with_empty_fields():
    assert parse_dut(f"canopen:interface=virtual,channel=x,eds={CANOPENNODE}").options["eds"] == str(CANOPENNODE)


def test_an_eds_generated_from_a_foreign_profile_drafts_back_to_that_profile(tmp_path):
    """A profile's dictionary written as an EDS names each object by its role: the draft finds
    every mapped object again (so a new role is one profile entry, and its EDS follows)."""
    foreign = load_profile(ROOT / "examples" / "acme-p3-canopen.toml")
    eds = tmp_path / "acme.eds"
    eds.write_text(eds_text(foreign, file_name=eds.name))
    assert read_eds(eds, 5)[0x3000].name == "strategy"
    draft = tmp_path / "draft.toml"
    draft.write_text(draft_from_eds(str(eds)))
    back = load_profile(draft).bind(2, 5, read_eds(eds, 5))
    own = foreign.bind(2, 5, read_eds(eds, 5))
    mapped = {r: (o.index, o.subindex, o.count, o.type) for r, o in own.objects.items() if not o.default}
    assert mapped.items() <= {r: (o.index, o.subindex, o.count, o.type) for r, o in back.objects.items()}.items()


def test_the_docs_list_the_shipped_dictionary_as_it_is_served():
    """docs/controller.md's table of the built-in dictionary is a copy a reader trusts: every
    object the device serves is in it, with the types and access it is served with."""
    from hil.dut.eds import object_dictionary, virtual_identity
    from hil.dut.profile import shipped

    text = (ROOT / "docs" / "controller.md").read_text()
    section = text[text.index("## CANopen face") :]
    section = section[: section.index("\n## ", 1)]
    rows = re.findall(r"^\| 0x([0-9A-F]{4}) \| [^|]+ \| ([^|]+) \| ([^|]+) \|$", section, re.M)
    od = object_dictionary(shipped("canopen").bind(2, 5), 5, virtual_identity())
    assert {int(index, 16) for index, _, _ in rows} == set(od.indices)
    names = {0x03: "I16", 0x05: "U8", 0x06: "U16", 0x07: "U32", 0x08: "REAL32", 0x09: "VISIBLE_STRING", 0x11: "REAL64"}
    for index, types, access in rows:
        obj = od[int(index, 16)]
        members = [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else [
            v for v in obj.values() if v.name != "Highest sub-index supported"]
        served = {names[v.data_type] for v in members}
        listed = {t.split()[0] for t in types.split("/")}
        assert served == listed or (types.strip() == "mixed" and len(served) > 1), (index, served, types)
        assert {v.access_type for v in members} == {a.strip() for a in access.split("/")}, (index, access)


def test_the_docs_list_the_shipped_register_map_as_it_is_served():
    """The same for the Modbus face's table: each mapped register in a row of its object's type
    and access, the mailbox where the profile puts it, and no row the map does not have."""
    from hil.dut.profile import REPLY_WORDS, ROLES, mailbox_words, shipped

    text = (ROOT / "docs" / "controller.md").read_text()
    section = text[text.index("## Modbus face") :]
    section = section[: section.index("\n## ", 1)]
    rows = [(int(a), int(b or a), types, access) for a, b, types, access in
            re.findall(r"^\| (\d+)(?:-(\d+))? \| [^|]+ \| ([^|]+) \| (ro|rw|wo) \|$", section, re.M)]
    profile = shipped("modbus").bind(2)
    hook = profile.edge_hook
    mailbox = {(hook.reply_address, hook.reply_address + REPLY_WORDS - 1, "ro"),
               (hook.request_address, hook.request_address + mailbox_words(profile) - 1, "wo")}
    assert mailbox <= {(a, b, access) for a, b, _, access in rows}
    listed = {r for a, b, _, _ in rows if (a, b) not in {(m[0], m[1]) for m in mailbox} for r in range(a, b + 1)}
    assert listed == {r for o in profile.objects.values() for r in range(o.address, o.end)}
    for o in profile.objects.values():
        a, b, types, access = next(row for row in rows if row[0] <= o.address <= row[1])
        assert o.type.upper() in types and access == {"r": "ro", "rw": "rw", "w": "wo"}[ROLES[o.role].access], o.role
