"""``hil signals export``: Hall and phase-current stimulus an instrument can play, with its truth.

Hall edges come from the plant's kinematic mode (``plant_models.kinematic.simulate_edges``) on
the imposed speed profile, with the plant's sensor layer: the pins see the conditioned edge
(installation and pole offsets, hysteresis, armature reaction, conditioning RC, jitter) but not
the controller's own capture-timer quantisation, which is the controller's business. Phase
currents come from the electrical plant (:mod:`hil.signals.currents`), through the current
sensors' gain error, offset and noise of the plant file, scaled to volts.

Everything is generated in chunks of simulated time and written as it goes: memory does not
grow with the duration (the VCD writes only changes; the CSV writes every sample).
"""

from __future__ import annotations

import dataclasses
import json
import math
import platform
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TextIO

import numpy as np

from bldc.hall import hall_state
from bldc.tomlfile import load_toml
from bldc.units import rpm_to_deg_e_per_s
from plant_models import ConfigError, PlantConfig
from plant_models.effects import effect_from_mapping
from plant_models.kinematic import OperatingPoint, simulate_edges
from plant_models.plant import CurrentSensorParameters

from ..recording.errors import SignalError
from ..recording.vcd import Timescale, VcdWriter
from .currents import CurrentTables, tabulate
from .trajectory import Trajectory

FORMAT = "hil-signals/1"
HALL_NAMES = ("HA", "HB", "HC")
CURRENT_NAMES = ("IA", "IB", "IC")
TRUTH_COLUMNS = (
    "n",
    "t_ideal_s",
    "sector",
    "theta_e_deg",
    "theta_m_deg",
    "speed_rpm",
    "t_hall_pin_s",
    "hall_sensor",
    "hall_rising",
)
#: simulated time per generation chunk (bounds the memory: a chunk's samples are ~1e6 at 1 MHz)
CHUNK_S = 0.25
#: events this close to a chunk's end wait for the next chunk (a conditioned edge may land
#: after the chunk whose rotor angle produced it)
GUARD_S = 2e-3


@dataclass
class ExportSettings:
    config: PlantConfig
    breakpoints: list[tuple[float, float]]
    duration_s: float
    sample_rate_hz: float = 1e6
    seed: int = 0
    #: current-sensor output scale and zero (V = zero + scale * measured current)
    current_v_per_a: float = 0.1
    current_zero_v: float = 0.0
    #: the analog channels' update rate and output resolution (an AWG's step)
    analog_rate_hz: float = 50e3
    analog_lsb_v: float = 1e-3
    currents: bool = True
    csv_max_bytes: float = 1e9
    write_csv: bool = True
    start_angle_deg_e: float = 30.0
    #: what produced it (command line), recorded in meta.json
    command: str = ""
    effects_source: str = ""
    deviations: bool = True


@dataclass
class ExportResult:
    out_dir: Path
    n_edges: int = 0
    n_commutations: int = 0
    vcd_bytes: int = 0
    csv_bytes: int | None = None
    csv_skipped_reason: str = ""
    wall_s: float = 0.0
    files: list[str] = field(default_factory=list)


def load_effects(path: str | Path):
    """Effects from a TOML file of ``[[effects]]`` tables."""
    path = Path(path)
    data = load_toml(path, {"effects": [None]})
    tables = data.get("effects")
    if not isinstance(tables, list):
        raise SignalError(str(path), "expected [[effects]] tables")

    try:
        return tuple(effect_from_mapping(t, f"{path}: effects[{i}].") for i, t in enumerate(tables))
    except ConfigError as exc:
        raise SignalError(str(path), str(exc)) from None


def ideal(config: PlantConfig) -> PlantConfig:
    """The plant without deviations: no effects, ideal current sensors."""
    return dataclasses.replace(
        config, effects=(), current_sensor=CurrentSensorParameters(), name=config.name + " (ideal)"
    )


def _seed(seed: int, *parts: int) -> int:
    return int(np.random.SeedSequence([seed, *parts]).generate_state(1)[0])


def csv_row_bytes(settings: ExportSettings) -> int:
    """Bytes of one stimulus.csv row (time, three bits, three volts)."""
    return len(_time_format(settings.sample_rate_hz) % 600.0) + 6 + (3 * 10 if settings.currents else 0) + 1


def _time_format(sample_rate_hz: float) -> str:
    return "%." + str(max(int(math.ceil(math.log10(sample_rate_hz))), 0) + 1) + "f"


@dataclass
class _Plan:
    """What the settings fix before the first sample: the trajectory, the sampling and its VCD
    timescale, the analog decimation, the current tables and sensors, and the CSV's fate."""

    out: Path
    settings: ExportSettings
    traj: Trajectory
    fs: float
    timescale: Timescale
    ticks_per_sample: int
    n_samples: int
    decim: int
    analog_rate: float
    tables: CurrentTables | None
    gain: np.ndarray
    offset: np.ndarray
    n_chunks: int
    write_csv: bool
    csv_skipped_reason: str

    @property
    def config(self) -> PlantConfig:
        return self.settings.config

    def chunk_span(self, c: int) -> tuple[float, float]:
        return c * CHUNK_S, min((c + 1) * CHUNK_S, self.settings.duration_s)

    def last(self, c: int) -> bool:
        return c == self.n_chunks - 1


@dataclass
class _Stream:
    """What the chunks carry to the next: events and truth rows not yet written, the pin edge of each
    sector boundary, how far the files are written, and the values held at that point."""

    hall_now: list[int]
    carry_ev: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (sample index, variable, value)
    carry_truth: list[np.ndarray] = field(default_factory=list)
    pin_of_n: dict[int, tuple[int, int, int]] = field(default_factory=dict)
    written_until: int = 0  # samples before this are in the files
    analog_now: np.ndarray | None = None
    last_volts: np.ndarray | None = None
    n_next: int = 0  # next sector boundary index


@dataclass
class _Files:
    """The files a stimulus is written into as it is generated (stimulus.csv: None when not written)."""

    vcd: VcdWriter
    truth: TextIO
    csv: TextIO | None

    def close(self, end_tick: int) -> None:
        self.vcd.close(end_tick)
        self.truth.close()
        if self.csv is not None:
            self.csv.close()


def _plan(out: Path, settings: ExportSettings) -> _Plan:
    config = settings.config
    traj = Trajectory(settings.breakpoints, settings.duration_s, config.motor.pole_pairs, settings.start_angle_deg_e)
    fs = float(settings.sample_rate_hz)
    timescale, ticks_per_sample = Timescale.for_sample_rate(fs)
    n_samples = int(round(settings.duration_s * fs))
    decim = max(int(round(fs / settings.analog_rate_hz)), 1)
    tables: CurrentTables | None = None
    if settings.currents:
        tables = tabulate(
            config,
            [p[1] for p in settings.breakpoints] + [float(traj.speed_rpm(settings.duration_s))],
            seed=settings.seed,
        )
    cs = config.current_sensor
    write_csv, csv_skipped_reason = _csv_choice(settings, n_samples)
    return _Plan(
        out=out, settings=settings, traj=traj, fs=fs, timescale=timescale,
        ticks_per_sample=ticks_per_sample, n_samples=n_samples, decim=decim, analog_rate=fs / decim, tables=tables,
        gain=1.0 + np.asarray(cs.gain_error), offset=np.asarray(cs.offset_a),
        n_chunks=max(int(math.ceil(settings.duration_s / CHUNK_S)), 1), write_csv=write_csv,
        csv_skipped_reason=csv_skipped_reason,
    )


def _csv_choice(settings: ExportSettings, n_samples: int) -> tuple[bool, str]:
    """Whether stimulus.csv is written, and why not: it is optional above a size threshold."""
    csv_estimate = n_samples * csv_row_bytes(settings)
    if settings.write_csv and csv_estimate > settings.csv_max_bytes:
        return False, (
            f"stimulus.csv skipped: {n_samples} samples would take about {csv_estimate / 1e9:.1f} GB, above the "
            f"{settings.csv_max_bytes / 1e9:.1f} GB limit (--csv-max-bytes); stimulus.vcd has the same signals"
        )
    if not settings.write_csv:
        return False, "stimulus.csv not written (--no-csv)"
    return True, ""


def _initial_hall_levels(settings: ExportSettings, first) -> list[int]:
    """Hall levels at t = 0 from the first edge of each sensor (its opposite); a sensor that never
    switches keeps its ideal level."""
    levels = hall_state(settings.start_angle_deg_e).astype(np.int64).tolist()
    for x in range(3):
        mine = np.nonzero(first.sensor == x)[0]
        if mine.size:
            levels[x] = 0 if first.rising[mine[0]] else 1
    return levels


def _open_files(plan: _Plan) -> _Files:
    settings, out = plan.settings, plan.out
    reals = list(CURRENT_NAMES) if settings.currents else []
    comment = (f"bldc-hil stimulus: Hall pins HA HB HC (1 = high), phase-current sensor outputs IA IB IC in volts; "
               f"sample rate {plan.fs:g} Hz; plant {plan.config.name} ({plan.config.config_hash()}); "
               f"seed {settings.seed}")
    vcd = VcdWriter(
        out / "stimulus.vcd", plan.timescale, list(HALL_NAMES), reals, scope="stimulus", comment=comment,
        real_format="%.6g"
    )
    csv_file = open(out / "stimulus.csv", "w", newline="\n") if plan.write_csv else None
    if csv_file is not None:
        csv_file.write(
            "t_s," + ",".join(HALL_NAMES) + ("," + ",".join(CURRENT_NAMES) if settings.currents else "") + "\n"
        )
    truth_file = open(out / "truth.csv", "w", newline="\n")
    truth_file.write(",".join(TRUTH_COLUMNS) + "\n")
    return _Files(vcd, truth_file, csv_file)


def _hall_events(plan: _Plan, log, stream: _Stream) -> np.ndarray:
    """A chunk's Hall pin changes, quantised to the nearest sample (|error| <= half a sample period),
    as (sample, sensor, level); the pin edge of each sector boundary is remembered for the truth."""
    idx = np.rint(log.t_conditioned_s * plan.fs).astype(np.int64)
    keep = (idx >= 0) & (idx < plan.n_samples)
    ev = np.column_stack([idx[keep], log.sensor[keep].astype(float), log.rising[keep].astype(float)])
    n_edge = 3 * log.boundary + 2 * log.sensor  # the sector boundary each edge announces (60 n deg e)
    for n, i, x, r in zip(n_edge.tolist(), idx.tolist(), log.sensor.tolist(), log.rising.tolist()):
        stream.pin_of_n[n] = (i, x, int(r))
    return ev


def _analog_events(plan: _Plan, c: int, stream: _Stream) -> np.ndarray | None:
    """A chunk's current-sensor outputs as (sample, 3 + phase, volts): updated every ``decim`` samples,
    only where a value changed (after the LSB); None without currents or samples."""
    settings = plan.settings
    ta, tb = plan.chunk_span(c)
    k0 = int(math.ceil(ta * plan.fs / plan.decim)) * plan.decim
    k1 = min(int(math.ceil(tb * plan.fs / plan.decim)) * plan.decim, plan.n_samples)
    if not settings.currents or k1 <= k0:
        return None
    ks = np.arange(k0, k1, plan.decim)
    t = ks / plan.fs
    theta_m = plan.traj.angle_deg_e(t) / plan.config.motor.pole_pairs
    amps = plan.tables.currents_a(theta_m, plan.traj.speed_rpm(t))
    meas = amps.T * plan.gain + plan.offset
    cs = plan.config.current_sensor
    if cs.noise_rms_a > 0:
        meas = meas + cs.noise_rms_a * np.random.default_rng(_seed(settings.seed, 2, c)).standard_normal(meas.shape)
    volts = (
        np.rint((settings.current_zero_v + settings.current_v_per_a * meas) / settings.analog_lsb_v)
        * settings.analog_lsb_v
    )
    if stream.last_volts is None:
        stream.last_volts = volts[0].copy()
        stream.analog_now = volts[0].copy()
    prev = np.vstack([stream.last_volts, volts[:-1]])
    changed = volts != prev
    rows, cols = np.nonzero(changed)
    stream.last_volts = volts[-1].copy()
    return np.column_stack([ks[rows], 3 + cols, volts[rows, cols]])


def _collect_truth(plan: _Plan, c: int, stream: _Stream) -> None:
    """Every sector boundary the rotor crosses in chunk ``c``, as truth rows waiting to be written."""
    traj, pp = plan.traj, plan.config.motor.pole_pairs
    th_b = float(traj.angle_deg_e(plan.chunk_span(c)[1]))
    n_hi = int(math.floor(th_b / 60.0)) if plan.last(c) else int(math.ceil(th_b / 60.0)) - 1
    if n_hi >= stream.n_next:
        ns = np.arange(stream.n_next, n_hi + 1)
        t_id = traj.time_at_deg_e(60.0 * ns)
        ok = t_id <= plan.settings.duration_s
        ns, t_id = ns[ok], t_id[ok]
        stream.carry_truth.append(
            np.column_stack([ns, t_id, np.mod(ns, 6), 60.0 * ns, 60.0 * ns / pp, traj.speed_rpm(t_id)])
        )
        stream.n_next = int(ns[-1]) + 1 if ns.size else stream.n_next


def _write_signals(plan: _Plan, c: int, fresh: np.ndarray, stream: _Stream, files: _Files, levels: list[int]) -> None:
    """Every event before chunk ``c``'s guard into the VCD and the CSV; the rest waits for the next
    chunk (a conditioned edge may land after the chunk whose rotor angle produced it)."""
    settings, fs = plan.settings, plan.fs
    if fresh.size and fresh[:, 0].min() < stream.written_until:
        raise SignalError(
            "export",
            f"an edge at sample {int(fresh[:, 0].min())} arrived after samples up to {stream.written_until} were "
            f"written (conditioning delay plus jitter beyond the {GUARD_S * 1e3:g} ms chunk guard)",
        )
    events = np.concatenate([stream.carry_ev, fresh])
    events = events[np.lexsort((events[:, 1], events[:, 0]))]
    limit = plan.n_samples if plan.last(c) else int(math.floor((plan.chunk_span(c)[1] - GUARD_S) * fs))
    now = events[:, 0] < limit
    batch, stream.carry_ev = events[now], events[~now]
    if c == 0:
        init = list(map(float, levels)) + (list(map(float, stream.analog_now)) if settings.currents else [])
        files.vcd.initial(init)
        # the tick-0 analog values are in $dumpvars
        batch = batch[~((batch[:, 0] == 0) & (batch[:, 1] >= 3))]
    files.vcd.changes(
        (batch[:, 0] * plan.ticks_per_sample).astype(np.int64), batch[:, 1].astype(np.int64), batch[:, 2]
    )
    if files.csv is not None and limit > stream.written_until:
        # (updates hall_now and analog_now to the values at `limit`)
        _write_csv_rows(
            files.csv,
            stream.written_until,
            limit,
            batch,
            stream.hall_now,
            stream.analog_now if settings.currents else None,
            plan.decim,
            fs,
            _time_format(fs),
        )
    stream.written_until = max(stream.written_until, limit)


def _flush_truth(plan: _Plan, c: int, stream: _Stream, files: _Files, res: ExportResult) -> None:
    """The truth rows whose Hall edge (within 30 deg e of the boundary) has surely been generated."""
    if not stream.carry_truth:
        return
    tr = np.concatenate(stream.carry_truth)
    done = (tr[:, 3] < float(plan.traj.angle_deg_e(plan.chunk_span(c)[1])) - 30.0) | plan.last(c)
    _write_truth(files.truth, tr[done], stream.pin_of_n, plan.fs)
    res.n_commutations += int(done.sum())
    stream.carry_truth = [tr[~done]]
    oldest = int(tr[~done, 0].min()) if (~done).any() else stream.n_next
    for n in [n for n in stream.pin_of_n if n < oldest - 12]:
        del stream.pin_of_n[n]


def _list_files(plan: _Plan, res: ExportResult) -> None:
    """The sizes and names of what was written; a stale CSV from an earlier export must not pass for
    this one."""
    out = plan.out
    res.vcd_bytes = (out / "stimulus.vcd").stat().st_size
    res.files = ["stimulus.vcd", "truth.csv", "meta.json"]
    if plan.write_csv:
        res.csv_bytes = (out / "stimulus.csv").stat().st_size
        res.files.insert(1, "stimulus.csv")
    elif (out / "stimulus.csv").exists():
        (out / "stimulus.csv").unlink()


def export(out_dir: str | Path, settings: ExportSettings, progress=None) -> ExportResult:
    """Generate the stimulus chunk by chunk into ``out_dir``: stimulus.vcd, stimulus.csv (unless too
    large or not wanted), truth.csv and meta.json."""
    wall0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plan = _plan(out, settings)
    res = ExportResult(plan.out, csv_skipped_reason=plan.csv_skipped_reason)
    first = _chunk_edges(plan.config, plan.traj, 0, min(CHUNK_S, settings.duration_s), settings, plan.tables)
    levels = _initial_hall_levels(settings, first)
    files = _open_files(plan)
    stream = _Stream(hall_now=list(levels), n_next=int(math.floor(settings.start_angle_deg_e / 60.0)) + 1)
    for c in range(plan.n_chunks):
        ta, tb = plan.chunk_span(c)
        log = first if c == 0 else _chunk_edges(plan.config, plan.traj, ta, tb, settings, plan.tables, chunk=c)
        res.n_edges += len(log)
        ev = [_hall_events(plan, log, stream)]
        analog = _analog_events(plan, c, stream)
        if analog is not None:
            ev.append(analog)
        _collect_truth(plan, c, stream)
        _write_signals(plan, c, np.concatenate(ev), stream, files, levels)
        _flush_truth(plan, c, stream, files, res)
        if progress:
            progress(c + 1, plan.n_chunks)
    files.close(plan.n_samples * plan.ticks_per_sample)
    _list_files(plan, res)
    res.wall_s = time.perf_counter() - wall0
    _write_meta(plan.out, settings, res, plan.timescale, plan.ticks_per_sample, plan.analog_rate, plan.tables)
    return res


def _chunk_edges(config, traj: Trajectory, ta: float, tb: float, settings: ExportSettings, tables, chunk: int = 0):
    ops = []
    for a, b, r0, r1 in traj.pieces(ta, tb):
        current = tables.mean_abs_current_a(0.5 * (r0 + r1)) if tables is not None else 0.0
        ops.append(OperatingPoint(duration_s=b - a, speed_rpm=r0, end_speed_rpm=r1, mean_phase_current_a=current))
    return simulate_edges(
        config, ops, seed=_seed(settings.seed, 1, chunk), start_angle_deg_e=float(traj.angle_deg_e(ta)), start_time_s=ta
    )


def _write_csv_rows(
    f, k_from: int, k_to: int, batch: np.ndarray, hall_now: list[int], analog_now, decim: int, fs: float, tfmt: str
) -> None:
    """Samples k_from..k_to-1 of the signals the VCD describes (zero-order hold), in blocks."""
    block = 1 << 18
    decimals = int(tfmt[2:-1])
    hall_ev = batch[batch[:, 1] < 3]
    ana_ev = batch[batch[:, 1] >= 3]
    hall_text = [(",%d,%d,%d" % ((c >> 2) & 1, (c >> 1) & 1, c & 1)).encode() for c in range(8)]
    for s in range(k_from, k_to, block):
        e = min(s + block, k_to)
        k = np.arange(s, e)
        code = np.zeros(k.size, dtype=np.int64)
        for x in range(3):
            code = code * 2 + _held(hall_ev, x, k, hall_now)
        rows = [_time_text(k, fs, decimals), [hall_text[c] for c in code.tolist()]]
        if analog_now is not None:
            # the analog values change at most every `decim` samples: format those, then repeat
            first = (s // decim) * decim
            ku = np.arange(first, e, decim)
            held = [_held(ana_ev, 3 + x, ku, analog_now) for x in range(3)]
            text = [(",%.4f,%.4f,%.4f" % v).encode() for v in zip(*(h.tolist() for h in held))]
            rows.append([text[j] for j in ((k - first) // decim).tolist()])
        f.write(b"\n".join(map(b"".join, zip(*rows))).decode() + "\n")


def _held(events: np.ndarray, var: int, k: np.ndarray, now: list) -> np.ndarray:
    """Value of ``var`` at samples ``k`` (zero-order hold of its events; ``now`` = value before
    them, updated to the value after the block)."""
    ex = events[events[:, 1] == var]
    slot = var % 3
    if ex.size == 0:
        return np.full(k.size, now[slot])
    j = np.searchsorted(ex[:, 0], k, side="right")
    vals = np.where(j > 0, ex[np.maximum(j - 1, 0), 2], now[slot])
    done = ex[ex[:, 0] <= k[-1]]
    if done.size:
        now[slot] = type(now[slot])(done[-1, 2]) if not isinstance(now, np.ndarray) else done[-1, 2]
    return vals.astype(np.int64) if var < 3 else vals


def _time_text(k: np.ndarray, fs: float, decimals: int) -> list[bytes]:
    """``k / fs`` as fixed-decimal text, built digit by digit in numpy (savetxt is 20x slower)."""
    q = np.rint(k * (10.0 ** decimals / fs)).astype(np.int64)
    whole, frac = np.divmod(q, 10 ** decimals)
    out: list[bytes] = [b""] * k.size
    width = np.where(whole > 0, np.floor(np.log10(np.maximum(whole, 1))).astype(np.int64) + 1, 1)
    for w in np.unique(width).tolist():
        sel = np.nonzero(width == w)[0]
        mat = np.empty((sel.size, w + 1 + decimals), dtype=np.uint8)
        v = whole[sel]
        for j in range(w - 1, -1, -1):
            v, d = np.divmod(v, 10)
            mat[:, j] = d + 48
        mat[:, w] = ord(".")
        v = frac[sel]
        for j in range(w + decimals, w, -1):
            v, d = np.divmod(v, 10)
            mat[:, j] = d + 48
        texts = mat.view(f"S{mat.shape[1]}").ravel().tolist()
        for i, t in zip(sel.tolist(), texts):
            out[i] = t
    return out


def _write_truth(f, rows: np.ndarray, pin_of_n: dict, fs: float) -> None:
    lines = []
    for n, t, s, th_e, th_m, rpm in rows.tolist():
        pin = pin_of_n.get(int(n))
        pin_text = f"{pin[0] / fs:.9f},{'ABC'[pin[1]]},{pin[2]}" if pin is not None else ",,"
        lines.append(f"{int(n)},{t:.12f},{int(s)},{th_e:.6f},{th_m:.6f},{rpm:.6f},{pin_text}")
    if lines:
        f.write("\n".join(lines) + "\n")


def _write_meta(
    out: Path,
    s: ExportSettings,
    res: ExportResult,
    timescale: Timescale,
    ticks_per_sample: int,
    analog_rate: float,
    tables: CurrentTables | None,
) -> None:
    try:
        version = metadata.version("bldc-hil")
    except metadata.PackageNotFoundError:  # pragma: no cover
        version = "unknown"
    fs = s.sample_rate_hz
    pp = s.config.motor.pole_pairs
    top_rpm = max(p[1] for p in s.breakpoints)
    meta = {
        "format": FORMAT,
        "files": {
            "stimulus_vcd": "stimulus.vcd",
            "stimulus_csv": "stimulus.csv" if res.csv_bytes is not None else None,
            "truth": "truth.csv",
        },
        "csv_skipped": res.csv_skipped_reason or None,
        "sample_rate_hz": fs,
        "vcd_timescale": str(timescale),
        "vcd_ticks_per_sample": ticks_per_sample,
        "duration_s": s.duration_s,
        "direction": "forward",
        "start_angle_deg_e": s.start_angle_deg_e,
        "profile_t_rpm": [list(p) for p in s.breakpoints],
        "pole_pairs": pp,
        "hall": {
            "names": list(HALL_NAMES),
            "high": 1,
            "edge_quantisation": "nearest sample",
            "max_abs_timing_error_s": 0.5 / fs,
            "max_abs_angle_error_deg_e_at_top_speed": 0.5 / fs * rpm_to_deg_e_per_s(top_rpm, pp),
        },
        "currents": None
        if not s.currents
        else {
            "names": list(CURRENT_NAMES),
            "unit": "V",
            "v_per_a": s.current_v_per_a,
            "zero_v": s.current_zero_v,
            "gain_error": list(s.config.current_sensor.gain_error),
            "offset_a": list(s.config.current_sensor.offset_a),
            "noise_rms_a": s.config.current_sensor.noise_rms_a,
            "update_rate_hz": analog_rate,
            "lsb_v": s.analog_lsb_v,
            "model": "electrical plant, ideal commutation, at the duty of its torque balance, "
            "tabulated per mechanical angle at a speed grid (quasi-static)",
            "grid_rpm": tables.speeds_rpm.tolist() if tables is not None else [],
        },
        "truth": {
            "columns": list(TRUTH_COLUMNS),
            "meaning": "one row per ideal commutation: the rotor reaches theta_e_deg = 60 n "
            "(sector n mod 6 begins) at t_ideal_s; "
            "speed_rpm is the true speed then; t_hall_pin_s is when the Hall change announcing it is on the pins",
        },
        "plant": s.config.to_dict(),
        "plant_sha256_16": s.config.config_hash(),
        "deviations": s.deviations,
        "effects_source": s.effects_source or None,
        "seed": s.seed,
        "edges": res.n_edges,
        "commutations": res.n_commutations,
        "command": s.command,
        "generator": {"bldc-hil": version, "python": platform.python_version(), "numpy": np.__version__},
        "wall_s": round(res.wall_s, 3),
    }
    (out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
