"""What the history holds of one run, built from the run's report content (``ReportWriter.content()``,
the same data as ``hil-report.json``): a live run and an imported report go through ``from_report``.

Standard library only (the plugin builds a record at the end of every run it reports).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import subprocess
import uuid as uuidlib
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

#: the namespace of the UUID an imported report gets when it carries none (the same report, the same UUID)
IMPORT_NAMESPACE = uuidlib.UUID("5b0d6a36-4f0e-4c38-9a57-0c4f7d1e2a47")
#: a replay file larger than this is recorded by path and hash only
REPLAY_MAX_BYTES = 1 << 20
#: the kinds of run
KINDS = ("acceptance", "pytest", "qualify", "campaign")


@dataclass
class DutRecord:
    """One controller of a run: its spec, the identity it read from the device, its build."""

    dut: str  #: the spec's id in the report (``virtual-canopen``)
    spec: str = ""
    vendor: str | None = None
    product: str | None = None
    revision: str | None = None
    serial: str | None = None
    firmware: str | None = None  #: what the device says of its firmware (0x100A, hil_sil_describe)
    firmware_sha256: str | None = None  #: the content hash of a firmware build (sil:, pil:)
    profile: str | None = None
    profile_sha256: str | None = None
    identity_key: str = ""  #: the device: vendor, product, serial (``identity_key``)
    build: str = ""  #: the firmware build: version text, revision, content hash (``build_label``)
    identity: dict = field(default_factory=dict)


@dataclass
class RunRecord:
    uuid: str
    kind: str
    started: datetime.datetime | None  #: UTC
    finished: datetime.datetime | None
    verdict: str
    report_complete: bool
    exit_status: int | None
    seed: int | None
    hypothesis_seed: str | None
    framework_version: str | None
    framework_commit: str | None
    station: str
    host: str
    command: str
    dut_specs: str
    plant: str | None
    plant_sha256: str | None
    budgets: str | None
    budgets_sha256: str | None
    report_path: str | None
    seeded_defect: str | None = None
    session: dict = field(default_factory=dict)
    verdict_reasons: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    duts: list[DutRecord] = field(default_factory=list)
    requirements: list[dict] = field(default_factory=list)  #: requirement, verdict
    #: requirement, budget, test, dut, identity_key, measured, limit, margin, unit, verdict, limit_kind,
    #: interval_low, interval_high
    measurements: list[dict] = field(default_factory=list)
    replays: list[dict] = field(default_factory=list)  #: test, path, sha256, content

    def as_dict(self) -> dict:
        d = asdict(self)
        for k in ("started", "finished"):
            d[k] = iso(d[k])
        return d


def iso(t: datetime.datetime | None) -> str | None:
    """A UTC time as ISO 8601 with its ``Z``."""
    return None if t is None else t.replace(microsecond=0).isoformat() + "Z"


def utc(text) -> datetime.datetime | None:
    """An ISO 8601 time (with its offset; none: local time) as naive UTC, or None."""
    if not text:
        return None
    if isinstance(text, datetime.datetime):
        t = text
    else:
        try:
            t = datetime.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
        except ValueError:
            return None
    if t.tzinfo is None:
        t = t.astimezone()
    return t.astimezone(datetime.timezone.utc).replace(tzinfo=None)


def _text(v) -> str | None:
    """An identity value as text: integers in hex (as the report shows them), None kept."""
    if v is None or v == "":
        return None
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return f"0x{v:X}"
    return str(v)


def identity_key(identity: dict, spec: str = "") -> str:
    """The device a run judged, as one string: vendor, product and serial read from it (a seeded
    defect of ``hil qualify`` makes it another device: a mutant never joins the real one's trends).
    A device that reads none of them is named by its spec."""
    parts = {k: _text(identity.get(name)) for k, name in (("vendor", "vendor_id"), ("product", "product_code"),
                                                           ("serial", "serial"))}
    if not any(parts.values()):
        key = f"spec={spec}"
    else:
        key = ",".join(f"{k}={v or '-'}" for k, v in parts.items())
    defect = identity.get("seeded defect")
    return key + (f",defect={defect}" if defect else "")


def build_label(identity: dict, firmware_sha256: str | None = None) -> str:
    """The firmware build, as a person names it: what the device says of its firmware (else its
    revision), with the build's content hash where there is one (sil:, pil:)."""
    name = _text(identity.get("firmware")) or (f"rev {_text(identity.get('revision'))}"
                                               if identity.get("revision") is not None else "")
    if firmware_sha256:
        name = f"{name} #{firmware_sha256[:10]}".strip()
    return name or "-"


def file_sha256(path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def dut_build(link) -> dict:
    """What a run records of an opened controller's build (the plugin calls it once per DUT): the
    content hash of a firmware image it loaded (``sil:``'s shared library, a ``pil:`` ELF), and its
    device profile with the profile file's hash."""
    out: dict = {}
    for attr in ("library", "elf", "image", "firmware_path"):
        path = getattr(link, attr, None)
        if path and Path(path).is_file():
            out["firmware_sha256"] = file_sha256(path)
            break
    profile = getattr(getattr(link, "profile", None), "path", None)
    if profile:
        out["profile"] = str(profile)
        out["profile_sha256"] = file_sha256(profile)
    return out


@lru_cache(maxsize=1)
def framework_commit() -> str | None:
    """The git commit of the framework's source (``-dirty`` with changes), or None outside a checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=40"],
                             capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def kind_of(command: str, configured: str | None = None) -> str:
    """acceptance, qualify, campaign or pytest: as configured (``HIL_RUN_KIND``), else from the command."""
    if configured in KINDS:
        return configured
    words = command.split()
    for k in ("acceptance", "qualify", "campaign"):
        if k in words[:4]:
            return k
    return "pytest"


def _replays(report_dir: Path | None, started: datetime.datetime | None, failing: set[str]) -> list[dict]:
    """The replay files (``replays/*.json``) this run wrote for its failing tests: each stimulus names
    its test; a file older than the run is an earlier run's."""
    if report_dir is None or not (Path(report_dir) / "replays").is_dir():
        return []
    since = (started - datetime.timedelta(seconds=2)).replace(tzinfo=datetime.timezone.utc).timestamp() \
        if started else 0.0
    out = []
    for path in sorted((Path(report_dir) / "replays").glob("*.json")):
        try:
            if path.stat().st_mtime < since:
                continue
            data = path.read_bytes()
        except OSError:
            continue
        try:
            test = json.loads(data).get("test") or ""
        except (ValueError, AttributeError):
            test = ""
        if failing and test and test not in failing:
            continue
        out.append({"test": test, "path": str(path), "sha256": hashlib.sha256(data).hexdigest(),
                    "content": data.decode("utf-8", "replace") if len(data) <= REPLAY_MAX_BYTES else None})
    return out


def from_report(content: dict, *, report_dir: Path | None = None, station: str | None = None,
                kind: str | None = None) -> RunRecord:
    """The record of a run from its report content (a live run's, or a ``hil-report.json`` read back)."""
    s = content.get("session", {}) or {}
    started, finished = utc(s.get("started")), utc(s.get("finished"))
    command = str(s.get("command", ""))
    run_uuid = s.get("run_uuid") or str(uuidlib.uuid5(
        IMPORT_NAMESPACE, json.dumps({k: s.get(k) for k in ("started", "host", "command", "dut", "finished")},
                                     sort_keys=True, default=str)))
    builds = content.get("dut_builds", {}) or {}
    specs = [t.strip() for t in str(s.get("dut", "")).split(",") if t.strip()]
    duts: dict[str, DutRecord] = {}
    for dut, identity in (content.get("duts") or {}).items():
        b = builds.get(dut, {})
        duts[dut] = DutRecord(
            dut=dut, spec=next((t for t in specs if _spec_id(t) == dut), dut),
            vendor=_text(identity.get("vendor_id")), product=_text(identity.get("product_code")),
            revision=_text(identity.get("revision")), serial=_text(identity.get("serial")),
            firmware=_text(identity.get("firmware")), firmware_sha256=b.get("firmware_sha256"),
            profile=b.get("profile"), profile_sha256=b.get("profile_sha256"),
            identity_key=identity_key(identity, dut), build=build_label(identity, b.get("firmware_sha256")),
            identity=dict(identity))
    measurements, failing = [], set()
    for t in content.get("tests", []):
        if t.get("verdict", t.get("outcome")) in ("fail", "error", "failed"):
            failing.add(t["nodeid"])
        dut = t.get("dut", "") or ""
        for m in t.get("measurements", []):
            interval = m.get("interval") or [m.get("interval_low"), m.get("interval_high")]
            measurements.append({
                "requirement": m.get("requirement", ""), "budget": m.get("budget", ""), "test": t["nodeid"],
                "dut": dut,
                "identity_key": duts[dut].identity_key if dut in duts else f"spec={dut or s.get('dut', '')}",
                "measured": _num(m.get("measured")), "limit_value": _num(m.get("limit")),
                "margin": _num(m.get("margin")),
                "unit": m.get("unit", ""), "verdict": m.get("verdict", ""), "limit_kind": m.get("limit_kind", "max"),
                "interval_low": _num(interval[0]) if len(interval) > 1 else None,
                "interval_high": _num(interval[1]) if len(interval) > 1 else None,
            })
    defects = {str(i.get("seeded defect")) for i in (content.get("duts") or {}).values() if i.get("seeded defect")}
    versions = s.get("versions", {}) or {}
    return RunRecord(
        uuid=str(run_uuid), kind=kind_of(command, kind or s.get("run_kind")), started=started, finished=finished,
        verdict=str(content.get("verdict", "")), report_complete=bool(content.get("complete")),
        exit_status=s.get("exit_status"), seed=_int(s.get("seed")),
        hypothesis_seed=None if s.get("hypothesis_seed") is None else str(s.get("hypothesis_seed")),
        framework_version=versions.get("bldc-hil"), framework_commit=s.get("framework_commit"),
        station=station or s.get("station") or s.get("host") or "", host=str(s.get("host", "")), command=command,
        dut_specs=str(s.get("dut", "")), plant=s.get("plant"), plant_sha256=s.get("plant_sha256"),
        budgets=s.get("budgets"), budgets_sha256=s.get("budgets_sha256"),
        report_path=str(Path(report_dir) / "hil-report.json") if report_dir else s.get("report_path"),
        seeded_defect=", ".join(sorted(defects)) or s.get("seeded_defect"),
        session={k: v for k, v in s.items() if k not in ("history",)},
        verdict_reasons=list(content.get("verdict_reasons", [])), counts=dict(content.get("counts", {})),
        duts=list(duts.values()),
        requirements=[{"requirement": r["id"], "verdict": r.get("verdict", "")}
                      for r in content.get("traceability", [])],
        measurements=measurements, replays=_replays(report_dir, started, failing))


def _spec_id(text: str) -> str:
    """A spec's id as the report names its DUT (``hil.dut.spec.DutSpec.id``; loaded only when needed)."""
    try:
        from ..dut.spec import parse_dut

        return parse_dut(text).id
    except Exception:
        return text


def _num(v) -> float | None:
    try:
        return None if v is None or isinstance(v, bool) else float(v)
    except (TypeError, ValueError):
        return None


def _int(v) -> int | None:
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None


def from_campaign(summary: dict, rows: list[dict], budgets: dict[str, dict], *, out_dir: Path, plant_sha256: str | None,
                  finished: datetime.datetime, station: str, run_uuid: str, command: str) -> RunRecord:
    """The record of a ``hil campaign`` (``CampaignResult.summary()`` and its rows; ``budgets``: name ->
    requirement, unit, limit, kind): per budget the worst point's figure, per requirement the worst
    of its budgets' verdicts over the points, the failing points' replay files. Its verdict: FAIL
    with a failing or erroring point, INCOMPLETE when interrupted, else PASS."""
    import math
    import platform

    order = ("fail", "marginal", "pass")
    measurements, verdicts = [], {}
    for name, b in budgets.items():
        done = [r for r in rows if isinstance(r.get(f"{name}.measured"), (int, float))
                and math.isfinite(r[f"{name}.measured"])]
        worst = (max if b["kind"] == "max" else min)(done, key=lambda r: r[f"{name}.measured"]) if done else None
        for r in rows:
            v = r.get(f"{name}.verdict", "error")
            v = "fail" if v == "error" else v
            verdicts[b["requirement"]] = min(verdicts.get(b["requirement"], "pass"), v, key=order.index)
        if worst is not None:
            measurements.append({
                "requirement": b["requirement"], "budget": name,
                "test": f"campaign {summary['campaign']} point {worst['index']}", "dut": "",
                "identity_key": "spec=virtual:in-process", "measured": float(worst[f"{name}.measured"]),
                "limit_value": float(b["limit"]), "margin": _num(worst.get(f"{name}.margin")), "unit": b["unit"],
                "verdict": worst.get(f"{name}.verdict", ""), "limit_kind": b["kind"],
                "interval_low": None, "interval_high": None})
    if summary.get("interrupted") or not summary.get("complete"):
        verdict = "INCOMPLETE" if not (summary.get("fail") or summary.get("error")) else "FAIL"
    else:
        verdict = "FAIL" if summary.get("fail") or summary.get("error") else "PASS"
    started = finished - datetime.timedelta(seconds=float(summary.get("elapsed_s") or 0.0))
    replays = []
    for r in rows:
        if r.get("replay"):
            data = Path(r["replay"]).read_bytes() if Path(r["replay"]).is_file() else b""
            replays.append({"test": f"campaign {summary['campaign']} point {r['index']}", "path": str(r["replay"]),
                            "sha256": hashlib.sha256(data).hexdigest(),
                            "content": data.decode("utf-8", "replace") if 0 < len(data) <= REPLAY_MAX_BYTES else None})
    from importlib import metadata

    try:
        version = metadata.version("bldc-hil")
    except metadata.PackageNotFoundError:
        version = None
    return RunRecord(
        uuid=run_uuid, kind="campaign", started=started, finished=finished, verdict=verdict,
        report_complete=bool(summary.get("complete")), exit_status=None, seed=_int(summary.get("seed")),
        hypothesis_seed=None, framework_version=version, framework_commit=framework_commit(), station=station,
        host=platform.node(), command=command, dut_specs="virtual:in-process", plant=summary.get("spec"),
        plant_sha256=plant_sha256, budgets=summary.get("spec"), budgets_sha256=file_sha256(summary["spec"])
        if summary.get("spec") else None, report_path=str(Path(out_dir) / "campaign.json"),
        session={k: summary.get(k) for k in ("campaign", "spec", "kind", "points_planned", "points_done",
                                             "scheduler", "workers_used", "elapsed_s")},
        verdict_reasons=[f"{summary.get('fail', 0)} failing and {summary.get('error', 0)} erroring point(s) of "
                         f"{summary.get('points_done', 0)}"] if verdict != "PASS" else [],
        counts={k: summary.get(k, 0) for k in ("pass", "marginal", "fail", "error")},
        duts=[DutRecord(dut="", spec="virtual:in-process", identity_key="spec=virtual:in-process",
                        build=f"bldc-hil {version or '-'}")],
        requirements=[{"requirement": k, "verdict": v} for k, v in sorted(verdicts.items())],
        measurements=measurements, replays=replays)
