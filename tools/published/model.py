"""What a group of published figures is, and what its producer returns: the declarations the
engine (:mod:`published.engine`) and the producers (:mod:`published.producers`) share."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

#: the repository's root, where the producers run their commands and the engine finds the pages
ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Figure:
    """One published number. ``tolerance_abs``/``tolerance_rel``: how far a recomputation may drift
    before ``--quick`` calls it a change (the larger of the two applies); ``fmt``: how docs show it."""

    value: float | int | str | None
    unit: str = ""
    fmt: str = "{:.3g}"
    tolerance_abs: float = 0.0
    tolerance_rel: float = 0.0
    reproducible: bool = True  # False for run times: published with provenance, never held to a tolerance

    def text(self) -> str:
        if self.value is None:
            return "n/a"
        if isinstance(self.value, str):
            return self.value
        return self.fmt.format(self.value)

    def drift(self, recomputed: "Figure") -> str | None:
        """Why ``recomputed`` is not this figure within tolerance, or None."""
        a, b = self.value, recomputed.value
        if not self.reproducible:
            return None
        if isinstance(a, str) or isinstance(b, str) or a is None or b is None:
            return None if a == b else f"{a!r} -> {b!r}"
        bound = max(self.tolerance_abs, self.tolerance_rel * abs(a))
        if math.isfinite(a) and math.isfinite(b) and abs(b - a) <= bound:
            return None
        return f"{a:.6g} -> {b:.6g} (|change| {abs(b - a):.3g} > tolerance {bound:.3g} {self.unit})"

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items()}


@dataclass
class Run:
    """What a producer measured: its figures and how (the commands as a user types them, seeds)."""

    figures: dict[str, Figure] = field(default_factory=dict)
    commands: list[str] = field(default_factory=list)
    seeds: list[int] = field(default_factory=list)
    tables: dict[str, list[list[str]]] = field(default_factory=dict)
    blocks: dict[str, str] = field(default_factory=dict)  # a command's output as printed, shown verbatim
    last_command_s: float = 0.0  #: wall time of the last command run (``_hil``)


@dataclass(frozen=True)
class Group:
    """A set of figures computed together, declared once in its producer's module
    (``tools/published/producers/``). ``inputs``: globs of the tracked paths whose change can change
    its figures (``!glob`` leaves paths out), its producer's own file among them
    (:func:`published.producers.common.inputs`); ``--check`` recomputes the group when one of them
    changed since its provenance commit. ``quick``: recomputed by every CI run; ``rotation``: one of
    these is recomputed by each CI run, chosen by the commit (:func:`published.engine.rotation_group`):
    groups that take at most a minute with the plant compiled, so that the suite (about eight and a
    half minutes) stays within its ten (docs/architecture.md, "Published figures", names the others
    and what covers them)."""

    name: str
    what: str
    quick: bool
    produce: Callable[[Path], Run]
    inputs: tuple[str, ...]
    rotation: bool = False

