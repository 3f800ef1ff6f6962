"""docs/qualify.md: ``hil qualify --sensitivity``, the sensitivity table."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from ..model import ROOT, Figure, Group, Run
from .common import SUITE, inputs


def produce_qualify(work: Path) -> Run:
    """docs/qualify.md: ``hil qualify --sensitivity`` (each defect on the tests of the requirements
    that name its class, no -x): the sensitivity table and the detection figure. The command exits
    1 when a defect survives; what it saw is published either way."""
    run = Run(seeds=[0])
    out = work / "qualify.json"
    args = ["qualify", "--sensitivity", "--json", str(out), "--report-dir", str(work / "qualify")]
    run.commands.append("python -m hil " + " ".join(a.replace(str(work), "$WORK") for a in args))
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "hil", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=4 * 3600)
    run.last_command_s = time.perf_counter() - t0
    if done.returncode not in (0, 1) or not out.is_file():
        raise RuntimeError(f"hil qualify exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    result = json.loads(out.read_text())
    d = result["detection"] or {"killed": None, "total": len(result["mutants"])}
    run.figures = {
        "control_verdict": Figure(result["control_verdict"], fmt="{}"),
        "caught": Figure(d["killed"], fmt="{}"),
        "defects": Figure(d["total"], fmt="{}"),
        "wall_s": Figure(run.last_command_s, "s", "{:.0f}", reproducible=False),
    }
    from hil.qualify.run import CATCH_LABELS, SENSITIVITY_COLUMNS, sensitivity_rows

    run.tables["sensitivity"] = [SENSITIVITY_COLUMNS] + sensitivity_rows(result)
    run.tables["outcomes"] = [["defect", "caught by", "what caught it", "requirements"]] + [
        [f"`{m['name']}`", m["caught_by"] or "survived",
         "; ".join(sorted({CATCH_LABELS.get(c["by"], c["by"]) for c in m["catches"]})) or "-",
         ", ".join(m["killed_by"]) or "-"] for m in result["mutants"]]
    return run


GROUPS = (
    Group("qualify", "docs/qualify.md: hil qualify --sensitivity, the sensitivity table", False, produce_qualify,
          inputs(__file__, *SUITE)),
)
