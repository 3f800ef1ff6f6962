"""Compare two hil-report.json files field by field, ignoring times, durations, dates, hosts, paths and
xdist workers (tests and requirements matched by nodeid / id, not by the order they finished in).

    python firmware/reference/tools/compare_reports.py A/hil-report.json B/hil-report.json
"""
import json
import re
import sys
IGN = re.compile(r"(duration|time|date|elapsed|started|finished|wall|_s_wall|timestamp|when|host|report_dir|path"
                 r"|html|worker)", re.I)
def keyed(x):
    """a list of tests or requirements (finished in worker order) as a dict by nodeid / id"""
    if isinstance(x, list) and x and all(isinstance(e, dict) for e in x):
        for key in ("nodeid", "id"):
            if all(key in e for e in x) and len({e[key] for e in x}) == len(x):
                return {e[key]: e for e in x}
    return x
def walk(a, b, where, out):
    a, b = keyed(a), keyed(b)
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if IGN.search(str(k)):
                continue
            if k not in a or k not in b:
                out.append(f"{where}.{k}: only in {'first' if k in a else 'second'}")
                continue
            walk(a[k], b[k], f"{where}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: lengths {len(a)} != {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{where}[{i}]", out)
    elif a != b:
        if isinstance(a, str) and isinstance(b, str) and re.sub(r"[\d.]+ ?s\b", "", a) == re.sub(r"[\d.]+ ?s\b", "", b):
            return  # the same text but for a time in seconds
        out.append(f"{where}: {str(a)[:200]!r} != {str(b)[:200]!r}")
a, b = (json.load(open(p)) for p in sys.argv[1:3])
out = []
walk(a, b, "$", out)
print("\n".join(out[:60]))
print(f"{len(out)} differences (times, durations and dates ignored)")
sys.exit(1 if out else 0)
