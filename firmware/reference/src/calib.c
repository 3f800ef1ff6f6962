/* calib.c: calibration tables: validation exactly as hil/controller/virtual.py validate_corrections. */
#include <math.h>
#include <string.h>

#include "calib.h"
#include "defects.h"

void cal_zero(cal_table_t *t)
{
    memset(t, 0, sizeof *t);
}

float cal_get(const cal_table_t *t, int i)
{
    if (i < 3) return t->installation_deg_e[i];
    if (i < 3 + N_POLES) return t->pole_deg_e[i - 3];
    if (i == 3 + N_POLES) return t->delay_rise_s;
    if (i == 4 + N_POLES) return t->delay_fall_s;
    return t->armature_deg_e_per_a;
}

void cal_set(cal_table_t *t, int i, float v)
{
    if (i < 3) t->installation_deg_e[i] = v;
    else if (i < 3 + N_POLES) t->pole_deg_e[i - 3] = v;
    else if (i == 3 + N_POLES) t->delay_rise_s = v;
    else if (i == 4 + N_POLES) t->delay_fall_s = v;
    else t->armature_deg_e_per_a = v;
}

/* the bounds are compared in double: the stored float32 value against the library's decimal
   bound, as the reference compares them (float32(500e-6) lies above 500e-6 and is refused) */
int cal_valid(const cal_table_t *t)
{
#if defined(HIL_DEFECT_NO_TABLE_VALIDATION)
    (void)t;
    return 1;
#else
    int i;
    for (i = 0; i < 3; i++) {
        double v = (double)t->installation_deg_e[i];
        if (!isfinite(v) || fabs(v) > CAL_MAX_INSTALLATION_DEG_E) return 0;
    }
    for (i = 0; i < N_POLES; i++) {
        double v = (double)t->pole_deg_e[i];
        if (!isfinite(v) || fabs(v) > CAL_MAX_POLE_DEG_E) return 0;
    }
    {
        double r = (double)t->delay_rise_s, f = (double)t->delay_fall_s, a = (double)t->armature_deg_e_per_a;
        if (!isfinite(r) || !(r >= 0.0 && r <= CAL_MAX_DELAY_S)) return 0;
        if (!isfinite(f) || !(f >= 0.0 && f <= CAL_MAX_DELAY_S)) return 0;
        if (!isfinite(a) || fabs(a) > CAL_MAX_ARMATURE_DEG_E_PER_A) return 0;
    }
    return 1;
#endif
}

void cal_effective(const cal_table_t *applied, cal_table_t *run)
{
    *run = *applied;
#if defined(HIL_DEFECT_POLE_TABLE_ONE_POLE_OFF)
    {
        int j;
        for (j = 0; j < N_POLES; j++) run->pole_deg_e[j] = applied->pole_deg_e[(j + N_POLES - 1) % N_POLES];
    }
#endif
#if defined(HIL_DEFECT_RISE_FALL_DELAYS_SWAPPED)
    run->delay_rise_s = applied->delay_fall_s;
    run->delay_fall_s = applied->delay_rise_s;
#endif
#if defined(HIL_DEFECT_INSTALLATION_ON_WRONG_SENSOR)
    run->installation_deg_e[0] = applied->installation_deg_e[2];
    run->installation_deg_e[1] = applied->installation_deg_e[0];
    run->installation_deg_e[2] = applied->installation_deg_e[1];
#endif
#if defined(HIL_DEFECT_ARMATURE_SIGN_INVERTED)
    run->armature_deg_e_per_a = -applied->armature_deg_e_per_a;
#endif
#if defined(HIL_DEFECT_DELAY_APPLIED_AT_90_PERCENT)
    run->delay_rise_s = 0.9f * applied->delay_rise_s;
    run->delay_fall_s = 0.9f * applied->delay_fall_s;
#endif
#if defined(HIL_DEFECT_TABLE_NEVER_APPLIED)
    cal_zero(run);
#endif
}
