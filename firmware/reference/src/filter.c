/* filter.c: Sage-Husa adaptive Kalman filter and fixed-noise Kalman filter (paper Eq. 7-12), a
   float32 port of hil/predictors/filters.py (same equations, guards and order of operations). The
   state is X = [w (rad/s e), theta (rad, from the last corrected edge), I (A, mean |i|)]. */
#include <math.h>
#include <string.h>

#include "filter.h"
#include "fw_config.h"
#include "defects.h"

/* peer_settings.TUNED rounded to two digits (registry.pump_defaults) */
const filter_vector_t FILTER_SH_DEFAULT = {0.9916f, {0.0003f, 1e-9f, 0.00085f}, {0.0f, 0.018f}, {5e4f, 5e4f, 5e4f}};
const filter_vector_t FILTER_KF_DEFAULT = {0.98f, {0.013f, 1e-9f, 0.0016f}, {0.00074f, 0.0093f}, {5e4f, 5e4f, 5e4f}};

#define CHI2_2DOF_999 13.815510557964274f
#define HUBER_C_95 2.4477468306808166f
#define HUBER_KAPPA_95 0.9720501841799771f
/* variance_match_bounds(30, 2400 Hz, 1000 s): the tuned R interval of 30 edges */
#define R_MATCH_HI_30 3.458510965688847f
#define R_MATCH_LO_30 0.10482028200616153f
#define WHITENESS_GAIN 4.0f
#define CUSUM_UP 10.0f
#define CUSUM_DOWN 0.1f
/* float32 rounding: a negative eigenvalue within this fraction of the magnitude the matrix was
   computed from (the largest eigenvalue, or for P the largest diagonal of P_k,k-1: the Joseph form
   cancels terms that large, e.g. 5e4 - 991 x 50.4 in the first step on R_theta = 0) is rounding, not
   a lost covariance (the double-precision reference uses 1e-12 of the largest eigenvalue) */
#define REPAIR_REL_TOL 1e-5f

int filter_vector_valid(const filter_vector_t *v)
{
    int i;
    if (!(v->forgetting_b > 0.0f && v->forgetting_b < 1.0f)) return 0;
    for (i = 0; i < 3; i++) {
        if (!(isfinite(v->q0[i]) && v->q0[i] > 0.0f)) return 0;
        if (!(isfinite(v->p0[i]) && v->p0[i] > 0.0f)) return 0;
    }
    for (i = 0; i < 2; i++)
        if (!(isfinite(v->r0[i]) && v->r0[i] >= 0.0f)) return 0;
    return 1;
}

void filter_restart(filter_t *f)
{
    filter_params_t fp = f->fp;
    filter_vector_t v = f->v;
    uint8_t sh = f->sh;
    int i;
    memset(f, 0, sizeof *f);
    f->fp = fp;
    f->v = v;
    f->sh = sh;
    for (i = 0; i < 3; i++) {
        f->P[4 * i] = v.p0[i];
        f->Q[4 * i] = v.q0[i];
        f->Qn[4 * i] = v.q0[i];
    }
    f->q_raw[0] = f->Q[0];
    f->q_raw[1] = f->Q[8];
    f->R[0] = v.r0[0];
    f->R[3] = v.r0[1];
}

void filter_init(filter_t *f, const filter_vector_t *v, int adaptive)
{
    filter_params_t *fp = &f->fp;
    float res = 1e-3f; /* current_resolution_a */
    memset(f, 0, sizeof *f);
    f->v = *v;
    f->sh = (uint8_t)(adaptive != 0);
    fp->b = v->forgetting_b;
    fp->interval = adaptive ? 60u : 120u;
    fp->r_b = adaptive ? 0.84f : 0.98f;
    fp->r_interval = adaptive ? 30u : 120u;
    fp->warmup = 120u;
    fp->gate = CHI2_2DOF_999;
    fp->band = 100.0f;
    fp->floor = 1e-9f;
    fp->mask = adaptive ? (ADAPT_R | ADAPT_Q_WHITE | ADAPT_Q_CURRENT | ADAPT_R_CURRENT_FLOOR) : 0u;
    fp->divergence_run = 3u;
    fp->huber_c = HUBER_C_95;
    fp->huber_kappa = HUBER_KAPPA_95;
    fp->gate_state = adaptive ? 1u : 0u;
    fp->r_i_floor = res * res / 12.0f;
    if (fp->mask & ADAPT_R_CURRENT_FLOOR && v->r0[1] > fp->r_i_floor) fp->r_i_floor = v->r0[1];
    fp->r_match_hi = adaptive ? R_MATCH_HI_30 : 1.9066439030315223f;
    fp->r_match_lo = adaptive ? R_MATCH_LO_30 : 0.42750721300066064f;
    fp->cusum_h = 25.0f;
#if defined(HIL_DEFECT_SAGE_HUSA_WITHOUT_ADAPTATION)
    if (adaptive) fp->mask = 0u;
#endif
#if defined(HIL_DEFECT_SAGE_HUSA_NOISE_WITHOUT_MEMORY)
    if (adaptive) {
        fp->r_b = 1e-3f;
        fp->r_interval = 2u;
        fp->b = 1e-3f;
        fp->interval = 1u;
        fp->r_match_hi = 0.0f; /* variance_match_bounds of an interval < 3: off */
        fp->r_match_lo = 0.0f;
    }
#endif
    /* MotorModel.from_plant: K_T = 3 ke per ampere of mean |i|, M the fan coefficient, B the friction */
    fp->accel_per_amp = (float)POLE_PAIRS * (3.0f * MOTOR_KE_V_S) / MOTOR_J_KG_M2;
    fp->load_per_wm2 = (float)POLE_PAIRS * MOTOR_FAN / MOTOR_J_KG_M2;
    fp->load_per_wm = (float)POLE_PAIRS * MOTOR_FRICTION / MOTOR_J_KG_M2;
    filter_restart(f);
}

/* ---- small symmetric eigen-solver (Jacobi) for the covariance repair ----------------------- */
static void jacobi_eig(float *a, int n, float *w, float *v)
{
    int i, j, p, q, sweep;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) v[i * n + j] = (i == j) ? 1.0f : 0.0f;
    for (sweep = 0; sweep < 30; sweep++) {
        float off = 0.0f;
        for (p = 0; p < n; p++)
            for (q = p + 1; q < n; q++) off += a[p * n + q] * a[p * n + q];
        if (off == 0.0f) break;
        for (p = 0; p < n; p++) {
            for (q = p + 1; q < n; q++) {
                float apq = a[p * n + q], theta, t, c, s;
                if (apq == 0.0f) continue;
                theta = (a[q * n + q] - a[p * n + p]) / (2.0f * apq);
                t = (theta >= 0.0f ? 1.0f : -1.0f) / (fabsf(theta) + sqrtf(theta * theta + 1.0f));
                c = 1.0f / sqrtf(t * t + 1.0f);
                s = t * c;
                for (i = 0; i < n; i++) { /* A = J^T A J */
                    float aip = a[i * n + p], aiq = a[i * n + q];
                    a[i * n + p] = c * aip - s * aiq;
                    a[i * n + q] = s * aip + c * aiq;
                }
                for (i = 0; i < n; i++) {
                    float api = a[p * n + i], aqi = a[q * n + i];
                    a[p * n + i] = c * api - s * aqi;
                    a[q * n + i] = s * api + c * aqi;
                }
                for (i = 0; i < n; i++) {
                    float vip = v[i * n + p], viq = v[i * n + q];
                    v[i * n + p] = c * vip - s * viq;
                    v[i * n + q] = s * vip + c * viq;
                }
            }
        }
    }
    for (i = 0; i < n; i++) w[i] = a[i * n + i];
}

/* symmetrise m (n x n, row-major), floor its eigenvalues; 1 if it was indefinite beyond the
   rounding of values of magnitude ``scale`` (a repair) */
static int sym_pd_floor(float *m, int n, float floor, float scale)
{
    int i, j, k, ok = 0, repaired;
    float a[9], w[3], v[9], wmin, wmax;
    for (i = 0; i < n; i++)
        for (j = i + 1; j < n; j++) {
            float x = 0.5f * (m[i * n + j] + m[j * n + i]);
            m[i * n + j] = x;
            m[j * n + i] = x;
        }
    if (n == 2) {
        ok = m[0] > floor && m[3] - m[1] * m[1] / m[0] > floor;
    } else if (m[0] > floor) {
        float l10 = m[1] / sqrtf(m[0]), l20 = m[2] / sqrtf(m[0]);
        float d1 = m[4] - l10 * l10;
        if (d1 > floor) {
            float l21 = (m[5] - l20 * l10) / sqrtf(d1);
            ok = m[8] - l20 * l20 - l21 * l21 > floor;
        }
    }
    if (ok) return 0;
    memcpy(a, m, sizeof(float) * (size_t)(n * n));
    jacobi_eig(a, n, w, v);
    wmin = w[0];
    wmax = fabsf(w[0]);
    for (i = 1; i < n; i++) {
        if (w[i] < wmin) wmin = w[i];
        if (fabsf(w[i]) > wmax) wmax = fabsf(w[i]);
    }
    if (scale > wmax) wmax = scale;
    repaired = wmin < -REPAIR_REL_TOL * (wmax > 1.0f ? wmax : 1.0f);
    for (i = 0; i < n; i++)
        if (w[i] < floor) w[i] = floor;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            float s = 0.0f;
            for (k = 0; k < n; k++) s += v[i * n + k] * w[k] * v[j * n + k];
            a[i * n + j] = s;
        }
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) m[i * n + j] = 0.5f * (a[i * n + j] + a[j * n + i]);
    return repaired;
}

static void mm3(const float *a, const float *b, float *out)
{
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

static void mm3t(const float *a, const float *b, float *out)
{
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            out[3 * i + j] = a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] + a[3 * i + 2] * b[3 * j + 2];
}

/* the firmware's store of R_theta (the seeded R defects write here what the filter computed) */
static void store_r_theta(filter_t *f, float before, float after)
{
#if defined(HIL_DEFECT_SAGE_HUSA_R_FROZEN)
    if (after != before) f->R[0] = before > 0.0f ? before : after;
#elif defined(HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SIGN)
    if (after != before) {
        float v = before - (after - before);
        f->R[0] = v > 0.0f ? v : 0.0f;
    }
#elif defined(HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SCALE)
    if (after != before) f->R[0] = 0.25f * after;
#else
    (void)f;
    (void)before;
    (void)after;
#endif
}

static void adapt_small_rq(filter_t *f, uint32_t k, float z_theta, float z_i, float hx0, float hx1,
                           const float *x_new, const float *phi, const float *x, const float *u)
{
    const filter_params_t *fp = &f->fp;
    int i;
    f->acc_small_r[0] += z_theta - hx0;
    f->acc_small_r[1] += z_i - hx1;
    for (i = 0; i < 3; i++)
        f->acc_small_q[i] += x_new[i] - (phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i]);
    f->n_acc += 1u;
    if (f->n_acc >= fp->interval || k + 1u == fp->warmup) {
        float n = (float)f->n_acc, b = fp->b;
        float dj = (1.0f - b) / (1.0f - powf(b, (float)f->k_interval + 1.0f));
        if (fp->mask & ADAPT_SMALL_R)
            for (i = 0; i < 2; i++) f->small_r[i] = (1.0f - dj) * f->small_r[i] + dj * f->acc_small_r[i] / n;
        if (fp->mask & ADAPT_SMALL_Q)
            for (i = 0; i < 3; i++) f->small_q[i] = (1.0f - dj) * f->small_q[i] + dj * f->acc_small_q[i] / n;
        f->acc_small_r[0] = f->acc_small_r[1] = 0.0f;
        f->acc_small_q[0] = f->acc_small_q[1] = f->acc_small_q[2] = 0.0f;
        f->n_acc = 0u;
        f->k_interval += 1u;
    }
}

static void rebase_p(filter_t *f, float r_warm, float r_new, float dt)
{
    float two_ww, two_wt, scale;
    if (!(r_new > r_warm && dt > 0.0f)) return;
    two_ww = 2.0f * r_new / (dt * dt);
    two_wt = r_new / dt;
    scale = r_warm > 0.0f ? r_new / r_warm : INFINITY;
    if (f->P[0] * scale >= two_ww) {
        f->P[0] = two_ww;
        f->P[1] = f->P[3] = two_wt;
        f->P[4] = r_new;
        f->P[2] = f->P[5] = f->P[6] = f->P[7] = 0.0f;
    } else {
        f->P[0] *= scale;
        f->P[1] *= scale;
        f->P[3] *= scale;
        f->P[4] *= scale;
    }
}

static void restart_r_interval(filter_t *f)
{
    f->acc_R[0] = f->acc_R[1] = 0.0f;
    f->acc_R_mean[0] = f->acc_R_mean[1] = 0.0f;
    f->acc_edge[0] = f->acc_edge[1] = f->acc_edge[2] = 0.0f;
    f->acc_z0[0] = f->acc_z0[1] = f->acc_z0[2] = 0.0f;
    f->n_acc_r = 0u;
}

static void accumulate_r(filter_t *f, float innov0, float innov1, float nis, const float *p_pred)
{
    float c = f->fp.huber_c;
    float m = nis > 0.0f ? sqrtf(nis) : 0.0f;
    float w = m <= c ? 1.0f : c / m;
    float g = w / f->fp.huber_kappa, sg;
    f->acc_R[0] += g * innov0 * innov0 - p_pred[4];
    f->acc_R[1] += g * innov1 * innov1 - p_pred[8];
    sg = sqrtf(g);
    f->acc_R_mean[0] += sg * innov0;
    f->acc_R_mean[1] += sg * innov1;
    f->n_acc_r += 1u;
    f->acc_z0[0] += innov0;
    f->acc_z0[1] += innov0 * innov0;
    f->acc_z0[2] += p_pred[4];
}

static void variance_match(filter_t *f, float n)
{
    float ne = f->acc_edge[0], mean, r_edge, var0, r_innov;
    if (!(f->fp.r_match_hi > 0.0f && ne > 2.0f)) return;
    mean = f->acc_edge[1] / ne;
    r_edge = (f->acc_edge[2] - ne * mean * mean) / (ne - 1.0f) / 6.0f;
    if (!(r_edge > 0.0f) || (f->fp.r_match_lo * f->R[0] <= r_edge && r_edge <= f->fp.r_match_hi * f->R[0])) return;
    var0 = n > 1.0f ? (f->acc_z0[1] - f->acc_z0[0] * f->acc_z0[0] / n) / (n - 1.0f) : 0.0f;
    r_innov = var0 - f->acc_z0[2] / n;
    f->R[0] = r_innov >= f->fp.r_match_lo * r_edge ? r_innov : r_edge;
}

static void adapt_r(filter_t *f, uint32_t k, float innov0, float innov1, float nis, const float *p_pred)
{
    const filter_params_t *fp = &f->fp;
    int warm = k < fp->warmup, i;
    float n, b, dj, unbias, r_before;
    uint32_t j;
    accumulate_r(f, innov0, innov1, nis, p_pred);
    if ((warm && k + 1u != fp->warmup) || (!warm && f->n_acc_r < fp->r_interval)) return;
    n = (float)f->n_acc_r;
    j = f->k_interval_r;
    r_before = f->R[0];
    b = fp->r_b;
    dj = (1.0f - b) / (1.0f - powf(b, (float)j + 1.0f));
    unbias = n > 1.0f ? n / (n - 1.0f) : 1.0f;
    for (i = 0; i < 2; i++) {
        float mean = f->acc_R_mean[i] / n;
        float term = unbias * (f->acc_R[i] - n * mean * mean) / n;
        f->R[3 * i] = (1.0f - dj) * f->R[3 * i] + dj * term;
    }
    if (!warm) variance_match(f, n);
    if (j == 0u && f->edge_stats[0] > 2.0f) {
        float mean = f->edge_stats[1] / f->edge_stats[0];
        float v = f->edge_stats[2] / f->edge_stats[0] - mean * mean;
        f->R[0] = (v > 0.0f ? v : 0.0f) / 6.0f;
        rebase_p(f, r_before, f->R[0], f->dt_prev);
    }
    f->R[1] = 0.0f;
    f->R[2] = 0.0f;
    if (sym_pd_floor(f->R, 2, fp->floor, 0.0f)) f->guards[GUARD_R_PD] += 1u;
    if (f->R[3] < fp->r_i_floor) f->R[3] = fp->r_i_floor;
    restart_r_interval(f);
    f->k_interval_r = j + 1u;
    f->changed[0] = f->changed[1] = 0.0f;
}

static void innovation_inverse(const filter_t *f, const float *p_pred, float *inv)
{
    float s00 = p_pred[4] + f->R[0], s01 = p_pred[5] + f->R[1];
    float s10 = p_pred[7] + f->R[2], s11 = p_pred[8] + f->R[3];
    float det = s00 * s11 - s01 * s10;
    inv[0] = s11 / det;
    inv[1] = -s01 / det;
    inv[2] = -s10 / det;
    inv[3] = s00 / det;
}

/* the chi-square gate and the divergence fade: returns 1 gated, 2 faded, 0 neither */
static int gate(filter_t *f, uint32_t k, uint32_t gate_from, float innov0, float nis, float *p_pred)
{
    const filter_params_t *fp = &f->fp;
    float run;
    int i;
    if (!(fp->gate_state && k >= gate_from && nis > fp->gate)) {
        f->gated_run = 0.0f;
        return 0;
    }
    run = f->gated_run;
    if (innov0 >= 0.0f) run = run > 0.0f ? run + 1.0f : 1.0f;
    else run = run < 0.0f ? run - 1.0f : -1.0f;
    f->gated_run = run;
    if (fp->divergence_run > 0u && fabsf(run) >= (float)fp->divergence_run) {
        float fade = nis / 2.0f;
        for (i = 0; i < 9; i++) p_pred[i] *= fade;
        f->guards[GUARD_DIVERGENCE] += 1u;
        return 2;
    }
    f->guards[GUARD_GATE] += 1u;
    return 1;
}

static void kalman_update(filter_t *f, float innov0, float innov1, const float *inv, const float *x_pred,
                          const float *p_pred, float *gain, float *x_new, float *p_new)
{
    float ikh[9], tmp[9];
    int i, j;
    for (i = 0; i < 3; i++) {
        float a0 = p_pred[3 * i + 1], a1 = p_pred[3 * i + 2];
        gain[2 * i] = a0 * inv[0] + a1 * inv[2];
        gain[2 * i + 1] = a0 * inv[1] + a1 * inv[3];
    }
    for (i = 0; i < 3; i++) x_new[i] = x_pred[i] + gain[2 * i] * innov0 + gain[2 * i + 1] * innov1;
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++) ikh[3 * i + j] = i == j ? 1.0f : 0.0f;
        ikh[3 * i + 1] -= gain[2 * i];
        ikh[3 * i + 2] -= gain[2 * i + 1];
    }
    mm3(ikh, p_pred, tmp);
    mm3t(tmp, ikh, p_new);
    for (i = 0; i < 3; i++) {
        float g0 = gain[2 * i], g1 = gain[2 * i + 1];
        for (j = 0; j < 3; j++) {
            float h0 = gain[2 * j], h1 = gain[2 * j + 1];
            p_new[3 * i + j] += g0 * (f->R[0] * h0 + f->R[1] * h1) + g1 * (f->R[2] * h0 + f->R[3] * h1);
        }
    }
    {
        float scale = p_pred[0] > p_pred[4] ? p_pred[0] : p_pred[4];
        if (p_pred[8] > scale) scale = p_pred[8];
        if (sym_pd_floor(p_new, 3, 1e-12f, scale)) f->guards[GUARD_P_PD] += 1u;
    }
}

static void adapt_q_whiteness(filter_t *f, uint32_t k, float innov0)
{
    const filter_params_t *fp = &f->fp;
    f->acc_white[0] += innov0 * f->prev_innov;
    f->acc_white[1] += innov0 * innov0;
    if (f->acc_white[1] > 0.0f && (k + 1u - fp->warmup) % fp->interval == 0u) {
        float c1 = f->acc_white[0] / f->acc_white[1];
        float q = f->Q[0] * expf(WHITENESS_GAIN * c1);
        float lo = f->Qn[0] / fp->band, hi = f->Qn[0] * fp->band;
        f->Q[0] = q < lo ? lo : (q > hi ? hi : q);
        f->acc_white[0] = f->acc_white[1] = 0.0f;
    }
}

static float edge_noise(filter_t *f, float dt, int warm)
{
    float x2 = NAN;
    if (f->dt_prev > 0.0f) {
        float *at = warm ? f->edge_stats : f->acc_edge;
        x2 = FW_SECTOR_RAD / dt * (dt - f->dt_prev);
        at[0] += 1.0f;
        at[1] += x2;
        at[2] += x2 * x2;
    }
    f->dt_prev = dt;
    return x2;
}

static void change_detect(filter_t *f, float x2)
{
    float r, u;
    int side, i;
    if (f->changed[1] > 0.0f && x2 == x2) {
        f->changed[0] += x2 * x2 / 6.0f;
        f->changed[1] += 1.0f;
        f->R[0] = f->changed[0] / f->changed[1];
    }
    r = f->R[0];
    if (!(r > 0.0f && x2 == x2)) return;
    u = x2 * x2 / (6.0f * r);
    for (side = 0; side < 2; side++) {
        float v = side == 0 ? CUSUM_UP : CUSUM_DOWN;
        float *c = &f->cusum[3 * side];
        float g = c[0] + 0.5f * u * (1.0f - 1.0f / v) - 0.5f * logf(v);
        if (g <= 0.0f) {
            c[0] = c[1] = c[2] = 0.0f;
            continue;
        }
        c[0] = g;
        c[1] += x2 * x2 / 6.0f;
        c[2] += 1.0f;
        if (g > f->fp.cusum_h) {
            f->changed[0] = c[1];
            f->changed[1] = c[2];
            f->R[0] = c[1] / c[2];
            for (i = 0; i < 6; i++) f->cusum[i] = 0.0f;
            restart_r_interval(f);
            return;
        }
    }
}

static void adapt_q(filter_t *f, uint32_t k, float innov0, float innov1, const float *gain, const float *p_new,
                    const float *phi_p_phi)
{
    const filter_params_t *fp = &f->fp;
    float b = fp->b, d = (1.0f - b) / (1.0f - powf(b, (float)k + 1.0f));
    int clamped = 0, i, r;
    for (r = 0; r < 2; r++) {
        int i_diag = r == 0 ? 0 : 2;
        float kz, term, nominal, lo, hi, v;
        if (i_diag == 0 && ((fp->mask & ADAPT_Q_WHITE) || !(fp->mask & ADAPT_Q))) continue;
        kz = gain[2 * i_diag] * innov0 + gain[2 * i_diag + 1] * innov1;
        term = kz * kz + p_new[4 * i_diag] - phi_p_phi[4 * i_diag];
        nominal = f->Qn[4 * i_diag];
        lo = nominal / fp->band;
        hi = nominal * fp->band;
        v = (1.0f - d) * f->q_raw[r] + d * term;
        v = v < -hi ? -hi : (v > hi ? hi : v);
        f->q_raw[r] = v;
        if (!(v > 0.0f)) f->guards[GUARD_Q_PD] += 1u;
        if (v < lo) {
            v = lo;
            clamped = 1;
        } else if (v >= hi) {
            v = hi;
            clamped = 1;
        }
        f->Q[4 * i_diag] = v;
    }
    for (i = 1; i < 8; i++)
        if (i != 4) f->Q[i] = 0.0f;
    f->Q[4] = f->Qn[4];
    if (clamped) f->guards[GUARD_Q_BAND] += 1u;
}

/* one commutation cycle: Eq. 9 prediction, Eq. 11 update, Eq. 12 adaptation */
static void step(filter_t *f, float z_theta, float z_i, float dt, float accel_per_amp, float decel_load)
{
    const filter_params_t *fp = &f->fp;
    float phi[9], u[3], x[3], p[9], x_pred[3], p_pred[9], tmp[9], gain[6], p_new[9], phi_p_phi[9], x_new[3];
    float a = accel_per_amp, hx0, hx1, innov0, innov1, inv[4], nis, x2;
    uint32_t k = f->k_step, gate_from, mask = fp->mask;
    int warm = k < fp->warmup, g, gated, faded, settled, q_on, i;

    memset(gain, 0, sizeof gain);
    phi[0] = 1.0f; phi[1] = 0.0f; phi[2] = a * dt;
    phi[3] = dt; phi[4] = 1.0f; phi[5] = 0.5f * a * dt * dt;
    phi[6] = 0.0f; phi[7] = 0.0f; phi[8] = 1.0f;
    u[0] = -dt * decel_load;
    u[1] = -0.5f * dt * dt * decel_load;
    u[2] = 0.0f;
    for (i = 0; i < 3; i++) x[i] = f->x[i];
    for (i = 0; i < 9; i++) p[i] = f->P[i];
    for (i = 0; i < 3; i++)
        x_pred[i] = phi[3 * i] * x[0] + phi[3 * i + 1] * x[1] + phi[3 * i + 2] * x[2] + u[i] + f->small_q[i];
    mm3(phi, p, tmp);
    mm3t(tmp, phi, phi_p_phi);
    for (i = 0; i < 9; i++) p_pred[i] = phi_p_phi[i] + f->Q[i];
    f->x_pred_theta = x_pred[1];

    hx0 = x_pred[1];
    hx1 = x_pred[2];
    innov0 = z_theta - hx0 - f->small_r[0];
    innov1 = z_i - hx1 - f->small_r[1];
    innovation_inverse(f, p_pred, inv);
    nis = innov0 * (inv[0] * innov0 + inv[1] * innov1) + innov1 * (inv[2] * innov0 + inv[3] * innov1);
    gate_from = fp->warmup + ((mask & ADAPT_R) ? fp->r_interval : 0u);
    g = gate(f, k, gate_from, innov0, nis, p_pred);
    gated = g == 1;
    faded = g == 2;
    if (gated) {
        for (i = 0; i < 3; i++) x_new[i] = x_pred[i];
        for (i = 0; i < 9; i++) p_new[i] = p_pred[i];
    } else {
        if (faded) innovation_inverse(f, p_pred, inv);
        kalman_update(f, innov0, innov1, inv, x_pred, p_pred, gain, x_new, p_new);
    }
    for (i = 0; i < 3; i++) f->x[i] = x_new[i];
    f->x[1] -= FW_SECTOR_RAD;
    for (i = 0; i < 9; i++) f->P[i] = p_new[i];
    f->last_nis = nis;
    f->k_step = k + 1u;
    if (mask == 0u) return;
    q_on = k >= gate_from;
    if ((mask & ADAPT_Q_WHITE) && q_on) adapt_q_whiteness(f, k, innov0);
    f->prev_innov = innov0;
    x2 = edge_noise(f, dt, warm);
    if (fp->cusum_h > 0.0f && (mask & ADAPT_R) && !warm) change_detect(f, x2);
    settled = (float)k >= 0.5f * (float)fp->warmup;
    if ((mask & ADAPT_R) && settled && !faded) adapt_r(f, k, innov0, innov1, nis, p_pred);
    if (gated) return;
    if ((mask & (ADAPT_SMALL_R | ADAPT_SMALL_Q)) && settled)
        adapt_small_rq(f, k, z_theta, z_i, hx0, hx1, x_new, phi, x, u);
    if (q_on && (mask & (ADAPT_Q | ADAPT_Q_CURRENT))) adapt_q(f, k, innov0, innov1, gain, p_new, phi_p_phi);
}

static float predict_next_s(const filter_t *f, float accel_per_amp, float decel_load)
{
    float w = f->x[0], theta = f->x[1];
    float eps = accel_per_amp * f->x[2] - decel_load;
    float d = FW_SECTOR_RAD - theta, disc = w * w + 2.0f * eps * d;
    if (w <= 0.0f || d <= 0.0f) return (d > 0.0f ? d : 0.0f) / (w > 1e-9f ? w : 1e-9f);
    if (disc < 0.0f) disc = 0.0f;
    return 2.0f * d / (w + sqrtf(disc));
}

static void restart_state(filter_t *f, float dt, float current)
{
    float r = f->R[0];
    f->x[0] = FW_SECTOR_RAD / dt;
    f->x[1] = 0.0f;
    f->x[2] = current;
    if (r > 0.0f) {
        f->P[0] = 2.0f * r / (dt * dt);
        f->P[1] = f->P[3] = r / dt;
        f->P[4] = r;
        f->P[2] = f->P[5] = f->P[6] = f->P[7] = 0.0f;
    }
    f->gated_run = 0.0f;
}

/* filters.edge: the whole online update of one corrected edge; the time to the next commutation */
static float filter_edge(filter_t *f, float dt, float current)
{
    float w_m;
    if (!f->initialised) {
        f->x[0] = FW_SECTOR_RAD / dt;
        f->x[1] = 0.0f;
        f->x[2] = current;
        f->initialised = 1u;
    } else {
        float innov_theta, w;
        step(f, FW_SECTOR_RAD, current, dt, f->coef[0], f->coef[1]);
        innov_theta = FW_SECTOR_RAD - f->x_pred_theta;
        w = f->x[0];
        if (!(w > 0.0f && fabsf(innov_theta) <= FW_SECTOR_RAD)) {
            restart_state(f, dt, current);
            f->guards[GUARD_LOST_LOCK] += 1u;
        }
    }
    w_m = f->x[0] / (float)POLE_PAIRS;
    f->coef[0] = f->fp.accel_per_amp;
    f->coef[1] = f->fp.load_per_wm2 * w_m * w_m + f->fp.load_per_wm * w_m; /* Eq. 8's load: fan and friction */
    return predict_next_s(f, f->coef[0], f->coef[1]);
}

int filter_update(filter_t *f, int64_t t_ticks, float current_a, int64_t *predicted_ticks)
{
    float dt, tau, r_before;
    if (!f->has_last) {
        f->has_last = 1u;
        f->last_t = t_ticks;
        return 0;
    }
    if (!(t_ticks > f->last_t)) return -1;
    dt = (float)(t_ticks - f->last_t) * SECONDS_PER_TICK;
    f->last_t = t_ticks;
    r_before = f->R[0];
    tau = filter_edge(f, dt, current_a);
    if (f->sh) store_r_theta(f, r_before, f->R[0]);
    if (!(tau == tau) || tau > 1.0f) tau = 1.0f; /* a prediction beyond a second is no prediction */
    *predicted_ticks = t_ticks + (int64_t)(tau * (float)TIMER_HZ + 0.5f);
    return 1;
}

uint32_t filter_covariance_repairs(const filter_t *f)
{
    return f->guards[GUARD_R_PD] + f->guards[GUARD_P_PD];
}

uint32_t filter_guard_total(const filter_t *f)
{
    uint32_t s = 0u;
    int i;
    for (i = 0; i < N_GUARDS; i++) s += f->guards[i];
    return s;
}
