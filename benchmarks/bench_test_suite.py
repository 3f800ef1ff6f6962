"""README's test command (``python -m pytest -q``) on a fresh clone, wall and CPU time, against the base revision.

``python benchmarks/bench_test_suite.py`` (goal: <= 10 min on 2 cores with the install; 24-32 min at
2234cd1). Each revision is cloned afresh (``git clone``, so nothing of this checkout's caches or
reports is used) and run with this interpreter; the install is not part of this figure (``pip
install -e .`` into a fresh venv took 44 s at 2234cd1).
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

from _against_base import PYTHON, ROOT, arguments, timed, line

if __name__ == "__main__":
    args = arguments(__doc__).parse_args()
    results = {}
    for name, rev in [("this checkout", "HEAD")] + ([] if args.no_base else [(args.base, args.base)]):
        clone = Path(tempfile.mkdtemp(prefix="bench-suite-")) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        subprocess.run(["git", "-C", str(clone), "checkout", "-q", rev], check=True)
        results[name] = r = timed([PYTHON, "-m", "pytest", "-q"], clone)
        print(line(f"README's test command ({name})", r), flush=True)
        print("   " + (r["stdout"].strip().splitlines() or ["(no output)"])[-1])
    if len(results) == 2:
        head, base = results.values()
        print(f"README's test command: {head['wall_s'] / base['wall_s']:.2f} x the wall time, "
              f"{head['cpu_s'] / base['cpu_s']:.2f} x the CPU time of {args.base}")
