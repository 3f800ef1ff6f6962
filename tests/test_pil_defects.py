"""Defects only the part shows (issue 45, item 6): the reference firmware's four seeded defects of
the part are declared for ``pil:`` alone (defects.toml's ``kinds``); on the emulated core one of them
fails with a named processor fault, which the pytest plugin and ``hil qualify`` count as the part's
own failure, labelled by the fault; through ``sil:`` the same build runs on; and ``hil qualify`` on a
kind not meant to catch a defect shows it, never as a survivor and outside the detection figure."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from bldc.motor import MotorParameters, steady_state
from hil.qualify import run as qrun
from plant_models import PlantConfig

REFERENCE = Path(__file__).parent.parent / "firmware" / "reference"
PART_DEFECTS = {"time-product-overflow": "commutation-timing", "double-in-control-isr": "processor-time",
                "stack-hungry-isr": "processor-memory", "unaligned-64bit-access": "processor-memory"}


def test_the_defects_of_the_part_are_declared_for_pil_alone():
    defects = qrun.firmware_defects(f"pil:{REFERENCE}")
    sources = "".join(p.read_text() for p in (*(REFERENCE / "src").glob("*.c"), *(REFERENCE / "include").glob("*.h")))
    for name, defect_class in PART_DEFECTS.items():
        d = defects[name]
        assert d.kinds == ("pil",) and d.defect_class == defect_class and d.define in sources, d
        assert d.expected_on("pil") and not d.expected_on("sil")
    # every other defect is every kind's to catch
    assert all(d.kinds == () for n, d in defects.items() if n not in PART_DEFECTS)


def test_a_bad_kinds_list_names_the_table_and_the_key(tmp_path):
    (tmp_path / "defects.toml").write_text('format = "bldc-hil-firmware-defects/1"\n[[defect]]\nname = "x"\n'
                                           'define = "X"\ndescription = "y"\nkinds = ["arm"]\n')
    (tmp_path / "sil.toml").write_text('format = "hil-sil-build/1"\nsources = []\n')
    with pytest.raises(ValueError, match=r"defects.toml: \[\[defect\]\]\[0\]\.kinds: must be a list of DUT kinds"):
        qrun.firmware_defects(f"sil:{tmp_path}")


def _bench(dut: str):
    from hil.bench.lockstep import LockstepBench
    from hil.dut.spec import open_dut, parse_dut

    config = PlantConfig()
    duty = steady_state(config.motor, 6000.0)["duty"]
    opened = open_dut(parse_dut(dut), MotorParameters())
    return opened, lambda: LockstepBench(config, opened.link, initial_speed_rpm=6000.0, duty=duty, seed=1)


def test_the_unaligned_store_is_a_named_usage_fault_on_the_part_and_passes_on_the_pc():
    """The seeded int64_t store one byte into a record: on the emulated Cortex-M4F the first Hall
    interrupt takes a UsageFault (UNALIGNED) at its STRD, named with the function and the source line;
    the plugin calls it a device failure (the part's own) and qualify's catch is labelled by the fault.
    The same source built for the PC runs the same 20 ms without a word."""
    from hil.verdicts.judging import device_failure
    from hil.pytest_plugin import failure_kind
    from hil.sil.link import FirmwareFault

    define = "define=HIL_DEFECT_UNALIGNED_64BIT_ACCESS"
    opened, bench = _bench(f"pil:{REFERENCE},{define}")
    with opened:
        fault = (r"processor fault: UsageFault in ctl_hall_isr \(control\.c:\d+\) at pc 0x[0-9A-F]+: UNALIGNED: strd "
                 r"at address 0x[0-9A-F]*[1235679ABDEF] ")
        with pytest.raises(FirmwareFault, match=fault) as e:
            bench().sim.run_until(0.02)
    assert device_failure(e.value) and failure_kind(e.value) == "device failure"
    report = {"tests": [{"nodeid": "test_cases/test_processor.py::t[pil]", "outcome": "failed",
                         "failed_by": "device failure", "message": f"{type(e.value).__name__}: {e.value}",
                         "requirements": ["REQ-PIL-003"], "measurements": []}]}
    caught_by, killed_by, _, catches = qrun.what_caught(report)
    assert caught_by == "processor fault" and killed_by == ["REQ-PIL-003"]
    assert catches[0]["by"].startswith("processor fault UsageFault in ctl_hall_isr (control.c:")

    opened, bench = _bench(f"sil:{REFERENCE},{define}")
    with opened:
        b = bench()
        b.sim.run_until(0.02)
        assert b.sim.interrupts["hall"] > 0  # the store ran, on a PC it just works


def _mutant(name: str, killed: bool, expected: bool = True) -> qrun.Run:
    return qrun.Run(name, "d", "FAIL" if killed else "PASS", killed, "budget" if killed else None,
                    ["REQ-PIL-002"] if killed else [], defect_class="processor-time", kinds=[] if expected else ["pil"],
                    expected=expected)


def test_a_defect_another_kind_must_catch_is_shown_never_a_survivor_nor_in_the_detection_figure(tmp_path,
                                                                                              monkeypatch):
    q = qrun.Qualification("sil:fw", 0, {}, qrun.Run("control", "c", "PASS", False),
                           [_mutant("caught", True), _mutant("missed", False), _mutant("of-the-part", False, False)],
                           1.0)
    assert q.survivors == ["missed"] and q.detection_ratio == 0.5 and [m.name for m in q.by_design] == ["of-the-part"]
    out = q.to_json()
    assert out["detection"]["total"] == 2 and out["not_this_kind"]["of-the-part"]["verdict"] == "PASS"
    rows = [r for r in qrun.sensitivity_rows(out) if r[0] == "`of-the-part`"]
    assert rows and all(r[4].startswith("not caught here by design (a defect pil: catches)") for r in rows)

    # on sil: the defect runs the whole suite with -x, even under --sensitivity
    seen = []
    monkeypatch.setattr(qrun, "run_pytest", lambda cmd, timeout_s, env=None: seen.append(cmd) or (1, ""))
    args = argparse.Namespace(report_dir=str(tmp_path), dut=f"sil:{REFERENCE}", seed=0, budgets=None, defects=None,
                              suite=str(REFERENCE.parent.parent / "test_cases"), sensitivity=True,
                              firmware_defects=qrun.firmware_defects(f"sil:{REFERENCE}"))
    r = qrun._run("double-in-control-isr", "d", "double-in-control-isr", args)
    assert not r.expected and r.kinds == ["pil"]
    assert "--hil-stop-at-catch" in seen[0] and "--hil-requirements" not in seen[0]
    args.dut = f"pil:{REFERENCE}"
    r = qrun._run("double-in-control-isr", "d", "double-in-control-isr", args)
    assert r.expected and seen[1][seen[1].index("--hil-requirements") + 1] == "REQ-PIL-001,REQ-PIL-002"
