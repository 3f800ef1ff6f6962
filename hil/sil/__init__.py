"""Firmware in the loop (``hil-sil/1``): the suite against C firmware compiled for the PC.

``--dut sil:PATH[,profile=FILE]``: PATH is a shared library exporting the ``hil_sil_*`` functions
(``include/hil_sil.h``), or a folder with a ``sil.toml`` whose sources the framework compiles
(``hil.sil.build``). The firmware runs in a process of its own (``hil.sil.worker``) beside the
plant, behind emulated peripherals (``hil.sil.peripherals``); the suite reaches it through its
object dictionary as a device profile maps it, and judges its commutation from the gates it
switched (``hil.sil.link``). docs/firmware-in-the-loop.md.
"""

from __future__ import annotations

from pathlib import Path

from ..dut.link import LinkError

#: the node id a profile's $NODEID resolves to on SIL (the built-in map's; nothing is sent on a bus)
SIL_NODE_ID = 5


def check_options(text: str, options: dict) -> None:
    """A firmware path that is neither a shared library nor a folder with a readable sil.toml, or a
    bad option, is refused before anything is built (``hil.dut.kinds``: sil's and pil's check). The
    profile is checked after this by ``hil.dut.spec``."""
    from ..dut.spec import DutSpecError

    path = Path(options["path"])
    if not path.exists():
        raise DutSpecError(f"--hil-dut {text!r}: {path}: no such file or folder")
    if path.is_dir():
        from bldc.tomlfile import TomlError

        from .build import SilBuildError, read_build_spec

        try:
            read_build_spec(path)
        except (SilBuildError, TomlError) as exc:
            raise DutSpecError(f"--hil-dut {text!r}: {exc}") from None
    elif options["define"]:
        raise DutSpecError(f"--hil-dut {text!r}: define= needs a firmware folder with a sil.toml, not a "
                           f"{'library' if 'target' not in options else 'linked ELF'}")
    if not options["hang"] > 0:
        raise DutSpecError(f"--hil-dut {text!r}: hang must be positive (seconds of wall time)")
    if "compiler" in options and options["compiler"] not in ("auto", "system", "ziglang"):
        raise DutSpecError(f"--hil-dut {text!r}: compiler must be auto, system or ziglang")
    if "target" in options:  # pil: the part it runs on
        from .processor import check_target

        check_target(text, path, options)


def open_dut(spec, motor, controller=None):
    """The opened ``sil:`` or ``pil:`` DUT (``hil.dut.kinds``); ``controller`` is the virtual kind's."""
    from ..dut.spec import Dut

    return Dut(spec, open_sil(spec, motor))


def resolve_library(spec) -> tuple[Path, Path | None, str]:
    """The shared library of a ``sil:`` DUT (built when PATH is a folder), the profile its
    ``sil.toml`` names (None for a library), and one line on how it was obtained."""
    from .build import SilBuildError, build, read_build_spec
    from .sources import SourcesError
    from .processor import extra_defines

    path = Path(spec.options["path"])
    if not path.is_dir():
        return path.resolve(), None, f"library {path}"
    build_spec = read_build_spec(path)
    try:
        built = build(build_spec, extra_defines(spec), prefer=spec.options["compiler"])
    except (SilBuildError, SourcesError) as exc:
        raise LinkError(str(exc)) from None
    how = f"{'cached build' if built.cached else 'built'} {built.key} with {built.toolchain}"
    if built.fetched:
        how += f"; sources of {built.fetched}"
    return built.library, build_spec.profile, how


def open_sil(spec, motor):
    """The SilLink of a ``sil:`` or ``pil:`` DUT, refused in one line when the firmware breaks the
    interface, the profile cannot be read or the firmware is configured for other pole pairs than
    ``motor``. ``pil:`` runs the firmware built for its part on an emulated core (``hil.sil.processor``)."""
    from ..dut.profile import ProfileError, bound_profile
    from .firmware import SilInterfaceError
    from .link import SilLink

    label = f"{spec.kind}:{spec.options['path']}"
    target = None
    if spec.kind == "pil":
        from .processor import resolve_elf

        library, target, built_profile, how = resolve_elf(spec)
    else:
        library, built_profile, how = resolve_library(spec)
    profile_path = spec.options["profile"] or built_profile
    try:
        # a firmware in the loop has no bus: its profile's edge hook is ignored, and a $NODEID in it is
        # resolved with the built-in map's node so that a CAN bench's profile serves unchanged
        profile = bound_profile("canopen", str(profile_path) if profile_path else None, motor.pole_pairs,
                                node_id=SIL_NODE_ID)
    except ProfileError as exc:
        raise LinkError(f"{label}: profile {exc}") from None
    try:
        link = SilLink(library, profile, hang_s=spec.options["hang"], wrap_at_s=spec.options["wrap_at"],
                       label=f"{spec.kind.upper()} firmware {spec.options['path']}", kind=spec.kind, target=target)
    except SilInterfaceError as exc:
        raise LinkError(f"{label}: {exc}") from None
    link.build = how
    _drop_absent_defaults(link)
    if link.info.pole_pairs != motor.pole_pairs:
        link.close()
        raise LinkError(
            f"{label}: the firmware is configured for {link.info.pole_pairs} pole pairs "
            f"(hil_sil_describe), the plant has {motor.pole_pairs}"
        )
    return link


def _drop_absent_defaults(link) -> None:
    """The CiA 301 objects a CANopen profile assumes when it does not list them (identity,
    error register, heartbeat) are the firmware's only where its dictionary has them: one it answers
    with "object does not exist" (0x06020000) or "sub-index does not exist" (0x06090011) is an absent
    role, not a refusal (a heartbeat is a bus service a firmware in the loop need not keep)."""
    from dataclasses import replace

    absent = []
    for role, obj in link.profile.objects.items():
        if not obj.default or not obj.readable:
            continue
        for k in range(obj.count):
            answer = link.process.call("od_read", obj.index, obj.subindex_of(k), obj.size)
            if isinstance(answer, int) and (-answer) & 0xFFFFFFFF in (0x06020000, 0x06090011):
                absent.append(role)
                break
    if absent:
        link.profile = replace(link.profile, objects={r: o for r, o in link.profile.objects.items() if r not in absent})
