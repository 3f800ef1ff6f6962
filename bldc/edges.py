"""Captured Hall edges read as steps of the rotor: the one decoder, and speed from edges.

Every reader of captured edges (the controller's sector logic aside, which sees one edge at a
time and takes its code from ``bldc.hall.sector_of_levels``) goes through ``decode_edges``: both
calibration routes, the gap diagnosis, the predictor comparison on a recording and the bench
signal tools. One bit order (``bldc.hall.hall_code``, A = bit 2), one rule for each kind of edge
that is not a rotor step, and counts of what was removed:

* **invalid states**: an edge that leaves the illegal code 000 or 111, that finds its line
  already at the level it switches to, or that moves the sector by two or three (a lost edge);
* **glitches**: a single step against the direction of rotation, undone at once, with one of its
  two intervals below ``GLITCH_FRACTION`` of the local sector time (a line bouncing, not a rotor
  that rocked back); both edges of the pair are dropped;
* **reversals**: the direction changes and stays changed: the run is split there;
* **stalls**: a sector ``STALL_FACTOR`` times longer than both neighbours (the rotor stopped and
  restarted): the run is split there;
* runs shorter than ``min_run_edges`` are dropped (counted as short runs).

Speed from edges (``electrical_speed_hz``) is the number of 60 deg e sectors in a window of
edges over the time they took, within a run; the window is centred or causal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .hall import SECTOR_OF_CODE, SENSORS

#: a one-edge excursion of the direction whose shorter interval is below this fraction of the
#: neighbouring sector times is a glitch (a line bouncing), not a rotor that rocked back
GLITCH_FRACTION = 0.1
#: a sector this many times longer than both neighbours is a stall: the trajectory is split there
STALL_FACTOR = 4.0
#: runs shorter than this (edges) are dropped by default: four electrical cycles
MIN_RUN_EDGES = 24
#: the Hall line's bit in ``bldc.hall.hall_code`` (A = bit 2, B = bit 1, C = bit 0)
LINE_BIT = np.array([4, 2, 1], dtype=np.int64)
#: sensor at boundary 60 m deg e, by m mod 3 (A at 0/180, C at 60/240, B at 120/300) ...
SENSOR_OF_BOUNDARY = np.array([0, 2, 1])
#: ... and that sensor's position in units of 60 deg e (A 0, B 120, C 240)
SENSOR_POSITION_60 = np.array([0, 4, 2])


class HallEdgeError(ValueError):
    """The edges cannot be read as rotor steps; the message says why."""


@dataclass
class HallSteps:
    """The captured edges read as steps of the Hall state (one entry per captured edge)."""

    t_s: np.ndarray
    sensor: np.ndarray
    rising: np.ndarray
    direction: np.ndarray  #: +1 forward (A, B, C), -1 reverse, 0 dropped
    boundary: np.ndarray  #: unwrapped boundary index m: the edge is at 60 m deg e (ideal)
    run: np.ndarray  #: run of constant direction and no stall; -1 dropped
    glitches: int = 0  #: glitch pairs removed (two edges each)
    invalid_states: int = 0  #: edges dropped as invalid (illegal code, inconsistent level, lost edge)
    stalls: int = 0  #: runs split at a stall
    reversals: int = 0  #: runs split at a reversal
    short_runs_dropped: int = 0  #: runs shorter than the minimum, dropped

    @property
    def label(self) -> np.ndarray:
        """Which of the six boundaries of an electrical turn each edge is (0 .. 5)."""
        return np.mod(self.boundary, 6)

    def used(self) -> np.ndarray:
        return self.run >= 0

    def counts(self) -> dict[str, int]:
        """What the decoding removed, by kind."""
        return {
            "glitches_removed": self.glitches,
            "invalid_states_dropped": self.invalid_states,
            "stalls_split": self.stalls,
            "reversals": self.reversals,
            "short_runs_dropped": self.short_runs_dropped,
        }


def initial_levels(sensor: np.ndarray, rising: np.ndarray) -> np.ndarray:
    """The level of each Hall line (A, B, C) before the first edge: the opposite of its first edge's polarity."""
    levels = np.zeros(3, dtype=np.int64)
    for x in range(3):
        idx = np.nonzero(sensor == x)[0]
        if idx.size == 0:
            raise HallEdgeError(f"no edge of sensor {SENSORS[x]}: three Hall lines are needed")
        levels[x] = 0 if rising[idx[0]] else 1
    return levels


def codes_after_edges(sensor: np.ndarray, rising: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Hall code (``bldc.hall.hall_code`` order) after each edge, starting from line
    ``levels``, and whether each edge found its line at the opposite level (a rise must find it low)."""
    sensor, rising = np.asarray(sensor, np.int64), np.asarray(rising, bool)
    code = int(np.dot(np.asarray(levels, np.int64), LINE_BIT))
    codes = np.empty(sensor.size, dtype=np.int64)
    consistent = np.ones(sensor.size, dtype=bool)
    bits = LINE_BIT[sensor]
    for k in range(sensor.size):  # a plain loop: some 0.1 s per million edges is not worth vectorising
        bit = int(bits[k])
        consistent[k] = bool(code & bit) != bool(rising[k])
        code = code | bit if rising[k] else code & ~bit
        codes[k] = code
    return codes, consistent


def decode_edges(
    t_s: np.ndarray,
    sensor: np.ndarray,
    rising: np.ndarray,
    *,
    min_run_edges: int = MIN_RUN_EDGES,
    glitch_fraction: float = GLITCH_FRACTION,
    stall_factor: float = STALL_FACTOR,
) -> HallSteps:
    """Direction, boundary and run of every edge; glitches, invalid states and stalls removed
    (the module's docstring states the rules)."""
    t_s, sensor, rising = np.asarray(t_s, float), np.asarray(sensor, np.int64), np.asarray(rising, bool)
    n = t_s.size
    if n < min_run_edges:
        raise HallEdgeError(f"only {n} edges: at least {min_run_edges} are needed")
    levels = initial_levels(sensor, rising)
    codes, consistent = codes_after_edges(sensor, rising, levels)
    sector = SECTOR_OF_CODE[codes]
    prev = np.concatenate([[SECTOR_OF_CODE[int(np.dot(levels, LINE_BIT))]], sector[:-1]])
    step = np.mod(sector - prev, 6)
    ok = consistent & (sector >= 0) & (prev >= 0)
    direction = np.where(ok & (step == 1), 1, np.where(ok & (step == 5), -1, 0))
    invalid = int(np.sum(direction == 0))
    glitches = _drop_glitches(t_s, direction, glitch_fraction)
    boundary = _unwrapped_boundary(direction, sector, int(prev[0]))
    run, stalls, reversals, short = _runs(t_s, direction, boundary, stall_factor, min_run_edges)
    return HallSteps(t_s, sensor, rising, direction, boundary, run, glitches, invalid, stalls, reversals, short)


def _drop_glitches(t_s: np.ndarray, direction: np.ndarray, fraction: float) -> int:
    """Zero the direction of glitch pairs in place (a single edge against the direction, undone
    at once, one interval short against the local sector time); their count."""
    dt = np.diff(t_s, prepend=t_s[0])
    glitches = 0
    d = direction
    candidates = np.nonzero((d[1:-1] != 0) & (d[1:-1] == -d[:-2]) & (d[2:] == d[:-2]))[0] + 1
    for k in candidates:
        if d[k] == 0 or d[k - 1] == 0:
            continue  # already part of a pair dropped just before
        local = np.median(dt[max(1, k - 6) : k + 7])
        before, after = dt[k], dt[k + 1]
        if min(before, after) < fraction * local:
            pair = (k - 1, k) if before < after else (k, k + 1)
            d[list(pair)] = 0
            glitches += 1
    return glitches


def _unwrapped_boundary(direction: np.ndarray, sector: np.ndarray, start_sector: int) -> np.ndarray:
    """The unwrapped boundary index of each edge: a forward step enters sector u + 1 across
    boundary u + 1; a reverse step leaves sector u across boundary u; dropped edges move the count
    as their states say."""
    n = direction.size
    boundary = np.zeros(n, dtype=np.int64)
    u = start_sector if start_sector >= 0 else 0
    for k in range(n):
        if direction[k] > 0:
            u += 1
            boundary[k] = u
        elif direction[k] < 0:
            boundary[k] = u
            u -= 1
        elif sector[k] >= 0:
            d = int(np.mod(sector[k] - np.mod(u, 6), 6))
            u += {0: 0, 1: 1, 5: -1}.get(d, 0)
    return boundary


def _runs(
    t_s: np.ndarray, direction: np.ndarray, boundary: np.ndarray, stall_factor: float, min_run_edges: int
) -> tuple[np.ndarray, int, int, int]:
    """Runs of constant direction with no stall and no dropped edge inside; the run of each edge
    (-1 dropped), and the stalls, reversals and short runs counted."""
    run = np.full(t_s.size, -1, dtype=np.int64)
    kept = np.nonzero(direction != 0)[0]
    if not kept.size:
        return run, 0, 0, 0
    gap = np.diff(t_s[kept])
    new = np.zeros(kept.size, dtype=bool)
    new[0] = True
    rev = direction[kept][1:] != direction[kept][:-1]
    new[1:] |= rev
    reversals = int(rev.sum())
    # consecutive kept edges must be neighbours (a dropped edge between breaks the run)
    new[1:] |= np.abs(np.diff(boundary[kept])) != 1
    stalls = 0
    if gap.size > 2:
        left = np.concatenate([[np.inf], gap[:-1]])
        right = np.concatenate([gap[1:], [np.inf]])
        stall = (gap > stall_factor * left) & (gap > stall_factor * right)
        stall |= (gap > stall_factor * np.minimum(left, right)) & ~np.isfinite(np.maximum(left, right))
        stalls = int(np.sum(stall & ~rev))
        new[1:] |= stall
    rid = np.cumsum(new) - 1
    sizes = np.bincount(rid)
    keep_run = sizes[rid] >= min_run_edges
    short = int(np.sum(sizes < min_run_edges))
    remap = np.full(sizes.size, -1)
    good = np.nonzero(sizes >= min_run_edges)[0]
    remap[good] = np.arange(good.size)
    run[kept[keep_run]] = remap[rid[keep_run]]
    return run, stalls, reversals, short


def pole_of_boundary(boundary: np.ndarray, pole_pairs: int) -> np.ndarray:
    """The magnet pole boundary (0 .. 2p-1) that boundary 60 m deg e is: the sensor there sits at
    60 s, the boundaries of the magnet pass it every 180 deg e."""
    m = np.asarray(boundary)
    return np.mod((m - SENSOR_POSITION_60[np.mod(m, 3)]) // 3, 2 * pole_pairs)


def longest_run(steps: HallSteps) -> np.ndarray:
    """Indices of the edges of the longest run (empty when no run is kept)."""
    if not steps.used().any():
        return np.zeros(0, dtype=np.int64)
    sizes = np.bincount(steps.run[steps.run >= 0])
    return np.nonzero(steps.run == int(np.argmax(sizes)))[0]


# --- speed from edges ------------------------------------------------------------------------------


def electrical_speed_hz(
    t_s: np.ndarray, *, window_sectors: int = 2, causal: bool = False, run: np.ndarray | None = None
) -> np.ndarray:
    """Electrical speed (Hz) at each edge: the sectors (60 deg e each) of a window of edges over
    the time they took. Centred: edges k - w/2 .. k + w/2, clipped at a run's ends (w = 2 is
    ``1 / (6 np.gradient(t))``); causal: edges k - w .. k, clipped at the run's start. Edges of
    consecutive runs never share a window; edges with ``run`` < 0 get nan. Units: Hz electrical
    (times 360 for deg e/s, times 2 pi for rad/s)."""
    t_s = np.asarray(t_s, float)
    out = np.full(t_s.size, np.nan)
    if window_sectors < 1 or (not causal and window_sectors % 2):
        raise ValueError(f"window_sectors {window_sectors}: a positive count, even when centred")
    if run is None:
        groups = [np.arange(t_s.size)]
    else:
        run = np.asarray(run)
        groups = [np.nonzero(run == r)[0] for r in np.unique(run[run >= 0])]
    for idx in groups:
        n = idx.size
        if n < 2:
            continue
        k = np.arange(n)
        if causal:
            lo, hi = np.maximum(k - window_sectors, 0), k
            lo[0], hi[0] = 0, 1  # the first edge: the sector after it
        else:
            half = window_sectors // 2
            lo, hi = np.maximum(k - half, 0), np.minimum(k + half, n - 1)
        t = t_s[idx]
        out[idx] = (hi - lo) / (6.0 * np.maximum(t[hi] - t[lo], 1e-12))
    return out
