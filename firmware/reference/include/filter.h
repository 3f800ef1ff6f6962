/* filter.h: the commutation predictor of paper Eq. 7-12 in float32: the Sage-Husa adaptive
   Kalman filter and, with adaptation off, the fixed-noise Kalman filter (a port of
   hil/predictors/filters.py, one step per corrected edge). */
#ifndef FILTER_H
#define FILTER_H

#include <stdint.h>

/* which Eq. 12 estimates adapt (filters.ADAPT_*) */
#define ADAPT_Q 1u
#define ADAPT_R 2u
#define ADAPT_SMALL_R 4u
#define ADAPT_SMALL_Q 8u
#define ADAPT_Q_WHITE 16u
#define ADAPT_Q_CURRENT 32u
#define ADAPT_R_CURRENT_FLOOR 64u

enum { GUARD_GATE, GUARD_Q_PD, GUARD_Q_BAND, GUARD_R_PD, GUARD_P_PD, GUARD_DIVERGENCE, GUARD_LOST_LOCK, N_GUARDS };

/* the nine settings the object dictionary carries (bldc/contract.py filter_vector) */
typedef struct {
    float forgetting_b;
    float q0[3];
    float r0[2];
    float p0[3];
} filter_vector_t;

/* everything else the filter runs on (FilterSettings.params) */
typedef struct {
    float b, r_b;
    uint32_t interval, r_interval, warmup;
    float gate, band, floor;
    uint32_t mask;
    uint32_t divergence_run;
    float huber_c, huber_kappa;
    uint8_t gate_state;
    float r_i_floor, r_match_hi, r_match_lo, cusum_h;
    float accel_per_amp;   /* p K_T / J */
    float load_per_wm2;    /* p M / J */
    float load_per_wm;     /* p B / J (friction) */
} filter_params_t;

typedef struct {
    filter_params_t fp;
    filter_vector_t v;
    uint8_t sh;             /* 1: the Sage-Husa strategy's filter */
    float x[3], P[9], Q[9], R[4], Qn[9];
    float small_q[3], small_r[2], acc_small_r[2], acc_small_q[3];
    uint32_t n_acc, k_interval;
    float acc_R[2], acc_R_mean[2];
    uint32_t n_acc_r, k_interval_r;
    float q_raw[2];
    uint32_t k_step;
    uint8_t initialised;
    float last_nis, gated_run, dt_prev;
    float acc_z0[3], acc_edge[3], edge_stats[3];
    float prev_innov, acc_white[2], coef[2], cusum[6], changed[2];
    uint32_t guards[N_GUARDS];
    uint8_t has_last;
    int64_t last_t;         /* the last corrected edge, ticks */
    float x_pred_theta;     /* the last step's predicted angle (lost-lock test) */
} filter_t;

extern const filter_vector_t FILTER_SH_DEFAULT;
extern const filter_vector_t FILTER_KF_DEFAULT;

int filter_vector_valid(const filter_vector_t *v);
/* adaptive = 1: Sage-Husa (adapt mask 114, the tuned design), 0: fixed-noise Kalman filter */
void filter_init(filter_t *f, const filter_vector_t *v, int adaptive);
void filter_restart(filter_t *f);   /* predictor.reset(): state, counters and guards from the settings */
/* one corrected edge; returns 1 and the predicted next commutation (ticks) once two edges were
   seen, 0 on the first (no prediction), -1 when t does not increase (nothing done) */
int filter_update(filter_t *f, int64_t t_ticks, float current_a, int64_t *predicted_ticks);
uint32_t filter_covariance_repairs(const filter_t *f);
uint32_t filter_guard_total(const filter_t *f);

#endif /* FILTER_H */
