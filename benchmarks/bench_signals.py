"""Streaming figures of `hil signals`: export, loopback and scoring of a long run at 1 MHz.

Each phase runs in its own process and reports its wall time and peak resident memory. The
named peer is the same pipeline on a run one tenth as long, in the same invocation: bounded
memory shows as a peak-memory ratio near 1, linear time as a time ratio near 10.

    nice -n 10 python benchmarks/bench_signals.py --minutes 10 --out /tmp/bench-signals
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

CHILD = """
import resource, sys, time
from hil.cli import main
t = time.perf_counter()
rc = main(sys.argv[1:])
print("BENCH", rc, time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
"""


def phase(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True, check=True)
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("BENCH"))
    _, rc, wall, rss = line.split()
    if int(rc) != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{out.stdout}\n{out.stderr}")
    return {"wall_s": float(wall), "peak_rss_mb": int(rss) / 1e6, "stdout": out.stdout}


def pipeline(out: Path, duration_s: float, speed_rpm: float) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    res = {
        "export": phase(
            ["signals", "export", "--out", str(out), "--duration-s", str(duration_s), "--speed-rpm", str(speed_rpm)]
        )
    }
    res["loopback"] = phase(["signals", "loopback", str(out), "--out", str(out / "gates.vcd")])
    res["score"] = phase(["signals", "score", str(out), str(out / "gates.vcd"), "--json", str(out / "score.json")])
    res["files_mb"] = {p.name: round(p.stat().st_size / 1e6, 1) for p in sorted(out.iterdir()) if p.is_file()}
    res["score_json"] = json.loads((out / "score.json").read_text())
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--speed-rpm", type=float, default=6000.0)
    ap.add_argument("--out", default="reports/bench-signals")
    a = ap.parse_args()
    long_s = a.minutes * 60.0
    t0 = time.perf_counter()
    peer = pipeline(Path(a.out) / "peer", long_s / 10.0, a.speed_rpm)
    run = pipeline(Path(a.out) / "long", long_s, a.speed_rpm)
    print(f"1 MHz stimulus, paper-bench+deviations at {a.speed_rpm:g} rpm; peer = the same at {long_s / 10:g} s")
    print(f"{'phase':<9} {'wall (s)':>9} {'peak RSS (MB)':>14} {'wall ratio':>11} {'RSS ratio':>10}")
    for name in ("export", "loopback", "score"):
        r, p = run[name], peer[name]
        print(
            f"{name:<9} {r['wall_s']:>9.1f} {r['peak_rss_mb']:>14.0f} {r['wall_s'] / p['wall_s']:>11.2f} "
            f"{r['peak_rss_mb'] / p['peak_rss_mb']:>10.2f}"
        )
    print(f"files ({long_s:g} s): {run['files_mb']}")
    print(f"export says: {run['export']['stdout'].splitlines()[1:3]}")
    print(f"score: {json.dumps(run['score_json'])}")
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
