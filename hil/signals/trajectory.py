"""The imposed rotor trajectory of a stimulus: a piecewise-linear speed profile, forward rotation.

Speed is linear in time between breakpoints, so the electrical angle is an exact quadratic in
each segment (the same law the kinematic plant mode uses), and the instant the rotor reaches
any angle is an exact root.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bldc.units import deg_e_per_s_to_rpm, rpm_to_deg_e_per_s

from ..recording.errors import SignalError


def parse_profile(text: str) -> list[tuple[float, float]]:
    """``"t:rpm,t:rpm,..."`` -> breakpoints (seconds, rpm), strictly increasing times from 0."""
    points = []
    for i, item in enumerate(p for p in text.split(",") if p.strip()):
        try:
            t, rpm = (float(v) for v in item.split(":"))
        except ValueError:
            raise SignalError(f"--profile item {i + 1}", f"{item.strip()!r} is not t:rpm") from None
        if not (math.isfinite(t) and math.isfinite(rpm)) or rpm < 0:
            raise SignalError(
                f"--profile item {i + 1}", f"{item.strip()!r}: time and speed must be finite, speed >= 0 rpm"
            )
        if points and t <= points[-1][0]:
            raise SignalError(f"--profile item {i + 1}", f"time {t} s does not increase (previous {points[-1][0]} s)")
        points.append((t, rpm))
    if not points:
        raise SignalError("--profile", "empty profile")
    if points[0][0] != 0.0:
        raise SignalError("--profile item 1", f"the profile starts at t = 0, got {points[0][0]} s")
    return points


@dataclass
class Trajectory:
    """Speed breakpoints (s, rpm) extended to ``duration_s`` at the last speed."""

    breakpoints: list[tuple[float, float]]
    duration_s: float
    pole_pairs: int
    start_angle_deg_e: float = 30.0

    def __post_init__(self):
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise SignalError("--duration-s", f"must be > 0 s, got {self.duration_s!r}")
        pts = [p for p in self.breakpoints if p[0] < self.duration_s]
        last_rpm = float(np.interp(self.duration_s, [p[0] for p in self.breakpoints], [p[1] for p in self.breakpoints]))
        pts.append((self.duration_s, last_rpm))
        t = np.array([p[0] for p in pts])
        w = rpm_to_deg_e_per_s(np.array([p[1] for p in pts]), self.pole_pairs)  # deg_e / s
        self.t0 = t[:-1]
        self.t1 = t[1:]
        self.w0 = w[:-1]
        self.w1 = w[1:]
        self.acc = (self.w1 - self.w0) / (self.t1 - self.t0)
        travel = self.w0 * (self.t1 - self.t0) + 0.5 * self.acc * (self.t1 - self.t0) ** 2
        self.theta0 = self.start_angle_deg_e + np.concatenate([[0.0], np.cumsum(travel)[:-1]])
        self.theta_end = float(self.start_angle_deg_e + travel.sum())

    def _segment(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, self.t0.size - 1)

    def angle_deg_e(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        i = self._segment(t)
        dt = t - self.t0[i]
        return self.theta0[i] + self.w0[i] * dt + 0.5 * self.acc[i] * dt * dt

    def speed_rpm(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        i = self._segment(t)
        return deg_e_per_s_to_rpm(self.w0[i] + self.acc[i] * (t - self.t0[i]), self.pole_pairs)

    def time_at_deg_e(self, theta_deg_e) -> np.ndarray:
        """First instant the rotor reaches each angle (angles within the trajectory)."""
        th = np.asarray(theta_deg_e, dtype=float)
        # the segment that ends at or after th: skip standstill segments that only touch it
        i = np.clip(np.searchsorted(self.theta0 + self._travel(), th, side="left"), 0, self.t0.size - 1)
        d = np.maximum(th - self.theta0[i], 0.0)
        w0, a = self.w0[i], self.acc[i]
        root = np.sqrt(np.maximum(w0 * w0 + 2.0 * a * d, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            dt = np.where(d > 0, 2.0 * d / (w0 + root), 0.0)  # the stable root of w0 dt + a dt^2 / 2 = d
        return self.t0[i] + dt

    def _travel(self) -> np.ndarray:
        h = self.t1 - self.t0
        return self.w0 * h + 0.5 * self.acc * h * h

    def pieces(self, ta: float, tb: float):
        """(start, end, start rpm, end rpm) of the linear pieces covering [ta, tb)."""
        cuts = np.concatenate([[ta], self.t0[(self.t0 > ta) & (self.t0 < tb)], [tb]])
        rpm = self.speed_rpm(cuts)
        # the speed at a breakpoint from the left may differ only if the profile jumps; it does not
        return [
            (
                float(cuts[k]),
                float(cuts[k + 1]),
                float(rpm[k]),
                float(self.speed_rpm(np.nextafter(cuts[k + 1], cuts[k]))),
            )
            for k in range(cuts.size - 1)
            if cuts[k + 1] > cuts[k]
        ]
