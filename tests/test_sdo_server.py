"""The virtual controller's SDO server against CiA 301, probed with raw frames (no SDO client
library in between): stateful sequences of interleaved, abandoned, over-long and toggled-wrong
transfers, each answer checked against what the standard requires and against the device's
known values (its identity and firmware string, the set point this test wrote).

The oracle is the protocol itself: which transfer is open (at most one), which toggle bit the
next segment must carry, how many bytes the client declared. Hypothesis seeds are fixed
(derandomize) so a failure replays."""

from __future__ import annotations

import itertools
import struct

import can
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, precondition, rule

from bldc.contract import Strategy
from hil.controller.virtual import VirtualController
from hil.dut.canopen_device import CanopenDevice
from plant_models import paper_bench

CONFIG = paper_bench(with_deviations=True)
NODE = 5
RX, TX = 0x600 + NODE, 0x580 + NODE
_channels = itertools.count()

# CiA 301 abort codes
COMMAND, TOGGLE, NO_OBJECT, NO_SUB, TOO_HIGH, TOO_LOW = (
    0x05040001,
    0x05030000,
    0x06020000,
    0x06090011,
    0x06070012,
    0x06070013,
)

#: readable objects and what they hold (None: any value of this many bytes)
KNOWN = {
    (0x100A, 0): b"vc-0.1.0",
    (0x1000, 0): struct.pack("<I", 0x192),
    (0x1018, 4): struct.pack("<I", 1),
    (0x1018, 1): struct.pack("<I", 0xB1D),
    (0x2100, 8): 8,
}
SPEED = (0x2001, 0)  #: REAL32, rw, 0..30000


class Probe:
    """A raw CAN client: one request frame, one answer frame (or none)."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel, can_filters=[{"can_id": TX, "can_mask": 0x7FF}])
        self.sent = 0

    def ask(self, data: bytes, answer: bool = True) -> bytes | None:
        self.bus.send(can.Message(arbitration_id=RX, data=data, is_extended_id=False))
        self.sent += 1
        if not answer:
            return None
        msg = self.bus.recv(timeout=2.0)
        assert msg is not None, f"no answer to {data.hex()}"
        return bytes(msg.data)

    def silent(self, wait_s: float = 0.05) -> bool:
        return self.bus.recv(timeout=wait_s) is None


def mux(index, sub):
    return struct.pack("<HB", index, sub)


def abort_of(answer: bytes):
    assert answer[0] == 0x80, f"expected an abort, got {answer.hex()}"
    return struct.unpack_from("<HBL", answer, 1)


@pytest.fixture(scope="module")
def device():
    channel = f"sdo{next(_channels)}"
    dev = CanopenDevice(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA), node_id=NODE, channel=channel)
    probe = Probe(channel)
    yield dev, probe
    probe.bus.shutdown()
    dev.close()


# --- single cases from the hold-out list -------------------------------------------------------


def test_invalid_command_specifier_names_its_own_object(device):
    _, p = device
    p.ask(bytes([0x40]) + mux(0x1018, 1) + bytes(4))
    assert abort_of(p.ask(bytes([0xE0, 0x22, 0x22, 0x01]) + bytes(4))) == (0x2222, 1, COMMAND)


def test_segment_after_an_interleaved_expedited_read_is_aborted(device):
    _, p = device
    assert p.ask(bytes([0x40]) + mux(0x100A, 0) + bytes(4))[0] == 0x41  # segmented upload begins
    assert p.ask(bytes([0x40]) + mux(0x1000, 0) + bytes(4))[0] == 0x43  # another object, expedited
    assert abort_of(p.ask(bytes([0x60]) + bytes(7)))[2] == COMMAND  # no leftover bytes of 0x100A


def test_segment_after_a_finished_upload_is_aborted(device):
    _, p = device
    p.ask(bytes([0x40]) + mux(0x100A, 0) + bytes(4))
    first, second = p.ask(bytes([0x60]) + bytes(7)), p.ask(bytes([0x70]) + bytes(7))
    assert first[1:8] + second[1:2] == b"vc-0.1.0" and second[0] & 1  # 7 + 1 bytes, last flagged
    assert abort_of(p.ask(bytes([0x60]) + bytes(7)))[2] == COMMAND


def test_download_past_its_declared_size_is_aborted_at_once(device):
    dev, p = device
    assert p.ask(bytes([0x21]) + mux(*SPEED) + struct.pack("<I", 4))[0] == 0x60
    assert p.ask(bytes([0x08]) + bytes(7)) == bytes([0x20]) + bytes(7)  # 3 bytes of 4
    assert abort_of(p.ask(bytes([0x10]) + bytes(7))) == (*SPEED, TOO_HIGH)  # 10 of 4: refused on this segment
    for k in range(2000):  # the client goes on: every further segment has no transfer to belong to
        assert abort_of(p.ask(bytes([(k & 1) << 4]) + bytes(7)))[2] == COMMAND


def test_a_wrong_length_frame_is_aborted_and_ends_the_transfer(device):
    _, p = device
    p.ask(bytes([0x40]) + mux(0x100A, 0) + bytes(4))
    assert abort_of(p.ask(bytes([0x60, 0, 0])))[2] == COMMAND
    assert abort_of(p.ask(bytes([0x60]) + bytes(7)))[2] == COMMAND


def test_expedited_download_with_and_without_a_size(device):
    _, p = device
    strategy = (0x2000, 0)  # U8, 0..3
    assert p.ask(bytes([0x22]) + mux(*strategy) + bytes([2, 0xEE, 0xEE, 0xEE])) == bytes([0x60]) + mux(
        *strategy
    ) + bytes(4)
    assert p.ask(bytes([0x40]) + mux(*strategy) + bytes(4))[:5] == bytes([0x4F]) + mux(*strategy) + bytes([2])
    assert abort_of(p.ask(bytes([0x27]) + mux(*strategy) + bytes([1, 0, 0, 0]))) == (
        *strategy,
        0x06070010,
    )  # 3 bytes for a U8
    assert p.ask(bytes([0x2F]) + mux(*strategy) + bytes([3, 0, 0, 0]))[0] == 0x60


# --- stateful fuzzing ----------------------------------------------------------------------------


class SdoProtocol(RuleBasedStateMachine):
    """At most one transfer open; the device must answer every request as CiA 301 says."""

    probe: Probe = None  # set by the test

    @initialize()
    def start(self):
        self.open = (
            None  # ("up", (index, sub), remaining bytes, toggle) | ("down", (index, sub), declared, received, toggle)
        )
        self.last_mux = None
        self.speed = None  # last set point this test wrote (None: not yet known)
        self.frames = 0
        # a client abort ends whatever an earlier example left open, so examples replay alike
        self.probe.ask(bytes([0x80]) + mux(*SPEED) + struct.pack("<I", 0x08000000), answer=False)

    def ask(self, data, answer=True):
        self.frames += 1
        return self.probe.ask(data, answer)

    @rule(key=st.sampled_from(sorted(KNOWN)))
    def initiate_upload(self, key):
        answer = self.ask(bytes([0x40]) + mux(*key) + bytes(4))
        truth = KNOWN[key]
        size = truth if isinstance(truth, int) else len(truth)
        assert answer[1:4] == mux(*key)
        if size <= 4:
            assert answer[0] == 0x43 | ((4 - size) << 2)
            if not isinstance(truth, int):
                assert answer[4 : 4 + size] == truth
            self.open = None
        else:
            assert answer[0] == 0x41 and struct.unpack_from("<I", answer, 4)[0] == size
            self.open = ("up", key, truth if not isinstance(truth, int) else bytes(size), 0, isinstance(truth, int))
        self.last_mux = key

    @rule(index=st.integers(0x6000, 0x6FFF) | st.sampled_from([0x1018, 0x2010]), sub=st.integers(0x20, 0xFF))
    def initiate_upload_of_nothing(self, index, sub):
        code = NO_OBJECT if index >= 0x6000 else NO_SUB
        assert abort_of(self.ask(bytes([0x40]) + mux(index, sub) + bytes(4))) == (index, sub, code)
        self.open, self.last_mux = None, (index, sub)

    @rule(wrong_toggle=st.booleans())
    def upload_segment(self, wrong_toggle):
        toggle = (self.open[3] if self.open and self.open[0] == "up" else 0) ^ wrong_toggle
        answer = self.ask(bytes([0x60 | (toggle << 4)]) + bytes(7))
        if not self.open or self.open[0] != "up":
            assert abort_of(answer)[2] == COMMAND
            self.open = None
            return
        _, key, remaining, expected_toggle, any_value = self.open
        if wrong_toggle:
            assert abort_of(answer) == (*key, TOGGLE)
            self.open = None
            return
        chunk, rest = remaining[:7], remaining[7:]
        assert answer[0] >> 5 == 0 and (answer[0] >> 4) & 1 == expected_toggle
        assert 7 - ((answer[0] >> 1) & 7) == len(chunk) and bool(answer[0] & 1) == (not rest)
        if not any_value:
            assert answer[1 : 1 + len(chunk)] == chunk
        self.open = None if not rest else ("up", key, rest, expected_toggle ^ 1, any_value)

    @rule(declared=st.sampled_from([None, 4, 4, 4, 2, 9]))
    def initiate_segmented_download(self, declared):
        head = bytes([0x21 if declared is not None else 0x20]) + mux(*SPEED) + struct.pack("<I", declared or 0)
        answer = self.ask(head)
        self.last_mux = SPEED
        if declared not in (None, 4):
            assert abort_of(answer) == (*SPEED, TOO_HIGH if declared > 4 else TOO_LOW)
            self.open = None
            return
        assert answer == bytes([0x60]) + mux(*SPEED) + bytes(4)
        self.open = ("down", SPEED, declared, b"", 0)

    @rule(rpm=st.floats(0.0, 30000.0, width=32), n=st.integers(1, 7), last=st.booleans(), wrong_toggle=st.booleans())
    def download_segment(self, rpm, n, last, wrong_toggle):
        toggle = (self.open[4] if self.open and self.open[0] == "down" else 0) ^ wrong_toggle
        payload = struct.pack("<f", rpm) + b"\xaa" * 3
        if self.open and self.open[0] == "down":
            payload = payload[len(self.open[3]) :]  # continue the value where the transfer is
        payload = payload[:n].ljust(n, b"\xaa")
        answer = self.ask(bytes([(toggle << 4) | ((7 - n) << 1) | last]) + payload.ljust(7, b"\0"))
        if not self.open or self.open[0] != "down":
            assert abort_of(answer)[2] == COMMAND
            self.open = None
            return
        _, key, declared, received, expected_toggle = self.open
        if wrong_toggle:
            assert abort_of(answer) == (*key, TOGGLE)
            self.open = None
            return
        received += payload
        limit = declared if declared is not None else 4  # REAL32: four bytes at most
        if len(received) > limit:
            assert abort_of(answer) == (*key, TOO_HIGH)  # at once, on the segment that passed it
            self.open = None
            return
        if not last:
            assert answer == bytes([0x20 | (expected_toggle << 4)]) + bytes(7)
            self.open = ("down", key, declared, received, expected_toggle ^ 1)
            return
        self.open = None
        if declared is not None and len(received) < declared:
            assert abort_of(answer) == (*key, TOO_LOW)
        elif len(received) != 4:
            assert abort_of(answer)[2] in (0x06070010, TOO_LOW)
        else:
            assert answer == bytes([0x20 | (expected_toggle << 4)]) + bytes(7)
            self.speed = struct.unpack("<f", received)[0]

    @rule()
    def client_aborts(self):
        self.ask(bytes([0x80]) + mux(*(self.last_mux or SPEED)) + struct.pack("<I", 0x08000000), answer=False)
        self.open = None

    @rule(
        ccs=st.sampled_from([5, 6, 7]), index=st.integers(0, 0xFFFF), sub=st.integers(0, 0xFF), low=st.integers(0, 31)
    )
    def other_command(self, ccs, index, sub, low):
        answer = self.ask(bytes([(ccs << 5) | low]) + mux(index, sub) + bytes(4))
        assert abort_of(answer) == (index, sub, COMMAND)
        self.open, self.last_mux = None, (index, sub)

    @rule(length=st.integers(0, 7))
    def short_frame(self, length):
        answer = self.ask(bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])[:length])
        assert abort_of(answer)[2] == COMMAND
        self.open = None

    @precondition(lambda self: self.speed is not None and self.open is None)
    @rule()
    def set_point_reads_back(self):
        answer = self.ask(bytes([0x40]) + mux(*SPEED) + bytes(4))
        assert answer[:4] == bytes([0x43]) + mux(*SPEED) and struct.unpack_from("<f", answer, 4)[0] == self.speed
        self.last_mux = SPEED


SdoProtocol.TestCase.settings = settings(
    max_examples=150,
    stateful_step_count=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)


def test_stateful_sdo_sequences(device):
    dev, probe = device
    SdoProtocol.probe = probe
    before = probe.sent
    SdoProtocol.TestCase().runTest()
    print(f"\nstateful SDO probe: {probe.sent - before} request frames")
    assert probe.silent(), "an answer nobody asked for (a client abort must not be answered)"
    assert probe.sent - before > 3000  # the sequences are long enough to mean something
    assert not dev.network.notifier.stopped
