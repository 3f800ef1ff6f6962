"""The controller's current measurement from its own ADC window (edge message version 2).

Firmware samples its phase-current sensors and, at a Hall capture, computes two currents from its
ADC ring: the current at the edge's own instant, one applied conditioning delay of the edge's
polarity before the capture (where the armature field that moved the edge acted: paper Eq. 5),
and the mean |i| over the commutation cycle the edge ends (the current Eq. 8's K_T is defined
for). The built-in controller does both here; a controller that reads its ADC at the capture
interrupt instead is a known firmware defect the acceptance suite must catch (``hil qualify``).
"""

from __future__ import annotations

import numpy as np


def mean_abs_current_a(phase_currents_a: np.ndarray) -> np.ndarray:
    """Mean |i| over the three phases, per sample (rows of three)."""
    return np.abs(phase_currents_a).mean(axis=1)


def current_at_a(t_s: float, adc_t_s: np.ndarray, mean_abs_a: np.ndarray, commutations_s=()) -> float:
    """Mean |i| at ``t_s``: linear between the two samples around it, held at the window's ends.
    Where one of the controller's own commutations (``commutations_s``) falls between those two
    samples the current turns there, so the reading comes from the samples on ``t_s``'s side of
    it: the nearest one, held (a line across the commutation missed by up to 2 deg e of armature
    correction at 1.4 deg e/A)."""
    k = int(np.searchsorted(adc_t_s, t_s))
    if 0 < k < adc_t_s.size:
        lo, hi = adc_t_s[k - 1], adc_t_s[k]
        for c in commutations_s:
            if lo < c <= hi:
                return float(mean_abs_a[k - 1] if t_s < c else mean_abs_a[k])
    return float(np.interp(t_s, adc_t_s, mean_abs_a))


def cycle_mean_current_a(after_s: float | None, adc_t_s: np.ndarray, mean_abs_a: np.ndarray) -> float | None:
    """Mean |i| over the samples after ``after_s`` (the previous edge's capture; None: the whole
    window); None when no sample fell in the cycle."""
    in_cycle = mean_abs_a if after_s is None else mean_abs_a[adc_t_s > after_s]
    return float(in_cycle.mean()) if in_cycle.size else None


def edge_currents(edge: dict, delay_s: float, previous_capture_s: float | None, commutations_s=()) -> dict:
    """``edge`` with ``current_a`` (at the capture minus ``delay_s``) and ``cycle_current_a`` (since
    ``previous_capture_s``) computed from its ADC window; unchanged when it carries none."""
    adc_t = edge.get("adc_t_s")
    if adc_t is None or len(adc_t) == 0:
        return edge
    mean_abs = mean_abs_current_a(edge["adc_phase_currents_a"])
    edge["current_a"] = current_at_a(float(edge["t_capture_s"]) - delay_s, adc_t, mean_abs, commutations_s)
    cycle = cycle_mean_current_a(previous_capture_s, adc_t, mean_abs)
    if cycle is not None:
        edge["cycle_current_a"] = cycle
    return edge
