"""The kinds of DUT a ``--dut`` / ``--hil-dut`` string names: one declaration each.

A kind says which keys its string takes (with their converters and defaults), whether a path or a
transport comes first, which protocol its conformance tests probe, which form its device profile
takes, how it opens (a function path, imported only when a DUT of that kind is opened: parsing
stays light), whether it is a firmware in the loop (its edges reach it through its own Hall pins,
its seeded defects are a ``defects.toml``, and each xdist worker opens its own instance) and what
``--help`` and docs/cli.md say of it. ``hil.dut.spec`` parses and opens every kind from this table
alone: a new kind is one more ``DutKind`` here.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from types import MappingProxyType
from typing import Any, Callable

#: a key: its converter from the string and its default (None: required)
Key = tuple[Callable[[str], Any], Any]


@dataclass(frozen=True)
class DutKind:
    name: str
    #: the keys its string takes, in the order ``--help`` lists them
    keys: MappingProxyType
    #: the protocol its conformance tests probe (``dut_protocol`` marks); "" for the virtual kind,
    #: whose protocol is its transport
    protocol: str
    #: the form of its device profile (``hil-device-profile/1``): canopen or modbus; "" for the
    #: virtual kind (its transport's)
    profile_form: str
    #: ``module:function(spec, motor, controller) -> Dut``, imported when a DUT of this kind opens
    opener: str
    #: one line for ``--help`` and docs/cli.md
    summary: str
    #: example strings, for the module docs and docs/cli.md
    forms: tuple[str, ...] = ()
    #: the first item is a path without ``path=`` (sil:firmware/reference)
    path_first: bool = False
    #: the first item names one of these transports (virtual:modbus); the first is the default
    transports: tuple[str, ...] = ()
    #: a firmware in the loop: edges through its own pins, seeded defects from its defects.toml
    firmware: bool = False
    #: opened once per xdist worker (a virtual controller, a firmware in a process of its own); a
    #: kind that is not local is one real device, which serves one session
    local: bool = False
    #: ``module:function(text, options)``: further checks of the options, raising DutSpecError
    check: str = ""
    #: a whole-suite run of this kind takes up to this many times a virtual controller's wall time:
    #: ``hil qualify``'s limit on one run (a safety net against a hung run, never a verdict on speed)
    #: scales with it
    run_time_factor: float = 1.0

    def open(self, spec, motor, controller=None):
        return _function(self.opener)(spec, motor, controller)

    def validate(self, text: str, options: dict) -> None:
        if self.check:
            _function(self.check)(text, options)


def _function(path: str):
    module, _, name = path.partition(":")
    return getattr(import_module(module), name)


def _keys(**keys: Key) -> MappingProxyType:
    return MappingProxyType(dict(keys))


_TIMEOUT: Key = (float, 1.0)
_PROFILE: Key = (str, "")
#: a firmware's keys, sil: and pil: alike. hang: the wall time a call into the firmware may take;
#: wrap_at: the simulated instant of the timer's (first) wrap; define: extra -D NAME[=VALUE] for a
#: folder's build, joined by '+' (the seeded defects' switches)
_FIRMWARE = dict(path=(str, None), profile=_PROFILE, timeout=_TIMEOUT, hang=(float, 1.0), wrap_at=(float, 0.25),
                 define=(str, ""))

_DECLARED = (
    DutKind(
        "virtual", _keys(timeout=_TIMEOUT, node=(int, 5), unit=(int, 1), profile=_PROFILE),
        protocol="", profile_form="", opener="hil.dut.spec:open_virtual",
        transports=("canopen", "modbus", "in-process"), local=True,
        summary="the built-in virtual controller: over CANopen (default), Modbus TCP on 127.0.0.1, or called "
                "in-process",
        forms=("virtual", "virtual:canopen", "virtual:modbus", "virtual:in-process",
               "virtual:modbus,profile=acme-p3.toml"),
    ),
    DutKind(
        "canopen",
        _keys(interface=(str, None), channel=(str, None), node=(int, 5), bitrate=(int, 0), eds=(str, ""),
              host=(str, ""), port=(int, 0), timeout=_TIMEOUT, profile=_PROFILE),
        protocol="canopen", profile_form="canopen", opener="hil.dut.spec:open_canopen",
        check="hil.dut.spec:check_canopen",
        summary="a CANopen node through python-can (or socketcand: hil dut serve)",
        forms=("canopen:interface=pcan,channel=PCAN_USBBUS1,node=5,bitrate=500000,eds=my.eds",
               "canopen:interface=socketcand,channel=can0,host=127.0.0.1,port=29536,node=5"),
    ),
    DutKind(
        "modbus-tcp", _keys(host=(str, None), port=(int, 502), unit=(int, 1), timeout=_TIMEOUT, profile=_PROFILE),
        protocol="modbus", profile_form="modbus", opener="hil.dut.spec:open_modbus",
        summary="a Modbus TCP server", forms=("modbus-tcp:host=192.168.0.10,port=502,unit=1",
                                              "modbus-tcp:host=192.168.0.10,profile=acme-p3.toml"),
    ),
    DutKind(
        "modbus-rtu", _keys(port=(str, None), baud=(int, 115200), unit=(int, 1), timeout=_TIMEOUT, profile=_PROFILE),
        protocol="modbus", profile_form="modbus", opener="hil.dut.spec:open_modbus",
        summary="a Modbus RTU slave on a serial port", forms=("modbus-rtu:port=/dev/ttyUSB0,baud=115200,unit=1",),
    ),
    DutKind(
        # compiler: auto, system or ziglang
        "sil", _keys(**_FIRMWARE, compiler=(str, "auto")),
        protocol="sil", profile_form="canopen", opener="hil.sil:open_dut", check="hil.sil:check_options",
        path_first=True, firmware=True, local=True,
        summary="C firmware in the loop, compiled for the PC: a folder with a sil.toml, or a shared library "
                "(docs/firmware-in-the-loop.md)",
        forms=("sil:firmware/reference", "sil:build/libpump.so,profile=pump.toml"),
    ),
    DutKind(
        # target: the [target] table's file, for an ELF linked elsewhere (a folder's is in its sil.toml)
        # hang: only a safety net of the process here (60 s of wall time): a call that runs past its
        # cycle budget is the core's hang (hil.pil.core.ProcessorHang), in simulated time, and naming
        # a fault reads the ELF's line table (seconds) before the finding comes back
        "pil", _keys(**{**_FIRMWARE, "hang": (float, 60.0)}, target=(str, "")),
        protocol="sil", profile_form="canopen", opener="hil.sil:open_dut", check="hil.sil:check_options",
        path_first=True, firmware=True, local=True,
        # an emulated core runs every instruction of the firmware: a suite run takes about 3x sil:'s wall
        # time (docs/processor-in-the-loop.md, "Speed"), which took about the virtual controller's; under
        # the former 1200 s the whole suite on pil: was stopped on a loaded 2-core host (INCOMPLETE)
        run_time_factor=4.0,
        summary="the same firmware built for its Cortex-M part and run on an emulated core: a folder whose "
                "sil.toml has a [target] table, or an ELF with target=FILE.toml (docs/processor-in-the-loop.md)",
        forms=("pil:firmware/reference", "pil:build/pump.elf,target=target.toml"),
    ),
)
#: every kind, by name, in the order ``--help`` lists them
KINDS = MappingProxyType({k.name: k for k in _DECLARED})


def kinds_help() -> str:
    """The kinds for a ``--dut`` help text: name and summary, one after the other."""
    return "; ".join(f"{k.name}:... {k.summary}" for k in _DECLARED if k.name != "virtual")


def firmware_kinds() -> tuple[str, ...]:
    return tuple(k.name for k in _DECLARED if k.firmware)
