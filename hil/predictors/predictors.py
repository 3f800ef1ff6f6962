"""Commutation predictors: Sage-Husa, fixed-noise Kalman, and pre-calibration only.

Each consumes the corrected edge times (calibration applied) and the mean phase current of each
commutation cycle, and predicts the instant of the next commutation. ``update`` is the online
form (one call per commutation, as firmware would run it); ``run`` filters a whole recorded
sequence in one compiled loop.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

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
    forgetting_b: float = 0.98                         # design notes: 0.95-0.995
    adapt_interval: int = 120                          # paper 4.4: r, R, q every 120 commutations
    warmup: int = 120
    chi2_gate: float = F.CHI2_2DOF_999
    q_band_factor: float = 100.0
    eig_floor: float = 1e-9
    #: consecutive innovations beyond the gate, all of one sign, taken as divergence (P faded); 0 = never
    divergence_run: int = 2
    #: which Eq. 12 estimates adapt: 1 Q, 2 R, 4 r, 8 q (15 = all, the paper's filter);
    #: 16 steers Q's speed entry by innovation whiteness instead (an option, not the paper's)
    adapt_mask: int = F.ADAPT_ALL

    def check(self) -> None:
        if not 0.0 < self.forgetting_b < 1.0:
            raise ValueError(f"forgetting_b must be in (0, 1), got {self.forgetting_b!r}")
        for name in ("q0_diag", "p0_diag"):
            if any(not math.isfinite(v) or v <= 0 for v in getattr(self, name)):
                raise ValueError(f"{name} must be positive and finite, got {getattr(self, name)!r}")
        if any(not math.isfinite(v) or v < 0 for v in self.r0_diag):
            raise ValueError(f"r0_diag must be >= 0 and finite, got {self.r0_diag!r}")
        if self.adapt_interval < 1:
            raise ValueError("adapt_interval must be >= 1")
        if self.divergence_run < 0:
            raise ValueError(f"divergence_run must be >= 0 (0 = off), got {self.divergence_run!r}")


GUARD_NAMES = ("innovation_gate", "q_not_pd", "q_band", "r_not_pd", "p_not_pd", "divergence")


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
        self._speed_list, self._kt_list, self._m_list = (list(map(float, a)) for a in (self.speed_tab, self.kt_tab, self.m_tab))
        fp = np.zeros(F.N_FPARAMS)
        fp[F.F_B] = settings.forgetting_b
        fp[F.F_INTERVAL] = settings.adapt_interval
        fp[F.F_WARMUP] = settings.warmup
        fp[F.F_GATE] = settings.chi2_gate
        fp[F.F_BAND] = settings.q_band_factor
        fp[F.F_FLOOR] = settings.eig_floor
        fp[F.F_ADAPTIVE] = float(settings.adapt_mask) if self.adaptive else 0.0
        fp[F.F_POLE_PAIRS] = model.pole_pairs
        fp[F.F_J] = model.inertia_kg_m2
        fp[F.F_DIVERGENCE_RUN] = settings.divergence_run
        self.fp = fp
        self.reset()

    def _interp(self, n_rpm: float) -> tuple[float, float]:
        """K_T(n) and M(n) by linear interpolation, clamped at the table ends (as ``np.interp``),
        in plain floats: the online path runs it twice per edge."""
        speeds = self._speed_list
        j = bisect.bisect_right(speeds, n_rpm)
        if j == 0:
            return self._kt_list[0], self._m_list[0]
        if j == len(speeds):
            return self._kt_list[-1], self._m_list[-1]
        f = (n_rpm - speeds[j - 1]) / (speeds[j] - speeds[j - 1])
        return (self._kt_list[j - 1] + f * (self._kt_list[j] - self._kt_list[j - 1]),
                self._m_list[j - 1] + f * (self._m_list[j] - self._m_list[j - 1]))

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
    def covariance_guard_trips(self) -> int:
        """Guard trips other than the innovation gate and the divergence fade (a gated outlier or a
        faded P is not a covariance repair)."""
        c = self.guard_counts.tolist()
        return sum(c) - c[F.GUARD_GATE] - c[F.GUARD_DIVERGENCE]

    @property
    def q_matrix(self) -> np.ndarray:
        return self.state[F.Q0:F.Q0 + 9].reshape(3, 3).copy()

    @property
    def r_matrix(self) -> np.ndarray:
        return self.state[F.R0:F.R0 + 4].reshape(2, 2).copy()

    @property
    def p_matrix(self) -> np.ndarray:
        return self.state[F.P0:F.P0 + 9].reshape(3, 3).copy()

    @property
    def speed_rad_s(self) -> float:
        return float(self.state[F.X0])

    def _coefficients(self, w_e: float) -> tuple[float, float]:
        p = self.model.pole_pairs
        n_rpm = w_e / p * 60 / (2 * math.pi)
        kt, m = self._interp(n_rpm)
        w_m = w_e / p
        return p * kt / self.model.inertia_kg_m2, p * m * w_m * w_m / self.model.inertia_kg_m2

    def update(self, t_corrected_s: float, mean_current_a: float) -> float | None:
        """Feed one corrected edge (end of a commutation cycle); returns the predicted next instant."""
        if self._last_t is None:
            self._last_t = t_corrected_s
            return None
        dt = t_corrected_s - self._last_t
        if not dt > 0:
            raise ValueError(f"edge times must increase: {t_corrected_s!r} after {self._last_t!r}")
        self._last_t = t_corrected_s
        if self.state[F.INITIALISED] == 0.0:  # the first cycle initialises speed and current
            self.state[F.X0:F.X0 + 3] = (SECTOR_RAD / dt, 0.0, mean_current_a)
            self.state[F.INITIALISED] = 1.0
        else:
            a, dl = self._coefficients(float(self.state[F.X0]))
            F.step(self.state, self.fp, self.guard_counts, SECTOR_RAD, mean_current_a, dt, a, dl, self._work)
        a, dl = self._coefficients(float(self.state[F.X0]))
        return t_corrected_s + float(F.predict_next_s(self.state, a, dl))

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
        F.run_batch(self.state, self.fp, self.guard_counts, t, cur, self.speed_tab, self.kt_tab, self.m_tab, pred, w)
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
