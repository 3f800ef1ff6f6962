"""The controller link: the one interface through which the framework reaches a controller.

The acceptance suite never knows which implementation it has: ``hil.dut.in_process`` (the virtual
controller called directly), ``hil.dut.canopen_link`` or ``hil.dut.modbus_link``. This module
imports nothing heavy (no protocol stack, no controller, no numba), so a type annotation or an
``except LinkError`` costs nothing.
"""

from __future__ import annotations

import math
from typing import Protocol

from bldc.contract import Command, FilterSettingsVector

from ..calibration.corrections import Corrections


class LinkError(RuntimeError):
    """The controller misbehaved or refused a request; the message says what and where."""


class LinkTimeout(LinkError):
    """The controller did not answer within the link's timeout."""


class ControllerLink(Protocol):
    name: str
    #: where the controller is, for messages ("CANopen node 5 on virtual:hil")
    where: str
    #: the correction table the controller applies, as read back at the last download (None
    #: before one): the bench reads each edge's current at the edge's own instant with its delays
    applied_calibration: Corrections | None

    def identity(self) -> dict: ...
    def reset(self) -> None: ...
    def download_calibration(self, corrections: Corrections) -> None: ...
    def set_filter_settings(self, settings: FilterSettingsVector) -> None: ...
    def set_strategy(self, strategy: int) -> None: ...
    def set_speed(self, rpm: float) -> None: ...
    def edge(self, edge: dict) -> list[Command]: ...
    def status(self) -> dict: ...
    def close(self) -> None: ...


def link_has(link, *roles: str) -> bool:
    """Whether ``link``'s device profile maps every role (a link without a profile, the in-process
    one, has all of them)."""
    profile = getattr(link, "profile", None)
    return profile is None or all(profile.has(r) for r in roles)


def edge_hook_kind(link) -> str:
    """How edges reach ``link``'s controller: its profile's edge hook, or ``pins`` for a firmware in
    the loop (its interrupts see the plant's Hall pins; the profile's hook is ignored there)."""
    return "pins" if getattr(link, "edges_through_pins", False) else link.profile.edge_hook.kind


def verify_calibration(written: Corrections, read_back: Corrections, tolerance: dict[str, float] | None = None) -> None:
    """Compare a downloaded table with its read-back (within the link's declared scaling)."""
    tol = {"deg_e": 1e-9, "s": 1e-15, "deg_e_per_a": 1e-9, **(tolerance or {})}
    pairs = [
        (
            f"installation_offset_deg_e.{s}",
            written.installation_offset_deg_e[s],
            read_back.installation_offset_deg_e[s],
            tol["deg_e"],
        )
        for s in "ABC"
    ]
    pairs += [
        (f"pole_offset_deg_e[{j}]", a, b, tol["deg_e"])
        for j, (a, b) in enumerate(zip(written.pole_offset_deg_e, read_back.pole_offset_deg_e))
    ]
    pairs += [
        (f"conditioning_delay_s.{k}", written.conditioning_delay_s[k], read_back.conditioning_delay_s[k], tol["s"])
        for k in ("rise", "fall")
    ]
    pairs.append(
        (
            "armature_reaction_deg_e_per_a",
            written.armature_reaction_deg_e_per_a,
            read_back.armature_reaction_deg_e_per_a,
            tol["deg_e_per_a"],
        )
    )
    for name, a, b, t in pairs:
        if not (math.isfinite(b) and abs(a - b) <= t):
            raise LinkError(f"calibration read-back mismatch at {name}: wrote {a!r}, read {b!r} (tolerance {t})")
