"""Modbus face of the virtual controller (exception codes, register map, robustness) and the Modbus
link, over TCP on 127.0.0.1."""

import socket
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bldc.contract import Fault, Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import LockstepBench
from hil.calibration.campaign import station_corrections
from hil.controller.virtual import VirtualController
from hil.dut.in_process import InProcessLink
from hil.dut.link import LinkError, LinkTimeout
from hil.dut.modbus_device import ModbusDevice
from hil.dut.modbus_link import ModbusLink
from plant_models import paper_bench

CONFIG = paper_bench(with_deviations=True)


@pytest.fixture(scope="module")
def corrections():
    return station_corrections(CONFIG, seed=0)


@pytest.fixture
def device():
    dev = ModbusDevice(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0))
    yield dev
    dev.close()


def ask(port, pdu, unit=1, tid=7, timeout=1.0):
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
        data = s.recv(260)
    return data


def test_binds_loopback_by_default(device):
    assert device.host == "127.0.0.1"


def test_lockstep_over_modbus_tcp_is_identical_to_in_process(device, corrections):
    runs = []
    for link in (
        ModbusLink(port=device.port),
        InProcessLink(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0)),
    ):
        link.download_calibration(corrections)
        b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
        b.run_setpoints([6000.0, 6300.0], hold_s=0.1, settle_s=0.05)
        runs.append(b.sim.commutations())
        link.close()
    a, c = runs
    assert len(a) > 200
    np.testing.assert_array_equal(a.t_s, c.t_s)
    np.testing.assert_array_equal(a.sector, c.sector)


@pytest.mark.parametrize(
    "pdu, answer",
    [
        (bytes([0x41, 0, 0]), "c101"),  # unknown function: 01
        (bytes([0x01, 0, 0, 0, 1]), "8101"),  # coils are not implemented: 01
        (bytes([0x04, 0, 0, 0, 1]), "8401"),  # input registers are not implemented: 01
        (struct.pack(">BHH", 3, 0, 0), "8303"),  # quantity 0: 03
        (struct.pack(">BHH", 3, 0, 126), "8303"),  # quantity above 125: 03
        (struct.pack(">BHH", 3, 5000, 1), "8302"),  # no such register: 02
        (struct.pack(">BHH", 6, 0, 9), "8603"),  # strategy 9 out of range: 03
        (struct.pack(">BHH", 6, 40, 1), "8602"),  # applied calibration is read-only: 02
        (struct.pack(">BHHBH", 16, 0, 1, 4, 1), "9003"),  # byte count does not match: 03
        (struct.pack(">BHHBI", 16, 1, 1, 2, 0), "9003"),  # half a FLOAT32 (speed): 03 (byte count also off)
        (struct.pack(">BHHBH", 16, 2, 1, 2, 0), "9003"),  # the low word of the FLOAT32 alone: 03
        (struct.pack(">BHH", 3, 0, 1), "03020003"),  # a good read: strategy 3
    ],
)
def test_exception_codes(device, pdu, answer):
    reply = ask(device.port, pdu)
    assert struct.unpack_from(">H", reply, 0)[0] == 7  # the transaction of the request, never a stale one
    assert reply[7:].hex() == answer


def test_calibration_download_read_back_and_refusal(device, corrections):
    link = ModbusLink(port=device.port)
    link.download_calibration(corrections)
    assert link.identity()["vendor_id"] == 0x0B1D
    bad = corrections.__class__.from_json_dict(corrections.to_json_dict())
    bad.pole_offset_deg_e[2] = 50.0  # beyond the +-20 deg_e the controller accepts (MAX_POLE_TABLE_OFFSET_DEG_E)
    with pytest.raises(LinkError, match="exception code 03"):
        link.download_calibration(bad)
    st_ = link.status()
    assert st_["error_register"] & 0x81 == 0x81
    assert (0.0, Fault.INVALID_CALIBRATION) in st_["faults"]
    link.close()


def test_dead_controller_gives_a_precise_error_within_the_timeout():
    dev = ModbusDevice(VirtualController(CONFIG.motor))
    link = ModbusLink(port=dev.port, timeout_s=0.5)
    assert link.read(0, 1) == [3]
    dev.close()
    t = time.monotonic()
    with pytest.raises(LinkTimeout, match=r"Modbus unit 1 at 127.0.0.1:\d+: no answer"):
        link.edge({"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0})
    assert time.monotonic() - t < 2.0
    link.close()


ADUS = st.tuples(
    st.integers(0, 0xFFFF),  # transaction id
    st.sampled_from([0, 0, 0, 1, 0xFFFF]),  # protocol id (0 = Modbus)
    st.sampled_from([1, 1, 1, 1, 0, 2, 255]),  # unit (mostly ours)
    st.one_of(
        st.binary(min_size=0, max_size=40),  # any PDU
        st.builds(
            lambda fc, rest: bytes([fc]) + rest,
            st.sampled_from([1, 2, 3, 4, 5, 6, 15, 16, 23, 43, 0x41, 0x83]),
            st.binary(min_size=0, max_size=12),
        ),
    ),
    st.sampled_from([True, True, True, False]),  # a truthful MBAP length?
)
RESULTS = []


@settings(max_examples=2000, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(ADUS)
def _fuzz(port, adu):
    tid, proto, unit, pdu, truthful = adu
    length = len(pdu) + 1 if truthful else (len(pdu) + 5) & 0xFFFF
    answer_due = truthful and proto == 0 and unit == 1 and len(pdu) >= 1
    with socket.create_connection(("127.0.0.1", port), timeout=1.0) as s:
        s.sendall(struct.pack(">HHHB", tid, proto, length, unit) + pdu)
        reply = b""
        if answer_due:  # a frame the protocol answers; the others are sent and left
            try:
                reply = s.recv(300)
            except (socket.timeout, ConnectionResetError):
                reply = b""
    if reply:
        # an answer is to this transaction, and is either the request's function or its exception
        assert struct.unpack_from(">H", reply, 0)[0] == tid
        fc = reply[7]
        assert fc in (pdu[0], pdu[0] | 0x80, (pdu[0] | 0x80) & 0xFF)
        if fc & 0x80:
            assert reply[8] in (1, 2, 3, 4)
    RESULTS.append(bool(reply))


def test_two_thousand_malformed_adus_do_not_break_the_device(device):
    RESULTS.clear()
    _fuzz(device.port)
    assert len(RESULTS) >= 2000
    assert sum(RESULTS) > 300  # a good share of the frames called for (and got) an answer
    link = ModbusLink(port=device.port)  # still serving well-formed requests, correctly
    assert link.read(0, 1)[0] in (0, 1, 2, 3) and link.identity()["serial"] == 1
    link.close()


# --- RTU over a null modem (two pseudo-terminals bridged) ------------------------------------------


class NullModem:
    """Two pseudo-terminals whose master sides are bridged: a serial line inside this machine."""

    def __init__(self):
        import os
        import threading

        self.a_master, a_slave = os.openpty()
        self.b_master, b_slave = os.openpty()
        self.a_path, self.b_path = os.ttyname(a_slave), os.ttyname(b_slave)
        self._slaves = (a_slave, b_slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._bridge, daemon=True)
        self._thread.start()

    def _bridge(self):
        import os
        import select

        pairs = {self.a_master: self.b_master, self.b_master: self.a_master}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(pairs), [], [], 0.05)
            for fd in ready:
                try:
                    os.write(pairs[fd], os.read(fd, 1024))
                except OSError:
                    return

    def close(self):
        import os

        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self.a_master, self.b_master, *self._slaves):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def rtu():
    line = NullModem()
    dev = ModbusDevice(
        VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0), serial_port=line.a_path
    )
    link = ModbusLink(serial_port=line.b_path, timeout_s=1.0)
    yield dev, link, line
    link.close()
    dev.close()
    line.close()


def test_rtu_framer_serves_the_same_map_and_exceptions(rtu, corrections):
    dev, link, line = rtu
    assert link.identity()["vendor_id"] == 0x0B1D
    link.download_calibration(corrections)
    commands = link.edge({"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0})
    assert isinstance(commands, list)
    with pytest.raises(LinkError, match="exception code 03"):
        link.write(0, [9])  # strategy 9
    with pytest.raises(LinkError, match="exception code 02"):
        link.read(5000, 1)
    # quantity above 125: 03, not pymodbus's 01 (sent raw: pymodbus's own client refuses to send it)
    import serial
    from pymodbus.framer.rtu import FramerRTU

    link.close()
    frame = struct.pack(">BBHH", 1, 3, 0, 126)
    with serial.Serial(line.b_path, 115200, timeout=1.0) as port:
        port.write(frame + FramerRTU.compute_CRC(frame).to_bytes(2, "big"))
        reply = port.read(5)
    assert reply[:3] == bytes([1, 0x83, 3])
    assert FramerRTU.check_CRC(reply[:3], int.from_bytes(reply[3:5], "big"))
