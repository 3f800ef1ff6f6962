"""Which controller a run talks to: ``--hil-dut`` specifications, parsed and opened.

A DUT is configuration (labgrid's idea): one string says where the controller is and how to
reach it, and ``open_dut`` gives the one ``ControllerLink`` the acceptance suite uses.

    virtual                      the built-in virtual controller over CANopen (python-can ``virtual``)
    virtual:modbus               the built-in virtual controller over Modbus TCP on 127.0.0.1
    canopen:interface=pcan,channel=PCAN_USBBUS1,node=5,bitrate=500000,eds=my.eds
    modbus-tcp:host=192.168.0.10,profile=acme-p3.toml        (the device's own register map: docs/device-profiles.md)
    sil:firmware/reference                                   (C firmware in the loop: docs/firmware-in-the-loop.md)
    pil:firmware/reference                                   (the same on an emulated Cortex-M core:
                                                              docs/processor-in-the-loop.md)

Each kind, its keys and how it opens is one declaration in ``hil.dut.kinds``.
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

from .kinds import KINDS as DECLARED
from .kinds import DutKind

KINDS = tuple(DECLARED)
VIRTUAL_TRANSPORTS = DECLARED["virtual"].transports
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
    def declaration(self) -> DutKind:
        """The kind's declaration (``hil.dut.kinds``)."""
        return DECLARED[self.kind]

    @property
    def is_virtual(self) -> bool:
        return self.kind == "virtual"

    @property
    def firmware(self) -> bool:
        """A firmware in the loop (sil:, pil:): its pins close the loop, its defects are a defects.toml."""
        return self.declaration.firmware

    @property
    def local(self) -> bool:
        """Opened once per xdist worker (a virtual controller or a firmware in its own process)."""
        return self.declaration.local

    @property
    def protocol(self) -> str:
        """``canopen``, ``modbus``, ``in-process`` or ``sil``: which conformance tests apply."""
        return self.declaration.protocol or self.transport

    @property
    def profile_form(self) -> str:
        """The form its device profile takes: ``canopen``, ``modbus`` (``in-process``: none)."""
        return self.declaration.profile_form or self.transport

    @property
    def id(self) -> str:
        """A short name for test ids and reports."""
        return f"virtual-{self.transport}" if self.is_virtual else self.kind


def parse_dut(text: str) -> DutSpec:
    text = (text or "virtual").strip()
    head, _, rest = text.partition(":")
    kind = head.strip().lower()
    if kind not in DECLARED:
        raise DutSpecError(f"--hil-dut {text!r}: unknown kind {kind!r} (use one of {', '.join(KINDS)})")
    declared = DECLARED[kind]
    transport = ""
    if declared.transports:
        first, _, more = rest.partition(",")
        if first and "=" not in first:
            transport, rest = first.strip().lower(), more
        else:
            transport = declared.transports[0]
        if transport not in declared.transports:
            raise DutSpecError(
                f"--hil-dut {text!r}: unknown {kind} transport {transport!r} (use one of "
                f"{', '.join(declared.transports)})"
            )
    keys = declared.keys
    options = {}
    if declared.path_first:
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
    spec = DutSpec(kind, transport, options, text)
    declared.validate(text, options)
    if options["profile"]:
        check_profile(text, spec.profile_form, options["profile"])
    if options.get("eds"):
        _check_eds(text, options["eds"])
    return spec


def check_canopen(text: str, options: dict) -> None:
    """An interface python-can does not know is refused before anything opens."""
    if why := unknown_can_interface(options["interface"]):
        raise DutSpecError(f"--hil-dut {text!r}: {why}")


def _check_eds(text: str, path: str) -> None:
    """An EDS that cannot be read is refused before anything opens, naming its section and key."""
    from .eds import EdsError, read_eds

    try:
        read_eds(path)
    except EdsError as exc:
        raise DutSpecError(f"--hil-dut {text!r}: eds {exc}") from None


def check_profile(text: str, protocol: str, path: str) -> None:
    """A profile that cannot be read, or is for the other protocol, is refused before anything opens."""
    from bldc.tomlfile import TomlError

    from .profile import ProfileError, load_profile

    try:
        profile = load_profile(path)
    except (ProfileError, TomlError) as exc:
        raise DutSpecError(f"--hil-dut {text!r}: profile {exc}") from None
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
    built for ``motor``). How each kind opens is its declaration's (``hil.dut.kinds``)."""
    spec = parse_dut(spec) if isinstance(spec, str) else spec
    return spec.declaration.open(spec, motor, controller)


def _profile_args(spec: DutSpec, motor: MotorParameters) -> dict:
    return {"profile": spec.options["profile"] or None, "pole_pairs": motor.pole_pairs}


def open_canopen(spec: DutSpec, motor: MotorParameters, controller=None) -> Dut:
    from .canopen_link import CanopenLink

    o = spec.options
    bus = {k: o[k] for k in ("bitrate", "host", "port") if o[k]}
    return Dut(spec, CanopenLink(node_id=o["node"], interface=o["interface"], channel=o["channel"],
                                 eds=o["eds"] or None, timeout_s=o["timeout"], **_profile_args(spec, motor), **bus))


def open_modbus(spec: DutSpec, motor: MotorParameters, controller=None) -> Dut:
    """modbus-tcp (host, port) or modbus-rtu (a serial port and its baud rate)."""
    from .modbus_link import ModbusLink

    o = spec.options
    where = {"host": o["host"], "port": o["port"]} if spec.kind == "modbus-tcp" else {
        "serial_port": o["port"], "baudrate": o["baud"]}
    return Dut(spec, ModbusLink(unit=o["unit"], timeout_s=o["timeout"], **where, **_profile_args(spec, motor)))


def open_virtual(spec: DutSpec, motor: MotorParameters, controller=None) -> Dut:
    """The built-in controller (or ``controller``), called in-process or served over its protocol
    in this process."""
    from ..controller.virtual import VirtualController
    from .in_process import InProcessLink

    o = spec.options
    profile = _profile_args(spec, motor)
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
