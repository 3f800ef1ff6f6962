"""Sage-Husa through the controller against the same filter offline (``hil paper table5 --closed-loop``).

The paper scenario (seven set points 5000-10,000 rpm, calibration downloaded, 3 us type III
jitter) runs in lockstep through the virtual controller on each link; the controller predicts
every commutation with its Sage-Husa filter and the plant scores each commutation against the
true rotor angle. The captured edges of the same run are then replayed offline (corrected with
the same tables and the currents the edges carried, with the cycle-mean currents the edge
messages carried, as the plant sent them) through a fresh Sage-Husa with the controller's
settings and model, and scored against the same truth (``Recording``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from bldc.contract import FILTER_COUNTERS, Strategy, edge_as_received, filter_vector, with_filter_vector
from bldc.motor import steady_state
from bldc.units import rpm_to_deg_e_per_s

from ..bench.lockstep import acceptance_max_step_s, make_bench, own_plant, rms
from ..calibration.campaign import station_corrections
from ..calibration.corrections import corrected_edge_times
from ..controller.adc import edge_currents
from ..controller.virtual import VirtualController
from ..dut.spec import open_dut
from ..predictors.model import MotorModel
from ..predictors.predictors import SageHusaPredictor, split_counters
from .table5 import SETPOINTS_RPM, scenario_plant

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


@dataclass
class Recording:
    """One closed-loop run of the paper scenario as a bench records it: the captured edges
    corrected with the downloaded tables and the currents the edges carried, the cycle-mean
    currents the edge messages carried (the predictor's input), and the plant's ground truth for
    the judged edges; with what the controller's own commutations scored. Offline, any predictor
    replays it and is scored like the closed loop."""

    seed: int
    #: the strategy that commutated while the edges were recorded ("SAGE_HUSA", "KF", ...)
    strategy: str
    t_corrected_s: np.ndarray
    cycle_current_a: np.ndarray
    #: edges whose prediction (made at edge k for edge k + 1) is judged: captured at or after the
    #: first set point's step, as the closed loop's commutations are
    judged: np.ndarray
    t_ideal_next_s: np.ndarray       #: ideal instant of edge k + 1, per judged k
    w_true_next_deg_e_s: np.ndarray  #: true electrical speed at edge k + 1, per judged k
    closed_loop_error_deg_e: np.ndarray
    counters: dict

    def replay(self, predictor) -> tuple[np.ndarray, dict[str, int]]:
        """The commutation angle error of ``predictor`` replaying the recorded edges (a fresh
        run), and its counters (``FILTER_COUNTERS``)."""
        run = predictor.run(self.t_corrected_s, self.cycle_current_a)
        return (run.pred_t_s[self.judged] - self.t_ideal_next_s) * self.w_true_next_deg_e_s, split_counters(run.guards)

    def replay_angle_rms_deg_e(self, predictor) -> float:
        return rms(self.replay(predictor)[0])

    def save(self, path) -> None:
        np.savez_compressed(path, **{k: np.asarray(v) for k, v in self.__dict__.items() if k != "counters"},
                            **{f"counter_{k}": v for k, v in self.counters.items()})

    @classmethod
    def load(cls, path) -> "Recording":
        """A recording written by ``save``; anything else is refused naming the file and what it lacks."""
        try:
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: not a closed-loop recording (.npz written by Recording.save): {exc}") from None
        counters = {k[len("counter_"):]: int(d.pop(k)) for k in list(d) if k.startswith("counter_")}
        fields = [f.name for f in dataclasses.fields(cls) if f.name != "counters"]
        missing = [name for name in fields if name not in d]
        if missing or set(d) - set(fields):
            raise ValueError(f"{path}: not a closed-loop recording: missing {missing or 'nothing'}, "
                             f"unknown {sorted(set(d) - set(fields)) or 'nothing'}")
        return cls(seed=int(d.pop("seed")), strategy=str(d.pop("strategy")), counters=counters, **d)


def as_carried(settings, design):
    """``design`` with the b, Q0, R0 and P0 of ``settings`` as a link carries them (IEEE single):
    what a controller whose own design is ``design`` runs after ``settings`` were written."""
    return with_filter_vector(design, [float(np.float32(v)) for v in filter_vector(settings)])


def commutation_time_mape_pct(error_deg_e: np.ndarray) -> float:
    """Commutation time error over the ideal commutation interval, (err / w) / (60 deg / w), in %."""
    return float(np.mean(np.abs(error_deg_e) / 60.0) * 100)


class _EdgeTap:
    """A link that passes everything through and keeps, for the offline replay, the currents the
    controller computes from each edge's ADC window with the applied table's delays: the edge's
    current (for the correction) and the cycle mean (the predictor's input). The experiment knows
    the table it downloaded; the bench itself gives the controller only the samples."""

    def __init__(self, link, corrections):
        self._link = link
        self._delay_s = corrections.as_float32().conditioning_delay_s
        self.current_a: list[float] = []
        self.cycle_current_a: list[float] = []

    def edge(self, edge: dict):
        seen = edge_currents(edge_as_received(edge, 0), self._delay_s["rise" if edge["rising"] else "fall"])
        self.current_a.append(seen.get("current_a", 0.0))
        # where no conversion fell in the cycle the controller falls back to the edge's current
        self.cycle_current_a.append(seen.get("cycle_current_a", self.current_a[-1]))
        return self._link.edge(edge)

    def __getattr__(self, name):
        return getattr(self._link, name)


def record_link(link, config, corrections, seed: int = 0, hold_s: float = HOLD_S,
                strategy: Strategy = Strategy.SAGE_HUSA, filter_settings=None,
                setpoints_rpm=SETPOINTS_RPM, settle_s: float = SETTLE_S, edge_jitter_s=None) -> Recording:
    """The scenario through ``link`` (a ControllerLink to a controller for ``config.motor``) with
    ``strategy`` commutating; ``filter_settings`` (b, Q0, R0, P0) written first when given;
    ``setpoints_rpm``: the operating profile (default: the paper's seven steps); ``edge_jitter_s``:
    the edges' jitter from each set point on (default: the plant's own throughout)."""

    link.reset()
    if filter_settings is not None:
        link.set_filter_settings(filter_settings)
    link.download_calibration(corrections)
    link.set_strategy(int(strategy))
    first = setpoints_rpm[0]
    # a firmware in the loop takes its edges on its own pins (hil.sil): no edge message to tap, so
    # the currents it computed at each edge are unknown and the offline replay's inputs are NaN
    tap = None if own_plant(link) is not None else _EdgeTap(link, corrections)
    bench = make_bench(
        config,
        tap or link,
        initial_speed_rpm=first,
        duty=steady_state(config.motor, first)["duty"],
        seed=seed,
        sim_options={"max_step_s": acceptance_max_step_s(config)},
    )
    steps = bench.run_setpoints(list(setpoints_rpm), hold_s=hold_s, settle_s=settle_s, edge_jitter_s=edge_jitter_s)
    c = bench.sim.commutations()
    status = link.status()
    edges = bench.sim.edges()
    # corrected with the currents the controller computed at each edge's own instant
    sent = np.asarray(tap.current_a[: len(edges)]) if tap is not None else np.full(len(edges), np.nan)
    t_corr = corrected_edge_times(edges.t_capture_s, edges.sensor, edges.rising, edges.pole, corrections, sent,
                                  config.motor.pole_pairs)
    k = np.nonzero(edges.t_capture_s[:-1] >= steps[0])[0]
    return Recording(
        seed=seed,
        strategy=Strategy(int(strategy)).name,
        t_corrected_s=t_corr,
        cycle_current_a=(np.asarray(tap.cycle_current_a[: len(edges)], dtype=float) if tap is not None
                         else np.full(len(edges), np.nan)),
        judged=k,
        t_ideal_next_s=edges.t_ideal_s[k + 1],
        w_true_next_deg_e_s=rpm_to_deg_e_per_s(edges.speed_rpm[k + 1], config.motor.pole_pairs),
        closed_loop_error_deg_e=c.error_deg_e[c.t_s >= steps[0]],
        counters={key: int(status[key]) for key in FILTER_COUNTERS},
    )


def run_link(link, config, corrections, seed: int = 0, hold_s: float = HOLD_S, filter_settings=None) -> LinkResult:
    """Sage-Husa through ``link``, and the same filter replaying the run's edges offline."""
    # the settings are written every time (a controller keeps the last ones written); the offline
    # filter gets them as the link carries them, in IEEE single precision
    # the link carries b, Q0, R0 and P0; the rest of the filter's design is the controller's own
    # (the virtual controller's, which this replay assumes)
    settings = filter_settings or VirtualController(config.motor).filter_settings
    r = record_link(link, config, corrections, seed, hold_s, Strategy.SAGE_HUSA, settings)
    settings = as_carried(settings, VirtualController(config.motor).filter_settings)
    offline = r.replay_angle_rms_deg_e(SageHusaPredictor(MotorModel.from_plant(config.motor), settings))
    return LinkResult(rms(r.closed_loop_error_deg_e), offline, r.counters["covariance_repairs"], r.counters,
                      int(r.closed_loop_error_deg_e.size))


def closed_loop(seed: int = 0, links=LINKS, hold_s: float = HOLD_S) -> ClosedLoopResult:
    config = scenario_plant()
    corrections = station_corrections(config, seed=seed)
    out = {}
    for name in links:
        with open_dut(f"virtual:{name}", config.motor) as dut:
            out[name] = run_link(dut.link, config, corrections, seed=seed, hold_s=hold_s)
    return ClosedLoopResult(out)
