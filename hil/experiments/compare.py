"""Table 5 under stated protocols: the three predictors on the paper scenario (docs/sage-husa.md).

The paper gives no Q or R for its KF and no disturbance statistics (Sections 3.3, 4.4), so each
protocol states its own and prints them:

* ``paper``: the KF is the same filter with adaptation off; both start from the paper's R0, q0,
  r0, P0 and the stated nominal Q0, scored on ten seeds, with Q0 scanned over 0.01-100x nominal;
* ``tuned``: both filters tuned with the same search budget (a log grid of the same size, then
  the same number of Nelder-Mead evaluations) on training seeds, scored on others; beside them a
  KF given the true noise schedule by an oracle (the headroom any adaptation has);
* ``misspecified``: both start from the noise measured at one steady point (5000 rpm: the KF
  tuned there on ground truth), then run the speed profile;
* ``bursts``: edge-time noise bursts on top of the base jitter (``scenario.Bursts``), both filters
  tuned on bursty training seeds; the oracle is a KF told the true burst state.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from ..predictors import filters as F
from ..predictors.model import MotorModel
from ..predictors.predictors import FilterSettings, KalmanPredictor, PrecalibrationPredictor, SageHusaPredictor
from ..predictors.registry import (  # noqa: F401 - the filters' design and grids, declared with the predictors
    B_R_RANGE,
    B_RANGE,
    KF_GRID,
    R_INTERVAL_RANGE,
    SH_DESIGN,
    SH_GRID,
    sh_settings,
)
from .identify import identify
from .table5 import Bursts, ScenarioRun, Table5Row, run_scenario, score

#: the JSON's metric keys and the Table5Row field each one reads
METRICS = {
    "speed_mape_regulation_pct": "regulation_speed_mape_pct",
    "max_overshoot_pct": "max_overshoot_pct",
    "speed_mape_constant_pct": "constant_speed_mape_pct",
    "commutation_time_mape_pct": "commutation_time_mape_pct",
    "angle_rms_deg_e": "angle_rms_deg_e",
}
#: paper Table 5, Sage-Husa over KF in percent (the paper states no angle RMS)
PAPER_IMPROVEMENT_PCT = {"speed_mape_regulation_pct": 44.8, "max_overshoot_pct": 56.0, "speed_mape_constant_pct": 54.9,
                         "commutation_time_mape_pct": 14.7}
PROTOCOLS = ("paper", "tuned", "misspecified", "bursts")
#: stated nominal Q0 per commutation cycle: speed (rad/s)^2, angle rad^2, current A^2
NOMINAL_Q0 = (0.1, 1e-9, 1e-6)
Q0_SCAN = (0.01, 0.1, 1.0, 10.0, 100.0)
TRAIN_SEEDS = (1, 2, 12, 13)
EVAL_SEEDS = (0, 3, 4, 5, 6, 7, 8, 9, 10, 11)
SH_ADAPT = 3  # Q and R; the noise means r and q (Eq. 12) stay at r0 = q0 = 0, see docs
#: what the bursts protocol's statement changes in that design, each from the stated disturbance:
#: inside a burst R has not learned yet every edge may be gated, so the divergence run is derived
#: for p_gated = 1 (23 at 12,000 rpm; 3 fires by chance in a quarter of a burst's gated
#: triplets); and Eq. 12 adapts Q's current entry only: burst innovations enter the Q_w term
#: (K Z~)^2 although dt^2 Q_w is about 1/200 of R_theta, so its recursion follows the bursts, not
#: the process noise, and drifts to the band floor, where the filter can no longer follow a
#: set-point step (docs/sage-husa.md)
BURSTS_SH = dict(SH_DESIGN, adapt_mask=F.ADAPT_R | F.ADAPT_Q_CURRENT,
                 divergence_run=F.divergence_run_for(F.CHI2_2DOF_999, F.MAX_EDGE_RATE_HZ, p_gated=1.0))
BURSTS_GRID = dict(q_w=KF_GRID["q_w"], q_i=KF_GRID["q_i"], one_minus_b=(0.05, 0.02, 0.005, 0.001),
                   one_minus_b_r=(0.7, 0.1))
#: Nelder-Mead evaluations after the grid, the same budget for both filters
REFINE_EVALUATIONS = 80
#: grid points the refinement starts from (each gets an equal share of the evaluations)
REFINE_STARTS = 2
W_REF_RAD_S = 1571.0  # 7500 rpm, 2 pole pairs: the middle of the profile (oracle schedule reference)


def _mean_angle_rms(runs: list[ScenarioRun], predictor) -> float:
    """The tuning objective: commutation angle RMS, averaged over the training runs."""
    rms = []
    for run in runs:
        r = predictor.run(run.t_corrected_s, run.mean_current_a)
        rms.append(score(run, "", r.pred_t_s, r.speed_rad_s).angle_rms_deg_e)
    return float(np.mean(rms))


def _grid_then_refine(objective, grid: dict[str, tuple[float, ...]]) -> tuple[float, ...]:
    """The best REFINE_STARTS grid points, then Nelder-Mead in log space around each with an
    equal share of REFINE_EVALUATIONS; the best point seen. The same search for both filters,
    so neither wins by being tuned harder. Several starts because the objective is rough (the
    gate, the fades and the variance match are thresholds): from one start the refinement of
    Sage-Husa ended 2 points worse on its own training runs than a point it had not visited."""
    scored = sorted(((objective(x), x) for x in itertools.product(*grid.values())), key=lambda vx: vx[0])
    best_value, best = scored[0]
    for _, start in scored[:REFINE_STARTS]:
        z0 = np.log10(start)
        simplex = np.vstack([z0] + [z0 + 0.5 * row for row in np.eye(len(z0))])
        res = minimize(lambda z: objective(tuple(10.0 ** z)), z0, method="Nelder-Mead",
                       options=dict(maxfev=REFINE_EVALUATIONS // REFINE_STARTS, xatol=0.02, fatol=1e-4,
                                    initial_simplex=simplex))
        if res.fun < best_value:
            best_value, best = float(res.fun), tuple(float(v) for v in 10.0 ** res.x)
    return best


def tune_kf(
    runs: list, model: MotorModel, divergence_run: int = FilterSettings().divergence_run, objective=_mean_angle_rms
) -> FilterSettings:
    """Fixed Q = diag(q_w, 1e-9, q_i) and R = diag(r_theta, r_i) minimising commutation angle RMS,
    with and without the innovation gate on the state update; the better on the training runs.
    ``divergence_run``: the gated filter's run, as the protocol derives it for Sage-Husa;
    ``objective(runs, predictor)``: the score to minimise (default: mean angle RMS over ScenarioRuns)."""
    best = None
    for gate in (False, True):
        def settings(x, gate=gate):
            q_w, q_i, r_t, r_i = x
            return FilterSettings(
                q0_diag=(q_w, 1e-9, q_i), r0_diag=(r_t, r_i), gate_state_update=gate, divergence_run=divergence_run
            )

        s = settings(_grid_then_refine(lambda x: objective(runs, KalmanPredictor(model, settings(x))), KF_GRID))
        value = objective(runs, KalmanPredictor(model, s))
        if best is None or value < best[0]:
            best = (value, s)
    return best[1]


def tune_sh(runs: list, model: MotorModel, design: dict | None = None, grid: dict | None = None,
            objective=_mean_angle_rms) -> FilterSettings:
    """Sage-Husa keeps the paper's R0, P0, q0, r0; its nominal Q_w and Q_i (independently, as the
    KF's) and the forgetting factors of Q and R are searched with the KF's budget. ``design``:
    the stated design the search starts from (default SH_DESIGN); ``grid``: the coarse grid
    (default SH_GRID; a ``r_interval`` axis searches R's interval too); ``objective``: as tune_kf's."""
    design = SH_DESIGN if design is None else design
    grid = SH_GRID if grid is None else grid

    def settings(x):
        return sh_settings(design, dict(zip(grid, x)))

    return settings(_grid_then_refine(lambda x: objective(runs, SageHusaPredictor(model, settings(x))), grid))


# --- the oracle: a KF told the true noise schedule ----------------------------------------------

@dataclass(frozen=True)
class Oracle:
    """A fixed-Q KF whose edge-angle variance follows the true schedule: R_theta(k) = r_theta
    (w_k / W_REF)^2 (a time jitter is an angle noise growing with speed) plus, during a true
    burst, burst_factor (sigma_burst w_k)^2. Its four noise values and the burst factor are tuned
    like the KF's."""

    x: tuple[float, float, float, float]
    burst_factor: float = 0.0

    def row(
        self, run: ScenarioRun, model: MotorModel, burst: np.ndarray | None, burst_rms_s: float, name: str = "oracle"
    ) -> Table5Row:
        q_w, q_i, r_t, r_i = self.x
        kf = KalmanPredictor(
            model, FilterSettings(q0_diag=(q_w, 1e-9, q_i), r0_diag=(r_t, r_i), gate_state_update=False)
        )
        w_true = run.true_speed_rad_s
        r_theta = r_t * (w_true / W_REF_RAD_S) ** 2
        if burst is not None:
            r_theta = r_theta + self.burst_factor * burst * (burst_rms_s * w_true) ** 2
        t, cur = run.t_corrected_s, run.mean_current_a
        pred, w = np.full(t.size, np.nan), np.full(t.size, np.nan)
        state, r_at = kf.state, F.ST.R
        for k in range(t.size):
            state[r_at] = r_theta[k]
            p = kf.update(float(t[k]), float(cur[k]))
            if p is not None:
                pred[k], w[k] = p, state[F.ST.X]
        return score(run, name, pred, w)


def tune_oracle(
    runs: list[ScenarioRun], bursts: list | None, model: MotorModel, start: FilterSettings, burst_rms_s: float
) -> Oracle:
    z0 = list(np.log10([start.q0_diag[0], start.q0_diag[2], *start.r0_diag])) + ([0.0] if bursts else [])

    def oracle(z):
        return Oracle(tuple(10.0 ** np.asarray(z[:4])), 10.0 ** z[4] if bursts else 0.0)

    def objective(z):
        o = oracle(z)
        return float(
            np.mean(
                [o.row(r, model, b, burst_rms_s).angle_rms_deg_e for r, b in zip(runs, bursts or [None] * len(runs))]
            )
        )

    res = minimize(objective, z0, method="Nelder-Mead", options=dict(maxfev=REFINE_EVALUATIONS, xatol=0.02, fatol=1e-4))
    return oracle(res.x)


# --- the protocols ------------------------------------------------------------------------------------

@dataclass
class ProtocolResult:
    protocol: str
    #: what the protocol states: Q, R, disturbance statistics, seeds, how each filter was set
    statement: list[str]
    seeds: tuple[int, ...]
    #: per predictor ("sage_husa", "kf", "precal", and "oracle" where there is one): one row per seed
    rows: dict[str, list[Table5Row]]
    #: paper protocol: (Q0 factor, improvement_pct, sh_wins_fraction) across the scan
    scan: list[tuple[float, dict, dict]] = field(default_factory=list)

    def metrics(self, name: str) -> dict[str, float]:
        return {m: float(np.mean([getattr(r, f) for r in self.rows[name]])) for m, f in METRICS.items()}

    def _mean(self, name: str, attr: str) -> float:
        return float(np.mean([getattr(r, attr) for r in self.rows[name]]))

    def improvement_pct(self, other: str = "sage_husa") -> dict[str, float]:
        kf, sh = self.metrics("kf"), self.metrics(other)
        return {m: 100.0 * (kf[m] - sh[m]) / kf[m] if kf[m] else 0.0 for m in METRICS}

    def sh_wins_fraction(self) -> dict[str, float]:
        return {
            m: float(np.mean([getattr(s, f) < getattr(k, f) for s, k in zip(self.rows["sage_husa"], self.rows["kf"])]))
            for m, f in METRICS.items()
        }

    def to_json(self) -> dict:
        out = {"protocol": self.protocol, "seeds_evaluated": list(self.seeds),
               "metrics": {name: self.metrics(name) for name in ("sage_husa", "kf", "precal")},
               "improvement_pct": self.improvement_pct(), "sh_wins_fraction": self.sh_wins_fraction()}
        if "oracle" in self.rows:
            out["oracle_improvement_pct"] = self.improvement_pct("oracle")
        return out

    def format(self) -> str:
        """The table, 100 columns at most."""
        names = [n for n in ("sage_husa", "kf", "precal", "oracle") if n in self.rows]
        heads = {"sage_husa": "Sage-Husa", "kf": "KF", "precal": "precal", "oracle": "oracle"}
        labels = {"speed_mape_regulation_pct": "speed MAPE regulation %", "max_overshoot_pct": "max overshoot %",
                  "speed_mape_constant_pct": "speed MAPE constant %", "commutation_time_mape_pct": "comm. time MAPE %",
                  "angle_rms_deg_e": "angle RMS deg e"}
        imp, wins = self.improvement_pct(), self.sh_wins_fraction()
        lines = [
            f"{'metric (mean of ' + str(len(self.seeds)) + ' seeds)':<27}"
            + "".join(f"{heads[n]:>10}" for n in names)
            + f"{'SH vs KF':>10}{'SH wins':>9}{'paper':>8}"
        ]
        for m in METRICS:
            paper = PAPER_IMPROVEMENT_PCT.get(m)
            lines.append(
                f"{labels[m]:<27}"
                + "".join(f"{self.metrics(n)[m]:>10.4f}" for n in names)
                + f"{imp[m]:>+9.1f}%{wins[m]:>9.0%}"
                + (f"{paper:>+7.1f}%" if paper is not None else f"{'-':>8}")
            )
            if m == "max_overshoot_pct":
                lines.append(
                    f"{'  mean signed error, reg. %':<27}"
                    + "".join(f"{self._mean(n, 'regulation_signed_error_pct'):>+10.4f}" for n in names)
                    + "  (< 0: lag)"
                )
            if m == "speed_mape_constant_pct":
                lines.append(
                    f"{'  constant-stage edges':<27}"
                    + "".join(f"{self._mean(n, 'constant_edges'):>10.0f}" for n in names)
                )
        if "oracle" in self.rows:
            o = self.improvement_pct("oracle")["angle_rms_deg_e"]
            if o > 0:
                share = f"Sage-Husa captures {imp['angle_rms_deg_e'] / o:.0%} of it"
            else:  # a share of no gain means nothing
                share = "none for Sage-Husa to capture"
            lines.append(f"oracle headroom (angle RMS): {o:+.1f} % over the KF; {share}")
        for factor, scan_imp, scan_wins in self.scan:
            lines.append(f"Q0 x{factor:<6g} SH vs KF: " + " ".join(f"{scan_imp[m]:+.1f}%" for m in METRICS)
                         + "  wins " + "/".join(f"{scan_wins[m]:.0%}" for m in METRICS))
        return "\n".join(lines)


def _rows(runs: list[ScenarioRun], predictors: dict) -> dict[str, list[Table5Row]]:
    out = {}
    for name, predictor in predictors.items():
        out[name] = []
        for run in runs:
            r = predictor.run(run.t_corrected_s, run.mean_current_a)
            out[name].append(score(run, name, r.pred_t_s, r.speed_rad_s, r.guards))
    return out


def _jitter_s(run: ScenarioRun) -> float:
    return sum(getattr(e, "time_rms_s", 0.0) for e in run.config.effects if type(e).__name__ == "EdgeJitter")


def _settings_line(name: str, s: FilterSettings, adaptive: bool) -> str:
    line = (f"{name}: Q0 = diag({s.q0_diag[0]:.3g}, {s.q0_diag[1]:.3g}, {s.q0_diag[2]:.3g}), "
            f"R0 = diag({s.r0_diag[0]:.3g}, {s.r0_diag[1]:.3g}), P0 = diag({s.p0_diag[0]:g}, ...), "
            f"gate on the state {'on' if s.gate_state_update else 'off'}")
    if adaptive:
        m = s.adapt_mask
        q_i = f"Q_i by Eq. 12 (b = {s.forgetting_b:.4g})" if m & (F.ADAPT_Q | F.ADAPT_Q_CURRENT) else "Q_i fixed"
        if m & F.ADAPT_Q_WHITE:
            q_w = f"Q_w by innovation whiteness every {s.adapt_interval} edges"
        else:
            q_w = "Q_w by Eq. 12" if m & F.ADAPT_Q else "Q_w fixed"
        q = f"{q_w}, {q_i}"
        line += (
            f"; {q}, Q band x{s.q_band_factor:g}; R by Eq. 12 (b_R = {s.r_forgetting_b:.4g} "
            f"every {s.r_interval} edges, Huber c = {s.huber_c:.3g}"
            + (f", R_i >= {s.r0_diag[1]:.3g}" if m & F.ADAPT_R_CURRENT_FLOOR else "")
            + f"), divergence run {s.divergence_run}"
        )
    return line


def run_protocol(protocol: str, eval_seeds=EVAL_SEEDS, train_seeds=TRAIN_SEEDS, hold_s: float = 1.0,
                 bursts: Bursts = Bursts(), oracle: bool = True) -> ProtocolResult:
    """``oracle``: the tuned protocols' oracle row too (its own tuning, a quarter of the protocol's
    time); a reference of headroom, not a predictor under judgement, so a check of the filters
    alone can leave it out."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    if set(eval_seeds) & set(train_seeds):
        raise ValueError(f"evaluation seeds {sorted(set(eval_seeds) & set(train_seeds))} are also training seeds")
    evaluation = [run_scenario(seed=s, hold_s=hold_s) for s in eval_seeds]
    model = identify(evaluation[0].config, seed=train_seeds[0]).model
    base = (f"paper scenario: 7 set points 5000-10,000 rpm held {hold_s:g} s, PI speed loop, calibration applied, "
            f"type III jitter {_jitter_s(evaluation[0]) * 1e6:g} us RMS on every edge")
    statement = [base]
    precal = PrecalibrationPredictor()
    if protocol == "paper":
        scan, main = [], None
        for factor in Q0_SCAN:
            q0 = tuple(factor * q for q in NOMINAL_Q0)
            # the KF's gate is off: with the paper's R_theta = 0 a gate would refuse every edge
            kf_s = FilterSettings(q0_diag=q0, gate_state_update=False)
            sh_s = FilterSettings(q0_diag=q0, adapt_mask=SH_ADAPT)
            rows = _rows(evaluation, {"sage_husa": SageHusaPredictor(model, sh_s), "kf": KalmanPredictor(model, kf_s)})
            res = ProtocolResult(protocol, statement, tuple(eval_seeds), {**rows, "precal": rows["kf"]})
            scan.append((factor, res.improvement_pct(), res.sh_wins_fraction()))
            if factor == 1.0:
                main = (rows, kf_s, sh_s)
        rows, kf_s, sh_s = main
        statement += [
            "KF = the same filter with adaptation off; both from the paper's R0, q0 = r0 = 0, P0",
            _settings_line("KF", kf_s, False),
            _settings_line("Sage-Husa", sh_s, True),
            f"Q0 scanned over {', '.join(f'{f:g}' for f in Q0_SCAN)} x nominal (rows 'Q0 x'; metrics in table order)",
        ]
        rows["precal"] = _rows(evaluation, {"precal": precal})["precal"]
        return ProtocolResult(protocol, statement, tuple(eval_seeds), rows, scan)
    if protocol == "misspecified":
        steady = [run_scenario(seed=s, setpoints_rpm=(5000.0,), hold_s=3.0) for s in train_seeds]
        kf_s = tune_kf(steady, model)
        sh_s = FilterSettings(**{**SH_DESIGN, "q0_diag": kf_s.q0_diag, "r0_diag": kf_s.r0_diag})
        statement += [
            "noise measured at one steady point: the KF tuned on ground truth at 5000 rpm "
            f"(3 s, seeds {tuple(train_seeds)})",
            _settings_line("KF", kf_s, False),
            _settings_line("Sage-Husa (starts there)", sh_s, True),
        ]
        rows = _rows(
            evaluation,
            {"sage_husa": SageHusaPredictor(model, sh_s), "kf": KalmanPredictor(model, kf_s), "precal": precal},
        )
        return ProtocolResult(protocol, statement, tuple(eval_seeds), rows)
    train = [run_scenario(seed=s, hold_s=hold_s) for s in train_seeds]
    burst_train = burst_eval = None
    if protocol == "bursts":
        pairs = [bursts.apply(r, s) for r, s in zip(train, train_seeds)]
        train, burst_train = [p[0] for p in pairs], [p[1] for p in pairs]
        pairs = [bursts.apply(r, s) for r, s in zip(evaluation, eval_seeds)]
        evaluation, burst_eval = [p[0] for p in pairs], [p[1] for p in pairs]
        on = float(np.mean(np.concatenate(burst_eval)))
        statement.append(
            f"bursts: {bursts.time_rms_s * 1e6:g} us RMS edge-time noise, "
            f"exponential dwell {bursts.on_mean_s:g} s on / "
            f"{bursts.off_mean_s:g} s off (edges in a burst: {on:.1%} on the evaluation seeds)"
        )
    # the KF's gate gets the same derived divergence run as Sage-Husa's (bursts: 23)
    kf_s = tune_kf(
        train,
        model,
        (BURSTS_SH if protocol == "bursts" else SH_DESIGN).get("divergence_run", FilterSettings().divergence_run),
    )
    sh_s = tune_sh(train, model, *((BURSTS_SH, BURSTS_GRID) if protocol == "bursts" else (SH_DESIGN, SH_GRID)))
    statement += [f"both tuned with the same budget ({math.prod(len(v) for v in KF_GRID.values())}-point grid + "
                  f"{REFINE_EVALUATIONS} Nelder-Mead evaluations from its {REFINE_STARTS} best points) "
                  f"on seeds {tuple(train_seeds)}",
                  _settings_line("KF", kf_s, False), _settings_line("Sage-Husa", sh_s, True)]
    rows = _rows(
        evaluation, {"sage_husa": SageHusaPredictor(model, sh_s), "kf": KalmanPredictor(model, kf_s), "precal": precal}
    )
    if oracle:
        told = tune_oracle(train, burst_train, model, kf_s, bursts.time_rms_s)
        statement.append(f"oracle: KF with R_theta = {told.x[2]:.3g} (w / {W_REF_RAD_S:g})^2"
                         + (f" + {told.burst_factor:.3g} (sigma_burst w)^2 in a true burst" if burst_eval else "")
                         + f", Q = diag({told.x[0]:.3g}, 1e-9, {told.x[1]:.3g}), tuned alike")
        rows["oracle"] = [
            told.row(r, model, b, bursts.time_rms_s) for r, b in zip(evaluation, burst_eval or [None] * len(evaluation))
        ]
    return ProtocolResult(protocol, statement, tuple(eval_seeds), rows)
