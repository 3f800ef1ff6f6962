"""Sage-Husa through the controller against the same filter offline (``hil table5 --closed-loop``).

The paper scenario (seven set points 5000-10,000 rpm, calibration downloaded, 3 us type III
jitter) runs in lockstep through the virtual controller on each link; the controller predicts
every commutation with its Sage-Husa filter and the plant scores each commutation against the
true rotor angle. The captured edges of the same run are then replayed offline (corrected with
the same tables, cycle-mean currents from the sampled currents) through a fresh Sage-Husa with
the controller's settings and model, and scored against the same truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bldc.contract import Strategy, filter_vector, with_filter_vector
from bldc.motor import steady_state
from bldc.units import rpm_to_deg_e_per_s

from ..bench import ACCEPTANCE_MAX_STEP_S, LockstepBench, rms
from ..calibration.campaign import station_corrections
from ..calibration.corrections import corrected_edge_times
from ..controller.virtual import VirtualController
from ..dut.spec import open_dut
from ..predictors.model import MotorModel
from ..predictors.predictors import SageHusaPredictor
from .table5 import SETPOINTS_RPM, cycle_mean_currents, scenario_plant

LINKS = ("in-process", "canopen", "modbus")
HOLD_S = 0.4
SETTLE_S = 0.3


@dataclass
class LinkResult:
    sage_husa_angle_rms_deg_e: float
    offline_angle_rms_deg_e: float
    covariance_repairs: int
    counters: dict
    commutations: int


@dataclass
class ClosedLoopResult:
    links: dict[str, LinkResult]

    def to_json(self) -> dict:
        return {"links": {name: {"sage_husa_angle_rms_deg_e": r.sage_husa_angle_rms_deg_e,
                                 "offline_angle_rms_deg_e": r.offline_angle_rms_deg_e,
                                 "covariance_repairs": r.covariance_repairs} for name, r in self.links.items()}}

    def format(self) -> str:
        lines = ["commutation angle RMS (deg e) through the controller and in the offline replay; filter counters",
                 f"{'link':<12}{'commutations':>13}{'closed loop':>12}{'offline':>9}{'ratio':>7}"
                 f"{'gated':>7}{'repairs':>8}{'fades':>7}{'band':>7}"]
        for name, r in self.links.items():
            c = r.counters
            lines.append(f"{name:<12}{r.commutations:>13}{r.sage_husa_angle_rms_deg_e:>12.4f}{r.offline_angle_rms_deg_e:>9.4f}"
                         f"{r.sage_husa_angle_rms_deg_e / r.offline_angle_rms_deg_e:>7.3f}{c['gated_edges']:>7}"
                         f"{c['covariance_repairs']:>8}{c['divergence_fades']:>7}{c['band_projections']:>7}")
        return "\n".join(lines)


def run_link(link, config, corrections, seed: int = 0, hold_s: float = HOLD_S, filter_settings=None) -> LinkResult:
    """The scenario through ``link`` (a ControllerLink to a controller for ``config.motor``)."""

    link.reset()
    # the settings are written every time (a controller keeps the last ones written); the offline
    # filter gets them as the link carries them, in IEEE single precision
    # the link carries b, Q0, R0 and P0; the rest of the filter's design is the controller's own
    # (the virtual controller's, which this replay assumes)
    settings = filter_settings or VirtualController(config.motor).filter_settings
    link.set_filter_settings(settings)
    settings = with_filter_vector(VirtualController(config.motor).filter_settings,
                                  [float(np.float32(v)) for v in filter_vector(settings)])
    link.download_calibration(corrections)
    link.set_strategy(int(Strategy.SAGE_HUSA))
    first = SETPOINTS_RPM[0]
    bench = LockstepBench(
        config,
        link,
        initial_speed_rpm=first,
        duty=steady_state(config.motor, first)["duty"],
        seed=seed,
        sim_options={"max_step_s": ACCEPTANCE_MAX_STEP_S},
    )
    steps = bench.run_setpoints(list(SETPOINTS_RPM), hold_s=hold_s, settle_s=SETTLE_S)
    c = bench.sim.commutations()
    closed = c.error_deg_e[c.t_s >= steps[0]]
    status = link.status()
    # offline: the same edges, corrected with the same tables, through a fresh filter
    edges = bench.sim.edges()
    cycle_current = cycle_mean_currents(bench.sim.samples(), edges)
    # corrected with the currents the edges carried to the controller (each at the edge's instant)
    sent = np.asarray(bench.source.edge_currents_a[: len(edges)])
    t_corr = corrected_edge_times(edges.t_capture_s, edges.sensor, edges.rising, edges.pole, corrections, sent,
                                  config.motor.pole_pairs)
    run = SageHusaPredictor(MotorModel.from_plant(config.motor), settings).run(t_corr, cycle_current)
    k = np.nonzero(edges.t_capture_s[:-1] >= steps[0])[0]
    w_true = rpm_to_deg_e_per_s(edges.speed_rpm[k + 1], config.motor.pole_pairs)
    offline = (run.pred_t_s[k] - edges.t_ideal_s[k + 1]) * w_true
    counters = {
        key: int(status[key]) for key in ("gated_edges", "covariance_repairs", "divergence_fades", "band_projections")
    }
    return LinkResult(rms(closed), rms(offline), counters["covariance_repairs"], counters, int(closed.size))


def closed_loop(seed: int = 0, links=LINKS, hold_s: float = HOLD_S) -> ClosedLoopResult:
    config = scenario_plant()
    corrections = station_corrections(config, seed=seed)
    out = {}
    for name in links:
        with open_dut(f"virtual:{name}", config.motor) as dut:
            out[name] = run_link(dut.link, config, corrections, seed=seed, hold_s=hold_s)
    return ClosedLoopResult(out)
