"""How much could any adaptive noise estimate gain over the tuned KF on the paper scenario?

Not a test and not a speed benchmark: the analysis behind docs/sage-husa.md, section "Why
Sage-Husa does not beat the tuned KF here". An adaptive filter can only beat a well-tuned fixed
one by giving it the right Q and R at each moment. Here the right schedule is handed to a plain
KF by an oracle (R and Q scaled with the true speed; or, with interference bursts, R switched by
the true burst state), every schedule tuned like the KF (Nelder-Mead on the training runs), and
all scored on the evaluation runs. The gap between the fixed KF and the best oracle bounds what
Sage-Husa's adaptation can win.

    python tools/table5_headroom.py
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from hil.experiments.compare import tune_kf
from hil.experiments.identify import identify
from hil.experiments.table5 import Bursts, run_scenario, score
from hil.predictors import filters as F
from hil.predictors.predictors import FilterSettings, KalmanPredictor

W_REF_RAD_S = 1571.0  # 7500 rpm, 2 pole pairs: the middle of the scenario
METRICS = ("MAPE reg. %", "overshoot %", "MAPE const. %", "MAPE comm. time %", "angle RMS", "p99", "max")


def run_scheduled(run, model, x, r_scale, q_scale):
    """A plain KF whose R_theta and Q_w are rescaled before every step by the oracle's schedule."""
    q_w, q_i, r_t, r_i = x
    kf = KalmanPredictor(model, FilterSettings(q0_diag=(q_w, 1e-9, q_i), r0_diag=(r_t, r_i)))
    t, cur = run.t_corrected_s, run.mean_current_a
    pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
    for k in range(t.size):
        s = kf.state
        if s[F.ST.INITIALISED]:
            s[F.ST.R] = r_t * r_scale(k, s[F.ST.X])
            s[F.ST.Q] = q_w * q_scale(k, s[F.ST.X])
        p = kf.update(t[k], cur[k])
        if p is not None:
            pred[k], w[k] = p, s[F.ST.X]
    return score(run, "", pred, w)


def tune_and_score(train, evaluation, model, start, r_scale, q_scale):
    def objective(z):
        return float(np.mean([run_scheduled(r, model, 10.0 ** z, r_scale, q_scale).angle_rms_deg_e for r in train]))

    z = minimize(objective, np.log10(start), method="Nelder-Mead", options=dict(maxfev=60)).x
    return np.mean([run_scheduled(r, model, 10.0 ** z, r_scale, q_scale).all_values() for r in evaluation], axis=0)


def score_fixed(kf_settings, model, evaluation):
    rows = []
    for r in evaluation:
        o = KalmanPredictor(model, kf_settings).run(r.t_corrected_s, r.mean_current_a)
        rows.append(score(r, "", o.pred_t_s, o.speed_rad_s).all_values())
    return np.mean(rows, axis=0)


def table(title, rows):
    print(title)
    print(f"{'schedule':<34} " + " ".join(f"{m:>17}" for m in METRICS))
    base = rows[0][1]
    for name, v in rows:
        print(f"{name:<34} " + " ".join(f"{x:>17.5f}" for x in v))
        if v is not base:
            print(f"{'  gain over fixed KF':<34} " + " ".join(f"{1 - x / b:>17.1%}" for x, b in zip(v, base)))


def main():
    runs = {s: run_scenario(seed=s) for s in (0, 1, 2, 3, 4)}
    model = identify(runs[1].config, seed=1).model
    train, evaluation = [runs[1], runs[2]], [runs[0], runs[3], runs[4]]
    kf = tune_kf(train, model)
    start = (kf.q0_diag[0], kf.q0_diag[2], *kf.r0_diag)
    fixed = score_fixed(kf, model, evaluation)
    rows = [("fixed Q, R (the tuned KF)", fixed)]
    for name, rp, qp in (("R ~ w^2 (time jitter in angle)", 2, 0), ("Q_w ~ w^4", 0, 4), ("R ~ w^2, Q_w ~ w^6", 2, 6)):
        rows.append((name, tune_and_score(train, evaluation, model, start, lambda k, w, p=rp: (w / W_REF_RAD_S) ** p,
                                          lambda k, w, p=qp: (w / W_REF_RAD_S) ** p)))
    table("paper scenario (stationary 3 us jitter): oracle schedules against the fixed tuned KF", rows)

    bursty = {s: Bursts(time_rms_s=12e-6).apply(runs[s], 100 + s) for s in runs}
    b_train, b_eval = [bursty[1][0], bursty[2][0]], [bursty[s][0] for s in (0, 3, 4)]
    kf_b = tune_kf(b_train, model)
    fixed_b = score_fixed(kf_b, model, b_eval)
    start_b = (kf_b.q0_diag[0], kf_b.q0_diag[2], *kf_b.r0_diag)
    state_of = {id(run): state for run, state in bursty.values()}

    def oracle_rows(z, group):
        """The KF with R_theta multiplied by the burst factor 10^z[4] while the true burst is on."""
        x, factor = 10.0 ** z[:4], 10.0 ** z[4]
        return [
            run_scheduled(r, model, x, lambda k, w, b=state_of[id(r)]: factor if b[k] else 1.0, lambda k, w: 1.0)
            for r in group
        ]

    z = minimize(
        lambda z: float(np.mean([row.angle_rms_deg_e for row in oracle_rows(z, b_train)])),
        np.log10([*start_b, 16.0]),
        method="Nelder-Mead",
        options=dict(maxfev=80),
    ).x
    oracle_b = np.mean([row.all_values() for row in oracle_rows(z, b_eval)], axis=0)
    table(
        "with interference bursts (12 us RMS, ~0.4 s in every ~1.9 s): R switched by the true burst state "
        f"(x{10 ** z[4]:.1f})",
        [("fixed Q, R (the tuned KF)", fixed_b), ("oracle R by burst state", oracle_b)],
    )


if __name__ == "__main__":
    main()
