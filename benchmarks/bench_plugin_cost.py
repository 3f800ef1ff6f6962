"""What the installed plugin costs a pytest run that never uses it, run on demand:
``python benchmarks/bench_plugin_cost.py [--runs 7]``.

In an empty temporary directory with one trivial test file, ``python -m pytest -q`` against the
named peer ``python -m pytest -q -p no:hil`` (the same run with the plugin switched off),
alternated run by run so that machine load hits both alike; best of ``--runs`` each, and the
difference (the bound in docs/acceptance.md: at most 0.25 s). The child interpreters import this
checkout's code (PYTHONPATH).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    variants = {"plugin installed": [], "-p no:hil (peer)": ["-p", "no:hil"]}
    best = dict.fromkeys(variants, float("inf"))
    with tempfile.TemporaryDirectory() as tmp:
        Path(tmp, "test_trivial.py").write_text("def test_trivial():\n    assert 1 + 1 == 2\n")
        for _ in range(args.runs):
            for name, extra in variants.items():
                t0 = time.perf_counter()
                subprocess.run(
                    [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *extra],
                    cwd=tmp,
                    env=env,
                    check=True,
                    capture_output=True,
                )
                best[name] = min(best[name], time.perf_counter() - t0)
    for name, seconds in best.items():
        print(f"{name:>20}: best of {args.runs} {seconds:.3f} s")
    plugin, peer = best.values()
    print(f"plugin cost: {plugin - peer:+.3f} s ({plugin / peer:.2f}x the peer); bound 0.25 s")


if __name__ == "__main__":
    main()
