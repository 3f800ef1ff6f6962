"""A calibration table applied while the motor runs (REQ-CAL-005: "downloaded, applied and read back").

Every other bench starts from a power cycle with its table already in place, so none sees how a
controller swaps the table its interrupts read while they run. Here the motor runs corrected on the
paper's combined deviations and a table is applied in mid-run, several times, at the same instants
of two otherwise identical runs: in one the original table again, in the other alternately an
equivalent one and the original. The equivalent table holds the same corrections written
differently (every installation offset ``SHIFT_DEG_E`` larger, every pole offset as much smaller;
an edge's correction is their sum), so a controller that swaps its table atomically commutates the
same in both runs, whatever its apply does to its commutation logic (both controllers here restart
it, and relearn the pole alignment). One whose interrupts read a half-copied table (new installation
offsets with old pole offsets) misplaces commutations by up to ``SHIFT_DEG_E`` meanwhile.

Judged against the plant's true rotor angle: each commutation of the second run may differ from
its counterpart in the first by no more than the corrected commutation budget
(``commutation_angle_p99``: an apply must cost the commutation nothing beyond what corrected
commutation is allowed at all), and once the last apply has settled (the turns the pole alignment
needs) the commutation meets that budget (REQ-COMM-001's p99).
"""

import numpy as np
import pytest

from bldc.contract import Strategy
from hil.bench.lockstep import p99_abs as p99
from hil.dut.link import edge_hook_kind
from plant_models import effects as fx
from plant_models.plant import paper_installation_offsets_deg_e, paper_pole_offsets_deg_e

SPEED_RPM = 8000.0
SHIFT_DEG_E = 10.0  # within the table's bounds (installation 30, pole 20 deg e) for the paper's offsets
APPLIES = 4
#: the paper's combined deviations, as test_calibration_recovery.py has them (the campaign is cached)
EFFECTS = (
    fx.InstallationOffset(paper_installation_offsets_deg_e()),
    fx.PoleOffset(paper_pole_offsets_deg_e()),
    fx.ConditioningDelay(rise_delay_s=6.6e-6, fall_delay_s=1.0e-6),
    fx.ArmatureReaction(slope_deg_e_per_a=0.35),
)


def shifted(corrections, shift_deg_e: float):
    """The same corrections with every installation offset ``shift_deg_e`` larger and every pole
    offset as much smaller (each edge's correction unchanged)."""
    out = corrections.__class__.from_json_dict(corrections.to_json_dict())
    out.installation_offset_deg_e = {s: v + shift_deg_e for s, v in corrections.installation_offset_deg_e.items()}
    out.pole_offset_deg_e = [v - shift_deg_e for v in corrections.pole_offset_deg_e]
    return out


def run_with_applies(hil_bench, hil_link, plant, effects, speed_rpm, tables):
    """A corrected bench run on ``tables[0]``; each later table applied in mid-run, each held for the
    turns the pole alignment needs and one more. Returns the commutations and the apply instants."""
    bench = hil_bench(Strategy.CORRECTED, corrections=tables[0], effects=effects, speed_rpm=speed_rpm)
    bench.run_setpoints([speed_rpm], hold_s=0.0, settle_s=plant.suite_settle_s(0.1, speed_rpm))
    # the settling the pole alignment needs and one more turn, judged (on a slow rotor of many pole
    # pairs the settling alone is the whole window and would leave nothing to judge)
    window_s = plant.suite_settle_s(0.04, speed_rpm) + 60.0 / speed_rpm
    applied_at = []
    for table in tables[1:]:
        applied_at.append(bench.sim.t_s)
        hil_link.download_calibration(table)  # written, read back, compared, applied
        bench.sim.run_until(applied_at[-1] + window_s)
    return bench.sim.commutations(), applied_at


@pytest.mark.requirement("REQ-CAL-005")
def test_table_applied_while_the_motor_runs(calibrate, hil_bench, hil_budget, hil_budgets, hil_evidence,
                                            hil_plant_config, hil_link):
    if getattr(hil_link, "profile", None) is not None and edge_hook_kind(hil_link) == "none":
        pytest.skip("the commutation is judged on the closed-loop bench: the profile has no edge hook")
    plant = hil_plant_config
    effects = plant.suite_deviations(EFFECTS)
    speed_rpm = plant.suite_speed_rpm(SPEED_RPM)
    original = calibrate(effects)
    equivalent = shifted(original, SHIFT_DEG_E)
    same, applied_at = run_with_applies(hil_bench, hil_link, plant, effects, speed_rpm, [original] * (APPLIES + 1))
    swapped, applied_at2 = run_with_applies(hil_bench, hil_link, plant, effects, speed_rpm,
                                            [original] + [equivalent, original] * (APPLIES // 2))
    assert np.allclose(applied_at, applied_at2)
    judged_from = applied_at[0]
    a = same.error_deg_e[same.t_s >= judged_from]
    b = swapped.error_deg_e[swapped.t_s >= judged_from]
    limit = hil_budgets["commutation_angle_p99"].limit
    hil_evidence.text("tables", f"the original, and the same with installation offsets +{SHIFT_DEG_E:g} deg e and "
                                f"pole offsets -{SHIFT_DEG_E:g} deg e, applied {APPLIES} times in mid-run at "
                                f"{speed_rpm:.0f} rpm ({', '.join(f'{t:.3f}' for t in applied_at)} s)")
    assert a.size == b.size, (
        f"{b.size} commutations from the first apply with the equivalent table, {a.size} with the original: "
        "the apply changed the commutation sequence"
    )
    assert a.size, (
        f"no commutation from the first apply at {judged_from:.3f} s on: the controller stopped switching "
        "its gates from one sector to the next while the motor ran"
    )
    diff = np.abs(b - a)
    worst = int(np.argmax(diff))
    hil_evidence.table(
        "commutation angle error from the first apply on (deg e)",
        ["run", "commutations", "p99", "max |error|"],
        [["original re-applied", a.size, p99(a), float(np.max(np.abs(a)))],
         ["equivalent table applied", b.size, p99(b), float(np.max(np.abs(b)))]],
    )
    hil_evidence.value("largest difference between the runs", float(diff[worst]), "deg_e")
    assert diff[worst] <= limit, (
        f"applying an equivalent table in mid-run moved the commutation at "
        f"{swapped.t_s[swapped.t_s >= judged_from][worst]:.5f} s by {diff[worst]:.2f} deg e (error {b[worst]:+.2f} "
        f"against {a[worst]:+.2f} with the original re-applied; limit {limit:g} deg e, the corrected commutation "
        "budget): the interrupts read a table that was neither the old one nor the new one"
    )
    settled = swapped.error_deg_e[swapped.t_s >= applied_at[-1] + plant.suite_settle_s(0.0, speed_rpm)]
    assert settled.size, "no commutation after the last apply had settled: the controller stopped switching"
    hil_budget("commutation_angle_p99", p99(settled))
