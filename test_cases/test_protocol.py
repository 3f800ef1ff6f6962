"""Protocol conformance of the controller (CiA 301 over CANopen, the Modbus application protocol).

Object indexes and limits come from the EDS the link was given (the shipped one for the
virtual controller), so the same tests judge any CANopen device; Modbus requests use the
device's register map only where the standard leaves no choice.
"""

import socket
import struct
import time

import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from hil.dut.link import LinkError

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


def _probe(od, kind):
    """A request the EDS says must be refused with ``kind``'s abort code."""
    variables = list(_variables(od))
    if kind == "no object":
        index = next(i for i in range(0x5FFF, 0x1FFF, -1) if i not in od)
        return f"read 0x{index:04X}", lambda sdo: sdo.upload(index, 0)
    if kind == "no sub-index":
        obj = next(o for o in od.values() if not isinstance(o, canopen.objectdictionary.ODVariable))
        sub = max(obj.subindices) + 1
        return f"read 0x{obj.index:04X}:{sub:02X}", lambda sdo: sdo.upload(obj.index, sub)
    if kind == "read-only":
        var, sub = next((v, s) for v, s in variables if v.access_type == "ro")
        return f"write 0x{var.index:04X}", lambda sdo: sdo.download(
            var.index, sub or 0, var.encode_raw(0) if var.data_type != 0x0009 else b"x"
        )
    if kind == "write-only":
        var, sub = next(((v, s) for v, s in variables if v.access_type == "wo"), (None, None))
        if var is None:
            pytest.skip("the EDS declares no write-only object")
        return f"read 0x{var.index:04X}", lambda sdo: sdo.upload(var.index, sub or 0)
    if kind == "value range":
        var, sub = next(
            (
                (v, s)
                for v, s in variables
                if "w" in v.access_type and v.max is not None and v.data_type in canopen.objectdictionary.INTEGER_TYPES
            ),
            (None, None),
        )
        if var is None:
            pytest.skip("the EDS declares no writable integer with a high limit")
        return f"write 0x{var.index:04X} = {var.max + 1}", lambda sdo: sdo.download(
            var.index, sub or 0, var.encode_raw(var.max + 1)
        )
    if kind == "length":
        var, sub = next((v, s) for v, s in variables if "w" in v.access_type and v.data_type == 0x0005)  # a writable U8
        return f"write 0x{var.index:04X} with 4 bytes", lambda sdo: sdo.download(
            var.index, sub or 0, struct.pack("<I", 1)
        )
    raise ValueError(kind)


@pytest.mark.requirement("REQ-PROT-003")
@pytest.mark.parametrize("kind", list(ABORT), ids=[k.replace(" ", "-") for k in ABORT])
def test_sdo_abort_codes(kind, hil_dut, hil_link, hil_evidence):
    _need(hil_dut, "canopen")
    what, request = _probe(hil_link.node.object_dictionary, kind)
    with pytest.raises(SdoAbortedError) as info:
        request(hil_link.node.sdo)
    hil_evidence.value(f"abort code for '{what}'", f"0x{info.value.code:08X}")
    assert info.value.code == ABORT[kind], (
        f"{what}: SDO abort 0x{info.value.code:08X}, CiA 301 requires 0x{ABORT[kind]:08X} ({kind})"
    )
    assert hil_link.read(0x1000) is not None  # still serving well-formed requests


@pytest.mark.requirement("REQ-PROT-002")
def test_heartbeat_period_matches_0x1017(hil_dut, hil_link, hil_budget, hil_evidence):
    _need(hil_dut, "canopen")
    period_ms = 50
    stamps = []
    hil_link.write(0x1017, None, period_ms)

    def on_heartbeat(cid, data, ts):
        if bytes(data) != b"\x00":
            stamps.append(time.monotonic())

    hil_link.network.subscribe(0x700 + hil_link.node_id, on_heartbeat)
    try:
        time.sleep(1.0)
    finally:
        hil_link.network.unsubscribe(0x700 + hil_link.node_id, on_heartbeat)  # the link's own boot-up listener stays
        hil_link.write(0x1017, None, 100)
    intervals = np.diff(stamps[1:])
    assert len(intervals) >= 10, f"only {len(stamps)} heartbeats in 1 s at a {period_ms} ms period"
    hil_evidence.value("heartbeats in 1 s", len(stamps))
    hil_evidence.value("median heartbeat period", float(np.median(intervals) * 1e3), "ms")
    hil_budget("heartbeat_period_error", abs(float(np.median(intervals)) / (period_ms / 1e3) - 1.0))


@pytest.mark.requirement("REQ-PROT-002", "REQ-CAL-005")
def test_refused_calibration_sends_emcy_and_sets_0x1001(hil_dut, hil_link, calibrate, hil_evidence):
    _need(hil_dut, "canopen")
    bad = calibrate(())
    bad = bad.__class__.from_json_dict({**bad.to_json_dict(), "conditioning_delay_s": {"rise": 1e-3, "fall": 0.0}})
    while not hil_link.emcy.empty():
        hil_link.emcy.get_nowait()
    with pytest.raises(LinkError, match="0x06090030"):
        hil_link.download_calibration(bad)
    _, frame = hil_link.emcy.get(timeout=hil_link.timeout_s)
    code, register = struct.unpack_from("<HB", frame)
    hil_evidence.value("EMCY error code", f"0x{code:04X}")
    hil_evidence.value("error register (0x1001)", f"0x{hil_link.read(0x1001):02X}")
    assert register & 0x01 and hil_link.read(0x1001) & 0x01, (
        "the error register's generic bit must be set with the EMCY"
    )
    assert hil_link.read(0x1003, 0) >= 1 and hil_link.read(0x1003, 1) == code, (
        "0x1003:1 must hold the newest error code"
    )


def _modbus_ask(link, pdu: bytes) -> bytes:
    with socket.create_connection((link.host, link.port), timeout=link.timeout_s) as s:
        s.sendall(struct.pack(">HHHB", 0x1234, 0, len(pdu) + 1, link.unit) + pdu)
        reply = s.recv(260)
    assert struct.unpack_from(">H", reply, 0)[0] == 0x1234, "the answer must carry the request's transaction id"
    return reply[7:]


@pytest.mark.requirement("REQ-PROT-003")
@pytest.mark.parametrize(
    "name, pdu, code",
    [
        pytest.param("unknown function code 0x41", bytes([0x41, 0, 0]), 0x01, id="function-0x41"),
        pytest.param("read 1 register at 0xFFF0", struct.pack(">BHH", 3, 0xFFF0, 1), 0x02, id="register-0xFFF0"),
        pytest.param("read quantity 0", struct.pack(">BHH", 3, 0, 0), 0x03, id="quantity-0"),
        pytest.param("read quantity 126", struct.pack(">BHH", 3, 0, 126), 0x03, id="quantity-126"),
    ],
)
def test_modbus_exception_codes(name, pdu, code, hil_dut, hil_link, hil_evidence):
    _need(hil_dut, "modbus")
    if hil_link.serial_port is not None:
        pytest.skip("raw ADUs are sent over TCP only")
    answer = _modbus_ask(hil_link, pdu)
    hil_evidence.value(f"answer to {name}", answer.hex())
    assert answer[0] == (pdu[0] | 0x80) and answer[1] == code, (
        f"{name}: answered {answer.hex()}, the Modbus application protocol requires exception {code:02d}"
    )
    assert hil_link.identity()["vendor_id"]  # still serving
