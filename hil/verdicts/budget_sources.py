"""Where every default budget's limit comes from, computed in one place (docs/budgets.md, "Sources").

Each built-in budget of the requirement registry (``hil.verdicts.requirements``) takes its limit, its
marginal bound and its ``limit_source`` text from :func:`derived`. A derivation is one of:

- ``paper``: a table, section or figure of the paper (Wang, Cheng, Yin, Sensors 2023, 23, 6604,
  DOI 10.3390/s23146604), its value quoted, and the arithmetic from it;
- ``standard``: a clause of a standard;
- ``physics``: stated motor and bench parameters and the arithmetic from them;
- ``example``: no outside source exists. The default is an example for the user's own
  specification and says what it was chosen from; a budgets file (docs/budgets.md, "File
  format") sets the user's value.

No value measured on the built-in controller is an input here. The arithmetic is code, so a
reviewer (and ``tests/test_budget_sources.py``) can recompute every limit from its stated inputs.
History: the "bench specification S1-S6" the earlier defaults cited was written after their values
(unchanged since 40ac7f7); where a value derived here differs from those, the derived one is the
default now (docs/budgets.md, "What changed").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist

KINDS = ("paper", "standard", "physics", "example")

# ---------------------------------------------------------------------------------------------
# Inputs. Each is quoted from where a reviewer finds it without this repository, or is a stated
# bench parameter (the paper bench: plant_models/plant.py, docs/plant.md), or an example choice.

#: paper Section 4.3: "12 discrete steps per 360 deg mechanical angle" (6 per electrical turn), and
#: Section 2.3: 90 deg mechanical between poles: 2 pole pairs
PAPER_POLE_PAIRS = 2
#: paper Sections 4.1 and 4.4: the pump runs 5000-10,000 rpm
PAPER_TOP_SPEED_RPM = 10_000.0
#: square-wave two-phase conduction: a commutation interval is 60 deg e (paper Section 4.3)
INTERVAL_DEG_E = 60.0
#: the paper's percentages of Tables 2 and 4 read as percent of the 60 deg e commutation interval
#: (the paper does not state the base; plant_models/plant.py PAPER_PERCENT_BASE_DEG_E reads it so)
PAPER_PERCENT_BASE_DEG_E = 60.0
#: paper Table 3, correction of the relative deviation of each rising edge (deg, read as electrical:
#: Eq. 1-5 work in electrical angle), at 960 / 1107 / 1330 rpm
PAPER_TABLE3_DEG = {
    "A1": (-0.906, -0.935, -0.980), "B1": (0.031, 0.028, 0.027), "C1": (0.875, 0.933, 0.953),
    "A2": (-0.772, -0.803, -0.819), "B2": (-0.182, -0.193, -0.165), "C2": (0.955, 0.996, 0.985),
}
#: paper Table 3, weighted sums (the corrections applied), A1, B1, C1
PAPER_TABLE3_WEIGHTED_DEG = (-0.930, 0.021, 0.908)
#: paper Table 2, pole offsets (% of the interval) of HallAF1, HallAR1, HallAF2 at 960 / 1107 / 1330 rpm
PAPER_TABLE2_PERCENT = {"AF1": (1.67, 1.54, 1.46), "AR1": (0.03, 0.03, 0.03), "AF2": (0.22, 0.22, 0.23)}
#: paper Table 2, weighted sums
PAPER_TABLE2_WEIGHTED_PERCENT = (1.59, 0.03, 0.22)
#: paper Table 4, weighted sum: HallAR trails the falling E_BC zero crossing by 4.22 % (HallAR1)
PAPER_TABLE4_WEIGHTED_PERCENT = 4.22
#: paper Table 5, "The MAPE of the Commutation Time (%)": 0.0087 / 0.0077 / 0.0066, read as fractions
#: of the commutation interval (0.87 %, 0.77 %, 0.66 %). The column header says "(%)": read literally
#: the figures would be a hundred times smaller (docs/budgets.md says what that would mean).
PAPER_TABLE5_TIME_MAPE = {"pre-calibration": 0.0087, "kf": 0.0077, "sage_husa": 0.0066}
#: paper Table 5, the regulation stage: the speed MAPE through the speed steps, pre-calibration 0.75 %,
#: Sage-Husa 0.37 % (read as fractions)
PAPER_TABLE5_REGULATION_SPEED_MAPE = {"pre-calibration": 0.0075, "sage_husa": 0.0037}
#: paper Section 4.3: "the average current post-calibration stands at a mere 37.2 % of its former value"
PAPER_SEC43_CURRENT_RATIO = 0.372
#: paper Section 4.4: "R_k, r_k and q_k are selected for tracking at intervals of 10 turns (120
#: commutation cycles)": the paper's noise statistics are estimated over 120 edges
PAPER_NOISE_INTERVAL_EDGES = 120
#: paper Table 1: LA25-P measurement range 0-25 A
PAPER_LA25P_RANGE_A = 25.0

#: the paper bench's armature reaction (a stated bench parameter: docs/plant.md, plant_models)
BENCH_ARMATURE_SLOPE_DEG_E_PER_A = 0.35
#: the paper bench's motor (stated bench parameters, docs/plant.md "The paper bench"): fan load
#: coefficient, back-EMF constant and friction, from which the current at a speed follows
BENCH_FAN_COEFFICIENT_N_M_S2 = 1.5e-7
BENCH_KE_V_S_PER_RAD = 0.0216
BENCH_FRICTION_N_M_S_PER_RAD = 1e-5
#: the paper bench's ratings (paper Section 4.1 and Table 1; plant_models.plant defaults): the
#: LA25-P's 0-25 A range, the IPB200N25N3 G switches' 64 A continuous drain current (Infineon datasheet)
PAPER_SWITCH_CURRENT_RATING_A = 64.0
#: statistics conventions (stated, not tuned): a band of three standard errors (99.73 % two-sided
#: for a Gaussian estimate); the p99 of |e| of a zero-mean Gaussian error is z(0.995) sigma
BAND_STANDARD_ERRORS = 3.0
#: the marginal warning of REQ-CAL-005 sits where the residual reaches 0.7 of its RMS allowance (ours)
FRACTION_MARGINAL_SHARE = 0.7
Z_P99_ABS = NormalDist().inv_cdf(0.995)  # 2.5758

#: REQ-PRED-002 (statistics conventions, stated): a Sage-Husa exactly as good as the KF fails one of
#: the requirement's operating profiles by chance in at most 1 % of runs, split evenly over its
#: four profiles (Bonferroni: each profile at 1 % / 4, one-sided)
PRED_002_FALSE_FAIL = 0.01
PRED_002_PROFILES = 4
#: the acceptance design REQ-PRED-002's default limit is stated for (test_cases/test_sage_husa.py):
#: six seeds of the paper's seven set points 5000-10,000 rpm (Section 4.4), 0.4 s judged on each;
#: each profile's own limit is derived for the commutations it actually judged
PRED_002_SEEDS = 6
PRED_002_HOLD_S = 0.4
PAPER_SETPOINTS_RPM = tuple(5000.0 + 5000.0 * i / 6 for i in range(7))
#: C. L. Liu and J. W. Layland, "Scheduling Algorithms for Multiprogramming in a Hard-Real-Time
#: Environment", J. ACM 20(1), 46-61 (1973): a periodic task's deadline is its next request (the end
#: of its period), and n tasks under rate-monotonic priorities all meet their deadlines when their
#: utilisation is at most n (2^(1/n) - 1) (their Theorem 5). The hil-sil/1 interrupts are three tasks:
#: the Hall capture, the compare unit, the control interrupt
RM_TASKS = 3
#: a Hall sensor set gives six edges per electrical turn (three sensors, two edges each)
HALL_EDGES_PER_TURN_E = 6

#: example choices (no outside source; the user's own specification sets these)
EXAMPLE_TORQUE_RIPPLE_ALLOWANCE = 0.01  # from commutation timing: chosen in the earlier S1, cited nothing
EXAMPLE_EXCESS_CURRENT_REMOVED = 0.5  # of raw Hall commutation's excess current, the speed loop taken out


# ---------------------------------------------------------------------------------------------
# Arithmetic, one function per derived quantity (the tests recompute them by hand)


def electrical_deg_per_s(rpm: float, pole_pairs: int) -> float:
    return rpm / 60.0 * 360.0 * pole_pairs


def commutation_error_for_ripple(ripple: float) -> float:
    """A commutation delta deg e early or late, in a trapezoidal machine with a 120 deg e flat top,
    puts one phase delta deg e onto its back-EMF ramp at the sector's edge: the line EMF, and the
    torque at constant current, dips by delta / 60 there. The delta a peak-ripple share allows."""
    return ripple * INTERVAL_DEG_E


def mean_phase_current_a(rpm: float) -> float:
    """The mean |i| over the three phases holding ``rpm`` against the paper pump's fan load (torque
    balance of six-step commutation, bldc.motor.steady_state): two phases carry I = T / (2 ke) on
    their flat tops, the third none, so the mean over three is 2 I / 3."""
    w = rpm / 60.0 * 2.0 * math.pi
    torque = BENCH_FAN_COEFFICIENT_N_M_S2 * w * w + BENCH_FRICTION_N_M_S_PER_RAD * w
    return 2.0 / 3.0 * torque / (2.0 * BENCH_KE_V_S_PER_RAD)


def current_limit_a(sensor_range_a: float, switch_rating_a: float) -> float:
    """The phase current a controller may not exceed: the smaller of what its current sensors can
    see (beyond their range the current is not measured, so not controlled) and what its switches
    are rated to carry."""
    return min(sensor_range_a, switch_rating_a)


def current_limit_for(range_a: float, switch_rating_a: float, where: str = "the paper bench") -> "Derivation":
    """REQ-CUR-001's peak-current limit for a plant's ratings (its TOML's ``current_sensor.range_a``
    and ``inverter.switch_current_rating_a``; the paper bench's by default)."""
    limit = current_limit_a(range_a, switch_rating_a)
    return _d(
        "phase_current_peak_a", "physics",
        f"the ratings of {where}: current sensors measuring 0-{range_a:g} A (the paper bench's LA25-P, paper "
        f"Table 1), switches rated {switch_rating_a:g} A continuous (the paper bench's IPB200N25N3 G, Infineon "
        "datasheet); a current beyond the sensors' range is not seen, so not controlled",
        f"min({range_a:g} A, {switch_rating_a:g} A) = {limit:g} A", limit, 0.9 * limit,
        sensor_range_a=range_a, switch_rating_a=switch_rating_a)


def paper_profile_commutations() -> int:
    """The commutations REQ-PRED-002's paper profile judges at most, by its design: six edges per
    electrical turn at each set point, held 0.4 s, over six seeds (the rotor reaches a set point
    after a while at the current limit, so a run judges fewer: each profile's own count sets its
    limit, ``sage_husa_over_kf_limit_for``)."""
    per_seed = sum(rpm / 60.0 * 6 * PAPER_POLE_PAIRS * PRED_002_HOLD_S for rpm in PAPER_SETPOINTS_RPM)
    return int(round(PRED_002_SEEDS * per_seed))


def ratio_allowance(commutations: int, profiles: int = PRED_002_PROFILES,
                    false_fail: float = PRED_002_FALSE_FAIL) -> float:
    """The sampling error allowed on a ratio of two commutation-error RMS values, each over
    ``commutations`` errors: the RMS of n independent zero-mean Gaussian errors has a relative
    standard error of 1 / sqrt(2 n) (var(s^2) = 2 sigma^4 / n, halved for the root); the ratio of two
    independent ones sqrt(1 / (2 n) + 1 / (2 n)) = 1 / sqrt(n). A one-step predictor's errors are
    independent from edge to edge when it is optimal (its innovations are white: Kailath 1968), and
    the two filters' errors on one run share the edges' noise, which can only shrink the ratio's
    error, so this is at most its sampling error. z: one-sided, ``false_fail`` shared by ``profiles``."""
    z = NormalDist().inv_cdf(1.0 - false_fail / profiles)
    return z / math.sqrt(commutations)


def sage_husa_over_kf_limit_for(commutations: int, where: str = "the paper profile's by design") -> "Derivation":
    """REQ-PRED-002's limit on one operating profile whose Sage-Husa and KF runs each judged
    ``commutations`` commutations: no worse than the KF (the paper's claim, Table 5) beyond the
    ratio's own sampling error (``ratio_allowance``)."""
    allowance = ratio_allowance(commutations)
    z = NormalDist().inv_cdf(1.0 - PRED_002_FALSE_FAIL / PRED_002_PROFILES)
    mape = PAPER_TABLE5_TIME_MAPE
    return _d(
        "sage_husa_over_kf_angle_rms", "paper",
        f"Table 5: Sage-Husa's commutation time MAPE {mape['sage_husa']} against the KF's {mape['kf']} "
        f"({mape['sage_husa'] / mape['kf']:.3f}; Section 4.4: 14.7 % better): the method is no worse than the KF. "
        "Plus the ratio's sampling error: the RMS of n independent Gaussian errors has a relative standard error "
        "1 / sqrt(2 n), a ratio of two 1 / sqrt(n); one-sided, a 1 % chance of a false fail shared by the "
        f"requirement's {PRED_002_PROFILES} profiles; n = {commutations} commutations ({where})",
        f"1 + {z:.3f} / sqrt({commutations}) = {1.0 + allowance:.4f}", 1.0 + allowance, 1.0,
        paper_ratio=mape["sage_husa"] / mape["kf"], commutations=commutations, z=z,
        false_fail=PRED_002_FALSE_FAIL, profiles=PRED_002_PROFILES, was=1.05)


def spread(values) -> float:
    return max(values) - min(values)


def table3_repeatability_deg_e() -> float:
    """The largest speed-to-speed spread of one edge's correction in Table 3 (C1: 0.875-0.953)."""
    return max(spread(v) for v in PAPER_TABLE3_DEG.values())


def table2_repeatability_deg_e() -> float:
    """The largest speed-to-speed spread of one pole edge's offset in Table 2 (AF1: 1.46-1.67 %)."""
    return max(spread(v) for v in PAPER_TABLE2_PERCENT.values()) / 100.0 * PAPER_PERCENT_BASE_DEG_E


def paper_raw_edge_errors_deg_e() -> list[float]:
    """Raw Hall commutation's error of every rising edge over a mechanical turn from the paper's
    Tables 2-4 (the time-independent deviations: installation, Eq. 5, and poles, Eq. 6)."""
    absolute = PAPER_TABLE4_WEIGHTED_PERCENT / 100.0 * PAPER_PERCENT_BASE_DEG_E
    install = [absolute + r - PAPER_TABLE3_WEIGHTED_DEG[0] for r in PAPER_TABLE3_WEIGHTED_DEG]
    poles = [0.0] + [-p / 100.0 * PAPER_PERCENT_BASE_DEG_E for p in PAPER_TABLE2_WEIGHTED_PERCENT]
    return [i + p for p in poles for i in install]


def liu_layland_bound(n: int) -> float:
    """Liu and Layland's least upper bound of the utilisation of n rate-monotonic tasks (Theorem 5)."""
    return n * (2.0 ** (1.0 / n) - 1.0)


def min_hall_interval_s(rpm: float, pole_pairs: int) -> float:
    """The shortest interval between two Hall edges (of any sensor) at ``rpm``: 60 / (rpm p 6)."""
    return 60.0 / (rpm * pole_pairs * HALL_EDGES_PER_TURN_E)


def rms(values) -> float:
    values = list(values)
    return math.sqrt(sum(v * v for v in values) / len(values))


def log_band() -> float:
    """Three relative standard errors of a variance estimated from the paper's 120 edges, in ln."""
    return BAND_STANDARD_ERRORS * math.sqrt(2.0 / PAPER_NOISE_INTERVAL_EDGES)


# ---------------------------------------------------------------------------------------------

def fraction_removed_for(raw_rms_deg_e: float, budget: str = "calibrated_fraction_removed",
                         raw_what: str = "the raw RMS the scenario's injected deviations put on its edges (the "
                                         "plant's truth table over the judged edges, Eq. 1-8)",
                         was: float | None = None) -> "Derivation":
    """REQ-CAL-005's limit for a scenario whose edges carry ``raw_rms_deg_e`` of deviation: the
    commutation limit as an RMS (a zero-mean Gaussian residual has p99 |e| = z sigma) left over from
    that raw RMS. The share removed that a calibration meeting the commutation limit reaches depends
    on how much there was to remove: a limit derived once for the paper's 3.30 deg e would ask a
    0.45 deg e scenario to remove more than the commutation limit requires."""
    comm = commutation_error_for_ripple(EXAMPLE_TORQUE_RIPPLE_ALLOWANCE)  # 0.6 deg e
    sigma = comm / Z_P99_ABS
    fraction = max(0.0, 1.0 - sigma / raw_rms_deg_e)
    marginal = 1.0 - FRACTION_MARGINAL_SHARE * sigma / raw_rms_deg_e
    return _d(
        budget, "physics",
        "the commutation limit (0.6 deg e, a p99) as an RMS: a zero-mean Gaussian residual has p99 |e| = 2.576 "
        f"sigma, so sigma <= {sigma:.3f} deg e; {raw_what} is {raw_rms_deg_e:.3f} deg e",
        f"1 - ({comm:g} / {Z_P99_ABS:.3f}) / {raw_rms_deg_e:.3f} = {fraction:.3f} of the raw RMS removed (at least 0; "
        "the earlier 0.9 compared an RMS with the p99 limit)", fraction, max(fraction, marginal), was=was,
        p99_limit_deg_e=comm, z_p99=Z_P99_ABS, raw_rms_deg_e=raw_rms_deg_e)


@dataclass(frozen=True)
class Derivation:
    """One budget's limit: ``kind`` (KINDS), ``cite`` (where a reviewer checks it), ``inputs``
    (name -> value, each named above), ``arithmetic`` (the formula in words), ``limit`` (computed)
    and the marginal bound (ours: a warning inside the limit, never a limit)."""

    budget: str
    kind: str
    cite: str
    arithmetic: str
    limit: float
    marginal: float | None
    inputs: dict = field(default_factory=dict)
    was: float | None = None  #: the default before this derivation (40ac7f7 .. 8b4eb4e), where it differs

    @property
    def source(self) -> str:
        head = {"paper": "paper", "standard": "standard", "physics": "physics",
                "example": "example for your own specification"}[self.kind]
        return f"{head}: {self.cite}; {self.arithmetic}"


def _d(budget, kind, cite, arithmetic, limit, marginal, was=None, **inputs) -> Derivation:
    return Derivation(budget, kind, cite, arithmetic, float(limit), marginal, dict(inputs), was)


def _derivations() -> list[Derivation]:
    out: list[Derivation] = []
    w_top = electrical_deg_per_s(PAPER_TOP_SPEED_RPM, PAPER_POLE_PAIRS)  # 120,000 deg e/s
    comm = commutation_error_for_ripple(EXAMPLE_TORQUE_RIPPLE_ALLOWANCE)  # 0.6 deg e
    out.append(_d(
        "commutation_angle_p99", "example",
        "a torque-ripple allowance of 1 % from commutation timing (chosen in the earlier spec S1; no outside "
        "source: set your pump's). Physics: a commutation delta deg e off puts one phase delta onto its "
        "back-EMF ramp at the sector's edge, a torque dip of delta / 60 deg e",
        "60 deg e x 0.01 = 0.6 deg e", comm, 0.4, was=0.5,
        ripple_allowance=EXAMPLE_TORQUE_RIPPLE_ALLOWANCE, interval_deg_e=INTERVAL_DEG_E))
    common = out[-1]  # one definition: the single-deviation scenarios take it as it is
    for deviation in ("installation", "pole", "conditioning_delay", "armature_reaction"):
        # REQ-CAL-001..004: REQ-COMM-001's limit on the scenario in which that deviation alone is calibrated
        out.append(_d(
            f"{deviation}_corrected_angle_p99", common.kind, common.cite, common.arithmetic, common.limit,
            common.marginal, was=common.was, **common.inputs))

    cal = table3_repeatability_deg_e()  # 0.078 deg e
    out.append(_d(
        "installation_offset_error", "paper",
        "Table 3: the paper's own installation corrections repeat across its three calibration speeds within "
        "0.078 deg (C1: 0.875, 0.933, 0.953; read as electrical, as Eq. 1-5)",
        "a calibration at least as repeatable as the paper's: error <= the largest speed-to-speed spread of an "
        "edge's correction, 0.953 - 0.875 = 0.078 deg e", cal, 0.04, was=0.05,
        table3_deg=PAPER_TABLE3_DEG))
    pole = table2_repeatability_deg_e()  # 0.126 deg e
    out.append(_d(
        "pole_offset_error", "paper",
        "Table 2: the paper's pole offsets repeat across its three calibration speeds within 0.21 % (HallAF1: "
        "1.67, 1.54, 1.46 %), of the 60 deg e interval",
        "error <= the largest spread, (1.67 - 1.46) % x 60 deg e = 0.126 deg e", pole, 0.04, was=0.05,
        table2_percent=PAPER_TABLE2_PERCENT, percent_base_deg_e=PAPER_PERCENT_BASE_DEG_E))
    out.append(_d(
        "conditioning_delay_error", "physics",
        "the installation offset's paper repeatability (0.078 deg e, Table 3) as a time at the paper's top "
        "speed, 10,000 rpm, 2 pole pairs (Sections 4.1, 4.3)",
        "w_e = 10,000 / 60 x 360 x 2 = 120,000 deg e/s; 0.078 / 120,000 = 0.65 us", cal / w_top, 4e-7, was=5e-7,
        angle_deg_e=cal, top_speed_rpm=PAPER_TOP_SPEED_RPM, pole_pairs=PAPER_POLE_PAIRS))
    top_current_a = mean_phase_current_a(PAPER_TOP_SPEED_RPM)  # 2.70 A
    slope_current = BENCH_ARMATURE_SLOPE_DEG_E_PER_A * top_current_a
    out.append(_d(
        "armature_slope_error", "physics",
        "the installation offset's paper repeatability (0.078 deg e, Table 3) as a share of the paper bench's "
        f"armature offset at top speed: 0.35 deg e/A at {top_current_a:.2f} A, the mean phase current at 10,000 "
        "rpm against the pump's fan load (torque balance from the stated bench parameters, docs/plant.md: "
        "T = 1.5e-7 w^2 + 1e-5 w N m, I = T / (2 ke), ke = 0.0216 V s/rad; two of three phases conduct, "
        "mean |i| = 2 I / 3)",
        f"0.078 / (0.35 x {top_current_a:.2f}) = {cal / slope_current:.4f}", cal / slope_current, 0.04, was=0.0796,
        angle_deg_e=cal, slope_deg_e_per_a=BENCH_ARMATURE_SLOPE_DEG_E_PER_A, current_a=top_current_a))

    out.append(fraction_removed_for(rms(paper_raw_edge_errors_deg_e()), "calibrated_fraction_removed", (
        "the raw RMS of the paper's installation and pole deviations (Tables 2-4 through Eq. 5-6, every rising "
        "edge over a turn)"), was=0.9))

    mape_sh = PAPER_TABLE5_TIME_MAPE["sage_husa"]
    mae_deg = mape_sh * INTERVAL_DEG_E
    sigma_sh = mae_deg * math.sqrt(math.pi / 2.0)
    out.append(_d(
        "sage_husa_commutation_angle_rms", "paper",
        "Table 5: Sage-Husa's commutation time MAPE 0.0066 of the interval, through the paper's speed steps",
        "mean |e| = 0.0066 x 60 = 0.396 deg e; a zero-mean Gaussian error has RMS = mean |e| x sqrt(pi / 2) "
        f"= {sigma_sh:.3f} deg e", sigma_sh, 0.8 * sigma_sh, was=1.0, mape=mape_sh,
        interval_deg_e=INTERVAL_DEG_E))
    out.append(_d(
        "sage_husa_commutation_angle_p99", "paper",
        "Table 5: Sage-Husa's commutation time MAPE 0.0066 of the interval",
        f"as the RMS budget, sigma = {sigma_sh:.3f} deg e; p99 |e| = 2.576 sigma = {Z_P99_ABS * sigma_sh:.2f} deg e",
        Z_P99_ABS * sigma_sh, 0.8 * Z_P99_ABS * sigma_sh, was=2.5, mape=mape_sh, z_p99=Z_P99_ABS))
    for name in ("sage_husa_commutation_time_mape", "commutation_time_mape"):
        out.append(_d(
            name, "paper",
            "Table 5: MAPE of the commutation time, Sage-Husa 0.0066 (KF 0.0077, pre-calibration 0.0087)",
            "the Sage-Husa predictor at least as accurate as the paper's: 0.0066 = 0.66 % of the interval",
            mape_sh * 100.0, 0.5, was=1.0, mape=mape_sh))
    out.append(sage_husa_over_kf_limit_for(paper_profile_commutations()))
    reg = PAPER_TABLE5_REGULATION_SPEED_MAPE
    out.append(_d(
        "sage_husa_over_precalibration_regulation_rms", "paper",
        "Table 5, the regulation stage: Sage-Husa's speed MAPE 0.37 % against pre-calibration's 0.75 %",
        "0.37 / 0.75 = 0.49 (to two places)", round(reg["sage_husa"] / reg["pre-calibration"], 2), 0.4,
        sage_husa=reg["sage_husa"], pre_calibration=reg["pre-calibration"]))

    band = log_band()
    out.append(_d(
        "edge_noise_estimate_low", "paper",
        "Section 4.4: the paper estimates its noise statistics over 120 commutation cycles (10 turns); a variance "
        "from n samples has a relative standard error sqrt(2 / n); a band of three standard errors",
        f"exp(-3 sqrt(2 / 120)) = {math.exp(-band):.3f}", math.exp(-band), 1.0 - 0.5 * (1.0 - math.exp(-band)),
        was=0.5, n=PAPER_NOISE_INTERVAL_EDGES, standard_errors=BAND_STANDARD_ERRORS))
    out.append(_d(
        "edge_noise_estimate_high", "paper",
        "Section 4.4 (as edge_noise_estimate_low)",
        f"exp(+3 sqrt(2 / 120)) = {math.exp(band):.3f}", math.exp(band), 1.0 + 0.5 * (math.exp(band) - 1.0),
        was=2.0, n=PAPER_NOISE_INTERVAL_EDGES, standard_errors=BAND_STANDARD_ERRORS))
    out.append(_d(
        "edge_noise_estimate_log_scatter", "paper",
        "Section 4.4: noise statistics over 120 commutation cycles; the standard deviation of ln of a variance "
        "from n Gaussian samples is sqrt(2 / n)",
        f"sqrt(2 / 120) = {math.sqrt(2.0 / PAPER_NOISE_INTERVAL_EDGES):.3f}",
        math.sqrt(2.0 / PAPER_NOISE_INTERVAL_EDGES), 0.8 * math.sqrt(2.0 / PAPER_NOISE_INTERVAL_EDGES), was=0.26,
        n=PAPER_NOISE_INTERVAL_EDGES))
    steady_edges = round(8000.0 / 60.0 * 6 * PAPER_POLE_PAIRS * 0.4)  # 640
    out.append(_d(
        "edge_noise_estimate_log_scatter_low", "physics",
        "a variance estimated from at most the 640 edges of a steady 0.4 s phase at 8000 rpm, 2 pole pairs "
        "(8000 / 60 x 12 x 0.4) scatters by sqrt(2 / 640) = 0.056 in ln; a frozen estimate scatters by 0; the "
        "limit, half of it, is ours (a longer memory could not track a step within REQ-PRED-004)",
        "sqrt(2 / 640) / 2 = 0.028", round(math.sqrt(2.0 / steady_edges) / 2.0, 3), 0.035,
        edges=steady_edges, rpm=8000.0, phase_s=0.4, pole_pairs=PAPER_POLE_PAIRS))
    out.append(_d(
        "edge_noise_tracking_edges", "paper",
        "Section 4.4: noise statistics re-estimated every 120 commutation cycles; after a step of the noise, "
        "the window that straddles it ends within 120 edges and the next, all after the step, within 240",
        "2 x 120 = 240 edges", 2 * PAPER_NOISE_INTERVAL_EDGES, 0.8 * 2 * PAPER_NOISE_INTERVAL_EDGES, was=100,
        n=PAPER_NOISE_INTERVAL_EDGES))
    out.append(_d(
        "learned_edge_noise_ratio", "example",
        "chosen (earlier, for a start 100x wrong) as a factor 4 below the truth, twice the earlier [0.5, 2] band "
        "in ln; no outside source",
        "1 / 4 = 0.25", 0.25, 0.5, factor=4.0))
    out.append(_d(
        "learned_edge_noise_ratio_high", "example",
        "chosen as learned_edge_noise_ratio, from the upper side (a runaway estimate grows past it): within a "
        "factor 4 of the truth; no outside source",
        "1 / 0.25 = 4", 4.0, 2.0, factor=4.0))

    out.append(_d(
        "heartbeat_period_error", "example",
        "CiA 301 defines the producer heartbeat time (object 0x1017) but no tolerance on it; chosen so that a "
        "consumer set to 1.1x the period keeps half of its 10 % margin for one period's jitter",
        "(1.1 - 1) / 2 = 0.05", (1.1 - 1.0) / 2.0, 0.03, consumer_factor=1.1))
    for name, scenario in (
        ("any_deviations_commutation_angle_p99",
         "any calibrated deviation set within the effect library's physical bounds"),
        ("recovered_commutation_angle_p99",
         "the 30 ms that end a 60 ms recovery after a wiring fault (recovered: the machine runs as before it)"),
    ):
        # REQ-ROB-001/002: the machine the calibration or the recovery leaves runs under the same torque-ripple
        # allowance as the paper scenario's (REQ-COMM-001): the limit is the same, not a multiple of it
        out.append(_d(
            name, common.kind, f"{common.cite}; applied to {scenario}", common.arithmetic, common.limit,
            common.marginal, was=1.0, **common.inputs))
    out.append(current_limit_for(PAPER_LA25P_RANGE_A, PAPER_SWITCH_CURRENT_RATING_A))
    out.append(_d(
        "raw_excess_current_removed", "example",
        "chosen: calibrated commutation removes at least half of the excess mean phase current that raw Hall "
        "commutation costs over the ideal commutation, every strategy held at the same speed by the bench's own "
        "loop on the true speed (no outside source: set your pump's). The paper's Section 4.3 figure (the current "
        "fell to 37.2 %) is of its whole controller, each strategy on its own speed measurement: a speed loop fed "
        "by uneven sectors, not only the commutation, and so not a limit for this quantity (docs/budgets.md)",
        "1 / 2 of raw Hall commutation's excess removed", EXAMPLE_EXCESS_CURRENT_REMOVED, 0.6, was=0.944,
        paper_ratio_whole_controller=PAPER_SEC43_CURRENT_RATIO))
    zn_decay = 0.25  # Ziegler and Nichols (1942): quarter-amplitude decay
    out.append(_d(
        "speed_step_overshoot", "example",
        "chosen from Ziegler and Nichols (1942), quarter-amplitude decay: a second-order loop whose decay ratio "
        "is 1/4 overshoots by sqrt(1/4) = 0.5 of the step (a 2 % step the current limit does not bound)",
        "sqrt(0.25) = 0.5 of the step", math.sqrt(zn_decay), 0.45, decay_ratio=zn_decay))
    out.append(_d(
        "speed_step_decay_ratio", "example",
        "chosen from Ziegler and Nichols (1942): quarter-amplitude decay, the classic limit of ringing",
        "1 / 4 = 0.25", zn_decay, 0.2, decay_ratio=zn_decay))
    out.append(_d(
        "speed_step_settling_s", "example",
        "chosen (earlier spec S6) from the US DOE's automotive fuel-cell system transient target (10-90 % of "
        "rated power in 1 s; DOE Hydrogen and Fuel Cell Technologies Office, fuel cell technical targets): "
        "the pump follows the stack within the stack's transient. The target is outside; its use as a "
        "settling time into +-10 % of a 2 % step is ours", "1 s", 1.0, 0.8, doe_transient_s=1.0))
    out.append(_d(
        "speed_limited_step_overshoot", "example",
        "the same Ziegler and Nichols (1942) bound as the small step's, on the current-limited 10 % step once the "
        "limit releases: a loop whose integral winds up through the ramp overshoots by most of the step",
        "sqrt(0.25) = 0.5 of the step", math.sqrt(zn_decay), 0.45, decay_ratio=zn_decay))
    out.append(_d(
        "speed_load_step_recovery_s", "example",
        "the same 1 s as the step's settling time (chosen from the US DOE's fuel-cell system transient target, "
        "10-90 % of rated power in 1 s), for the speed to return within the settling band's width (0.2 % of the "
        "set point) after the pump's load torque steps to 1.5 times its own", "1 s", 1.0, 0.8,
        doe_transient_s=1.0))
    out.append(_d(
        "speed_hold_current_over_load", "example",
        "the mean phase current holding the new set point over the current its load needs there (the "
        "denominator is physics from the motor parameters: fan and friction torque over 2 ke, 0.74 A per phase "
        "at 5100 rpm on the paper pump); a quarter more current is 56 % more copper loss",
        "1 + 0.25 = 1.25 (1.25^2 = 1.56)", 1.25, 1.15, allowance=0.25))
    out += _processor_derivations()
    return out


def _processor_derivations() -> list[Derivation]:
    """The part's requirements (REQ-PIL-*, processor in the loop): deadlines, load, memory."""
    out: list[Derivation] = []
    hall_s = min_hall_interval_s(PAPER_TOP_SPEED_RPM, PAPER_POLE_PAIRS)  # 0.5 ms
    for kind, why in (("hall", "the Hall capture interrupt"),
                      ("compare", "the compare interrupt (one commutation per Hall interval)")):
        out.append(_d(
            f"{kind}_isr_response_s", "physics",
            f"{why} finishes before the next Hall edge can come: the shortest Hall interval at the paper's top "
            "speed, 10,000 rpm with 2 pole pairs (Sections 4.1, 4.3), six edges per electrical turn; a deadline at "
            "the next request as Liu and Layland (J. ACM 20(1), 1973) define it",
            "60 / (10,000 x 2 x 6) = 0.5 ms from the event to the return", hall_s, 0.8 * hall_s,
            top_speed_rpm=PAPER_TOP_SPEED_RPM, pole_pairs=PAPER_POLE_PAIRS, edges_per_turn=HALL_EDGES_PER_TURN_E))
    out.append(_d(
        "control_isr_response_over_period", "physics",
        "the control interrupt finishes before its next request: Liu and Layland (J. ACM 20(1), 1973), Section 3, "
        "a periodic task's deadline is the end of its period (1 / control_hz, the firmware's own rate)",
        "worst (return - event) / (1 / control_hz) <= 1", 1.0, 0.8))
    out.append(_d(
        "interrupt_overruns", "physics",
        "an interrupt still running or pending when its own next instance is due has missed the deadline Liu "
        "and Layland (J. ACM 20(1), 1973) set at the next request",
        "no overrun: 0", 0.0, None))
    bound = liu_layland_bound(RM_TASKS)
    out.append(_d(
        "cpu_load_worst", "physics",
        "Liu and Layland (J. ACM 20(1), 1973), Theorem 5: n periodic tasks under rate-monotonic priorities meet "
        "every deadline when their utilisation is at most n (2^(1/n) - 1); the hil-sil/1 interrupts are n = 3 "
        "tasks (Hall capture, compare, control)",
        f"3 x (2^(1/3) - 1) = {bound:.4f} of the CPU: the busy share of the worst window as long as the set's "
        "longest period (the Hall edge interval at the plant's top speed, 60 / (rpm x pole pairs x 6); a "
        "window of one control period that one Hall interrupt fills is busy under any schedule)",
        bound, 0.8 * bound,
        tasks=RM_TASKS))
    for name, what, marginal in (
        ("stack_high_water_fraction", "the deepest stack of any call over the part's main stack (stack_bytes)", 0.75),
        ("flash_used_fraction", "the ELF's code and constants over the part's flash (flash_bytes)", 0.9),
        ("ram_used_fraction", "the ELF's .data and .bss plus the main stack over the part's RAM (ram_bytes)", 0.9),
    ):
        out.append(_d(
            name, "physics",
            f"{what}: the part's memory map as its datasheet gives it, declared in the firmware's [target] table; "
            "beyond it the stack writes into the data below it, the code does not fit",
            "used / available <= 1", 1.0, marginal))
    return out


DERIVATIONS: dict[str, Derivation] = {d.budget: d for d in _derivations()}


def derived(budget: str) -> dict:
    """The registry's keyword arguments for ``budget``: limit, marginal, limit_source."""
    try:
        d = DERIVATIONS[budget]
    except KeyError:
        raise KeyError(f"no derivation for the default budget {budget!r}: add it to hil/verdicts/budget_sources.py "
                       "(docs/budgets.md, 'Sources')") from None
    return {"limit": d.limit, "marginal": d.marginal, "limit_source": d.source}
