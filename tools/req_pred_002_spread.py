"""REQ-PRED-002 with the controller's defaults from the training-pump tuning, judged through the
in-process controller over held-out seeds and the operating profiles of
``controller_tuning.PROFILES``; prints each run, the pooled ratio and its leave-one-seed-out range
(docs/sage-husa.md, "Peers").

    python tools/req_pred_002_spread.py [--seed S ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.experiments.controller_tuning import judge_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(judge_main())
