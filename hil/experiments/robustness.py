"""Sage-Husa against the fixed-noise KF over drawn conditions (docs/sage-husa.md, "Robustness").

Each condition draws edge-time jitter (0.2-10 us RMS), edge-angle jitter (0-0.2 deg e), a
start and optionally an end speed (2000-12,000 rpm), a load scale (0.3-2) and a factor on the
nominal Q0 (10^-2 to 10^2) that both filters start from. Edges come from the kinematic plant with
currents that make the filters' own equation of motion true; runs last at least 1 s and give at
least 500 scored edges. Both filters are scored against the plant's ideal instants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.units import edges_per_s, rpm_to_deg_e_per_s, rpm_to_rad_per_s
from plant_models import effects as fx
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint, simulate_edges

from ..predictors.model import MotorModel
from ..predictors.predictors import FilterSettings, KalmanPredictor, SageHusaPredictor
from .compare import SH_DESIGN

NOMINAL_Q0 = (0.1, 1e-9, 1e-6)
SKIP_EDGES = 150
MIN_SCORED_EDGES = 500
MIN_DURATION_S = 1.0
#: the KF's fixed edge-angle variance: (3.2 mrad)^2, the scale of a few us of jitter at mid speed
KF_R0 = (1e-5, 1.0)
#: Sage-Husa as shipped outside the paper protocol (no bursts in these conditions)
SH_SETTINGS = SH_DESIGN


@dataclass(frozen=True)
class Condition:
    jitter_s: float
    angle_jitter_deg: float
    q_factor_log10: float
    start_rpm: float
    end_rpm: float | None
    load_scale: float
    seed: int

    def duration_s(self, pole_pairs: int) -> float:
        """Long enough for MIN_SCORED_EDGES after the skipped start-up at the slowest speed."""
        slowest = min(self.start_rpm, self.end_rpm or self.start_rpm)
        slowest_edges_per_s = edges_per_s(slowest, pole_pairs)
        return max(MIN_DURATION_S, (SKIP_EDGES + MIN_SCORED_EDGES + 10) / slowest_edges_per_s)


def draw_conditions(n: int, seed: int = 0) -> list[Condition]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        out.append(
            Condition(
                jitter_s=float(rng.uniform(0.2e-6, 10e-6)),
                angle_jitter_deg=float(rng.uniform(0.0, 0.2)),
                q_factor_log10=float(rng.uniform(-2.0, 2.0)),
                start_rpm=float(rng.uniform(2000.0, 12000.0)),
                end_rpm=float(rng.uniform(2000.0, 12000.0)) if rng.random() < 0.5 else None,
                load_scale=float(rng.uniform(0.3, 2.0)),
                seed=int(rng.integers(0, 2**16)),
            )
        )
    return out


BASE = paper_bench()
MODEL = MotorModel.from_plant(BASE.motor)


def consistent_current(profile, load_scale, motor=BASE.motor):
    """Mean |i| that makes the filter's own equation of motion true for this profile."""
    out = []
    for op in profile:
        w_m = rpm_to_rad_per_s(op.speed_rpm)
        acc = rpm_to_rad_per_s((op.end_speed_rpm or op.speed_rpm) - op.speed_rpm) / op.duration_s
        torque = motor.inertia_kg_m2 * acc + load_scale * motor.fan_coefficient_n_m_s2 * w_m * w_m
        out.append(max(torque, 0.0) / (3 * motor.ke_v_s_per_rad))
    return out


def edges_and_currents(profile, jitter_s, angle_jitter_deg, load_scale, seed):
    currents = consistent_current(profile, load_scale)
    ops = [
        OperatingPoint(op.duration_s, op.speed_rpm, c, end_speed_rpm=op.end_speed_rpm)
        for op, c in zip(profile, currents)
    ]
    config = BASE.with_effects(fx.EdgeJitter(time_rms_s=jitter_s, angle_rms_deg_e=angle_jitter_deg))
    e = simulate_edges(config, ops, seed=seed)
    return e, e.mean_abs_current_a


def angle_error_deg(e, pred, skip=SKIP_EDGES):
    k = np.arange(skip, len(e) - 1)
    return (pred[k] - e.t_ideal_s[k + 1]) * rpm_to_deg_e_per_s(e.speed_rpm[k + 1], MODEL.pole_pairs)


def _pd(m) -> bool:
    return bool(np.all(np.isfinite(m)) and np.allclose(m, m.T) and np.all(np.linalg.eigvalsh(m) > 0))


def run_condition(c: Condition) -> dict:
    profile = [OperatingPoint(c.duration_s(MODEL.pole_pairs), c.start_rpm, end_speed_rpm=c.end_rpm)]
    e, cur = edges_and_currents(profile, c.jitter_s, c.angle_jitter_deg, c.load_scale, c.seed)
    q0 = tuple(q * 10 ** c.q_factor_log10 for q in NOMINAL_Q0)
    out = dict(c.__dict__, duration_s=profile[0].duration_s)
    for name, cls, s in (("kf", KalmanPredictor, FilterSettings(q0_diag=q0, r0_diag=KF_R0, gate_state_update=False)),
                         ("sh", SageHusaPredictor, FilterSettings(q0_diag=q0, **SH_SETTINGS))):
        f = cls(MODEL, s)
        run = f.run(e.t_conditioned_s, cur)
        err = angle_error_deg(e, run.pred_t_s)
        out[name] = float(np.sqrt(np.mean(err**2)))
        out["scored_edges"] = int(err.size)
        out[name + "_finite"] = bool(np.all(np.isfinite(run.pred_t_s[1:])) and np.all(np.isfinite(f.state)))
        out[name + "_pd"] = all(_pd(m) for m in (f.p_matrix, f.q_matrix, f.r_matrix))
    return out


def summarise(results: list[dict]) -> dict:
    n = len(results)
    ratio = np.array([r["sh"] / r["kf"] for r in results])
    return {
        "conditions": n,
        "min_scored_edges": min(r["scored_edges"] for r in results),
        "min_duration_s": min(r["duration_s"] for r in results),
        "pd_and_finite": sum(r["kf_finite"] and r["sh_finite"] and r["kf_pd"] and r["sh_pd"] for r in results) / n,
        "sh_under_2x_kf": float(np.mean(ratio < 2.0)),
        "sh_within_5pct_plus_0.01": float(np.mean([r["sh"] <= 1.05 * r["kf"] + 0.01 for r in results])),
        "median_ratio": float(np.median(ratio)),
        "p90_ratio": float(np.percentile(ratio, 90)),
        "worst_ratio": float(np.max(ratio)),
    }
