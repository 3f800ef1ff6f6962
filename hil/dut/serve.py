"""``hil dut serve``: the virtual controller in its own process, on loopback by default.

CANopen: the device sits on an in-process python-can ``virtual`` channel, exposed to other
processes by python-can-remote's server bound to the given host (127.0.0.1 unless asked);
clients connect with ``CanopenLink(interface="remote", channel="ws://127.0.0.1:PORT/")``.
Modbus: TCP on host:port. Never all interfaces unless asked (``--host 0.0.0.0``).
"""

from __future__ import annotations

import signal
import sys
import threading

from plant_models import PRESETS

from .virtual import Strategy, VirtualController


def serve(canopen_port: int | None, modbus_port: int | None, host: str = "127.0.0.1", node_id: int = 5, unit: int = 1,
          strategy: int = int(Strategy.SAGE_HUSA), preset: str = "paper-bench", stop: threading.Event | None = None) -> None:
    controller = VirtualController(PRESETS[preset]().motor, strategy=Strategy(strategy))
    closers = []
    if canopen_port is not None:
        from can_remote.server import RemoteServer

        from .canopen_face import CanopenDevice

        channel = f"hil-dut-{canopen_port}"
        device = CanopenDevice(controller, node_id=node_id, interface="virtual", channel=channel)
        server = RemoteServer(host, canopen_port, interface="virtual", channel=channel)
        threading.Thread(target=server.serve_forever, name="can-remote", daemon=True).start()
        closers += [server.shutdown, device.close]
        print(f"CANopen node {node_id}: interface=remote channel=ws://{host}:{canopen_port}/", flush=True)
    if modbus_port is not None:
        from .modbus_face import ModbusDevice

        mdev = ModbusDevice(controller, host=host, port=modbus_port, unit=unit)
        closers.append(mdev.close)
        print(f"Modbus TCP unit {unit}: {host}:{mdev.port}", flush=True)
    print("ready", flush=True)
    stop = stop or threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    for close in closers:
        try:
            close()
        except Exception:  # pragma: no cover - best effort on the way out
            pass
    sys.stdout.flush()
