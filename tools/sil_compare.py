"""The reference firmware's figures beside the built-in controller's, per budget, in one table.

    python tools/sil_compare.py                 # runs both suites (seeds 0 and 1 each), prints the table
    python tools/sil_compare.py --json out.json

Each controller runs the acceptance suite twice, on seeds 0 and 1 (``hil acceptance --seed``),
the built-in one in-process and the firmware through ``sil:firmware/reference``. A figure's
uncertainty is taken as the larger of the two controllers' seed-to-seed spreads (half the
difference of its two seeds); a difference of the seed means beyond it is marked for explanation
(docs/firmware-in-the-loop.md, "The reference firmware against the built-in controller").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DUTS = {"python": "virtual:in-process", "c": "sil:firmware/reference"}


def run(dut: str, seed: int) -> dict:
    reports = Path(tempfile.mkdtemp(prefix="sil-compare-"))
    subprocess.run([sys.executable, "-m", "hil", "acceptance", "--dut", dut, "--seed", str(seed), "--out",
                    str(reports)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return json.loads((reports / "hil-report.json").read_text())


def figures(report: dict) -> dict[tuple[str, str, str], float]:
    """(requirement, budget, test without its DUT id) -> measured, for every judged budget."""
    out = {}
    for t in report["tests"]:
        node = t["nodeid"].replace("[virtual-in-process-", "[").replace("[sil-", "[")
        node = node.replace("[virtual-in-process]", "").replace("[sil]", "")
        for m in t["measurements"]:
            out[(m["requirement"], m["budget"], node)] = float(m["measured"])
    return out


def table(runs: dict[str, list[dict]]) -> tuple[list[dict], dict[str, str]]:
    per = {k: [figures(r) for r in reports] for k, reports in runs.items()}
    keys = sorted(set().union(*(set(f) for fs in per.values() for f in fs)))
    rows = []
    for key in keys:
        vals = {k: [f[key] for f in fs if key in f] for k, fs in per.items()}
        if not all(vals.values()):
            continue
        mean = {k: sum(v) / len(v) for k, v in vals.items()}
        spread = max((max(v) - min(v)) / 2 for v in vals.values())
        diff = mean["c"] - mean["python"]
        rows.append({"requirement": key[0], "budget": key[1], "test": key[2], "python": mean["python"],
                     "c": mean["c"], "difference": diff, "seed_spread": spread,
                     "beyond_uncertainty": abs(diff) > max(spread, 1e-12)})
    verdicts = {k: ", ".join(r["verdict"] for r in reports) for k, reports in runs.items()}
    return rows, verdicts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json")
    parser.add_argument("--seeds", default="0,1")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    runs = defaultdict(list)
    for name, dut in DUTS.items():
        for seed in seeds:
            runs[name].append(run(dut, seed))
    rows, verdicts = table(runs)
    print(f"verdicts: built-in (Python) {verdicts['python']}; reference firmware (C) {verdicts['c']}")
    print("| requirement | budget | test | built-in (Python) | reference firmware (C) | C - Python | seed spread |")
    print("|---|---|---|---:|---:|---:|---:|")
    for r in rows:
        mark = " **" if r["beyond_uncertainty"] else ""
        print(f"| {r['requirement']} | `{r['budget']}` | `{r['test'].split('::')[-1][:60]}` | {r['python']:.4g} | "
              f"{r['c']:.4g} | {r['difference']:+.3g}{mark} | {r['seed_spread']:.2g} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"seeds": seeds, "verdicts": verdicts, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
