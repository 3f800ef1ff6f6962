"""docs/firmware-in-the-loop.md: the reference firmware beside the built-in controller."""

from __future__ import annotations

import json
from pathlib import Path

from ..model import Figure, Group, Run
from .common import FIRMWARE, SUITE, inputs, run_tool


def produce_sil_reference(work: Path) -> Run:
    """docs/firmware-in-the-loop.md: the reference firmware (C, through ``sil:``) beside the built-in
    controller (in-process), per judged budget, on seeds 0 and 1 (``tools/sil_compare.py``)."""
    run = Run(seeds=[0, 1])
    out = work / "sil-compare.json"
    run_tool(run, "sil_compare.py", "--json", str(out), "--seeds", "0,1")
    result = json.loads(out.read_text())
    rows = [["requirement", "budget", "test", "built-in (Python)", "reference firmware (C)", "C - Python",
             "seed spread", "beyond it"]]
    for r in result["rows"]:
        rows.append([r["requirement"], f"`{r['budget']}`", f"`{r['test'].split('::')[-1]}`", f"{r['python']:.4g}",
                     f"{r['c']:.4g}", f"{r['difference']:+.3g}", f"{r['seed_spread']:.2g}",
                     "yes" if r["beyond_uncertainty"] else "no"])
    run.tables["budgets"] = rows
    run.figures["python_verdicts"] = Figure(result["verdicts"]["python"])
    run.figures["c_verdicts"] = Figure(result["verdicts"]["c"])
    run.figures["beyond"] = Figure(sum(r["beyond_uncertainty"] for r in result["rows"]), "", "{:d}",
                                   tolerance_abs=3)
    run.figures["compared"] = Figure(len(result["rows"]), "", "{:d}")
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("sil_reference", "docs/firmware-in-the-loop.md: the reference firmware beside the built-in controller",
          False, produce_sil_reference, inputs(__file__, *SUITE, *FIRMWARE, "tools/sil_compare.py")),
)
