"""The command line's one grammar (docs/cli.md), held by walking every parser of ``hil``: one
spelling for output, workers, JSON, progress, strategy, presets and RECORDING; every old spelling
parses as its new one with one deprecation line; ``hil --help`` imports nothing heavy."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from bldc.contract import STRATEGY_NAMES
from hil import cli_grammar as grammar
from hil.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]

#: spellings the grammar replaced: never shown in a --help (they parse, hidden, for one release)
OLD_SPELLINGS = {"--output", "--jobs", "-n", "--report-dir", "--train-seed"}


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            yield from action.choices.items()


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("hil",)):
    """(command path, parser) for every parser of ``hil``, sub-CLIs (signals, twin) included."""
    yield path, parser
    for name, sub in _subparsers(parser):
        yield from walk(sub, (*path, name))


PARSERS = dict(walk(build_parser()))
COMMANDS = {path: p for path, p in PARSERS.items() if not any(True for _ in _subparsers(p))}


def _options(p: argparse.ArgumentParser):
    return [a for a in p._actions if a.option_strings and not isinstance(a, argparse._HelpAction)]


def test_the_walk_reaches_every_command():
    names = {" ".join(path) for path in COMMANDS}
    assert {"hil paper table5", "hil paper demo", "hil paper compare-correction", "hil twin from-capture",
            "hil twin check", "hil signals export", "hil acceptance", "hil gap validate"} <= names
    assert not {"hil table5", "hil demo", "hil compare-correction", "hil plant from-capture"} & names
    assert len(COMMANDS) >= 24


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=" ".join)
def test_every_option_follows_the_grammar(path):
    p = COMMANDS[path]
    where = " ".join(path)
    for a in _options(p):
        shown = a.help != argparse.SUPPRESS
        if not shown:  # a hidden option is an old spelling, nothing else
            assert isinstance(a, grammar.Deprecated), f"{where}: {a.option_strings} hidden but not deprecated"
            continue
        assert not set(a.option_strings) & OLD_SPELLINGS, f"{where}: {a.option_strings} is an old spelling"
        if "--out" in a.option_strings or "-o" in a.option_strings or a.dest == "out":
            assert a.option_strings == ["-o", "--out"] and a.dest == "out", f"{where}: output is -o/--out"
        if a.dest == "workers" or "-j" in a.option_strings:
            assert a.option_strings == ["-j", "--workers"] and a.type is grammar.workers, f"{where}: -j/--workers"
        if a.dest == "json":
            assert a.option_strings == ["--json"] and not a.required and a.default is None, f"{where}: --json PATH"
        if "progress" in a.dest:
            assert isinstance(a, argparse.BooleanOptionalAction) and a.option_strings == ["--progress",
                                                                                       "--no-progress"]
            assert a.default is True, f"{where}: progress is on by default"
        if a.dest == "strategy":
            assert a.type is grammar.strategy and a.default in STRATEGY_NAMES and a.metavar == "NAME", where
        if a.dest == "preset":
            assert a.default == grammar.DEFAULT_PRESET and tuple(a.choices) == grammar.PRESET_NAMES, where
        if a.dest == "plant":
            assert a.option_strings == ["--plant"] and a.metavar == "TOML", f"{where}: --plant TOML"
    for a in p._actions:
        if not a.option_strings and a.dest == "recording":
            assert a.metavar == "RECORDING" and a.help.startswith(grammar.RECORDING_HELP), f"{where}: RECORDING"


def test_one_spelling_means_one_thing_across_commands():
    """A long option shown by several commands stores to the same name with the same type."""
    seen: dict[str, tuple] = {}
    clashes = []
    for path, p in COMMANDS.items():
        for a in _options(p):
            if a.help == argparse.SUPPRESS:
                continue
            for opt in a.option_strings:
                key = (a.dest, getattr(a.type, "__name__", a.type), a.nargs)
                if opt in seen and seen[opt][0] != key:
                    clashes.append(f"{opt}: {' '.join(seen[opt][1])} {seen[opt][0]} vs {' '.join(path)} {key}")
                seen.setdefault(opt, (key, path))
    assert not clashes, clashes


#: (old spelling, new spelling, the new spelling as the deprecation line names it): each old one parses
#: to the same arguments as its new one, with one line on stderr naming the new
OLD_AND_NEW = [
    (["demo"], ["paper", "demo"], "hil paper demo"),
    (["table5", "--protocol", "paper"], ["paper", "table5", "--protocol", "paper"], "hil paper table5"),
    (["compare-correction", "--turns", "3"], ["paper", "compare-correction", "--turns", "3"],
     "hil paper compare-correction"),
    (["plant", "from-capture", "cap.vcd", "-o", "t.toml"], ["twin", "from-capture", "cap.vcd", "-o", "t.toml"],
     "hil twin from-capture"),
    (["paper", "table5", "--seed", "0", "3"], ["paper", "table5", "--seeds", "0", "3"], "--seeds"),
    (["paper", "table5", "--train-seed", "1"], ["paper", "table5", "--train-seeds", "1"], "--train-seeds"),
    (["dut", "profile", "--from-eds", "x.eds", "--output", "p.toml"],
     ["dut", "profile", "--from-eds", "x.eds", "-o", "p.toml"], "-o/--out"),
    (["acceptance", "-n", "0"], ["acceptance", "-j", "0"], "-j/--workers"),
    (["acceptance", "-n", "auto"], ["acceptance", "--workers", "auto"], "-j/--workers"),
    (["acceptance", "--report-dir", "r"], ["acceptance", "-o", "r"], "-o/--out"),
    (["qualify", "-n", "3"], ["qualify", "-j", "3"], "-j/--workers"),
    (["qualify", "--report-dir", "r"], ["qualify", "--out", "r"], "-o/--out"),
    (["gap", "validate", "--jobs", "1"], ["gap", "validate", "-j", "0"], "-j/--workers"),
    (["gap", "validate", "--jobs", "3"], ["gap", "validate", "-j", "3"], "-j/--workers"),
    (["dut", "serve", "--strategy", "2"], ["dut", "serve", "--strategy", "kf"], "--strategy kf"),
    (["signals", "loopback", "s", "-o", "g.vcd", "--strategy", "0"], ["signals", "loopback", "s", "-o", "g.vcd"],
     "--strategy raw"),
    (["signals", "export", "-o", "d", "--profile", "0:1000"],
     ["signals", "export", "-o", "d", "--speed-profile", "0:1000"], "--speed-profile"),
]


@pytest.mark.parametrize("old, new, named", OLD_AND_NEW, ids=[" ".join(o) for o, _, _ in OLD_AND_NEW])
def test_an_old_spelling_parses_as_the_new_one_with_one_deprecation_line(old, new, named, capsys):
    parser = build_parser()
    got_new = vars(parser.parse_args(grammar.modernize(new)))
    assert capsys.readouterr().err == ""
    got_old = vars(parser.parse_args(grammar.modernize(old)))
    err = capsys.readouterr().err.splitlines()
    assert got_old == got_new
    assert len(err) == 1 and err[0].startswith("hil: deprecated: "), err
    assert f"is now `{named}`" in err[0], err[0]


def test_strategy_names_and_the_old_codes():
    assert [grammar.strategy(s) for s in [*STRATEGY_NAMES, "sage-husa"]] == [*STRATEGY_NAMES, "sage_husa"]
    with pytest.raises(argparse.ArgumentTypeError, match="known: raw, corrected, kf, sage_husa"):
        grammar.strategy("5")


def test_the_names_repeated_in_the_grammar_equal_their_owners():
    from hil.signals.cli import HOLD_OFF_HELP_US
    from hil.signals.commutations import DEFAULT_HOLD_OFF_S
    from plant_models import PRESETS

    assert grammar.PRESET_NAMES == tuple(PRESETS)
    assert grammar.STRATEGY_HELP.endswith(", ".join(list(STRATEGY_NAMES)[:-1]) + " or " + list(STRATEGY_NAMES)[-1])
    assert HOLD_OFF_HELP_US == pytest.approx(DEFAULT_HOLD_OFF_S * 1e6)


def test_importing_the_cli_loads_nothing_heavy():
    """``hil --help`` builds every parser without the plant, numba, scipy or numpy (the time it
    takes is a figure: benchmarks/bench_cli_help.py)."""
    code = ("import sys, hil.cli; hil.cli.build_parser(); "
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numba', 'scipy', 'plant_models', 'numpy'))))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT, env=env)
    assert out.stdout.split() == [], f"importing hil.cli loads {out.stdout.split()}"


def test_every_command_is_in_docs_cli_md():
    doc = (ROOT / "docs" / "cli.md").read_text()
    missing = [" ".join(path) for path in COMMANDS if f"`{' '.join(path)}" not in doc]
    assert not missing, f"docs/cli.md does not list {missing}"


def _documented_commands():
    """Every ``python -m hil ...`` / ``hil ...`` command in README.md and docs/ (provenance lines aside:
    they record what was run at a commit)."""
    for path in [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "cli.md")]:
        for line in path.read_text().splitlines():
            if line.startswith("<sub>"):
                continue
            for m in re.finditer(r"(?:python -m hil|`hil) ([a-z][^`\n]*?)(?:`|$|  +#)", line):
                yield path.name, m.group(1)


def test_the_docs_show_no_old_spelling(capsys):
    parser = build_parser()
    old = []
    for name, command in _documented_commands():
        try:
            args = shlex.split(command.split("&&")[0].split("|")[0])
        except ValueError:
            continue
        try:
            parser.parse_args(grammar.modernize(args))
        except SystemExit:
            pass  # a placeholder (P, OUT) or a fragment: the README's own test parses its commands
        if "deprecated" in capsys.readouterr().err:
            old.append(f"{name}: hil {command}")
    assert not old, old


def test_twin_check_writes_json_only_when_asked(tmp_path, monkeypatch, capsys):
    """--json is never required: twin check without it prints the comparison and writes nothing."""
    import hil.twin.check as check
    import hil.twin.report as report

    class Checked:  # twin_check's typed result (TwinCheck): only its JSON is read here
        def to_json(self):
            return {"fake": True}

    monkeypatch.setattr(check, "twin_check", lambda *a, **k: Checked())
    monkeypatch.setattr(check, "format_check", lambda r: "compared")
    monkeypatch.setattr(report, "write_html", lambda *a: None)
    monkeypatch.chdir(tmp_path)
    assert main(["twin", "check", "cap.vcd", "twin.toml"]) == 0
    assert "compared" in capsys.readouterr().out and list(tmp_path.iterdir()) == []
    assert main(["twin", "check", "cap.vcd", "twin.toml", "--json", "c.json"]) == 0
    assert (tmp_path / "c.json").is_file()


#: the parsers outside ``hil`` (module, main): the same spellings, old ones hidden and named
SIDE_PARSERS = [("hil.dut.eds", "main"), ("hil.experiments.controller_tuning", "main"),
                ("hil.experiments.peers", "tuning_main")]


@pytest.mark.parametrize("module, main", SIDE_PARSERS, ids=[m for m, _ in SIDE_PARSERS])
def test_the_side_parsers_speak_the_grammar(module, main, capsys):
    import importlib

    with pytest.raises(SystemExit):
        getattr(importlib.import_module(module), main)(["--help"])
    shown = set(re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", capsys.readouterr().out))
    assert not shown & OLD_SPELLINGS, f"{module} shows {sorted(shown & OLD_SPELLINGS)}"
    assert not {"--seed", "--output"} & shown, f"{module} shows an old spelling"
