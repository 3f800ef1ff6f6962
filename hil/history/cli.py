"""``hil history``: list, show, diff, trend and import the runs of a results history (docs/history.md).

Every action prints a table on the terminal and, with ``--json PATH`` (``-`` for standard output),
writes the same result as JSON. Nothing heavy at the top (``hil --help`` builds this parser).
"""

from __future__ import annotations

import datetime
import json
import sys
from pathlib import Path

from .. import cli_grammar as grammar


def add_parser(sub) -> None:
    p = sub.add_parser("history", help="the results history: every run recorded (docs/history.md)")
    hs = p.add_subparsers(dest="sub", metavar="ACTION", required=True)

    q = hs.add_parser("list", help="the runs, newest first, filtered by controller, firmware, station, verdict, date")
    q.add_argument("--dut", help="a controller: its identity (vendor=..,product=..,serial=.., or a part), serial, "
                                 "spec or id")
    q.add_argument("--firmware", help="a firmware build: its version text, build label or content hash (a prefix)")
    q.add_argument("--station", help="the station's name")
    q.add_argument("--verdict", help="PASS, FAIL, INCOMPLETE or NO TESTS")
    q.add_argument("--kind", choices=("acceptance", "pytest", "qualify", "campaign"), help="the kind of run")
    q.add_argument("--since", type=_date, metavar="DATE", help="started on or after (YYYY-MM-DD or ISO time, UTC)")
    q.add_argument("--until", type=_date, metavar="DATE", help="started before (YYYY-MM-DD or ISO time, UTC)")
    q.add_argument("--limit", type=int, default=50, help="at most this many runs (default 50; 0: all)")
    _common(q, "the runs")
    q.set_defaults(func=cmd_list)

    q = hs.add_parser("show", help="one run: its controllers, requirement verdicts, budgets and replays")
    q.add_argument("run", metavar="RUN", help="the run's number or UUID (a prefix of 8 characters or more)")
    _common(q, "the run")
    q.set_defaults(func=cmd_show)

    q = hs.add_parser("diff", help="two runs requirement by requirement and budget by budget: verdicts that changed, "
                                   "figures that moved beyond their spread")
    q.add_argument("run_a", metavar="RUN_A", help="the earlier run (number or UUID)")
    q.add_argument("run_b", metavar="RUN_B", help="the later run (number or UUID)")
    q.add_argument("--all", action="store_true", help="list every figure, not only those that changed")
    _common(q, "the comparison")
    q.set_defaults(func=cmd_diff)

    q = hs.add_parser("trend", help="one budget's figure over the runs of one controller (PNG, HTML)")
    q.add_argument("budget", metavar="BUDGET", help="the budget's name (commutation_angle_p99)")
    q.add_argument("--dut", help="the controller's identity (default: the one controller that measured BUDGET)")
    q.add_argument("--test", help="only the tests whose node id holds this text")
    q.add_argument("--last", type=int, default=100, help="the last N runs (default 100)")
    q.add_argument("--plot", metavar="PATH", help="the trend as a PNG")
    q.add_argument("--html", metavar="PATH", help="the trend as a page (the PNG inlined, the table below)")
    _common(q, "the figures")
    q.set_defaults(func=cmd_trend)

    q = hs.add_parser("import", help="record existing hil-report.json files (a run already recorded is skipped)")
    q.add_argument("reports", metavar="REPORT", nargs="+", help="a hil-report.json, or a directory holding one")
    q.add_argument("--station", help="the station the runs ran at (default: the report's, else its host)")
    _common(q, "what was imported")
    q.set_defaults(func=cmd_import)


def _common(p, what: str) -> None:
    grammar.add_history(p)
    grammar.add_json(p, f"{what} ('-': standard output)")


def _date(text: str) -> datetime.datetime:
    from .record import utc

    t = utc(text if "T" in text else f"{text}T00:00:00+00:00")
    if t is None:
        import argparse

        raise argparse.ArgumentTypeError(f"{text!r}: give a date (YYYY-MM-DD) or an ISO 8601 time")
    return t


def _open(args):
    from .location import resolve
    from .store import HistoryError, Store

    url = resolve(args.history)
    if url is None:
        raise HistoryError("the history is off (--history off or HIL_HISTORY=off): nothing to read")
    return Store.open(url)


def _emit_json(path: str | None, data) -> None:
    if not path:
        return
    from .store import plain

    text = json.dumps(plain(data) if isinstance(data, dict) else [plain(x) for x in data], indent=1, default=str)
    if path == "-":
        print(text)
    else:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(text + "\n")


def table(rows: list[list], header: list[str]) -> str:
    """Rows as aligned text columns (numbers right-aligned)."""
    cells = [[_cell(v) for v in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(header)]
    numeric = [all(isinstance(r[i], (int, float)) or r[i] in (None, "") for r in rows) and rows
               for i in range(len(header))]
    fmt = lambda vals: "  ".join(v.rjust(w) if n else v.ljust(w) for v, w, n in zip(vals, widths, numeric))  # noqa: E731
    return "\n".join([fmt(header).rstrip(), fmt(["-" * w for w in widths]).rstrip(), *(fmt(r).rstrip() for r in cells)])


def _cell(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, datetime.datetime):
        return v.strftime("%Y-%m-%d %H:%M")
    return str(v)


def _builds(run: dict) -> str:
    return ", ".join(dict.fromkeys(d["build"] or "-" for d in run["duts"])) or "-"


def cmd_list(args) -> int:
    store = _open(args)
    try:
        runs = store.runs(dut=args.dut, firmware=args.firmware, station=args.station, verdict=args.verdict,
                          kind=args.kind, since=args.since, until=args.until, limit=args.limit or None)
    finally:
        store.close()
    if args.json != "-":
        print(f"{len(runs)} run(s) in {store.shown}" + (" (newest first)" if runs else ""))
        if runs:
            print(table([[r["id"], r["started"], r["kind"], r["verdict"], r["station"], _builds(r),
                          ", ".join(dict.fromkeys(d["identity_key"] for d in r["duts"])) or r["dut_specs"],
                          r["seed"], r["uuid"][:8]] for r in runs],
                        ["run", "started (UTC)", "kind", "verdict", "station", "build", "controller", "seed", "uuid"]))
    _emit_json(args.json, runs)
    return 0


def cmd_show(args) -> int:
    store = _open(args)
    try:
        run = store.find(args.run)
    finally:
        store.close()
    if args.json != "-":
        print(f"run {run['id']} ({run['uuid']}): {run['verdict']}, {run['kind']} at {run['station']}")
        print(f"  started {_cell(run['started'])} UTC, finished {_cell(run['finished'])} UTC, seed {run['seed']}, "
              f"exit status {run['exit_status']}")
        print(f"  bldc-hil {run['framework_version'] or '-'} at {run['framework_commit'] or '-'}")
        print(f"  command: {run['command']}")
        print(f"  plant {run['plant']} ({(run['plant_sha256'] or '-')[:16]}), budgets {run['budgets']} "
              f"({(run['budgets_sha256'] or '-')[:16]})")
        if run["report_path"]:
            print(f"  report: {run['report_path']}")
        for reason in run["verdict_reasons"] or []:
            print(f"  why: {reason}")
        if run["duts"]:
            print(table([[d["dut"], d["identity_key"], d["build"], d["firmware_sha256"] and d["firmware_sha256"][:16],
                          d["profile"] and Path(d["profile"]).name, d["profile_sha256"] and d["profile_sha256"][:12]]
                         for d in run["duts"]],
                        ["DUT", "identity", "build", "firmware sha256", "profile", "profile sha256"]))
        print(table([[r["requirement"], r["verdict"]] for r in run["requirements"]], ["requirement", "verdict"]))
        if run["measurements"]:
            print(table([[m["requirement"], m["budget"], m["measured"], m["limit_value"], m["margin"], m["unit"],
                          m["verdict"], m["test"].rpartition("::")[2]] for m in run["measurements"]],
                        ["requirement", "budget", "measured", "limit", "margin", "unit", "verdict", "test"]))
        for r in run["replays"]:
            print(f"  replay of {r['test'] or '?'}: {r['path']} ({r['sha256'][:12]})")
    run["replays"] = [{k: v for k, v in r.items() if k != "content"} | {"has_content": r.get("content") is not None}
                      for r in run["replays"]]
    _emit_json(args.json, run)
    return 0


def cmd_diff(args) -> int:
    from .compare import comparable_test, diff

    store = _open(args)
    try:
        a, b = store.find(args.run_a), store.find(args.run_b)
        # each figure's spread over the last 20 runs of run A's controller before run B
        earlier = store.history_of(sorted({m["identity_key"] for m in a["measurements"]}),
                                   sorted({m["budget"] for m in a["measurements"]}), before=b["started"], last=20)
        spreads: dict[tuple, list] = {}
        for x in earlier:
            spreads.setdefault((x["budget"], comparable_test(x["test"], x.get("dut"))), []).append(x["measured"])
    finally:
        store.close()
    d = diff(a, b, spreads)
    if args.json != "-":
        print(f"run {a['id']} ({_builds(a)}, {a['verdict']}) -> run {b['id']} ({_builds(b)}, {b['verdict']})")
        changed = d["verdicts_changed"]
        print(f"requirements: {len(changed)} verdict(s) changed of {len(d['requirements'])}")
        if changed:
            print(table([[r["requirement"], r["a"], r["b"]] for r in changed],
                        ["requirement", f"run {a['id']}", f"run {b['id']}"]))
        rows = d["figures"] if args.all else [f for f in d["figures"] if f["moved"] or f["a"] is None
                                               or f["b"] is None or f["verdict_a"] != f["verdict_b"]]
        print(f"budgets: {len(d['moved'])} figure(s) moved beyond their spread of {len(d['figures'])}"
              + ("" if args.all else " (--all lists every figure)"))
        if rows:
            print(table([[f["requirement"], f["budget"], f["a"], f["b"], f["worse_by"], f["spread"], _moved(f),
                          f["verdict_a"], f["verdict_b"], f["test"].rpartition("::")[2]] for f in rows],
                        ["requirement", "budget", f"run {a['id']}", f"run {b['id']}", "worse by", "spread", "moved",
                         "verdict A", "verdict B", "test"]))
    _emit_json(args.json, d)
    return 0


def _moved(f: dict) -> str:
    if f["moved"] is None:
        return "spread unknown" if f["a"] is not None and f["b"] is not None else "only in one"
    if not f["moved"]:
        return "within spread"
    return "WORSE" if f["worse_by"] > 0 else "better"


def cmd_trend(args) -> int:
    store = _open(args)
    try:
        ident = args.dut
        if not ident or not store.series(ident, args.budget, last=1):
            matches = [k for k in store.identities(args.budget) if not ident or ident in k]
            if len(matches) != 1:
                raise ValueError(f"{len(matches)} controllers measured {args.budget}"
                                 + (f": give --dut one of {', '.join(matches)}" if matches else f" in {store.shown}"))
            ident = matches[0]
        rows = store.series(ident, args.budget, last=args.last * 20)
    finally:
        store.close()
    if args.test:
        rows = [r for r in rows if args.test in (r["test"] or "")]
    runs = sorted({r["run"] for r in rows}, key=lambda i: [r["started"] for r in rows if r["run"] == i][0])
    keep = set(runs[-args.last:])
    rows = [r for r in rows if r["run"] in keep]
    if not rows:
        raise ValueError(f"no figure of {args.budget} for {ident}")
    result = {"identity": ident, "budget": args.budget, "unit": rows[-1]["unit"], "points": rows}
    if args.json != "-":
        print(f"{args.budget} of {ident}: {len(keep)} run(s)")
        print(table([[r["run"], r["started"], r["build"], r["station"], r["measured"], r["limit_value"], r["verdict"],
                      r["run_verdict"], r["test"].rpartition("::")[2]] for r in rows],
                    ["run", "started (UTC)", "build", "station", "measured", "limit", "verdict", "run", "test"]))
    if args.plot or args.html:
        from .plots import trend_figure, trend_page

        png = trend_figure(result, args.plot or str(Path(args.html).with_suffix(".png")))
        print(f"written: {png}")
        if args.html:
            print(f"written: {trend_page(result, png, args.html)}")
    _emit_json(args.json, result)
    return 0


def cmd_import(args) -> int:
    from .record import from_report

    store = _open(args)
    done = []
    try:
        for given in args.reports:
            path = Path(given)
            if path.is_dir():
                path = path / "hil-report.json"
            try:
                content = json.loads(path.read_text())
            except (OSError, ValueError) as exc:
                raise ValueError(f"{path}: not a readable hil-report.json ({exc})") from None
            if not isinstance(content, dict) or content.get("format") != "hil-report/1":
                raise ValueError(f"{path}: not a hil-report/1 file (format {content.get('format')!r})"
                                 if isinstance(content, dict) else f"{path}: not a hil-report/1 file")
            rec = from_report(content, report_dir=path.parent, station=args.station)
            run_id, new = store.write(rec)
            done.append({"report": str(path), "run": run_id, "uuid": rec.uuid, "new": new})
            if args.json != "-":
                print(f"{path}: {'recorded as' if new else 'recorded already:'} run {run_id} ({rec.verdict}, "
                      f"{rec.started and rec.started.isoformat(sep=' ')} UTC)")
    finally:
        store.close()
    _emit_json(args.json, done)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit("use: hil history ACTION")
