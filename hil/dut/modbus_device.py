"""The simulated Modbus device: the virtual controller served over Modbus (pymodbus, TCP or RTU framer).

It reads the register map from a device profile (hil.dut.profile; the virtual controller's own
map is hil/dut/profiles/virtual-modbus.toml, docs/controller.md has the table): nothing here
knows an address. Edges are exchanged in one transaction: function 23 (read/write multiple
registers) writes the edge message to the profile's mailbox and reads the reply at its reply
address (count, then up to four command messages), so a plant step costs one round trip.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import threading
import time
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from bldc.contract import (
    EdgeMessage,
    Fault,
    encode_reply,
    next_epoch,
)

from ..controller.virtual import VirtualController, warm_up
from .modbus_codec import (
    FUNCTION_TABLE,
    MESSAGE_REST_WORDS,
    REPLY_FRAMES,
    bytes_of,
    registers_of,
    request_exception,
    supported_functions,
)
from .profile import (
    EDGE_HEADER_WORDS,
    REPLY_WORDS,
    ROLES,
    Profile,
    ProfileValueError,
    bound_profile,
    mailbox_words,
)
from .tcp import close_handlers
from .virtual_roles import VirtualRoles

UNIT_ANY = 0xFF  #: Modbus TCP's "unit identifier not used" value: this device answers it as its own
GATEWAY_NO_RESPONSE = 0x0B
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TcpLimits:
    max_clients: int = 16
    partial_timeout_s: float = 5.0   #: an ADU begun must be complete within this (slow-loris)
    idle_timeout_s: float = 300.0    #: a connection that sends nothing, or reads nothing, for this long is closed


class ModbusDevice:
    """Serves a VirtualController over Modbus TCP on 127.0.0.1 (or another address if asked).

    TCP framing is ours (the MBAP header is seven bytes): pipelined requests in one segment are
    each answered, in order; a malformed request is one log line at debug level and its
    conformant exception; a connection that stalls mid-request or sits idle is closed. The PDUs
    are decoded and executed by pymodbus against the register map (the same ``SimDevice`` the
    RTU framer serves).

    Unit-id rule: the device answers its own unit and 0xFF (Modbus TCP's "not used" value); any
    other unit gets exception 0x0B (gateway target device failed to respond), so a client with
    a wrong unit id learns it at once instead of timing out.
    """

    def __init__(self, controller: VirtualController, host: str = "127.0.0.1", port: int = 0, unit: int = 1,
                 serial_port: str | None = None, baudrate: int = 115200, idle_timeout_s: float | None = None,
                 profile: Profile | str | None = None):
        """TCP on host:port, or RTU on ``serial_port`` (a serial device path) when given; the
        register map is ``profile``'s (default: the virtual controller's own, hil/dut/profiles)."""
        warm_up()  # ready before the port opens
        self.controller, self.host, self.unit = controller, host, unit
        self.profile = bound_profile("modbus", profile, controller.motor.pole_pairs)
        self.roles = VirtualRoles(controller, self.profile)
        self.supported = supported_functions(self.profile)
        self.map = RegisterMap(self.profile)
        hook = self.profile.edge_hook
        self._reply = [0] * REPLY_WORDS
        self._mailbox = None
        if hook.kind == "mailbox":
            self._mailbox = (hook.request_address, mailbox_words(self.profile), hook.reply_address)
            self._request = [0] * self._mailbox[1]
        #: the message rest written ahead of its header (appended, taken by the next header)
        self._rest_ahead: list[int] = []
        self.serial_port, self.baudrate = serial_port, baudrate
        self.limits = TcpLimits() if idle_timeout_s is None else TcpLimits(idle_timeout_s=idle_timeout_s)
        self.port = port
        self.connections = 0
        self.refused = 0  #: malformed requests answered with an exception or dropped connections
        self._last_summary = 0.0
        self._epoch = 0
        self._last_ticks = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="modbus-device", daemon=True)
        self._thread.start()
        if not self._ready.wait(5.0) or self._error is not None:
            raise OSError(f"Modbus device on {host}:{port} did not start: {self._error}")

    def _run(self):
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # reported to the constructor (a port in use)
            self._error = exc
            self._ready.set()

    async def _serve(self):
        self.loop = asyncio.get_running_loop()
        if self.serial_port is not None:
            from pymodbus.framer import FramerType
            from pymodbus.server import ModbusSerialServer

            self._expected: dict[int, bytes] = {}
            self.server = ModbusSerialServer(
                SimDevice(self.unit, simdata=[SimData(0, 1, 0, DataType.REGISTERS)]),  # replaced below
                framer=FramerType.RTU,
                port=self.serial_port,
                baudrate=self.baudrate,
                trace_packet=self._trace_packet_rtu,
            )
            self.server.context = self  # the profile's map answers (async_getValues / async_setValues)
            task = asyncio.create_task(self.server.serve_forever())
            await asyncio.sleep(0.2)
            self._ready.set()
            await task
            return
        from pymodbus.pdu import DecodePDU

        self._context, self._decoder = self, DecodePDU(True)
        self._stopped = asyncio.Event()
        self._handlers: dict[asyncio.Task, asyncio.StreamWriter] = {}
        server = await asyncio.start_server(self._connection, self.host, self.port)
        self.port = server.sockets[0].getsockname()[1]
        self._ready.set()
        async with server:
            await self._stopped.wait()
        await close_handlers(self._handlers)

    # --- Modbus TCP: framing, pipelining, limits ----------------------------------------------------
    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.connections >= self.limits.max_clients:
            self._refuse("connection refused: %d clients already", self.limits.max_clients)
            writer.close()
            return
        self.connections += 1
        self._handlers[asyncio.current_task()] = writer
        buffer = bytearray()
        try:
            while True:
                answers = []
                while len(buffer) >= 7:  # every complete ADU in the buffer, in order
                    tid, protocol, length, unit = struct.unpack_from(">HHHB", buffer)
                    if not 2 <= length <= 254:
                        self._refuse("MBAP length %d outside 2..254 (transaction %d): connection closed", length, tid)
                        return
                    if len(buffer) < 6 + length:
                        break
                    pdu = bytes(buffer[7 : 6 + length])
                    del buffer[: 6 + length]
                    if protocol != 0:
                        self._refuse("protocol id %d is not Modbus (transaction %d): request dropped", protocol, tid)
                        continue
                    answer = await self._answer(unit, pdu)
                    answers.append(struct.pack(">HHHB", tid, 0, len(answer) + 1, unit) + answer)
                if answers:
                    writer.write(b"".join(answers))
                    # the answers are in the kernel's buffer unless the client stops reading: only
                    # then is there anything to wait for (wait_for wraps the wait in a task of its
                    # own, two loop turns a request)
                    if writer.transport.get_write_buffer_size():
                        await asyncio.wait_for(writer.drain(), self.limits.idle_timeout_s)
                timeout = self.limits.partial_timeout_s if buffer else self.limits.idle_timeout_s
                try:
                    async with asyncio.timeout(timeout):  # no task of its own, as wait_for's
                        chunk = await reader.read(4096)
                except TimeoutError:
                    if buffer:
                        self._refuse("request incomplete after %.1f s: connection closed", timeout)
                    return
                if not chunk:
                    return
                buffer += chunk
                del chunk
        except (ConnectionError, OSError, asyncio.TimeoutError):
            pass
        finally:
            self.connections -= 1
            self._handlers.pop(asyncio.current_task(), None)
            writer.close()

    async def _answer(self, unit: int, pdu: bytes) -> bytes:
        """The response PDU to one request PDU."""
        from pymodbus.pdu import ExceptionResponse

        fc = pdu[0] if pdu else 0
        if unit not in (self.unit, UNIT_ANY):
            return bytes([(fc | 0x80) & 0xFF, GATEWAY_NO_RESPONSE])
        exc = request_exception(pdu, self.supported)
        if exc is not None:
            self._refuse("function %d: malformed request %s answered with exception %02X", fc, pdu[:16].hex(), exc[1])
            return exc
        request = self._decoder.decode(pdu)
        if request is None:  # request_exception passed it, pymodbus could not: a value it refuses
            self._refuse("function %d: request %s not decodable", fc, pdu[:16].hex())
            return bytes([fc | 0x80, 0x03])
        try:
            response = await request.datastore_update(self._context, self.unit)
        except Exception as exc:  # the register map failed: the device reports it, the server lives on
            self._refuse("function %d: %s: %s", fc, type(exc).__name__, exc)
            response = ExceptionResponse(fc, ExcCodes.DEVICE_FAILURE)
        return bytes([response.function_code]) + response.encode()

    def _refuse(self, message: str, *args) -> None:
        """One debug line per refused request; a one-line summary at most every 10 s at info."""
        self.refused += 1
        log.debug(message, *args)
        now = time.monotonic()
        if now - self._last_summary > 10.0:
            self._last_summary = now
            log.info(
                "Modbus unit %d: %d malformed requests refused so far (last: %s)",
                self.unit,
                self.refused,
                message % args,
            )

    def _trace_packet_rtu(self, sending: bool, data: bytes) -> bytes:
        """RTU: the same rules as TCP; a serial line is strictly request then answer, so the
        verdict of the last request is the one to apply (CRC recomputed on a rewrite)."""
        from pymodbus.framer.rtu import FramerRTU

        if len(data) < 4:
            return data
        if not sending:
            self._expected = {0: exc} if (exc := request_exception(data[1:-2], self.supported)) is not None else {}
            return data
        exc = self._expected.pop(0, None)
        if exc is None:
            return data
        frame = data[:1] + exc
        return frame + FramerRTU.compute_CRC(frame).to_bytes(2, "big")

    def close(self):
        if not self._thread.is_alive():
            return
        if getattr(self, "server", None) is not None:  # RTU: pymodbus's server
            fut = asyncio.run_coroutine_threadsafe(self.server.shutdown(), self.loop)
            try:
                fut.result(timeout=5.0)
            except Exception:  # pragma: no cover
                pass
        else:
            self.loop.call_soon_threadsafe(self._stopped.set)
        self._thread.join(timeout=5.0)

    # --- the register map's behaviour (pymodbus calls these for every decoded request) ------------
    def device_ids(self) -> list[int]:
        return [self.unit]

    def _check_unit(self, device_id: int) -> None:
        """RTU: another unit's request is not this device's (pymodbus answers 0x0B, as the TCP rule)."""
        if device_id != self.unit:
            from pymodbus.exceptions import NoSuchIdException

            raise NoSuchIdException(f"unit {device_id}")

    async def async_getValues(self, device_id: int, fc: int, address: int, count: int = 1):
        self._check_unit(device_id)
        try:
            return self._read(FUNCTION_TABLE[fc], address, count)
        except Exception:  # bad input never stops the server: report and refuse
            self.controller.raise_fault(Fault.INTERNAL, 0.0)
            return ExcCodes.DEVICE_FAILURE

    async def async_setValues(self, device_id: int, fc: int, address: int, values):
        self._check_unit(device_id)
        try:
            return self._write(FUNCTION_TABLE[fc], address, [int(v) for v in values])
        except Exception:
            self.controller.raise_fault(Fault.INTERNAL, 0.0)
            return ExcCodes.DEVICE_FAILURE

    def _read(self, table: str, address: int, count: int):
        if self._mailbox is not None and table == "holding":
            request, words, reply = self._mailbox
            clear_of_request = address + count <= request or request + words <= address
            if clear_of_request and reply <= address and address + count <= reply + REPLY_WORDS:
                return self._reply[address - reply : address - reply + count]  # an edge's reply
        cells = self.map.cells(table, address, count, self._mailbox, write=False)
        if cells is None:
            return ExcCodes.ILLEGAL_ADDRESS
        out, encoded = [], {}
        for cell in cells:
            if cell[0] == "request":
                out.append(self._request[cell[1]])
            elif cell[0] == "reply":
                out.append(self._reply[cell[1]])
            else:
                obj, k, w = cell
                if obj.role not in encoded:
                    encoded[obj.role] = self._encode(obj)
                out.append(encoded[obj.role][k][w])
        return [bool(v) for v in out] if table in ("coil", "discrete") else out

    def _encode(self, obj) -> list[list[int]]:
        """Each element's registers of ``obj`` as the device holds it now."""
        values = self.roles.read(obj.role, obj.count)
        return [obj.to_registers(obj.to_raw(v, self.profile.pole_pairs, saturate=True) if not obj.is_action else 0)
                for v in values]

    def _write(self, table: str, address: int, values: list[int]):
        if self._mailbox is not None and table == "holding":
            first = address - self._mailbox[0]
            if 0 <= first and first + len(values) <= self._mailbox[1]:  # an edge message (or its part)
                return self._write_mailbox(first, values)
        cells = self.map.cells(table, address, len(values), self._mailbox, write=True)
        if cells is None:
            return ExcCodes.ILLEGAL_ADDRESS
        touched: dict[str, dict[int, dict[int, int]]] = {}
        objects, mailbox = {}, {}
        for cell, v in zip(cells, values):
            if cell[0] == "request":
                mailbox[cell[1]] = v
            else:
                obj, k, w = cell
                objects[obj.role] = obj
                touched.setdefault(obj.role, {}).setdefault(k, {})[w] = v
        # a write must cover whole values (a FLOAT32 is two registers), and the edge message whole
        for role, elements in touched.items():
            if any(len(words) != objects[role].registers for words in elements.values()):
                return ExcCodes.ILLEGAL_VALUE
        first = min(mailbox, default=0)  # the mailbox's words of a write are one run of them
        words = [mailbox[i] for i in sorted(mailbox)]
        if _splits_the_header(first, len(words)):
            return ExcCodes.ILLEGAL_VALUE
        try:  # in address order: a staged table written with its apply action is applied whole
            for role in sorted(touched, key=lambda r: objects[r].address):
                obj, elements = objects[role], touched[role]
                raws = {k: obj.from_registers([ws[w] for w in range(obj.registers)]) for k, ws in elements.items()}
                if obj.is_action:
                    if any(raw != obj.write for raw in raws.values()):
                        return ExcCodes.ILLEGAL_VALUE
                    self.roles.write(role, [])
                    if role == "reset":
                        self._epoch, self._last_ticks = 0, None
                    continue
                present = self.roles.read(role, obj.count)
                for k, raw in raws.items():
                    present[k] = obj.from_raw(raw, self.profile.pole_pairs)
                self.roles.write(role, present)
        except (ValueError, ProfileValueError):  # CalibrationTableError included
            return ExcCodes.ILLEGAL_VALUE
        return self._write_mailbox(first, words) if mailbox else None

    def _write_mailbox(self, first: int, words: list[int]):
        """The mailbox's words from word ``first`` on written: a header written whole runs the
        edge; a part of a message's rest without it waits for the header."""
        if _splits_the_header(first, len(words)):
            return ExcCodes.ILLEGAL_VALUE
        self._request[first : first + len(words)] = words
        if first:  # a part of a message's rest, ahead of its header
            self._rest_ahead += words
            if len(self._rest_ahead) > MESSAGE_REST_WORDS:
                self._rest_ahead = []
                return ExcCodes.ILLEGAL_VALUE
            return None
        ahead, self._rest_ahead = self._rest_ahead, []
        return self._edge(words[:EDGE_HEADER_WORDS] + ahead + words[EDGE_HEADER_WORDS:])

    def _edge(self, words: list[int]):
        """The edge message written to the mailbox: run the controller, leave the reply."""
        c = self.controller
        try:
            msg = EdgeMessage.unpack(bytes_of(words))
        except ValueError:
            return ExcCodes.ILLEGAL_VALUE
        self._epoch = next_epoch(self._epoch, self._last_ticks, msg.ticks)
        self._last_ticks = msg.ticks
        frames = encode_reply(c.capture(msg.to_edge(self._epoch)), msg.seq)[:REPLY_FRAMES]
        reply = [len(frames)] + sum((registers_of(f.pack()) for f in frames), [])
        self._reply = reply + [0] * (REPLY_WORDS - len(reply))
        return None


def _splits_the_header(first: int, count: int) -> bool:
    """Whether ``count`` mailbox words from word ``first`` cover a part of the header only (it
    is written whole)."""
    return first < EDGE_HEADER_WORDS and (first > 0 or count < EDGE_HEADER_WORDS) and count > 0


class RegisterMap:
    """Which object, element and word each register of a profile is."""

    def __init__(self, profile: Profile):
        self.profile = profile
        # (table, address) -> (object, element, word), as read and as written (Profile.cell_map)
        self._reads, self._writes = ({cell: (o, *divmod(i, o.registers)) for cell, (o, i) in cells.items()}
                                     for cells in profile.cell_map())

    def cells(self, table: str, address: int, count: int, mailbox, write: bool) -> list | None:
        """The cells of ``count`` registers from ``address``, or None when one is not in the map
        (or is read-only, for a write)."""
        out = []
        for a in range(address, address + count):
            if mailbox is not None and table == "holding":
                req, request_words, rep = mailbox
                if req <= a < req + request_words:
                    out.append(("request", a - req))
                    continue
                if rep <= a < rep + REPLY_WORDS:
                    if write:
                        return None
                    out.append(("reply", a - rep))
                    continue
            cell = (self._writes if write else self._reads).get((table, a))
            if cell is None:
                return None
            if write and not (cell[0].role in ROLES and "w" in ROLES[cell[0].role].access):
                return None
            out.append(cell)
        return out
