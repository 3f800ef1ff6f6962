"""The lockstep bench: plant and controller advance together in virtual time.

Every captured edge goes to the controller through its link at the plant instant the capture
interrupt would fire; the commands that come back are scheduled on the plant. Results do not
depend on the host's speed, only on the plant, the controller and the scenario.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bldc.contract import Command
from plant_models import PlantConfig, Simulation

from .dut.link import ControllerLink

#: plant step bound of acceptance runs: the armature reaction follows the instantaneous current,
#: which moves fast right after a commutation, and a coarser step would blur it
ACCEPTANCE_MAX_STEP_S = 2e-6


def p99_abs(values) -> float:
    """99th percentile of |values| (the budgets' p99)."""
    return float(np.percentile(np.abs(values), 99))


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


class LinkSource:
    """Adapts a ControllerLink to the plant's commutation-source interface."""

    def __init__(self, link: ControllerLink):
        self.link = link
        self.edges = 0
        self._sample_from = 0
        #: the current each edge carried to the controller, in order (an offline replay of the
        #: same edges gets the same inputs)
        self.edge_currents_a: list[float] = []

    def _cycle_mean_current_a(self, sim) -> float | None:
        """Mean |i| over the phases and the plant samples since the last edge, through the current
        sensors' gain and offset: what the controller's ADC averages over the commutation cycle
        (the current Eq. 8's K_T is defined for). None when no sample fell in the cycle."""
        start, self._sample_from = self._sample_from, sim.samples_taken
        return sim.measured_mean_abs_current_since_a(start)

    def on_edge(self, edge: dict, sim) -> list:
        """The controller answers in its own capture-timer time; a command for an instant that has
        already passed on the plant (the capture stamp precedes the interrupt) applies now."""
        self.edges += 1
        edge["cycle_current_a"] = self._cycle_mean_current_a(sim)
        table = getattr(self.link, "applied_calibration", None)
        if table is not None:
            # the edge's current at its own instant: the MCU's ADC ring read one applied
            # conditioning delay before the capture, where the armature field that moved the edge
            # acted (bldc.contract, EdgeMessage)
            delay = table.conditioning_delay_s["rise" if edge["rising"] else "fall"]
            edge["current_a"] = sim.measured_mean_abs_current_at_a(edge["t_capture_s"] - delay)
        self.edge_currents_a.append(edge["current_a"])
        now = sim.t_s
        return [c if c.at_s >= now else Command(now, c.sector, c.duty, c.direction) for c in self.link.edge(edge)]


@dataclass
class LockstepBench:
    config: PlantConfig
    link: ControllerLink
    initial_speed_rpm: float = 5000.0
    duty: float = 0.3
    seed: int = 0
    sample_rate_hz: float = 50e3
    #: further Simulation options (max_step_s, ...)
    sim_options: dict = field(default_factory=dict)
    sim: Simulation = field(init=False)

    def __post_init__(self):
        self.source = LinkSource(self.link)
        self.sim = Simulation(
            self.config,
            self.source,
            duty=self.duty,
            initial_speed_rpm=self.initial_speed_rpm,
            seed=self.seed,
            sample_rate_hz=self.sample_rate_hz,
            capacity=1 << 18,
            **self.sim_options,
        )

    def angle_errors_deg_e(self, since_s: float = 0.0):
        """Commutation angle error (deg electrical, + = late) of every commutation from ``since_s``,
        against the plant's true rotor angle."""
        c = self.sim.commutations()
        return c.error_deg_e[c.t_s >= since_s]

    def run_setpoints(self, setpoints_rpm, hold_s: float, settle_s: float = 0.5) -> list[float]:
        """Hold each set point for ``hold_s`` after ``settle_s`` at the first; returns the step instants."""
        self.link.set_speed(setpoints_rpm[0])
        self.sim.run_until(self.sim.t_s + settle_s)
        steps = []
        for rpm in setpoints_rpm:
            steps.append(self.sim.t_s)
            self.link.set_speed(rpm)
            self.sim.run_until(steps[-1] + hold_s)
        return steps
