"""The part a firmware ships on: a ``[target]`` table, and one declaration per Cortex-M core.

``[target]`` sits in a firmware's ``sil.toml`` (``sil:`` ignores it) or in a TOML file of its own
(``pil:FILE.elf,target=FILE.toml``)::

    [target]
    cpu = "cortex-m4f"          # cortex-m0plus, cortex-m3, cortex-m4, cortex-m4f, cortex-m7f
    clock_hz = 168_000_000
    flash_bytes = 1_048_576
    ram_bytes = 196_608
    stack_bytes = 4096
    priorities = { hall = 0, compare = 0, control = 1 }   # NVIC: a lower number preempts
    flags = ["-O2"]             # optional, after sil.toml's flags, for the target build only

``CORES`` holds, per core, its Thumb ISA, its FPU, the compiler flags that build for it, the
Unicorn CPU model that runs it and its cycle table (docs/processor-in-the-loop.md, "Cycle table",
cites the Technical Reference Manuals each figure comes from).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from unicorn import arm_const

from bldc.tomlfile import TomlError, load_toml

#: what a ``[target]`` table may hold
TARGET_KEYS = ("cpu", "clock_hz", "flash_bytes", "ram_bytes", "stack_bytes", "priorities", "flags")
#: the interrupts whose NVIC priorities a target gives
INTERRUPTS = ("hall", "compare", "control")


@dataclass(frozen=True)
class CycleTable:
    """Cycles per instruction class at zero flash wait states (hil/pil/cycles.py classifies).

    A taken branch costs its class's figure plus ``taken``, and ``wide_target`` more when it lands
    on a 32-bit instruction at a halfword (not word) address (the Cortex-M3/M4 fetch a word at a
    time: P of the TRMs' tables, 1 to 3, is charged 1 or 2; the third cycle of an unspeculated
    branch is not modelled). Load/store multiple cost ``multiple`` plus one per register."""

    alu: int = 1                #: data processing, moves, shifts, compares, extends, bit fields
    mul: int = 1                #: MUL
    mla: int = 2                #: MLA, MLS
    mull: int = 1               #: UMULL, SMULL, UMLAL, SMLAL, UMAAL
    dsp: int = 1                #: SIMD, saturating, halfword multiplies (ARMv7E-M)
    div: int = 12               #: SDIV, UDIV: the TRMs give 2..12 by operand; the upper bound is charged
    load: int = 2               #: LDR, LDRH, LDRB (and their signed forms)
    store: int = 2              #: STR, STRH, STRB
    dual: int = 3               #: LDRD, STRD (1 + N, N = 2)
    multiple: int = 1           #: LDM, STM, PUSH, POP: ``multiple`` + N registers
    branch: int = 1             #: B, BL, BX, BLX, CBZ, CBNZ, not taken (+ ``taken`` when taken)
    taken: int = 1              #: pipeline refill P of a taken branch, a call, a return
    load_pc: int = 0            #: refill after a load into PC (POP {..,PC}, LDR PC) beyond ``taken``
    call: int = 0               #: BL beyond ``branch`` + ``taken``
    wide_target: int = 1        #: extra refill when the target is a 32-bit instruction at addr % 4 == 2
    table_branch: int = 2       #: TBB, TBH (+ ``taken``)
    sysreg: int = 1             #: MRS, MSR
    barrier: int = 1            #: DMB, DSB, ISB (B, the barrier's own wait, taken as 0)
    other: int = 1              #: NOP, IT, CPS, WFI, YIELD, SEV
    fp_alu: int = 1             #: VADD, VSUB, VMUL, VNMUL, VABS, VNEG, VCMP, VCVT, VMOV (.F32)
    fp_mac: int = 3             #: VMLA, VMLS, VNMLA, VNMLS, VFMA, VFMS, VFNMA, VFNMS
    fp_div: int = 14            #: VDIV.F32, VSQRT.F32
    fp_div_double: int = 14     #: VDIV.F64, VSQRT.F64 (Cortex-M7 only)
    fp_load: int = 2            #: VLDR (VLDM/VPUSH/VPOP/VSTM: ``multiple`` + N words)
    fp_store: int = 2           #: VSTR
    fp_move: int = 1            #: VMOV core <-> FP register, VMRS, VMSR (two core registers: 2)
    exception_entry: int = 12   #: interrupt latency: push of 8 words, vector fetch, refill
    exception_return: int = 10  #: unstacking of 8 words and refill
    lazy_fp_stacking: int = 17  #: S0-S15 and FPSCR pushed at the handler's first FP instruction
    lazy_fp_return: int = 17    #: and popped at its return


@dataclass(frozen=True)
class Core:
    """One Cortex-M core: what it executes, how it is built for, how Unicorn emulates it."""

    name: str
    isa: str                    #: "ARMv6-M", "ARMv7-M" or "ARMv7E-M"
    fpu: str                    #: "none", "single" or "double"
    zig_cpu: str                #: Zig's -mcpu (its CPU model and features)
    gcc_flags: tuple[str, ...]  #: the same target for arm-none-eabi-gcc (a user's own build)
    uc_model: int               #: unicorn.arm_const.UC_CPU_ARM_CORTEX_*
    cycles: CycleTable
    cycles_source: str          #: where the cycle table comes from

    @property
    def hard_float(self) -> bool:
        return self.fpu != "none"

    @property
    def zig_abi(self) -> str:
        """The EABI variant: hard-float calling convention only where the core has an FPU."""
        return "eabihf" if self.hard_float else "eabi"

    @property
    def v6m(self) -> bool:
        return self.isa == "ARMv6-M"


# Cortex-M4 r0p1 TRM (ARM DDI 0439B) section 3.3 Table 3-1 and section 7.2.3 Table 7-1; the
# exception entry of 12 cycles and the lazy stacking of the FP context from ARM Application Note
# 298 (DAI 0298A) "Cortex-M4(F) Lazy Stacking and Context Switching"; a return of 10 cycles as
# J. Yiu, "The Definitive Guide to ARM Cortex-M3 and Cortex-M4 Processors", 3rd ed., section 8.9.
_M4 = CycleTable()
# Cortex-M3 r2p1 TRM (ARM DDI 0337I) section 18.2 Table 18-1: as the M4's integer table, but the
# long multiplies take 3..5 cycles (5 charged) and there are no DSP instructions.
_M3 = CycleTable(mull=5)
# Cortex-M0+ r0p1 TRM (ARM DDI 0484C) section 3.3 Table 3-1 (single-cycle multiplier option):
# two-stage pipeline, a taken branch 2 cycles (B) / 3 (BL), POP {PC} 3 + N, MRS/MSR and the
# barriers 3; no halfword fetch penalty. Interrupt latency 15 cycles (ARM's Cortex-M0+ product
# documentation; J. Yiu, "The Definitive Guide to ARM Cortex-M0 and Cortex-M0+ Processors", 2nd ed.,
# section 8.7); an exception return taken as 12 (8 words unstacked at one per cycle, a refill of
# 2 and the EXC_RETURN decode: no figure is published).
_M0P = CycleTable(mull=1, div=0, dsp=0, dual=0, branch=1, taken=1, load_pc=1, call=1, wide_target=0, sysreg=3,
                  barrier=3,
                  exception_entry=15, exception_return=12, lazy_fp_stacking=0, lazy_fp_return=0)
# Cortex-M7: its TRM (ARM DDI 0489) publishes no instruction timing (dual issue, caches). The M4
# table is used as an approximation without dual issue (an upper bound for most code), with the
# double-precision divide and square root taken as 29 cycles (an estimate) and a cache hit on
# every fetch (the flash wait-state assumption of every core: 0).
_M7 = CycleTable(fp_div_double=29)

_CORES = (
    Core("cortex-m0plus", "ARMv6-M", "none", "cortex_m0plus", ("-mcpu=cortex-m0plus", "-mfloat-abi=soft"),
         arm_const.UC_CPU_ARM_CORTEX_M0, _M0P, "ARM DDI 0484C (Cortex-M0+ TRM) Table 3-1"),
    Core("cortex-m3", "ARMv7-M", "none", "cortex_m3", ("-mcpu=cortex-m3", "-mfloat-abi=soft"),
         arm_const.UC_CPU_ARM_CORTEX_M3, _M3, "ARM DDI 0337I (Cortex-M3 TRM) Table 18-1"),
    Core("cortex-m4", "ARMv7E-M", "none", "cortex_m4", ("-mcpu=cortex-m4", "-mfloat-abi=soft"),
         arm_const.UC_CPU_ARM_CORTEX_M4, _M4, "ARM DDI 0439B (Cortex-M4 TRM) Table 3-1"),
    Core("cortex-m4f", "ARMv7E-M", "single", "cortex_m4+vfp4d16sp",
         ("-mcpu=cortex-m4", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"),
         arm_const.UC_CPU_ARM_CORTEX_M4, _M4, "ARM DDI 0439B (Cortex-M4 TRM) Tables 3-1 and 7-1"),
    Core("cortex-m7f", "ARMv7E-M", "double", "cortex_m7+fp_armv8d16",
         ("-mcpu=cortex-m7", "-mfloat-abi=hard", "-mfpu=fpv5-d16"),
         arm_const.UC_CPU_ARM_CORTEX_M7, _M7, "approximation: the Cortex-M4 tables (ARM DDI 0439B)"),
)
#: every core a target may name, by its ``cpu`` name
CORES = MappingProxyType({c.name: c for c in _CORES})


@dataclass(frozen=True)
class Target:
    """A ``[target]`` table, read strictly."""

    cpu: str
    clock_hz: int
    flash_bytes: int
    ram_bytes: int
    stack_bytes: int
    priorities: dict[str, int] = field(default_factory=lambda: dict.fromkeys(INTERRUPTS, 0))
    flags: tuple[str, ...] = ()
    where: str = ""  #: the file it was read from (for messages)

    @property
    def core(self) -> Core:
        return CORES[self.cpu]

    def cycles_to_s(self, cycles: float) -> float:
        return cycles / self.clock_hz


def read_target(path_or_table: str | Path | dict, where: str | None = None) -> Target:
    """The ``[target]`` table of a TOML file (a sil.toml or a target file), or a table already read
    (``where`` then names its file). Bad input is a ``TomlError`` naming the file and key."""
    if isinstance(path_or_table, dict):
        where = where or "<target>"
        table = path_or_table.get("target", path_or_table) if "cpu" not in path_or_table else path_or_table
    else:
        where = where or str(path_or_table)
        data = load_toml(path_or_table, None, name=where)
        if "target" not in data:
            raise TomlError(where, "no [target] table (pil: needs the part's cpu, clock_hz, flash_bytes, ram_bytes, "
                                   "stack_bytes)")
        table = data["target"]
    if not isinstance(table, dict):
        raise TomlError(where, f"must be a table, got {table!r}", key="target")
    for key in table:
        if key not in TARGET_KEYS:
            raise TomlError(where, f"unknown key (known: {', '.join(sorted(TARGET_KEYS))})", table="[target]",
                            key=key)
    for key in ("cpu", "clock_hz", "flash_bytes", "ram_bytes", "stack_bytes"):
        if key not in table:
            raise TomlError(where, "required", table="[target]", key=key)
    cpu = table["cpu"]
    if cpu not in CORES:
        raise TomlError(where, f"unknown cpu {cpu!r} (known: {', '.join(CORES)})", table="[target]", key="cpu")

    def positive(key: str) -> int:
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise TomlError(where, f"must be a positive integer, got {v!r}", table="[target]", key=key)
        return v

    clock_hz, flash, ram, stack = (positive(k) for k in ("clock_hz", "flash_bytes", "ram_bytes", "stack_bytes"))
    if stack % 8 or stack >= ram:
        raise TomlError(where, f"must be a multiple of 8 below ram_bytes ({ram}), got {stack}", table="[target]",
                        key="stack_bytes")
    priorities = dict.fromkeys(INTERRUPTS, 0)
    given = table.get("priorities", {})
    if not isinstance(given, dict):
        raise TomlError(where, f"must be a table {{ hall = 0, compare = 0, control = 1 }}, got {given!r}",
                        table="[target]", key="priorities")
    for name, value in given.items():
        if name not in INTERRUPTS:
            raise TomlError(where, f"unknown interrupt (known: {', '.join(INTERRUPTS)})",
                            table="[target.priorities]", key=name)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
            raise TomlError(where, f"an NVIC priority 0..255, got {value!r}", table="[target.priorities]", key=name)
        priorities[name] = value
    flags = table.get("flags", [])
    if not isinstance(flags, list) or not all(isinstance(f, str) for f in flags):
        raise TomlError(where, f"must be a list of strings, got {flags!r}", table="[target]", key="flags")
    return Target(cpu, clock_hz, flash, ram, stack, priorities, tuple(flags), where)
