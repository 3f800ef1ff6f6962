"""Every commutation predictor on every scenario: the firmware peers (sector hold, moving
average, PLL), the KF, Sage-Husa and the VB-AKF (``hil predictors compare``, docs/sage-husa.md).

Scenarios:

* ``paper``: the paper's speed-step scenario (``table5.run_scenario``), seeds ``compare.EVAL_SEEDS``,
  truth from the plant;
* ``pumps``: pumps drawn from ``PUMP_RANGE`` (pole pairs, inertia and fan load around the paper
  bench, a speed-step profile inside 3,000-15,000 rpm, the effect library's Hall deviations), each
  calibrated by the calibration station, then run through the speed steps; truth from the plant;
  held-out seeds ``HELD_OUT_PUMP_SEEDS``, none of which any tuning saw;
* a recording (hil-recording/1): calibrated by the project's calibration
  (``hil.calibration.calibrate``, the one ``hil calibrate`` runs), scored on the second half of
  its longest run against the corrected edge instants (``compare_recording``).

Every predictor's settings come from ``peer_settings.TUNED``, written once by
``tools/predictor_tuning.py`` from a tuning on the training pumps ``TRAIN_PUMP_SEEDS``
(``tune``); ``compare`` only evaluates.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bldc.edges import electrical_speed_hz
from bldc.motor import steady_state
from plant_models import PlantConfig, paper_bench
from plant_models import effects as fx
from plant_models.plant import PAPER_BENCH_CIRCUIT

from ..calibration.campaign import station_corrections
from ..predictors.model import MotorModel
from ..predictors.predictors import FilterSettings, KalmanPredictor, split_counters
from ..predictors.registry import (
    KINEMATIC_MODEL,
    PREDICTORS,
    build,
    rebuilt,
    settings_of,
)
from . import compare
from .identify import identify
from .table5 import ScenarioRun, run_scenario, scenario_plant, score

#: the pumps' range: pole pairs, and inertia and fan load as factors of the paper bench's
PUMP_RANGE = dict(pole_pairs=(1, 4), inertia_factor=(0.3, 3.0), fan_factor=(0.5, 2.0), speed_rpm=(3000.0, 15000.0),
                  installation_offset_deg_e=(-3.0, 3.0), pole_offset_deg_e=(-2.0, 2.0),
                  conditioning_c1_factor=(0.5, 2.0), armature_slope_deg_e_per_a=(0.0, 0.5),
                  edge_jitter_time_rms_s=(1e-6, 5e-6), timer_tick_s=1e-7)
#: a pump's profile: this many set points, each held this long, from a low to a high speed at
#: least this far apart; speeds above what the supply holds at 95 % duty are left out
PUMP_SETPOINTS, PUMP_HOLD_S, PUMP_MIN_SPAN_RPM, PUMP_MAX_DUTY = 5, 0.6, 2000.0, 0.95
HELD_OUT_PUMP_SEEDS = tuple(range(1000, 1024))
TRAIN_PUMP_SEEDS = tuple(range(2000, 2008))
@dataclass
class Pump:
    seed: int
    params: dict
    config: PlantConfig
    setpoints_rpm: tuple[float, ...]


def draw_pump(seed: int) -> Pump:
    """One pump from PUMP_RANGE (log-uniform factors, uniform offsets), its deviations inside the
    effect library's bounds."""
    rng = np.random.default_rng([seed, 0x9035])
    r = PUMP_RANGE
    base = paper_bench()
    pp = int(rng.integers(r["pole_pairs"][0], r["pole_pairs"][1] + 1))

    def log_uniform(lo_hi):
        return float(np.exp(rng.uniform(*np.log(lo_hi))))

    j_f, fan_f, c1_f = log_uniform(r["inertia_factor"]), log_uniform(r["fan_factor"]), log_uniform(
        r["conditioning_c1_factor"])
    motor = dataclasses.replace(base.motor, pole_pairs=pp, inertia_kg_m2=base.motor.inertia_kg_m2 * j_f,
                                fan_coefficient_n_m_s2=base.motor.fan_coefficient_n_m_s2 * fan_f)
    # the fastest speed the supply holds at PUMP_MAX_DUTY (the analytic steady state, bisected)
    lo_rpm, hi_rpm = r["speed_rpm"]
    if steady_state(motor, hi_rpm)["duty"] > PUMP_MAX_DUTY:
        a, b = lo_rpm, hi_rpm
        for _ in range(40):
            mid = 0.5 * (a + b)
            a, b = (mid, b) if steady_state(motor, mid)["duty"] <= PUMP_MAX_DUTY else (a, mid)
        hi_rpm = a
    low = float(rng.uniform(lo_rpm, max(lo_rpm, hi_rpm - PUMP_MIN_SPAN_RPM)))
    high = float(rng.uniform(min(low + PUMP_MIN_SPAN_RPM, hi_rpm), hi_rpm))
    setpoints = tuple(float(v) for v in np.linspace(low, high, PUMP_SETPOINTS))
    install = tuple(float(v) for v in rng.uniform(*r["installation_offset_deg_e"], 3))
    poles = tuple(float(v) for v in rng.uniform(*r["pole_offset_deg_e"], 2 * pp))
    circuit = dataclasses.replace(PAPER_BENCH_CIRCUIT, c1_f=PAPER_BENCH_CIRCUIT.c1_f * c1_f)
    arm = float(rng.uniform(*r["armature_slope_deg_e_per_a"]))
    jitter = float(rng.uniform(*r["edge_jitter_time_rms_s"]))
    config = dataclasses.replace(
        base, motor=motor, name=f"pump-{seed}",
        effects=(fx.InstallationOffset(offset_deg_e=install), fx.PoleOffset(offset_deg_e=poles),
                 fx.ConditioningDelay.from_circuit(circuit), fx.ArmatureReaction(slope_deg_e_per_a=arm),
                 fx.EdgeJitter(time_rms_s=jitter), fx.TimerQuantization(tick_s=r["timer_tick_s"])))
    params = dict(seed=seed, pole_pairs=pp, inertia_kg_m2=motor.inertia_kg_m2, inertia_factor=j_f,
                  fan_coefficient_n_m_s2=motor.fan_coefficient_n_m_s2, fan_factor=fan_f, setpoints_rpm=list(setpoints),
                  hold_s=PUMP_HOLD_S, installation_offset_deg_e=list(install), pole_offset_deg_e=list(poles),
                  conditioning_c1_f=circuit.c1_f, armature_slope_deg_e_per_a=arm, edge_jitter_time_rms_s=jitter,
                  timer_tick_s=r["timer_tick_s"])
    return Pump(seed, params, config, setpoints)


def pump_run(pump: Pump) -> tuple[ScenarioRun, MotorModel]:
    """The pump calibrated by the station, run through its speed steps; its identified model."""
    corrections = station_corrections(pump.config, seed=pump.seed)
    run = run_scenario(pump.config, corrections, hold_s=PUMP_HOLD_S, setpoints_rpm=pump.setpoints_rpm, seed=pump.seed)
    return run, identify(pump.config, seed=pump.seed).model


# --- the predictors from their settings ---------------------------------------------------------

# --- tuning (tools/predictor_tuning.py; never run by compare) -----------------------------------------

def _pair_objective(runs, predictor, kinematic: bool = False) -> float:
    """The tuning objective over (run, model) pairs: mean commutation angle RMS, each pump's
    predictor rebuilt on its own model (compare's objective takes one model for all runs);
    ``kinematic``: the model-based filters in their kinematic form (``build``). Infinite
    (refused) where a run needed a covariance repair: the controller that ships the KF's and
    Sage-Husa's settings raises EMCY 0xFF03 on one and REQ-PRED-001 asserts none (the closed-loop
    tuning's rule, ``controller_tuning.replay_objective``; the same for every predictor)."""
    out = []
    for run, model in runs:
        p = rebuilt(predictor, model, kinematic)
        cur = np.zeros(run.t_corrected_s.size) if kinematic else run.mean_current_a
        r = p.run(run.t_corrected_s, cur)
        if split_counters(r.guards)["covariance_repairs"]:
            return math.inf
        out.append(score(run, "", r.pred_t_s, r.speed_rad_s).angle_rms_deg_e)
    value = float(np.mean(out))
    return value if math.isfinite(value) else math.inf


def search(entry, objective, model0: MotorModel, kinematic: bool = False) -> tuple[float, object]:
    """The best predictor in ``entry``'s tuning space (the registry's data): for each option set,
    the axes' grid searched (exhaustively, or then refined: ``compare._grid_then_refine``); the
    best over the option sets (the first on a tie). ``objective(predictor)`` is minimised; returns
    (its value, the predictor)."""
    space = entry.tuning_space
    best = None
    for opts in space.option_sets():
        def make(x, opts=opts):
            return entry.make(space.settings(space.point(x), opts), model0, kinematic)

        if not space.axes:
            x = ()
        elif space.exhaustive:
            x = min(itertools.product(*space.grid.values()), key=lambda x: objective(make(x)))
        else:
            x = compare._grid_then_refine(lambda x: objective(make(x)), space.grid)
        p = make(x)
        value = objective(p)
        if best is None or value < best[0]:
            best = (value, p)
    return best


def tune(runs: list[tuple[ScenarioRun, MotorModel]], kinematic: bool = False, log=print) -> dict[str, dict]:
    """Each predictor's settings minimising the mean commutation angle RMS over ``runs`` (training
    pumps), each searched in its registry tuning space (``search``), at most compare's budget per
    option (stated in ``BUDGETS``); ``kinematic``: only the model-based filters, in their
    kinematic form (for recordings)."""
    model0 = KINEMATIC_MODEL if kinematic else runs[0][1]
    tuned: dict[str, dict] = {}
    t0 = time.monotonic()
    for name, entry in PREDICTORS.items():
        if kinematic and not entry.model_based:
            continue
        value, p = search(entry, lambda predictor: _pair_objective(runs, predictor, kinematic), model0, kinematic)
        tuned[name] = settings_of(p)
        log(f"{name}: {tuned[name]} ({value:.4f} deg e) {time.monotonic() - t0:.0f} s")
    return tuned


BUDGETS = {name: entry.tuning_space.describe() for name, entry in PREDICTORS.items()}


# --- evaluation ------------------------------------------------------------------------------------

def _figures(name: str, predictor, pairs) -> tuple[list, list[float]]:
    """One predictor over (run, model) pairs: each run's Table5Row against the plant's truth and
    its cost per edge (the batch run's wall time over its edges, after one compile call)."""
    predictor.run(pairs[0][0].t_corrected_s[:64], pairs[0][0].mean_current_a[:64])
    rows, cost = [], []
    for run, _ in pairs:
        t0 = time.perf_counter()
        r = predictor.run(run.t_corrected_s, run.mean_current_a)
        cost.append((time.perf_counter() - t0) / run.t_corrected_s.size * 1e6)
        row = score(run, name, r.pred_t_s, r.speed_rad_s)
        rows.append(row)
    return rows, cost


def _row_json(name: str, rows, cost, settings) -> dict:
    def mean(attr):
        v = [getattr(r, attr) for r in rows]
        return float(np.mean(v)) if all(np.isfinite(v)) else None

    def nanmean(attr):
        # a run without a constant (or regulation) stage has no such MAPE; the others are averaged
        v = np.array([getattr(r, attr) for r in rows], dtype=float)
        return float(np.nanmean(v)) if np.isfinite(v).any() else None

    return {"name": name, "angle_rms_deg_e": mean("angle_rms_deg_e"), "angle_p99_deg_e": mean("angle_p99_deg_e"),
            "angle_max_deg_e": float(max(r.angle_max_deg_e for r in rows)), "us_per_edge": float(np.median(cost)),
            "speed_mape_constant_pct": nanmean("constant_speed_mape_pct"),
            "speed_mape_regulation_pct": nanmean("regulation_speed_mape_pct"), "settings": settings}


def _tuned():
    from ..predictors.peer_settings import PROVENANCE, TUNED

    return TUNED, PROVENANCE


def shipped_settings(name: str, kinematic: bool = False) -> dict:
    """The tuned settings of predictor ``name`` (``peer_settings.TUNED``, or its kinematic form's);
    a predictor whose tuning space has no setting needs no tuning: the settings of its empty point."""
    from ..predictors.peer_settings import TUNED

    block = TUNED["kinematic"] if kinematic else TUNED
    if name in block:
        return block[name]
    space = PREDICTORS[name].tuning_space
    if not space.axes and not space.options:
        return space.settings({}, {})
    form = " (kinematic form)" if kinematic else ""
    raise ValueError(f"predictor {name!r}{form} has no tuned settings in hil/predictors/peer_settings.py: "
                     "run tools/predictor_tuning.py")


def compare_paper(seeds=compare.EVAL_SEEDS, hold_s: float = 1.0) -> dict:
    tuned, provenance = _tuned()
    config = scenario_plant()
    model = identify(config, seed=compare.TRAIN_SEEDS[0]).model
    pairs = [(run_scenario(config, station_corrections(config, seed=s), hold_s=hold_s, seed=s), model) for s in seeds]
    preds = []
    for name in PREDICTORS:
        p = build(name, shipped_settings(name), model)
        rows, cost = _figures(name, p, pairs)
        preds.append(_row_json(name, rows, cost, settings_of(p)))
    return {"source": f"scenario paper: 7 set points 5000-10,000 rpm held {hold_s:g} s, seeds {list(seeds)}",
            "reference": "the plant's ideal edge instants (ground truth); figures are means over the seeds, "
                         "max the largest", "settings_provenance": provenance, "predictors": preds}


def compare_pumps(seeds=HELD_OUT_PUMP_SEEDS) -> dict:
    tuned, provenance = _tuned()
    if set(seeds) & set(provenance["train_pump_seeds"]):
        raise ValueError(f"pump seeds {sorted(set(seeds) & set(provenance['train_pump_seeds']))} were tuned on")
    pumps = [draw_pump(s) for s in seeds]
    pairs = [pump_run(p) for p in pumps]
    per_pump = [{"params": p.params, "predictors": []} for p in pumps]
    preds = []
    for name in PREDICTORS:
        p = build(name, shipped_settings(name), pairs[0][1])
        rows, cost = [], []
        for j, pair in enumerate(pairs):
            q = build(name, shipped_settings(name), pair[1])
            r, c = _figures(name, q, [pair])
            rows += r
            cost += c
            per_pump[j]["predictors"].append(_row_json(name, r, c, None))
        row = _row_json(name, rows, cost, settings_of(p))
        rms = [r.angle_rms_deg_e for r in rows]
        row["angle_rms_median_deg_e"] = float(np.median(rms))
        preds.append(row)
    by_name = {r["name"]: r for r in preds}
    return {"source": f"scenario pumps: {len(seeds)} held-out pumps (seeds {seeds[0]}-{seeds[-1]}) drawn from "
                      f"{PUMP_RANGE}; {PUMP_SETPOINTS} set points each held {PUMP_HOLD_S:g} s, calibrated by "
                      "the station",
            "reference": "the plant's ideal edge instants (ground truth); figures are means over the pumps, "
                         "angle_rms_median_deg_e the median, max the largest",
            "settings_provenance": provenance,
            "sage_husa_over_kf_median_rms": (by_name["sage_husa"]["angle_rms_median_deg_e"]
                                             / by_name["kf"]["angle_rms_median_deg_e"]),
            "predictors": preds, "pumps": per_pump}


#: the training pump on which CI recomputes the shipped settings' training score (the first one
#: the tuning saw; its whole profile, about 3000 edges: a second or two once compiled)
SCORE_PUMP_SEED = TRAIN_PUMP_SEEDS[0]


@functools.lru_cache(maxsize=4)
def _training_pair(pump_seed: int) -> tuple[ScenarioRun, MotorModel]:
    return pump_run(draw_pump(pump_seed))


def training_score(name: str, pump_seed: int = SCORE_PUMP_SEED, kinematic: bool = False) -> float:
    """The tuning objective (commutation angle RMS against the plant's truth, deg e) of the shipped
    settings of predictor ``name`` (``kinematic``: its kinematic form) on the training pump
    ``pump_seed``; ``PROVENANCE["training_score"]`` holds what the tuning measured, so a change in
    the code under the settings shows as a different figure."""
    if pump_seed not in TRAIN_PUMP_SEEDS:
        raise ValueError(f"pump {pump_seed} is not a training pump ({TRAIN_PUMP_SEEDS[0]}-{TRAIN_PUMP_SEEDS[-1]})")
    pair = _training_pair(pump_seed)
    settings = shipped_settings(name, kinematic)
    return _pair_objective([pair], build(name, settings, pair[1], kinematic=kinematic), kinematic)


def _score_key(name: str, kinematic: bool) -> str:
    return f"{name} (kinematic)" if kinematic else name


def tuning_main(argv=None) -> int:
    """Tune every predictor on the training pumps and write ``peer_settings.py`` (run once, by
    tools/predictor_tuning.py)."""
    import argparse
    import pprint

    ap = argparse.ArgumentParser(description=tuning_main.__doc__.splitlines()[0])
    from hil import cli_grammar as grammar

    ap.add_argument("--train-seeds", type=int, nargs="+", default=list(TRAIN_PUMP_SEEDS), dest="train_seed")
    grammar.add_deprecated(ap, "--train-seed", dest="train_seed", new="--train-seeds", type=int, nargs="+")
    grammar.add_out(ap, "where the tuned settings go", default=str(Path(__file__).parents[1] / "predictors"
                                                                   / "peer_settings.py"))
    args = ap.parse_args(argv)
    args.out = Path(args.out)
    if set(args.train_seed) & set(HELD_OUT_PUMP_SEEDS):
        ap.error(f"training seeds {sorted(set(args.train_seed) & set(HELD_OUT_PUMP_SEEDS))} are held out")
    t0 = time.monotonic()
    commit = _commit()  # the code that runs, before anything is written
    runs = [pump_run(draw_pump(s)) for s in args.train_seed]
    print(f"{len(runs)} training pumps, {sum(r.t_corrected_s.size for r, _ in runs)} edges, "
          f"{time.monotonic() - t0:.0f} s")
    tuned = tune(runs)
    print("kinematic forms (no current, no motor data), for recordings:")
    tuned["kinematic"] = tune(runs, kinematic=True)
    forms = [(name, False) for name in PREDICTORS] + [(name, True) for name in tuned["kinematic"]]

    def objective(pairs, name, kinematic):
        settings = tuned["kinematic"][name] if kinematic else tuned[name]
        return _pair_objective(pairs, build(name, settings, pairs[0][1], kinematic=kinematic), kinematic)

    training = {_score_key(n, k): objective(runs, n, k) for n, k in forms}
    one_pump = {_score_key(n, k): objective(runs[:1], n, k) for n, k in forms}
    provenance = {"tool": "tools/predictor_tuning.py", "train_pump_seeds": list(args.train_seed),
                  "pump_range": {k: list(v) if isinstance(v, tuple) else v for k, v in PUMP_RANGE.items()},
                  "objective": "mean commutation angle RMS (deg e) over the training pumps, ground truth; "
                               "settings that need a covariance repair on any training pump refused",
                  "budgets": BUDGETS, "training_angle_rms_deg_e": training,
                  "training_score": {"pump_seed": args.train_seed[0], "angle_rms_deg_e": one_pump,
                                     "recomputed_by": "hil.experiments.peers.training_score"},
                  "search": "deterministic: seeded pumps, a fixed grid, Nelder-Mead from fixed simplices",
                  "commit": commit, "tuning_wall_time_s": round(time.monotonic() - t0)}
    defaults = settings_of(KalmanPredictor(KINEMATIC_MODEL, FilterSettings()))

    def compact(d: dict) -> dict:
        # a filter's settings as they differ from FilterSettings' defaults (filter_settings fills in the rest)
        return {k: v for k, v in d.items() if k not in defaults or v != defaults[k]}

    for block in (tuned, tuned["kinematic"]):
        for name in ("kf", "sage_husa"):
            block[name] = compact(block[name])
    text = ('"""Every predictor\'s settings, from tools/predictor_tuning.py on the training pumps (written by\n'
            'it; do not edit by hand: rerun the tool). ``PROVENANCE`` says what was searched, on what. The\n'
            'filters\' settings list what differs from ``FilterSettings``\' defaults."""\n\n'
            f"TUNED = {pprint.pformat(tuned, width=100, sort_dicts=False)}\n\n"
            f"PROVENANCE = {pprint.pformat(provenance, width=100, sort_dicts=False)}\n")
    args.out.write_text(text)
    for name, v in training.items():
        print(f"  {name}: {v:.4f} deg e on the training pumps")
    print(f"wrote {args.out} in {time.monotonic() - t0:.0f} s")
    return 0


#: what the tuning runs: an uncommitted change here makes the recorded commit "+dirty"
CODE_DIRS = ("bldc", "plant_models", "hil", "tools")


def _commit() -> str | None:
    """The repository's commit the tuning ran at, if known, with "+dirty" where the code it runs
    (bldc, plant_models, hil, tools) has uncommitted changes; tests and docs do not count."""
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_DIRS], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


# --- a recording ---------------------------------------------------------------------------------

RECORDING_REFERENCE = (
    "no encoder: each prediction of edge k+1 is scored against the corrected instant of edge k+1 "
    "(the project's calibration of the recording, the one `hil calibrate` runs, its installation, "
    "pole and rise-minus-fall delay terms taken off the capture times; the predictors run over the "
    "longest run of rotor steps and are scored on its second half), converted to deg e with the speed over the two "
    "sectors around it; this is the best reference a capture without encoder allows, and it still "
    "holds the edges' own noise and quantisation")


@dataclass
class RecordingEdges:
    """The edges a predictor runs on: one run of rotor steps, with the calibration's corrected instants."""

    t_s: np.ndarray  #: capture times of the kept edges
    t_corrected_s: np.ndarray  #: the same edges, the calibration's deviations taken off
    first_scored: int  #: the first scored edge: the second half of the run (the predictors settle on the first)
    dropped: int  #: edges outside the run (bounces, invalid states, reversals, stalls, short runs)
    direction: int  #: +1 forward (A, B, C), -1 reverse
    calibration: object  #: the recording's ``hil.calibration.result.Calibration``


def recording_edges(rec) -> RecordingEdges:
    """The longest run of rotor steps that ``bldc.edges`` reads from the recording (constant
    direction, no stall; bounces and invalid states removed: each edge is the next sector
    boundary), and its corrected instants: the recording is calibrated by
    ``hil.calibration.calibrate`` as an ordinary run (what ``hil calibrate`` reports for a
    capture), and the table's sensor effects are taken off every edge of the run."""
    from bldc.edges import longest_run

    from ..calibration import calibrate
    from ..calibration.ordinary import edge_corrections_s, hall_steps

    ordinary = dataclasses.replace(rec, segments=[], segment=np.zeros(len(rec), dtype=np.int64),
                                   ref_angle_mech_deg=None)
    steps = hall_steps(ordinary.t_s, ordinary.sensor, ordinary.rising)
    idx = longest_run(steps)
    if idx.size < 200:
        raise ValueError(f"{getattr(rec, 'path', None) or 'recording'}: {idx.size} usable edges in its longest run "
                         "of rotor steps; at least 200 are needed (half to calibrate)")
    half = idx.size // 2
    cal = calibrate(ordinary)
    t_corrected = steps.t_s[idx] - edge_corrections_s(cal, steps, idx)
    return RecordingEdges(steps.t_s[idx], t_corrected, half, int(steps.t_s.size - idx.size),
                          int(steps.direction[idx[0]]), cal)


def score_recording(tc: np.ndarray, pred: np.ndarray, speed: np.ndarray, first: int) -> dict:
    """Angle error of each prediction made at edge k >= first (for edge k + 1) against the corrected
    instant of edge k + 1, in deg e at the two-sector speed around it; the speed estimate after
    edge k against the two-sector speed around edge k."""
    k = np.arange(max(first, 1), tc.size - 2)
    w = 2.0 * np.pi * electrical_speed_hz(tc, window_sectors=2)  # rad/s e over the two sectors around each edge
    err = np.degrees((pred[k] - tc[k + 1]) * w[k + 1])
    ape = np.abs(speed[k] / w[k] - 1.0) * 100.0
    finite = np.isfinite(err)
    return {"angle_rms_deg_e": float(np.sqrt(np.mean(err**2))) if finite.all() else None,
            "angle_p99_deg_e": float(np.percentile(np.abs(err), 99)) if finite.all() else None,
            "angle_max_deg_e": float(np.max(np.abs(err))) if finite.all() else None,
            "speed_mape_pct": float(np.mean(ape)) if np.isfinite(ape).all() else None,
            "edges_scored": int(k.size)}


#: what a recording's meta.json motor block needs for the model-based filters (with phase currents)
MODEL_KEYS = ("inertia_kg_m2", "ke_v_s_per_rad", "fan_coefficient_n_m_s2")


def recording_model(rec, t_edges_s: np.ndarray) -> tuple[MotorModel | None, np.ndarray | None]:
    """The paper's model from the recording's motor block and the mean |i| over the three phases
    of each commutation cycle (samples from the previous edge up to this one; the nearest sample
    where a cycle holds none), or (None, None) when the phase currents or the motor data are missing."""
    s, motor = rec.samples, rec.motor
    if not s or any(c not in s for c in ("i_a", "i_b", "i_c")) or any(k not in motor for k in MODEL_KEYS):
        return None, None
    model = MotorModel(int(motor["pole_pairs"]), float(motor["inertia_kg_m2"]),
                       (3.0 * float(motor["ke_v_s_per_rad"]),), (float(motor["fan_coefficient_n_m_s2"]),))
    mean_abs = (np.abs(s["i_a"]) + np.abs(s["i_b"]) + np.abs(s["i_c"])) / 3.0
    csum = np.concatenate(([0.0], np.cumsum(mean_abs)))
    hi = np.searchsorted(s["t_s"], t_edges_s)
    lo = np.concatenate(([hi[0]], hi[:-1]))
    nearest = mean_abs[np.clip(hi, 0, mean_abs.size - 1)]
    count = hi - lo
    cycle = np.where(count > 0, (csum[hi] - csum[lo]) / np.maximum(count, 1), nearest)
    return model, cycle


def compare_recording(rec, source: str, edges: RecordingEdges | None = None) -> dict:
    """Every predictor on a recording (``edges``: its ``recording_edges``, if already read)."""
    tuned, provenance = _tuned()
    e = edges or recording_edges(rec)
    tc, half = e.t_corrected_s, e.first_scored
    model, current = recording_model(rec, e.t_s)
    kinematic = model is None
    if kinematic:
        current = np.zeros(tc.size)
    preds = []
    for name, entry in PREDICTORS.items():
        kin = kinematic and entry.model_based
        settings = shipped_settings(name, kin)
        p = build(name, settings, KINEMATIC_MODEL if kinematic else model, kinematic=kin)
        p.run(tc[:64], current[:64])
        t0 = time.perf_counter()
        r = p.run(tc, current)
        us = (time.perf_counter() - t0) / tc.size * 1e6
        row = {"name": name, **score_recording(tc, r.pred_t_s, r.speed_rad_s, half), "us_per_edge": us,
               "speed_mape_constant_pct": None, "speed_mape_regulation_pct": None, "settings": settings_of(p)}
        if kin:
            row["mode"] = "kinematic"
        preds.append(row)
    tick = getattr(rec, "timer_tick_s", None)
    return {"source": f"recording {source}: {len(rec)} edges, {e.t_s.size} kept ({e.dropped} outside the longest "
                      "run of rotor steps: bounces, invalid states, reversals, stalls, shorter runs), "
                      f"direction {'forward' if e.direction > 0 else 'reverse'}, timer tick "
                      f"{(tick or 0) * 1e6:.3g} us",
            "reference": RECORDING_REFERENCE,
            "calibration": _calibration_summary(e.calibration, half),
            "model": ("kf, sage_husa and vb_akf run kinematic: no current or motor data, the state is angle, "
                      "speed and acceleration (K_T = J = 1, no load, the current channel unobserved); their "
                      "settings are the kinematic tuning on the training pumps" if kinematic else
                      "kf, sage_husa and vb_akf run the paper's model: J, K_T = 3 ke and M from the recording's "
                      "motor block, the cycle-mean |i| from its phase currents; their settings are the "
                      "training pumps' tuning"),
            "speed_mape_note": "constant-speed and regulation-stage MAPE need set-point stages a recording "
                               "does not state: null; speed_mape_pct is over all scored edges against the "
                               "two-sector speed",
            "settings_provenance": provenance, "predictors": preds}


def _calibration_summary(cal, half: int) -> dict:
    """What the comparison took off the edges: the calibration's table, from the first ``half`` edges."""
    out = cal.to_json_dict()
    keys = ("installation_offset_deg_e", "pole_offset_deg_e", "rise_fall_delay_difference_s", "refused")
    return {"method": "hil calibrate (ordinary run) on the recording; its installation, pole and rise-minus-fall "
                      f"delay terms taken off every edge; the predictors scored from edge {half} of the run on",
            **{k: out[k] for k in keys}}


def format_result(result: dict) -> str:
    """The comparison as a table, 100 columns at most."""
    import textwrap

    lines = [textwrap.fill(result["source"], 100, subsequent_indent="    "),
             textwrap.fill("reference: " + result["reference"], 100, subsequent_indent="    ")]
    if "model" in result:
        lines.append(textwrap.fill(result["model"], 100, subsequent_indent="    "))
    head = f"{'predictor':<15}{'RMS deg e':>10}{'p99':>9}{'max':>9}{'MAPE c %':>10}{'MAPE r %':>10}{'us/edge':>9}"
    lines.append(head)

    def f(v, width, fmt):
        if v is None:
            return f"{'-':>{width}}"
        return f"{v:>{width}.2e}" if abs(v) >= 1e4 else f"{v:>{width}{fmt}}"  # a lost filter stays legible

    for r in result["predictors"]:
        const = r.get("speed_mape_constant_pct")
        if const is None:
            const = r.get("speed_mape_pct")
        lines.append(f"{r['name']:<15}{f(r['angle_rms_deg_e'], 10, '.4f')}{f(r['angle_p99_deg_e'], 9, '.3f')}"
                     f"{f(r['angle_max_deg_e'], 9, '.3f')}{f(const, 10, '.4f')}"
                     f"{f(r.get('speed_mape_regulation_pct'), 10, '.4f')}{r['us_per_edge']:>9.2f}")
    if "sage_husa_over_kf_median_rms" in result:
        lines.append(f"Sage-Husa / KF, median angle RMS over the pumps: {result['sage_husa_over_kf_median_rms']:.3f}")
    if "speed_mape_note" in result:
        lines.append(textwrap.fill(result["speed_mape_note"], 100, subsequent_indent="    "))
    return "\n".join(lines)
