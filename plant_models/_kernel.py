"""Numba kernel of the electrical plant: six-step inverter, star-connected BLDC, rotor, Hall layer.

Integration: each phase current is advanced with the exact solution of L di/dt = v - R i for
the step's (held) terminal, neutral and back-EMF voltages; the rotor with constant acceleration
over the step, so the angle is an exact quadratic inside it. Events that change the physics or
what an observer sees (a commutation boundary of the oracle, a captured Hall edge) are located
inside a trial step, and the step is cut back to end exactly on them: edges are exact roots of
the angle equation, never rounded to the step.

Speed: the step loop allocates nothing and is compiled without numba's reference-counting
runtime (``_nrt=False``, the ``_kernel_jit`` decorator below). With it, numba wrapped every
array argument, view and row in atomic increments and decrements that were about a third of the
step's cost and kept LLVM from holding the state in registers; the one allocation, the step
loop's scratch, is made once per :func:`run` call by that thin wrapper.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bldc.hall import (
    BEMF_ZERO_DEG_E,
    SECTOR_HIGH_PHASE,
    SECTOR_LOW_PHASE,
    SECTOR_OF_CODE,
    SENSOR_POSITION_DEG_E,
    trapezoid,
)
from bldc.units import rad_per_s_to_rpm

from .layout import (
    CURRENT_RING,
    I_RING_N,
    E_BOUNDARY,
    E_CURRENT,
    E_DIR,
    E_POLE,
    E_RISING,
    E_SENSOR,
    E_SPEED_RPM,
    E_T_CAPTURE,
    E_T_COND,
    E_T_RAW,
    E_THETA_CAPTURE,
    E_THETA_RAW,
    I_CMD_COUNT,
    I_CMD_HEAD,
    I_DIR,
    I_IDEAL_REGION,
    I_MODE,
    I_N_COMM,
    GATE_PATTERN_BASE,
    I_N_EDGES,
    I_N_IDEAL,
    I_N_PENDING,
    I_N_SAMPLES,
    I_NOISE,
    I_ORACLE_N,
    I_RAW_REGION,
    I_SAMPLE_K,
    I_SECTOR,
    I_SEEN,
    MAX_PENDING,
    MODE_EXTERNAL,
    MODE_ORACLE,
    MODE_RAW_HALL,
    N_EDGE_COLS,
    N_FSTATE,
    P_COG_AMP,
    P_COG_N,
    P_COG_PHASE,
    P_DEAD,
    P_FAN,
    P_FLAT,
    P_FPWM,
    P_FRICTION,
    P_HMAX,
    P_ISAT,
    P_J,
    P_KE,
    P_L,
    P_LATENCY,
    P_LMIN,
    P_POLE_PAIRS,
    P_R,
    P_SAMPLE,
    P_TICK,
    P_VDC,
    S_DECAY_A,
    S_DECAY_H,
    S_DUTY,
    S_E_CU,
    S_E_IN,
    S_E_LOAD,
    S_E_MECH,
    S_IA,
    S_IB,
    S_IC,
    S_NEXT_SAMPLE,
    S_OMEGA_M,
    S_SAMPLE_T0,
    S_T,
    S_THETA_M,
    STOP_EDGE,
    STOP_FULL,
    STOP_NOISE,
    STOP_TIME,
    _kernel_inline,
    _kernel_jit,
)
from .sensor import (
    armature_shift,
    crossing_direction,
    edge_emit_time,
    hold_crossing,
    pending_of,
    sensor_crossing,
    set_targets,
)

RAD2DEG = 180.0 / math.pi

# every function the step loop calls: no allocation, no reference counting (module docstring)


_trap = _kernel_inline(trapezoid)
_rad_per_s_to_rpm = _kernel_inline(rad_per_s_to_rpm)


@_kernel_inline
def _root(th0, w0, acc, target, h):
    """Time tau in [0, h] at which th0 + w0 tau + acc tau^2 / 2 reaches target (stable form)."""
    d = target - th0
    disc = w0 * w0 + 2.0 * acc * d
    if disc < 0.0:
        disc = 0.0
    sgn = 1.0 if (w0 > 0.0 or (w0 == 0.0 and d > 0.0)) else -1.0
    den = w0 + sgn * math.sqrt(disc)
    tau = 2.0 * d / den if den != 0.0 else 0.0
    if tau < 0.0:
        tau = 0.0
    if tau > h:
        tau = h
    return tau


@_kernel_inline
def _commutate(p, st, ist, out_comm, sector):
    """Switch to ``sector``, logging (t, sector, true theta_e) when it changes."""
    if sector == ist[I_SECTOR]:
        return
    ist[I_SECTOR] = sector
    n = ist[I_N_COMM]
    if n < out_comm.shape[0]:
        out_comm[n, 0] = st[S_T]
        out_comm[n, 1] = sector
        out_comm[n, 2] = p[P_POLE_PAIRS] * st[S_THETA_M] * RAD2DEG
        out_comm[n, 3] = ist[I_DIR]
        ist[I_N_COMM] = n + 1


@_kernel_inline
def _voltages(p, i, e, sector, drive_dir, duty, u, driven):
    """Terminal voltages u (to ground) and the neutral voltage for the present switch state.

    driven[x] = 1: PWM or low switch sets u; 2: diode-clamped by its own current; 0: open.
    """
    vdc = p[P_VDC]
    for x in range(3):
        driven[x] = 0
    if sector >= GATE_PATTERN_BASE:
        # a gate pattern as a firmware sets it (hil.sil): bit 2x the high switch of phase x,
        # chopped at the duty, bit 2x+1 its low switch on; a leg with neither floats. Both
        # switches of one leg are refused before they reach the plant (hil.sil.peripherals)
        gates = sector - GATE_PATTERN_BASE
        for x in range(3):
            if gates & (1 << (2 * x)):
                d = duty - p[P_DEAD] * p[P_FPWM] * (1.0 if i[x] >= 0.0 else -1.0)
                u[x] = min(max(d, 0.0), 1.0) * vdc
                driven[x] = 1
            elif gates & (2 << (2 * x)):
                u[x] = 0.0
                driven[x] = 1
    elif sector >= 0:
        hi = SECTOR_HIGH_PHASE[sector]
        lo = SECTOR_LOW_PHASE[sector]
        if drive_dir < 0:
            hi, lo = lo, hi
        d = duty - p[P_DEAD] * p[P_FPWM] * (1.0 if i[hi] >= 0.0 else -1.0)
        d = min(max(d, 0.0), 1.0)
        u[hi] = d * vdc
        u[lo] = 0.0
        driven[hi] = 1
        driven[lo] = 1
    for x in range(3):
        if driven[x] == 0 and i[x] != 0.0:
            driven[x] = 2
            u[x] = 0.0 if i[x] > 0.0 else vdc
    for _ in range(2):
        n_d = 0
        s = 0.0
        for x in range(3):
            if driven[x] != 0:
                n_d += 1
                s += u[x] - e[x]
        if n_d >= 2:
            un = s / n_d
        elif n_d == 1:
            un = s
        else:
            un = -(e[0] + e[1] + e[2]) / 3.0
        changed = False
        for x in range(3):
            if driven[x] == 0:
                v_open = un + e[x]
                if v_open > vdc and n_d >= 1:
                    driven[x] = 2
                    u[x] = vdc
                    changed = True
                elif v_open < 0.0 and n_d >= 1:
                    driven[x] = 2
                    u[x] = 0.0
                    changed = True
                else:
                    u[x] = v_open
        if not changed:
            return un
    return un


@_kernel_inline
def _step(p, st, ist, h, tmp_u, tmp_d, out_u, out_e, out_te, wk):
    """Advance currents and rotor by h with inputs held over the step; ``wk`` is scratch (12)."""
    pp = p[P_POLE_PAIRS]
    theta_m = st[S_THETA_M]
    w0 = st[S_OMEGA_M]
    # back-EMF shape at the step midpoint (second order in h; holding the start value lags
    # the whole electrical model by half a step)
    the = pp * (theta_m + 0.5 * h * w0) * RAD2DEG
    ke = p[P_KE]
    i = wk[0:3]
    f = wk[3:6]
    e = wk[6:9]
    i1 = wk[9:12]
    i[0] = st[S_IA]
    i[1] = st[S_IB]
    i[2] = st[S_IC]
    for x in range(3):
        f[x] = _trap(the - BEMF_ZERO_DEG_E[x], p[P_FLAT])
        e[x] = ke * w0 * f[x]
    sector = ist[I_SECTOR]
    un = _voltages(p, i, e, sector, ist[I_DIR], st[S_DUTY], tmp_u, tmp_d)
    R = p[P_R]
    saturating = p[P_LMIN] < 1.0
    # shared decay unless saturation makes L differ per phase; most steps are h_max long, so
    # the last exact decay is kept (S_DECAY_H, S_DECAY_A) instead of calling exp on every step (56 ns,
    # a third of a step). A step that ends on a sample is h_max only to within a few ulps (the
    # sample instant minus the accumulated time), so a step within 1e-10 h of the kept one takes
    # exp(-R h / L) = a_kept exp(-R dh / L) = a_kept (1 - R dh / L): the next term, (R dh / L)^2 / 2,
    # is at most 5e-21 (R h / L)^2 of a, under a double's resolution for any step shorter than
    # a hundred electrical time constants
    # (R and L are fixed for a simulation's life: p is packed once, in Simulation.__init__)
    a = 0.0
    if not saturating:
        dh = h - st[S_DECAY_H]
        if abs(dh) <= 1e-10 * h:
            a = st[S_DECAY_A] * (1.0 - R * dh / p[P_L])
        else:
            a = math.exp(-R * h / p[P_L])
            st[S_DECAY_H] = h
            st[S_DECAY_A] = a
    for x in range(3):
        if tmp_d[x] == 0:
            i1[x] = 0.0
            continue
        if saturating:
            L = p[P_L] * max(p[P_LMIN], 1.0 / (1.0 + (i[x] / p[P_ISAT]) ** 2))
            a = math.exp(-R * h / L)
        v = tmp_u[x] - un - e[x]
        i1[x] = v / R + (i[x] - v / R) * a
    # a diode-clamped phase whose current reached zero opens; keep sum(i) = 0
    for x in range(3):
        if tmp_d[x] == 2 and i1[x] * i[x] < 0.0:
            i1[x] = 0.0
    s = i1[0] + i1[1] + i1[2]
    if s != 0.0:
        cnt = 0
        for x in range(3):
            if i1[x] != 0.0:
                cnt += 1
        for x in range(3):
            if i1[x] != 0.0:
                i1[x] -= s / cnt
    te = 0.0
    e_in = 0.0
    e_cu = 0.0
    for x in range(3):
        ia = 0.5 * (i[x] + i1[x])
        te += ke * f[x] * ia
        e_in += tmp_u[x] * ia
        e_cu += R * (i[x] * i[x] + i[x] * i1[x] + i1[x] * i1[x]) / 3.0
    t_load = p[P_FAN] * w0 * abs(w0) + p[P_FRICTION] * w0
    if p[P_COG_AMP] != 0.0:
        # at the step midpoint, like the back-EMF: the start angle lags the torque by half a step
        t_load += p[P_COG_AMP] * math.sin(p[P_COG_N] * (theta_m + 0.5 * h * w0) + p[P_COG_PHASE])
    w1 = w0 + h * (te - t_load) / p[P_J]
    st[S_OMEGA_M] = w1
    st[S_THETA_M] = theta_m + 0.5 * h * (w0 + w1)
    st[S_IA] = i1[0]
    st[S_IB] = i1[1]
    st[S_IC] = i1[2]
    st[S_T] += h
    wa = 0.5 * (w0 + w1)
    st[S_E_IN] += h * e_in
    st[S_E_CU] += h * e_cu
    st[S_E_MECH] += h * te * wa
    st[S_E_LOAD] += h * t_load * wa
    for x in range(3):
        out_u[x] = tmp_u[x]
        out_e[x] = e[x]
    out_te[0] = te
    return w0, w1


# step-loop scratch (float): the trial step's starting state, then small per-phase vectors
W_BACKUP = 0
W_U, W_U_NOW, W_E_NOW = N_FSTATE, N_FSTATE + 3, N_FSTATE + 6
W_TE, W_I3, W_STEP = N_FSTATE + 9, N_FSTATE + 10, N_FSTATE + 13
W_CROSS = W_STEP + 12  # 3 x (direction, switching angle, rate) of the trial step's sensor crossings
N_WORK = W_CROSS + 9


@njit(cache=True)
def run(
    p, st, ist, switch_off, arm_i, arm_deg, noise, cmds, pending, out_edges, out_ideal, out_samples, out_comm,
    current_ring, t_stop
):
    """Advance the plant to t_stop; stop early on a captured edge (external mode) or a full buffer."""
    return _advance(p, st, ist, switch_off, arm_i, arm_deg, noise, cmds, pending, out_edges, out_ideal, out_samples,
                    out_comm, current_ring, t_stop, np.zeros(N_WORK), np.zeros(3, dtype=np.int64))


@_kernel_jit
def _advance(p, st, ist, switch_off, arm_i, arm_deg, noise, cmds, pending, out_edges, out_ideal, out_samples, out_comm,
             current_ring, t_stop, work, tmp_d):
    """:func:`run`'s step loop, on the scratch ``work`` (N_WORK floats) and ``tmp_d`` (3 ints)."""
    pp = p[P_POLE_PAIRS]
    n_poles = switch_off.shape[1]
    h_max = p[P_HMAX]
    backup = work[W_BACKUP:W_BACKUP + N_FSTATE]
    tmp_u = work[W_U:W_U + 3]
    u_now = work[W_U_NOW:W_U_NOW + 3]
    e_now = work[W_E_NOW:W_E_NOW + 3]
    te_now = work[W_TE:W_TE + 1]
    i3 = work[W_I3:W_I3 + 3]
    wk = work[W_STEP:W_STEP + 12]
    crossing = work[W_CROSS:W_CROSS + 9]
    mode = ist[I_MODE]
    while True:
        t = st[S_T]
        # the phase currents' recent history (CURRENT_RING rows), from which the controller's ADC
        # window is read before each capture (Simulation.adc_conversions)
        ring_n = ist[I_RING_N]
        k = ring_n & (CURRENT_RING - 1)  # CURRENT_RING is a power of two
        if ring_n == 0 or current_ring[(ring_n - 1) & (CURRENT_RING - 1), 0] < t:
            current_ring[k, 0] = t
            current_ring[k, 1] = st[S_IA]
            current_ring[k, 2] = st[S_IB]
            current_ring[k, 3] = st[S_IC]
            ist[I_RING_N] = ring_n + 1
        # apply due commands
        while ist[I_CMD_HEAD] < ist[I_CMD_COUNT] and cmds[ist[I_CMD_HEAD], 0] <= t + 1e-12:
            c = ist[I_CMD_HEAD]
            if cmds[c, 3] != 0.0:
                ist[I_DIR] = int(cmds[c, 3])
            if cmds[c, 1] >= -1.0:
                _commutate(p, st, ist, out_comm, int(cmds[c, 1]))
            if cmds[c, 2] >= 0.0:
                st[S_DUTY] = cmds[c, 2]
            ist[I_CMD_HEAD] = c + 1
        # emit due captured edges
        stop_edge = False
        while ist[I_N_PENDING] > 0:
            j = 0
            for q in range(1, ist[I_N_PENDING]):
                if pending[q, E_T_CAPTURE] < pending[j, E_T_CAPTURE]:
                    j = q
            if pending[j, E_T_CAPTURE] > t + 1e-12:
                break
            if ist[I_N_EDGES] >= out_edges.shape[0]:
                return STOP_FULL
            row = out_edges[ist[I_N_EDGES]]
            for c in range(N_EDGE_COLS):
                row[c] = pending[j, c]
            # pending[...,E_T_CAPTURE] held the emission time; restore the timer's view
            t_cond = pending[j, E_T_COND]
            row[E_T_CAPTURE] = math.floor(t_cond / p[P_TICK]) * p[P_TICK] if p[P_TICK] > 0.0 else t_cond
            # a capture that jitter placed before the physical switch is emitted at the switch
            # (causality); its true angle is the rotor's at the capture instant, not now
            row[E_THETA_CAPTURE] = pp * (st[S_THETA_M] - st[S_OMEGA_M] * (t - t_cond)) * RAD2DEG
            row[E_SPEED_RPM] = _rad_per_s_to_rpm(st[S_OMEGA_M])
            ist[I_N_EDGES] += 1
            x = int(row[E_SENSOR])
            ist[I_SEEN + x] = 1 if row[E_RISING] > 0.5 else 0
            last = ist[I_N_PENDING] - 1
            for c in range(N_EDGE_COLS):
                pending[j, c] = pending[last, c]
            ist[I_N_PENDING] = last
            if mode == MODE_RAW_HALL:
                code = ist[I_SEEN] * 4 + ist[I_SEEN + 1] * 2 + ist[I_SEEN + 2]
                s = SECTOR_OF_CODE[code]
                if s >= 0:
                    if p[P_LATENCY] > 0.0:
                        k = ist[I_CMD_COUNT]
                        if k < cmds.shape[0]:
                            cmds[k, 0] = t + p[P_LATENCY]
                            cmds[k, 1] = s
                            cmds[k, 2] = -1.0
                            cmds[k, 3] = 0.0
                            ist[I_CMD_COUNT] = k + 1
                    else:
                        _commutate(p, st, ist, out_comm, s)
            elif mode == MODE_EXTERNAL:
                stop_edge = True
        # samples
        if t >= st[S_NEXT_SAMPLE] - 1e-13:
            if ist[I_N_SAMPLES] >= out_samples.shape[0]:
                return STOP_FULL
            the = pp * st[S_THETA_M] * RAD2DEG
            i3[0] = st[S_IA]
            i3[1] = st[S_IB]
            i3[2] = st[S_IC]
            te = 0.0
            for x in range(3):
                f = _trap(the - BEMF_ZERO_DEG_E[x], p[P_FLAT])
                e_now[x] = p[P_KE] * st[S_OMEGA_M] * f
                te += p[P_KE] * f * i3[x]
            _voltages(p, i3, e_now, ist[I_SECTOR], ist[I_DIR], st[S_DUTY], u_now, tmp_d)
            r = out_samples[ist[I_N_SAMPLES]]
            r[0] = t
            r[1] = i3[0]
            r[2] = i3[1]
            r[3] = i3[2]
            r[4] = u_now[0]
            r[5] = u_now[1]
            r[6] = u_now[2]
            r[7] = _rad_per_s_to_rpm(st[S_OMEGA_M])
            r[8] = st[S_THETA_M] * RAD2DEG
            r[9] = st[S_DUTY]
            r[10] = ist[I_SECTOR]
            r[11] = e_now[0]
            r[12] = e_now[1]
            r[13] = e_now[2]
            r[14] = te
            ist[I_N_SAMPLES] += 1
            ist[I_SAMPLE_K] += 1
            st[S_NEXT_SAMPLE] = st[S_SAMPLE_T0] + ist[I_SAMPLE_K] * p[P_SAMPLE]
        if stop_edge:
            return STOP_EDGE
        if t >= t_stop - 1e-15:
            return STOP_TIME
        if ist[I_N_IDEAL] >= out_ideal.shape[0] or ist[I_N_COMM] >= out_comm.shape[0]:
            return STOP_FULL
        # step length: never past a known event
        h = min(h_max, t_stop - t, st[S_NEXT_SAMPLE] - t)
        if ist[I_CMD_HEAD] < ist[I_CMD_COUNT]:
            h = min(h, cmds[ist[I_CMD_HEAD], 0] - t)
        for q in range(ist[I_N_PENDING]):
            h = min(h, pending[q, E_T_CAPTURE] - t)
        if h < 1e-13:
            h = 1e-13
        # (the integer state is not backed up: a step moves only the float state)
        for c in range(N_FSTATE):
            backup[c] = st[c]
        w0, w1 = _step(p, st, ist, h, tmp_u, tmp_d, u_now, e_now, te_now, wk)
        # first unknown event inside the trial step: oracle boundary or an edge emission
        th0 = pp * backup[S_THETA_M] * RAD2DEG
        th1 = pp * st[S_THETA_M] * RAD2DEG
        we0 = pp * w0 * RAD2DEG
        acc = pp * (w1 - w0) / h * RAD2DEG
        # an angle is "reached" within the rotation of 0.1 ns: a step cut back to an event is
        # re-integrated over the shorter span and may end a few nano-degrees short of it, and
        # steps are never cut below 0.1 ns, so without this margin the event would be committed
        # one full step late (its time exact, but the rotor's angle at emission not)
        # The margin applies in the direction of motion only; against it a crossing must be
        # strict, or an edge just committed would flip straight back (both targets coincide
        # when there is no hysteresis).
        eps_deg = 1e-9 + abs(we0) * 1e-10
        eps_f = eps_deg if we0 >= 0.0 else -1e-9
        eps_r = eps_deg if we0 < 0.0 else -1e-9
        t_event = st[S_T]
        if mode == MODE_ORACLE:
            n = ist[I_ORACLE_N]
            d = crossing_direction(th1, 60.0 * (n + 1), 60.0 * n, eps_f, eps_r)
            if d > 0 and th0 < 60.0 * (n + 1) - eps_f:
                t_event = min(t_event, backup[S_T] + _root(th0, we0, acc, 60.0 * (n + 1), h))
            elif d < 0:
                t_event = min(t_event, backup[S_T] + _root(th0, we0, acc, 60.0 * n, h))
        # mean |i| and the armature shift run linearly over the trial step; a step cut back to
        # an event keeps this trial's line, so it sees the switching angle the trial located
        i_start = (abs(backup[S_IA]) + abs(backup[S_IB]) + abs(backup[S_IC])) / 3.0
        i_rate = ((abs(st[S_IA]) + abs(st[S_IB]) + abs(st[S_IC])) / 3.0 - i_start) / h
        arm0 = armature_shift(p, ist, arm_i, arm_deg, i_start)
        arm_rate = (armature_shift(p, ist, arm_i, arm_deg, i_start + i_rate * h) - arm0) / h
        for x in range(3):
            d, target, rate = sensor_crossing(p, st, ist, x, th1, arm0, arm_rate, h, eps_f, eps_r)
            # kept for the commit below, which sees the same crossing unless the step is cut
            crossing[3 * x], crossing[3 * x + 1], crossing[3 * x + 2] = d, target, rate
            if d == 0:
                continue
            t_raw = backup[S_T] + _root(th0, we0 - rate, acc, target, h)
            rising = (ist[I_RAW_REGION + x] + d) % 2 == 0
            t_cond, t_emit = edge_emit_time(p, st, ist, noise, t_raw, rising, True)
            t_event = min(t_event, t_emit)
        # (a cut never shrinks a step below 0.1 ns, so a pathological event cannot stall the
        # loop; edge times stay exact roots either way)
        cut = t_event < st[S_T] - 1e-13 and t_event - backup[S_T] >= 1e-10
        if cut:
            for c in range(N_FSTATE):
                st[c] = backup[c]
            h = t_event - backup[S_T]
            if h < 1e-13:
                h = 1e-13
            w0, w1 = _step(p, st, ist, h, tmp_u, tmp_d, u_now, e_now, te_now, wk)
            th1 = pp * st[S_THETA_M] * RAD2DEG
            acc = pp * (w1 - w0) / h * RAD2DEG
        t0 = backup[S_T]
        # commit: oracle sector
        if mode == MODE_ORACLE:
            n = ist[I_ORACLE_N]
            n += crossing_direction(th1, 60.0 * (n + 1), 60.0 * n, eps_f, eps_r)
            ist[I_ORACLE_N] = n
            _commutate(p, st, ist, out_comm, n % 6)
        # commit: ideal edges (perfect sensor, perfect magnet)
        for x in range(3):
            m = ist[I_IDEAL_REGION + x]
            tf = 180.0 * (m + 1) + SENSOR_POSITION_DEG_E[x]
            trv = 180.0 * m + SENSOR_POSITION_DEG_E[x]
            d = crossing_direction(th1, tf, trv, eps_f, eps_r)
            if d == 0:
                continue
            k = m + 1 if d > 0 else m
            target = tf if d > 0 else trv
            ist[I_IDEAL_REGION + x] = m + d
            r = out_ideal[ist[I_N_IDEAL]]
            r[0] = t0 + _root(th0, we0, acc, target, h)
            r[1] = x
            r[2] = k
            r[3] = d
            ist[I_N_IDEAL] += 1
        # commit: raw sensor edges into the pending queue
        for x in range(3):
            if cut:
                d, target, rate = sensor_crossing(p, st, ist, x, th1, arm0, arm_rate, h, eps_f, eps_r)
            else:  # sensor x's switching angles and last crossing are as the trial saw them
                d, target, rate = int(crossing[3 * x]), crossing[3 * x + 1], crossing[3 * x + 2]
            if d == 0:
                continue
            tau = _root(th0, we0 - rate, acc, target, h)
            target += rate * tau
            hold_crossing(st, ist, x, d, arm0 + arm_rate * tau)
            m = ist[I_RAW_REGION + x]
            k = m + 1 if d > 0 else m
            ist[I_RAW_REGION + x] = m + d
            rising = ist[I_RAW_REGION + x] % 2 == 0
            t_raw = t0 + tau
            t_cond, t_emit = edge_emit_time(p, st, ist, noise, t_raw, rising, False)
            set_targets(p, st, ist, switch_off, noise, x, d)
            # the conditioning circuit is a state (its capacitor), not a delay per edge: a raw
            # pulse that ends before the capacitor crossed the MCU threshold never reaches the
            # MCU, and its end does not either (inertial delay). Delayed independently, the two
            # could swap places (rise and fall delays far apart) and the MCU would see the same
            # level twice.
            q = pending_of(pending, ist, x)
            if q >= 0:
                last = ist[I_N_PENDING] - 1
                for c in range(N_EDGE_COLS):
                    pending[q, c] = pending[last, c]
                ist[I_N_PENDING] = last
                continue
            q = ist[I_N_PENDING]
            if q >= MAX_PENDING:
                return STOP_FULL
            r = pending[q]
            r[E_T_CAPTURE] = t_emit
            r[E_T_COND] = t_cond
            r[E_T_RAW] = t_raw
            r[E_SENSOR] = x
            r[E_RISING] = 1.0 if rising else 0.0
            r[E_BOUNDARY] = k
            r[E_DIR] = d
            r[E_THETA_RAW] = target
            r[E_CURRENT] = i_start + i_rate * tau
            r[E_POLE] = k % n_poles
            ist[I_N_PENDING] = q + 1
        if ist[I_NOISE] > noise.size - 64:
            return STOP_NOISE
