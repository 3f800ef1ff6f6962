"""The contract between the controller and the framework: the one module both sides import.

Everything that crosses the link is defined here and nowhere else: the commutation ``Command`` the
plant executes, the ``Strategy`` codes, the ``Fault`` (EMCY) codes, the refusal of a calibration
table, the nine-value filter-settings vector, and the 8-byte edge and command messages. The
controller (``hil.controller``) and the simulator (``plant_models``) both depend on this module and
never on each other (``docs/architecture.md``). The wire layouts are in ``docs/controller.md``.

The edge and command messages every link carries, in one 8-byte format (CANopen PDO payload,
Modbus register block, and the in-process link encodes and decodes them too, so all links give
the controller bit-identical inputs).

EdgeMessage (plant -> controller, RPDO1):
    U32 capture time in 100 ns timer ticks (wraps after 429 s), U16 mean |i| in mA at the edge's
    own instant (the MCU's ADC ring read one applied conditioning delay of the edge's polarity
    before the capture: where the armature field that moved the edge acted; at the capture
    before a calibration is applied),
    U8 flags (bits 0-1 sensor A/B/C = 0/1/2, bit 7 rising), U8 sequence number.
CycleCurrentMessage (plant -> controller, RPDO2, sent before its edge; Modbus register 204):
    U16 mean |i| over the commutation cycle the edge ends, in mA (0xFFFF: not measured), U8
    sequence number of that edge. The predictor's K_T is per ampere of this cycle mean (Eq. 8);
    without it the controller falls back to the current at the edge.
CommandMessage (controller -> plant, TPDO1):
    U32 instant in 100 ns ticks, U16 duty x 65535 (0xFFFF... see KEEP_DUTY), U8 sector (0-5,
    0xFF keep), U8 sequence number of the edge it answers | 0x80 on the last frame of the reply.
"""

from __future__ import annotations

import dataclasses
import enum
import struct
from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True)
class Command:
    """A commutation command for the plant: from ``at_s`` on, energise ``sector`` (0..5, -1 = all
    switches off) with ``duty`` (None = keep) and torque ``direction`` (+1 / -1, None = keep)."""

    at_s: float
    sector: int | None = None
    duty: float | None = None
    direction: int | None = None


class Strategy(enum.IntEnum):
    """How the controller commutates (CANopen 0x2010, Modbus register 10)."""

    RAW = 0
    CORRECTED = 1
    KF = 2
    SAGE_HUSA = 3


class Fault(enum.IntEnum):
    """EMCY error codes (CiA 301: 0xFF00-0xFFFF manufacturer specific)."""

    ILLEGAL_HALL_CODE = 0xFF01
    MISSING_EDGE = 0xFF02
    FILTER_GUARD_TRIP = 0xFF03
    INVALID_CALIBRATION = 0xFF04
    CAPTURE_TIMING = 0xFF05      #: a capture time that does not increase (edge discarded)
    INTERNAL = 0x6100            #: CiA 301 internal software error


class CalibrationTableError(ValueError):
    """A downloaded table is refused; ``field`` names the entry."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


class FilterSettingsVector(Protocol):
    """What crosses the link of the predictors' ``FilterSettings`` (the contract does not import the
    predictors, which compile numba kernels): the forgetting factor b and the Q0, R0, P0 diagonals."""

    forgetting_b: float
    q0_diag: tuple[float, float, float]
    r0_diag: tuple[float, float]
    p0_diag: tuple[float, float, float]

    def check(self) -> None: ...


def filter_vector(settings: FilterSettingsVector) -> list[float]:
    """The nine filter settings every link carries (CANopen 0x2020, Modbus 60-77), in order."""
    return [settings.forgetting_b, *settings.q0_diag, *settings.r0_diag, *settings.p0_diag]


def with_filter_vector(settings: FilterSettingsVector, vector) -> FilterSettingsVector:
    """``settings`` with b, Q0, R0 and P0 taken from the nine-value vector (validated)."""
    v = [float(x) for x in vector]
    new = dataclasses.replace(
        settings, forgetting_b=v[0], q0_diag=tuple(v[1:4]), r0_diag=tuple(v[4:6]), p0_diag=tuple(v[6:9])
    )
    new.check()
    return new


TICK_S = 1e-7
WRAP = 1 << 32
KEEP_SECTOR = 0xFF
KEEP_DUTY = 0xFFFF
DUTY_SCALE = 65534.0  # duty 1.0 -> 65534; 0xFFFF means "keep"
_FMT = "<IHBB"


def next_epoch(epoch: int, last_ticks: int | None, ticks: int) -> int:
    """The device's capture-timer epoch for an edge stamped ``ticks`` after one stamped ``last_ticks``:
    a step back by more than half the 32-bit range is a wrap; a small step back is a bad stamp, not a wrap."""
    if last_ticks is not None and ticks < last_ticks and last_ticks - ticks > WRAP // 2:
        return epoch + WRAP
    return epoch


def edge_epoch(t_s: float) -> int:
    """Ticks of the capture timer's completed wraps at time t_s (both ends know the plant's
    time base, so a wrap of the 32-bit timer is undone the same way on every link)."""
    return (int(round(t_s / TICK_S)) >> 32) << 32


def _ticks(t_s: float) -> int:
    """Capture-timer ticks of an instant, before the 32-bit wrap."""
    return int(round(t_s / TICK_S))


def _current_ma(current_a: float) -> int:
    """The edge message's U16 mean |i| in mA (clamped to its range)."""
    return max(0, min(int(round(current_a * 1000.0)), 0xFFFF))


def _duty_u16(duty: float) -> int:
    """The command message's duty, clamped to 0..1 and scaled (KEEP_DUTY is never produced)."""
    return int(round(min(max(duty, 0.0), 1.0) * DUTY_SCALE))


@dataclass(frozen=True)
class EdgeMessage:
    ticks: int
    current_ma: int
    sensor: int
    rising: bool
    seq: int

    def pack(self) -> bytes:
        return struct.pack(
            _FMT,
            self.ticks % WRAP,
            self.current_ma,
            (self.sensor & 0x03) | (0x80 if self.rising else 0),
            self.seq & 0xFF,
        )

    @classmethod
    def unpack(cls, data: bytes) -> "EdgeMessage":
        if len(data) != 8:
            raise ValueError(f"edge message needs 8 bytes, got {len(data)}")
        ticks, ma, flags, seq = struct.unpack(_FMT, bytes(data))
        if flags & 0x03 == 3 or flags & 0x7C:
            raise ValueError(f"edge message flags 0x{flags:02X}: sensor must be 0-2 and bits 2-6 clear")
        return cls(ticks, ma, flags & 0x03, bool(flags & 0x80), seq)

    @classmethod
    def from_edge(cls, edge: dict, seq: int) -> "EdgeMessage":
        return cls(
            _ticks(edge["t_capture_s"]),
            _current_ma(edge.get("current_a", 0.0)),
            int(edge["sensor"]),
            bool(edge["rising"]),
            seq,
        )

    def to_edge(self, epoch_ticks: int = 0) -> dict:
        """As the controller sees it: its own clock is the capture timer (``epoch_ticks`` undoes the wrap)."""
        t = (epoch_ticks + self.ticks) * TICK_S
        return {
            "t_capture_s": t,
            "sensor": self.sensor,
            "rising": self.rising,
            "now_s": t,
            "current_a": self.current_ma / 1000.0,
        }


NO_CURRENT = 0xFFFF


@dataclass(frozen=True)
class CycleCurrentMessage:
    current_ma: int
    seq: int

    def pack(self) -> bytes:
        return struct.pack("<HB", self.current_ma, self.seq & 0xFF)

    @classmethod
    def unpack(cls, data: bytes) -> "CycleCurrentMessage":
        if len(data) != 3:
            raise ValueError(f"cycle-current message needs 3 bytes, got {len(data)}")
        ma, seq = struct.unpack("<HB", bytes(data))
        return cls(ma, seq)

    @classmethod
    def from_edge(cls, edge: dict, seq: int) -> "CycleCurrentMessage | None":
        """The message for ``edge``'s cycle-mean current, or None when the edge has none."""
        if edge.get("cycle_current_a") is None:
            return None
        return cls(min(_current_ma(edge["cycle_current_a"]), NO_CURRENT - 1), seq)

    @property
    def current_a(self) -> float | None:
        return None if self.current_ma == NO_CURRENT else self.current_ma / 1000.0


def with_cycle_current(edge: dict, current_ma: int | None) -> dict:
    """The received edge with its cycle-mean current (mA as carried; None or NO_CURRENT: none)."""
    if current_ma is not None and current_ma != NO_CURRENT:
        edge["cycle_current_a"] = current_ma / 1000.0
    return edge


@dataclass(frozen=True)
class CommandMessage:
    ticks: int
    duty_u16: int
    sector: int
    seq: int
    last: bool

    def pack(self) -> bytes:
        return struct.pack(
            _FMT, self.ticks % WRAP, self.duty_u16, self.sector, (self.seq & 0x7F) | (0x80 if self.last else 0)
        )

    @property
    def keeps_everything(self) -> bool:
        """The frame of an empty reply (see encode_reply): no command for the plant."""
        return self.sector == KEEP_SECTOR and self.duty_u16 == KEEP_DUTY

    @classmethod
    def unpack(cls, data: bytes) -> "CommandMessage":
        if len(data) != 8:
            raise ValueError(f"command message needs 8 bytes, got {len(data)}")
        ticks, duty, sector, seq = struct.unpack(_FMT, bytes(data))
        return cls(ticks, duty, sector, seq & 0x7F, bool(seq & 0x80))

    @classmethod
    def from_command(cls, command, seq: int, last: bool) -> "CommandMessage":
        duty = KEEP_DUTY if command.duty is None else _duty_u16(command.duty)
        sector = KEEP_SECTOR if command.sector is None else int(command.sector)
        return cls(_ticks(command.at_s), duty, sector, seq, last)

    def to_command(self, epoch_ticks: int = 0) -> Command:
        return Command(
            at_s=(epoch_ticks + self.ticks) * TICK_S,
            sector=None if self.sector == KEEP_SECTOR else self.sector,
            duty=None if self.duty_u16 == KEEP_DUTY else self.duty_u16 / DUTY_SCALE,
        )


def edge_as_received(edge: dict, epoch_ticks: int) -> dict:
    """What the controller receives for ``edge``: ``EdgeMessage.unpack(EdgeMessage.from_edge(edge,
    seq).pack()).to_edge(epoch_ticks)`` without building the bytes (the in-process link's hot
    path; tests/test_dut.py holds the two equal)."""
    if int(edge["sensor"]) not in (0, 1, 2):
        raise ValueError(f"edge message flags: sensor must be 0-2, got {edge['sensor']!r}")
    t = (epoch_ticks + _ticks(edge["t_capture_s"]) % WRAP) * TICK_S
    out = {
        "t_capture_s": t,
        "sensor": int(edge["sensor"]),
        "rising": bool(edge["rising"]),
        "now_s": t,
        "current_a": _current_ma(edge.get("current_a", 0.0)) / 1000.0,
    }
    cycle = edge.get("cycle_current_a")
    return with_cycle_current(out, None if cycle is None else min(_current_ma(cycle), NO_CURRENT - 1))


def commands_as_received(commands, epoch_ticks: int) -> list:
    """What the plant receives for a reply: the commands through ``encode_reply``, pack, unpack
    and ``to_command`` without building the bytes (the in-process link's hot path)."""
    out = []
    for c in commands:
        if c.sector is None and c.duty is None:
            continue  # a "keep everything" frame: nothing for the plant
        duty = None if c.duty is None else _duty_u16(c.duty) / DUTY_SCALE
        out.append(
            Command(
                at_s=(epoch_ticks + _ticks(c.at_s) % WRAP) * TICK_S,
                sector=None if c.sector is None else int(c.sector),
                duty=duty,
            )
        )
    return out


def encode_reply(commands, seq: int) -> list[CommandMessage]:
    """The frames answering edge ``seq``; an empty reply is one 'keep everything' frame marked last."""
    if not commands:
        return [CommandMessage(0, KEEP_DUTY, KEEP_SECTOR, seq, True)]
    return [CommandMessage.from_command(c, seq, i == len(commands) - 1) for i, c in enumerate(commands)]
