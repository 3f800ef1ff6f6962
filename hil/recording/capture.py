"""Logic-analyser captures of the six gate signals (and the three Hall lines): VCD, sigrok
session (.sr), CSV with time. Every format is one :class:`CaptureFormat`, given its suffixes in
``formats.FORMATS``; the gate import, the Hall import (``hil recording import``, ``hall.py``) and every
command that takes a RECORDING open a capture file through that table alone (``formats.open_capture``).

Every reader yields the capture as a stream of state changes in bounded chunks: ``(t_s, state)``
arrays where ``state`` packs the six gates (bit 0 AH, 1 AL, 2 BH, 3 BL, 4 CH, 5 CL; 1 = switch
on) and holds from ``t_s`` until the next row. The first row is the state at the capture's
start. After the iteration, ``end_s`` is where the capture ends.

Which capture channel is which gate is a :class:`GateMapping` (TOML or ``AH=D0,AL=D1,...``).
"""

from __future__ import annotations

import configparser
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from bldc.tomlfile import load_toml

from .errors import SignalError
from .vcd import VcdReader

GATES = ("AH", "AL", "BH", "BL", "CH", "CL")

_TIME_UNITS = {"s": 1.0, "sec": 1.0, "seconds": 1.0, "ms": 1e-3, "milliseconds": 1e-3, "us": 1e-6, "µs": 1e-6,
               "microseconds": 1e-6, "ns": 1e-9, "nanoseconds": 1e-9, "ps": 1e-12}


@dataclass(frozen=True)
class GateMapping:
    """Capture channel of each gate (by name; a CSV column may also be given by 1-based number)."""

    channels: dict[str, str] = field(default_factory=lambda: {g: g for g in GATES})
    #: CSV: the time column (default: the first column) and its unit in seconds (default: from
    #: the header, "Time [us]", "microseconds", ...; else seconds)
    time: str | None = None
    time_scale: float | None = None
    #: CSV: a value above this is a 1 (for analog-looking exports)
    threshold: float = 0.5
    #: gates whose capture channel reads 0 when the switch is on (inverting gate drivers)
    active_low: tuple[str, ...] = ()
    #: the logic signals read, bit j of the state is ``signals[j]`` (the six gates; the Hall
    #: importer reads the three Hall lines A, B, C with the same readers)
    signals: tuple[str, ...] = GATES

    def __post_init__(self):
        missing = [g for g in self.signals if g not in self.channels]
        unknown = [g for g in self.channels if g not in self.signals]
        if missing or unknown:
            raise SignalError(
                "mapping",
                f"needs exactly the signals {', '.join(self.signals)}"
                + (f"; missing {', '.join(missing)}" if missing else "")
                + (f"; unknown {', '.join(unknown)}" if unknown else ""),
            )
        bad = [g for g in self.active_low if g not in self.signals]
        if bad:
            raise SignalError("mapping.active_low", f"unknown gate(s) {', '.join(bad)}")

    @classmethod
    def parse(cls, text: str) -> "GateMapping":
        """``AH=D0,AL=D1,...`` (gates not named map to themselves)."""
        channels = {g: g for g in GATES}
        for item in (p.strip() for p in text.split(",") if p.strip()):
            if "=" not in item:
                raise SignalError("--channels", f"{item!r} is not GATE=CHANNEL")
            g, ch = (v.strip() for v in item.split("=", 1))
            if g not in GATES:
                raise SignalError("--channels", f"{g!r} is not a gate ({', '.join(GATES)})")
            channels[g] = ch
        return cls(channels)

    @classmethod
    def from_toml(cls, path: str | Path) -> "GateMapping":
        """``[channels] AH = "D0" ...``; optional ``time``, ``time_scale``, ``threshold``, ``active_low``."""
        data = load_toml(path, {"channels": set(GATES), "time": None, "time_scale": None, "threshold": None,
                                "active_low": None})
        channels = {g: g for g in GATES} | {g: str(ch) for g, ch in data.get("channels", {}).items()}
        try:
            return cls(channels, data.get("time"), data.get("time_scale"), float(data.get("threshold", 0.5)),
                       tuple(data.get("active_low", ())))
        except SignalError as exc:
            raise SignalError(f"{path}: {exc.where}", str(exc).split(": ", 1)[1]) from None

    @property
    def invert_mask(self) -> int:
        return sum(1 << self.signals.index(g) for g in self.active_low)


class Capture:
    """A capture file read in its format; iterate :meth:`states` for the change stream
    (``formats.open_capture`` opens one by its suffix)."""

    def __init__(self, path: str | Path, fmt: "CaptureFormat", mapping: GateMapping | None = None):
        self.path = Path(path)
        self.mapping = mapping or GateMapping()
        self.format = fmt
        self.kind = self.format.name
        self.end_s: float | None = None
        self.start_s: float | None = None
        self.sample_period_s: float | None = None  #: time resolution of the capture

    def states(self, chunk: int = 1 << 20) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        source = self.format.read(self, chunk)
        inv = self.mapping.invert_mask
        last = -1
        for t, s in source:
            s = s ^ inv if inv else s
            keep = np.ones(s.size, dtype=bool)
            keep[1:] = s[1:] != s[:-1]
            if s.size and s[0] == last:
                keep[0] = False
            if keep.any():
                if self.start_s is None:
                    self.start_s = float(t[0])
                yield t[keep], s[keep]
                last = int(s[-1])

    # --- VCD -------------------------------------------------------------------------------------
    def _vcd(self, chunk: int):
        r = VcdReader(self.path)
        scale = r.timescale.seconds
        self.sample_period_s = scale
        names, bit_of = [], []
        for g in self.mapping.signals:
            name, bit = _vcd_channel(r, self.mapping.channels[g])
            names.append(name)
            bit_of.append(bit)
        n_signals = len(self.mapping.signals)
        bits = np.zeros(n_signals, dtype=np.int64)
        first = True
        for ticks, slot, val in r.changes(names, chunk):
            if any(b is not None for b in bit_of):  # one bit of a vector (a gate bus)
                val = val.copy()
                for j, b in enumerate(bit_of):
                    if b is not None:
                        mine = slot == j
                        val[mine] = (val[mine].astype(np.int64) >> b) & 1
            n = ticks.size
            state = np.empty(n, dtype=np.int64)
            # each gate's value after every change: forward fill of its own changes
            acc = np.zeros(n, dtype=np.int64)
            for j in range(n_signals):
                mine = slot == j
                vals = np.where(mine, val.astype(np.int64), -1)
                idx = np.where(mine, np.arange(n), -1)
                np.maximum.accumulate(idx, out=idx)
                col = np.where(idx >= 0, vals[np.maximum(idx, 0)], bits[j])
                acc |= (col & 1) << j
                if mine.any():
                    bits[j] = int(vals[np.nonzero(mine)[0][-1]])
            state[:] = acc
            # the state after the last change at each timestamp
            last_of_tick = np.ones(n, dtype=bool)
            last_of_tick[:-1] = ticks[1:] != ticks[:-1]
            if first:
                first = False
                if ticks[0] > 0:  # no $dumpvars at #0: everything off until the first change
                    yield np.array([0.0]), np.array([0], dtype=np.int64)
            yield ticks[last_of_tick] * scale, state[last_of_tick]
        self.end_s = r.end_tick * scale

    # --- sigrok session ----------------------------------------------------------------------------
    def _sigrok(self, chunk: int):
        where = str(self.path)
        try:
            zf = zipfile.ZipFile(self.path)
        except zipfile.BadZipFile:
            raise SignalError(where, "not a sigrok session file (not a zip archive)") from None
        with zf:
            names = set(zf.namelist())
            if "metadata" not in names:
                raise SignalError(where, "no 'metadata' member: not a sigrok session file")
            version = zf.read("version").decode().strip() if "version" in names else "?"
            if version != "2":
                raise SignalError(
                    f"{where}: version", f"sigrok session format version {version!r}; this reader knows version 2"
                )
            meta = configparser.ConfigParser(interpolation=None)
            meta.read_string(zf.read("metadata").decode())
            dev = next((s for s in meta.sections() if s.startswith("device")), None)
            if dev is None:
                raise SignalError(f"{where}: metadata", "no [device N] section")
            sec = meta[dev]
            rate = _parse_rate(sec.get("samplerate", ""), f"{where}: metadata samplerate")
            unitsize = int(sec.get("unitsize", "1"))
            capturefile = sec.get("capturefile", "logic-1")
            probes = {sec[k]: int(k[5:]) - 1 for k in sec if re.fullmatch(r"probe\d+", k)}
            bit_of = []
            for g in self.mapping.signals:
                ch = self.mapping.channels[g]
                if ch not in probes:
                    raise SignalError(where, f"no logic channel {ch!r} for gate {g} (have: {', '.join(probes)})")
                bit_of.append(probes[ch])
            parts = sorted(
                (n for n in names if re.fullmatch(re.escape(capturefile) + r"-\d+", n)),
                key=lambda n: int(n.rsplit("-", 1)[1]),
            )
            if not parts and capturefile in names:
                parts = [capturefile]  # very old single-file sessions
            self.sample_period_s = 1.0 / rate
            k0 = 0
            prev = None
            step = max(chunk, 1) * unitsize
            for part in parts:
                with zf.open(part) as fh:
                    tail = b""
                    while True:
                        data = fh.read(step)
                        if not data:
                            break
                        data = tail + data
                        cut = len(data) - len(data) % unitsize
                        data, tail = data[:cut], data[cut:]
                        raw = np.frombuffer(data, dtype=np.uint8).reshape(-1, unitsize)
                        word = np.zeros(raw.shape[0], dtype=np.int64)
                        for b in range(unitsize):
                            word |= raw[:, b].astype(np.int64) << (8 * b)
                        state = np.zeros(word.size, dtype=np.int64)
                        for j, bit in enumerate(bit_of):
                            state |= ((word >> bit) & 1) << j
                        change = np.ones(state.size, dtype=bool)
                        change[1:] = state[1:] != state[:-1]
                        if prev is not None:
                            change[0] = state[0] != prev
                        idx = np.nonzero(change)[0]
                        if idx.size:
                            yield (k0 + idx) / rate, state[idx]
                        prev = int(state[-1]) if state.size else prev
                        k0 += state.size
            self.end_s = k0 / rate

    # --- CSV -----------------------------------------------------------------------------------------
    def _csv(self, chunk: int):
        import pandas as pd

        where = str(self.path)
        header_line, header, comments = _csv_header(self.path)
        cols = [c.strip() for c in header]
        time_col = self.mapping.time if self.mapping.time is not None else cols[0]
        t_index = _column_index(time_col, cols, where, "time")
        idx = [_column_index(self.mapping.channels[g], cols, where, g) for g in self.mapping.signals]
        scale = self.mapping.time_scale if self.mapping.time_scale is not None else _unit_of(cols[t_index])
        shift = 0.0
        sigrok = _libsigrok_rate(comments)
        if sigrok is not None:
            # libsigrok's CSV output: the time unit is the coarsest one in which a sample period is
            # whole (unnamed with label=channel), and sample k is printed at (k + 1) periods
            period = 1.0 / sigrok
            if self.mapping.time_scale is None and cols[t_index].lower() not in _TIME_UNITS:
                scale = next(
                    u
                    for u in (1.0, 1e-3, 1e-6, 1e-9, 1e-12)
                    if abs(period / u - round(period / u)) < 1e-6 * period / u and round(period / u) >= 1
                )
            shift = period
            self.sample_period_s = period
        prev_t = -np.inf
        t_last = None
        line = header_line + 1
        try:
            use = sorted(set([t_index] + idx))
            reader = pd.read_csv(
                self.path,
                skiprows=header_line,
                header=0,
                chunksize=chunk,
                usecols=use,
                skipinitialspace=True,
                dtype=float,
            )
            for frame in reader:
                a = frame.to_numpy(dtype=float)
                a = a[:, [use.index(c) for c in [t_index] + idx]]
                t = a[:, 0] * scale - shift
                bad = np.nonzero(~np.isfinite(a).all(axis=1))[0]
                if bad.size:
                    raise SignalError(f"{where}, line {line + int(bad[0]) + 1}", "non-numeric or empty value")
                back = np.nonzero(np.diff(np.concatenate([[prev_t], t])) < 0)[0]
                if back.size:
                    raise SignalError(f"{where}, line {line + int(back[0]) + 1}", f"time goes back ({t[back[0]]!r} s)")
                state = np.zeros(t.size, dtype=np.int64)
                for j in range(len(idx)):
                    state |= (a[:, 1 + j] > self.mapping.threshold).astype(np.int64) << j
                if t.size > 1 and self.sample_period_s is None:
                    d = np.diff(t)
                    d = d[d > 0]
                    self.sample_period_s = float(d.min()) if d.size else None
                line += t.size
                prev_t = t[-1]
                t_last = t[-1]
                yield t, state
        except ValueError as exc:
            if isinstance(exc, SignalError):
                raise
            raise SignalError(where, f"not a readable CSV capture: {exc}") from None
        self.end_s = float(t_last) if t_last is not None else 0.0


def _vcd_channel(reader: VcdReader, channel: str) -> tuple[str, int | None]:
    """A gate's VCD variable: a 1-bit variable by name, or bit ``k`` of a vector as ``name[k]``."""
    try:
        reader.find(channel)
        return channel, None
    except SignalError:
        m = re.fullmatch(r"(.+)\[(\d+)\]", channel)
        if not m:
            raise
        base, bit = m.group(1), int(m.group(2))
        hits = [v for v in reader.variables if v.size > 1 and re.sub(r"\[.*\]$", "", v.name) == base]
        if len(hits) != 1:
            raise
        v = hits[0]
        lsb = 0
        rng = re.search(r"\[(\d+):(\d+)\]$", v.name)
        if rng:
            lsb = min(int(rng.group(1)), int(rng.group(2)))
        if not 0 <= bit - lsb < v.size:
            raise SignalError(str(reader.path), f"{channel!r}: bit {bit} is outside {v.name} ({v.size} bits)") from None
        return v.path, bit - lsb


def _csv_header(path: Path) -> tuple[int, list[str], list[str]]:
    """(0-based line of the header, its fields, the comment lines before it): the header is the
    first line that is not a ';' or '#' comment."""
    comments = []
    with open(path, newline="") as f:
        for i, line in enumerate(f):
            s = line.strip()
            if not s or s[0] in ";#":
                comments.append(s)
                continue
            return i, s.split(","), comments
    raise SignalError(str(path), "no header line (CSV captures need a header with a time column)")


def _libsigrok_rate(comments: list[str]) -> float | None:
    """The sample rate of a libsigrok CSV export (None for other CSV files)."""
    if not any("generated by libsigrok" in c for c in comments):
        return None
    for c in comments:
        m = re.search(r"Samplerate:\s*(.+)$", c)
        if m:
            return _parse_rate(m.group(1), "libsigrok CSV samplerate")
    return None


def _column_index(name: str, cols: list[str], where: str, what: str) -> int:
    if name in cols:
        if cols.count(name) > 1:
            raise SignalError(
                where, f"column {name!r} ({what}) appears {cols.count(name)} times; map it by number (1-based)"
            )
        return cols.index(name)
    if str(name).isdigit() and 1 <= int(name) <= len(cols):
        return int(name) - 1
    raise SignalError(where, f"no column {name!r} for {what} (have: {', '.join(cols)})")


def _unit_of(name: str) -> float:
    """Seconds per unit of a time column named like "Time [us]", "t_s", "microseconds"."""
    low = name.strip().lower()
    m = re.search(r"[\[(]\s*([a-zµ]+)\s*[\])]", low)
    if m and m.group(1) in _TIME_UNITS:
        return _TIME_UNITS[m.group(1)]
    if low in _TIME_UNITS:
        return _TIME_UNITS[low]
    m = re.search(r"_(s|ms|us|ns)$", low)
    if m:
        return _TIME_UNITS[m.group(1)]
    return 1.0


def _parse_rate(text: str, where: str) -> float:
    m = re.fullmatch(r"\s*([0-9.]+)\s*([kMG]?)Hz\s*", text)
    if not m:
        raise SignalError(where, f"cannot read sample rate {text!r}")
    return float(m.group(1)) * {"": 1.0, "k": 1e3, "M": 1e6, "G": 1e9}[m.group(2)]


# --- channel names and time base of each format (what the Hall import asks of a capture) -------------

#: CSV times are whole multiples of the step to this relative tolerance (printed decimals)
CSV_STEP_TOLERANCE = 1e-3


def time_step(t_s: np.ndarray, unit_s: float | None) -> float | None:
    """The greatest common step of the time stamps: on integer ticks of ``unit_s`` (a VCD), or,
    for printed decimal times (``unit_s`` None), the smallest step if every step is a whole
    multiple of it within CSV_STEP_TOLERANCE."""
    if t_s.size < 2:
        return None
    d = np.diff(t_s)
    d = d[d > 0]
    if not d.size:
        return None
    if unit_s is not None:
        ticks = np.round(d / unit_s).astype(np.int64)
        return float(np.gcd.reduce(ticks)) * unit_s
    step = float(d.min())
    ratio = d / step
    if np.all(np.abs(ratio - np.round(ratio)) < CSV_STEP_TOLERANCE * np.maximum(ratio, 1.0)):
        return step
    return None


def _vcd_channels(path: Path, time_column: str | None) -> list[str]:
    return [v.name for v in VcdReader(path).variables if v.size == 1]


def _vcd_time_base(cap: "Capture", t_s: np.ndarray) -> tuple[float | None, str]:
    unit = VcdReader(cap.path).timescale.seconds
    return time_step(t_s, unit), f"the greatest common step of the VCD's time stamps ({unit:g} s timescale)"


def _sigrok_channels(path: Path, time_column: str | None) -> list[str]:
    try:
        with zipfile.ZipFile(path) as zf:
            meta = configparser.ConfigParser(interpolation=None)
            meta.read_string(zf.read("metadata").decode())
    except (zipfile.BadZipFile, KeyError):
        raise SignalError(str(path), "not a sigrok session file (a zip archive with 'metadata')") from None
    dev = next((s for s in meta.sections() if s.startswith("device")), None)
    if dev is None:
        raise SignalError(f"{path}: metadata", "no [device N] section")
    probes = sorted((int(k[5:]), v) for k, v in meta[dev].items() if re.fullmatch(r"probe\d+", k))
    return [v for _, v in probes]


def _sigrok_time_base(cap: "Capture", t_s: np.ndarray) -> tuple[float | None, str]:
    return cap.sample_period_s, "the sigrok session's sample rate"


def _csv_channels(path: Path, time_column: str | None) -> list[str]:
    _, header, _ = _csv_header(path)
    cols = [c.strip() for c in header]
    t = time_column if time_column is not None else cols[0]
    return [c for c in cols if c != t]


def _csv_time_base(cap: "Capture", t_s: np.ndarray) -> tuple[float | None, str]:
    return time_step(t_s, None), "the smallest step of the CSV's times (every step a whole multiple of it)"


@dataclass(frozen=True)
class CaptureFormat:
    """One capture file format, declared once: how its file is read and what it says of itself."""

    name: str  #: the reader's name (``Capture.kind``)
    label: str  #: how messages name it ("VCD", "sigrok session")
    #: (capture, chunk) -> the stream of ``(t_s, state)`` arrays (see the module doc); the reader
    #: sets ``capture.end_s`` at the end and may set ``capture.sample_period_s``
    read: Callable[["Capture", int], Iterator[tuple[np.ndarray, np.ndarray]]]
    #: (path, time column or None) -> the capture's logic channel names, in file order
    channels: Callable[[Path, str | None], list[str]]
    #: (capture after reading, its change times) -> (the time base in s or None, how it was found)
    time_base: Callable[["Capture", np.ndarray], tuple[float | None, str]]
    #: the time is a column of the file (a table): ``--time-column`` and ``--sample-rate-hz``
    #: (the column counts samples) apply
    time_column: bool = False


#: the capture formats (``formats.FORMATS`` gives each its file suffixes)
VCD = CaptureFormat("vcd", "VCD", Capture._vcd, _vcd_channels, _vcd_time_base)
SIGROK = CaptureFormat("sigrok", "sigrok session", Capture._sigrok, _sigrok_channels, _sigrok_time_base)
CSV = CaptureFormat("csv", "CSV", Capture._csv, _csv_channels, _csv_time_base, time_column=True)
