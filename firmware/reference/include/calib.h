/* calib.h: the calibration tables (paper Fig. 4) in fixed-size arrays, their validation and the
   protocol order of their values: installation A, B, C, poles 0..2p-1, rise, fall, armature. */
#ifndef CALIB_H
#define CALIB_H

#include "fw_config.h"

typedef struct {
    float installation_deg_e[3];
    float pole_deg_e[N_POLES];
    float delay_rise_s;
    float delay_fall_s;
    float armature_deg_e_per_a;
} cal_table_t;

void cal_zero(cal_table_t *t);
float cal_get(const cal_table_t *t, int i);            /* i in 0..CAL_N_VALUES-1 */
void cal_set(cal_table_t *t, int i, float v);
int cal_valid(const cal_table_t *t);                   /* virtual.py validate_corrections */
/* the table the commutation runs on, made from the applied one (the seeded table defects act here) */
void cal_effective(const cal_table_t *applied, cal_table_t *run);

#endif /* CALIB_H */
