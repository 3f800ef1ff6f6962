"""``hil qualify``: the acceptance suite run against each seeded firmware defect.

The control run (the built-in controller as shipped) must PASS; each defect then runs the same
suite with ``--hil-defect NAME`` and stops at its first failing test (``-x``). A defect is
caught when a test failed an assertion (a judged figure outside its bound: ``caught_by =
"assertion"``); the requirements that failed are what caught it. A test that errored (an
exception other than an assertion: ``caught_by = "error"``) judged nothing: a finding to fix,
not a kill. Without a control run that PASSes there is no detection figure. The suite's files
run cheapest first, so a caught defect costs seconds, a survivor the whole suite.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .defects import CATALOGUE, load_defects

#: the acceptance suite's files, cheapest and most discriminating first (the property searches last)
SUITE_ORDER = (
    "test_protocol.py",
    "test_faults.py",
    "test_calibration_recovery.py",
    "test_live_calibration.py",
    "test_signal_injection.py",
    "test_sage_husa_learning.py",
    "test_sage_husa.py",
    "test_fault_injection.py",
)
#: a run that has not finished after this long is stopped and reported as undecided
RUN_TIMEOUT_S = 1200.0


@dataclass
class Run:
    name: str
    description: str
    verdict: str  #: the report's verdict: PASS, FAIL, or "no report"
    killed: bool  #: caught by an assertion
    #: "assertion" (a test failed a judged bound), "error" (a test raised something else and
    #: none failed an assertion), or None (nothing failed)
    caught_by: str | None = None
    killed_by: list[str] = field(default_factory=list)  #: requirement ids that failed
    failed_tests: list[str] = field(default_factory=list)
    duration_s: float = 0.0
    report: str = ""
    note: str = ""


def suite_files(suite: Path) -> list[str]:
    """The suite's test files in SUITE_ORDER (others after them, by name)."""
    files = sorted(p.name for p in suite.glob("test_*.py"))
    if not files:
        raise FileNotFoundError(f"no test_*.py in the acceptance suite {suite}")
    ordered = [f for f in SUITE_ORDER if f in files] + [f for f in files if f not in SUITE_ORDER]
    return [str(suite / f) for f in ordered]


def out_of_scope_budgets(dut: str, budgets: str | None, directory: Path) -> tuple[str | None, dict[str, str]]:
    """A budgets file that takes out of scope each requirement the DUT form's profile cannot show
    (hil.requirements: the Modbus controller has no heartbeat and no EMCY), over the
    user's ``budgets``; its path (None when nothing is out of scope) and the requirements with why."""
    from ..requirements import REQUIREMENTS, missing_needs
    from ..dut.profile import load_profile, shipped
    from ..dut.spec import parse_dut

    spec = parse_dut(dut)
    if spec.kind == "sil":  # a firmware in the loop: its own profile; its pins close the loop
        from ..sil.build import read_build_spec

        path = spec.options.get("profile") or (
            read_build_spec(spec.options["path"]).profile if Path(spec.options["path"]).is_dir() else None)
        profile = load_profile(path) if path else shipped("canopen")
        hook = "pins"
    elif not spec.is_virtual or spec.transport not in ("canopen", "modbus"):
        raise ValueError(f"hil qualify seeds defects into the built-in controller or a firmware folder: give "
                         f"virtual:canopen, virtual:modbus (with profile=FILE if you like) or sil:DIR, not {dut}")
    else:
        path = spec.options.get("profile")
        profile = load_profile(path) if path else shipped(spec.transport)
        hook = profile.edge_hook.kind
    lacking = {}
    for rid in REQUIREMENTS:
        missing = missing_needs([rid], profile.has, hook, profile.fault_sources)
        if missing:
            lacking[rid] = f"not testable on {dut} (its profile lacks {', '.join(missing)})"
    if not lacking:
        return budgets, {}
    text = Path(budgets).read_text() + "\n" if budgets else ""
    for rid, why in lacking.items():
        text += f'\n[[out_of_scope]]\nrequirement = "{rid}"\nreason = "{why}"\nowner = "hil qualify"\n'
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / "qualify-budgets.toml"
    out.write_text(text)
    return str(out), lacking


def what_caught(report: dict) -> tuple[str | None, list[str], list[str]]:
    """From a run's HIL report: ``caught_by`` ("assertion" when a test failed an assertion,
    "error" when tests only errored, None), the requirements of the tests that failed an
    assertion, and every failed or errored test. A verdict short of PASS for another reason (a
    requirement the run could not test) or a test that errored is not a catch."""
    failed = [t for t in report.get("tests", []) if t.get("outcome") in ("failed", "error")]
    kinds = {t.get("failed_by") or "error" for t in failed}
    caught_by = "assertion" if "assertion" in kinds else ("error" if kinds else None)
    requirements = sorted({r for t in failed if t.get("failed_by") == "assertion" for r in t.get("requirements", [])})
    return caught_by, requirements, [t["nodeid"] for t in failed]


FIRMWARE_DEFECTS_FORMAT = "bldc-hil-firmware-defects/1"


@dataclass(frozen=True)
class FirmwareDefect:
    """A seeded defect of a firmware folder: a compile-time switch its ``defects.toml`` lists."""

    name: str
    define: str
    description: str
    requirements: tuple[str, ...] = ()


def firmware_defects(dut: str) -> dict[str, FirmwareDefect]:
    """The seeded defects of a ``sil:DIR`` firmware: ``DIR/defects.toml`` (format
    ``bldc-hil-firmware-defects/1``: ``[[defect]]`` tables of name, define, description,
    requirements), or {} for any other DUT. Errors name the file, the table and the key."""
    from bldc.tomlfile import TomlError, load_toml

    from ..dut.spec import parse_dut

    spec = parse_dut(dut)
    if spec.kind != "sil":
        return {}
    path = Path(spec.options["path"]) / "defects.toml"
    if not path.is_file():
        raise ValueError(f"{path}: no such file: a firmware's seeded defects are listed there "
                         "(docs/firmware-in-the-loop.md)")
    schema = {"format": None, "defect": [{"name": None, "define": None, "description": None, "requirements": None}]}
    data = load_toml(path, schema)
    if data.get("format") != FIRMWARE_DEFECTS_FORMAT:
        raise TomlError(path, f"must be {FIRMWARE_DEFECTS_FORMAT!r}", key="format")
    out = {}
    for i, d in enumerate(data.get("defect", [])):
        for key in ("name", "define", "description"):
            if not isinstance(d.get(key), str) or not d[key]:
                raise TomlError(path, "required, a non-empty string", table=f"[[defect]][{i}]", key=key)
        out[d["name"]] = FirmwareDefect(d["name"], d["define"], d["description"], tuple(d.get("requirements", ())))
    return out


def _run(name: str, description: str, defect: str | None, args) -> Run:
    report_dir = Path(args.report_dir) / (defect or "control")
    firmware = getattr(args, "firmware_defects", None) or {}
    dut = args.dut + (f",define={firmware[defect].define}" if defect in firmware else "")
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "--hil-dut", dut,
           "--hil-report-dir", str(report_dir), "--hil-seed", str(args.seed)]
    if args.budgets:
        cmd += ["--hil-budgets", args.budgets]
    if defect is not None and defect not in firmware:
        cmd += ["--hil-defect", defect]
        if args.defects:
            cmd += ["--hil-defects", args.defects]
    cmd += suite_files(Path(args.suite))
    started = time.monotonic()
    note = ""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"})
        output = proc.stdout + proc.stderr
    except subprocess.TimeoutExpired:
        output, note = "", f"stopped after {RUN_TIMEOUT_S:.0f} s"
    duration = time.monotonic() - started
    report_json = report_dir / "hil-report.json"
    if not report_json.is_file():
        tail = " | ".join(output.strip().splitlines()[-3:])
        return Run(name, description, "no report", False, None, duration_s=duration, report=str(report_json),
                   note=note or f"the run wrote no report: {tail}")
    report = json.loads(report_json.read_text())
    verdict = report.get("verdict", "no verdict")
    caught_by, failed_reqs, failed_tests = what_caught(report)
    if caught_by == "error":
        note = (note + "; " if note else "") + "a test errored (no assertion failed): a finding to fix, not a catch"
    return Run(name, description, verdict, caught_by == "assertion", caught_by, failed_reqs, failed_tests, duration,
               str(report_json), note)


def qualify(args, progress=print) -> dict:
    """Control run and one run per defect (``args.only`` or the whole catalogue), ``args.workers``
    at a time; the result as the JSON ``hil qualify`` writes."""
    if args.defects:
        load_defects(args.defects)
    # a firmware folder brings its own defects (compile-time switches); the built-in controller the catalogue's
    args.firmware_defects = firmware_defects(args.dut)
    catalogue = args.firmware_defects or CATALOGUE
    names = list(catalogue) if not args.only else args.only
    unknown = [n for n in names if n not in catalogue]
    if unknown:
        raise ValueError(f"unknown defect(s) {', '.join(unknown)}; known: {', '.join(catalogue)}")
    args.budgets, out_of_scope = out_of_scope_budgets(args.dut, args.budgets, Path(args.report_dir))
    for rid, why in out_of_scope.items():
        progress(f"out of scope: {rid}: {why}")
    control = "the firmware as built" if args.firmware_defects else "the built-in controller as shipped"
    jobs = [("control", control, None)] + [(n, catalogue[n].description, n) for n in names]
    started = time.monotonic()
    with ThreadPoolExecutor(max_workers=max(int(args.workers), 1)) as pool:
        futures = [pool.submit(_run, name, description, defect, args) for name, description, defect in jobs]
        runs = []
        for future in futures:
            run = future.result()
            runs.append(run)
            caught = ", ".join(run.killed_by) or "-"
            state = "control" if run.name == "control" else (
                "killed" if run.killed else ("ERRORED" if run.caught_by == "error" else "SURVIVED"))
            progress(f"{run.name:<34} {state:<9} {run.verdict:<9} {run.duration_s:6.1f} s  caught by: {caught}"
                     + (f"  ({run.note})" if run.note else ""))
    control, mutants = runs[0], runs[1:]
    killed = [m for m in mutants if m.killed]
    by_requirement: dict[str, list[str]] = {}
    for m in killed:
        for req in m.killed_by:
            by_requirement.setdefault(req, []).append(m.name)
    return {
        "format": "hil-qualify/1",
        "dut": args.dut,
        "seed": args.seed,
        "control_verdict": control.verdict,
        "out_of_scope": out_of_scope,
        "control": asdict(control),
        "mutants": [asdict(m) for m in mutants],
        # a detection figure only over a control run that PASSes: against a failing control a
        # "caught" defect may be the control's own failure
        "detection": {
            "killed": len(killed),
            "total": len(mutants),
            "ratio": len(killed) / len(mutants) if mutants else None,
        } if control.verdict == "PASS" else None,
        "no_detection_because": None if control.verdict == "PASS" else (
            f"the control run's verdict is {control.verdict}, not PASS: a defect's failure could be the "
            f"control's own ({', '.join(control.failed_tests) or control.note or 'see its report'})"),
        "errored": [m.name for m in mutants if m.caught_by == "error"],
        "requirements": {req: sorted(names_) for req, names_ in sorted(by_requirement.items())},
        "survivors": [m.name for m in mutants if m.caught_by is None],
        "duration_s": time.monotonic() - started,
    }
