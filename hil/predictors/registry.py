"""Every commutation predictor, declared once: its name, class, how it is built from its settings,
whether it runs on the motor model (and so has a kinematic form for recordings without current
or motor data), the controller strategy that runs it, and the tuning space searched for it (data:
its axes, their grids and options, and how a point becomes settings).

``hil predictors compare``, the tuning (``tools/predictor_tuning.py``, ``hil.experiments.peers``),
the virtual controller (``hil.controller.virtual``: the entry whose ``strategy`` it runs) and the
docs take names, classes and spaces from here; the tuned settings and their provenance are
written by the tuning into ``hil.predictors.peer_settings`` (``TUNED[name]``,
``TUNED["kinematic"][name]``, ``PROVENANCE``). A new predictor is one entry here (and its class);
the tuning's one search (``hil.experiments.peers.tune``) reads its space.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from . import filters as F
from .model import MotorModel
from .peers import MovingAveragePredictor, PllPredictor, SectorHoldPredictor, VbAkfPredictor
from .predictors import FilterSettings, KalmanPredictor, SageHusaPredictor

#: the kinematic form of the model-based filters (no current, no motor data): K_T = 1, J = 1, one
#: pole pair, no load, so the third state is the acceleration (rad/s^2 e); the current channel
#: carries 0 with this variance (A^2 = (rad/s^2)^2), so it says nothing of the acceleration
KINEMATIC_MODEL = MotorModel(1, 1.0, (1.0,), (0.0,))
KINEMATIC_R_I = 1e12

#: the tuning spaces' grids (what ``hil.experiments.peers.tune`` searches, each refinement
#: ``compare.REFINE_EVALUATIONS`` Nelder-Mead evaluations; the filters' grids serve the paper
#: protocols of ``hil.experiments.compare`` as well)
MA_FIFO_GRID = tuple(range(1, 145))
PLL_BW_GRID_RAD_S = tuple(float(v) for v in np.geomspace(10.0, 2e4, 144))
VB_ITERATIONS = (2, 10)
VB_R_THETA = (1e-5, 1e-3)
VB_TAU = (1.0, 10.0)
VB_ONE_MINUS_RHO = (math.exp(-4.0), 1e-3)

#: Sage-Husa's own design outside the paper protocol: R every 30 edges (a burst of 0.4 s holds
#: about 20 such intervals at 5000-10,000 rpm), Q band x100 around its start. Q_w is steered by
#: innovation whiteness every 60 edges (``filters.ADAPT_Q_WHITE``) and Q_i by Eq. 12: a one-step
#: innovation carries almost nothing of Q_w (dt^2 Q_w is about 1/200 of R_theta), so its Eq. 12
#: recursion falls to the band floor where no process noise is, and the filter then cannot follow
#: a load its model has wrong (1000 drawn conditions within 1.05 x KF + 0.01 deg e: 90.9 % with
#: Eq. 12 on Q_w, 95.6 % with whiteness; docs/sage-husa.md, Robustness). R's current entry never
#: below its R0 (``filters.ADAPT_R_CURRENT_FLOOR``): it stands for the acceleration input's error
#: as well as the sensor's noise, which is all Eq. 12 learns (``tuned``: -4.0 % angle RMS with
#: R_i free, +3.0 % floored at its tuned R0; robustness 96.0 %)
SH_DESIGN = dict(
    adapt_mask=F.ADAPT_R | F.ADAPT_Q_WHITE | F.ADAPT_Q_CURRENT | F.ADAPT_R_CURRENT_FLOOR,
    adapt_interval=60,
    r_interval=30,
    r_forgetting_b=0.9,
    forgetting_b=0.98,
    q_band_factor=100.0,
)

#: coarse grids (log-spaced) from which both filters' refinement starts: 144 points each
KF_GRID = dict(
    q_w=(1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0), q_i=(1e-5, 1e-3, 1e-1), r_theta=(1e-6, 1e-5, 1e-4, 1e-3), r_i=(1e-2, 1.0)
)
SH_GRID = dict(q_w=KF_GRID["q_w"], q_i=KF_GRID["q_i"], one_minus_b=(0.02, 0.005), one_minus_b_r=(0.7, 0.1),
               r_i=KF_GRID["r_i"])

#: Q's forgetting factor within the usual 0.95 (docs/sage-husa.md) and a memory of 10,000 cycles; R's per interval
B_RANGE = (0.95, 0.9999)
B_R_RANGE = (0.05, 0.999)
#: R's interval where a search has it: a tenth of the paper's 120 edges to twice it
R_INTERVAL_RANGE = (12, 240)

def sh_settings(design: dict, point: dict[str, float]) -> FilterSettings:
    """Sage-Husa's settings at one point of a search: ``design`` with the nominal Q_w and Q_i, the
    forgetting factors of Q and R (as 1 - b, clipped to their ranges) and, where the search has
    it, R's interval (rounded to whole edges, clipped to R_INTERVAL_RANGE) and R's current entry."""
    extra = {}
    if "r_i" in point:  # R0's current entry, for a design that floors R_i there (filters.ADAPT_R_CURRENT_FLOOR)
        extra["r0_diag"] = (design.get("r0_diag", FilterSettings().r0_diag)[0], point["r_i"])
    if "r_interval" in point:
        extra["r_interval"] = min(max(int(round(point["r_interval"])), R_INTERVAL_RANGE[0]), R_INTERVAL_RANGE[1])
    return FilterSettings(**{**design, "q0_diag": (point["q_w"], 1e-9, point["q_i"]),
                             "forgetting_b": min(max(1.0 - point["one_minus_b"], B_RANGE[0]), B_RANGE[1]),
                             "r_forgetting_b": min(max(1.0 - point["one_minus_b_r"], B_R_RANGE[0]), B_R_RANGE[1]),
                             **extra})


def filter_settings(d: dict) -> FilterSettings:
    """``FilterSettings`` from a settings dict (lists as tuples; unknown keys ignored)."""
    fields = {f.name for f in dataclasses.fields(FilterSettings)}
    return FilterSettings(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in fields})


#: significant digits the tuned filter values are rounded to before they become the controller's
#: defaults (and before a closed-loop candidate is evaluated, so what is evaluated is what the
#: defaults are)
DIGITS = 2


def _round(v: float, digits: int = DIGITS) -> float:
    return float(f"{v:.{digits}g}")


def rounded(s: FilterSettings) -> FilterSettings:
    """The settings with Q0, R0 and the forgetting factors' distance from 1 to DIGITS digits."""
    return dataclasses.replace(
        s,
        q0_diag=tuple(_round(v) for v in s.q0_diag),
        r0_diag=tuple(_round(v) for v in s.r0_diag),
        forgetting_b=1.0 - _round(1.0 - s.forgetting_b),
        r_forgetting_b=1.0 - _round(1.0 - s.r_forgetting_b),
    )


def pump_defaults() -> tuple[FilterSettings, FilterSettings]:
    """The controller's Sage-Husa and KF settings: the training-pump tuning shipped in
    ``peer_settings.TUNED`` (no scenario seed of the controller's plant was seen), rounded to
    DIGITS significant digits. Read from that file, never copied: a rerun of the tuning moves them."""
    from .peer_settings import TUNED

    return rounded(filter_settings(TUNED["sage_husa"])), rounded(filter_settings(TUNED["kf"]))


def settings_of(predictor) -> dict:
    """A predictor's settings as ``peer_settings.TUNED`` holds them."""
    if isinstance(predictor, (KalmanPredictor, SageHusaPredictor)):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(predictor.settings).items()}
    return predictor.settings


def _filter(cls):
    def make(settings: dict, model: MotorModel, kinematic: bool):
        s = filter_settings(settings)
        if kinematic:
            s = dataclasses.replace(s, r0_diag=(s.r0_diag[0], KINEMATIC_R_I))
        return cls(model, s)

    return make


def _vb_akf(settings: dict, model: MotorModel, kinematic: bool):
    kw = {k: settings[k] for k in ("q0_diag", "r0_diag", "tau", "rho", "iterations")}
    return VbAkfPredictor(model, **kw, use_current=not kinematic)


@dataclass(frozen=True)
class Axis:
    """One searched setting: the coarse grid the search scores, then (``refine``) Nelder-Mead in
    log10 from the grid's best points (``hil.experiments.compare._grid_then_refine``); without
    ``refine`` the grid is the whole search (exhaustive: whole numbers)."""

    grid: tuple[float, ...]
    refine: bool = True

    def __post_init__(self):
        if not self.grid:
            raise ValueError("an Axis needs at least one grid point")


@dataclass(frozen=True)
class TuningSpace:
    """What the tuning searches for one predictor, as data: its axes (name -> Axis), its discrete
    options (name -> values, each value searched over the axes in turn, the best kept), and how a
    point becomes the settings ``PredictorEntry.make`` reads (``settings(point, options)``)."""

    settings: Callable[[dict, dict], dict]
    axes: Mapping[str, Axis] = field(default_factory=dict)
    options: Mapping[str, tuple] = field(default_factory=dict)

    def __post_init__(self):
        refine = {a.refine for a in self.axes.values()}
        if len(refine) > 1:
            raise ValueError(f"axes {', '.join(self.axes)}: all refined or all exhaustive, not mixed")

    @property
    def exhaustive(self) -> bool:
        return not any(a.refine for a in self.axes.values())

    @property
    def grid(self) -> dict[str, tuple[float, ...]]:
        return {k: a.grid for k, a in self.axes.items()}

    def option_sets(self) -> list[dict]:
        """Every combination of the options (one empty set when there are none)."""
        return [dict(zip(self.options, v)) for v in itertools.product(*self.options.values())]

    def point(self, x) -> dict:
        """A search vector as the axes name it."""
        return dict(zip(self.axes, x))

    def describe(self) -> str:
        """The search in one sentence (``PROVENANCE["budgets"]``)."""
        if not self.axes:
            return "no setting"
        n = math.prod(len(a.grid) for a in self.axes.values())
        axes = ", ".join(f"{k} {min(a.grid):g}-{max(a.grid):g}" for k, a in self.axes.items())
        how = "exhaustive" if self.exhaustive else "+ Nelder-Mead refinement (log10)"
        opts = "".join(f"; each of {k} = {', '.join(map(str, v))}" for k, v in self.options.items())
        return f"{axes} on a {n}-point grid, {how}{opts}"


def _as_dict(s: FilterSettings) -> dict:
    """FilterSettings as ``peer_settings.TUNED`` holds them (lists for tuples)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(s).items()}


def _kf_point(p: dict, o: dict) -> dict:
    return _as_dict(FilterSettings(q0_diag=(p["q_w"], 1e-9, p["q_i"]), r0_diag=(p["r_theta"], p["r_i"]),
                                   gate_state_update=o["gate_state_update"]))


def _vb_point(p: dict, o: dict) -> dict:
    return {"q0_diag": (p["q_w"], 1e-9, p["q_i"]), "r0_diag": (p["r_theta"], KF_GRID["r_i"][1]), "tau": p["tau"],
            "rho": 1.0 - min(p["one_minus_rho"], 0.5), "iterations": o["iterations"]}


def _refined(grid: dict[str, tuple[float, ...]]) -> dict[str, Axis]:
    return {k: Axis(tuple(v)) for k, v in grid.items()}


@dataclass(frozen=True)
class PredictorEntry:
    name: str
    cls: type
    #: (settings, model, kinematic) -> a predictor with ``run(t_s, current_a)``
    make: Callable[[dict, MotorModel, bool], object]
    model_based: bool  #: runs on the motor model (J, K_T, load): has a kinematic form
    #: the controller strategy (``bldc.contract.Strategy`` name) that runs it, if any (RAW and
    #: CORRECTED commutate at the edges themselves, no predictor); the virtual controller picks
    #: its predictor by this
    strategy: str | None
    tuning_space: TuningSpace  #: what the tuning searches (its sentence is stated in ``PROVENANCE``)


PREDICTORS: dict[str, PredictorEntry] = {
    e.name: e
    for e in (
        PredictorEntry("sector_hold", SectorHoldPredictor, lambda s, m, k: SectorHoldPredictor(), False, None,
                       TuningSpace(lambda p, o: {})),
        PredictorEntry("moving_average", MovingAveragePredictor,
                       lambda s, m, k: MovingAveragePredictor(int(s["fifo_edges"])), False, None,
                       TuningSpace(lambda p, o: {"fifo_edges": int(p["fifo_edges"])},
                                   {"fifo_edges": Axis(MA_FIFO_GRID, refine=False)})),
        PredictorEntry("pll", PllPredictor,
                       lambda s, m, k: PllPredictor(float(s["bandwidth_rad_s"]), bool(s["two_edge"])), False, None,
                       TuningSpace(lambda p, o: {"bandwidth_rad_s": min(max(p["bandwidth_rad_s"], 1.0), 1e5),
                                                 "two_edge": o["two_edge"]},
                                   {"bandwidth_rad_s": Axis(PLL_BW_GRID_RAD_S)}, {"two_edge": (False, True)})),
        PredictorEntry("kf", KalmanPredictor, _filter(KalmanPredictor), True, "KF",
                       TuningSpace(_kf_point, _refined(KF_GRID), {"gate_state_update": (False, True)})),
        PredictorEntry("sage_husa", SageHusaPredictor, _filter(SageHusaPredictor), True, "SAGE_HUSA",
                       TuningSpace(lambda p, o: _as_dict(sh_settings(SH_DESIGN, p)), _refined(SH_GRID))),
        PredictorEntry("vb_akf", VbAkfPredictor, _vb_akf, True, None,
                       TuningSpace(_vb_point, _refined(dict(q_w=KF_GRID["q_w"], q_i=KF_GRID["q_i"],
                                                            r_theta=VB_R_THETA, tau=VB_TAU,
                                                            one_minus_rho=VB_ONE_MINUS_RHO)),
                                   {"iterations": VB_ITERATIONS})),
    )
}


def for_strategy(strategy: str) -> PredictorEntry | None:
    """The predictor the controller strategy ``strategy`` (a ``bldc.contract.Strategy`` name) runs;
    None: the strategy commutates at the edges themselves."""
    return next((e for e in PREDICTORS.values() if e.strategy == strategy), None)


def build(name: str, settings: dict, model: MotorModel, kinematic: bool = False):
    """The predictor ``name`` with ``settings`` (as ``peer_settings.TUNED`` holds them) on
    ``model``; ``kinematic``: a model-based filter without current or motor data (``KINEMATIC_MODEL``)."""
    if name not in PREDICTORS:
        raise ValueError(f"unknown predictor {name!r}; one of {', '.join(PREDICTORS)}")
    entry = PREDICTORS[name]
    kinematic = kinematic and entry.model_based
    return entry.make(settings, KINEMATIC_MODEL if kinematic else model, kinematic)


def rebuilt(predictor, model: MotorModel, kinematic: bool = False):
    """The same predictor with the same settings on another model (a tuning objective over pumps)."""
    entry = next((e for e in PREDICTORS.values() if type(predictor) is e.cls), None)
    if entry is None or not entry.model_based:
        return predictor
    return build(entry.name, settings_of(predictor), model, kinematic)
