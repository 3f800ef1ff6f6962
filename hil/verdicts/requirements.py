"""The requirement registry: every requirement the acceptance suite judges, declared once.

An entry holds what the requirement asks, how the suite tests it, the page of the docs that
explains it, what a device profile must offer for a test to show it (roles, the edge hook, a fault
source) and its default budgets (limit, marginal bound, unit, and where the limit comes from).
Everything else derives from it:

- the built-in budgets (``hil.verdicts.budgets.Budgets.defaults``) and the report's requirement titles;
- "not testable with this profile" (``missing_needs``: the plugin's skip, ``hil qualify``'s
  out-of-scope entries, ``hil dut check``);
- the requirement table of docs/acceptance.md and the defaults table of docs/budgets.md
  (``python -m hil.verdicts.requirements`` rewrites them; tests/test_budgets.py holds the docs to them).

Adding a requirement is one entry here and its test in test_cases/ (marked
``@pytest.mark.requirement("REQ-...")``, or parametrised with the ID).
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, replace
from pathlib import Path

from bldc.contract import FILTER_COUNTERS, GUARD_TRIPS

from .budget_sources import derived


@dataclass(frozen=True)
class DefaultBudget:
    """A built-in budget (docs/budgets.md): ``kind`` "max", the measurement must not exceed
    ``limit``; "min", it must reach it; beyond ``marginal`` it passes but is flagged."""

    name: str
    unit: str
    limit: float
    marginal: float | None = None
    kind: str = "max"
    description: str = ""
    #: where the limit's value comes from (a paper table, a datasheet, a customer specification);
    #: empty where no source is stated yet
    limit_source: str = ""


#: the kinds of judgement beside the customer's budgets: a budget says what the customer needs; these
#: give the suite power over defects the budgets let through (docs/qualify.md, "Power beside compliance")
JUDGEMENTS = {
    "back-to-back": "the controller against the reference implementation of the paper's method (the built-in "
                    "controller as shipped, in-process) on the same bench, seeds and set points; the tolerance is "
                    "the seed-to-seed spread measured in the same run",
    "physics": "what any correct predictor obeys, with a bound from an outside source",
}


@dataclass(frozen=True)
class JudgedCheck:
    """A judged check that is no budget (``JUDGEMENTS``): its bound is computed in the run by the
    stated rule ``bound``, so no budgets file sets it. It fails its requirement as a missed budget
    does, and the report and ``hil qualify`` name it by its judgement."""

    name: str
    unit: str
    judgement: str  #: a JUDGEMENTS key
    description: str
    bound: str  #: the rule for the bound and where it comes from
    kind_of_limit: str = "max"
    requirement: str = ""  #: the requirement that declares it (set by the registry)


@dataclass(frozen=True)
class Requirement:
    id: str
    statement: str  #: what it asks (the report's title)
    tested_by: str  #: the suite's test(s) and what they do
    doc: str  #: the page and heading that explain how it is judged, "page.md#anchor" under docs/
    #: what a device profile must offer (hil.dut.profile roles, docs/device-profiles.md); a profile
    #: that lacks one makes the requirement "not testable with this profile"
    roles: tuple[str, ...] = ()
    #: closed loop: the plant's edges reach the controller (the lockstep edge hook, or a firmware's
    #: own pins in the loop, ``hil.sil``) and its commutation is judged on the plant
    edge_hook: bool = False
    #: how its faults must be seen: "emcy", or "any" (the ``fault_code`` role or EMCY)
    fault_source: str | None = None
    budgets: tuple[DefaultBudget, ...] = ()
    #: roles used when the profile has them and not needed: without the strategy and the calibration
    #: roles, a controller that calibrates itself or keeps its own tables is judged as it comes, with
    #: the deviations present and nothing downloaded (the accuracy its user would get)
    uses: tuple[str, ...] = ()
    #: the defect classes it exists to catch (``DEFECT_CLASSES``): ``hil qualify`` seeds defects of
    #: each class and its sensitivity table shows, per requirement, which its own budgets catch
    judges: tuple[str, ...] = ()
    #: the DUT kinds it applies to (``hil.dut.kinds``); empty: every kind. A requirement of the part
    #: (its interrupts' time, its stack) means nothing for a firmware on the PC or a device on a bus:
    #: there it is "not applicable", neither passed nor failed
    kinds: tuple[str, ...] = ()
    #: judged checks beside its budgets (``JudgedCheck``): back-to-back against the reference, physics
    checks: tuple[JudgedCheck, ...] = ()


def not_applicable(requirements, kind: str) -> list[str]:
    """The requirements among ``requirements`` that do not apply to a DUT of ``kind``."""
    return sorted(r for r in set(requirements) if (req := REQUIREMENTS.get(r)) is not None and req.kinds
                  and kind not in req.kinds)


#: the defect classes a requirement names (``Requirement.judges``); each seeded defect of
#: hil/qualify/defects.py belongs to one
DEFECT_CLASSES = {
    "calibration-table": "the downloaded calibration table applied wrongly (a pole off, delays swapped or scaled, "
                         "a sensor's offset on another, a sign, never applied)",
    "edge-current": "the current the controller reads for an edge's armature correction from the wrong instant or "
                    "window",
    "model-input": "the predictor model's input wrong: Eq. 8's cycle-mean current in the wrong unit, scale, or "
                   "summed over the phases with its sign (about 0 A in a star winding)",
    "commutation-timing": "commutation commands late or early by a latency the controller does not compensate",
    "predictor-model": "the commutation predictor's filter or model wrong (the strategy, its adaptation)",
    "noise-learning": "what the Sage-Husa filter learns wrong: its edge-noise estimate frozen, runaway, of the "
                      "wrong sign, scale or memory",
    "fault-handling": "a fault not reported, reported without a cause, or not recovered from",
    "table-validation": "an invalid calibration table accepted",
    "current-limit": "the phase current not held within the controller's limit",
    "speed-loop": "the speed loop's gains or structure wrong (commissioning errors)",
    "protocol": "an answer that is not the standard's (identity, SDO abort and Modbus exception codes, heartbeat)",
    "processor-time": "an interrupt too slow for the part: a double routine in software, an interrupt that holds "
                      "a more urgent one off (seen only on the part: pil:)",
    "processor-memory": "the part's memory broken: a stack beyond stack_bytes, an unaligned 64-bit access, code "
                        "or data that does not fit (seen only on the part: pil:)",
}

#: role groups (hil.dut.profile roles) several requirements need
CALIBRATION = ("installation_offset", "pole_offset", "conditioning_delay_rise", "conditioning_delay_fall",
               "armature_slope", "calibration_apply")
FILTER_SETTINGS = ("filter_forgetting", "filter_q0", "filter_r0", "filter_p0")
FILTER_STATE = ("filter_q_diag", "filter_r_diag")
COUNTERS = (GUARD_TRIPS, *FILTER_COUNTERS)
#: the groups by the words the docs use for them
ROLE_GROUPS = {"calibration": CALIBRATION, "filter settings": FILTER_SETTINGS, "filter Q and R": FILTER_STATE,
               "filter counters": COUNTERS}

_BENCH = ("strategy", *CALIBRATION)  # a lockstep bench run: the strategy set, the calibration downloaded
_SPEED_LOOP = ("strategy", "speed_setpoint", *CALIBRATION)  # judged on the plant's true currents and speed

_CAL_DOC = "calibration.md#the-procedure-and-what-each-step-needs-from-the-bench"
_CAL_TEST = ("`test_calibration_recovery.py`: the deviation alone, calibrated, downloaded, corrected commutation "
             "p99 and the share of the raw error removed")
_FLT_TEST = ("`test_faults.py`: the wiring fault on the captured-edge stream gives the promised fault code and "
             "nothing unexplained; commutation recovers")
_PRED_TEST = ("`test_sage_husa.py`: the paper's seven set points, Sage–Husa, KF and pre-calibration on the same "
              "plant and seed")
_PRED_DOC = "sage-husa.md#the-scenario"
_CANOPEN_DOC = "controller.md#canopen-face"
_CONTROLLER_DOC = "controller.md#virtual-controller"
_SPEED_STEP = "5000 to 5500 rpm"
_LEARN_TEST = ("`test_sage_husa_learning.py`: 8000 rpm, the plant's edge jitter stepped 3 -> 9 -> 3 us, the "
               "controller's R_theta read every 5 ms against the plant's (jitter w_e)^2")
_LEARN_DOC = "sage-husa.md#what-the-filter-learns"

#: the corrected commutation's angle budget (REQ-COMM-001's); each single deviation's requirement
#: judges the corrected commutation of its own scenario against the same limit (``_corrected``)
_COMMUTATION_P99 = DefaultBudget(
    'commutation_angle_p99', 'deg_e',
    description='p99 commutation angle error after calibration (paper 4.3 scenario)',
    **derived('commutation_angle_p99'),  # limit, marginal, limit_source: budget_sources.py
)


def _corrected(deviation: str, what: str) -> DefaultBudget:
    """REQ-COMM-001's angle budget for the scenario in which ``deviation`` alone is calibrated: what
    the requirement that this deviation is removed judges on the controller."""
    name = f"{deviation}_corrected_angle_p99"
    return replace(_COMMUTATION_P99, name=name,
                   description=f"p99 commutation angle error after calibration, {what} alone (paper 4.3 scenario, "
                               "8000 rpm)",
                   **derived(name))  # commutation_angle_p99's limit (hil/verdicts/budget_sources.py)


_REGISTRY = (
    Requirement(
        "REQ-CAL-001", "Installation deviations of the Hall sensors are removed by the pre-calibration (paper Eq. 1-5)",
        _CAL_TEST, _CAL_DOC, _BENCH, edge_hook=True,
        budgets=(_corrected('installation', 'the installation offsets'), DefaultBudget(
            'installation_offset_error', 'deg_e',
            description='calibrated installation offsets against truth',
            **derived('installation_offset_error'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table',),
    ),
    Requirement(
        "REQ-CAL-002", "Magnet-pole deviations are removed by the pre-calibration (paper Eq. 6)",
        _CAL_TEST, _CAL_DOC, _BENCH, edge_hook=True,
        budgets=(_corrected('pole', 'the magnet-pole offsets'), DefaultBudget(
            'pole_offset_error', 'deg_e',
            description='calibrated pole offsets against truth',
            **derived('pole_offset_error'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table',),
    ),
    Requirement(
        "REQ-CAL-003", "Conditioning-circuit (RC) delays are removed, rising and falling edges apart (paper Eq. 7-8)",
        _CAL_TEST, _CAL_DOC, _BENCH, edge_hook=True,
        budgets=(_corrected('conditioning_delay', 'the conditioning delays'), DefaultBudget(
            'conditioning_delay_error', 's',
            description='calibrated rise and fall delays against truth',
            **derived('conditioning_delay_error'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table',),
    ),
    Requirement(
        "REQ-CAL-004", "Armature-reaction deviation is removed as a function of phase current",
        _CAL_TEST, _CAL_DOC, _BENCH, edge_hook=True,
        budgets=(_corrected('armature_reaction', 'the armature reaction'), DefaultBudget(
            'armature_slope_error', 'fraction',
            description='calibrated armature-reaction slope, relative error',
            **derived('armature_slope_error'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table',),
    ),
    Requirement(
        "REQ-CAL-005",
        "The calibration table is downloaded, applied and read back exactly",
        "every download is read back and compared; the share of the raw error the downloaded table removes "
        "(`test_calibration_recovery.py`, `test_live_calibration.py`)",
        _CONTROLLER_DOC, CALIBRATION,
        budgets=(DefaultBudget(
            'calibrated_fraction_removed', 'fraction',
            kind='min',
            description='share of the raw commutation angle RMS that the downloaded calibration removes',
            **derived('calibrated_fraction_removed'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table',),
    ),
    Requirement(
        # pass/fail, judged by its fault code: a check of a requirement without a budget is a catch
        # (docs/qualify.md); it was REQ-CAL-005's second half, whose budget judges the applied table
        "REQ-CAL-006", "An invalid calibration table is refused with fault 0xFF04 and a valid one is accepted after it",
        "`test_faults.py`: a table with a pole offset beyond any magnet's tolerance is refused with 0xFF04; on "
        "CANopen and a firmware also by EMCY and 0x1001 (`test_protocol.py`)",
        _CONTROLLER_DOC, (*CALIBRATION, "fault_code"),
        judges=('table-validation',),
    ),
    Requirement(
        "REQ-COMM-001", "Corrected commutation lands within the angle budget over the speed range",
        "the combined deviations (`test_calibration_recovery.py[combined]`); the same through the pins "
        "(`test_signal_injection.py`)",
        "calibration.md#raw-versus-corrected-commutation-paper-section-43", ("speed_setpoint",), edge_hook=True,
        uses=_BENCH,
        budgets=(_COMMUTATION_P99,),
        judges=('calibration-table', 'commutation-timing'),
    ),
    Requirement(
        "REQ-PRED-001", "The Sage-Husa predictor meets the commutation budgets in the paper's speed-step scenario",
        _PRED_TEST, _PRED_DOC, (*_BENCH, *FILTER_SETTINGS, *COUNTERS), edge_hook=True,
        budgets=(
            DefaultBudget(
                'sage_husa_commutation_angle_rms', 'deg_e',
                description=(
                    "RMS commutation angle error of the Sage-Husa predictor in the paper's speed-step scenario"
                ),
                **derived('sage_husa_commutation_angle_rms'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'sage_husa_commutation_angle_p99', 'deg_e',
                description=(
                    "p99 commutation angle error of the Sage-Husa predictor in the paper's speed-step scenario"
                ),
                **derived('sage_husa_commutation_angle_p99'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'sage_husa_commutation_time_mape', '%',
                description=(
                    "mean absolute commutation time error of the Sage-Husa predictor against the plant's ideal "
                    'commutation instants, over the ideal commutation interval (60 deg e), paper scenario (1 % is 0.6'
                    ' deg e)'
                ),
                **derived('sage_husa_commutation_time_mape'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'commutation_time_mape', 'percent',
                description=(
                    'MAPE of the predicted commutation instant over the ideal interval (paper Table 5 scenario)'
                ),
                **derived('commutation_time_mape'),  # limit, marginal, limit_source: budget_sources.py
            ),
        ),
        # predictor-model: its budgets and its back-to-back check let sage-husa-runs-kf through (a KF
        # commutates within a few percent of Sage-Husa on stationary noise): REQ-PRED-003 judges that class
        judges=('commutation-timing', 'model-input'),
        checks=(JudgedCheck(
            'sage_husa_rms_against_reference', 'deg_e', 'back-to-back',
            "Sage-Husa's commutation angle RMS in the paper scenario, mean over three seeds (the run's and the "
            "next two), minus the reference implementation's on the same plant, calibration, filter settings, "
            "seeds and set points, absolute",
            "three times the seed-to-seed standard deviation of one run's RMS, both implementations' seeds pooled, "
            "measured in the same run (hil.verdicts.budget_sources.BAND_STANDARD_ERRORS): a controller that "
            "declares the paper's method commutates as its reference does, within what the seed alone moves",
        ),),
    ),
    Requirement(
        "REQ-PRED-002", "The Sage-Husa predictor is no worse than the fixed-noise Kalman filter",
        "`test_sage_husa.py`: Sage–Husa and the KF on the same plant and seeds, six seeds on each of four operating "
        "profiles (the paper's seven set points 5000-10,000 rpm, 3000-6000, 9000-14,000 rpm, and the paper's set "
        "points with the edge jitter 3 and 9 us in turn); each profile its own verdict, its limit derived for the "
        "commutations it judged",
        _PRED_DOC, (*_BENCH, *FILTER_SETTINGS), edge_hook=True,
        budgets=(DefaultBudget(
            'sage_husa_over_kf_angle_rms', 'ratio',
            description=(
                "Sage-Husa commutation angle RMS over the tuned Kalman filter's on one operating profile (mean over "
                'its seeds), each profile judged on its own: no worse than the KF beyond the ratio\'s sampling error'
            ),
            **derived('sage_husa_over_kf_angle_rms'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        # predictor-model: a KF in Sage-Husa's place scores the KF's own figure, by construction
        judges=('noise-learning',),
    ),
    Requirement(
        "REQ-PRED-003", "The Sage-Husa predictor adapts its noise statistics to the measured edge noise",
        "`test_sage_husa.py`: Sage–Husa started with R0 = 0 and Q0 100x too large learns the injected edge-angle "
        "noise (read back over the link); `test_sage_husa_learning.py`: R_theta within a band of the plant's "
        "(jitter w_e)^2 once converged",
        "sage-husa.md#what-adapts-and-the-guards", (*_BENCH, *FILTER_SETTINGS, *FILTER_STATE), edge_hook=True,
        budgets=(DefaultBudget(
            'learned_edge_noise_ratio', 'ratio',
            kind='min',
            description=(
                'edge-angle noise variance the Sage-Husa filter learned, over the variance the plant injects (a '
                'filter that adapts nothing stays at R0 = 0)'
            ),
            **derived('learned_edge_noise_ratio'),  # limit, marginal, limit_source: budget_sources.py
        ),
        DefaultBudget(
            'learned_edge_noise_ratio_high', 'ratio',
            description=(
                'edge-angle noise variance the Sage-Husa filter learned, over the variance the plant injects, from '
                'the upper side (a runaway estimate grows past it)'
            ),
            **derived('learned_edge_noise_ratio_high'),  # limit, marginal, limit_source: budget_sources.py
        ),
        DefaultBudget(
            'edge_noise_estimate_low', 'ratio',
            kind='min',
            description=(
                'lowest R_theta read back over the true edge-angle noise variance, converged, through 3-9-3 us jitter'
                ' at 8000 rpm'
            ),
            **derived('edge_noise_estimate_low'),  # limit, marginal, limit_source: budget_sources.py
        ),
        DefaultBudget(
            'edge_noise_estimate_high', 'ratio',
            description=(
                'highest R_theta read back over the true edge-angle noise variance, converged, through 3-9-3 us '
                'jitter at 8000 rpm'
            ),
            **derived('edge_noise_estimate_high'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('noise-learning', 'predictor-model'),
    ),
    Requirement(
        "REQ-PRED-004", "The Sage-Husa predictor's edge-noise estimate tracks a step of the edge noise",
        _LEARN_TEST, _LEARN_DOC, (*_BENCH, *FILTER_SETTINGS, *FILTER_STATE), edge_hook=True,
        budgets=(DefaultBudget(
            'edge_noise_tracking_edges', 'edges',
            description=(
                'edges from a step of the edge jitter (3 to 9 us, 9 to 3 us) until R_theta stays within the '
                'REQ-PRED-003 band of the truth'
            ),
            **derived('edge_noise_tracking_edges'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('noise-learning',),
    ),
    Requirement(
        "REQ-PRED-005", "The Sage-Husa predictor's edge-noise estimate is steady while the edge noise is",
        _LEARN_TEST, _LEARN_DOC, (*_BENCH, *FILTER_SETTINGS, *FILTER_STATE), edge_hook=True,
        budgets=(DefaultBudget(
            'edge_noise_estimate_log_scatter', 'ln ratio',
            description=(
                "standard deviation of ln R_theta about each steady phase's mean, polled every 5 ms while the jitter "
                'is steady'
            ),
            **derived('edge_noise_estimate_log_scatter'),  # limit, marginal, limit_source: budget_sources.py
        ),
        DefaultBudget(
            'edge_noise_estimate_log_scatter_low', 'ln ratio',
            kind='min',
            description=(
                "standard deviation of ln R_theta about each steady phase's mean, from below: an estimate of a "
                'random noise that does not move is not estimating it (a frozen R scatters by 0)'
            ),
            **derived('edge_noise_estimate_log_scatter_low'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('noise-learning',),
    ),
    Requirement(
        "REQ-PRED-006",
        "Through the paper's speed steps (its regulation stage), where Eq. 8's current term moves the rotor, the "
        "Sage-Husa predictor commutates closer to the true angle than the constant-speed rule of pre-calibration",
        "`test_sage_husa.py`: the paper scenario's runs of REQ-PRED-001 (Sage-Husa and pre-calibration, same plant "
        "and seed), the commutations of the 0.12 s after each of its six set-point steps (the current-limited "
        "acceleration)",
        "sage-husa.md#the-scenario", (*_BENCH, *FILTER_SETTINGS), edge_hook=True,
        # predictor-model: sage-husa-runs-kf passes (a KF has the same Eq. 8 model); edge-current: the
        # armature correction's current instant does not move the prediction (docs/qualify.md)
        judges=("model-input",),
        checks=(JudgedCheck(
            'commutation_error_growth_with_current', 'deg_e', 'physics',
            "how far Sage-Husa's signed commutation error (against the true angle) moves with the phase current "
            "through the paper scenario: its least-squares slope against the plant's mean |i| at each commutation, "
            "times that current's span (5th to 95th percentile), absolute",
            "0.078 deg e, the paper's calibration repeatability (Table 3; installation_offset_error's source): "
            "the armature term removes the current's shift of the edges to that accuracy and Eq. 8's current term "
            "the load's acceleration, so a correct predictor's error does not move with the current by more",
        ),),
        budgets=(DefaultBudget(
            'sage_husa_over_precalibration_regulation_rms', 'ratio',
            description=(
                "Sage-Husa's commutation angle RMS over the pre-calibration rule's, the 0.12 s after each set-point "
                "step of the paper scenario, same plant and seed"
            ),
            **derived('sage_husa_over_precalibration_regulation_rms'),  # hil/verdicts/budget_sources.py
        ),),
    ),
    Requirement(
        "REQ-PROT-001", "The controller identifies itself (vendor, product, revision, serial, firmware)",
        "`test_protocol.py`: identity read over the link", _CANOPEN_DOC,
        ("identity_vendor", "identity_product", "identity_revision", "identity_serial"),
        judges=('protocol',),
    ),
    Requirement(
        "REQ-PROT-002", "CANopen: heartbeat at the period of 0x1017; EMCY and 0x1001/0x1003 on a fault",
        "`test_protocol.py`: heartbeat against 0x1017, EMCY with 0x1001/0x1003 on a refused calibration",
        _CANOPEN_DOC, ("heartbeat_period", "error_register", "fault_code", *CALIBRATION), fault_source="emcy",
        budgets=(DefaultBudget(
            'heartbeat_period_error', 'fraction',
            description='mean heartbeat period against 0x1017 (CiA 301), relative',
            **derived('heartbeat_period_error'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('protocol', 'fault-handling'),
    ),
    Requirement(
        "REQ-PROT-003", "Bad requests get the standard's answer (SDO abort codes, Modbus exception codes)",
        "`test_protocol.py`: every SDO abort code from the EDS, Modbus exceptions 01/02/03", _CANOPEN_DOC,
        ("strategy",),
        judges=('protocol',),
    ),
    Requirement(
        "REQ-FLT-001", "An illegal Hall code (000/111) raises fault 0xFF01", _FLT_TEST + " (a Hall spike)",
        _CONTROLLER_DOC, ("speed_setpoint",), edge_hook=True, fault_source="any", uses=_BENCH,
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-FLT-002", "A missing edge raises fault 0xFF02", _FLT_TEST + " (a lost edge)",
        _CONTROLLER_DOC, ("speed_setpoint",), edge_hook=True, fault_source="any", uses=_BENCH,
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-FLT-003", "A Hall sensor drop-out is detected as a fault", _FLT_TEST + " (0xFF01 or 0xFF02)",
        _CONTROLLER_DOC, ("speed_setpoint",), edge_hook=True, fault_source="any", uses=_BENCH,
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-FLT-004", "A filter guard trip raises fault 0xFF03", "`test_faults.py`: a forced covariance repair",
        _CONTROLLER_DOC, (*_BENCH, *FILTER_SETTINGS, GUARD_TRIPS), edge_hook=True, fault_source="any",
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-FLT-005", "No fault is raised on a healthy run",
        "`test_faults.py`: a healthy run raises none, on the paper's deviations and on a plant whose calibrated "
        "sectors are as uneven as the effect library's bounds allow (a lost edge told from a neighbouring sector "
        "reads them as lost edges)",
        _CONTROLLER_DOC, ("speed_setpoint",), edge_hook=True, fault_source="any", uses=_BENCH,
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-ROB-001", "Any combination of bounded deviations, once calibrated, meets the commutation budget",
        "`test_fault_injection.py`: hypothesis over deviation sets (`target()` on the p99; 100 examples); the "
        "evidence carries `examples run` and the seed, and a search that ran fewer examples than it claims fails",
        "acceptance.md#findings-and-the-search-bounds", ("speed_setpoint",), edge_hook=True, uses=_BENCH,
        budgets=(DefaultBudget(
            'any_deviations_commutation_angle_p99', 'deg_e',
            description=(
                'p99 commutation angle error, corrected, for any drawn set of calibratable deviations (property '
                'search)'
            ),
            **derived('any_deviations_commutation_angle_p99'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table', 'edge-current'),
    ),
    Requirement(
        "REQ-ROB-002", "Faults switched on and off while running are reported and recovered from",
        "`test_fault_injection.py`: a stateful machine of wiring faults switched on and off (50 sequences)",
        "acceptance.md#findings-and-the-search-bounds", ("speed_setpoint",), edge_hook=True, fault_source="any",
        uses=_BENCH,
        budgets=(DefaultBudget(
            'recovered_commutation_angle_p99', 'deg_e',
            description=(
                'p99 commutation angle error in the 30 ms before the end of a 60 ms recovery window after a wiring '
                'fault'
            ),
            **derived('recovered_commutation_angle_p99'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('fault-handling',),
    ),
    Requirement(
        "REQ-CUR-001", "The phase current stays within the drive's rated current through a set-point step",
        f"`test_current.py`: the controller's own speed loop stepped {_SPEED_STEP} with calibrated commutation; "
        "peak phase current from the plant's true currents",
        _CONTROLLER_DOC, ("speed_setpoint",), edge_hook=True, uses=_BENCH,
        budgets=(DefaultBudget(
            'phase_current_peak_a', 'A',
            description=(
                "peak phase current (plant truth) through a 5000 to 5500 rpm step of the controller's own speed loop:"
                " the smaller of the plant's current-sensor range and switch rating (its TOML's; the paper bench's)"
            ),
            **derived('phase_current_peak_a'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('current-limit',),
    ),
    Requirement(
        "REQ-CUR-002", "Calibrated commutation lowers the mean phase current against raw Hall commutation (paper 4.3)",
        "`test_current.py`: the commutation's effect on the mean phase current, the speed loop taken out: the "
        "controller's calibrated commutation (its errors against the true angle, replayed), raw Hall commutation and "
        "the ideal commutation, each held at the same speed by the bench's own loop on the true speed, at 5000, "
        "5700 and 7000 rpm x 3 seeds, pump load, paper-sized deviations, same plant and seed "
        "(hil.experiments.commutation_current); the controller's own current on its own loop reported",
        "calibration.md#raw-versus-corrected-commutation-paper-section-43", _SPEED_LOOP, edge_hook=True,
        budgets=(DefaultBudget(
            'raw_excess_current_removed', 'fraction',
            kind='min',
            description=(
                "share of raw Hall commutation's excess mean phase current (over the ideal-commutation floor) that "
                "the controller's calibrated commutation removes, every strategy under the bench's loop on the true "
                "speed at the same set point, 5000/5700/7000 rpm x 3 seeds, pump load, paper-sized deviations, "
                "worst case"
            ),
            **derived('raw_excess_current_removed'),  # limit, marginal, limit_source: budget_sources.py
        ),),
        judges=('calibration-table', 'commutation-timing'),
    ),
    Requirement(
        "REQ-SPD-001",
        "The controller's speed loop settles a set-point step the current limit does not bound, without ringing or "
        "chatter, does not wind up through a current-limited step, and rejects a load step",
        "`test_current.py`: the controller's own speed loop stepped 2 % (5000 to 5100 rpm: about 10 A of its 15 A "
        "limit, so the response is the loop's own); overshoot, decay ratio and settling from the plant's true speed "
        "averaged over a turn, the holding current from its true currents; the overshoot once the current limit "
        "releases on REQ-CUR-001's 10 % step; the recovery from a load step (the pump's load torque x1.5 at "
        "5000 rpm) (`hil/experiments/speed_step.py`)",
        "controller.md#the-speed-loop", ("speed_setpoint",), edge_hook=True, uses=_BENCH,
        judges=("speed-loop",),
        budgets=(
            DefaultBudget(
                'speed_step_overshoot', 'fraction',
                description=(
                    'first overshoot of the true speed (averaged over a turn) past the set point of a 2 % set-point '
                    'step, over the step'
                ),
                **derived('speed_step_overshoot'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'speed_step_decay_ratio', 'ratio',
                description=(
                    'second overshoot over the first (same direction, one period of ringing later), 2 % set-point '
                    'step; 0 when the speed does not pass the set point twice by more than 5 % of the step'
                ),
                **derived('speed_step_decay_ratio'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'speed_step_settling_s', 's',
                description=(
                    'time from a 2 % set-point step until the true speed (averaged over a turn) stays within +-10 % '
                    'of the step (inside the overshoot limit)'
                ),
                **derived('speed_step_settling_s'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'speed_hold_current_over_load', 'ratio',
                description=(
                    'mean phase |i| over the last 0.3 s of holding the new set point, over the mean |i| its load '
                    'needs there (physics: fan and friction torque over 2 ke, two phases of three conducting)'
                ),
                **derived('speed_hold_current_over_load'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'speed_limited_step_overshoot', 'fraction',
                description=(
                    'first overshoot of the true speed (averaged over a turn) past the set point of the '
                    'current-limited 10 % step (5000 to 5500 rpm, REQ-CUR-001\'s), over the step: the integral must '
                    'not wind up through the ramp'
                ),
                **derived('speed_limited_step_overshoot'),  # limit, marginal, limit_source: budget_sources.py
            ),
            DefaultBudget(
                'speed_load_step_recovery_s', 's',
                description=(
                    'time from a load step at a held 5000 rpm (the pump\'s load torque x1.5) until the true speed '
                    '(averaged over a turn) stays within 0.2 % of the set point (the settling band\'s width); inf when '
                    'it never returns (no integral action)'
                ),
                **derived('speed_load_step_recovery_s'),  # limit, marginal, limit_source: budget_sources.py
            ),
        ),
    ),
)

_PIL_TEST = ("`test_processor.py`: the paper's deviations calibrated, Sage-Husa at 8000 rpm on the emulated core; "
             "the interrupt schedule's responses, overruns and CPU load, the core's stack and the ELF's sizes")
_PIL_DOC = "processor-in-the-loop.md#requirements-of-the-part"
_REGISTRY += (
    Requirement(
        "REQ-PIL-001", "Every interrupt finishes within its period on the part (no overrun)",
        _PIL_TEST, _PIL_DOC, _BENCH, edge_hook=True, kinds=("pil",), judges=("processor-time",),
        budgets=(
            DefaultBudget('control_isr_response_over_period', 'ratio',
                          description='worst time from a control interrupt\'s request to its return, over the '
                                      'control period (1 / control_hz)',
                          **derived('control_isr_response_over_period')),  # hil/verdicts/budget_sources.py
            DefaultBudget('hall_isr_response_s', 's',
                          description='worst time from a Hall edge to its interrupt\'s return (preemption and '
                                      'waiting included)',
                          **derived('hall_isr_response_s')),  # hil/verdicts/budget_sources.py
            DefaultBudget('compare_isr_response_s', 's',
                          description='worst time from a compare match to its interrupt\'s return',
                          **derived('compare_isr_response_s')),  # hil/verdicts/budget_sources.py
            DefaultBudget('interrupt_overruns', 'count',
                          description='interrupts still running or pending when their own next instance was due',
                          **derived('interrupt_overruns')),  # hil/verdicts/budget_sources.py
        ),
    ),
    Requirement(
        "REQ-PIL-002", "The worst CPU load over the longest interrupt period is within the rate-monotonic bound",
        _PIL_TEST, _PIL_DOC, _BENCH, edge_hook=True, kinds=("pil",), judges=("processor-time",),
        budgets=(DefaultBudget('cpu_load_worst', 'fraction',
                               description='the share of the worst window as long as the longest interrupt period '
                                           '(the Hall interval at top speed) the CPU spent in interrupts',
                               **derived('cpu_load_worst')),),  # hil/verdicts/budget_sources.py
    ),
    Requirement(
        "REQ-PIL-003", "The stack stays within stack_bytes; code and data fit the part's flash and RAM",
        _PIL_TEST, _PIL_DOC, _BENCH, edge_hook=True, kinds=("pil",), judges=("processor-memory",),
        budgets=(
            DefaultBudget('stack_high_water_fraction', 'fraction',
                          description='the deepest stack of any call over stack_bytes',
                          **derived('stack_high_water_fraction')),  # hil/verdicts/budget_sources.py
            DefaultBudget('flash_used_fraction', 'fraction', description='flash used over flash_bytes',
                          **derived('flash_used_fraction')),  # hil/verdicts/budget_sources.py
            DefaultBudget('ram_used_fraction', 'fraction',
                          description='.data, .bss and the main stack over ram_bytes',
                          **derived('ram_used_fraction')),  # hil/verdicts/budget_sources.py
        ),
    ),
)

#: the registry by ID, in the order above; each judged check knows its requirement
REQUIREMENTS: dict[str, Requirement] = {
    r.id: replace(r, checks=tuple(replace(c, requirement=r.id) for c in r.checks)) for r in _REGISTRY}
#: every judged check by name
JUDGED_CHECKS: dict[str, JudgedCheck] = {c.name: c for r in REQUIREMENTS.values() for c in r.checks}


def missing_needs(requirements, has_role, edge_hook: str, fault_sources) -> list[str]:
    """What a device profile lacks for ``requirements`` (``has_role(role)``, its edge hook kind, its
    fault sources), one phrase each; empty when every requirement is testable through it. A
    requirement the registry does not hold (a user's own budget's) needs nothing. ``edge_hook`` is
    the profile's ``[edge_hook] kind``, or ``"pins"`` for a firmware in the loop (its own Hall pins
    close the loop; ``hil.sil``)."""
    out: list[str] = []
    for rid in sorted(set(requirements)):
        if (req := REQUIREMENTS.get(rid)) is None:
            continue
        out += [f"role {r}" for r in req.roles if not has_role(r) and f"role {r}" not in out]
        if req.edge_hook and edge_hook == "none" and "an edge hook" not in out:
            out.append("an edge hook")
        if req.fault_source == "any":
            if not has_role("fault_code") and "emcy" not in fault_sources and "a fault source" not in out:
                out.append("a fault source (the fault_code role or EMCY)")
        elif (req.fault_source and req.fault_source not in fault_sources
              and f"fault source {req.fault_source}" not in out):
            out.append(f"fault source {req.fault_source}")
    return out


# --- the docs' tables -----------------------------------------------------------------------------
DOCS = Path(__file__).resolve().parents[2] / "docs"


def _roles_in_words(roles: tuple[str, ...]) -> str:
    """The roles with each complete group named by its word (``calibration`` for its six roles)."""
    words, left = [], list(roles)
    for word, group in ROLE_GROUPS.items():
        if set(group) <= set(left):
            words.append(word)
            left = [r for r in left if r not in group]
    return ", ".join(words + [f"`{r}`" for r in left])


def _needs_in_words(req: Requirement) -> str:
    parts = [_roles_in_words(req.roles)] if req.roles else []
    parts += ["closed loop (the edge hook, or firmware in the loop)"] if req.edge_hook else []
    parts += (["the fault_code role or EMCY"] if req.fault_source == "any"
              else [f"fault source {req.fault_source}"] if req.fault_source else [])
    parts += [f"uses {_roles_in_words(req.uses)} when present"] if req.uses else []
    parts += [f"a {' or '.join(k + ':' for k in req.kinds)} DUT (other kinds: not applicable)"] if req.kinds else []
    return "; ".join(parts) or "–"


def _bound(b: DefaultBudget) -> str:
    return f"`{b.name}` {'≤' if b.kind == 'max' else '≥'} {b.limit:g} {b.unit}"


def requirements_table() -> str:
    """The requirement table of docs/acceptance.md (markdown), one row per requirement."""
    rows = ["| requirement | what it asks | tested by | default budgets | the defects it judges | "
            "the device profile must offer |",
            "|---|---|---|---|---|---|"]
    for r in REQUIREMENTS.values():
        budgets = "; ".join(_bound(b) for b in r.budgets) or "– (pass or fail)"
        budgets += "".join(f"; judged check `{c.name}` ({c.judgement})" for c in r.checks)
        judges = ", ".join(r.judges) or "–"
        rows.append(f"| [{r.id}]({r.doc}) | {r.statement} | {r.tested_by} | {budgets} | {judges} | "
                    f"{_needs_in_words(r)} |")
    return "\n".join(rows) + "\n"


def budgets_table() -> str:
    """The defaults table of docs/budgets.md (markdown), one row per built-in budget."""
    rows = ["| budget | requirement | kind | limit | marginal from | unit | meaning | limit from |",
            "|---|---|---|---|---|---|---|---|"]
    for r in REQUIREMENTS.values():
        for b in r.budgets:
            marginal = "–" if b.marginal is None else f"{b.marginal:g}"
            rows.append(f"| {b.name} | {r.id} | {b.kind} | {b.limit:g} | {marginal} | {b.unit} | {b.description} | "
                        f"{b.limit_source or 'not stated yet'} |")
    return "\n".join(rows) + "\n"


#: page -> (the generated table's function); the table sits between these two lines of the page
GENERATED = {"acceptance.md": requirements_table, "budgets.md": budgets_table}
BEGIN = ("<!-- generated from hil/verdicts/requirements.py by `python -m hil.verdicts.requirements`: "
         "edit the registry, not this table -->")
END = "<!-- end of the generated table -->"


def rendered(page: str, text: str) -> str:
    """``text`` (the page's content) with its generated table as the registry gives it now."""
    pattern = re.compile(re.escape(BEGIN) + r"\n.*?" + re.escape(END), re.DOTALL)
    if len(pattern.findall(text)) != 1:
        raise ValueError(f"docs/{page}: needs exactly one generated table between the lines {BEGIN!r} and {END!r}")
    return pattern.sub(lambda _: f"{BEGIN}\n{GENERATED[page]()}{END}", text)


def main() -> int:
    """Rewrite the generated tables of the docs in place."""
    for page in GENERATED:
        path = DOCS / page
        text = path.read_text()
        new = rendered(page, text)
        if new != text:
            path.write_text(new)
            print(f"docs/{page}: table rewritten from the registry")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
