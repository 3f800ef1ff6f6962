"""``hil dut serve``: the virtual controller in its own process, on loopback by default.

CANopen: the device sits on an in-process python-can ``virtual`` channel, exposed to other
processes by a socketcand-protocol server (hil.dut.socketcand) bound to the given host
(127.0.0.1 unless asked); clients use python-can's own ``socketcand`` interface:
``CanopenLink(interface="socketcand", channel="can0", host="127.0.0.1", port=PORT)``.
Modbus: TCP on host:port. Never all interfaces unless asked (``--host 0.0.0.0``).
``--profile FILE`` serves the controller under a device profile (docs/device-profiles.md), so a
profile can be tried before the hardware exists.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import threading

from bldc.contract import Strategy
from plant_models import PRESETS

from ..controller.virtual import VirtualController
from .socketcand import SocketcandLimits


def serve(
    canopen_port: int | None,
    modbus_port: int | None,
    host: str = "127.0.0.1",
    node_id: int = 5,
    unit: int = 1,
    strategy: int = int(Strategy.SAGE_HUSA),
    preset: str = "paper-bench",
    stop: threading.Event | None = None,
    bus_name: str = "can0",
    limits: SocketcandLimits = SocketcandLimits(),
    idle_timeout_s: float | None = None,
    profile: str | None = None,
) -> None:
    """Serve until ``stop`` (or SIGINT / SIGTERM); ``profile``: a device profile the face of its
    protocol serves instead of the virtual controller's own map (the other face keeps its own)."""
    from .profile import load_profile

    protocol = load_profile(profile).protocol if profile else None
    controller = VirtualController(PRESETS[preset]().motor, strategy=Strategy(strategy))
    closers = []
    if idle_timeout_s is not None:
        limits = dataclasses.replace(limits, idle_timeout_s=idle_timeout_s)
    try:
        if canopen_port is not None:
            from .canopen_device import CanopenDevice
            from .socketcand import SocketcandServer

            channel = f"hil-dut-{id(controller)}"
            device = CanopenDevice(
                controller,
                node_id=node_id,
                interface="virtual",
                channel=channel,
                profile=profile if protocol == "canopen" else None,
            )
            closers.append(device.close)
            server = SocketcandServer(
                host, canopen_port, bus_name=bus_name, interface="virtual", channel=channel, limits=limits
            )
            closers.insert(0, server.close)
            print(
                f"CANopen node {node_id}: interface=socketcand channel={bus_name} host={host} port={server.port}",
                flush=True,
            )
        if modbus_port is not None:
            from .modbus_device import ModbusDevice

            mdev = ModbusDevice(
                controller,
                host=host,
                port=modbus_port,
                unit=unit,
                idle_timeout_s=limits.idle_timeout_s,
                profile=profile if protocol == "modbus" else None,
            )
            closers.append(mdev.close)
            print(f"Modbus TCP unit {unit}: {host}:{mdev.port}", flush=True)
        print("ready", flush=True)
        stop = stop or threading.Event()
        signalled = []
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: (signalled.append(True), stop.set()))
        stop.wait()
    finally:
        for close in closers:
            try:
                close()
            except Exception:  # pragma: no cover - best effort on the way out
                pass
        sys.stdout.flush()
    if signalled:
        # stopped by a signal: the process is ours and everything it served is closed above.
        # The interpreter's own finalization (tearing down numba, scipy, canopen, ... module by
        # module) would take another second on a busy machine, and a service manager waits for
        # it; nothing is left that needs it, so the streams are flushed and the process ends now.
        logging.shutdown()
        sys.stderr.flush()
        os._exit(0)
