"""Firmware in the loop (hil.sil): the build, the interface checks, the peripherals' semantics and
the firmware's faults as findings, on the six-step test firmware (tests/data/sil/sixstep, C++17)
and a Python stand-in for the compare unit's timing."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from bldc.motor import MotorParameters, steady_state
from hil.bench.lockstep import LockstepBench
from hil.dut.link import LinkError
from hil.dut.spec import DutSpecError, open_dut, parse_dut
from hil.sil.build import SilBuildError, build, read_build_spec
from hil.sil.firmware import FirmwareInfo
from hil.sil.link import FirmwareFault
from hil.sil.peripherals import GATE_TABLE, SHOOT_THROUGH, Peripherals
from plant_models import PlantConfig
from plant_models import effects as fx
from plant_models.simulation import Simulation

SIXSTEP = Path(__file__).parent / "data" / "sil" / "sixstep"
REFERENCE = Path(__file__).parent.parent / "firmware" / "reference"


@pytest.fixture(scope="module", autouse=True)
def _cache(tmp_path_factory):
    """Each module run builds into its own cache (the user's stays untouched)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("HIL_SIL_CACHE", str(tmp_path_factory.mktemp("sil-cache")))
    yield
    mp.undo()


def bench(link, seconds: float, rpm: float = 6000.0, seed: int = 1, effects=()):
    config = PlantConfig().with_effects(*effects)
    b = LockstepBench(config, link, initial_speed_rpm=rpm, duty=steady_state(config.motor, rpm)["duty"], seed=seed,
                   sim_options={"max_step_s": 2e-6})
    b.sim.run_until(seconds)
    return b


def opened(text: str):
    return open_dut(parse_dut(text), MotorParameters())


# --- the build -----------------------------------------------------------------------------------
def test_a_folder_builds_once_and_again_only_when_a_source_or_setting_changes(tmp_path):
    folder = tmp_path / "fw"
    shutil.copytree(SIXSTEP, folder)
    spec = read_build_spec(folder)
    first = build(spec)
    again = build(spec)
    assert not first.cached and again.cached and again.library == first.library
    assert build(spec, (("SIXSTEP_HANG", ""),)).key != first.key  # an extra define is a setting
    source = folder / "src" / "sixstep.cc"
    source.write_text(source.read_text() + "\n// a changed source\n")
    assert build(read_build_spec(folder)).key != first.key


def test_a_bad_sil_toml_names_the_file_and_the_key(tmp_path):
    folder = tmp_path / "fw"
    shutil.copytree(SIXSTEP, folder)
    toml = folder / "sil.toml"
    toml.write_text(toml.read_text() + 'optimise = "yes"\n')
    with pytest.raises(DutSpecError, match=r"sil.toml: optimise: unknown key"):
        parse_dut(f"sil:{folder}")
    toml.write_text(toml.read_text().replace('optimise = "yes"\n', "").replace('"src/*.cc"', '"src/*.cpp"'))
    with pytest.raises(DutSpecError, match=r"sil.toml: sources: 'src/\*.cpp' matches no file"):
        parse_dut(f"sil:{folder}")


def test_a_compile_error_is_one_error_naming_the_file(tmp_path):
    folder = tmp_path / "fw"
    shutil.copytree(SIXSTEP, folder)
    (folder / "src" / "broken.cc").write_text("int broken( {\n")
    with pytest.raises(SilBuildError, match=r"compiling .*broken.cc failed"):
        build(read_build_spec(folder))


def test_the_pip_compiler_builds_the_firmware_without_a_system_compiler(tmp_path, monkeypatch):
    """README's commands work where only Python and pip are: Zig's clang from the ziglang wheel
    builds the reference firmware (C99; a C++ firmware builds the same way, after Zig has
    compiled its libc++ once, minutes on two cores, which this test does not spend), and the
    library it builds runs."""
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, c++, gcc or clang on PATH
    monkeypatch.delenv("HIL_SIL_CC", raising=False)
    from hil.sil import build as build_module

    build_module.toolchain.cache_clear()
    try:
        built = build(read_build_spec(REFERENCE), prefer="auto")
    finally:
        build_module.toolchain.cache_clear()
    assert "ziglang" in built.toolchain and built.library.is_file()
    monkeypatch.undo()
    with opened(f"sil:{REFERENCE},compiler=ziglang") as dut:
        assert dut.link.info.name.startswith("bldc-hil reference firmware")
        b = bench(dut.link, 0.05)
        assert b.sim.interrupts["control"] == 1000 and b.sim.interrupts["hall"] > 30


# --- the interface, checked before anything runs ---------------------------------------------------
@pytest.mark.parametrize("define, message", [
    ("SIXSTEP_MISSING_EXPORT", r"missing export hil_sil_gates"),
    ("SIXSTEP_WRONG_ABI", r"hil_sil_describe gave abi = 2: must be 1"),
])
def test_a_broken_interface_is_one_line_before_anything_runs(define, message):
    with pytest.raises(LinkError, match=message) as caught:
        opened(f"sil:{SIXSTEP},define={define}")
    assert "\n" not in str(caught.value)


def test_a_plant_of_other_pole_pairs_is_refused_in_one_line():
    with pytest.raises(LinkError, match=r"configured for 2 pole pairs .* the plant has 4"):
        open_dut(parse_dut(f"sil:{SIXSTEP}"), MotorParameters(pole_pairs=4))


# --- closed loop, judged from the gates --------------------------------------------------------------
def test_commutation_is_judged_from_the_gates_against_the_true_rotor_angle():
    """Raw six-step commutation on a plant whose sensor A sits 6 deg e late: the gates switch
    when the pins change, so every commutation A's edges cause is 6 deg e late on the true angle,
    the others on time (the plant's own record, not the firmware's word)."""
    with opened(f"sil:{SIXSTEP}") as dut:
        b = bench(dut.link, 0.2, effects=(fx.InstallationOffset((6.0, 0.0, 0.0)),))
        c = b.sim.commutations()
        err = c.error_deg_e[c.t_s > 0.05]
        assert err.size > 150
        late = np.abs(err - 6.0) < 0.2
        on_time = np.abs(err) < 0.2
        assert np.all(late | on_time)
        assert 0.25 < late.mean() < 0.42  # A's two edges of the six (one third), a few hundredths aside
        assert b.sim.interrupts["control"] == 4000  # 20 kHz for 0.2 s


def test_a_firmware_that_switches_in_its_pwm_interrupt_is_judged_from_its_gates():
    """A FOC-style firmware estimates the angle at each 20 kHz interrupt and switches when the
    estimate enters the next sector (or the next Hall edge says so): it reports no commutation
    instant, and its gates are late by up to one interrupt period, 3.6 deg e at 6000 rpm on 2 pole
    pairs (200 Hz electrical x 50 us x 360 deg), and early at most by what the estimate misses: the
    1 us capture tick (0.07 deg e) on each of the two edges it extrapolates from, and the speed loop's
    change over one sector."""
    with opened(f"sil:{SIXSTEP},define=SIXSTEP_ESTIMATED_ANGLE") as dut:
        b = bench(dut.link, 0.2)
        c = b.sim.commutations()
        err = c.error_deg_e[c.t_s > 0.05]
    period_deg = 360.0 * 200.0 * 50e-6
    assert err.size > 150
    assert err.min() > -0.2 and err.max() < period_deg + 0.2
    assert 0.3 * period_deg < err.mean() < 0.7 * period_deg  # the interrupt grid against the edges: uniform


def test_the_same_seed_gives_the_same_run_bit_for_bit():
    with opened(f"sil:{SIXSTEP}") as dut:
        first = bench(dut.link, 0.1, seed=3).sim.commutations()
        dut.link.reset()
        second = bench(dut.link, 0.1, seed=3).sim.commutations()
    assert np.array_equal(first.t_s, second.t_s) and np.array_equal(first.theta_e_deg, second.theta_e_deg)


# --- the firmware's faults: findings, not crashes of the run ----------------------------------------
def test_a_crash_in_an_interrupt_names_the_signal_the_event_and_the_counter_and_the_next_run_starts_afresh():
    with opened(f"sil:{SIXSTEP},define=SIXSTEP_CRASH") as dut:
        with pytest.raises(FirmwareFault, match=r"crashed with SIGSEGV in hil_sil_control_isr at t = 0\.25000"
                                                r"\d+ s \(counter \d+\)"):
            bench(dut.link, 0.5)
        dut.link.reset()  # a freshly loaded firmware: it runs again until its defect strikes again
        b = bench(dut.link, 0.2)
        assert b.sim.interrupts["control"] == 4000
        assert dut.link.process.starts == 2


def test_an_interrupt_that_does_not_return_is_a_hang_within_the_stated_wall_time():
    with opened(f"sil:{SIXSTEP},define=SIXSTEP_HANG,hang=0.3") as dut:
        with pytest.raises(FirmwareFault, match=r"hung: hil_sil_hall_isr at t = 0\.\d+ s \(counter \d+\) did not "
                                                r"return within 0\.3 s"):
            bench(dut.link, 0.5)


def test_shoot_through_is_refused_naming_the_leg():
    with opened(f"sil:{SIXSTEP},define=SIXSTEP_SHOOT_THROUGH") as dut:
        with pytest.raises(FirmwareFault, match=r"hil_sil_hall_isr at t = 0\.\d+ s \(counter \d+\): shoot-through: "
                                                r"both switches of leg A on"):
            bench(dut.link, 0.5)


def test_the_gate_table_refuses_every_leg_with_both_switches():
    for g in range(64):
        both = any((g >> 2 * x) & 3 == 3 for x in range(3))
        assert (GATE_TABLE[g] == SHOOT_THROUGH) == both


# --- the timer and the compare unit, as the specification states them -------------------------------
class _CompareFirmware:
    """A Python stand-in for a firmware's compare unit: arms ``arm(count_now)`` at each control
    interrupt until it fires once; records when its compare interrupt runs."""

    has_compare, has_emcy = True, False

    def __init__(self, arm):
        self.arm, self.armed, self.fired = arm, None, []
        self.adc = [0, 0, 0]

    def reset(self, levels):
        pass

    def gates(self):
        return 0

    def duty(self):
        return 0

    def control_isr(self, count, adc):
        if self.armed is None and not self.fired:
            self.armed = self.arm(count)

    def hall_isr(self, count, pin, levels, adc):
        pass

    def compare(self):
        return self.armed

    def compare_isr(self, count):
        self.fired.append(count)
        self.armed = None


def _periph(fw, wrap_at_s=0.0):
    info = FirmwareInfo(1, "stand-in", 1_000_000, 16, 20_000, 0.01, 2, True, False)
    sim = Simulation(PlantConfig(), _CompareFirmware, duty=0.0, initial_speed_rpm=1000.0, max_step_s=5e-6)
    return Peripherals(fw, info, sim, seed=0, wrap_at_s=wrap_at_s)


def test_a_compare_armed_ahead_fires_at_its_count():
    fw = _CompareFirmware(lambda now: (now + 30) & 0xFFFF)
    p = _periph(fw)
    p.run_until(0.001)
    assert fw.fired == [(p.count(50e-6) + 30) & 0xFFFF]


def test_a_compare_armed_at_the_counter_fires_one_wrap_later():
    fw = _CompareFirmware(lambda now: now)
    p = _periph(fw)
    p.run_until(0.05)
    assert fw.fired == []  # not within 2^16 ticks of 1 us
    p.run_until(0.07)
    assert fw.fired == [p.count(50e-6)]


def test_the_timer_wraps_inside_the_run():
    fw = _CompareFirmware(lambda now: None)
    p = _periph(fw, wrap_at_s=0.01)
    before, after = p.count(0.0099995), p.count(0.0100005)
    assert before > 0xFF00 and after < 0x100
    assert math.isclose(p.ticks(0.25), 250000)


# --- the firmware's own seeded defects (hil qualify --dut sil:DIR) ------------------------------------
def test_the_reference_firmwares_defects_are_switches_its_sources_know():
    from hil.qualify.run import firmware_defects

    defects = firmware_defects(f"sil:{REFERENCE}")
    assert len(defects) >= 8
    sources = "".join(p.read_text() for p in (REFERENCE / "src").glob("*.c"))
    sources += "".join(p.read_text() for p in (REFERENCE / "include").glob("*.h"))
    for d in defects.values():
        assert d.define.startswith("HIL_DEFECT_") and d.define in sources, d
        assert all(r.startswith("REQ-") for r in d.requirements), d
    firmware_only = {"HIL_DEFECT_TIMER_WRAP", "HIL_DEFECT_FLOAT_SECONDS", "HIL_DEFECT_LATE_COMPARE",
                     "HIL_DEFECT_TORN_TABLE"}
    assert firmware_only <= {d.define for d in defects.values()}


def test_a_bad_defects_file_names_the_table_and_the_key(tmp_path):
    from hil.qualify.run import firmware_defects

    folder = tmp_path / "fw"
    shutil.copytree(SIXSTEP, folder)
    (folder / "defects.toml").write_text('format = "bldc-hil-firmware-defects/1"\n[[defect]]\nname = "x"\n'
                                         'description = "y"\n')
    with pytest.raises(ValueError, match=r"defects.toml: \[\[defect\]\]\[0\]\.define: required"):
        firmware_defects(f"sil:{folder}")


def test_a_firmware_defect_has_an_optional_class_that_the_sensitivity_run_uses(tmp_path, monkeypatch):
    """defects.toml's optional ``class`` (a DEFECT_CLASSES key) is the defect's class: hil qualify
    --sensitivity builds it (define=) and runs the tests of the requirements naming its class, no -x."""
    import argparse

    from hil.qualify import run as qrun

    folder = tmp_path / "fw"
    shutil.copytree(SIXSTEP, folder)
    body = ('format = "bldc-hil-firmware-defects/1"\n[[defect]]\nname = "x"\ndefine = "HIL_DEFECT_X"\n'
            'description = "y"\n')
    (folder / "defects.toml").write_text(body + 'class = "speed-loop"\n')
    defects = qrun.firmware_defects(f"sil:{folder}")
    assert defects["x"].defect_class == "speed-loop"
    (folder / "defects.toml").write_text(body)
    assert qrun.firmware_defects(f"sil:{folder}")["x"].defect_class == ""
    (folder / "defects.toml").write_text(body + 'class = "no-such-class"\n')
    with pytest.raises(ValueError, match=r"defects.toml: \[\[defect\]\]\[0\]\.class"):
        qrun.firmware_defects(f"sil:{folder}")

    seen = []
    monkeypatch.setattr(qrun, "run_pytest", lambda cmd, timeout_s, env=None: seen.append(cmd) or (1, ""))
    args = argparse.Namespace(report_dir=str(tmp_path / "r"), dut=f"sil:{folder}", seed=0, budgets=None, defects=None,
                              suite=str(REFERENCE.parent.parent / "test_cases"), sensitivity=True,
                              firmware_defects={"x": qrun.FirmwareDefect("x", "HIL_DEFECT_X", "y", (), "speed-loop")})
    r = qrun._run("x", "y", "x", args)
    cmd = seen[0]
    assert r.defect_class == "speed-loop" and "-x" not in cmd and "--hil-defect" not in cmd
    assert cmd[cmd.index("--hil-dut") + 1] == f"sil:{folder},define=HIL_DEFECT_X"
    assert cmd[cmd.index("--hil-requirements") + 1] == "REQ-SPD-001"


def test_the_firmware_benchs_plant_offers_everything_the_suite_asks_of_a_bench_plant():
    """A bench with a firmware in the loop runs its plant in the firmware's process
    (``RemoteSimulation``): every ``bench.sim`` method or property the acceptance suite uses must be
    there too, or a test errors on a firmware alone (the load step's ``set_load_scale`` did)."""
    import re
    from pathlib import Path

    from hil.sil.link import RemoteSimulation

    root = Path(__file__).resolve().parents[1]
    sources = [*sorted((root / "test_cases").glob("*.py")), root / "hil" / "experiments" / "speed_step.py"]
    used = {name for path in sources for name in re.findall(r"\bbench\.sim\.([a-z_]+)", path.read_text())}
    assert {"run_until", "set_load_scale", "set_edge_jitter"} <= used  # the scan sees the suite
    # (t_s is an attribute each bench sets as its plant runs)
    missing = sorted(name for name in used if not hasattr(RemoteSimulation, name) and name != "t_s")
    assert not missing, f"RemoteSimulation lacks {missing}"
