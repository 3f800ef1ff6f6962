"""hil.dut's files say what they hold, and the boundaries between them hold: a client link loads
no simulated device (no controller, no numba), and no face serves an object by its index."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DUT = ROOT / "hil" / "dut"


@pytest.mark.parametrize("link", ["hil.dut.canopen_link", "hil.dut.modbus_link"])
def test_a_client_link_loads_no_simulated_device(link):
    code = (f"import sys, {link}; print(sorted(m for m in sys.modules if m in ('numba', 'hil.controller.virtual', "
            "'hil.dut.canopen_device', 'hil.dut.modbus_device', 'hil.dut.virtual_roles', 'pymodbus.simulator')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_no_face_serves_an_object_by_its_index_or_address():
    """Every object reaches the controller through its role (hil.dut.virtual_roles): a chain of
    ``index == 0x2...`` (or ``address == ...``) tests would be a second copy of a profile."""
    chains = {
        path.name: re.findall(r"\b(?:index|subindex|address)\s*==\s*(?:0x[0-9A-Fa-f]+|\d+)", path.read_text())
        for path in DUT.glob("*.py")
    }
    assert not {name: found for name, found in chains.items() if found}
