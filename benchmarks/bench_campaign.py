"""Campaign scaling, run on demand: ``python benchmarks/bench_campaign.py [SPEC] [--workers 1 2]``.

The same campaign (default examples/campaign.toml) on a local Dask cluster of 1, then 2 worker
processes, in one run: points per second once the workers are up (cluster start reported
apart), and the ratio against the 1-worker run, the named peer. How many cores the workers
actually got (their CPU seconds per wall second) is printed beside it: on a shared machine
that, not the scheduler, bounds the ratio. The tables must be identical
apart from timings: a scaling figure of a run that changed its results would mean nothing.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from hil.campaign import load_spec, read_table, run_campaign


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "spec", nargs="?", default=str(Path(__file__).resolve().parent.parent / "examples" / "campaign.toml")
    )
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--keep", help="keep the campaign outputs in this directory (default: a temporary one)")
    args = ap.parse_args()
    spec = load_spec(args.spec)
    print(f"{spec.name}: {spec.size} points; {os.cpu_count()} cores; load average before: {os.getloadavg()[0]:.1f}")
    rates, tables = {}, {}
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.keep or scratch
        for n in args.workers:
            c0 = time.process_time()
            r = run_campaign(spec, Path(tmp) / f"w{n}", workers=n, progress=False)
            client_cpu = time.process_time() - c0  # this process: the client, the local scheduler, the table
            s = r.summary()
            rates[n] = s["points_per_s"]
            table = read_table(r.paths["table"])
            tables[n] = table.drop(columns=["duration_s", "cpu_s", "replay"])
            # CPU seconds the workers got per wall second of the run: n on an idle machine
            cores = table["cpu_s"].sum() / (s["elapsed_s"] - s["startup_s"])
            print(
                f"  {n} worker(s): {s['points_done']} points in {s['elapsed_s']:.1f} s (cluster start "
                f"{s['startup_s']:.1f} s), "
                f"{rates[n]:.3f} points/s, {s['workers_used']} worker(s) used; {table['cpu_s'].mean():.3f} CPU s per "
                "point, "
                f"the workers got {cores:.2f} cores, the client and scheduler used {client_cpu:.1f} CPU s; "
                f"load average now {os.getloadavg()[0]:.1f}"
            )
    first = args.workers[0]
    for n in args.workers[1:]:
        diff = tables[n].compare(tables[first]) if tables[n].shape == tables[first].shape else "shapes differ"
        same = isinstance(diff, str) is False and diff.empty
        print(f"  {n} vs {first} worker(s): x{rates[n] / rates[first]:.2f} points/s; tables identical: {same}")
        if not same:
            print(diff)


if __name__ == "__main__":
    main()
