"""The block hook and the instruction checks in C (``native.c``), handed to Unicorn through its C API.

Unicorn's Python binding costs about 1.7 us per hooked block and about 10 us per checked
instruction (a callback, then a register read); a Hall interrupt of the reference firmware runs
hundreds of blocks. ``native.c`` does what ``Core._on_block`` and ``Core._on_check`` do, in C, from
a table Python fills: when Python first decodes a block (Capstone, hil.pil.cycles) it inserts the
block's cost, instruction count, taken-branch extras, FP flag and soft-float entry into the C hash
map. A block the map does not hold (or holds with another size), and a block whose decoding found
a fault, go to Python's hook, so the first sight of every block, and every finding, stay Python's.
Soft-float entries are counted per routine in C and added to the running call's statistics when
the emulation returns to Python. The C file is compiled for the host once (the compiler ``sil:``
builds with: ``HIL_SIL_CC``, else ``cc``, else Zig's clang from pip) into ``hil.sil.build``'s
cache. Where that build or its loading fails, ``Core`` keeps the Python hooks (one warning line),
which stay the reference implementation: the same calls give the same cycles, instructions,
soft-float counts and stack either way (tests/test_pil_core.py).

The state the two share (``_State``, ``pil_state`` in C) is written by Python before every
``uc_emu_start`` (``push``) and read after it and around every call back into Python (``pull``).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import math
import sys
import warnings
from pathlib import Path

import unicorn

from hil.sil.build import SilBuildError, cached_build, run_compiler, toolchain

from .cycles import Block

SOURCE = Path(__file__).resolve().with_name("native.c")
SOFT_FLOAT_MAX = 256  #: PIL_SOFT_FLOAT_MAX: soft-float routines counted in C (more stay Python's)
FP, PYTHON = 1, 2  #: pil_block.flags
_SUFFIX = {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")


#: the leading int64 fields of ``pil_state``, in order (Python reads and writes them as one array)
_SHARED = ("cycles", "instructions", "stop_at", "prev_fallthrough", "prev_taken_extra", "charge", "uses_fp",
           "fp_frame", "lazy_stacked", "softfloat_dirty", "lazy_fp_stacking", "framework_lo", "framework_hi",
           "tail_cycles", "tail_instructions", "hang_at")
_INF = (1 << 63) - 1  #: stop_at of a call that runs to its end (INT64_MAX)


class _State(ctypes.Structure):
    """``pil_state`` of native.c (the same fields in the same order)."""

    _fields_ = [*((name, ctypes.c_int64) for name in _SHARED),
                ("softfloat_counts", ctypes.c_int64 * SOFT_FLOAT_MAX),
                ("emu_stop", ctypes.c_void_p), ("reg_read", ctypes.c_void_p), ("slow_block", ctypes.c_void_p),
                ("slow_check", ctypes.c_void_p), ("table", ctypes.c_void_p), ("mask", ctypes.c_uint64),
                ("used", ctypes.c_uint64)]


class _Check(ctypes.Structure):
    """``pil_check`` of native.c: one checked instruction."""

    _fields_ = [("state", ctypes.c_void_p), ("kind", ctypes.c_uint32), ("reg", ctypes.c_int32),
                ("offset", ctypes.c_uint32), ("index", ctypes.c_uint32), ("index_reg", ctypes.c_int32),
                ("mask", ctypes.c_uint32)]


_SLOW_BLOCK = ctypes.CFUNCTYPE(None, ctypes.c_uint64, ctypes.c_uint32)
_SLOW_CHECK = ctypes.CFUNCTYPE(None, ctypes.c_uint64, ctypes.c_uint32, ctypes.c_uint32)


def _uclib() -> ctypes.CDLL:
    """The libunicorn the Python binding loaded (unicorn 2.1's binding keeps it here)."""
    from unicorn.unicorn_py3.unicorn import uclib

    return uclib


def _build() -> Path:
    tc = toolchain()
    source = SOURCE.read_bytes()
    flags = ["-shared", "-O2", "-fPIC", "-fvisibility=hidden"]
    key = "pil-native-" + hashlib.sha256(repr((tc.cc, tc.version, flags, sys.platform)).encode()
                                         + source).hexdigest()[:20]

    def make(work: Path, log: list[str]) -> None:
        from .build import _Where

        run_compiler([*tc.cc, *flags, str(SOURCE), "-o", str(work / f"pil_native{_SUFFIX}")], _Where(SOURCE), log,
                     "building the native block hook for the host")

    library, _, _ = cached_build(key, f"pil_native{_SUFFIX}", make)
    return library


@functools.lru_cache(maxsize=None)
def library() -> ctypes.CDLL | None:
    """native.c built for the host and loaded, with its prototypes; None (and one warning line) where
    the host build or loading fails: the Python hooks are then used."""
    try:
        lib = ctypes.CDLL(str(_build()))
        _uclib()
    except (SilBuildError, OSError, ImportError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        warnings.warn(f"hil.pil: the native block hook is not available ({first}); cycles are counted by the "
                      "Python hook (the same figures, slower)", RuntimeWarning, stacklevel=3)
        return None
    v, u64, u32 = ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint32
    lib.pil_new.restype = v
    lib.pil_new.argtypes = [v, v, v, v, ctypes.c_int64]
    lib.pil_free.restype = None
    lib.pil_free.argtypes = [v]
    lib.pil_state_size.restype = u64
    lib.pil_insert.restype = ctypes.c_int
    lib.pil_insert.argtypes = [v, u64, u32, u32, u32, u32, u32, ctypes.c_int32, u32]
    if lib.pil_state_size() != ctypes.sizeof(_State):
        warnings.warn("hil.pil: the native block hook's state does not match its Python declaration; cycles are "
                      "counted by the Python hook", RuntimeWarning, stacklevel=3)
        return None
    return lib


def _release(lib, uclib, pointer: int, uc_ref, uch, hooks: list[int]) -> None:
    """The C state freed, its hooks first taken off an engine that outlives them."""
    if uc_ref() is not None:
        for handle in hooks:
            uclib.uc_hook_del(uch, ctypes.c_size_t(handle))
    lib.pil_free(pointer)


class NativeHooks:
    """The C block hook and instruction checks of one ``hil.pil.core.Core``."""

    def __init__(self, lib: ctypes.CDLL, core) -> None:
        import weakref

        uclib = _uclib()
        self.lib, self.core = lib, core
        self.error: BaseException | None = None  #: what a call back into Python raised (``raise_error``)
        self._slow_block = _SLOW_BLOCK(lambda address, size: self._guard(core._native_block, address, size))
        self._slow_check = _SLOW_CHECK(lambda address, size, k: self._guard(core._native_check, address, size, k))
        addr = lambda f: ctypes.cast(f, ctypes.c_void_p).value  # noqa: E731
        pointer = lib.pil_new(addr(uclib.uc_emu_stop), addr(uclib.uc_reg_read), addr(self._slow_block),
                              addr(self._slow_check), core.table.lazy_fp_stacking)
        if not pointer:
            raise MemoryError("hil.pil: the native block hook's state")
        self._hooks: list[int] = []
        self._finalizer = weakref.finalize(self, _release, lib, uclib, pointer, weakref.ref(core.uc), core.uc._uch,
                                           self._hooks)
        self.pointer = pointer
        self.state = s = _State.from_address(pointer)
        self._shared = (ctypes.c_int64 * len(_SHARED)).from_address(pointer)
        self._counts = s.softfloat_counts
        self._names: list[str] = []  #: soft-float routine by index
        self._index: dict[str, int] = {}
        uch = core.uc._uch
        self._add(uclib, uch, unicorn.UC_HOOK_BLOCK, lib.pil_block_hook, pointer, 1, 0)
        self.checks = list(core._checks.items())
        self._check_records = (_Check * max(len(self.checks), 1))()
        for k, (address, (kind, reg, offset, _, index_reg, mask)) in enumerate(self.checks):
            rec = self._check_records[k]
            rec.state, rec.kind, rec.reg, rec.offset, rec.index = pointer, 0 if kind == "div" else 1, reg, \
                offset & 0xFFFFFFFF, k
            rec.index_reg, rec.mask = index_reg, mask
            self._add(uclib, uch, unicorn.UC_HOOK_CODE, lib.pil_check_hook, ctypes.addressof(rec), address, address)

    def _add(self, uclib, uch, kind: int, function, user: int, begin: int, end: int) -> None:
        handle = ctypes.c_size_t()
        status = uclib.uc_hook_add(uch, ctypes.byref(handle), kind, ctypes.cast(function, ctypes.c_void_p),
                                   ctypes.c_void_p(user), ctypes.c_uint64(begin), ctypes.c_uint64(end))
        if status != unicorn.UC_ERR_OK:
            raise unicorn.UcError(status)
        self._hooks.append(handle.value)

    def _guard(self, method, *args) -> None:
        """A call back from C: an exception is kept for ``raise_error`` and stops the emulation (a
        ctypes callback cannot raise through C)."""
        try:
            method(*args)
        except BaseException as exc:  # noqa: BLE001  (re-raised after uc_emu_start returns)
            if self.error is None:
                self.error = exc
            self.core.uc.emu_stop()

    # --- the table ------------------------------------------------------------------------------------
    def insert(self, b) -> None:
        """``b`` (a hil.pil.cycles.Block just decoded) into the C table."""
        softfloat = -1
        if b.softfloat is not None:
            softfloat = self._index.get(b.softfloat, -1)
            if softfloat < 0:
                softfloat = self._index[b.softfloat] = len(self._names)
                self._names.append(b.softfloat)
        flags = (FP if b.fp else 0) | (PYTHON if b.fault is not None else 0)
        self.lib.pil_insert(self.pointer, b.address, b.size, b.cycles, b.count, b.taken_extra, b.entry_extra,
                            softfloat, flags)

    # --- the shared state -----------------------------------------------------------------------------
    def push(self, frame) -> None:
        """The core's counters and the running call, into C (before uc_emu_start, after Python's hook)."""
        core = self.core
        stop, prev = core._stop_at, core._prev
        if stop.__class__ is not int:  # a float (inf, or a fraction of a cycle): the next whole cycle
            stop = _INF if stop >= _INF else math.ceil(stop)
        self._shared[0:9] = (core.cycles, core.instructions, min(max(stop, 0), _INF),
                             prev.fallthrough, prev.taken_extra, frame.charge and core._tail is None, frame.uses_fp,
                             frame.fp_frame, frame.lazy_stacked)
        tail = core._tail
        hang = frame.hang_at
        self._shared[11:16] = (*core._framework, *(tail if tail is not None else (-1, 0)),
                               _INF if hang >= _INF else math.ceil(hang))

    def pull(self, frame) -> None:
        """C's counters back into the core and the running call (after uc_emu_start, before Python's
        hook): cycles, instructions, the block before the next, the call's FP state, soft-float calls."""
        core = self.core
        core.cycles, core.instructions, _, fallthrough, taken_extra, _, uses_fp, _, lazy_stacked, dirty = \
            self._shared[0:10]
        tail_cycles, tail_instructions = self._shared[13:15]
        core._tail = (tail_cycles, tail_instructions) if tail_cycles >= 0 else None
        prev = core._prev
        if prev.fallthrough != fallthrough or prev.taken_extra != taken_extra:
            core._prev = Block(0, 0, 0, 0, fallthrough, taken_extra, 0, False)
        frame.uses_fp, frame.lazy_stacked = bool(uses_fp), bool(lazy_stacked)
        if dirty:
            counts, tally = self._counts, core.stats[frame.label].soft_float
            for k, name in enumerate(self._names):
                if counts[k]:
                    tally[name] += counts[k]
                    counts[k] = 0
            self.state.softfloat_dirty = 0

    def raise_error(self) -> None:
        if self.error is not None:
            error, self.error = self.error, None
            raise error


class Registers:
    """The core registers a call sets and reads, through libunicorn's C API with ctypes buffers made
    once (the binding builds them per call: about 5 us a read and 15 us a batched write, against
    about 1 us here); the binding's own methods where libunicorn is not reachable."""

    def __init__(self, uc: unicorn.Uc) -> None:
        self.uc = uc
        try:
            self._lib = _uclib()
        except ImportError:
            self._lib = None
        self._uch = uc._uch
        self._batches: dict[tuple[int, ...], tuple] = {}

    def read(self, regs: tuple[int, ...]) -> list[int]:
        """32-bit core registers (R0-R12, SP, LR, PC, xPSR) in one call."""
        if self._lib is None:
            return self.uc.reg_read_batch(list(regs))
        ids, words, pointers = self._batch(regs)
        status = self._lib.uc_reg_read_batch(self._uch, ids, pointers, len(regs))
        if status != unicorn.UC_ERR_OK:
            raise unicorn.UcError(status)
        return words[:]

    def _batch(self, regs: tuple[int, ...]) -> tuple:
        batch = self._batches.get(regs)
        if batch is None:
            words = (ctypes.c_uint32 * len(regs))()
            pointers = (ctypes.c_void_p * len(regs))(*(ctypes.addressof(words) + 4 * k for k in range(len(regs))))
            batch = self._batches[regs] = ((ctypes.c_int32 * len(regs))(*regs), words, pointers)
        return batch

    def write(self, regs: tuple[int, ...], values) -> None:
        """32-bit core registers ``regs`` set to ``values`` in one call."""
        if self._lib is None:
            self.uc.reg_write_batch(list(zip(regs, values)))
            return
        ids, words, pointers = self._batch(regs)
        words[:] = values
        status = self._lib.uc_reg_write_batch(self._uch, ids, pointers, len(regs))
        if status != unicorn.UC_ERR_OK:
            raise unicorn.UcError(status)
