"""Firmware in the loop against its peers, in one run: the acceptance suite's wall and CPU time
through ``sil:firmware/reference`` beside ``virtual:in-process`` and ``virtual:canopen``.

``python benchmarks/bench_sil.py`` (goal: the SIL suite within 2x of in-process in the same run;
the first build of the firmware is timed apart, then every run takes the cached build). Each run is
one ``hil acceptance`` on 2 pytest-xdist workers; the figure is a ratio, never a pass/fail.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PEERS = {
    "in-process": "virtual:in-process",
    "canopen": "virtual:canopen",
    "sil (reference firmware, C)": "sil:firmware/reference",
}


def timed(cmd: list[str], env: dict | None = None) -> tuple[float, float, int]:
    """Wall time, CPU time of the command and its children, exit code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), code


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    cache = tempfile.mkdtemp(prefix="bench-sil-cache-")
    env = {**os.environ, "HIL_SIL_CACHE": cache}
    build_wall, build_cpu, _ = timed([sys.executable, "-m", "hil", "dut", "check", "--dut", PEERS[
        "sil (reference firmware, C)"]], env)
    print(f"first build and check of the reference firmware: {build_wall:.1f} s wall, {build_cpu:.1f} s CPU")
    rows = {}
    for name, dut in PEERS.items():
        reports = tempfile.mkdtemp(prefix="bench-sil-")
        load = os.getloadavg()[0]
        wall, cpu, code = timed([sys.executable, "-m", "hil", "acceptance", "--dut", dut, "--out", reports],
                                env)
        verdict = json.loads((Path(reports) / "hil-report.json").read_text()).get("verdict", "?") if (
            Path(reports) / "hil-report.json").is_file() else "no report"
        rows[name] = {"dut": dut, "wall_s": wall, "cpu_s": cpu, "exit": code, "verdict": verdict, "load_before": load}
        print(f"{name:<30} {wall:7.1f} s wall {cpu:7.1f} s CPU  verdict {verdict}  (load {load:.1f} before)")
    base = rows["in-process"]
    for name, row in rows.items():
        row["wall_ratio_to_in_process"] = row["wall_s"] / base["wall_s"]
        print(f"{name:<30} {row['wall_ratio_to_in_process']:.2f} x in-process (goal for sil: <= 2)")
    if args.json:
        Path(args.json).write_text(json.dumps({"build": {"wall_s": build_wall, "cpu_s": build_cpu}, "runs": rows},
                                              indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
