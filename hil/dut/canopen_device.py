"""The simulated CANopen device: the virtual controller as a CiA 301 node on a python-can bus.

Device: a ``canopen.LocalNode`` holding the dictionary its profile describes (hil.dut.eds; the
built-in controller's: hil/dut/profiles/virtual-canopen.toml), every object served through the
controller's roles (hil.dut.virtual_roles) as Modbus is, behind our own validation (the library
leaves PDOs unlinked, leaves 0x1001/0x1003 untouched on EMCY, sends no boot-up after an NMT reset
and echoes stale indexes in some aborts: docs/controller.md, Library traps).
Edges arrive on the profile's receive COB-IDs (the built-in controller's: the header in RPDO1,
0x200 + node, after its accumulators and ADC window, one data frame each, in RPDO2, 0x300 +
node); commands leave on its transmit COB-ID (TPDO1, 0x180 + node), in the messages of
bldc.contract (edge message version 2).
"""

from __future__ import annotations

import struct
import threading
from dataclasses import dataclass

import canopen
from canopen.sdo.exceptions import SdoAbortedError

from bldc.contract import (
    MAX_ADC_SAMPLES,
    EdgeMessage,
    Fault,
    encode_reply,
    next_epoch,
)

from ..controller.virtual import VirtualController, warm_up
from .canopen_codec import (
    ABORT_COMMAND,
    ABORT_GENERAL,
    ABORT_LENGTH_HIGH,
    ABORT_LENGTH_LOW,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_RANGE,
    ABORT_READ_ONLY,
    ABORT_TOGGLE,
    ABORT_WRITE_ONLY,
    NMT_PREOP,
    NMT_RESET_COMM,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
)
from .eds import object_dictionary, virtual_identity
from .profile import Profile, bound_profile
from .virtual_can import VirtualCanBus, receive_inline
from .virtual_roles import VirtualRoles

#: the longest value any object of a dictionary built from a profile holds (VISIBLE_STRINGs are short); a
#: segmented download without a declared size is refused past this
SDO_MAX_DOWNLOAD_BYTES = 256


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
        inline: bool = False,
        **bus_kwargs,
    ):
        """Node ``node_id`` on the bus, serving the dictionary of ``profile`` (default: the virtual
        controller's own, hil/dut/profiles/virtual-canopen.toml) through the controller's roles.
        ``inline``: on a python-can ``virtual`` channel, take each frame in the thread that sends
        it, with no receive thread of its own (hil.dut.virtual_can: a host in the same process)."""
        self.profile = bound_profile("canopen", profile, controller.motor.pole_pairs, node_id)
        self.roles = VirtualRoles(controller, self.profile)
        self._reads, self._writes = self.profile.cell_map()  # (index, sub) -> (object, element)

        warm_up()  # ready before the boot-up message, as firmware is
        self.controller = controller
        self.node_id = node_id
        self.network = canopen.Network()
        # the notifier looks for a stop this often; close() waits for it (canopen's 1 s made
        # ``hil dut serve`` take up to a second longer to exit on SIGTERM)
        self.network.NOTIFIER_CYCLE = 0.05
        if inline:
            if interface != "virtual":
                raise ValueError(f"an inline device needs python-can's virtual interface, not {interface!r}")
            self.network.bus = VirtualCanBus(channel=channel, **bus_kwargs)
            receive_inline(self.network)
        else:
            self.network.connect(interface=interface, channel=channel, **bus_kwargs)
        self.node = canopen.LocalNode(node_id, object_dictionary(self.profile, node_id, virtual_identity()))
        self.network.add_node(self.node)
        self.od = self.node.object_dictionary
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
        #: data frames received since the last edge header: the accumulators and the ADC window of the
        #: edge whose header follows them (bounded: a stream without headers keeps the newest)
        self._data_frames: list[bytes] = []
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
            if cmd == NMT_RESET_NODE:  # CiA 301's reset application: faults cleared, logic restarted
                with self._lock:
                    self.roles.write("reset", [])
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

    # --- the profile's objects: the controller's roles, encoded as the profile says -----------------
    def _on_read(self, index: int, subindex: int, od):
        cell = self._reads.get((index, subindex))
        if cell is None:
            return None  # an object of CiA 301's (0x1000, a record's highest sub-index): its default
        obj, k = cell
        if obj.is_action:
            return 0
        return obj.to_raw(self.roles.read(obj.role, obj.count)[k], self.profile.pole_pairs, saturate=True)

    def _on_write(self, index: int, subindex: int, od, data) -> None:
        obj, k = self._writes[(index, subindex)]
        raw = od.decode_raw(data)
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

    def _on_fault(self, code: int, t_s: float) -> None:  # the roles keep the history (0x1003)
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

    def close(self) -> None:
        try:
            self.node.nmt.stop_heartbeat()
        finally:
            self.network.disconnect()
