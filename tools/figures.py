"""Every figure published in README.md and docs/, computed from the code at HEAD.

    python tools/figures.py                 # compute every group, write docs/figures.json, render the docs
    python tools/figures.py --only demo ... # compute these groups only (the others keep their values)
    python tools/figures.py --quick         # recompute the quick subset; exit 1 on drift beyond tolerance
    python tools/figures.py --render        # rewrite the docs from docs/figures.json (no computing)
    python tools/figures.py --check         # exit 1 where a doc disagrees with docs/figures.json, a group's
                                            # content is not what the tool wrote, its commit is not HEAD's
                                            # ancestor, or a group recomputed differs: every group whose
                                            # declared inputs changed since its commit is recomputed
    python tools/figures.py --stale         # the groups --check would recompute, and why
    python tools/figures.py --check --all   # the release check: recompute EVERY group and compare figures and
                                            # table cells with the file (slow: the whole test suite is one group);
                                            # its record is kept in the file and shown in README.md
    python tools/figures.py --check --only G ...  # the same for some groups

A figure lives in ``docs/figures.json`` with its value, unit, tolerance and the provenance of its group
(commit, command, seeds, duration, machine). A document shows it between markers, which ``--render``
fills in and ``--check`` (and ``tests/test_figures.py``) holds to the file:

    <!-- fig:demo.rms_deg_e -->3.986<!-- /fig -->
    <!-- figtable:pump_predictors -->
    | ... rendered table ... |
    <!-- /figtable -->

So no published number is typed by hand: a doc that says something else fails the test, and a code
change that moves a quick figure beyond its tolerance fails ``--quick`` in CI.

What ``--check`` holds:

- every marked figure and table of the docs is the file's;
- every group's content (figures, tables, blocks, provenance) hashes to the digest the tool wrote
  with it: a number, a table cell or a provenance commit edited by hand in the file fails. The digest
  has no key, and a key would not help: in an open repository anyone can read it, and a forger runs
  the tool's own ``digest()``. It catches an edit by hand, never a forgery;
- every group's provenance commit is a commit of this repository and an ancestor of HEAD
  (``git merge-base --is-ancestor``); in a clone without history (``git clone --depth 1``, an
  archive) the check says that it could not check, and does not pass it silently;
- every group whose declared inputs (``Group.inputs``: the code it runs and the data it reads)
  changed between its provenance commit and the working tree, or whose commit is not an ancestor, is
  recomputed and compared figure by figure and cell by cell: such a group cannot pass on its file
  entry. A forged cell whose group names an old commit (the root commit, say) is recomputed and fails.

What only a recompute catches: a figure rewritten with a provenance commit newer than its group's
last input change (the forger names HEAD). ``tests/test_figures.py`` recomputes the quick groups on
every CI run, ``tests/test_figures_rotation.py`` one of the rotating groups in turn
(:func:`rotation_group`); ``--check --all`` (before each release) recomputes every group.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import shlex
import statistics
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
#: where the docs say when every group was last recomputed and compared (``--check --all``)
CHECK_MARK = re.compile(r"<!-- figcheck -->(?P<text>.*?)<!-- /figcheck -->", re.S)
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
    """A set of figures computed together. ``inputs``: globs of the tracked paths whose change can
    change its figures (``!glob`` leaves paths out); ``--check`` recomputes the group when one of
    them changed since its provenance commit. ``quick``: recomputed by every CI run;
    ``rotation``: one of these is recomputed by each CI run, chosen by the commit
    (:func:`rotation_group`): groups that take at most a minute with the plant compiled, so that the
    suite (about eight and a half minutes) stays within its ten (docs/architecture.md, "Published
    figures", names the others and what covers them)."""

    name: str
    what: str
    quick: bool
    produce: Callable[[Path], Run]
    inputs: tuple[str, ...]
    rotation: bool = False


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
        _hil(run, work, "recording", "import", str(REAL_CAPTURES / vcd), "-o", str(out))
    return out


# ---------------------------------------------------------------- producers


def produce_demo(work: Path) -> Run:
    run = Run(seeds=[0])
    done = _hil(run, work, "paper", "demo", "-o", str(work / "demo"))
    m = re.search(r"all edges: mean ([\d.\-]+), RMS ([\d.]+), max \|err\| ([\d.]+)", done.stdout)
    if not m:
        raise RuntimeError(f"hil paper demo printed no summary line:\n{done.stdout[-1500:]}")
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
        _hil(run, work, "acceptance", "-o", str(report_dir))
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


#: fresh clones measured by ``first_run``: its wall time varies by ten seconds and more from run to
#: run on a shared machine, so the figure is the median, and the slowest is published beside it
FIRST_RUN_CLONES = 3


def produce_first_run(work: Path) -> Run:
    """README's first command on fresh clones of HEAD (each numba cache empty: the compile
    included), then once more on the last one's warm cache: wall times and the first result's
    instant."""
    run = Run(commands=["git clone <repository> fresh && cd fresh", "python -m hil acceptance",
                        "python -m hil acceptance"])
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}

    def acceptance(clone: Path, out: Path) -> tuple[float, int | None, str]:
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "hil", "acceptance", "-o", str(out)], cwd=clone, env=env,
                              capture_output=True, text=True, timeout=1800)
        wall = time.perf_counter() - t0
        # the progress lines: "[ 1/37  0:18] passed   <test>" (count, elapsed m:ss, outcome)
        first = re.search(r"^\[\s*\d+/\d+\s+(\d+):(\d\d)\] (?:passed|failed|skipped|error)", done.stdout, re.M)
        verdict = re.search(r"hil acceptance: (\w+)", done.stdout)
        return wall, 60 * int(first[1]) + int(first[2]) if first else None, (
            verdict[1] if verdict else f"exit {done.returncode}")

    fresh = []
    for k in range(FIRST_RUN_CLONES):
        clone = work / f"fresh{k}"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        fresh.append(acceptance(clone, work / f"fresh{k}-report"))
    warm = acceptance(clone, work / "warm-report")
    walls = sorted(w for w, _, _ in fresh)
    firsts = sorted(f for _, f, _ in fresh if f is not None)
    verdicts = sorted({v for _, _, v in fresh} | {warm[2]})
    run.figures = {
        "fresh_wall_s": Figure(float(statistics.median(walls)), "s", "{:.0f}", reproducible=False),
        "fresh_wall_max_s": Figure(walls[-1], "s", "{:.0f}", reproducible=False),
        "fresh_clones": Figure(FIRST_RUN_CLONES, "", "{:d}"),
        "fresh_first_result_s": Figure(float(statistics.median(firsts)) if firsts else None, "s", "{:.0f}",
                                       reproducible=False),
        "warm_wall_s": Figure(warm[0], "s", "{:.0f}", reproducible=False),
        "verdict": Figure(", ".join(verdicts), fmt="{}"),
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
    """docs/twin.md: the capture's twin (``hil twin from-capture``), checked against the capture
    (``hil twin check``) and put through the acceptance suite in-process (``hil acceptance --plant``)."""

    def produce(work: Path) -> Run:
        run = Run(seeds=[0])
        twin = work / f"{Path(vcd).stem}-twin.toml"
        _hil(run, work, "twin", "from-capture", str(REAL_CAPTURES / vcd), "-o", str(twin))
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
            _hil(run, work, "acceptance", "--plant", str(twin), "--dut", "virtual:in-process", "-o",
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


def _tool(run: Run, script: str, *args: str, timeout_s: float = 3600) -> subprocess.CompletedProcess:
    """``python tools/SCRIPT ARGS`` from the repository root, recorded in the run's commands (the
    scratch directory shown as $WORK)."""
    run.commands.append(re.sub(r"\S*/hil-figures-[^/\s]+", "$WORK",
                               " ".join(["python", f"tools/{script}", *map(shlex.quote, args)])))
    t0 = time.perf_counter()
    # a script's own directory comes first on its path, not the checkout's: without ROOT on
    # PYTHONPATH it would import an installed copy of hil (an editable install of another checkout)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, str(ROOT / "tools" / script), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout_s, env=env)
    run.last_command_s = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"tools/{script} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return done


#: Table 5's metrics in the table's order, and each protocol's bar (docs/sage-husa.md, "Results")
T5_METRICS = ("speed_mape_regulation_pct", "max_overshoot_pct", "speed_mape_constant_pct",
              "commutation_time_mape_pct", "angle_rms_deg_e")
T5_BARS = {
    "paper": ">= 22/28/27/7 % in >= 90 % of seeds, at nominal and across the Q0 scan (paper: 44.8/56.0/54.9/14.7)",
    "tuned": ">= -5 % on angle RMS and comm. time MAPE",
    "misspecified": ">= +50 % on angle RMS and comm. time MAPE",
    "bursts": "captures >= 30 % of the oracle's angle-RMS gain (goal 60 %), >= -5 % on reg. MAPE, overshoot, "
              "comm. time MAPE, angle RMS",
}


def _t5_met(protocol: str, imp: dict, wins: dict, scan: list[tuple[dict, dict]], oracle: dict | None) -> str:
    if protocol == "paper":
        bars = dict(zip(T5_METRICS, (22.0, 28.0, 27.0, 7.0)))
        ok = all(i[m] >= b and w[m] >= 0.9 for i, w in [(imp, wins), *scan] for m, b in bars.items())
        return "yes, at nominal and across the scan" if ok else "no"
    if protocol == "tuned":
        return "yes" if min(imp["angle_rms_deg_e"], imp["commutation_time_mape_pct"]) >= -5 else "no"
    if protocol == "misspecified":
        return "yes" if min(imp["angle_rms_deg_e"], imp["commutation_time_mape_pct"]) >= 50 else "no"
    captured = imp["angle_rms_deg_e"] / oracle["angle_rms_deg_e"] if oracle and oracle["angle_rms_deg_e"] > 0 else 0
    rest = min(imp[m] for m in ("speed_mape_regulation_pct", "max_overshoot_pct", "commutation_time_mape_pct",
                                "angle_rms_deg_e"))
    return f"{'yes' if captured >= 0.3 and rest >= -5 else 'no'}: {100 * captured:.0f} % captured"


def produce_table5(work: Path) -> Run:
    """docs/sage-husa.md, "Results": Table 5's comparison under the four protocols, Sage-Husa over the KF
    (``python -m hil table5 --protocol P``; the paper protocol's Q0 scan from its printout)."""
    run = Run(seeds=[0, 3, 4, 5, 6, 7, 8, 9, 10, 11])
    rows = [["protocol", "speed MAPE reg.", "max overshoot", "speed MAPE const.", "comm. time MAPE", "angle RMS",
             "judged by", "met?"]]

    def cells(imp, wins):
        return [f"{imp[m]:+.1f} % ({100 * wins[m]:.0f} %)".replace("-", "\u2212") for m in T5_METRICS]

    for protocol in ("paper", "tuned", "misspecified", "bursts"):
        out = work / f"table5-{protocol}.json"
        done = _hil(run, work, "table5", "--protocol", protocol, "--json", str(out))
        result = json.loads(out.read_text())
        imp, wins = result["improvement_pct"], result["sh_wins_fraction"]
        scan = []
        for factor, body in re.findall(r"Q0 x(\S+)\s+SH vs KF: (.*)", done.stdout):
            pcts = [float(x) for x in re.findall(r"([-+][\d.]+)%", body.split("wins")[0])]
            shares = [float(x) / 100 for x in re.findall(r"(\d+)%", body.split("wins")[1])]
            if float(factor) != 1.0:
                scan.append((factor, dict(zip(T5_METRICS, pcts)), dict(zip(T5_METRICS, shares))))
        met = _t5_met(protocol, imp, wins, [(i, w) for _, i, w in scan], result.get("oracle_improvement_pct"))
        label = f"`{protocol}`" + (", Q0 x1" if protocol == "paper" else "")
        rows.append([label, *cells(imp, wins), T5_BARS[protocol], met])
        for factor, i, w in scan:
            rows.append([f"`paper`, Q0 x{factor}", *cells(i, w), "", ""])
        for m in T5_METRICS:
            run.figures[f"{protocol}.{m}.improvement_pct"] = Figure(imp[m], "%", "{:.1f}", tolerance_abs=1.0)
        for name in ("sage_husa", "kf", "precal"):
            run.figures[f"{protocol}.{name}.angle_rms_deg_e"] = Figure(
                result["metrics"][name]["angle_rms_deg_e"], "deg e", "{:.3g}", tolerance_rel=0.03)
        if "oracle_improvement_pct" in result:
            run.figures[f"{protocol}.oracle.angle_rms_improvement_pct"] = Figure(
                result["oracle_improvement_pct"]["angle_rms_deg_e"], "%", "{:.1f}", tolerance_abs=1.0)
        run.figures[f"{protocol}.met"] = Figure(met)
    run.tables["protocols"] = rows
    return run


#: the shipped real captures as docs/real-captures.md names them
CAPTURE_LABELS = {"20260618-spindle-hw": "spindle", "20250616-hboard-cycle": "hoverboard, speed cycles",
                  "20250616-back-and-forth": "hoverboard, back and forth", "20250615-new-slow": "slow rotation"}


def _pm_text(value: float | None, stderr: float | None, scale: float, fmt: str) -> str:
    if value is None or stderr is None:
        return "-"
    return f"{fmt.format(value * scale)} +- {stderr * scale:.2g}"


def produce_capture_halves(work: Path) -> Run:
    """docs/real-captures.md: each shipped capture calibrated whole, and its halves calibrated alone
    (``tools/calibration_coverage.py --captures 0 --halves``)."""
    run = Run()
    out = work / "halves.json"
    _tool(run, "calibration_coverage.py", "--captures", "0", "--halves", "--json", str(out))
    result = json.loads(out.read_text())["halves"]
    halves = [["capture", "delay difference, halves", "z", "asymmetry z", "installation z (A, B, C)",
               "pole offsets: largest z"]]
    whole = [["capture", "rise-minus-fall delay `D`", "method cross-check: `D` (constant asymmetry)",
              "constant asymmetry", "pole pairs found"]]
    for stem, label in CAPTURE_LABELS.items():
        h = result[stem]
        rows = {r["figure"]: r for r in h["rows"]}
        key = stem.split("-", 1)[1].replace("-", "_")
        d = rows["delay_difference"]
        z = dict(tolerance_abs=0.3, fmt="{:.1f}")
        run.figures[f"{key}.delay_z"] = Figure(d["z"], "", **z)
        run.figures[f"{key}.asymmetry_z"] = Figure(rows["asymmetry"]["z"], "", **z)
        poles = [r["z"] for name, r in rows.items() if name.startswith("pole ")]
        if poles:
            run.figures[f"{key}.pole_z_max"] = Figure(max(poles), "", **z)
        for i, part in enumerate(("first", "second")):
            run.figures[f"{key}.delay_{part}_half_us"] = Figure(d["halves"][i] * 1e6, "us", "{:.1f}",
                                                                tolerance_abs=max(0.5, 0.25 * d["stderr"][i] * 1e6))
            run.figures[f"{key}.delay_{part}_half_stderr_us"] = Figure(d["stderr"][i] * 1e6, "us", "{:.2g}",
                                                                       tolerance_rel=0.25)
        halves.append([
            label,
            " / ".join(_pm_text(a, s_, 1e6, "{:+.4g}") for a, s_ in zip(d["halves"], d["stderr"])) + " us",
            f"{d['z']:.1f}", f"{rows['asymmetry']['z']:.1f}",
            ", ".join(f"{rows[f'installation {x}']['z']:.1f}" for x in "ABC" if f"installation {x}" in rows),
            f"{max(poles):.1f} ({len(poles)} poles)" if poles else "(no pole count)",
        ])
        w = h["whole"]
        cc = w.get("method_cross_check") or {}
        dd, aa = w["rise_fall_delay_difference_s"], w["rise_fall_angle_asymmetry_deg_e"]
        ccd, cca = cc.get("rise_fall_delay_difference_s") or {}, cc.get("rise_fall_angle_asymmetry_deg_e") or {}
        whole.append([
            label,
            _pm_text(dd.get("value"), dd.get("stderr"), 1e6, "{:+.4g}") + " us",
            _pm_text(ccd.get("value"), ccd.get("stderr"), 1e6, "{:+.4g}") + " us ("
            + _pm_text(cca.get("value"), cca.get("stderr"), 1.0, "{:+.3g}") + " deg e)",
            _pm_text(aa.get("value"), aa.get("stderr"), 1.0, "{:+.3g}") + " deg e",
            str(h["pole_pairs"] or "none stands out"),
        ])
    run.tables["halves"] = halves
    run.tables["whole"] = whole
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


def produce_gap_captures(work: Path) -> Run:
    """docs/real-captures.md and docs/gap.md: ``hil gap diagnose`` on each shipped real capture."""
    run = Run()
    rows = [["capture", "gap", "accepted (in order)", "confounded",
             "held-out gap, shrink (90 % interval)", "split-half `D`"]]
    for stem, label in CAPTURE_LABELS.items():
        rec = _import_capture(run, work, f"{stem}.vcd")
        out = work / f"{stem}-gap.json"
        _hil(run, work, "gap", "diagnose", str(rec), "--json", str(out))
        g = json.loads(out.read_text())
        key = stem.split("-", 1)[1].replace("-", "_")
        run.figures[f"{key}.gap_deg_e"] = Figure(g["gap_before"], "deg e", "{:.2f}", tolerance_abs=0.02)
        accepted = [a["effect"] for a in g.get("accepted", [])]
        run.figures[f"{key}.accepted"] = Figure(", ".join(accepted) or "none")
        heldout = "-"
        if g.get("gap_after_heldout") is not None:
            shrink, (lo, hi) = g["heldout_shrink"], g["heldout_interval"]
            run.figures[f"{key}.heldout_shrink_pct"] = Figure(100 * shrink, "%", "{:.1f}", tolerance_abs=1.0)
            heldout = (f"{g['gap_after_heldout']:.3g} deg e, {100 * shrink:.1f} % ({100 * lo:.1f}-{100 * hi:.1f} %)"
                       + (": not established" if lo <= 0 else ""))
        rep = g.get("repeatability") or {}
        split = "-"
        if rep.get("rise_fall_delay_difference_s"):
            a, b = (1e6 * v for v in rep["rise_fall_delay_difference_s"])
            split = f"{a:.1f} / {b:.1f} us (z {rep['delay_difference_z']:.1f})"
        rows.append([label, f"{g['gap_before']:.2f} deg e",
                     ", ".join(accepted) or "none", "; ".join("/".join(c) for c in g.get("confounded", [])) or "none",
                     heldout, split])
    run.tables["captures"] = rows
    return run


def produce_gap_validation(work: Path) -> Run:
    """docs/gap.md, "Validation": ``hil gap validate`` at its default size, the figures at SNR >= 3
    against their bars."""
    run = Run(seeds=[0])
    out = work / "validate.json"
    _hil(run, work, "gap", "validate", "--no-progress", "--json", str(out), timeout_s=7200)
    s = json.loads(out.read_text())["summary_snr_ge_3"]

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f} %"

    for key in ("top1_rate", "top3_rate", "false_alarm_rate", "no_trace_alarm_rate", "unexplained_rate",
                "param_within_20pct_rate", "median_param_error", "median_heldout_shrink",
                "two_effect_both_found_rate"):
        run.figures[key] = Figure(None if s.get(key) is None else 100 * s[key], "%", "{:.1f}", tolerance_abs=2.0)
    electrical = s.get("top1_rate_by_generator", {}).get("electrical")
    run.tables["snr3"] = [
        ["at SNR >= 3", "measured", "bar"],
        ["top-1 identification", f"{pct(s['top1_rate'])} ({s['single_cases']} cases; {pct(electrical)} on the "
                                 "electrical plant)", ">= 90 %"],
        ["top-3 identification", pct(s["top3_rate"]), ">= 98 %"],
        ["false alarms on null recordings", f"{pct(s['false_alarm_rate'])} ({s['null_cases']})", "<= 5 %"],
        ["dead time withheld, flagged", f"{pct(s['no_trace_alarm_rate'])} ({s['no_trace_cases']})", "(no trace)"],
        ["out-of-library called unexplained", f"{pct(s['unexplained_rate'])} ({s['out_of_library_cases']})",
         ">= 90 %"],
        ["fitted magnitudes within 20 %", f"{pct(s['param_within_20pct_rate'])} (median error "
                                          f"{pct(s['median_param_error'])})", "within 20 %"],
        ["median held-out shrink", pct(s["median_heldout_shrink"]), ">= 80 %"],
        ["both of two withheld effects found", f"{pct(s['two_effect_both_found_rate'])} ({s['two_effect_cases']})",
         "(reported)"],
    ]
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


def produce_compare_correction(work: Path) -> Run:
    """docs/calibration.md, "Raw versus corrected commutation": ``hil compare-correction``."""
    run = Run(seeds=[0])
    done = _hil(run, work, "compare-correction", "--plot", str(work / "headline.png"))
    rows = [["strategy", "speed fluctuation MSE", "mean phase current", "commutation error RMS", "p99"]]
    labels = {"raw": "raw Hall edges", "corrected": "corrected edges"}
    found = re.findall(r"^(raw Hall edges|corrected edges)\s+([\d.e+\-]+) rpm2\s+[\d.e+\-]+ rpm2\s+"
                       r"([\d.]+) A\s+([\d.]+) de\s+([\d.]+) de", done.stdout, re.M)
    red = re.search(r"speed MSE ([\d.\-]+)% .*mean phase current ([\d.\-]+)%", done.stdout)
    if len(found) != 2 or not red:
        raise RuntimeError(f"hil compare-correction printed no table:\n{done.stdout[-1500:]}")
    for name, mse, cur, rms_, p99 in found:
        key = "raw" if "raw" in name.lower() else "corrected"
        rows.append([labels[key], f"{float(mse):.2g} rpm^2", f"{float(cur):.4f} A", f"{float(rms_):.2f} deg e",
                     f"{float(p99):.2f} deg e"])
        run.figures[f"{key}.rms_deg_e"] = Figure(float(rms_), "deg e", "{:.2f}", tolerance_abs=0.02)
    run.figures["speed_mse_reduction_pct"] = Figure(float(red[1]), "%", "{:.1f}", tolerance_abs=1.0)
    run.figures["mean_current_reduction_pct"] = Figure(float(red[2]), "%", "{:.1f}", tolerance_abs=0.5)
    run.tables["strategies"] = rows
    return run


def produce_closed_loop(work: Path) -> Run:
    """docs/sage-husa.md, "Closed loop": ``hil table5 --closed-loop`` (seed 0), Sage-Husa through the
    controller on every link against its offline replay, and the filter's counters."""
    run = Run(seeds=[0])
    done = _hil(run, work, "table5", "--closed-loop", "--json", str(work / "closed-loop.json"))
    found = re.findall(r"^(in-process|canopen|modbus)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)\s+"
                       r"(\d+)\s+(\d+)\s+(\d+)\s*$", done.stdout, re.M)
    if len(found) != 3:
        raise RuntimeError(f"hil table5 --closed-loop printed no table:\n{done.stdout[-1500:]}")
    rows = [["link", "commutations", "closed loop RMS deg e", "offline RMS deg e", "ratio", "gated edges",
             "covariance repairs", "divergence fades", "band projections"]]
    for link, n, cl, off, ratio, gated, repairs, fades, band in found:
        rows.append([link, n, cl, off, ratio, gated, repairs, fades, band])
        key = link.replace("-", "_")
        run.figures[f"{key}.ratio"] = Figure(float(ratio), "", "{:.3f}", tolerance_abs=0.01)
        run.figures[f"{key}.closed_loop_rms_deg_e"] = Figure(float(cl), "deg e", "{:.4f}", tolerance_rel=0.03)
        run.figures[f"{key}.repairs"] = Figure(int(repairs), "", "{:d}")
    run.tables["links"] = rows
    return run


def produce_req_pred_002_spread(work: Path) -> Run:
    """docs/sage-husa.md, REQ-PRED-002: the controller's defaults, Sage-Husa over the KF per operating
    profile over ten held-out seeds, in-process (``tools/req_pred_002_spread.py``)."""
    run = Run(seeds=list(range(10)))
    out = _tool(run, "req_pred_002_spread.py").stdout
    profiles = re.findall(r"\n(\w+) ([\d,\- ]+rpm), acceptance plant.*?\nSH/KF of the mean RMS ([\d.]+); per seed "
                          r"([\d.]+)-([\d.]+) .*?SH ahead on (\d+) of (\d+)", out, re.S)
    pooled = re.search(r"pooled SH/KF over (\d+) runs: ([\d.]+); per run ([\d.]+)-([\d.]+); leaving one seed out "
                       r"([\d.]+)-([\d.]+)", out)
    if not profiles or not pooled:
        raise RuntimeError(f"tools/req_pred_002_spread.py printed no summary:\n{out[-1500:]}")
    rows = [["profile", "Sage-Husa / KF (pooled)", "per seed", "Sage-Husa ahead"]]
    ratio = dict(tolerance_abs=0.01, fmt="{:.3f}")
    ahead_total = 0
    for name, rpm, r, lo, hi, ahead, n in profiles:
        run.figures[f"{name}.ratio"] = Figure(float(r), "", **ratio)
        run.figures[f"{name}.ahead"] = Figure(int(ahead), "", "{:d}", tolerance_abs=2)
        ahead_total += int(ahead)
        rows.append([f"{name}, {rpm}", r, f"{lo}-{hi}", f"{ahead} of {n}"])
    n_runs, r, lo, hi, loo_lo, loo_hi = pooled.groups()
    rows.append([f"all {n_runs} runs", f"**{r}**", f"{lo}-{hi}", f"{ahead_total} of {n_runs}"])
    run.figures["pooled_ratio"] = Figure(float(r), "", **ratio)
    run.figures["leave_one_out_low"] = Figure(float(loo_lo), "", **ratio)
    run.figures["leave_one_out_high"] = Figure(float(loo_hi), "", **ratio)
    for name in ("paper", "high"):  # "N % behind the KF" in the prose
        if f"{name}.ratio" in run.figures:
            run.figures[f"{name}.behind_pct"] = Figure(100 * (run.figures[f"{name}.ratio"].value - 1), "%",
                                                       "{:.1f}", tolerance_abs=1.0)
    run.tables["profiles"] = rows
    run.figures["wall_s"] = Figure(run.last_command_s, "s", "{:.0f}", reproducible=False)
    return run


def produce_sil_reference(work: Path) -> Run:
    """docs/firmware-in-the-loop.md: the reference firmware (C, through ``sil:``) beside the built-in
    controller (in-process), per judged budget, on seeds 0 and 1 (``tools/sil_compare.py``)."""
    run = Run(seeds=[0, 1])
    out = work / "sil-compare.json"
    _tool(run, "sil_compare.py", "--json", str(out), "--seeds", "0,1")
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


def produce_pil_reference(work: Path) -> Run:
    """docs/processor-in-the-loop.md: the reference firmware through sil: and pil: (Cortex-M4F, 168 MHz)
    per judged budget on seeds 0 and 1, its defects of the part through both, and the firmware on a
    Cortex-M0+ (``tools/pil_compare.py``)."""
    run = Run(seeds=[0, 1])
    out = work / "pil-compare.json"
    _tool(run, "pil_compare.py", "--json", str(out), "--seeds", "0,1", "--pil-seeds", "0", "--work",
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


def produce_sil_speed(work: Path) -> Run:
    """docs/firmware-in-the-loop.md, "Speed": the acceptance suite through the reference firmware
    beside in-process and CANopen in one run (``benchmarks/bench_sil.py``); run times, never held."""
    run = Run()
    out = work / "bench-sil.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_sil.py"), "--json", str(out)]
    run.commands.append("python benchmarks/bench_sil.py --json $WORK/bench-sil.json")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=7200, env=env)
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


def _children_cpu_s() -> float:
    t = os.times()
    return t.children_user + t.children_system


# ---------------------------------------------------------------- what each group reads
# Every group's producer is code of this file (its parsing and its tables): until each producer has
# a file of its own, a change here is a change to every group's inputs.
PRODUCERS = ("tools/figures.py",)
#: what ``python -m hil`` runs, and what any script importing ``hil`` may reach. Not narrower: every
#: command goes through hil/cli.py, which imports each command's modules inside its function, and the
#: imports of the files it reaches (anywhere in a file: tests/test_figures.py follows them) reach all
#: but a handful of the three packages' modules; their data (report templates, device profiles, the
#: firmware-in-the-loop header) are read by the same code.
HIL = (*PRODUCERS, "hil/**", "bldc/**", "plant_models/**")
#: the acceptance suite as ``hil acceptance`` and ``hil qualify`` run it: pytest on test_cases/ from the
#: repository's root, so the root conftest.py and pyproject.toml's pytest settings apply
SUITE = (*HIL, "test_cases/**", "conftest.py", "pyproject.toml")
#: the reference firmware, built and run through ``sil:firmware/reference``
FIRMWARE = ("firmware/reference/**",)


def _capture(vcd: str) -> str:
    return str((REAL_CAPTURES / vcd).relative_to(ROOT))


SPINDLE, HOVERBOARD = "20260618-spindle-hw.vcd", "20250616-hboard-cycle.vcd"
ALL_CAPTURES = _capture("*.vcd")

GROUPS: list[Group] = [
    Group("demo", "README tour step 1: the paper-bench demo's captured-edge error", True, produce_demo, HIL),
    Group("spindle_calibration", "docs/real-captures.md: the spindle capture calibrated", True,
          _produce_real_calibration(SPINDLE), (*HIL, _capture(SPINDLE))),
    Group("hoverboard_calibration", "docs/real-captures.md: the hoverboard speed cycles calibrated", False,
          _produce_real_calibration(HOVERBOARD), (*HIL, _capture(HOVERBOARD)), rotation=True),
    Group("spindle_predictors", "docs/sage-husa.md: every predictor on the spindle capture", True,
          _produce_real_predictors(SPINDLE), (*HIL, _capture(SPINDLE))),
    Group("pump_predictors", "docs/sage-husa.md: every predictor on the held-out pumps", False,
          produce_pump_predictors, HIL, rotation=True),
    Group("paper_predictors", "docs/sage-husa.md: every predictor in the paper's speed-step scenario", False,
          produce_paper_predictors, HIL, rotation=True),
    Group("capture_halves", "docs/real-captures.md: each shipped capture whole and in halves", False,
          produce_capture_halves, (*HIL, "tools/calibration_coverage.py", ALL_CAPTURES)),
    Group("gap_captures", "docs/real-captures.md, docs/gap.md: hil gap diagnose on each shipped capture", False,
          produce_gap_captures, (*HIL, ALL_CAPTURES)),
    Group("gap_validation", "docs/gap.md: hil gap validate at its default size", False, produce_gap_validation,
          HIL),
    Group("compare_correction", "docs/calibration.md: raw versus corrected commutation (paper Section 4.3)", False,
          produce_compare_correction, HIL, rotation=True),
    Group("closed_loop", "docs/sage-husa.md: Sage-Husa through the controller against its offline replay", False,
          produce_closed_loop, HIL, rotation=True),
    Group("table5", "docs/sage-husa.md: Table 5's comparison under the four protocols", False, produce_table5,
          HIL),
    Group("req_pred_002_spread", "docs/sage-husa.md: REQ-PRED-002 per operating profile, held-out seeds", False,
          produce_req_pred_002_spread, (*HIL, "tools/req_pred_002_spread.py")),
    Group("spindle_twin", "docs/twin.md: the spindle's twin, checked and put through the suite", False,
          _produce_twin(SPINDLE), (*SUITE, _capture(SPINDLE))),
    Group("hoverboard_twin", "docs/twin.md: the hoverboard's twin, checked and put through the suite", False,
          _produce_twin(HOVERBOARD), (*SUITE, _capture(HOVERBOARD))),
    Group("sil_reference", "docs/firmware-in-the-loop.md: the reference firmware beside the built-in controller",
          False, produce_sil_reference, (*SUITE, *FIRMWARE, "tools/sil_compare.py")),
    Group("pil_reference", "docs/processor-in-the-loop.md: the reference firmware through sil: and pil:, its defects "
          "of the part, the Cortex-M0+", False, produce_pil_reference, (*SUITE, *FIRMWARE, "tools/pil_compare.py")),
    Group("sil_speed", "docs/firmware-in-the-loop.md: the suite's run time through the reference firmware", False,
          produce_sil_speed, (*SUITE, *FIRMWARE, "benchmarks/bench_sil.py")),
    Group("acceptance", "README: the default acceptance run's verdict and run time", False, produce_acceptance,
          SUITE),
    # everything the suite reads but the figures' own output: each figures commit rewrites the file and
    # the pages, and the suite's tests of them (tests/test_figures.py, tests/test_readme.py) run in CI on
    # every commit anyway, as the whole suite does
    Group("test_suite", "README: the test command's run time", False, produce_test_suite,
          ("**", "!docs/figures.json", "!docs/*.md", "!README.md")),
    Group("first_run", "docs/acceptance.md: the default acceptance on a fresh clone, compile included, then warm",
          False, produce_first_run, SUITE),
    Group("qualify", "docs/qualify.md: hil qualify --sensitivity, the sensitivity table", False, produce_qualify,
          SUITE),
]


# ---------------------------------------------------------------- the file and the docs


def _commit() -> str:
    """HEAD, marked when tracked files differ from it."""
    commit = _git("rev-parse", "HEAD").stdout.strip()
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no").stdout.strip())
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
            out[g.name]["digest"] = digest(json.loads(json.dumps(out[g.name])))
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


def release_check_text(data: dict) -> str:
    """The release check's record as the docs show it."""
    r = data.get("release_check")
    if not r:
        return ("never run against this figures file: run `python tools/figures.py --check --all` before a "
                "release")
    return (f"`python tools/figures.py --check --all` on {r['date'][:10]} at {r['commit'][:10]}: "
            f"{len(r['groups'])} groups recomputed in {r['duration_s']:.0f} s, {len(r.get('agreed', []))} of "
            f"them agree with the file: {r['result']}")


def _release_digest(r: dict) -> str:
    import hashlib

    content = json.dumps({k: v for k, v in r.items() if k != "digest"}, sort_keys=True)
    return hashlib.sha256(content.encode()).hexdigest()


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

    text = CHECK_MARK.sub(lambda m: f"<!-- figcheck -->{release_check_text(data)}<!-- /figcheck -->", text)
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
        for m in CHECK_MARK.finditer(text):
            if m["text"] != release_check_text(data):
                line = text.count("\n", 0, m.start()) + 1
                out.append(f"{path.relative_to(ROOT)}:{line}: the release check's record differs from the figures file")
    release = data.get("release_check")
    if release and release.get("digest") != _release_digest(release):
        out.append(f"{FIGURES_FILE.name}: release_check: not what tools/figures.py wrote (digest mismatch)")
    return out


#: a decimal number in prose or a table (what ``unmarked_numbers`` counts)
DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?![\w.])")
#: the requirement registry's generated tables (hil/requirements.py): limits and sources, not measurements
GENERATED_MARK = re.compile(r"<!-- generated from hil/requirements\.py.*?<!-- end of the generated table -->", re.S)


def unmarked_numbers(text: str) -> list[tuple[int, str]]:
    """(line, number) of every decimal outside the figure markers and the registry's generated tables:
    parameters, the paper's values, limits, and measurements not yet under a marker."""
    blank = lambda m: "\n" * m[0].count("\n")  # noqa: E731 - keep line numbers
    for mark in (FIG_MARK, TABLE_MARK, CHECK_MARK, GENERATED_MARK):
        text = mark.sub(blank, text)
    return [(text.count("\n", 0, m.start()) + 1, m[0]) for m in DECIMAL.finditer(text)]


def unmarked_counts() -> dict[str, int]:
    return {str(p.relative_to(ROOT)): len(unmarked_numbers(p.read_text())) for p in PUBLISHED}


def unmarked_growth(data: dict) -> list[str]:
    """Pages with more unmarked decimals than the file's ledger allows (the ledger only shrinks)."""
    ledger = data.get("unmarked_ledger", {})
    return [f"{page}: {n} decimals outside the figure markers, the ledger allows {ledger.get(page, 0)}: put a "
            "measurement under a marker (tools/figures.py), or remove it"
            for page, n in unmarked_counts().items() if n > ledger.get(page, 0)]


def render(data: dict) -> list[Path]:
    changed = []
    for path in PUBLISHED:
        old = path.read_text()
        new = render_text(old, data)
        if new != old:
            path.write_text(new)
            changed.append(path)
    return changed


NUMBER = re.compile(r"[-+\u2212]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def _cell_drift(old: str, new: str, rel: float) -> str | None:
    """Why cell ``new`` is not cell ``old``: the words must be the same and every number within the
    larger of ``rel`` of it and one unit of its last printed digit."""
    if old == new:
        return None
    if NUMBER.sub("#", old) != NUMBER.sub("#", new):
        return f"{old!r} -> {new!r}"
    for a, b in zip(NUMBER.findall(old), NUMBER.findall(new)):
        x, y = float(a.replace("\u2212", "-")), float(b.replace("\u2212", "-"))
        digits = len(a.split(".")[1].split("e")[0]) if "." in a else 0
        if abs(y - x) > max(rel * abs(x), 10.0 ** -digits) + 1e-12:
            return f"{old!r} -> {new!r}"
    return None


#: how far a recomputed table cell may move (relative; at least one unit of its last digit)
TABLE_TOLERANCE_REL = 0.03


def _tables_drift(gname: str, old: dict, new: dict) -> list[str]:
    out = []
    for kind in ("tables", "blocks"):
        for name, rows in new.get(kind, {}).items():
            if name not in old.get(kind, {}):
                out.append(f"{gname}-{name}: new {kind[:-1]}, not in the file")
                continue
            was = old[kind][name]
            if kind == "blocks":
                rows, was = [[line] for line in rows.splitlines()], [[line] for line in was.splitlines()]
            if len(rows) != len(was) or any(len(a) != len(b) for a, b in zip(rows, was)):
                out.append(f"{gname}-{name}: {kind[:-1]} shape {len(was)} rows -> {len(rows)} rows")
                continue
            for i, (ra, rb) in enumerate(zip(was, rows)):
                for j, (a, b) in enumerate(zip(ra, rb)):
                    why = _cell_drift(a, b, TABLE_TOLERANCE_REL)
                    if why:
                        out.append(f"{gname}-{name}: row {i} column {j}: {why}")
        for name in old.get(kind, {}):
            if name not in new.get(kind, {}):
                out.append(f"{gname}-{name}: no longer computed")
    return out


def digest(group: dict) -> str:
    """What the tool wrote for a group, hashed: its figures, tables, blocks and provenance."""
    import hashlib

    content = {k: group.get(k) for k in ("figures", "tables", "blocks", "provenance")}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def history_note() -> str | None:
    """Why provenance commits cannot be checked here (no git, a clone without history), or None."""
    try:
        inside = _git("rev-parse", "--is-inside-work-tree")
    except FileNotFoundError:
        return "provenance NOT checked: git is not installed"
    if inside.returncode != 0:
        return "provenance NOT checked: not a git checkout (an archive has no history to check commits against)"
    if _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        return ("provenance NOT checked: this clone has no history (shallow); `git fetch --unshallow` "
                "and check again")
    return None


def _not_an_ancestor(commit: str) -> str | None:
    """Why ``commit`` is not an ancestor of HEAD in this repository, or None (history assumed: see
    :func:`history_note`)."""
    if not re.fullmatch(r"[0-9a-f]{40}", commit):
        return f"{commit!r} is not a commit"
    if _git("cat-file", "-e", f"{commit}^{{commit}}").returncode != 0:
        return f"{commit[:12]} is no commit of this repository"
    if _git("merge-base", "--is-ancestor", commit, "HEAD").returncode != 0:
        return f"{commit[:12]} is not an ancestor of HEAD"
    return None


def _glob_regex(glob: str) -> re.Pattern:
    """A path glob of :attr:`Group.inputs`: ``**`` spans directories, ``*`` and ``?`` stay within a name."""
    parts = re.split(r"(\*\*|\*|\?)", glob)
    wild = {"**": ".*", "*": "[^/]*", "?": "[^/]"}
    return re.compile("".join(wild.get(x, re.escape(x)) for x in parts) + r"\Z")


def matching(paths: list[str], globs: tuple[str, ...]) -> list[str]:
    """The paths a group's inputs name (``!glob`` takes paths out again)."""
    keep = [_glob_regex(g) for g in globs if not g.startswith("!")]
    drop = [_glob_regex(g[1:]) for g in globs if g.startswith("!")]
    return [p for p in paths if any(k.match(p) for k in keep) and not any(d.match(p) for d in drop)]


def changed_since(commit: str) -> list[str]:
    """Every path that differs between ``commit`` and the working tree: changed in later commits,
    staged or not, and untracked files git does not ignore."""
    diff = _git("diff", "--name-only", "--no-renames", "-z", commit, "--")
    if diff.returncode != 0:
        raise RuntimeError(f"git diff {commit}: {diff.stderr.strip()}")
    untracked = _git("ls-files", "--others", "--exclude-standard", "-z").stdout
    return sorted((set(diff.stdout.split("\0")) | set(untracked.split("\0"))) - {""})


def stale_groups(data: dict) -> dict[str, str]:
    """The file's groups that cannot pass ``--check`` unless recomputed, and why: their provenance
    commit is not an ancestor of HEAD (or this checkout cannot tell), or one of their declared inputs
    changed since it. A group whose commit and inputs say nothing changed is not recomputed: the check
    then holds its content (digest) and the docs to the file, and only a recompute (the CI rotation,
    the release check) would see a figure rewritten with a commit after its last input change."""
    note = history_note()
    declared = {g.name: g for g in GROUPS}
    changes: dict[str, list[str]] = {}
    out = {}
    for name, g in data.get("groups", {}).items():
        if name not in declared:
            continue  # provenance_problems names it; there is nothing to recompute it with
        commit = str((g.get("provenance") or {}).get("commit", ""))
        why = note or _not_an_ancestor(commit)
        if why:
            out[name] = why if note else f"provenance commit {why}"
            continue
        if commit not in changes:
            changes[commit] = changed_since(commit)
        hit = matching(changes[commit], declared[name].inputs)
        if hit:
            out[name] = (f"{len(hit)} of its inputs changed since {commit[:10]} ({', '.join(hit[:3])}"
                         + (", ...)" if len(hit) > 3 else ")"))
    return out


def rotation_group() -> Group:
    """The slow group this commit's CI run recomputes (``rotation=True``): the next one per commit,
    counted along HEAD's history, so each is recomputed once in any run of that many commits; in a
    clone without history, HEAD's hash picks it."""
    rotating = [g for g in GROUPS if g.rotation]
    count = _git("rev-list", "--count", "HEAD").stdout.strip()
    n = int(count) if history_note() is None and count.isdigit() else int(_git("rev-parse", "HEAD").stdout, 16)
    return rotating[n % len(rotating)]


def provenance_problems(data: dict) -> list[str]:
    """Groups whose content is not what the tool wrote (digest) or whose commit is not HEAD's ancestor;
    commits are not looked at when :func:`history_note` says this checkout cannot show them."""
    out = []
    note = history_note()
    declared = {g.name for g in GROUPS}
    for name, g in data.get("groups", {}).items():
        prov = g.get("provenance") or {}
        if name not in declared:  # nothing would ever recompute it
            out.append(f"{FIGURES_FILE.name}: group {name}: no such group in tools/figures.py")
        if g.get("digest") != digest(g):
            out.append(f"{FIGURES_FILE.name}: group {name}: its content is not what tools/figures.py wrote "
                       f"(digest mismatch: edited by hand?); recompute it: python tools/figures.py --only {name}")
        if not prov.get("commands") or not prov.get("date"):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance without commands or date")
        commit = str(prov.get("commit", ""))
        if not re.fullmatch(r"[0-9a-f]{40}", commit):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance commit {commit!r} is not a commit "
                       "(computed from uncommitted files is not reproducible: commit, then compute)")
            continue
        if note is None and (why := _not_an_ancestor(commit)):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance commit {why}")
    release = data.get("release_check")
    if release and note is None and (why := _not_an_ancestor(str(release.get("commit", "")))):
        out.append(f"{FIGURES_FILE.name}: release_check: commit {why}")
    return out


def drift(stored: dict, fresh: dict) -> list[str]:
    """Where recomputed groups differ from the file: figures beyond their tolerance, table and block
    cells beyond ``TABLE_TOLERANCE_REL`` (words exactly)."""
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
        out += _tables_drift(gname, old, g)
    return out


def check(data: dict, only: list[str] | None = None, every: bool = False) -> int:
    """``--check``: the docs against the file, each group's digest and commit, and every group that
    cannot pass without it recomputed (:func:`stale_groups`), or the groups named (``only``), or all
    of them (``every``: the release check, whose record the file keeps and README.md shows)."""
    bad = disagreements(data) + provenance_problems(data) + unmarked_growth(data)
    note = history_note()
    if note:
        print(f"figures: {note}")
    stale = stale_groups(data)
    published = [g for g in GROUPS if g.name in data.get("groups", {})]
    chosen = published if every else [g for g in published if (g.name in only if only else g.name in stale)]
    for g in GROUPS:
        if g.name not in data.get("groups", {}):
            print(f"figures: {g.name}: never computed, nothing of it is published")
        elif g.name in stale:
            print(f"figures: {g.name}: {stale[g.name]}: "
                  + ("recomputing" if g in chosen else "NOT recomputed here (outside --only)"), flush=True)
    t0 = time.perf_counter()
    differ = {}
    for g in chosen:  # one at a time: a producer that fails is a difference, and the others still run
        try:
            differ[g.name] = drift(data, compute([g]))
        except (RuntimeError, OSError, subprocess.SubprocessError, ValueError, KeyError) as exc:
            differ[g.name] = [f"{g.name}: its producer failed: {str(exc).strip()[:1000]}"]
    bad += [line for lines in differ.values() for line in lines]
    if every:  # the record the docs show (README.md, "Published figures")
        record = {
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "commit": _commit(),
            "groups": [g.name for g in chosen],
            "agreed": [name for name, lines in differ.items() if not lines],
            "duration_s": round(time.perf_counter() - t0, 1),
        }
        record["result"] = ("every figure and table cell within tolerance" if len(record["agreed"]) == len(chosen)
                            else f"{len(chosen) - len(record['agreed'])} groups differ: "
                            + ", ".join(name for name, lines in differ.items() if lines))
        record["digest"] = _release_digest(record)
        data["release_check"] = record
        save(data)
        render(data)
    unchecked = sorted(set(stale) - {g.name for g in chosen})
    if bad:
        print("\n".join(bad))
    elif unchecked:
        print(f"figures: the {len(chosen)} groups recomputed agree with {FIGURES_FILE.name}; NOT checked: "
              f"{', '.join(unchecked)} (their inputs changed: `python tools/figures.py --check` recomputes them)")
    else:
        print(f"figures: every published figure agrees with {FIGURES_FILE.name} ({len(chosen)} groups "
              f"recomputed{': ' + ', '.join(g.name for g in chosen) if chosen else ''})")
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="recompute the quick subset; exit 1 on drift")
    mode.add_argument("--render", action="store_true", help="rewrite the docs from the figures file")
    mode.add_argument("--check", action="store_true",
                      help="exit 1 where a doc disagrees with the figures file, a group is not what the tool wrote "
                           "or its commit is not an ancestor of HEAD, or a group recomputed differs; recomputes "
                           "every group whose declared inputs changed since its commit (see --stale)")
    mode.add_argument("--stale", action="store_true",
                      help="list the groups --check would recompute, and why (nothing is computed)")
    ap.add_argument("--only", nargs="+", metavar="GROUP", choices=[g.name for g in GROUPS],
                    help="compute (or with --check, recompute and compare) these groups only")
    ap.add_argument("--all", action="store_true",
                    help="with --check: recompute every group and compare figures and table cells (the release "
                         "check; its record is kept in the file and shown in README.md)")
    mode.add_argument("--unmarked", action="store_true",
                      help="list every decimal of README.md and docs/ outside a figure marker, lower the ledger "
                           "where a page has fewer (exit 1 where a page has more)")
    args = ap.parse_args(argv)
    if args.all and not args.check:
        ap.error("--all goes with --check (plain `python tools/figures.py` computes every group)")
    data = load()
    if args.unmarked:
        for path in PUBLISHED:
            for line, number in unmarked_numbers(path.read_text()):
                print(f"{path.relative_to(ROOT)}:{line}: {number}")
        counts, ledger = unmarked_counts(), data.setdefault("unmarked_ledger", {})
        grew = unmarked_growth(data)
        lowered = {page: n for page, n in counts.items() if n < ledger.get(page, 0)}
        if lowered:  # the ledger only shrinks
            ledger.update(lowered)
            save(data)
        print("\n".join(grew) + "\n" if grew else "", end="")
        print(f"figures: {sum(counts.values())} decimals outside the markers; the ledger allows "
              f"{sum(ledger.values())}" + (f" (lowered on {', '.join(sorted(lowered))})" if lowered else ""))
        return 1 if grew else 0
    if args.check:
        return check(data, args.only, args.all)
    if args.stale:
        durations = {name: g["provenance"]["duration_s"] for name, g in data.get("groups", {}).items()}
        stale = stale_groups(data)
        for name, why in stale.items():
            print(f"{name}: {why} (last computed in {durations[name]:.0f} s)")
        print(f"figures: {len(stale)} of {len(durations)} groups to recompute (they took "
              f"{sum(durations[n] for n in stale):.0f} s when last computed)")
        return 0
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
    data = load()  # as it is now: another run may have written its groups meanwhile
    data.setdefault("groups", {}).update(fresh)
    save(data)
    for p in render(data):
        print(f"rendered {p.relative_to(ROOT)}")
    print(f"figures: wrote {FIGURES_FILE.relative_to(ROOT)} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
