"""Replayable stimuli: what a property-based test drew (effects, wiring-fault steps, seed,
scenario), saved as JSON when it fails and re-run by ``hil replay FILE``.

The acceptance tests and ``hil replay`` run a stimulus through the same function, ``run``, so a
replay reproduces the failing check exactly (same plant, same seed, same steps), against the
virtual controller or any ``--dut``.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bldc.contract import Strategy, strategy_named
from bldc.motor import steady_state
from plant_models import PlantConfig
from plant_models.effects import effect_from_mapping

from .lockstep import acceptance_max_step_s, make_bench, p99_abs, rms
from ..dut.link import link_has
from ..dut.profile import CALIBRATION_ROLES
from ..calibration.campaign import station_corrections
from ..dut.faults import WIRING_FAULTS, FaultInjector, wiring_fault_from_dict

FORMAT = "hil-stimulus/1"
#: what a run measures, per kind (deg electrical): the commutation angle error's p99, RMS and
#: maximum of |error| over the judged window; after a fault sequence, p99 in the recovery window
METRICS = {"deviations": ("angle_p99", "angle_rms", "angle_max"), "fault_sequence": ("recovered_p99",)}
DEFAULT_BUDGETS = {"deviations": {"any_deviations_commutation_angle_p99": "angle_p99"},
                   "fault_sequence": {"recovered_commutation_angle_p99": "recovered_p99"}}


@dataclass
class Stimulus:
    """``kind``: "deviations" (calibrate, then run corrected) or "fault_sequence" (steps of
    ("run", seconds) / ("on", fault dict) / ("off", fault dict), corrected strategy)."""

    kind: str
    effects: list[dict] = field(default_factory=list)
    steps: list[list] = field(default_factory=list)
    seed: int = 0
    speed_rpm: float = 6000.0
    run_s: float = 0.25
    test: str = ""
    plant: dict = field(
        default_factory=dict
    )  #: the nominal plant (PlantConfig.to_dict), so a replay needs nothing else
    #: the controller's commutation strategy (bldc.contract.STRATEGY_NAMES); faults always run corrected
    strategy: str = "corrected"
    #: budget name -> the measured metric it judges (METRICS); empty: the acceptance suite's budget of the kind
    budgets: dict = field(default_factory=dict)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"format": FORMAT, **asdict(self)}, indent=1))
        return path

    @classmethod
    def load(cls, path: str | Path) -> "Stimulus":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as exc:
            raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: line {exc.lineno}, column {exc.colno}: not valid JSON: {exc.msg}") from None
        if data.pop("format", None) != FORMAT:
            raise ValueError(f"{path}: not a {FORMAT} file (field 'format')")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"{path}: unknown field(s) {', '.join(sorted(unknown))}")
        if data.get("kind") not in ("deviations", "fault_sequence"):
            raise ValueError(f"{path}: field 'kind' must be 'deviations' or 'fault_sequence', got {data.get('kind')!r}")
        try:
            # the contract's spelling ("sage-husa", as replays were once written, reads as sage_husa)
            data["strategy"] = strategy_named(data.get("strategy", "corrected")).name.lower()
        except ValueError as exc:
            raise ValueError(f"{path}: field 'strategy': {exc}") from None
        for name, metric in dict(data.get("budgets") or {}).items():
            if metric not in METRICS[data["kind"]]:
                raise ValueError(
                    f"{path}: field 'budgets.{name}': metric must be one of {', '.join(METRICS[data['kind']])}, got "
                    f"{metric!r}"
                )
        return cls(**data)

    def plant_config(self) -> PlantConfig:
        base = PlantConfig.from_dict(self.plant) if self.plant else PlantConfig.from_dict({"preset": "paper-bench"})
        return base.with_effects(*(effect_from_mapping(e, f"effects[{i}].") for i, e in enumerate(self.effects)))


@dataclass
class Outcome:
    ok: bool
    message: str
    values: dict = field(default_factory=dict)
    verdicts: list = field(default_factory=list)  #: one budgets.Verdict per judged budget


def replay_path(report_dir: str | Path | None, nodeid: str) -> Path:
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid)[-120:]
    return Path(report_dir or "reports") / "replays" / f"{slug}.json"


def run(stimulus: Stimulus, link, budgets) -> Outcome:
    """Run the stimulus on the lockstep bench through ``link`` and judge it against ``budgets``."""
    config = stimulus.plant_config()
    # both kinds commutate on corrected edges with the station's tables for this plant
    link.reset()
    # a controller without the calibration or strategy roles is judged with its own (nothing downloaded)
    if link_has(link, *CALIBRATION_ROLES, "calibration_apply"):
        link.download_calibration(station_corrections(config, seed=stimulus.seed))
    strategy = strategy_named(stimulus.strategy) if stimulus.kind == "deviations" else Strategy.CORRECTED
    if link_has(link, "strategy"):
        link.set_strategy(int(strategy))
    injector = FaultInjector(link)
    bench = make_bench(
        config,
        injector,
        initial_speed_rpm=stimulus.speed_rpm,
        duty=steady_state(config.motor, stimulus.speed_rpm)["duty"],
        seed=stimulus.seed,
        sim_options={"max_step_s": acceptance_max_step_s(config)},
    )
    if stimulus.kind == "deviations":
        # the settling windows as on the paper pump, and whole turns on a slow many-pole rotor (PlantConfig)
        bench.run_setpoints([stimulus.speed_rpm], hold_s=stimulus.run_s,
                            settle_s=config.suite_settle_s(0.1, stimulus.speed_rpm))
        err = bench.angle_errors_deg_e(config.suite_settle_s(0.15, stimulus.speed_rpm))
        nan = float("nan")
        metrics = {
            "angle_p99": p99_abs(err) if err.size else nan,
            "angle_rms": rms(err) if err.size else nan,
            "angle_max": float(np.max(np.abs(err))) if err.size else nan,
        }
        verdicts = [
            budgets.check(name, metrics[metric])
            for name, metric in (stimulus.budgets or DEFAULT_BUDGETS["deviations"]).items()
        ]
        failed = [v for v in verdicts if v.verdict == "fail"]
        values = {"commutation_angle_p99_deg_e": metrics["angle_p99"], "commutations": int(err.size)}
        if stimulus.budgets:
            values.update(
                commutation_angle_rms_deg_e=metrics["angle_rms"], commutation_angle_max_deg_e=metrics["angle_max"]
            )
        return Outcome(not failed, "; ".join(v.message() for v in (failed or verdicts)), values, verdicts)
    # a fault sequence: every switched-on fault must give one of its promised codes, nothing else may appear,
    # and the commutation must be back within budget once the faults are off
    link.set_speed(stimulus.speed_rpm)
    # settle and learn the pole alignment before anything is injected
    bench.sim.run_until(config.suite_settle_s(0.1, stimulus.speed_rpm))
    for index, step in enumerate(stimulus.steps):
        action, arg = step
        if action == "run":
            bench.sim.run_until(bench.sim.t_s + float(arg))
        elif action == "on":
            injector.switch_on(wiring_fault_from_dict(arg))
        elif action == "off":
            injector.switch_off(wiring_fault_from_dict(arg))
        else:
            raise ValueError(f"steps[{index}]: unknown action {action!r} (run, on, off)")
    for fault in list(injector.active):
        injector.switch_off(fault)
    # a recovery window with every fault off: a resynchronised controller learns its pole alignment afresh,
    # so the window's judged second half starts a whole settling window after the faults went off
    judged_s = config.suite_settle_s(0.03, stimulus.speed_rpm)
    bench.sim.run_until(bench.sim.t_s + 2.0 * judged_s)
    acted = {name for _, what, name in injector.log if what == "acted"}
    codes = {code for _, code in link.status()["faults"]}
    allowed = set().union(*(set(WIRING_FAULTS[n].promised) | set(WIRING_FAULTS[n].allowed) for n in acted))
    problems = []
    for name in sorted(acted):
        if not codes & set(WIRING_FAULTS[name].promised):
            problems.append(
                f"{name} acted but none of its fault codes {[hex(c) for c in WIRING_FAULTS[name].promised]} was "
                "reported"
            )
    unexpected = codes - allowed
    if unexpected:
        problems.append(
            f"fault code(s) {[hex(c) for c in sorted(unexpected)]} reported without a cause (acted: "
            f"{sorted(acted) or 'none'})"
        )
    recovery = bench.angle_errors_deg_e(bench.sim.t_s - judged_s)
    p99 = p99_abs(recovery) if recovery.size else float("inf")
    verdicts = [budgets.check(name, p99) for name in (stimulus.budgets or DEFAULT_BUDGETS["fault_sequence"])]
    problems += [v.message() for v in verdicts if v.verdict == "fail"]
    values = {"acted": sorted(acted), "codes": sorted(hex(x) for x in codes), "recovered_p99_deg_e": p99}
    return Outcome(
        not problems,
        "; ".join(problems) or "every fault reported, none spurious, commutation recovered",
        values,
        verdicts,
    )
