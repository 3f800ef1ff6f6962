"""A controller that cannot be opened is one line, not a traceback or one error per test."""

import subprocess
import sys

import pytest

WRONG = "canopen:interface=nonexistent,channel=can0,node=5"


@pytest.mark.parametrize("argv", [
    ["-m", "hil", "acceptance", "--dut", WRONG],
    ["-m", "pytest", "-q", "-p", "no:cacheprovider", "test_cases", f"--hil-dut={WRONG}"],
], ids=["hil-acceptance", "pytest"])
def test_a_wrong_can_interface_is_one_line_naming_it_and_the_installed_ones(argv):
    out = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=120)
    lines = [line for line in (out.stdout + out.stderr).splitlines() if line.strip()]
    assert out.returncode != 0 and len(lines) <= 3 and "Traceback" not in out.stderr, lines
    assert any("'nonexistent'" in line and "socketcand" in line and "virtual" in line for line in lines), lines


def test_an_unreachable_socketcand_server_is_one_line():
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    spec = f"canopen:interface=socketcand,channel=can0,host=127.0.0.1,port={port},node=5,timeout=0.5"
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_cases", f"--hil-dut={spec}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    # a third-party plugin's own warning (pytest-benchmark's under xdist, with its source line) is not ours
    lines = [line for line in (out.stdout + out.stderr).splitlines()
             if line.strip() and "site-packages" not in line and "warner(" not in line]
    assert out.returncode == 3 and len(lines) <= 3 and "Traceback" not in out.stderr, lines
    assert any(f"cannot reach the socketcand server at 127.0.0.1:{port}" in line for line in lines), lines
