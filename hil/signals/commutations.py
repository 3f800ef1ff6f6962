"""Commutations from the six gate signals, with PWM never taken for one.

Six-step drive energises a pair of phases: one high (its high-side switch on, possibly chopped
by PWM), one low (its low-side switch on, possibly chopped), the third floating (both of its
switches off). PWM, complementary switching and dead time only ever toggle switches of the
two energised phases. So:

* **evidence**: a switch of the floating phase turns on. That instant is the candidate
  commutation (the earliest moment the gates show the controller left the old pair);
* **hold-off**: over the hold-off window that follows, the switches' on-times decide the new
  pair (the two phases with the longest on-time; the high one is the one whose high side is
  on longer than its low side). If that is a different pair, the commutation is accepted at
  the evidence instant; if it is the old pair, the evidence was a glitch and is rejected.

The window must span at least one PWM period (so a chopped switch shows) and be shorter than
the shortest sector. A commutation that changes only the chopped phase while a free-running
carrier holds the chopped switch off becomes visible when it next turns on; the instant is then
only known to lie in that off-interval and is reported at its midpoint (:func:`_in_off_time`,
docs/signals.md: within half the off-time, unbiased for an instant uniform over the carrier).

For one such commutation the gates of a carrier restarted at commutation on a whole number of
periods are identical, so the carrier mode is decided once for the whole capture
(:func:`carrier_mode`) from the commutations that do tell it (:func:`_classify_carrier`), and the
midpoint is used only when they show a free-running carrier.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from bldc.hall import SECTOR_PHASES

#: default hold-off: two periods of a 20 kHz PWM, a third of a sector at 15,000 rpm (2 pole pairs)
DEFAULT_HOLD_OFF_S = 100e-6

_SECTOR_OF_PAIR = np.full(9, -1, dtype=np.int64)
for _s, (_hi, _lo) in enumerate(SECTOR_PHASES):
    _SECTOR_OF_PAIR[_hi * 3 + _lo] = _s
_HI = SECTOR_PHASES[:, 0].copy()
_LO = SECTOR_PHASES[:, 1].copy()

# carried state (floats, ints)
F_PREV_T, F_T_E, F_ACC = 0, 1, 2          # F_ACC..F_ACC+5: on-time of each switch in the window
F_T_REP = 8                               # the instant reported for the open window
F_CHG_T = 9                               # when the state before the current sample began
F_ON1, F_ON2 = 10, 16                     # last and last-but-one turn-on of each switch
F_TOL = 22                                # carrier-grid tolerance: capture resolution (s)
F_SNAP1, F_SNAP2 = 23, 29                 # F_ON1, F_ON2 as they were when the window opened
F_NEXT = 35                               # first turn-on of each switch after the window opened
F_RUN0, F_RUNN = 41, 47                   # first turn-on of each switch after the window opened, and how many
F_SRUN0, F_SRUNN = 53, 59                 # the same as they were when the window opened
N_F = 65
I_SECTOR, I_PREV_S, I_PENDING, I_GLITCH, I_AMBIG, I_STARTED, I_PP, I_HIDDEN, I_OFF_TIME, I_FREE, I_RESTART = range(11)
N_I = 11

#: the carrier mode is taken as shown when at least this share of the commutations that tell it agree
CARRIER_SHARE = 0.9


@njit(cache=True)
def _floating_on(state, sector):
    x = 3 - _HI[sector] - _LO[sector]
    return (state >> (2 * x)) & 3


@njit(cache=True)
def _decide(fs, ist, hold_s, out_t, out_m, out_s, out_k, n_out):
    """Close the window opened at fs[F_T_E]: the new pair from the switches' on-times."""
    phase_on = np.zeros(3)
    role = np.zeros(3)
    for x in range(3):
        phase_on[x] = fs[F_ACC + 2 * x] + fs[F_ACC + 2 * x + 1]
        role[x] = fs[F_ACC + 2 * x] - fs[F_ACC + 2 * x + 1]
    order = np.argsort(-phase_on)
    a, b, c = order[0], order[1], order[2]
    cur = ist[I_SECTOR]
    new = -1
    if phase_on[c] > 0.25 * hold_s:
        ist[I_AMBIG] += 1
    if phase_on[b] > 0.0:
        hi, lo = (a, b) if role[a] >= role[b] else (b, a)
        new = _SECTOR_OF_PAIR[hi * 3 + lo]
    elif phase_on[a] > 0.0 and cur >= 0:
        # one phase seen (the other's switch chopped to nothing): the neighbouring sector that has it in that role
        for step in (1, 5):
            s = (cur + step) % 6
            if (role[a] > 0 and _HI[s] == a) or (role[a] <= 0 and _LO[s] == a):
                new = s
                break
    ist[I_PENDING] = 0
    if new < 0 or new == cur:
        if cur >= 0:
            ist[I_GLITCH] += 1
        return n_out
    out_t[n_out] = fs[F_T_E]
    out_m[n_out] = fs[F_T_REP] if ist[I_HIDDEN] and cur >= 0 else np.nan
    out_s[n_out] = new
    out_k[n_out] = 1 if cur >= 0 else 0
    if cur >= 0:
        if ist[I_HIDDEN]:
            ist[I_OFF_TIME] += 1
        _classify_carrier(fs, ist, cur, new, hold_s)
    ist[I_SECTOR] = new
    return n_out + 1


@njit(cache=True)
def _grid_tol(fs, period):
    """How far from the next carrier turn-on one may lie and still be it: quantisation of both
    turn-ons and of the period, capped so that a carrier restarted at commutation is rarely taken
    for the grid (a change-list CSV's resolution is only bounded)."""
    return min(2.5 * fs[F_TOL], 0.02 * period) + 1e-6 * period


@njit(cache=True)
def _run_tol(fs, period, k, n):
    # each turn-on within half a sample, the mean period within a sample over its n - 1 periods;
    # 1.5 samples, not 1, leave room for a carrier clock's own jitter
    return 1.5 * fs[F_TOL] * (1.0 + k / (n - 1.0)) + 1e-6 * period * max(1.0, k)


@njit(cache=True)
def _off_grid_s(t, on1, period):
    """Distance of ``t`` from the grid of turn-ons ``on1 + k period``, and ``k``."""
    k = np.round((t - on1) / period)
    return abs(t - on1 - k * period), k


@njit(cache=True)
def _classify_carrier(fs, ist, old, new, hold_s):
    """Count an accepted commutation (from sector ``old`` to ``new``, evidence at fs[F_T_E]) as
    evidence of the carrier mode, where it holds any.

    The chopped role r is the one whose old switch was turning on periodically: at least two
    turn-ons after the previous evidence (one carrier phase in either mode), their mean period
    within the hold-off and equal to the last interval (a regular run), the last within two
    periods of the evidence. If the evidence instant is clearly off that old carrier grid (twice
    the grid tolerance), the first turn-on after it of the new pair's switch in role r tells the
    mode: on the old grid, the carrier ran on across
    the commutation (free-running); off it, its phase was reset there (restarted at commutation).
    Evidence on the grid tells nothing: both modes turn on there. The tolerance is 1.5 capture
    samples for the two turn-ons compared plus the period's share extrapolated over k periods
    (the period is measured over the n - 1 periods of the run, so its quantisation shrinks)."""
    t_c = fs[F_T_E]
    for r in range(2):
        old_ph = _HI[old] if r == 0 else _LO[old]
        new_ph = _HI[new] if r == 0 else _LO[new]
        jo, jn = 2 * old_ph + r, 2 * new_ph + r
        on1, n = fs[F_SNAP1 + jo], fs[F_SRUNN + jo]
        if not n >= 2.0:
            continue
        period = (on1 - fs[F_SRUN0 + jo]) / (n - 1.0)
        if not (0.0 < period <= hold_s and t_c - on1 < 2.0 * period):
            continue
        if abs(on1 - fs[F_SNAP2 + jo] - period) > _run_tol(fs, period, 1.0, n):
            return  # an irregular run (the carrier's period or phase changed inside it) tells nothing
        t_next = fs[F_NEXT + jn]
        if np.isnan(t_next):
            return
        d_c, k_c = _off_grid_s(t_c, on1, period)
        if d_c <= 2.0 * _run_tol(fs, period, k_c, n):
            return
        d_n, k_n = _off_grid_s(t_next, on1, period)
        if d_n <= _run_tol(fs, period, k_n, n):
            ist[I_FREE] += 1
        else:
            ist[I_RESTART] += 1
        return


@njit(cache=True)
def _integrate(fs, state, t_from, t_to, hold_s):
    a = max(t_from, fs[F_T_E])
    b = min(t_to, fs[F_T_E] + hold_s)
    if b > a:
        for j in range(6):
            if (state >> j) & 1:
                fs[F_ACC + j] += b - a


@njit(cache=True)
def _open(fs, ist, t):
    ist[I_PENDING] = 1
    ist[I_HIDDEN] = 0
    fs[F_T_E] = t
    fs[F_T_REP] = t
    for j in range(6):
        fs[F_ACC + j] = 0.0
        fs[F_SNAP1 + j] = fs[F_ON1 + j]
        fs[F_SNAP2 + j] = fs[F_ON2 + j]
        fs[F_NEXT + j] = np.nan
        fs[F_SRUN0 + j] = fs[F_RUN0 + j]
        fs[F_SRUNN + j] = fs[F_RUNN + j]
        fs[F_RUN0 + j] = np.nan
        fs[F_RUNN + j] = 0.0


@njit(cache=True)
def _in_off_time(fs, ist, new_state, prev, t_on, hold_s):
    """The off-interval of the chopped switch that hid a commutation, as its midpoint; NaN if the
    evidence at ``t_on`` is not that pattern.

    Pattern (chopped role r: 0 = high side, 1 = low side): the old pair's chopped switch turned
    off and left only the other (unchopped) switch on at ``t_off``; at ``t_on`` the floating
    phase's switch of the same role turned on, ``t_on`` being the carrier's next turn-on (one
    period, measured between the old switch's last two turn-ons, after its last one). The
    controller then changed the chopped phase somewhere inside ``[t_off, t_on]`` and a
    free-running carrier held it off; without further evidence the midpoint is the estimate
    that is unbiased for an instant uniform in the interval (error within +-half the off-time).
    A turn-on off the carrier grid (carrier restarted at commutation) is the commutation itself;
    one on it is only a candidate, used if the capture shows a free-running carrier."""
    cur = ist[I_SECTOR]
    if cur < 0:
        return np.nan
    hi, lo = _HI[cur], _LO[cur]
    x = 3 - hi - lo
    for r in range(2):
        stay, gone = (lo, hi) if r == 0 else (hi, lo)
        stay_bit = 1 << (2 * stay + 1 - r)
        j = 2 * gone + r
        if prev != stay_bit or ist[I_PP] != (stay_bit | (1 << j)) or new_state != (stay_bit | (1 << (2 * x + r))):
            continue
        on1, on2, t_off = fs[F_ON1 + j], fs[F_ON2 + j], fs[F_CHG_T]
        period = on1 - on2
        if not (0.0 < period <= hold_s and on1 < t_off < t_on):
            continue
        if abs(t_on - (on1 + period)) <= _grid_tol(fs, period):
            return 0.5 * (t_off + t_on)
    return np.nan


@njit(cache=True)
def _run(t, s, fs, ist, hold_s, out_t, out_m, out_s, out_k):
    n_out = 0
    for k in range(t.size):
        tk = t[k]
        prev = ist[I_PREV_S]
        if ist[I_STARTED]:
            if ist[I_PENDING]:
                _integrate(fs, prev, fs[F_PREV_T], tk, hold_s)
                if tk >= fs[F_T_E] + hold_s:
                    t_close = fs[F_T_E] + hold_s
                    n_out = _decide(fs, ist, hold_s, out_t, out_m, out_s, out_k, n_out)
                    # the state that ran past the window may already contradict the new pair
                    if prev != 0 and (ist[I_SECTOR] < 0 or _floating_on(prev, ist[I_SECTOR]) != 0):
                        _open(fs, ist, max(fs[F_PREV_T], t_close))
                        _integrate(fs, prev, fs[F_PREV_T], tk, hold_s)
        ist[I_STARTED] = 1
        sk = s[k]
        if not ist[I_PENDING] and sk != 0:
            if ist[I_SECTOR] < 0 or _floating_on(sk, ist[I_SECTOR]) != 0:
                _open(fs, ist, tk)
                t_hidden = _in_off_time(fs, ist, sk, prev, tk, hold_s)
                if not np.isnan(t_hidden):
                    fs[F_T_REP] = t_hidden
                    ist[I_HIDDEN] = 1
        if sk != prev:
            rising = sk & ~prev
            for j in range(6):
                if (rising >> j) & 1:
                    if ist[I_PENDING] and tk > fs[F_T_E] and np.isnan(fs[F_NEXT + j]):
                        fs[F_NEXT + j] = tk
                    # the run starts after the evidence: a switch turned on at the commutation
                    # itself is off the grid of a free-running carrier
                    if tk > fs[F_T_E]:
                        if np.isnan(fs[F_RUN0 + j]):
                            fs[F_RUN0 + j] = tk
                            fs[F_RUNN + j] = 1.0
                        else:
                            fs[F_RUNN + j] += 1.0
                    fs[F_ON2 + j] = fs[F_ON1 + j]
                    fs[F_ON1 + j] = tk
            ist[I_PP] = prev
            fs[F_CHG_T] = tk
        ist[I_PREV_S] = sk
        fs[F_PREV_T] = tk
    return n_out


@njit(cache=True)
def _finish(end_t, fs, ist, hold_s, out_t, out_m, out_s, out_k):
    if ist[I_PENDING] and ist[I_STARTED]:
        _integrate(fs, ist[I_PREV_S], fs[F_PREV_T], end_t, hold_s)
        if end_t >= fs[F_T_E] + hold_s:
            return _decide(fs, ist, hold_s, out_t, out_m, out_s, out_k, 0)
    return 0


def carrier_mode(free: int, restart: int) -> str:
    """The capture's carrier mode from its commutations that tell it (docs/signals.md): a mode is
    shown when at least :data:`CARRIER_SHARE` of them agree; none, or no such majority, is
    "undetermined"."""
    told = free + restart
    if told and free >= CARRIER_SHARE * told:
        return "free-running"
    if told and restart >= CARRIER_SHARE * told:
        return "restarted"
    return "undetermined"


@dataclass
class Extracted:
    t_s: np.ndarray            #: reported instant of each accepted change of pair
    sector: np.ndarray         #: sector entered (six-step table of bldc.hall)
    initial: np.ndarray        #: True for the first pair (the start, not a commutation)
    glitches: int = 0          #: evidence rejected by the hold-off (the old pair came back)
    ambiguous: int = 0         #: windows where all three phases conducted noticeably
    #: commutations hidden in an off-time of a free-running carrier, located at its midpoint
    located_in_off_time: int = 0
    start_s: float = 0.0
    end_s: float = 0.0
    resolution_s: float | None = None
    #: the capture's carrier: "free-running", "restarted" (at commutation) or "undetermined"
    carrier: str = "undetermined"
    carrier_free_evidence: int = 0      #: commutations whose carrier grid ran on across them
    carrier_restart_evidence: int = 0   #: commutations whose carrier phase was reset at them
    #: commutations whose gates fit a change hidden in a free-running off-time (only located at its
    #: midpoint when the carrier is free-running; else reported at the turn-on)
    off_time_candidates: int = 0

    @property
    def commutations(self) -> tuple[np.ndarray, np.ndarray]:
        keep = ~self.initial
        return self.t_s[keep], self.sector[keep]

    @property
    def established_s(self) -> float:
        """When the first pair was established (NaN if never)."""
        return float(self.t_s[self.initial][0]) if self.initial.any() else float("nan")


@dataclass
class Extractor:
    """Streaming extraction: feed change chunks, then :meth:`finish` with the capture's end."""

    hold_off_s: float = DEFAULT_HOLD_OFF_S
    #: time resolution of the capture (s): the tolerance of the carrier-grid test is 2.5 of it
    resolution_s: float = 0.0
    _fs: np.ndarray = field(default_factory=lambda: np.concatenate([np.zeros(F_ON1), np.full(12, np.nan), np.zeros(1),
                                                                    np.full(N_F - F_SNAP1, np.nan)]))
    _is: np.ndarray = field(default_factory=lambda: np.array([-1] + [0] * (N_I - 1), dtype=np.int64))
    _t: list = field(default_factory=list)
    _m: list = field(default_factory=list)
    _s: list = field(default_factory=list)
    _k: list = field(default_factory=list)

    def __post_init__(self):
        if not self.hold_off_s > 0:
            raise ValueError(f"hold-off must be > 0 s, got {self.hold_off_s!r}")

    @staticmethod
    def _out(n: int):
        return np.empty(n), np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)

    def feed(self, t_s: np.ndarray, state: np.ndarray) -> None:
        self._fs[F_TOL] = self.resolution_s or 0.0
        out = self._out(t_s.size + 1)
        m = _run(np.ascontiguousarray(t_s, dtype=np.float64), np.ascontiguousarray(state, dtype=np.int64),
                 self._fs, self._is, float(self.hold_off_s), *out)
        self._keep(out, m)

    def _keep(self, out, m):
        if m:
            for acc, x in zip((self._t, self._m, self._s, self._k), out):
                acc.append(x[:m].copy())

    def finish(self, end_s: float, start_s: float = 0.0, resolution_s: float | None = None) -> Extracted:
        out = self._out(1)
        m = _finish(float(end_s), self._fs, self._is, float(self.hold_off_s), *out)
        self._keep(out, m)
        cat = (lambda xs, dt: np.concatenate(xs) if xs else np.zeros(0, dtype=dt))  # noqa: E731
        t_on, t_mid = cat(self._t, float), cat(self._m, float)
        free, restart = int(self._is[I_FREE]), int(self._is[I_RESTART])
        mode = carrier_mode(free, restart)
        # the midpoint only where the capture shows a free-running carrier; otherwise the turn-on,
        # which is where a restarted carrier commutates (docs/signals.md)
        located = mode == "free-running"
        t = np.where(np.isnan(t_mid), t_on, t_mid) if located else t_on
        candidates = int(self._is[I_OFF_TIME])
        return Extracted(t, cat(self._s, np.int64), cat(self._k, np.int64) == 0, int(self._is[I_GLITCH]),
                         int(self._is[I_AMBIG]), candidates if located else 0, start_s, float(end_s), resolution_s,
                         mode, free, restart, candidates)


def extract(capture, hold_off_s: float = DEFAULT_HOLD_OFF_S) -> Extracted:
    """Commutations of a :class:`~hil.recording.capture.Capture` (streamed)."""
    ex = Extractor(hold_off_s)
    for t, s in capture.states():
        ex.resolution_s = capture.sample_period_s or 0.0  # known once the reader has started
        ex.feed(t, s)
    end = capture.end_s if capture.end_s is not None else 0.0
    return ex.finish(end, capture.start_s or 0.0, capture.sample_period_s)
