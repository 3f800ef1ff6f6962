"""Bus time of one acceptance run on a 1 Mbit/s CAN link (and CAN FD 1/5 Mbit/s), against hil-edge/2.

``python benchmarks/bench_bus.py`` runs the acceptance suite on the virtual CANopen controller and
prints the report's ``traffic`` (goal: <= 600 s at 1 Mbit/s); ``--report hil-report.json`` reads a
report instead. The base figure is computed, not run (2234cd1 counted nothing): the same edges
each carrying hil-edge/2's full message, 3 accumulator frames, 52 conversion frames and the header
(its window always reached 100 us back), with the same reply frames, each 8 bytes, worst-case
stuffing (hil.dut.traffic).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from _against_base import PYTHON, ROOT, line, timed

from hil.dut.traffic import CAN_BIT_RATE, can_fd_message_s, can_fd_frame_s, can_frame_bits

V2_FRAMES_PER_EDGE = 3 + 52 + 1

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--report", help="an acceptance report (hil-report.json) to read instead of running one")
    args = p.parse_args()
    if args.report:
        report = Path(args.report)
    else:
        out = Path(tempfile.mkdtemp(prefix="bench-bus-"))
        r = timed([PYTHON, "-m", "hil", "acceptance", "--dut", "virtual:canopen", "--report-dir", str(out)], ROOT)
        print(line("acceptance on virtual:canopen", r))
        report = out / "hil-report.json"
    content = json.loads(report.read_text())
    t = content["traffic"]["virtual-canopen"]
    print(json.dumps({"virtual-canopen": t}, indent=1))
    edges = t["edges"]
    v2_bits = edges * V2_FRAMES_PER_EDGE * can_frame_bits(8) + t["frames_from_device"] * can_frame_bits(8)
    v2_fd = edges * can_fd_message_s(8 * V2_FRAMES_PER_EDGE) + t["frames_from_device"] * can_fd_frame_s(8)
    now = t["bus_time_s"]
    print(f"bus time at 1 Mbit/s: {now['can_1mbit']:.0f} s ({now['can_1mbit'] / 60:.1f} min; goal <= 600 s), "
          f"hil-edge/2 on the same edges {v2_bits / CAN_BIT_RATE:.0f} s: "
          f"{now['can_1mbit'] / (v2_bits / CAN_BIT_RATE):.2f} x")
    print(f"bus time on CAN FD 1/5 Mbit/s: {now['can_fd_5mbit']:.0f} s, hil-edge/2 {v2_fd:.0f} s: "
          f"{now['can_fd_5mbit'] / v2_fd:.2f} x")
    print(f"frames per edge: {t['frames_per_edge']} (hil-edge/2: {V2_FRAMES_PER_EDGE} + the replies)")
