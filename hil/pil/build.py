"""Build a firmware folder (``sil.toml``) for the core its ``[target]`` names, into an ELF.

The compiler is Zig's clang from the ``ziglang`` wheel (no system cross compiler is needed):

- **Compile** each source with ``-target thumb-linux-musleabi[hf] -mcpu=<core>``: Thumb code for
  the core, hard float only where it has an FPU (single precision on the Cortex-M4F, so a
  ``double`` there is a software routine; double on the Cortex-M7F), and the C and C++ headers
  that ship with Zig (musl's C library headers, LLVM's libc++ headers: ``<array>``,
  ``<algorithm>``, ``<cmath>``, ``<cstdint>``). The Linux target only lends its headers: its
  macros (``__linux__``, ``__unix__``) are undefined and libc++ is told there are no threads. C is
  C99 and C++ C++17 (``-fno-exceptions -fno-rtti``), as for ``sil:``, plus ``-DHIL_PIL=1``.
- **Link** with ``-target thumb-freestanding-eabi[hf]`` against this module's linker script. Zig
  links its compiler-rt built for the core: the run-time ABI (``__aeabi_dadd`` ... soft float,
  64-bit division), ``memcpy``/``memset``/``memmove`` and most of the C maths library (``sinf``,
  ``cosf``, ``sqrtf``, ``fmodf``, ``expf``, ``logf``, ``floorf`` ...); ``support/libc_extra.zig``
  (built per core with ``zig build-obj``) adds the rest of ``<math.h>`` that firmware uses
  (``atan2f``, ``asinf``, ``powf``, ``hypotf`` ...) and ``memcmp``/``strlen``/``strcmp`` from Zig's
  standard library. A firmware that calls what neither has (``printf``, ``malloc``) fails to link,
  naming the symbol. Zig's maths functions are musl's algorithms: ``sinf``/``cosf`` reduce in
  double, so on an M4F they call soft-double routines (newlib's float versions would not).
- **Memory.** Flash at 0x08000000 (``flash_bytes``), RAM at 0x20000000 (``ram_bytes``), the
  main stack at the top of RAM (``stack_bytes``); ``.data`` is loaded from flash into RAM and
  ``.bss`` zeroed by the loader (hil.pil.core), as a start-up routine would. ``.text`` beyond the
  flash, or ``.data`` + ``.bss`` reaching into the stack, fail the link in one message.
- The ELF keeps DWARF line information (``-g``) for faults' source lines.

The cache is ``hil.sil.build``'s (same folder, same kind of key, salted with the core, the
target's flags and sizes and the support files). A user's own ELF (``pil:FILE.elf``) is checked by
``check_elf``: an ELF32 for ARM, M profile, an architecture the core executes.
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

from hil.sil.build import (CXX_SUFFIXES, HEADER_DIR, BuildSpec, SilBuildError, _key, _language_flags, _run,
                           _std_flags, _version, cached_build)

from .target import Core, Target

FLASH_BASE = 0x0800_0000
RAM_BASE = 0x2000_0000
SUPPORT = Path(__file__).resolve().parent / "support" / "libc_extra.zig"
#: every hil-sil/1 export, kept by the linker's garbage collection whether referenced or not
EXPORTS = ("hil_sil_describe", "hil_sil_reset", "hil_sil_hall_isr", "hil_sil_control_isr", "hil_sil_compare_isr",
           "hil_sil_gates", "hil_sil_duty", "hil_sil_compare", "hil_sil_od_read", "hil_sil_od_write", "hil_sil_emcy")
#: what the Linux target defines that a bare-metal build must not see
_NOT_LINUX = ("-U__linux__", "-U__linux", "-Ulinux", "-U__gnu_linux__", "-U__unix__", "-U__unix", "-Uunix",
              "-U_LIBCPP_HAS_THREADS", "-D_LIBCPP_HAS_THREADS=0")

_LINKER_SCRIPT = """\
/* hil.pil.build: {cpu}, {flash_bytes} bytes of flash, {ram_bytes} of RAM, a {stack_bytes}-byte main stack */
MEMORY
{{
  FLASH (rx)  : ORIGIN = 0x{flash:08X}, LENGTH = {flash_bytes}
  RAM   (rwx) : ORIGIN = 0x{ram:08X}, LENGTH = {ram_bytes}
}}
__stack_top = ORIGIN(RAM) + LENGTH(RAM);
__stack_bottom = __stack_top - {stack_bytes};
SECTIONS
{{
  .text : {{ *(.text .text.*) *(.rodata .rodata.*) . = ALIGN(4); }} > FLASH
  .ARM.extab : {{ *(.ARM.extab* .gnu.linkonce.armextab.*) }} > FLASH
  .ARM.exidx : {{ *(.ARM.exidx* .gnu.linkonce.armexidx.*) }} > FLASH
  .init_array : {{ KEEP(*(SORT(.init_array.*))) KEEP(*(.init_array)) }} > FLASH
  .data : {{ . = ALIGN(4); *(.data .data.*) . = ALIGN(4); }} > RAM AT > FLASH
  .bss (NOLOAD) : {{ *(.bss .bss.* COMMON) . = ALIGN(8); __bss_end = .; }} > RAM
  ASSERT(__bss_end <= __stack_bottom, "RAM: .data and .bss reach into the main stack (ram_bytes - stack_bytes)")
}}
"""


def linker_script(target: Target) -> str:
    return _LINKER_SCRIPT.format(cpu=target.cpu, flash=FLASH_BASE, ram=RAM_BASE, flash_bytes=target.flash_bytes,
                                 ram_bytes=target.ram_bytes, stack_bytes=target.stack_bytes)


def zig() -> tuple[str, ...]:
    try:
        import ziglang  # noqa: F401  (the wheel that carries Zig's clang)
    except ImportError:
        raise SilBuildError("pil: builds with the ziglang package, which is not installed "
                            "(python -m pip install ziglang)") from None
    return (sys.executable, "-m", "ziglang")


@dataclass(frozen=True)
class BuiltElf:
    elf: Path
    key: str
    toolchain: str
    cached: bool


def compile_flags(core: Core) -> list[str]:
    """The flags that make Zig's clang compile for ``core`` (with the C library's headers)."""
    return ["-target", f"thumb-linux-musl{core.zig_abi}", f"-mcpu={core.zig_cpu}", *_NOT_LINUX,
            "-ffunction-sections", "-fdata-sections", "-g", "-DHIL_PIL=1"]


def support_object(core: Core) -> Path:
    """``support/libc_extra.zig`` built for ``core`` (cached)."""
    z = zig()
    source = SUPPORT.read_bytes()
    key = "pil-support-" + hashlib.sha256(core.zig_cpu.encode() + core.zig_abi.encode() + source
                                          + _version((*z, "cc")).encode()).hexdigest()[:20]

    def make(work: Path, log: list[str]) -> None:
        cmd = [*z, "build-obj", "-target", f"thumb-freestanding-{core.zig_abi}", f"-mcpu={core.zig_cpu}",
               "-OReleaseFast", "-ffunction-sections", "-fno-stack-check", str(SUPPORT),
               f"-femit-bin={work / 'libc_extra.o'}", "--cache-dir", str(work / "zig-cache")]
        _run(cmd, _Where(SUPPORT), log, f"building {SUPPORT.name} for {core.name}")

    obj, _, _ = cached_build(key, "libc_extra.o", make)
    return obj


@dataclass(frozen=True)
class _Where:
    """What ``hil.sil.build._run`` needs of a spec: the file errors name and the folder to run in."""

    path: Path

    @property
    def folder(self) -> Path:
        return self.path.parent


def build_elf(spec: BuildSpec, target: Target, extra_defines: tuple[tuple[str, str], ...] = (),
              keep: tuple[str, ...] = ()) -> BuiltElf:
    """The ELF of ``spec`` for ``target``'s core (built now, or taken from the cache). The linker
    drops what nothing references, as a firmware's release link does, but the ``hil-sil/1``
    exports and the functions named in ``keep``."""
    from hil.sil.build import Toolchain

    core = target.core
    z = zig()
    cc, cxx = (*z, "cc"), (*z, "c++")
    tc = Toolchain(cc, cxx, _version(cc), "ziglang")
    script = linker_script(target)
    salt = {"pil": core.name, "target_flags": target.flags, "script": script, "keep": keep,
            "support": hashlib.sha256(SUPPORT.read_bytes()).hexdigest()}
    key = "pil-" + _key(spec, tc, extra_defines, salt)
    support = support_object(core)
    flags = (*spec.flags, *target.flags)

    def make(work: Path, log: list[str]) -> None:
        objects, any_cxx = [], False
        common = [*compile_flags(core), f"-I{HEADER_DIR}", *(f"-I{p}" for p in spec.include)]
        common += [f"-D{n}" if v == "" else f"-D{n}={v}" for n, v in (*spec.defines, *extra_defines)]
        for k, src in enumerate(spec.sources):
            cxx = src.suffix in CXX_SUFFIXES
            any_cxx |= cxx
            obj = work / f"{k:03d}-{src.stem}.o"
            lang = ["-fno-exceptions", "-fno-rtti"] if cxx else []
            cmd = [*(tc.cxx if cxx else tc.cc), *_std_flags(flags, cxx), *common, *lang,
                   *_language_flags(flags, cxx), "-c", str(src), "-o", str(obj)]
            _run(cmd, spec, log, f"compiling {src} for {core.name}")
            objects.append(str(obj))
        (work / "target.ld").write_text(script)
        kept = [f"-Wl,-u,{name}" for name in (*EXPORTS, *keep)]
        cmd = [*tc.cc, "-target", f"thumb-freestanding-{core.zig_abi}", f"-mcpu={core.zig_cpu}", "-g",
               "-nostartfiles", "-Wl,--gc-sections", *kept, "-T", str(work / "target.ld"), *objects, str(support),
               "-o", str(work / "firmware.elf")]
        _run(cmd, spec, log, f"linking for {core.name}")

    elf, cached, _ = cached_build(key, "firmware.elf", make)
    return BuiltElf(elf, key, f"zig cc {tc.version} for {core.name} ({core.isa}, FPU {core.fpu})", cached)


#: ELF e_machine names of the architectures one might hand over by mistake
_MACHINES = {"EM_ARM": "ARM", "EM_X86_64": "x86-64", "EM_386": "x86", "EM_AARCH64": "AArch64", "EM_RISCV": "RISC-V",
             "EM_XTENSA": "Xtensa", "EM_AVR": "AVR"}
#: Tag_CPU_arch values (ARM IHI 0045, "Addenda to the ARM ABI") of the M-profile architectures
_ARCH_M = {10: "ARMv7", 11: "ARMv6-M", 12: "ARMv6S-M", 13: "ARMv7E-M", 16: "ARMv8-M.base", 17: "ARMv8-M.main"}


class PilElfError(SilBuildError):
    """An ELF the target's core cannot run; one line naming the file."""


def check_elf(path: str | Path, core: Core) -> None:
    """Refuse, in one line naming the file, what is not an ELF32 for an M-profile ARM that ``core``
    executes (an ARMv7-M ELF on an ARMv6-M core, a host library, a Cortex-A build)."""
    from elftools.common.exceptions import ELFError
    from elftools.elf.elffile import ELFFile

    path = Path(path)
    try:
        with open(path, "rb") as f:
            elf = ELFFile(f)
            machine, bits = elf["e_machine"], elf.elfclass
            arch = profile = None
            attrs = elf.get_section_by_name(".ARM.attributes")
            if machine == "EM_ARM" and attrs is not None and hasattr(attrs, "iter_subsections"):
                for sub in attrs.iter_subsections():
                    for subsub in sub.iter_subsubsections():
                        for a in subsub.iter_attributes():
                            if a.tag == "TAG_CPU_ARCH":
                                arch = a.value
                            elif a.tag == "TAG_CPU_ARCH_PROFILE":
                                profile = a.value
    except OSError as exc:
        raise PilElfError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    except ELFError as exc:
        raise PilElfError(f"{path}: not an ELF file ({exc})") from None
    if machine != "EM_ARM" or bits != 32:
        name = _MACHINES.get(machine, str(machine))
        raise PilElfError(f"{path}: e_machine {machine} ({name}, ELF{bits}): pil: runs ELF32 for ARM "
                          "(ARMv6-M or ARMv7-M, Thumb)")
    if profile is not None and profile not in (ord("M"), "M"):
        raise PilElfError(f"{path}: an ARM ELF for the {chr(profile) if isinstance(profile, int) else profile!r} "
                          "profile (Tag_CPU_arch_profile): pil: runs M-profile (Cortex-M) code")
    if arch is not None and core.v6m and arch not in (11, 12):
        raise PilElfError(f"{path}: built for {_ARCH_M.get(arch, f'Tag_CPU_arch {arch}')}, which {core.name} "
                          f"({core.isa}) cannot execute")
