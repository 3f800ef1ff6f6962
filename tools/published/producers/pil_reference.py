"""docs/processor-in-the-loop.md: the reference firmware through sil: and pil:, its defects of the part,
the Cortex-M0+."""

from __future__ import annotations

import json
from pathlib import Path

from ..model import Figure, Group, Run
from .common import FIRMWARE, SUITE, inputs, run_tool


def produce_pil_reference(work: Path) -> Run:
    """docs/processor-in-the-loop.md: the reference firmware through sil: and pil: (Cortex-M4F, 168 MHz)
    per judged budget on seeds 0 and 1, its defects of the part through both, and the firmware on a
    Cortex-M0+ (``tools/pil_compare.py``)."""
    run = Run(seeds=[0, 1])
    out = work / "pil-compare.json"
    run_tool(run, "pil_compare.py", "--json", str(out), "--seeds", "0,1", "--pil-seeds", "0", "--work",
          str(work / "pil-compare"), timeout_s=4 * 3600)
    result = json.loads(out.read_text())
    num = "{:.4g}".format
    rows = [["requirement", "budget", "test", "sil: (PC)", "pil: (Cortex-M4F)", "pil - sil", "seed spread",
             "beyond it", "why"]]
    for r in result["rows"]:
        rows.append([r["requirement"], f"`{r['budget']}`", f"`{r['test'].split('::')[-1]}`",
                     "n/a" if r["sil"] is None else num(r["sil"]), "n/a" if r["pil"] is None else num(r["pil"]),
                     "–" if r["difference"] is None else f"{r['difference']:+.3g}", f"{r['seed_spread']:.2g}",
                     "yes" if r["beyond_spread"] else "no", r["why"]])
    run.tables["budgets"] = rows
    defects = [["defect", "class", "through sil:", "through pil:, caught by"]]
    for name, d in result["defects"].items():
        caught = "; ".join(sorted({f"{c['requirement']} ({c['by']})" for c in d["pil"]["catches"]})) or "–"
        defects.append([f"`{name}`", d["class"], f"{d['sil']['verdict']} (not a sil: catch by design)",
                        f"{d['pil']['verdict']}: {caught}"])
    run.tables["defects"] = defects
    m0 = result["m0plus"]
    run.tables["m0plus"] = [["requirement", "budget", "measured", "limit", "verdict"]] + [
        [m["requirement"], f"`{m['budget']}`", num(m["measured"]), num(m["limit"]), m["verdict"]]
        for m in m0["measurements"] if m["requirement"].startswith("REQ-PIL") or m["budget"] == "commutation_angle_p99"]
    cores = {"Cortex-M4F, 168 MHz": result["processor"].get("pil", {}), "Cortex-M0+, 64 MHz": m0["processor"].get(
        "pil", {})}
    interrupts = [["core", "interrupt", "calls", "cycles median", "cycles p99", "cycles max", "µs max",
                   "worst response µs"]]
    for core, p in cores.items():
        for k, v in p.get("interrupts", {}).items():
            interrupts.append([core, k, str(v["calls"]), *(f"{v['cycles'][q]:.0f}" for q in ("median", "p99", "max")),
                               f"{v['us']['max']:.1f}", f"{v['worst_response_us']:.1f}"])
    run.tables["interrupts"] = interrupts
    run.figures["sil_verdicts"] = Figure(", ".join(result["verdicts"]["sil"]))
    run.figures["pil_verdicts"] = Figure(", ".join(result["verdicts"]["pil"]))
    run.figures["m0plus_verdict"] = Figure(m0["verdict"])
    run.figures["m0plus_failed"] = Figure(", ".join(r for r, v in sorted(m0["requirements"].items()) if v == "fail")
                                          or "none")
    run.figures["beyond"] = Figure(sum(bool(r["beyond_spread"]) for r in result["rows"]), "", "{:d}",
                                   tolerance_abs=3)
    run.figures["defects_caught_on_pil"] = Figure(sum(d["pil"]["caught"] for d in result["defects"].values()), "",
                                                  "{:d}")
    run.figures["defects_passing_on_sil"] = Figure(sum(d["sil"]["verdict"] == "PASS"
                                                       for d in result["defects"].values()), "", "{:d}")
    run.figures["pil_control_verdict"] = Figure(result["qualify_pil"]["control_verdict"])
    times = result["times"]
    run.figures["pil_over_sil_wall"] = Figure(times["pil seed 0"]["wall_s"] / times["sil seed 0"]["wall_s"], "",
                                              "{:.1f}", reproducible=False)
    run.figures["pil_over_sil_cpu"] = Figure(times["pil seed 0"]["cpu_s"] / times["sil seed 0"]["cpu_s"], "",
                                             "{:.1f}", reproducible=False)
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


GROUPS = (
    Group("pil_reference", "docs/processor-in-the-loop.md: the reference firmware through sil: and pil:, its defects "
          "of the part, the Cortex-M0+", False, produce_pil_reference,
          inputs(__file__, *SUITE, *FIRMWARE, "tools/pil_compare.py")),
)
