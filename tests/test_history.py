"""The results history (docs/history.md): what a record holds, the schema's migrations, the commands,
regressions, and that a failing store never costs a run its report. The store tests run on SQLite
and on a real PostgreSQL server this module starts (skipped, with the reason, where it cannot)."""

from __future__ import annotations

import datetime
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from glob import glob
from pathlib import Path

import pytest
import sqlalchemy as sa

import hil.verdicts.budgets  # noqa: F401  (loaded before the in-process pytest runs below: pytester drops what a run imports)
import hil.pytest_plugin  # noqa: F401
from hil.cli import main
from hil.history import store as store_module
from hil.history.compare import diff, look_back
from hil.history.hook import RunHistory
from hil.history.record import from_campaign, from_report
from hil.history.store import SCHEMA_VERSION, T, HistoryError, Store

ROOT = Path(__file__).resolve().parents[1]
IDENTITY = {"vendor_id": 0xB1D, "product_code": 0x480001, "revision": 0x10000, "serial": 7, "firmware": "fw-1.4"}


def report(*, measured: float = 0.29, verdict: str = "PASS", started: str = "2026-01-05T10:00:00+00:00",
           firmware: str = "fw-1.4", serial: int = 7, station: str = "st1", interval=None, run_uuid: str | None = None,
           req_verdict: str = "pass", extra_budgets: int = 0) -> dict:
    """A tiny hil-report/1 content: one controller, one requirement, one budget (and ``extra_budgets`` more)."""
    identity = {**IDENTITY, "firmware": firmware, "serial": serial}
    m = {"budget": "commutation_angle_p99", "requirement": "REQ-COMM-001", "measured": measured, "limit": 0.6,
         "unit": "deg_e", "margin": 0.6 - measured, "verdict": "pass" if measured <= 0.6 else "fail",
         "limit_kind": "max"}
    ms = [m] + [{**m, "budget": f"extra_{k}", "requirement": f"REQ-X-{k:03d}", "measured": 0.1 * k}
                for k in range(extra_budgets)]
    if interval:
        m["interval"] = list(interval)
    nodeid = "test_cases/test_calibration_recovery.py::test_calibration[virtual-canopen-combined]"
    return {
        "format": "hil-report/1", "complete": True, "incomplete_reason": "", "verdict": verdict,
        "verdict_reasons": [] if verdict == "PASS" else ["REQ-COMM-001: fail"],
        "counts": {"passed": 1},
        "session": {"started": started, "finished": started.replace("10:00:00", "10:05:00"), "host": "vm",
                    "station": station, "command": "hil acceptance", "dut": "virtual:canopen",
                    "plant": "paper-bench (preset)", "plant_sha256": "e14047dbb56dc230", "budgets": "defaults",
                    "seed": 3, "hypothesis_seed": "3", "versions": {"bldc-hil": "0.1.0"},
                    "framework_commit": "abc123", "exit_status": 0, **({"run_uuid": run_uuid} if run_uuid else {})},
        "duts": {"virtual-canopen": identity},
        "dut_builds": {"virtual-canopen": {"spec": "virtual:canopen", "firmware_sha256": "f" * 64,
                                           "profile": "canopen.toml", "profile_sha256": "a" * 64}},
        "traceability": [{"id": "REQ-COMM-001", "verdict": req_verdict, "tests": []}],
        "tests": [{"nodeid": nodeid, "outcome": "passed", "verdict": "pass", "dut": "virtual-canopen",
                   "measurements": ms, "requirements": ["REQ-COMM-001"]}],
    }


# ------------------------------------------------------------------------------ PostgreSQL, started here
def _pg_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def postgres_url():
    """A throwaway PostgreSQL cluster on a loopback port (initdb, pg_ctl; as the ``postgres`` user when
    this runs as root, which PostgreSQL refuses), stopped and removed at the end."""
    initdb, pg_ctl = _pg_bin("initdb"), _pg_bin("pg_ctl")
    if not (initdb and pg_ctl):
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not found: apt-get install postgresql")
    base = Path(tempfile.mkdtemp(prefix="hil-pg-"))
    prefix: list[str] = []
    if os.geteuid() == 0:  # initdb and postgres refuse to run as root
        import pwd

        user = next((u for u in ("postgres", "nobody") if _has_user(u, pwd)), None)
        if user is None or not shutil.which("runuser"):
            pytest.skip("running as root with no postgres/nobody user and runuser to start PostgreSQL as")
        shutil.chown(base, user)
        prefix = ["runuser", "-u", user, "--"]
    port = _free_port()
    data = base / "data"
    try:
        out = subprocess.run([*prefix, initdb, "-D", str(data), "-A", "trust", "-U", "hil", "--no-sync", "-E", "UTF8"],
                             capture_output=True, text=True, timeout=120)
        if out.returncode != 0:
            pytest.skip(f"PostgreSQL initdb failed: {(out.stderr or out.stdout).strip().splitlines()[-1:]}")
        out = subprocess.run([*prefix, pg_ctl, "-D", str(data), "-l", str(base / "log"), "-w", "-t", "60", "-o",
                              f"-k {base} -p {port} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=60",
                              "start"], capture_output=True, text=True, timeout=120)
        if out.returncode != 0:
            log = (base / "log").read_text() if (base / "log").exists() else out.stderr
            pytest.skip(f"PostgreSQL did not start: {log.strip().splitlines()[-1:]}")
        yield f"postgresql+psycopg://hil@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "immediate", "stop"], capture_output=True, timeout=60)
        shutil.rmtree(base, ignore_errors=True)


def _has_user(name, pwd) -> bool:
    try:
        pwd.getpwnam(name)
        return True
    except KeyError:
        return False


@pytest.fixture(params=["sqlite", "postgresql"])
def url(request, tmp_path):
    """A new, empty store: an SQLite file, or a database of its own on the session's PostgreSQL server."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'history.sqlite'}"
    server = request.getfixturevalue("postgres_url")
    name = f"h{uuid.uuid4().hex[:12]}"
    engine = sa.create_engine(server, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sa.text(f"CREATE DATABASE {name}"))
    engine.dispose()
    return server.rsplit("/", 1)[0] + f"/{name}"


# ------------------------------------------------------------------------------ records and the store
def test_a_record_holds_the_run_its_controller_build_requirements_and_budgets(url):
    store = Store.open(url)
    rec = from_report(report(interval=(0.27, 0.31)))
    run_id, new = store.write(rec)
    assert new
    run = store.find(str(run_id))
    assert (run["verdict"], run["seed"], run["station"], run["framework_version"], run["framework_commit"]) == (
        "PASS", 3, "st1", "0.1.0", "abc123")
    assert run["started"] == datetime.datetime(2026, 1, 5, 10, 0) and run["complete"]
    (dut,) = run["duts"]
    assert dut["identity_key"] == "vendor=0xB1D,product=0x480001,serial=0x7"
    assert (dut["firmware"], dut["revision"], dut["firmware_sha256"], dut["profile_sha256"]) == (
        "fw-1.4", "0x10000", "f" * 64, "a" * 64)
    assert dut["build"] == "fw-1.4 #ffffffffff"
    assert run["requirements"] == [{"id": run["requirements"][0]["id"], "run_id": run_id,
                                    "requirement": "REQ-COMM-001", "verdict": "pass"}]
    (m,) = run["measurements"]
    assert (m["measured"], m["limit_value"], m["unit"], m["interval_low"], m["interval_high"]) == (
        0.29, 0.6, "deg_e", 0.27, 0.31)
    assert m["margin"] == pytest.approx(0.31)
    assert store.find(rec.uuid[:8])["id"] == run_id  # by a UUID prefix too
    assert store.write(rec) == (run_id, False)  # the same run again: nothing written twice
    assert store.counts() == {"runs": 1, "measurements": 1}
    store.close()


def test_a_write_that_fails_half_way_leaves_nothing(url):
    """One transaction per run: a record whose measurements cannot be written leaves no run row."""
    store = Store.open(url)
    rec = from_report(report())
    rec.measurements.append({**rec.measurements[0], "budget": None})  # NOT NULL: the insert fails
    with pytest.raises(sa.exc.IntegrityError):
        store.write(rec)
    assert store.counts() == {"runs": 0, "measurements": 0}
    store.close()


WRITER = """
import sys, uuid
from hil.history.record import from_report
from hil.history.store import Store
sys.path.insert(0, {tests!r})
from test_history import report
store = Store.open(sys.argv[1])
for k in range(int(sys.argv[3])):
    store.write(from_report(report(run_uuid=str(uuid.uuid4()), station='st' + sys.argv[2], extra_budgets=9)))
store.write(from_report(report(run_uuid='00000000-0000-4000-8000-000000000001')))  # every writer: the same run
"""


def test_concurrent_writers_lose_and_duplicate_nothing(url, tmp_path):
    """Four processes (stations, xdist workers) write at once: every run once, every figure once."""
    Store.open(url).close()  # built once; the race is the writes
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(tests=str(ROOT / "tests")))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    procs = [subprocess.Popen([sys.executable, str(script), url, str(k), "8"], env=env, stderr=subprocess.PIPE,
                              text=True) for k in range(4)]
    errors = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, errors
    store = Store.open(url)
    with store.engine.connect() as conn:
        uuids = [r.uuid for r in conn.execute(sa.select(T["runs"].c.uuid))]
        per_station = dict(conn.execute(sa.select(T["runs"].c.station, sa.func.count()).group_by(T["runs"].c.station))
                           .all())
    assert len(uuids) == len(set(uuids)) == 4 * 8 + 1
    assert store.counts() == {"runs": 33, "measurements": 32 * 10 + 1}
    assert per_station == {"st0": 8, "st1": 8 + 1, "st2": 8, "st3": 8}  # the shared run names st1
    store.close()


KILLED = """
import os, sys, time
import sqlalchemy as sa
from hil.history.record import from_report
from hil.history.store import Store
sys.path.insert(0, {tests!r})
from test_history import report
store = Store.open(sys.argv[1])

@sa.event.listens_for(store.engine, "before_cursor_execute")
def stall(conn, cursor, statement, *args):
    if "INSERT INTO hil_measurements" in statement:
        open(sys.argv[2], "w").close()
        time.sleep(60)

store.write(from_report(report()))
"""


def test_a_run_killed_while_it_writes_leaves_no_record(tmp_path):
    url = f"sqlite:///{tmp_path / 'h.sqlite'}"
    Store.open(url).close()
    script, marker = tmp_path / "killed.py", tmp_path / "writing"
    script.write_text(KILLED.format(tests=str(ROOT / "tests")))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, str(script), url, str(marker)], env=env)
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert marker.exists(), "the writer never reached its measurements"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    store = Store.open(url)
    assert store.counts() == {"runs": 0, "measurements": 0} and store.runs() == []
    store.close()


# ------------------------------------------------------------------------------ schema and migrations
def test_migrations_from_nothing_give_the_schema_the_package_reads(tmp_path):
    store = Store.open(f"sqlite:///{tmp_path / 'h.sqlite'}")
    inspector = sa.inspect(store.engine)
    for table in T.values():
        assert {c["name"] for c in inspector.get_columns(table.name)} == {c.name for c in table.columns}, table.name
    assert store.version() == SCHEMA_VERSION
    store.close()


def test_an_older_store_is_upgraded_with_its_runs_kept(tmp_path, monkeypatch):
    url = f"sqlite:///{tmp_path / 'h.sqlite'}"
    monkeypatch.setattr(store_module, "SCHEMA_VERSION", 1)
    monkeypatch.setattr(store_module, "MIGRATIONS", store_module.MIGRATIONS[:1])
    old = Store.open(url)
    assert old.version() == 1
    with old.engine.begin() as conn:  # a run as version 1 wrote it (no interval columns)
        conn.execute(sa.text("INSERT INTO hil_runs (uuid, complete, kind, verdict) "
                             "VALUES ('u-1', 1, 'pytest', 'PASS')"))
        conn.execute(sa.text("INSERT INTO hil_measurements (run_id, budget, measured) VALUES (1, 'b', 0.5)"))
    old.close()
    monkeypatch.undo()
    store = Store.open(url)
    assert store.version() == SCHEMA_VERSION == 2
    run = store.run(1)
    assert run["uuid"] == "u-1" and run["measurements"][0]["measured"] == 0.5
    assert run["measurements"][0]["interval_low"] is None
    store.close()


def test_a_newer_store_is_refused_in_one_line(tmp_path, capsys):
    path = tmp_path / "h.sqlite"
    store = Store.open(f"sqlite:///{path}")
    with store.engine.begin() as conn:
        conn.execute(T["schema"].insert().values(version=SCHEMA_VERSION + 5, description="future",
                                                 applied=datetime.datetime(2030, 1, 1)))
    store.close()
    with pytest.raises(HistoryError) as exc:
        Store.open(f"sqlite:///{path}")
    assert "\n" not in str(exc.value) and f"schema version {SCHEMA_VERSION + 5} is newer" in str(exc.value)
    assert main(["history", "list", "--history", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "newer than this bldc-hil reads" in err[0], err


# ------------------------------------------------------------------------------ compare, regressions
def _store_with_builds(url: str) -> Store:
    """Runs of one controller: build 1.3 and 1.4 pass near 0.29 deg e, build 1.5 gives 0.41 (within
    the 0.6 limit, worse all the same; its runs FAIL on another requirement), on two stations; and
    another controller."""
    store = Store.open(url)
    figures = [("fw-1.3", 0.290), ("fw-1.3", 0.295), ("fw-1.4", 0.288), ("fw-1.4", 0.292), ("fw-1.4", 0.291),
               ("fw-1.5", 0.41), ("fw-1.5", 0.409)]
    for k, (fw, v) in enumerate(figures):
        store.write(from_report(report(measured=v, firmware=fw, started=f"2026-01-{k + 1:02d}T10:00:00+00:00",
                                       station=f"st{1 + k % 2}", verdict="FAIL" if fw == "fw-1.5" else "PASS")))
    store.write(from_report(report(measured=0.5, serial=9, started="2026-01-03T11:00:00+00:00", verdict="FAIL",
                                   req_verdict="fail")))
    return store


def test_list_filters_by_controller_firmware_station_verdict_and_date(tmp_path):
    store = _store_with_builds(f"sqlite:///{tmp_path / 'h.sqlite'}")
    assert len(store.runs()) == 8
    assert len(store.runs(dut="serial=0x9")) == 1 and len(store.runs(dut="0x7")) == 7
    assert [r["duts"][0]["firmware"] for r in store.runs(firmware="fw-1.5")] == ["fw-1.5", "fw-1.5"]
    assert len(store.runs(firmware="ffffff")) == 8  # by the build's content hash
    assert len(store.runs(station="st2")) == 3 and len(store.runs(verdict="fail")) == 3
    since = datetime.datetime(2026, 1, 6)
    assert [r["id"] for r in store.runs(since=since)] == [7, 6]
    assert len(store.runs(until=datetime.datetime(2026, 1, 3))) == 2
    store.close()


def test_a_regression_is_named_with_the_run_and_build_where_it_started(tmp_path):
    store = _store_with_builds(f"sqlite:///{tmp_path / 'h.sqlite'}")
    content = report(measured=0.41, firmware="fw-1.5", started="2026-01-09T10:00:00+00:00")
    h = RunHistory(f"sqlite:///{tmp_path / 'h.sqlite'}")
    back = h.look_back(content)
    (reg,) = back["regressions"]
    assert reg["name"] == "REQ-COMM-001 commutation_angle_p99"
    assert reg["last_pass"] == {"run": 5, "build": "fw-1.4 #ffffffffff", "measured": 0.291}
    assert reg["started"] == {"run": 6, "build": "fw-1.5 #ffffffffff"}
    assert reg["worse_by"] == pytest.approx(0.119)
    assert reg["line"].startswith("REQ-COMM-001 commutation_angle_p99 0.41 deg e, 0.12 above build fw-1.4 "
                                  "#ffffffffff's run 5 (the last PASS;")
    (trend,) = back["trends"].values()
    assert [p["run"] for p in trend] == [1, 2, 3, 4, 5, 6, 7]  # this controller's runs only
    # within the spread: no regression
    assert look_back(report(measured=0.292), [], {"virtual-canopen": "x"})["regressions"] == []
    store.close()


def test_diff_names_changed_verdicts_and_figures_moved_beyond_their_intervals():
    a = from_report(report(measured=0.29, interval=(0.28, 0.30), extra_budgets=2)).as_dict()
    b = from_report(report(measured=0.33, interval=(0.32, 0.34), req_verdict="marginal", extra_budgets=2)).as_dict()
    a["id"], b["id"] = 1, 2
    d = diff(a, b)
    assert [(r["requirement"], r["a"], r["b"]) for r in d["verdicts_changed"]] == [("REQ-COMM-001", "pass",
                                                                                     "marginal")]
    moved = {f["budget"]: f for f in d["figures"]}
    assert moved["commutation_angle_p99"]["moved"] and moved["commutation_angle_p99"]["spread_from"] == "intervals"
    assert moved["extra_1"]["moved"] is None  # no interval, no earlier runs: the spread is unknown
    # overlapping intervals: within the spread
    c = from_report(report(measured=0.305, interval=(0.29, 0.32))).as_dict()
    c["id"] = 3
    assert not diff(a, c)["figures"][0]["moved"]


def test_history_commands_print_tables_and_json(tmp_path, capsys):
    path = tmp_path / "h.sqlite"
    _store_with_builds(f"sqlite:///{path}").close()
    assert main(["history", "list", "--history", str(path), "--station", "st1"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("5 run(s) in sqlite:///") and "fw-1.5 #ffffffffff" in out
    assert main(["history", "list", "--history", str(path), "--json", "-"]) == 0
    runs = json.loads(capsys.readouterr().out)
    assert len(runs) == 8 and runs[0]["started"] == "2026-01-07T10:00:00Z"
    assert main(["history", "diff", "5", "6", "--history", str(path), "--json", "-"]) == 0
    d = json.loads(capsys.readouterr().out)
    (f,) = d["moved"]
    assert f["worse_by"] == pytest.approx(0.119) and f["spread_from"].startswith("2 sd of 5 runs")
    assert main(["history", "show", "8", "--history", str(path)]) == 0
    assert "REQ-COMM-001  fail" in capsys.readouterr().out
    png, page = tmp_path / "t.png", tmp_path / "t.html"
    assert main(["history", "trend", "commutation_angle_p99", "--dut", "serial=0x7", "--history", str(path),
                 "--plot", str(png), "--html", str(page)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG" and "fw-1.5" in page.read_text()
    assert main(["history", "trend", "commutation_angle_p99", "--history", str(path)]) == 2  # two controllers
    assert "give --dut one of" in capsys.readouterr().err


def test_import_records_a_report_once(tmp_path, capsys):
    path = tmp_path / "h.sqlite"
    rep = tmp_path / "rep"
    (rep / "replays").mkdir(parents=True)
    content = report(measured=0.7, verdict="FAIL", req_verdict="fail", started="2020-01-01T00:00:00+00:00")
    (rep / "hil-report.json").write_text(json.dumps(content))
    (rep / "replays" / "x.json").write_text(json.dumps({"test": content["tests"][0]["nodeid"], "kind": "deviations"}))
    assert main(["history", "import", str(rep), "--history", str(path)]) == 0
    assert "recorded as run 1 (FAIL" in capsys.readouterr().out
    assert main(["history", "import", str(rep / "hil-report.json"), "--history", str(path)]) == 0
    assert "recorded already: run 1" in capsys.readouterr().out
    store = Store.open(f"sqlite:///{path}")
    (replay,) = store.run(1)["replays"]
    assert replay["test"] == content["tests"][0]["nodeid"] and '"deviations"' in replay["content"]
    store.close()
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    assert main(["history", "import", str(tmp_path / "bad.json"), "--history", str(path)]) == 2
    assert "not a hil-report/1 file" in capsys.readouterr().err


def test_a_campaign_is_recorded_with_its_worst_points():
    summary = {"campaign": "sweep", "spec": None, "seed": 1, "complete": True, "interrupted": False, "fail": 1,
               "error": 0, "pass": 1, "marginal": 0, "points_done": 2, "elapsed_s": 3.0}
    rows = [{"index": 0, "b.measured": 0.2, "b.margin": 0.4, "b.verdict": "pass", "replay": None},
            {"index": 1, "b.measured": 0.9, "b.margin": -0.3, "b.verdict": "fail", "replay": None}]
    rec = from_campaign(summary, rows, {"b": {"requirement": "REQ-COMM-001", "unit": "deg_e", "limit": 0.6,
                                              "kind": "max"}}, out_dir=Path("."), plant_sha256="p", station="s",
                        run_uuid=str(uuid.uuid4()), command="hil campaign x.toml",
                        finished=datetime.datetime(2026, 1, 1))
    assert rec.verdict == "FAIL" and rec.kind == "campaign"
    assert rec.requirements == [{"requirement": "REQ-COMM-001", "verdict": "fail"}]
    (m,) = rec.measurements
    assert (m["measured"], m["margin"], m["test"]) == (0.9, -0.3, "campaign sweep point 1")


# ------------------------------------------------------------------------------ never the run's report
def test_a_locked_store_is_one_warning_and_records_nothing(tmp_path, monkeypatch):
    path = tmp_path / "h.sqlite"
    Store.open(f"sqlite:///{path}").close()
    monkeypatch.setattr(store_module, "LOCK_WAIT_S", 0.2)
    import sqlite3

    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        h = RunHistory(str(path))
        assert h.record(report(), None) is None
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    (line,) = h.summary_lines()
    assert line.startswith("hil history: warning: not recorded:") and "locked" in line


def test_a_password_is_never_shown(capsys):
    h = RunHistory("postgresql://hil:s3cret-pw@127.0.0.1:1/db")
    assert h.look_back(report()) is None and h.record(report(), None) is None
    (line,) = h.summary_lines()
    assert "s3cret-pw" not in line and "***" in line
    assert main(["history", "list", "--history", "postgresql+psycopg://hil:s3cret-pw@127.0.0.1:1/db"]) == 2
    err = capsys.readouterr().err
    assert "s3cret-pw" not in err and len(err.strip().splitlines()) == 1


PLUGIN_TEST = """
import pytest

@pytest.mark.requirement("REQ-COMM-001")
def test_measures(hil_budget):
    hil_budget("commutation_angle_p99", {value})

def test_plain():
    pass
"""


def test_a_pytest_run_with_the_plugin_is_recorded_and_its_report_shows_the_trend(pytester, monkeypatch, tmp_path):
    """End to end: three runs through the plugin (the third without a report directory), then an
    import of the first report finds it recorded already."""
    path = tmp_path / "h.sqlite"
    monkeypatch.setenv("HIL_HISTORY", str(path))
    pytester.makepyfile(test_m=PLUGIN_TEST.format(value=0.3))
    result = pytester.runpytest("--hil-report-dir", "rep", "--hil-station", "bench-3", "-p", "no:xdist")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines(["hil history: run 1 recorded in sqlite:///*h.sqlite"])
    first = json.loads((pytester.path / "rep" / "hil-report.json").read_text())
    pytester.makepyfile(test_m=PLUGIN_TEST.format(value=0.35))
    pytester.runpytest("--hil-report-dir", "rep2", "-p", "no:xdist").assert_outcomes(passed=2)
    html = (pytester.path / "rep2" / "hil-report.html").read_text()
    assert '<svg class="spark"' in html
    second = json.loads((pytester.path / "rep2" / "hil-report.json").read_text())
    assert [p["measured"] for p in next(iter(second["history"]["trends"].values()))] == [0.3]
    result = pytester.runpytest("-p", "no:xdist")  # no report directory: the history all the same
    result.stdout.fnmatch_lines(["hil history: run 3 recorded in *"])
    store = Store.open(f"sqlite:///{path}")
    runs = store.runs()
    assert [r["id"] for r in runs] == [3, 2, 1] and runs[2]["station"] == "bench-3"
    assert runs[2]["uuid"] == first["session"]["run_uuid"] and runs[2]["report_path"].endswith("hil-report.json")
    store.close()
    assert main(["history", "import", str(pytester.path / "rep"), "--history", str(path)]) == 0


def test_a_corrupt_store_costs_the_run_nothing_but_one_line(pytester, monkeypatch, tmp_path):
    bad = tmp_path / "corrupt.sqlite"
    bad.write_bytes(b"this is not a database" * 100)
    monkeypatch.setenv("HIL_HISTORY", str(bad))
    pytester.makepyfile(test_m=PLUGIN_TEST.format(value=0.3))
    result = pytester.runpytest("--hil-report-dir", "rep", "-p", "no:xdist")
    assert result.ret == 0
    lines = [line for line in result.outlines + result.errlines if "hil history" in line]
    assert len(lines) == 1 and "warning: not recorded" in lines[0], lines
    assert json.loads((pytester.path / "rep" / "hil-report.json").read_text())["verdict"] == "PASS"
