"""The in-process link: the virtual controller called directly, the reference for the other links."""

from __future__ import annotations

import numpy as np

from bldc.contract import (
    CalibrationTableError,
    Command,
    commands_as_received,
    edge_as_received,
    edge_epoch,
    filter_vector,
    with_filter_vector,
)

from ..calibration.corrections import Corrections
from ..controller.virtual import VirtualController
from ..predictors import FilterSettings
from .link import LinkError, verify_calibration


class InProcessLink:
    """The virtual controller called directly (no protocol): the reference for the other links."""

    name = "in-process"

    def __init__(self, controller: VirtualController):
        self.controller = controller
        self.where = "in-process virtual controller"
        self.applied_calibration: Corrections | None = None

    def reset(self) -> None:
        """Clear the faults and restart the control logic (calibration and settings are kept)."""
        self.controller.clear_faults()
        self.controller.reset()

    def set_filter_settings(self, settings: FilterSettings) -> None:
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
        self.applied_calibration = self.controller.corrections

    def set_speed(self, rpm: float) -> None:
        self.controller.set_speed(float(np.float32(rpm)))

    def set_strategy(self, strategy: int) -> None:
        self.controller.set_strategy(strategy)

    def edge(self, edge: dict) -> list[Command]:
        # quantised exactly as the 8-byte messages of the protocol links, so all links are
        # bit-identical, without building the bytes (bldc.contract.edge_as_received)
        epoch = edge_epoch(edge["t_capture_s"])
        commands = self.controller.capture(edge_as_received(edge, epoch))
        return commands_as_received(commands, epoch)

    def status(self) -> dict:
        return self.controller.status()

    def close(self) -> None:
        pass
