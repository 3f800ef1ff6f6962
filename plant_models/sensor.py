"""The Hall sensor layer of the plant: where each sensor output switches, and when the MCU sees it.

Compiled with numba and inlined into the kernel's step loop (``_kernel``); everything here acts
on the kernel's state vectors (``layout``).

Where: the switching angle of sensor x around its region (``set_targets``) is its position
(``bldc.hall``) plus the installation, pole and field-model offsets and angle jitter; hysteresis
opens a band around it and armature reaction moves it with the current (``sensor_crossing``,
``hold_crossing``). When: the conditioning circuit delays each edge inertially (a pulse shorter
than the delay never arrives, ``pending_of``) and adds time jitter (``edge_emit_time``).
"""

from __future__ import annotations

import math

from bldc.hall import SENSOR_POSITION_DEG_E

from .layout import (
    E_SENSOR,
    I_DIR,
    I_LAST_CROSS,
    I_N_PENDING,
    I_NOISE,
    I_RAW_REGION,
    P_ARM_SLOPE,
    P_FALL,
    P_HYST,
    P_JIT_A,
    P_JIT_RHO,
    P_JIT_T,
    P_RISE,
    S_AR_ANGLE,
    S_AR_TIME,
    S_FWD_TARGET,
    S_HELD_ARM,
    S_REV_TARGET,
    _kernel_inline,
    _kernel_jit,
)


#: the largest armature-reaction shift of a switching angle, deg e (the bound of
#: ``ArmatureReaction``'s table too). The shift is the turn of the field the sensor sees, the
#: magnet's plus the armature's, so it grows with the current only while the armature field is
#: small beside the magnet's and can never pass the armature field's own direction; the linear
#: form saturates at the library's bound instead of carrying a 2 deg e/A slope to 1000 deg e at
#: the 500 A a stalled commutation drives through the plant's windings (that moved the edges on,
#: the commutation after them, and the current further up: a runaway no sensor has)
ARMATURE_SHIFT_LIMIT_DEG_E = 30.0


@_kernel_inline
def _armature(p, arm_i, arm_deg, current):
    if arm_i.size > 0:
        return _interp(current, arm_i, arm_deg)
    return min(max(p[P_ARM_SLOPE] * current, -ARMATURE_SHIFT_LIMIT_DEG_E), ARMATURE_SHIFT_LIMIT_DEG_E)


@_kernel_inline
def _interp(x, xp, fp):
    """np.interp for one point (xp increasing, >= 2 points), without its array allocation:
    numba's own np.interp allocates its result even for a scalar. Same arithmetic, same
    result bit for bit (NumPy's arr_interp: clamped ends, exact at a table point, the slope
    taken from the other end of the interval if the first gives NaN)."""
    n = xp.size
    if math.isnan(x):
        return x
    if x < xp[0]:
        return fp[0]
    if x > xp[n - 1]:
        return fp[n - 1]
    j = 0
    while j < n - 1 and xp[j + 1] <= x:
        j += 1
    if j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    y = slope * (x - xp[j]) + fp[j]
    if math.isnan(y):
        y = slope * (x - xp[j + 1]) + fp[j + 1]
        if math.isnan(y) and fp[j] == fp[j + 1]:
            y = fp[j]
    return y


@_kernel_jit
def _draw(st, ist, noise, slot, rms, rho):
    """One sample of a stationary AR(1) process with RMS ``rms`` (white when rho = 0)."""
    if rms == 0.0:
        return 0.0
    k = ist[I_NOISE]
    w = noise[k % noise.size]
    ist[I_NOISE] = k + 1
    x = rho * st[slot] + math.sqrt(1.0 - rho * rho) * w
    st[slot] = x
    return rms * x


@_kernel_jit
def set_targets(p, st, ist, switch_off, noise, x, crossed=0):
    """Base switching angles of sensor x around its current region, from the switching-angle
    table ``switch_off[sensor, pole, 0 forward / 1 reverse]`` (installation and pole offsets and
    the field-level sensor model, CompiledPlant.switch_table_deg_e), plus angle jitter.

    ``crossed`` = +1 (-1): the sensor has just entered this region forward (backward), so the
    boundary behind it is the one it crossed, at the angle it crossed it: the field is the same
    field, and its angle noise has not moved in between. A fresh draw there would put the way
    back in front of the rotor half the time, and the sensor would flip back at once. Both
    sides are still drawn, so the noise stream, and every run that never turns back, stays the
    same whichever way the last crossing went.
    """
    m = ist[I_RAW_REGION + x]
    n_poles = switch_off.shape[1]
    kf = m + 1
    km = m
    base = SENSOR_POSITION_DEG_E[x]
    kept = st[S_FWD_TARGET + x] if crossed > 0 else st[S_REV_TARGET + x]
    st[S_FWD_TARGET + x] = (
        180.0 * kf + base + switch_off[x, kf % n_poles, 0] + _draw(st, ist, noise, S_AR_ANGLE, p[P_JIT_A], p[P_JIT_RHO])
    )
    st[S_REV_TARGET + x] = (
        180.0 * km + base + switch_off[x, km % n_poles, 1] + _draw(st, ist, noise, S_AR_ANGLE, p[P_JIT_A], p[P_JIT_RHO])
    )
    if crossed > 0:
        st[S_REV_TARGET + x] = kept
    elif crossed < 0:
        st[S_FWD_TARGET + x] = kept


@_kernel_inline
def armature_shift(p, ist, arm_i, arm_deg, current):
    """Armature-reaction shift of the Hall switching angles at mean |i| = ``current`` (deg e).

    Its sign follows the torque (the stator MMF reverses with the drive direction), so a
    positive slope lags in motoring whichever way the rotor turns."""
    return ist[I_DIR] * _armature(p, arm_i, arm_deg, current)


@_kernel_inline
def crossing_direction(th1, ahead, behind, eps_f, eps_r):
    """+1 if the rotor, now at th1 (deg e), has reached the angle ``ahead``, -1 if it has fallen
    back to ``behind``, else 0: the one crossing test of the kernel (oracle sectors, ideal and
    raw Hall edges). The margins ``eps_f``/``eps_r`` are positive in the direction of motion
    and negative against it (see the step loop)."""
    if th1 >= ahead - eps_f:
        return 1
    if th1 <= behind + eps_r:
        return -1
    return 0


@_kernel_inline
def sensor_crossing(p, st, ist, x, th1, arm0, arm_rate, h, eps_f, eps_r):
    """Whether the rotor, at th1 (deg e) after a step of h seconds, has switched sensor x.

    Returns (+1 forward, -1 backward or 0; the switching angle at the step start; its rate in
    deg e/s over the step). The one place the raw Hall outputs switch. ``arm0`` is the armature
    shift at the step start and ``arm_rate`` its rate over the step (the current's, taken
    linear within the step): an edge sits at the current of its own instant, not at the
    current of the step it fell in.

    The hysteresis opens a band around the switching point: forward the rotor must pass it by
    the hysteresis, backward fall short of it by as much, so the band is never negative. The
    armature reaction is the edge's lag at the current of its edge, not a band: it moves the
    switching point ahead of the sensor with the current, while the boundary the sensor has just
    crossed stays where it was crossed (``S_HELD_ARM``), so the way back is the crossing angle
    less twice the hysteresis. (Applied like the hysteresis, in whichever way the rotor
    crosses, a leading shift made the band negative and the sensor flipped back on every step
    after an edge; applied to both sides live, a current that moves faster than the rotor
    after a commutation dragged the boundary just crossed back over the rotor.)
    """
    last = ist[I_LAST_CROSS + x]
    if last < 0:
        lag_f, rate_f = p[P_HYST] + st[S_HELD_ARM + x], 0.0
    else:
        lag_f, rate_f = p[P_HYST] + arm0, arm_rate
    if last > 0:
        lag_r, rate_r = p[P_HYST] - st[S_HELD_ARM + x], 0.0
    else:
        lag_r, rate_r = p[P_HYST] - arm0, arm_rate
    # the switching angles at the step's end, the lag moving at its rate over the step
    ahead = st[S_FWD_TARGET + x] + (lag_f + rate_f * h)
    behind = st[S_REV_TARGET + x] - (lag_r - rate_r * h)
    d = crossing_direction(th1, ahead, behind, eps_f, eps_r)
    if d > 0:
        return 1, st[S_FWD_TARGET + x] + lag_f, rate_f
    if d < 0:
        return -1, st[S_REV_TARGET + x] - lag_r, rate_r
    return 0, 0.0, 0.0


@_kernel_inline
def hold_crossing(st, ist, x, d, arm):
    """Sensor x has just switched going ``d`` (present armature shift ``arm``): the boundary
    behind it keeps the shift it was crossed with."""
    if d * ist[I_LAST_CROSS + x] >= 0:  # crossed on the live side (the held one is behind)
        st[S_HELD_ARM + x] = arm
    ist[I_LAST_CROSS + x] = d


@_kernel_jit
def edge_emit_time(p, st, ist, noise, t_raw, rising, peek):
    delay = p[P_RISE] if rising else p[P_FALL]
    jitter = 0.0
    if p[P_JIT_T] > 0.0:
        if peek:
            k = ist[I_NOISE]
            rho = p[P_JIT_RHO]
            jitter = p[P_JIT_T] * (rho * st[S_AR_TIME] + math.sqrt(1.0 - rho * rho) * noise[k % noise.size])
        else:
            jitter = _draw(st, ist, noise, S_AR_TIME, p[P_JIT_T], p[P_JIT_RHO])
    t_cond = t_raw + delay + jitter
    return t_cond, max(t_cond, t_raw)


@_kernel_inline
def pending_of(pending, ist, x):
    """Row of sensor x's edge still on its way through the conditioning circuit, or -1."""
    for q in range(ist[I_N_PENDING]):
        if pending[q, E_SENSOR] == x:
            return q
    return -1
