"""Filter cost, run on demand (not a test): ``python benchmarks/bench_predictors.py``.

Per-step cost of our Sage-Husa online update (Eq. 9 predict, Eq. 11 update, Eq. 12 adaptation,
guards) against filterpy's ``KalmanFilter.predict() + update()`` on the same 3-state model
(F and B from Eq. 9, H observing angle and current), measured in the same run; and the batch
mode over a whole recorded edge sequence in filter steps per second on one core; then the batch
cost per edge of every predictor ``hil predictors compare`` runs, with its shipped settings
(hil/predictors/peer_settings.py), on the same edges.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from hil.predictors import FilterSettings, MotorModel, SageHusaPredictor  # noqa: E402
from plant_models import effects as fx  # noqa: E402
from plant_models import paper_bench  # noqa: E402
from plant_models.kinematic import OperatingPoint, simulate_edges  # noqa: E402


def edges(seconds: float):
    config = paper_bench().with_effects(fx.EdgeJitter(time_rms_s=2e-6))
    e = simulate_edges(config, [OperatingPoint(seconds, 8000.0, 2.0, end_speed_rpm=9000.0)], seed=1)
    return e.t_conditioned_s, np.full(len(e), 2.0)


def per_step_ours(t, cur, n):
    sh = SageHusaPredictor(MotorModel.from_plant(paper_bench().motor), FilterSettings(q0_diag=(0.1, 1e-9, 1e-6)))
    for k in range(50):
        sh.update(t[k], cur[k])  # JIT warm-up
    sh.reset()
    start = time.perf_counter()
    for k in range(n):
        sh.update(t[k], cur[k])
    return (time.perf_counter() - start) / n


def per_step_filterpy(t, cur, n):
    from filterpy.kalman import KalmanFilter

    model = MotorModel.from_plant(paper_bench().motor)
    kf = KalmanFilter(dim_x=3, dim_z=2, dim_u=1)
    kf.x = np.array([[np.pi / 3 / (t[1] - t[0])], [0.0], [cur[0]]])
    kf.P = np.diag([5e4, 5e4, 5e4])
    kf.Q = np.diag([0.1, 1e-9, 1e-6])
    kf.R = np.diag([1e-5, 1.0])
    kf.H = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    a = model.pole_pairs * model.torque_coefficient_n_m_per_a[0] / model.inertia_kg_m2
    c = model.pole_pairs * model.fan_coefficient_n_m_s2[0] / model.inertia_kg_m2
    z = np.zeros((2, 1))
    start = time.perf_counter()
    for k in range(1, n + 1):
        dt = t[k] - t[k - 1]
        kf.F = np.array([[1.0, 0.0, a * dt], [dt, 1.0, 0.5 * a * dt * dt], [0.0, 0.0, 1.0]])  # Eq. 9
        w_m = kf.x[0, 0] / model.pole_pairs
        kf.B = np.array([[-dt], [-0.5 * dt * dt], [0.0]])
        kf.predict(u=np.array([[c * w_m * w_m]]))
        z[0, 0] = np.pi / 3
        z[1, 0] = cur[k]
        kf.update(z)
        kf.x[1, 0] -= np.pi / 3  # the same re-referencing of the angle as ours
    return (time.perf_counter() - start) / n


def batch_rate(t, cur):
    sh = SageHusaPredictor(MotorModel.from_plant(paper_bench().motor), FilterSettings(q0_diag=(0.1, 1e-9, 1e-6)))
    sh.run(t[:100], cur[:100])
    best = min(_timed(lambda: sh.run(t, cur)) for _ in range(3))
    return (t.size - 1) / best


def _timed(fn):
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def peer_costs(t, cur) -> dict[str, float]:
    """Batch run time per edge (us, best of 3 after a compile call) of each compared predictor."""
    from hil.experiments import peers

    model = MotorModel.from_plant(paper_bench().motor)
    out = {}
    for name in peers.PREDICTORS:
        p = peers.build(name, peers.shipped_settings(name), model)
        p.run(t[:100], cur[:100])
        out[name] = min(_timed(lambda: p.run(t, cur)) for _ in range(3)) / t.size * 1e6
    return out


def main():
    t, cur = edges(12.0)  # about 20,000 edges
    n = 15000
    ours = min(per_step_ours(t, cur, n) for _ in range(3))
    theirs = min(per_step_filterpy(t, cur, n) for _ in range(3))
    rate = batch_rate(t, cur)
    print(f"{'case':<58} {'per step':>12} {'ratio':>10}")
    print(
        f"{'ours: Sage-Husa online update (predict+update+adapt+guards)':<58} {ours * 1e6:>9.2f} us "
        f"{theirs / ours:>9.1f}x faster"
    )
    import filterpy

    print(
        f"{'filterpy ' + filterpy.__version__ + ' KalmanFilter.predict() + update(), same model':<58} "
        f"{theirs * 1e6:>9.2f} us {'1.0x':>10}"
    )
    print(
        f"{'ours: batch mode over ' + format(t.size, ',') + ' recorded edges':<58} {1e6 / rate:>9.3f} us "
        f"{rate:>12,.0f} steps/s (bar >= 1,000,000)"
    )
    for name, us in peer_costs(t, cur).items():
        print(f"{'batch, ' + name + ' (shipped settings)':<58} {us:>9.3f} us")


if __name__ == "__main__":
    main()
