"""A test's record, typed from the plugin to the report writers: what the test did (``Outcome``),
why it failed (``FailedBy``), each budget's or judged check's ``Verdict``, and the verdict the
report gives it (``Status``).

The plugin builds one ``TestRecord`` per test from pytest's phase reports; ``hil.report`` judges
it (``TestRecord.status``) and writes it (``to_json``: one line of ``results.jsonl``, one entry of
the JSON report's ``tests``). ``from_json`` reads it back, from this version's files and from the
files of earlier versions (a key they did not have takes its default). The enumerations are string
enumerations: a saved report says ``"failed"`` and ``"pass"`` as it always did, and code compares
members, never spellings.

Standard library only: a session that never uses the plugin imports this module and nothing heavy
(tests/test_plugin_lazy.py).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from enum import StrEnum


class Outcome(StrEnum):
    """What pytest said of a test, the worst of its phases (the order: worst first)."""

    FAILED = "failed"
    ERROR = "error"
    XPASSED = "xpassed"  #: an unexpected pass of a known failure
    XFAILED = "xfailed"  #: a known failure
    SKIPPED = "skipped"
    PASSED = "passed"

    def worse_than(self, other: Outcome) -> bool:
        order = list(Outcome)
        return order.index(self) < order.index(other)


#: outcomes that are evidence of a defect: a failure, a known failure (xfail), an unexpected pass
FAILING_OUTCOMES = (Outcome.FAILED, Outcome.XFAILED, Outcome.XPASSED)


class FailedBy(StrEnum):
    """Why a failed or errored test did (``hil.pytest_plugin.failure_kind``)."""

    NOTHING = ""  #: the test did not fail
    BUDGET = "budget"  #: only budgets (or judged checks) were missed: each requirement has its own verdict
    ASSERTION = "assertion"  #: a check failed
    DEVICE_FAILURE = "device failure"  #: the controller signalled its own failure on valid input
    NOT_JUDGED = "not judged"  #: a setup check: the scenario did not provoke what the test judges
    ERROR = "error"  #: anything else


class Status(StrEnum):
    """A test's or a requirement's verdict, the worst first."""

    FAIL = "fail"
    ERROR = "error"
    WAIVED = "waived"
    NOT_TESTABLE = "not testable"  #: the device's profile lacks what the test needs
    NOT_TESTED = "not tested"
    OUT_OF_SCOPE = "out of scope"
    NOT_APPLICABLE = "not applicable"  #: a requirement of another kind of DUT (the part's, on pil:)
    MARGINAL = "marginal"
    PASS = "pass"

    @staticmethod
    def worst(statuses) -> Status:
        order = list(Status)
        return min(statuses, key=order.index)

    @staticmethod
    def of_measurements(verdicts) -> Status:
        """fail when one failed, marginal when one is marginal, else pass (none: pass)."""
        verdicts = set(verdicts)
        return Status.FAIL if Status.FAIL in verdicts else (Status.MARGINAL if Status.MARGINAL in verdicts
                                                             else Status.PASS)


@dataclass(frozen=True)
class Verdict:
    """A budget's or a judged check's verdict on one measurement (``hil.budgets``)."""

    budget: str
    requirement: str
    measured: float
    limit: float
    unit: str
    margin: float  #: how far inside the limit (negative: outside), in the budget's unit
    verdict: Status  #: pass, marginal or fail

    def __post_init__(self):
        object.__setattr__(self, "verdict", Status(self.verdict))

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Verdict:
        """A verdict as a report holds it; a key it lacks (a record written by hand, or by an older
        version) reads as unknown: no name, no unit, not a number."""
        known = {f.name for f in fields(cls)}
        unknown = {"budget": "", "unit": "", "measured": math.nan, "limit": math.nan, "margin": math.nan}
        return cls(**{**unknown, **{k: v for k, v in data.items() if k in known}})

    def message(self) -> str:
        if self.judgement != "budget":  # a judged check (hil.requirements.JudgedCheck): its bound is no budget
            return (f"{self.judgement} check {self.budget} ({self.requirement}): measured {self.measured:.6g} "
                    f"{self.unit}, bound {'at most' if self.limit_kind == 'max' else 'at least'} {self.limit:.6g} "
                    f"{self.unit} (margin {self.margin:+.3g} {self.unit}): {self.verdict.upper()}")
        rel = (
            ("exceeds" if self.limit_kind == "max" else "falls short of")
            if self.verdict == Status.FAIL and self.margin < 0
            else "is within"
        )
        side = "at most" if self.limit_kind == "max" else "at least"
        return (
            f"{self.budget} ({self.requirement}): measured {self.measured:.6g} {self.unit} {rel} the limit of "
            f"{side} {self.limit:.6g} {self.unit} (margin {self.margin:+.3g} {self.unit}): {self.verdict.upper()}"
        )

    limit_kind: str = "max"
    #: "budget" (the customer's limit), or the kind of a judged check that is no budget: "back-to-back"
    #: (against the reference implementation, its tolerance the run's seed-to-seed spread) or "physics"
    #: (what any correct predictor obeys); hil.requirements.JudgedCheck
    judgement: str = "budget"


@dataclass(frozen=True)
class Unanswerable:
    """Requirements a test could not answer for on this DUT, and why: its profile lacks what they
    need (not testable), or they judge another kind of DUT (not applicable)."""

    reason: str
    requirements: tuple[str, ...]

    def to_json(self) -> dict:
        return {"reason": self.reason, "requirements": list(self.requirements)}

    @classmethod
    def from_json(cls, data: dict | None) -> Unanswerable | None:
        return None if not data else cls(data.get("reason", ""), tuple(data.get("requirements", ())))


@dataclass
class TestRecord:
    """One test, as the reports hold it."""

    __test__ = False  # not a pytest test class, whatever its name

    nodeid: str
    outcome: Outcome
    duration_s: float = 0.0
    message: str = ""
    details: str = ""
    requirements: list[str] = field(default_factory=list)
    #: the requirements tied to the test only by a budget it measured: judged by their budgets alone,
    #: whatever the test's other checks found
    budget_only: list[str] = field(default_factory=list)
    measurements: list[Verdict] = field(default_factory=list)
    evidence: list[dict] = field(default_factory=list)
    dut: str = ""
    dut_identity: dict = field(default_factory=dict)
    doc: str = ""
    worker: str = ""  #: the pytest-xdist worker that ran it ("" without xdist)
    xfail_reason: str = ""
    not_testable: Unanswerable | None = None
    not_applicable: Unanswerable | None = None
    failed_by: FailedBy = FailedBy.NOTHING
    dut_build: dict | None = None  #: a firmware DUT's spec, build hash and profile hash
    traffic: dict | None = None  #: what the edges moved on the DUT's link (hil.dut.traffic)
    processor: dict | None = None  #: pil: what the emulated core and the interrupt schedule measured

    #: written only when present, as earlier versions did
    _OPTIONAL = ("dut_build", "traffic", "processor")

    def to_json(self) -> dict:
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in self._OPTIONAL and value is None:
                continue
            if f.name == "measurements":
                value = [m.as_dict() for m in value]
            elif isinstance(value, Unanswerable):
                value = value.to_json()
            out[f.name] = value
        return out

    @classmethod
    def from_json(cls, data: dict) -> TestRecord:
        """A record from a report of this version or an earlier one (keys it lacks take their
        defaults; keys a later version added and this one does not know are left out)."""
        known = {f.name for f in fields(cls)}
        kept = {k: v for k, v in data.items() if k in known}
        kept["outcome"] = Outcome(data["outcome"])
        kept["failed_by"] = FailedBy(data.get("failed_by") or "")
        kept["measurements"] = [Verdict.from_dict(m) for m in data.get("measurements", [])]
        kept["not_testable"] = Unanswerable.from_json(data.get("not_testable"))
        kept["not_applicable"] = Unanswerable.from_json(data.get("not_applicable"))
        return cls(**kept)

    @property
    def traced(self) -> set[str]:
        """Every requirement the test answers for: its markers' and its measurements'."""
        return set(self.requirements) | {m.requirement for m in self.measurements}

    def relevant(self, rid: str | None) -> list[Verdict]:
        """The test's measurements of ``rid``'s budgets; a test tied to ``rid`` by its marker only
        answers for it with all of its measurements."""
        ms = self.measurements
        return ([m for m in ms if m.requirement == rid] or ms) if rid else ms

    def status(self, rid: str | None = None) -> Status:
        """The test's verdict (for requirement ``rid``, or overall): fail, error, not tested,
        not testable, not applicable, marginal or pass.

        A known failure (xfail) and an unexpected pass (xpass) are ``fail``; a skip is ``not tested``
        (the plugin turns a skip that hides an unreachable controller into an error), or ``not
        testable`` for a requirement the device's profile lacks what it needs for."""
        lacking, elsewhere = self.not_testable, self.not_applicable
        if elsewhere and self.outcome != Outcome.ERROR and (
            (rid is not None and rid in elsewhere.requirements) or (rid is None and self.outcome == Outcome.SKIPPED)
        ):
            return Status.NOT_APPLICABLE
        if rid is not None and lacking and rid in lacking.requirements and self.outcome != Outcome.ERROR:
            # a test that ran for its other requirements judged nothing of this one
            return Status.NOT_TESTABLE
        if self.outcome == Outcome.ERROR:
            return Status.ERROR
        if self.outcome == Outcome.FAILED and rid is not None and (
            self.failed_by == FailedBy.BUDGET or rid in self.budget_only
        ):
            # the failure was only missed budgets, or ``rid`` is tied to the test by its budgets alone:
            # ``rid`` is judged by its own budgets (one with none here was judged by the test's checks,
            # which all held)
            return Status.of_measurements(m.verdict for m in self.measurements if m.requirement == rid)
        if self.outcome in FAILING_OUTCOMES:
            return Status.FAIL
        if self.outcome == Outcome.SKIPPED:
            return Status.NOT_TESTABLE if lacking and rid is None else Status.NOT_TESTED
        return Status.of_measurements(m.verdict for m in self.relevant(rid))
