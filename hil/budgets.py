"""Accuracy budgets: named limits with units, an optional marginal band, traced to requirement IDs.

A budgets TOML file holds one table per budget:

    [commutation_angle_p99]
    requirement = "REQ-COMM-001"
    unit = "deg_e"
    limit = 0.5            # the measured value must not exceed it (kind = "max", the default)
    marginal = 0.4         # optional: beyond this, still passing but marginal
    kind = "max"           # or "min": the measured value must reach the limit
    description = "..."

Checking a measurement gives a Verdict (measured, limit, margin, pass / marginal / fail);
asserting it raises BudgetExceeded with a message a person understands.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

from plant_models.params import ConfigError


@dataclass(frozen=True)
class Budget:
    name: str
    requirement: str
    unit: str
    limit: float
    kind: str = "max"
    marginal: float | None = None
    description: str = ""


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
        rel = ("exceeds" if self.limit_kind == "max" else "falls short of") if self.verdict == "fail" and self.margin < 0 else "is within"
        side = "at most" if self.limit_kind == "max" else "at least"
        return (f"{self.budget} ({self.requirement}): measured {self.measured:.6g} {self.unit} {rel} the limit of "
                f"{side} {self.limit:.6g} {self.unit} (margin {self.margin:+.3g} {self.unit}): {self.verdict.upper()}")

    limit_kind: str = "max"


class BudgetExceeded(AssertionError):
    def __init__(self, verdict: Verdict):
        self.verdict = verdict
        super().__init__(verdict.message())


#: defaults derived from the paper and the issues' acceptance bounds
DEFAULTS = {
    "commutation_angle_p99": Budget("commutation_angle_p99", "REQ-COMM-001", "deg_e", 0.5, marginal=0.4,
                                    description="p99 commutation angle error after calibration (paper 4.3 scenario)"),
    "installation_offset_error": Budget("installation_offset_error", "REQ-CAL-001", "deg_e", 0.05, marginal=0.04,
                                        description="calibrated installation offsets against truth"),
    "pole_offset_error": Budget("pole_offset_error", "REQ-CAL-002", "deg_e", 0.05, marginal=0.04,
                                description="calibrated pole offsets against truth"),
    "conditioning_delay_error": Budget("conditioning_delay_error", "REQ-CAL-003", "s", 0.5e-6, marginal=0.4e-6,
                                       description="calibrated rise and fall delays against truth"),
    "armature_slope_error": Budget("armature_slope_error", "REQ-CAL-004", "fraction", 0.05, marginal=0.04,
                                   description="calibrated armature-reaction slope, relative error"),
    "calibrated_fraction_removed": Budget("calibrated_fraction_removed", "REQ-CAL-005", "fraction", 0.90, kind="min", marginal=0.95,
                                          description="share of the raw commutation angle RMS that the downloaded calibration removes"),
    "any_deviations_commutation_angle_p99": Budget("any_deviations_commutation_angle_p99", "REQ-ROB-001", "deg_e", 1.0, marginal=0.5,
                                                   description="p99 commutation angle error, corrected, for any drawn set of calibratable deviations (property search)"),
    "recovered_commutation_angle_p99": Budget("recovered_commutation_angle_p99", "REQ-ROB-002", "deg_e", 1.0, marginal=0.8,
                                              description="p99 commutation angle error in the 30 ms before the end of a 60 ms recovery window after a wiring fault"),
    "sage_husa_commutation_angle_rms": Budget("sage_husa_commutation_angle_rms", "REQ-PRED-001", "deg_e", 1.0, marginal=0.8,
                                              description="RMS commutation angle error of the Sage-Husa predictor in the paper's speed-step scenario"),
    "sage_husa_commutation_angle_p99": Budget("sage_husa_commutation_angle_p99", "REQ-PRED-001", "deg_e", 2.5, marginal=2.0,
                                              description="p99 commutation angle error of the Sage-Husa predictor in the paper's speed-step scenario"),
    "sage_husa_over_kf_angle_rms": Budget("sage_husa_over_kf_angle_rms", "REQ-PRED-002", "ratio", 1.05, marginal=1.0,
                                          description="Sage-Husa commutation angle RMS over the tuned Kalman filter's, same scenario (issue 4: no worse by more than 5 %)"),
    "learned_edge_noise_ratio": Budget("learned_edge_noise_ratio", "REQ-PRED-003", "ratio", 0.25, kind="min", marginal=0.5,
                                       description="edge-angle noise variance the Sage-Husa filter learned, over the variance the plant injects (a filter that adapts nothing stays at R0 = 0)"),
    "heartbeat_period_error": Budget("heartbeat_period_error", "REQ-PROT-002", "fraction", 0.05, marginal=0.03,
                                     description="mean heartbeat period against 0x1017 (CiA 301), relative"),
    "commutation_time_mape": Budget("commutation_time_mape", "REQ-PRED-001", "percent", 1.0, marginal=0.9,
                                    description="MAPE of the predicted commutation instant over the ideal interval (paper Table 5 scenario)"),
}


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
}


class Budgets:
    def __init__(self, budgets: dict[str, Budget], source: str = "defaults"):
        self.budgets, self.source = budgets, source

    def __contains__(self, name: str) -> bool:
        return name in self.budgets

    def __getitem__(self, name: str) -> Budget:
        try:
            return self.budgets[name]
        except KeyError:
            raise KeyError(f"no budget named {name!r} in {self.source} (have: {', '.join(sorted(self.budgets))})") from None

    @classmethod
    def defaults(cls) -> "Budgets":
        return cls(dict(DEFAULTS))

    @classmethod
    def from_toml(cls, path: str | Path, base: "Budgets | None" = None) -> "Budgets":
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except OSError as exc:
            raise ConfigError(str(path), f"cannot read: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(str(path), f"not valid TOML: {exc}") from None
        budgets = dict((base or cls.defaults()).budgets)
        known = {"requirement", "unit", "limit", "marginal", "kind", "description"}
        for name, table in data.items():
            where = f"{path}: [{name}]"
            if not isinstance(table, dict):
                raise ConfigError(where, "each budget is a table")
            for key in table:
                if key not in known:
                    raise ConfigError(f"{where}.{key}", f"unknown key (known: {', '.join(sorted(known))})")
            for key in ("requirement", "unit", "limit"):
                if key not in table and name not in budgets:
                    raise ConfigError(f"{where}.{key}", "required")
            inherited = asdict(budgets[name]) if name in budgets else {}
            if "limit" in table and "marginal" not in table:
                inherited.pop("marginal", None)  # a marginal band belongs to the limit it was set with
            merged = {**inherited, **table, "name": name}
            for key in ("limit", "marginal"):
                v = merged.get(key)
                if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
                    raise ConfigError(f"{where}.{key}", f"must be a finite number, got {v!r}")
            if merged.get("kind", "max") not in ("max", "min"):
                raise ConfigError(f"{where}.kind", f"must be 'max' or 'min', got {merged['kind']!r}")
            m, lim = merged.get("marginal"), merged["limit"]
            if m is not None and ((merged.get("kind", "max") == "max" and m > lim) or (merged.get("kind") == "min" and m < lim)):
                raise ConfigError(f"{where}.marginal", "the marginal band must lie on the passing side of the limit")
            budgets[name] = Budget(**merged)
        return cls(budgets, str(path))

    def check(self, name: str, measured: float) -> Verdict:
        b = self[name]
        if not isinstance(measured, (int, float)) or not math.isfinite(measured):
            return Verdict(b.name, b.requirement, float("nan"), b.limit, b.unit, float("-inf"), "fail", b.kind)
        margin = (b.limit - measured) if b.kind == "max" else (measured - b.limit)
        if margin < 0:
            verdict = "fail"
        elif b.marginal is not None and ((b.kind == "max" and measured > b.marginal) or (b.kind == "min" and measured < b.marginal)):
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
