"""Report figures show what they judge: the judged window on its own scale, the budget as lines,
and file names that read from the front."""

import numpy as np

from hil.verdicts.plots import commutation_error_figure, pyplot
from hil.pytest_plugin import figure_file_name


def test_commutation_figure_keeps_the_start_up_transient_out_of_the_judged_scale():
    t = np.linspace(0.0, 0.35, 3500)
    rng = np.random.default_rng(0)
    raw = 3.5 + 0.1 * rng.standard_normal(t.size)
    corrected = 0.05 * rng.standard_normal(t.size)
    raw[t < 0.02] = corrected[t < 0.02] = -60.0  # the start-up transient
    fig = commutation_error_figure(
        {"raw": (t, raw), "corrected": (t, corrected)}, "x", judged_from_s=0.15, budget_deg_e=0.5
    )
    start_up, judged = fig.axes
    lo, hi = judged.get_ylim()
    # raw (3.5) and corrected (0) sit more than half the judged axis apart; the transient is only in its own panel
    assert -1.5 < lo < -0.5 and 3.6 < hi < 6.0 and (3.5 - 0.0) / (hi - lo) > 0.5, (lo, hi)
    assert start_up.get_ylim()[0] < -55.0
    levels = {round(line.get_ydata()[0], 3) for line in judged.get_lines() if len(set(line.get_ydata())) == 1}
    assert {0.5, -0.5} <= levels, levels  # the budget, drawn
    pyplot().close(fig)


def test_figure_file_names_read_from_the_front_and_stay_unique():
    nodeid = ("test_cases/test_calibration_recovery.py::"
              "test_calibration_removes_the_deviation[virtual-modbus-conditioning_delay]")
    name = figure_file_name(nodeid, "conditioning_delay: raw and corrected commutation error")
    assert name.startswith(
        "calibration_removes_the_deviation_virtual-modbus-conditioning_delay_-conditioning_delay_raw_and_corrected"
    )
    assert name != figure_file_name(
        nodeid.replace("modbus", "canopen"), "conditioning_delay: raw and corrected commutation error"
    )
