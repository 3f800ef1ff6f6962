"""``hil qualify``: the acceptance suite run against each seeded firmware defect.

The control run (the built-in controller as shipped) must PASS; each defect then runs the same
suite with ``--hil-defect NAME``, the tests of the requirements that name its class first
(``--hil-first``), and stops after the first test whose failure is a catch (``--hil-stop-at-catch``;
not ``-x``, which would also stop at a setup check or at a check that counts for nothing, before
the real catch ran). What the run saw (``what_caught``), test by test from its HIL report. A catch
is one of:

* a failed **budget** (a measurement whose verdict is fail): caught by that budget's requirement,
  whichever test's marker measured it;
* a failed **judged check** (hil.verdicts.requirements.JudgedCheck: back-to-back against the reference, or
  physics), its requirement's as a budget's is, labelled by its judgement;
* a **processor fault** (``pil:``: the emulated core met a HardFault, UsageFault, BusFault,
  MemManage, a stack overflow or a hang, ``hil.pil.core``): the part's own failure, a failed
  requirement of the test that met it, labelled by the fault and where ("processor fault
  UsageFault in ctl_hall_isr (control.c:837)");
* a **device failure** (the controller signalled its own failure on valid input: a Modbus
  exception 04, an SDO abort 0x08000000 or 0x06060000; hil.verdicts.judging): a failed requirement, the
  test's;
* a failed **check** (an assertion that is no budget) of a requirement that has no budget (a
  pass/fail requirement, judged by its fault code, say).

Nothing else is a catch: a plain assertion in a test of a requirement that has budgets is listed
(``checks_not_counted``) and catches nothing, so a requirement is credited only with what its own
budgets, judged checks or device failures saw. **not judged** (a setup check found that the
scenario did not provoke what the test judges) and **error** (anything else) catch nothing
either: findings to fix.

With ``--sensitivity`` each defect runs to the end, restricted to the tests of the
requirements that name its class (``hil.verdicts.requirements``, ``judges``), and the result holds the
sensitivity table: requirement x defect -> caught by that requirement's own budget or check, with
the margin (``sensitivity_markdown``). Without a control run that PASSes there is no detection
figure.

**Defects of one kind of DUT.** A firmware defect may name the DUT kinds that must catch it
(defects.toml's ``kinds``: a 32-bit overflow, a ``double`` in an interrupt, a stack or an unaligned
access show only on the part, ``["pil"]``). On another kind (``sil:``) it still runs, the whole
suite, and is shown with its verdict, passing as expected: "not a sil: catch by
design", never a survivor, and outside the detection figure, which counts the defects this kind
must catch.
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..sil.link import processor_fault
from .defects import CATALOGUE, load_defects
from .forked import run_pytest

#: the acceptance suite's files, cheapest and most discriminating first (the property searches last;
#: the current and speed-loop tests before them, or a speed-loop defect costs the whole suite)
SUITE_ORDER = (
    "test_protocol.py",
    # the part's deadlines, load and memory: seconds on pil:, not applicable (at once) elsewhere
    "test_processor.py",
    "test_faults.py",
    "test_calibration_recovery.py",
    "test_live_calibration.py",
    "test_signal_injection.py",
    "test_sage_husa_learning.py",
    "test_sage_husa.py",
    "test_current.py",
    "test_fault_injection.py",
)
#: a run that has not finished after this long (times the DUT kind's ``run_time_factor``, or
#: ``--run-limit-s``) is stopped and reported as undecided. A safety net against a hung run, never a
#: verdict on speed: an hour, about ten times the whole suite's run on a quiet 2-core machine. At
#: 1200 s the release check's qualify control run (the whole suite, beside other work at a load of
#: about 8 on 2 cores) was stopped, and its figure read INCOMPLETE where the code passes
RUN_TIMEOUT_S = 3600.0


def run_limit_s(args) -> float:
    """The wall time one run may take before it is stopped: ``--run-limit-s``, else RUN_TIMEOUT_S
    scaled by the DUT kind's ``run_time_factor`` (``hil.dut.kinds``)."""
    from ..dut.kinds import KINDS

    given = getattr(args, "run_limit_s", None)
    return float(given) if given is not None else RUN_TIMEOUT_S * KINDS[_kind(args.dut)].run_time_factor


@dataclass
class Run:
    name: str
    description: str
    verdict: str  #: the report's verdict: PASS, FAIL, or "no report"
    killed: bool  #: caught by a failed budget, check or device failure of a requirement
    #: "budget", "check" or "device failure" (what caught it, the strongest first), "not judged" (only
    #: setup checks failed), "error" (a test raised something else and nothing caught it), or None
    caught_by: str | None = None
    killed_by: list[str] = field(default_factory=list)  #: requirement ids that failed
    failed_tests: list[str] = field(default_factory=list)
    duration_s: float = 0.0
    report: str = ""
    note: str = ""
    #: what failed, one entry per requirement and cause: requirement, by ("budget NAME",
    #: "back-to-back NAME", "physics NAME", "device failure", "check"), margin (budgets, judged
    #: checks), test
    catches: list[dict] = field(default_factory=list)
    #: every budget judged in the run: requirement, budget, verdict, margin, test
    measurements: list[dict] = field(default_factory=list)
    defect_class: str = ""
    #: the requirements of every test that ran to a verdict (passed or failed): a pass/fail
    #: requirement that ran and passed has no measurement to show for it
    requirements_run: list[str] = field(default_factory=list)
    #: assertions that failed in tests of requirements with budgets: evidence, never a catch
    checks_not_counted: list[dict] = field(default_factory=list)
    #: the DUT kinds that must catch the defect (defects.toml's ``kinds``; empty: every kind)
    kinds: list[str] = field(default_factory=list)
    #: whether this run's DUT kind must catch it; False: run and shown, "not a catch by design"
    expected: bool = True


#: what caught a defect, the strongest evidence first: a customer's budget, a judged check
#: (hil.verdicts.requirements.JUDGEMENTS), a device's own signal, a pass/fail requirement's check
CATCH_KINDS = ("budget", "back-to-back", "physics", "processor fault", "device failure", "check")


#: the sensitivity table's words for the catches that carry no name
CATCH_LABELS = {"check": "check (no budget)", "device failure": "device failure"}


def _catch_kind(by: str) -> str:
    """The kind of a catch's label: "budget NAME" -> "budget", "back-to-back NAME" -> "back-to-back"."""
    return next((k for k in CATCH_KINDS if by == k or by.startswith(k + " ")), by)


def suite_files(suite: Path) -> list[str]:
    """The suite's test files in SUITE_ORDER (others after them, by name)."""
    files = sorted(p.name for p in suite.glob("test_*.py"))
    if not files:
        raise FileNotFoundError(f"no test_*.py in the acceptance suite {suite}")
    ordered = [f for f in SUITE_ORDER if f in files] + [f for f in files if f not in SUITE_ORDER]
    return [str(suite / f) for f in ordered]


def out_of_scope_budgets(dut: str, budgets: str | None, directory: Path) -> tuple[str | None, dict[str, str]]:
    """A budgets file that takes out of scope each requirement the DUT form's profile cannot show
    (hil.verdicts.requirements: the Modbus controller has no heartbeat and no EMCY), over the
    user's ``budgets``; its path (None when nothing is out of scope) and the requirements with why."""
    from ..verdicts.requirements import REQUIREMENTS, missing_needs
    from ..dut.profile import load_profile, shipped
    from ..dut.spec import parse_dut

    spec = parse_dut(dut)
    if spec.firmware:  # a firmware in the loop: its own profile; its pins close the loop
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


def what_caught(report: dict, registry: dict | None = None) -> tuple[str | None, list[str], list[str], list[dict]]:
    """From a run's HIL report: ``caught_by`` (``CATCH_KINDS``, "not judged", "error" or None), the
    requirements that caught the defect, every failed or errored test, and the catches (requirement,
    by, margin, test). Module docstring: a budget's or a judged check's failure is its
    requirement's, whatever test measured it; a check catches only for a requirement without
    budgets; a setup check or an error catches nothing."""
    return _judged(report, registry)[:4]


def checks_not_counted(report: dict, registry: dict | None = None) -> list[dict]:
    """The failed assertions of a run that are no catch: checks in tests of requirements that
    have budgets (requirement, test)."""
    return _judged(report, registry)[4]


def _judged(report: dict, registry: dict | None):
    from ..verdicts.record import FailedBy, Outcome, Status, TestRecord

    if registry is None:
        from ..verdicts.requirements import REQUIREMENTS as registry
    saved = [t for t in report.get("tests", []) if t.get("outcome") in (Outcome.FAILED, Outcome.ERROR)]
    failed = [TestRecord.from_json(t) for t in saved]
    catches: list[dict] = []
    uncounted: list[dict] = []
    kinds = set()
    for t, as_saved in zip(failed, saved):
        kind = t.failed_by or FailedBy.ERROR
        kinds.add(kind)
        if kind in (FailedBy.ASSERTION, FailedBy.BUDGET):
            over = [m for m in t.measurements if m.verdict == Status.FAIL]
            catches += [{"requirement": m.requirement, "by": f"{m.judgement} {m.budget}", "margin": m.margin,
                         "test": t.nodeid} for m in over]
            if kind == FailedBy.BUDGET or (over and "budget_only" not in as_saved):
                continue  # only budgets missed (a report of an older version: its first miss raised)
            # a check failed: a catch of the requirements the test is tied to by more than a budget
            # that have no budget of their own; for the others it is evidence, never a catch
            for r in (r for r in t.requirements if r not in t.budget_only):
                if r in registry and not registry[r].budgets:
                    catches.append({"requirement": r, "by": "check", "margin": None, "test": t.nodeid})
                else:
                    uncounted.append({"requirement": r, "test": t.nodeid})
        elif kind == FailedBy.DEVICE_FAILURE:
            # the emulated core's fault (pil:) is named; another device failure is the device's answer
            fault = processor_fault(t.message)
            by = f"processor fault {fault}" if fault else "device failure"
            catches += [{"requirement": r, "by": by, "margin": None, "test": t.nodeid} for r in t.requirements]
    by = {_catch_kind(c["by"]) for c in catches}
    caught_by = next((k for k in CATCH_KINDS if k in by), None)
    if caught_by is None and failed:
        caught_by = ("not judged" if kinds == {FailedBy.NOT_JUDGED} else
                     None if uncounted and kinds <= {FailedBy.ASSERTION, FailedBy.BUDGET, FailedBy.NOT_JUDGED}
                     else "error")
    return caught_by, sorted({c["requirement"] for c in catches}), [t.nodeid for t in failed], catches, uncounted


def judged_measurements(report: dict) -> list[dict]:
    """Every budget's and judged check's verdict of a run: requirement, budget, judgement, verdict,
    margin, test."""
    return [{"requirement": m["requirement"], "budget": m["budget"], "judgement": m.get("judgement", "budget"),
             "verdict": m["verdict"], "margin": m["margin"], "test": t["nodeid"]}
            for t in report.get("tests", []) for m in t.get("measurements", [])]


def naming(defect_class: str, registry: dict | None = None) -> list[str]:
    """The requirements that name ``defect_class`` among the defects they judge."""
    if registry is None:
        from ..verdicts.requirements import REQUIREMENTS as registry
    return [r.id for r in registry.values() if defect_class and defect_class in r.judges]


def sensitivity(mutants: list[Run], registry: dict | None = None) -> list[dict]:
    """The sensitivity table: one cell per (requirement, defect) where the requirement names the
    defect's class or caught it. ``caught`` by its own budget, judged check, device failure, or, for
    a requirement without budgets, its check; ``by`` (what failed, the strongest) and ``margin`` (the
    failed budget's, else the smallest margin of its budgets in the run: how close it came);
    ``ran`` False when no test of the requirement ran (the run stopped earlier, or was restricted)."""
    if registry is None:
        from ..verdicts.requirements import REQUIREMENTS as registry
    cells = []
    for m in mutants:
        named = naming(m.defect_class, registry)
        caught: dict[str, dict] = {}
        for c in sorted(m.catches, key=lambda c: CATCH_KINDS.index(_catch_kind(c["by"]))):
            caught.setdefault(c["requirement"], c)  # its strongest: a failed budget before a check
        for rid in named + [r for r in sorted(caught) if r not in named]:
            mine = [x for x in m.measurements if x["requirement"] == rid]
            c = caught.get(rid)
            margin = c["margin"] if c is not None else (min(x["margin"] for x in mine) if mine else None)
            ran = bool(mine) or c is not None or rid in m.requirements_run
            cells.append({"requirement": rid, "defect": m.name, "defect_class": m.defect_class,
                          "named": rid in named, "caught": c is not None, "by": c["by"] if c else None,
                          "margin": margin, "ran": ran,
                          # a defect this DUT kind is not meant to catch: shown, never a miss
                          "by_design": not m.expected, "kinds": m.kinds,
                          # a check of a requirement with budgets failed: shown, never counted
                          "check_not_counted": c is None and any(u["requirement"] == rid
                                                                 for u in m.checks_not_counted)})
    return cells


SENSITIVITY_COLUMNS = ["defect", "class", "requirement", "names the class", "verdict", "by", "margin"]


def sensitivity_rows(result: dict) -> list[list[str]]:
    """The sensitivity table of a ``hil qualify`` result, one row (``SENSITIVITY_COLUMNS``) per
    (defect, requirement) cell of ``sensitivity``: whether the requirement names the defect's class,
    what caught it (a budget and its margin, a judged check, a device failure, the check of a
    requirement without budgets) or, missed, its budgets' smallest margin in the run ("not run"
    where none of its tests ran; a failed check of a requirement with budgets is said, and is no
    catch)."""
    rows = []
    for c in result.get("sensitivity") or []:
        verdict = "**caught**" if c["caught"] else ("missed" if c["ran"] else "not run")
        if c.get("by_design") and not c["caught"]:
            verdict = f"not caught here by design (a defect {', '.join(k + ':' for k in c['kinds'])} catches)"
        if c.get("check_not_counted"):
            verdict += " (a check failed: not counted, the requirement has budgets)"
        by = CATCH_LABELS.get(c["by"] or "", c["by"] or "")
        rows.append([f"`{c['defect']}`", c["defect_class"] or "–", c["requirement"], "yes" if c["named"] else "no",
                     verdict, by or "–", "–" if c["margin"] is None else f"{c['margin']:+.3g}"])
    return rows


def sensitivity_markdown(result: dict) -> str:
    """``sensitivity_rows`` as a markdown table."""
    lines = ["| " + " | ".join(SENSITIVITY_COLUMNS) + " |", "|" + "---|" * len(SENSITIVITY_COLUMNS)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in sensitivity_rows(result)]) + "\n"


FIRMWARE_DEFECTS_FORMAT = "bldc-hil-firmware-defects/1"


@dataclass(frozen=True)
class FirmwareDefect:
    """A seeded defect of a firmware folder: a compile-time switch its ``defects.toml`` lists."""

    name: str
    define: str
    description: str
    requirements: tuple[str, ...] = ()
    #: its class (``hil.verdicts.requirements.DEFECT_CLASSES``; defects.toml's optional ``class``), "" when unclassed
    defect_class: str = ""
    #: the DUT kinds that must catch it (defects.toml's optional ``kinds``, firmware kinds of
    #: ``hil.dut.kinds``); empty: every kind. A defect only the part shows is ``("pil",)``
    kinds: tuple[str, ...] = ()

    def expected_on(self, kind: str) -> bool:
        """Whether a DUT of ``kind`` must catch it."""
        return not self.kinds or kind in self.kinds


def firmware_defects(dut: str) -> dict[str, FirmwareDefect]:
    """The seeded defects of a ``sil:DIR`` firmware: ``DIR/defects.toml`` (format
    ``bldc-hil-firmware-defects/1``: ``[[defect]]`` tables of name, define, description,
    requirements, and optionally class, a ``DEFECT_CLASSES`` key, and kinds, the firmware kinds that
    must catch it), or {} for any other DUT. Errors name the file, the table and the key."""
    from bldc.tomlfile import TomlError, load_toml

    from ..dut.kinds import firmware_kinds
    from ..dut.spec import parse_dut
    from ..verdicts.requirements import DEFECT_CLASSES

    spec = parse_dut(dut)
    if not spec.firmware:
        return {}
    path = Path(spec.options["path"]) / "defects.toml"
    if not path.is_file():
        raise ValueError(f"{path}: no such file: a firmware's seeded defects are listed there "
                         "(docs/firmware-in-the-loop.md)")
    schema = {"format": None, "defect": [{"name": None, "define": None, "description": None, "requirements": None,
                                   "class": None, "kinds": None}]}
    data = load_toml(path, schema)
    if data.get("format") != FIRMWARE_DEFECTS_FORMAT:
        raise TomlError(path, f"must be {FIRMWARE_DEFECTS_FORMAT!r}", key="format")
    out = {}
    for i, d in enumerate(data.get("defect", [])):
        for key in ("name", "define", "description"):
            if not isinstance(d.get(key), str) or not d[key]:
                raise TomlError(path, "required, a non-empty string", table=f"[[defect]][{i}]", key=key)
        defect_class = d.get("class", "")
        if not isinstance(defect_class, str) or (defect_class and defect_class not in DEFECT_CLASSES):
            raise TomlError(path, f"must be one of {', '.join(DEFECT_CLASSES)}", table=f"[[defect]][{i}]",
                            key="class")
        kinds = d.get("kinds", [])
        if not isinstance(kinds, list) or any(k not in firmware_kinds() for k in kinds):
            raise TomlError(path, f"must be a list of DUT kinds among {', '.join(firmware_kinds())}",
                            table=f"[[defect]][{i}]", key="kinds")
        out[d["name"]] = FirmwareDefect(d["name"], d["define"], d["description"], tuple(d.get("requirements", ())),
                                        defect_class, tuple(kinds))
    return out


def _run(name: str, description: str, defect: str | None, args) -> Run:
    report_dir = Path(args.report_dir) / (defect or "control")
    firmware = getattr(args, "firmware_defects", None) or {}
    dut = args.dut + (f",define={firmware[defect].define}" if defect in firmware else "")
    sensitive = bool(getattr(args, "sensitivity", False))
    kinds = list(firmware[defect].kinds) if defect in firmware else []
    # a defect this kind of DUT is not meant to catch (a defect of the part on sil:) runs the whole suite,
    # unrestricted, to its first catch: shown passing (or caught after all), never a miss
    expected = defect not in firmware or firmware[defect].expected_on(_kind(args.dut))
    if not expected:
        sensitive = False
    cmd = ["-q", "-p", "no:cacheprovider", "--hil-dut", dut, "--hil-report-dir", str(report_dir),
           "--hil-seed", str(args.seed)]
    if not sensitive:
        cmd.append("--hil-stop-at-catch")  # not -x: a setup check or an uncounted check is no catch
    if args.budgets:
        cmd += ["--hil-budgets", args.budgets]
    if defect is None:
        defect_class = ""
    else:
        defect_class = (firmware[defect] if defect in firmware else CATALOGUE[defect]).defect_class
    if defect is not None and defect not in firmware:
        cmd += ["--hil-defect", defect]
        if args.defects:
            cmd += ["--hil-defects", args.defects]
    if sensitive and naming(defect_class):
        # the tests of the requirements that name its class, every one of them (no -x); a firmware
        # defect (a compile-time switch in the DUT) as a catalogue one
        cmd += ["--hil-requirements", ",".join(naming(defect_class))]
    elif not sensitive and naming(defect_class):
        # the tests of the requirements that name its class run first: the run stops at the catch there
        # instead of after every test ahead of it in the suite (the rest still run when none fails)
        cmd += ["--hil-first", ",".join(naming(defect_class))]
    elif sensitive and defect is None and getattr(args, "control_requirements", None):
        # the control needs to pass where the defects are judged, and nowhere else
        cmd += ["--hil-requirements", ",".join(args.control_requirements)]
    cmd += suite_files(Path(args.suite))
    started = time.monotonic()
    note = ""
    limit_s = run_limit_s(args)
    code, output = run_pytest(cmd, limit_s, {**os.environ, "PYTHONUNBUFFERED": "1"})
    if code is None:
        note = f"stopped after {limit_s:.0f} s (the run time limit, --run-limit-s)"
    duration = time.monotonic() - started
    report_json = report_dir / "hil-report.json"
    if not report_json.is_file():
        tail = " | ".join(output.strip().splitlines()[-3:])
        return Run(name, description, "no report", False, None, duration_s=duration, report=str(report_json),
                   note=note or f"the run wrote no report: {tail}", defect_class=defect_class, kinds=kinds,
                   expected=expected)
    report = json.loads(report_json.read_text())
    verdict = report.get("verdict", "no verdict")
    caught_by, failed_reqs, failed_tests, catches, uncounted = _judged(report, None)
    if not expected:
        note = (note + "; " if note else "") + (
            f"not a {_kind(args.dut)}: catch by design (a defect {', '.join(k + ':' for k in kinds)} must catch)")
    if caught_by == "error":
        note = (note + "; " if note else "") + "a test errored (nothing was caught): a finding to fix, not a catch"
    elif caught_by is None and uncounted:
        owners = ", ".join(sorted({u["requirement"] for u in uncounted}))
        note = (note + "; " if note else "") + f"only checks of requirements with budgets failed ({owners}): no catch"
    elif caught_by == "not judged":
        note = (note + "; " if note else "") + "a setup check failed (the scenario did not provoke what it judges)"
    ran = sorted({r for t in report.get("tests", []) if t.get("outcome") in ("passed", "failed")
                  for r in t.get("requirements", [])})
    return Run(name, description, verdict, caught_by in CATCH_KINDS, caught_by, failed_reqs, failed_tests, duration,
               str(report_json), note, catches, judged_measurements(report), defect_class, ran, uncounted, kinds,
               expected)


def _kind(dut: str) -> str:
    from ..dut.spec import parse_dut

    return parse_dut(dut).kind


@dataclass
class Qualification:
    """A ``hil qualify`` result: the control run and one run per defect; the figures (what was
    caught, by which requirement, what survived) follow from the runs, and ``to_json()`` is the
    JSON ``hil qualify --json`` writes (docs/qualify.md)."""

    dut: str
    seed: int
    out_of_scope: dict[str, str]  #: requirement -> why the DUT cannot be judged on it
    control: Run
    mutants: list[Run]
    duration_s: float

    @property
    def control_passed(self) -> bool:
        return self.control.verdict == "PASS"

    @property
    def judged(self) -> list[Run]:
        """The defects this kind of DUT must catch (module docstring: defects of one kind)."""
        return [m for m in self.mutants if m.expected]

    @property
    def by_design(self) -> list[Run]:
        """The defects this kind of DUT is not meant to catch (a defect of the part on sil:): run,
        shown, never a survivor and outside the detection figure."""
        return [m for m in self.mutants if not m.expected]

    @property
    def killed(self) -> list[Run]:
        return [m for m in self.judged if m.killed]

    @property
    def errored(self) -> list[str]:
        return [m.name for m in self.mutants if m.caught_by == "error"]

    @property
    def not_judged(self) -> list[str]:
        return [m.name for m in self.mutants if m.caught_by == "not judged"]

    @property
    def survivors(self) -> list[str]:
        return [m.name for m in self.judged if not m.killed and m.caught_by not in ("error", "not judged")]

    @property
    def detection_ratio(self) -> float | None:
        """Killed over all defects; None without a passing control run (against a failing control
        a "caught" defect may be the control's own failure) or without defects."""
        return len(self.killed) / len(self.judged) if self.control_passed and self.judged else None

    def requirements(self) -> dict[str, list[str]]:
        """Requirement -> the defects its failure caught."""
        by_requirement: dict[str, list[str]] = {}
        for m in self.killed:
            for req in m.killed_by:
                by_requirement.setdefault(req, []).append(m.name)
        return {req: sorted(names) for req, names in sorted(by_requirement.items())}

    def to_json(self) -> dict:
        control = self.control
        return {
            "format": "hil-qualify/1",
            "dut": self.dut,
            "seed": self.seed,
            "control_verdict": control.verdict,
            "out_of_scope": self.out_of_scope,
            "control": asdict(control),
            "mutants": [asdict(m) for m in self.mutants],
            "detection": {
                "killed": len(self.killed),
                "total": len(self.judged),
                "ratio": self.detection_ratio,
            } if self.control_passed else None,
            "no_detection_because": None if self.control_passed else (
                f"the control run's verdict is {control.verdict}, not PASS: a defect's failure could be the "
                f"control's own ({', '.join(control.failed_tests) or control.note or 'see its report'})"),
            "errored": self.errored,
            "not_judged": self.not_judged,
            "sensitivity": sensitivity(self.mutants),
            "requirements": self.requirements(),
            "survivors": self.survivors,
            #: defect -> its verdict here, for the defects this DUT kind is not meant to catch
            "not_this_kind": {m.name: {"verdict": m.verdict, "kinds": m.kinds, "caught_by": m.caught_by}
                              for m in self.by_design},
            "duration_s": self.duration_s,
        }


def qualify(args, progress=print) -> Qualification:
    """Control run and one run per defect (``args.only`` or the whole catalogue), ``args.workers``
    at a time; ``to_json()`` of the result is the JSON ``hil qualify`` writes."""
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
    classes = [catalogue[n].defect_class for n in names]
    # with --sensitivity each defect runs the requirements that name its class: the control runs their
    # union (all of the suite when a defect has no class, or this kind is not meant to catch it: those
    # runs are the whole suite)
    kind = _kind(args.dut)
    by_design = [n for n in names if n in args.firmware_defects and not args.firmware_defects[n].expected_on(kind)]
    args.control_requirements = (sorted({r for c in classes for r in naming(c)})
                                 if all(classes) and names and not by_design else None)
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
                ("caught" if run.killed else "passes") if not run.expected else
                "killed" if run.killed else {"error": "ERRORED", "not judged": "NOT JUDGED"}.get(run.caught_by,
                                                                                           "SURVIVED"))
            progress(f"{run.name:<34} {state:<9} {run.verdict:<9} {run.duration_s:6.1f} s  caught by: {caught}"
                     + (f"  ({run.note})" if run.note else ""))
    return Qualification(args.dut, args.seed, out_of_scope, runs[0], runs[1:], time.monotonic() - started)
