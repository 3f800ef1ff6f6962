"""Cycle cost of a basic block: each instruction decoded once with Capstone, classed, and charged
from the core's ``CycleTable`` (hil.pil.target; the table and its sources in
docs/processor-in-the-loop.md).

A block ends at a branch (Unicorn's translation blocks are basic blocks). Its ``cycles`` assume the
branch at its end is not taken; a taken one (the next block does not start at ``fallthrough``)
costs ``taken_extra`` more, plus the target block's ``entry_extra`` (a 32-bit instruction at a
halfword address refills one cycle later on the Cortex-M3/M4/M7).
"""

from __future__ import annotations

from dataclasses import dataclass

import capstone
from capstone import arm_const as A

from .target import CycleTable

_LOADS = {"ldr", "ldrb", "ldrh", "ldrsb", "ldrsh", "ldrex", "ldrexb", "ldrexh", "ldrt", "ldrbt", "ldrht", "ldrsbt",
          "ldrsht", "pld", "pli"}
_STORES = {"str", "strb", "strh", "strex", "strexb", "strexh", "strt", "strbt", "strht"}
_MULTIPLE = {"ldm", "ldmdb", "stm", "stmdb", "push", "pop"}
_BRANCHES = {"b", "bl", "blx", "bx", "cbz", "cbnz"}
_MULL = {"umull", "smull", "umlal", "smlal", "umaal"}
_FP_MAC = {"vmla", "vmls", "vnmla", "vnmls", "vfma", "vfms", "vfnma", "vfnms"}
_FP_MULTIPLE = {"vldmia", "vldmdb", "vstmia", "vstmdb", "vpush", "vpop", "vldm", "vstm"}
_FP_MOVE = {"vmrs", "vmsr", "fmstat"}
_SYSREG = {"mrs", "msr"}
_BARRIERS = {"dmb", "dsb", "isb"}
_OTHER = {"it", "hint", "nop", "cpsid", "cpsie", "cps", "wfi", "wfe", "yield", "sev"}
#: instructions the framework checks at run time (per-address hooks, hil.pil.core)
DIVIDES = {"udiv", "sdiv"}
DUALS = {"ldrd", "strd"}
MULTIPLES_CHECKED = {"ldm", "ldmdb", "stm", "stmdb"}
#: single loads and stores that need alignment on ARMv6-M, which has no unaligned access at all (the
#: ARMv6-M Architecture Reference Manual, A3.2: an unaligned LDR, STR, LDRH, STRH or LDRSH is a HardFault;
#: ARMv7-M allows them): the mask of their address's bits that must be zero
SINGLES_V6M = {"ldr": 3, "str": 3, "ldrh": 1, "strh": 1, "ldrsh": 1}


def disassembler() -> capstone.Cs:
    md = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
    md.detail = True
    return md


def is_fp(name: str) -> bool:
    return name.startswith("v") or name in ("fconsts", "fconstd", "fmstat")


def _writes_pc(insn) -> bool:
    ops = insn.operands
    return bool(ops) and ops[0].type == A.ARM_OP_REG and ops[0].reg == A.ARM_REG_PC


def _reg_list_has_pc(insn) -> bool:
    return any(op.type == A.ARM_OP_REG and op.reg == A.ARM_REG_PC for op in insn.operands)



#: instruction classes of one fixed cost, in the order they are tried: (mnemonics, the cycle-table field)
_FIXED_COST = ((_STORES, "store"), (DUALS, "dual"), (DIVIDES, "div"), (frozenset({"mul"}), "mul"),
               (frozenset({"mla", "mls"}), "mla"), (_MULL, "mull"), (_SYSREG, "sysreg"), (_BARRIERS, "barrier"),
               (_OTHER, "other"))

def insn_cycles(insn, t: CycleTable) -> tuple[int, int]:
    """(cycles when not taken, extra when it transfers control) of one decoded instruction."""
    name = insn.insn_name()
    if name in _BRANCHES:
        return t.branch + (t.call if name == "bl" else 0), t.taken
    if name in ("tbb", "tbh"):
        return t.table_branch, t.taken
    if name in _MULTIPLE:
        regs = sum(1 for op in insn.operands if op.type == A.ARM_OP_REG) - (0 if name in ("push", "pop") else 1)
        if name in ("pop", "ldm", "ldmdb") and _reg_list_has_pc(insn):
            return t.multiple + regs, t.taken + t.load_pc
        return t.multiple + regs, 0
    if name in _LOADS:
        return (t.load, t.taken + t.load_pc) if _writes_pc(insn) else (t.load, 0)
    for names, field in _FIXED_COST:
        if name in names:
            return getattr(t, field), 0
    if is_fp(name):
        mnemonic = insn.mnemonic
        if name in ("vdiv", "vsqrt"):
            return (t.fp_div_double if ".f64" in mnemonic else t.fp_div), 0
        if name in _FP_MAC:
            return t.fp_mac, 0
        if name == "vldr":
            return t.fp_load, 0
        if name == "vstr":
            return t.fp_store, 0
        if name in _FP_MULTIPLE:
            words = sum(2 if insn.reg_name(op.reg).startswith("d") else 1
                        for op in insn.operands if op.type == A.ARM_OP_REG
                        and insn.reg_name(op.reg)[0] in "sd" and insn.reg_name(op.reg) != "sp")
            return t.multiple + words, 0
        if name in _FP_MOVE:
            return t.fp_move, 0
        if name == "vmov":
            core_regs = sum(1 for op in insn.operands if op.type == A.ARM_OP_REG and insn.reg_name(op.reg)[0] == "r"
                            or op.type == A.ARM_OP_REG and insn.reg_name(op.reg) in ("ip", "lr", "sb", "sl", "fp"))
            return (t.fp_move * max(core_regs, 1), 0) if core_regs else (t.fp_alu, 0)
        return t.fp_alu, 0
    if name in ("sdiv", "udiv"):
        return t.div, 0
    if name.startswith(("sm", "um", "q", "uq", "sh", "uh", "sadd", "ssub", "uadd", "usub", "sasx", "ssax", "uasx",
                        "usax", "sel", "usad")):
        return t.dsp, 0
    # data processing, moves, shifts, compares, extends, bit fields (a write to PC refills)
    return (t.alu, t.taken) if _writes_pc(insn) else (t.alu, 0)


@dataclass(slots=True, eq=False)
class Block:
    """One decoded basic block (see the module docstring)."""

    address: int
    size: int
    cycles: int
    count: int                  #: instructions
    fallthrough: int            #: the address after its last instruction
    taken_extra: int            #: cycles more when control does not fall through
    entry_extra: int            #: cycles more when a taken branch lands here
    fp: bool                    #: holds a floating-point instruction
    special: bool = False       #: needs the slow path of the block hook (FP, soft-float entry, fault)
    softfloat: str | None = None  #: the soft-float routine this block is the entry of
    fault: tuple | None = None  #: (kind, cause, address) found by decoding (an FP instruction without an FPU)


#: the block "before" the first one of a call: nothing to add
START = Block(0, 0, 0, 0, -1, 0, 0, False)


def row(insn, t: CycleTable) -> tuple[int, int, str, str, int, int, bool]:
    """What a block's cost needs of one decoded instruction: (address, size, mnemonic, operands,
    cycles when not taken, extra when taken, FP)."""
    c, taken = insn_cycles(insn, t)
    return insn.address, insn.size, insn.mnemonic, insn.op_str, c, taken, is_fp(insn.insn_name())


def decode_block(md: capstone.Cs, code: bytes, address: int, t: CycleTable, has_fpu: bool,
                 known: dict[int, tuple] | None = None) -> Block:
    """The block of ``code`` at ``address``, each instruction decoded in full by Capstone (tens of
    microseconds an instruction in Python). ``known``: rows (``row``) by address from a full decode
    of the ELF's functions made before (hil.pil.core's sweep); a block whose light decode (address,
    size, mnemonic, operand text: a few microseconds an instruction) finds every instruction there,
    decoded alike, is summed from those rows instead. Decoded alike means the same encoding (the
    same bytes at the same address) shown the same way: the text carries the decoder's context
    (the condition an IT block adds) and every operand ``insn_cycles`` reads."""
    rows = _known_rows(md, code, address, known) if known else None
    if rows is None:
        rows = [row(insn, t) for insn in md.disasm(code, address)]
    cycles = count = taken = 0
    fp = False
    fault = None
    end = address
    first_wide = None
    for a, size, mnemonic, op_str, c, taken, insn_fp in rows:
        cycles += c
        count += 1
        end = a + size
        if first_wide is None:
            first_wide = size == 4 and address % 4 == 2
        if insn_fp:
            fp = True
            if not has_fpu and fault is None:
                fault = ("UsageFault", f"NOCP: floating-point instruction {mnemonic} {op_str} on a core "
                                       "without an FPU", a)
    if end != address + len(code) and fault is None:
        fault = ("UsageFault", "UNDEFINSTR: an instruction Capstone cannot decode", end)
    return Block(address, len(code), cycles, count, address + len(code), taken,
                 t.wide_target if first_wide else 0, fp, special=fp or fault is not None, fault=fault)


def _known_rows(md: capstone.Cs, code: bytes, address: int, known: dict[int, tuple]) -> list[tuple] | None:
    rows = []
    for a, size, mnemonic, op_str in md.disasm_lite(code, address):
        r = known.get(a)
        if r is None or r[1] != size or r[2] != mnemonic or r[3] != op_str:
            return None
        rows.append(r)
    return rows
