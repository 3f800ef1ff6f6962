"""Property-based fault injection (hypothesis): the search for what breaks the controller.

* Deviations: any combination of the calibratable effects of the library, drawn inside their
  physical bounds, is calibrated by the station and downloaded; the controller's corrected
  commutation must then meet the angle budget. ``target()`` steers toward the worst p99.
* Fault sequences (stateful): wiring faults switched on and off while the plant runs; every
  fault must give a promised code, none may appear without a cause, and the commutation must be
  back within budget once they are off.

Each failing example is saved as a stimulus file (effects, steps, seed, scenario) in the report
directory's ``replays/``; ``hil replay FILE`` re-runs it. Settings: the ``hil`` profile (no
deadline, examples kept in the report directory's database). The search is seeded from the HIL
seed (``--hil-seed``, default 0), so ``pytest test_cases`` and ``hil acceptance`` with the same
seed draw the same examples and reach the same verdict (unseeded, a plain pytest run drew new
examples each time while ``hil acceptance`` fixed them).
"""

import json

import pytest
from hypothesis import example, given, seed, target
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, rule, run_state_machine_as_test

from hil.dut.faults import wiring_fault_strategy
from hil.verdicts.judging import not_judged
from hil.verdicts.progress import note
from hil.pytest_plugin import hil_settings
from hil.bench.stimulus import Stimulus, replay_path, run
from plant_models import effects as fx

#: examples each search runs in the default run: enough that "any calibrated deviation set meets
#: the budget" rests on a hundred closed-loop draws, not eight (a quality engineer signs the count,
#: which the report shows as "examples run" beside the seed)
DEVIATION_EXAMPLES = 100
FAULT_SEQUENCE_EXAMPLES = 50
#: the fault-sequence search draws up to this many sequences to find FAULT_SEQUENCE_EXAMPLES
#: distinct ones: a stateful search repeats itself (at seed 7, 56 draws held 34 distinct
#: sequences); a repeat or a draw after the count is reached is not run
FAULT_SEQUENCE_DRAWS = 8 * FAULT_SEQUENCE_EXAMPLES
#: deviation sets the search once found the built-in controller failing, run in every search as
#: explicit examples (for plants with their pole pairs): uneven calibrated sectors that read as a
#: lost edge every turn (16.5 deg e p99; tests/test_findings.py keeps its stimulus)
FOUND_DEVIATION_SETS = [
    (
        2,
        7000.0,
        [
            {"name": "installation_offset", "offset_deg_e": [2.3955, 1.8000, -8.9772]},
            {"name": "pole_offset", "offset_deg_e": [-0.8301, -4.7743, -4.7151, 1.5470]},
            {"name": "armature_reaction", "slope_deg_e_per_a": 0.0},
            {"name": "conditioning_delay", "rise_delay_s": 14e-6, "fall_delay_s": 50e-6},
        ],
    ),
]


def deviations(pole_pairs: int, delay_draws: str = "library"):
    """The calibratable effects, each drawn by the effect library's own strategy, inside its full
    physical bounds (installation +-10 deg e, poles +-5 deg e, armature +-2 deg e/A), delays in the
    stated range: to 50 us, or to 300 us with ``--hil-delay-draws real-wiring`` (fx.DRAW_DELAY_S)."""
    return st.tuples(fx.InstallationOffset.strategy(pole_pairs), fx.PoleOffset.strategy(pole_pairs),
                     fx.ArmatureReaction.strategy(pole_pairs),
                     fx.ConditioningDelay.strategy(pole_pairs, fx.DRAW_DELAY_S[delay_draws]))


def judge(stimulus, outcome, request):
    if not outcome.ok:
        # the budgets the failing example missed, recorded as the test's measurements: what caught
        # it is their requirement's budget (hil qualify), not only the message
        for v in outcome.verdicts:
            if v.verdict == "fail":
                request.node.user_properties.append((f"budget:{v.budget}", json.dumps(v.as_dict())))
                request.node.user_properties.append(("requirement", v.requirement))
        path = stimulus.save(replay_path(request.config.getoption("--hil-report-dir"), request.node.nodeid))
        raise AssertionError(f"{outcome.message} (stimulus saved: hil replay {path})")


@pytest.mark.requirement("REQ-ROB-001")
def test_any_calibrated_deviation_set_meets_the_commutation_budget(
    hil_link, hil_plant_config, hil_budget, hil_budgets, hil_evidence, hil_seed, request
):
    plant = hil_plant_config
    worst = {"p99": 0.0, "effects": None, "speed": float("nan")}
    explicit = [
        (tuple(fx.effect_from_mapping(e, f"FOUND_DEVIATION_SETS[{k}].") for k, e in enumerate(found)),
         plant.suite_speed_rpm(speed_rpm))
        for pole_pairs, speed_rpm, found in FOUND_DEVIATION_SETS
        if pole_pairs == plant.motor.pole_pairs
    ]
    examples = []  #: (speed, explicit?) of every example run
    delay_draws = request.config.getoption("--hil-delay-draws")
    hil_evidence.text("conditioning delays drawn", f"{delay_draws}: 0-{fx.DRAW_DELAY_S[delay_draws] * 1e6:.0f} us")

    @seed(hil_seed)
    @hil_settings(max_examples=DEVIATION_EXAMPLES)
    @given(effects=deviations(hil_plant_config.motor.pole_pairs, delay_draws),
           speed_rpm=st.sampled_from([plant.suite_speed_rpm(rpm) for rpm in (4000.0, 7000.0, 10000.0)]))
    def check(effects, speed_rpm):
        examples.append((speed_rpm, (effects, speed_rpm) in explicit))
        note(f"search example {len(examples)}/{DEVIATION_EXAMPLES + len(explicit)}: calibrated deviation set at "
             f"{speed_rpm:.0f} rpm")
        stim = Stimulus(
            "deviations",
            effects=[e.to_dict() for e in effects],
            seed=hil_seed,
            speed_rpm=speed_rpm,
            run_s=plant.suite_duration_s(Stimulus.run_s),
            test=request.node.nodeid,
            plant=plant.to_dict(),
        )
        outcome = run(stim, hil_link, hil_budgets)
        p99 = outcome.values["commutation_angle_p99_deg_e"]
        target(p99, label="commutation angle p99 (deg e)")
        if p99 >= worst["p99"]:
            worst.update(p99=p99, effects=[e.to_dict() for e in effects], speed=speed_rpm)
        judge(stim, outcome, request)

    for effects, speed_rpm in explicit:
        check = example(effects=effects, speed_rpm=speed_rpm)(check)
    try:
        check()
    finally:  # the evidence of the search so far, failed or not
        random_draws = sum(not was_explicit for _, was_explicit in examples)
        hil_evidence.value("random draws", random_draws)
        hil_evidence.value("explicit examples (found failing before, run on top)",
                           sum(was_explicit for _, was_explicit in examples))
        hil_evidence.value("seed", hil_seed)
        hil_evidence.value("worst p99 found", worst["p99"], "deg_e")
        hil_evidence.text("worst example", f"{worst['speed']:.0f} rpm: {worst['effects']}")
    not_judged(random_draws >= DEVIATION_EXAMPLES,
               f"the search ran {random_draws} random draws, not {DEVIATION_EXAMPLES}")
    # every example met the budget: the figure judged is the worst one the search found
    hil_budget("any_deviations_commutation_angle_p99", worst["p99"])


@pytest.mark.requirement("REQ-ROB-002")
def test_fault_sequences_are_reported_and_recovered(
    hil_link, hil_plant_config, hil_budgets, hil_evidence, hil_seed, request
):
    from plant_models.plant import paper_bench

    plant = hil_plant_config
    effects = [e.to_dict() for e in plant.suite_deviations(paper_bench(with_deviations=True).effects)]
    runs = []
    with_fault: set[str] = set()  #: the distinct step sequences in which at least one fault acted
    #: every distinct step sequence run, with its failure (None: it passed). Hypothesis runs a failing
    #: example again to confirm it and must see it fail again; a repeat skipped as seen read as a flaky
    #: controller (FlakyFailure: "produces unreliable results") where the run was deterministic
    seen: dict[str, AssertionError | None] = {}
    skipped = [0]  #: draws not run (repeats, and draws after the count was reached)

    class FaultSequence(RuleBasedStateMachine):
        @initialize(fault=wiring_fault_strategy(), seconds=st.sampled_from([0.005, 0.01, 0.02]))
        def start(self, fault, seconds):
            # every sequence switches a fault on and runs the plant with it: a sequence without a
            # fault that acted would count as an example without testing anything
            self.steps = [["on", fault.as_dict()], ["run", seconds]]
            self.active = [] if fault.one_shot else [fault]

        @rule(seconds=st.sampled_from([0.005, 0.01, 0.02]))
        def run_plant(self, seconds):
            self.steps.append(["run", seconds])

        @rule(fault=wiring_fault_strategy())
        def switch_on(self, fault):
            self.steps.append(["on", fault.as_dict()])
            if not fault.one_shot:
                self.active.append(fault)

        @rule(data=st.data())
        def switch_off(self, data):
            if self.active:
                fault = self.active.pop(data.draw(st.integers(0, len(self.active) - 1)))
                self.steps.append(["off", fault.as_dict()])

        def teardown(self):
            key = json.dumps(self.steps, sort_keys=True)
            if seen.get(key) is not None:
                raise seen[key]
            if key in seen or len(with_fault) >= FAULT_SEQUENCE_EXAMPLES:
                skipped[0] += 1  # a repeat tests nothing new; past the count the search is done
                return
            seen[key] = None
            note(f"search example {len(with_fault) + 1}/{FAULT_SEQUENCE_EXAMPLES}: fault sequence of "
                 f"{len(self.steps)} steps")
            stim = Stimulus(
                "fault_sequence",
                effects=effects,
                # the drawn run times are the paper pump's; as many electrical periods on this motor
                steps=[[a, plant.suite_duration_s(x)] if a == "run" else [a, x] for a, x in self.steps],
                seed=hil_seed,
                speed_rpm=plant.suite_speed_rpm(Stimulus.speed_rpm),
                test=request.node.nodeid,
                plant=plant.to_dict(),
            )
            outcome = run(stim, hil_link, hil_budgets)
            if outcome.values["acted"]:
                with_fault.add(key)
            runs.append(
                [
                    len(self.steps),
                    ", ".join(outcome.values["acted"]) or "none",
                    ", ".join(outcome.values["codes"]) or "none",
                    outcome.values["recovered_p99_deg_e"],
                ]
            )
            try:
                judge(stim, outcome, request)
            except AssertionError as exc:
                seen[key] = exc
                raise

    try:
        run_state_machine_as_test(
            seed(hil_seed)(FaultSequence),
            settings=hil_settings(max_examples=FAULT_SEQUENCE_DRAWS, stateful_step_count=6),
        )
    finally:  # the evidence of the search so far, failed or not
        hil_evidence.value("sequences with a fault", len(with_fault))
        hil_evidence.value("sequences run", len(runs))
        hil_evidence.value("draws not run (repeats, or after the count was reached)", skipped[0])
        hil_evidence.value("seed", hil_seed)
        hil_evidence.table(
            "fault sequences run", ["steps", "faults that acted", "codes reported", "recovered p99 deg e"], runs
        )
    not_judged(len(with_fault) >= FAULT_SEQUENCE_EXAMPLES, (
        f"the search ran {len(with_fault)} distinct sequences in which a fault acted, not {FAULT_SEQUENCE_EXAMPLES}"
    ))
