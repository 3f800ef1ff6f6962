/* od.c: the object dictionary. Indices, sub-indices and types are those of the built-in map
   (hil/dut/profiles/virtual-canopen.toml, its EDS virtual-canopen.eds); what each write does is
   hil/dut/virtual_roles.py's. Little-endian. */
#include <math.h>
#include <string.h>

#include "calib.h"
#include "control.h"
#include "faults.h"
#include "filter.h"
#include "fw_config.h"
#include "nvm.h"
#include "od.h"

#define FIRMWARE_VERSION "ref-c-1.0"
#define IDENTITY_VENDOR 0x00000B1Du
#define IDENTITY_PRODUCT 0x00480002u
#define IDENTITY_REVISION 0x00010000u
#define IDENTITY_SERIAL 0x00000001u
#define DEVICE_TYPE 0x00000192u
#define NODE_ID 5u

enum { T_U8, T_U16, T_U32, T_F32, T_F64, T_STR };
enum { A_RO, A_RW, A_WO, A_CONST };

#define CAL_LAST_SUB (3 + N_POLES + 3) /* highest sub-index of 0x2010 / 0x2012 */

typedef struct {
    uint8_t type, access;
} od_entry_t;

static int32_t lookup(uint16_t index, uint8_t sub, od_entry_t *e)
{
    switch (index) {
    case 0x1000: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U32; e->access = A_RO; return 0;
    case 0x1001: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U8; e->access = A_RO; return 0;
    case 0x1003:
        if (sub > FAULT_HISTORY) return -SDO_NO_SUBINDEX;
        e->type = sub ? T_U32 : T_U8;
        e->access = sub ? A_RO : A_RW;
        return 0;
    case 0x100A: if (sub) return -SDO_NO_SUBINDEX; e->type = T_STR; e->access = A_CONST; return 0;
    case 0x1014: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U32; e->access = A_RO; return 0;
    case 0x1017: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U16; e->access = A_RW; return 0;
    case 0x1018:
        if (sub > 4) return -SDO_NO_SUBINDEX;
        e->type = sub ? T_U32 : T_U8;
        e->access = sub ? A_RO : A_CONST;
        return 0;
    case 0x2000: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U8; e->access = A_RW; return 0;
    case 0x2001: if (sub) return -SDO_NO_SUBINDEX; e->type = T_F32; e->access = A_RW; return 0;
    case 0x2002: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U8; e->access = A_WO; return 0; /* clear faults */
    case 0x2010:
    case 0x2012:
        if (sub > CAL_LAST_SUB) return -SDO_NO_SUBINDEX;
        e->type = sub ? T_F32 : T_U8;
        e->access = sub ? (index == 0x2010 ? A_RW : A_RO) : A_CONST;
        return 0;
    case 0x2011: if (sub) return -SDO_NO_SUBINDEX; e->type = T_U8; e->access = A_WO; return 0;
    case 0x2020:
        if (sub > 9) return -SDO_NO_SUBINDEX;
        e->type = sub ? T_F32 : T_U8;
        e->access = sub ? A_RW : A_CONST;
        return 0;
    case 0x2100:
        if (sub > 8) return -SDO_NO_SUBINDEX;
        e->type = sub == 0 ? T_U8 : (sub == 7 ? T_U32 : (sub == 8 ? T_F64 : T_F32));
        e->access = sub ? A_RO : A_CONST;
        return 0;
    case 0x2101:
        if (sub > 4) return -SDO_NO_SUBINDEX;
        e->type = sub ? T_U32 : T_U8;
        e->access = sub ? A_RO : A_CONST;
        return 0;
    default:
        return -SDO_NO_OBJECT;
    }
}

static uint32_t size_of(uint8_t type)
{
    switch (type) {
    case T_U8: return 1u;
    case T_U16: return 2u;
    case T_U32: case T_F32: return 4u;
    case T_F64: return 8u;
    default: return (uint32_t)strlen(FIRMWARE_VERSION);
    }
}

static void put_le(uint8_t *buf, uint64_t v, uint32_t n)
{
    uint32_t i;
    for (i = 0u; i < n; i++) buf[i] = (uint8_t)(v >> (8u * i));
}

static uint64_t get_le(const uint8_t *buf, uint32_t n)
{
    uint64_t v = 0u;
    uint32_t i;
    for (i = 0u; i < n; i++) v |= (uint64_t)buf[i] << (8u * i);
    return v;
}

static uint32_t f32_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    return u;
}

static float bits_f32(uint32_t u)
{
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static float *filter_value(filter_vector_t *v, uint8_t sub) /* 0x2020 sub 1..9 */
{
    if (sub == 1) return &v->forgetting_b;
    if (sub <= 4) return &v->q0[sub - 2];
    if (sub <= 6) return &v->r0[sub - 5];
    return &v->p0[sub - 7];
}

/* the value of a readable entry, as raw bits (floats by their IEEE bits) */
static uint64_t value_of(uint16_t index, uint8_t sub)
{
    float q[3], r[2];
    uint32_t c[4];
    double d;
    uint64_t u;
    switch (index) {
    case 0x1000: return DEVICE_TYPE;
    case 0x1001: return faults_error_register();
    case 0x1003: return sub ? faults_history((uint8_t)(sub - 1u)) : faults_history_count();
    case 0x1014: return 0x80u + NODE_ID;
    case 0x1017: return nvm.heartbeat_ms;
    case 0x1018:
        switch (sub) {
        case 0: return 4u;
        case 1: return IDENTITY_VENDOR;
        case 2: return IDENTITY_PRODUCT;
        case 3: return IDENTITY_REVISION;
        default: return IDENTITY_SERIAL;
        }
    case 0x2000: return nvm.strategy;
    case 0x2001: return f32_bits(nvm.speed_setpoint_rpm);
    case 0x2010: return sub ? f32_bits(cal_get(&nvm.staged, sub - 1)) : CAL_LAST_SUB;
    case 0x2012: return sub ? f32_bits(cal_get(&nvm.applied, sub - 1)) : CAL_LAST_SUB;
    case 0x2020: return sub ? f32_bits(*filter_value(&nvm.sage_husa, sub)) : 9u;
    case 0x2100:
        ctl_filter_diag(q, r);
        switch (sub) {
        case 0: return 8u;
        case 1: return f32_bits(ctl_speed_rpm());
        case 2: case 3: case 4: return f32_bits(q[sub - 2]);
        case 5: case 6: return f32_bits(r[sub - 5]);
        case 7: return ctl_guard_trips();
        default:
            d = ctl_last_prediction_s();
            memcpy(&u, &d, 8);
            return u;
        }
    case 0x2101:
        if (!sub) return 4u;
        ctl_filter_counters(c);
        return c[sub - 1];
    default: return 0u;
    }
}

int32_t od_read(uint16_t index, uint8_t sub, uint8_t *buf, uint32_t size)
{
    od_entry_t e;
    uint32_t n;
    int32_t rc = lookup(index, sub, &e);
    if (rc) return rc;
    if (e.access == A_WO) return -SDO_WRITE_ONLY;
    n = size_of(e.type);
    if (size < n) return -SDO_LENGTH;
    if (e.type == T_STR) memcpy(buf, FIRMWARE_VERSION, n);
    else put_le(buf, value_of(index, sub), n);
    return (int32_t)n;
}

int32_t od_write(uint16_t index, uint8_t sub, const uint8_t *buf, uint32_t size)
{
    od_entry_t e;
    uint64_t raw;
    float f = 0.0f;
    int32_t rc = lookup(index, sub, &e);
    if (rc) return rc;
    if (e.access == A_RO || e.access == A_CONST) return -SDO_READ_ONLY;
    if (size != size_of(e.type)) return -SDO_LENGTH;
    raw = get_le(buf, size);
    if (e.type == T_F32) {
        f = bits_f32((uint32_t)raw);
        if (!isfinite(f)) return -SDO_RANGE; /* not a value the device has */
    }
    switch (index) {
    case 0x1003: /* sub 0: writing 0 clears the history, nothing else */
        if (raw != 0u) return -SDO_RANGE;
        faults_clear_history();
        return 0;
    case 0x1017:
        nvm.heartbeat_ms = (uint16_t)raw;
        return 0;
    case 0x2000:
        if (raw > STRATEGY_SAGE_HUSA) return -SDO_RANGE;
        nvm.strategy = (uint8_t)raw;
        ctl_restart_logic();
        return 0;
    case 0x2001:
        if (!(f >= 0.0f && f <= SPEED_SETPOINT_MAX_RPM)) return -SDO_RANGE;
        nvm.speed_setpoint_rpm = f;
        ctl_set_speed(f);
        return 0;
    case 0x2002:
        if (raw != 1u) return -SDO_RANGE;
        faults_clear();
        return 0;
    case 0x2010:
        cal_set(&nvm.staged, sub - 1, f);
        return 0;
    case 0x2011:
        if (raw != 1u) return -SDO_RANGE;
        if (!cal_valid(&nvm.staged)) {
            fault_raise(FAULT_INVALID_CALIBRATION);
            return -SDO_RANGE;
        }
        nvm.applied = nvm.staged;
        ctl_restart_logic();
        return 0;
    case 0x2020: {
        /* takes effect at the next logic restart (strategy write, apply, reset), as the filter restarts then */
        filter_vector_t v = nvm.sage_husa;
        *filter_value(&v, sub) = f;
        if (!filter_vector_valid(&v)) return -SDO_RANGE;
        nvm.sage_husa = v;
        return 0;
    }
    default:
        return -SDO_READ_ONLY;
    }
}
