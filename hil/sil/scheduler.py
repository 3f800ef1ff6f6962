"""Interrupts that take time: the peripherals of ``hil.sil.peripherals`` around a firmware that
reports its cycles (``pil:``, ``hil.pil.firmware.PilFirmware``), with the NVIC's scheduling.

A firmware in the loop on the PC (``sil:``) runs every interrupt at its event, in zero time; this
module is for a firmware on an emulated core, whose every instruction costs cycles at the
target's ``clock_hz`` (docs/processor-in-the-loop.md, "Timing and interrupts"):

- **Duration.** An interrupt started at t0 runs for its cycles / clock_hz, exception entry and
  return included (the core counts them). Its event's arguments are latched at the event: the
  capture count, the ADC conversion the event triggered.
- **Outputs at the return.** What it writes (gates, duty, compare) takes effect when it returns;
  the plant keeps the old gates meanwhile.
- **Priorities.** An interrupt that becomes pending while another runs preempts it when its NVIC
  priority number (the target's ``priorities``) is strictly lower; otherwise it waits, and is
  tail-chained when the running one returns (the tail-chain's cycles instead of a return and a
  new entry). Among pending ones the lowest number runs first, then Hall, compare, control (the
  order of their events at one instant).
- **Overrun.** An interrupt still running, or still pending, when its own next instance is due
  (the same capture channel for Hall) is a finding naming the interrupt, its cycles and its
  period. A control or compare instance due while its predecessor is still pending is lost (the
  NVIC's pending bit is set once); every Hall capture is delivered.

**How the plant and the core keep step.** The plant cannot see an interrupt's outputs before it
returns, so while an interrupt runs the plant can be stepped ahead with the old gates to its next
event (``Simulation.step_until`` stops at a Hall edge) and the core run up to that instant
(``Core.run(until_cycle)``); a Hall edge there that preempts begins a nested call on the paused
core. If the interrupt returned before the plant's instant, the plant went too far: it goes back to
its checkpoint (``Simulation.checkpoint``/``restore``) and steps to the return. When no Hall edge
can preempt the running interrupt, the core runs first, to its return or the next timer event,
and the plant follows. Nothing depends on the host's speed: the same seed gives the same run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .peripherals import _EPS_S, _KIND, COMPARE, CONTROL, EVENTS, HALL, FirmwareFault, Peripherals

#: the tail-chain, in cycles, where the core's cycle table does not give it: the Cortex-M3 and M4
#: Technical Reference Manuals (ARM DDI 0337, DDI 0439, "Exception handling": tail-chaining, 6 cycles)
TAIL_CHAIN_CYCLES = 6
#: the ADC result registers each interrupt's conversion is written to (regular for the control
#: interrupt, injected for the Hall capture), as int16[3] at ADC_BASE + 8 * slot
_ADC_SLOT = {CONTROL: 0, HALL: 1}
#: overrun findings kept in full (the rest are counted)
MAX_OVERRUNS = 100


def _processor(fault: FirmwareFault, finding) -> FirmwareFault:
    """``fault`` marked as the core's ``finding`` (its kind: UsageFault, StackOverflow, Hang ...): the
    worker reports it as a processor fault, the device's own failure (``hil.sil.link``)."""
    fault.processor = finding.kind
    return fault


@dataclass
class _Call:
    """An interrupt instance: pending (not started) or on the stack (running or preempted)."""

    event: int
    priority: int
    seq: int
    t_event_s: float
    count: int
    args: tuple  #: the ISR's arguments after the count, the ADC registers as their values
    key: object  #: what its own next instance is (the kind; for Hall, the capture channel)
    start_cycle: int = 0


class TimedPeripherals(Peripherals):
    """``Peripherals`` whose interrupts take the firmware's cycles (``fw.core``) at
    ``fw.target.clock_hz`` and are scheduled by ``fw.target.priorities`` (module docstring)."""

    def __init__(self, fw, info, sim, **kwargs):
        self.core = fw.core
        target = fw.target
        self.clock_hz = float(target.clock_hz)
        self.priority = {event: int(target.priorities.get(kind, 0)) for event, kind in _KIND.items()}
        table = self.core.table
        self._exit_cycles = table.exception_return
        #: the framework's output read an interrupt returns into (one emulated call per interrupt)
        self._then = getattr(fw, "isr_tail", None)
        self._tail_cycles = getattr(table, "tail_chain", TAIL_CHAIN_CYCLES)
        self._stack: list[_Call] = []
        self._queued: list[_Call] = []
        self._seq = 0
        self._anchor_t, self._anchor_c = 0.0, 0
        self._busy_since: float | None = None
        #: a pending interrupt would preempt but the running code masks it (PRIMASK, BASEPRI): the
        #: core then runs a basic block at a time, so that it is taken at the block after the unmask
        self._masked = False
        self.masked_waits = 0
        self._last_event: dict = {}
        #: what the schedule measured (``figures``)
        self.overruns: list[dict] = []
        self.overrun_count = 0
        self.lost = {"compare": 0, "control": 0}
        self.response_s = {kind: [] for kind in _KIND.values()}
        self.busy_by_period: dict[int, float] = {}
        self.plant_rollbacks = 0
        super().__init__(fw, info, sim, **kwargs)
        from hil.pil.core import ADC_BASE

        self._adc_base = ADC_BASE

    # --- the time line -----------------------------------------------------------------------------
    def _time(self, cycles: float) -> float:
        return self._anchor_t + (cycles - self._anchor_c) / self.clock_hz

    def _cycle(self, t_s: float) -> float:
        return self._anchor_c + (t_s - self._anchor_t) * self.clock_hz

    # --- interrupts ----------------------------------------------------------------------------------
    def _raise(self, event: int, t_s: float, count: int, args: tuple) -> None:
        """An interrupt's event at ``t_s``: pending from now (``_dispatch`` starts it)."""
        kind = _KIND[event]
        key = (kind, args[0]) if event == HALL else kind
        values = tuple(tuple(int(v) for v in a) if hasattr(a, "__len__") else a for a in args)
        busy = [c for c in self._stack if c.key == key] + [c for c in self._queued if c.key == key]
        if busy:
            self._overrun(busy[0], kind, t_s)
            if event != HALL and busy[0] in self._queued:
                self.lost[kind] += 1
                return  # its pending bit is set already: this instance is lost
        self._last_event[key] = t_s
        self._seq += 1
        self._queued.append(_Call(event, self.priority[event], self._seq, t_s, count, values, key))

    def _overrun(self, running: _Call, kind: str, t_s: float) -> None:
        self.overrun_count += 1
        if len(self.overruns) >= MAX_OVERRUNS:
            return
        started = running in self._stack
        cycles = int(self.core.cycles - running.start_cycle) if started else 0
        top = self._stack[-1] if self._stack else None
        # the control interrupt's period is its rate's; a Hall channel's or the compare's, the time
        # since the instance still running or pending
        period = self.control_period_s if running.event == CONTROL else t_s - running.t_event_s
        self.overruns.append({
            "interrupt": kind + (f" (pin {'ABC'[running.key[1]]})" if running.event == HALL else ""),
            "t_s": t_s, "count": self.count(t_s), "state": "running" if started else "pending",
            "cycles": cycles, "us": cycles / self.clock_hz * 1e6, "period_s": period,
            # what kept it from finishing: the interrupt running at that instant, and its cycles so far
            "running": _KIND[top.event] if top is not None else "",
            "running_cycles": int(self.core.cycles - top.start_cycle) if top is not None else 0,
        })

    def _dispatch(self, t_s: float, tail: bool = False) -> None:
        """Start the pending interrupts that may run at ``t_s``: the most urgent one when nothing
        runs, or when it preempts the running one (a strictly lower priority number)."""
        self._masked = False
        while self._queued:
            best = min(self._queued, key=lambda c: (c.priority, c.event, c.seq))
            if self._stack and best.priority >= self._stack[-1].priority:
                return
            if self._stack and self.core.masked(best.priority):
                self._masked = True  # the running code masks it: taken once it unmasks (``_run``)
                return
            self._queued.remove(best)
            self._start(best, t_s, tail and not self._stack)
            tail = False

    def _start(self, call: _Call, t_s: float, tail: bool) -> None:
        core = self.core
        if self._busy_since is None:
            self._busy_since = t_s
        event = call.event
        args = list(call.args)
        if event in _ADC_SLOT:  # the conversion the event triggered, in its result registers
            address = self._adc_base + 8 * _ADC_SLOT[event]
            core.write(address, np.asarray(args[-1], dtype="<i2").tobytes())
            args[-1] = address
        self._enter(event, t_s, call.count)
        c0 = core.cycles
        call.start_cycle = c0
        core.begin(EVENTS[event], (call.count, *args), interrupt=True, label=_KIND[event], then=self._then)
        if tail:  # tail-chained: the return's and the entry's cycles are one tail-chain
            self._anchor_t = t_s - (self._exit_cycles - self._tail_cycles) / self.clock_hz
            self._anchor_c = core.cycles
        else:
            self._anchor_t, self._anchor_c = t_s, c0
        self._stack.append(call)

    def _returned(self, t_s: float) -> None:
        """The innermost interrupt returned at ``t_s`` (the plant is there): its outputs take effect."""
        call = self._stack.pop()
        kind = _KIND[call.event]
        self.interrupts[kind] += 1
        self.response_s[kind].append(t_s - call.t_event_s)
        self._outputs(call.event, t_s, call.count)
        if not self._stack:
            if self._queued:
                self._dispatch(t_s, tail=True)
            else:
                self._account_busy(self._busy_since, t_s)
                self._busy_since = None
        else:
            self._dispatch(t_s)

    def _account_busy(self, t0: float, t1: float, into: dict | None = None) -> None:
        """The CPU was busy from ``t0`` to ``t1``: its share of each control period it overlaps."""
        into = self.busy_by_period if into is None else into
        period = self.control_period_s
        k = math.floor(t0 / period)
        while t0 < t1:
            end = min(t1, (k + 1) * period)
            into[k] = into.get(k, 0.0) + (end - t0)
            t0, k = end, k + 1

    # --- the run -------------------------------------------------------------------------------------
    def run_until(self, t_stop_s: float) -> None:
        from hil.pil.core import ProcessorFinding

        try:
            self._run(t_stop_s)
        except ProcessorFinding as exc:
            t = self._time(exc.cycles) if self._stack else self.sim.t_s
            raise _processor(FirmwareFault(f"{exc} at t = {t:.9f} s (counter {self.count(t)})"), exc) from None

    def _plant_to(self, t_s: float) -> None:
        """The plant to ``t_s`` with the outputs in force; its Hall edges meanwhile are pending."""
        while (edge := self.sim.step_until(t_s)) is not None:
            self._hall([edge])

    def _events_at(self, t_s: float) -> None:
        """The wiring faults' pin changes, compare and control due at ``t_s`` (the plant is there)."""
        if self.next_pin_s <= t_s + _EPS_S:
            self._pins_due(self.next_pin_s)
        self._timers_due(t_s)

    def _run(self, t_stop_s: float) -> None:
        sim, core = self.sim, self.core
        hall_priority = self.priority[HALL]
        while True:
            t_timer = min(t_stop_s, self.next_control_s, self.compare_s, self.next_pin_s)
            if not self._stack:
                edge = sim.step_until(t_timer)
                if edge is not None:
                    self._hall([edge])
                else:
                    self._events_at(t_timer)
                self._dispatch(sim.t_s)
                if edge is None and not self._stack and t_timer >= t_stop_s:
                    return
                continue
            t_timer = max(t_timer, sim.t_s)
            if self._masked:  # a block at a time until the running code unmasks the pending interrupt
                self.masked_waits += 1
                t_timer = max(sim.t_s, min(t_timer, self._time(core.cycles + 1)))
            if hall_priority < self._stack[-1].priority:
                # a Hall edge would preempt: the plant first, to its next event, with the old outputs
                checkpoint = sim.checkpoint()
                edge = sim.step_until(t_timer)
                t_plant = sim.t_s
                returned = core.run(self._cycle(t_plant))
                t_cpu = self._time(core.cycles)
                if returned and t_cpu < t_plant - _EPS_S:
                    sim.restore(checkpoint)  # it returned first: its outputs take effect there
                    self.plant_rollbacks += 1
                    self._plant_to(t_cpu)
                    self._returned(t_cpu)
                    continue
                if edge is not None:
                    self._hall([edge])
                else:
                    self._events_at(t_plant)
            else:
                returned = core.run(self._cycle(t_timer))
                t_cpu = self._time(core.cycles)
                t_plant = min(t_cpu, t_timer)
                self._plant_to(t_plant)
                if not returned:
                    self._events_at(t_timer)
            if returned:
                self._plant_to(t_cpu)
                self._returned(t_cpu)
            else:
                self._dispatch(t_cpu)
                if t_plant >= t_stop_s - _EPS_S:  # the plant's instant may round a hair below the stop
                    return

    def finish(self) -> None:
        """Before a power cycle or the next bench: the interrupts still running (a run ends at its
        instant, mid-interrupt perhaps) run to their returns on the core, and the pending ones are
        dropped, so that the core's next call starts from thread mode."""
        from hil.pil.core import ProcessorFinding

        try:
            while self._stack:
                self.core.run()
                self._stack.pop()
        except ProcessorFinding as exc:
            raise _processor(FirmwareFault(f"{exc} (finishing the interrupts of the last run)"), exc) from None
        self._queued.clear()

    # --- what the schedule measured ------------------------------------------------------------------
    def figures(self) -> dict:
        """Per interrupt its responses (event to return: median, p99, max, in s), the overruns, the
        lost instances, and the CPU load of each control period (its worst)."""
        out = {}
        for kind, r in self.response_s.items():
            if r:
                a = np.asarray(r)
                out[kind] = {"calls": int(a.size), "response_s": {
                    "median": float(np.median(a)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}}
        period = self.control_period_s
        busy = dict(self.busy_by_period)
        if self._busy_since is not None:  # still busy: up to the plant's instant
            self._account_busy(self._busy_since, self.sim.t_s, busy)
        loads = [b / period for b in busy.values()]
        # Liu and Layland bound a utilisation: each task's time over its period, the longest period of
        # the set included. The Hall interrupt's period is the edge interval at the plant's top speed
        # (six edges per electrical turn); a window of one control period that a Hall interrupt fills
        # is busy whatever the schedule, so the load judged is the worst over a window that long
        cfg = self.sim.config
        hall_period_s = 60.0 / (cfg.operating.top_speed_rpm * cfg.motor.pole_pairs * 6)
        window = max(1, math.ceil(hall_period_s / period - 1e-9))
        first, last = (min(busy), max(busy)) if busy else (0, -1)
        per = np.array([busy.get(k, 0.0) for k in range(first, last + 1)])
        window = min(window, per.size) or 1  # a run shorter than the window: its whole span
        windowed = float(np.convolve(per, np.ones(window), mode="valid").max() / (window * period)) if per.size \
            else 0.0
        return {"interrupts": out, "overruns": self.overruns, "overrun_count": self.overrun_count,
                "lost": dict(self.lost), "worst_load": windowed, "worst_load_window_s": window * period,
                "worst_load_one_period": max(loads, default=0.0),
                "mean_load": (sum(busy.values()) / (len(loads) * period)) if loads else 0.0,
                "periods": len(loads), "plant_rollbacks": self.plant_rollbacks, "masked_waits": self.masked_waits,
                "priorities": {_KIND[e]: p for e, p in self.priority.items()}}


def peripherals_for(fw):
    """The peripherals class a firmware needs: timed when it reports cycles (a core), else the
    zero-time ones of ``hil.sil.peripherals``."""
    return TimedPeripherals if getattr(fw, "core", None) is not None else Peripherals


__all__ = ["COMPARE", "TimedPeripherals", "peripherals_for"]
