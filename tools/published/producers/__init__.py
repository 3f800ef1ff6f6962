"""The producers of the published figures: one module per producer, each declaring the groups it
computes (``GROUPS``: name, what, quick and rotation flags, the producer, the inputs) beside its
code. A producer that serves two captures (the calibration, the twin) declares one group per capture.

A new group: a module here with its producer and its ``Group`` (its inputs through
:func:`common.inputs`, which adds the module's own file), and its line in :data:`GROUPS` below.
"""

from __future__ import annotations

from ..model import Group
from . import (
    acceptance,
    capture_halves,
    closed_loop,
    compare_correction,
    demo,
    first_run,
    gap_captures,
    gap_validation,
    qualify,
    real_calibration,
    real_predictors,
    req_pred_002_spread,
    scenario_predictors,
    sil_reference,
    sil_speed,
    suite,
    table5,
    twin,
)

#: every group, in the order ``--check`` and ``--stale`` name them and the CI rotation takes its
#: turns (:func:`published.engine.rotation_group` counts commits along the rotating ones in this order)
GROUPS: list[Group] = [
    *demo.GROUPS,
    *real_calibration.GROUPS,
    *real_predictors.GROUPS,
    *scenario_predictors.GROUPS,
    *capture_halves.GROUPS,
    *gap_captures.GROUPS,
    *gap_validation.GROUPS,
    *compare_correction.GROUPS,
    *closed_loop.GROUPS,
    *table5.GROUPS,
    *req_pred_002_spread.GROUPS,
    *twin.GROUPS,
    *sil_reference.GROUPS,
    *sil_speed.GROUPS,
    *acceptance.GROUPS,
    *suite.GROUPS,
    *first_run.GROUPS,
    *qualify.GROUPS,
]
