"""The bounds and refusals every calibration route applies (``hil.calibration.route``): a value
beyond its physical bound is refused with the reason, never clipped into the table."""

from __future__ import annotations

from dataclasses import dataclass

from bldc.contract import MAX_POLE_TABLE_OFFSET_DEG_E
from bldc.reasons import Reason

from .corrections import SENSORS
from .result import Refusal

#: the controller's table bound on a pole offset (its physics: bldc/contract.py)
POLE_OFFSET_BOUND_DEG_E = MAX_POLE_TABLE_OFFSET_DEG_E
#: default bound on a conditioning delay when the circuit is not stated: open-collector Hall
#: outputs with a pull-up into a filter capacitor and cable capacitance are measured at 130-270 us
#: (rise minus fall); 1 ms covers a 10 kOhm pull-up into 33 nF (3 RC to cross a 95 % threshold)
DEFAULT_DELAY_MAX_S = 1e-3
#: a delay must stay well inside one sector at the top speed: beyond half a sector the captured
#: edges of a 60 deg e sector would reorder before the next one
DELAY_SECTOR_FRACTION = 0.5
#: an installation offset beyond half a sector is a wiring or labelling error, not an offset
INSTALLATION_BOUND_DEG_E = 30.0


@dataclass
class Circuit:
    """What the user says about the conditioning circuit (all optional)."""

    pullup_ohm: float | None = None
    filter_farad: float | None = None
    delay_max_s: float | None = None

    def bound_s(self) -> tuple[float, Reason]:
        if self.delay_max_s is not None:
            return self.delay_max_s, Reason("CAL-010", {"bound_us": self.delay_max_s * 1e6})
        if self.pullup_ohm is not None and self.filter_farad is not None:
            rc = self.pullup_ohm * self.filter_farad
            return 3.0 * rc, Reason("CAL-011", {"pullup_ohm": self.pullup_ohm, "filter_farad": self.filter_farad})
        return DEFAULT_DELAY_MAX_S, Reason("CAL-012", {"bound_us": DEFAULT_DELAY_MAX_S * 1e6})


def pole_table_refusal(poles: list[float]) -> Refusal | None:
    """The refusal of a pole table with an entry beyond the controller's bound, or None. A table
    with a hole would be worse than none: the whole table is refused."""
    out = [j for j, v in enumerate(poles) if abs(v) > POLE_OFFSET_BOUND_DEG_E]
    if not out:
        return None
    return Refusal("pole_offset_deg_e", Reason("CAL-001", {
        "poles": out, "offsets_deg_e": [float(poles[j]) for j in out], "bound_deg_e": POLE_OFFSET_BOUND_DEG_E}))


def installation_refusal(inst: dict[str, float]) -> Refusal | None:
    """The refusal of installation offsets beyond half a sector (a wiring or labelling error), or None."""
    bad = [n for n in SENSORS if abs(inst[n]) > INSTALLATION_BOUND_DEG_E]
    if not bad:
        return None
    return Refusal("installation_offset_deg_e", Reason("CAL-002", {
        "offsets_deg_e": {n: float(inst[n]) for n in bad}, "bound_deg_e": INSTALLATION_BOUND_DEG_E}))


def delay_refusal(field: str, value_s: float | None, bound_s: float, bound_why: Reason) -> Refusal | None:
    """The refusal of a conditioning delay beyond its bound (``Circuit.bound_s``, or half a sector
    at the top speed), or None."""
    if value_s is None or abs(value_s) <= bound_s:
        return None
    return Refusal(field, Reason("CAL-003", {"value_us": value_s * 1e6, "bound_us": bound_s * 1e6,
                                             "bound_why": bound_why}))


def delay_bound_s(circuit: Circuit, top_hz_e: float) -> tuple[float, Reason]:
    """The bound on a conditioning delay: the circuit's, or half a sector at the top speed if tighter."""
    bound_s, bound_why = circuit.bound_s()
    sector_s = 1.0 / (6.0 * top_hz_e)
    if DELAY_SECTOR_FRACTION * sector_s < bound_s:
        return DELAY_SECTOR_FRACTION * sector_s, Reason("CAL-013", {"top_hz_e": top_hz_e, "sector_us": sector_s * 1e6})
    return bound_s, bound_why
