"""What a new user's first mistakes print: one line naming the file and what is wrong."""

from pathlib import Path

from hil.cli import main

ROOT = Path(__file__).resolve().parent.parent


def test_unknown_preset_is_one_line_naming_file_and_known_presets(tmp_path, capsys):
    plant = tmp_path / "my_pump.toml"
    plant.write_text('preset = "nope"\n')
    assert main(["plant", "check", str(plant)]) == 2
    err = capsys.readouterr().err
    assert (
        err.strip()
        == f"hil: error: {plant}: preset: unknown preset 'nope' (known: paper-bench, paper-bench+deviations)"
    )


def test_gap_diagnose_of_something_else_says_it_is_not_a_recording(tmp_path, capsys):
    assert main(["gap", "diagnose", str(ROOT / "README.md")]) == 2
    err = capsys.readouterr().err
    assert "README.md: not a recording or a trace file" in err and len(err.strip().splitlines()) == 1
    assert main(["gap", "diagnose", str(tmp_path / "absent.csv")]) == 2
    assert "absent.csv: no such file or directory" in capsys.readouterr().err
