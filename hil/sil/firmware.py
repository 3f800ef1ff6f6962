"""A firmware's shared library, loaded with ctypes and checked against ``hil-sil/1``.

Loaded only in a firmware's own process (``hil.sil.worker``): a firmware that crashes takes its
process with it, never the run.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

ABI = 1
#: exports every firmware has, and the optional ones (the compare unit's pair, the EMCY queue)
REQUIRED = ("hil_sil_describe", "hil_sil_reset", "hil_sil_hall_isr", "hil_sil_control_isr", "hil_sil_gates",
            "hil_sil_duty", "hil_sil_od_read", "hil_sil_od_write")
OPTIONAL = ("hil_sil_compare_isr", "hil_sil_compare", "hil_sil_emcy")


class SilInterfaceError(RuntimeError):
    """The library breaks ``hil-sil/1`` before anything runs (a missing export, a wrong abi, an
    impossible description); one line naming the export or field."""


class _Info(ctypes.Structure):
    _fields_ = [
        ("abi", ctypes.c_uint32),
        ("name", ctypes.c_char_p),
        ("timer_hz", ctypes.c_uint32),
        ("timer_bits", ctypes.c_uint8),
        ("control_hz", ctypes.c_uint32),
        ("amps_per_count", ctypes.c_float),
        ("pole_pairs", ctypes.c_uint8),
    ]


@dataclass(frozen=True)
class FirmwareInfo:
    """``hil_sil_describe``'s answer."""

    abi: int
    name: str
    timer_hz: int
    timer_bits: int
    control_hz: int
    amps_per_count: float
    pole_pairs: int
    has_compare: bool
    has_emcy: bool

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def check_info(path: str, info: FirmwareInfo) -> None:
    """Refuse an impossible ``hil_sil_describe`` answer in one line naming the field (every kind of
    firmware: a library here, an ELF on an emulated core in hil.pil.firmware)."""
    checks = (
        ("abi", info.abi == ABI, f"must be {ABI} (hil-sil/{ABI})"),
        ("timer_bits", info.timer_bits in (16, 32), "must be 16 or 32"),
        ("timer_hz", info.timer_hz > 0, "must be positive"),
        ("control_hz", 0 < info.control_hz <= info.timer_hz, "must be positive and at most timer_hz"),
        ("amps_per_count", math.isfinite(info.amps_per_count) and info.amps_per_count > 0,
         "must be positive and finite"),
        ("pole_pairs", info.pole_pairs >= 1, "must be at least 1"),
    )
    for field_name, ok, rule in checks:
        if not ok:
            raise SilInterfaceError(
                f"{path}: hil_sil_describe gave {field_name} = {getattr(info, field_name)!r}: {rule}")


def check_exports(path: str, has) -> dict[str, bool]:
    """The optional exports ``path`` has (``has(name)``), after refusing a missing required one
    or half of the compare unit, in one line."""
    missing = [name for name in REQUIRED if not has(name)]
    if missing:
        raise SilInterfaceError(f"{path}: missing export{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    found = {name: has(name) for name in OPTIONAL}
    if found["hil_sil_compare"] != found["hil_sil_compare_isr"]:
        one, other = ("hil_sil_compare", "hil_sil_compare_isr") if found["hil_sil_compare"] else (
            "hil_sil_compare_isr", "hil_sil_compare")
        raise SilInterfaceError(f"{path}: exports {one} but not {other} (the compare unit needs both)")
    return found


class Firmware:
    """The exports of one loaded library, typed."""

    def __init__(self, path: str):
        try:
            self.lib = lib = ctypes.CDLL(path)
        except OSError as exc:
            raise SilInterfaceError(f"{path}: cannot be loaded: {exc}") from None
        has = check_exports(path, lambda name: hasattr(lib, name))
        u8, u16, u32, i16p = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.POINTER(ctypes.c_int16)
        lib.hil_sil_describe.argtypes, lib.hil_sil_describe.restype = [ctypes.POINTER(_Info)], None
        lib.hil_sil_reset.argtypes, lib.hil_sil_reset.restype = [u8], None
        lib.hil_sil_hall_isr.argtypes, lib.hil_sil_hall_isr.restype = [u32, u8, u8, i16p], None
        lib.hil_sil_control_isr.argtypes, lib.hil_sil_control_isr.restype = [u32, i16p], None
        lib.hil_sil_gates.argtypes, lib.hil_sil_gates.restype = [], u8
        lib.hil_sil_duty.argtypes, lib.hil_sil_duty.restype = [], u16
        lib.hil_sil_od_read.argtypes = [u16, u8, ctypes.c_char_p, u32]
        lib.hil_sil_od_read.restype = ctypes.c_int32
        lib.hil_sil_od_write.argtypes = [u16, u8, ctypes.c_char_p, u32]
        lib.hil_sil_od_write.restype = ctypes.c_int32
        if has["hil_sil_compare"]:
            lib.hil_sil_compare_isr.argtypes, lib.hil_sil_compare_isr.restype = [u32], None
            lib.hil_sil_compare.argtypes = [ctypes.POINTER(u32)]
            lib.hil_sil_compare.restype = ctypes.c_int
        if has["hil_sil_emcy"]:
            lib.hil_sil_emcy.argtypes, lib.hil_sil_emcy.restype = [ctypes.POINTER(u16)], ctypes.c_int
        self.path = path
        self.has_compare, self.has_emcy = has["hil_sil_compare"], has["hil_sil_emcy"]
        # the hot calls, bound once
        self.hall_isr = lib.hil_sil_hall_isr
        self.control_isr = lib.hil_sil_control_isr
        self.gates = lib.hil_sil_gates
        self.duty = lib.hil_sil_duty
        self.compare_isr = lib.hil_sil_compare_isr if self.has_compare else None
        self._compare = lib.hil_sil_compare if self.has_compare else None
        self._emcy = lib.hil_sil_emcy if self.has_emcy else None
        self._count = ctypes.c_uint32(0)
        self._count_ref = ctypes.byref(self._count)
        self._code = ctypes.c_uint16(0)
        self._code_ref = ctypes.byref(self._code)
        self.adc = (ctypes.c_int16 * 3)()  #: the ADC's result registers, passed to every ISR

    def describe(self) -> FirmwareInfo:
        raw = _Info()
        self.lib.hil_sil_describe(ctypes.byref(raw))
        name = raw.name.decode("utf-8", "replace") if raw.name else ""
        info = FirmwareInfo(int(raw.abi), name, int(raw.timer_hz), int(raw.timer_bits), int(raw.control_hz),
                            float(raw.amps_per_count), int(raw.pole_pairs), self.has_compare, self.has_emcy)
        check_info(self.path, info)
        return info

    def reset(self, levels: int) -> None:
        self.lib.hil_sil_reset(levels)

    def compare(self) -> int | None:
        """The armed compare count, or None."""
        return int(self._count.value) if self._compare(self._count_ref) else None

    def emcy(self) -> int | None:
        """One EMCY code popped from the firmware's queue, or None."""
        return int(self._code.value) if self._emcy is not None and self._emcy(self._code_ref) else None

    def od_read(self, index: int, sub: int, size: int) -> bytes | int:
        """The object's bytes, or the (negative) SDO abort code."""
        buf = ctypes.create_string_buffer(max(size, 1))
        n = int(self.lib.hil_sil_od_read(index, sub, buf, size))
        if n < 0:
            return n
        if n > size:
            raise SilInterfaceError(
                f"hil_sil_od_read(0x{index:04X}, {sub}) returned {n} bytes into a buffer of {size}"
            )
        return buf.raw[:n]

    def od_write(self, index: int, sub: int, data: bytes) -> int:
        return int(self.lib.hil_sil_od_write(index, sub, data, len(data)))
