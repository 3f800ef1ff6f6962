"""The lockstep bench: plant and controller advance together in virtual time.

Every captured edge goes to the controller through its link at the plant instant the capture
interrupt would fire; the commands that come back are scheduled on the plant. Results do not
depend on the host's speed, only on the plant, the controller and the scenario.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bldc.contract import ADC_PERIOD_S, MAX_ADC_SAMPLES, MAX_CONDITIONING_DELAY_S, Command
from bldc.motor import MotorParameters
from plant_models import PlantConfig, Simulation

from ..dut.link import ControllerLink

#: plant step bound of acceptance runs: the armature reaction follows the instantaneous current,
#: which moves fast right after a commutation, and a coarser step would blur it
ACCEPTANCE_MAX_STEP_S = 2e-6


def acceptance_max_step_s(config: PlantConfig) -> float:
    """``ACCEPTANCE_MAX_STEP_S`` on the paper pump. On a motor whose currents move slower (its
    electrical time constant L/R longer, and its top electrical frequency lower, as on a motor
    ``bldc.motor.rewound`` for a lower top speed), as many steps per electrical period and per time
    constant: stretched by the smaller of the two ratios, never shortened."""
    paper = MotorParameters()
    slower_currents = (config.motor.phase_inductance_h / config.motor.phase_resistance_ohm) / (
        paper.phase_inductance_h / paper.phase_resistance_ohm
    )
    return ACCEPTANCE_MAX_STEP_S * max(1.0, min(config.suite_time_scale, slower_currents))


def p99_abs(values) -> float:
    """99th percentile of |values| (the budgets' p99)."""
    return float(np.percentile(np.abs(values), 99))


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def adc_reach_s(link: ControllerLink | None) -> float:
    """How far before a capture the controller may read its ADC, so how far back an edge's window
    reaches: what its profile declares (``[edge_hook] adc_reach_s``), else the largest conditioning
    delay of the table the framework downloaded to it, else the edge message's bound (a table the
    framework did not download may hold any delay). docs/controller.md, "The bus"."""
    profile = getattr(link, "profile", None)
    declared = profile.edge_hook.adc_reach_s if profile is not None else None
    if declared is not None:
        return declared
    table = getattr(link, "applied_calibration", None)
    return max(table.conditioning_delay_s.values()) if table is not None else MAX_CONDITIONING_DELAY_S


class LinkSource:
    """Adapts a ControllerLink to the plant's commutation-source interface.

    Each edge goes to the controller with what its own peripherals hold at the capture: the
    capture stamp and pin level, and the ADC window of its phase-current sensors' outputs
    (``bldc.contract.EdgeMessage``). The bench computes no current for the controller and reads
    nothing back from it: the controller computes the edge's and the cycle's currents itself."""

    def __init__(self, link: ControllerLink):
        self.link = link
        self.edges = 0
        self._cycle_first_sample = 0  #: the first plant sample after the previous capture

    def on_edge(self, edge: dict, sim) -> list:
        """The controller answers in its own capture-timer time; a command for an instant that has
        already passed on the plant (the capture stamp precedes the interrupt) applies now."""
        self.edges += 1
        self.with_adc(edge, sim)
        now = sim.t_s
        return [c if c.at_s >= now else Command(now, c.sector, c.duty, c.direction) for c in self.link.edge(edge)]

    def with_adc(self, edge: dict, sim) -> dict:
        """``edge`` as the controller's peripherals hold it at the capture: the stamp and pin level,
        the ADC's window (the conversion the capture triggers and the newest periodic ones) and the
        conversions accumulated
        since the previous capture (one per plant sample); the plant's own current taken out."""
        t = edge["t_capture_s"]
        edge.pop("current_a", None)  # the plant's present current: not the controller's to have
        # the periodic conversions (every ADC_PERIOD_S from t = 0) up to the capture, back to one
        # beyond the controller's reach (the capture stamp it rebuilds its window from is rounded
        # to a tick), and the one the capture triggers
        newest = math.floor(t / ADC_PERIOD_S + 1e-9)
        oldest = math.floor((t - adc_reach_s(self.link)) / ADC_PERIOD_S) - 1
        grid = np.arange(max(oldest, newest - MAX_ADC_SAMPLES + 2, 0), newest + 1) * ADC_PERIOD_S
        converted = sim.adc_conversions_at(np.append(grid, t))
        edge["adc_t_s"], edge["adc_phase_currents_a"] = grid, converted[:-1]
        edge["capture_phase_currents_a"] = converted[-1]
        cycle = sim.sensed_samples_since(self._cycle_first_sample, t)
        edge["adc_cycle_phase_currents_a"] = cycle
        self._cycle_first_sample += cycle.shape[0]
        return edge


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
        own = own_plant(self.link)
        if own is not None:  # a firmware in the loop runs the plant beside its peripherals (hil.sil)
            factory, wiring = own
            self.source = None
            self.sim = factory(self.config, self.seed, wiring=wiring, duty=self.duty,
                               initial_speed_rpm=self.initial_speed_rpm, sample_rate_hz=self.sample_rate_hz,
                               capacity=1 << 18, **self.sim_options)
            return
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

    def run_setpoints(self, setpoints_rpm, hold_s: float, settle_s: float = 0.5,
                      edge_jitter_s=None) -> list[float]:
        """Hold each set point for ``hold_s`` after ``settle_s`` at the first; returns the step instants.
        ``edge_jitter_s``, one per set point, sets the plant's Hall edge time jitter (s RMS) as each
        set point begins (the settling keeps the plant's own)."""
        if edge_jitter_s is not None and len(edge_jitter_s) != len(setpoints_rpm):
            raise ValueError(f"edge_jitter_s: {len(edge_jitter_s)} values for {len(setpoints_rpm)} set points")
        self.link.set_speed(setpoints_rpm[0])
        self.sim.run_until(self.sim.t_s + settle_s)
        steps = []
        for k, rpm in enumerate(setpoints_rpm):
            steps.append(self.sim.t_s)
            if edge_jitter_s is not None:
                self.sim.set_edge_jitter(edge_jitter_s[k])
            self.link.set_speed(rpm)
            self.sim.run_until(steps[-1] + hold_s)
        return steps



def own_plant(link):
    """(the link's plant factory, the wiring faults' injector or None) when ``link`` runs the plant
    itself (a firmware in the loop: ``hil.sil``; its ``simulation(config, seed, wiring=..., **sim
    options)``), possibly inside a ``hil.dut.faults.FaultInjector``, whose faults then act on the
    firmware's pins; None when the bench sends the link every edge."""
    wrapped = getattr(link, "mirror", False) is not False and getattr(link, "link", None)
    if wrapped and callable(getattr(wrapped, "simulation", None)):
        return wrapped.simulation, link
    own = getattr(link, "simulation", None)
    return (own, None) if callable(own) else None


def make_bench(config: PlantConfig, link, **kwargs) -> LockstepBench:
    """The bench for ``link`` (kept as the one place a suite makes one)."""
    return LockstepBench(config, link, **kwargs)
