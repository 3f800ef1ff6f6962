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


def export(out_dir: str | Path, settings: ExportSettings, progress=None) -> ExportResult:
    wall0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res = ExportResult(out)
    config = settings.config
    pp = config.motor.pole_pairs
    traj = Trajectory(settings.breakpoints, settings.duration_s, pp, settings.start_angle_deg_e)
    fs = float(settings.sample_rate_hz)
    timescale, ticks_per_sample = Timescale.for_sample_rate(fs)
    n_samples = int(round(settings.duration_s * fs))
    decim = max(int(round(fs / settings.analog_rate_hz)), 1)
    analog_rate = fs / decim
    tables: CurrentTables | None = None
    if settings.currents:
        tables = tabulate(
            config,
            [p[1] for p in settings.breakpoints] + [float(traj.speed_rpm(settings.duration_s))],
            seed=settings.seed,
        )
    cs = config.current_sensor
    gain = 1.0 + np.asarray(cs.gain_error)
    offset = np.asarray(cs.offset_a)

    # the CSV is optional above a size threshold
    csv_estimate = n_samples * csv_row_bytes(settings)
    write_csv = settings.write_csv
    if write_csv and csv_estimate > settings.csv_max_bytes:
        write_csv = False
        res.csv_skipped_reason = (
            f"stimulus.csv skipped: {n_samples} samples would take about {csv_estimate / 1e9:.1f} GB, above the "
            f"{settings.csv_max_bytes / 1e9:.1f} GB limit (--csv-max-bytes); stimulus.vcd has the same signals"
        )
    elif not write_csv:
        res.csv_skipped_reason = "stimulus.csv not written (--no-csv)"

    # Hall levels at t = 0 from the first edge of each sensor (its opposite); a sensor that never
    # switches keeps its ideal level

    levels = hall_state(settings.start_angle_deg_e).astype(np.int64).tolist()
    first = _chunk_edges(config, traj, 0, min(CHUNK_S, settings.duration_s), settings, tables)
    for x in range(3):
        mine = np.nonzero(first.sensor == x)[0]
        if mine.size:
            levels[x] = 0 if first.rising[mine[0]] else 1

    reals = list(CURRENT_NAMES) if settings.currents else []
    comment = (f"bldc-hil stimulus: Hall pins HA HB HC (1 = high), phase-current sensor outputs IA IB IC in volts; "
               f"sample rate {fs:g} Hz; plant {config.name} ({config.config_hash()}); seed {settings.seed}")
    vcd = VcdWriter(
        out / "stimulus.vcd", timescale, list(HALL_NAMES), reals, scope="stimulus", comment=comment, real_format="%.6g"
    )
    n_chunks = max(int(math.ceil(settings.duration_s / CHUNK_S)), 1)
    last_volts = None
    csv_file = open(out / "stimulus.csv", "w", newline="\n") if write_csv else None
    if csv_file is not None:
        csv_file.write(
            "t_s," + ",".join(HALL_NAMES) + ("," + ",".join(CURRENT_NAMES) if settings.currents else "") + "\n"
        )
    truth_file = open(out / "truth.csv", "w", newline="\n")
    truth_file.write(",".join(TRUTH_COLUMNS) + "\n")
    tfmt = _time_format(fs)

    carry_ev = np.zeros((0, 3))          # (sample index, variable, value) not yet written
    carry_truth: list[np.ndarray] = []   # truth rows not yet written
    pin_of_n: dict[int, tuple[int, int, int]] = {}
    written_until = 0                    # samples before this are in the files
    hall_now = list(levels)
    analog_now = None
    n_next = int(math.floor(settings.start_angle_deg_e / 60.0)) + 1  # next sector boundary index
    for c in range(n_chunks):
        ta = c * CHUNK_S
        tb = min((c + 1) * CHUNK_S, settings.duration_s)
        log = first if c == 0 else _chunk_edges(config, traj, ta, tb, settings, tables, chunk=c)
        res.n_edges += len(log)
        # Hall pin changes, quantised to the nearest sample (|error| <= half a sample period)
        idx = np.rint(log.t_conditioned_s * fs).astype(np.int64)
        keep = (idx >= 0) & (idx < n_samples)
        ev = [np.column_stack([idx[keep], log.sensor[keep].astype(float), log.rising[keep].astype(float)])]
        n_edge = 3 * log.boundary + 2 * log.sensor  # the sector boundary each edge announces (60 n deg e)
        for n, i, x, r in zip(n_edge.tolist(), idx.tolist(), log.sensor.tolist(), log.rising.tolist()):
            pin_of_n[n] = (i, x, int(r))
        # analog updates every `decim` samples, only where a value changed (after the LSB)
        k0 = int(math.ceil(ta * fs / decim)) * decim
        k1 = min(int(math.ceil(tb * fs / decim)) * decim, n_samples)
        if settings.currents and k1 > k0:
            ks = np.arange(k0, k1, decim)
            t = ks / fs
            theta_m = traj.angle_deg_e(t) / pp
            amps = tables.currents_a(theta_m, traj.speed_rpm(t))
            meas = amps.T * gain + offset
            if cs.noise_rms_a > 0:
                meas = meas + cs.noise_rms_a * np.random.default_rng(_seed(settings.seed, 2, c)).standard_normal(
                    meas.shape
                )
            volts = (
                np.rint((settings.current_zero_v + settings.current_v_per_a * meas) / settings.analog_lsb_v)
                * settings.analog_lsb_v
            )
            if last_volts is None:
                last_volts = volts[0].copy()
                analog_now = volts[0].copy()
            prev = np.vstack([last_volts, volts[:-1]])
            changed = volts != prev
            rows, cols = np.nonzero(changed)
            ev.append(np.column_stack([ks[rows], 3 + cols, volts[rows, cols]]))
            last_volts = volts[-1].copy()
        # truth: every sector boundary the rotor crosses in this chunk
        th_b = float(traj.angle_deg_e(tb))
        n_hi = int(math.floor(th_b / 60.0)) if c == n_chunks - 1 else int(math.ceil(th_b / 60.0)) - 1
        if n_hi >= n_next:
            ns = np.arange(n_next, n_hi + 1)
            t_id = traj.time_at_deg_e(60.0 * ns)
            ok = t_id <= settings.duration_s
            ns, t_id = ns[ok], t_id[ok]
            carry_truth.append(
                np.column_stack([ns, t_id, np.mod(ns, 6), 60.0 * ns, 60.0 * ns / pp, traj.speed_rpm(t_id)])
            )
            n_next = int(ns[-1]) + 1 if ns.size else n_next
        # write everything before the guard
        fresh = np.concatenate(ev)
        if fresh.size and fresh[:, 0].min() < written_until:
            raise SignalError(
                "export",
                f"an edge at sample {int(fresh[:, 0].min())} arrived after samples up to {written_until} were "
                f"written (conditioning delay plus jitter beyond the {GUARD_S * 1e3:g} ms chunk guard)",
            )
        events = np.concatenate([carry_ev, fresh])
        events = events[np.lexsort((events[:, 1], events[:, 0]))]
        limit = n_samples if c == n_chunks - 1 else int(math.floor((tb - GUARD_S) * fs))
        now = events[:, 0] < limit
        batch, carry_ev = events[now], events[~now]
        if c == 0:
            init = list(map(float, levels)) + (list(map(float, analog_now)) if settings.currents else [])
            vcd.initial(init)
            # the tick-0 analog values are in $dumpvars
            batch = batch[~((batch[:, 0] == 0) & (batch[:, 1] >= 3))]
        vcd.changes((batch[:, 0] * ticks_per_sample).astype(np.int64), batch[:, 1].astype(np.int64), batch[:, 2])
        if csv_file is not None and limit > written_until:
            # (updates hall_now and analog_now to the values at `limit`)
            _write_csv_rows(
                csv_file,
                written_until,
                limit,
                batch,
                hall_now,
                analog_now if settings.currents else None,
                decim,
                fs,
                tfmt,
            )
        written_until = max(written_until, limit)
        # truth rows whose ideal instant is written
        if carry_truth:
            tr = np.concatenate(carry_truth)
            # a row waits until its Hall edge (within 30 deg e of it) has surely been generated
            done = (tr[:, 3] < float(traj.angle_deg_e(tb)) - 30.0) | (c == n_chunks - 1)
            _write_truth(truth_file, tr[done], pin_of_n, fs)
            res.n_commutations += int(done.sum())
            carry_truth = [tr[~done]]
            oldest = int(tr[~done, 0].min()) if (~done).any() else n_next
            for n in [n for n in pin_of_n if n < oldest - 12]:
                del pin_of_n[n]
        if progress:
            progress(c + 1, n_chunks)
    vcd.close(n_samples * ticks_per_sample)
    truth_file.close()
    if csv_file is not None:
        csv_file.close()
    res.vcd_bytes = (out / "stimulus.vcd").stat().st_size
    res.files = ["stimulus.vcd", "truth.csv", "meta.json"]
    if write_csv:
        res.csv_bytes = (out / "stimulus.csv").stat().st_size
        res.files.insert(1, "stimulus.csv")
    elif (out / "stimulus.csv").exists():
        (out / "stimulus.csv").unlink()  # a stale CSV from an earlier export must not pass for this one
    res.wall_s = time.perf_counter() - wall0
    _write_meta(out, settings, res, timescale, ticks_per_sample, analog_rate, tables)
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
