"""The virtual controller's CANopen face (CiA 301) on a python-can bus, and the CANopen link.

Device: a ``canopen.LocalNode`` with the shipped EDS, behind our own validation (the library
leaves PDOs unlinked, ignores EDS limits, leaves 0x1001/0x1003 untouched on EMCY, sends no
boot-up after an NMT reset and echoes stale indexes in some aborts: docs/controller.md, Library traps).
Edges arrive on the profile's receive COB-IDs (the built-in controller's: the header in RPDO1,
0x200 + node, after its accumulators and ADC window, one data frame each, in RPDO2, 0x300 +
node); commands leave on its transmit COB-ID (TPDO1, 0x180 + node), in the messages of
bldc.contract (edge message version 2).
"""

from __future__ import annotations

import queue
import socket
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from bldc.contract import (
    CalibrationTableError,
    CommandMessage,
    MAX_ADC_SAMPLES,
    EdgeMessage,
    Fault,
    edge_epoch,
    encode_reply,
    filter_vector,
    next_epoch,
    with_filter_vector,
)

from ..calibration.corrections import Corrections
from ..controller.virtual import VirtualController, warm_up
from .can_interfaces import unknown_can_interface
from .link import LinkError, LinkTimeout
from .od import EDS_PATH
from .profile import CANOPEN_TYPE_CODES, ROLES, Profile, ProfileError, load_profile, shipped
from .roles import RoleLink
from .traffic import LinkTraffic
from .virtual_roles import VirtualRoles

ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_READ_ONLY = 0x06010002
ABORT_WRITE_ONLY = 0x06010001
ABORT_RANGE = 0x06090030
ABORT_LENGTH = 0x06070010
ABORT_COMMAND = 0x05040001
ABORT_STATE = 0x08000022
ABORT_TOGGLE = 0x05030000
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_GENERAL = 0x08000000
#: the longest value any object of the shipped EDS holds (VISIBLE_STRINGs are short); a
#: segmented download without a declared size is refused past this
SDO_MAX_DOWNLOAD_BYTES = 256

NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82


@dataclass
class _Transfer:
    """A segmented transfer in progress: which object, which way, how far."""

    index: int
    subindex: int
    upload: bool
    data: bytearray
    declared: int | None = None   #: download: the size the client announced
    limit: int = 0                #: download: bytes beyond this are refused (declared, or the type's size)
    toggle: int = 0               #: the toggle bit the next segment must carry


class SdoServer:
    """A CiA 301 SDO server (expedited and segmented, both ways) on a ``canopen.LocalNode``'s
    object dictionary and read/write callbacks.

    canopen 2.4.1's own server keeps the last transfer's state and index around: a segment
    request after a finished upload, or after an expedited read of another object, is answered
    from what was left; an invalid command is aborted with the previous request's index; a
    segmented download runs on past its declared size. Here the state is explicit: at most one
    transfer is open; any initiate or abort ends it; a segment without an open transfer of its
    direction, or with the wrong toggle bit, is aborted and ends it; a download is aborted with
    0x06070012 the moment it passes its declared size (without one: the type's size, or
    SDO_MAX_DOWNLOAD_BYTES).
    Every abort names the object of the request it answers (a segment: the object of its
    transfer, or of the last transfer when none is open). Block transfers are not offered:
    aborted with 0x05040001 as CiA 301 allows.
    """

    def __init__(self, node: canopen.LocalNode):
        self.node, self.od = node, node.object_dictionary
        self.transfer: _Transfer | None = None
        self._last_mux = (0, 0)

    def request(self, data: bytes) -> bytes | None:
        """The answer to one request frame (None: no answer, after a client's abort)."""
        mux = struct.unpack_from("<HB", data, 1) if len(data) >= 4 else self._last_mux
        if len(data) != 8:
            self.transfer = None
            return self._abort(*mux, ABORT_COMMAND)
        ccs = data[0] >> 5
        if ccs == 4:  # the client aborts: the transfer ends, nothing is answered
            self.transfer = None
            return None
        if ccs in (0, 3):  # segments carry no multiplexer: they belong to the open transfer
            transfer, upload = self.transfer, ccs == 3
            if transfer is None or transfer.upload != upload:
                self.transfer = None
                return self._abort(*self._last_mux, ABORT_COMMAND)
            if (data[0] >> 4) & 1 != transfer.toggle:
                self.transfer = None
                return self._abort(transfer.index, transfer.subindex, ABORT_TOGGLE)
            return self._upload_segment(transfer) if upload else self._download_segment(transfer, data)
        index, subindex = mux
        self.transfer = None  # any initiate ends the transfer before it
        self._last_mux = (index, subindex)
        if ccs not in (1, 2):  # 5, 6: block transfers; 7: no such command
            return self._abort(index, subindex, ABORT_COMMAND)
        try:
            var = self._variable(index, subindex)
            return (
                self._initiate_upload(var, index, subindex)
                if ccs == 2
                else self._initiate_download(var, index, subindex, data)
            )
        except SdoAbortedError as exc:
            self.transfer = None
            return self._abort(index, subindex, exc.code)
        except Exception:  # a callback failed: a general error, and the device lives on
            self.transfer = None
            return self._abort(index, subindex, ABORT_GENERAL)

    def _variable(self, index: int, subindex: int):
        if index not in self.od:
            raise SdoAbortedError(ABORT_NO_OBJECT)
        obj = self.od[index]
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            if subindex != 0:
                raise SdoAbortedError(ABORT_NO_SUBINDEX)
            return obj
        # an ARRAY answers any sub-index in the library (it makes them up): only declared ones exist
        if subindex not in obj.subindices:
            raise SdoAbortedError(ABORT_NO_SUBINDEX)
        return obj[subindex]

    def _initiate_upload(self, var, index: int, subindex: int) -> bytes:
        if not var.readable:
            raise SdoAbortedError(ABORT_WRITE_ONLY)
        value = self.node.get_data(index, subindex)
        if len(value) <= 4:
            return struct.pack("<BHB", 0x43 | ((4 - len(value)) << 2), index, subindex) + value.ljust(4, b"\0")
        self.transfer = _Transfer(index, subindex, True, bytearray(value))
        return struct.pack("<BHBL", 0x41, index, subindex, len(value))

    def _upload_segment(self, t: _Transfer) -> bytes:
        chunk, t.data = bytes(t.data[:7]), t.data[7:]
        last = not t.data
        answer = bytes([(t.toggle << 4) | ((7 - len(chunk)) << 1) | last]) + chunk.ljust(7, b"\0")
        t.toggle ^= 1
        if last:
            self.transfer = None
        return answer

    def _initiate_download(self, var, index: int, subindex: int, data: bytes) -> bytes:
        if not var.writable:
            raise SdoAbortedError(ABORT_READ_ONLY)
        expedited, sized = data[0] & 0x02, data[0] & 0x01
        numeric = var.data_type in canopen.objectdictionary.NUMBER_TYPES
        if expedited:
            # size not indicated: the object's own size (a number), else all four bytes
            unsized = data[4 : 4 + min(len(var) // 8, 4)] if numeric else data[4:8]
            self.node.set_data(index, subindex, data[4 : 8 - ((data[0] >> 2) & 3)] if sized else unsized)
        else:
            declared = struct.unpack_from("<L", data, 4)[0] if sized else None
            if declared is not None and numeric and declared != len(var) // 8:
                raise SdoAbortedError(ABORT_LENGTH_HIGH if declared > len(var) // 8 else ABORT_LENGTH_LOW)
            limit = declared if declared is not None else (len(var) // 8 if numeric else SDO_MAX_DOWNLOAD_BYTES)
            self.transfer = _Transfer(index, subindex, False, bytearray(), declared, limit)
        return struct.pack("<BHBL", 0x60, index, subindex, 0)

    def _download_segment(self, t: _Transfer, data: bytes) -> bytes:
        t.data += data[1 : 8 - ((data[0] >> 1) & 7)]
        if len(t.data) > t.limit:
            self.transfer = None
            return self._abort(t.index, t.subindex, ABORT_LENGTH_HIGH)
        answer = bytes([0x20 | (t.toggle << 4)]) + bytes(7)
        t.toggle ^= 1
        if data[0] & 0x01:  # the last segment: the value is complete
            self.transfer = None
            if t.declared is not None and len(t.data) < t.declared:
                return self._abort(t.index, t.subindex, ABORT_LENGTH_LOW)
            try:
                self.node.set_data(t.index, t.subindex, bytes(t.data))
            except SdoAbortedError as exc:
                return self._abort(t.index, t.subindex, exc.code)
            except Exception:
                return self._abort(t.index, t.subindex, ABORT_GENERAL)
        return answer

    @staticmethod
    def _abort(index: int, subindex: int, code: int) -> bytes:
        return struct.pack("<BHBL", 0x80, index, subindex, code)


class CanopenDevice:
    """Serves a VirtualController as CANopen node ``node_id`` on a python-can bus."""

    def __init__(
        self,
        controller: VirtualController,
        node_id: int = 5,
        interface: str = "virtual",
        channel: str = "hil",
        profile: Profile | str | None = None,
        **bus_kwargs,
    ):
        """Node ``node_id`` on the bus; the dictionary is the shipped EDS for the controller's own
        profile, else one built from ``profile`` (every object it maps, CiA 301's mandatory ones)."""
        self.profile = _profile(profile, controller.motor.pole_pairs, node_id, None)
        own = self.profile.objects == shipped("canopen").bind(controller.motor.pole_pairs, node_id).objects
        if own and controller.motor.pole_pairs != 2:
            raise ValueError("the shipped EDS describes a 2-pole-pair motor (four pole offsets)")
        #: the roles of a foreign profile (None: the shipped EDS's own objects, served below)
        self.roles = None if own else VirtualRoles(controller, self.profile)
        self._cells = {
            (o.index, o.subindex_of(k)): (o, k) for o in self.profile.objects.values() for k in range(o.count)
        }

        warm_up()  # ready before the boot-up message, as firmware is
        self.controller = controller
        self.node_id = node_id
        self.network = canopen.Network()
        # the notifier looks for a stop this often; close() waits for it (canopen's 1 s made
        # ``hil dut serve`` take up to a second longer to exit on SIGTERM)
        self.network.NOTIFIER_CYCLE = 0.05
        self.network.connect(interface=interface, channel=channel, **bus_kwargs)
        od = canopen.import_od(str(EDS_PATH), node_id) if self.roles is None else object_dictionary(self.profile)
        self.node = canopen.LocalNode(node_id, od)
        self.network.add_node(self.node)
        self.od = self.node.object_dictionary
        self.staged = (controller.corrections or Corrections()).as_float32().as_vector()
        self.filter = filter_vector(controller.filter_settings)
        self.history: list[int] = [] if self.roles is None else self.roles.history
        self._epoch = 0
        self._last_ticks: int | None = None
        self._lock = threading.Lock()
        self.state = "PRE-OPERATIONAL"
        # our own SDO server (SdoServer below) on the library's object dictionary and callbacks
        self.sdo_server = SdoServer(self.node)
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.network.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        self.network.unsubscribe(0, self.node.nmt.on_command)
        self.network.subscribe(0, self._on_nmt)
        hook = self.profile.edge_hook
        if hook.kind == "pdo":
            self.network.subscribe(hook.rx_cob_ids[0], self._on_rpdo)
            if len(hook.rx_cob_ids) > 1:
                self.network.subscribe(hook.rx_cob_ids[1], self._on_data)
        self._last_edge = EdgeMessage(0, 0, False, 0)
        #: data frames received since the last edge header: the accumulators and the ADC window of the
        #: edge whose header follows them (bounded: a stream without headers keeps the newest)
        self._data_frames: list[bytes] = []
        self._last_data = bytes(8)  #: the last data frame, for 0x2201 reads
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        controller.on_fault(self._on_fault)
        self._heartbeat_ms = 100
        self._boot()

    # --- NMT -------------------------------------------------------------------------------------
    def _boot(self) -> None:
        self.state = "PRE-OPERATIONAL"
        self.network.send_message(0x700 + self.node_id, b"\x00")  # boot-up
        self._start_heartbeat()

    def _start_heartbeat(self) -> None:
        self.node.nmt.state = self.state
        if self._heartbeat_ms:
            self.node.nmt.start_heartbeat(self._heartbeat_ms)
        else:
            self.node.nmt.stop_heartbeat()

    def _on_nmt(self, can_id, data, timestamp) -> None:
        if (
            len(data) != 2
            or data[1] not in (0, self.node_id)
            or data[0] not in (NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM)
        ):
            return  # malformed or foreign NMT commands are ignored
        cmd = data[0]
        if cmd == NMT_START:
            self.state = "OPERATIONAL"
        elif cmd == NMT_STOP:
            self.state = "STOPPED"
        elif cmd == NMT_PREOP:
            self.state = "PRE-OPERATIONAL"
        elif cmd in (NMT_RESET_NODE, NMT_RESET_COMM):
            if cmd == NMT_RESET_NODE:
                with self._lock:
                    self.controller.clear_faults()
                    self.history.clear()
                    self.controller.reset()
                    self._epoch, self._last_ticks = 0, None
            self._boot()
            return
        self._start_heartbeat()

    # --- SDO ------------------------------------------------------------------------------------
    def _on_sdo(self, can_id, data, timestamp) -> None:
        if self.state == "STOPPED":
            return  # CiA 301: no SDO in STOPPED
        with self._lock:
            answer = self.sdo_server.request(bytes(data))
        if answer is not None:
            self.network.send_message(0x580 + self.node_id, answer)

    def _on_read(self, index, subindex, od):
        if self.roles is not None:
            return self._role_read(index, subindex)
        c = self.controller
        if index == 0x1001:
            return c.error_register
        if index == 0x1003:
            return (
                len(self.history)
                if subindex == 0
                else (self.history[subindex - 1] if subindex <= len(self.history) else 0)
            )
        if index == 0x1017:
            return self._heartbeat_ms
        if index == 0x2000:
            return int(c.strategy)
        if index == 0x2001:
            return c.speed_setpoint_rpm
        if index == 0x2010 and subindex >= 1:
            return self.staged[subindex - 1]
        if index == 0x2012 and subindex >= 1:
            return (c.corrections or Corrections()).as_vector()[subindex - 1]
        if index == 0x2020 and subindex >= 1:
            return self.filter[subindex - 1]
        if index == 0x2101 and subindex >= 1:
            st = c.status()
            return int(st[("gated_edges", "covariance_repairs", "divergence_fades", "band_projections")[subindex - 1]])
        if index == 0x2200 and subindex >= 1:
            e = self._last_edge
            return (e.ticks, (e.sensor & 0x03) | (0x80 if e.rising else 0), e.seq, e.newest_sample_age_ticks)[
                subindex - 1
            ]
        if index == 0x2201 and subindex >= 1:
            return struct.unpack("<hhhBB", self._last_data)[subindex - 1]
        if index == 0x2100 and subindex >= 1:
            st = c.status()
            values = [
                st["estimated_speed_rpm"],
                *st["q_diag"],
                *st["r_diag"],
                st["guard_trips"],
                st["last_predicted_commutation_s"],
            ]
            v = values[subindex - 1]
            return 0.0 if isinstance(v, float) and not np.isfinite(v) else v
        return None

    def _on_write(self, index, subindex, od, data):
        if self.roles is not None:
            return self._role_write(index, subindex, od.decode_raw(data))
        value = od.decode_raw(data)
        limits_low = od.min if od.min is not None else None
        limits_high = od.max if od.max is not None else None
        if isinstance(value, float) and not np.isfinite(value):
            raise SdoAbortedError(ABORT_RANGE)
        if (limits_low is not None and value < limits_low) or (limits_high is not None and value > limits_high):
            raise SdoAbortedError(ABORT_RANGE)
        c = self.controller
        if index == 0x1003 and subindex == 0:
            if value != 0:
                raise SdoAbortedError(ABORT_RANGE)
            self.history.clear()
        elif index == 0x1017:
            self._heartbeat_ms = int(value)
            self._start_heartbeat()
        elif index == 0x2000:
            c.set_strategy(int(value))
        elif index == 0x2001:
            c.set_speed(float(value))
        elif index == 0x2010:
            self.staged[subindex - 1] = float(value)
        elif index == 0x2011:
            try:
                c.download_calibration(Corrections.from_vector(self.staged))
            except CalibrationTableError:
                raise SdoAbortedError(ABORT_RANGE) from None
        elif index == 0x2020:
            new = list(self.filter)
            new[subindex - 1] = float(value)
            try:  # takes effect at the next strategy write or NMT reset, as the filter restarts then
                c.filter_settings = with_filter_vector(c.filter_settings, new)
            except ValueError:
                raise SdoAbortedError(ABORT_RANGE) from None
            self.filter = new

    # --- EMCY ------------------------------------------------------------------------------------
    # --- a foreign profile's objects: the controller's roles, encoded as the profile says ----------
    def _role_read(self, index: int, subindex: int):
        cell = self._cells.get((index, subindex))
        if cell is None:
            return None  # an object of CiA 301's (0x1000, a record's highest sub-index): its default
        obj, k = cell
        if obj.is_action:
            return 0
        return obj.to_raw(self.roles.read(obj.role, obj.count)[k], self.profile.pole_pairs, saturate=True)

    def _role_write(self, index: int, subindex: int, raw) -> None:
        obj, k = self._cells[(index, subindex)]
        try:
            if obj.is_action:
                if raw != obj.write:
                    raise ValueError(f"{obj.role} takes {obj.write}, got {raw!r}")
                self.roles.write(obj.role, [])
                if obj.role == "reset":
                    self._epoch, self._last_ticks = 0, None
                return
            present = self.roles.read(obj.role, obj.count)
            present[k] = obj.from_raw(raw, self.profile.pole_pairs)
            self.roles.write(obj.role, present)
        except ValueError:  # CalibrationTableError and ProfileValueError included
            raise SdoAbortedError(ABORT_RANGE) from None
        if obj.role == "heartbeat_period":
            self._heartbeat_ms = self.roles.heartbeat_ms
            self._start_heartbeat()

    def _on_fault(self, code: int, t_s: float) -> None:
        if self.roles is None:  # a foreign profile's roles keep the history themselves
            self.history.insert(0, code)
            del self.history[8:]
        self.node.emcy.send(self.profile.device_fault(code), self.controller.error_register)

    # --- PDO -------------------------------------------------------------------------------------
    def _on_rpdo(self, can_id, data, timestamp) -> None:
        if self.state != "OPERATIONAL":
            return
        with self._lock:
            frames, self._data_frames = self._data_frames, []
            try:
                msg = EdgeMessage.from_frames(bytes(data), frames)
            except ValueError:
                return  # a malformed PDO or frame set is ignored, as CiA 301 devices do
            self._epoch = next_epoch(self._epoch, self._last_ticks, msg.ticks)
            self._last_ticks = msg.ticks
            self._last_edge = msg
            try:
                commands = self.controller.capture(msg.to_edge(self._epoch))
            except Exception:  # never let bad input kill the receive thread: report and answer
                self.controller.raise_fault(Fault.INTERNAL, 0.0)
                commands = []
            frames = encode_reply(commands, msg.seq)
        for f in frames:
            self.network.send_message(self.profile.edge_hook.tx_cob_id, f.pack())

    def _on_data(self, can_id, data, timestamp) -> None:
        """A data frame (accumulators or one ADC conversion) of the edge whose header follows."""
        if self.state != "OPERATIONAL" or len(data) != 8:
            return
        with self._lock:
            self._data_frames.append(bytes(data))
            del self._data_frames[: -(MAX_ADC_SAMPLES + 3)]
            self._last_data = bytes(data)

    def close(self) -> None:
        try:
            self.node.nmt.stop_heartbeat()
        finally:
            self.network.disconnect()


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
    try:
        bus = can.Bus(interface=interface, channel=channel, **bus_kwargs)
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
        **bus_kwargs,
    ):
        """``profile``: the device's object dictionary map (default: the virtual controller's own);
        ``eds``: the device's EDS, which gives the type of each object the profile leaves untyped."""
        self.node_id, self.timeout_s = node_id, timeout_s
        self.profile = _profile(profile, pole_pairs, node_id, eds)
        self.applied_calibration: Corrections | None = None
        where = f"{interface}:{channel}" + (
            f"@{bus_kwargs['host']}:{bus_kwargs.get('port')}" if "host" in bus_kwargs else ""
        )
        self.where = f"CANopen node {node_id} on {where}"
        self.network = canopen.Network()
        self.network.bus = _open_bus(self.where, interface, channel, timeout_s, bus_kwargs)
        self.network.connect()
        # the device's own EDS; else the shipped one for the virtual controller's own profile, or
        # the dictionary the profile describes
        own = self.profile.objects == shipped("canopen").bind(pole_pairs, node_id).objects
        self.node = self.network.add_node(node_id, eds or (str(EDS_PATH) if own else object_dictionary(self.profile)))
        # the client is already subscribed to the response COB-ID; swapping its class keeps that
        # subscription and adds the multiplexer check
        self.node.sdo.__class__ = MuxCheckedSdoClient
        self.node.sdo.RESPONSE_TIMEOUT = timeout_s
        # canopen 2.4.1 counts retries down and stops at zero: MAX_RETRIES = 0 would retry forever
        # (-1 is truthy); 1 means a single attempt, so a silent node fails within timeout_s
        self.node.sdo.MAX_RETRIES = 1
        self.replies: queue.Queue = queue.Queue()
        self.emcy: queue.Queue = queue.Queue()
        hook = self.profile.edge_hook
        if hook.kind == "pdo":
            self.network.subscribe(hook.tx_cob_id, lambda cid, data, ts: self.replies.put(bytes(data)))
        self.network.subscribe(0x80 + node_id, lambda cid, data, ts: self.emcy.put((ts, bytes(data))))
        self.boot_ups: queue.Queue = queue.Queue()
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
                frame = CommandMessage.unpack(self.replies.get(timeout=max(deadline - time.monotonic(), 0.0)))
            except queue.Empty:
                raise LinkTimeout(
                    f"{self.where}: no TPDO reply to edge #{seq} (t = {edge['t_capture_s']:.7f} s) within "
                    f"{self.timeout_s} s"
                ) from None
            received.append(frame)
            if frame.seq != seq:
                continue  # a late frame of an earlier edge
            if not frame.keeps_everything:
                commands.append(frame.to_command(epoch))
            if frame.last:
                self.traffic.can_message(sent, [f.pack() for f in received])
                return commands

    def close(self) -> None:
        try:
            self.network.disconnect()
        except Exception:  # a bus that is already gone cannot be closed more
            pass


def _profile(profile: Profile | str | None, pole_pairs: int, node_id: int, eds: str | None) -> Profile:
    """A bound CANopen profile (default: the virtual controller's own, typed by the shipped EDS)."""
    if profile is None or isinstance(profile, (str, Path)):
        profile = load_profile(profile) if profile is not None else shipped("canopen")
    if profile.protocol != "canopen":
        raise ProfileError(profile.path, f"a {profile.protocol} profile on a CANopen device")
    return profile.bind(pole_pairs, node_id, eds)


_TYPE_CODES = {name: code for code, name in CANOPEN_TYPE_CODES.items()}


def object_dictionary(profile: Profile):
    """A CiA 301 object dictionary holding every object of ``profile`` (an object with sub-indices
    is a RECORD with its highest sub-index at 0, unless a role maps sub 0) and 0x1000: what a
    device with this profile has, for the virtual device and for a link without the device's EDS."""
    od = canopen.ObjectDictionary()
    by_index: dict[int, dict[int, tuple]] = {}
    for o in profile.objects.values():
        for k in range(o.count):
            by_index.setdefault(o.index, {})[o.subindex_of(k)] = (o, k)

    def variable(o, index: int, sub: int, name: str) -> canopen.objectdictionary.ODVariable:
        var = canopen.objectdictionary.ODVariable(name, index, sub)
        var.data_type = _TYPE_CODES[o.type]
        access = ROLES[o.role].access if o.role in ROLES else "r"
        var.access_type = {"r": "ro", "rw": "rw", "w": "wo"}[access]
        var.default = False if o.type == "bool" else (0.0 if o.type.startswith("float") else 0)
        return var

    if 0x1000 not in by_index:
        device_type = canopen.objectdictionary.ODVariable("Device type", 0x1000, 0)
        device_type.data_type, device_type.access_type, device_type.default = 0x07, "ro", 0
        od.add_object(device_type)
    for index, subs in sorted(by_index.items()):
        if list(subs) == [0] and subs[0][0].count == 1:
            o, _ = subs[0]
            od.add_object(variable(o, index, 0, o.role))
            continue
        record = canopen.objectdictionary.ODRecord(f"{subs[min(subs)][0].role} record", index)
        if 0 not in subs:
            highest = canopen.objectdictionary.ODVariable("Highest sub-index supported", index, 0)
            highest.data_type, highest.access_type, highest.default = 0x05, "const", max(subs)
            record.add_member(highest)
        for sub, (o, k) in sorted(subs.items()):
            record.add_member(variable(o, index, sub, f"{o.role}[{k}]" if o.count > 1 else o.role))
        od.add_object(record)
    return od
