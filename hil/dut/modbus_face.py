"""The virtual controller's Modbus face (pymodbus, TCP or RTU framer) and the Modbus link.

Register map (holding registers, one unit; FLOAT32 = IEEE single, two registers, high word
first; docs/controller.md has the table). Edges are exchanged in one transaction: function 23
(read/write multiple registers) writes the edge message (header and ADC window) to the mailbox at 300 and reads
the reply at 210 (count, then up to four 8-byte command messages), so a plant step costs one
round trip.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import threading
import time
from dataclasses import dataclass

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

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
from .link import LinkError, LinkTimeout, verify_calibration
from .tcp import close_handlers

# addresses
STRATEGY, SPEED = 0, 1
CAL_STAGED, CAL_APPLY, COMMAND, CAL_APPLIED = 10, 30, 31, 40
RESET_APPLICATION = 1  #: COMMAND value: clear faults, restart the control logic
FILTER = 60
#: read-back block from 100: speed, Q diagonal (3), R diagonal (2) as FLOAT32 (100..113)
RB_SPEED, RB_TRIPS, RB_PRED = 100, 112, 114
#: fault block from 120: error register, fault count, then the fault history's codes
ERROR_REGISTER = 120
#: gated edges, covariance repairs, divergence fades, band projections: UINT32 each
RB_COUNTERS = 130
COUNTER_KEYS = ("gated_edges", "covariance_repairs", "divergence_fades", "band_projections")
IDENTITY = 150  # vendor, product, revision, serial: UINT32 each
REPLY = 210
#: the edge mailbox (edge message version 2): its bytes (``EdgeMessage.pack``: header, accumulators,
#: then the ADC window newest first), two per register, the first one high; the write's length says
#: how many conversions it holds. The write triggers the controller.
EDGE_IN = 300
#: conversions the mailbox's own write holds (read/write multiple registers writes at most 121)
MAILBOX_CONVERSIONS = 36
EDGE_MAILBOX_REGISTERS = 11 + 3 * MAILBOX_CONVERSIONS
#: an edge's older conversions (index 36 on), when it has more, written just before its mailbox
#: (write multiple registers); the mailbox write takes them and empties the block
EDGE_OLDER = EDGE_IN + EDGE_MAILBOX_REGISTERS
EDGE_OLDER_REGISTERS = 3 * (MAX_ADC_SAMPLES - MAILBOX_CONVERSIONS)
REPLY_FRAMES = 4


def _f32_regs(v: float) -> list[int]:
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [hi, lo]


def _regs_f32(r) -> float:
    return struct.unpack(">f", struct.pack(">HH", *r))[0]


def _bytes_regs(b: bytes) -> list[int]:
    return list(struct.unpack(">HHHH", b))


def _regs_bytes(r) -> bytes:
    return struct.pack(">HHHH", *r)


def _bytes_to_regs(b: bytes) -> list[int]:
    """A byte string (even length) as registers, two bytes each, the first one high."""
    return list(struct.unpack(f">{len(b) // 2}H", b))


def _regs_to_bytes(r) -> bytes:
    return struct.pack(f">{len(r)}H", *r)


def simdata() -> list[SimData]:
    """The register map: everything not listed is an illegal address."""
    return [
        SimData(STRATEGY, 1, 3, DataType.UINT16),
        SimData(SPEED, 1, 5000.0, DataType.FLOAT32),
        SimData(CAL_STAGED, 10, 0.0, DataType.FLOAT32),
        SimData(CAL_APPLY, 1, 0, DataType.UINT16),
        SimData(COMMAND, 1, 0, DataType.UINT16),
        SimData(CAL_APPLIED, 10, 0.0, DataType.FLOAT32, readonly=True),
        SimData(FILTER, 9, 0.0, DataType.FLOAT32),
        SimData(RB_SPEED, 7, 0.0, DataType.FLOAT32, readonly=True),
        SimData(RB_TRIPS, 1, 0, DataType.UINT32, readonly=True),
        SimData(RB_PRED, 1, 0.0, DataType.FLOAT64, readonly=True),
        SimData(ERROR_REGISTER, 10, 0, DataType.UINT16, readonly=True),
        SimData(IDENTITY, 4, 0, DataType.UINT32, readonly=True),
        SimData(RB_COUNTERS, 4, 0, DataType.UINT32, readonly=True),
        SimData(EDGE_IN, EDGE_MAILBOX_REGISTERS, 0, DataType.REGISTERS),
        SimData(EDGE_OLDER, EDGE_OLDER_REGISTERS, 0, DataType.REGISTERS),
        SimData(REPLY, 1 + 4 * REPLY_FRAMES, 0, DataType.REGISTERS, readonly=True),
    ]


SUPPORTED_FUNCTIONS = (3, 6, 16, 23)


def request_exception(pdu: bytes) -> bytes | None:
    """The exception PDU the Modbus application protocol requires for a malformed request, or None.

    01 illegal function: a function code this device does not implement (only holding registers:
    3, 6, 16, 23); 03 illegal data value: a quantity out of range or a byte count that does not
    match it. Addresses (02) and values of well-formed requests are judged by the register map.
    """
    if not pdu:
        return None
    fc = pdu[0]
    if fc & 0x80 or fc not in SUPPORTED_FUNCTIONS:
        return bytes([(fc | 0x80) & 0xFF, 0x01])
    bad = bytes([fc | 0x80, 0x03])
    try:
        if fc == 3:
            _, qty = struct.unpack_from(">HH", pdu, 1)
            return bad if not 1 <= qty <= 125 or len(pdu) != 5 else None
        if fc == 6:
            return bad if len(pdu) != 5 else None
        if fc == 16:
            _, qty, nbytes = struct.unpack_from(">HHB", pdu, 1)
            return bad if not 1 <= qty <= 123 or nbytes != 2 * qty or len(pdu) != 6 + nbytes else None
        if fc == 23:
            _, rqty, _, wqty, nbytes = struct.unpack_from(">HHHHB", pdu, 1)
            ok = 1 <= rqty <= 125 and 1 <= wqty <= 121 and nbytes == 2 * wqty and len(pdu) == 10 + nbytes
            return None if ok else bad
    except struct.error:
        return bad
    return None


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
                 serial_port: str | None = None, baudrate: int = 115200, idle_timeout_s: float | None = None):
        """TCP on host:port, or RTU on ``serial_port`` (a serial device path) when given."""
        warm_up()  # ready before the port opens
        self.controller, self.host, self.unit = controller, host, unit
        self.serial_port, self.baudrate = serial_port, baudrate
        self.limits = TcpLimits() if idle_timeout_s is None else TcpLimits(idle_timeout_s=idle_timeout_s)
        self.port = port
        self.connections = 0
        self.refused = 0  #: malformed requests answered with an exception or dropped connections
        self._last_summary = 0.0
        self.history: list[int] = []
        controller.on_fault(lambda code, t: (self.history.insert(0, code), self.history.__delitem__(slice(8, None))))
        self._epoch = 0
        self._last_ticks = None
        self._older: list[int] = []  #: the last write to EDGE_OLDER, for the next mailbox write
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
        device = SimDevice(self.unit, simdata=simdata(), action=self._action)
        if self.serial_port is not None:
            from pymodbus.framer import FramerType
            from pymodbus.server import ModbusSerialServer

            self._expected: dict[int, bytes] = {}
            self.server = ModbusSerialServer(
                device,
                framer=FramerType.RTU,
                port=self.serial_port,
                baudrate=self.baudrate,
                trace_packet=self._trace_packet_rtu,
            )
            task = asyncio.create_task(self.server.serve_forever())
            await asyncio.sleep(0.2)
            self._ready.set()
            await task
            return
        from pymodbus.pdu import DecodePDU
        from pymodbus.simulator.simcore import SimCore

        self._context, self._decoder = SimCore(device), DecodePDU(True)
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
                    await asyncio.wait_for(writer.drain(), self.limits.idle_timeout_s)
                timeout = self.limits.partial_timeout_s if buffer else self.limits.idle_timeout_s
                try:
                    chunk = await asyncio.wait_for(reader.read(4096), timeout)
                except asyncio.TimeoutError:
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
        exc = request_exception(pdu)
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
            self._expected = {0: exc} if (exc := request_exception(data[1:-2])) is not None else {}
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

    # --- the register map's behaviour --------------------------------------------------------------
    def _refresh(self, regs: list[int], base: int) -> None:
        """Read-backs into the block before any read."""
        c = self.controller

        def put(addr, values):
            regs[addr - base : addr - base + len(values)] = values

        st = c.status()
        put(STRATEGY, [int(c.strategy)])
        put(SPEED, _f32_regs(c.speed_setpoint_rpm))
        applied = (c.corrections or Corrections()).as_vector()
        put(CAL_APPLIED, sum((_f32_regs(v) for v in applied), []))
        put(FILTER, sum((_f32_regs(v) for v in filter_vector(c.filter_settings)), []))
        speed = st["estimated_speed_rpm"] if np.isfinite(st["estimated_speed_rpm"]) else 0.0
        put(RB_SPEED, sum((_f32_regs(v) for v in [speed, *st["q_diag"], *st["r_diag"]]), []))
        put(RB_TRIPS, [(st["guard_trips"] >> 16) & 0xFFFF, st["guard_trips"] & 0xFFFF])
        pred = st["last_predicted_commutation_s"] if np.isfinite(st["last_predicted_commutation_s"]) else 0.0
        put(RB_PRED, list(struct.unpack(">HHHH", struct.pack(">d", pred))))
        put(RB_COUNTERS, sum(([(st[k] >> 16) & 0xFFFF, st[k] & 0xFFFF] for k in COUNTER_KEYS), []))
        codes = (self.history + [0] * 8)[:8]
        put(ERROR_REGISTER, [c.error_register, len(self.history)] + codes)
        i = c.identity
        put(
            IDENTITY,
            sum(([(v >> 16) & 0xFFFF, v & 0xFFFF] for v in (i.vendor_id, i.product_code, i.revision, i.serial)), []),
        )

    async def _action(self, fc, start, address, count, regs, values):
        try:
            if values is None:
                self._refresh(regs, start)
                return None
            return self._write(address, list(values), regs, start)
        except Exception:  # bad input never stops the server: report and refuse
            self.controller.raise_fault(Fault.INTERNAL, 0.0)
            return ExcCodes.DEVICE_FAILURE

    def _write(self, address: int, values: list[int], regs: list[int], base: int):
        c = self.controller
        end = address + len(values)

        def covers(a, n=1):
            return address <= a and a + n <= end

        def part(a, n):
            return values[a - address : a - address + n]

        # a write must cover whole values (a FLOAT32 is two registers)
        for a, n, size in ((SPEED, 1, 2), (CAL_STAGED, 10, 2), (FILTER, 9, 2), (EDGE_IN, 1, 11)):
            for k in range(n):
                lo, hi = a + size * k, a + size * (k + 1)
                if address < hi and end > lo and not (address <= lo and end >= hi):
                    return ExcCodes.ILLEGAL_VALUE
        if covers(STRATEGY):
            v = part(STRATEGY, 1)[0]
            if v > 3:
                return ExcCodes.ILLEGAL_VALUE
            c.set_strategy(v)
        if covers(SPEED, 2):
            rpm = _regs_f32(part(SPEED, 2))
            if not (np.isfinite(rpm) and 0.0 <= rpm <= 30000.0):
                return ExcCodes.ILLEGAL_VALUE
            c.set_speed(rpm)
        for k in range(10):
            if covers(CAL_STAGED + 2 * k, 2) and not np.isfinite(_regs_f32(part(CAL_STAGED + 2 * k, 2))):
                return ExcCodes.ILLEGAL_VALUE
        if covers(CAL_APPLY):
            if part(CAL_APPLY, 1)[0] != 1:
                return ExcCodes.ILLEGAL_VALUE
            # the staged table is in the block already (earlier writes) or in this request
            staged = [
                _regs_f32(part(CAL_STAGED + 2 * k, 2))
                if covers(CAL_STAGED + 2 * k, 2)
                else _regs_f32(regs[CAL_STAGED + 2 * k - base : CAL_STAGED + 2 * k - base + 2])
                for k in range(10)
            ]
            try:
                c.download_calibration(Corrections.from_vector(staged))
            except CalibrationTableError:
                return ExcCodes.ILLEGAL_VALUE
            values[CAL_APPLY - address] = 0  # write-only trigger reads back as 0
        if any(covers(FILTER + 2 * k, 2) for k in range(9)):
            vector = filter_vector(c.filter_settings)
            for k in range(9):
                if covers(FILTER + 2 * k, 2):
                    vector[k] = _regs_f32(part(FILTER + 2 * k, 2))
            try:  # takes effect at the next strategy write or reset command, as the filter restarts then
                c.filter_settings = with_filter_vector(c.filter_settings, vector)
            except ValueError:
                return ExcCodes.ILLEGAL_VALUE
        if covers(COMMAND):
            if part(COMMAND, 1)[0] != RESET_APPLICATION:
                return ExcCodes.ILLEGAL_VALUE
            c.clear_faults()
            self.history.clear()
            c.reset()
            self._epoch, self._last_ticks = 0, None
            values[COMMAND - address] = 0  # a trigger reads back as 0
        if address >= EDGE_OLDER:
            if address != EDGE_OLDER or len(values) % 3:
                return ExcCodes.ILLEGAL_VALUE  # whole conversions from the block's start
            self._older = list(values)
        if covers(EDGE_IN, 11):
            if address != EDGE_IN or (end - EDGE_IN - 11) % 3:
                return ExcCodes.ILLEGAL_VALUE  # a mailbox write is the header, the sums and whole conversions
            older, self._older = self._older, []
            if older and end != EDGE_OLDER:
                return ExcCodes.ILLEGAL_VALUE  # older conversions follow a full mailbox only
            try:
                msg = EdgeMessage.unpack(_regs_to_bytes(list(values) + older))
            except ValueError:
                return ExcCodes.ILLEGAL_VALUE
            self._epoch = next_epoch(self._epoch, self._last_ticks, msg.ticks)
            self._last_ticks = msg.ticks
            frames = encode_reply(c.capture(msg.to_edge(self._epoch)), msg.seq)[:REPLY_FRAMES]
            reply = [len(frames)] + sum((_bytes_regs(f.pack()) for f in frames), [])
            regs[REPLY - base : REPLY - base + len(reply)] = reply
        return None


class ModbusLink:
    """The framework's view of a Modbus TCP controller."""

    name = "modbus"

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 502,
        unit: int = 1,
        timeout_s: float = 1.0,
        serial_port: str | None = None,
        baudrate: int = 115200,
    ):
        """Modbus TCP at host:port, or Modbus RTU on ``serial_port`` when given."""
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient
        from pymodbus.framer import FramerType

        self.unit, self.timeout_s = unit, timeout_s
        self.host, self.port, self.serial_port = host, port, serial_port
        self.applied_calibration: Corrections | None = None
        if serial_port is not None:
            self.where = f"Modbus RTU unit {unit} on {serial_port}"
            self.client = ModbusSerialClient(
                serial_port, framer=FramerType.RTU, baudrate=baudrate, timeout=timeout_s, retries=0
            )
        else:
            self.where = f"Modbus unit {unit} at {host}:{port}"
            self.client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
        if not self.client.connect():
            raise LinkTimeout(f"{self.where}: cannot connect within {timeout_s} s")
        self._seq = 0

    def _call(self, what: str, fn):
        from pymodbus.exceptions import ModbusException

        try:
            r = fn()
        except ModbusException as exc:
            raise LinkTimeout(f"{self.where}: no answer to {what} within {self.timeout_s} s ({exc})") from None
        except Exception as exc:  # the transport itself failed (a reset connection, a closed port)
            raise LinkError(f"{self.where}: {what} failed: {type(exc).__name__}: {exc}") from None
        if r.isError():
            code = getattr(r, "exception_code", None)
            raise LinkError(
                f"{self.where}: {what} refused with exception code {code:02d}"
                if code is not None
                else f"{self.where}: {what} failed: {r}"
            )
        return r

    def read(self, address: int, count: int) -> list[int]:
        return self._call(
            f"read {count} registers at {address}",
            lambda: self.client.read_holding_registers(address, count=count, device_id=self.unit),
        ).registers

    def write(self, address: int, registers: list[int]) -> None:
        self._call(
            f"write {len(registers)} registers at {address}",
            lambda: self.client.write_registers(address, registers, device_id=self.unit),
        )

    def identity(self) -> dict:
        r = self.read(IDENTITY, 8)
        v = [(r[2 * k] << 16) | r[2 * k + 1] for k in range(4)]
        return {
            "vendor_id": v[0],
            "product_code": v[1],
            "revision": v[2],
            "serial": v[3],
            "device_type": None,
            "firmware": None,
        }

    def download_calibration(self, corrections: Corrections) -> None:
        table = corrections.as_float32()
        self.write(CAL_STAGED, sum((_f32_regs(v) for v in table.as_vector()), []))
        self.write(CAL_APPLY, [1])
        back = self.read(CAL_APPLIED, 20)
        read_back = Corrections.from_vector([_regs_f32(back[2 * k : 2 * k + 2]) for k in range(10)])
        verify_calibration(table, read_back)
        self.applied_calibration = read_back

    def reset(self) -> None:
        """Command register: clear the faults and restart the control logic (calibration kept)."""
        self.write(COMMAND, [RESET_APPLICATION])
        self._seq = 0

    def set_filter_settings(self, settings) -> None:
        self.write(FILTER, sum((_f32_regs(v) for v in filter_vector(settings)), []))
        self.write(STRATEGY, self.read(STRATEGY, 1))  # the filter restarts with its new settings

    def set_strategy(self, strategy: int) -> None:
        self.write(STRATEGY, [int(strategy)])

    def set_speed(self, rpm: float) -> None:
        self.write(SPEED, _f32_regs(rpm))

    def edge(self, edge: dict) -> list:
        epoch = edge_epoch(edge["t_capture_s"])
        seq = self._seq
        self._seq = (self._seq + 1) & 0x7F
        values = _bytes_to_regs(EdgeMessage.from_edge(edge, seq).pack())
        if len(values) > EDGE_MAILBOX_REGISTERS:  # the older conversions first, in a write of their own
            older, values = values[EDGE_MAILBOX_REGISTERS:], values[:EDGE_MAILBOX_REGISTERS]
            self._call(
                f"older ADC conversions of edge #{seq}",
                lambda: self.client.write_registers(EDGE_OLDER, older, device_id=self.unit),
            )
        r = self._call(
            f"edge #{seq} (t = {edge['t_capture_s']:.7f} s)",
            lambda: self.client.readwrite_registers(
                read_address=REPLY,
                read_count=1 + 4 * REPLY_FRAMES,
                write_address=EDGE_IN,
                values=values,
                device_id=self.unit,
            ),
        )
        regs = r.registers
        if len(regs) != 1 + 4 * REPLY_FRAMES or regs[0] > REPLY_FRAMES:
            raise LinkError(
                f"{self.where}: reply to edge #{seq} is malformed ({len(regs)} registers, {regs[:1]} frames)"
            )
        commands = []
        for k in range(min(regs[0], REPLY_FRAMES)):
            f = CommandMessage.unpack(_regs_bytes(regs[1 + 4 * k : 5 + 4 * k]))
            if f.seq != seq & 0x7F:
                raise LinkError(f"{self.where}: reply to edge #{seq} carries sequence {f.seq} (a stale answer)")
            if not f.keeps_everything:
                commands.append(f.to_command(epoch))
        return commands

    def status(self) -> dict:
        rb = self.read(RB_SPEED, 18)
        err = self.read(ERROR_REGISTER, 10)
        cn = self.read(RB_COUNTERS, 8)
        counters = {k: (cn[2 * i] << 16) | cn[2 * i + 1] for i, k in enumerate(COUNTER_KEYS)}
        f = [_regs_f32(rb[2 * k : 2 * k + 2]) for k in range(6)]
        return {
            **counters,
            "strategy": self.read(STRATEGY, 1)[0],
            "speed_setpoint_rpm": _regs_f32(self.read(SPEED, 2)),
            "estimated_speed_rpm": f[0],
            "q_diag": f[1:4],
            "r_diag": f[4:6],
            "guard_trips": (rb[12] << 16) | rb[13],
            "last_predicted_commutation_s": struct.unpack(">d", struct.pack(">HHHH", *rb[14:18]))[0],
            "error_register": err[0],
            "faults": [(0.0, code) for code in err[2 : 2 + err[1]]],
        }

    def close(self) -> None:
        self.client.close()
