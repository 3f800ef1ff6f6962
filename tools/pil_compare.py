"""The reference firmware through ``sil:`` (the PC) and ``pil:`` (its Cortex-M4F at 168 MHz): every
judged figure side by side, the defects only the part shows, and the firmware on a Cortex-M0+.

    python tools/pil_compare.py --json out.json [--seeds 0,1] [--pil-seeds 0] [--work DIR]

- **Side by side.** ``hil acceptance`` through ``sil:`` on ``--seeds`` and through ``pil:`` on
  ``--pil-seeds`` (the emulated part is the slow one), each judged budget's figure of the two (the
  mean over the seeds) and their difference; a difference is marked when it exceeds the larger of
  the seed-to-seed spreads (half the range over the seeds, of either DUT that ran more than one),
  as ``tools/sil_compare.py`` does for the built-in controller against the firmware. The wall and
  CPU time of each acceptance run are kept (the speed figure of ``benchmarks/bench_pil.py`` has its
  own run).
- **Defects of the part.** ``hil qualify --only`` the defects whose defects.toml ``kinds`` is
  ``["pil"]``, through ``sil:`` and through ``pil:``: what each run's verdict was and what caught it.
- **Cortex-M0+.** ``firmware/reference/targets/cortex-m0plus.toml`` (64 MHz, no FPU) on the part's
  requirements and the combined calibration (REQ-PIL-001..003, REQ-COMM-001): what it says.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIRMWARE = "firmware/reference"
DUTS = {"sil": f"sil:{FIRMWARE}", "pil": f"pil:{FIRMWARE}"}
M0PLUS = f"pil:{FIRMWARE},target={FIRMWARE}/targets/cortex-m0plus.toml"
#: what the Cortex-M0+ runs: the part's requirements, and the commutation with the paper's deviations
#: calibrated (REQ-COMM-001's test), so the table says what its interrupt times do to the motor
M0PLUS_TESTS = ("test_cases/test_processor.py",
                "test_cases/test_calibration_recovery.py::test_calibration_removes_the_deviation[pil-combined]")


def _hil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], cwd=ROOT, capture_output=True, text=True)


def _acceptance(dut: str, seed: int, out: Path) -> tuple[dict, dict]:
    """One ``hil acceptance`` run: its report, and its wall and CPU seconds (the command and the children it
    waited for, from its own ``wait4``: other runs of this tool go on beside it)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "hil", "acceptance", "--dut", dut, "--seed", str(seed), "--out",
                             str(out)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, _, usage = os.wait4(proc.pid, 0)
    proc.returncode = 0  # reaped here, not by Popen
    cpu = usage.ru_utime + usage.ru_stime
    return json.loads((out / "hil-report.json").read_text()), {"wall_s": time.monotonic() - t0, "cpu_s": cpu}


#: why a figure differs between the PC and the part, by what the budget measures (docs/processor-in-the-loop.md,
#: "The reference firmware through sil: and pil:", says how each was found)
WHY = (
    ("REQ-PIL-", "the part's own: not applicable through sil:"),
    ("angle", "commutation on the part: a command the Hall interrupt makes at once takes effect when it returns"),
    ("mape", "commutation on the part: a command the Hall interrupt makes at once takes effect when it returns"),
)


def why(row: dict) -> str:
    if row["sil"] is None or row["pil"] is None:
        return next((w for key, w in WHY if row["requirement"].startswith(key)), "judged through one only")
    if not row["beyond_spread"]:
        return "within the seed spread"
    if row["budget"].endswith("_error"):  # a table entry's error, not a commutation error
        return "a table entry computed from a recording the firmware's own commutation drove"
    return next((w for key, w in WHY[1:] if key in row["budget"]),
                "follows the commutation: the plant's current and speed answer the later gates")


def part_defects() -> list[str]:
    sys.path.insert(0, str(ROOT))
    from hil.qualify.run import firmware_defects

    return [n for n, d in firmware_defects(DUTS["sil"]).items() if d.kinds == ("pil",)]


def figures(report: dict) -> dict[tuple[str, str, str], float]:
    """(requirement, budget, test without its DUT id) -> measured, for every judged budget."""
    out = {}
    for t in report["tests"]:
        node = re.sub(r"\[(sil|pil)\]", "", re.sub(r"\[(sil|pil)-", "[", t["nodeid"]))
        for m in t["measurements"]:
            out[(m["requirement"], m["budget"], node)] = float(m["measured"])
    return out


def side_by_side(reports: dict[str, list[dict]]) -> list[dict]:
    per = {k: [figures(r) for r in rs] for k, rs in reports.items()}
    keys = sorted(set().union(*(set(f) for fs in per.values() for f in fs)))
    rows = []
    for key in keys:
        vals = {k: [f[key] for f in fs if key in f] for k, fs in per.items()}
        mean = {k: sum(v) / len(v) if v else None for k, v in vals.items()}
        spread = max(((max(v) - min(v)) / 2 for v in vals.values() if v), default=0.0)
        both = mean["sil"] is not None and mean["pil"] is not None
        diff = mean["pil"] - mean["sil"] if both else None
        rows.append({"requirement": key[0], "budget": key[1], "test": key[2], "sil": mean["sil"], "pil": mean["pil"],
                     "difference": diff, "seed_spread": spread,
                     "beyond_spread": both and abs(diff) > max(spread, 1e-12)})
        rows[-1]["why"] = why(rows[-1])
    return rows


def verdicts(report: dict) -> dict[str, str]:
    """Requirement -> its verdict in a report, for the requirements its tests judged."""
    return {r["id"]: r["verdict"] for r in report.get("traceability", []) if r.get("tests")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json")
    parser.add_argument("--seeds", default="0,1", help="the sil: runs' seeds")
    parser.add_argument("--pil-seeds", default="0", help="the pil: runs' seeds")
    parser.add_argument("--work", help="where the runs' reports go (default: a temporary folder)")
    args = parser.parse_args()
    seeds = {"sil": [int(s) for s in args.seeds.split(",")], "pil": [int(s) for s in args.pil_seeds.split(",")]}
    work = Path(args.work or tempfile.mkdtemp(prefix="pil-compare-"))
    defects = part_defects()
    out: dict = {"seeds": seeds, "defects": {}, "reports": {"sil": [], "pil": []}, "times": {}}

    def accept(kind: str) -> None:
        for seed in seeds[kind]:
            report, spent = _acceptance(DUTS[kind], seed, work / f"acceptance-{kind}-{seed}")
            out["reports"][kind].append(report)
            out["times"][f"{kind} seed {seed}"] = spent

    def qualify(kind: str) -> None:
        # the defects of the part, through each (hil qualify: its control run, then each defect)
        q = work / f"qualify-{kind}"
        done = _hil("qualify", "--dut", DUTS[kind], "--only", ",".join(defects), "--seed", str(seeds["pil"][0]),
                    "--json", str(q / "qualify.json"), "--out", str(q))
        if not (q / "qualify.json").is_file():
            raise RuntimeError(f"hil qualify --dut {DUTS[kind]} wrote no result:\n{done.stdout[-2000:]}\n"
                               f"{done.stderr[-2000:]}")
        result = json.loads((q / "qualify.json").read_text())
        out[f"qualify_{kind}"] = {"control_verdict": result["control_verdict"],
                                  "control_failed_tests": result["control"]["failed_tests"],
                                  "no_detection_because": result["no_detection_because"]}
        for m in result["mutants"]:
            out["defects"].setdefault(m["name"], {"class": m["defect_class"], "kinds": m["kinds"]})[kind] = {
                "verdict": m["verdict"], "caught": m["killed"], "expected": m["expected"],
                "catches": m["catches"], "failed_tests": m["failed_tests"]}

    def m0plus() -> None:
        m0 = work / "m0plus"
        subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                        "--hil-dut", M0PLUS, "--hil-seed", str(seeds["pil"][0]), "--hil-report-dir", str(m0),
                        *M0PLUS_TESTS], cwd=ROOT, capture_output=True, text=True)
        report = json.loads((m0 / "hil-report.json").read_text())
        out["m0plus"] = {"dut": M0PLUS, "verdict": report.get("verdict"), "requirements": verdicts(report),
                         "measurements": [{**m, "test": t["nodeid"]} for t in report["tests"]
                                          for m in t["measurements"]],
                         "failures": [{"test": t["nodeid"], "failed_by": t["failed_by"],
                                       "message": t["message"][:400]}
                                      for t in report["tests"] if t["outcome"] in ("failed", "error")],
                         "processor": report.get("processor", {})}

    # the runs are independent: side by side on the machine (the acceptance runs' times are then taken
    # under the same load, sil: beside pil:)
    with ThreadPoolExecutor(max_workers=4) as pool:
        jobs = [pool.submit(accept, "sil"), pool.submit(qualify, "sil"), pool.submit(accept, "pil"),
                pool.submit(lambda: (qualify("pil"), m0plus()))]
        for job in jobs:
            job.result()
    out["rows"] = side_by_side(out["reports"])
    out["verdicts"] = {k: [r.get("verdict", "?") for r in rs] for k, rs in out["reports"].items()}
    out["processor"] = out["reports"]["pil"][0].get("processor", {})
    del out["reports"]
    print(f"verdicts: sil {out['verdicts']['sil']}; pil {out['verdicts']['pil']}; cortex-m0plus "
          f"{out['m0plus']['verdict']}")
    for r in out["rows"]:
        print(f"{r['requirement']:<12} {r['budget']:<40} sil {r['sil']} pil {r['pil']}"
              + (" **" if r["beyond_spread"] else ""))
    for name, d in out["defects"].items():
        print(f"{name:<26} sil: {d['sil']['verdict']:<5} pil: {d['pil']['verdict']:<5} "
              f"{'; '.join(c['by'] for c in d['pil']['catches'][:1])}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
