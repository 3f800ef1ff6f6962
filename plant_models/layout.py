"""Memory layout shared by the plant's compiled kernel and its sensor layer: the parameter vector,
the float and int state vectors, the edge, ideal-edge and sample records, and the two numba
decorators both use (no reference-counting runtime: see ``_kernel``)."""

from __future__ import annotations

from numba import njit

from ._numba_cache import drop_stale_cache

# before any of the package's numba functions is first called (numba reads its cache then): its
# index stamps the kernel with _kernel.py alone, which inlines sensor.py's and this module's code
drop_stale_cache()

_kernel_jit = njit(cache=True, _nrt=False)
_kernel_inline = njit(cache=True, inline="always", _nrt=False)

# parameter vector layout
P_POLE_PAIRS, P_R, P_L, P_KE, P_FLAT, P_J, P_FRICTION, P_FAN, P_VDC, P_FPWM = range(10)
P_HYST, P_ARM_SLOPE, P_RISE, P_FALL, P_JIT_T, P_JIT_A, P_JIT_RHO, P_TICK = range(10, 18)
P_COG_AMP, P_COG_N, P_COG_PHASE, P_DEAD, P_ISAT, P_LMIN, P_HMAX, P_SAMPLE, P_LATENCY = range(18, 27)
N_PARAMS = 27
#: the parameter vector, declared once: slot <- CompiledPlant field (Simulation packs the plant
#: from this table alone), then the three slots the run itself sets
PLANT_PARAMS = (
    (P_POLE_PAIRS, "pole_pairs"), (P_R, "phase_resistance_ohm"), (P_L, "phase_inductance_h"), (P_KE, "ke_v_s_per_rad"),
    (P_FLAT, "flat_top_deg_e"), (P_J, "inertia_kg_m2"), (P_FRICTION, "friction_n_m_s_per_rad"),
    (P_FAN, "fan_coefficient_n_m_s2"), (P_VDC, "supply_v"), (P_FPWM, "pwm_frequency_hz"), (P_HYST, "hysteresis_deg_e"),
    (P_ARM_SLOPE, "armature_slope_deg_e_per_a"), (P_RISE, "rise_delay_s"), (P_FALL, "fall_delay_s"),
    (P_JIT_T, "jitter_time_rms_s"), (P_JIT_A, "jitter_angle_rms_deg_e"), (P_JIT_RHO, "jitter_correlation"),
    (P_TICK, "timer_tick_s"), (P_COG_AMP, "cogging_amplitude_n_m"), (P_COG_N, "cogging_periods_per_rev"),
    (P_COG_PHASE, "cogging_phase_rad"), (P_DEAD, "dead_time_s"), (P_ISAT, "saturation_current_a"),
    (P_LMIN, "min_inductance_fraction"),
)
RUN_PARAMS = ((P_SAMPLE, "sample_period_s"), (P_HMAX, "max_step_s"), (P_LATENCY, "latency_s"))

# float state layout
S_T, S_THETA_M, S_OMEGA_M, S_IA, S_IB, S_IC, S_DUTY, S_NEXT_SAMPLE = range(8)
S_AR_TIME, S_AR_ANGLE, S_E_IN, S_E_CU, S_E_MECH, S_E_LOAD = range(8, 14)
S_FWD_TARGET = 14  # 3 values: base forward switching angle per sensor (deg_e, unwrapped)
S_REV_TARGET = 17  # 3 values
S_SAMPLE_T0 = 20
S_HELD_ARM = 21  # 3 values: armature shift (deg_e) held by the boundary behind each sensor
#: the last exact current decay exp(-R h / L) and its step h (the kernel's ``_step``), kept in
#: the state so that a run in many calls is the very same run as in one
S_DECAY_H, S_DECAY_A = 24, 25
N_FSTATE = 26

# int state layout
I_SECTOR, I_DIR, I_MODE, I_N_EDGES, I_N_IDEAL, I_N_SAMPLES, I_NOISE = range(7)
I_RAW_REGION = 7  # 3 values
I_IDEAL_REGION = 10  # 3 values
I_N_PENDING, I_ORACLE_N, I_CMD_HEAD, I_CMD_COUNT, I_SAMPLE_K = range(13, 18)
I_SEEN = 18  # 3 values: Hall state as the controller has seen it
I_N_COMM = 21
I_LAST_CROSS = 22  # 3 values: direction of each sensor's last switch (+1, -1; 0 = none yet)
I_RING_N = 25  # phase-current history rows written so far (the MCU ADC's ring, see CURRENT_RING)
N_ISTATE = 26

MODE_EXTERNAL, MODE_RAW_HALL, MODE_ORACLE = 0, 1, 2
#: the inverter's switch state: -1 all open, 0..5 a six-step sector (driven the way I_DIR says),
#: GATE_PATTERN_BASE + g any other gate pattern g of a firmware (bit 2x high switch of phase x,
#: 2x+1 its low switch: hil.sil)
GATE_PATTERN_BASE = 8
STOP_TIME, STOP_EDGE, STOP_FULL, STOP_NOISE = 0, 1, 2, 3

# captured edge record
E_T_CAPTURE, E_T_COND, E_T_RAW, E_SENSOR, E_RISING, E_BOUNDARY, E_DIR = range(7)
E_THETA_RAW, E_THETA_CAPTURE, E_SPEED_RPM, E_CURRENT, E_POLE = range(7, 12)
N_EDGE_COLS = 12
N_IDEAL_COLS = 4  # t, sensor, boundary, direction
# samples
N_SAMPLE_COLS = 15  # t, i_a..c, u_a..c, speed_rpm, theta_m_deg, duty, sector, e_a..c, torque
MAX_PENDING = 32
#: phase-current history: (t, i_a, i_b, i_c) at the start of every accepted step, the last
#: CURRENT_RING of them, from which the controller's ADC window is read (bldc.contract: 104 us
#: before the capture). Steps are at most 2 us in acceptance runs but split at every sample, edge
#: and command: 64 rows spanned as little as 47 us; 512 span at least 190 us
CURRENT_RING = 512
