"""docs/firmware-in-the-loop.md, "Speed": the suite's run time through the reference firmware."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from ..model import ROOT, Figure, Group, Run
from .common import FIRMWARE, SUITE, inputs, with_checkout_on_path


def produce_sil_speed(work: Path) -> Run:
    """docs/firmware-in-the-loop.md, "Speed": the acceptance suite through the reference firmware
    beside in-process and CANopen in one run (``benchmarks/bench_sil.py``); run times, never held."""
    run = Run()
    out = work / "bench-sil.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_sil.py"), "--json", str(out)]
    run.commands.append("python benchmarks/bench_sil.py --json $WORK/bench-sil.json")
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=7200, env=with_checkout_on_path())
    if done.returncode != 0:
        raise RuntimeError(f"benchmarks/bench_sil.py exited {done.returncode}:\n{done.stderr[-2000:]}")
    result = json.loads(out.read_text())
    rows = [["DUT", "wall s", "CPU s", "wall / in-process", "verdict", "load before"]]
    for name, r in result["runs"].items():
        rows.append([name, f"{r['wall_s']:.0f}", f"{r['cpu_s']:.0f}", f"{r['wall_ratio_to_in_process']:.2f}",
                     r["verdict"], f"{r['load_before']:.1f}"])
    run.tables["runs"] = rows
    sil = result["runs"]["sil (reference firmware, C)"]
    run.figures["sil_over_in_process"] = Figure(sil["wall_ratio_to_in_process"], "", "{:.2f}", reproducible=False)
    run.figures["first_build_s"] = Figure(result["build"]["wall_s"], "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("sil_speed", "docs/firmware-in-the-loop.md: the suite's run time through the reference firmware", False,
          produce_sil_speed, inputs(__file__, *SUITE, *FIRMWARE, "benchmarks/bench_sil.py")),
)
