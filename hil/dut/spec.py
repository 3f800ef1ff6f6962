"""Which controller a run talks to: ``--hil-dut`` specifications, parsed and opened.

A DUT is configuration (labgrid's idea): one string says where the controller is and how to
reach it, and ``open_dut`` gives the one ``ControllerLink`` the acceptance suite uses.

    virtual                      the built-in virtual controller over CANopen (python-can ``virtual``)
    virtual:canopen              the same, said explicitly
    virtual:modbus               the built-in virtual controller over Modbus TCP on 127.0.0.1
    virtual:in-process           the built-in virtual controller called directly (no protocol)
    canopen:interface=pcan,channel=PCAN_USBBUS1,node=5,bitrate=500000,eds=my.eds
    canopen:interface=socketcand,channel=can0,host=127.0.0.1,port=29536,node=5   (hil dut serve, or a socketcand daemon)
    modbus-tcp:host=192.168.0.10,port=502,unit=1
    modbus-rtu:port=/dev/ttyUSB0,baud=115200,unit=1
    modbus-tcp:host=192.168.0.10,profile=acme-p3.toml        (the device's own register map: docs/device-profiles.md)
    sil:firmware/reference                                   (C firmware in the loop: a folder with a sil.toml,
    sil:build/libpump.so,profile=pump.toml                    or a shared library; docs/firmware-in-the-loop.md)
    virtual:modbus,profile=acme-p3.toml                      (the virtual controller served under that map)

Every protocol form takes ``profile=FILE``, a device profile (``hil-device-profile/1``) mapping the
framework's roles to the device's objects; without one, the virtual controller's own map.
Every form takes ``timeout=SECONDS`` (default 1.0): a controller that stops answering fails
the test within it, naming the request.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field

from bldc.motor import MotorParameters

from .can_interfaces import unknown_can_interface

KINDS = ("virtual", "canopen", "modbus-tcp", "modbus-rtu", "sil")
VIRTUAL_TRANSPORTS = ("canopen", "modbus", "in-process")
#: keys each kind accepts, with a converter and a default (None: required)
_KEYS = {
    "virtual": {"timeout": (float, 1.0), "node": (int, 5), "unit": (int, 1), "profile": (str, "")},
    "canopen": {
        "interface": (str, None),
        "channel": (str, None),
        "node": (int, 5),
        "bitrate": (int, 0),
        "eds": (str, ""),
        "host": (str, ""),
        "port": (int, 0),
        "timeout": (float, 1.0),
        "profile": (str, ""),
    },
    "modbus-tcp": {
        "host": (str, None), "port": (int, 502), "unit": (int, 1), "timeout": (float, 1.0), "profile": (str, "")
    },
    "modbus-rtu": {
        "port": (str, None), "baud": (int, 115200), "unit": (int, 1), "timeout": (float, 1.0), "profile": (str, "")
    },
    # sil:PATH: the path comes first; hang: the wall time an interrupt may take; wrap_at: the
    # simulated instant of the timer's (first) wrap; define: extra -D NAME[=VALUE] for a folder's
    # build, joined by '+' (the seeded defects' switches); compiler: auto, system or ziglang
    "sil": {
        "path": (str, None), "profile": (str, ""), "timeout": (float, 1.0), "hang": (float, 1.0),
        "wrap_at": (float, 0.25), "define": (str, ""), "compiler": (str, "auto"),
    },
}
_channels = itertools.count()


class DutSpecError(ValueError):
    """A ``--hil-dut`` string that cannot be used; the message quotes it and names the part."""


@dataclass(frozen=True)
class DutSpec:
    kind: str
    transport: str = ""  #: virtual only: canopen, modbus or in-process
    options: dict = field(default_factory=dict)  #: the kind's keys, converted, defaults filled in
    text: str = "virtual"

    @property
    def is_virtual(self) -> bool:
        return self.kind == "virtual"

    @property
    def protocol(self) -> str:
        """``canopen``, ``modbus``, ``in-process`` or ``sil``: which conformance tests apply."""
        if self.is_virtual:
            return self.transport
        if self.kind == "sil":
            return "sil"
        return "canopen" if self.kind == "canopen" else "modbus"

    @property
    def id(self) -> str:
        """A short name for test ids and reports."""
        return f"virtual-{self.transport}" if self.is_virtual else self.kind


def parse_dut(text: str) -> DutSpec:
    text = (text or "virtual").strip()
    head, _, rest = text.partition(":")
    kind = head.strip().lower()
    if kind not in KINDS:
        raise DutSpecError(f"--hil-dut {text!r}: unknown kind {kind!r} (use one of {', '.join(KINDS)})")
    transport = ""
    if kind == "virtual":
        first, _, more = rest.partition(",")
        if first and "=" not in first:
            transport, rest = first.strip().lower(), more
        else:
            transport = "canopen"
        if transport not in VIRTUAL_TRANSPORTS:
            raise DutSpecError(
                f"--hil-dut {text!r}: unknown virtual transport {transport!r} (use one of "
                f"{', '.join(VIRTUAL_TRANSPORTS)})"
            )
    keys = _KEYS[kind]
    options = {}
    if kind == "sil":
        first, _, more = rest.partition(",")
        if first.strip() and "=" not in first:
            options["path"], rest = first.strip(), more
    for part in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = part.partition("=")
        key = key.strip().lower()
        if not eq:
            raise DutSpecError(f"--hil-dut {text!r}: {part!r} is not key=value")
        if key not in keys:
            raise DutSpecError(f"--hil-dut {text!r}: unknown key {key!r} for {kind} (known: {', '.join(keys)})")
        try:
            options[key] = keys[key][0](value.strip())
        except ValueError:
            raise DutSpecError(f"--hil-dut {text!r}: {key}={value!r} is not a valid {keys[key][0].__name__}") from None
    for key, (_, default) in keys.items():
        if key not in options:
            if default is None:
                raise DutSpecError(f"--hil-dut {text!r}: {kind} needs {key}=...")
            options[key] = default
    if not options["timeout"] > 0:
        raise DutSpecError(f"--hil-dut {text!r}: timeout must be positive")
    if kind == "canopen" and (why := unknown_can_interface(options["interface"])):
        raise DutSpecError(f"--hil-dut {text!r}: {why}")
    if kind == "sil":
        _check_sil(text, options)
    elif options["profile"]:
        _check_profile(text, kind, transport, options["profile"])
    if options.get("eds"):
        _check_eds(text, options["eds"])
    return DutSpec(kind, transport, options, text)


def _check_eds(text: str, path: str) -> None:
    """An EDS that cannot be read is refused before anything opens, naming its section and key."""
    from .eds import EdsError, read_eds

    try:
        read_eds(path)
    except EdsError as exc:
        raise DutSpecError(f"--hil-dut {text!r}: eds {exc}") from None


def _check_sil(text: str, options: dict) -> None:
    """A firmware path that is neither a shared library nor a folder with a readable sil.toml, a
    profile that cannot be read or is not in CANopen form, or a bad option is refused before
    anything is built."""
    from pathlib import Path

    path = Path(options["path"])
    if not path.exists():
        raise DutSpecError(f"--hil-dut {text!r}: {path}: no such file or folder")
    if path.is_dir():
        from ..sil.build import SilBuildError, read_build_spec
        from bldc.tomlfile import TomlError

        try:
            read_build_spec(path)
        except (SilBuildError, TomlError) as exc:
            raise DutSpecError(f"--hil-dut {text!r}: {exc}") from None
    elif options["define"]:
        raise DutSpecError(f"--hil-dut {text!r}: define= needs a firmware folder with a sil.toml, not a library")
    if not options["hang"] > 0:
        raise DutSpecError(f"--hil-dut {text!r}: hang must be positive (seconds of wall time)")
    if options["compiler"] not in ("auto", "system", "ziglang"):
        raise DutSpecError(f"--hil-dut {text!r}: compiler must be auto, system or ziglang")
    if options["profile"]:
        _check_profile(text, "sil", "", options["profile"])


def _check_profile(text: str, kind: str, transport: str, path: str) -> None:
    """A profile that cannot be read, or is for the other protocol, is refused before anything opens."""
    from bldc.tomlfile import TomlError

    from .profile import ProfileError, load_profile

    try:
        profile = load_profile(path)
    except (ProfileError, TomlError) as exc:
        raise DutSpecError(f"--hil-dut {text!r}: profile {exc}") from None
    # a firmware in the loop is described in its CANopen form (its object dictionary)
    protocol = transport if kind == "virtual" else ("canopen" if kind in ("canopen", "sil") else "modbus")
    if protocol == "in-process":
        raise DutSpecError(f"--hil-dut {text!r}: the in-process link has no object dictionary for a profile")
    if profile.protocol != protocol:
        raise DutSpecError(f"--hil-dut {text!r}: {path} is a {profile.protocol} profile, the DUT speaks {protocol}")


class Dut:
    """An opened controller: ``link`` for the suite; the virtual device's pieces are kept only to close them."""

    def __init__(self, spec: DutSpec, link, closers=()):
        self.spec, self.link, self._closers = spec, link, list(closers)

    @property
    def protocol(self) -> str:
        return self.spec.protocol

    def close(self) -> None:
        for close in [self.link.close, *self._closers]:
            try:
                close()
            except Exception:  # closing what already failed must not hide the failure
                pass

    def __enter__(self) -> "Dut":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_dut(spec: DutSpec | str, motor: MotorParameters, controller=None) -> Dut:
    """Open the controller; for ``virtual`` serve ``controller`` (default: the reference controller
    built for ``motor``)."""
    spec = parse_dut(spec) if isinstance(spec, str) else spec
    o = spec.options
    profile = {"profile": o["profile"] or None, "pole_pairs": motor.pole_pairs}
    if spec.kind == "canopen":
        from .canopen_link import CanopenLink

        bus = {k: o[k] for k in ("bitrate", "host", "port") if o[k]}
        return Dut(
            spec,
            CanopenLink(
                node_id=o["node"],
                interface=o["interface"],
                channel=o["channel"],
                eds=o["eds"] or None,
                timeout_s=o["timeout"],
                profile=o["profile"] or None,
                pole_pairs=motor.pole_pairs,
                **bus,
            ),
        )
    if spec.kind == "sil":
        from ..sil import open_sil

        return Dut(spec, open_sil(spec, motor))
    if spec.kind == "modbus-tcp":
        from .modbus_link import ModbusLink

        link = ModbusLink(host=o["host"], port=o["port"], unit=o["unit"], timeout_s=o["timeout"], **profile)
        return Dut(spec, link)
    if spec.kind == "modbus-rtu":
        from .modbus_link import ModbusLink

        link = ModbusLink(unit=o["unit"], timeout_s=o["timeout"], serial_port=o["port"], baudrate=o["baud"], **profile)
        return Dut(spec, link)
    from ..controller.virtual import VirtualController
    from .in_process import InProcessLink

    controller = controller if controller is not None else VirtualController(motor)
    if spec.transport == "in-process":
        return Dut(spec, InProcessLink(controller))
    if spec.transport == "canopen":
        from .canopen_device import CanopenDevice
        from .canopen_link import CanopenLink

        channel = f"hil-{os.getpid()}-{next(_channels)}"  # one bus per opened controller (and per xdist worker)
        # both ends in this process: each frame is taken in the thread that sends it (hil.dut.virtual_can)
        device = CanopenDevice(
            controller, node_id=o["node"], interface="virtual", channel=channel, profile=profile["profile"],
            inline=True,
        )
        return _served(
            spec,
            device,
            lambda: CanopenLink(
                node_id=o["node"], interface="virtual", channel=channel, timeout_s=o["timeout"], inline=True,
                **profile,
            ),
        )
    from .modbus_device import ModbusDevice
    from .modbus_link import ModbusLink

    device = ModbusDevice(controller, host="127.0.0.1", port=0, unit=o["unit"], profile=profile["profile"])
    return _served(
        spec,
        device,
        lambda: ModbusLink(host="127.0.0.1", port=device.port, unit=o["unit"], timeout_s=o["timeout"], **profile),
    )


def _served(spec: DutSpec, device, connect) -> Dut:
    """A virtual device and the link to it; the device is closed if the link cannot connect."""
    try:
        link = connect()
    except Exception:
        device.close()
        raise
    return Dut(spec, link, [device.close])
