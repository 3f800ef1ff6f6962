"""The Hall-edge core (``bldc.edges``): decoded steps against a generated ground truth (the true
boundary each edge crosses, in which direction), counts of what was removed (glitch pairs,
spikes through an illegal code, stalls, reversals), and speed from edges.

Hypothesis runs derandomized (seed fixed by the example database being off and
``derandomize=True``), so a failure reproduces."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bldc import edges
from bldc.hall import SECTOR_OF_CODE, hall_code, hall_state, sector_of_levels

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])


def truth_edges(start_sector: int, legs: list[int], sector_s: list[float]):
    """Edges of a rotor that starts in ``start_sector`` and moves ``legs[i]`` sectors (sign =
    direction) in turn; leg i's sectors each take ``sector_s[i]``. Returns t, sensor, rising and
    the true direction and boundary of every edge."""
    t, sensor, rising, direction, boundary = [], [], [], [], []
    u, now = start_sector, 0.0
    for leg, dt in zip(legs, sector_s):
        d = 1 if leg > 0 else -1
        for _ in range(abs(leg)):
            now += dt
            m = u + 1 if d > 0 else u  # the boundary crossed
            before, after = hall_state(60.0 * u + 30.0), hall_state(60.0 * (u + d) + 30.0)
            x = int(np.nonzero(before != after)[0][0])
            t.append(now)
            sensor.append(x)
            rising.append(bool(after[x]))
            direction.append(d)
            boundary.append(m)
            u += d
    return (np.array(t), np.array(sensor), np.array(rising), np.array(direction), np.array(boundary))


legs_strategy = st.lists(st.integers(30, 80), min_size=1, max_size=4)


@SETTINGS
@given(start=st.integers(0, 5), legs=legs_strategy, first_reverse=st.booleans(),
       speeds=st.lists(st.floats(1e-4, 1e-2), min_size=4, max_size=4))
def test_decode_recovers_the_true_direction_and_boundary_and_counts_the_reversals(start, legs, first_reverse, speeds):
    signed = [n if (i % 2 == 0) != first_reverse else -n for i, n in enumerate(legs)]
    t, s, r, d, m = truth_edges(start, signed, speeds[: len(legs)])
    steps = edges.decode_edges(t, s, r)
    np.testing.assert_array_equal(steps.direction, d)
    np.testing.assert_array_equal(steps.boundary, m)
    assert steps.reversals == len(legs) - 1
    assert (steps.glitches, steps.invalid_states, steps.stalls, steps.short_runs_dropped) == (0, 0, 0, 0)
    assert steps.run.max() + 1 == len(legs) and steps.used().all()
    # the label is the boundary within an electrical turn; the sensor at it is the one that switched
    np.testing.assert_array_equal(edges.SENSOR_OF_BOUNDARY[np.mod(steps.boundary, 3)], s)


@SETTINGS
@given(n=st.integers(60, 200), where=st.lists(st.floats(0.1, 0.9), min_size=1, max_size=5, unique=True),
       spikes=st.integers(0, 3), reverse=st.booleans())
def test_glitch_pairs_and_illegal_spikes_are_removed_and_counted(n, where, spikes, reverse):
    """A bounce (the line that just switched switches back and again within 1 % of a sector) is
    one glitch pair; a spike on the line whose toggle leaves an illegal code is two invalid edges.
    Every other edge keeps its true direction and boundary."""
    dt = 1e-3
    t, s, r, d, m = truth_edges(2, [-n if reverse else n], [dt])
    extra = []  # (t, sensor, rising, is_true_edge_index or -1)
    ks = sorted({int(w * (n - 10)) + 5 for w in where})
    ks = [k for i, k in enumerate(ks) if i == 0 or k - ks[i - 1] > 4]
    for k in ks:  # bounce on the edge k: back and forth 10 us and 20 us after it
        extra += [(t[k] + 1e-5, s[k], not r[k]), (t[k] + 2e-5, s[k], r[k])]
    spike_at = [k + 2 for k in ks][:spikes] if ks else []
    for k in spike_at:  # in the sector after edge k: toggle the line that leaves an illegal code
        levels = hall_state(60.0 * (2 + (-1 if reverse else 1) * (k + 1)) + 30.0)
        x = next(x for x in range(3) if SECTOR_OF_CODE[hall_code(np.where(np.arange(3) == x, 1 - levels, levels))] < 0)
        extra += [(t[k] + 0.3 * dt, x, not levels[x]), (t[k] + 0.31 * dt, x, bool(levels[x]))]
    all_t = np.concatenate([t, [e[0] for e in extra]])
    order = np.argsort(all_t, kind="stable")
    true_edge = np.concatenate([np.arange(t.size), np.full(len(extra), -1)])[order]
    steps = edges.decode_edges(all_t[order], np.concatenate([s, [e[1] for e in extra]]).astype(int)[order],
                               np.concatenate([r, [e[2] for e in extra]]).astype(bool)[order])
    assert steps.glitches == len(ks)
    assert steps.invalid_states == 2 * len(spike_at)
    kept = steps.direction != 0
    assert kept.sum() == t.size
    # each kept edge is its true edge, or the bounce's last edge standing in for it (the pair
    # with the shorter interval is dropped: the same line and polarity, 20 us later), with the
    # direction and boundary the truth says
    assert np.all(np.abs(all_t[order][kept] - t) <= 2.0001e-5)
    assert np.sum(true_edge[kept] < 0) <= len(ks)
    np.testing.assert_array_equal(steps.direction[kept], d)
    np.testing.assert_array_equal(steps.boundary[kept], m)


def test_a_stall_splits_the_run_and_short_runs_are_dropped():
    t, s, r, _, _ = truth_edges(0, [40, 40, 10], [1e-3, 1e-3, 1e-3])
    t = t + np.where(np.arange(t.size) >= 40, 0.02, 0.0)  # the rotor stops 20 sectors' time, then goes on
    t = t + np.where(np.arange(t.size) >= 80, 0.05, 0.0)  # ... and again before its last 10 sectors
    steps = edges.decode_edges(t, s, r)
    assert steps.stalls == 2 and steps.reversals == 0
    assert steps.short_runs_dropped == 1 and steps.run.max() == 1
    assert np.sum(steps.used()) == 80
    np.testing.assert_array_equal(edges.longest_run(steps), np.arange(40))


def test_too_few_edges_and_a_missing_line_are_refused_with_the_reason():
    t, s, r, _, _ = truth_edges(0, [30], [1e-3])
    with pytest.raises(edges.HallEdgeError, match="only 10 edges"):
        edges.decode_edges(t[:10], s[:10], r[:10])
    with pytest.raises(edges.HallEdgeError, match="no edge of sensor B"):
        edges.decode_edges(t, np.where(s == 1, 0, s), r)


def test_speed_from_edges_centred_and_causal():
    """On a rotor whose sector time grows linearly, the centred two-sector speed is
    1 / (6 np.gradient(t)) and the causal window the sectors before the edge over their time."""
    sector = 1e-3 * (1.0 + 0.01 * np.arange(100))
    t = np.cumsum(sector)
    np.testing.assert_allclose(edges.electrical_speed_hz(t), 1.0 / (6.0 * np.gradient(t)), rtol=1e-12)
    causal = edges.electrical_speed_hz(t, window_sectors=6, causal=True)
    np.testing.assert_allclose(causal[10], 6.0 / (6.0 * (t[10] - t[4])), rtol=1e-12)
    run = np.where(np.arange(100) < 50, 0, 1)
    split = edges.electrical_speed_hz(t, window_sectors=4, run=run)
    np.testing.assert_allclose(split[49], 2.0 / (6.0 * (t[49] - t[47])), rtol=1e-12)  # never across runs
    np.testing.assert_allclose(split[50], 2.0 / (6.0 * (t[52] - t[50])), rtol=1e-12)
    with pytest.raises(ValueError, match="even"):
        edges.electrical_speed_hz(t, window_sectors=3)


def test_one_bit_order_everywhere_and_the_kernel_inline_form_agrees():
    """``sector_of_levels`` and the plant kernel's inline code (numba keeps it inline) give
    ``SECTOR_OF_CODE[hall_code(levels)]`` for all eight level sets."""
    forms = []
    for path in (ROOT / "plant_models" / "_kernel.py", ROOT / "plant_models" / "simulation.py"):
        m = re.search(r"code = (.*\* 4 \+ .*\* 2 \+ .*)\n", path.read_text())
        assert m, f"{path}: the inline Hall code moved; update this test"
        forms.append(re.sub(r"(self\.)?ist\[(L\.)?I_SEEN( \+ (\d))?\]", lambda g: f"levels[{g.group(4) or 0}]",
                            m.group(1)))
    for code in range(8):
        levels = [(code >> 2) & 1, (code >> 1) & 1, code & 1]
        want = int(SECTOR_OF_CODE[hall_code(np.array(levels))])
        assert sector_of_levels(levels) == want
        for form in forms:
            assert int(SECTOR_OF_CODE[eval(form, {"levels": levels})]) == want  # noqa: S307
