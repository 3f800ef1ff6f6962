"""``pil:``: the firmware of a ``sil:`` DUT built for its Cortex-M part and run on an emulated core
(``hil.pil``), behind the same link, worker process and peripherals as ``sil:`` (the firmware kind
is their parameter; ``hil.sil.scheduler`` gives its interrupts their time).

``pil:FOLDER``: a folder with a ``sil.toml`` holding a ``[target]`` table, built with Zig's clang
for the declared core (``hil.pil.build``). ``pil:FILE.elf,target=FILE.toml``: an ELF linked
elsewhere, its ``[target]`` table in a file of its own. docs/processor-in-the-loop.md, "Using pil:".
"""

from __future__ import annotations

from pathlib import Path

from ..dut.link import LinkError


def _target_file(path: Path, options: dict) -> Path:
    return Path(options["target"]) if options.get("target") else path / "sil.toml"


def check_target(text: str, path: Path, options: dict) -> None:
    """The ``[target]`` a ``pil:`` DUT runs on, and an ELF's architecture, refused in one line
    before anything is built: a missing table or key, an unknown cpu, an ELF of another machine."""
    from bldc.tomlfile import TomlError

    from ..dut.spec import DutSpecError
    from ..pil.target import read_target

    if not path.is_dir() and not options.get("target"):
        raise DutSpecError(f"--hil-dut {text!r}: an ELF needs target=FILE.toml (its [target] table: cpu, clock_hz, "
                           "flash_bytes, ram_bytes, stack_bytes)")
    where = _target_file(path, options)
    if not where.is_file():
        raise DutSpecError(f"--hil-dut {text!r}: target {where}: no such file")
    try:
        target = read_target(where)
    except TomlError as exc:
        raise DutSpecError(f"--hil-dut {text!r}: {exc}") from None
    if not path.is_dir():
        from ..pil.build import PilElfError, check_elf

        try:
            check_elf(path, target.core)
        except PilElfError as exc:
            raise DutSpecError(f"--hil-dut {text!r}: {exc}") from None


def resolve_elf(spec) -> tuple[Path, Path, Path | None, str]:
    """The ELF of a ``pil:`` DUT (built when PATH is a folder), the file holding its ``[target]``,
    the profile its ``sil.toml`` names (None for an ELF), and one line on how it was obtained."""
    from ..pil.build import build_elf
    from ..pil.target import read_target
    from .build import SilBuildError, read_build_spec

    path = Path(spec.options["path"])
    where = _target_file(path, spec.options)
    if not path.is_dir():
        return path.resolve(), where.resolve(), None, f"ELF {path}"
    build_spec = read_build_spec(path)
    try:
        built = build_elf(build_spec, read_target(where), extra_defines(spec))
    except SilBuildError as exc:
        raise LinkError(str(exc)) from None
    how = f"{'cached build' if built.cached else 'built'} {built.key} with {built.toolchain}"
    return built.elf, where.resolve(), build_spec.profile, how


def extra_defines(spec) -> tuple[tuple[str, str], ...]:
    """``define=A+B=1``: the extra ``-D`` switches of a folder's build (the seeded defects')."""
    out = []
    for part in filter(None, spec.options["define"].split("+")):
        name, _, value = part.partition("=")
        out.append((name.strip(), value.strip()))
    return tuple(out)


def processor_firmware(elf: str, target: str):
    """The firmware of a ``pil:`` worker process: the ELF on a fresh core of the ``[target]`` in
    ``target`` (``hil.sil.worker``)."""
    from ..pil.firmware import PilFirmware
    from ..pil.target import read_target

    return PilFirmware(elf, read_target(target))
