"""Processor in the loop's core (hil.pil): targets, the Cortex-M build, cycles from the TRM tables,
nesting, faults, the stack, determinism, and the reference firmware against its SIL build.

The snippets are compiled with Zig's clang for the core into ELFs (the build cache keeps them: a
second session takes seconds); the expected cycle counts are the TRMs' (docs/processor-in-the-loop.md,
"Cycle table"), written out per instruction beside each test.
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import pytest
from unicorn import arm_const as U
from unicorn.arm_const import UC_ARM_REG_S0

from bldc.tomlfile import TomlError
from hil.pil.build import PilElfError, build_elf, check_elf
from hil.pil.core import (RAM_BASE, SCRATCH_BASE, Core, ProcessorFault, ProcessorHang, StackOverflow)
from hil.pil.firmware import PilFirmware
from hil.pil.target import CORES, read_target
from hil.sil.build import read_build_spec
from hil.sil.firmware import SilInterfaceError

REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "reference"

# Every snippet function in one source (one build per core); /* @NAME */ marks the line a fault names.
SNIPPET = r"""
#include <stdint.h>
#include <math.h>

/* M4: adds 1, mul 1, udiv 12 (the upper bound of 2..12), ldr 2, push{r4,r5} 1+2, pop{r4,r5} 1+2,
   vmov 1, vsqrt.f32 14, vdiv.f32 14, bx lr 1 (its refill is the caller's) = 52 */
__attribute__((naked)) int seq_m4(int a, int b, int *p)
{
    __asm volatile(
        "adds r0, r0, r1\n"
        "mul r0, r0, r1\n"
        "udiv r0, r0, r1\n"
        "ldr r3, [r2]\n"
        "push {r4, r5}\n"
        "pop {r4, r5}\n"
        "vmov s0, r0\n"
        "vsqrt.f32 s0, s0\n"
        "vdiv.f32 s0, s0, s0\n"
        "bx lr\n");
}

/* BASEPRI (ARMv7-M only): interrupts of priority value v and above wait */
void basepri(uint32_t v) { __asm volatile("msr basepri, %0" : : "r"(v) : "memory"); }

/* a loop of five: movs, adds, cmp, bne (taken 4 times: 1 + P = 2), bx lr */
__attribute__((naked)) int loop5(void)
{
    __asm volatile(
        "movs r0, #0\n"
        "1: adds r0, #1\n"
        "cmp r0, #5\n"
        "bne 1b\n"
        "bx lr\n");
}

volatile uint32_t ticks, seen_ticks;
uint32_t count_to(uint32_t n)
{
    uint32_t k;
    for (k = 0; k < n; k++) ticks = k + 1;
    return ticks;
}
uint32_t peek(uint32_t plus) { seen_ticks = ticks; return ticks + plus; }

volatile float gf = 1.25f, of;
volatile double gd = 1.25, od;
void float_op(void) { of = gf * 3.0f + 1.0f; }
void double_op(void) { od = gd * 3.0 + 1.0; }
float lib_op(float x) { return sinf(x) + sqrtf(x) + atan2f(x, 2.0f) + fmodf(x, 0.5f); }

void bus_fault(void) { *(volatile uint32_t *)0x60000000u = 1u; /* @BUS */ }
int64_t load64(const int64_t *p) { return *p; /* @DUAL */ }
uint32_t load32(const volatile uint32_t *p, uint32_t k) { return p[k]; /* @WORD */ }
int32_t load16(const volatile int16_t *p) { return *p; /* @HALF */ }
uint32_t divide(uint32_t a, uint32_t b) { return a / b; /* @DIV */ }
void trap(void) { __builtin_trap(); /* @UDF */ }
void jump_to_ram(void) { ((void (*)(void))(0x20000101u))(); /* @XN */ }
void spin(void) { for (;;) { ticks++; } }
void irq_off(void) { __asm volatile("cpsid i" : : : "memory"); }
void irq_on(void) { __asm volatile("cpsie i" : : : "memory"); }
uint32_t deep(uint32_t n)
{
    volatile uint8_t frame[64];
    uint32_t k, r;
    for (k = 0; k < 64; k++) frame[k] = (uint8_t)n; /* @DEEP */
    if (n == 0) return 0;
    r = deep(n - 1);
    frame[1] = (uint8_t)r; /* used after the call: no tail call */
    return frame[0] + frame[1];
}
"""


SNIPPET_FUNCTIONS = ("seq_m4", "loop5", "count_to", "peek", "float_op", "double_op", "lib_op", "bus_fault", "load64",
                     "load32", "load16", "divide", "trap", "jump_to_ram", "spin", "deep", "basepri", "irq_off",
                     "irq_on")


def _line(marker: str, cpu: str = "cortex-m4f") -> int:
    source = _TEXTS.get(cpu, SNIPPET)
    return next(k for k, text in enumerate(source.splitlines(), start=1) if f"/* @{marker} */" in text)


def _target(cpu: str, **over):
    table = {"cpu": cpu, "clock_hz": 168_000_000, "flash_bytes": 65536, "ram_bytes": 16384, "stack_bytes": 2048}
    table.update(over)
    return read_target(table, "test-target.toml")


@pytest.fixture(scope="session")
def snippet_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("pil-snippet")
    (folder / "src").mkdir()
    (folder / "src" / "snippet.c").write_text(SNIPPET)
    (folder / "sil.toml").write_text('format = "hil-sil-build/1"\nsources = ["src/*.c"]\nflags = ["-O2"]\n'
                                     '[target]\ncpu = "cortex-m4f"\nclock_hz = 168_000_000\nflash_bytes = 65536\n'
                                     'ram_bytes = 16384\nstack_bytes = 2048\n')
    return folder


_ELVES: dict = {}
_TEXTS: dict = {}  #: the source each core's build compiled (the M4 sequence cut from the others)


def _elf(folder: Path, cpu: str) -> Path:
    """The snippet built for ``cpu`` (minus what the core has no instructions for)."""
    if cpu not in _ELVES:
        spec = read_build_spec(folder)
        if CORES[cpu].v6m or not CORES[cpu].hard_float:
            text = SNIPPET.replace(SNIPPET[SNIPPET.index("/* M4:"):SNIPPET.index("/* a loop of five")], "")
            if CORES[cpu].v6m:
                text = text.replace("return a / b;", "return a + b;")
            sub = folder / cpu
            (sub / "src").mkdir(parents=True, exist_ok=True)
            (sub / "src" / "snippet.c").write_text(text)
            _TEXTS[cpu] = text
            (sub / "sil.toml").write_text((folder / "sil.toml").read_text())
            spec = read_build_spec(sub)
        _ELVES[cpu] = build_elf(spec, _target(cpu), keep=SNIPPET_FUNCTIONS).elf
    return _ELVES[cpu]


@pytest.fixture(scope="session")
def m4f(snippet_folder) -> Path:
    return _elf(snippet_folder, "cortex-m4f")


@pytest.fixture(scope="session")
def m0plus(snippet_folder) -> Path:
    return _elf(snippet_folder, "cortex-m0plus")


# --- the target table ---------------------------------------------------------------------------------
def test_target_errors_name_file_and_key(tmp_path):
    with pytest.raises(TomlError, match=r"t\.toml: \[target\]\.cpu: unknown cpu 'cortex-m33' \(known: "
                                        r"cortex-m0plus, cortex-m3, cortex-m4, cortex-m4f, cortex-m7f\)"):
        read_target({"cpu": "cortex-m33", "clock_hz": 1, "flash_bytes": 1, "ram_bytes": 1, "stack_bytes": 1},
                    "t.toml")
    path = tmp_path / "fw.toml"
    path.write_text('format = "x"\n')
    with pytest.raises(TomlError, match=r"fw\.toml: no \[target\] table"):
        read_target(path)
    path.write_text('[target]\ncpu = "cortex-m4f"\nclock_hz = 168000000\nflash_bytes = 1\nram_bytes = 8192\n'
                    'stack_bytes = 1024\npriorities = { hall = 0, pwm = 1 }\n')
    with pytest.raises(TomlError, match=r"\[target\.priorities\]\.pwm: unknown interrupt"):
        read_target(path)
    path.write_text('[target]\ncpu = "cortex-m4f"\nclock_hz = 168000000\nflash_bytes = 1\nram_bytes = 8192\n')
    with pytest.raises(TomlError, match=r"\[target\]\.stack_bytes: required"):
        read_target(path)


def test_sil_toml_with_a_target_table_reads_for_sil(snippet_folder):
    """``sil:`` ignores ``[target]`` (an unknown key is still refused)."""
    spec = read_build_spec(snippet_folder)
    assert spec.sources and read_target(snippet_folder / "sil.toml", None).cpu == "cortex-m4f"


# --- architecture and exports -------------------------------------------------------------------------
def test_a_host_elf_is_refused_naming_its_machine():
    host = Path(sys.executable).resolve()
    with pytest.raises(PilElfError, match=rf"{host}: e_machine EM_X86_64 .*ELF32 for ARM"):
        check_elf(host, CORES["cortex-m4f"])


def test_an_armv7m_elf_is_refused_on_an_armv6m_core(m4f):
    with pytest.raises(PilElfError, match="ARMv7E-M, which cortex-m0plus \\(ARMv6-M\\) cannot execute"):
        check_elf(m4f, CORES["cortex-m0plus"])


def test_missing_exports_are_named(m4f):
    with pytest.raises(SilInterfaceError, match=rf"{m4f}: missing exports hil_sil_describe, hil_sil_reset"):
        PilFirmware(m4f, _target("cortex-m4f"))
    with pytest.raises(SilInterfaceError, match=rf"{m4f}: missing export no_such_function"):
        Core(m4f, _target("cortex-m4f")).call("no_such_function")


# --- cycles -----------------------------------------------------------------------------------------------
def test_cycles_of_a_known_sequence_are_the_trm_table(m4f):
    core = Core(m4f, _target("cortex-m4f"))
    core.call("seq_m4", 6, 3, SCRATCH_BASE)
    assert (core.last_cycles, core.instructions) == (52, 10)
    core.call("loop5")
    # movs adds cmp bne (4), then four times adds cmp bne taken (3 + P of 1), then bx lr (1)
    assert core.result() == 5 and core.last_cycles == 4 + 4 * (3 + 1) + 1


def test_loop_cycles_on_the_cortex_m0plus(m0plus):
    core = Core(m0plus, _target("cortex-m0plus"))
    core.call("loop5")  # Cortex-M0+: a taken B<cond> 2 cycles, not taken 1, as the M4 here
    assert core.last_cycles == 21


def test_exception_entry_and_return_are_charged(m4f, m0plus):
    for elf, cpu, entry, ret in ((m4f, "cortex-m4f", 12, 10), (m0plus, "cortex-m0plus", 15, 12)):
        core = Core(elf, _target(cpu))
        core.call("loop5")
        plain = core.last_cycles
        core.call("loop5", interrupt=True, label="control")
        assert core.last_cycles == plain + entry + ret, cpu
        assert core.stats["control"].cycles == [plain + entry + ret]


def test_same_calls_same_cycles(m4f):
    runs = []
    for _ in range(2):
        core = Core(m4f, _target("cortex-m4f"))
        out = [core.call("count_to", 37), core.call("lib_op", 0), core.call("deep", 6)]
        runs.append((out, core.cycles, core.instructions))
    assert runs[0] == runs[1]


# --- nesting ----------------------------------------------------------------------------------------------
def test_a_preempting_interrupt_runs_between_and_the_preempted_call_ends_as_alone(m4f):
    alone = Core(m4f, _target("cortex-m4f"))
    assert alone.call("count_to", 200) == 200
    alone_cycles = alone.last_cycles
    alone_stack = alone.stack_high_water

    core = Core(m4f, _target("cortex-m4f"))
    core.begin("count_to", (200,))
    assert core.run(until_cycle=core.cycles + 300) is False  # paused part-way
    paused_at = core.cycles
    assert 300 <= paused_at < alone_cycles
    core.begin("peek", (1000,), interrupt=True, label="hall")
    assert core.run() is True
    seen = struct.unpack("<I", core.read(_object(core, "seen_ticks"), 4))[0]
    assert 0 < seen < 200 and core.result() == 1000 + seen  # it ran in the middle of the loop
    hall_cycles = core.last_cycles
    assert core.run() is True and core.result() == 200
    assert core.last_cycles == alone_cycles + hall_cycles  # the preempted call's own cycles plus the interrupt's
    assert core.stack_high_water >= alone_stack + 32  # the interrupt's frame below the paused call's stack


def test_an_interrupt_taken_within_an_it_block_starts_outside_it_and_the_return_restores_it(m4f):
    """Exception entry stacks xPSR and clears its IT bits (ARMv7-M Architecture Reference Manual,
    B1.5.6): a handler begun on a call paused just after an IT instruction runs its own first
    instructions unconditionally. Found on the reference firmware: the Hall interrupt paused after
    ``it lo`` in filter_update, and the control interrupt's first PUSH ran as that block's
    conditional instruction (skipped), its POP then loading a stacked word into LR (a BusFault)."""
    core = Core(m4f, _target("cortex-m4f"))
    core.begin("count_to", (200,))
    assert core.run(until_cycle=core.cycles + 300) is False  # paused part-way
    # the pause as if just after ``it ne`` with Z set: the one instruction left in the block would be skipped
    it_ne_one_left, z_and_thumb = 0x1800, 0x41000000
    core.uc.reg_write(U.UC_ARM_REG_XPSR, z_and_thumb | it_ne_one_left)
    core.begin("deep", (2,), interrupt=True, label="hall")
    assert core.run() is True and core.result() == 3  # its PUSH ran: 2 + deep(1) = 3
    assert core.uc.reg_read(U.UC_ARM_REG_XPSR) & 0x0600FC00 == it_ne_one_left  # the paused call's, back


def test_primask_and_basepri_mask_interrupts_as_the_architecture_says(m4f, m0plus):
    """CPSID i masks every priority until CPSIE i; BASEPRI v masks priority values v and above, and
    0 masks none (ARMv7-M Architecture Reference Manual, B1.5.4). ARMv6-M has PRIMASK alone."""
    core = Core(m4f, _target("cortex-m4f"))
    assert not core.masked(0)
    core.call("irq_off")
    assert core.masked(0) and core.masked(255)
    core.call("irq_on")
    assert not core.masked(0)
    core.call("basepri", 0x20)
    assert core.masked(0x20) and core.masked(0x40) and not core.masked(0x1F)
    core.call("basepri", 0)
    assert not core.masked(255)
    m0 = Core(m0plus, _target("cortex-m0plus"))
    m0.call("irq_off")
    assert m0.masked(0)
    m0.call("irq_on")
    assert not m0.masked(0)


def _object(core: Core, name: str) -> int:
    return core._symbols[name]


# --- soft floating point ----------------------------------------------------------------------------------
def test_soft_float_routines_are_counted_for_double_not_float_on_m4f(m4f):
    core = Core(m4f, _target("cortex-m4f"))
    core.call("float_op", interrupt=True, label="control")
    core.call("double_op", interrupt=True, label="hall")
    assert dict(core.stats["control"].soft_float) == {}
    assert dict(core.stats["hall"].soft_float) == {"__aeabi_dadd": 1, "__aeabi_dmul": 1}


def test_the_maths_library_links_and_runs(m4f, m0plus):
    import math

    x = 0.7
    expected = math.sin(x) + math.sqrt(x) + math.atan2(x, 2.0) + math.fmod(x, 0.5)
    for elf, cpu in ((m4f, "cortex-m4f"), (m0plus, "cortex-m0plus")):
        core = Core(elf, _target(cpu))
        if CORES[cpu].hard_float:  # a float argument and result in s0 (AAPCS-VFP)
            core.uc.reg_write(UC_ARM_REG_S0, struct.unpack("<I", struct.pack("<f", x))[0])
            core.call("lib_op")
            bits = core.uc.reg_read(UC_ARM_REG_S0)
        else:
            bits = core.call("lib_op", struct.unpack("<I", struct.pack("<f", x))[0])
        got = struct.unpack("<f", struct.pack("<I", bits))[0]
        assert got == pytest.approx(expected, rel=1e-6), cpu


# --- faults -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("function, args, kind, cause, marker", [
    ("bus_fault", (), "BusFault", "PRECISERR: write to 0x60000000", "BUS"),
    ("load64", (RAM_BASE + 2,), "UsageFault", "UNALIGNED: ldrd", "DUAL"),
    ("divide", (7, 0), "UsageFault", "DIVBYZERO: udiv", "DIV"),
    ("trap", (), "UsageFault", "UNDEFINSTR", "UDF"),
])
def test_faults_name_kind_function_and_line(m4f, function, args, kind, cause, marker):
    core = Core(m4f, _target("cortex-m4f"))
    with pytest.raises(ProcessorFault) as info:
        core.call(function, *args, interrupt=True, label="control")
    f = info.value
    assert (f.kind, f.function, f.source_line) == (kind, function, f"snippet.c:{_line(marker)}")
    assert cause in f.cause and f.call == function and f.pc is not None
    assert f"{kind} in {function} (snippet.c:{_line(marker)}) at pc 0x" in str(f)


def test_execution_from_ram_is_a_memmanage_fault(m4f):
    core = Core(m4f, _target("cortex-m4f"))
    with pytest.raises(ProcessorFault, match=r"MemManage .* IACCVIOL: instruction fetch from 0x20000100") as info:
        core.call("jump_to_ram")
    assert info.value.call == "jump_to_ram"


def test_every_fault_is_a_hardfault_on_armv6m(m0plus):
    core = Core(m0plus, _target("cortex-m0plus"))
    with pytest.raises(ProcessorFault) as info:
        core.call("bus_fault")
    assert info.value.kind == "HardFault" and "BusFault on ARMv7-M; PRECISERR" in info.value.cause
    assert info.value.source_line == f"snippet.c:{_line('BUS', 'cortex-m0plus')}"


@pytest.mark.parametrize("hooks", ["native", "python"])
@pytest.mark.parametrize("function, args, at, mnemonic, marker", [
    ("load32", (RAM_BASE + 2, 1), RAM_BASE + 6, "ldr", "WORD"),  # a register offset: [r0, r1, lsl #2]
    ("load16", (RAM_BASE + 1,), RAM_BASE + 1, "ldrsh", "HALF"),
])
def test_an_unaligned_single_load_is_a_hardfault_on_armv6m_and_allowed_on_armv7m(m0plus, m4f, hooks, function, args,
                                                                                at, mnemonic, marker):
    """ARMv6-M has no unaligned access (its Architecture Reference Manual, A3.2): an LDR, STR, LDRH, STRH
    or LDRSH at an address not a multiple of its size is a HardFault, named with its ARMv7-M cause; an
    aligned one runs; ARMv7-M allows it (UNALIGN_TRP clear)."""
    core = Core(m0plus, _target("cortex-m0plus"), hooks=hooks)
    with pytest.raises(ProcessorFault) as info:
        core.call(function, *args)
    f = info.value
    assert f.kind == "HardFault" and f.function == function
    assert f"UsageFault on ARMv7-M; UNALIGNED: {mnemonic} at address 0x{at:08X}" in f.cause
    assert f.source_line == f"snippet.c:{_line(marker, 'cortex-m0plus')}"
    Core(m0plus, _target("cortex-m0plus"), hooks=hooks).call(function, RAM_BASE, *args[1:])
    Core(m4f, _target("cortex-m4f"), hooks=hooks).call(function, *args)


def test_a_fault_leaves_the_core_unusable(m4f):
    core = Core(m4f, _target("cortex-m4f"))
    with pytest.raises(ProcessorFault):
        core.call("bus_fault")
    with pytest.raises(RuntimeError, match="make a new Core"):
        core.call("loop5")


# --- the stack and hangs ----------------------------------------------------------------------------------
def test_stack_high_water_grows_with_depth_and_an_overflow_names_the_instruction(m4f):
    core = Core(m4f, _target("cortex-m4f", stack_bytes=2048))
    core.call("deep", 2)
    shallow = core.stack_high_water
    core.call("deep", 6)
    # four more frames of deep(): 64 bytes of locals plus saved registers each (at least 4 * 72)
    assert core.stack_high_water - shallow >= 4 * 72
    assert core.stack_high_water < 2048
    with pytest.raises(StackOverflow) as info:
        core.call("deep", 1000)
    f = info.value
    assert f.function == "deep" and f.pc is not None and "below the stack's bottom 0x20003800" in f.cause
    assert f.source_line is not None and f.source_line.startswith("snippet.c:")


def test_a_call_past_its_budget_is_a_hang(m4f):
    core = Core(m4f, _target("cortex-m4f"), budget_cycles=10_000)
    with pytest.raises(ProcessorHang, match=r"Hang in spin .*spin ran past its budget of 10000 cycles") as info:
        core.call("spin")
    assert 10_000 <= info.value.cycles < 10_100


# --- the reference firmware: pil against sil ----------------------------------------------------------
def test_reference_firmware_on_m4f_answers_as_its_sil_build():
    """describe, reset, a turn of Hall edges with control interrupts between them, and object
    reads: the same answers from the Cortex-M4F build as from the PC build (float arithmetic is
    IEEE single on both; the duty is compared within 1 count of 65535 for the M4F's fused
    multiply-adds)."""
    from hil.sil.build import build
    from hil.sil.firmware import Firmware

    spec = read_build_spec(REFERENCE)
    sil = Firmware(str(build(spec).library))
    pil = PilFirmware(build_elf(spec, _target("cortex-m4f", flash_bytes=1 << 20, ram_bytes=196608,
                                              stack_bytes=4096)).elf,
                      _target("cortex-m4f", flash_bytes=1 << 20, ram_bytes=196608, stack_bytes=4096))
    info_sil, info_pil = sil.describe(), pil.describe()
    assert info_pil == info_sil
    for fw in (sil, pil):
        fw.reset(0b001)
    sequence = (0b011, 0b010, 0b110, 0b100, 0b101, 0b001) * 3  # forward rotation, six edges per cycle
    count = 1000
    for k, levels in enumerate(sequence):
        count += 2500  # 4 kHz of edges at 10 MHz
        pin = [b for b in range(3) if (levels ^ sequence[k - 1]) >> b & 1][0] if k else 1
        for fw in (sil, pil):
            fw.adc[0], fw.adc[1], fw.adc[2] = 120, -60, -60
            fw.hall_isr(count, pin, levels, fw.adc)
        assert pil.gates() == sil.gates(), f"edge {k}"
        assert abs(pil.duty() - sil.duty()) <= 1, f"edge {k}"
        for c in range(1, 5):
            for fw in (sil, pil):
                fw.control_isr(count + 500 * c, fw.adc)
            assert pil.gates() == sil.gates() and abs(pil.duty() - sil.duty()) <= 1
    for index, sub, size in ((0x1000, 0, 4), (0x2000, 0, 1), (0x2001, 0, 4), (0x1018, 1, 4), (0x2010, 1, 4),
                             (0x1001, 0, 1), (0x9999, 0, 4)):
        assert pil.od_read(index, sub, size) == sil.od_read(index, sub, size), hex(index)
    stats = pil.stats()
    assert stats["interrupts"]["hall"]["calls"] == len(sequence)
    assert stats["interrupts"]["control"]["calls"] == 4 * len(sequence)
    assert 0 < stats["stack"]["high_water_bytes"] < 4096
