"""Reaching the device under test: the link interface (``link``), its implementations (in-process,
CANopen, Modbus), the virtual controller's protocol faces, and ``--dut`` specifications (``spec``).

Import the module you need; this package imports nothing, so ``hil.dut.link`` stays light.
"""
