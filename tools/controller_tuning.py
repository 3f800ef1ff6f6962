"""Tune the virtual controller's Sage-Husa and Kalman filter alike on its own closed loop, then
judge both through the controller on held-out seeds (REQ-PRED-002; docs/sage-husa.md).

    python tools/controller_tuning.py [--train-seeds S ...] [--seeds S ...] [--hold S] [--json OUT]

Records the paper scenario through the in-process controller for the training seeds (default
1 2 12 13), tunes both filters on the replays with the ``tuned`` protocol's search, rounds the
results to two significant digits, and runs the controller with its present defaults and with
the tuned settings on the evaluation seeds (default 0 3-11). Prints what was searched, the
settings found and one table per settings pair (100 columns at most).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.experiments.controller_tuning import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
