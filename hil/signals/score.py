"""``hil signals score``: a gate capture's commutations against the stimulus' ideal instants.

Each commutation the gates show (:mod:`hil.signals.commutations`) is matched to the ideal
commutation of the same sector nearest in time (``truth.csv``). Its time error is the capture
instant minus the ideal instant (+ = late); its **angle error** is that time error times the
true electrical speed at the ideal instant (``speed_rpm`` of the truth row times 6 times the
pole pairs, in deg e per second): the angle the rotor turns between the ideal and the actual
commutation.

A commutation that matches no ideal one, or one already matched, is ``extra``; an ideal
commutation inside the scored span that none matches is ``missed``. The scored span runs from
the first energised pair the gates show (the controller's start, not itself a commutation; an
ideal commutation into that pair up to half a sector later was done early at the start) to
the end of the capture less the hold-off and half a sector (a commutation there could not be
confirmed).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bldc.units import rpm_to_deg_e_per_s

from ..recording.capture import GateMapping
from ..recording.errors import SignalError
from ..recording.formats import open_capture
from .commutations import DEFAULT_HOLD_OFF_S, Extracted, extract


@dataclass
class Truth:
    n: np.ndarray
    t_ideal_s: np.ndarray
    sector: np.ndarray
    speed_rpm: np.ndarray
    pole_pairs: int
    sample_rate_hz: float
    meta: dict

    @property
    def omega_e_deg_s(self) -> np.ndarray:
        return rpm_to_deg_e_per_s(self.speed_rpm, self.pole_pairs)

    @classmethod
    def load(cls, stimulus_dir: str | Path) -> "Truth":
        import pandas as pd

        d = Path(stimulus_dir)
        meta_path, truth_path = d / "meta.json", d / "truth.csv"
        for p in (meta_path, truth_path):
            if not p.is_file():
                raise SignalError(str(p), "missing (give the directory `hil signals export` wrote)")
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as exc:
            raise SignalError(f"{meta_path}, line {exc.lineno}", f"not valid JSON: {exc.msg}") from None
        for key in ("pole_pairs", "sample_rate_hz"):
            if key not in meta:
                raise SignalError(f"{meta_path}: {key}", "missing key")
        try:
            frame = pd.read_csv(truth_path, usecols=["n", "t_ideal_s", "sector", "speed_rpm"])
        except ValueError as exc:
            raise SignalError(str(truth_path), f"not a truth table: {exc}") from None
        a = frame.to_numpy(dtype=float)
        bad = np.nonzero(~np.isfinite(a).all(axis=1))[0]
        if bad.size:
            raise SignalError(f"{truth_path}, line {int(bad[0]) + 2}", "non-numeric value")
        if a.shape[0] > 1 and np.any(np.diff(a[:, 1]) < 0):
            line = int(np.nonzero(np.diff(a[:, 1]) < 0)[0][0]) + 3
            raise SignalError(str(truth_path), f"t_ideal_s goes back at line {line}")
        return cls(a[:, 0].astype(np.int64), a[:, 1], a[:, 2].astype(np.int64), a[:, 3], int(meta["pole_pairs"]),
                   float(meta["sample_rate_hz"]),
                   meta)


@dataclass
class Score:
    commutations: int
    missed: int
    extra: int
    angle_error_deg_e: np.ndarray    #: per matched commutation
    time_error_s: np.ndarray
    t_ideal_s: np.ndarray            #: of each matched commutation
    sector: np.ndarray
    missed_t_s: np.ndarray
    extra_t_s: np.ndarray
    extracted: Extracted
    span_s: tuple[float, float]
    hold_off_s: float
    #: timing bound of the sampled signals: half a stimulus sample plus one capture sample
    sample_bound_s: float
    #: decoded sector -> ideal sector, when the gates do not follow the documented table
    sector_map: np.ndarray | None = None

    def to_json(self) -> dict:
        """The result contract (docs/signals.md): exactly these keys."""
        a, t = self.angle_error_deg_e, self.time_error_s

        def stat(x, f):
            return float(f(x)) if x.size else None

        return {
            "commutations": int(self.commutations),
            "missed": int(self.missed),
            "extra": int(self.extra),
            "angle_error_deg_e": {"mean": stat(a, np.mean), "rms": stat(a, lambda v: np.sqrt(np.mean(v * v))),
                                  "p99": stat(a, lambda v: np.percentile(np.abs(v), 99)),
                                  "max_abs": stat(a, lambda v: np.max(np.abs(v)))},
            "time_error_s": {"mean": stat(t, np.mean), "rms": stat(t, lambda v: np.sqrt(np.mean(v * v)))},
        }

    def per_sector(self) -> list[dict]:
        rows = []
        for s in range(6):
            e = self.angle_error_deg_e[self.sector == s]
            rows.append({"sector": s, "n": int(e.size), "mean": float(np.mean(e)) if e.size else math.nan,
                         "rms": float(np.sqrt(np.mean(e * e))) if e.size else math.nan,
                         "max_abs": float(np.max(np.abs(e))) if e.size else math.nan})
        return rows

    def over_time(self, bins: int = 10) -> list[dict]:
        if not self.t_ideal_s.size:
            return []
        lo, hi = self.span_s
        edges = np.linspace(lo, hi, bins + 1)
        rows = []
        for i in range(bins):
            upper = self.t_ideal_s < edges[i + 1] if i < bins - 1 else self.t_ideal_s <= edges[i + 1]
            m = (self.t_ideal_s >= edges[i]) & upper
            e = self.angle_error_deg_e[m]
            rows.append({"t0_s": float(edges[i]), "t1_s": float(edges[i + 1]), "n": int(e.size),
                         "mean": float(np.mean(e)) if e.size else math.nan,
                         "rms": float(np.sqrt(np.mean(e * e))) if e.size else math.nan,
                         "max_abs": float(np.max(np.abs(e))) if e.size else math.nan,
                         "missed": int(((self.missed_t_s >= edges[i]) & (self.missed_t_s < edges[i + 1])).sum()),
                         "extra": int(((self.extra_t_s >= edges[i]) & (self.extra_t_s < edges[i + 1])).sum())})
        return rows

    def summary(self) -> str:
        j = self.to_json()
        a, t = j["angle_error_deg_e"], j["time_error_s"]
        fmt = (lambda v, f="{:+.4f}": "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f.format(v))  # noqa: E731
        ex = self.extracted
        lines = [
            f"commutations {j['commutations']}, missed {j['missed']}, extra {j['extra']} "
            f"(scored span {self.span_s[0]:.6f}-{self.span_s[1]:.6f} s, "
            f"hold-off {self.hold_off_s * 1e6:g} us; {ex.glitches} glitches rejected, "
            f"{ex.ambiguous} ambiguous windows; "
            f"{ex.located_in_off_time} located in an off-time of a free-running carrier, at its midpoint)",
            _carrier_line(ex),
            f"angle error (deg e, + = late): mean {fmt(a['mean'])}, RMS {fmt(a['rms'], '{:.4f}')}, "
            f"p99 |e| {fmt(a['p99'], '{:.4f}')}, "
            f"max |e| {fmt(a['max_abs'], '{:.4f}')}",
            f"time error: mean {fmt(None if t['mean'] is None else t['mean'] * 1e6, '{:+.3f}')} us, "
            f"RMS {fmt(None if t['rms'] is None else t['rms'] * 1e6, '{:.3f}')} us "
            f"(sampling bound +-{self.sample_bound_s * 1e6:.3f} us)",
            "per sector entered:   sector     n      mean       RMS    max|e|",
        ]
        if self.sector_map is not None:
            pairs = ", ".join(f"{d}->{m}" for d, m in enumerate(self.sector_map.tolist()))
            lines.insert(3, "NOTE: the gates do not follow the documented six-step table (docs/signals.md); "
                            "scored with the pair of sector d read as ideal sector " + pairs)
        for r in self.per_sector():
            lines.append(f"                      {r['sector']:>6} {r['n']:>5} {fmt(r['mean'])} "
                         f"{fmt(r['rms'], '{:9.4f}')} {fmt(r['max_abs'], '{:9.4f}')}")
        lines.append("over time:            from (s)      to (s)      n      mean       RMS    max|e| missed extra")
        for r in self.over_time():
            lines.append(f"                      {r['t0_s']:>8.4f}  {r['t1_s']:>10.4f} {r['n']:>6} {fmt(r['mean'])} "
                         f"{fmt(r['rms'], '{:9.4f}')} "
                         f"{fmt(r['max_abs'], '{:9.4f}')} {r['missed']:>6} {r['extra']:>5}")
        return "\n".join(lines)


def _carrier_line(ex: Extracted) -> str:
    told = (f"{ex.carrier_free_evidence} commutations show the carrier grid running on across them, "
            f"{ex.carrier_restart_evidence} show its phase reset at them")
    if ex.carrier == "free-running":
        return f"carrier: free-running ({told}); {ex.off_time_candidates} off-time commutations located at the midpoint"
    why = told if ex.carrier_free_evidence + ex.carrier_restart_evidence else "no commutation tells the carrier mode"
    return (f"carrier: {ex.carrier} ({why}); {ex.off_time_candidates} commutations that fit an off-time one "
            f"reported at the turn-on" + ("" if ex.carrier == "restarted" or not ex.off_time_candidates else
                              ", each late by at most its off-time if the carrier runs freely"))


def _sector_map(truth: Truth, t_c: np.ndarray, s_c: np.ndarray) -> np.ndarray | None:
    """How the pairs the gates energise map onto the documented six-step table, if they do not
    follow it: each commutation votes for the sector of the ideal commutation nearest in time.
    A controller whose table is rotated (another Hall alignment) or mirrored is then still
    scored against the right instants, and the summary says so. None = the documented table."""
    if t_c.size < 12 or truth.t_ideal_s.size < 2:
        return None
    j = np.clip(np.searchsorted(truth.t_ideal_s, t_c), 1, truth.t_ideal_s.size - 1)
    j = np.where(np.abs(t_c - truth.t_ideal_s[j - 1]) <= np.abs(t_c - truth.t_ideal_s[j]), j - 1, j)
    votes = np.zeros((6, 6), dtype=np.int64)
    np.add.at(votes, (s_c, truth.sector[j]), 1)
    seen = votes.sum(axis=1) > 0
    best = votes.argmax(axis=1)
    clear = votes[np.arange(6), best] >= 0.9 * votes.sum(axis=1)
    if not (seen & clear).sum() == seen.sum() or np.array_equal(best[seen], np.arange(6)[seen]):
        return None
    if np.unique(best[seen]).size != seen.sum():
        return None  # not a one-to-one relabelling: score against the documented table
    mapping = np.arange(6)
    mapping[seen] = best[seen]
    return mapping


def score_extracted(truth: Truth, ex: Extracted, hold_off_s: float = DEFAULT_HOLD_OFF_S) -> Score:
    t_c, s_c = ex.commutations
    sector_map = _sector_map(truth, t_c, s_c)
    if sector_map is not None:
        s_c = sector_map[s_c]
    start = ex.established_s if math.isfinite(ex.established_s) else ex.end_s
    end = ex.end_s - hold_off_s
    # nearest ideal commutation of the same sector
    match = np.full(t_c.size, -1, dtype=np.int64)
    for s in range(6):
        rows = np.nonzero(truth.sector == s)[0]
        mine = np.nonzero(s_c == s)[0]
        if not rows.size or not mine.size:
            continue
        tr = truth.t_ideal_s[rows]
        j = np.searchsorted(tr, t_c[mine])
        lo, hi = np.clip(j - 1, 0, tr.size - 1), np.clip(j, 0, tr.size - 1)
        pick = np.where(np.abs(t_c[mine] - tr[lo]) <= np.abs(t_c[mine] - tr[hi]), lo, hi)
        cand = rows[pick]
        # within half an electrical period (180 deg e) of it, else it matches nothing
        ok = np.abs(t_c[mine] - truth.t_ideal_s[cand]) * truth.omega_e_deg_s[cand] < 180.0
        match[mine[ok]] = cand[ok]
    # an ideal commutation matched twice: the first in time counts, the others are extra
    first = np.zeros(match.size, dtype=bool)
    seen = set()
    for i, m in enumerate(match.tolist()):
        if m >= 0 and m not in seen:
            seen.add(m)
            first[i] = True
    extra_mask = ~first
    rows = match[first]
    dt = t_c[first] - truth.t_ideal_s[rows]
    angle = dt * truth.omega_e_deg_s[rows]
    # expected: ideal commutations after the start whose commutation, up to half a sector late,
    # still has a whole hold-off window inside the capture
    half_sector_s = 30.0 / np.maximum(truth.omega_e_deg_s, 1e-9)
    expected = (truth.t_ideal_s > start) & (truth.t_ideal_s + half_sector_s <= end)
    # the first pair the gates show is the start, not a commutation; when it is already the pair an
    # ideal commutation up to half a sector later asks for, the controller entered that sector
    # early at its start: that commutation is done, not missed
    if ex.initial.any():
        first_sector = int(ex.sector[ex.initial][0])
        first_sector = first_sector if sector_map is None else int(sector_map[first_sector])
        entered = (truth.sector == first_sector) & (truth.t_ideal_s <= start + half_sector_s)
        expected &= ~(entered & (np.cumsum(expected) == 1))
    expected = np.nonzero(expected)[0]
    missed_rows = np.setdiff1d(expected, rows)
    res = truth.sample_rate_hz
    bound = 0.5 / res + (ex.resolution_s or 0.0)
    return Score(int(rows.size), int(missed_rows.size), int(extra_mask.sum()), angle, dt, truth.t_ideal_s[rows],
                 truth.sector[rows], truth.t_ideal_s[missed_rows], t_c[extra_mask], ex, (float(start), float(end)),
                 hold_off_s, bound, sector_map)


def score(
    stimulus_dir: str | Path,
    capture_path: str | Path,
    mapping: GateMapping | None = None,
    hold_off_s: float = DEFAULT_HOLD_OFF_S,
) -> Score:
    truth = Truth.load(stimulus_dir)
    shortest = float(np.min(60.0 / np.maximum(truth.omega_e_deg_s, 1e-9))) if truth.n.size else math.inf
    if hold_off_s >= shortest:
        raise SignalError(
            "--hold-off-s",
            f"{hold_off_s * 1e6:g} us is not shorter than the shortest sector of the stimulus "
            f"({shortest * 1e6:.1f} us); two commutations would fall in one window",
        )
    cap = open_capture(capture_path, mapping)
    ex = extract(cap, hold_off_s)
    return score_extracted(truth, ex, hold_off_s)


def write_html(path: str | Path, sc: Score, title: str) -> Path:
    """One self-contained page: the JSON figures, the tables and the error over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    ax[0].plot(sc.t_ideal_s, sc.angle_error_deg_e, ".", ms=2)
    ax[0].set_xlabel("ideal commutation instant (s)")
    ax[0].set_ylabel("angle error (deg e, + = late)")
    for s in range(6):
        e = sc.angle_error_deg_e[sc.sector == s]
        ax[1].boxplot([e] if e.size else [[np.nan]], positions=[s], widths=0.6)
    ax[1].set_xlabel("sector entered")
    ax[1].set_ylabel("angle error (deg e)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    img = base64.b64encode(buf.getvalue()).decode()
    page = (
        f"<!doctype html><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<h1>{html.escape(title)}</h1><pre>{html.escape(json.dumps(sc.to_json(), indent=1))}</pre>"
        f"<pre>{html.escape(sc.summary())}</pre><img alt='angle error' src='data:image/png;base64,{img}'>"
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page)
    return path
