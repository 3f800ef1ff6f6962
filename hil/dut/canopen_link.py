"""The CANopen client link: the framework's view of a CANopen controller on any python-can
interface, through its device profile (hil.dut.profile; the objects' values through
hil.dut.role_link). Edges go out on the profile's receive COB-IDs in the messages of
bldc.contract; the reply comes back on its transmit COB-ID.
"""

from __future__ import annotations

import os
import queue
import socket
import struct
import threading
import time

import can
import canopen
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from bldc.contract import CommandMessage, EdgeMessage, edge_epoch

from ..calibration.corrections import Corrections
from .can_interfaces import unknown_can_interface
from .canopen_codec import NMT_RESET_NODE, NMT_START
from .eds import object_dictionary, read_eds
from .link import LinkError, LinkTimeout
from .profile import Profile, bound_profile
from .role_link import RoleLink
from .traffic import LinkTraffic
from .virtual_can import VirtualCanBus, receive_inline


class MuxCheckedSdoClient(SdoClient):
    """An SDO client that matches each answer's multiplexer to its request.

    canopen 2.4.1 takes the first frame on the response COB-ID as the answer. A device's late
    answer to an earlier request (a timed-out read, or a malformed request another node sent)
    would then be taken for this request's answer, or its abort raised for it. Aborts and
    initiate responses carry the index and sub-index; one for another object is dropped and
    the wait goes on. Segment responses carry none and are taken as they come."""

    _expected_mux: bytes | None = None

    def send_request(self, request):
        command = request[0] >> 5
        # initiate download (1) and upload (2) name the object; segment requests do not
        self._expected_mux = bytes(request[1:4]) if command in (1, 2) else None
        super().send_request(request)

    def read_response(self):
        deadline = time.monotonic() + self.RESPONSE_TIMEOUT
        while True:
            try:
                response = self.responses.get(block=True, timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                raise SdoCommunicationError("No SDO response received") from None
            aborted = response[0] == 0x80
            names_object = aborted or (response[0] >> 5) in (2, 3)  # abort, initiate upload / download response
            if self._expected_mux is not None and names_object and bytes(response[1:4]) != self._expected_mux:
                continue  # an answer to another request
            if aborted:
                raise SdoAbortedError(struct.unpack_from("<L", response, 4)[0])
            return response


def _open_bus(where: str, interface: str, channel: str, timeout_s: float, bus_kwargs: dict):
    """A python-can bus for the link, or a one-line LinkError naming what is wrong.

    For ``socketcand`` the server is reached first with our own timeout (python-can's client
    retries a refused connection in a busy loop for 10 s, logging each attempt), and the bus is
    fenced: when the server closes the connection the client would spin on the empty socket and
    later raise BrokenPipeError; instead its sends raise CanOperationError, which the link
    reports as a LinkError naming the node and the request."""

    if why := unknown_can_interface(interface):
        raise LinkError(f"{where}: {why}")
    if interface == "socketcand":
        host, port = bus_kwargs.get("host"), bus_kwargs.get("port")
        if not host or not port:
            raise LinkError(f"{where}: the socketcand interface needs host=... and port=...")
        try:
            socket.create_connection((host, port), timeout=timeout_s).close()
        except OSError as exc:
            raise LinkError(f"{where}: cannot reach the socketcand server at {host}:{port}: {exc}") from None
        # python-can's low-latency option (TCP_NODELAY, TCP_QUICKACK; not on Windows): without it an
        # edge's header waits behind its data frames for the server's delayed ACK, about 33 ms an
        # edge on loopback (30 edges/s, against 2,000 and more with it)
        bus_kwargs = {"tcp_tune": os.name != "nt", **bus_kwargs}
    try:
        # python-can's virtual bus, with cheaper copies (hil.dut.virtual_can); any other through python-can
        bus = VirtualCanBus(channel=channel, **bus_kwargs) if interface == "virtual" else can.Bus(
            interface=interface, channel=channel, **bus_kwargs
        )
    except Exception as exc:  # a missing driver, a wrong channel, a refused handshake
        raise LinkError(f"{where}: cannot open the bus: {type(exc).__name__}: {' '.join(str(exc).split())}") from None
    if interface == "socketcand":
        _fence_socketcand(bus)
    return bus


def _fence_socketcand(bus) -> None:
    """python-can 4.6.1's socketcand client: a closed connection becomes CanOperationError."""

    sock = bus._SocketCanDaemonBus__socket
    recv, send = bus._recv_internal, bus.send
    closed = threading.Event()

    def _recv_internal(timeout):
        if closed.is_set():
            time.sleep(timeout or 0.1)  # nothing will come; do not spin the notifier
            return None, False
        msg, filtered = recv(timeout)
        if msg is None:
            try:
                closed_now = sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
            except BlockingIOError:
                closed_now = False
            except OSError:
                closed_now = True
            if closed_now:
                closed.set()
        return msg, filtered

    def _send(msg, timeout=None):
        if closed.is_set():
            raise can.CanOperationError("the socketcand server closed the connection")
        try:
            send(msg, timeout)
        except OSError as exc:
            closed.set()
            raise can.CanOperationError(f"the socketcand server closed the connection ({exc})") from None

    bus._recv_internal, bus.send = _recv_internal, _send


class CanopenLink(RoleLink):
    """The framework's view of a CANopen controller on any python-can interface, through its profile."""

    name = "canopen"

    def __init__(
        self,
        node_id: int = 5,
        interface: str = "virtual",
        channel: str = "hil",
        eds: str | None = None,
        timeout_s: float = 1.0,
        profile: Profile | str | None = None,
        pole_pairs: int = 2,
        inline: bool = False,
        **bus_kwargs,
    ):
        """``profile``: the device's object dictionary map (default: the virtual controller's own);
        ``eds``: the device's EDS, which gives the type of each object the profile leaves untyped;
        ``inline``: on python-can's ``virtual`` interface, take each frame in the thread that sends
        it, with no notifier thread (hil.dut.virtual_can: a device in the same process)."""
        self.node_id, self.timeout_s = node_id, timeout_s
        device_od = read_eds(eds, node_id) if eds else None
        self.profile = bound_profile("canopen", profile, pole_pairs, node_id, device_od)
        self.applied_calibration: Corrections | None = None
        where = f"{interface}:{channel}" + (
            f"@{bus_kwargs['host']}:{bus_kwargs.get('port')}" if "host" in bus_kwargs else ""
        )
        self.where = f"CANopen node {node_id} on {where}"
        self.network = canopen.Network()
        if inline and interface != "virtual":
            raise LinkError(f"{self.where}: only python-can's virtual interface can be received inline")
        self.network.bus = _open_bus(self.where, interface, channel, timeout_s, bus_kwargs)
        if inline:
            receive_inline(self.network)
        else:
            self.network.connect()
        # the device's own EDS, else the dictionary the profile describes
        self.node = self.network.add_node(
            node_id, device_od if device_od is not None else object_dictionary(self.profile, node_id)
        )
        # the client is already subscribed to the response COB-ID; swapping its class keeps that
        # subscription and adds the multiplexer check
        self.node.sdo.__class__ = MuxCheckedSdoClient
        self.node.sdo.RESPONSE_TIMEOUT = timeout_s
        # canopen 2.4.1 counts retries down and stops at zero: MAX_RETRIES = 0 would retry forever
        # (-1 is truthy); 1 means a single attempt, so a silent node fails within timeout_s
        self.node.sdo.MAX_RETRIES = 1
        # SimpleQueue: a reply frame is put and taken in a few microseconds less than by a Queue
        self.replies: queue.SimpleQueue = queue.SimpleQueue()
        self.emcy: queue.SimpleQueue = queue.SimpleQueue()
        hook = self.profile.edge_hook
        if hook.kind == "pdo":
            self.network.subscribe(hook.tx_cob_id, lambda cid, data, ts: self.replies.put(bytes(data)))
        self.network.subscribe(0x80 + node_id, lambda cid, data, ts: self.emcy.put((ts, bytes(data))))
        self.boot_ups: queue.SimpleQueue = queue.SimpleQueue()
        self.network.subscribe(0x700 + node_id, lambda cid, data, ts: bytes(data) == b"\x00" and self.boot_ups.put(ts))
        self._seq = 0
        self.traffic = LinkTraffic("canopen")  #: what the edges moved on the bus (hil.dut.traffic)
        self._send("NMT start", 0, bytes([NMT_START, node_id]))

    def _send(self, what: str, can_id: int, data: bytes) -> None:
        try:
            self.network.send_message(can_id, data)
        except Exception as exc:  # the transport itself failed (a closed remote bus, a dead adapter)
            raise LinkError(f"{self.where}: {what} could not be sent: {type(exc).__name__}: {exc}") from None

    def reset(self) -> None:
        """The profile's reset action when it lists one; else NMT reset node (faults cleared, logic
        restarted: CiA 301's reset application), wait for the boot-up, then start."""
        if self.profile.has("clear_faults"):
            self.act("clear_faults")
        if self.profile.get("reset") is not None:
            self.act("reset")
            self._seq = 0
            return
        for q in (self.boot_ups, self.replies, self.emcy):
            while not q.empty():
                q.get_nowait()
        self._send("NMT reset node", 0, bytes([NMT_RESET_NODE, self.node_id]))
        try:
            self.boot_ups.get(timeout=self.timeout_s)
        except queue.Empty:
            raise LinkTimeout(f"{self.where}: no boot-up within {self.timeout_s} s after NMT reset node") from None
        self._send("NMT start", 0, bytes([NMT_START, self.node_id]))
        self._seq = 0

    # --- SDO helpers -----------------------------------------------------------------------------
    def _sdo(self, what: str, fn):
        try:
            return fn()
        except SdoAbortedError as exc:
            raise LinkError(f"{self.where}: {what} refused with SDO abort 0x{exc.code:08X}") from None
        except SdoCommunicationError as exc:
            raise LinkTimeout(f"{self.where}: no SDO answer to {what} within {self.timeout_s} s ({exc})") from None
        except Exception as exc:  # the transport itself failed (a closed remote bus, a dead adapter)
            raise LinkError(f"{self.where}: {what} failed on the bus: {type(exc).__name__}: {exc}") from None

    def read(self, index: int, sub: int | None = None):
        obj = self.node.sdo[index] if sub is None else self.node.sdo[index][sub]
        return self._sdo(f"read 0x{index:04X}" + ("" if sub is None else f":{sub:02X}"), lambda: obj.raw)

    def write(self, index: int, sub: int | None, value) -> None:
        obj = self.node.sdo[index] if sub is None else self.node.sdo[index][sub]
        self._sdo(
            f"write 0x{index:04X}" + ("" if sub is None else f":{sub:02X}") + f" = {value!r}",
            lambda: setattr(obj, "raw", value),
        )

    # --- RoleLink: raw values of an object by SDO --------------------------------------------------
    def read_raw(self, obj) -> list:
        out = []
        for k in range(obj.count):
            sub = obj.subindex_of(k)
            data = self._sdo(f"read {obj.label(k)} ({obj.role})", lambda: self.node.sdo.upload(obj.index, sub))
            out.append(obj.unpack_le(data))
        return out

    def write_raw(self, obj, raws: list) -> None:
        for k, raw in enumerate(raws):
            self._sdo(
                f"write {obj.label(k)} ({obj.role}) = {raw!r}",
                lambda: self.node.sdo.download(obj.index, obj.subindex_of(k), obj.pack_le(raw)),
            )

    def identity(self) -> dict:
        ident = super().identity()
        ident["device_type"] = self._sdo(
            "read 0x1000", lambda: struct.unpack("<I", self.node.sdo.upload(0x1000, 0)[:4])[0]
        )
        try:  # optional in CiA 301
            ident["firmware"] = self.node.sdo.upload(0x100A, 0).decode("ascii", "replace")
        except Exception:
            ident["firmware"] = None
        return ident

    def edge(self, edge: dict) -> list:
        hook = self.profile.edge_hook
        if hook.kind != "pdo":
            raise LinkError(f"{self.where}: the profile {self.profile.path} gives edges no PDOs ({hook.kind})")
        edge_cob, data_cob = hook.rx_cob_ids[0], (hook.rx_cob_ids[1] if len(hook.rx_cob_ids) > 1 else None)
        epoch = edge_epoch(edge["t_capture_s"])
        seq = self._seq
        self._seq = (self._seq + 1) & 0x7F
        msg = EdgeMessage.from_edge(edge, seq)
        sent = msg.data_frames() if data_cob is not None else []
        for frame in sent:  # the accumulators and the window before their header: the header triggers
            self._send(f"ADC data frame {frame[7]} of edge #{seq}", data_cob, frame)
        self._send(f"edge #{seq}", edge_cob, msg.header())
        sent.append(msg.header())
        commands, received = [], []
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                data = self.replies.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                raise LinkTimeout(
                    f"{self.where}: no TPDO reply to edge #{seq} (t = {edge['t_capture_s']:.7f} s) within "
                    f"{self.timeout_s} s"
                ) from None
            frame = CommandMessage.unpack(data)
            received.append(data)
            if frame.seq != seq:
                continue  # a late frame of an earlier edge
            if not frame.keeps_everything:
                commands.append(frame.to_command(epoch))
            if frame.last:
                self.traffic.can_message(sent, received)
                return commands

    def close(self) -> None:
        try:
            self.network.disconnect()
        except Exception:  # a bus that is already gone cannot be closed more
            pass
