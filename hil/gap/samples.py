"""The sampled signals' part of the gap diagnosis: effects with no edge-angle signature.

Two residuals, each against the model's own physics driven by what was measured:

- **voltage** (V): the line-to-line voltage equation of the star-connected motor between two
  consecutive samples, ``u_xy = R i_xy + L di_xy/dt + e_xy(theta_e, w)``, trapezoidal in time,
  for the pairs a-b and b-c (the neutral cancels). Intervals across a commutation or a diode
  clamp (a terminal-voltage step) are dropped. Winding temperature shows as ``dR * i``, magnet
  temperature as ``(dk_e / k_e) * e``, saturation as the flux deficit of ``L(i)`` over ``L``.
- **speed** (rad/s): measured speed minus the speed the model's torque balance integrates from
  the measured currents (so the commutation torque ripple cancels), detrended per segment (a
  mean torque mismatch, e.g. unknown friction, is a drift, not a pattern). Cogging torque
  ``A sin(n theta_m + phi)`` shows as ``A cos(n theta_m + phi) / (n J w)``.

Residuals are averaged into cells (segment x angle bin; electrical bins for the voltage,
mechanical bins for the speed) with electrical periods or mechanical turns as replicates: the
noise floor of a cell mean is the scatter of its replicates, so slow drifts and correlated
noise widen it instead of faking a pattern. Candidates are fitted to the cell means by weighted
least squares (saturation's knee and cogging's order by a profile over a grid), selected
forward with the same BIC rule as the edge candidates, and judged on held-out segments.

Dead time leaves no trace here: the recorded terminal voltages already carry its loss and the
duty is not part of the format.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import stats
from scipy.integrate import cumulative_trapezoid
from scipy.optimize import minimize_scalar

from bldc.edges import electrical_speed_hz
from bldc.hall import BEMF_ZERO_DEG_E, SENSOR_POSITION_DEG_E, trapezoid
from bldc.units import rpm_to_rad_per_s
from hil.recording.format import Recording
from plant_models.effects import EFFECTS, SampleSignature

from ..calibration.stats import chi2_p_value
from .fitting import cell_rms
from .fitting import wls as _wls
from .relevance import OperatingEnvelope, sample_relevance
from .result import FittedEffect, HeldOut, OrderSpectrum, SampleLocalisation, SegmentResidual, gap_metric
from .selection import ALPHA, BlockSums, Selection, Trial, confounded_rivals, forward_select, heldout_shrink

ELECTRICAL_BINS = 12         #: 30 deg_e per voltage cell
MECHANICAL_BINS = 96         #: speed cells per turn: cogging orders up to 48 are resolved
JUMP_FRACTION = 0.08         #: a terminal-voltage step above this share of V_dc marks a switching event
RAIL_TOLERANCE = 0.02        #: a terminal this close to the highest / lowest (share of their spread) sits at that rail
#: what the cells resolve, for the shape grids of the effects' sample signatures
LIMITS = {"max_periods_per_rev": MECHANICAL_BINS // 2}
#: nuisance of the voltage residual without an encoder: the Hall reference's common angle offset
REFERENCE = "hall_reference_offset"


#: the residuals of the sampled signals, in the order their effects are listed, reported and validated
DOMAINS = ("voltage", "speed")


class _SampleEffects(Mapping):
    """The registered effects that declare a sample signature (``Effect.sample_signature``), each
    with the residual it shows in ("voltage" or "speed"): by domain (``DOMAINS``), then in the
    registry's order; read on each use."""

    def __getitem__(self, name: str) -> str:
        cls = EFFECTS.get(name)
        sig = cls.sample_signature() if cls is not None else None
        if sig is None:
            raise KeyError(name)
        return sig.domain

    def __iter__(self) -> Iterator[str]:
        domain = {name: sig.domain for name, cls in EFFECTS.items() if (sig := cls.sample_signature()) is not None}
        return iter(sorted(domain, key=lambda name: DOMAINS.index(domain[name])))  # stable: registry order within

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: the residual in which each sampled-signal effect shows
EFFECT_DOMAIN: Mapping[str, str] = _SampleEffects()


@dataclass(frozen=True)
class NominalMotor:
    """What the diagnosis knows of the motor (meta.json's nominal values, or --model)."""

    pole_pairs: int
    resistance_ohm: float
    inductance_h: float
    ke_v_s_per_rad: float
    flat_top_deg_e: float
    inertia_kg_m2: float
    fan_n_m_s2: float
    friction_n_m_s_per_rad: float
    supply_v: float

    @classmethod
    def of(cls, rec: Recording, model=None) -> "NominalMotor":
        if model is not None:
            cp = model.compile()
            return cls(
                cp.pole_pairs,
                cp.phase_resistance_ohm,
                cp.phase_inductance_h,
                cp.ke_v_s_per_rad,
                cp.flat_top_deg_e,
                cp.inertia_kg_m2,
                cp.fan_coefficient_n_m_s2,
                cp.friction_n_m_s_per_rad,
                cp.supply_v,
            )
        m = rec.motor
        return cls(
            int(m["pole_pairs"]),
            float(m["phase_resistance_ohm"]),
            float(m["phase_inductance_h"]),
            float(m["ke_v_s_per_rad"]),
            float(m.get("flat_top_deg_e", 120.0)),
            float(m["inertia_kg_m2"]),
            float(m["fan_coefficient_n_m_s2"]),
            float(m.get("friction_n_m_s_per_rad", 0.0)),
            float(m["supply_v"]),
        )


# --- residuals -----------------------------------------------------------------------------


@dataclass
class SampleResiduals:
    """Per-row residuals and candidate regressors of one domain, with their cell coordinates."""

    domain: str  #: "voltage" or "speed"
    unit: str
    y: np.ndarray
    segment: np.ndarray
    bin: np.ndarray  #: angle bin (with the line pair folded in for the voltage)
    replicate: np.ndarray  #: electrical period or mechanical turn within the segment
    regressors: dict[str, np.ndarray] = field(default_factory=dict)


def _angles(rec: Recording, edge_error_deg_e: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """Unwrapped electrical and mechanical angle (deg) at every sample, NaN outside the edges.

    From the reference encoder when recorded; else from the ideal angles of the Hall edges
    (the mechanical angle is then only known up to a pole, so the speed domain is skipped),
    each moved by ``edge_error_deg_e`` (per edge, + = trails) when given: the edge errors the
    accepted edge effects predict are where the rotor really was."""
    s = rec.samples
    p = rec.pole_pairs
    th_e = np.full(s["t_s"].size, np.nan)
    th_m = np.full(s["t_s"].size, np.nan)
    source = "encoder" if rec.ref_angle_mech_deg is not None else "hall"
    for k, seg in enumerate(rec.segments):
        e_sel = rec.segment == k
        s_sel = s["segment"] == k
        if e_sel.sum() < 2 or not s_sel.any():
            continue
        t = rec.t_s[e_sel]
        if source == "encoder":
            mech = np.unwrap(rec.ref_angle_mech_deg[e_sel], period=360.0)
        else:
            ideal = _ideal_edge_deg_e(rec.sensor[e_sel], rec.rising[e_sel], seg.direction_sign)
            if edge_error_deg_e is not None:
                ideal = ideal + seg.direction_sign * edge_error_deg_e[e_sel]
            mech = np.unwrap(ideal, period=360.0) / p
        ts = s["t_s"][s_sel]
        inside = (ts >= t[0]) & (ts <= t[-1])
        m = np.where(inside, np.interp(ts, t, mech), np.nan)
        th_m[s_sel] = m
        th_e[s_sel] = p * m
    return th_e, (th_m if source == "encoder" else np.full_like(th_m, np.nan)), source


def _ideal_edge_deg_e(sensor: np.ndarray, rising: np.ndarray, direction: int) -> np.ndarray:
    rise_fwd = SENSOR_POSITION_DEG_E[sensor]
    at_rise = rising.astype(bool) if direction > 0 else ~rising.astype(bool)
    return np.where(at_rise, rise_fwd, rise_fwd + 180.0) % 360.0


def _speed_rad_s(rec: Recording, th_m_deg: np.ndarray) -> np.ndarray:
    """Signed mechanical speed: the speed column with the segment's direction; else, with the
    reference encoder, d(theta)/dt of its angle; else speed from the Hall edges (``bldc.edges``:
    two sectors around each edge), interpolated to the samples."""
    s = rec.samples
    sign = np.array([seg.direction_sign for seg in rec.segments])[s["segment"]]
    if "speed_rpm" in s:
        return sign * rpm_to_rad_per_s(np.abs(s["speed_rpm"]))
    if rec.ref_angle_mech_deg is not None:
        return np.gradient(np.deg2rad(th_m_deg), s["t_s"])
    w = np.full(s["t_s"].size, np.nan)
    for k in range(len(rec.segments)):
        e_sel, s_sel = rec.segment == k, s["segment"] == k
        if e_sel.sum() < 3 or not s_sel.any():
            continue
        t = rec.t_s[e_sel]
        f_hz = electrical_speed_hz(t, window_sectors=2)
        w[s_sel] = 2.0 * np.pi * np.interp(s["t_s"][s_sel], t, f_hz) / rec.pole_pairs
    return sign * w


def _steady_intervals(
    u: np.ndarray, seg: np.ndarray, supply_v: float, guard_before: int = 1, guard_after: int = 2
) -> np.ndarray:
    """Intervals between samples with no switching event in or near them.

    A commutation changes which terminals sit at the rails; a diode clamp that ends makes a
    terminal-voltage step. Around either, a current may reach zero mid-interval, where the
    held-voltage equation breaks. Terminals are classed against the rails with a tolerance of
    a few per cent of the terminals' spread, so measurement noise cannot toggle the class (a noise-dependent
    choice of intervals would bias the residual)."""
    hi, lo = u.max(axis=1, keepdims=True), u.min(axis=1, keepdims=True)
    tol = RAIL_TOLERANCE * (hi - lo)
    top = u >= hi - tol
    bottom = u <= lo + tol
    pattern = (2 * top + bottom) @ np.array([1, 4, 16])
    event = (pattern[1:] != pattern[:-1]) | np.any(np.abs(np.diff(u, axis=0)) > JUMP_FRACTION * supply_v, axis=1)
    event |= seg[1:] != seg[:-1]
    bad = event.copy()
    for k in range(1, guard_after + 1):
        bad[k:] |= event[:-k]
    for k in range(1, guard_before + 1):
        bad[:-k] |= event[k:]
    return ~bad


def voltage_residuals(
    rec: Recording, motor: NominalMotor, th_e: np.ndarray, w: np.ndarray, hall_reference: bool = False
) -> SampleResiduals | None:
    """The voltage equation's residual. ``hall_reference``: the angle comes from the Hall edges
    (no encoder), whose common offset no edge can show; its back-EMF signature (de/dtheta per
    deg_e) is then a nuisance column every fit carries (``REFERENCE``)."""
    s = rec.samples
    if not all(c in s for c in ("i_a", "i_b", "i_c", "u_a", "u_b", "u_c")):
        return None
    i = np.column_stack([s["i_a"], s["i_b"], s["i_c"]])
    u = np.column_stack([s["u_a"], s["u_b"], s["u_c"]])
    f = np.column_stack([trapezoid(th_e - z, motor.flat_top_deg_e) for z in BEMF_ZERO_DEG_E])
    e = motor.ke_v_s_per_rad * w[:, None] * f
    t = s["t_s"]
    seg = s["segment"]
    ok = (seg[1:] == seg[:-1]) & np.isfinite(th_e[1:]) & np.isfinite(th_e[:-1])
    ok &= _steady_intervals(u, seg, motor.supply_v)
    h = np.diff(t)
    f_d = np.column_stack(
        [
            trapezoid(th_e - z + 0.5, motor.flat_top_deg_e) - trapezoid(th_e - z - 0.5, motor.flat_top_deg_e)
            for z in BEMF_ZERO_DEG_E
        ]
    )
    e_d = motor.ke_v_s_per_rad * w[:, None] * f_d  # V per deg_e of angle error
    rows = {k: [] for k in ("y", "segment", "bin", "replicate", "i", "e", "ed", "i0x", "i1x", "i0y", "i1y", "h")}
    avg = lambda a: 0.5 * (a[1:] + a[:-1])  # noqa: E731 - trapezoid over one interval
    mid = avg(th_e)
    # electrical periods counted from each segment's lowest angle (either direction)
    rel = (
        mid
        - np.array([np.nanmin(th_e[seg == k]) if np.any(seg == k) else 0.0 for k in range(len(rec.segments))])[seg[1:]]
    )
    for pair, (x, yy) in enumerate(((0, 1), (1, 2))):
        ixy = i[:, x] - i[:, yy]
        uxy = u[:, x] - u[:, yy]
        exy = e[:, x] - e[:, yy]
        resid = avg(uxy) - motor.resistance_ohm * avg(ixy) - motor.inductance_h * np.diff(ixy) / h - avg(exy)
        rows["y"].append(resid[ok])
        rows["segment"].append(seg[1:][ok])
        rows["bin"].append(
            (np.floor(np.mod(mid[ok], 360.0) / (360.0 / ELECTRICAL_BINS)).astype(np.int64) % ELECTRICAL_BINS)
            + pair * ELECTRICAL_BINS
        )
        rows["replicate"].append(np.floor(rel[ok] / 360.0).astype(np.int64))
        rows["i"].append(avg(ixy)[ok])
        rows["e"].append(avg(exy)[ok])
        rows["ed"].append(avg(e_d[:, x] - e_d[:, yy])[ok])
        rows["i0x"].append(i[:-1, x][ok])
        rows["i1x"].append(i[1:, x][ok])
        rows["i0y"].append(i[:-1, yy][ok])
        rows["i1y"].append(i[1:, yy][ok])
        rows["h"].append(h[ok])
    r = {k: np.concatenate(v) for k, v in rows.items()}
    if r["y"].size == 0:
        return None
    # the rows the effects' sample signatures read (SampleSignature)
    regs = {k: r[k] for k in ("i", "e", "i0x", "i1x", "i0y", "i1y", "h")}
    if hall_reference:
        regs[REFERENCE] = r["ed"]
    return SampleResiduals("voltage", "V", r["y"], r["segment"], r["bin"], r["replicate"], regs)


def speed_residuals(
    rec: Recording, motor: NominalMotor, th_e: np.ndarray, th_m: np.ndarray, w: np.ndarray
) -> SampleResiduals | None:
    s = rec.samples
    if "speed_rpm" not in s or not all(c in s for c in ("i_a", "i_b", "i_c")) or not np.isfinite(th_m).any():
        return None
    i = np.column_stack([s["i_a"], s["i_b"], s["i_c"]])
    f = np.column_stack([trapezoid(th_e - z, motor.flat_top_deg_e) for z in BEMF_ZERO_DEG_E])
    ys, segs, bins, reps, t_rows, th_rows, err_rows = [], [], [], [], [], [], []
    for k, seg in enumerate(rec.segments):
        sel = (s["segment"] == k) & np.isfinite(th_m)
        if sel.sum() < 8:
            continue
        t = s["t_s"][sel]
        wk = w[sel]
        torque = motor.ke_v_s_per_rad * np.sum(f[sel] * i[sel], axis=1)
        load = seg.load_scale * motor.fan_n_m_s2 * wk * np.abs(wk) + motor.friction_n_m_s_per_rad * wk
        accel = (torque - load) / motor.inertia_kg_m2
        pred = wk[0] + cumulative_trapezoid(accel, t, initial=0.0)
        resid = _detrend(t, wk - pred)  # a mean torque mismatch is a drift, not a pattern
        # the integral is only as good as the sampling of the current transients: the change
        # from half to full rate (a conservative bound on the full-rate error when transients
        # are sharper than the sampling, where Richardson's /3 is too hopeful) joins the noise
        # floor of each cell
        coarse = np.interp(t, t[::2], wk[0] + cumulative_trapezoid(accel[::2], t[::2], initial=0.0))
        err_rows.append(_detrend(t, pred - coarse))
        m = th_m[sel]
        ys.append(resid)
        segs.append(np.full(resid.size, k))
        bins.append(np.floor(np.mod(m, 360.0) / (360.0 / MECHANICAL_BINS)).astype(np.int64) % MECHANICAL_BINS)
        reps.append(np.floor(seg.direction_sign * (m - m[0]) / 360.0).astype(np.int64))
        t_rows.append(t)
        th_rows.append(np.deg2rad(m))
    if not ys:
        return None
    regs = {
        "theta_m": np.concatenate(th_rows),
        "t": np.concatenate(t_rows),
        "_integration_error": np.concatenate(err_rows),
    }
    return SampleResiduals(
        "speed", "rad/s", np.concatenate(ys), np.concatenate(segs), np.concatenate(bins), np.concatenate(reps), regs
    )


# --- cells ---------------------------------------------------------------------------------


@dataclass
class SampleCells:
    mean: np.ndarray
    var: np.ndarray  #: variance of the cell mean (replicate scatter / replicates)
    n: np.ndarray  #: rows in the cell
    n_rep: np.ndarray  #: replicates in the cell
    segment: np.ndarray
    row_cell: np.ndarray  #: cell of each row (-1: dropped)
    row_rep: np.ndarray  #: (cell, replicate) group of each row
    cache: dict = field(default_factory=dict)  #: design columns by (effect, shape parameter)

    @property
    def weight(self) -> np.ndarray:
        return 1.0 / self.var

    def average(self, x: np.ndarray) -> np.ndarray:
        """Cell means of a per-row regressor, averaged like the residual (replicate means first)."""
        keep = self.row_cell >= 0
        g = self.row_rep[keep]
        n_g = np.bincount(g)
        rep_mean = np.bincount(g, x[keep]) / np.maximum(n_g, 1)
        cell_of_g = np.full(n_g.size, -1)
        cell_of_g[g] = self.row_cell[keep]
        used = n_g > 0
        return np.bincount(cell_of_g[used], rep_mean[used], minlength=self.mean.size) / self.n_rep

    def chi2(self, resid: np.ndarray) -> float:
        return float(np.sum(resid * resid / self.var))

    def significance(self, resid: np.ndarray, n_params: int = 0, rows: np.ndarray | None = None) -> float:
        """p-value of the cell means ``resid`` (of the cells ``rows``, default all) against the
        noise floor. Each cell's t statistic (replicate variance, n_rep - 1 dof) is mapped to
        chi-square(1), so small replicate counts do not fake a gap."""
        rows = np.arange(self.mean.size) if rows is None else rows
        resid = resid[rows]
        t = np.abs(resid) / np.sqrt(self.var[rows])
        p_cell = np.clip(2 * stats.t.sf(t, np.maximum(self.n_rep[rows] - 1, 1)), 1e-300, 1.0)
        stat = float(np.sum(stats.chi2.isf(p_cell, 1)))
        return chi2_p_value(stat, max(resid.size - n_params, 1))


def build_cells(r: SampleResiduals, min_replicates: int = 4) -> SampleCells:
    key = (r.segment.astype(np.int64) * 10_000 + r.bin) * 1_000_000 + r.replicate
    g_keys, g = np.unique(key, return_inverse=True)
    rep_mean = np.bincount(g, r.y) / np.bincount(g)
    cell_key = g_keys // 1_000_000
    c_keys, c_of_g = np.unique(cell_key, return_inverse=True)
    n_rep = np.bincount(c_of_g).astype(float)
    mean = np.bincount(c_of_g, rep_mean) / n_rep
    dev = rep_mean - mean[c_of_g]
    var_rep = np.bincount(c_of_g, dev * dev) / np.maximum(n_rep - 1, 1)
    good = n_rep >= min_replicates
    # a cell's replicate variance from few replicates is itself noisy: shrink it towards the
    # pooled variance of its segment's cells (never below it by more than half)
    seg_of_cell = c_keys // 10_000
    var = np.empty_like(var_rep)
    for sgm in np.unique(seg_of_cell):
        sel = seg_of_cell == sgm
        pooled = np.sum(var_rep[sel & good] * (n_rep[sel & good] - 1)) / max(np.sum(n_rep[sel & good] - 1), 1)
        var[sel] = np.maximum(var_rep[sel], 0.5 * pooled)
    var = np.maximum(var / n_rep, 1e-30)
    new_index = np.cumsum(good) - 1
    row_cell = np.where(good[c_of_g[g]], new_index[c_of_g[g]], -1)
    n_rows = np.bincount(c_of_g[g], minlength=c_keys.size).astype(float)
    return SampleCells(mean[good], var[good], n_rows[good], n_rep[good], seg_of_cell[good], row_cell, g)


# --- candidates ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SampleCandidate:
    """An effect as a cell design block, linear given its shape parameter (a grid is profiled)."""

    name: str
    domain: str
    columns: Callable[[SampleResiduals, SampleCells, float | None], np.ndarray]
    params: Callable[[np.ndarray, float | None, NominalMotor], dict]
    physical: Callable[[np.ndarray, np.ndarray, NominalMotor], bool]
    grid: tuple = (None,)
    n_coef: int = 1  #: fitted coefficients (0: the column enters with coefficient 1, only its shape is fitted)
    #: shape parameters refined by a bounded scalar search around the best grid point
    refine: bool = False
    signature: SampleSignature | None = None  #: the effect's declaration (None: the Hall reference's nuisance)


def _detrend(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Remove a quadratic in time (what the speed residual has removed per segment)."""
    tc = t - t.mean()
    return y - np.polyval(np.polyfit(tc, y, 2), tc)


def _speed_taken(r: SampleResiduals, torque: np.ndarray, motor: NominalMotor) -> np.ndarray:
    """The speed a torque column takes away, integrated along the measured trajectory exactly as
    the residual was: -(1/J) int torque dt per segment, detrended."""
    t = r.regressors["t"]
    out = np.empty_like(torque)
    for k in np.unique(r.segment):
        sel = r.segment == k
        for j in range(torque.shape[1]):
            out[sel, j] = _detrend(
                t[sel], -cumulative_trapezoid(torque[sel, j], t[sel], initial=0.0) / motor.inertia_kg_m2
            )
    return out


def _block(sig: SampleSignature, motor: NominalMotor):
    """The cell design block of an effect's declared per-row columns."""

    def columns(r, cells, shape):
        x = sig.columns(r.regressors, shape, motor)
        if r.domain == "speed":
            x = _speed_taken(r, x, motor)
        return np.column_stack([cells.average(x[:, j]) for j in range(x.shape[1])])

    return columns


def sample_candidates(motor: NominalMotor) -> dict[str, SampleCandidate]:
    """The Hall reference's nuisance, then every registered effect's sample signature."""
    out = {
        REFERENCE: SampleCandidate(
            REFERENCE,
            "voltage",
            lambda r, cells, _: cells.average(r.regressors[REFERENCE])[:, None],
            lambda c, _, m: {"offset_deg_e": float(c[0])},
            lambda c, se, m: True,
        )
    }
    for name in EFFECT_DOMAIN:
        sig = EFFECTS[name].sample_signature()
        out[name] = SampleCandidate(name, sig.domain, _block(sig, motor), sig.params, sig.physical,
                                    tuple(sig.grid(motor, LIMITS)), sig.n_coef, sig.refine, sig)
    return out


# --- fitting and selection -----------------------------------------------------------------


@dataclass
class _Fit:
    names: list[str]
    shapes: list
    coef: np.ndarray
    se: np.ndarray
    chi2: float
    resid: np.ndarray


def _fit(r, cells, cands, names, shapes, rows=None) -> _Fit:
    """Fit ``names`` (with their shape parameters) jointly on the cells ``rows`` (default all)."""
    rows = np.arange(cells.mean.size) if rows is None else rows
    y = cells.mean.copy()
    lin = []
    for n, s in zip(names, shapes):
        col = cells.cache.get((n, s))
        if col is None:
            col = cells.cache[(n, s)] = cands[n].columns(r, cells, s)
        if cands[n].n_coef == 0:
            y = y - col[:, 0]
        else:
            lin.append(col)
    x = np.column_stack(lin) if lin else np.zeros((y.size, 0))
    coef, se, _ = _wls(x[rows], y[rows], cells.weight[rows])
    resid = y - x @ coef
    return _Fit(list(names), list(shapes), coef, se, float(np.sum(resid[rows] ** 2 / cells.var[rows])), resid)


def _own(fit: _Fit, cands, name):
    """(coef, se) of ``name`` inside a joint fit."""
    col = 0
    for n in fit.names:
        k = cands[n].n_coef
        if n == name:
            return fit.coef[col : col + k], fit.se[col : col + k]
        col += k
    raise KeyError(name)


def _best_shape(r, cells, cands, accepted, shapes, name, rows=None) -> _Fit:
    """Fit ``accepted`` plus ``name`` with the shape parameter of ``name`` that fits best (on
    ``rows``, default all cells): the grid, then a bounded search around its best point."""
    cand = cands[name]

    def fit(shape):
        return _fit(r, cells, cands, accepted + [name], shapes + [shape], rows=rows)

    best = min((fit(s) for s in cand.grid), key=lambda f: f.chi2)
    if cand.refine and len(cand.grid) > 1:
        k = cand.grid.index(best.shapes[-1])
        lo, hi = cand.grid[max(k - 1, 0)], cand.grid[min(k + 1, len(cand.grid) - 1)]
        res = minimize_scalar(
            lambda lg: fit(math.exp(lg)).chi2,
            bounds=(math.log(lo), math.log(hi)),
            method="bounded",
            options={"xatol": 1e-3},
        )
        refined = fit(math.exp(res.x))
        if refined.chi2 < best.chi2:
            best = refined
    return best


def _n_params(cands, names) -> int:
    return sum(cands[n].n_coef + (1 if len(cands[n].grid) > 1 else 0) for n in names)


@dataclass
class DomainDiagnosis:
    domain: str
    unit: str
    significant: bool
    p_value: float
    accepted: list[FittedEffect]
    first_scores: dict[str, float]
    unexplained: bool
    gap_before: float
    gap_after_heldout: float | None
    heldout_shrink: float | None
    heldout_interval: list[float] | None
    heldout: HeldOut
    localisation: SampleLocalisation
    chi2_excess: float
    confounded: list[list[str]] = field(default_factory=list)
    below_relevance: list[FittedEffect] = field(default_factory=list)  #: detected, fitted, too small to matter

    def to_json(self) -> dict:
        return {
            "domain": self.domain,
            "unit": self.unit,
            "significant": self.significant,
            "p_value": self.p_value,
            "accepted": [a.to_json() for a in self.accepted],
            "below_relevance": [b.to_json() for b in self.below_relevance],
            "unexplained": self.unexplained,
            "confounded": self.confounded,
            "gap_before": self.gap_before,
            "gap_after_heldout": self.gap_after_heldout,
            "heldout_shrink": self.heldout_shrink,
            "heldout_interval": self.heldout_interval,
            "heldout_note": self.heldout.text(),
            "localisation": self.localisation.to_json(),
        } | {
            "ranking": [
                {"effect": n, "score": round(s, 4)} for n, s in sorted(self.first_scores.items(), key=lambda kv: -kv[1])
            ],
            "gap_metric": gap_metric("samples", (self.domain, self.unit)),
        }


def diagnose_domain(
    r: SampleResiduals,
    cands: dict[str, SampleCandidate],
    motor: NominalMotor,
    segment_ids: list[str],
    env: OperatingEnvelope | None = None,
) -> DomainDiagnosis | None:
    cells = build_cells(r)
    if cells.mean.size < 4:
        return None
    if "_integration_error" in r.regressors:
        cells.var = cells.var + cells.average(r.regressors["_integration_error"]) ** 2
    names = [n for n, c in cands.items() if c.domain == r.domain and n != REFERENCE]
    p0, sel, shapes, current = _select_domain(r, cells, cands, names, motor)
    significant = p0 < ALPHA
    n_cells = cells.mean.size
    accepted = sel.fitted
    unexplained = bool(significant and cells.significance(current.resid, _n_params(cands, accepted)) < ALPHA)
    accepted_rows, below = _rows(cands, current, accepted, shapes, motor, env)
    below_names = {b.effect for b in below}
    kept = [n for n in accepted if n not in below_names]
    gap_before = cell_rms(cells.mean, cells.n)
    any_kept = bool([n for n in kept if n != REFERENCE])
    shrink, after, interval, held = _heldout(r, cells, cands, names, motor, env, any_kept)
    if below and not any_kept:
        held = HeldOut("below relevance", "samples")
    kept_shapes = [s for n, s in zip(accepted, shapes) if n in kept]

    def refit_chi2(m: str) -> float:
        return _best_shape(r, cells, cands, kept, kept_shapes, m).chi2

    return DomainDiagnosis(
        r.domain,
        r.unit,
        significant,
        p0,
        accepted_rows,
        {n: sel.share_alone(n) for n in names},
        unexplained,
        gap_before,
        after,
        shrink,
        interval,
        held,
        _localise(r, cells, segment_ids),
        sel.chi2_0 - n_cells,
        confounded_rivals(sel, [n for n in kept if n != REFERENCE], names, refit_chi2),
        below,
    )


def _select_domain(r, cells, cands, names, motor, rows=None):
    """The domain's gap test and the engine's selection on the cells ``rows`` (default all):
    (p-value, selection, shape parameters of the kept effects, their joint fit). Without an
    encoder every fit carries the Hall reference's unknown common angle offset."""
    rows = np.arange(cells.mean.size) if rows is None else rows
    start: list[str] = [REFERENCE] if REFERENCE in r.regressors else []
    shapes_of: dict[tuple, list] = {tuple(start): [None] * len(start)}
    fits: dict[tuple, _Fit] = {tuple(start): _fit(r, cells, cands, start, shapes_of[tuple(start)], rows=rows)}
    p0 = cells.significance(fits[tuple(start)].resid, len(start), rows)

    def try_add(fitted: list[str], name: str) -> Trial:
        f = _best_shape(r, cells, cands, fitted, shapes_of[tuple(fitted)], name, rows=rows)
        key = tuple(fitted + [name])
        shapes_of[key], fits[key] = f.shapes, f
        coef, se = _own(f, cands, name)
        search = math.log(len(cands[name].grid)) * 2 if len(cands[name].grid) > 1 else 0.0
        return Trial(name, f.chi2, _n_params(cands, [name]), cands[name].physical(coef, se, motor), search, f)

    def remainder_p(fitted: list[str], t: Trial) -> float:
        return cells.significance(t.fit.resid, _n_params(cands, fitted), rows)

    chi2_0 = fits[tuple(start)].chi2
    if p0 < ALPHA:
        sel = forward_select(names, try_add, chi2_0, rows.size, remainder_p, start=start)
    else:
        sel = Selection(list(start), [], {}, [], chi2_0, chi2_0, rows.size)
    key = tuple(sel.fitted)
    return p0, sel, shapes_of[key], fits[key]


def _rows(cands, fit: _Fit, names, shapes, motor, env):
    """Accepted rows and rows below practical relevance: an effect whose fitted magnitude does not
    matter stays in the fit (its pattern is explained, not unexplained) but is not accepted."""
    accepted_rows, below = [], []
    for n, s in zip(names, shapes):
        if n == REFERENCE:
            continue
        coef, se = _own(fit, cands, n)
        params = cands[n].params(coef, s, motor)
        rel = sample_relevance(cands[n].signature, params, motor, env) if env is not None else None
        row = FittedEffect(n, params, _stderr(cands[n], coef, se, s, motor), rel)
        (accepted_rows if row.relevant else below).append(row)
    return accepted_rows, below


def _stderr(cand, coef, se, shape, motor) -> dict:
    """Standard errors of the linear parameters (model-based, from the weighted fit of the
    cells); a searched shape parameter (knee, order) has none."""
    if cand.n_coef == 0:
        return {}
    lo, hi = cand.params(coef - se, shape, motor), cand.params(coef + se, shape, motor)
    out = {}
    for k, v in cand.params(coef, shape, motor).items():
        if isinstance(v, float) and k not in cand.signature.constants:
            out[k] = abs(hi[k] - lo[k]) / 2.0
    return out


def _heldout(r, cells, cands, names, motor, env, any_kept: bool):
    """Leave one operating point out: the gap test, the effects, their shape parameters and values
    are chosen on the other segments alone and predict the held-out one."""
    segs = np.unique(cells.segment)
    if segs.size < 2:
        return None, None, None, HeldOut("single segment", "samples")
    if not any_kept:
        return 0.0, None, None, HeldOut("no effect accepted", "samples")
    pred_resid = np.full(cells.mean.size, np.nan)
    for s in segs:
        test = cells.segment == s
        train = np.nonzero(~test)[0]
        _, sel, shapes, f = _select_domain(r, cells, cands, names, motor, rows=train)
        _, below = _rows(cands, f, sel.fitted, shapes, motor, env)
        drop = {b.effect for b in below}
        if drop:
            kept = [(n, sh) for n, sh in zip(sel.fitted, shapes) if n not in drop]
            f = _fit(r, cells, cands, [n for n, _ in kept], [sh for _, sh in kept], rows=train)
        pred_resid[test] = f.resid[test]
    ok = np.isfinite(pred_resid)
    seg, n = cells.segment[ok], cells.n[ok]
    res = heldout_shrink(BlockSums.of(seg, n, cells.mean[ok]), BlockSums.of(seg, n, pred_resid[ok]))
    return res.shrink, res.after, res.interval, HeldOut("leave one out", "samples", segments=res.blocks)


def _localise(r: SampleResiduals, cells: SampleCells, segment_ids: list[str]) -> SampleLocalisation:
    per_segment = []
    for s in np.unique(cells.segment):
        sel = cells.segment == s
        per_segment.append(SegmentResidual(segment_ids[s], cell_rms(cells.mean[sel], cells.n[sel]), int(sel.sum())))
    if r.domain == "speed":
        # order spectrum of the turn-averaged speed residual: cogging appears at its periods per turn
        spectra = []
        for s in np.unique(cells.segment):
            sel = r.segment == s
            pattern = np.bincount(r.bin[sel], r.y[sel], minlength=MECHANICAL_BINS) / np.maximum(
                np.bincount(r.bin[sel], minlength=MECHANICAL_BINS), 1
            )
            spectra.append(np.abs(np.fft.rfft(pattern)) / MECHANICAL_BINS * 2)
        amp = np.mean(spectra, axis=0)
        return SampleLocalisation(per_segment, order_spectrum=OrderSpectrum([float(v) for v in amp], unit="rad_s"))
    pattern = np.bincount(cells_bin := (r.bin % ELECTRICAL_BINS), r.y, minlength=ELECTRICAL_BINS) / np.maximum(
        np.bincount(cells_bin, minlength=ELECTRICAL_BINS), 1
    )
    angle = {int(k * 360 / ELECTRICAL_BINS): float(v) for k, v in enumerate(pattern)}
    return SampleLocalisation(per_segment, per_electrical_angle_v=angle)


def envelope(rec: Recording, motor: NominalMotor) -> OperatingEnvelope:
    """Per operating point: mean |phase current| (measured), speed and load torque."""
    s = rec.samples
    mean_abs = (
        (np.abs(s["i_a"]) + np.abs(s["i_b"]) + np.abs(s["i_c"])) / 3.0
        if all(c in s for c in ("i_a", "i_b", "i_c"))
        else None
    )
    cur, spd, load = [], [], []
    for k, seg in enumerate(rec.segments):
        sel = s["segment"] == k
        w = rpm_to_rad_per_s(seg.speed_rpm)
        cur.append(float(np.mean(mean_abs[sel])) if mean_abs is not None and sel.any() else seg.mean_phase_current_a)
        spd.append(w)
        load.append(seg.load_scale * motor.fan_n_m_s2 * w * w + motor.friction_n_m_s_per_rad * w)
    i_max = (
        float(np.max(np.abs(np.column_stack([s["i_a"], s["i_b"], s["i_c"]]))))
        if mean_abs is not None
        else max(cur, default=0.0)
    )
    return OperatingEnvelope(np.array(cur), np.array(spd), np.array(load), i_max)


def diagnose_samples(
    rec: Recording, model=None, edge_error_deg_e: np.ndarray | None = None
) -> dict[str, DomainDiagnosis]:
    """Diagnose the sampled signals of ``rec`` (empty when it has none). Without an encoder the
    electrical angle comes from the Hall edges: ``edge_error_deg_e`` (per edge, what the accepted
    edge effects predict) puts each edge where the rotor really was, so a sampled-signal effect
    is only accepted for what the edge errors do not already produce through the same angle."""
    if rec.samples is None:
        return {}
    motor = NominalMotor.of(rec, model)
    th_e, th_m, _ = _angles(rec, edge_error_deg_e if rec.ref_angle_mech_deg is None else None)
    w = _speed_rad_s(rec, th_m if np.isfinite(th_m).any() else th_e / motor.pole_pairs)
    cands = sample_candidates(motor)
    env = envelope(rec, motor)
    out = {}
    hall = rec.ref_angle_mech_deg is None
    for r in (voltage_residuals(rec, motor, th_e, w, hall_reference=hall), speed_residuals(rec, motor, th_e, th_m, w)):
        if r is not None:
            d = diagnose_domain(r, cands, motor, rec.segment_ids, env)
            if d is not None:
                out[r.domain] = d
    return out
