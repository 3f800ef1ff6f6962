"""The contract between the controller and the framework: the one module both sides import.

Everything that crosses the link is defined here and nowhere else: the commutation ``Command`` the
plant executes, the ``Strategy`` codes and their names, the ``Fault`` (EMCY) codes and their names,
the filter's counters, the refusal of a calibration table, the nine-value filter-settings vector,
and the edge and command messages. Where a device keeps each of them (a CANopen index, a Modbus
register) is not the contract's business: that is its device profile (``hil/dut/profiles``,
docs/device-profiles.md). The
controller (``hil.controller``) and the simulator (``plant_models``) both depend on this module and
never on each other (``docs/architecture.md``). The wire layouts are in ``docs/controller.md``.

The edge and command messages every link carries (CANopen PDOs, a Modbus register block; the
in-process link builds the same fields without the bytes, so all links give the controller
bit-identical inputs). Wire layouts and versions: docs/controller.md.

EdgeMessage, version 2 (plant -> controller): what the MCU's own peripherals hold at a capture
    (docs/controller.md). Header, 8 bytes, sent last (it triggers): U32 capture time in 100 ns
    timer ticks (wraps after 429 s), U8 flags (bits 0-1 sensor A/B/C = 0/1/2, bit 7 rising), U8
    sequence number, U16 age of the newest periodic conversion in ticks (0xFFFF: none).
    Accumulators: the phase-current sensors' conversions summed since the previous capture (I32
    per phase, in counts) and how many (U16). Window: conversion 0 at the capture event, then the
    newest periodic conversions, ADC_PERIOD_TICKS apart (I16 a, b, c in counts). CANopen: the
    header on the first COB-ID, after 8-byte data frames on the second (accumulators at indices
    0xFD-0xFF, then the conversions oldest first, each ending in U8 sequence number, U8 index).
    Modbus: ``pack``'s bytes, two per register, the first one high, from the mailbox's first
    register (the parts that do not fit written before it). The controller computes the current
    at the edge's own instant and the cycle's mean current (Eq. 8's input) from them itself.
    Version 1 (8 bytes carrying currents the bench computed) is withdrawn.
CommandMessage (controller -> plant, TPDO1):
    U32 instant in 100 ns ticks, U16 duty x 65535 (0xFFFF... see KEEP_DUTY), U8 sector (0-5,
    0xFF keep), U8 sequence number of the edge it answers | 0x80 on the last frame of the reply.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import struct
from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class Command:
    """A commutation command for the plant: from ``at_s`` on, energise ``sector`` (0..5, -1 = all
    switches off) with ``duty`` (None = keep) and torque ``direction`` (+1 / -1, None = keep)."""

    at_s: float
    sector: int | None = None
    duty: float | None = None
    direction: int | None = None


class Strategy(enum.IntEnum):
    """How the controller commutates (the device profile's ``strategy`` role says where a device keeps it)."""

    RAW = 0
    CORRECTED = 1
    KF = 2
    SAGE_HUSA = 3


#: the strategies by the names files, device profiles, reports and the command line use:
#: raw, corrected, kf, sage_husa
STRATEGY_NAMES = {s.name.lower(): s for s in Strategy}


def strategy_named(name: str) -> Strategy:
    """The strategy called ``name``; ``sage-husa``, as stimulus files and campaign specs were once
    written, reads as ``sage_husa``. ValueError names the known strategies."""
    try:
        return STRATEGY_NAMES[name.replace("-", "_") if isinstance(name, str) else name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown strategy {name!r} (known: {', '.join(STRATEGY_NAMES)})") from None


class Fault(enum.IntEnum):
    """EMCY error codes (CiA 301: 0xFF00-0xFFFF manufacturer specific)."""

    ILLEGAL_HALL_CODE = 0xFF01
    MISSING_EDGE = 0xFF02
    FILTER_GUARD_TRIP = 0xFF03
    INVALID_CALIBRATION = 0xFF04
    CAPTURE_TIMING = 0xFF05      #: a capture time that does not increase (edge discarded)
    INTERNAL_ERROR = 0x6100      #: CiA 301 internal software error
    INTERNAL = INTERNAL_ERROR    #: the same code under the shorter name the device faces raise it by


#: the faults by the names device profiles use to map a device's own codes onto them:
#: illegal_hall_code, missing_edge, filter_guard_trip, invalid_calibration, capture_timing, internal_error
FAULT_NAMES = {f.name.lower(): f for f in Fault}

#: the Sage-Husa filter's counters a controller exposes, in this order (docs/controller.md): edges
#: the innovation gate held back, covariance matrices repaired (an eigenvalue floor on R or P),
#: divergence fades, and Q estimates projected onto their band
FILTER_COUNTERS = ("gated_edges", "covariance_repairs", "divergence_fades", "band_projections")
#: the counter of every guard intervention of the filter (the sum of all guards)
GUARD_TRIPS = "guard_trips"


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
    """The nine filter settings every link carries, in order (the profile's filter_* roles say where)."""
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


def _duty_u16(duty: float) -> int:
    """The command message's duty, clamped to 0..1 and scaled (KEEP_DUTY is never produced)."""
    return int(round(min(max(duty, 0.0), 1.0) * DUTY_SCALE))


#: The largest conditioning delay (rise or fall, s) a calibration table may carry, and the effect
#: library's bound on a plant's. Physics: a delay must stay well inside a sector at the top speed,
#: at most half of one (beyond it, an edge the circuit holds back is captured after the middle of
#: the next sector, and the Hall code at the capture no longer names the sector the rotor is in).
#: Sector time at N rpm and p pole pairs: 60 / (360 p N / 60) s. Real open-collector wiring (pull-up
#: into a 1 nF filter and the cable) is measured at 134 us rise minus fall on a spindle motor (top
#: 333 Hz e: 500 us sectors) and 276 us on a hoverboard hub motor; the slowest-commutating motors
#: with such wiring are many-pole hub motors: 15 pole pairs at a top speed of 600 rpm is 150 Hz e,
#: a 1.11 ms sector, half of it 556 us; 500 us is that rounded down. A motor faster than that
#: bounds its own delay tighter (the calibration checks half a sector at the capture's top speed).
MAX_CONDITIONING_DELAY_S = 500e-6

#: The largest pole-table entry (deg e) a calibration table may carry. The table holds each magnet
#: boundary relative to pole N1's, so two of the effect library's pole offsets (+-5 deg e each) apart,
#: and a rise-minus-fall switching asymmetry common to the three sensors falls on every other pole
#: (the library bounds it at +-10 deg e): 5 + 5 + 10. It stays a third of a sector, so a table
#: beyond it is garbage, not a magnet.
MAX_POLE_TABLE_OFFSET_DEG_E = 20.0

#: The controller's ADC as the bench emulates it (docs/controller.md, "What the controller's
#: peripherals hold"). Its three phase-current sensors are converted at the capture event (an
#: injected conversion the capture timer triggers, as MCU timers can) and every ADC_PERIOD_TICKS
#: of the capture timer (500 kHz, into a DMA ring, as motor-control MCUs' 2-5 MS/s ADCs allow: the
#: current right after a commutation turns within microseconds, and at 20 us between conversions a
#: line between them missed the current at the Hall switch by up to 1.7 A; at 4 us the worst
#: calibrated deviation set of the acceptance search still missed REQ-ROB-001 by 1 %), and
#: at a lower rate a conversion is also added to per-phase accumulators that the capture
#: interrupt reads and clears (the commutation cycle's sums; the bench adds one conversion per plant
#: sample, 50 kHz by default, and the count goes with the sums).
ADC_PERIOD_TICKS = 20
ADC_PERIOD_S = ADC_PERIOD_TICKS * TICK_S
#: the most conversions an edge message carries: the capture's and the periodic ones back to
#: MAX_CONDITIONING_DELAY_S (the built-in controller's table bound: the edge's current is read this
#: long before its capture at most) and one beyond (the line through the oldest instant needs both
#: ends). A message carries only as many as the controller's own table reaches (hil-edge/3)
MAX_ADC_SAMPLES = math.ceil(MAX_CONDITIONING_DELAY_S / ADC_PERIOD_S - 1e-9) + 2
#: one count of a conversion: 2 mA, so an I16 spans +-65.5 A (beyond it a conversion saturates)
ADC_LSB_A = 2e-3
NO_SAMPLES = 0xFFFF  #: the header's newest-conversion age when the message carries no window
_HEADER_FMT = "<IBBH"
_SAMPLE_FMT = "<hhhBB"
_SUM_FMT = "<iHBB"
#: the data frames' indices of the three accumulators (conversions take 0..MAX_ADC_SAMPLES - 1)
ACCUMULATOR_INDEX = 0xFD
assert MAX_ADC_SAMPLES <= ACCUMULATOR_INDEX, "a conversion's frame index would collide with the accumulators'"


def _adc_counts(current_a) -> np.ndarray:
    """Phase-current sensor outputs in ADC counts (I16, saturating)."""
    counts = np.rint(np.asarray(current_a, dtype=float) / ADC_LSB_A)
    # np.clip's python wrappers cost more than the work on an edge's few values
    return np.minimum(np.maximum(counts, -32768.0), 32767.0).astype(np.int64)


@dataclass(frozen=True)
class EdgeMessage:
    """The edge message, version 2 (docs/controller.md): the capture and the controller's ADC.

    ``samples``: the window, three sensor outputs per conversion in counts, newest first: 0 the
    conversion the capture event triggers, k >= 1 taken ``newest_sample_age_ticks + (k - 1) *
    ADC_PERIOD_TICKS`` ticks before the capture.
    ``sums`` and ``summed``: the per-phase accumulators (counts) and the number of conversions they
    hold since the previous capture. The controller computes the current at the edge's own
    instant and the commutation cycle's mean from them itself, as firmware does from its ADC."""

    ticks: int
    sensor: int
    rising: bool
    seq: int
    newest_sample_age_ticks: int = NO_SAMPLES
    samples: tuple[tuple[int, int, int], ...] = ()
    sums: tuple[int, int, int] = (0, 0, 0)
    summed: int = 0

    def __post_init__(self):
        if len(self.samples) > MAX_ADC_SAMPLES:
            raise ValueError(f"edge message carries at most {MAX_ADC_SAMPLES} ADC samples, got {len(self.samples)}")
        if (len(self.samples) > 1) != (self.newest_sample_age_ticks != NO_SAMPLES):
            raise ValueError("edge message: the periodic conversions' age needs them, and they need an age")
        if not 0 <= self.summed <= 0xFFFF:
            raise ValueError(f"edge message: the accumulators hold 0-65535 conversions, got {self.summed}")

    # --- wire forms (docs/controller.md) ---------------------------------------------------------
    def header(self) -> bytes:
        """The 8-byte header (CANopen RPDO1; Modbus mailbox registers 0-3), sent last: it triggers."""
        return struct.pack(
            _HEADER_FMT,
            self.ticks % WRAP,
            (self.sensor & 0x03) | (0x80 if self.rising else 0),
            self.seq & 0xFF,
            self.newest_sample_age_ticks,
        )

    def data_frames(self) -> list[bytes]:
        """The frames that precede the header (CANopen: the second RPDO), 8 bytes each, ending in
        U8 sequence number and U8 index: the accumulators at indices ACCUMULATOR_INDEX.. (I32 sum of
        phase a with U16 conversions summed, then I32 sums of b and c with U16 0), then one frame
        per conversion, oldest first (I16 phase a, b, c; index 0 the capture's)."""
        seq = self.seq & 0xFF
        sums = [
            struct.pack(_SUM_FMT, self.sums[k], self.summed if k == 0 else 0, seq, ACCUMULATOR_INDEX + k)
            for k in range(3)
        ]
        return sums + [struct.pack(_SAMPLE_FMT, *self.samples[k], seq, k) for k in range(len(self.samples) - 1, -1, -1)]

    def pack(self) -> bytes:
        """Header, accumulators and window as one byte string (the Modbus mailbox's content)."""
        return (
            self.header()
            + struct.pack("<iiiH", *self.sums, self.summed)
            + b"".join(struct.pack("<hhh", *s) for s in self.samples)
        )

    @classmethod
    def _unpack_header(cls, data: bytes) -> tuple["EdgeMessage", int]:
        """The header without the rest, and the newest conversion's age it announces."""
        if len(data) != 8:
            raise ValueError(f"edge message header needs 8 bytes, got {len(data)}")
        ticks, flags, seq, age = struct.unpack(_HEADER_FMT, bytes(data))
        if flags & 0x03 == 3 or flags & 0x7C:
            raise ValueError(f"edge message flags 0x{flags:02X}: sensor must be 0-2 and bits 2-6 clear")
        return cls(ticks, flags & 0x03, bool(flags & 0x80), seq), age

    def _with(self, age: int, samples, sums, summed) -> "EdgeMessage":
        return EdgeMessage(self.ticks, self.sensor, self.rising, self.seq, age if len(samples) > 1 else NO_SAMPLES,
                           tuple(samples), tuple(sums), summed)

    @classmethod
    def unpack(cls, data: bytes) -> "EdgeMessage":
        """Header, accumulators and window from one byte string (``pack``)."""
        data = bytes(data)
        if len(data) < 22 or (len(data) - 22) % 6:
            raise ValueError(f"edge message needs 22 + 6 n bytes, got {len(data)}")
        head, age = cls._unpack_header(data[:8])
        a, b, c, summed = struct.unpack_from("<iiiH", data, 8)
        samples = [struct.unpack_from("<hhh", data, 22 + 6 * k) for k in range((len(data) - 22) // 6)]
        return head._with(age, samples, (a, b, c), summed)

    @classmethod
    def from_frames(cls, header: bytes, frames: list[bytes]) -> "EdgeMessage":
        """The message from its header and the data frames received before it: frames of another
        sequence number are stale and ignored; the conversions of this one must be indices 0..n-1
        once each; without its accumulator frames the accumulators read empty."""
        head, age = cls._unpack_header(header)
        by_index: dict[int, bytes] = {}
        for f in frames:
            if len(f) != 8:
                raise ValueError(f"edge data frame needs 8 bytes, got {len(f)}")
            seq, k = f[6], f[7]
            if seq != head.seq:
                continue
            if k in by_index:
                raise ValueError(f"edge #{seq}: data frame {k} received twice")
            by_index[k] = bytes(f)
        sums, summed = [0, 0, 0], 0
        if all(ACCUMULATOR_INDEX + k in by_index for k in range(3)):
            for k in range(3):
                sums[k], n, _, _ = struct.unpack(_SUM_FMT, by_index.pop(ACCUMULATOR_INDEX + k))
                summed = n if k == 0 else summed
        if sorted(by_index) != list(range(len(by_index))):
            raise ValueError(f"edge #{head.seq}: conversion indices {sorted(by_index)} are not 0..n-1")
        samples = [struct.unpack(_SAMPLE_FMT, by_index[k])[:3] for k in range(len(by_index))]
        return head._with(age, samples, sums, summed)

    # --- the two ends ---------------------------------------------------------------------------
    @classmethod
    def from_edge(cls, edge: dict, seq: int) -> "EdgeMessage":
        """What the bench sends for ``edge``: its capture; the conversion the capture triggers,
        ``capture_phase_currents_a`` (three values), and the periodic window ``adc_t_s``
        (ascending, ADC_PERIOD_S apart) with ``adc_phase_currents_a`` (a row of three per
        conversion); the cycle's accumulated conversions ``adc_cycle_phase_currents_a`` (rows of
        three), when given."""
        ticks = _ticks(edge["t_capture_s"])
        samples, age = _window_counts(edge, ticks)
        sums, summed = _cycle_counts(edge)
        head = cls(ticks, int(edge["sensor"]), bool(edge["rising"]), seq)
        return head._with(age, tuple(map(tuple, samples.tolist())), sums, summed)

    def to_edge(self, epoch_ticks: int = 0) -> dict:
        """As the controller sees it: its own clock is the capture timer (``epoch_ticks`` undoes the
        wrap); the window ascending in time, in amperes; the accumulators in ampere-conversions."""
        return _received(self.ticks, self.sensor, self.rising, self.newest_sample_age_ticks, self.samples, self.sums,
                         self.summed, epoch_ticks)


def _window_counts(edge: dict, ticks: int) -> tuple[np.ndarray, int]:
    """An edge's ADC window in counts, newest first (the capture's conversion, then the periodic
    ones, at most MAX_ADC_SAMPLES), and the newest periodic conversion's age in ticks."""
    if edge.get("capture_phase_currents_a") is None:
        return np.empty((0, 3), dtype=np.int64), NO_SAMPLES
    capture = _adc_counts(edge["capture_phase_currents_a"]).reshape(1, 3)
    t = edge.get("adc_t_s")
    if t is None or not len(t):
        return capture, NO_SAMPLES
    periodic = _adc_counts(edge["adc_phase_currents_a"]).reshape(-1, 3)[::-1][: MAX_ADC_SAMPLES - 1]
    age = ticks - _ticks(t[-1])
    if not 0 <= age < NO_SAMPLES:
        raise ValueError(f"edge ADC window: the newest conversion must precede the capture ({age} ticks)")
    return np.concatenate([capture, periodic]), age


def _cycle_counts(edge: dict) -> tuple[tuple[int, int, int], int]:
    """The accumulators: the cycle's conversions summed per phase (counts), and how many (the last 65535)."""
    cycle = edge.get("adc_cycle_phase_currents_a")
    counts = _adc_counts(cycle if cycle is not None else np.empty((0, 3)))[-0xFFFF:]
    return tuple(int(v) for v in counts.sum(axis=0)), len(counts)


def _received(ticks: int, sensor: int, rising: bool, age: int, samples, sums, summed: int, epoch_ticks: int) -> dict:
    """The edge as the controller sees it (``EdgeMessage.to_edge``) from the message's fields;
    ``samples`` newest first, in counts."""
    t = (epoch_ticks + ticks) * TICK_S
    edge = {"t_capture_s": t, "sensor": sensor, "rising": rising, "now_s": t,
            "adc_cycle_sums_a": np.asarray(sums, dtype=float) * ADC_LSB_A,
            "adc_cycle_conversions": summed}
    if len(samples):
        k = np.arange(len(samples) - 2, -1, -1)
        periodic = (epoch_ticks + ticks - age - k * ADC_PERIOD_TICKS) * TICK_S
        edge["adc_t_s"] = np.append(periodic, t)
        edge["adc_phase_currents_a"] = np.asarray(samples[::-1], dtype=float) * ADC_LSB_A
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
    """What the controller receives for ``edge``: the message's fields as they cross any link
    (``unpack(pack(m)) == m``: tests/test_dut.py), without building the bytes or the message (the
    in-process link's hot path)."""
    if int(edge["sensor"]) not in (0, 1, 2):
        raise ValueError(f"edge message flags: sensor must be 0-2, got {edge['sensor']!r}")
    ticks = _ticks(edge["t_capture_s"])
    samples, age = _window_counts(edge, ticks)
    sums, summed = _cycle_counts(edge)
    return _received(ticks % WRAP, int(edge["sensor"]), bool(edge["rising"]), age if len(samples) > 1 else NO_SAMPLES,
                     samples, sums, summed, epoch_ticks)


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
