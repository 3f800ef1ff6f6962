"""What the simulator and the framework share, below both: the Hall conventions (``hall``), unit
conversions (``units``), the motor nameplate (``motor``), bounded configuration fields
(``params``), the controller ⇄ framework contract (``contract``) and why a figure is not given,
refused or bounded: numbered codes with their numbers, worded in one place (``reasons``).

``plant_models`` (the simulator) and ``hil`` (the framework, with its virtual controller) both
import this package; it imports neither (``docs/architecture.md``).
"""
