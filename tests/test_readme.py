"""The README tells the truth: its demo output is what ``hil demo`` prints, its ``hil`` commands
parse, the files and pictures it names exist, and its Python snippet runs."""

import re
import shlex
from pathlib import Path

import pytest

from hil.cli import build_parser, main

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def code_blocks(lang: str = "") -> list[str]:
    """The README's fenced blocks in language ``lang`` ("" for plain ones)."""
    return [body for tag, body in re.findall(r"^```(\w*)\n(.*?)^```", README, re.S | re.M) if tag == lang]


def test_demo_output_in_the_readme_is_what_hil_demo_prints(tmp_path, capsys):
    block = next(b for b in code_blocks() if b.startswith("paper-bench demo:"))
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    printed = capsys.readouterr().out.splitlines()
    shown = block.rstrip("\n").splitlines()
    assert printed[: len(shown)] == shown, "README's demo output differs from `python -m hil demo`:\n" + "\n".join(
        printed[: len(shown)]
    )


def test_every_hil_command_in_the_readme_parses():
    commands = re.findall(r"python -m hil ([^`\n]*?)(?:`|\n|  +#)", README)
    assert len(commands) >= 15
    parser = build_parser()
    for command in commands:
        args = shlex.split(command.split("&&")[0])
        # "a|b|c" in a command is a choice: each alternative must parse
        choices = next((i for i, a in enumerate(args) if "|" in a), None)
        variants = (
            [args]
            if choices is None
            else [args[:choices] + [alt] + args[choices + 1 :] for alt in args[choices].split("|")]
        )
        for variant in variants:
            try:
                parser.parse_args(variant)
            except SystemExit:
                pytest.fail(f"README: `python -m hil {' '.join(variant)}` is not a valid command")


def test_files_and_pictures_named_in_the_readme_exist():
    named = set(re.findall(r"\((docs/img/[^)]+\.png)\)", README)) | set(re.findall(r"(examples/[\w./-]+\w)", README))
    assert {
        "docs/img/acceptance-report.png",
        "docs/img/gap-report.png",
        "examples/my_pump.toml",
        "examples/budgets.toml",
    } <= named
    missing = [n for n in named if not (ROOT / n).exists()]
    assert not missing, f"README names files that do not exist: {missing}"


def test_the_python_snippet_runs():
    block = next(b for b in code_blocks("python") if "Simulation" in b)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    edges = namespace["edges"]
    assert len(edges.capture_error_deg_e) > 500 and namespace["samples"] is not None
