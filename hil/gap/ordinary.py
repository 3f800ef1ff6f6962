"""Gap diagnosis of an ordinary run: Hall capture times only (a logic analyser's recording).

The model a simulation makes of such a capture is an ideal motor with ideal sensors: every edge
60 deg e after the last, on a smooth speed trajectory. The gap is what the edges do beyond that:
the RMS over edges of the systematic edge-angle residual (cell means per held-out stretch,
sensor boundary, direction and speed band, less their noise), in electrical degrees.

The candidates are the effects capture times can see, each declaring its set of columns of the
joint fit of :mod:`hil.calibration.ordinary` (``Effect.ordinary``; ``hil.gap.candidates``
reads them): ``installation_offset`` (per sensor, both edges alike), ``hysteresis`` (per sensor,
rise minus fall, constant in angle: asymmetric switching points), ``conditioning_delay`` (rise
minus fall, constant in time: grows with speed), ``pole_offset`` (per magnet pole, when the pole
count is stated or found), and ``torque_ripple`` (beyond the effect library,
``candidates.ROTOR_MOTION``: the rotor's speed ripple locked to the six-step commutation, an
angle per sector boundary falling with 1/speed^2; it is the rotor that moves, so calibration
never corrects it).
They are chosen by the selection engine (hil.gap.selection); for the held-out check the gap
test, knots, pole count, effects and values are chosen on every other stretch of time alone and
judged on the stretches held out, where only the trajectory is refitted. What capture times
cannot attribute is listed in ``not_assessed``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bldc.edges import electrical_speed_hz
from bldc.reasons import Reason
from hil.calibration.ordinary import (
    MIN_RUN_EDGES,
    SENSOR_OF_BOUNDARY,
    Effects,
    Fit,
    HallSteps,
    OrdinaryRunError,
    choose_knots,
    KNOT_CYCLES,
    choose_pole_pairs,
    fit_ordinary,
    hall_steps,
)
from hil.recording.format import Recording

from ..verdicts.plots import pyplot
from ..calibration.stats import chi2_p_value, inliers
from .candidates import ORDINARY_CANDIDATES
from .diagnose import Diagnosis, RankedEffect
from .relevance import Relevance, edge_relevance
from .result import (
    STATED_IN_RECORDING,
    ORDINARY_ROUTE,
    Confounded,
    HeldOut,
    FittedEffect,
    OrdinaryLocalisation,
    SensorPolarityMean,
    SplitHalf,
)
from .selection import ALPHA, BlockSums, Selection, Trial, confounded_rivals, forward_select, heldout_shrink

#: the model of the whole run: its used edges in this many consecutive stretches, each with its
#: own trajectory (the cells of the gap are per stretch)
MODEL_STRETCHES = 10
#: held-out design: the used edges in up to this many consecutive stretches, every other one held
#: out: the bootstrap of the held-out shrink resamples the held-out stretches (blocks of time, so
#: correlated residuals stay together)
N_STRETCHES = 20
#: a held-out stretch holds at least this many used edges (its own trajectory, 48 cells), so a
#: short capture gets fewer stretches (at least four: two held out)
MIN_STRETCH_EDGES = 150


def n_stretches(steps: HallSteps) -> int:
    """How many stretches the held-out design cuts ``steps`` into (an even number, 4 to 20).
    The whole run's model keeps ``MODEL_STRETCHES`` and chooses its knots and pole count on
    whole runs: cut finer, the trajectories of short stretches take up part of a slow pole
    pattern (on the hoverboard, 15 pole pairs gain 152 in BIC on whole runs, 125 in 10
    stretches, and 5 pole pairs win in 18)."""
    used = int(steps.used().sum())
    return int(min(N_STRETCHES, max(4, 2 * (used // (2 * MIN_STRETCH_EDGES)))))
#: speed bands of the cells (quantiles of the electrical speed)
N_SPEED_BANDS = 4
#: two estimates this correlated cannot be told apart by this capture
CONFOUND_CORR = 0.9

#: what capture times cannot show: a common lag, the absolute offset, the sampled-signal effects, the rotor's own
NOT_ASSESSED = [Reason("GAP-012"), Reason("GAP-013"), Reason("GAP-014"), Reason("GAP-015")]


def _merge(names: list[str], pole_pairs: int | None) -> Effects:
    """The calibration's fit with the column sets the candidates ``names`` declare switched on."""
    e = Effects(static=False, delay=False)
    for n in names:
        flag = ORDINARY_CANDIDATES[n].columns
        e = replace(e, pole_pairs=pole_pairs) if flag == "pole_pairs" else replace(e, **{flag: True})
    return e


def candidate_names(pole_pairs: int | None) -> list[str]:
    """The ordinary run's candidates in the order they are tried: those a pole count enables last."""
    names = list(ORDINARY_CANDIDATES)
    needs_poles = [n for n in names if ORDINARY_CANDIDATES[n].columns == "pole_pairs"]
    return [n for n in names if n not in needs_poles] + (needs_poles if pole_pairs else [])


def _stretched(steps: HallSteps, n: int) -> tuple[HallSteps, np.ndarray]:
    """``steps`` with each run cut at ``n`` equal stretches of the used edges (each stretch gets its
    own trajectory), and the stretch of every edge (-1 unused)."""
    used = np.nonzero(steps.used())[0]
    stretch = np.full(steps.t_s.size, -1, dtype=np.int64)
    stretch[used] = np.minimum((np.arange(used.size) * n) // max(used.size, 1), n - 1)
    run = np.where(steps.run >= 0, steps.run * n + stretch, -1)
    sizes = np.bincount(run[run >= 0]) if (run >= 0).any() else np.zeros(0, dtype=int)
    short = (run >= 0) & (sizes[np.maximum(run, 0)] < MIN_RUN_EDGES)
    run = np.where(short, -1, run)
    return replace(steps, run=run), stretch


def _cells(steps: HallSteps, fit: Fit, stretch: np.ndarray, band: np.ndarray) -> dict:
    """Cell means of the angle residual: (stretch, direction, boundary, speed band)."""
    idx = fit.index
    r = fit.residual_s / fit.tau_s_per_deg
    keep = inliers(fit.residual_s, fit.sigma_s)
    key = ((stretch[idx] * 2 + (steps.direction[idx] > 0)) * 6 + steps.label[idx]) * N_SPEED_BANDS + band[idx]
    key, r = key[keep], r[keep]
    uniq, inv = np.unique(key, return_inverse=True)
    n = np.bincount(inv).astype(float)
    mean = np.bincount(inv, weights=r) / n
    var = np.bincount(inv, weights=r**2) / n - mean**2
    ok = n >= 3
    return {
        "key": uniq[ok],
        "n": n[ok],
        "mean": mean[ok],
        "var_of_mean": var[ok] * n[ok] / (n[ok] - 1) / n[ok],
        "stretch": uniq[ok] // (2 * 6 * N_SPEED_BANDS),
    }


def _blocks(cells: dict) -> BlockSums:
    return BlockSums.of(cells["stretch"], cells["n"], cells["mean"], cells["var_of_mean"])


def _gap(cells: dict) -> float:
    """RMS over edges of the systematic part of the cell means (their noise removed)."""
    return _blocks(cells).gap()


def _p_value(cells: dict) -> float:
    chi2 = float(np.sum(cells["mean"] ** 2 / np.maximum(cells["var_of_mean"], 1e-12)))
    return chi2_p_value(chi2, cells["n"].size)


def _chi2(fit: Fit, ref: Fit) -> tuple[float, int]:
    """Chi-square of ``fit`` with the noise of ``ref`` over the edges neither left out, and their
    number (every candidate shares the trajectory splines and the edges; each fit's own noise
    estimate would make every chi-square about n)."""
    keep = inliers(ref.residual_s, ref.sigma_s) & inliers(fit.residual_s, fit.sigma_s)
    z = fit.residual_s[keep] / ref.sigma_s[keep]
    return float(np.sum(z**2)), int(keep.sum())


def _params(name: str, fit: Fit) -> tuple[dict, dict]:
    """The effect's parameters and their standard errors, named with their units (its declaration)."""
    sig = ORDINARY_CANDIDATES[name]
    if sig.scalar:
        v, e = fit.get(sig.coefficients)
        return {sig.key: v}, {sig.key: e}
    got = [(k, *fit.get(k)) for k in fit.names if k.startswith(sig.coefficients)]
    return {sig.key: {k: float(v) for k, v, _ in got}}, {sig.key: {k: float(e) for k, _, e in got}}


@dataclass
class _Pipeline:
    """What the capture (or its training stretches) chooses: knots, pole pairs, effects, fits."""

    knot_cycles: float
    pole_pairs: int | None
    pole_note: Reason  #: where the pole pairs come from (stated, found, or none found)
    names: list[str]
    sel: Selection
    relevance: dict[str, Relevance]
    none: Fit  #: the trajectory alone
    full: Fit  #: the trajectory with the chosen effects
    p_value: float
    single_gap: dict[str, float]  #: gap with each candidate alone (for the figures)

    @property
    def effects(self) -> Effects:
        return _merge(self.sel.fitted, self.pole_pairs)


def _pipeline(
    steps: HallSteps, tick: float | None, stated_pole_pairs: int | None, stretch, band, choice: HallSteps
) -> _Pipeline:
    """Knots, pole pairs and effects chosen on the used edges of ``steps`` alone, by the engine;
    the knots and the pole count on ``choice`` (the same edges, in whole runs where it can)."""
    kc, base = choose_knots(choice, tick)  # the calibration's model: the pole search sees the same
    pole_pairs, p_note = stated_pole_pairs, STATED_IN_RECORDING
    if not pole_pairs:
        pole_pairs, p_note = choose_pole_pairs(choice, tick, base, kc)
    names = candidate_names(pole_pairs)

    def fit(effects: list[str]) -> Fit:
        return fit_ordinary(steps, _merge(effects, pole_pairs), tick_s=tick, knot_cycles=kc)

    f0 = fit([])
    chi2_0, n_obs = _chi2(f0, f0)
    p0 = _p_value(_cells(steps, f0, stretch, band))
    fits: dict[tuple, Fit] = {(): f0}

    def fit_set(effects: list[str]) -> Fit:
        key = tuple(sorted(effects))
        if key not in fits:
            fits[key] = fit(effects)
        return fits[key]

    def try_add(fitted: list[str], name: str) -> Trial | None:
        f = fit_set(fitted + [name])
        k = len(f.names) - len(fit_set(fitted).names)
        if k <= 0:
            return None
        return Trial(name, _chi2(f, f0)[0], k, True, fit=f)

    def remainder_p(_fitted, t: Trial) -> float:
        return _p_value(_cells(steps, t.fit, stretch, band))

    if p0 < ALPHA:
        sel = forward_select(names, try_add, chi2_0, n_obs, remainder_p)
    else:
        sel = Selection([], [], {}, [], chi2_0, chi2_0, n_obs)
    relevance: dict[str, Relevance] = {}
    before = np.zeros(f0.index.size)
    for t in sel.steps:
        relevance[t.name] = edge_relevance(t.fit.trail_deg_e - before, np.ones(before.size))
        before = t.fit.trail_deg_e
    single_gap = {n: _gap(_cells(steps, sel.first[n].fit, stretch, band)) for n in sel.first}
    return _Pipeline(kc, pole_pairs, p_note, names, sel, relevance, f0, fit_set(sel.fitted), p0, single_gap)


def diagnose_ordinary(rec: Recording, steps: HallSteps, notes: list[Reason] | None = None) -> Diagnosis:
    """The diagnosis of an ordinary run (one result type with the segments route)."""
    tick = rec.timer_tick_s
    f_hz = electrical_speed_hz(steps.t_s, window_sectors=2, run=steps.run)
    edges_b = np.quantile(f_hz[steps.used()], np.linspace(0, 1, N_SPEED_BANDS + 1))
    band = np.clip(np.searchsorted(edges_b, f_hz, side="right") - 1, 0, N_SPEED_BANDS - 1)
    band = np.where(np.isfinite(f_hz), band, 0)
    st, stretch = _stretched(steps, MODEL_STRETCHES)
    whole = _pipeline(st, tick, rec.stated_pole_pairs, stretch, band, choice=steps)
    sel, full = whole.sel, whole.full
    significant = whole.p_value < ALPHA
    gap_before = _gap(_cells(st, whole.none, stretch, band))
    below = {n for n, r in whole.relevance.items() if not r.relevant}
    accepted = [n for n in sel.fitted if n not in below]
    # shares of the squared gap (the cell means' systematic part: a per-edge chi-square carries the
    # trajectory fit's own noise estimate, which already holds the pattern)
    g0 = max(gap_before, 1e-12)
    share_alone = {n: max(1.0 - (whole.single_gap.get(n, g0) / g0) ** 2, 0.0) for n in whole.names}
    share_added, prev = {}, 1.0
    for t in sel.steps:
        now = (_gap(_cells(st, t.fit, stretch, band)) / g0) ** 2
        share_added[t.name] = max(prev - now, 0.0)
        prev = now
    rest = sorted((n for n in whole.names if n not in sel.fitted), key=lambda n: -share_alone[n])
    ranking = [
        RankedEffect(n, round(share_alone[n], 4),
                     round(float(share_added[n]), 4) if n in share_added else None, n in below)
        for n in sel.fitted + rest
    ]
    rows = {}
    for n in sel.fitted:
        params, stderr = _params(n, full)
        rows[n] = FittedEffect(n, params, stderr, whole.relevance[n])
    remainder_p = _p_value(_cells(st, full, stretch, band))
    unexplained = bool(significant and remainder_p < ALPHA)
    shrink, after, interval, held = _heldout(steps, band, tick, rec.stated_pole_pairs, bool(accepted))
    confounded = [list(t) for t in sel.ties]

    def refit_chi2(m: str) -> float:
        return _chi2(fit_ordinary(st, _merge(sel.fitted + [m], whole.pole_pairs), tick_s=tick,
                                  knot_cycles=whole.knot_cycles), whole.none)[0]

    # what each explains alone: its share of the squared gap (see the ranking)
    rivals = confounded_rivals(sel, accepted, whole.names, refit_chi2, alone=share_alone)
    confounded += [p for p in rivals if p not in confounded]
    if "conditioning_delay" in accepted and "hysteresis" in accepted:
        # both earned their place; they are confounded only if this capture cannot separate them
        delay, delay_se = full.get("delay_diff_s")
        pair = ["conditioning_delay", "hysteresis"]
        if _delay_switch_corr(full) > CONFOUND_CORR and delay_se > 0.1 * abs(delay) and pair not in confounded:
            confounded.append(pair)
    not_assessed = list(NOT_ASSESSED) + list(notes or [])
    if not whole.pole_pairs:
        not_assessed.append(Reason("GAP-016", {"pole_note": whole.pole_note}))
    bic_alone = {n: round(t.delta_bic, 1) for n, t in sel.first.items()}
    return Diagnosis(
        significant=significant,
        ranking=ranking,
        accepted=[rows[n] for n in accepted],
        below_relevance=[rows[n] for n in sel.fitted if n in below],
        confounded=[Confounded(pair) for pair in confounded],
        unexplained=unexplained,
        gap_before=gap_before,
        gap_after_heldout=after,
        heldout_shrink=shrink,
        heldout_interval=interval,
        heldout=held,
        localisation=_localise(st, whole.none),
        noise_floor_deg_e={
            "edge_angle_rms": float(np.sqrt(np.median((whole.none.residual_s / whole.none.tau_s_per_deg) ** 2)))
        },
        p_value=whole.p_value,
        reference="none (capture times only: an ordinary run)",
        not_assessed=not_assessed,
        route=ORDINARY_ROUTE,
        pole_pairs=whole.pole_pairs,
        pole_pairs_source=whole.pole_note,
        knot_cycles=whole.knot_cycles,
        remainder_p_value=remainder_p,
        repeatability=split_half(steps, whole.effects, tick, whole.knot_cycles),
        ranking_bic_gain=bic_alone,
    )


def _heldout(steps: HallSteps, band, tick, stated_pole_pairs, any_accepted: bool):
    """Every other stretch trains: the gap test, the knots, the pole pairs, the effects and their
    values are chosen there alone; the held-out stretches are then fitted with those effects fixed
    and only their own speed trajectory free. Returns (shrink, gap after, interval, how: HeldOut)."""
    if not any_accepted:
        return None, None, None, HeldOut("no effect accepted")
    n_st = n_stretches(steps)
    st, stretch = _stretched(steps, n_st)
    train = np.isin(stretch, np.arange(0, n_st, 2))
    test = np.isin(stretch, np.arange(1, n_st, 2))
    try:
        train_steps = replace(st, run=np.where(train, st.run, -1))
        t = _pipeline(train_steps, tick, stated_pole_pairs, stretch, band, choice=train_steps)
    except OrdinaryRunError as exc:
        return None, None, None, HeldOut("not measurable", reason=str(exc))
    chosen = [n for n in t.sel.fitted if t.relevance[n].relevant]
    if not chosen:
        return 0.0, None, None, HeldOut("training chose none")
    f_train = fit_ordinary(st, _merge(chosen, t.pole_pairs), select=train, tick_s=tick, knot_cycles=t.knot_cycles)
    h0 = fit_ordinary(st, _merge([], t.pole_pairs), select=test, tick_s=tick, knot_cycles=t.knot_cycles)
    h1 = fit_ordinary(
        st, _merge(chosen, t.pole_pairs), select=test, tick_s=tick, knot_cycles=t.knot_cycles, fixed_from=f_train
    )
    res = heldout_shrink(_blocks(_cells(st, h0, stretch, band)), _blocks(_cells(st, h1, stretch, band)))
    held = HeldOut("stretches", stretches=n_st, knot_cycles=t.knot_cycles, pole_pairs=t.pole_pairs,
                   chosen=tuple(chosen), gap_before_deg_e=res.before, segments=res.blocks, shrink=res.shrink)
    return res.shrink, res.after, res.interval, held


def report_fit(rec: Recording, d: Diagnosis) -> tuple[HallSteps, Fit]:
    """The stretched steps and the joint fit of the kept effects that ``d`` chose (for figures)."""
    st, _ = _stretched(hall_steps(rec.t_s, rec.sensor, rec.rising), MODEL_STRETCHES)
    kept = [a.effect for a in d.accepted + d.below_relevance]
    eff = _merge(kept, d.pole_pairs)
    return st, fit_ordinary(st, eff, tick_s=rec.timer_tick_s, knot_cycles=d.knot_cycles or KNOT_CYCLES)


def _delay_switch_corr(fit: Fit) -> float:
    i = fit.names.index("delay_diff_s")
    js = [j for j, n in enumerate(fit.names) if n.startswith("switch_")]
    if not js:
        return 0.0
    w = np.zeros(len(fit.names))
    w[js] = 1.0 / len(js)
    cov_dw = float(fit.cov[i] @ w)
    var_w = float(w @ fit.cov @ w)
    return abs(cov_dw) / np.sqrt(max(fit.cov[i, i] * var_w, 1e-300))


def _localise(st: HallSteps, f: Fit) -> OrdinaryLocalisation:
    """Mean angle residual of the trajectory-only fit per sensor and polarity (deg e, + = trails)."""
    idx = f.index
    r = f.residual_s / f.tau_s_per_deg
    keep = inliers(f.residual_s, f.sigma_s)
    sensor = SENSOR_OF_BOUNDARY[np.mod(st.label[idx], 3)]
    out = []
    for x, name in enumerate("ABC"):
        for rising, pol in ((True, "rise"), (False, "fall")):
            sel = keep & (sensor == x) & (st.rising[idx] == rising)
            out.append(SensorPolarityMean(name, pol, float(np.mean(r[sel])) if sel.any() else None))
    return OrdinaryLocalisation(out)


def split_half(steps: HallSteps, eff: Effects, tick: float | None, kc: float) -> SplitHalf:
    """The same model fitted on the first and the second half of the run (by edge count): how far
    the estimates repeat on the same motor."""
    used = np.nonzero(steps.used())[0]
    first = np.zeros(steps.t_s.size, dtype=bool)
    first[used[: used.size // 2]] = True
    second = np.zeros(steps.t_s.size, dtype=bool)
    second[used[used.size // 2 :]] = True
    halves = []
    for sel in (first, second):
        try:
            halves.append(fit_ordinary(steps, eff, select=sel, tick_s=tick, knot_cycles=kc))
        except OrdinaryRunError as exc:
            return SplitHalf(failure=str(exc))
    delay = stderr = None
    if "delay_diff_s" in halves[0].names and "delay_diff_s" in halves[1].names:
        (a, sa), (b, sb) = halves[0].get("delay_diff_s"), halves[1].get("delay_diff_s")
        delay, stderr = (a, b), (sa, sb)
    # the static offsets of each half as angles per sensor boundary and direction
    common = [n for n in halves[0].names if n in halves[1].names and n != "delay_diff_s"]
    if not common:
        return SplitHalf(delay_diff_s=delay, delay_diff_stderr_s=stderr)
    va = np.array([halves[0].get(n)[0] for n in common])
    vb = np.array([halves[1].get(n)[0] for n in common])
    return SplitHalf(
        delay_diff_s=delay,
        delay_diff_stderr_s=stderr,
        static_rms_difference_deg_e=float(np.sqrt(np.mean((va - vb) ** 2))),
        static_rms_deg_e=float(np.sqrt(np.mean(((va + vb) / 2) ** 2))),
    )


# --- report ------------------------------------------------------------------------------------


def sector_width_figure(steps: HallSteps, fit: Fit, title: str = ""):
    """Sector width (deg e) against electrical speed, per sector (the edge that opens it), before and
    after the fitted effects are taken off the edge times: the picture a user wants first."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    idx = fit.index
    t = steps.t_s[idx]
    sensor_trail = fit.trail_deg_e if fit.sensor_trail_deg_e is None else fit.sensor_trail_deg_e
    corrected = t - sensor_trail * fit.tau_s_per_deg
    run = steps.run[idx]
    sensor = SENSOR_OF_BOUNDARY[np.mod(steps.label[idx], 3)]
    same = run[1:] == run[:-1]
    k = np.nonzero(same)[0]  # sector k opens at edge k
    # the local speed (Hz e): an electrical turn of captured sectors around each one (bldc.edges)
    f_edge = electrical_speed_hz(t, window_sectors=6, run=run)
    speed = 0.5 * (f_edge[1:] + f_edge[:-1])[same]
    for ax, times, what in ((axes[0], t, "as captured"), (axes[1], corrected, "after calibration")):
        width = 360.0 * np.diff(times)[same] * speed
        for x, name in enumerate("ABC"):
            for rising, mk in ((True, "^"), (False, "v")):
                sel = (sensor[k] == x) & (steps.rising[idx][k] == rising) & np.isfinite(width)
                if not sel.any():
                    continue
                order = np.argsort(speed[sel])
                xs, ys = speed[sel][order], width[sel][order]
                bins = np.array_split(np.arange(xs.size), max(min(xs.size // 40, 30), 1))
                ax.plot(
                    [xs[b].mean() for b in bins],
                    [ys[b].mean() for b in bins],
                    marker=mk,
                    ms=4,
                    lw=1,
                    label=f"sector opened by {name} {'rise' if rising else 'fall'}",
                )
        ax.axhline(60.0, color="k", lw=0.8, ls=":")
        ax.set_xlabel("electrical speed (Hz)")
        ax.set_title(what)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("sector width (deg e), binned means")
    axes[1].legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def save_sector_width_figure(path, steps: HallSteps, fit: Fit, title: str = "") -> None:
    from pathlib import Path

    fig = sector_width_figure(steps, fit, title)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    pyplot().close(fig)
