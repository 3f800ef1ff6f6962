"""The hil command and the pytest plugin, as a user meets them."""

import subprocess
import sys

from hil.cli import main


def test_hil_help_lists_subcommands(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    for sub in ("paper", "recording", "plant", "twin", "effects"):
        assert sub in out


def test_console_script_is_installed():
    out = subprocess.run([sys.executable, "-m", "hil", "--help"], capture_output=True, text=True, check=True).stdout
    assert "usage: hil" in out


def test_demo_prints_edge_errors_and_writes_a_valid_recording(tmp_path, capsys):
    assert main(["paper", "demo", "--duration-s", "0.1", "-o", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "A  rise    0" in out and "all edges" in out
    assert main(["recording", "check", str(tmp_path / "demo")]) == 0
    assert "samples yes (i_a, i_b, i_c, u_a, u_b, u_c, speed_rpm)" in capsys.readouterr().out


def test_bad_recording_exits_2_with_location(tmp_path, capsys):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "meta.json").write_text("{")
    assert main(["recording", "check", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "meta.json, line 1" in err


def test_bad_plant_toml_exits_2_naming_field(tmp_path, capsys):
    path = tmp_path / "p.toml"
    path.write_text('[[effects]]\nname = "warp_drive"\n')
    assert main(["plant", "check", str(path)]) == 2
    assert "effects[0].name" in capsys.readouterr().err


def test_plant_simulate_writes_recording(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["plant", "simulate", "--speeds-rpm", "1000", "4000", "--duration-s", "0.05", "--out", str(out)]) == 0
    assert main(["recording", "check", str(out)]) == 0
    assert "2 segments" in capsys.readouterr().out


def test_effects_listing_shows_units_and_bounds(capsys):
    assert main(["effects"]) == 0
    out = capsys.readouterr().out
    assert "installation_offset" in out and "deg_e" in out and "saturation" in out


def test_plugin_options_and_fixtures(pytester):
    """Loaded through the pytest11 entry point (no -p needed)."""
    pytester.makefile(".toml", plant='preset = "paper-bench"\n[[effects]]\nname = "hysteresis"\nlag_deg_e = 0.7\n')
    pytester.makepyfile(
        """
        import numpy as np
        from plant_models.kinematic import OperatingPoint

        def test_uses_plant(hil_plant_config, hil_seed, hil_kinematic):
            assert hil_seed == 17
            assert hil_plant_config.effect("hysteresis").lag_deg_e == 0.7
            e = hil_kinematic([OperatingPoint(0.05, 2000.0)])
            assert np.allclose(e.switch_error_deg_e, 0.7)
        """
    )
    result = pytester.runpytest("--hil-plant", "plant.toml", "--hil-seed", "17")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["hil: dut=virtual plant=plant.toml seed=17"])


def test_plugin_reads_ini_keys(pytester):
    pytester.makeini("[pytest]\nhil_seed = 5\n")
    pytester.makepyfile("def test_seed(hil_seed):\n    assert hil_seed == 5\n")
    pytester.runpytest().assert_outcomes(passed=1)


def test_effects_reference_in_docs_is_current():
    """docs/effects.md is generated from the library; a changed bound must regenerate it."""
    from pathlib import Path

    from hil.cli import effects_markdown

    doc = Path(__file__).resolve().parents[1] / "docs" / "effects.md"
    assert doc.read_text().strip() == effects_markdown().strip(), (
        "run: python -m hil effects --markdown > docs/effects.md"
    )
