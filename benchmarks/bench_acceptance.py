"""The default ``hil acceptance`` (CANopen and Modbus; PASS), wall and CPU time, against the base revision.

``python benchmarks/bench_acceptance.py`` (goal: <= 90 s on 2 cores; 432 s at 2234cd1 on a quiet
machine); ``--in-process`` for the in-process figure (goal <= 30 s; 79-136 s at 2234cd1). Both
checkouts run the same command from their own directory, one after the other.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from _against_base import PYTHON, arguments, compare

if __name__ == "__main__":
    parser = arguments(__doc__)
    parser.add_argument("--in-process", action="store_true", help="--dut virtual:in-process")
    args = parser.parse_args()
    reports = Path(tempfile.mkdtemp(prefix="bench-acceptance-"))
    cmd = [PYTHON, "-m", "hil", "acceptance", "--report-dir", str(reports)]
    if args.in_process:
        cmd += ["--dut", "virtual:in-process"]
    head, _ = compare("in-process acceptance" if args.in_process else "default acceptance", cmd, args)
    content = json.loads((reports / "hil-report.json").read_text())  # the base run wrote its own over it
    print(f"verdict of the last run: {content['verdict']}")
