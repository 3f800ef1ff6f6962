"""Commutation predictors: Sage-Husa, fixed-noise Kalman, and pre-calibration only.

Each consumes the corrected edge times (calibration applied) and the mean phase current of each
commutation cycle, and predicts the instant of the next commutation. ``update`` is the online
form (one call per commutation, as firmware would run it); ``run`` filters a whole recorded
sequence in one compiled loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bldc.contract import FILTER_COUNTERS

from . import filters as F
from .model import SECTOR_RAD, MotorModel


@dataclass(frozen=True)
class FilterSettings:
    """Noise settings and guards. Q0 is per commutation cycle: (rad/s)^2, rad^2, A^2."""

    q0_diag: tuple[float, float, float] = (4.0, 1e-6, 1e-3)
    #: paper 4.4: R0 = diag(0, 0.02); the first entry is the edge-angle variance (rad^2), 0
    #: because pre-calibration removed the deterministic edge errors; the guards floor it
    r0_diag: tuple[float, float] = (0.0, 0.02)
    p0_diag: tuple[float, float, float] = (5e4, 5e4, 5e4)  # paper 4.4
    forgetting_b: float = 0.98  # Q's b (Eq. 12, per step); usual range 0.95-0.995 (docs/sage-husa.md)
    adapt_interval: int = 120                          # paper 4.4: r and q every 120 commutations
    #: R's own forgetting factor (per R interval) and interval (paper 4.4: 120 commutations)
    r_forgetting_b: float = 0.98
    r_interval: int = 120
    warmup: int = 120
    chi2_gate: float = F.CHI2_2DOF_999
    #: a gated innovation leaves the state at its prediction (and still teaches R); off = every
    #: edge updates the state at full gain, as a textbook Kalman filter does
    gate_state_update: bool = True
    #: Huber threshold on sqrt(NIS) for the R update (default: 95 % of chi-square, 2 dof)
    huber_c: float = F.HUBER_C_95
    q_band_factor: float = 100.0
    eig_floor: float = 1e-9
    #: resolution of the current measurement (the edge messages carry mA): R's current variance
    #: never goes below its quantisation variance, resolution^2 / 12
    current_resolution_a: float = 1e-3
    #: consecutive innovations beyond the gate, all of one sign, taken as divergence (P faded);
    #: 0 = never. 3 = ``filters.divergence_run_for(chi2_gate, 2400 edges/s)``: a chance trigger
    #: of consistent Gaussian innovations is rarer than once per 1000 s at 12,000 rpm, 2 pole
    #: pairs. Where bursts of edge noise are stated, every edge may be gated inside one before R
    #: learns it, and the run is ``divergence_run_for(..., p_gated=1)`` = 23 (compare.BURSTS_SH)
    divergence_run: int = 3
    #: variance match of R_theta (filters.variance_match_bounds): an R interval whose edges show
    #: an edge noise inconsistent with R_theta beyond what chance gives once per this many
    #: seconds of edges at 12,000 rpm replaces R_theta at once; 0 = off (R by Eq. 12 only)
    r_match_horizon_s: float = 1000.0
    #: which Eq. 12 estimates adapt: 1 Q, 2 R, 4 r, 8 q (15 = all, the paper's filter). Options,
    #: not the paper's: 16 steers Q's speed entry by innovation whiteness instead; 32 adapts Q's
    #: current entry only (Q_w stays nominal); 64 keeps R's current entry at or above its R0
    #: (``filters.ADAPT_*``, docs/sage-husa.md "What adapts")
    adapt_mask: int = F.ADAPT_ALL
    #: threshold of the edge-noise change detector (``filters._change_detect``); 0 = off. The
    #: default is the one at which white edge noise raises a chance alarm less than once per
    #: 1000 s at 12,000 rpm, 2 pole pairs (``filters.CUSUM_H_1000S``)
    cusum_h: float = F.CUSUM_H_1000S

    def check(self) -> None:
        for name in ("forgetting_b", "r_forgetting_b"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {getattr(self, name)!r}")
        for name in ("q0_diag", "p0_diag"):
            if any(not math.isfinite(v) or v <= 0 for v in getattr(self, name)):
                raise ValueError(f"{name} must be positive and finite, got {getattr(self, name)!r}")
        if any(not math.isfinite(v) or v < 0 for v in self.r0_diag):
            raise ValueError(f"r0_diag must be >= 0 and finite, got {self.r0_diag!r}")
        for name in ("adapt_interval", "r_interval"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if self.divergence_run < 0:
            raise ValueError(f"divergence_run must be >= 0 (0 = off), got {self.divergence_run!r}")
        if not self.current_resolution_a >= 0:
            raise ValueError(f"current_resolution_a must be >= 0, got {self.current_resolution_a!r}")
        if not self.r_match_horizon_s >= 0:
            raise ValueError(f"r_match_horizon_s must be >= 0 (0 = off), got {self.r_match_horizon_s!r}")
        if not (self.cusum_h >= 0 and math.isfinite(self.cusum_h)):
            raise ValueError(f"cusum_h must be >= 0 and finite (0 = off), got {self.cusum_h!r}")
        if not self.huber_c > 0:
            raise ValueError(f"huber_c must be > 0, got {self.huber_c!r}")

    def params(self, adaptive: bool, pole_pairs: int, inertia_kg_m2: float,
               friction_n_m_s_per_rad: float = 0.0) -> np.ndarray:
        """The filter's parameter vector (layout ``filters.PARAM_TABLE``)."""
        fp = np.zeros(F.N_FPARAMS)
        fp[F.FP.B] = self.forgetting_b
        fp[F.FP.INTERVAL] = self.adapt_interval
        fp[F.FP.WARMUP] = self.warmup
        fp[F.FP.GATE] = self.chi2_gate
        fp[F.FP.BAND] = self.q_band_factor
        fp[F.FP.FLOOR] = self.eig_floor
        fp[F.FP.ADAPTIVE] = float(self.adapt_mask) if adaptive else 0.0
        fp[F.FP.POLE_PAIRS] = pole_pairs
        fp[F.FP.J] = inertia_kg_m2
        fp[F.FP.FRICTION] = friction_n_m_s_per_rad
        fp[F.FP.DIVERGENCE_RUN] = self.divergence_run
        fp[F.FP.R_B] = self.r_forgetting_b
        fp[F.FP.R_INTERVAL] = self.r_interval
        fp[F.FP.HUBER_C] = self.huber_c
        fp[F.FP.HUBER_KAPPA] = F.huber_kappa(self.huber_c)
        fp[F.FP.GATE_STATE] = 1.0 if self.gate_state_update else 0.0
        fp[F.FP.R_I_FLOOR] = max(self.current_resolution_a ** 2 / 12.0,
                                 self.r0_diag[1] if self.adapt_mask & F.ADAPT_R_CURRENT_FLOOR else 0.0)
        if self.r_match_horizon_s > 0:
            fp[F.FP.R_MATCH_HI], fp[F.FP.R_MATCH_LO] = F.variance_match_bounds(
                self.r_interval, horizon_s=self.r_match_horizon_s
            )
        fp[F.FP.CUSUM_H] = self.cusum_h
        return fp


GUARD_NAMES = ("innovation_gate", "q_not_pd", "q_band", "r_not_pd", "p_not_pd", "divergence", "lost_lock")


def split_counters(guards: dict[str, int]) -> dict[str, int]:
    """The counters a controller exposes (``bldc.contract.FILTER_COUNTERS``) from the guard counts:
    gated edges, covariance repairs (eigenvalue floors on R or P: a matrix in use had to be
    repaired), divergence fades and band projections (Q's Eq. 12 estimate projected onto its
    band, including a non-positive estimate)."""
    g = guards.get
    counts = (g("innovation_gate", 0), g("r_not_pd", 0) + g("p_not_pd", 0), g("divergence", 0), g("q_band", 0))
    return dict(zip(FILTER_COUNTERS, counts, strict=True))


@dataclass
class PredictionRun:
    """Predictions over a sequence: pred_t_s[k] is the predicted instant of edge k + 1."""

    pred_t_s: np.ndarray
    speed_rad_s: np.ndarray   #: the predictor's speed estimate after edge k (electrical)
    guards: dict[str, int] = field(default_factory=dict)


class _KalmanCore:
    adaptive = False

    def __init__(self, model: MotorModel, settings: FilterSettings = FilterSettings()):
        settings.check()
        self.model, self.settings = model, settings
        self.speed_tab, self.kt_tab, self.m_tab = model.arrays()
        #: rows speed (rpm), K_T, M: one array, one argument of the compiled call
        self.tables = np.ascontiguousarray(np.vstack((self.speed_tab, self.kt_tab, self.m_tab)), dtype=float)
        self.fp = settings.params(self.adaptive, model.pole_pairs, model.inertia_kg_m2, model.friction_n_m_s_per_rad)
        self.reset()

    def reset(self) -> None:
        s = self.settings
        self.state = F.new_state(np.diag(s.q0_diag), s.r0_diag, s.p0_diag)
        self.guard_counts = np.zeros(F.N_GUARDS, dtype=np.int64)
        self._work = np.empty(F.N_WORK)
        self._last_t: float | None = None

    # --- views for the caller (read-backs a controller would expose) --------------------------
    @property
    def guards(self) -> dict[str, int]:
        return dict(zip(GUARD_NAMES, map(int, self.guard_counts)))

    @property
    def counters(self) -> dict[str, int]:
        """Gated edges, covariance repairs, divergence fades, band projections (``split_counters``)."""
        return split_counters(self.guards)

    @property
    def covariance_repairs(self) -> int:
        """Eigenvalue floors on R or P (a gated outlier, a faded P or a Q projected onto its band
        is not a covariance repair)."""
        return int(self.guard_counts[F.GUARD_R_PD] + self.guard_counts[F.GUARD_P_PD])

    @property
    def q_matrix(self) -> np.ndarray:
        return self.state[F.ST.Q:F.ST.Q + 9].reshape(3, 3).copy()

    @property
    def r_matrix(self) -> np.ndarray:
        return self.state[F.ST.R:F.ST.R + 4].reshape(2, 2).copy()

    @property
    def p_matrix(self) -> np.ndarray:
        return self.state[F.ST.P:F.ST.P + 9].reshape(3, 3).copy()

    @property
    def speed_rad_s(self) -> float:
        return float(self.state[F.ST.X])

    @property
    def steps(self) -> int:
        """Filter steps taken (the first edge initialises and is not a step)."""
        return int(self.state[F.ST.K_STEP])

    def update(self, t_corrected_s: float, mean_current_a: float) -> float | None:
        """Feed one corrected edge (end of a commutation cycle); returns the predicted next instant."""
        last = self._last_t
        self._last_t = t_corrected_s
        if last is None:
            return None
        if not t_corrected_s > last:
            self._last_t = last
            raise ValueError(f"edge times must increase: {t_corrected_s!r} after {last!r}")
        return t_corrected_s + F.edge(
            self.state, self.fp, self.guard_counts, t_corrected_s - last, mean_current_a, self.tables, self._work
        )

    def run(self, t_corrected_s: np.ndarray, mean_current_a: np.ndarray) -> PredictionRun:
        t = np.ascontiguousarray(t_corrected_s, dtype=float)
        cur = np.ascontiguousarray(mean_current_a, dtype=float)
        if t.size != cur.size:
            raise ValueError("one mean current per edge is needed")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            k = int(np.nonzero(np.diff(t) <= 0)[0][0]) + 1
            raise ValueError(f"edge times must increase (edge {k}: {t[k]!r} after {t[k - 1]!r})")
        self.reset()
        pred = np.full(t.size, np.nan)
        w = np.full(t.size, np.nan)
        F.run_batch(self.state, self.fp, self.guard_counts, t, cur, self.tables, pred, w)
        return PredictionRun(pred, w, self.guards)


class KalmanPredictor(_KalmanCore):
    """Plain Kalman filter with fixed Q and R (Eq. 11 only): the first baseline."""

    adaptive = False


class SageHusaPredictor(_KalmanCore):
    """Sage-Husa adaptive filter: Eq. 11 plus Eq. 12 (Q every cycle; r, R, q every interval)."""

    adaptive = True


class PrecalibrationPredictor:
    """The second baseline: next commutation 60 deg electrical after the last corrected edge,
    at the speed of the cycle that just ended."""

    guards: dict[str, int] = {}

    def run(self, t_corrected_s: np.ndarray, mean_current_a: np.ndarray | None = None) -> PredictionRun:
        t = np.asarray(t_corrected_s, dtype=float)
        pred = np.full(t.size, np.nan)
        w = np.full(t.size, np.nan)
        dt = np.diff(t)
        pred[1:] = t[1:] + dt
        w[1:] = SECTOR_RAD / dt
        return PredictionRun(pred, w, {})
