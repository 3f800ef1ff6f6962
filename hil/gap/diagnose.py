"""Diagnose the sim-to-real gap of a recording (docs/gap.md; the output keys are in docs/recording-format.md).

Where: per-edge residuals against the model, localised per sensor, polarity, pole, operating
region and mechanical order, gated against the noise floor estimated inside each residual
cell (segment x sensor x polarity x pole). Which: every candidate effect is scored by the
chi-square it removes from the cell means (weighted by effective sample sizes corrected for
autocorrelation), accepted by the selection engine (hil.gap.selection: forward selection with a
BIC penalty, parsimony ties and a physical-bounds check); pairs that explain the same pattern
equally are reported as confounded with the knob that separates them; a significant remainder is
"unexplained". How far: on all but one operating point the gap is tested and the effects are
chosen and fitted, and the gap is measured on the one held out, in turn.

The gap metric is the RMS over edges of the systematic residual (the cell means), in degrees
electrical: per-edge noise cannot be removed by any model and would cap the shrink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from bldc.reasons import Reason, words
from hil.recording.format import Recording
from plant_models.effects import EFFECTS

from ..calibration.stats import chi2_p_value
from .candidates import CANDIDATES
from .fitting import cell_rms
from .fitting import wls as _wls
from .relevance import Relevance, edge_relevance, jitter_relevance
from .residuals import EdgeResiduals, model_prediction, residuals
from .result import (
    EdgeLocalisation,
    FittedEffect,
    NoiseGap,
    OrderSpectrum,
    OrdinaryLocalisation,
    RegionResidual,
    SplitHalf,
    Confounded,
    STATED_IN_RECORDING,
    HeldOut,
    gap_metric,
    knob,
)
from .samples import EFFECT_DOMAIN, DomainDiagnosis, diagnose_samples
from .selection import (
    ALPHA,
    BlockSums,
    Selection,
    Trial,
    confounded_rivals,
    equal_within_noise,
    forward_select,
    heldout_shrink,
)

__all__ = ["ALPHA", "Diagnosis", "diagnose_segments", "equal_within_noise", "knob"]


@dataclass
class Cells:
    mean: np.ndarray
    n: np.ndarray
    n_eff: np.ndarray
    var: np.ndarray       #: noise variance of one edge in the cell's segment
    features: dict
    edge_cell: np.ndarray
    dof: np.ndarray       #: degrees of freedom of the segment's pooled noise variance

    @property
    def weight(self) -> np.ndarray:
        return self.n_eff / self.var

    def subset(self, keep: np.ndarray) -> "Cells":
        """The cells ``keep`` (a boolean mask) alone: what a held-out check trains on."""
        feats = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in self.features.items()}
        n, n_eff, var, dof = self.n[keep], self.n_eff[keep], self.var[keep], self.dof[keep]
        return Cells(self.mean[keep], n, n_eff, var, feats, self.edge_cell, dof)


def build_cells(r: EdgeResiduals) -> Cells:
    cid = r.cell_index()
    uniq, inv = np.unique(cid, return_inverse=True)
    n = np.bincount(inv).astype(float)
    s1 = np.bincount(inv, r.residual_deg_e)
    mean = s1 / n
    dev = r.residual_deg_e - mean[inv]
    # lag-1 autocorrelation of the deviations, cell by cell in turn order (edges are in time order)
    order = np.lexsort((np.arange(len(r)), inv))
    d_sorted, c_sorted = dev[order], inv[order]
    same = c_sorted[1:] == c_sorted[:-1]
    num = np.bincount(c_sorted[1:][same], d_sorted[1:][same] * d_sorted[:-1][same], minlength=uniq.size)
    den = np.bincount(inv, dev * dev, minlength=uniq.size)
    # pooled noise variance per segment (the noise floor), from within-cell scatter
    seg_of_cell = np.zeros(uniq.size, dtype=np.int64)
    seg_of_cell[inv] = r.segment
    var_cell = den / np.maximum(n - 1, 1)
    var = np.empty(uniq.size)
    for s in np.unique(seg_of_cell):
        sel = seg_of_cell == s
        var[sel] = max(np.sum(var_cell[sel] * (n[sel] - 1)) / max(np.sum(n[sel] - 1), 1), 1e-12)
    rho_seg = np.empty(uniq.size)
    for s in np.unique(seg_of_cell):
        sel = seg_of_cell == s
        rho_seg[sel] = np.sum(num[sel]) / max(np.sum(den[sel]), 1e-300)
    # deviations from a cell's own mean carry a lag-1 correlation bias of about -1/n; correct it,
    # and never let a negative estimate inflate the sample size (stay conservative)
    n_mean = np.empty(uniq.size)
    for s in np.unique(seg_of_cell):
        sel = seg_of_cell == s
        n_mean[sel] = np.mean(n[sel])
    rho_seg = np.clip(rho_seg + 1.0 / np.maximum(n_mean - 1.0, 1.0), 0.0, 0.95)
    n_eff = n * (1 - rho_seg) / (1 + rho_seg)
    first = np.zeros(uniq.size, dtype=np.int64)
    first[inv[::-1]] = np.arange(len(r))[::-1]
    feats = {
        "sensor": r.sensor[first],
        "rising": r.rising[first],
        "pole": r.pole[first],
        "direction": r.direction[first].astype(float),
        "w_e": r.w_e_deg_s[first],
        "current": np.bincount(inv, r.current_a) / n,
        "load": r.load_scale[first],
        "segment": r.segment[first],
        "pole_pairs": r.pole_pairs,
    }
    dof = np.zeros(uniq.size)
    for seg_id in np.unique(seg_of_cell):
        sel = seg_of_cell == seg_id
        dof[sel] = max(np.sum(n[sel] - 1), 1)
    return Cells(mean, n, np.maximum(n_eff, 1.0), var, feats, inv, dof)


def _design(names, cells):
    if not names:
        return np.zeros((cells.mean.size, 0))
    return np.column_stack([CANDIDATES[n].columns(cells.features) for n in names])


def _remove_collinear(x: np.ndarray) -> np.ndarray:
    """Columns of x reduced to an independent set (QR with pivoting)."""
    if x.shape[1] == 0:
        return x
    from scipy.linalg import qr

    _, r, piv = qr(x, mode="economic", pivoting=True)
    tol = abs(r[0, 0]) * 1e-9 if r.size else 0
    rank = int(np.sum(np.abs(np.diag(r)) > tol))
    return x[:, np.sort(piv[:rank])]


@dataclass
class RankedEffect:
    """A candidate's row of the ranking: what it explains alone, and (kept) what it adds."""

    effect: str
    score: float  #: its share of the gap fitted alone (rounded to 4 places; shares of rivals overlap)
    share_added: float | None = None  #: kept: its share added after the effects chosen before it
    below_relevance: bool = False  #: kept, but too small to matter

    def to_json(self) -> dict:
        out: dict = {"effect": self.effect, "score": self.score}
        if self.share_added is not None:
            out["share_added"] = self.share_added
        if self.below_relevance:
            out["below_relevance"] = True
        return out


@dataclass
class Diagnosis:
    significant: bool
    ranking: list[RankedEffect]
    accepted: list[FittedEffect]
    confounded: list[Confounded]
    unexplained: bool
    gap_before: float
    gap_after_heldout: float | None
    heldout_shrink: float | None
    heldout_interval: list[float] | None = None
    heldout: HeldOut = HeldOut()  #: how the held-out figures were measured, or why not
    localisation: EdgeLocalisation | OrdinaryLocalisation | None = None
    noise_floor_deg_e: dict[str, float] = field(default_factory=dict)  #: per segment id (ordinary: one figure)
    p_value: float = 1.0
    reference: str = "encoder"
    not_assessed: list[Reason] = field(default_factory=list)  #: what this route cannot assess, and why
    noise_gap: NoiseGap | None = None  #: None: an ordinary run (no per-segment noise to test)
    samples: dict[str, DomainDiagnosis] = field(default_factory=dict)  #: per sampled domain (voltage, speed)
    below_relevance: list[FittedEffect] = field(default_factory=list)  #: detected, fitted, too small to matter
    #: (domain, unit) of the sampled signal whose gap the headline figures are; None: the edges'
    gap_sampled: tuple[str, str] | None = None
    #: "segments" (a recording with operating points) or "ordinary run" (capture times only)
    route: str = "segments"
    pole_pairs: int | None = None
    pole_pairs_source: Reason = STATED_IN_RECORDING  #: stated, found (with its BIC gain) or not found
    knot_cycles: float | None = None  #: an ordinary run's trajectory knot spacing (electrical cycles)
    remainder_p_value: float | None = None  #: the remainder after the kept effects, against the noise floor
    repeatability: SplitHalf | None = None  #: an ordinary run's split-half figures
    ranking_bic_gain: dict[str, float] = field(default_factory=dict)  #: BIC gain of each candidate alone

    @property
    def heldout_note(self) -> str:
        return self.heldout.text()

    @property
    def gap_metric(self) -> str:
        """What the gap figures measure, worded (``hil.gap.result.gap_metric``)."""
        return gap_metric(self.route, self.gap_sampled)

    def to_json(self) -> dict:
        return {
            "route": self.route,
            "pole_pairs": self.pole_pairs,
            "pole_pairs_source": words(self.pole_pairs_source),
            "knot_cycles": self.knot_cycles,
            "remainder_p_value": self.remainder_p_value,
            "repeatability": self.repeatability.to_json() if self.repeatability else {},
            "ranking_bic_gain": self.ranking_bic_gain,
            "significant": self.significant,
            "ranking": [r.to_json() for r in self.ranking],
            "accepted": [a.to_json(self.route) for a in self.accepted],
            "confounded": [c.names for c in self.confounded],
            "unexplained": self.unexplained,
            "gap_before": self.gap_before,
            "gap_after_heldout": self.gap_after_heldout,
            "heldout_shrink": self.heldout_shrink,
            "heldout_interval": self.heldout_interval,
            "heldout_note": self.heldout_note,
            "knobs": {"/".join(c.names): c.knob(self.route) for c in self.confounded},
            "gap_metric": self.gap_metric,
            "p_value": self.p_value,
            "reference": self.reference,
            "noise_floor_deg_e": self.noise_floor_deg_e,
            "localisation": self.localisation.to_json() if self.localisation else {},
            "not_assessed": [words(n) for n in self.not_assessed],
            "noise_gap": self.noise_gap.to_json() if self.noise_gap else {},
            "samples": {k: v.to_json() for k, v in self.samples.items()},
            "below_relevance": [b.to_json(self.route) for b in self.below_relevance],
        }


@dataclass
class EdgeSelection:
    sel: Selection  #: the engine's selection (order, single-effect trials, ties)
    below: dict[str, Relevance]  #: of the kept effects, the ones below practical relevance
    relevance: dict[str, Relevance]  #: relevance of every kept effect

    @property
    def fitted(self) -> list[str]:
        return self.sel.fitted

    @property
    def accepted(self) -> list[str]:
        return [n for n in self.sel.fitted if n not in self.below]


def _try_add(cells: Cells):
    """The engine's view of the edge cells: ``fitted`` plus ``name`` by weighted least squares."""
    w, y = cells.weight, cells.mean

    def try_add(fitted: list[str], name: str) -> Trial | None:
        x_acc = _design(fitted, cells)
        k_acc = _remove_collinear(x_acc).shape[1]
        x_c = CANDIDATES[name].columns(cells.features)
        x = np.column_stack([x_acc, x_c])
        k_new = _remove_collinear(x).shape[1] - k_acc
        if k_new <= 0:
            return None
        coef, se, chi2 = _wls(x, y, w)
        k_c = x_c.shape[1]
        physical = CANDIDATES[name].physical(coef[-k_c:], se[-k_c:])
        return Trial(name, chi2, k_new, physical, fit=x @ coef)

    return try_add


def _select(cells: Cells, candidates: list[str]) -> EdgeSelection:
    """Forward selection by the engine (hil.gap.selection), then parsimony swaps, then practical
    significance: each chosen effect's predicted angle shift (what it adds to the fit before it)
    is tested against its practical floor; below it, the effect stays in the fit but is not
    accepted."""
    n_cells = cells.mean.size
    chi2_0 = float(np.sum(cells.weight * cells.mean**2))

    def remainder_p(fitted: list[str], t: Trial) -> float:
        return chi2_p_value(t.chi2, max(n_cells - _rank(fitted, cells), 1))

    sel = forward_select(candidates, _try_add(cells), chi2_0, n_cells, remainder_p)
    below: dict[str, Relevance] = {}
    relevance: dict[str, Relevance] = {}
    pred_now = np.zeros_like(cells.mean)
    for t in sel.steps:
        rel = edge_relevance(t.fit - pred_now, cells.n)
        relevance[t.name] = rel
        if not rel.relevant:
            below[t.name] = rel
        pred_now = t.fit
    sel.chi2_end = _parsimony_swaps(cells, candidates, sel, below, relevance)
    return EdgeSelection(sel, below, relevance)


def _rank(names: list[str], cells: Cells) -> int:
    return _remove_collinear(_design(names, cells)).shape[1]


def _parsimony_swaps(cells, candidates, sel: Selection, below, relevance) -> float:
    """After forward selection: replace a kept effect by a rival with fewer parameters when the
    whole set then explains the same within noise. Forward selection can take the bigger model
    first when it also soaks up part of another cause (a per-pole pattern absorbs the rising /
    falling split of a delay at one speed, because rising and falling edges alternate with the
    poles), and the smaller one never earns its place once the bigger is in. Edits
    ``sel.fitted``, ``sel.ties``, ``below`` and ``relevance``; returns the new remainder chi-square."""
    w, y = cells.weight, cells.mean
    fitted, chi2_0, chi2_now = sel.fitted, sel.chi2_0, sel.chi2_end
    swapped = True
    while swapped:
        swapped = False
        k_full = _rank(fitted, cells)
        for i, a in enumerate(list(fitted)):
            for b in candidates:
                if b in fitted:
                    continue
                alt = fitted[:i] + [b] + fitted[i + 1 :]
                k_alt = _rank(alt, cells)
                if k_alt >= k_full:
                    continue
                x_alt = _design(alt, cells)
                coef, se, chi2_alt = _wls(x_alt, y, w)
                col = sum(CANDIDATES[n].columns(cells.features).shape[1] for n in alt[:i])
                k_b = CANDIDATES[b].columns(cells.features).shape[1]
                if not CANDIDATES[b].physical(coef[col : col + k_b], se[col : col + k_b]):
                    continue
                if not equal_within_noise(chi2_0 - chi2_now, k_full, chi2_0 - chi2_alt, k_alt):
                    continue
                # what b adds to the set without it: its practical relevance
                rest = alt[:i] + alt[i + 1 :]
                pred_rest = _design(rest, cells) @ _wls(_design(rest, cells), y, w)[0] if rest else np.zeros_like(y)
                rel = edge_relevance(x_alt @ coef - pred_rest, cells.n)
                fitted[i] = b
                below.pop(a, None)
                relevance.pop(a, None)
                relevance[b] = rel
                if not rel.relevant:
                    below[b] = rel
                sel.ties.append([b, a])
                chi2_now = chi2_alt
                swapped = True
                break
            if swapped:
                break
    return chi2_now


def _n_params(name: str, cells: Cells) -> int:
    return _remove_collinear(CANDIDATES[name].columns(cells.features)).shape[1]


def edge_features(r: EdgeResiduals) -> dict:
    """Per-edge features in the form the candidates' columns take (one row per edge)."""
    return {
        "sensor": r.sensor,
        "rising": r.rising,
        "pole": r.pole,
        "direction": r.direction.astype(float),
        "w_e": r.w_e_deg_s,
        "current": r.current_a,
        "load": r.load_scale,
        "segment": r.segment,
        "pole_pairs": r.pole_pairs,
    }


def _edge_selection(cells: Cells, names: list[str]) -> tuple[float, EdgeSelection]:
    """The gap's p-value against the noise floor, and the selection when it is significant."""
    chi2_0 = float(np.sum(cells.weight * cells.mean**2))
    p0 = chi2_p_value(chi2_0, cells.mean.size)
    if p0 >= ALPHA:
        return p0, EdgeSelection(Selection([], [], {}, [], chi2_0, chi2_0, cells.mean.size), {}, {})
    return p0, _select(cells, names)


def diagnose_segments(rec: Recording, model=None, candidates: list[str] | None = None) -> Diagnosis:
    """Diagnose a recording with operating points against ``model`` (a PlantConfig; None = the
    nominal motor, no effects)."""
    r = residuals(rec, model_prediction(model, rec) if model is not None else None)
    if len(r) < 6 * rec.pole_pairs:
        raise ValueError(f"{rec.path or 'recording'}: too few usable edges ({len(r)}) to diagnose")
    cells = build_cells(r)
    names = list(candidates or CANDIDATES)
    if r.reference == "turn":
        # relative errors: common shifts and equal lags are invisible without an encoder
        names = [n for n in names if not CANDIDATES[n].needs_encoder]
    n_cells = cells.mean.size
    p0, es = _edge_selection(cells, names)
    significant = p0 < ALPHA
    sel = es.sel
    accepted_names = es.accepted
    below_names = [n for n in sel.fitted if n in es.below]
    k_of = {n: _n_params(n, cells) for n in names}
    # ranking: accepted first (in order), then the ones detected below practical relevance, then
    # by single-effect score (scores equal to three decimals: fewer parameters first)
    rest = sorted((n for n in names if n not in sel.fitted), key=lambda n: (-round(sel.share_alone(n), 3), k_of[n]))
    ranking = [RankedEffect(n, round(sel.share_alone(n), 4)) for n in accepted_names + below_names + rest]
    excess = max(sel.chi2_0 - n_cells, 1e-12)
    chi2_prev = sel.chi2_0
    share_added = {}
    for i, n in enumerate(sel.fitted):  # what each kept effect adds after those before it
        chi2_i = _wls(_design(sel.fitted[: i + 1], cells), cells.mean, cells.weight)[2]
        share_added[n] = round(max(chi2_prev - chi2_i, 0.0) / excess, 4)
        chi2_prev = chi2_i
    for row in ranking:
        row.share_added = share_added.get(row.effect)
        row.below_relevance = row.effect in es.below
    # fitted parameters of every kept effect, jointly on all data
    accepted, below = [], []
    if sel.fitted:
        x = _design(sel.fitted, cells)
        coef, se, _ = _wls(x, cells.mean, cells.weight)
        col = 0
        for n in sel.fitted:
            k = CANDIDATES[n].columns(cells.features).shape[1]
            c, s_c = coef[col : col + k], se[col : col + k]
            row = FittedEffect(n, CANDIDATES[n].params(c), CANDIDATES[n].stderr(c, s_c), es.relevance[n])
            (below if n in es.below else accepted).append(row)
            col += k
    dof_end = max(n_cells - _rank(sel.fitted, cells), 1)
    unexplained = bool(significant and chi2_p_value(sel.chi2_end, dof_end) < ALPHA)
    confounded: list[Confounded] = []

    def confound(a: str, b: str) -> None:
        pair = sorted([a, b])
        if all(c.names != pair for c in confounded):
            confounded.append(Confounded(pair, (a, b)))

    # equal within noise at selection: the smaller model was kept, the rival stays named
    for chosen, rival in sel.ties:
        confound(chosen, rival)

    def refit_chi2(m: str) -> float:
        x_both = _remove_collinear(np.column_stack([_design(sel.fitted, cells), CANDIDATES[m].columns(cells.features)]))
        return _wls(x_both, cells.mean, cells.weight)[2]

    for pair in confounded_rivals(sel, accepted_names, names, refit_chi2):
        confound(*pair)
    shrink, after, interval, held = _heldout(cells, names) if accepted_names else (None, None, None, HeldOut())
    if not accepted_names:
        shrink, held = (0.0, HeldOut("no effect accepted")) if np.unique(cells.features["segment"]).size > 1 else (
            None, HeldOut("single segment"))
    if below_names and not accepted_names:
        held = HeldOut("below relevance")
    # the noise: edge jitter is a variance effect; accepted quantisation adds its own variance
    tick_fit = next((a.params["tick_s"] for a in accepted + below if a.effect == "timer_quantization"), 0.0)
    expected = expected_noise_var(cells.features["w_e"], model, rec.timer_tick_s, tick_fit)
    p_noise, jitter_params, jitter_score, noise_before, noise_after, noise_shrink = _noise_gap(cells, expected)
    noise_significant = p_noise < ALPHA
    jitter_row = RankedEffect("edge_jitter", round(jitter_score if noise_significant else 0.0, 4))
    if noise_significant:
        rel = jitter_relevance(
            jitter_params["time_rms_s"], jitter_params["angle_rms_deg_e"], cells.features["w_e"], cells.n
        )
        row = FittedEffect("edge_jitter", jitter_params, relevance=rel)
        if rel.relevant:
            accepted.append(row)
            ranking.insert(len(accepted_names), jitter_row)
        else:
            below.append(row)
            jitter_row.below_relevance = True
            ranking.insert(len(accepted_names) + len(below_names), jitter_row)
    else:
        ranking.append(jitter_row)
    if not significant and noise_significant and shrink is None and noise_shrink is not None:
        held = HeldOut("noise only")
    diagnosis = Diagnosis(
        significant=significant or noise_significant,
        ranking=ranking,
        accepted=accepted,
        confounded=confounded,
        unexplained=unexplained,
        gap_before=cell_rms(cells.mean, cells.n),
        gap_after_heldout=after,
        heldout_shrink=shrink,
        heldout_interval=interval,
        heldout=held,
        noise_gap=NoiseGap(p_noise, noise_significant, noise_before, noise_after, noise_shrink),
        localisation=localise(r, cells),
        p_value=p0,
        reference=r.reference,
        noise_floor_deg_e={
            str(rec.segments[s].id): float(np.sqrt(cells.var[cells.features["segment"] == s][0]))
            for s in np.unique(cells.features["segment"])
        },
        below_relevance=below,
        pole_pairs=rec.pole_pairs,
        remainder_p_value=chi2_p_value(sel.chi2_end, dof_end),
        ranking_bic_gain={n: round(t.delta_bic, 1) for n, t in sel.first.items()},
    )
    edge_error = None
    if r.reference == "turn" and sel.fitted:
        # without an encoder the sampled signals' angle comes from these very edges: what the
        # kept edge effects predict for each edge moves it to where the rotor was
        xe = np.column_stack([CANDIDATES[n].columns(edge_features(r)) for n in sel.fitted])
        edge_error = np.zeros(len(rec))
        edge_error[r.edge_index] = xe @ coef
    _add_samples(diagnosis, rec, model, edge_error)
    return diagnosis


def _add_samples(d: Diagnosis, rec: Recording, model, edge_error_deg_e: np.ndarray | None = None) -> None:
    """Fold the sampled signals' diagnosis (voltage equation, speed) into ``d``.

    Its accepted effects follow the edge effects; its candidates join the ranking by score.
    When the edges show no gap but a sampled signal does, the headline gap figures are that
    signal's (``gap_metric`` says which)."""
    domains = diagnose_samples(rec, model, edge_error_deg_e)
    d.samples = domains
    assessed = {n for dom in domains.values() for n in dom.first_scores}
    d.not_assessed = [Reason("GAP-010", {"effect": n, "no_trace": cls.no_trace}) for n, cls in EFFECTS.items()
                      if cls.no_trace]
    d.not_assessed += [Reason("GAP-011", {"effect": n}) for n in EFFECT_DOMAIN if n not in assessed]
    if not domains:
        return
    edge_rows = len(d.accepted) + len(d.below_relevance)
    extra_rows = []
    for dom in sorted(domains.values(), key=lambda x: x.p_value):
        if dom.significant:
            d.accepted.extend(dom.accepted)
            d.below_relevance.extend(dom.below_relevance)
            d.unexplained = d.unexplained or dom.unexplained
            d.confounded.extend(Confounded(pair) for pair in dom.confounded)
        for name, score in dom.first_scores.items():
            extra_rows.append(
                {
                    "effect": name,
                    "score": round(score if dom.significant else 0.0, 4),
                    "accepted": any(a.effect == name for a in dom.accepted) and dom.significant,
                    "below": any(a.effect == name for a in dom.below_relevance) and dom.significant,
                }
            )
    accepted_extra = [RankedEffect(x["effect"], x["score"]) for x in extra_rows if x["accepted"]]
    below_extra = [RankedEffect(x["effect"], x["score"], below_relevance=True) for x in extra_rows if x["below"]]
    rest = [RankedEffect(x["effect"], x["score"]) for x in extra_rows if not (x["accepted"] or x["below"])]
    n_acc = sum(1 for r in d.ranking[:edge_rows] if not r.below_relevance)
    head, head_below = d.ranking[:n_acc], d.ranking[n_acc:edge_rows]
    tail = sorted(d.ranking[edge_rows:] + rest, key=lambda x: -x.score)
    d.ranking = head + accepted_extra + head_below + below_extra + tail
    sampled_gap = [dom for dom in sorted(domains.values(), key=lambda x: x.p_value) if dom.significant]
    if sampled_gap and d.p_value >= ALPHA:  # no mean edge gap: the headline is the sampled signal's
        dom = sampled_gap[0]
        d.gap_sampled = (dom.domain, dom.unit)
        d.gap_before, d.gap_after_heldout, d.heldout_shrink = dom.gap_before, dom.gap_after_heldout, dom.heldout_shrink
        d.heldout_interval, d.heldout = dom.heldout_interval, dom.heldout
    d.significant = d.significant or bool(sampled_gap)


def expected_noise_var(w_e: np.ndarray, model, tick_s: float | None, extra_tick_s: float = 0.0) -> np.ndarray:
    """Per-edge noise variance (deg_e^2) the model expects: its own edge jitter, plus the capture
    timer (floor quantisation: tick^2 / 12 in time)."""
    var = np.zeros_like(w_e, dtype=float)
    if model is not None:
        cp = model.compile()
        var = var + (w_e * cp.jitter_time_rms_s) ** 2 + cp.jitter_angle_rms_deg_e**2
    tick2 = (tick_s or 0.0) ** 2 + extra_tick_s**2
    return var + (w_e**2) * tick2 / 12.0


def _noise_gap(cells: Cells, expected: np.ndarray):
    """Per-segment measured and expected noise; chi-square test of the excess; jitter fit with
    leave-one-segment-out shrink of the noise gap (RMS over segments of measured minus
    expected noise RMS, deg_e)."""
    seg = cells.features["segment"]
    segs = np.unique(seg)
    first = np.array([np.nonzero(seg == s)[0][0] for s in segs])
    var_m, var_e, dof = cells.var[first], expected[first], cells.dof[first]
    w = cells.features["w_e"][first]
    n_edges = np.array([cells.n[seg == s].sum() for s in segs])
    # pooled test: sum of dof * measured / expected is chi-square with sum(dof) under the model
    with np.errstate(divide="ignore"):
        stat = float(np.sum(dof * var_m / np.maximum(var_e, 1e-300)))
    p = chi2_p_value(stat, float(np.sum(dof))) if np.all(var_e > 0) else 0.0
    excess = var_m - var_e

    def fit(idx):
        a = np.column_stack([w[idx] ** 2, np.ones(idx.size)])
        coef, _ = nnls(a * np.sqrt(n_edges[idx])[:, None], excess[idx] * np.sqrt(n_edges[idx]))
        return coef

    coef = fit(np.arange(segs.size))
    # the noise gap is the difference in noise RMS (deg_e) between recording and model
    sd_m, sd_e = np.sqrt(var_m), np.sqrt(np.maximum(var_e, 0.0))
    before = float(np.sqrt(np.sum(n_edges * (sd_m - sd_e) ** 2) / np.sum(n_edges)))
    after = shrink = None
    if segs.size >= 2:
        resid = np.empty(segs.size)
        for i in range(segs.size):
            c = fit(np.delete(np.arange(segs.size), i))
            resid[i] = sd_m[i] - math.sqrt(max(var_e[i] + c[0] * w[i] ** 2 + c[1], 0.0))
        after = float(np.sqrt(np.sum(n_edges * resid**2) / np.sum(n_edges)))
        shrink = 1 - after / before if before > 0 else 0.0
    explained = 1 - float(np.sum(n_edges * (excess - (coef[0] * w**2 + coef[1])) ** 2)) / max(
        float(np.sum(n_edges * excess**2)), 1e-300
    )
    params = {"time_rms_s": float(np.sqrt(coef[0])), "angle_rms_deg_e": float(np.sqrt(coef[1]))}
    return p, params, max(min(explained, 1.0), 0.0), before, after, shrink


def _heldout(cells: Cells, names: list[str]):
    """Leave one operating point out: on the other segments the gap is tested, the effects are
    chosen and fitted (the held-out segment influences neither), and they predict the held-out
    one. Returns (shrink, gap after, 5-95 % interval from a bootstrap over segments, how: HeldOut)."""
    seg = cells.features["segment"]
    segments = np.unique(seg)
    if segments.size < 2:
        return None, None, None, HeldOut("single segment")
    pred = np.zeros_like(cells.mean)
    fitted_ok = np.zeros(cells.mean.size, dtype=bool)
    differ = 0
    for s in segments:
        test = seg == s
        train_cells = cells.subset(~test)
        _, es = _edge_selection(train_cells, names)
        chosen = es.accepted
        if not chosen:
            fitted_ok[test] = True  # nothing chosen: the held-out segment keeps its gap
            differ += 1
            continue
        x = _design(chosen, cells)
        xt = x[~test]
        keep = np.any(xt != 0, axis=0)
        # a held-out cell that needs a column never seen in training cannot be predicted
        if not keep.any() or np.any(np.abs(x[test][:, ~keep]).sum(axis=0) > 0):
            continue
        coef, _, _ = _wls(xt[:, keep], cells.mean[~test], cells.weight[~test])
        pred[test] = x[test][:, keep] @ coef
        fitted_ok[test] = True
    if not fitted_ok.any():
        return None, None, None, HeldOut("unpredicted")
    ok = fitted_ok
    res = heldout_shrink(
        BlockSums.of(seg[ok], cells.n[ok], cells.mean[ok]), BlockSums.of(seg[ok], cells.n[ok], (cells.mean - pred)[ok])
    )
    held = HeldOut("leave one out", segments=res.blocks, segments_choosing_nothing=differ)
    return res.shrink, res.after, res.interval, held


def localise(r: EdgeResiduals, cells: Cells) -> EdgeLocalisation:
    res = r.residual_deg_e
    regions = []
    for s in np.unique(r.segment):
        sel = r.segment == s
        regions.append(
            RegionResidual(
                segment=int(s),
                speed_rpm=float(r.w_e_deg_s[sel][0] / (6 * r.pole_pairs)),
                current_a=float(r.current_a[sel][0]),
                load_scale=float(r.load_scale[sel][0]),
                direction=int(r.direction[sel][0]),
                mean_deg_e=float(np.mean(res[sel])),
                rms_deg_e=float(np.sqrt(np.mean(res[sel] ** 2))),
            )
        )
    # order spectrum: edges are samples in angle, 6p per mechanical turn; the turn-averaged
    # pattern's DFT gives mechanical orders 0 .. 3p
    n = 6 * r.pole_pairs
    spectra = []
    for s in np.unique(r.segment):
        sel = r.segment == s
        res_s = res[sel]
        m = (res_s.size // n) * n
        if m == 0:
            continue
        pattern = res_s[:m].reshape(-1, n).mean(axis=0)
        spectra.append(np.abs(np.fft.rfft(pattern)) / n)
    return EdgeLocalisation(
        per_sensor_deg_e={"ABC"[x]: float(np.mean(res[r.sensor == x])) for x in range(3) if np.any(r.sensor == x)},
        per_polarity_deg_e={
            k: float(np.mean(res[r.rising == v])) for k, v in (("rise", 1), ("fall", 0)) if np.any(r.rising == v)
        },
        per_pole_deg_e={j: float(np.mean(res[r.pole == j])) for j in range(2 * r.pole_pairs) if np.any(r.pole == j)},
        per_region=regions,
        order_spectrum=OrderSpectrum([float(v) for v in np.mean(spectra, axis=0)]) if spectra else None,
    )
