"""The virtual controller's CANopen object dictionary, declared once: it generates the EDS file
shipped in the package (hil/dut/virtual_controller.eds) and drives the SDO validation.

Manufacturer objects: 0x2000 strategy, 0x2001 speed set point, 0x2010 calibration (staged),
0x2011 apply calibration (write 1), 0x2012 applied calibration (read-back), 0x2020 filter
settings, 0x2100 read-backs, 0x2101 filter counters, 0x2200 / 0x2201 the last edge message header
(RPDO1) and data frame (RPDO2) received (version 2). PDO payloads are documented in bldc/contract.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bldc.contract import FILTER_COUNTERS

I16 = 0x0003
U8, U16, U32, REAL32, VSTRING, REAL64 = 0x0005, 0x0006, 0x0007, 0x0008, 0x0009, 0x0011


@dataclass(frozen=True)
class Entry:
    index: int
    sub: int | None  # None: a VAR object; else a sub-index of a RECORD/ARRAY
    name: str
    data_type: int
    access: str  # ro, rw, wo, const
    default: str = "0"
    low: str | None = None
    high: str | None = None
    pdo: bool = False  #: mapped into a PDO


@dataclass(frozen=True)
class Group:
    index: int
    name: str
    kind: int  # 8 = ARRAY, 9 = RECORD
    entries: tuple[Entry, ...]


CAL_NAMES = ("installation A deg_e", "installation B deg_e", "installation C deg_e", "pole 0 deg_e", "pole 1 deg_e",
             "pole 2 deg_e", "pole 3 deg_e", "rise delay s", "fall delay s", "armature deg_e per A")
FILTER_NAMES = ("forgetting b", "Q0 w", "Q0 theta", "Q0 I", "R0 theta", "R0 I", "P0 w", "P0 theta", "P0 I")
#: the split filter counters (0x2101), in order, as the EDS names them
COUNTERS = tuple(name.replace("_", " ") for name in FILTER_COUNTERS)
#: the edge message's (version 2) header (0x2200, mapped by RPDO1) and one data frame (0x2201, RPDO2):
#: a conversion of its window, or at index 0xFD-0xFF an accumulator (its first six bytes then I32
#: sum and U16 conversions summed: bldc.contract)
EDGE_FIELDS = (
    ("capture time 100 ns ticks", U32, 32),
    ("flags", U8, 8),
    ("sequence", U8, 8),
    ("newest ADC conversion age ticks (0xFFFF: none)", U16, 16),
)
SAMPLE_FIELDS = (
    ("phase a sensor counts (2 mA)", I16, 16),
    ("phase b sensor counts (2 mA)", I16, 16),
    ("phase c sensor counts (2 mA)", I16, 16),
    ("sequence of its edge", U8, 8),
    ("index (conversions from 0, the capture's; accumulators 0xFD-0xFF)", U8, 8),
)
READBACK = (
    ("estimated speed rpm", REAL32),
    ("Q w", REAL32),
    ("Q theta", REAL32),
    ("Q I", REAL32),
    ("R theta", REAL32),
    ("R I", REAL32),
    ("guard trips", U32),
    ("last predicted commutation s", REAL64),
)


def objects(node_id: int = 1) -> list:
    items: list = [
        Entry(0x1000, None, "Device type", U32, "ro", "0x00000192"),
        Entry(0x1001, None, "Error register", U8, "ro", "0"),
        Entry(0x100A, None, "Manufacturer software version", VSTRING, "const", "vc-0.1.0"),
        Group(
            0x1003,
            "Pre-defined error field",
            8,
            (Entry(0x1003, 0, "Number of errors (write 0 to clear)", U8, "rw", "0"),)
            + tuple(Entry(0x1003, k, f"Standard error field {k}", U32, "ro", "0") for k in range(1, 9)),
        ),
        Entry(0x1014, None, "COB-ID EMCY", U32, "ro", "$NODEID+0x80"),
        Entry(0x1017, None, "Producer heartbeat time", U16, "rw", "100"),
        Group(
            0x1018,
            "Identity object",
            9,
            (
                Entry(0x1018, 0, "Highest sub-index supported", U8, "const", "4"),
                Entry(0x1018, 1, "Vendor-ID", U32, "ro", "0x00000B1D"),
                Entry(0x1018, 2, "Product code", U32, "ro", "0x00480001"),
                Entry(0x1018, 3, "Revision number", U32, "ro", "0x00010000"),
                Entry(0x1018, 4, "Serial number", U32, "ro", "0x00000001"),
            ),
        ),
        Entry(0x2000, None, "Strategy (0 raw, 1 corrected, 2 KF, 3 Sage-Husa)", U8, "rw", "3", "0", "3"),
        Entry(0x2001, None, "Speed set point rpm", REAL32, "rw", "5000", "0", "30000"),
        Group(
            0x2010,
            "Calibration (staged)",
            9,
            (Entry(0x2010, 0, "Highest sub-index supported", U8, "const", str(len(CAL_NAMES))),)
            + tuple(Entry(0x2010, k + 1, n, REAL32, "rw", "0") for k, n in enumerate(CAL_NAMES)),
        ),
        Entry(0x2011, None, "Apply calibration (write 1)", U8, "wo", "0", "1", "1"),
        Group(
            0x2012,
            "Calibration (applied)",
            9,
            (Entry(0x2012, 0, "Highest sub-index supported", U8, "const", str(len(CAL_NAMES))),)
            + tuple(Entry(0x2012, k + 1, n, REAL32, "ro", "0") for k, n in enumerate(CAL_NAMES)),
        ),
        Group(
            0x2020,
            "Filter settings",
            9,
            (Entry(0x2020, 0, "Highest sub-index supported", U8, "const", str(len(FILTER_NAMES))),)
            + tuple(Entry(0x2020, k + 1, n, REAL32, "rw", "0") for k, n in enumerate(FILTER_NAMES)),
        ),
        *_rpdo(0, 0x200, 0x2200, EDGE_FIELDS),
        *_rpdo(1, 0x300, 0x2201, SAMPLE_FIELDS),

        Group(
            0x2100,
            "Read-backs",
            9,
            (Entry(0x2100, 0, "Highest sub-index supported", U8, "const", str(len(READBACK))),)
            + tuple(Entry(0x2100, k + 1, n, t, "ro", "0") for k, (n, t) in enumerate(READBACK)),
        ),
        Group(
            0x2101,
            "Filter counters",
            9,
            (Entry(0x2101, 0, "Highest sub-index supported", U8, "const", str(len(COUNTERS))),)
            + tuple(Entry(0x2101, k + 1, n, U32, "ro", "0") for k, n in enumerate(COUNTERS)),
        ),
        _mapped(0x2200, "Edge message v2 header (RPDO1)", EDGE_FIELDS),
        _mapped(0x2201, "Edge message v2 data frame (RPDO2: a conversion, or an accumulator at 0xFD-0xFF)",
                SAMPLE_FIELDS),

    ]
    return sorted(items, key=lambda o: o.index)


def _mapped(index: int, name: str, fields) -> Group:
    """A record the plant writes by PDO; read back by SDO it gives the last one received."""
    return Group(
        index,
        name,
        9,
        (Entry(index, 0, "Highest sub-index supported", U8, "const", str(len(fields))),)
        + tuple(Entry(index, k + 1, n, t, "ro", "0", pdo=True) for k, (n, t, _) in enumerate(fields)),
    )


def _rpdo(number: int, cob_base: int, target: int, fields) -> tuple[Group, Group]:
    """CiA 301 RPDO communication (0x1400 + n) and mapping (0x1600 + n) parameters, fixed."""
    comm = Group(
        0x1400 + number,
        f"RPDO{number + 1} communication parameter",
        9,
        (
            Entry(0x1400 + number, 0, "Highest sub-index supported", U8, "const", "2"),
            Entry(0x1400 + number, 1, "COB-ID used by RPDO", U32, "ro", f"$NODEID+0x{cob_base:X}"),
            Entry(0x1400 + number, 2, "Transmission type", U8, "ro", "0xFE"),
        ),
    )
    mapping = Group(
        0x1600 + number,
        f"RPDO{number + 1} mapping parameter",
        9,
        (Entry(0x1600 + number, 0, "Number of mapped objects", U8, "const", str(len(fields))),)
        + tuple(
            Entry(
                0x1600 + number, k + 1, f"Mapped object {k + 1}", U32, "const", f"0x{target:04X}{k + 1:02X}{bits:02X}"
            )
            for k, (_, _, bits) in enumerate(fields)
        ),
    )
    return comm, mapping


def _entry_lines(e: Entry) -> list[str]:
    lines = [
        f"ParameterName={e.name}",
        "ObjectType=0x7",
        f"DataType=0x{e.data_type:04X}",
        f"AccessType={e.access}",
        f"DefaultValue={e.default}",
        f"PDOMapping={int(e.pdo)}",
    ]
    if e.low is not None:
        lines.insert(4, f"LowLimit={e.low}")
    if e.high is not None:
        lines.insert(5 if e.low is not None else 4, f"HighLimit={e.high}")
    return lines


def eds_text() -> str:
    items = objects()
    mandatory = [0x1000, 0x1001, 0x1018]
    optional = [o.index for o in items if o.index < 0x2000 and o.index not in mandatory]
    manufacturer = [o.index for o in items if o.index >= 0x2000]
    out = [
        "[FileInfo]",
        "FileName=virtual_controller.eds",
        "FileVersion=1",
        "FileRevision=0",
        "EDSVersion=4.0",
        "Description=bldc-hil virtual pump controller (Hall calibration, Sage-Husa commutation)",
        "CreatedBy=bldc-hil",
        "",
        "[DeviceInfo]",
        "VendorName=bldc-hil",
        "VendorNumber=0x00000B1D",
        "ProductName=Virtual pump controller",
        "ProductNumber=0x00480001",
        "RevisionNumber=0x00010000",
        "BaudRate_1000=1",
        "SimpleBootUpSlave=1",
        "Granularity=0",
        "NrOfRXPDO=2",
        "NrOfTXPDO=1",
        "",
        "[MandatoryObjects]",
        f"SupportedObjects={len(mandatory)}",
    ]
    out += [f"{k + 1}=0x{i:04X}" for k, i in enumerate(mandatory)]
    out += ["", "[OptionalObjects]", f"SupportedObjects={len(optional)}"] + [
        f"{k + 1}=0x{i:04X}" for k, i in enumerate(optional)
    ]
    out += ["", "[ManufacturerObjects]", f"SupportedObjects={len(manufacturer)}"] + [
        f"{k + 1}=0x{i:04X}" for k, i in enumerate(manufacturer)
    ]
    for o in items:
        out.append("")
        if isinstance(o, Entry):
            out.append(f"[{o.index:04X}]")
            out += _entry_lines(o)
        else:
            out += [
                f"[{o.index:04X}]",
                f"ParameterName={o.name}",
                f"ObjectType=0x{o.kind:X}",
                f"SubNumber={len(o.entries)}",
            ]
            for e in o.entries:
                out += ["", f"[{o.index:04X}sub{e.sub:X}]"] + _entry_lines(e)
    return "\n".join(out) + "\n"


EDS_PATH = Path(__file__).with_name("virtual_controller.eds")
