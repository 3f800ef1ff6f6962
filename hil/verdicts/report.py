"""Compliance reports, written incrementally: HTML (one self-contained file), JSON and JUnit XML.

Every finished test is appended to ``results.jsonl`` (flushed and synced) and the three
reports are re-rendered from it at once, each through a temporary file and an atomic rename,
so a crash or a killed run leaves reports holding every test finished so far. Under
pytest-xdist only the controlling process writes; the workers' measurements and evidence
reach it inside the test reports (``user_properties``), so the reports merge by construction.

A test's record: node id, outcome, duration, requirement IDs (``requirement`` marker), the DUT
it ran against, budget verdicts (``hil_budget``) and evidence (``hil_evidence``: values, tables,
figures, text).

The verdicts (each test's, each requirement's, the run's) are computed here once, from the
records and the waivers in force, and the three formats only present them (docs/acceptance.md,
Verdicts): a known failure is a failure, a waiver is explicit, and PASS needs a complete run in
which at least one test ran.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from .record import Outcome, Status, TestRecord
from .report_html import html  # the HTML report's presentation (labels, summary, matrix rows)

PROPERTY_PREFIX = "hil:"
#: the worst first: a test's outcome is the worst of its phases
OUTCOME_ORDER = tuple(Outcome)


def atomic_write(path: Path, text: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(text.encode("utf-8", "replace") if isinstance(text, str) else text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


#: pytest exit statuses after which every collected test has had its say
_FINISHED_EXIT = {0: "ok", 1: "tests failed", 5: "no tests collected"}
_EXIT_NAMES = {2: "interrupted", 3: "internal error", 4: "usage error"}
#: test and requirement verdicts, the worst first
VERDICTS = tuple(Status)
#: a requirement verdict that leaves the run short of PASS (besides fail and error)
_UNANSWERED = (Status.NOT_TESTED, Status.NOT_TESTABLE)


def test_status(test: TestRecord | dict, rid: str | None = None) -> Status:
    """One test's verdict (for requirement ``rid``, or overall): ``TestRecord.status``; a record
    read from a saved report (a dict) is read as a ``TestRecord`` first."""
    return _typed(test).status(rid)


def _typed(test: TestRecord | dict) -> TestRecord:
    return test if isinstance(test, TestRecord) else TestRecord.from_json(test)


def find_waiver(waivers, rid: str, nodeid: str | None):
    """The first waiver of ``rid`` covering the test ``nodeid`` (None: the requirement as a whole,
    which only a waiver not limited to tests covers)."""
    for w in waivers:
        if w.kind != "waiver" and nodeid is not None:
            continue  # out of scope stands for a requirement no test judged, never for a failure
        if w.requirement == rid and (w.covers(nodeid) if nodeid is not None else not w.tests):
            return w
    return None


def test_waiver(waivers, requirements, nodeid: str):
    """The waiver that waives a failing test: one that covers it under every requirement it
    traces to (a test tied to an unwaived requirement still fails), or None."""
    found = [find_waiver(waivers, rid, nodeid) for rid in sorted(set(requirements))]
    return found[0] if found and all(found) else None


def requirement_verdict(rid: str, tests: list[TestRecord | dict], waivers=()) -> tuple[Status, object]:
    """(verdict, waiver or None) of requirement ``rid`` from the tests traced to it.

    pass only when every traced test passed (skips aside) and at least one did; marginal when one
    is marginal; a failing test (failure, xfail, xpass, failed budget) gives fail unless a waiver of
    ``rid`` covers that test (then waived); an error gives error (an error is never waived: it is
    no evidence either way); no test that ran gives not tested (not testable when the device's
    profile lacks what its tests need), or waived / out of scope under an entry of the budgets file
    for the whole requirement."""
    statuses, used = [], None
    for t in map(_typed, tests):
        s = t.status(rid)
        if s == Status.FAIL and (w := find_waiver(waivers, rid, t.nodeid)) is not None:
            s, used = Status.WAIVED, used or w
        statuses.append(s)
    answered = {Status.PASS, Status.MARGINAL, Status.WAIVED, Status.FAIL, Status.ERROR}
    if not answered & set(statuses):
        w = find_waiver(waivers, rid, None)
        if w is not None:
            return (Status.OUT_OF_SCOPE if w.kind == "out of scope" else Status.WAIVED), w
        if Status.NOT_TESTABLE in statuses:
            return Status.NOT_TESTABLE, None
        return (Status.NOT_APPLICABLE if Status.NOT_APPLICABLE in statuses else Status.NOT_TESTED), None
    worst = Status.worst(statuses)
    if worst in (*_UNANSWERED, Status.NOT_APPLICABLE):  # skipped beside passing ones: the skips do not apply here
        worst = Status.MARGINAL if Status.MARGINAL in statuses else Status.PASS
    return worst, (used if worst == Status.WAIVED else None)


def traffic_total(counts: list[dict]) -> dict:
    """The edge traffic of many tests on one DUT (``hil.dut.traffic``: counts, and for CAN the bus
    time in seconds) summed; for CAN also the frames per edge, both ways."""
    def add(total: dict, c: dict) -> dict:
        for k, v in c.items():
            if isinstance(v, dict):
                total[k] = add(total.get(k, {}), v)
            else:
                total[k] = v if isinstance(v, str) else total.get(k, 0) + v
        return total

    total: dict = {}
    for c in counts:
        add(total, c)
    if "bus_time_s" in total:
        total["bus_time_s"] = {k: round(v, 1) for k, v in total["bus_time_s"].items()}
        frames = total["frames_to_device"] + total["frames_from_device"]
        total["frames_per_edge"] = round(frames / max(total["edges"], 1), 2)
        total["stuffing"] = "worst case"
    return total


def processor_summary(figures: dict) -> dict:
    """The report's processor section of one ``pil:`` DUT from its link's figures
    (``SilLink.processor``): per interrupt its calls, cycles (median, p99, max, and in us) and worst
    response; the worst CPU load of any control period and the overruns; the stack, flash and RAM;
    the soft floating-point routines each interrupt ran, by name, with calls per simulated second."""
    core = figures["core"]
    schedules = figures.get("schedules") or [{}]
    seconds = figures.get("simulated_s") or 0.0
    interrupts = {}
    for kind, c in core.get("interrupts", {}).items():
        worst = max((s.get("interrupts", {}).get(kind, {}).get("response_s", {}).get("max", 0.0) for s in schedules),
                    default=0.0)
        interrupts[kind] = {
            "calls": c["calls"], "cycles": c["cycles"], "us": c["us"], "worst_response_us": worst * 1e6,
            "soft_float": [{"routine": name, "calls": n, "per_s": n / seconds if seconds else None}
                           for name, n in sorted(c.get("soft_float", {}).items(), key=lambda kv: -kv[1])],
        }
    overruns = [o for s in schedules for o in s.get("overruns", [])]
    return {
        "cpu": core["cpu"], "clock_hz": core["clock_hz"], "simulated_s": seconds, "interrupts": interrupts,
        "worst_load": max((s.get("worst_load", 0.0) for s in schedules), default=0.0),
        "overrun_count": sum(s.get("overrun_count", 0) for s in schedules), "overruns": overruns[:20],
        "stack": core["stack"], "flash": core["flash"], "ram": core["ram"],
    }


@dataclass
class ReportWriter:
    directory: Path | None  #: None: nothing written (a run kept only for the results history)
    session: dict = field(default_factory=dict)
    requirements: dict = field(default_factory=dict)  #: id -> title (budgets and the catalogue)
    basename: str = "hil-report"
    waivers: tuple = ()  #: hil.verdicts.budgets.Waiver, from the budgets in force
    #: the run's figures against the device's earlier runs (hil.history: trends, regressions), or None
    history: dict | None = None

    def __post_init__(self):
        self.records: list[TestRecord] = []
        self.jsonl = None
        if self.directory is not None:
            self.directory = Path(self.directory)
            self.directory.mkdir(parents=True, exist_ok=True)
            self.jsonl = self.directory / "results.jsonl"
            self.jsonl.write_text("")  # a new run starts a new log
        self.complete = False
        self.incomplete_reason = "the run has not finished (still running, or stopped before its end)"
        self.collected: set[str] | None = None

    @classmethod
    def clear(cls, directory: Path, basename: str = "hil-report") -> None:
        """Remove a previous run's reports, so that a run that stops before writing its own
        (a usage error) cannot leave an old verdict in place."""
        for name in (f"{basename}.html", f"{basename}.json", f"{basename}-junit.xml", "results.jsonl"):
            (Path(directory) / name).unlink(missing_ok=True)

    @property
    def paths(self) -> dict[str, Path]:
        return {
            "html": self.directory / f"{self.basename}.html",
            "json": self.directory / f"{self.basename}.json",
            "junit": self.directory / f"{self.basename}-junit.xml",
        }

    def add(self, record: TestRecord) -> None:
        self.records.append(record)
        if self.jsonl is None:
            return
        with open(self.jsonl, "a") as f:
            f.write(json.dumps(record.to_json()) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.render()

    def expect(self, nodeids) -> None:
        """The tests this run collected (called again per xdist worker: the union counts)."""
        self.collected = (self.collected or set()) | set(nodeids)
        self.session["collected"] = len(self.collected)

    def finish(self, summary: dict) -> None:
        """The session ended with ``summary["exit_status"]``: complete when pytest finished normally
        and every collected test reported."""
        self.session = {**self.session, **summary}
        status = int(summary.get("exit_status", 0))
        missing = sorted((self.collected or set()) - {r.nodeid for r in self.records})
        if status not in _FINISHED_EXIT:
            self.incomplete_reason = f"pytest stopped with exit status {status} ({_EXIT_NAMES.get(status, 'unknown')})"
        elif missing:
            self.incomplete_reason = (
                f"{len(missing)} of {len(self.collected)} collected tests never reported (first: {missing[0]})"
            )
        else:
            self.complete, self.incomplete_reason = True, ""
        self.render()

    # --- content ---------------------------------------------------------------------------------
    def content(self) -> dict:
        counts = {str(k): 0 for k in OUTCOME_ORDER}
        for r in self.records:
            counts[r.outcome] += 1
        tests = [self._judged(r) for r in self.records]
        reqs: dict[str, dict] = {
            rid: {"id": rid, "title": title, "tests": []} for rid, title in self.requirements.items()
        }
        for r in self.records:
            for rid in sorted(r.traced):
                reqs.setdefault(rid, {"id": rid, "title": "", "tests": []})["tests"].append(r)
        matrix = []
        for rid in sorted(reqs):
            traced = reqs[rid]["tests"]
            verdict, waiver = requirement_verdict(rid, traced, self.waivers)
            rows = []
            for t in traced:
                status = t.status(rid)
                w = find_waiver(self.waivers, rid, t.nodeid) if status == Status.FAIL else None
                # a test that ran for its other requirements says why it could not show this one;
                # its message and figures are theirs
                lacking = (t.not_testable if status == Status.NOT_TESTABLE else
                           t.not_applicable if status == Status.NOT_APPLICABLE else None)
                rows.append(
                    {
                        "nodeid": t.nodeid,
                        "dut": t.dut,
                        "outcome": t.outcome,
                        "verdict": Status.WAIVED if w else status,
                        "message": lacking.reason if lacking else t.message,
                        "measurements": [] if lacking else [m.as_dict() for m in t.relevant(rid)],
                        "waiver": w.as_dict() if w else None,
                    }
                )
            matrix.append(
                {
                    "id": rid,
                    "title": reqs[rid]["title"],
                    "verdict": verdict,
                    "traced": bool(traced),
                    "waiver": waiver.as_dict() if waiver else None,
                    "tests": rows,
                }
            )
        duts = {}
        for r in self.records:
            if r.dut and r.dut_identity:
                duts.setdefault(r.dut, r.dut_identity)
        builds = {r.dut: r.dut_build for r in self.records if r.dut and r.dut_build}
        traffic: dict[str, list] = {}
        for r in self.records:
            if r.dut and r.traffic:
                traffic.setdefault(r.dut, []).append(r.traffic)
        processor = {}  # pil: what the emulated core and the interrupt schedule measured, per DUT
        for r in self.records:
            if r.dut and r.processor:
                processor[r.dut] = processor_summary(r.processor)
        verdict, reasons = self._overall(tests, matrix)
        counts["waived"] = sum(t["verdict"] == Status.WAIVED for t in tests)
        waivers = [
            {
                **w.as_dict(),
                "tests_waived": [t["nodeid"] for t in tests if t["waiver"] and t["waiver"]["source"] == w.source]
                + [
                    f"{r['id']} (not tested)"
                    for r in matrix
                    if r["waiver"]
                    and r["waiver"]["source"] == w.source
                    and not any(row["waiver"] for row in r["tests"])
                ],
            }
            for w in self.waivers
        ]
        return {
            "format": "hil-report/1",
            "complete": self.complete,
            "incomplete_reason": self.incomplete_reason,
            "verdict": verdict,
            "verdict_reasons": reasons,
            "counts": counts,
            "session": self.session,
            "duts": duts,
            # each DUT's spec, firmware build hash and profile hash (hil.history.record.dut_build)
            "dut_builds": builds,
            # what the edges moved on each DUT's link, with the bus time (hil.dut.traffic)
            "traffic": {dut: traffic_total(counts) for dut, counts in traffic.items()},
            # processor in the loop: per interrupt its calls and cycles, the load, the stack, flash, RAM
            # and the soft floating-point routines run inside interrupts (hil.sil.scheduler, hil.pil)
            "processor": processor,
            "waivers": waivers,
            "traceability": matrix,
            "tests": tests,
            "history": self.history,
        }

    def _judged(self, record: TestRecord) -> dict:
        """The record as the JSON report writes it, with its verdict (``TestRecord.status``, or
        waived under ``test_waiver``)."""
        status, waiver = record.status(), None
        if status == Status.FAIL:
            if (waiver := test_waiver(self.waivers, record.traced, record.nodeid)) is not None:
                status = Status.WAIVED
        return {**record.to_json(), "verdict": status, "waiver": waiver.as_dict() if waiver else None}

    def _overall(self, tests: list[dict], matrix: list[dict]) -> tuple[str, list[str]]:
        """PASS only when at least one test ran, the run is complete and every traced requirement
        is pass, marginal or waived; otherwise FAIL, INCOMPLETE or NO TESTS, each with its reasons."""
        reasons = []
        for t in tests:
            if t["verdict"] in (Status.FAIL, Status.ERROR):
                what = {Outcome.XFAILED: "known failure (xfail)", Outcome.XPASSED: "unexpected pass (xpass)"}.get(
                    t["outcome"], t["outcome"]
                )
                # control characters written out: a reason is printed on terminals and shown in HTML
                reasons.append(
                    xml_safe(
                        f"{t['nodeid']}: {what}" + (f": {t['message'].splitlines()[0][:200]}" if t["message"] else "")
                    )
                )
        for r in matrix:
            if r["traced"] and r["verdict"] in (Status.FAIL, Status.ERROR, *_UNANSWERED):
                why = next((t["message"] for t in r["tests"] if t["verdict"] == Status.NOT_TESTABLE), "")
                # "with this profile" explains a requirement no test could show, never a failure
                profile = " with this profile" if why and r["verdict"] == Status.NOT_TESTABLE else ""
                reasons.append(f"{r['id']}: {r['verdict']}{profile}")
        if not self.complete:
            reasons.append(f"incomplete: {self.incomplete_reason}")
        ran = [t for t in tests if t["outcome"] != Outcome.SKIPPED]
        if not ran and self.complete:
            reasons.append(
                f"no test ran ({len(tests)} reported, all skipped)"
                if tests
                else "no test was collected (or every one was deselected)"
            )
        failing = any(t["verdict"] in (Status.FAIL, Status.ERROR) for t in tests) or any(
            r["traced"] and r["verdict"] in (Status.FAIL, Status.ERROR) for r in matrix
        )
        if failing:
            return "FAIL", reasons
        if not self.complete:
            return "INCOMPLETE", reasons
        if not ran:
            return "NO TESTS", reasons
        if reasons:  # a traced requirement that no test answered for
            return "FAIL", reasons
        return "PASS", reasons

    # --- rendering -------------------------------------------------------------------------------
    def render(self) -> None:
        if self.directory is None:
            return
        content = self.content()
        atomic_write(self.paths["json"], json.dumps(content, indent=1, default=str))
        atomic_write(self.paths["junit"], junit_xml(content))
        atomic_write(self.paths["html"], html(content, self.directory, VERDICTS))


#: characters XML 1.0 does not allow (section 2.2), lone surrogates included
_XML_FORBIDDEN = re.compile("[^\u0009\u000a\u000d\u0020-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def xml_safe(text) -> str:
    """``text`` with every character XML 1.0 forbids written out as ``\\xNN`` / ``\\uNNNN``, so a
    test message holding terminal colours or NUL bytes still gives a well-formed file."""

    def escape(m: re.Match) -> str:
        c = ord(m.group())
        return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"

    return _XML_FORBIDDEN.sub(escape, str(text))


def _element(parent, tag: str, text: str | None = None, **attrs) -> ET.Element:
    el = ET.SubElement(parent, tag, {k: xml_safe(v) for k, v in attrs.items()})
    if text:
        el.text = xml_safe(text)
    return el


def junit_xml(content: dict) -> bytes:
    tests = content["tests"]
    n = {v: sum(t["verdict"] == v for t in tests) for v in VERDICTS}
    incomplete = not content["complete"]
    suite = ET.Element(
        "testsuite",
        {
            "name": "hil",
            "tests": str(len(tests) + incomplete),
            "failures": str(n[Status.FAIL]),
            "errors": str(n["error"] + incomplete),
            "skipped": str(n["waived"] + n["not tested"]),
            "time": f"{sum(t['duration_s'] for t in tests):.3f}",
            "timestamp": xml_safe(content["session"].get("started", "")),
        },
    )
    props = ET.SubElement(suite, "properties")
    _element(props, "property", name="hil.verdict", value=content["verdict"])
    _element(props, "property", name="hil.complete", value=str(content["complete"]).lower())
    if incomplete:
        _element(props, "property", name="hil.incomplete_reason", value=content["incomplete_reason"])
    for reason in content["verdict_reasons"]:
        _element(props, "property", name="hil.verdict_reason", value=reason)
    for key in ("plant", "plant_sha256", "seed", "hypothesis_seed", "budgets"):
        if key in content["session"]:
            _element(props, "property", name=f"hil.{key}", value=content["session"][key])
    for w in content["waivers"]:
        _element(props, "property", name=f"hil.waiver:{w['requirement']}", value=f"{w['reason']} (owner {w['owner']})")
    for r in content["traceability"]:
        if r["traced"]:
            _element(props, "property", name=f"hil.requirement:{r['id']}", value=r["verdict"])
    for t in tests:
        module, _, name = t["nodeid"].rpartition("::")
        case = _element(
            suite,
            "testcase",
            classname=module.replace("/", ".").removesuffix(".py"),
            name=name,
            time=f"{t['duration_s']:.3f}",
        )
        cp = ET.SubElement(case, "properties")
        for rid in t["requirements"]:
            _element(cp, "property", name="requirement", value=rid)
        if t.get("dut"):
            _element(cp, "property", name="dut", value=t["dut"])
        for m in t["measurements"]:
            _element(
                cp,
                "property",
                name=f"measurement:{m['budget']}",
                value=f"{m['measured']:.6g} {m['unit']} (limit {m['limit']:.6g}, {m['verdict']}, {m['requirement']})",
            )
        for e in t["evidence"]:
            if e["kind"] == "value":
                _element(cp, "property", name=f"value:{e['name']}", value=f"{e['value']} {e.get('unit', '')}".strip())
        message = t["message"][:500]
        if t["verdict"] == Status.WAIVED:
            w = t["waiver"]
            _element(
                case,
                "skipped",
                f"{t['outcome']}: {t['message']}\n\n{t['details']}".strip(),
                message=f"WAIVED ({w['requirement']}, owner {w['owner']}): {w['reason']}"[:1000],
            )
        elif t["verdict"] == Status.FAIL and t["outcome"] == Outcome.XFAILED:
            why = f" ({t['xfail_reason']})" if t.get("xfail_reason") else ""
            _element(
                case,
                "failure",
                t["details"],
                message=f"known failure, marked xfail{why}: {message}"[:1000],
                type="xfail",
            )
        elif t["verdict"] == Status.FAIL and t["outcome"] == Outcome.XPASSED:
            _element(
                case,
                "failure",
                message=f"unexpected pass of a test marked as a known failure (xfail: {t.get('xfail_reason', '')}); "
                "the mark no longer matches the controller"[:1000],
                type="xpass",
            )
        elif t["verdict"] == Status.FAIL:
            _element(case, "failure", t["details"], message=message or "failed")
        elif t["verdict"] == Status.ERROR:
            _element(case, "error", t["details"], message=message or "error")
        elif t["verdict"] == Status.NOT_TESTED:
            _element(case, "skipped", message=message)
    if incomplete:
        case = _element(suite, "testcase", classname="hil", name="run incomplete", time="0")
        _element(case, "error", message=f"the HIL run is incomplete: {content['incomplete_reason']}", type="incomplete")
    ET.indent(suite)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
