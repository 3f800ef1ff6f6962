"""Every commutation predictor, declared once: its name, class, how it is built from its settings,
whether it runs on the motor model (and so has a kinematic form for recordings without current
or motor data), the controller strategy that runs it, and the tuning space searched for it.

``hil predictors compare``, the tuning (``tools/predictor_tuning.py``, ``hil.experiments.peers``)
and the docs take names, classes and spaces from here; the tuned settings and their provenance
are written by the tuning into ``hil.predictors.peer_settings`` (``TUNED[name]``,
``TUNED["kinematic"][name]``, ``PROVENANCE``). A new predictor is one entry here, its class, and
its search in ``hil.experiments.peers.tune``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .model import MotorModel
from .peers import MovingAveragePredictor, PllPredictor, SectorHoldPredictor, VbAkfPredictor
from .predictors import FilterSettings, KalmanPredictor, SageHusaPredictor

#: the kinematic form of the model-based filters (no current, no motor data): K_T = 1, J = 1, one
#: pole pair, no load, so the third state is the acceleration (rad/s^2 e); the current channel
#: carries 0 with this variance (A^2 = (rad/s^2)^2), so it says nothing of the acceleration
KINEMATIC_MODEL = MotorModel(1, 1.0, (1.0,), (0.0,))
KINEMATIC_R_I = 1e12

#: the tuning spaces (what ``hil.experiments.peers.tune`` searches; the filters' grids are
#: ``hil.experiments.compare.KF_GRID`` and its Sage-Husa design; each refinement is
#: ``compare.REFINE_EVALUATIONS`` Nelder-Mead evaluations)
MA_FIFO_GRID = tuple(range(1, 145))
PLL_BW_GRID_RAD_S = tuple(float(v) for v in np.geomspace(10.0, 2e4, 144))
VB_ITERATIONS = (2, 10)
VB_R_THETA = (1e-5, 1e-3)
VB_TAU = (1.0, 10.0)
VB_ONE_MINUS_RHO = (math.exp(-4.0), 1e-3)


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
class PredictorEntry:
    name: str
    cls: type
    #: (settings, model, kinematic) -> a predictor with ``run(t_s, current_a)``
    make: Callable[[dict, MotorModel, bool], object]
    model_based: bool  #: runs on the motor model (J, K_T, load): has a kinematic form
    #: the controller strategy (``bldc.contract.Strategy`` name) that runs it, if any (RAW and
    #: CORRECTED commutate at the edges themselves, no predictor)
    strategy: str | None
    tuning_space: str  #: what the tuning searches (the budget stated in ``PROVENANCE``)


PREDICTORS: dict[str, PredictorEntry] = {
    e.name: e
    for e in (
        PredictorEntry("sector_hold", SectorHoldPredictor, lambda s, m, k: SectorHoldPredictor(), False, None,
                       "no setting"),
        PredictorEntry("moving_average", MovingAveragePredictor,
                       lambda s, m, k: MovingAveragePredictor(int(s["fifo_edges"])), False, None,
                       f"FIFO length {MA_FIFO_GRID[0]}-{MA_FIFO_GRID[-1]} edges, exhaustive "
                       f"({len(MA_FIFO_GRID)} evaluations)"),
        PredictorEntry("pll", PllPredictor,
                       lambda s, m, k: PllPredictor(float(s["bandwidth_rad_s"]), bool(s["two_edge"])), False, None,
                       f"bandwidth on a {len(PLL_BW_GRID_RAD_S)}-point log grid {PLL_BW_GRID_RAD_S[0]:g}-"
                       f"{PLL_BW_GRID_RAD_S[-1]:g} rad/s + Nelder-Mead refinement, two-edge option off and on"),
        PredictorEntry("kf", KalmanPredictor, _filter(KalmanPredictor), True, "KF",
                       "Q_w, Q_i, R_theta, R_i on a 144-point grid + Nelder-Mead refinement, gate off and on "
                       "(compare.tune_kf)"),
        PredictorEntry("sage_husa", SageHusaPredictor, _filter(SageHusaPredictor), True, "SAGE_HUSA",
                       "nominal Q_w, Q_i, b, b_R, R0_i on a 144-point grid + Nelder-Mead refinement, design "
                       "compare.SH_DESIGN (compare.tune_sh)"),
        PredictorEntry("vb_akf", VbAkfPredictor, _vb_akf, True, None,
                       "nominal Q_w, Q_i, R_theta, tau, 1 - rho on a 144-point grid + Nelder-Mead refinement, "
                       f"{' and '.join(map(str, VB_ITERATIONS))} variational iterations"),
    )
}
NAMES = tuple(PREDICTORS)
MODEL_BASED = tuple(n for n, e in PREDICTORS.items() if e.model_based)


def build(name: str, settings: dict, model: MotorModel, kinematic: bool = False):
    """The predictor ``name`` with ``settings`` (as ``peer_settings.TUNED`` holds them) on
    ``model``; ``kinematic``: a model-based filter without current or motor data (``KINEMATIC_MODEL``)."""
    if name not in PREDICTORS:
        raise ValueError(f"unknown predictor {name!r}; one of {', '.join(NAMES)}")
    entry = PREDICTORS[name]
    kinematic = kinematic and entry.model_based
    return entry.make(settings, KINEMATIC_MODEL if kinematic else model, kinematic)


def rebuilt(predictor, model: MotorModel, kinematic: bool = False):
    """The same predictor with the same settings on another model (a tuning objective over pumps)."""
    entry = next((e for e in PREDICTORS.values() if type(predictor) is e.cls), None)
    if entry is None or not entry.model_based:
        return predictor
    return build(entry.name, settings_of(predictor), model, kinematic)
