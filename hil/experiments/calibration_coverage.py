"""Are the ordinary-run calibration's intervals honest? Coverage on captures with known truth,
and agreement of the two halves of each real capture.

The generator here is this check's own (not the gap diagnosis's, not the tests'): a rotor whose
electrical speed ramps with a slow random drift on top (a few low-frequency sinusoids of random
phase, a few percent each), Hall sensors with installation offsets, rise-minus-fall switching
asymmetries, magnet pole offsets and a rise-minus-fall conditioning delay, edge times with
AR(1) jitter correlated from edge to edge, and a logic analyser's timer quantisation (floor to
the sample grid, random phase). The calibration is run on each capture as a user runs it
(``ordinary_calibration``) and each reported figure's interval, value +- z * stderr, is checked
against the truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from hil.calibration.corrections import SENSORS
from hil.calibration.ordinary import hall_steps, ordinary_calibration, pole_of_boundary
from hil.calibration.result import Calibration

#: the moteus captures' sample period (30 kHz)
TICK_S = 33_333e-9
#: two-sided coverage the intervals claim, and its normal quantile
COVERAGE = 0.95
Z = float(stats.norm.ppf(0.5 + COVERAGE / 2))
FIGURES = ("delay_difference", "asymmetry", "installation", "pole")


@dataclass
class SyntheticCapture:
    """Edges of one synthetic capture and the truth in the calibration's conventions."""

    t_s: np.ndarray
    sensor: np.ndarray
    rising: np.ndarray
    pole_pairs: int
    #: the pole index (``pole_of_boundary`` of the true boundary) of each edge
    true_pole: np.ndarray
    delay_difference_s: float
    asymmetry_deg_e: float
    installation_deg_e: np.ndarray  #: A, B, C, relative (sum zero)
    pole_deg_e: np.ndarray  #: per magnet pole boundary, zero mean per parity
    settings: dict = field(default_factory=dict)


def correlated_capture(
    seed: int,
    *,
    duration_s: float = 6.0,
    pole_pairs: int = 4,
    jitter_rms_s: tuple[float, float] = (3e-6, 20e-6),
    jitter_correlation: tuple[float, float] = (0.5, 0.85),
    tick_s: float = TICK_S,
) -> SyntheticCapture:
    """One capture with AR(1) edge jitter and a slowly drifting speed; the truth drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    direction = int(rng.choice([-1, 1]))
    f_lo = rng.uniform(30.0, 60.0)
    f_hi = f_lo * rng.uniform(3.0, 6.0)  # Hz electrical: a ramp spanning a speed range
    dt = 20e-6
    t = np.arange(0.0, duration_s, dt)
    ramp = f_lo + (f_hi - f_lo) * np.clip(t / duration_s * rng.uniform(1.0, 1.5), 0.0, 1.0)
    drift = np.ones_like(t)
    for _ in range(3):  # slow speed drift: 0.05-0.8 Hz, a few percent each
        drift += rng.uniform(0.01, 0.05) * np.sin(2 * np.pi * rng.uniform(0.05, 0.8) * t + rng.uniform(0, 2 * np.pi))
    theta = np.concatenate([[0.0], np.cumsum(ramp * drift)[:-1]]) * dt * 360.0  # travelled deg e
    delay = rng.uniform(50e-6, 300e-6)
    switching = rng.normal(0.4, 0.6, 3)  # rise minus fall per sensor, deg e
    inst = rng.normal(0.0, 1.5, 3)
    poles = rng.normal(0.0, 1.0, 2 * pole_pairs)
    for parity in (0, 1):
        poles[parity::2] -= poles[parity::2].mean()
    m = np.arange(2, int(theta[-1] / 60.0) - 2)  # travelled boundaries
    mt = direction * m  # the boundaries in electrical angle
    sensor = np.array([0, 2, 1])[np.mod(mt, 3)]
    rising = (np.mod(mt, 2) == 0) if direction > 0 else (np.mod(mt, 2) == 1)
    true_pole = pole_of_boundary(mt, pole_pairs)
    static = inst[sensor] + poles[true_pole]  # where the sensor switches, deg e
    trail = direction * static + np.where(rising, 0.5, -0.5) * switching[sensor]
    t_edge = np.interp(60.0 * m + trail, theta, t) + np.where(rising, delay, 0.0)
    rho = rng.uniform(*jitter_correlation)
    sd = rng.uniform(*jitter_rms_s)
    innov = rng.normal(0.0, sd * np.sqrt(1 - rho**2), m.size)
    jitter = np.empty(m.size)
    jitter[0] = rng.normal(0.0, sd)
    for k in range(1, m.size):  # AR(1) from edge to edge
        jitter[k] = rho * jitter[k - 1] + innov[k]
    t_edge = t_edge + jitter
    t_edge = np.floor((t_edge + rng.uniform(0, tick_s)) / tick_s) * tick_s
    order = np.argsort(t_edge, kind="stable")
    keep = np.ones(order.size, dtype=bool)
    keep[1:] = np.diff(t_edge[order]) > 0  # two edges in one sample cannot be ordered: dropped
    order = order[keep]
    return SyntheticCapture(
        t_edge[order],
        sensor[order],
        rising[order],
        pole_pairs,
        true_pole[order],
        delay,
        float(np.mean(switching)),
        inst - inst.mean(),
        poles,
        {"direction": direction, "speed_hz_e": (f_lo, f_hi), "jitter_rms_s": sd, "jitter_lag1": rho},
    )


@dataclass
class Check:
    """One figure of one capture: estimate, standard error and truth."""

    figure: str
    value: float
    stderr: float
    truth: float

    @property
    def z(self) -> float:
        return abs(self.value - self.truth) / self.stderr if self.stderr > 0 else float("inf")


def check_capture(cap: SyntheticCapture) -> list[Check]:
    """Calibrate ``cap`` with its pole count stated and compare every figure with the truth."""
    steps = hall_steps(cap.t_s, cap.sensor, cap.rising)
    cal = ordinary_calibration(steps, tick_s=TICK_S, pole_pairs=cap.pole_pairs)
    table = cal.corrections
    checks = []
    d = cal.ordinary.rise_fall_delay_difference_s
    if d.value is not None:
        checks.append(Check("delay_difference", d.value * 1e6, d.stderr * 1e6, cap.delay_difference_s * 1e6))
    a = cal.ordinary.rise_fall_angle_asymmetry_deg_e
    if a.value is not None:
        checks.append(Check("asymmetry", a.value, a.stderr, cap.asymmetry_deg_e))
    inst, inst_se = table.installation_offset_deg_e, table.uncertainty["installation_offset_deg_e"]
    for x, name in enumerate(SENSORS):
        if inst_se.get(name):
            checks.append(Check("installation", inst[name], inst_se[name], float(cap.installation_deg_e[x])))
    poles, poles_se = table.pole_offset_deg_e, table.uncertainty["pole_offset_deg_e"]
    if poles:
        # the calibration numbers the poles from its own boundary count: map each of its poles to
        # the true one through the edges they share
        used = steps.used()
        est_pole = pole_of_boundary(steps.boundary[used], cap.pole_pairs)
        true_pole = cap.true_pole[used]
        for j in range(2 * cap.pole_pairs):
            match = np.unique(true_pole[est_pole == j])
            if match.size != 1:
                raise AssertionError(f"pole {j} maps to true poles {match.tolist()}")
            checks.append(Check("pole", poles[j], poles_se[j], float(cap.pole_deg_e[match[0]])))
    return checks


@dataclass
class CoverageRow:
    """One figure over a coverage study: how often value +- Z stderr held the truth, how wide those
    intervals were, and how far the estimates really were from the truth (an honest interval's
    half-width is about Z times the RMS error; the RMS of z is about 1)."""

    figure: str
    n: int
    coverage: float
    mean_halfwidth: float
    rms_error: float
    rms_z: float
    unit: str


UNITS = {"delay_difference": "us", "asymmetry": "deg e", "installation": "deg e", "pole": "deg e"}


def coverage_study(n_captures: int, seed: int = 0, **capture_kwargs) -> tuple[list[CoverageRow], dict]:
    """Coverage of the +-Z stderr intervals per figure over ``n_captures`` synthetic captures."""
    t0 = time.process_time()
    checks: list[Check] = []
    edges = []
    for i in range(n_captures):
        cap = correlated_capture(seed * 100_003 + i, **capture_kwargs)
        edges.append(cap.t_s.size)
        checks += check_capture(cap)
    rows = []
    for fig in FIGURES:
        mine = [c for c in checks if c.figure == fig]
        if not mine:
            continue
        z = np.array([c.z for c in mine])
        err = np.array([c.value - c.truth for c in mine])
        halfwidth = Z * float(np.mean([c.stderr for c in mine]))
        rms_error, rms_z = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(z**2)))
        rows.append(CoverageRow(fig, len(mine), float(np.mean(z <= Z)), halfwidth, rms_error, rms_z, UNITS[fig]))
    info = {
        "captures": n_captures,
        "seed": seed,
        "edges_per_capture_mean": float(np.mean(edges)),
        "cpu_s": time.process_time() - t0,
    }
    return rows, info


def half_split(
    t_s: np.ndarray, sensor: np.ndarray, rising: np.ndarray, tick_s: float, pole_pairs: int | None
) -> tuple[list[dict], list[Calibration]]:
    """Each half of a capture (by edge count) calibrated alone: per figure the two values, their
    standard errors and z = |a - b| / hypot(se_a, se_b); and the two calibrations."""
    whole = hall_steps(t_s, sensor, rising)
    half = t_s.size // 2
    cals = []
    for first, sl in ((0, slice(0, half)), (half, slice(half, None))):
        steps = hall_steps(t_s[sl], sensor[sl], rising[sl])
        # number the boundaries (and so the poles) as the whole capture does
        both = np.nonzero((steps.direction != 0) & (whole.direction[sl] != 0))[0]
        if both.size:
            steps.boundary += whole.boundary[first + both[0]] - steps.boundary[both[0]]
        cals.append(ordinary_calibration(steps, tick_s=tick_s, pole_pairs=pole_pairs))
    rows = []

    def add(name, pairs):
        (a, sa), (b, sb) = pairs
        if None in (a, sa, b, sb):
            return
        rows.append({"figure": name, "halves": [a, b], "stderr": [sa, sb], "z": float(abs(a - b) / np.hypot(sa, sb))})

    add("delay_difference", [(c.ordinary.rise_fall_delay_difference_s.value,
                              c.ordinary.rise_fall_delay_difference_s.stderr) for c in cals])
    add("asymmetry", [(c.ordinary.rise_fall_angle_asymmetry_deg_e.value,
                       c.ordinary.rise_fall_angle_asymmetry_deg_e.stderr) for c in cals])
    tables = [c.corrections for c in cals]
    for x in SENSORS:
        add(f"installation {x}",
            [(t.installation_offset_deg_e[x], t.uncertainty["installation_offset_deg_e"].get(x)) for t in tables])
    if pole_pairs and all(len(t.pole_offset_deg_e) == 2 * pole_pairs for t in tables):
        for j in range(2 * pole_pairs):
            add(f"pole {j}", [(t.pole_offset_deg_e[j], t.uncertainty["pole_offset_deg_e"][j]) for t in tables])
    return rows, cals
