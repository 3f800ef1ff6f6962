"""Compliance reports, written incrementally: HTML (one self-contained file), JSON and JUnit XML.

Every finished test is appended to ``results.jsonl`` (flushed and synced) and the three
reports are re-rendered from it at once, each through a temporary file and an atomic rename,
so a crash or a killed run leaves reports holding every test finished so far. Under
pytest-xdist only the controlling process writes; the workers' measurements and evidence
reach it inside the test reports (``user_properties``), so the reports merge by construction.

A test's record: node id, outcome, duration, requirement IDs (``requirement`` marker), the DUT
it ran against, budget verdicts (``hil_budget``) and evidence (``hil_evidence``: values, tables,
figures, text).
"""

from __future__ import annotations

import hashlib
import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from .report_html import html  # the HTML report's presentation (labels, summary, matrix rows)

PROPERTY_PREFIX = "hil:"
#: the worst first: a test's outcome is the worst of its phases
OUTCOME_ORDER = ("failed", "error", "xpassed", "xfailed", "skipped", "passed")


def _atomic_write(path: Path, text: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(text.encode() if isinstance(text, str) else text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def requirement_verdict(tests: list[dict]) -> str:
    """fail: a test failed or a budget failed; marginal: a budget marginal; pass; or not tested."""
    ran = [t for t in tests if t["outcome"] not in ("skipped",)]
    if not ran:
        return "not tested"
    if any(t["outcome"] in ("failed", "error", "xpassed") for t in ran) or any(m["verdict"] == "fail" for t in ran for m in t["measurements"]):
        return "fail"
    if any(m["verdict"] == "marginal" for t in ran for m in t["measurements"]):
        return "marginal"
    return "pass"


@dataclass
class ReportWriter:
    directory: Path
    session: dict = field(default_factory=dict)
    requirements: dict = field(default_factory=dict)  #: id -> title (budgets and the catalogue)
    basename: str = "hil-report"

    def __post_init__(self):
        self.directory = Path(self.directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.records: list[dict] = []
        self.jsonl = self.directory / "results.jsonl"
        self.jsonl.write_text("")  # a new run starts a new log
        self.complete = False

    @property
    def paths(self) -> dict[str, Path]:
        return {"html": self.directory / f"{self.basename}.html", "json": self.directory / f"{self.basename}.json",
                "junit": self.directory / f"{self.basename}-junit.xml"}

    def add(self, record: dict) -> None:
        self.records.append(record)
        with open(self.jsonl, "a") as f:
            f.write(json.dumps(record) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.render()

    def finish(self, summary: dict) -> None:
        self.complete = True
        self.session = {**self.session, **summary}
        self.render()

    # --- content ---------------------------------------------------------------------------------
    def content(self) -> dict:
        counts = {k: 0 for k in OUTCOME_ORDER}
        for r in self.records:
            counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
        reqs: dict[str, dict] = {rid: {"id": rid, "title": title, "tests": []} for rid, title in self.requirements.items()}
        for r in self.records:
            ids = set(r["requirements"]) | {m["requirement"] for m in r["measurements"]}
            for rid in sorted(ids):
                reqs.setdefault(rid, {"id": rid, "title": "", "tests": []})["tests"].append(r)
        matrix = []
        for rid in sorted(reqs):
            tests = reqs[rid]["tests"]
            # a test's measurements of this requirement's budgets; a test tied by its marker only
            # proves the requirement with all of its measurements
            rows = [{"nodeid": t["nodeid"], "dut": t.get("dut", ""), "outcome": t["outcome"],
                     "measurements": [m for m in t["measurements"] if m["requirement"] == rid] or t["measurements"]}
                    for t in tests]
            matrix.append({"id": rid, "title": reqs[rid]["title"], "verdict": requirement_verdict(tests), "tests": rows})
        duts = {}
        for r in self.records:
            if r.get("dut") and r.get("dut_identity"):
                duts.setdefault(r["dut"], r["dut_identity"])
        failed = counts["failed"] + counts["error"] + counts["xpassed"]
        verdict = "FAIL" if failed or any(m["verdict"] == "fail" for m in matrix) else ("INCOMPLETE" if not self.complete else "PASS")
        return {"format": "hil-report/1", "complete": self.complete, "verdict": verdict, "counts": counts,
                "session": self.session, "duts": duts, "traceability": matrix, "tests": self.records}

    # --- rendering -------------------------------------------------------------------------------
    def render(self) -> None:
        content = self.content()
        _atomic_write(self.paths["json"], json.dumps(content, indent=1, default=str))
        _atomic_write(self.paths["junit"], junit_xml(content))
        _atomic_write(self.paths["html"], html(content, self.directory))


def junit_xml(content: dict) -> bytes:
    c = content["counts"]
    suite = ET.Element("testsuite", name="hil", tests=str(len(content["tests"])), failures=str(c["failed"] + c["xpassed"]),
                       errors=str(c["error"]), skipped=str(c["skipped"] + c["xfailed"]),
                       time=f"{sum(t['duration_s'] for t in content['tests']):.3f}",
                       timestamp=str(content["session"].get("started", "")))
    props = ET.SubElement(suite, "properties")
    for key in ("plant", "plant_sha256", "seed", "hypothesis_seed", "budgets"):
        if key in content["session"]:
            ET.SubElement(props, "property", name=f"hil.{key}", value=str(content["session"][key]))
    for t in content["tests"]:
        module, _, name = t["nodeid"].rpartition("::")
        case = ET.SubElement(suite, "testcase", classname=module.replace("/", ".").removesuffix(".py"), name=name,
                             time=f"{t['duration_s']:.3f}")
        cp = ET.SubElement(case, "properties")
        for rid in t["requirements"]:
            ET.SubElement(cp, "property", name="requirement", value=rid)
        if t.get("dut"):
            ET.SubElement(cp, "property", name="dut", value=t["dut"])
        for m in t["measurements"]:
            ET.SubElement(cp, "property", name=f"measurement:{m['budget']}",
                          value=f"{m['measured']:.6g} {m['unit']} (limit {m['limit']:.6g}, {m['verdict']}, {m['requirement']})")
        for e in t["evidence"]:
            if e["kind"] == "value":
                ET.SubElement(cp, "property", name=f"value:{e['name']}", value=f"{e['value']} {e.get('unit', '')}".strip())
        if t["outcome"] in ("failed", "xpassed"):
            ET.SubElement(case, "failure", message=t["message"][:500]).text = t["details"]
        elif t["outcome"] == "error":
            ET.SubElement(case, "error", message=t["message"][:500]).text = t["details"]
        elif t["outcome"] in ("skipped", "xfailed"):
            ET.SubElement(case, "skipped", message=t["message"][:500])
    ET.indent(suite)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
