"""Hall-line captures in: a logic analyser's file in any capture format of ``formats.FORMATS`` (VCD,
sigrok session .sr, CSV), as an ordinary-run recording (``hil recording import``).

The three Hall lines are read with the same readers as the gate captures (:class:`Capture`), each
level change becomes an edge (sensor, rise or fall, time), and the capture's time base becomes
the recording's ``timer_tick_s``: the greatest common step of the time stamps (a VCD's integer
ticks; a CSV's times within 0.1 % of a whole number of its smallest step), the sigrok session's
sample rate, or ``--sample-rate-hz``. Nothing about the motor is assumed: the recording says
only what the capture holds.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .capture import GateMapping, _csv_header
from .errors import SignalError
from .format import Recording
from .formats import capture_format, open_capture

HALL_SIGNALS = ("A", "B", "C")
#: the wire names looked for first; else the capture's first three channels
DEFAULT_CHANNELS = ("hall_a", "hall_b", "hall_c")


@dataclass
class HallCapture:
    t_s: np.ndarray
    sensor: np.ndarray
    rising: np.ndarray
    timer_tick_s: float | None
    tick_source: str
    channels: dict[str, str]
    simultaneous_dropped: int = 0
    notes: list[str] = field(default_factory=list)


def parse_channels(text: str) -> dict[str, str]:
    """``A=hall_a,B=hall_b,C=hall_c`` (channel names, or 1-based CSV column numbers)."""
    out = {}
    for item in (p.strip() for p in text.split(",") if p.strip()):
        if "=" not in item:
            raise SignalError("--channels", f"{item!r} is not SENSOR=CHANNEL (e.g. A=hall_a,B=hall_b,C=hall_c)")
        k, v = (x.strip() for x in item.split("=", 1))
        if k.upper() not in HALL_SIGNALS:
            raise SignalError("--channels", f"{k!r} is not a Hall sensor (A, B or C)")
        out[k.upper()] = v
    missing = [s for s in HALL_SIGNALS if s not in out]
    if missing:
        raise SignalError("--channels", f"no channel for sensor(s) {', '.join(missing)}")
    return out


def default_channels(path: Path, time_column: str | None = None) -> dict[str, str]:
    """``hall_a``/``hall_b``/``hall_c`` (any case) if the capture has them, else its first three channels."""
    names = capture_format(path).channels(path, time_column)
    low = {n.lower(): n for n in names}
    if all(c in low for c in DEFAULT_CHANNELS):
        return {s: low[c] for s, c in zip(HALL_SIGNALS, DEFAULT_CHANNELS)}
    if len(names) < 3:
        raise SignalError(
            str(path), f"three Hall channels are needed, the capture has {len(names)}: {', '.join(names)}"
        )
    return dict(zip(HALL_SIGNALS, names[:3]))


def read_hall_capture(
    path: str | Path,
    channels: dict[str, str] | None = None,
    *,
    sample_rate_hz: float | None = None,
    time_column: str | None = None,
    active_low: tuple[str, ...] = (),
    threshold: float = 0.5,
) -> HallCapture:
    """The Hall edges of a capture file (VCD, sigrok .sr, CSV with a time or sample-index column)."""
    path = Path(path)
    probe = open_capture(path)  # checks the file and its kind
    chosen = channels or default_channels(path, time_column)
    time_scale = None
    if probe.format.time_column and sample_rate_hz:
        time_scale = 1.0 / sample_rate_hz  # the time column counts samples
    elif probe.format.time_column:
        _, header, _ = _csv_header(path)
        t_name = (time_column or header[0]).strip()
        if re.fullmatch(r"(?i)(sample|samples|sample_?index|index|n|k)", t_name):
            raise SignalError(
                f"{path}: column {t_name}", "counts samples, not seconds: give --sample-rate-hz (or a time column)"
            )
    mapping = GateMapping(
        chosen,
        time=time_column,
        time_scale=time_scale,
        threshold=threshold,
        active_low=active_low,
        signals=HALL_SIGNALS,
    )
    cap = open_capture(path, mapping)
    ts, ss = [], []
    for t, s in cap.states():
        ts.append(t)
        ss.append(s)
    if not ts:
        raise SignalError(str(path), "no samples in the capture")
    t = np.concatenate(ts)
    state = np.concatenate(ss)
    # the first row is the state at the start; every later row is a change of one or more lines
    changed = state[1:] ^ state[:-1]
    t_change = t[1:]
    n_lines = ((changed >> 0) & 1) + ((changed >> 1) & 1) + ((changed >> 2) & 1)
    multi = n_lines > 1
    sensor_of = np.array([-1, 0, 1, -1, 2, -1, -1, -1])  # single-bit masks only
    keep = ~multi
    sensor = sensor_of[changed[keep]]
    rising = ((state[1:][keep] >> sensor) & 1).astype(bool)
    # the time base
    if sample_rate_hz:
        tick, how = 1.0 / sample_rate_hz, f"--sample-rate-hz {sample_rate_hz:g}"
    else:
        tick, how = probe.format.time_base(cap, t)
    notes = []
    if tick is None:
        how = "unknown: the time stamps have no common step; give --sample-rate-hz"
    elif tick > 0:
        notes.append(f"every edge time is quantised to {tick * 1e6:.4g} us")
    if multi.any():
        notes.append(
            f"{int(multi.sum())} sample(s) changed two or more lines at once (their order is unknown): "
            "those edges are left out"
        )
    return HallCapture(t_change[keep], sensor.astype(np.int64), rising, tick, how, chosen, int(multi.sum()), notes)


def capture_recording(cap: HallCapture, pole_pairs: int | None = None, source: str = "") -> Recording:
    """An ordinary-run recording (no segments) of a Hall capture."""
    if cap.t_s.size == 0:
        raise SignalError(source or "capture", "no Hall edge in the capture")
    motor = {"pole_pairs": int(pole_pairs)} if pole_pairs else {}
    tick = cap.timer_tick_s if cap.timer_tick_s and math.isfinite(cap.timer_tick_s) else None
    return Recording(
        motor=motor,
        segments=[],
        t_s=cap.t_s,
        sensor=cap.sensor,
        rising=cap.rising,
        segment=np.full(cap.t_s.size, -1, dtype=np.int64),
        timer_tick_s=tick,
        meta_extra={
            "source": {
                "capture": source,
                "channels": cap.channels,
                "time_base": cap.tick_source,
                "simultaneous_edges_dropped": cap.simultaneous_dropped,
            }
        },
    )


def step_summary(t_s: np.ndarray, sensor: np.ndarray, rising: np.ndarray) -> str:
    """How the Hall-edge core (``bldc.edges``) reads the captured edges as rotor steps: runs,
    direction, and what it removes (the same reading every analysis of the recording makes)."""
    from bldc.edges import HallEdgeError, decode_edges

    try:
        steps = decode_edges(t_s, sensor, rising)
    except HallEdgeError as e:
        return f"not readable as rotor steps: {e}"
    used = steps.used()
    fwd, rev = int(np.sum(steps.direction[used] > 0)), int(np.sum(steps.direction[used] < 0))
    c = steps.counts()
    return (
        f"{int(used.sum())} of {steps.t_s.size} edges in {int(steps.run.max()) + 1 if used.any() else 0} run(s) "
        f"({fwd} forward, {rev} reverse); removed: {c['glitches_removed']} glitch pair(s), "
        f"{c['invalid_states_dropped']} invalid-state edge(s), {c['short_runs_dropped']} short run(s); split at "
        f"{c['reversals']} reversal(s) and {c['stalls_split']} stall(s)"
    )
