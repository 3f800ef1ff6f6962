"""The command line's one grammar (docs/cli.md): every shared option is added here, once, with its
one spelling, and every old spelling is kept for one release with one deprecation line on stderr.

This module sits in the architecture's layer 0, beside ``bldc``, and imports nothing heavy at the
top (no numpy, numba, scipy or plant): ``hil --help`` builds every parser from it and must stay
fast (tests/test_cli_grammar.py imports ``hil.cli`` in a fresh interpreter and checks what it
loaded). The preset names are repeated here as plain strings (the same test holds them equal to
``plant_models.PRESETS``); the strategy names are read from ``bldc.contract`` when a
``--strategy`` value is parsed, never listed here.
"""

from __future__ import annotations

import argparse
import sys

#: the built-in plants (``plant_models.PRESETS``; tests/test_cli_grammar.py holds them equal)
PRESET_NAMES = ("paper-bench", "paper-bench+deviations")
#: the one default of ``--preset``: the paper bench with the paper's deviations (the two presets
#: share the motor, so a command that only reads the motor, ``hil dut serve``, is unchanged by it)
DEFAULT_PRESET = "paper-bench+deviations"
#: how ``--help`` names the strategies (a sentence; the names themselves are ``bldc.contract``'s)
STRATEGY_HELP = "by name: raw, corrected, kf or sage_husa"

#: what a RECORDING argument accepts, the same in every command (``hil.recording.load.load_recording`` reads it)
RECORDING_HELP = "a hil-recording/1 directory, or a Hall capture file (VCD, sigrok .sr, CSV)"

#: commands that moved under a noun: old words -> new words (one release, then the old go)
MOVED_COMMANDS = {
    ("demo",): ("paper", "demo"),
    ("table5",): ("paper", "table5"),
    ("compare-correction",): ("paper", "compare-correction"),
    ("plant", "from-capture"): ("twin", "from-capture"),
}


def deprecated(old: str, new: str) -> None:
    """The one deprecation line: the old spelling, the new one, on stderr."""
    print(f"hil: deprecated: `{old}` is now `{new}` (the old spelling goes in the next release)", file=sys.stderr)


def modernize(argv: list[str]) -> list[str]:
    """``argv`` with a moved command's old words replaced by its new ones (and the line said)."""
    for old, new in MOVED_COMMANDS.items():
        if tuple(argv[: len(old)]) == old:
            deprecated("hil " + " ".join(old), "hil " + " ".join(new))
            return [*new, *argv[len(old):]]
    return list(argv)


class Deprecated(argparse.Action):
    """An old option spelling: stored where the new one stores, after one deprecation line. Hidden
    from ``--help``; ``convert`` maps an old value to the new option's meaning."""

    def __init__(self, option_strings, dest, new: str = "", convert=None, **kwargs):
        kwargs.setdefault("help", argparse.SUPPRESS)
        kwargs.setdefault("default", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)
        self.new = new
        self.convert = convert

    def __call__(self, parser, namespace, values, option_string=None):
        deprecated(option_string, self.new)
        setattr(namespace, self.dest, self.convert(values) if self.convert else values)


def add_deprecated(p, *old: str, dest: str, new: str, **kwargs) -> None:
    """Old spellings of the option ``new`` (stored in ``dest``); ``kwargs`` as ``add_argument``'s
    (``type``, ``nargs``) and ``convert`` (old value -> new meaning)."""
    p.add_argument(*old, dest=dest, action=Deprecated, new=new, **kwargs)


# ---------------------------------------------------------------- the shared options


def add_out(p, help: str, *, required: bool = False, default: str | None = None, metavar: str = "PATH") -> None:
    """``-o/--out PATH``: where the command writes its product (a file or a directory)."""
    p.add_argument("-o", "--out", required=required, default=default, metavar=metavar, help=help)


def add_json(p, what: str) -> None:
    """``--json PATH``: also write ``what`` as JSON; never required, no default path."""
    p.add_argument("--json", metavar="PATH", help=f"write {what} as JSON here")


def workers(text: str):
    """A ``--workers`` value: ``auto`` or a count (0: no worker processes)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a count (0: none) or auto") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: give a count (0: none) or auto")
    return n


def add_workers(p, help: str, *, default="auto") -> None:
    """``-j/--workers N|auto``: worker processes at once (auto: the command's own choice, per core)."""
    p.add_argument("-j", "--workers", type=workers, default=default, metavar="N|auto", help=help)


def add_progress(p) -> None:
    """``--progress/--no-progress``: progress on stderr, on by default."""
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="progress on stderr")


def strategy(text: str) -> str:
    """A ``--strategy`` value: a name of ``bldc.contract.STRATEGY_NAMES`` (``sage-husa`` reads as
    ``sage_husa``); the old integer codes for one release, with a deprecation line."""
    from bldc.contract import STRATEGY_NAMES, Strategy

    name = text.strip().lower().replace("-", "_")
    if name.isdigit() and int(name) in set(Strategy):
        new = Strategy(int(name)).name.lower()
        deprecated(f"--strategy {text}", f"--strategy {new}")
        return new
    if name not in STRATEGY_NAMES:
        raise argparse.ArgumentTypeError(f"unknown strategy {text!r} (known: {', '.join(STRATEGY_NAMES)})")
    return name


def add_strategy(p, help: str, *, default: str) -> None:
    """``--strategy NAME``: the controller's commutation strategy, by name."""
    p.add_argument("--strategy", type=strategy, default=default, metavar="NAME", help=f"{help}; {STRATEGY_HELP}")


def add_preset(p, help: str = "a built-in plant") -> None:
    """``--preset NAME``: a built-in plant, one default (``DEFAULT_PRESET``) in every command."""
    p.add_argument("--preset", default=DEFAULT_PRESET, choices=PRESET_NAMES, help=f"{help} (default: {DEFAULT_PRESET})")


def add_plant_source(p, plant_help: str = "plant TOML file") -> None:
    """``--plant TOML`` or ``--preset NAME``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--plant", metavar="TOML", help=plant_help)
    add_preset(g)


def add_history(p) -> None:
    """``--history URL``: the results history (docs/history.md): an SQLite file, ``sqlite:///PATH``,
    ``postgresql+psycopg://...`` or ``off``; default ``HIL_HISTORY``, else the user's own file."""
    p.add_argument("--history", metavar="URL", help="the results history: an SQLite file, sqlite:///PATH, "
                   "postgresql+psycopg://USER@HOST/DB or off (default: HIL_HISTORY, else the user's history.sqlite)")


def add_station(p) -> None:
    """``--station NAME``: the station's name in the results history (default: HIL_STATION, else the host)."""
    p.add_argument("--station", metavar="NAME", help="the station's name in the results history (default: "
                   "HIL_STATION, else the host name)")


def add_recording(p, extra: str = "", *, nargs=None) -> None:
    """The positional RECORDING: the same forms in every command (``hil.recording.load.load_recording``)."""
    p.add_argument("recording", metavar="RECORDING", nargs=nargs, help=RECORDING_HELP + (f"; {extra}" if extra else ""))


__all__ = [
    "DEFAULT_PRESET", "Deprecated", "MOVED_COMMANDS", "PRESET_NAMES", "RECORDING_HELP", "STRATEGY_HELP",
    "add_deprecated", "add_history", "add_json", "add_out", "add_plant_source", "add_preset", "add_progress",
    "add_recording", "add_station", "add_strategy", "add_workers", "deprecated", "modernize", "strategy", "workers",
]
