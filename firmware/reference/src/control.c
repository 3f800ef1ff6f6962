/* control.c: the reference firmware's control logic, a port of the built-in Python controller
   (hil/controller/virtual.py VirtualController.capture, hil/controller/commutation.py
   HallCommutation.on_edge and SpeedPI, hil/controller/adc.py). Times are 64-bit tick counts of the
   capture timer, extended in software from the free-running counter every interrupt sees;
   intervals are differences of those (modular in the counter's width). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "board.h"
#include "calib.h"
#include "control.h"
#include "defects.h"
#include "faults.h"
#include "filter.h"
#include "fw_config.h"
#include "hil_sil_util.h"
#include "nvm.h"
#ifdef FW_DEBUG
#include <stdio.h>
#endif

/* ---- Hall geometry and the six-step table (bldc/hall.py; the tables are hil_sil_util.h's) ------- */
static const float SENSOR_POSITION_DEG_E[3] = {0.0f, 120.0f, 240.0f};

static int sector_of_bits(const uint8_t bits[3])
{
    return HIL_SECTOR_OF_CODE[(bits[0] << 2) | (bits[1] << 1) | bits[2]];
}

static int mod_int(int32_t a, int32_t m)
{
    int32_t r = a % m;
    return (int)(r < 0 ? r + m : r);
}

/* ---- time base: the counter extended to 64 bits ----------------------------------------------- */
static int64_t tb_ticks;
static uint32_t tb_last;
static uint8_t tb_valid;

/* the 64-bit time of a counter value: the last one seen plus the counter's step since, taken
   modulo the width and signed (a capture latched a little before the last interrupt's count is a
   little in the past, not a wrap ahead); the clock advances to the newest count */
static int64_t tb_advance(uint32_t count)
{
    int64_t delta, t;
    count &= TIMER_MASK;
    if (!tb_valid) {
        tb_valid = 1u;
        tb_ticks = (int64_t)count; /* ticks since the timer started */
        tb_last = count;
    }
#if defined(HIL_DEFECT_TIMER_WRAP)
    delta = (int64_t)count - (int64_t)tb_last; /* not modular: a wrap steps back 2^bits */
    t = tb_ticks + delta;
    if (delta > 0 || delta <= -(int64_t)TIMER_HALF) {
        tb_ticks = t;
        tb_last = count;
    }
#else
    {
        uint32_t d = (count - tb_last) & TIMER_MASK;
        delta = d >= TIMER_HALF ? (int64_t)d - (int64_t)TIMER_MASK - 1 : (int64_t)d;
    }
    t = tb_ticks + delta;
    if (delta > 0) {
        tb_ticks = t;
        tb_last = count;
    }
#endif
#if defined(HIL_DEFECT_FLOAT_SECONDS)
    {   /* the firmware's clock as float32 seconds: 24 bits of mantissa for the whole run */
        float s = (float)t * SECONDS_PER_TICK;
        return (int64_t)(s * (float)TIMER_HZ);
    }
#else
    return t;
#endif
}

/* every interrupt advances the clock: one at a time (board_irq_lock) */
static int64_t tb_at(uint32_t count)
{
    uint32_t primask = board_irq_lock();
    int64_t t = tb_advance(count);
    board_irq_unlock(primask);
    return t;
}

static float seconds(int64_t ticks)
{
    return (float)ticks * SECONDS_PER_TICK;
}

/* ---- outputs: gates, duty, and the commands pending on the compare unit ---------------------- */
typedef struct {
    int64_t at;
    int8_t sector; /* -1 keep */
    float duty;    /* < 0 keep */
} command_t;

#define QUEUE 8
#define COMPARE_LEAD_TICKS 1  /* an instant this close is made now: an arm at the counter fires a wrap late */
/* The compare unit is armed COMPARE_LATENCY_TICKS (fw_config.h) before a command's instant, so that
   its gates change at that instant, the one apply() records for the ADC's transient segments */
static int64_t arm_at(const command_t *c)
{
    return c->at - (int64_t)COMPARE_LATENCY_TICKS;
}
/* The Hall interrupt knows its capture's count, not the counter's present value: when edge noise
   places the conditioned edge before the physical switch (noise beyond the conditioning delay),
   the capture was latched before the interrupt could run. An instant that close after the capture
   is made at once (armed, it would lie behind the counter and fire a wrap late); the guard is
   three standard deviations of the measured edge noise beyond the edge's conditioning delay, at
   least two ticks, at most HALL_GUARD_MAX. The control interrupt makes anything a late arm missed. */
#define HALL_GUARD_MIN_TICKS 2
#define HALL_GUARD_MAX_TICKS ((int64_t)(20e-6 * TIMER_HZ))
#define EDGE_NOISE_GAIN 0.05f
/* half a sector at the highest set point */
#define MIN_SECTOR_TICKS ((int64_t)(0.5 * 60.0 / (SPEED_SETPOINT_MAX_RPM * 6.0 * POLE_PAIRS) * TIMER_HZ))
static command_t queue[QUEUE];
static int n_queue;
static uint8_t out_gates;
static uint8_t pins_levels; /* the Hall pins as last read */
#define SWITCHES 4
static int64_t switch_t[SWITCHES]; /* the last commutations (gates changed), a ring */
static uint8_t switch_from[SWITCHES], switch_to[SWITCHES]; /* the gates before and after each */
static float switch_duty[SWITCHES]; /* the duty in force at each */
static float out_duty;
static int switch_head, n_switch;
#if defined(HIL_DEFECT_LATE_COMPARE)
static command_t late;       /* the due command armed on the compare instead of made */
static uint8_t late_armed;
#endif

static void apply(const command_t *c)
{
#ifdef FW_DEBUG
    fprintf(stderr, "apply at=%lld sector=%d duty=%.4f\n", (long long)c->at, c->sector, c->duty);
#endif
    if (c->sector >= 0) {
        uint8_t g = hil_gates_of_sector(c->sector);
        if (g != out_gates) { /* a commutation: its instant, for the ADC's segments */
            switch_t[switch_head] = c->at;
            switch_from[switch_head] = out_gates;
            switch_to[switch_head] = g;
            switch_duty[switch_head] = c->duty >= 0.0f ? (c->duty > 1.0f ? 1.0f : c->duty) : out_duty;
            switch_head = (switch_head + 1) % SWITCHES;
            if (n_switch < SWITCHES) n_switch++;
        }
        out_gates = g;
        board_set_gates(out_gates);
    }
    if (c->duty >= 0.0f) {
        float d = c->duty > 1.0f ? 1.0f : c->duty;
        out_duty = d;
        board_set_duty((uint16_t)(d * 65535.0f + 0.5f));
    }
}

static void rearm(int64_t now)
{
    if (n_queue > 0) {
        int64_t ahead = arm_at(&queue[0]) - now;
        if (ahead > COMPARE_LEAD_TICKS && ahead < (int64_t)TIMER_HALF) {
            board_compare_arm((uint32_t)arm_at(&queue[0]) & TIMER_MASK);
#if defined(HIL_DEFECT_LATE_COMPARE)
            late_armed = 0u;
#endif
            return;
        }
    }
#if defined(HIL_DEFECT_LATE_COMPARE)
    if (late_armed) {
        board_compare_arm((uint32_t)late.at & TIMER_MASK);
        return;
    }
#endif
    board_compare_disarm(); /* nothing pending, or too far ahead for one wrap: armed later */
}

static void run_due(int64_t now, int64_t lead);

/* a command from ``at`` on (Python: Command(at_s, sector, duty)); made now when due (within
   ``lead`` of ``now``), else queued for the compare unit; queued ones now due are made too */
static void queue_command(int64_t now, int64_t at, int sector, float duty, int64_t lead)
{
    command_t c;
    int i;
    c.at = at + (int64_t)DEFECT_GATE_LATENCY_TICKS;
    c.sector = (int8_t)sector;
    c.duty = duty;
    if (arm_at(&c) - now <= lead) {
#if defined(HIL_DEFECT_LATE_COMPARE)
        late = c;      /* armed for an instant already due: the compare fires a wrap later */
        late_armed = 1u;
        rearm(now);
        board_compare_arm((uint32_t)c.at & TIMER_MASK);
        return;
#else
        apply(&c);
        return;
#endif
    }
    if (n_queue == QUEUE) { /* cannot happen at one schedule per edge; the oldest goes */
        for (i = 1; i < QUEUE; i++) queue[i - 1] = queue[i];
        n_queue--;
    }
    i = n_queue;
    while (i > 0 && queue[i - 1].at > c.at) {
        queue[i] = queue[i - 1];
        i--;
    }
    queue[i] = c;
    n_queue++;
#if !defined(HIL_DEFECT_LATE_COMPARE)
    run_due(now, lead);
#endif
    rearm(now);
}

/* the command queue and the compare unit are the Hall, compare and control interrupts' at once:
   each change of them runs with interrupts off (board_irq_lock) */
static void emit(int64_t now, int64_t at, int sector, float duty, int64_t lead)
{
    uint32_t primask = board_irq_lock();
    queue_command(now, at, sector, duty, lead);
    board_irq_unlock(primask);
}

static void run_due(int64_t now, int64_t lead)
{
    while (n_queue > 0 && arm_at(&queue[0]) - now <= lead) {
        int i;
        apply(&queue[0]);
        for (i = 1; i < n_queue; i++) queue[i - 1] = queue[i];
        n_queue--;
    }
}

/* ---- ADC: a ring of conversions (control interrupt and capture) and the cycle accumulators -- */
#define ADC_RING 32
typedef struct {
    int64_t t;
    int16_t i[3];
} conversion_t;
static conversion_t adc_ring[ADC_RING];
static int adc_n, adc_head; /* head: the oldest */
static int32_t cycle_sum[3];
static uint32_t cycle_n;

static void adc_push(int64_t t, const int16_t adc[3])
{
    int at;
    uint32_t primask = board_irq_lock();
    if (adc_n < ADC_RING) {
        at = (adc_head + adc_n) % ADC_RING;
        adc_n++;
    } else {
        at = adc_head;
        adc_head = (adc_head + 1) % ADC_RING;
    }
    adc_ring[at].t = t;
    adc_ring[at].i[0] = adc[0];
    adc_ring[at].i[1] = adc[1];
    adc_ring[at].i[2] = adc[2];
    board_irq_unlock(primask);
}

/* The mean |i| moves from one level to another at each commutation, in a ramp of about 9 us on
   the paper pump (the outgoing phase's current freewheeling down), and smoothly between them. With
   conversions 50 us apart a line across a commutation misses the current at the edge by amperes
   (and the armature correction by degrees); the Python controller reads a 500 kHz window. So the
   firmware uses what it knows, its own commutation instants: between two commutations, a line
   through that segment's conversions (after the ramp), held at its ends; within a ramp, a line
   from the segment before (at the commutation) to the segment after (at the ramp's end). */
#define ADC_RAMP_TICKS ((int64_t)(9e-6 * TIMER_HZ))

static float mean_abs(const conversion_t *c0, const conversion_t *c1, int64_t t)
{
    float s = 0.0f;
    int k;
    if (c1 == c0 || c1->t == c0->t || t <= c0->t) {
        for (k = 0; k < 3; k++) s += fabsf((float)c0->i[k]);
    } else if (t >= c1->t) {
        for (k = 0; k < 3; k++) s += fabsf((float)c1->i[k]);
    } else {
        float frac = (float)(t - c0->t) / (float)(c1->t - c0->t);
        for (k = 0; k < 3; k++) {
            float i0 = (float)c0->i[k], i1 = (float)c1->i[k];
            s += fabsf((i1 - i0) * frac + i0);
        }
    }
    return s / 3.0f * AMPS_PER_COUNT;
}

/* the current at t from the conversions in [lo, hi) (a line, held at the ends); -1 if none */
static float segment_current(int64_t lo, int64_t hi, int64_t t)
{
    const conversion_t *before = 0, *after = 0, *first = 0, *last = 0;
    int j;
    for (j = 0; j < adc_n; j++) {
        const conversion_t *c = &adc_ring[(adc_head + j) % ADC_RING];
        if (c->t < lo || c->t >= hi) continue;
        if (!first) first = c;
        last = c;
        if (c->t <= t) before = c;
        else if (!after) after = c;
    }
    if (!first) return -1.0f;
    if (!before) return mean_abs(first, first, t);
    if (!after) return mean_abs(last, last, t);
    return mean_abs(before, after, t);
}

#if !defined(HIL_DEFECT_CURRENT_SAMPLED_AT_CAPTURE)
/* the phase currents (A) at t from the segment [lo, hi): a line through its last two conversions at
   or before t (held with one); 0 when it has none */
static int segment_phases(int64_t lo, int64_t hi, int64_t t, float i[3])
{
    const conversion_t *a = 0, *b = 0;
    int j, k;
    for (j = 0; j < adc_n; j++) {
        const conversion_t *c = &adc_ring[(adc_head + j) % ADC_RING];
        if (c->t < lo || c->t >= hi || c->t > t) continue;
        a = b;
        b = c;
    }
    if (!b) return 0;
    for (k = 0; k < 3; k++) {
        float v = (float)b->i[k];
        if (a && b->t > a->t) v += ((float)b->i[k] - (float)a->i[k]) * (float)(t - b->t) / (float)(b->t - a->t);
        i[k] = v * AMPS_PER_COUNT;
    }
    return 1;
}

/* The commutation transient of the six-step bridge (H_PWM-L_ON, averaged over the PWM period),
   from what the firmware knows: the gates before and after the commutation, the duty, the back-EMF
   at its speed estimate (flat tops: the conducting phases at +-E, the outgoing one still at its
   own), the motor's R and L and the phase currents at the commutation. The outgoing phase
   freewheels through its diode (to 0 V when its current is positive, to the supply when negative)
   until its current dies; meanwhile all three phases conduct, then the incoming pair alone. Each
   phase moves at (u - u_n - e - R i) / L, a line over the microseconds this covers (L/R ~ 1 ms).
   The mean |i| at dt seconds after the commutation; *ext the time the outgoing current dies.
   0 when the gates are not a six-step commutation. */
static int transient_mean_abs(int sw, const float i0[3], float dt, float *mean, float *ext)
{
    uint8_t from = switch_from[sw], to = switch_to[sw];
    int x, hi = -1, lo = -1, out = -1;
    float d = switch_duty[sw], w_m = ctl_speed_rpm() * (2.0f * FW_PI_F / 60.0f), E, u[3], e[3], k[3], i[3];
    float un, t1 = 0.0f, s = 0.0f;
    for (x = 0; x < 3; x++) {
        uint8_t before = (uint8_t)((from >> (2 * x)) & 3u), after = (uint8_t)((to >> (2 * x)) & 3u);
        if (after == 1u) hi = x;
        else if (after == 2u) lo = x;
        else if (before != 0u) out = x;
    }
    if (hi < 0 || lo < 0 || out < 0 || w_m <= 0.0f) return 0;
    E = MOTOR_KE_V_S * w_m;
    u[hi] = d * MOTOR_SUPPLY_V;
    e[hi] = E;
    u[lo] = 0.0f;
    e[lo] = -E;
    u[out] = i0[out] > 0.0f ? 0.0f : MOTOR_SUPPLY_V;
    e[out] = ((from >> (2 * out)) & 1u) ? E : -E;
    un = (u[0] + u[1] + u[2] - e[0] - e[1] - e[2]) / 3.0f;
    for (x = 0; x < 3; x++) k[x] = (u[x] - un - e[x] - MOTOR_R_OHM * i0[x]) / MOTOR_L_H;
    if (i0[out] * k[out] < 0.0f) t1 = -i0[out] / k[out];
    if (dt <= t1) {
        for (x = 0; x < 3; x++) i[x] = i0[x] + k[x] * dt;
    } else { /* the incoming pair alone from t1 */
        float ip = 0.5f * ((i0[hi] + k[hi] * t1) - (i0[lo] + k[lo] * t1));
        ip += (d * MOTOR_SUPPLY_V - 2.0f * E - 2.0f * MOTOR_R_OHM * ip) / (2.0f * MOTOR_L_H) * (dt - t1);
        i[hi] = ip;
        i[lo] = -ip;
        i[out] = 0.0f;
    }
    for (x = 0; x < 3; x++) s += fabsf(i[x]);
    *mean = s / 3.0f;
    *ext = t1;
    return 1;
}

#endif

/* adc.current_at_a: mean |i| over the phases at t; -1 without conversions */
static float adc_current_at(int64_t t)
{
    if (adc_n == 0) return -1.0f;
#if !defined(HIL_DEFECT_CURRENT_SAMPLED_AT_CAPTURE)
  {
    int64_t lo = INT64_MIN, prev = INT64_MIN, hi = INT64_MAX;
    float i;
    int j, lo_at = -1;
    for (j = 0; j < n_switch; j++) { /* the commutations around t: prev < lo <= t < hi */
        int at = (switch_head + SWITCHES - 1 - j) % SWITCHES;
        int64_t sw = switch_t[at];
        if (sw <= t && sw > lo) {
            lo = sw;
            lo_at = at;
        }
        if (sw > t && sw < hi) hi = sw;
    }
    for (j = 0; j < n_switch; j++) {
        int64_t sw = switch_t[(switch_head + SWITCHES - 1 - j) % SWITCHES];
        if (sw < lo && sw > prev) prev = sw;
    }
    if (lo_at >= 0) { /* within a commutation's transient: its model, anchored on the conversions in it */
        float i0[3], m, ext, mc, ec;
        if (segment_phases(prev == INT64_MIN ? INT64_MIN : prev + ADC_RAMP_TICKS, lo, lo, i0) &&
            transient_mean_abs(lo_at, i0, seconds(t - lo), &m, &ext)) {
            int64_t end = lo + (int64_t)(ext * (float)TIMER_HZ) + ADC_RAMP_TICKS / 9;
            const conversion_t *near = 0;
            const conversion_t *clean = 0; /* the segment's first conversion after the transient */
            if (end < lo + ADC_RAMP_TICKS) end = lo + ADC_RAMP_TICKS;
            if (end > hi) end = hi;
            for (j = 0; j < adc_n; j++) {
                const conversion_t *c = &adc_ring[(adc_head + j) % ADC_RING];
                if (c->t >= end && c->t < hi && (!clean || c->t < clean->t)) clean = c;
            }
            /* within the transient, or after it but before the segment's first conversion after it:
               the line below would run through a conversion taken within the transient (at 10,000
               rpm the outgoing current dies 13 us after the commutation, beyond the 9 us ramp) or
               hold the first conversion after it, tens of microseconds later. Read there, a 13 us
               transient's dip left the edge current 0.49 A high (1.32 deg e/A: REQ-ROB-001 at
               --hil-seed 1, sector 1 commutated 0.5 deg e early every electrical period); the model
               follows the incoming pair's current from the transient's end */
            if (t < end || !clean || t < clean->t) {
                for (j = 0; j < adc_n; j++) { /* the conversion within the transient nearest t, or that first one */
                    const conversion_t *c = &adc_ring[(adc_head + j) % ADC_RING];
                    if (c->t <= lo || (c->t >= end && c != clean)) continue;
                    if (!near || llabs(c->t - t) < llabs(near->t - t)) near = c;
                }
                if (near && transient_mean_abs(lo_at, i0, seconds(near->t - lo), &mc, &ec)) {
                    float w = near->t <= t ? 1.0f : (float)(t - lo) / (float)(near->t - lo);
                    m += (mean_abs(near, near, near->t) - mc) * w;
                }
                return m > 0.0f ? m : 0.0f;
            }
        }
    }
    if (lo != INT64_MIN && t < lo + ADC_RAMP_TICKS) { /* within the ramp of the commutation at lo */
        float pre = segment_current(prev == INT64_MIN ? INT64_MIN : prev + ADC_RAMP_TICKS, lo, lo);
        int64_t end = lo + ADC_RAMP_TICKS;
        float post = segment_current(end, hi, end);
        if (post < 0.0f) { /* nothing after the ramp yet: the newest conversion within it (the capture's) */
            for (j = adc_n - 1; j >= 0; j--) {
                const conversion_t *c = &adc_ring[(adc_head + j) % ADC_RING];
                if (c->t >= t && c->t < end) {
                    end = c->t;
                    post = mean_abs(c, c, c->t);
                    break;
                }
            }
        }
        if (pre >= 0.0f && post >= 0.0f)
            return end > lo ? pre + (post - pre) * (float)(t - lo) / (float)(end - lo) : post;
        if (pre >= 0.0f || post >= 0.0f) return pre >= 0.0f ? pre : post;
    }
    i = segment_current(lo == INT64_MIN ? INT64_MIN : lo + ADC_RAMP_TICKS, hi, t);
    if (i >= 0.0f) return i;
  }
#endif
    return segment_current(INT64_MIN, INT64_MAX, t); /* no conversion in the segment: the whole ring */
}

/* ---- the control logic's state (what a logic restart rebuilds) ------------------------------- */
typedef struct {
    int64_t t;
    uint8_t sensor, rising;
    int32_t boundary;
    float current_a; /* what the armature correction read at this edge: the pole alignment uses it */
} hist_t;
#define HIST_KEEP (2 * EDGES_PER_TURN + 2)

static struct {
    /* configuration the logic was built with */
    uint8_t corrected;   /* corrections applied (every strategy but raw) */
    uint8_t predictor;   /* a filter runs (kf, sage_husa) */
    filter_t filt;
    /* VirtualController.capture */
    int8_t sector;
    uint8_t sensors_seen;
    uint8_t bits[3];
    int32_t edges_since_motion, normal_steps;
    uint8_t resync_pending;
    uint8_t has_last_t;
    int64_t last_t;
    float last_current_a;  /* the current at the last motion edge */
    float iv_dt[EDGES_PER_TURN];
    uint8_t iv_measured[EDGES_PER_TURN];
    int iv_n, iv_head;
    uint32_t guards_seen;
    /* HallCommutation.on_edge */
    uint8_t hc_has_last;
    int64_t hc_last_t, hc_last_corr_t;
    uint8_t seen[3];
    int32_t edge_index;
    float first_angle_deg_e;
    hist_t hist[HIST_KEEP];
    int hist_n, hist_head;
    int32_t pole_shift;  /* -1: not learned yet */
    uint8_t has_sched;
    int8_t sched_sector;
    int64_t sched_at;
    int8_t last_sector;
    int32_t index_at_last_sector;
    uint8_t has_prediction;
    int64_t last_prediction;
    float speed_est[EDGES_PER_TURN];
    int spd_n, spd_head;
    float dtc_prev, edge_noise_var;  /* the edge noise (s^2), for the Hall interrupt's guard */
    /* SpeedPI */
    float setpoint_rpm, feedforward, integral;
    uint8_t pi_ran;
    int8_t start_sector;   /* the pins' sector when the logic (re)started */
} L;

/* the table the interrupts read (the applied one, through cal_effective) */
static cal_table_t table;
#if defined(HIL_DEFECT_TORN_TABLE)
static cal_table_t table_next; /* apply copies this into ``table`` one value per control interrupt */
static int torn_copy_at = CAL_N_VALUES;
static unsigned torn_tick;
#endif

/* ---- speed loop ----------------------------------------------------------------------------- */
static float steady_duty(float rpm)
{
    float w = rpm * (2.0f * FW_PI_F / 60.0f);
    float torque = MOTOR_FAN * w * w + MOTOR_FRICTION * w;
    float current = torque / (2.0f * MOTOR_KE_V_S);
    return (2.0f * MOTOR_R_OHM * current + 2.0f * MOTOR_KE_V_S * w) / MOTOR_SUPPLY_V;
}

static void duty_bounds(float speed_rpm, float *lo, float *hi)
{
#if defined(HIL_DEFECT_CURRENT_LIMIT_NOT_ENFORCED)
    (void)speed_rpm;
    *lo = 0.0f;
    *hi = 1.0f;
#else
    float bemf = 2.0f * MOTOR_KE_V_S * speed_rpm * (2.0f * FW_PI_F / 60.0f);
    float span = 2.0f * MOTOR_R_OHM * CURRENT_LIMIT_A;
    float l = (bemf - span) / MOTOR_SUPPLY_V, h = (bemf + span) / MOTOR_SUPPLY_V;
    *lo = l > 0.0f ? l : 0.0f;
    *hi = h < 1.0f ? h : 1.0f;
#endif
}

static float pi_update(float speed_rpm, float dt_s, float lo, float hi)
{
    float error = L.setpoint_rpm - speed_rpm;
    float unclamped = L.feedforward + SPEED_KP_PER_RPM * error + SPEED_KI_PER_RPM_S * L.integral;
    int pushing = (unclamped >= hi && error > 0.0f) || (unclamped <= lo && error < 0.0f);
    float d;
    if (fabsf(error) <= SPEED_INTEGRATE_WITHIN * L.setpoint_rpm && !pushing) L.integral += error * dt_s;
    d = L.feedforward + SPEED_KP_PER_RPM * error + SPEED_KI_PER_RPM_S * L.integral;
    d = d > lo ? d : lo;
    return d < hi ? d : hi;
}

/* ---- history ring ----------------------------------------------------------------------------- */
static hist_t *hist_back(int m) /* m = 1: the newest */
{
    return &L.hist[(L.hist_head + L.hist_n - m) % HIST_KEEP];
}

static void hist_append(int64_t t, uint8_t sensor, uint8_t rising, int32_t boundary, float current_a)
{
    hist_t *h;
    if (L.hist_n == HIST_KEEP) {
        L.hist_head = (L.hist_head + 1) % HIST_KEEP;
        L.hist_n--;
    }
    L.hist_n++;
    h = hist_back(1);
    h->t = t;
    h->sensor = sensor;
    h->rising = rising;
    h->boundary = boundary;
    h->current_a = current_a;
}

/* ---- corrections (hil/calibration/corrections.py correction_one_deg_e) ----------------------- */
static float delay_of(uint8_t rising)
{
#if defined(HIL_DEFECT_TIME_PRODUCT_OVERFLOW)
    /* the delay taken to whole timer ticks through nanoseconds: ns x TIMER_HZ is 6.6e10 for 6.6 us at
       10 MHz, beyond 2^32, so an unsigned long (64 bits on a PC, 32 on a Cortex-M) wraps on the part */
    unsigned long ns = (unsigned long)lroundf((rising ? table.delay_rise_s : table.delay_fall_s) * 1e9f);
    unsigned long ticks = ns * (unsigned long)TIMER_HZ / 1000000000ul;
    return (float)ticks * SECONDS_PER_TICK;
#else
    return rising ? table.delay_rise_s : table.delay_fall_s;
#endif
}

static float correction_deg_e(int sensor, uint8_t rising, int pole, float speed_rpm, float current_a)
{
    return table.installation_deg_e[sensor] + table.pole_deg_e[pole] +
           speed_rpm * 6.0f * (float)POLE_PAIRS * delay_of(rising) + table.armature_deg_e_per_a * current_a;
}

/* the pole alignment whose corrections make one mechanical turn's sectors most even */
static void sync_poles(void)
{
    enum { N = EDGES_PER_TURN };
    float t_rel[N + 1], sector_s[N], best_var = INFINITY, w;
    int k, shift, best = 0;
    const hist_t *first;
    if (L.pole_shift >= 0 || L.hist_n < 2 * N + 1) return;
    /* a turn whose edges saw more current than the speed loop's limit is no turn of the motor under
       control (a start-up's late commutations run to tens of amperes): there the linear armature
       correction is extrapolated past where it holds (the sensors' shift saturates at 30 deg e,
       which the library's steepest 2 deg e/A reaches at 15 A), errs by tens of degrees and
       outweighs pole offsets a few degrees apart. Scored anyway (edges at tens of amperes), the
       alignment took the wrong electrical period for good (REQ-ROB-001, --hil-seed 3 once the
       start-up guard read the captured interval: 6.1 deg e p99). It waits for a turn within the
       limit */
    for (k = 1; k <= N + 1; k++)
        if (hist_back(k)->current_a > CURRENT_LIMIT_A) return;
    first = hist_back(N + 1);
    for (k = 0; k <= N; k++) t_rel[k] = seconds(hist_back(N + 1 - k)->t - first->t);
    w = 360.0f * (float)POLE_PAIRS / t_rel[N];
    for (shift = 0; shift < N_POLES; shift += 2) {
        float prev = 0.0f, ibar = 0.5f * (float)(N - 1), ybar = 0.0f, sxy = 0.0f, sxx = 0.0f, slope, mean = 0.0f, var = 0.0f;
        for (k = 0; k <= N; k++) {
            const hist_t *h = hist_back(N + 1 - k);
            int pole = mod_int(h->boundary + shift, N_POLES);
            /* the armature lag too: a start-up current's (2 deg e/A at 3-10 A) outweighs pole offsets
               a degree apart from one alignment to the next */
            float corr = table.installation_deg_e[h->sensor] + table.pole_deg_e[pole] +
                         table.armature_deg_e_per_a * h->current_a;
            float tc = t_rel[k] - corr / w - delay_of(h->rising);
            if (k > 0) sector_s[k - 1] = tc - prev;
            prev = tc;
        }
        for (k = 0; k < N; k++) ybar += sector_s[k];
        ybar /= (float)N;
        for (k = 0; k < N; k++) {
            sxy += ((float)k - ibar) * (sector_s[k] - ybar);
            sxx += ((float)k - ibar) * ((float)k - ibar);
        }
        slope = sxy / sxx;
        for (k = 0; k < N; k++) sector_s[k] -= ybar + slope * ((float)k - ibar);
        for (k = 0; k < N; k++) mean += sector_s[k];
        mean /= (float)N;
        for (k = 0; k < N; k++) var += (sector_s[k] - mean) * (sector_s[k] - mean);
        var /= (float)N;
        if (var < best_var) {
            best = shift;
            best_var = var;
        }
    }
    L.pole_shift = best;
}

static void hc_resync(void)
{
#if !defined(HIL_DEFECT_NEVER_RESYNCHRONISES)
    L.edge_index = -1;
    L.hist_n = 0;
    L.hist_head = 0;
    L.pole_shift = -1;
    L.has_sched = 0u;
    L.last_sector = -1;
    L.index_at_last_sector = -1;
    if (L.predictor) filter_restart(&L.filt);
#endif
}

/* HallCommutation.on_edge */
static void hc_on_edge(int64_t t, uint8_t x, uint8_t rising, uint8_t levels, float current_a, float cycle_a)
{
    int sector, k;
    float angle, duty = -1.0f;
    int32_t boundary;
    int64_t t_corr = t, now = t, guard = HALL_GUARD_MIN_TICKS;

    L.seen[x] = rising;
    L.edge_index++;
    if (L.edge_index == 0) {
        L.first_angle_deg_e = SENSOR_POSITION_DEG_E[x] + (rising ? 0.0f : 180.0f);
        if (!L.hc_has_last) {
            /* start-up: the Python controller infers the other two sensors from which edge this was
               (the rotor turning forward); the firmware reads them on its pins. A first edge that
               is not a forward one (the edge of a sensor the rotor stands at, moved back and forth
               by the start-up current through the armature reaction) then commutates the sector
               the pins name, not one 180 deg e away */
            for (k = 0; k < 3; k++) L.seen[k] = (uint8_t)((levels >> k) & 1u);
        }
    }
    angle = L.first_angle_deg_e + 60.0f * (float)L.edge_index;
    boundary = (int32_t)lroundf((angle - SENSOR_POSITION_DEG_E[x]) / 180.0f);
    hist_append(t, x, rising, boundary, current_a >= 0.0f ? current_a : 0.0f);
    sector = sector_of_bits(L.seen);
    if (sector < 0) return;
    if (sector == L.last_sector) { /* a glitch since the last valid edge, not rotor motion */
        int drop = (int)(L.edge_index - L.index_at_last_sector);
        L.hist_n = drop < L.hist_n ? L.hist_n - drop : 0;
        L.edge_index = L.index_at_last_sector;
        return;
    }
    L.last_sector = (int8_t)sector;
    L.index_at_last_sector = L.edge_index;

    if (L.corrected && L.hc_has_last) {
        float w_e, speed_rpm, corr;
        sync_poles();
        if (L.hist_n > EDGES_PER_TURN) {
            float span = seconds(t - hist_back(EDGES_PER_TURN + 1)->t);
            w_e = 360.0f * (float)POLE_PAIRS / (span > 1e-9f ? span : 1e-9f);
        } else {
            float span = seconds(t - L.hc_last_t);
            w_e = 60.0f / (span > 1e-9f ? span : 1e-9f);
        }
        speed_rpm = w_e / (6.0f * (float)POLE_PAIRS);
        if (L.pole_shift >= 0) {
            corr = correction_deg_e(x, rising, mod_int(boundary + L.pole_shift, N_POLES), speed_rpm, current_a);
        } else { /* until the alignment is learned: the poles' mean for the pole's own */
            float mean = 0.0f;
            for (k = 0; k < N_POLES; k++) mean += table.pole_deg_e[k];
            corr = correction_deg_e(x, rising, 0, speed_rpm, current_a) - table.pole_deg_e[0] + mean / (float)N_POLES;
        }
        t_corr = t - (int64_t)lroundf(corr / w_e * (float)TIMER_HZ);
    }
    if (L.hc_has_last && t_corr > L.hc_last_corr_t) {
        float speed_rpm;
        if (L.corrected && L.pole_shift < 0) { /* whole electrical periods until the alignment is known */
            int periods = (L.hist_n - 1 < EDGES_PER_TURN ? L.hist_n - 1 : EDGES_PER_TURN) / 6;
            speed_rpm = periods ? 60.0f * (float)periods / (float)POLE_PAIRS / seconds(t - hist_back(6 * periods + 1)->t)
                                : 0.0f;
        } else {
            speed_rpm = (60.0f / seconds(t_corr - L.hc_last_corr_t)) / (6.0f * (float)POLE_PAIRS);
        }
        if (speed_rpm > 0.0f) {
            float lo, hi;
            int at = (L.spd_head + L.spd_n) % EDGES_PER_TURN;
            if (L.spd_n < EDGES_PER_TURN) L.spd_n++;
            else L.spd_head = (L.spd_head + 1) % EDGES_PER_TURN;
            L.speed_est[at] = speed_rpm;
            duty_bounds(speed_rpm, &lo, &hi);
            duty = pi_update(speed_rpm, seconds(t - L.hc_last_t), lo, hi);
            L.pi_ran = 1u;
        }
    }
    if (L.corrected && L.hc_has_last && t_corr > L.hc_last_corr_t) {
        /* the edge noise, from the corrected intervals' second differences (variance 6 sigma^2) */
        float dtc = seconds(t_corr - L.hc_last_corr_t), g;
        if (L.dtc_prev > 0.0f) {
            float d2 = dtc - L.dtc_prev;
            L.edge_noise_var += EDGE_NOISE_GAIN * (d2 * d2 / 6.0f - L.edge_noise_var);
        }
        L.dtc_prev = dtc;
        g = 3.0f * sqrtf(L.edge_noise_var) - delay_of(rising);
        if (g * (float)TIMER_HZ > (float)HALL_GUARD_MAX_TICKS) guard = HALL_GUARD_MAX_TICKS;
        else if (g * (float)TIMER_HZ > (float)HALL_GUARD_MIN_TICKS) guard = (int64_t)(g * (float)TIMER_HZ);
    }
    if (!L.corrected || !L.hc_has_last) {
        emit(now, now, sector, duty, guard);
    } else {
        int64_t predicted = 0, at;
        int got = 0;
        float current;
        if (!L.has_sched || L.sched_sector != sector || L.sched_at <= now) emit(now, now, sector, duty, guard);
        else if (duty >= 0.0f) emit(now, now, -1, duty, guard);
        /* K_T of Eq. 8 is per ampere of the cycle mean: the cycle's accumulators, else the edge's */
        current = cycle_a >= 0.0f ? cycle_a : (current_a >= 0.0f ? current_a : 0.0f);
#if defined(HIL_DEFECT_PREDICTOR_FED_MILLIAMPERES)
        current *= 1000.0f;
#endif
        if (L.predictor) {
            int r = filter_update(&L.filt, t_corr, current, &predicted);
            if (r == 1) got = 1;
            else if (r < 0) fault_raise(FAULT_INTERNAL); /* corrected edges out of order */
        }
        if (!got) { /* pre-calibration: 60 deg e after the corrected edge at the last cycle's speed */
            int64_t dt = t_corr - L.hc_last_corr_t;
            predicted = t_corr + (dt > 0 ? dt : 0);
        }
        L.has_prediction = 1u;
        L.last_prediction = predicted;
        at = predicted > now ? predicted : now;
        L.has_sched = 1u;
        L.sched_sector = (int8_t)((sector + 1) % 6);
        L.sched_at = at;
        if (!got && t - L.hc_last_t < MIN_SECTOR_TICKS) {
            /* not the Python controller's: a captured interval shorter than half a sector at the
               highest set point is no sector (a sensor's edge moved back and forth at start-up,
               before any reference interval); 60 deg e after it would commutate a sector early for
               a whole sector. Commutated from the pins only; the next edge schedules again. The
               captured interval, not the corrected one: the armature correction shortens the
               corrected interval by slope x current, and at a start-up's tens of amperes (2 deg e/A
               x 26 A, 49 deg e) a whole sector read as a bounce; withholding the commutation the
               correction said was due left the winding commutated late until the next edge (which
               the same current delays), the current ran to 130 A over a mechanical turn and the pole
               alignment learned in it took the wrong electrical period (REQ-ROB-001, --hil-seed 2:
               7.34 deg e p99) */
            L.has_sched = 0u;
            L.hc_has_last = 1u;
            L.hc_last_t = t;
            L.hc_last_corr_t = t_corr;
            return;
        }
#ifdef FW_DEBUG
        fprintf(stderr, "edge t=%lld x=%d r=%d sector=%d tcorr=%lld pred=%lld shift=%d\n", (long long)t, x, rising, sector, (long long)t_corr, (long long)predicted, L.pole_shift);
#endif
        emit(now, at, L.sched_sector, -1.0f, guard);
    }
    L.hc_has_last = 1u;
    L.hc_last_t = t;
    L.hc_last_corr_t = t_corr;
}

/* ---- VirtualController.capture: fault logic around the commutation -------------------------- */
static void iv_clear(void)
{
    L.iv_n = 0;
    L.iv_head = 0;
}

static void iv_push(float dt, uint8_t measured)
{
    int at = (L.iv_head + L.iv_n) % EDGES_PER_TURN;
    if (L.iv_n < EDGES_PER_TURN) L.iv_n++;
    else L.iv_head = (L.iv_head + 1) % EDGES_PER_TURN;
    L.iv_dt[at] = dt;
    L.iv_measured[at] = measured;
}

/* the interval a sector is compared with to tell a lost edge or a glitch; 0 when none yet */
static int reference_interval(float *ref, float *ratio)
{
    *ratio = MISSING_EDGE_RATIO;
    if (L.iv_n == 0) return 0;
#if defined(HIL_DEFECT_LOST_EDGE_AGAINST_LAST_SECTOR)
    *ref = L.iv_dt[(L.iv_head + L.iv_n - 1) % EDGES_PER_TURN];
    return 1;
#else
    {
    int k;
    float s = 0.0f;
    if (L.iv_n == EDGES_PER_TURN && L.iv_measured[L.iv_head]) { /* the same sector one turn back */
        *ref = L.iv_dt[L.iv_head];
        *ratio = SAME_SECTOR_RATIO;
        return 1;
    }
    for (k = 0; k < L.iv_n; k++) s += L.iv_dt[(L.iv_head + k) % EDGES_PER_TURN];
    *ref = s / (float)L.iv_n;
    return 1;
    }
#endif
}

static void edge_lost(void)
{
    fault_raise(FAULT_MISSING_EDGE);
    iv_clear();
    L.normal_steps = 0;
    L.resync_pending = 1u;
}

void ctl_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3])
{
    int64_t t = tb_at(count);
    uint8_t rising, motion = 1u, one_step = 0u; /* one_step: the Hall code stepped one sector forward */
    float current_a, cycle_a = -1.0f, delay_s = 0.0f;
    int sector;
    uint32_t primask;

    if (pin > 2u) return;
#ifdef FW_DEBUG
    fprintf(stderr, "hall t=%lld pin=%d levels=%d\n", (long long)t, pin, levels);
#endif
#if defined(HIL_DEFECT_STACK_HUNGRY_ISR)
    {   /* a 4.4 kB scratch window of past intervals on the interrupt's stack (a median filter's
           buffer): on a PC's megabytes nothing happens, on a 4 kB main stack it overflows */
        volatile float window[1100];
        int k;
        for (k = 0; k < 1100; k++) window[k] = (float)k;
        delay_s = window[(uint32_t)t % 1100u] * 0.0f;
    }
#endif
#if defined(HIL_DEFECT_UNALIGNED_64BIT_ACCESS)
    {   /* the capture time packed into a byte record behind its one-byte pin field, stored through
           an int64_t pointer: the compiler emits STRD, which faults unaligned on a Cortex-M
           (UsageFault UNALIGNED); x86 does not care */
        static uint8_t record[16];
        record[0] = pin;
        *(volatile int64_t *)(void *)&record[1] = t;
    }
#endif
    adc_push(t, adc); /* the conversion the capture triggers */
    primask = board_irq_lock(); /* the control interrupt adds to the accumulators */
    if (cycle_n > 0u) {
#if defined(HIL_DEFECT_PREDICTOR_CURRENT_SIGNED_SUM)
        /* the signed sum of the phases, |a + b + c|: about 0 in a star winding */
        cycle_a = fabsf((float)cycle_sum[0] + (float)cycle_sum[1] + (float)cycle_sum[2]) /
                  (3.0f * (float)cycle_n) * AMPS_PER_COUNT;
#else
        cycle_a = (fabsf((float)cycle_sum[0]) + fabsf((float)cycle_sum[1]) + fabsf((float)cycle_sum[2])) /
                  (3.0f * (float)cycle_n) * AMPS_PER_COUNT;
#endif
    }
    cycle_sum[0] = cycle_sum[1] = cycle_sum[2] = 0;
    cycle_n = 0u;
    board_irq_unlock(primask);
    if (L.has_last_t && t <= L.last_t) { /* a capture stamp that does not increase */
        fault_raise(FAULT_CAPTURE_TIMING);
        return;
    }
    rising = (uint8_t)((levels >> pin) & 1u);
#if !defined(HIL_DEFECT_CURRENT_SAMPLED_AT_CAPTURE)
    if (L.corrected) delay_s = delay_of(rising);
#endif
    current_a = adc_current_at(t - (int64_t)lroundf(delay_s * (float)TIMER_HZ));
    if (current_a < 0.0f) current_a = 0.0f; /* no conversion yet: the current estimate, 0 A */

    pins_levels = levels;
    if (!L.hc_has_last && L.start_sector >= 0) {
        /* start-up (not the Python controller's, which does not see the pins at reset): the motor
           turns forward from the sector the pins named at power-on; an edge that does not step
           forward from it (a sensor the rotor stands at, its edge moved back and forth by the
           start-up current through the armature reaction) is no rotor motion yet */
        int s = hil_sector_of_levels(levels);
        int step = s < 0 ? -1 : mod_int(s - L.start_sector, 6);
        if (step != 1 && step != 2) {
            L.bits[pin] = rising;
            return;
        }
    }
    L.bits[pin] = rising;
    sector = sector_of_bits(L.bits);
    L.sensors_seen |= (uint8_t)(1u << pin);
    if (L.sensors_seen == 7u) { /* the Hall state is known once every sensor has switched */
        if (sector < 0) {
            fault_raise(FAULT_ILLEGAL_HALL_CODE);
            motion = 0u;
        } else if (sector == L.sector) {
            motion = 0u; /* back where the last valid edge left it: a spike or a bounce */
        } else if (L.sector >= 0 && mod_int(sector - L.sector, 6) != 1) {
            edge_lost(); /* a skipped sector, or a step against the direction of rotation */
        } else if (L.sector >= 0) {
            L.normal_steps++;
            one_step = 1u;
        }
        if (sector >= 0) L.sector = (int8_t)sector;
    }
    L.edges_since_motion++;
    if (motion) {
        if (L.has_last_t) {
            float dt = seconds(t - L.last_t), ref, ratio;
            uint8_t measured = 1u;
            if (reference_interval(&ref, &ratio)) {
                if (dt > ratio * ref) {
                    /* the Hall code stepped one sector: edges lost in between can only be whole
                       electrical periods, 1 + 6 k sectors, and the time picks k (read as
                       round(dt / ref), a reference too short counted every later sector as several
                       for good: the edge count, and the pole corrections with it, ran away) */
                    long sectors = one_step ? 1L + 6L * lroundf(fmaxf((dt / ref - 1.0f) / 6.0f, 0.0f))
                                            : lroundf(dt / ref);
                    long lost = sectors - (long)L.edges_since_motion;
                    edge_lost();
                    if (lost > 0) L.edge_index += (int32_t)lost; /* count_lost_edges */
                    if (sectors > 1L) { /* the interval of one sector stays the reference (not measured) */
                        dt = ref;
                        measured = 0u;
                    } /* else one sector, measured: it replaces the reference it exceeded */
                } else if (dt * ratio < ref) { /* a glitch that read as a step */
                    dt = ref;
                    measured = 0u;
                    iv_clear();
                }
            }
            if (current_a > CURRENT_LIMIT_A || L.last_current_a > CURRENT_LIMIT_A) {
                /* an edge of it saw more current than the speed loop's limit (a start-up's late
                   commutations): its time moved by an armature lag the motor under control never
                   has, so the interval is no measurement of its sector for the next turn (a start-up
                   sector shortened by 22 A, the same-sector reference a turn later, read a normal
                   sector as a lost edge: a false 0xFF02, REQ-ROB-001 at --hil-seed 1) */
                measured = 0u;
            }
            iv_push(dt, measured);
        }
        L.has_last_t = 1u;
        L.last_t = t;
        L.last_current_a = current_a;
        L.edges_since_motion = 0;
    }
    if (L.resync_pending && L.normal_steps >= 6) {
        hc_resync();
        L.resync_pending = 0u;
    }
#ifdef FW_DEBUG
    fprintf(stderr, "cur t=%lld pin=%d r=%d I=%.3f cyc=%.3f\n", (long long)t, pin, rising, current_a, cycle_a);
#endif
    hc_on_edge(t, pin, rising, levels, current_a, cycle_a);
    if (L.predictor) { /* guards firing while P settles from P0 (warm-up) are expected */
        uint32_t trips = filter_covariance_repairs(&L.filt);
        if (L.filt.k_step <= L.filt.fp.warmup) {
            L.guards_seen = trips;
        } else if (trips > L.guards_seen) {
            L.guards_seen = trips;
            fault_raise(FAULT_FILTER_GUARD_TRIP);
        }
    }
}

#if defined(HIL_DEFECT_DOUBLE_IN_CONTROL_ISR)
static double current_lp_a[3]; /* a low-passed phase current nobody needs at 20 kHz */
static int64_t current_lp_at = -1; /* the previous control interrupt's instant, in timer ticks */
#define CURRENT_LP_TAU_S 1e-3
#endif

void ctl_control_isr(uint32_t count, const int16_t adc[3])
{
    int64_t now = tb_at(count);
    uint32_t primask;
#if defined(HIL_DEFECT_DOUBLE_IN_CONTROL_ISR)
    {   /* a first-order low pass in double, its coefficient recomputed every period from the
           measured interval since the last one: on a PC a few instructions, on a Cortex-M4F
           (single-precision FPU) a software exp, a divide, multiplies and adds */
        double dt_s = current_lp_at < 0 ? 1.0 / CONTROL_HZ : (double)(now - current_lp_at) / (double)TIMER_HZ;
        double alpha = 1.0 - exp(-dt_s / CURRENT_LP_TAU_S);
        int k;
        current_lp_at = now;
        for (k = 0; k < 3; k++) current_lp_a[k] += alpha * ((double)adc[k] * (double)AMPS_PER_COUNT - current_lp_a[k]);
    }
#endif
    adc_push(now, adc);
    primask = board_irq_lock();
    cycle_sum[0] += adc[0];
    cycle_sum[1] += adc[1];
    cycle_sum[2] += adc[2];
    cycle_n++;
    board_irq_unlock(primask);
#if defined(HIL_DEFECT_TORN_TABLE)
    /* the 1 kHz background task (every CONTROL_HZ / 1000th control interrupt) copies one value per
       tick: the Hall ISR reads a half-copied table for CAL_N_VALUES ms */
    if (torn_copy_at < CAL_N_VALUES && ++torn_tick >= CONTROL_HZ / 1000) {
        torn_tick = 0u;
        cal_set(&table, torn_copy_at, cal_get(&table_next, torn_copy_at));
        torn_copy_at++;
    }
#endif
    primask = board_irq_lock();
#if !defined(HIL_DEFECT_LATE_COMPARE)
    run_due(now, COMPARE_LEAD_TICKS); /* a command too far ahead to arm when it was made */
#endif
    rearm(now);
    board_irq_unlock(primask);
}

void ctl_compare_isr(uint32_t count)
{
    int64_t now = tb_at(count);
    uint32_t primask;
#ifdef FW_DEBUG
    fprintf(stderr, "compare now=%lld q=%d head=%lld\n", (long long)now, n_queue, n_queue ? (long long)queue[0].at : 0LL);
#endif
    primask = board_irq_lock();
#if defined(HIL_DEFECT_LATE_COMPARE)
    if (late_armed && ((uint32_t)late.at & TIMER_MASK) == (count & TIMER_MASK)) {
        late_armed = 0u;
        apply(&late);
    }
#endif
    run_due(now, COMPARE_LEAD_TICKS);
    rearm(now);
    board_irq_unlock(primask);
}

/* ---- configuration ------------------------------------------------------------------------- */
void ctl_restart_logic(void)
{
    uint8_t strategy = nvm.strategy;
    memset(&L, 0, sizeof L);
    L.corrected = strategy != STRATEGY_RAW;
    L.predictor = strategy == STRATEGY_KF || strategy == STRATEGY_SAGE_HUSA;
#if defined(HIL_DEFECT_SAGE_HUSA_RUNS_KF)
    if (strategy == STRATEGY_SAGE_HUSA) filter_init(&L.filt, &FILTER_KF_DEFAULT, 0);
    else
#endif
    if (strategy == STRATEGY_SAGE_HUSA) filter_init(&L.filt, &nvm.sage_husa, 1);
    else if (strategy == STRATEGY_KF) filter_init(&L.filt, &FILTER_KF_DEFAULT, 0);
#if defined(HIL_DEFECT_TORN_TABLE)
    cal_effective(&nvm.applied, &table_next);
    torn_copy_at = 0;
    torn_tick = 0u;
#else
    cal_effective(&nvm.applied, &table);
#endif
    L.sector = -1;
    L.normal_steps = 6;
    L.edge_index = -1;
    L.pole_shift = -1;
    L.last_sector = -1;
    L.index_at_last_sector = -1;
    L.setpoint_rpm = nvm.speed_setpoint_rpm;
    L.feedforward = steady_duty(nvm.speed_setpoint_rpm);
    L.start_sector = (int8_t)hil_sector_of_levels(pins_levels);
}

void ctl_set_speed(float rpm)
{
    L.setpoint_rpm = rpm;
    L.feedforward = steady_duty(rpm);
    if (!L.pi_ran) { /* the speed loop has not run yet: start from the new set point's duty */
        command_t c;
        c.at = 0;
        c.sector = -1;
        c.duty = L.feedforward;
        apply(&c);
    }
}

void ctl_power_on(uint8_t levels)
{
    uint8_t bits[3];
    command_t c;
    tb_valid = 0u;
    n_queue = 0;
    /* the commutation ring and the outputs as at power-on: a ring kept from before the power cycle
       holds instants of the previous time base, which the edge current's segments would read */
    n_switch = switch_head = 0;
    out_gates = 0u;
    out_duty = 0.0f;
    adc_n = adc_head = 0;
    cycle_sum[0] = cycle_sum[1] = cycle_sum[2] = 0;
    cycle_n = 0u;
#if defined(HIL_DEFECT_LATE_COMPARE)
    late_armed = 0u;
#endif
#if defined(HIL_DEFECT_TORN_TABLE)
    cal_zero(&table);
#endif
    board_compare_disarm();
    pins_levels = levels;
    ctl_restart_logic();
    /* the motor is turning at power-on: drive the sector the Hall pins name at once */
    bits[0] = (uint8_t)(levels & 1u);
    bits[1] = (uint8_t)((levels >> 1) & 1u);
    bits[2] = (uint8_t)((levels >> 2) & 1u);
    c.at = 0;
    c.sector = (int8_t)sector_of_bits(bits);
    /* the start-up duty: the default set point's feed-forward, whatever set point the NVM holds
       (a set point written before the speed loop runs replaces it), so that a run does not
       depend on the set point a previous run left */
    c.duty = steady_duty(SPEED_SETPOINT_DEFAULT_RPM);
    if (c.sector < 0) {
        out_gates = 0u;
        board_set_gates(0u);
    }
    apply(&c);
}

/* ---- read-backs ------------------------------------------------------------------------------ */
float ctl_speed_rpm(void)
{
    float s = 0.0f;
    int k;
    if (L.predictor && L.filt.x[0] != 0.0f) return L.filt.x[0] / (float)POLE_PAIRS * 60.0f / (2.0f * FW_PI_F);
    if (L.spd_n == 0) return 0.0f;
    for (k = 0; k < L.spd_n; k++) s += 1.0f / L.speed_est[k];
    return (float)L.spd_n / s;
}

void ctl_filter_diag(float q[3], float r[2])
{
    int k;
    for (k = 0; k < 3; k++) q[k] = L.predictor ? L.filt.Q[4 * k] : 0.0f;
    for (k = 0; k < 2; k++) r[k] = L.predictor ? L.filt.R[3 * k] : 0.0f;
}

uint32_t ctl_guard_trips(void)
{
    return L.predictor ? filter_guard_total(&L.filt) : 0u;
}

void ctl_filter_counters(uint32_t c[4])
{
    if (!L.predictor) {
        c[0] = c[1] = c[2] = c[3] = 0u;
        return;
    }
    c[0] = L.filt.guards[GUARD_GATE];
    c[1] = filter_covariance_repairs(&L.filt);
    c[2] = L.filt.guards[GUARD_DIVERGENCE];
    c[3] = L.filt.guards[GUARD_Q_BAND];
}

double ctl_last_prediction_s(void)
{
    return L.has_prediction ? (double)L.last_prediction / (double)TIMER_HZ : 0.0;
}
