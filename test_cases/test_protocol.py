"""Protocol conformance of the controller (CiA 301 over CANopen, the Modbus application protocol).

The probes come from the device profile the link reads (a read-only object, an address beyond
the map, a value outside the strategy enumeration) and, for CANopen, from its EDS (the shipped
one for the virtual controller), so the same tests judge any device.
"""

import socket
import struct
import time

import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from hil.dut.link import LinkError
from hil.dut.profile import REPLY_WORDS, mailbox_words
from hil.dut.profile import ROLES

ABORT = {"no object": 0x06020000, "no sub-index": 0x06090011, "read-only": 0x06010002, "write-only": 0x06010001,
         "value range": 0x06090030, "length": 0x06070010}


@pytest.mark.requirement("REQ-PROT-001")
def test_controller_identifies_itself(hil_link, hil_evidence):
    ident = hil_link.identity()
    hil_evidence.table("identity read from the device", ["field", "value"],
                       [[k, f"0x{v:08X}" if isinstance(v, int) else str(v)] for k, v in ident.items()])
    for key in ("vendor_id", "product_code", "revision", "serial"):
        assert isinstance(ident[key], int) and ident[key] != 0, (
            f"identity {key} reads {ident[key]!r}: a device must identify itself"
        )


def _need(hil_dut, protocol):
    if hil_dut.protocol != protocol:
        pytest.skip(f"{protocol} conformance: the DUT speaks {hil_dut.protocol}")


def _variables(od):
    for obj in od.values():
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            yield obj, None
        else:
            for var in obj.values():
                yield var, var.subindex


def _read_only(profile):
    """An object only read: a role that is only read and shares its object with no action (0x1003:00
    read as fault_count and written with 0 as clear_faults is written, as CiA 301 defines it)."""
    return next(o for o in profile.objects.values()
                if o.role in ROLES and ROLES[o.role].access == "r" and profile.action_on(o) is None)


def _probe(od, profile, kind):
    """A request the profile (or the EDS) says must be refused with ``kind``'s abort code."""
    variables = list(_variables(od))
    if kind == "no object":
        mapped = {o.index for o in profile.objects.values()}
        index = next(i for i in range(0x5FFF, 0x1FFF, -1) if i not in od and i not in mapped)
        return f"read 0x{index:04X}", lambda sdo: sdo.upload(index, 0)
    if kind == "no sub-index":
        obj = next(o for o in od.values() if not isinstance(o, canopen.objectdictionary.ODVariable))
        sub = max(obj.subindices) + 1
        return f"read 0x{obj.index:04X}:{sub:02X}", lambda sdo: sdo.upload(obj.index, sub)
    if kind == "read-only":  # a role the profile says is only read
        obj = _read_only(profile)
        return f"write {obj.label()} ({obj.role})", lambda sdo: sdo.download(obj.index, obj.subindex, obj.pack_le(0))
    if kind == "write-only":
        var, sub = next(((v, s) for v, s in variables if v.access_type == "wo"), (None, None))
        if var is None:
            pytest.skip("the EDS declares no write-only object")
        return f"read 0x{var.index:04X}", lambda sdo: sdo.upload(var.index, sub or 0)
    if kind == "value range":  # one past the strategy enumeration's highest value
        obj = profile.get("strategy")
        value = max(obj.values.values()) + 1
        return f"write {obj.label()} (strategy) = {value}", lambda sdo: sdo.download(
            obj.index, obj.subindex, obj.pack_le(value)
        )
    if kind == "length":  # four bytes into a writable object shorter than that
        obj = next((o for o in profile.objects.values() if o.role in ROLES and "w" in ROLES[o.role].access
                    and not o.is_action and o.size < 4), None)
        if obj is None:
            pytest.skip("the profile maps no writable object shorter than four bytes")
        return f"write {obj.label()} ({obj.role}) with 4 bytes", lambda sdo: sdo.download(
            obj.index, obj.subindex, struct.pack("<I", 1)
        )
    raise ValueError(kind)


@pytest.mark.dut_protocol("canopen")
@pytest.mark.requirement("REQ-PROT-003")
@pytest.mark.parametrize("kind", list(ABORT), ids=[k.replace(" ", "-") for k in ABORT])
def test_sdo_abort_codes(kind, hil_link, hil_evidence):
    what, request = _probe(hil_link.node.object_dictionary, hil_link.profile, kind)
    with pytest.raises(SdoAbortedError) as info:
        request(hil_link.node.sdo)
    hil_evidence.value(f"abort code for '{what}'", f"0x{info.value.code:08X}")
    assert info.value.code == ABORT[kind], (
        f"{what}: SDO abort 0x{info.value.code:08X}, CiA 301 requires 0x{ABORT[kind]:08X} ({kind})"
    )
    assert hil_link.identity()["device_type"] is not None  # still serving well-formed requests


@pytest.mark.requirement("REQ-PROT-002")
def test_heartbeat_period_matches_0x1017(hil_dut, hil_link, hil_budget, hil_evidence):
    _need(hil_dut, "canopen")
    period_ms = 50
    stamps = []
    hil_link.write_role("heartbeat_period", [period_ms])

    def on_heartbeat(cid, data, ts):
        if bytes(data) != b"\x00":
            stamps.append(time.monotonic())

    hil_link.network.subscribe(0x700 + hil_link.node_id, on_heartbeat)
    try:
        time.sleep(1.0)
    finally:
        hil_link.network.unsubscribe(0x700 + hil_link.node_id, on_heartbeat)  # the link's own boot-up listener stays
        hil_link.write_role("heartbeat_period", [100])
    intervals = np.diff(stamps[1:])
    assert len(intervals) >= 10, f"only {len(stamps)} heartbeats in 1 s at a {period_ms} ms period"
    hil_evidence.value("heartbeats in 1 s", len(stamps))
    hil_evidence.value("median heartbeat period", float(np.median(intervals) * 1e3), "ms")
    hil_budget("heartbeat_period_error", abs(float(np.median(intervals)) / (period_ms / 1e3) - 1.0))


@pytest.mark.dut_protocol("canopen")
@pytest.mark.requirement("REQ-PROT-002", "REQ-CAL-006")
def test_refused_calibration_sends_emcy_and_sets_0x1001(hil_link, calibrate, hil_evidence):
    bad = calibrate(())
    bad = bad.__class__.from_json_dict({**bad.to_json_dict(), "conditioning_delay_s": {"rise": 1e-3, "fall": 0.0}})
    while not hil_link.emcy.empty():
        hil_link.emcy.get_nowait()
    with pytest.raises(LinkError, match="0x06090030"):
        hil_link.download_calibration(bad)
    _, frame = hil_link.emcy.get(timeout=hil_link.timeout_s)
    code, register = struct.unpack_from("<HB", frame)
    error_register = int(hil_link.read_role("error_register")[0])
    hil_evidence.value("EMCY error code", f"0x{code:04X}")
    hil_evidence.value("error register", f"0x{error_register:02X}")
    assert register & 0x01 and error_register & 0x01, "the error register's generic bit must be set with the EMCY"
    faults = hil_link.faults()
    assert faults and faults[0] == hil_link.profile.framework_fault(code), (
        f"the newest latched fault must be the EMCY's code 0x{code:04X} (latched: {faults})"
    )


def _sil_probe(link, kind):
    """A request to a firmware's object dictionary that CiA 301 says must be refused with ``kind``'s
    abort code, as (what, the firmware's answer). A firmware has no EDS: an index or sub-index
    that answers with data exists, and the next one is tried."""
    profile = link.profile
    if kind == "no object":
        mapped = {o.index for o in profile.objects.values()}
        for index in (i for i in range(0x5FFF, 0x5F00, -1) if i not in mapped):
            answer = link.od_read(index, 0, 8)
            if isinstance(answer, int):
                return f"read 0x{index:04X}", answer
        pytest.fail("0x5F01-0x5FFF all answered with data: no index the firmware lacks to probe")
    if kind == "no sub-index":
        obj = max((o for o in profile.objects.values() if o.subindex), key=lambda o: o.subindex + o.count)
        for sub in range(obj.subindex + obj.count, 0xFF):
            answer = link.od_read(obj.index, sub, 8)
            if isinstance(answer, int):
                return f"read 0x{obj.index:04X}:{sub:02X}", answer
        pytest.fail(f"every sub-index of 0x{obj.index:04X} answered with data")
    if kind == "read-only":
        obj = _read_only(profile)
        return f"write {obj.label()} ({obj.role})", link.od_write(obj.index, obj.subindex, obj.pack_le(0))
    if kind == "value range":
        obj = profile.get("strategy")
        value = max(obj.values.values()) + 1
        return f"write {obj.label()} (strategy) = {value}", link.od_write(obj.index, obj.subindex,
                                                                            obj.pack_le(value))
    if kind == "length":  # one byte more than a writable object holds
        obj = next(o for o in profile.objects.values() if o.role in ROLES and "w" in ROLES[o.role].access
                   and not o.is_action)
        return (f"write {obj.label()} ({obj.role}) with {obj.size + 1} bytes",
                link.od_write(obj.index, obj.subindex, obj.pack_le(0) + b"\0"))
    if kind == "write-only":  # an action the profile maps (apply, reset, clear faults) is only written
        obj = next((o for o in profile.objects.values() if o.is_action and o.index >= 0x2000), None)
        if obj is None:
            pytest.skip("the profile maps no action in the dictionary to read")
        return f"read {obj.label()} ({obj.role})", link.od_read(obj.index, obj.subindex, 8)
    raise ValueError(kind)


@pytest.mark.dut_protocol("sil")
@pytest.mark.requirement("REQ-PROT-003")
@pytest.mark.parametrize("kind", list(ABORT), ids=[k.replace(" ", "-") for k in ABORT])
def test_object_dictionary_abort_codes_of_a_firmware(kind, hil_link, hil_evidence):
    """The same CiA 301 answers from a firmware in the loop's own dictionary (``hil_sil_od_read``/
    ``_write``), which a CAN bench would later see through its SDO server."""
    what, answer = _sil_probe(hil_link, kind)
    assert isinstance(answer, int) and answer < 0, f"{what}: answered {answer!r}, CiA 301 requires an abort"
    code = (-answer) & 0xFFFFFFFF
    hil_evidence.value(f"abort code for '{what}'", f"0x{code:08X}")
    assert code == ABORT[kind], f"{what}: SDO abort 0x{code:08X}, CiA 301 requires 0x{ABORT[kind]:08X} ({kind})"


@pytest.mark.dut_protocol("sil")
@pytest.mark.requirement("REQ-PROT-002", "REQ-CAL-006")
def test_refused_calibration_sends_emcy_and_sets_0x1001_on_a_firmware(hil_link, calibrate, hil_evidence):
    """A firmware in the loop: the refused table's EMCY (``hil_sil_emcy``), the error register and
    the newest latched fault, as on the bus (its heartbeat is a bus service: judged on a CAN bench)."""
    bad = calibrate(())
    bad = bad.__class__.from_json_dict({**bad.to_json_dict(), "conditioning_delay_s": {"rise": 1e-3, "fall": 0.0}})
    before = len(hil_link.emcy_codes())
    with pytest.raises(LinkError, match="0x06090030"):
        hil_link.download_calibration(bad)
    codes = hil_link.emcy_codes()
    assert len(codes) > before, "the refused table sent no EMCY (hil_sil_emcy popped none)"
    code = codes[-1]
    error_register = int(hil_link.read_role("error_register")[0])
    hil_evidence.value("EMCY error code", f"0x{code:04X}")
    hil_evidence.value("error register", f"0x{error_register:02X}")
    assert error_register & 0x01, "the error register's generic bit must be set with the EMCY"
    faults = hil_link.faults()
    assert faults and faults[0] == hil_link.profile.framework_fault(code), (
        f"the newest latched fault must be the EMCY's code 0x{code:04X} (latched: {faults})"
    )


def _modbus_ask(link, pdu: bytes) -> bytes:
    with socket.create_connection((link.host, link.port), timeout=link.timeout_s) as s:
        s.sendall(struct.pack(">HHHB", 0x1234, 0, len(pdu) + 1, link.unit) + pdu)
        reply = s.recv(260)
    assert struct.unpack_from(">H", reply, 0)[0] == 0x1234, "the answer must carry the request's transaction id"
    return reply[7:]


MODBUS_PROBES = ("function-0x41", "beyond-the-map", "quantity-0", "quantity-126", "value-range", "read-only")


def _modbus_probe(profile, kind: str) -> tuple[str, bytes, int]:
    """(what, request PDU, the exception code the Modbus application protocol requires), from the
    device's profile: its register tables, the end of its map, its strategy enumeration."""
    objects = [o for o in profile.objects.values() if o.table in ("holding", "input")]
    table = "holding" if any(o.table == "holding" for o in objects) else "input"
    fc = 3 if table == "holding" else 4
    first = min(o.address for o in objects if o.table == table)
    if kind == "function-0x41":
        return "unknown function code 0x41", bytes([0x41, 0, 0]), 0x01
    if kind == "beyond-the-map":
        ends = [o.end for o in objects if o.table == table]
        hook = profile.edge_hook
        if hook.kind == "mailbox" and table == "holding":
            ends += [hook.request_address + mailbox_words(profile), hook.reply_address + REPLY_WORDS]
        end = max(ends)
        return f"read 1 {table} register at {end} (after the map)", struct.pack(">BHH", fc, end, 1), 0x02
    if kind == "quantity-0":
        return f"read quantity 0 at {first}", struct.pack(">BHH", fc, first, 0), 0x03
    if kind == "quantity-126":
        return f"read quantity 126 at {first}", struct.pack(">BHH", fc, first, 126), 0x03
    if kind == "value-range":
        obj = profile.get("strategy")
        if obj is None or obj.table != "holding" or obj.registers != 1:
            pytest.skip("the profile has no one-register strategy in a holding register")
        value = max(obj.values.values()) + 1
        return f"write strategy {value} at {obj.address}", struct.pack(">BHH", 6, obj.address, value), 0x03
    ro = next((o for o in profile.objects.values() if o.table == "holding" and o.role in ROLES
               and ROLES[o.role].access == "r" and o.registers == 1), None)
    if ro is None:
        pytest.skip("the profile maps no one-register read-only holding register")
    return f"write the read-only {ro.role} at {ro.address}", struct.pack(">BHH", 6, ro.address, 0), 0x02


@pytest.mark.dut_protocol("modbus")
@pytest.mark.requirement("REQ-PROT-003")
@pytest.mark.parametrize("kind", MODBUS_PROBES)
def test_modbus_exception_codes(kind, hil_link, hil_evidence):
    if hil_link.serial_port is not None:
        pytest.skip("raw ADUs are sent over TCP only")
    name, pdu, code = _modbus_probe(hil_link.profile, kind)
    answer = _modbus_ask(hil_link, pdu)
    hil_evidence.value(f"answer to {name}", answer.hex())
    assert answer[0] == (pdu[0] | 0x80) and answer[1] == code, (
        f"{name}: answered {answer.hex()}, the Modbus application protocol requires exception {code:02d}"
    )
    assert hil_link.identity()["vendor_id"]  # still serving
