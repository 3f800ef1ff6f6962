"""Accuracy budgets: named limits with units, an optional marginal bound, traced to requirement IDs;
and waivers: explicit, owned acceptances of a requirement that is not met.

A budgets TOML file holds one table per budget and any number of ``[[waiver]]`` entries:

    [commutation_angle_p99]
    requirement = "REQ-COMM-001"
    unit = "deg_e"
    limit = 0.5            # the measured value must not exceed it (kind = "max", the default)
    marginal = 0.4         # optional: beyond this, still passing but marginal
    kind = "max"           # or "min": the measured value must reach the limit
    description = "..."

    [[waiver]]
    requirement = "REQ-ROB-002"
    reason = "why this is accepted"
    owner = "name or role"
    tests = ["test_fault_sequences"]   # optional: node-id substrings it is limited to
    expires = "2027-06-30"             # optional: an expired waiver is refused

    [[out_of_scope]]                   # a requirement the device's profile cannot show
    requirement = "REQ-PROT-002"
    reason = "Modbus device: no heartbeat, no EMCY"
    owner = "name or role"

The built-in defaults are ``default_budgets.toml`` beside this module. Checking a measurement
gives a Verdict (measured, limit, margin, pass / marginal / fail); asserting it raises
BudgetExceeded with a message a person understands.
"""

from __future__ import annotations

import datetime
import math
import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from bldc.params import ConfigError


@dataclass(frozen=True)
class Budget:
    name: str
    requirement: str
    unit: str
    limit: float
    kind: str = "max"
    marginal: float | None = None
    description: str = ""
    #: where the limit comes from: the pump's specification, the paper or a standard (never the
    #: value it judges); docs/budgets.md, "Sources"
    source: str = ""


@dataclass(frozen=True)
class Verdict:
    budget: str
    requirement: str
    measured: float
    limit: float
    unit: str
    margin: float          #: how far inside the limit (negative: outside), in the budget's unit
    verdict: str           #: "pass", "marginal" or "fail"

    def as_dict(self) -> dict:
        return asdict(self)

    def message(self) -> str:
        rel = (
            ("exceeds" if self.limit_kind == "max" else "falls short of")
            if self.verdict == "fail" and self.margin < 0
            else "is within"
        )
        side = "at most" if self.limit_kind == "max" else "at least"
        return (
            f"{self.budget} ({self.requirement}): measured {self.measured:.6g} {self.unit} {rel} the limit of "
            f"{side} {self.limit:.6g} {self.unit} (margin {self.margin:+.3g} {self.unit}): {self.verdict.upper()}"
        )

    limit_kind: str = "max"


class BudgetExceeded(AssertionError):
    def __init__(self, verdict: Verdict):
        self.verdict = verdict
        super().__init__(verdict.message())


#: the requirement catalogue: what each ID means (budgets add their own descriptions)
REQUIREMENTS = {
    "REQ-CAL-001": "Installation deviations of the Hall sensors are removed by the pre-calibration (paper Eq. 1-5)",
    "REQ-CAL-002": "Magnet-pole deviations are removed by the pre-calibration (paper Eq. 6)",
    "REQ-CAL-003": "Conditioning-circuit (RC) delays are removed, rising and falling edges apart (paper Eq. 7-8)",
    "REQ-CAL-004": "Armature-reaction deviation is removed as a function of phase current",
    "REQ-CAL-005": "The calibration table is downloaded, applied and read back exactly; an invalid table is refused",
    "REQ-COMM-001": "Corrected commutation lands within the angle budget over the speed range",
    "REQ-PRED-001": "The Sage-Husa predictor meets the commutation budgets in the paper's speed-step scenario",
    "REQ-PRED-002": "The Sage-Husa predictor is no worse than the fixed-noise Kalman filter",
    "REQ-PRED-003": "The Sage-Husa predictor adapts its noise statistics to the measured edge noise",
    "REQ-PRED-004": "The Sage-Husa predictor's edge-noise estimate tracks a step of the edge noise",
    "REQ-PRED-005": "The Sage-Husa predictor's edge-noise estimate is steady while the edge noise is",
    "REQ-PROT-001": "The controller identifies itself (vendor, product, revision, serial, firmware)",
    "REQ-PROT-002": "CANopen: heartbeat at the period of 0x1017; EMCY and 0x1001/0x1003 on a fault",
    "REQ-PROT-003": "Bad requests get the standard's answer (SDO abort codes, Modbus exception codes)",
    "REQ-FLT-001": "An illegal Hall code (000/111) raises fault 0xFF01",
    "REQ-FLT-002": "A missing edge raises fault 0xFF02",
    "REQ-FLT-003": "A Hall sensor drop-out is detected as a fault",
    "REQ-FLT-004": "A filter guard trip raises fault 0xFF03",
    "REQ-FLT-005": "No fault is raised on a healthy run",
    "REQ-ROB-001": "Any combination of bounded deviations, once calibrated, meets the commutation budget",
    "REQ-ROB-002": "Faults switched on and off while running are reported and recovered from",
    "REQ-CUR-001": "The phase current stays within the controller's current limit through a set-point step",
    "REQ-CUR-002": "Calibrated commutation lowers the mean phase current against raw Hall commutation (paper 4.3)",
    "REQ-SPD-001": "The controller's speed loop settles a set-point step without excessive overshoot",
}

_CALIBRATION = ("installation_offset", "pole_offset", "conditioning_delay_rise", "conditioning_delay_fall",
                "armature_slope", "calibration_apply")
_FILTER = ("filter_forgetting", "filter_q0", "filter_r0", "filter_p0")
#: what each requirement's tests need of a device profile (hil.dut.profile roles, docs/device-profiles.md):
#: ``roles``, ``edge_hook`` (edges reach the controller: the lockstep bench), ``fault_source`` (how
#: faults are seen). A profile that lacks one makes the requirement "not testable with this profile".
REQUIREMENT_NEEDS = {
    **{f"REQ-CAL-00{k}": {"roles": ("strategy", *_CALIBRATION), "edge_hook": True} for k in (1, 2, 3, 4)},
    "REQ-CAL-005": {"roles": (*_CALIBRATION, "fault_code"), "edge_hook": False},
    "REQ-COMM-001": {"roles": ("strategy", *_CALIBRATION), "edge_hook": True},
    "REQ-PRED-001": {
        "roles": ("strategy", *_CALIBRATION, *_FILTER, "guard_trips", "gated_edges", "covariance_repairs",
                  "divergence_fades", "band_projections"),
        "edge_hook": True,
    },
    "REQ-PRED-002": {"roles": ("strategy", *_CALIBRATION, *_FILTER), "edge_hook": True},
    **{f"REQ-PRED-00{k}": {"roles": ("strategy", *_CALIBRATION, *_FILTER, "filter_q_diag", "filter_r_diag"),
                           "edge_hook": True} for k in (3, 4, 5)},
    "REQ-PROT-001": {"roles": ("identity_vendor", "identity_product", "identity_revision", "identity_serial")},
    "REQ-PROT-002": {"roles": ("heartbeat_period", "error_register", "fault_code", *_CALIBRATION),
                     "fault_source": "emcy"},
    "REQ-PROT-003": {"roles": ("strategy",)},
    **{f"REQ-FLT-00{k}": {"roles": ("strategy", *_CALIBRATION, "fault_code"), "edge_hook": True} for k in (1, 2, 3, 5)},
    "REQ-FLT-004": {"roles": ("strategy", *_CALIBRATION, *_FILTER, "guard_trips", "fault_code"), "edge_hook": True},
    "REQ-ROB-001": {"roles": ("strategy", *_CALIBRATION), "edge_hook": True},
    "REQ-ROB-002": {"roles": ("strategy", *_CALIBRATION, "fault_code"), "edge_hook": True},
    # judged on the plant's true currents and speed: the controller's own speed loop and set point
    "REQ-CUR-001": {"roles": ("strategy", "speed_setpoint", *_CALIBRATION), "edge_hook": True},
    "REQ-CUR-002": {"roles": ("strategy", "speed_setpoint", *_CALIBRATION), "edge_hook": True},
    "REQ-SPD-001": {"roles": ("strategy", "speed_setpoint", *_CALIBRATION), "edge_hook": True},
}


def missing_needs(requirements, has_role, edge_hook: str, fault_sources) -> list[str]:
    """What a device profile lacks for ``requirements`` (``has_role(role)``, its edge hook kind, its
    fault sources), one phrase each; empty when every requirement is testable through it."""
    out: list[str] = []
    for rid in sorted(set(requirements)):
        need = REQUIREMENT_NEEDS.get(rid, {})
        out += [f"role {r}" for r in need.get("roles", ()) if not has_role(r) and f"role {r}" not in out]
        if need.get("edge_hook") and edge_hook == "none" and "an edge hook" not in out:
            out.append("an edge hook")
        if (src := need.get("fault_source")) and src not in fault_sources and f"fault source {src}" not in out:
            out.append(f"fault source {src}")
    return out


DEFAULTS_TOML = Path(__file__).with_name("default_budgets.toml")
_BUDGET_KEYS = {"requirement", "unit", "limit", "marginal", "kind", "description", "source"}
_WAIVER_KEYS = {"requirement", "reason", "owner", "tests", "expires"}
_SCOPE_KEYS = {"requirement", "reason", "owner", "expires"}


@dataclass(frozen=True)
class Waiver:
    """An explicit acceptance of a requirement that is not met: the report shows it as WAIVED
    with its reason and owner, never as pass."""

    requirement: str
    reason: str
    owner: str
    tests: tuple[str, ...] = ()  #: node-id substrings it is limited to (empty: every test of the requirement)
    expires: datetime.date | None = None
    source: str = ""  #: where it was declared ("file: [[waiver]][i]")
    #: "waiver" (a failure accepted) or "out of scope" (a requirement the device cannot show: it
    #: stands for a requirement no test could judge, never for a failure)
    kind: str = "waiver"

    def covers(self, nodeid: str) -> bool:
        return not self.tests or any(s in nodeid for s in self.tests)

    def as_dict(self) -> dict:
        return {
            "requirement": self.requirement,
            "reason": self.reason,
            "owner": self.owner,
            "tests": list(self.tests),
            "expires": self.expires.isoformat() if self.expires else None,
            "source": self.source,
            "kind": self.kind,
        }


def _check_table(table, where: str, what: str, known: set[str]) -> None:
    if not isinstance(table, dict):
        raise ConfigError(where, f"each {what} is a table")
    for key in table:
        if key not in known:
            raise ConfigError(f"{where}.{key}", f"unknown key (known: {', '.join(sorted(known))})")


def _waiver(table, where: str, today: datetime.date, keys=_WAIVER_KEYS, what: str = "[[waiver]]") -> Waiver:
    _check_table(table, where, what, keys)
    for key in ("requirement", "reason", "owner"):
        v = table.get(key)
        if not isinstance(v, str) or not v.strip():
            raise ConfigError(
                f"{where}.{key}", "required: a non-empty string (a waiver without its " + key + " is not a waiver)"
            )
    tests = table.get("tests", [])
    if not isinstance(tests, list) or not all(isinstance(s, str) and s.strip() for s in tests):
        raise ConfigError(f"{where}.tests", f"must be a list of non-empty node-id substrings, got {tests!r}")
    expires = table.get("expires")
    if expires is not None:
        if isinstance(expires, str):
            try:
                expires = datetime.date.fromisoformat(expires)
            except ValueError:
                raise ConfigError(f"{where}.expires", f"must be an ISO date (YYYY-MM-DD), got {expires!r}") from None
        elif isinstance(expires, datetime.datetime) or not isinstance(expires, datetime.date):
            raise ConfigError(f"{where}.expires", f"must be an ISO date (YYYY-MM-DD), got {expires!r}")
        if expires < today:
            raise ConfigError(
                f"{where}.expires",
                f"the waiver of {table['requirement']} expired on {expires.isoformat()}: "
                "fix the defect or renew the waiver with a current reason",
            )
    return Waiver(
        table["requirement"].strip(),
        table["reason"].strip(),
        table["owner"].strip(),
        tuple(s.strip() for s in tests),
        expires,
        where,
    )


def _budget(name: str, table, inherited: Budget | None, where: str) -> Budget:
    _check_table(table, where, "budget", _BUDGET_KEYS)
    for key in ("requirement", "unit", "limit"):
        if key not in table and inherited is None:
            raise ConfigError(f"{where}.{key}", "required")
    merged = asdict(inherited) if inherited is not None else {}
    if "limit" in table and "marginal" not in table:
        merged.pop("marginal", None)  # a marginal bound belongs to the limit it was set with
    if "limit" in table and "source" not in table:
        merged.pop("source", None)  # and so does the source the limit was derived from
    merged = {**merged, **table, "name": name}
    for key in ("limit", "marginal"):
        v = merged.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise ConfigError(f"{where}.{key}", f"must be a finite number, got {v!r}")
    kind = merged.setdefault("kind", "max")
    if kind not in ("max", "min"):
        raise ConfigError(f"{where}.kind", f"must be 'max' or 'min', got {kind!r}")
    # every budget bounds a magnitude (an error, a ratio, a fraction, a percentage): a negative
    # limit is a typo or a sign convention the comparator does not know
    lim, m = merged["limit"], merged.get("marginal")
    if lim < 0:
        raise ConfigError(f"{where}.limit", f"a budget limits a magnitude and must be >= 0, got {lim!r}")
    if m is not None and not ((0 <= m <= lim) if kind == "max" else (m >= lim)):
        inside = (
            f"between 0 and the limit {lim!r}" if kind == "max" else f'at or above the limit {lim!r} (kind = "min")'
        )
        raise ConfigError(
            f"{where}.marginal", f"the marginal bound must lie on the passing side of the limit, {inside}; got {m!r}"
        )
    return Budget(**merged)


class Budgets:
    def __init__(self, budgets: dict[str, Budget], source: str = "defaults", waivers: tuple[Waiver, ...] = ()):
        self.budgets, self.source, self.waivers = budgets, source, tuple(waivers)

    def __contains__(self, name: str) -> bool:
        return name in self.budgets

    def __getitem__(self, name: str) -> Budget:
        try:
            return self.budgets[name]
        except KeyError:
            raise KeyError(
                f"no budget named {name!r} in {self.source} (have: {', '.join(sorted(self.budgets))})"
            ) from None

    @classmethod
    def defaults(cls) -> "Budgets":
        b = cls.from_toml(DEFAULTS_TOML, base=cls({}), name="hil/default_budgets.toml")
        b.source = "defaults"
        return b

    @classmethod
    def from_toml(
        cls,
        path: str | Path,
        base: "Budgets | None" = None,
        today: datetime.date | None = None,
        name: str | None = None,
    ) -> "Budgets":
        """``path`` laid over ``base`` (default: the built-in defaults): its budgets override or add,
        its waivers add to the base's. Errors and waiver sources name the file as ``name`` (default: ``path``)."""
        path = Path(path)
        where = name or str(path)
        try:
            data = tomllib.loads(path.read_text())
        except OSError as exc:
            raise ConfigError(where, f"cannot read: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(where, f"not valid TOML: {exc}") from None
        base = base if base is not None else cls.defaults()
        today = today or datetime.date.today()
        budgets, waivers = dict(base.budgets), list(base.waivers)
        for key, table in data.items():
            if key == "waiver":
                if not isinstance(table, list):
                    raise ConfigError(f"{where}: waiver", "waivers are an array of tables: write [[waiver]]")
                waivers += [_waiver(t, f"{where}: [[waiver]][{i}]", today) for i, t in enumerate(table)]
            elif key == "out_of_scope":
                if not isinstance(table, list):
                    raise ConfigError(f"{where}: out_of_scope", "an array of tables: write [[out_of_scope]]")
                waivers += [
                    replace(_waiver(t, f"{where}: [[out_of_scope]][{i}]", today, _SCOPE_KEYS, "[[out_of_scope]]"),
                            kind="out of scope")
                    for i, t in enumerate(table)
                ]
            else:
                budgets[key] = _budget(key, table, budgets.get(key), f"{where}: [{key}]")
        return cls(budgets, str(path), tuple(waivers))

    def check(self, name: str, measured: float) -> Verdict:
        b = self[name]
        if not isinstance(measured, (int, float)) or not math.isfinite(measured):
            return Verdict(b.name, b.requirement, float("nan"), b.limit, b.unit, float("-inf"), "fail", b.kind)
        margin = (b.limit - measured) if b.kind == "max" else (measured - b.limit)
        # exactly at the limit is inside it (a limit is "at most" / "at least"); exactly at the
        # marginal bound is a plain pass (the band lies beyond the bound)
        if margin < 0:
            verdict = "fail"
        elif b.marginal is not None and (
            (b.kind == "max" and measured > b.marginal) or (b.kind == "min" and measured < b.marginal)
        ):
            verdict = "marginal"
        else:
            verdict = "pass"
        return Verdict(b.name, b.requirement, float(measured), b.limit, b.unit, float(margin), verdict, b.kind)

    def require(self, name: str, measured: float) -> Verdict:
        """Check and raise BudgetExceeded on a fail (marginal passes)."""
        v = self.check(name, measured)
        if v.verdict == "fail":
            raise BudgetExceeded(v)
        return v

    def requirement_titles(self) -> dict[str, str]:
        """Every requirement this run knows of: the catalogue, then the budgets' own descriptions."""
        titles = dict(REQUIREMENTS)
        for b in self.budgets.values():
            titles.setdefault(b.requirement, b.description)
        return titles
