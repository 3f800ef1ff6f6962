"""The README tells the truth: its demo output is what ``hil paper demo`` prints, its ``hil`` commands
parse, the files, pictures and pages it names exist, its tour is one numbered sequence, and the
Python snippet it sends readers to (docs/plant.md) runs."""

import re
import shlex
from pathlib import Path

import pytest

from hil.cli import build_parser, main
from hil.cli_grammar import modernize

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def code_blocks(lang: str = "", text: str = README) -> list[str]:
    """The fenced blocks of ``text`` (the README) in language ``lang`` ("" for plain ones)."""
    return [body for tag, body in re.findall(r"^```(\w*)\n(.*?)^```", text, re.S | re.M) if tag == lang]


def test_demo_output_in_the_readme_is_what_hil_demo_prints(tmp_path, capsys):
    block = next(b for b in code_blocks() if b.startswith("paper-bench demo:"))
    assert main(["paper", "demo", "-o", str(tmp_path / "demo")]) == 0
    printed = capsys.readouterr().out.splitlines()
    shown = block.rstrip("\n").splitlines()
    assert printed[: len(shown)] == shown, (
        "README's demo output differs from `python -m hil paper demo`:\n" + "\n".join(printed[: len(shown)])
    )


def test_every_hil_command_in_the_readme_parses():
    commands = re.findall(r"python -m hil ([^`\n]*?)(?:`|\n|  +#)", README)
    assert len(commands) >= 12
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
                parser.parse_args(modernize(variant))  # a provenance line may keep an old spelling
            except SystemExit:
                pytest.fail(f"README: `python -m hil {' '.join(variant)}` is not a valid command")


def test_files_pictures_and_pages_named_in_the_readme_exist():
    named = set(re.findall(r"\((docs/img/[^)]+\.png)\)", README)) | set(re.findall(r"(examples/[\w./-]+\w)", README))
    assert {"docs/img/acceptance-report.png", "docs/img/demo-edge-errors.png"} <= named
    linked = set(re.findall(r"\]\(((?!https?:)[^)#]+)(?:#[^)]*)?\)", README))
    assert {"docs/acceptance.md", "docs/budgets.md", "docs/twin.md"} <= linked
    missing = [n for n in named | linked if not (ROOT / n).exists()]
    assert not missing, f"README names files that do not exist: {missing}"


def test_every_docs_page_is_in_the_readme_table():
    """The tour ends with a table of docs/ pages: a page missing from it is one no reader finds."""
    listed = set(re.findall(r"^\| \[(docs/[\w-]+\.md)\]", README, re.M))
    pages = {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}
    assert pages == listed, f"not in the README's table: {sorted(pages - listed)}; no page: {sorted(listed - pages)}"


def test_the_tour_is_one_numbered_sequence():
    tour = README.split("## A five-minute tour", 1)[1].split("\n## ", 1)[0]
    steps = [int(n) for n in re.findall(r"^\*\*(\d+)\. ", tour, re.M)]
    assert steps == list(range(1, len(steps) + 1)) and 4 <= len(steps) <= 7, steps


def test_the_plant_snippet_runs():
    """README's table sends readers to docs/plant.md for the Python API; its snippet runs."""
    block = next(b for b in code_blocks("python", (ROOT / "docs" / "plant.md").read_text()) if "Simulation" in b)
    namespace: dict = {}
    exec(compile(block, "docs/plant.md", "exec"), namespace)
    edges = namespace["edges"]
    assert len(edges.capture_error_deg_e) > 500 and namespace["samples"] is not None
