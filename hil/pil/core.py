"""One emulated Cortex-M core running an ELF: calls by the procedure call standard, cycles from the
core's Technical Reference Manual, nested interrupts, and faults as findings.

**Why Unicorn.** Unicorn (QEMU's CPU emulation as a library, on pip with wheels for every host)
has Cortex-M0/M3/M4/M7 models with the Thumb-2 and FPU decoders QEMU maintains, runs translated
blocks natively, and lets Python hook block starts, single addresses and invalid memory
accesses. The peers do not fit: QEMU's own system emulation (``qemu-system-arm``) is not on pip
and is driven through a gdb stub, far slower per call; pure-Python Thumb emulators decode every
instruction in Python (orders of magnitude slower) and have no FPU; Renode is a .NET application.
Unicorn does not model the M-profile system: no NVIC, no SCB (so no CCR traps), no exception
entry, no alignment checks of LDRD/STRD/LDM; this module adds what the findings need.

**Calls.** ``begin(symbol, args, interrupt=...)`` puts up to four word arguments in r0-r3 (AAPCS),
SP in RAM and LR at a magic return address (``MAGIC_RETURN``: emulation stops when the call
returns there); ``run(until_cycle)`` runs the innermost call until it returns (True) or the
cycle counter reaches ``until_cycle`` (False: paused at a basic-block boundary, the first one at
or after ``until_cycle``). A ``begin`` while a call is paused nests: the paused call's registers
are saved, an exception frame (8 words, 26 with the FP context) is written below its SP, and the
new call runs below that; when it returns, the paused call's registers come back and the next
``run`` resumes it. An interrupt call costs the core's exception entry and return cycles, and
the lazy FP stacking when it preempts a context that used the FPU and uses the FPU itself.
``call(symbol, *args)`` is ``begin`` then ``run`` to the end.

**Cycles.** Each translated block is decoded once with Capstone into its cycle cost
(hil.pil.cycles), cached by address, and charged by a block hook; ``cycles`` is a global
monotonic counter, ``instructions`` beside it. Nothing depends on the host's speed: the same
calls give the same cycles everywhere. The hook and the instruction checks run in C
(hil.pil.native, ``hooks="native"``, the default) with Python's own (``_on_block``, ``_on_check``:
``hooks="python"``) as the reference they equal, and the fallback where the C build fails.

**Memory.** Flash at 0x08000000 (read, execute), RAM at 0x20000000 (read, write; execute only
where the ELF places code in RAM), the stack at the top of RAM; a 1 KiB guard below the stack
(unmapped when the RAM between ``.bss`` and the stack leaves room), and the rest of the stack
region painted, so that the deepest stack write of every call gives the high-water mark. The
ADC's result registers (int16[3]) sit in a peripheral region (``ADC_BASE``); pointer arguments the
framework passes (the describe struct, object-dictionary buffers) in a scratch region
(``SCRATCH_BASE``), outside the firmware's RAM. Everything else is unmapped: an access there is a
bus fault.

**Faults** (``ProcessorFault``, a one-line finding with the function, the source line from the
ELF's DWARF line table, the pc and the cycle counter): an access outside the memory map
(BusFault), a write to flash (BusFault), an instruction fetch from a non-executable region
(MemManage, XN), an undefined instruction (UsageFault UNDEFINSTR) or an FP instruction on a core
without an FPU (UsageFault NOCP), an unaligned LDRD/STRD/LDM/STM (UsageFault UNALIGNED, always on
ARMv7-M; checked by per-address hooks on those instructions), an integer division by zero
(UsageFault DIVBYZERO: CCR.DIV_0_TRP is taken as set, as a start-up routine sets it), BKPT/SVC
without a handler (HardFault). On ARMv6-M every fault is a HardFault (its cause named). A stack
write into the guard is a ``StackOverflow`` at that instruction; a painted word below the
stack's bottom found after a call is one too (then the call, not the instruction, is named). A
call that runs past ``budget_cycles`` is a ``ProcessorHang``. After a finding the core is not
reused: the caller makes a new one.
"""

from __future__ import annotations

import bisect
import ctypes
import math
import mmap
import re
import struct
import weakref
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import unicorn
from capstone.arm_const import ARM_OP_IMM as CS_OP_IMM
from capstone.arm_const import ARM_OP_MEM as CS_OP_MEM
from capstone.arm_const import ARM_OP_REG as CS_OP_REG
from unicorn import arm_const as U

from hil.sil.firmware import SilInterfaceError

from . import native
from .build import FLASH_BASE, RAM_BASE
from .cycles import DIVIDES, DUALS, MULTIPLES_CHECKED, SINGLES_V6M, START, Block, decode_block, disassembler, row
from .target import Target

PAGE = 0x400  #: Unicorn's page on ARM (mappings are multiples of it)
MAGIC_RETURN = 0x1FFF_0000  #: LR of every call: emulation stops when a call returns here
ADC_BASE = 0x4001_2000  #: the ADC's result registers (int16[3]), a peripheral region
SCRATCH_BASE = 0x3000_0000  #: the framework's buffers for pointer arguments (not the firmware's RAM)
SCRATCH_BYTES = 0x1_0000
#: the framework's own code (``Core.load_framework_code``): a page beside MAGIC_RETURN, outside the firmware's map
FRAMEWORK_CODE = MAGIC_RETURN + PAGE
PAINT = 0xA5A5A5A5  #: the stack paint
#: default budget of one call: 2e6 cycles, 12 ms at 168 MHz, 240 periods of a 20 kHz control interrupt
BUDGET_CYCLES = 2_000_000
#: the soft floating-point routines of the ARM run-time ABI (AEABI) and of compiler-rt/libgcc
SOFT_FLOAT = re.compile(
    r"^__(aeabi_([fd](add|sub|rsub|mul|div|neg|cmp\w*|2\w+)|c[fd]\w*|u?[il]2[fd]|ul2[fd]|[fd]2u?[il]z?)"
    r"|(add|sub|mul|div|neg)[sd]f3|extendsfdf2|truncdfsf2|fix(uns)?[sd]f[sd]i|float(un)?[sd]i[sd]f"
    r"|(eq|ne|lt|le|gt|ge|unord|cmp)[sd]f2)$")
_FAULT_KINDS = ("HardFault", "UsageFault", "BusFault", "MemManage")
#: who charges the blocks and checks the instructions: C (hil.pil.native; Python where its host build
#: fails) or Python (the reference implementation)
HOOKS = ("native", "python")


#: per ELF (path, size, mtime): its DWARF line table, and the instructions checked at run time
_LINES: dict = {}
_CHECKS: dict = {}
#: per ELF, core and hook path: the blocks in flash decoded so far, by (address, size), for the next core of
#: the same ELF (a fresh core after every finding, one per test); the last few are kept
_DECODED: dict = {}
_DECODED_ELVES = 4
#: the registers ``begin`` sets, by the number of word arguments: r0.. (AAPCS), SP, LR
_CALL_REGISTERS = tuple((*(U.UC_ARM_REG_R0 + k for k in range(n)), U.UC_ARM_REG_SP, U.UC_ARM_REG_LR) for n in range(5))
#: the exception frame's registers (and SP, below which it goes) of a call an interrupt preempts
_STACKED_REGISTERS = (U.UC_ARM_REG_R0, U.UC_ARM_REG_R1, U.UC_ARM_REG_R2, U.UC_ARM_REG_R3, U.UC_ARM_REG_R12,
                      U.UC_ARM_REG_LR, U.UC_ARM_REG_PC, U.UC_ARM_REG_XPSR, U.UC_ARM_REG_SP)
#: the registers ``run`` reads when the emulation stops: where (a return, or a pause), and the result
_AFTER_REGISTERS = (U.UC_ARM_REG_PC, U.UC_ARM_REG_R0)
#: the exception mask registers (ARMv6-M has PRIMASK alone; Unicorn reads the others as 0 there)
_MASK_REGISTERS = (U.UC_ARM_REG_PRIMASK, U.UC_ARM_REG_FAULTMASK, U.UC_ARM_REG_BASEPRI)
#: xPSR's IT bits (EPSR.IT[1:0] at 26:25, IT[7:2] at 15:10): the state of an IT block part-way done.
#: Exception entry stacks them with xPSR and clears them, the handler starting outside any IT block
#: (ARMv7-M Architecture Reference Manual, ARM DDI 0403, B1.5.6 "Exception entry behavior"); a call
#: begun on a core paused just after an IT instruction would otherwise run its first instructions as
#: that block's conditional ones (a PUSH skipped, its POP then loading a stacked word into LR)
_XPSR_IT_BITS = 0x0600FC00


def _keep(*_) -> None:
    """A finalizer that only holds its arguments until its object goes."""


def _elf_key(path: str) -> tuple:
    st = Path(path).stat()
    return (str(Path(path).resolve()), st.st_size, st.st_mtime_ns)


class ProcessorFinding(RuntimeError):
    """What the core met while running firmware: the kind, the cause, where (function, source
    line, pc), when (the cycle counter) and in which call. One line as text."""

    def __init__(self, kind: str, cause: str, *, function: str | None, source_line: str | None, pc: int | None,
                 cycles: int, call: str | None, elf: str):
        self.kind, self.cause, self.function, self.source_line = kind, cause, function, source_line
        self.pc, self.cycles, self.call, self.elf = pc, cycles, call, elf
        where = function or "?"
        if source_line:
            where += f" ({source_line})"
        at = f" at pc 0x{pc:08X}" if pc is not None else ""
        super().__init__(f"{kind} in {where}{at}: {cause} [during {call}, cycle {cycles}]")


class ProcessorFault(ProcessorFinding):
    """A HardFault, UsageFault, BusFault or MemManage fault the silicon would take."""


class StackOverflow(ProcessorFinding):
    """The stack went below its bottom (``stack_bytes`` under the top of RAM)."""


class ProcessorHang(ProcessorFinding):
    """A call that ran past its cycle budget."""


@dataclass(slots=True)
class _Frame:
    symbol: str
    address: int
    interrupt: bool
    label: str
    start_cycle: int
    hang_at: float
    charge: bool                 #: False: a framework read, its cycles are given back
    start_instructions: int = 0
    pc: int = 0                  #: where run() starts or resumes it
    prev: Block = START          #: the block before the next one (taken-branch accounting)
    saved: object = None         #: the registers of the call it preempted
    fp_frame: bool = False       #: it preempted a context with live FP state (26-word frame)
    uses_fp: bool = False
    lazy_stacked: bool = False


@dataclass
class CallStats:
    calls: int = 0
    cycles: list[int] = field(default_factory=list)  #: per call, exception entry and return included
    instructions: list[int] = field(default_factory=list)  #: per call, preempting interrupts' included
    soft_float: Counter = field(default_factory=Counter)
    stack_bytes: int = 0  #: the deepest stack of any call of this kind (bytes below the top)


class Core:
    """One emulated core of ``target`` with ``elf`` loaded (module docstring)."""

    def __init__(self, elf: str | Path, target: Target, *, budget_cycles: int = BUDGET_CYCLES,
                 hooks: str = "native"):
        from elftools.elf.elffile import ELFFile

        from .build import check_elf

        self.elf = str(elf)
        self.target = target
        self.spec = spec = target.core
        self.table = spec.cycles
        self.budget_cycles = budget_cycles
        check_elf(self.elf, spec)
        self._file = open(self.elf, "rb")
        self._elffile = ELFFile(self._file)
        self.uc = uc = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(spec.uc_model)
        self.ram_top = RAM_BASE + target.ram_bytes
        self.stack_bottom = self.ram_top - target.stack_bytes
        self._symbols: dict[str, int] = {}
        self._functions: list[tuple[int, int, str]] = []
        self._read_symbols()
        self.flash_used, self.ram_used, ram_exec, data_end = self._layout()
        self._map(ram_exec, data_end)
        self._load()
        self.md = disassembler()
        self._regs = native.Registers(uc)
        self._blocks: dict[int, Block] = {}
        self._softfloat_entries = self._soft_float_entries()
        self._lines: tuple[list[int], list[str]] | None = None
        self.cycles = 0
        self.instructions = 0
        self._frames: list[_Frame] = []
        self._stop_at = math.inf
        self._prev = START
        self._fault: ProcessorFinding | None = None
        #: the framework's code (``load_framework_code``): [lo, hi), or (-1, -1) before any is loaded
        self._framework = (-1, -1)
        #: (cycles, instructions) where the running call reached the framework's code (its tail: the
        #: output read an interrupt returns into, ``begin(then=...)``), else None; given back at its return
        self._tail: tuple[int, int] | None = None
        #: ``firmware_runs`` when a call last ran the framework's output read at its end (``then``)
        self.outputs_ran_at = -1
        self._bad_access: tuple[int, int] | None = None
        self._result = 0
        self.last_cycles = 0  #: cycles of the last call that returned, with exception entry and return
        #: how many times firmware code ran as the firmware's own (a charged call started or resumed): what
        #: it last left in memory is current while this stands still (``hil.pil.firmware``'s output cache)
        self.firmware_runs = 0
        self.stats: dict[str, CallStats] = defaultdict(CallStats)
        self.stack_high_water = 0  #: the deepest stack of any call (bytes below the top of RAM)
        key = (*_elf_key(self.elf), target.flash_bytes, spec.name)
        if key not in _CHECKS:  # one disassembly per ELF, not per core
            _CHECKS.clear()
            _CHECKS[key] = self._sweep()
        self._checks, self._rows = _CHECKS[key]
        if hooks not in HOOKS:
            raise ValueError(f"hooks must be one of {', '.join(HOOKS)}, got {hooks!r}")
        lib = native.library() if hooks == "native" else None
        #: the block hook and instruction checks in C (hil.pil.native), or None: Python's (the reference)
        self._native = native.NativeHooks(lib, self) if lib is not None else None
        self.hooks = "native" if self._native is not None else "python"
        key = (*_elf_key(self.elf), spec.name, self.hooks)  # each path decodes for itself
        if key not in _DECODED and len(_DECODED) >= _DECODED_ELVES:
            del _DECODED[next(iter(_DECODED))]
        self._decoded = _DECODED.setdefault(key, {})
        self._flash = (FLASH_BASE, FLASH_BASE + target.flash_bytes)  # code there never changes: decoded once
        if self._native is None:
            uc.hook_add(unicorn.UC_HOOK_BLOCK, self._on_block)
            for address, check in self._checks.items():
                uc.hook_add(unicorn.UC_HOOK_CODE, self._on_check, check, address, address)
        uc.hook_add(unicorn.UC_HOOK_MEM_INVALID, self._on_invalid)
        uc.hook_add(unicorn.UC_HOOK_INTR, self._on_interrupt)

    # --- the ELF ----------------------------------------------------------------------------------
    def _read_symbols(self) -> None:
        symtab = self._elffile.get_section_by_name(".symtab")
        if symtab is None:
            raise SilInterfaceError(f"{self.elf}: no symbol table (pil: finds the hil-sil/1 exports by symbol; "
                                    "do not strip the ELF)")
        for s in symtab.iter_symbols():
            kind = s["st_info"]["type"]
            if kind == "STT_FUNC" and s["st_shndx"] != "SHN_UNDEF":
                address = s["st_value"] & ~1
                if s["st_info"]["bind"] in ("STB_GLOBAL", "STB_WEAK") or s.name not in self._symbols:
                    self._symbols[s.name] = address
                self._functions.append((address, address + max(s["st_size"], 2), s.name))
            elif kind == "STT_OBJECT" and s["st_shndx"] != "SHN_UNDEF":
                self._symbols.setdefault(s.name, s["st_value"])
        self._functions.sort()
        self._function_starts = [f[0] for f in self._functions]

    def _layout(self) -> tuple[int, int, bool, int]:
        """Flash used (the load image), RAM used (.data + .bss), whether code runs from RAM, the
        end of the RAM the ELF uses."""
        flash_end = FLASH_BASE + self.target.flash_bytes
        flash = ram = 0
        ram_exec = False
        data_end = RAM_BASE
        for seg in self._elffile.iter_segments():
            if seg["p_type"] != "PT_LOAD" or seg["p_memsz"] == 0:
                continue
            vaddr, paddr, filesz, memsz = seg["p_vaddr"], seg["p_paddr"], seg["p_filesz"], seg["p_memsz"]
            if FLASH_BASE <= paddr < flash_end:
                flash += filesz
            if RAM_BASE <= vaddr < self.ram_top:
                ram += memsz
                data_end = max(data_end, vaddr + memsz)
                ram_exec |= bool(seg["p_flags"] & 1)
            elif not FLASH_BASE <= vaddr < flash_end:
                raise SilInterfaceError(f"{self.elf}: a segment at 0x{vaddr:08X} is outside the target's flash "
                                        f"(0x{FLASH_BASE:08X}, {self.target.flash_bytes} bytes) and RAM "
                                        f"(0x{RAM_BASE:08X}, {self.target.ram_bytes} bytes)")
            if vaddr + memsz > (self.ram_top if vaddr >= RAM_BASE else flash_end):
                raise SilInterfaceError(f"{self.elf}: a segment at 0x{vaddr:08X} of {memsz} bytes does not fit the "
                                        f"target's {'RAM' if vaddr >= RAM_BASE else 'flash'}")
        return flash, ram, ram_exec, data_end

    def _map(self, ram_exec: bool, data_end: int) -> None:
        uc, R, W, X = self.uc, unicorn.UC_PROT_READ, unicorn.UC_PROT_WRITE, unicorn.UC_PROT_EXEC
        up = lambda n: -(-n // PAGE) * PAGE  # noqa: E731
        uc.mem_map(FLASH_BASE, up(self.target.flash_bytes), R | X)
        ram_prot = R | W | (X if ram_exec else 0)
        # RAM, the ADC's registers and the scratch buffers are host memory of ours (uc_mem_map_ptr): the
        # stack's paint is read and renewed in place after every call, the ADC written before every
        # interrupt without a copy through uc_mem_read / uc_mem_write
        self._host: list[tuple[int, int, mmap.mmap, int]] = []  #: (low, high, buffer, offset in it)
        weakref.finalize(uc, _keep, self._host)  # the memory outlives the engine that maps it
        self._ram_buffer = mmap.mmap(-1, up(self.ram_top) - RAM_BASE)
        self._ram = np.frombuffer(self._ram_buffer, dtype=np.uint8)

        def ram(lo: int, hi: int) -> None:
            self._map_host(lo, hi, ram_prot, self._ram_buffer, lo - RAM_BASE)

        guard_hi = self.stack_bottom // PAGE * PAGE
        guard_lo = guard_hi - PAGE
        if guard_lo >= up(data_end):
            ram(RAM_BASE, guard_lo) if guard_lo > RAM_BASE else None
            ram(guard_hi, up(self.ram_top))
            self.guard = (guard_lo, guard_hi)
            self._paint_lo = guard_hi
        else:  # no room for a guard: painting alone finds an overflow, after the call
            ram(RAM_BASE, up(self.ram_top))
            self.guard = None
            self._paint_lo = max(-(-data_end // 8) * 8, RAM_BASE)
        lo = self._paint_lo - RAM_BASE
        self._paint = self._ram[lo:lo + 4 * ((self.ram_top - self._paint_lo) // 4)].view("<u4")
        uc.mem_map(MAGIC_RETURN, PAGE, R | X)
        uc.mem_write(MAGIC_RETURN, b"\xfe\xe7" * (PAGE // 2))  # b . (never executed: emulation stops first)
        self._map_host(ADC_BASE, ADC_BASE + PAGE, R | W, mmap.mmap(-1, PAGE), 0)
        self._map_host(SCRATCH_BASE, SCRATCH_BASE + SCRATCH_BYTES, R | W, mmap.mmap(-1, SCRATCH_BYTES), 0)

    def _map_host(self, lo: int, hi: int, prot: int, buffer: mmap.mmap, offset: int) -> None:
        host = ctypes.addressof(ctypes.c_char.from_buffer(buffer, offset))
        self.uc.mem_map_ptr(lo, hi - lo, prot, host)
        self._host.append((lo, hi, buffer, offset))

    def _host_span(self, address: int, size: int) -> tuple[mmap.mmap, int] | None:
        """The host buffer and offset of ``size`` bytes at ``address``, when one host mapping holds them."""
        for lo, hi, buffer, offset in self._host:
            if lo <= address and address + size <= hi:
                return buffer, offset + address - lo
        return None

    def _load(self) -> None:
        """The PT_LOAD segments: code and .data's image into flash, .data into RAM (the copy a
        start-up routine makes), .bss zero; the stack painted."""
        for seg in self._elffile.iter_segments():
            if seg["p_type"] != "PT_LOAD" or seg["p_memsz"] == 0:
                continue
            data = seg.data()
            if seg["p_paddr"] != seg["p_vaddr"] and seg["p_filesz"]:
                self.uc.mem_write(seg["p_paddr"], data)
            self.uc.mem_write(seg["p_vaddr"], data + bytes(seg["p_memsz"] - seg["p_filesz"]))
        self._paint[:] = PAINT

    def _soft_float_entries(self) -> dict[int, str]:
        entries: dict[int, str] = {}
        for start, _, name in self._functions:
            if SOFT_FLOAT.match(name):
                entries.setdefault(start, name)
        return entries

    def _sweep(self) -> tuple[dict[int, tuple], dict[int, tuple]]:
        """Every function in flash disassembled once: the instructions whose faults Unicorn does not
        raise, (kind, base register, offset, mnemonic, index register or 0, alignment mask) by address;
        and every instruction's cost row (hil.pil.cycles.row), from which the native path sums a block it
        first meets (``decode_block``'s ``known``)."""
        checks: dict[int, tuple] = {}
        rows: dict[int, tuple] = {}
        flash_end = FLASH_BASE + self.target.flash_bytes
        for start, end, _ in self._functions:
            if not FLASH_BASE <= start < flash_end:
                continue
            code = bytes(self.uc.mem_read(start, min(end, flash_end) - start))
            for insn in self.md.disasm(code, start):
                rows[insn.address] = row(insn, self.table)
                name = insn.insn_name()
                # Capstone's register numbers are not Unicorn's: by name (r0..r12, sb, sl, fp, ip, sp, lr)
                uc_reg = lambda r: getattr(U, f"UC_ARM_REG_{insn.reg_name(r).upper()}")  # noqa: E731
                if name in DIVIDES:
                    regs = [op.reg for op in insn.operands if op.type == CS_OP_REG]
                    checks[insn.address] = ("div", uc_reg(regs[-1]), 0, insn.mnemonic, 0, 0)
                elif name in DUALS:
                    mem = next(op for op in insn.operands if op.type == CS_OP_MEM)
                    post = insn.operands[-1].type == CS_OP_IMM
                    checks[insn.address] = ("dual", uc_reg(mem.mem.base), 0 if post else mem.mem.disp, insn.mnemonic,
                                            0, 3)
                elif name in MULTIPLES_CHECKED:
                    if insn.reg_name(insn.operands[0].reg) != "sp":
                        checks[insn.address] = ("multiple", uc_reg(insn.operands[0].reg), 0, insn.mnemonic, 0, 3)
                elif self.spec.v6m and name in SINGLES_V6M:
                    mem = next((op for op in insn.operands if op.type == CS_OP_MEM), None)
                    # SP is word aligned by the procedure call standard; a literal's address by the encoding
                    if mem is not None and insn.reg_name(mem.mem.base) not in ("sp", "pc"):
                        index = uc_reg(mem.mem.index) if mem.mem.index else 0
                        checks[insn.address] = ("single", uc_reg(mem.mem.base), mem.mem.disp, insn.mnemonic, index,
                                                SINGLES_V6M[name])
        return checks, rows

    # --- symbols and source lines -----------------------------------------------------------------------
    def symbol(self, name: str) -> int:
        try:
            return self._symbols[name]
        except KeyError:
            raise SilInterfaceError(f"{self.elf}: missing export {name}") from None

    def has(self, name: str) -> bool:
        return name in self._symbols

    def function_at(self, pc: int) -> str | None:
        k = bisect.bisect_right(self._function_starts, pc) - 1
        if k >= 0 and self._functions[k][0] <= pc < self._functions[k][1]:
            return self._functions[k][2]
        return None

    def source_line(self, pc: int) -> str | None:
        """file:line of ``pc`` from the DWARF line table (None without one)."""
        if self._lines is None:
            key = _elf_key(self.elf)
            if key not in _LINES:  # parsed once per ELF (a fresh core after every fault reads the same)
                _LINES.clear()
                _LINES[key] = self._read_lines()
            self._lines = _LINES[key]
        addresses, places = self._lines
        k = bisect.bisect_right(addresses, pc) - 1
        return places[k] if k >= 0 and places[k] else None

    def _read_lines(self) -> tuple[list[int], list[str]]:
        rows: list[tuple[int, str]] = []
        if not self._elffile.has_dwarf_info():
            return [], []
        dwarf = self._elffile.get_dwarf_info()
        for cu in dwarf.iter_CUs():
            lp = dwarf.line_program_for_CU(cu)
            if lp is None:
                continue
            names = lp["file_entry"]
            base = 1 if lp.header["version"] < 5 else 0
            for entry in lp.get_entries():
                st = entry.state
                if st is None:
                    continue
                if st.end_sequence:
                    rows.append((st.address, ""))
                    continue
                k = st.file - base
                name = names[k].name.decode(errors="replace") if 0 <= k < len(names) else "?"
                rows.append((st.address, f"{name}:{st.line}"))
        rows.sort(key=lambda r: r[0])
        return [r[0] for r in rows], [r[1] for r in rows]

    # --- memory helpers ---------------------------------------------------------------------------------
    def read(self, address: int, size: int) -> bytes:
        span = self._host_span(address, size)
        if span is None:  # flash, or across mappings, or unmapped (Unicorn's error)
            return bytes(self.uc.mem_read(address, size))
        buffer, k = span
        return buffer[k:k + size]

    def write(self, address: int, data: bytes) -> None:
        data = bytes(data)
        span = self._host_span(address, len(data))
        if span is None:
            self.uc.mem_write(address, data)
            return
        buffer, k = span
        buffer[k:k + len(data)] = data

    def read_cstring(self, address: int, limit: int = 256) -> str:
        """A NUL-terminated string in emulated memory (flash or RAM)."""
        out = bytearray()
        while len(out) < limit:
            try:
                chunk = bytes(self.uc.mem_read(address + len(out), 16))
            except unicorn.UcError:
                break
            end = chunk.find(b"\0")
            if end >= 0:
                out += chunk[:end]
                break
            out += chunk
        return out.decode("utf-8", "replace")

    def load_framework_code(self, name: str, code: bytes) -> int:
        """Thumb code of the framework's own (``hil.pil.firmware``: the output registers read in one
        call), mapped read-only and executable at FRAMEWORK_CODE and callable as ``name``; its address."""
        if len(code) > PAGE:
            raise ValueError(f"framework code {name} of {len(code)} bytes (at most {PAGE})")
        self.uc.mem_map(FRAMEWORK_CODE, PAGE, unicorn.UC_PROT_READ | unicorn.UC_PROT_EXEC)
        self.uc.mem_write(FRAMEWORK_CODE, bytes(code))
        self._framework = (FRAMEWORK_CODE, FRAMEWORK_CODE + PAGE)
        self._symbols[name] = FRAMEWORK_CODE
        k = bisect.bisect_right(self._function_starts, FRAMEWORK_CODE)
        self._functions.insert(k, (FRAMEWORK_CODE, FRAMEWORK_CODE + len(code), name))
        self._function_starts.insert(k, FRAMEWORK_CODE)
        return FRAMEWORK_CODE

    # --- calls ------------------------------------------------------------------------------------------
    @property
    def active(self) -> int:
        """How many calls are in progress (paused or preempted)."""
        return len(self._frames)

    def result(self) -> int:
        """r0 of the last call that returned (unsigned 32 bits)."""
        return self._result

    def masked(self, priority: int) -> bool:
        """Whether the code running now keeps an interrupt of NVIC ``priority`` pending: PRIMASK or
        FAULTMASK set (``CPSID i``, ``CPSID f``), or BASEPRI non-zero and not above ``priority`` (the
        architecture's rule: BASEPRI masks every exception whose priority value is at least it).
        Unicorn executes CPSID, CPSIE, MRS and MSR of these registers; the scheduler asks here."""
        primask, faultmask, basepri = self._regs.read(_MASK_REGISTERS)
        return bool(primask & 1 or faultmask & 1 or (basepri & 0xFF and priority >= basepri & 0xFF))

    def begin(self, symbol: str, args=(), *, interrupt: bool = False, label: str | None = None,
              charge: bool = True, then: int | None = None) -> None:
        """Start a call of ``symbol`` (module docstring); ``charge=False``: a framework read whose
        cycles are given back when it returns. ``then``: an address in the framework's code the call
        returns into (its LR) instead of returning at once: code of the framework's own that runs
        within the same emulated call (the output read after an interrupt), its cycles and
        instructions given back, never paused (only stopped at the call's budget)."""
        if self._fault is not None:
            raise RuntimeError(f"{self.elf}: this core met {type(self._fault).__name__}; make a new Core")
        if len(args) > 4:
            raise ValueError("at most four word arguments (r0-r3)")
        address = self._symbols.get(symbol)
        if address is None:
            address = self.symbol(symbol)  # the error naming it
        uc = self.uc
        frame = _Frame(symbol, address, interrupt, label or symbol, self.cycles, self.cycles + self.budget_cycles,
                       charge, self.instructions, pc=address)
        if self._frames:
            outer = self._frames[-1]
            outer.prev = self._prev
            outer.saved = uc.context_save()
            r0, r1, r2, r3, r12, lr, pc, xpsr, sp = self._regs.read(_STACKED_REGISTERS)
            frame.fp_frame = self.spec.hard_float and outer.uses_fp
            words = 26 if frame.fp_frame else 8
            sp = (sp - 4 * words) & ~7  # STKALIGN: the frame is 8-byte aligned
            self._write_frame(sp, (r0, r1, r2, r3, r12, lr, pc, xpsr))
        elif interrupt:  # taken from the idle thread at the top of the stack
            sp = self.ram_top - 32
            self._write_frame(sp, (0, 0, 0, 0, 0, 0xFFFFFFFF, MAGIC_RETURN, 0x01000000))
        else:
            sp = self.ram_top
        self._regs.write(_CALL_REGISTERS[len(args)],
                         (*(int(a) & 0xFFFFFFFF for a in args), sp, (MAGIC_RETURN if then is None else then) | 1))
        xpsr = int(uc.reg_read(U.UC_ARM_REG_XPSR))
        if xpsr & _XPSR_IT_BITS:  # a pause within an IT block (stacked above with xPSR; the return restores it)
            uc.reg_write(U.UC_ARM_REG_XPSR, xpsr & ~_XPSR_IT_BITS)
        self._tail = None
        if interrupt and charge:
            self.cycles += self.table.exception_entry
        self._frames.append(frame)
        self._prev = START

    def _write_frame(self, sp: int, words) -> None:
        self.write(sp, struct.pack("<8I", *(int(w) & 0xFFFFFFFF for w in words)))

    def run(self, until_cycle: float = math.inf) -> bool:
        """Run the innermost call until it returns (True) or ``cycles`` reaches ``until_cycle``
        (False, paused). Raises the call's finding (ProcessorFault, StackOverflow, ProcessorHang)."""
        frame = self._frames[-1]
        self._stop_at = min(until_cycle, frame.hang_at)
        self._frame = frame
        self.firmware_runs += frame.charge
        n = self._native
        if n is not None:
            n.push(frame)
        error = None
        try:
            self.uc.emu_start(frame.pc | 1, MAGIC_RETURN)
        except unicorn.UcError as exc:
            error = exc
        if n is not None:
            n.pull(frame)
            n.raise_error()
        if error is not None:
            self._fault = self._fault or self._from_uc_error(error)
        if self._fault is not None:
            raise self._fault
        pc, r0 = self._regs.read(_AFTER_REGISTERS)
        if pc != MAGIC_RETURN:
            frame.pc = pc
            if self.cycles >= frame.hang_at:
                self._fault = self._finding(
                    ProcessorHang, "Hang", f"{frame.symbol} ran past its budget of {self.budget_cycles} cycles "
                    f"({self.instructions} instructions so far)", pc)
                raise self._fault
            return False
        self._returned(frame, r0)
        return True

    def _returned(self, frame: _Frame, r0: int) -> None:
        self._result = r0
        self._frames.pop()
        if self._tail is not None:  # what the framework's code ran is no time of the firmware's
            self.cycles, self.instructions = self._tail
            self._tail = None
            self.outputs_ran_at = self.firmware_runs
        if frame.interrupt and frame.charge:
            self.cycles += self.table.exception_return + (self.table.lazy_fp_return if frame.lazy_stacked else 0)
        spent = self.cycles - frame.start_cycle
        if not frame.charge:
            self.cycles = frame.start_cycle  # a framework read takes no time of the firmware's
        else:
            self.last_cycles = spent
            if frame.interrupt:
                s = self.stats[frame.label]
                s.calls += 1
                s.cycles.append(spent)
                s.instructions.append(self.instructions - frame.start_instructions)
        if self._frames:
            outer = self._frames[-1]
            self.uc.context_restore(outer.saved)
            outer.saved = None
            self._prev = outer.prev
        elif frame.charge:  # a framework read's few words are found by the next charged call's check
            self._stack_check(frame)

    def call(self, symbol: str, *args, interrupt: bool = False, label: str | None = None,
             charge: bool = True) -> int:
        """``begin`` and ``run`` to the end: r0 of the call."""
        self.begin(symbol, args, interrupt=interrupt, label=label, charge=charge)
        self.run()
        return self._result

    # --- the stack ----------------------------------------------------------------------------------------
    def _stack_check(self, frame: _Frame) -> None:
        """The deepest painted word the calls since the last check overwrote: the high-water mark
        (repainted for the next call); below the stack's bottom, a StackOverflow."""
        words = self._paint
        touched = words != PAINT
        k = int(touched.argmax())
        if not touched[k]:
            return
        deepest = self._paint_lo + 4 * k
        depth = self.ram_top - deepest
        self.stack_high_water = max(self.stack_high_water, depth)
        if frame.interrupt or frame.label in self.stats:
            s = self.stats[frame.label]
            s.stack_bytes = max(s.stack_bytes, depth)
        words[k:] = PAINT
        if deepest < self.stack_bottom:
            self._fault = self._finding(
                StackOverflow, "StackOverflow", f"the stack reached {depth} bytes below the top of RAM, "
                f"{self.stack_bottom - deepest} beyond stack_bytes = {self.target.stack_bytes}", None,
                function=frame.symbol)
            raise self._fault

    # --- hooks --------------------------------------------------------------------------------------------
    def _on_block(self, uc, address, size, _):
        if self._tail is None and self._framework[0] <= address < self._framework[1]:
            self._tail = (self.cycles, self.instructions)  # the firmware's part of the call ends here
        b = self._blocks.get(address)
        if b is None or b.size != size:
            b = self._decode(address, size)
        if self.cycles >= (self._stop_at if self._tail is None else self._frame.hang_at):
            uc.emu_stop()  # this block has not run: it is charged when the call resumes
            return
        prev = self._prev
        if address != prev.fallthrough:
            self.cycles += b.cycles + prev.taken_extra + b.entry_extra
        else:
            self.cycles += b.cycles
        self.instructions += b.count
        self._prev = b
        if b.special:
            self._special(b)

    def _decode(self, address: int, size: int) -> Block:
        b = self._decoded.get((address, size))
        if b is None:
            # the native path sums what the sweep decoded in full; Python's (the reference) decodes in full
            b = decode_block(self.md, bytes(self.uc.mem_read(address, size)), address, self.table,
                             self.spec.hard_float, self._rows if self._native is not None else None)
            name = self._softfloat_entries.get(address)
            if name is not None:
                b.softfloat, b.special = name, True
            if self._flash[0] <= address < self._flash[1]:
                self._decoded[(address, size)] = b
        self._blocks[address] = b
        if self._native is not None:
            self._native.insert(b)
        return b

    def _native_block(self, address: int, size: int) -> None:
        """The C block hook met a block it has no entry for (or one with a fault): Python's hook."""
        n, frame = self._native, self._frame
        n.pull(frame)
        self._on_block(self.uc, address, size, None)
        n.push(frame)

    def _native_check(self, address: int, size: int, index: int) -> None:
        """A C check failed: Python's names the fault."""
        n, frame = self._native, self._frame
        n.pull(frame)
        self._on_check(self.uc, address, size, n.checks[index][1])
        n.push(frame)

    def _special(self, b: Block) -> None:
        frame = self._frame
        if b.fault is not None:
            kind, cause, pc = b.fault
            self._stop(self._fault_finding(kind, cause, pc))
            return
        charge = frame.charge and self._tail is None
        if b.fp:
            frame.uses_fp = True
            if frame.fp_frame and not frame.lazy_stacked and charge:
                frame.lazy_stacked = True  # the FP context is pushed at the handler's first FP instruction
                self.cycles += self.table.lazy_fp_stacking
        if b.softfloat is not None and charge:
            self.stats[frame.label].soft_float[b.softfloat] += 1

    def _on_check(self, uc, address, size, check):
        kind, reg, offset, mnemonic, index, mask = check
        value = uc.reg_read(reg)
        if kind == "div":
            if value == 0:
                self._stop(self._fault_finding("UsageFault", f"DIVBYZERO: {mnemonic} by zero (CCR.DIV_0_TRP set)",
                                               address))
            return
        at = (value + offset + (uc.reg_read(index) if index else 0)) & 0xFFFFFFFF
        if at & mask:
            why = ("ARMv6-M has no unaligned access: LDR and STR need word, LDRH, STRH and LDRSH halfword "
                   "alignment" if kind == "single" else "LDRD, STRD, LDM and STM need word alignment")
            self._stop(self._fault_finding("UsageFault", f"UNALIGNED: {mnemonic} at address 0x{at:08X} ({why})",
                                           address))

    def _on_invalid(self, uc, access, address, size, value, _):
        self._bad_access = (access, address)
        return False

    def _on_interrupt(self, uc, intno, _):
        pc = uc.reg_read(U.UC_ARM_REG_PC)
        names = {1: "UNDEFINSTR: undefined instruction", 2: "SVC without an SVCall handler",
                 7: "BKPT without a debugger attached"}
        kind = "UsageFault" if intno == 1 else "HardFault"
        self._stop(self._fault_finding(kind, names.get(intno, f"exception {intno}"), pc))

    def _stop(self, finding: ProcessorFinding) -> None:
        if self._fault is None:
            self._fault = finding
        self.uc.emu_stop()

    # --- findings -------------------------------------------------------------------------------------------
    def _finding(self, cls, kind: str, cause: str, pc: int | None, function: str | None = None) -> ProcessorFinding:
        call = self._frames[-1].symbol if self._frames else None
        return cls(kind, cause, function=function or (self.function_at(pc) if pc is not None else None),
                   source_line=self.source_line(pc) if pc is not None else None, pc=pc, cycles=self.cycles,
                   call=call, elf=self.elf)

    def _fault_finding(self, kind: str, cause: str, pc: int) -> ProcessorFinding:
        if self.spec.v6m:  # ARMv6-M has only the HardFault
            cause, kind = f"{kind} on ARMv7-M; {cause}", "HardFault"
        return self._finding(ProcessorFault, kind, cause, pc)

    def _from_uc_error(self, exc: unicorn.UcError) -> ProcessorFinding:
        pc = self.uc.reg_read(U.UC_ARM_REG_PC)
        errno = exc.errno
        access = self._bad_access
        if access is not None:
            _, address = access
            if self.guard is not None and self.guard[0] <= address < self.guard[1]:
                return self._finding(StackOverflow, "StackOverflow", f"a stack access at 0x{address:08X}, below the "
                                     f"stack's bottom 0x{self.stack_bottom:08X} (stack_bytes = "
                                     f"{self.target.stack_bytes})", pc)
        what = f" 0x{access[1]:08X}" if access is not None else ""
        if errno in (unicorn.UC_ERR_READ_UNMAPPED, unicorn.UC_ERR_WRITE_UNMAPPED):
            verb = "read from" if errno == unicorn.UC_ERR_READ_UNMAPPED else "write to"
            return self._fault_finding("BusFault", f"PRECISERR: {verb}{what}, outside the memory map", pc)
        if errno == unicorn.UC_ERR_WRITE_PROT:
            return self._fault_finding("BusFault", f"PRECISERR: write to{what}, read-only (flash)", pc)
        if errno == unicorn.UC_ERR_FETCH_UNMAPPED:
            return self._fault_finding("BusFault", f"IBUSERR: instruction fetch from{what or f' 0x{pc:08X}'}, "
                                       "outside the memory map", access[1] if access else pc)
        if errno == unicorn.UC_ERR_FETCH_PROT:
            return self._fault_finding("MemManage", f"IACCVIOL: instruction fetch from{what or f' 0x{pc:08X}'}, "
                                       "a non-executable (XN) region", access[1] if access else pc)
        if errno in (unicorn.UC_ERR_INSN_INVALID, unicorn.UC_ERR_EXCEPTION):
            return self._fault_finding("UsageFault", "UNDEFINSTR: undefined instruction (or one this core does not "
                                       "implement)", pc)
        if errno in (unicorn.UC_ERR_READ_UNALIGNED, unicorn.UC_ERR_WRITE_UNALIGNED, unicorn.UC_ERR_FETCH_UNALIGNED):
            return self._fault_finding("UsageFault", "UNALIGNED: unaligned access", pc)
        return self._fault_finding("HardFault", f"emulation stopped: {exc}", pc)

    def close(self) -> None:
        self._file.close()
