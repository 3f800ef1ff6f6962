"""Lockstep throughput per link, run on demand: ``python benchmarks/bench_links.py``.

Commutations per second through the lockstep bench (plant + controller, Sage-Husa strategy,
6000 rpm) for the in-process link, CANopen on python-can's virtual bus (through notifier threads,
and inline as ``--dut virtual:canopen`` runs it: hil.dut.virtual_can), CANopen cross-process
(socketcand protocol on loopback) and Modbus TCP, with CAN's physical bound beside them: at
1 Mbit/s about 8,700 8-byte frames/s, and each edge takes at least two frames (RPDO in, TPDO
out), so at most about 4,350 edges/s. Goals: in-process >= 20,000/s, CANopen virtual >= 3,000/s,
Modbus TCP >= 2,000/s.
"""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
import time

from bldc.contract import Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import LockstepBench
from hil.calibration.campaign import CalibrationCampaign
from hil.calibration.fit import fit_corrections
from hil.controller.virtual import VirtualController
from hil.dut.canopen_device import CanopenDevice
from hil.dut.canopen_link import CanopenLink
from hil.dut.in_process import InProcessLink
from hil.dut.modbus_device import ModbusDevice
from hil.dut.modbus_link import ModbusLink
from plant_models import paper_bench

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
CONFIG = paper_bench(with_deviations=True)
CAN_FRAMES_PER_S = 8700  # 1 Mbit/s, 8-byte data frames with stuffing


def rate(link, corrections, hold_s):
    """Steady throughput: a short warm-up run first (numba cache loads, sockets and interpreter
    caches warm), then the measured run, both through the same link."""
    for run_s in (min(0.1, hold_s), hold_s):
        link.reset()
        link.download_calibration(corrections)
        b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
        t = time.perf_counter()
        b.run_setpoints([6000.0], hold_s=run_s, settle_s=0.0)
        wall = time.perf_counter() - t
    return b.source.edges / wall, len(b.sim.commutations()) / wall


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    corrections = fit_corrections(CalibrationCampaign().run(CONFIG, seed=0))
    rows = []
    rows.append(
        (
            "in-process",
            *rate(InProcessLink(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA)), corrections, 2.0),
            ">= 20,000",
        )
    )
    for inline, name in (
        (False, "CANopen, virtual bus, notifier threads"),
        (True, "CANopen, virtual bus, inline (--dut)"),
    ):
        channel = f"bench-{inline}"
        dev = CanopenDevice(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA), node_id=5, channel=channel,
                            inline=inline)
        link = CanopenLink(node_id=5, channel=channel, inline=inline)
        rows.append((name, *rate(link, corrections, 0.5), ">= 3,000"))
        link.close()
        dev.close()
    ports = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "hil", "dut", "serve", "--canopen-port", str(ports[0]),
                             "--modbus-port", str(ports[1]), "--preset", "paper-bench+deviations"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    while proc.stdout.readline().strip() != "ready":
        pass
    try:
        link = CanopenLink(interface="socketcand", channel="can0", host="127.0.0.1", port=ports[0], timeout_s=2.0)
        rows.append(("CANopen cross-process (socketcand protocol)", *rate(link, corrections, 0.2), "-"))
        link.close()
        link = ModbusLink(port=ports[1])
        rows.append(("Modbus TCP cross-process (hil dut serve)", *rate(link, corrections, 0.5), "-"))
        link.close()
    finally:
        proc.kill()
    mdev = ModbusDevice(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA))
    mlink = ModbusLink(port=mdev.port)
    rows.append(("Modbus TCP (loopback)", *rate(mlink, corrections, 0.5), ">= 2,000"))
    mlink.close()
    mdev.close()
    print(f"{'link':<44} {'edges/s':>10} {'commutations/s':>16}  goal (commutations/s)")
    for name, e, c, goal in rows:
        print(f"{name:<44} {e:>10,.0f} {c:>16,.0f}  {goal}")
    print(
        f"{'CAN 1 Mbit/s physical bound (2 frames/edge)':<44} {CAN_FRAMES_PER_S / 2:>10,.0f} "
        f"{CAN_FRAMES_PER_S / 2:>16,.0f}"
    )
    base = rows[0][2]
    print("ratios to in-process: " + ", ".join(f"{n}: {c / base:.2f}" for n, _, c, _ in rows[1:]))


if __name__ == "__main__":
    main()
