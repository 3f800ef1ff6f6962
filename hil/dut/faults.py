"""Wiring faults between the Hall sensors and the controller, switched on and off while running.

The plant's effect library (``plant_models.effects``) holds every deviation of the motor and its
sensors; these are the faults of the signal path itself (a broken wire, an EMI spike, a lost
capture interrupt), which a controller must detect and report. They act on the captured-edge
stream on its way through the link, so they work against any controller, and the plant's ground
truth is untouched. Each has the fault code the virtual controller promises for it
(docs/controller.md) and a hypothesis strategy.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

from hypothesis import strategies as st

from bldc.contract import Fault


@dataclass(frozen=True)
class WiringFault:
    name: ClassVar[str] = ""
    #: the fault codes a controller must raise for it (at least one of them)
    promised: ClassVar[tuple[int, ...]] = ()
    #: further codes it may raise as a consequence (a lost edge leaves the Hall state wrong, which
    #: can read as an illegal code until that sensor switches again)
    allowed: ClassVar[tuple[int, ...]] = ()
    #: one-shot faults act once and switch themselves off
    one_shot: ClassVar[bool] = False

    def as_dict(self) -> dict:
        return {"name": self.name, **asdict(self)}


@dataclass(frozen=True)
class SensorDropout(WiringFault):
    """The sensor's signal is lost: its level stays where it was, its edges never arrive."""

    name: ClassVar[str] = "sensor_dropout"
    promised: ClassVar[tuple[int, ...]] = (Fault.ILLEGAL_HALL_CODE, Fault.MISSING_EDGE)
    sensor: int = 0

    @classmethod
    def strategy(cls):
        return st.builds(cls, sensor=st.integers(0, 2))


@dataclass(frozen=True)
class LostEdge(WiringFault):
    """One capture is lost (a missed interrupt): the next edge never reaches the controller."""

    name: ClassVar[str] = "lost_edge"
    promised: ClassVar[tuple[int, ...]] = (Fault.MISSING_EDGE,)
    allowed: ClassVar[tuple[int, ...]] = (Fault.ILLEGAL_HALL_CODE,)
    one_shot: ClassVar[bool] = True

    @classmethod
    def strategy(cls):
        return st.just(cls())


@dataclass(frozen=True)
class HallSpike(WiringFault):
    """An EMI spike right after the next edge: one sensor toggles to the illegal code (000 or
    111) and back ``width_s`` later."""

    name: ClassVar[str] = "hall_spike"
    promised: ClassVar[tuple[int, ...]] = (Fault.ILLEGAL_HALL_CODE,)
    one_shot: ClassVar[bool] = True
    delay_s: float = 2e-6
    width_s: float = 3e-6

    @classmethod
    def strategy(cls):
        return st.builds(cls, delay_s=st.floats(1e-6, 10e-6), width_s=st.floats(1e-6, 10e-6))


WIRING_FAULTS = {cls.name: cls for cls in (SensorDropout, LostEdge, HallSpike)}


def wiring_fault_from_dict(data: dict) -> WiringFault:
    data = dict(data)
    name = data.pop("name", None)
    if name not in WIRING_FAULTS:
        raise ValueError(f"unknown wiring fault {name!r} (known: {', '.join(WIRING_FAULTS)})")
    return WIRING_FAULTS[name](**data)


def wiring_fault_strategy():
    return st.one_of([cls.strategy() for cls in WIRING_FAULTS.values()])


class FaultInjector:
    """A ControllerLink that passes the edge stream through the active wiring faults."""

    def __init__(self, link):
        self.link = link
        self.active: list[WiringFault] = []
        self.log: list[tuple[float, str, str]] = []  #: (plant time, "on"/"off"/"acted", fault name)
        self._bits: dict[int, int] = {}
        self._t = 0.0
        #: where the faults act when the edges do not pass through here (a firmware in the loop
        #: gets them on its pins, in its own process: ``hil.sil``): called with ("on"|"off", fault)
        self.mirror = None

    def __getattr__(self, name):  # everything but edges goes straight to the controller
        return getattr(self.link, name)

    def switch_on(self, fault: WiringFault) -> None:
        self.active.append(fault)
        if self.mirror is not None:  # it acts, and logs, where the pins are
            self.mirror("on", fault)
            return
        self.log.append((self._t, "on", fault.name))

    def switch_off(self, fault: WiringFault) -> None:
        if self.mirror is not None:
            if fault in self.active:
                self.active.remove(fault)
            self.mirror("off", fault)
            return
        if fault in self.active:
            self.active.remove(fault)
            self.log.append((self._t, "off", fault.name))

    def edge(self, edge: dict) -> list:
        self._t = edge["t_capture_s"]
        edges = [edge]
        for fault in list(self.active):
            edges = self._apply(fault, edges)
        commands = []
        for e in edges:
            self._bits[int(e["sensor"])] = 1 if e["rising"] else 0
            commands += self.link.edge(e)
        return commands

    def _acted(self, fault: WiringFault) -> None:
        self.log.append((self._t, "acted", fault.name))
        if fault.one_shot:
            self.active.remove(fault)

    def _apply(self, fault: WiringFault, edges: list[dict]) -> list[dict]:
        if isinstance(fault, SensorDropout):
            kept = [e for e in edges if int(e["sensor"]) != fault.sensor]
            if len(kept) < len(edges):
                self.log.append((self._t, "acted", fault.name))
            return kept
        if isinstance(fault, LostEdge):
            self._acted(fault)
            return edges[1:]
        if isinstance(fault, HallSpike) and edges:
            bits = dict(self._bits)
            for e in edges:
                bits[int(e["sensor"])] = 1 if e["rising"] else 0
            if len(bits) < 3:
                return edges  # the Hall state is not known yet: spike on a later edge
            ones = sum(bits.values())
            # toggling the lone high sensor gives 000, the lone low one gives 111
            sensor = next(s for s in range(3) if bits[s] == (1 if ones == 1 else 0))
            t0 = edges[-1]["t_capture_s"] + fault.delay_s
            toward = {**edges[-1], "sensor": sensor, "rising": not bits[sensor], "t_capture_s": t0, "now_s": t0}
            t1 = t0 + fault.width_s
            back = {**toward, "rising": bool(bits[sensor]), "t_capture_s": t1, "now_s": t1}
            self._acted(fault)
            return edges + [toward, back]
        return edges
