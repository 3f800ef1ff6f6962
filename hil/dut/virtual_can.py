"""python-can's ``virtual`` bus for a CANopen device and its host in one process.

``hil acceptance --dut virtual:canopen`` puts the virtual controller (hil.dut.canopen_device) and
the framework's CANopen link (hil.dut.canopen_link) on one python-can ``virtual`` channel. Every
frame crosses it as a ``can.Message``, and each side's canopen ``Network`` dispatches it to the
same subscribers, object dictionary and SDO server a real bus would; only the hand-over between
the two is cheaper:

- ``VirtualCanBus.send`` builds each receiver's copy of a frame directly. python-can 4.6.1's
  ``VirtualBus.send`` deep-copies the message for every receiver, about half of the bus's cost
  per frame, for a message whose data it then replaces anyway.
- ``receive_inline(network)`` feeds a canopen ``Network`` every frame of the channel in the
  thread that sends it (``Network.notify``, canopen's documented entry for a custom interface),
  instead of through a receive queue and a ``can.Notifier`` thread. An edge message is 4-56
  frames and its reply 1-4: with both sides inline an edge costs no thread hand-over at all;
  through the queues it cost three (link -> device -> link notifier -> link), each a wake-up and
  a GIL hand-over, together about half of the virtual CANopen link's time per edge on two busy
  cores. The frames, their order and their bytes are the same; the device answers before the
  frame's ``send`` returns, as a device infinitely faster than the bus would.

Plain ``VirtualBus`` instances on the same channel (a test's sniffer, the socketcand server of
``hil dut serve``) still receive every frame through their queues, and an inline receiver takes
theirs.
"""

from __future__ import annotations

import logging
import time

import can
from can.interfaces.virtual import VirtualBus, channels_lock

log = logging.getLogger(__name__)


class InlineReceiver:
    """Stands in a virtual channel's list of receive queues: a frame ``put`` in it goes to the
    network's subscribers at once, in the sender's thread (as canopen's ``MessageListener`` would
    from its notifier: error and remote frames are dropped, a failing callback is logged)."""

    def __init__(self, network):
        self.network = network

    def take(self, can_id: int, data: bytes, timestamp: float) -> None:
        try:
            self.network.notify(can_id, data, timestamp)
        except Exception as exc:  # a subscriber's fault must not become the sender's
            log.error("CANopen frame 0x%03X: %s: %s", can_id, type(exc).__name__, exc)

    def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
        """From a plain ``VirtualBus`` on the channel (queue.Queue's signature)."""
        if not (msg.is_error_frame or msg.is_remote_frame):
            self.take(msg.arbitration_id, bytes(msg.data), msg.timestamp)

    def qsize(self) -> int:
        return 0  # nothing ever waits here


class VirtualCanBus(VirtualBus):
    """python-can's ``virtual`` bus (the same channels, interoperable with plain ``VirtualBus``)
    whose ``send`` copies a frame for each receiver without ``deepcopy``."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        all_sent = True
        for receiver in list(self.channel):
            if receiver is self.queue and not self.receive_own_messages:
                continue
            if isinstance(receiver, InlineReceiver):
                if not (msg.is_error_frame or msg.is_remote_frame):
                    receiver.take(msg.arbitration_id, data, timestamp)
                continue
            copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, channel=self.channel_id,
                dlc=msg.dlc, data=data, is_fd=msg.is_fd, is_rx=receiver is not self.queue,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
            )
            try:
                receiver.put(copy, block=True, timeout=timeout)
            except Exception:  # queue.Full
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def receive_inline(network) -> None:
    """Connect a canopen ``Network`` whose ``bus`` is a ``VirtualCanBus`` without a notifier: the
    frames on its channel reach its subscribers in the thread that sends them."""
    bus = network.bus
    receiver = InlineReceiver(network)
    with channels_lock:
        bus.channel[bus.channel.index(bus.queue)] = receiver
        bus.queue = receiver  # VirtualBus.shutdown takes it off the channel
