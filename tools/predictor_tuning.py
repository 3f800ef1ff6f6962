"""Tune every commutation predictor (sector hold, moving average, PLL, KF, Sage-Husa, VB-AKF) on
the training pumps and write their settings, with provenance, to hil/predictors/peer_settings.py
(docs/sage-husa.md, "Peers").

    python tools/predictor_tuning.py [--train-seeds S ...] [--out PATH]

Run once; ``hil predictors compare`` only evaluates those settings, on pumps no tuning saw.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.experiments.peers import tuning_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(tuning_main())
