"""The results history's speed (docs/history.md): a store of 10,000 runs, and what one run costs.

Fills an SQLite store (or ``--history URL``) with a year of runs of three firmware lines on four
stations and six controllers (each run: 25 requirement verdicts, 30 figures), then times:

* recording one run at the end of an acceptance run: the look-back for the report's trends and
  regressions plus the write, against its named peer, the report's own rendering of the same run
  (``ReportWriter.render``: HTML, JSON, JUnit), the work every run already does at its end;
* ``hil history list`` (default, and with each filter), ``diff`` of two runs, ``show`` and ``trend``
  on the full store, each as the command's own function, in this process (the interpreter's start
  and imports are ``hil --help``'s figure, benchmarks/bench_cli_help.py).

A figure, not a test: ``python benchmarks/bench_history.py [--runs 10000] [--history URL]``.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import random
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REQUIREMENTS = [f"REQ-B-{k:03d}" for k in range(25)]
BUDGETS = [(f"budget_{k:02d}", REQUIREMENTS[k % 25]) for k in range(30)]
STATIONS = ["bench-1", "bench-2", "bench-3", "bench-4"]
LINES = ["pump-a", "pump-b", "pump-c"]


def fill(url: str, runs: int, seed: int = 0) -> None:
    """``runs`` complete runs written in bulk (a transaction per 500: filling is not what is timed)."""
    import sqlalchemy as sa

    from hil.history.store import T, Store

    rng = random.Random(seed)
    store = Store.open(url)
    start = datetime.datetime(2025, 1, 1)
    with store.engine.begin() as conn:
        next_id = int(conn.execute(sa.select(sa.func.coalesce(sa.func.max(T["runs"].c.id), 0))).scalar()) + 1
    for chunk in range(0, runs, 500):
        rows = {"runs": [], "duts": [], "requirements": [], "measurements": []}
        for k in range(chunk, min(runs, chunk + 500)):
            run_id = next_id + k
            line = LINES[k % 3]
            serial = 1 + k % 6
            build = f"{line}-v{1 + k * 12 // runs}"
            ident = f"vendor=0xB1D,product=0x48000{k % 3},serial=0x{serial:X}"
            verdict = "FAIL" if rng.random() < 0.1 else "PASS"
            t = start + datetime.timedelta(minutes=52 * k)
            rows["runs"].append({"id": run_id, "uuid": str(uuid.UUID(int=rng.getrandbits(128))), "complete": True,
                                 "kind": "acceptance", "started": t, "finished": t + datetime.timedelta(minutes=2),
                                 "verdict": verdict, "report_complete": True, "exit_status": int(verdict != "PASS"),
                                 "seed": k, "station": STATIONS[k % 4], "host": STATIONS[k % 4],
                                 "command": "hil acceptance", "dut_specs": "canopen:interface=pcan",
                                 "framework_version": "0.1.0", "plant": "paper-bench (preset)",
                                 "budgets": "defaults", "session": {}, "verdict_reasons": [], "counts": {}})
            rows["duts"].append({"run_id": run_id, "dut": "canopen-5", "spec": "canopen:interface=pcan",
                                 "vendor": "0xB1D", "product": f"0x48000{k % 3}", "serial": f"0x{serial:X}",
                                 "firmware": build, "identity_key": ident, "build": build, "identity": {}})
            rows["requirements"] += [{"run_id": run_id, "requirement": r, "verdict": "pass"} for r in REQUIREMENTS]
            rows["measurements"] += [
                {"run_id": run_id, "requirement": req, "budget": b, "dut": "canopen-5", "identity_key": ident,
                 "test": f"test_cases/test_x.py::test_{b}[canopen-5]", "measured": 0.3 + 0.01 * rng.gauss(0, 1),
                 "limit_value": 0.6, "margin": 0.3, "unit": "deg_e", "verdict": "pass", "limit_kind": "max"}
                for b, req in BUDGETS]
        with store.engine.begin() as conn:
            for name, values in rows.items():
                conn.execute(T[name].insert(), values)
    store.close()


def timed(fn, repeat: int = 5) -> float:
    """The median wall time of ``fn()`` over ``repeat`` calls, output swallowed."""
    times = []
    for _ in range(repeat):
        with contextlib.redirect_stdout(io.StringIO()):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def synthetic_report(measurements: int = 30) -> dict:
    """A run's report content as ``hil acceptance`` writes it: one controller, 37 tests."""
    ident = {"vendor_id": 0xB1D, "product_code": 0x480000, "revision": 1, "serial": 1, "firmware": "pump-a-v12"}
    tests = []
    for k in range(37):
        ms = [{"budget": b, "requirement": r, "measured": 0.31, "limit": 0.6, "unit": "deg_e", "margin": 0.29,
               "verdict": "pass", "limit_kind": "max"} for b, r in BUDGETS[k:k + 1]] if k < measurements else []
        tests.append({"nodeid": f"test_cases/test_x.py::test_{BUDGETS[k % 30][0]}[canopen-5]", "outcome": "passed",
                      "duration_s": 1.0, "message": "", "details": "", "requirements": [BUDGETS[k % 30][1]],
                      "budget_only": [], "measurements": ms, "evidence": [], "dut": "canopen-5",
                      "dut_identity": ident, "doc": "", "worker": "", "xfail_reason": "", "not_testable": None,
                      "failed_by": ""})
    return tests, ident


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--history", help="a store URL (default: a new SQLite file in a temporary directory)")
    args = ap.parse_args()
    from hil.history import cli as hcli
    from hil.history.hook import RunHistory
    from hil.history.location import resolve, shown
    from hil.history.store import Store
    from hil.verdicts.record import TestRecord
    from hil.verdicts.report import ReportWriter

    tmp = Path(tempfile.mkdtemp(prefix="bench-history-"))
    url = resolve(args.history or str(tmp / "history.sqlite"))
    t0 = time.perf_counter()
    fill(url, args.runs)
    print(f"filled {shown(url)} with {args.runs} runs in {time.perf_counter() - t0:.1f} s")
    store = Store.open(url)
    print(f"store: {store.counts()}")
    store.close()

    # one run's end: its report rendered (the peer), then the look-back and the write
    tests, ident = synthetic_report()
    writer = ReportWriter(tmp / "rep", session={"started": datetime.datetime.now().astimezone().isoformat(),
                                                 "dut": "canopen:interface=pcan", "host": "bench-1",
                                                 "command": "hil acceptance"})
    for t in tests:
        writer.records.append(TestRecord.from_json(t))
    writer.finish({"exit_status": 0})
    render_s = timed(writer.render, 3)

    def record():
        h = RunHistory(url)
        writer.history = h.look_back(writer.content())
        assert h.record(writer.content(), tmp / "rep") is not None, h.warning

    record_s = timed(record, 3)
    print(f"recording one run (look-back + write): {record_s * 1e3:.0f} ms; the report's rendering of the same run "
          f"{render_s * 1e3:.0f} ms (ratio {record_s / render_s:.2f})")

    ns = argparse.Namespace
    common = {"history": url, "json": None}
    cases = {
        "list": ns(dut=None, firmware=None, station=None, verdict=None, kind=None, since=None, until=None, limit=50),
        "list --dut serial=0x3": ns(dut="serial=0x3", firmware=None, station=None, verdict=None, kind=None, since=None,
                                    until=None, limit=50),
        "list --firmware pump-b-v7 --station bench-2": ns(dut=None, firmware="pump-b-v7", station="bench-2",
                                                          verdict=None, kind=None, since=None, until=None, limit=50),
        "list --verdict FAIL --since 2025-06-01 --until 2025-07-01": ns(
            dut=None, firmware=None, station=None, verdict="FAIL", kind=None, since=datetime.datetime(2025, 6, 1),
            until=datetime.datetime(2025, 7, 1), limit=50),
    }
    for name, a in cases.items():
        a.__dict__.update(common)
        print(f"hil history {name}: {timed(lambda: hcli.cmd_list(a)) * 1e3:.0f} ms")
    last = args.runs
    d = ns(run_a=str(last // 2), run_b=str(last), all=False, **common)
    print(f"hil history diff {last // 2} {last}: {timed(lambda: hcli.cmd_diff(d)) * 1e3:.0f} ms")
    s = ns(run=str(last), **common)
    print(f"hil history show {last}: {timed(lambda: hcli.cmd_show(s)) * 1e3:.0f} ms")
    tr = ns(budget="budget_03", dut="vendor=0xB1D,product=0x480000,serial=0x1", test=None, last=100, plot=None,
            html=None, **common)
    print(f"hil history trend budget_03 --dut ...: {timed(lambda: hcli.cmd_trend(tr)) * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
