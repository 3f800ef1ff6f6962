"""The virtual controller in its own process (``hil dut serve``): CANopen over the socketcand protocol and
Modbus TCP on loopback give the same commutations as in-process; a killed controller is a precise
error within the timeout, never a hang."""

import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from bldc.contract import Strategy
from bldc.motor import steady_state
from hil.bench.lockstep import LockstepBench
from hil.calibration.campaign import station_corrections
from hil.controller.virtual import VirtualController
from hil.dut.canopen_link import CanopenLink
from hil.dut.in_process import InProcessLink
from hil.dut.link import LinkError, LinkTimeout
from hil.dut.modbus_link import ModbusLink
from plant_models import paper_bench

CONFIG = paper_bench(with_deviations=True)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def server():
    ports = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "hil", "dut", "serve", "--canopen-port", str(ports[0]),
                             "--modbus-port", str(ports[1]), "--preset", "paper-bench+deviations"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + 60
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.strip() == "ready":
            break
    else:
        proc.kill()
        pytest.fail(f"hil dut serve did not start: {lines}")
    yield proc, ports
    proc.kill()
    proc.wait(timeout=10)
    proc.stdout.close()


@pytest.fixture(scope="module")
def corrections():
    return station_corrections(CONFIG, seed=0)


def commutations(link, corrections, hold_s=0.05):
    link.download_calibration(corrections)
    b = LockstepBench(CONFIG, link, initial_speed_rpm=6000.0, duty=steady_state(CONFIG.motor, 6000.0)["duty"])
    b.run_setpoints([6000.0], hold_s=hold_s, settle_s=0.02)
    return b.sim.commutations()


def test_cross_process_links_match_in_process(server, corrections):
    proc, (co_port, mb_port) = server
    reference = commutations(InProcessLink(VirtualController(CONFIG.motor, strategy=Strategy.SAGE_HUSA)), corrections)
    for link in (
        CanopenLink(interface="socketcand", channel="can0", host="127.0.0.1", port=co_port, timeout_s=2.0),
        ModbusLink(port=mb_port, timeout_s=2.0),
    ):
        link.set_strategy(int(Strategy.SAGE_HUSA))  # a fresh controller state for each link
        c = commutations(link, corrections)
        np.testing.assert_array_equal(c.t_s, reference.t_s)
        np.testing.assert_array_equal(c.sector, reference.sector)
        link.close()


def test_killing_the_controller_process_gives_a_precise_error(server, corrections):
    """Every request after the kill fails with LinkError or LinkTimeout naming the node or unit
    and the request, within the timeout: never a raw transport exception, never a hang."""
    proc, (co_port, mb_port) = server
    co = CanopenLink(interface="socketcand", channel="can0", host="127.0.0.1", port=co_port, timeout_s=0.5)
    mb = ModbusLink(port=mb_port, timeout_s=0.5)
    assert co.identity()["firmware"] == "vc-0.1.0" and mb.identity()["serial"] == 1
    proc.kill()
    proc.wait(timeout=10)
    edge = {"t_capture_s": 0.001, "sensor": 0, "rising": True, "current_a": 1.0}
    requests = [
        (lambda link: link.edge(edge), r"edge #\d+"),
        (lambda link: link.identity(), r"read"),
        (lambda link: link.set_speed(3000.0), r"write"),
        (lambda link: link.set_strategy(2), r"write"),
        (lambda link: link.status(), r"read"),
        (lambda link: link.reset(), r"(NMT reset node|write 1 registers at 31)"),
        (lambda link: link.download_calibration(corrections), r"write"),
        (lambda link: link.edge(edge), r"edge #\d+"),
    ]
    failures = 0
    for link, where in (
        (co, r"CANopen node 5 on socketcand:can0@127.0.0.1:\d+"),
        (mb, r"Modbus unit 1 at 127.0.0.1:\d+"),
    ):
        for call, what in requests:
            t = time.monotonic()
            with pytest.raises((LinkTimeout, LinkError), match=f"^{where}: .*{what}"):
                call(link)
            assert time.monotonic() - t < 3.0
            failures += 1
        link.close()
    assert failures == 2 * len(requests)
