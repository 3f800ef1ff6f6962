"""hil.dut.virtual_can: the CANopen device and link in one process, each frame taken in the sending thread.

What crosses the bus must not depend on it: the same run puts the same frames on the channel,
in the same order, whether the two ends take them inline or through python-can's notifier threads."""

import itertools
import logging

import can
import canopen
import pytest

from bldc.contract import Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import LockstepBench
from hil.calibration.campaign import station_corrections
from hil.controller.virtual import VirtualController
from hil.dut.canopen_device import CanopenDevice
from hil.dut.canopen_link import CanopenLink
from hil.dut.link import LinkError
from hil.dut.spec import open_dut
from hil.dut.virtual_can import InlineReceiver, VirtualCanBus, receive_inline
from plant_models import paper_bench

CONFIG = paper_bench(with_deviations=True)
HEARTBEAT = 0x700 + 5  #: sent on the device's own clock: not part of a run's frames
_channels = itertools.count()


def _frames_of_a_run(inline: bool, corrections) -> list[tuple[int, bytes]]:
    """Every frame a short lockstep run (calibration download, two set points) puts on the
    channel, as a third node on it sees them (python-can's own virtual bus)."""
    channel = f"vcan{next(_channels)}"
    sniffer = can.Bus(interface="virtual", channel=channel)
    vc = VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA, speed_setpoint_rpm=6000.0)
    dev = CanopenDevice(vc, node_id=5, channel=channel, inline=inline)
    link = CanopenLink(node_id=5, channel=channel, timeout_s=1.0, inline=inline)
    try:
        link.download_calibration(corrections)
        bench = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
        bench.run_setpoints([6000.0, 6300.0], hold_s=0.05, settle_s=0.02)
        edges = bench.source.edges
    finally:
        link.close()
        dev.close()
    frames = []
    while (msg := sniffer.recv(timeout=0.5)) is not None:
        if msg.arbitration_id != HEARTBEAT:
            frames.append((msg.arbitration_id, bytes(msg.data)))
    sniffer.shutdown()
    assert edges > 50
    return frames


def test_the_same_run_puts_the_same_frames_on_the_bus_inline_and_through_notifier_threads():
    corrections = station_corrections(CONFIG, seed=0)
    threaded, inline = _frames_of_a_run(False, corrections), _frames_of_a_run(True, corrections)
    assert len(threaded) > 500
    assert {cob for cob, _ in threaded} >= {0x205, 0x305, 0x185, 0x605, 0x585}  # RPDO1, RPDO2, TPDO1, SDO
    assert inline == threaded


def test_frames_cross_between_plain_and_inline_receivers_with_their_fields():
    channel = f"vcan{next(_channels)}"
    plain = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network()
    network.bus = VirtualCanBus(channel=channel)
    receive_inline(network)
    taken = []
    network.subscribe(0x123, lambda cob, data, ts: taken.append((cob, bytes(data), ts)))
    try:
        plain.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01\x02\x03"))
        assert [t[:2] for t in taken] == [(0x123, b"\x01\x02\x03")]  # before send returned: inline
        network.send_message(0x456, b"\xAA\xBB")
        msg = plain.recv(timeout=1.0)
        assert (msg.arbitration_id, bytes(msg.data), msg.dlc, msg.is_rx, msg.channel) == (
            0x456, b"\xAA\xBB", 2, True, channel)
        assert not msg.is_extended_id and msg.timestamp > 0
        plain.send(can.Message(arbitration_id=0x123, is_remote_frame=True, is_extended_id=False))
        assert len(taken) == 1  # a remote frame is dropped, as canopen's MessageListener drops it
    finally:
        network.disconnect()
        plain.shutdown()
    assert not any(isinstance(r, InlineReceiver) for r in can.interfaces.virtual.channels.get(channel, []))


def test_a_failing_subscriber_is_logged_and_the_sender_goes_on(caplog):
    channel = f"vcan{next(_channels)}"
    network = canopen.Network()
    network.bus = VirtualCanBus(channel=channel)
    receive_inline(network)
    network.subscribe(0x123, lambda *_: 1 / 0)
    sender = VirtualCanBus(channel=channel)
    try:
        with caplog.at_level(logging.ERROR, logger="hil.dut.virtual_can"):
            sender.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x00"))
        assert "0x123" in caplog.text and "ZeroDivisionError" in caplog.text
    finally:
        sender.shutdown()
        network.disconnect()


def test_inline_needs_the_virtual_interface():
    with pytest.raises(LinkError, match="virtual interface"):
        CanopenLink(interface="socketcand", channel="can0", host="127.0.0.1", port=1, inline=True)
    with pytest.raises(ValueError, match="virtual interface"):
        CanopenDevice(VirtualController(CONFIG.motor), interface="socketcand", channel="can0", inline=True)


def test_the_virtual_canopen_dut_runs_inline():
    """``--dut virtual:canopen``: neither end has a notifier thread."""
    with open_dut("virtual:canopen", CONFIG.motor) as dut:
        device = dut._closers[0].__self__
        assert isinstance(device, CanopenDevice)
        for network in (dut.link.network, device.network):
            assert network.notifier is None
            assert isinstance(network.bus.queue, InlineReceiver)
        assert dut.link.identity()["vendor_id"] == 0x0B1D  # an SDO exchange, answered inline
