"""One controller interface for the framework; the acceptance suite never knows which one it has."""

from __future__ import annotations

import math
from typing import Protocol

from plant_models.simulation import Command

from ..calibration.corrections import Corrections
from ..predictors import FilterSettings
from .messages import TICK_S, commands_as_received, edge_as_received
from .virtual import CalibrationTableError, VirtualController


class LinkError(RuntimeError):
    """The controller misbehaved or refused a request; the message says what and where."""


class LinkTimeout(LinkError):
    """The controller did not answer within the link's timeout."""


class ControllerLink(Protocol):
    name: str
    #: where the controller is, for messages ("CANopen node 5 on virtual:hil")
    where: str

    def identity(self) -> dict: ...
    def reset(self) -> None: ...
    def download_calibration(self, corrections: Corrections) -> None: ...
    def set_filter_settings(self, settings: FilterSettings) -> None: ...
    def set_strategy(self, strategy: int) -> None: ...
    def set_speed(self, rpm: float) -> None: ...
    def edge(self, edge: dict) -> list[Command]: ...
    def status(self) -> dict: ...
    def close(self) -> None: ...


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


def filter_vector(settings: FilterSettings) -> list[float]:
    """The nine filter settings every link carries (CANopen 0x2020, Modbus 60-77), in order."""
    return [settings.forgetting_b, *settings.q0_diag, *settings.r0_diag, *settings.p0_diag]


def with_filter_vector(settings: FilterSettings, vector) -> FilterSettings:
    """``settings`` with b, Q0, R0 and P0 taken from the nine-value vector (validated)."""
    import dataclasses

    v = [float(x) for x in vector]
    new = dataclasses.replace(
        settings, forgetting_b=v[0], q0_diag=tuple(v[1:4]), r0_diag=tuple(v[4:6]), p0_diag=tuple(v[6:9])
    )
    new.check()
    return new


def edge_epoch(t_s: float) -> int:
    """Ticks of the capture timer's completed wraps at time t_s (both ends know the plant's
    time base, so a wrap of the 32-bit timer is undone the same way on every link)."""
    return (int(round(t_s / TICK_S)) >> 32) << 32


class InProcessLink:
    """The virtual controller called directly (no protocol): the reference for the other links."""

    name = "in-process"

    def __init__(self, controller: VirtualController):
        self.controller = controller
        self.where = "in-process virtual controller"

    def reset(self) -> None:
        """Clear the faults and restart the control logic (calibration and settings are kept)."""
        self.controller.clear_faults()
        self.controller.reset()

    def set_filter_settings(self, settings: FilterSettings) -> None:
        import numpy as np

        vector = [float(np.float32(v)) for v in filter_vector(settings)]  # IEEE single, as on every link
        try:
            self.controller.filter_settings = with_filter_vector(self.controller.filter_settings, vector)
        except ValueError as exc:
            raise LinkError(f"{self.where}: filter settings refused: {exc}") from None
        self.controller.reset()

    def identity(self) -> dict:
        i = self.controller.identity
        return {
            "vendor_id": i.vendor_id,
            "product_code": i.product_code,
            "revision": i.revision,
            "serial": i.serial,
            "device_type": i.device_type,
            "firmware": i.firmware,
        }

    def download_calibration(self, corrections: Corrections) -> None:
        table = corrections.as_float32()  # IEEE single precision, as on every link
        try:
            self.controller.download_calibration(table)
        except CalibrationTableError as exc:
            raise LinkError(f"{self.name}: controller refused the calibration table: {exc}") from None
        verify_calibration(table, self.controller.corrections)

    def set_speed(self, rpm: float) -> None:
        import numpy as np

        self.controller.set_speed(float(np.float32(rpm)))

    def set_strategy(self, strategy: int) -> None:
        self.controller.set_strategy(strategy)

    def edge(self, edge: dict) -> list[Command]:
        # quantised exactly as the 8-byte messages of the protocol links, so all links are
        # bit-identical, without building the bytes (messages.edge_as_received)
        epoch = edge_epoch(edge["t_capture_s"])
        commands = self.controller.capture(edge_as_received(edge, epoch))
        return commands_as_received(commands, epoch)

    def status(self) -> dict:
        return self.controller.status()

    def close(self) -> None:
        pass
