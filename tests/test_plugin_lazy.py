"""The pytest plugin costs nothing until a session uses it, reads its configuration once with types,
and refuses xdist against a real controller (docs/acceptance.md, "The pytest plugin")."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

# loaded before the in-process runs below (pytester drops modules a run imported, and numpy
# cannot be imported twice in one process)
import hil.bench.lockstep  # noqa: F401
import hil.dut.spec  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]

#: what loading the plugin must not import in a session that does not use it
HEAVY = ("numpy", "scipy", "numba", "plant_models", "hil.dut", "hil.verdicts.budgets", "hil.bench", "can", "canopen",
         "pymodbus", "sqlalchemy")

TRIVIAL = "def test_trivial():\n    assert 1 + 1 == 2\n"


def _this_checkout(monkeypatch):
    """Subprocesses import this checkout's code (not whichever one the package was installed from)."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))


def _run_and_list_modules(pytester, monkeypatch, *args):
    """pytest in a fresh interpreter; returns (result, output, heavy modules it loaded)."""
    _this_checkout(monkeypatch)
    script = ("import sys, pytest\n"
              f"code = pytest.main([*{list(args)!r}, '-p', 'no:cacheprovider'])\n"
              f"heavy = sorted(m for m in sys.modules if m.startswith({HEAVY!r}))\n"
              "print('HEAVY=' + repr(heavy))\n"
              "sys.exit(code)\n")
    result = pytester.run(sys.executable, "-c", script)
    out = result.stdout.str()
    heavy = eval(next(line for line in out.splitlines() if line.startswith("HEAVY="))[len("HEAVY="):])
    return result, out, heavy


def test_a_session_that_does_not_use_the_plugin_loads_nothing_heavy_and_prints_no_header(pytester, monkeypatch):
    pytester.makepyfile(test_plain=TRIVIAL)
    result, out, heavy = _run_and_list_modules(pytester, monkeypatch)
    assert result.ret == 0, out
    assert heavy == [], f"loaded by a session that never used the plugin: {heavy}"
    assert "hil: dut=" not in out


def test_a_session_that_requests_a_fixture_loads_the_plant_and_prints_the_header(pytester, monkeypatch):
    pytester.makepyfile(
        test_uses="def test_uses(hil_plant_config):\n    assert hil_plant_config.motor.pole_pairs > 0\n"
    )
    result, out, heavy = _run_and_list_modules(pytester, monkeypatch)
    assert result.ret == 0, out
    assert "plant_models" in heavy
    assert "hil: dut=virtual plant=paper-bench (preset) seed=0" in out


def test_a_requirement_marker_alone_makes_the_session_use_the_plugin(pytester, monkeypatch):
    pytester.makepyfile(test_req="import pytest\n\n@pytest.mark.requirement('REQ-X')\ndef test_req():\n    assert 1\n")
    result, out, _ = _run_and_list_modules(pytester, monkeypatch)
    assert result.ret == 0, out
    assert "hil: dut=virtual" in out


def test_ini_paths_are_relative_to_the_ini_file_and_the_seed_is_an_int(pytester, monkeypatch):
    (pytester.path / "conf").mkdir()
    (pytester.path / "conf" / "plant.toml").write_text(
        'preset = "paper-bench"\n[[effects]]\nname = "hysteresis"\nlag_deg_e = 0.7\n'
    )
    pytester.makeini("[pytest]\nhil_plant = conf/plant.toml\nhil_seed = 7\n")
    pytester.makepyfile(
        test_ini="def test_ini(hil_plant_config, hil_seed):\n"
        "    assert [e.name for e in hil_plant_config.effects] == ['hysteresis']\n"
        "    assert hil_seed == 7 and type(hil_seed) is int\n"
    )
    elsewhere = pytester.path / "sub"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the current directory is not where the paths are relative to
    result = pytester.runpytest(str(pytester.path / "test_ini.py"))
    result.assert_outcomes(passed=1)


def test_a_seed_that_is_not_an_integer_is_refused(pytester):
    pytester.makeini("[pytest]\nhil_seed = five\n")
    pytester.makepyfile(test_seed="def test_seed(hil_seed):\n    pass\n")
    result = pytester.runpytest()
    assert result.ret != 0
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*ini key hil_seed in*tox.ini*must be an integer*five*"])


def test_two_ini_paths_for_one_file_are_refused_naming_the_key(pytester):
    pytester.makeini("[pytest]\nhil_budgets = a.toml b.toml\n")
    pytester.makepyfile(test_b=TRIVIAL)
    result = pytester.runpytest()
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*hil_budgets*takes one path, got 2*"])


def test_xdist_against_a_real_controller_is_refused_in_one_line(pytester):
    pytester.makepyfile(test_n=TRIVIAL)
    result = pytester.runpytest("-n", "2", "--hil-dut", "modbus-tcp:host=127.0.0.1,port=1,unit=1")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    lines = [line for line in result.stderr.lines if "hil:" in line]
    assert len(lines) == 1 and "-n 2" in lines[0] and "modbus-tcp" in lines[0], result.stderr.str()


def test_xdist_against_the_virtual_controller_runs_and_records_the_worker(pytester, monkeypatch):
    _this_checkout(monkeypatch)
    pytester.makepyfile(
        test_w="import pytest\n\n@pytest.mark.parametrize('i', range(4))\ndef test_w(hil_seed, i):\n    pass\n"
    )
    result = pytester.runpytest_subprocess("-n", "2", "--hil-report-dir", "rep")
    result.assert_outcomes(passed=4)
    records = json.loads((pytester.path / "rep" / "hil-report.json").read_text())["tests"]
    assert sorted({r["worker"] for r in records}) == ["gw0", "gw1"]


def test_the_controller_is_reset_once_per_test_and_once_more_per_further_bench(pytester, monkeypatch):
    _this_checkout(monkeypatch)  # in a subprocess: the bench compiles numba code, which pytester could not unload
    pytester.makeconftest(
        "import pytest\n\n"
        "@pytest.fixture\n"
        "def resets(hil_dut, monkeypatch):\n"
        "    count = []\n"
        "    real = hil_dut.link.reset\n"
        "    monkeypatch.setattr(hil_dut.link, 'reset', lambda: (count.append(1), real())[1])\n"
        "    return count\n"
    )
    pytester.makepyfile(
        test_r=(
            "from bldc.contract import Strategy\n\n"
            "def test_one_bench(resets, hil_bench):\n"
            "    hil_bench(Strategy.RAW)\n"
            "    assert len(resets) == 1\n\n"
            "def test_two_benches(resets, hil_bench):\n"
            "    hil_bench(Strategy.RAW)\n"
            "    hil_bench(Strategy.RAW)\n"
            "    assert len(resets) == 2\n"
        )
    )
    pytester.runpytest_subprocess("--hil-dut", "virtual:in-process").assert_outcomes(passed=2)
