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
    limit_source = "..."   # optional: where the limit comes from (a specification, a datasheet)

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

The built-in defaults are each requirement's default budgets in the requirement registry
(``hil.verdicts.requirements``); a file is laid over them. Checking a measurement
gives a Verdict (measured, limit, margin, pass / marginal / fail); asserting it raises
BudgetExceeded with a message a person understands.
"""

from __future__ import annotations

import datetime
import functools
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from bldc.params import ConfigError
from bldc.tomlfile import ANY_KEY, load_toml

from .record import Verdict
from .requirements import REQUIREMENTS


@dataclass(frozen=True)
class Budget:
    name: str
    requirement: str
    unit: str
    limit: float
    kind: str = "max"
    marginal: float | None = None
    description: str = ""
    limit_source: str = ""  #: where the limit's value comes from (hil.verdicts.requirements.DefaultBudget)


def judged(check, measured: float, bound: float) -> Verdict:
    """The verdict of a judged check (``hil.verdicts.requirements.JudgedCheck``) whose bound the run computed:
    pass or fail (no marginal band), never a pass for a measurement that is not a finite number."""
    if not isinstance(measured, (int, float)) or not math.isfinite(measured) or not math.isfinite(bound):
        return Verdict(check.name, check.requirement, float(measured), float(bound), check.unit, float("-inf"),
                       "fail", check.kind_of_limit, check.judgement)
    margin = (bound - measured) if check.kind_of_limit == "max" else (measured - bound)
    return Verdict(check.name, check.requirement, float(measured), float(bound), check.unit, float(margin),
                   "fail" if margin < 0 else "pass", check.kind_of_limit, check.judgement)


class BudgetExceeded(AssertionError):
    def __init__(self, verdict: Verdict):
        self.verdict = verdict
        super().__init__(verdict.message())


class BudgetsExceeded(AssertionError):
    """Every budget a test missed, raised when its body has returned: the fixture ``hil_budget``
    records a miss and lets the test go on, so that each requirement the test traces to is judged
    by its own budgets and checks (a missed recovery budget is not a failed fault code)."""

    def __init__(self, verdicts: list[Verdict]):
        self.verdicts = list(verdicts)
        super().__init__("\n".join(v.message() for v in self.verdicts))


_BUDGET_KEYS = {"requirement", "unit", "limit", "marginal", "kind", "description", "limit_source"}
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


#: what a budgets file may hold (bldc.tomlfile): any budget's table, waivers, out-of-scope entries
_SCHEMA = {"waiver": [_WAIVER_KEYS], "out_of_scope": [_SCOPE_KEYS], ANY_KEY: _BUDGET_KEYS}


def _waiver(table, where: str, today: datetime.date) -> Waiver:
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
    for key in ("requirement", "unit", "limit"):
        if key not in table and inherited is None:
            raise ConfigError(f"{where}.{key}", "required")
    merged = asdict(inherited) if inherited is not None else {}
    if "limit" in table:  # a marginal bound and a source belong to the limit they were set with
        merged = {k: v for k, v in merged.items() if k not in ("marginal", "limit_source")}
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


@functools.cache
def _default_budgets() -> dict[str, Budget]:
    return Budgets.defaults().budgets


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
        """The built-in budgets: each requirement's default budgets in the registry (hil.verdicts.requirements)."""
        budgets = {}
        for req in REQUIREMENTS.values():
            for b in req.budgets:
                table = {k: v for k, v in asdict(b).items() if k != "name"} | {"requirement": req.id}
                budgets[b.name] = _budget(b.name, table, None, f"hil/verdicts/requirements.py: {req.id}: {b.name}")
        return cls(budgets, "defaults")

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
        where = name or str(path)
        data = load_toml(path, _SCHEMA, name=where)
        base = base if base is not None else cls.defaults()
        today = today or datetime.date.today()
        budgets, waivers = dict(base.budgets), list(base.waivers)
        for key, table in data.items():
            if key == "waiver":
                waivers += [_waiver(t, f"{where}: [[waiver]][{i}]", today) for i, t in enumerate(table)]
            elif key == "out_of_scope":
                waivers += [replace(_waiver(t, f"{where}: [[out_of_scope]][{i}]", today), kind="out of scope")
                            for i, t in enumerate(table)]
            else:
                budgets[key] = _budget(key, table, budgets.get(key), f"{where}: [{key}]")
        return cls(budgets, str(path), tuple(waivers))

    def check(self, name: str, measured: float, scenario=None) -> Verdict:
        """``measured`` against budget ``name``. ``scenario``: a ``hil.verdicts.budget_sources.Derivation`` of
        this budget for the scenario the figure comes from (REQ-CAL-005's share removed depends on
        how much the scenario had to remove); it sets the limit where the budget is the built-in
        default, and a user's own limit (a budgets file) stands."""
        b = self[name]
        if scenario is not None and self._is_default(b):
            b = replace(b, limit=scenario.limit, marginal=scenario.marginal, limit_source=scenario.source)
        if not isinstance(measured, (int, float)) or not math.isfinite(measured):
            # never judged a pass: not a number, or "never" (inf: a settling that never came); the
            # record keeps which, so "inf edges" reads as the estimate never tracking, not as nan
            value = float(measured) if isinstance(measured, (int, float)) else float("nan")
            return Verdict(b.name, b.requirement, value, b.limit, b.unit, float("-inf"), "fail", b.kind)
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

    @staticmethod
    def _is_default(b: Budget) -> bool:
        default = _default_budgets().get(b.name)
        return default is not None and (b.limit, b.limit_source) == (default.limit, default.limit_source)

    def require(self, name: str, measured: float) -> Verdict:
        """Check and raise BudgetExceeded on a fail (marginal passes)."""
        v = self.check(name, measured)
        if v.verdict == "fail":
            raise BudgetExceeded(v)
        return v

    def requirement_titles(self) -> dict[str, str]:
        """Every requirement this run knows of: the registry's statements, then the budgets' own descriptions."""
        titles = {rid: req.statement for rid, req in REQUIREMENTS.items()}
        for b in self.budgets.values():
            titles.setdefault(b.requirement, b.description)
        return titles
