"""Every figure published in README.md and docs/, computed from the code at HEAD.

    python tools/figures.py                 # compute every group, write docs/figures.json, render the docs
    python tools/figures.py --only demo ... # compute these groups only (the others keep their values)
    python tools/figures.py --quick         # recompute the quick subset; exit 1 on drift beyond tolerance
    python tools/figures.py --render        # rewrite the docs from docs/figures.json (no computing)
    python tools/figures.py --check         # exit 1 where a doc disagrees with docs/figures.json

A figure lives in ``docs/figures.json`` with its value, unit, tolerance and the provenance of its group
(commit, command, seeds, duration, machine). A document shows it between markers, which ``--render``
fills in and ``--check`` (and ``tests/test_figures.py``) holds to the file:

    <!-- fig:demo.rms_deg_e -->3.986<!-- /fig -->
    <!-- figtable:pump_predictors -->
    | ... rendered table ... |
    <!-- /figtable -->

So no published number is typed by hand: a doc that says something else fails the test, and a code
change that moves a quick figure beyond its tolerance fails ``--quick`` in CI.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
FIGURES_FILE = ROOT / "docs" / "figures.json"
PUBLISHED = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
REAL_CAPTURES = ROOT / "tests" / "data" / "real-hall"

FIG_MARK = re.compile(r"<!-- fig:(?P<key>[\w.\-]+) -->(?P<text>.*?)<!-- /fig -->", re.S)
TABLE_MARK = re.compile(
    r"(?P<open><!-- figtable:(?P<name>[\w\-]+) -->\n)(?P<body>.*?)(?P<close><!-- /figtable -->)", re.S
)


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
    name: str
    what: str
    quick: bool
    produce: Callable[[Path], Run]


def _hil(run: Run, work: Path, *args: str, timeout_s: float = 3600) -> subprocess.CompletedProcess:
    """``python -m hil ARGS`` from the repository root, recorded in the run's commands."""
    cmd = [sys.executable, "-m", "hil", *args]
    shown = "python -m hil " + " ".join(
        shlex.quote(str(a)).replace(str(work), "$WORK").replace(str(ROOT) + "/", "") for a in args
    )
    run.commands.append(shown)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)
    run.last_command_s = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{shown} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return done


def _import_capture(run: Run, work: Path, vcd: str) -> Path:
    out = work / Path(vcd).stem
    if not out.exists():
        _hil(run, work, "recording", "import", str(REAL_CAPTURES / vcd), "--out", str(out))
    return out


# ---------------------------------------------------------------- producers


def produce_demo(work: Path) -> Run:
    run = Run(seeds=[0])
    done = _hil(run, work, "demo", "--out", str(work / "demo"))
    m = re.search(r"all edges: mean ([\d.\-]+), RMS ([\d.]+), max \|err\| ([\d.]+)", done.stdout)
    if not m:
        raise RuntimeError(f"hil demo printed no summary line:\n{done.stdout[-1500:]}")
    mean, rms, worst = (float(g) for g in m.groups())
    tol = dict(tolerance_abs=0.01, unit="deg e", fmt="{:.3f}")
    run.figures = {
        "mean_deg_e": Figure(mean, **tol),
        "rms_deg_e": Figure(rms, **tol),
        "max_deg_e": Figure(worst, **tol),
    }
    # the table as printed, without the last line (where the recording was written)
    run.blocks["output"] = "".join(line + "\n" for line in done.stdout.splitlines() if " written to " not in line)
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


def _calibration_figures(corrections: dict) -> dict[str, Figure]:
    """The ordinary-run calibration's headline figures with their standard errors."""
    figures: dict[str, Figure] = {}
    for key, name, scale, unit, fmt in (
        ("rise_fall_delay_difference_s", "delay_difference_us", 1e6, "us", "{:.1f}"),
        ("rise_fall_angle_asymmetry_deg_e", "asymmetry_deg_e", 1.0, "deg e", "{:.2f}"),
    ):
        item = corrections.get(key)
        if not isinstance(item, dict) or item.get("value") is None:
            continue
        value, stderr = item["value"] * scale, (item.get("stderr") or 0.0) * scale
        # a recomputation must agree within the figure's own stated uncertainty
        figures[name] = Figure(value, unit, fmt, tolerance_abs=max(stderr, 1e-3 * abs(value)))
        figures[name + "_stderr"] = Figure(stderr, unit, "{:.1f}" if unit == "us" else "{:.2f}",
                                           tolerance_abs=max(0.25 * stderr, 1e-6))
    check = (corrections.get("method_cross_check") or {}).get("rise_fall_delay_difference_s")
    if isinstance(check, dict) and check.get("value") is not None:
        figures["cross_check_delay_difference_us"] = Figure(
            check["value"] * 1e6, "us", "{:.1f}", tolerance_abs=max((check.get("stderr") or 0) * 1e6, 0.1)
        )
        check_stderr_us = (check.get("stderr") or 0) * 1e6
        figures["cross_check_delay_difference_us_stderr"] = Figure(
            check_stderr_us, "us", "{:.1f}", tolerance_abs=max(0.25 * check_stderr_us, 0.05)
        )
    pp = _find(corrections, "pole_pairs")
    if isinstance(pp, (int, float)):
        figures["pole_pairs"] = Figure(int(pp), "", "{:d}")
    return figures


def _find(tree, key: str):
    """The first value under ``key`` anywhere in a JSON tree (the calibration's keys are unique)."""
    if isinstance(tree, dict):
        if key in tree:
            return tree[key]
        for v in tree.values():
            found = _find(v, key)
            if found is not None:
                return found
    elif isinstance(tree, list):
        for v in tree:
            found = _find(v, key)
            if found is not None:
                return found
    return None


def _produce_real_calibration(vcd: str) -> Callable[[Path], Run]:
    def produce(work: Path) -> Run:
        run = Run()
        rec = _import_capture(run, work, vcd)
        out = work / f"{rec.name}-corrections.json"
        _hil(run, work, "calibrate", str(rec), "--json", str(out))
        run.figures = _calibration_figures(json.loads(out.read_text()))
        if not run.figures:
            raise RuntimeError(f"hil calibrate {rec}: no rise-fall figures in {out}")
        return run

    return produce


def _produce_real_predictors(vcd: str) -> Callable[[Path], Run]:
    def produce(work: Path) -> Run:
        run = Run()
        rec = _import_capture(run, work, vcd)
        out = work / f"{rec.name}-predictors.json"
        _hil(run, work, "predictors", "compare", str(rec), "--json", str(out))
        result = json.loads(out.read_text())
        rows = [["predictor", "RMS deg e", "p99 deg e", "max deg e", "edges scored"]]
        for p in result["predictors"]:
            run.figures[f"{p['name']}.rms_deg_e"] = Figure(
                p["angle_rms_deg_e"], "deg e", "{:.2f}", tolerance_abs=0.02, tolerance_rel=0.02
            )
            rows.append(
                [
                    p["name"],
                    f"{p['angle_rms_deg_e']:.2f}",
                    f"{p['angle_p99_deg_e']:.2f}",
                    f"{p['angle_max_deg_e']:.2f}",
                    f"{p['edges_scored']:d}",
                ]
            )
        best = min(result["predictors"], key=lambda p: p["angle_rms_deg_e"])
        run.figures["best"] = Figure(best["name"])
        run.tables["predictors"] = rows
        return run

    return produce


def _predictor_table(run: Run, result: dict, columns, tol_abs: float) -> list[list[str]]:
    """One row per predictor of ``hil predictors compare --json``; each cell also a figure."""
    rows = [["predictor"] + [label for _, label in columns]]
    for p in result["predictors"]:
        for key, _ in columns:
            if p.get(key) is not None:
                run.figures[f"{p['name']}.{key}"] = Figure(
                    p[key], "deg e", "{:.3f}", tolerance_abs=tol_abs, tolerance_rel=0.03
                )
        rows.append([p["name"]] + [f"{p[k]:.3f}" if p.get(k) is not None else "n/a" for k, _ in columns])
    return rows


def _scenario_seeds(result: dict) -> list[int]:
    """The seeds a scenario's ``source`` line names ("seeds 1000-1023" or "seeds [0, 1, ...]")."""
    text = result["source"].split("seeds", 1)[1]
    m = re.match(r"\s*(\d+)-(\d+)", text)
    if m:
        return list(range(int(m[1]), int(m[2]) + 1))
    return [int(x) for x in re.findall(r"\d+", text.split("]")[0])]


def produce_pump_predictors(work: Path) -> Run:
    run = Run()
    out = work / "pumps.json"
    _hil(run, work, "predictors", "compare", "--scenario", "pumps", "--json", str(out))
    result = json.loads(out.read_text())
    run.seeds = _scenario_seeds(result)
    columns = (("angle_rms_deg_e", "mean RMS"), ("angle_rms_median_deg_e", "median RMS"),
               ("angle_p99_deg_e", "mean p99"), ("angle_max_deg_e", "max"))
    run.tables["predictors"] = _predictor_table(run, result, columns, 0.005)
    run.figures["sage_husa_over_kf_median_rms"] = Figure(
        result["sage_husa_over_kf_median_rms"], "", "{:.3f}", tolerance_abs=0.01
    )
    # pump by pump: how often Sage-Husa is ahead of the KF, and the pump the KF does worst on
    by_pump = [{r["name"]: r["angle_rms_deg_e"] for r in pump["predictors"]} for pump in result["pumps"]]
    ratios = [p["sage_husa"] / p["kf"] for p in by_pump]
    run.figures["pumps"] = Figure(len(by_pump), "", "{:d}")
    run.figures["sage_husa_ahead_of_kf_pumps"] = Figure(sum(r < 1.0 for r in ratios), "", "{:d}", tolerance_abs=2)
    run.figures["sage_husa_over_kf_min"] = Figure(min(ratios), "", "{:.2f}", tolerance_abs=0.05)
    run.figures["sage_husa_over_kf_max"] = Figure(max(ratios), "", "{:.2f}", tolerance_abs=0.05)
    worst = max(range(len(by_pump)), key=lambda j: by_pump[j]["kf"])
    run.figures["kf_worst_pump_seed"] = Figure(run.seeds[worst] if run.seeds else worst, "", "{:d}")
    for name in ("kf", "sage_husa", "vb_akf", "pll"):
        run.figures[f"kf_worst_pump.{name}_rms_deg_e"] = Figure(
            by_pump[worst][name], "deg e", "{:.2f}", tolerance_abs=0.01, tolerance_rel=0.05
        )
    return run


def produce_paper_predictors(work: Path) -> Run:
    run = Run()
    out = work / "paper.json"
    _hil(run, work, "predictors", "compare", "--scenario", "paper", "--json", str(out))
    result = json.loads(out.read_text())
    run.seeds = _scenario_seeds(result)
    columns = (("angle_rms_deg_e", "RMS"), ("angle_p99_deg_e", "p99"), ("angle_max_deg_e", "max"))
    run.tables["predictors"] = _predictor_table(run, result, columns, 0.003)
    return run


def produce_acceptance(work: Path) -> Run:
    """The README's first command, timed (wall and CPU time of the whole run)."""
    run = Run()
    t0, c0 = time.perf_counter(), _children_cpu_s()
    report_dir = work / "acceptance"
    try:
        _hil(run, work, "acceptance", "--report-dir", str(report_dir))
    except RuntimeError:
        pass  # the verdict below says what happened
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    report = json.loads((report_dir / "hil-report.json").read_text())
    run.commands[-1] = "python -m hil acceptance"
    run.figures = {
        "verdict": Figure(str(_find(report, "verdict"))),
        "wall_s": Figure(wall, "s", "{:.0f}", reproducible=False),
        "cpu_s": Figure(cpu, "s", "{:.0f}", reproducible=False),
    }
    return run


def produce_test_suite(work: Path) -> Run:
    """The README's second command (pytest only; the install is timed apart by CI)."""
    run = Run(commands=["python -m pytest -q"])
    t0 = time.perf_counter()
    env = {**os.environ, "HIL_FIGURES_RUNNING": "test_suite"}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=ROOT,
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    m = re.search(r"(\d+) passed", done.stdout)
    failed = [line for line in done.stdout.splitlines() if line.startswith(("FAILED ", "ERROR "))]
    if failed:  # what made the exit status, kept with the figures
        run.blocks["failures"] = "\n".join(failed) + "\n"
    run.figures = {
        "wall_s": Figure(wall, "s", "{:.0f}", reproducible=False),
        "passed": Figure(int(m.group(1)) if m else 0, "", "{:d}", reproducible=False),
        "exit_status": Figure(done.returncode, "", "{:d}"),
    }
    return run


def _produce_twin(vcd: str) -> Callable[[Path], Run]:
    """docs/twin.md: the capture's twin (``hil plant from-capture``), checked against the capture
    (``hil twin check``) and put through the acceptance suite in-process (``hil acceptance --plant``)."""

    def produce(work: Path) -> Run:
        run = Run(seeds=[0])
        twin = work / f"{Path(vcd).stem}-twin.toml"
        _hil(run, work, "plant", "from-capture", str(REAL_CAPTURES / vcd), "-o", str(twin))
        check = work / f"{Path(vcd).stem}-twin-check.json"
        _hil(run, work, "twin", "check", str(REAL_CAPTURES / vcd), str(twin), "--json", str(check))
        result = json.loads(check.read_text())
        delay = {side: result["calibration"][side]["rise_fall_delay_difference_s"] for side in ("real", "twin")}
        for side, d in delay.items():
            run.figures[f"delay_{side}_us"] = Figure(d["value"] * 1e6, "us", "{:.1f}", tolerance_abs=0.5)
            run.figures[f"delay_{side}_stderr_us"] = Figure(d["stderr"] * 1e6, "us", "{:.1f}", tolerance_abs=0.5)
        rows = [["predictor", "real RMS deg e", "twin RMS deg e", "twin / real"]]
        for p in result["predictors"]:
            run.figures[f"ratio.{p['name']}"] = Figure(p["ratio"], "", "{:.2f}", tolerance_abs=0.03)
            rows.append([p["name"], f"{p['real_rms_deg_e']:.2f}", f"{p['twin_rms_deg_e']:.2f}", f"{p['ratio']:.2f}"])
        run.tables["predictors"] = rows
        report_dir = work / f"{Path(vcd).stem}-acceptance"
        t0 = time.perf_counter()
        try:
            _hil(run, work, "acceptance", "--plant", str(twin), "--dut", "virtual:in-process", "--report-dir",
                 str(report_dir))
        except RuntimeError:
            pass  # a FAIL verdict exits 1; the report says what happened
        run.figures["acceptance_wall_s"] = Figure(time.perf_counter() - t0, "s", "{:.0f}", reproducible=False)
        report = json.loads((report_dir / "hil-report.json").read_text())
        run.figures["acceptance_verdict"] = Figure(str(report["verdict"]))
        for outcome in ("passed", "failed", "error", "skipped"):
            run.figures[f"acceptance_{outcome}"] = Figure(int(report["counts"].get(outcome, 0)), "", "{:d}")
        rows = [["requirement", "verdict", "worst budget measured (limit)"]]
        for req in report["traceability"]:
            if not req["traced"]:
                continue
            run.figures[f"verdict.{req['id']}"] = Figure(str(req["verdict"]))
            # every budget its tests judged (a calibration test judges REQ-COMM-001's angle budget too),
            # the worst by its margin over its limit
            measured = [m for t in req["tests"] for m in t["measurements"]]
            worst = min(measured, key=lambda m: m["margin"] / max(abs(m["limit"]), 1e-12)) if measured else None
            bound = "-" if worst is None else "<=" if worst["limit_kind"] == "max" else ">="
            rows.append([req["id"], req["verdict"],
                         f"{worst['budget']} {worst['measured']:.3g} {worst['unit']} ({bound} {worst['limit']:g})"
                         if worst else "-"])
        run.tables["acceptance"] = rows
        return run

    return produce


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
    rows = [["defect", "class", "requirement", "names the class", "verdict", "by", "margin"]]
    for c in result["sensitivity"]:
        rows.append([f"`{c['defect']}`", c["defect_class"] or "-", c["requirement"], "yes" if c["named"] else "no",
                     "**caught**" if c["caught"] else ("missed" if c["ran"] else "not run"),
                     (c["by"] or "-").removeprefix("budget "),
                     "-" if c["margin"] is None else f"{c['margin']:+.3g}"])
    run.tables["sensitivity"] = rows
    run.tables["outcomes"] = [["defect", "caught by", "what caught it", "requirements"]] + [
        [f"`{m['name']}`", m["caught_by"] or "survived",
         "; ".join(sorted({c["by"].removeprefix("budget ") for c in m["catches"]})) or "-",
         ", ".join(m["killed_by"]) or "-"] for m in result["mutants"]]
    return run


def _children_cpu_s() -> float:
    t = os.times()
    return t.children_user + t.children_system


GROUPS: list[Group] = [
    Group("demo", "README tour step 1: the paper-bench demo's captured-edge error", True, produce_demo),
    Group("spindle_calibration", "docs/real-captures.md: the spindle capture calibrated", True,
          _produce_real_calibration("20260618-spindle-hw.vcd")),
    Group("hoverboard_calibration", "docs/real-captures.md: the hoverboard speed cycles calibrated", False,
          _produce_real_calibration("20250616-hboard-cycle.vcd")),
    Group("spindle_predictors", "docs/sage-husa.md: every predictor on the spindle capture", True,
          _produce_real_predictors("20260618-spindle-hw.vcd")),
    Group("pump_predictors", "docs/sage-husa.md: every predictor on the held-out pumps", False,
          produce_pump_predictors),
    Group("paper_predictors", "docs/sage-husa.md: every predictor in the paper's speed-step scenario", False,
          produce_paper_predictors),
    Group("spindle_twin", "docs/twin.md: the spindle's twin, checked and put through the suite", False,
          _produce_twin("20260618-spindle-hw.vcd")),
    Group("hoverboard_twin", "docs/twin.md: the hoverboard's twin, checked and put through the suite", False,
          _produce_twin("20250616-hboard-cycle.vcd")),
    Group("acceptance", "README: the default acceptance run's verdict and run time", False, produce_acceptance),
    Group("test_suite", "README: the test command's run time", False, produce_test_suite),
    Group("qualify", "docs/qualify.md: hil qualify --sensitivity, the sensitivity table", False, produce_qualify),
]


# ---------------------------------------------------------------- the file and the docs


def _commit() -> str:
    """HEAD, marked when tracked files differ from it."""
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip())
    return commit + ("+uncommitted" if dirty else "")


def _provenance(group: Group, run: Run, duration_s: float, commit: str) -> dict:
    return {
        "what": group.what,
        "commit": commit,
        "commands": run.commands,
        "seeds": run.seeds,
        "duration_s": round(duration_s, 1),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
                   f"load average {os.getloadavg()[0]:.1f} at the end",
        "quick": group.quick,
    }


def compute(groups: list[Group]) -> dict[str, dict]:
    out = {}
    with tempfile.TemporaryDirectory(prefix="hil-figures-") as tmp:
        work = Path(tmp)
        for g in groups:
            print(f"figures: {g.name}: {g.what} ...", flush=True)
            t0 = time.perf_counter()
            commit = _commit()  # before the run: a run may write files of its own (the suite's screenshots)
            run = g.produce(work)
            dt = time.perf_counter() - t0
            out[g.name] = {
                "provenance": _provenance(g, run, dt, commit),
                "figures": {k: f.to_json() for k, f in run.figures.items()},
                "tables": run.tables,
                "blocks": run.blocks,
            }
            print(f"figures: {g.name}: {len(run.figures)} figures in {dt:.0f} s", flush=True)
    return out


def load() -> dict:
    if not FIGURES_FILE.exists():
        return {"groups": {}}
    return json.loads(FIGURES_FILE.read_text())


def save(data: dict) -> None:
    FIGURES_FILE.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def figure(data: dict, key: str) -> Figure:
    group, _, name = key.partition(".")
    try:
        return Figure(**data["groups"][group]["figures"][name])
    except KeyError:
        raise KeyError(f"no figure {key!r} in docs/{FIGURES_FILE.name}") from None


def render_table(data: dict, name: str) -> str:
    """``GROUP-TABLE`` as a Markdown table (or ``GROUP-BLOCK`` as a code block) with its provenance."""
    group, _, table = name.partition("-")
    g = data["groups"].get(group, {})
    prov = g.get("provenance")
    if table in g.get("tables", {}):
        rows = g["tables"][table]
        lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
        lines += ["| " + " | ".join(r) + " |" for r in rows[1:]]
        body = "\n".join(lines) + "\n"
    elif table in g.get("blocks", {}):
        body = "```\n" + g["blocks"][table] + "```\n"
    else:
        raise KeyError(f"no table or block {name!r} in {FIGURES_FILE.relative_to(ROOT)}")
    return body + (
        f"\n<sub>`python tools/figures.py --only {group}` at {prov['commit'][:10]}, {prov['date'][:10]}, "
        f"{prov['duration_s']:.0f} s: `{'`; `'.join(prov['commands'])}`</sub>\n"
    )


def render_text(text: str, data: dict) -> str:
    def fig(m):
        try:
            return f"<!-- fig:{m['key']} -->{figure(data, m['key']).text()}<!-- /fig -->"
        except KeyError:  # not computed yet: left as it is, and --check names it
            return m[0]

    def table(m):
        try:
            return m["open"] + render_table(data, m["name"]) + m["close"]
        except KeyError:
            return m[0]

    return TABLE_MARK.sub(table, FIG_MARK.sub(fig, text))


def disagreements(data: dict, computing: frozenset[str] = frozenset()) -> list[str]:
    """Where a published document says something other than the figures file (the groups being
    computed, ``computing``, are left out: the suite runs inside ``test_suite``'s measurement)."""
    out = []
    for path in PUBLISHED:
        text = path.read_text()
        for m in FIG_MARK.finditer(text):
            if m["key"].partition(".")[0] in computing:
                continue
            line = text.count("\n", 0, m.start()) + 1
            try:
                want = figure(data, m["key"]).text()
            except KeyError as e:
                out.append(f"{path.relative_to(ROOT)}:{line}: {e.args[0]}")
                continue
            if m["text"] != want:
                out.append(
                    f"{path.relative_to(ROOT)}:{line}: {m['key']} reads {m['text']!r}, the figures file {want!r}"
                )
        for m in TABLE_MARK.finditer(text):
            if m["name"].partition("-")[0] in computing:
                continue
            line = text.count("\n", 0, m.start()) + 1
            try:
                want = render_table(data, m["name"])
            except KeyError as e:
                out.append(f"{path.relative_to(ROOT)}:{line}: {e.args[0]}")
                continue
            if m["body"] != want:
                out.append(f"{path.relative_to(ROOT)}:{line}: table {m['name']} differs from the figures file")
    return out


def render(data: dict) -> list[Path]:
    changed = []
    for path in PUBLISHED:
        old = path.read_text()
        new = render_text(old, data)
        if new != old:
            path.write_text(new)
            changed.append(path)
    return changed


def drift(stored: dict, fresh: dict) -> list[str]:
    out = []
    for gname, g in fresh.items():
        old = stored["groups"].get(gname)
        if old is None:
            out.append(f"{gname}: not in {FIGURES_FILE.relative_to(ROOT)}")
            continue
        for name, f in g["figures"].items():
            if name not in old["figures"]:
                out.append(f"{gname}.{name}: new figure, not in the file")
                continue
            why = Figure(**old["figures"][name]).drift(Figure(**f))
            if why:
                out.append(f"{gname}.{name}: {why}")
        for name in old["figures"]:
            if name not in g["figures"]:
                out.append(f"{gname}.{name}: no longer computed")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="recompute the quick subset; exit 1 on drift")
    mode.add_argument("--render", action="store_true", help="rewrite the docs from the figures file")
    mode.add_argument("--check", action="store_true", help="exit 1 where a doc disagrees with the figures file")
    ap.add_argument("--only", nargs="+", metavar="GROUP", choices=[g.name for g in GROUPS],
                    help="compute these groups only")
    args = ap.parse_args(argv)
    data = load()
    if args.check:
        bad = disagreements(data)
        print("\n".join(bad) if bad else f"figures: every published figure agrees with {FIGURES_FILE.name}")
        return 1 if bad else 0
    if args.render:
        for p in render(data):
            print(f"rendered {p.relative_to(ROOT)}")
        return 0
    if args.only:
        chosen = [g for g in GROUPS if g.name in args.only]
    else:
        chosen = [g for g in GROUPS if g.quick or not args.quick]
    t0 = time.perf_counter()
    fresh = compute(chosen)
    if args.quick:
        bad = drift(data, fresh)
        print("\n".join(bad) if bad else f"figures: {len(chosen)} quick groups reproduce within tolerance "
                                            f"({time.perf_counter() - t0:.0f} s)")
        return 1 if bad else 0
    data.setdefault("groups", {}).update(fresh)
    save(data)
    for p in render(data):
        print(f"rendered {p.relative_to(ROOT)}")
    print(f"figures: wrote {FIGURES_FILE.relative_to(ROOT)} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
