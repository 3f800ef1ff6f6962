"""``hil qualify`` (the control run and one run per seeded defect), wall and CPU time, against the base revision.

``python benchmarks/bench_qualify.py`` (goal: <= 300 s on 2 cores; 484 s at 2234cd1 on a quiet machine).
"""

from __future__ import annotations

import tempfile

from _against_base import PYTHON, arguments, compare

if __name__ == "__main__":
    args = arguments(__doc__).parse_args()
    out = tempfile.mkdtemp(prefix="bench-qualify-")
    compare("hil qualify", [PYTHON, "-m", "hil", "qualify", "--report-dir", out, "--json", f"{out}/q.json"], args)
