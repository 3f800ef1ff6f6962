"""The paper's headline comparison (Section 4.3, Figs. 8-9): raw versus corrected commutation."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bldc.motor import steady_state
from plant_models import Simulation, paper_bench

from ..calibration.campaign import station_corrections
from ..controller.commutation import HallCommutation, SpeedPI
from ..verdicts.plots import pyplot, save

#: paper Section 4.3: after correction the speed MSE fell by 92.0 % and the mean phase current by 62.8 %
PAPER_SPEED_MSE_REDUCTION = 0.920
PAPER_MEAN_CURRENT_REDUCTION = 0.628


@dataclass
class RunResult:
    name: str
    t_s: np.ndarray
    speed_rpm: np.ndarray
    speed_mse_rpm2: float           #: speed fluctuation: mean square about the window's linear trend
    setpoint_mse_rpm2: float        #: mean square error against the set point (includes slow regulation)
    mean_phase_current_a: float
    commutation_error_deg_e: np.ndarray

    @property
    def rms_deg_e(self) -> float:
        return float(np.sqrt(np.mean(self.commutation_error_deg_e**2)))

    @property
    def p99_deg_e(self) -> float:
        return float(np.percentile(np.abs(self.commutation_error_deg_e), 99))


def run_strategy(config, corrections, speed_rpm: float, settle_s: float, turns: int, seed: int, name: str) -> RunResult:
    duty0 = steady_state(config.motor, speed_rpm)["duty"]
    current0 = steady_state(config.motor, speed_rpm)["current_a"] * 2 / 3  # mean |i| over three phases
    source = HallCommutation(
        config.motor.pole_pairs, SpeedPI(speed_rpm, feedforward=duty0), corrections, current_estimate_a=current0
    )
    sim = Simulation(config, source, duty=duty0, initial_speed_rpm=speed_rpm, seed=seed, sample_rate_hz=50e3)
    sim.run_until(settle_s)
    t0 = sim.t_s
    sim.run_until(t0 + turns * 60.0 / speed_rpm)
    s = sim.samples()
    win = s.t_s >= t0
    c = sim.commutations()
    cw = c.t_s >= t0
    return RunResult(
        name=name,
        t_s=s.t_s[win] - t0,
        speed_rpm=s.speed_rpm[win],
        speed_mse_rpm2=_fluctuation_mse(s.t_s[win], s.speed_rpm[win]),
        setpoint_mse_rpm2=float(np.mean((s.speed_rpm[win] - speed_rpm) ** 2)),
        mean_phase_current_a=float(np.mean(np.abs(s.i_true_a[win]))),
        commutation_error_deg_e=c.error_deg_e[cw],
    )


def _fluctuation_mse(t_s: np.ndarray, speed_rpm: np.ndarray) -> float:
    trend = np.polyval(np.polyfit(t_s, speed_rpm, 1), t_s)
    return float(np.mean((speed_rpm - trend) ** 2))


def compare(speed_rpm: float = 5700.0, turns: int = 10, settle_s: float = 4.0, seed: int = 0, config=None):
    """Calibrate the paper bench, then run raw and corrected commutation on the same plant."""
    config = config or paper_bench(with_deviations=True)
    corrections = station_corrections(config, seed=seed)
    raw = run_strategy(config, None, speed_rpm, settle_s, turns, seed, "raw Hall edges")
    corrected = run_strategy(config, corrections, speed_rpm, settle_s, turns, seed, "corrected edges")
    return raw, corrected, corrections


def plot(raw: RunResult, corrected: RunResult, path: str | Path) -> Path:
    fig, ax = pyplot().subplots(figsize=(9, 3.5))
    for r in (raw, corrected):
        ax.plot(
            r.t_s * 1e3,
            r.speed_rpm,
            lw=1,
            label=f"{r.name}: fluctuation MSE {r.speed_mse_rpm2:.3g} rpm^2, mean |i| {r.mean_phase_current_a:.3f} A",
        )
    ax.set_xlabel("time [ms] (measurement window after settling)")
    ax.set_ylabel("true speed [rpm]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return save(fig, path)
