"""The microcontroller around a firmware: timer, Hall capture, ADC, compare unit, control
interrupt and inverter, closed loop with the plant (``hil-sil/1``; docs/firmware-in-the-loop.md).

- **Timer.** One free-running counter at ``timer_hz``, ``timer_bits`` wide, started at a count
  that makes it wrap ``wrap_at_s`` into the run. The count of an instant t is
  ``start + floor(t * timer_hz)`` modulo 2^bits.
- **Hall pins.** One interrupt per pin change after the conditioning circuit (the plant's
  conditioned edge), with the count its capture channel latched at that change; pins that change
  at one instant are one call each, in the order A, B, C, each reading the levels after all changed.
- **ADC.** Phase currents through the plant's current sensors (gain, offset, noise), in counts of
  ``amps_per_count``, saturating at the int16 range: at every control interrupt and at each Hall
  capture (the injected conversion the capture triggers).
- **Compare unit.** After every interrupt ``hil_sil_compare`` is read; an armed count fires when
  the counter next equals it: a count at or just behind the counter fires one wrap later, and one
  left armed at the count that just fired fires again one wrap later.
- **Order.** Events at one instant run Hall, then compare, then control.
- **Inverter.** The gates and duty the firmware leaves after any interrupt drive the plant until
  they change: a six-step pattern (one high switch chopped at the duty, one low switch on, one
  leg floating) is that sector; all open lets the phases float; any other pattern drives its legs
  as set. Both switches of one leg on is shoot-through: the run stops with a ``FirmwareFault``.
"""

from __future__ import annotations

import math

import numpy as np

from bldc.contract import Command
from bldc.hall import SECTOR_HIGH_PHASE, SECTOR_LOW_PHASE, pin_mask
from hil.dut.faults import FaultInjector
from plant_models import layout as L
from plant_models.simulation import Commutations, Simulation

from .firmware import Firmware, FirmwareInfo

#: interrupt and call kinds, as the crash/hang record names them
EVENTS = ("", "hil_sil_hall_isr", "hil_sil_compare_isr", "hil_sil_control_isr", "hil_sil_reset",
          "hil_sil_od_read", "hil_sil_od_write", "hil_sil_describe")
HALL, COMPARE, CONTROL, RESET, OD_READ, OD_WRITE, DESCRIBE = range(1, 8)
#: the interrupts by event, as ``interrupts`` and a target's ``priorities`` name them
_KIND = {HALL: "hall", COMPARE: "compare", CONTROL: "control"}
SHOOT_THROUGH = -100


def enter_call(record, event: int, t_s: float, count: float) -> None:
    """Open the call record (``[seq, event, t_s, count, in_call]``, shared with the parent, which
    names a crash or hang from it) before a call into the firmware."""
    record[1] = event
    record[2] = t_s
    record[3] = count
    record[4] = 1.0


def leave_call(record) -> None:
    """Close the call record after the firmware returned (a new sequence number: not stuck)."""
    record[4] = 0.0
    record[0] += 1.0
LEG_NAMES = ("A", "B", "C")
_EPS_S = 1e-12


class FirmwareFault(RuntimeError):
    """The firmware broke the interface while running (shoot-through, gates beyond bit 5, an
    impossible answer): the event, the simulated instant and the counter are in the message."""


def _gate_table() -> np.ndarray:
    """The plant's switch state of every gate pattern (``plant_models.layout``): a six-step
    sector 0..5, -1 all open, ``GATE_PATTERN_BASE + g`` another pattern, SHOOT_THROUGH refused."""
    table = np.empty(64, dtype=np.int64)
    six_step = {(int(SECTOR_HIGH_PHASE[s]), int(SECTOR_LOW_PHASE[s])): s for s in range(6)}
    for g in range(64):
        high = [x for x in range(3) if g >> (2 * x) & 1]
        low = [x for x in range(3) if g >> (2 * x + 1) & 1]
        if set(high) & set(low):
            table[g] = SHOOT_THROUGH
        elif not high and not low:
            table[g] = -1
        elif len(high) == 1 and len(low) == 1:
            table[g] = six_step[(high[0], low[0])]
        else:
            table[g] = L.GATE_PATTERN_BASE + g
    return table


GATE_TABLE = _gate_table()


def gates_text(g: int) -> str:
    names = ("AH", "AL", "BH", "BL", "CH", "CL")
    return "+".join(n for k, n in enumerate(names) if g >> k & 1) or "none"


class Peripherals:
    """One run of the plant with the firmware's interrupts between its steps."""

    def __init__(self, fw: Firmware, info: FirmwareInfo, sim: Simulation, *, seed: int, wrap_at_s: float,
                 record=None):
        self.fw, self.info, self.sim = fw, info, sim
        self.record = record if record is not None else np.zeros(5)  #: [seq, event, t_s, count, in_call]
        self.modulus = 1 << info.timer_bits
        self.mask = self.modulus - 1
        self.timer_hz = float(info.timer_hz)
        # the counter wraps wrap_at_s into the run (a 16-bit timer wraps again every 2^16 ticks)
        self.start_count = (self.modulus - round(wrap_at_s * info.timer_hz) % self.modulus) % self.modulus
        self.control_period_s = 1.0 / info.control_hz
        self.control_k = 1
        self.next_control_s = self.control_period_s
        self.compare_count: int | None = None
        self.compare_s = math.inf
        self.amps_per_count = info.amps_per_count
        cs = sim.config.current_sensor
        self._gain = [1.0 + g for g in cs.gain_error]
        self._offset = list(cs.offset_a)
        self._noise_rms = float(cs.noise_rms_a)
        self._noise = np.random.default_rng([seed, 0x51]).standard_normal((1 << 15, 3))
        self._noise_k = 0
        self._gates = -1
        self._sector = self._initial_sector = int(sim.ist[L.I_SECTOR])
        self.emcy: list[tuple[float, int]] = []  #: (t_s, code) popped during the run
        #: the Hall pins as the firmware's GPIO reads them (bit 0 A, 1 B, 2 C), and the wiring
        #: faults between the plant's conditioned edges and the pins
        self.pins = self.levels()
        self.injector = FaultInjector(self)
        self._delivered: list[dict] = []
        self._pending: list[dict] = []
        self.next_pin_s = math.inf
        self.interrupts = {"hall": 0, "compare": 0, "control": 0}
        self._isr = {HALL: fw.hall_isr, COMPARE: fw.compare_isr, CONTROL: fw.control_isr}
        self._enter(RESET, 0.0, self.count(0.0))  # every run starts from a power cycle, the pins as they are
        self.fw.reset(self.pins)
        self._outputs(RESET, 0.0, self.count(0.0))

    # --- the timer ---------------------------------------------------------------------------------
    def ticks(self, t_s: float) -> int:
        return math.floor(t_s * self.timer_hz + 1e-6)

    def count(self, t_s: float) -> int:
        return (self.start_count + self.ticks(t_s)) & self.mask

    def levels(self) -> int:
        ist = self.sim.ist
        return pin_mask(ist[L.I_SEEN], ist[L.I_SEEN + 1], ist[L.I_SEEN + 2])

    def edge(self, edge: dict) -> list:
        """The wiring faults' sink (``FaultInjector.link``): a pin change they let through."""
        self._delivered.append(edge)
        return []

    # --- the ADC ------------------------------------------------------------------------------------
    def _convert(self, currents_a) -> None:
        """The ADC's result registers for three phase currents (A) through the current sensors."""
        adc = self.fw.adc
        if self._noise_rms > 0.0:
            if self._noise_k >= self._noise.shape[0]:
                self._noise = np.random.default_rng([int(self._noise[0, 0] * 1e9) & 0xFFFFFFFF, 0x51]).standard_normal(
                    self._noise.shape)
                self._noise_k = 0
            noise = self._noise[self._noise_k]
            self._noise_k += 1
        else:
            noise = (0.0, 0.0, 0.0)
        for k in range(3):
            sensed = currents_a[k] * self._gain[k] + self._offset[k] + self._noise_rms * noise[k]
            counts = round(sensed / self.amps_per_count)
            adc[k] = -32768 if counts < -32768 else (32767 if counts > 32767 else counts)

    def _convert_now(self) -> None:
        st = self.sim.st
        self._convert((st[L.S_IA], st[L.S_IB], st[L.S_IC]))

    # --- calls into the firmware --------------------------------------------------------------------
    def _enter(self, event: int, t_s: float, count: int) -> None:
        enter_call(self.record, event, t_s, count)

    def outputs_after(self, event: int, t_s: float, count: int) -> None:
        """What the firmware left after a call outside the interrupts (an object-dictionary write)."""
        self._outputs(event, t_s, count)

    def _outputs(self, event: int, t_s: float, count: int) -> None:
        """Read what the firmware left after an interrupt: gates and duty into the inverter, the
        compare unit, the EMCY queue; then close the call record."""
        fw, sim = self.fw, self.sim
        g = int(fw.gates())
        if g != self._gates:
            if g > 0x3F:
                raise FirmwareFault(self._where(event, t_s, count) + f": hil_sil_gates returned 0x{g:02X}; "
                                    "bits 6-7 are no gates (bit 0 AH, 1 AL, 2 BH, 3 BL, 4 CH, 5 CL)")
            state = int(GATE_TABLE[g])
            if state == SHOOT_THROUGH:
                legs = [LEG_NAMES[x] for x in range(3) if (g >> 2 * x) & 3 == 3]
                raise FirmwareFault(
                    self._where(event, t_s, count) + f": shoot-through: both switches of leg "
                    f"{' and '.join(legs)} on (gates {gates_text(g)} = 0x{g:02X})"
                )
            self._gates = g
            if state != self._sector:
                self._sector = state
                sim.schedule(Command(sim.t_s, state, None, None))
        sim.st[L.S_DUTY] = fw.duty() / 65535.0
        if fw.has_compare:
            armed = fw.compare()
            if armed is None:
                self.compare_count, self.compare_s = None, math.inf
            elif armed != self.compare_count or self.compare_s == math.inf:
                self._arm(armed & self.mask, t_s)
        if fw.has_emcy:
            while (code := fw.emcy()) is not None:
                self.emcy.append((t_s, code))
        leave_call(self.record)

    def _arm(self, count: int, t_s: float) -> None:
        k_now = self.ticks(t_s)
        delta = (count - (self.start_count + k_now)) & self.mask
        if delta == 0:  # at the counter: the match has passed, it comes round one wrap later
            delta = self.modulus
        self.compare_count = count
        self.compare_s = (k_now + delta) / self.timer_hz

    def _where(self, event: int, t_s: float, count: int) -> str:
        return f"{EVENTS[event]} at t = {t_s:.9f} s (counter {count})"

    # --- the run --------------------------------------------------------------------------------------
    def run_until(self, t_stop_s: float) -> None:
        sim = self.sim
        while True:
            target = min(t_stop_s, self.next_control_s, self.compare_s, self.next_pin_s)
            edge = sim.step_until(target)
            if edge is not None:
                self._hall([edge])
                continue
            if self.next_pin_s <= target + _EPS_S:
                self._pins_due(self.next_pin_s)
            self._timers_due(target)
            if target >= t_stop_s:
                return

    def _timers_due(self, target: float) -> None:
        """The compare and control interrupts due at ``target`` (the plant is there)."""
        if self.compare_s <= target + _EPS_S:
            t = self.compare_s
            count = self.compare_count
            self.compare_s = math.inf  # fired; left armed at this count it comes round one wrap later
            self._raise(COMPARE, t, count, ())
        if self.next_control_s <= target + _EPS_S:
            t = self.next_control_s
            self._convert_now()
            self._raise(CONTROL, t, self.count(t), (self.fw.adc,))
            self.control_k += 1
            self.next_control_s = self.control_k * self.control_period_s

    def _raise(self, event: int, t_s: float, count: int, args: tuple) -> None:
        """An interrupt at ``t_s``: here it runs at once, to completion, in zero time, and its outputs
        are in force from ``t_s`` (``hil.sil.scheduler`` gives it the time a processor takes)."""
        self._enter(event, t_s, count)
        self._isr[event](count, *args)
        self.interrupts[_KIND[event]] += 1
        self._outputs(event, t_s, count)

    def _hall(self, edges: list[dict]) -> None:
        """The Hall interrupts of the pin changes at this instant: each plant edge through the
        wiring faults (``hil.dut.faults.FaultInjector``, the same faults every link's edge stream
        gets), then one interrupt per changed pin in the order A, B, C, each reading the levels
        after all of them changed. A change the faults move later (a spike) waits for its instant."""
        sim = self.sim
        now = sim.t_s
        while (more := sim.step_until(now)) is not None:  # pins that changed at the same instant
            edges.append(more)
        self._delivered = []
        for e in edges:
            # the capture channel latches the counter at the pin change (after the conditioning
            # circuit): the firmware's own timer quantises it, not the plant's timer effect
            e["t_capture_s"] = min(e["t_conditioned_s"], now)
            self.injector.edge(e)
        due = [e for e in self._delivered if e["t_capture_s"] <= now + _EPS_S]
        self._pending += [e for e in self._delivered if e["t_capture_s"] > now + _EPS_S]
        self._pending.sort(key=lambda e: e["t_capture_s"])
        self.next_pin_s = self._pending[0]["t_capture_s"] if self._pending else math.inf
        self._interrupt_pins(due, now)

    def _pins_due(self, t_s: float) -> None:
        """The pin changes a wiring fault placed at ``t_s`` (a spike and its return)."""
        due = [e for e in self._pending if e["t_capture_s"] <= t_s + _EPS_S]
        self._pending = [e for e in self._pending if e["t_capture_s"] > t_s + _EPS_S]
        self.next_pin_s = self._pending[0]["t_capture_s"] if self._pending else math.inf
        self._interrupt_pins(due, t_s)

    def _interrupt_pins(self, edges: list[dict], now: float) -> None:
        if not edges:
            return
        fw = self.fw
        for e in edges:
            bit = 1 << int(e["sensor"])
            self.pins = (self.pins | bit) if e["rising"] else (self.pins & ~bit)
        for e in sorted(edges, key=lambda e: e["sensor"]):
            t_c = e["t_capture_s"]
            count = self.count(t_c)
            if t_c >= now - _EPS_S:
                self._convert_now()
            else:  # jitter placed the change before its emission: the current at the change
                sensed = self.sim.adc_conversions_at(np.array([t_c]))[0]  # through the sensors' gain and offset
                self._convert([(sensed[k] - self._offset[k]) / self._gain[k] for k in range(3)])
            self._raise(HALL, now, count, (int(e["sensor"]), self.pins, fw.adc))

    # --- what the plant did ----------------------------------------------------------------------------
    def commutations(self) -> Commutations:
        """Every switch from one six-step sector into another, with the plant's true rotor angle
        (a change into or out of another pattern, all-open included, is not a commutation)."""
        c = self.sim.commutations()
        prev = np.concatenate([[self._initial_sector], c.sector[:-1]])
        keep = (c.sector >= 0) & (c.sector < 6) & (prev >= 0) & (prev < 6)
        return Commutations(t_s=c.t_s[keep], sector=c.sector[keep], theta_e_deg=c.theta_e_deg[keep],
                            direction=c.direction[keep])

