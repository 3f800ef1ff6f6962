"""The device under test: the virtual controller and the links that reach a controller."""

from .link import ControllerLink, InProcessLink, LinkError, LinkTimeout
from .virtual import CalibrationTableError, Fault, Identity, Strategy, VirtualController

__all__ = [
    "ControllerLink",
    "InProcessLink",
    "LinkError",
    "LinkTimeout",
    "CalibrationTableError",
    "Fault",
    "Identity",
    "Strategy",
    "VirtualController",
]
