"""IEEE 1364 Value Change Dump: a streaming writer and a streaming reader.

Both work on integer time ticks of the file's ``$timescale``. The writer takes batches of
changes in time order and writes only those (a wire that does not change costs nothing); the
reader yields the changes of the variables asked for in bounded chunks. Scalars (``0!``),
vectors (``b101 !``) and reals (``r1.25 !``) are read; ``x`` and ``z`` read as 0.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import SignalError

_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15}
_UNIT_NAMES = ("s", "ms", "us", "ns", "ps", "fs")


#: identifier characters: VCD allows ! to ~; '#' and '$' are left out so that no identifier
#: looks like a timestamp or a keyword to a simple reader
_ID_CHARS = [chr(c) for c in range(33, 127) if chr(c) not in "#$"]


def _id_code(index: int) -> str:
    """Short identifier of variable ``index``."""
    chars = []
    index += 1
    while index:
        index, r = divmod(index - 1, len(_ID_CHARS))
        chars.append(_ID_CHARS[r])
    return "".join(chars)


@dataclass(frozen=True)
class Timescale:
    """A VCD time unit: ``multiplier`` (1, 10 or 100) times ``unit`` ("s" ... "fs")."""

    multiplier: int
    unit: str

    @property
    def seconds(self) -> float:
        return self.multiplier * _UNITS[self.unit]

    def __str__(self) -> str:
        return f"{self.multiplier} {self.unit}"

    @classmethod
    def parse(cls, text: str, where: str) -> "Timescale":
        m = re.fullmatch(r"\s*(1|10|100)\s*(s|ms|us|ns|ps|fs)\s*", text)
        if not m:
            raise SignalError(where, f"$timescale {text.strip()!r} is not 1|10|100 followed by s, ms, us, ns, ps or fs")
        return cls(int(m.group(1)), m.group(2))

    @classmethod
    def for_sample_rate(cls, sample_rate_hz: float) -> tuple["Timescale", int]:
        """The coarsest VCD unit in which one sample period is a whole number of ticks, and that
        number. A power-of-ten rate gets a unit of exactly one sample (1 MHz: ``1 us``), which is
        also the rate a logic-analyser tool imports the file at."""
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise SignalError("sample_rate_hz", f"must be a positive number, got {sample_rate_hz!r}")
        period = 1.0 / sample_rate_hz
        for unit in _UNIT_NAMES:  # coarse to fine
            for mult in (100, 10, 1):
                ticks = period / (mult * _UNITS[unit])
                if ticks >= 1 - 1e-9 and abs(ticks - round(ticks)) <= 1e-9 * ticks:
                    return cls(mult, unit), int(round(ticks))
        raise SignalError(
            "sample_rate_hz", f"{sample_rate_hz!r} Hz has no sample period that is a whole number of femtoseconds"
        )


class VcdWriter:
    """Streams a VCD: declare variables, give the initial values, then batches of changes."""

    def __init__(
        self,
        path: str | Path,
        timescale: Timescale,
        wires: list[str],
        reals: list[str] = (),
        scope: str = "hil",
        comment: str = "",
        real_format: str = "%.6g",
    ):
        self.path = Path(path)
        self._f = open(self.path, "w", encoding="ascii", newline="\n")
        self.names = list(wires) + list(reals)
        self.n_wires = len(wires)
        self.codes = [_id_code(i) for i in range(len(self.names))]
        self.real_format = real_format
        self._last_tick = -1
        f = self._f
        f.write("$date\n   bldc-hil\n$end\n$version\n   bldc-hil signals\n$end\n")
        if comment:
            f.write("$comment\n   " + comment.replace("$end", "$ end") + "\n$end\n")
        f.write(f"$timescale {timescale} $end\n$scope module {scope} $end\n")
        for i, name in enumerate(self.names):
            kind, size = ("wire", 1) if i < self.n_wires else ("real", 64)
            f.write(f"$var {kind} {size} {self.codes[i]} {name} $end\n")
        f.write("$upscope $end\n$enddefinitions $end\n")

    def _value(self, index: int, value: float) -> str:
        if index < self.n_wires:
            return f"{int(value)}{self.codes[index]}"
        return f"r{self.real_format % value} {self.codes[index]}"

    def initial(self, values: list[float]) -> None:
        """Values of every variable at tick 0 (the ``$dumpvars`` block)."""
        self._f.write("#0\n$dumpvars\n" + "\n".join(self._value(i, v) for i, v in enumerate(values)) + "\n$end\n")
        self._last_tick = 0

    def changes(self, ticks: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
        """A batch of changes, sorted by tick (stable: a later change at one tick wins)."""
        if ticks.size == 0:
            return
        if ticks[0] < self._last_tick:
            raise ValueError(f"VCD changes out of order: tick {int(ticks[0])} after {self._last_tick}")
        lines = []
        last = self._last_tick
        codes, n_wires, fmt = self.codes, self.n_wires, self.real_format
        for t, i, v in zip(ticks.tolist(), index.tolist(), values.tolist()):
            if t != last:
                lines.append(f"#{t}")
                last = t
            lines.append(f"{int(v)}{codes[i]}" if i < n_wires else f"r{fmt % v} {codes[i]}")
        self._last_tick = last
        self._f.write("\n".join(lines) + "\n")

    def close(self, end_tick: int | None = None) -> None:
        """Close the file; ``end_tick`` marks where the recording ends (a bare timestamp)."""
        if end_tick is not None and end_tick > self._last_tick:
            self._f.write(f"#{int(end_tick)}\n")
        self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if not self._f.closed:
            self._f.close()


@dataclass(frozen=True)
class VcdVariable:
    code: str
    name: str        #: reference name as declared (``AH``, ``gates[0]``)
    path: str        #: dotted scope path and name (``top.dut.AH``)
    kind: str        #: wire, reg, real, ...
    size: int


class VcdReader:
    """Reads a VCD's header at once and its value changes in chunks (bounded memory)."""

    BLOCK_BYTES = 8 << 20

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise SignalError(str(path), "missing file")
        self.variables: list[VcdVariable] = []
        self.timescale: Timescale | None = None
        self._header_end = 0
        self._read_header()

    def _blocks(self, start: int = 0) -> Iterator[list[bytes]]:
        """Whitespace-separated tokens, a block at a time; a vector or real value never ends a
        block without the identifier that follows it."""
        with open(self.path, "rb") as f:
            f.seek(start)
            carry: list[bytes] = []
            cut = False  # the previous block ended inside a token (its last piece is carry[-1])
            while True:
                block = f.read(self.BLOCK_BYTES)
                if not block:
                    break
                parts = block.split()
                if carry:
                    if cut and parts and not block[:1].isspace():
                        parts = carry[:-1] + [carry[-1] + parts[0]] + parts[1:]
                    else:
                        parts = carry + parts
                carry = []
                cut = not block[-1:].isspace()
                if parts and cut:
                    carry.append(parts.pop())
                if parts and parts[-1][:1] in (b"b", b"B", b"r", b"R"):
                    carry.insert(0, parts.pop())
                if parts:
                    yield parts
            if carry:
                yield carry

    def _read_header(self) -> None:
        where = str(self.path)
        scope: list[str] = []
        with open(self.path, "rb") as f:
            head = b""
            while b"$enddefinitions" not in head:
                block = f.read(1 << 16)
                if not block:
                    raise SignalError(where, "no $enddefinitions: not a VCD file, or a truncated header")
                head += block
                if len(head) > 64 << 20:
                    raise SignalError(where, "header longer than 64 MB without $enddefinitions")
        end = head.index(b"$enddefinitions")
        after = head.index(b"$end", end + len(b"$enddefinitions"))
        self._header_end = after + len(b"$end")
        try:
            text = head[:end].decode("ascii", errors="replace")
        except Exception:  # pragma: no cover - decode with replace cannot fail
            raise SignalError(where, "header is not text") from None
        for m in re.finditer(r"\$(\w+)(.*?)\$end", text, flags=re.S):
            key, body = m.group(1), m.group(2).split()
            line = text.count("\n", 0, m.start()) + 1
            if key == "timescale":
                self.timescale = Timescale.parse(" ".join(body), f"{where}, line {line}")
            elif key == "scope":
                scope.append(body[1] if len(body) > 1 else (body[0] if body else ""))
            elif key == "upscope":
                if scope:
                    scope.pop()
            elif key == "var":
                if len(body) < 4:
                    raise SignalError(
                        f"{where}, line {line}", f"$var needs type, size, id and name, got {' '.join(body)!r}"
                    )
                name = body[3] + ("".join(body[4:]) if len(body) > 4 else "")
                try:
                    size = int(body[1])
                except ValueError:
                    raise SignalError(f"{where}, line {line}", f"$var size {body[1]!r} is not a number") from None
                self.variables.append(VcdVariable(body[2], name, ".".join([*scope, name]), body[0], size))
        if self.timescale is None:
            raise SignalError(where, "no $timescale in the header (the time unit must be stated)")

    def find(self, name: str) -> VcdVariable:
        """A variable by reference name, bit-indexed name or dotted path; the name must be unique."""
        hits = [v for v in self.variables if name in (v.name, v.path) or v.path.endswith("." + name)]
        if not hits:
            raise SignalError(
                str(self.path), f"no variable {name!r} (have: {', '.join(v.path for v in self.variables)})"
            )
        if len({v.code for v in hits}) > 1:
            raise SignalError(
                str(self.path),
                f"variable name {name!r} is ambiguous ({', '.join(v.path for v in hits)}); give the dotted path",
            )
        return hits[0]

    def changes(self, names: list[str], chunk: int = 1 << 20) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Yields ``(ticks, slot, value)`` arrays: the changes of ``names`` (slot = index into
        ``names``) in file order, one batch per block of the file. After the iteration
        :attr:`end_tick` is the last timestamp in the file."""
        del chunk  # batches follow the file's blocks (BLOCK_BYTES), which bound the memory
        slots: dict[bytes, list[int]] = {}
        for i, n in enumerate(names):
            slots.setdefault(self.find(n).code.encode(), []).append(i)
        self._t = 0
        self._last_t = -1
        self._skipping = False
        where = str(self.path)
        for tokens in self._blocks(self._header_end):
            if self._skipping or _ambiguous(tokens) or not _SKIPPED_BLOCKS.isdisjoint(tokens):
                out = self._slow(tokens, slots, where)
            else:
                out = self._fast(tokens, slots, where)
            if out[0].size:
                yield out
        self.end_tick = max(self._last_t, 0)

    def _fast(self, tokens: list[bytes], slots: dict[bytes, list[int]], where: str):
        """A block of tokens, classified in numpy (the common case: no comments inside)."""
        arr = np.array(tokens)
        first = arr.astype("S1")
        n = arr.size
        is_vec = np.isin(first, [b"b", b"B", b"r", b"R"])
        after_vec = np.zeros(n, dtype=bool)
        after_vec[1:] = is_vec[:-1]
        is_ts = (first == b"#") & ~after_vec
        known = is_ts | is_vec | after_vec | np.isin(first, [b"0", b"1", b"x", b"X", b"z", b"Z", b"$"])
        if not known.all():
            bad = int(np.nonzero(~known)[0][0])
            raise SignalError(where, f"unexpected token {tokens[bad][:40].decode(errors='replace')!r}")
        ts_pos = np.nonzero(is_ts)[0]
        try:
            ts_val = np.char.lstrip(arr[ts_pos], b"#").astype(np.int64)
        except ValueError:
            raise SignalError(where, "bad timestamp in the value changes") from None
        seq = np.concatenate([[self._last_t], ts_val])
        back = np.nonzero(np.diff(seq) < 0)[0]
        if back.size:
            raise SignalError(
                where, f"timestamp #{int(seq[back[0] + 1])} goes back in time (after #{int(seq[back[0]])})"
            )
        last_ts = np.where(is_ts, np.arange(n), -1)
        np.maximum.accumulate(last_ts, out=last_ts)
        time_of = np.where(
            last_ts >= 0, np.concatenate([ts_val, [0]])[np.searchsorted(ts_pos, np.maximum(last_ts, 0))], self._t
        )
        pos, slot, val = [], [], []
        for code, ss in slots.items():
            for prefix, v in ((b"1", 1.0), (b"0", 0.0), (b"x", 0.0), (b"X", 0.0), (b"z", 0.0), (b"Z", 0.0)):
                hit = np.nonzero((arr == prefix + code) & ~after_vec)[0]
                for k in ss:
                    pos.append(hit)
                    slot.append(np.full(hit.size, k))
                    val.append(np.full(hit.size, v))
            hit = np.nonzero(after_vec & (arr == code))[0]
            if hit.size:
                values = (
                    np.array([_vector_value(tokens[i - 1], where) for i in hit])
                    if hit.size < 64 or first[hit[0] - 1] not in (b"r", b"R")
                    else _reals(arr[hit - 1], tokens, hit, where)
                )
                for k in ss:
                    pos.append(hit)
                    slot.append(np.full(hit.size, k))
                    val.append(values)
        if ts_val.size:
            self._t = int(ts_val[-1])
            self._last_t = int(ts_val[-1])
        if not pos:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        p = np.concatenate(pos)
        order = np.argsort(p, kind="stable")
        return (
            time_of[p[order]].astype(np.int64),
            np.concatenate(slot)[order].astype(np.int64),
            np.concatenate(val)[order],
        )

    def _slow(self, tokens: list[bytes], slots: dict[bytes, list[int]], where: str):
        """A block token by token (comments inside the value changes)."""
        ticks: list[int] = []
        slot_out: list[int] = []
        vals: list[float] = []
        pending = None
        for tok in tokens:
            if self._skipping:
                if tok == b"$end":
                    self._skipping = False
                continue
            if pending is not None:
                for k in slots.get(tok, ()):
                    ticks.append(self._t)
                    slot_out.append(k)
                    vals.append(_vector_value(pending, where))
                pending = None
                continue
            c = tok[0]
            if c == 35:  # '#'
                try:
                    t = int(tok[1:])
                except ValueError:
                    raise SignalError(where, f"bad timestamp {tok.decode(errors='replace')!r}") from None
                if t < self._last_t:
                    raise SignalError(where, f"timestamp #{t} goes back in time (after #{self._last_t})")
                self._t = self._last_t = t
            elif c in b"01xXzZ":
                for k in slots.get(tok[1:], ()):
                    ticks.append(self._t)
                    slot_out.append(k)
                    vals.append(1.0 if c == 49 else 0.0)
            elif c in b"bBrR":
                pending = tok
            elif c == 36:  # '$'
                if tok in (b"$comment", b"$date", b"$version"):
                    self._skipping = True
            else:
                raise SignalError(where, f"unexpected token {tok[:40].decode(errors='replace')!r} after #{self._t}")
        return np.array(ticks, dtype=np.int64), np.array(slot_out, dtype=np.int64), np.array(vals, dtype=float)


_SKIPPED_BLOCKS = frozenset((b"$comment", b"$date", b"$version"))


def _ambiguous(tokens: list[bytes]) -> bool:
    """An identifier that itself starts like a vector or real value right after one (legal, rare):
    the block is read token by token."""
    vec = [t[:1] in (b"b", b"B", b"r", b"R") for t in tokens]
    return any(a and b for a, b in zip(vec, vec[1:]))


def _reals(values: np.ndarray, tokens: list[bytes], hit: np.ndarray, where: str) -> np.ndarray:
    try:
        return np.char.lstrip(values, b"rR").astype(float)
    except ValueError:  # a vector among them, or a bad number: one by one, with the message
        return np.array([_vector_value(tokens[i - 1], where) for i in hit])


def _vector_value(tok: bytes, where: str) -> float:
    body = tok[1:]
    if tok[:1] in b"rR":
        try:
            return float(body)
        except ValueError:
            raise SignalError(where, f"bad real value {tok.decode(errors='replace')!r}") from None
    bits = body.replace(b"x", b"0").replace(b"X", b"0").replace(b"z", b"0").replace(b"Z", b"0")
    try:
        return float(int(bits, 2))
    except ValueError:
        raise SignalError(where, f"bad vector value {tok.decode(errors='replace')!r}") from None
