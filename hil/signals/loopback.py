"""The loopback proof: a controller reads a stimulus VCD as its GPIO capture would, and its six
gate outputs, with PWM, are written as a VCD a logic analyser could have captured.

The controller is any :class:`~hil.dut.link.ControllerLink` that takes captured edges (the
virtual controller in-process, or over CANopen or Modbus): each Hall pin change becomes an
edge as the controller's input capture sees it (the pin's sample instant, floored to the
capture timer's tick), with the mean phase current its ADC reads from the current-sensor
channels at that instant. Its commands (sector, duty, at an instant) drive a six-step gate
pattern: the high side of the energised pair chopped at the PWM frequency, the PWM period
restarted at each commutation (on first), the low side on. Gate changes land on the
stimulus' sample grid, as a logic analyser at that rate would record them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bldc.hall import SECTOR_PHASES

from ..recording.capture import GATES
from ..recording.errors import SignalError
from ..recording.vcd import VcdReader, VcdWriter


@dataclass
class LoopbackResult:
    edges: int = 0
    commands: int = 0
    gate_changes: int = 0
    out_vcd: Path | None = None
    #: what the controller saw at each edge: (t_pin_s, t_capture_s, sensor, rising, current_a)
    captured: list = field(default_factory=list)


@dataclass
class GateTimeline:
    """Sector and duty in force from each instant; renders the gate pattern with PWM."""

    pwm_frequency_hz: float
    tick_s: float
    writer: VcdWriter
    sector: int = -1
    duty: float = 0.0
    since_s: float = 0.0
    carrier_origin_s: float = 0.0
    changes: int = 0
    _state: int = 0
    _pend_t: list = field(default_factory=list)
    _pend_s: list = field(default_factory=list)
    _pend_n: int = 0

    def apply(self, at_s: float, sector: int | None, duty: float | None) -> None:
        """Close the running interval at ``at_s`` and start the new one."""
        new_sector = self.sector if sector is None or sector == -2 else int(sector)
        new_duty = self.duty if duty is None or duty < 0 else float(duty)
        if new_sector == self.sector and new_duty == self.duty:
            return
        self.render(at_s)
        if new_sector != self.sector:
            self.carrier_origin_s = at_s  # PWM period restarted at commutation: the new pair conducts at once
        self.sector, self.duty, self.since_s = new_sector, new_duty, at_s
        self._emit(np.array([at_s]), np.array([self._pattern(at_s)]))

    def _pattern(self, t: float) -> int:
        if self.sector < 0:
            return 0
        hi, lo = SECTOR_PHASES[self.sector]
        period = 1.0 / self.pwm_frequency_hz
        on = ((t - self.carrier_origin_s) % period) < self.duty * period
        return (1 << (2 * lo + 1)) | ((1 << (2 * hi)) if on else 0)

    def render(self, until_s: float) -> None:
        """PWM edges of the running interval up to ``until_s``."""
        if self.sector < 0 or not 0.0 < self.duty < 1.0 or until_s <= self.since_s:
            self.since_s = max(self.since_s, until_s)
            return
        period = 1.0 / self.pwm_frequency_hz
        hi, lo = SECTOR_PHASES[self.sector]
        k = np.arange(
            math.floor((self.since_s - self.carrier_origin_s) / period),
            math.ceil((until_s - self.carrier_origin_s) / period) + 1,
        )
        rise = self.carrier_origin_s + k * period
        t = np.concatenate([rise, rise + self.duty * period])
        state = np.concatenate(
            [np.full(k.size, (1 << (2 * lo + 1)) | (1 << (2 * hi))), np.full(k.size, 1 << (2 * lo + 1))]
        )
        keep = (t > self.since_s) & (t < until_s)
        order = np.argsort(t[keep], kind="stable")
        self._emit(t[keep][order], state[keep][order])
        self.since_s = until_s

    def _emit(self, t_s: np.ndarray, states: np.ndarray) -> None:
        if t_s.size:
            self._pend_t.append(t_s)
            self._pend_s.append(states)
            self._pend_n += t_s.size
            if self._pend_n >= 1 << 16:
                self.flush()

    def flush(self) -> None:
        """Write the gate changes collected so far (each gate's own changes, on the sample grid)."""
        if not self._pend_t:
            return
        t_s, states = np.concatenate(self._pend_t), np.concatenate(self._pend_s).astype(np.int64)
        self._pend_t, self._pend_s, self._pend_n = [], [], 0
        ticks = np.rint(t_s / self.tick_s).astype(np.int64)
        prev = np.concatenate([[self._state], states[:-1]])
        out_t, out_i, out_v = [], [], []
        for j in range(6):
            changed = ((states ^ prev) >> j) & 1 == 1
            out_t.append(ticks[changed])
            out_i.append(np.full(int(changed.sum()), j))
            out_v.append(((states[changed] >> j) & 1).astype(float))
        t = np.concatenate(out_t)
        order = np.argsort(t, kind="stable")
        self.writer.changes(t[order], np.concatenate(out_i)[order], np.concatenate(out_v)[order])
        self.changes += int(t.size)
        self._state = int(states[-1])


def run_loopback(stimulus_dir: str | Path, link, out_vcd: str | Path, pwm_frequency_hz: float = 20e3,
                 capture_tick_s: float = 0.0, record: bool = False) -> LoopbackResult:
    """Play ``stimulus_dir/stimulus.vcd`` into the controller behind ``link``; write its gates."""
    d = Path(stimulus_dir)
    meta_path = d / "meta.json"
    if not meta_path.is_file():
        raise SignalError(str(meta_path), "missing (a stimulus directory from `hil signals export`)")
    meta = json.loads(meta_path.read_text())
    reader = VcdReader(d / "stimulus.vcd")
    scale = reader.timescale.seconds
    cur = meta.get("currents") or None
    names = ["HA", "HB", "HC"] + (["IA", "IB", "IC"] if cur else [])
    res = LoopbackResult(out_vcd=Path(out_vcd))
    writer = VcdWriter(out_vcd, reader.timescale, list(GATES), scope="gates",
                       comment=f"gate outputs of {getattr(link, 'where', 'a controller')} playing {d / 'stimulus.vcd'}")
    writer.initial([0.0] * 6)
    gates = GateTimeline(pwm_frequency_hz, scale, writer)
    levels = [-1, -1, -1]
    volts = [cur["zero_v"]] * 3 if cur else [0.0] * 3
    pending: list = []  # commands not yet due, in time order

    def run_due(until_s: float) -> None:
        while pending and pending[0].at_s <= until_s:
            c = pending.pop(0)
            gates.apply(c.at_s, c.sector, c.duty)
        gates.render(until_s)

    # the cycle-mean |i| the lockstep bench gives the controller (hil/bench/lockstep.py): the integral of the
    # phases' mean |i| over time, carried across chunks, differenced between consecutive Hall edges
    integral_as, integral_t_s, last_abs_a = 0.0, 0.0, 0.0
    edge_integral_as, edge_t_s = 0.0, 0.0

    for ticks, slot, val in reader.changes(names):
        hall = np.nonzero(slot < 3)[0]
        t_chunk = ticks * scale
        ana_at = []
        if cur:
            # the analog value in force after each change of the chunk: forward fill of each channel
            every = np.arange(slot.size)
            abs_a = np.zeros(slot.size)
            for x in range(3):
                mine = np.nonzero(slot == 3 + x)[0]
                j = np.searchsorted(mine, every, side="right") - 1
                filled = np.where(j >= 0, val[mine[np.maximum(j, 0)]] if mine.size else volts[x], volts[x])
                ana_at.append(filled[hall])
                abs_a += np.abs((filled - cur["zero_v"]) / cur["v_per_a"]) / 3.0
                if mine.size:
                    volts[x] = float(val[mine[-1]])
            # integral up to each change, the value before it held since the previous change
            held = np.concatenate(([last_abs_a], abs_a[:-1]))
            steps = np.diff(np.concatenate(([integral_t_s], t_chunk)))
            running = integral_as + np.cumsum(held * steps)
            if slot.size:
                integral_as, integral_t_s, last_abs_a = float(running[-1]), float(t_chunk[-1]), float(abs_a[-1])
        for n, i in enumerate(hall.tolist()):
            x, v = int(slot[i]), int(val[i])
            if levels[x] < 0 or levels[x] == v:  # the initial level, or no change: not an edge
                levels[x] = v
                continue
            levels[x] = v
            t_pin = int(ticks[i]) * scale
            t_cap = math.floor(t_pin / capture_tick_s + 1e-9) * capture_tick_s if capture_tick_s > 0 else t_pin
            current = (
                float(np.mean([abs((ana_at[k][n] - cur["zero_v"]) / cur["v_per_a"]) for k in range(3)])) if cur else 0.0
            )
            cycle_current = None
            if cur and t_pin > edge_t_s:
                cycle_current = (float(running[i]) - edge_integral_as) / (t_pin - edge_t_s)
                edge_integral_as, edge_t_s = float(running[i]), t_pin
            run_due(t_pin)
            edge = {"t_capture_s": t_cap, "sensor": x, "rising": v == 1, "now_s": t_pin, "current_a": current,
                    "cycle_current_a": cycle_current}
            res.edges += 1
            if record:
                res.captured.append((t_pin, t_cap, x, v == 1, current))
            for c in link.edge(edge):
                res.commands += 1
                at = max(c.at_s, t_pin)  # an instant already past applies now, as on the plant
                pending.append(type(c)(at, c.sector, c.duty, c.direction))
            pending.sort(key=lambda c: c.at_s)
            run_due(t_pin)
    end_s = reader.end_tick * scale
    run_due(end_s)
    gates.flush()
    writer.close(reader.end_tick)
    res.gate_changes = gates.changes
    return res
