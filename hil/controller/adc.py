"""The controller's current measurement from its own ADC (edge message version 2).

Firmware converts its phase-current sensors into a DMA ring and accumulates them over each
commutation cycle; at a Hall capture it computes two currents from what its ADC holds: the
current at the edge's own instant, one applied conditioning delay of the edge's polarity before
the capture (where the armature field that moved the edge acted: paper Eq. 5), and the mean |i|
over the commutation cycle the edge ends (the current Eq. 8's K_T is defined for). The built-in
controller does both here; one that reads its ADC at the capture interrupt instead is a known
firmware defect the acceptance suite must catch (``hil qualify``).
"""

from __future__ import annotations

import numpy as np


def current_at_a(t_s: float, adc_t_s: np.ndarray, phase_currents_a: np.ndarray) -> float:
    """Mean |i| over the phases at ``t_s``: each phase linear between the two conversions around
    it, held at the window's ends. ``np.interp``'s arithmetic, to the bit, with one search for the
    three phases (called once per edge: three interp calls and a mean were most of its cost)."""
    last = len(adc_t_s) - 1
    if t_s < adc_t_s[0]:
        a, b, c = phase_currents_a[0].tolist()
    elif t_s >= adc_t_s[last]:
        a, b, c = phase_currents_a[last].tolist()
    else:
        j = int(np.searchsorted(adc_t_s, t_s, side="right")) - 1  # adc_t_s[j] <= t_s < adc_t_s[j + 1]
        t0 = float(adc_t_s[j])
        if t0 == t_s:
            a, b, c = phase_currents_a[j].tolist()
        else:
            dt = float(adc_t_s[j + 1]) - t0
            before, after = phase_currents_a[j].tolist(), phase_currents_a[j + 1].tolist()
            a, b, c = ((i1 - i0) / dt * (t_s - t0) + i0 for i0, i1 in zip(before, after))
    return (abs(a) + abs(b) + abs(c)) / 3.0


def cycle_mean_current_a(sums_a: np.ndarray, conversions: int) -> float | None:
    """Mean |i| over the phases and the cycle from the per-phase accumulators: within one
    commutation cycle no phase current changes sign in six-step drive (a phase goes +, +, 0, -,
    -, 0 over the six sectors), so |sum| / n is the mean |i| of each phase. None when no
    conversion fell in the cycle."""
    return float(np.sum(np.abs(sums_a)) / (3.0 * conversions)) if conversions else None


def edge_currents(edge: dict, delay_s: float) -> dict:
    """``edge`` with ``current_a`` (at the capture minus ``delay_s``) and ``cycle_current_a``
    computed from its ADC; unchanged where it carries none."""
    adc_t = edge.get("adc_t_s")
    if adc_t is not None and len(adc_t):
        edge["current_a"] = current_at_a(float(edge["t_capture_s"]) - delay_s, adc_t, edge["adc_phase_currents_a"])
    cycle = cycle_mean_current_a(edge.get("adc_cycle_sums_a", np.zeros(3)), edge.get("adc_cycle_conversions", 0))
    if cycle is not None:
        edge["cycle_current_a"] = cycle
    return edge
