"""Processor in the loop against its peers, in one run: the acceptance suite's wall and CPU time
through ``pil:firmware/reference`` (the emulated Cortex-M4F) beside ``sil:firmware/reference`` and
``virtual:in-process``.

``python benchmarks/bench_pil.py [--json FILE]`` (goal: the PIL suite within 3x of the SIL suite's
wall time in the same run; the first builds, the PC's and the part's, are timed apart, then every
run takes the cached build). Each run is one ``hil acceptance`` (seed 0) on its default pytest-xdist
workers; the figures are ratios, never a pass/fail. The machine's load is printed beside each.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from _against_base import PYTHON, ROOT, line, timed

PEERS = {
    "in-process": "virtual:in-process",
    "sil (reference firmware, PC)": "sil:firmware/reference",
    "pil (reference firmware, Cortex-M4F)": "pil:firmware/reference",
}
SIL, PIL = "sil (reference firmware, PC)", "pil (reference firmware, Cortex-M4F)"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    builds = {}
    for name in (SIL, PIL):  # each build apart (cached when built before): the runs then take the cached build
        builds[name] = timed([PYTHON, "-m", "hil", "dut", "check", "--dut", PEERS[name]], ROOT)
        print(line(f"build (cached when built before) and check, {name}", builds[name]), flush=True)
    rows = {}
    for name, dut in PEERS.items():
        reports = Path(tempfile.mkdtemp(prefix="bench-pil-"))
        r = timed([PYTHON, "-m", "hil", "acceptance", "--dut", dut, "--seed", "0", "--out", str(reports)], ROOT)
        report = reports / "hil-report.json"
        verdict = json.loads(report.read_text()).get("verdict", "?") if report.is_file() else "no report"
        rows[name] = {"dut": dut, "wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "exit": r["returncode"],
                      "verdict": verdict, "load": r["load"]}
        print(line(f"{name} (verdict {verdict})", r), flush=True)
    for name, row in rows.items():
        row["wall_over_in_process"] = row["wall_s"] / rows["in-process"]["wall_s"]
        row["wall_over_sil"] = row["wall_s"] / rows[SIL]["wall_s"]
        row["cpu_over_sil"] = row["cpu_s"] / rows[SIL]["cpu_s"]
    pil = rows[PIL]
    print(f"pil: {pil['wall_over_sil']:.2f} x the sil run's wall time, {pil['cpu_over_sil']:.2f} x its CPU time "
          f"(goal: wall <= 3); {pil['wall_over_in_process']:.2f} x in-process")
    if args.json:
        Path(args.json).write_text(json.dumps({"builds": {k: {"wall_s": v["wall_s"], "cpu_s": v["cpu_s"]}
                                                          for k, v in builds.items()}, "runs": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
