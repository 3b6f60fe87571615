/* Sampled free runs of the physics-structured surrogate whose correction reads the control alone.
 *
 * The twin of PhysicsModel's torch path (activelearn/numerics/models/physics.py): the correction is a
 * function of the operating point (throttle, steering), so, per tile of TILE steps of a maneuver, the
 * sampled correction network (network.c) is evaluated once on the tile's distinct control rows; each
 * draw's bounded steady states, lags and noise level follow per row (the gate first moves every
 * draw's raw output towards their mean: z - (1 - weight) mean_s z), and the recurrence left per step
 * and draw is the single track's few flops:
 *
 *   v' = v_ss + (v - v_ss) a_v             (throttle 0 brakes: |v| falls by brake_decel dt)
 *   w' = w_ss + (w - w_ss) a_w,            w_ss = clip(v' tan(delta) / (L understeer) + r_w, +-cap)
 *
 * from the rates `rate_lag` steps back. The per-step spread over draws (the epistemic scale: each
 * draw's correction widened, read from the draws' common past, `widen_draws`), the moments over draws
 * and each draw's aleatoric noise (the counter-based noise of static_rollout.c, so a draw's noise
 * depends only on its key, the maneuver and the step) are added per step.
 *
 * Layout: per tile, every per-draw quantity is stored step-major with the S draws contiguous
 * ([row or step][S]), so each step's recurrence is one vectorised pass over the draws; the draws'
 * rates are then turned back to (S, 2, M, T) and, when asked, integrated to a pose while the tile is
 * in cache (al_pose_tile, the static kernel's integration).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "network.h"

#define TILE 512
#define N_TABLE 11 /* the datasheet's speed at throttle 0, 0.1, ..., 1 */

/* The layout of the parameter vector `p` (physics.py's NATIVE_PARAMETERS, same order). */
enum {
    P_DT,
    P_SPEED_GAIN,
    P_REVERSE_GAIN,
    P_SPEED_LAG,
    P_SCRUB,
    P_UNDERSTEER,
    P_YAW_LAG,
    P_BRAKE_DECEL,
    P_WHEELBASE,
    P_THROTTLE_LIMIT,
    P_SPEED_BOUND, /* residual_bound x the top speed */
    P_YAW_BOUND,   /* residual_bound x the yaw-rate limit */
    P_YAW_CAP,
    P_LOG_LAG_FACTOR,
    P_STD_V, /* the output scalers: a standardised variance of 1 is std_v^2 */
    P_STD_W,
    P_VAR_CAP_V, /* the largest standardised aleatoric variances */
    P_VAR_CAP_W,
    P_SPREAD,
    P_GATE, /* the share of the correction's mean over draws kept (1: all) */
    P_MIRROR, /* 0, or 1 / the steering limit: the correction reads (tau, delta^2) and its yaw residual is
                 multiplied by delta times this (mirror-symmetric by construction) */
    P_TABLE, /* N_TABLE speeds follow */
    P_COUNT = P_TABLE + N_TABLE
};

int al_physics_parameter_count(void) { return P_COUNT; }

/* The datasheet's steady forward speed at |throttle|, interpolated linearly. */
static float table_speed(const float *p, float throttle) {
    float x = fabsf(throttle);
    if (x > p[P_THROTTLE_LIMIT]) x = p[P_THROTTLE_LIMIT];
    x *= 10.0f;
    float i = floorf(x);
    if (i > 9.0f) i = 9.0f;
    const int k = (int)i;
    return p[P_TABLE + k] + (x - i) * (p[P_TABLE + k + 1] - p[P_TABLE + k]);
}

typedef struct {
    const al_network *net;
    const float *p;
    int64_t n_maneuvers, n_steps, rate_lag;
    const float *controls, *start;
    const uint64_t *keys;
    float *rates, *centre, *aleatoric, *epistemic;
    /* the pose (NULL x: none): dt of the log, the lever arm, each maneuver's heading */
    float pose_dt, arm;
    const float *yaw0;
    float *x, *y, *yaw;
} physics_context;

/* Per-draw coefficients of a tile's distinct rows, step-major with the draws contiguous. */
enum { C_VSS, C_AV, C_RW, C_AW, C_SDV, C_SDW, N_COEF };

typedef struct {
    al_scratch *network;
    float *rows_x;     /* a tile's distinct control rows, column layout (2, TILE) */
    float *rows_m;     /* with P_MIRROR: the rows as the correction reads them, (tau, delta^2) */
    float *draws;      /* (2 [mean, var], S, 4, TILE): the correction's raw outputs */
    float *by_draw;    /* (N_COEF, S, TILE): coefficients as computed, draw-major */
    float *coef;       /* (N_COEF, TILE, S): the same, row-major with the draws contiguous */
    float *per_row;    /* (3, TILE): 1/(L f) tan(delta), mean aleatoric variance of v, of w */
    float *noise;      /* (2, S, TILE) as drawn, then (2, TILE, S) */
    float *noise_t;
    float *hist;       /* (2, lag + TILE, S): sampled v, w from `lag` steps before the tile on */
    float *step;       /* (2, S): this step's means of v, w */
    float *path;       /* (2, TILE): one draw's v, w of the tile (zero-padded), for the pose */
    double *sums;      /* (S, 3) the pose's running sums */
    int32_t *row;      /* each step's distinct row */
    uint8_t *brake;    /* each distinct row: throttle 0 */
    int64_t rate_lag;
} physics_scratch;

static void physics_free(void *scratch) {
    physics_scratch *r = scratch;
    if (!r) return;
    al_scratch_free(r->network);
    free(r->rows_x);
    free(r->rows_m);
    free(r->draws);
    free(r->by_draw);
    free(r->coef);
    free(r->per_row);
    free(r->noise);
    free(r->noise_t);
    free(r->hist);
    free(r->step);
    free(r->path);
    free(r->sums);
    free(r->row);
    free(r->brake);
    free(r);
}

static void *physics_scratch_new(void *context) {
    const physics_context *c = context;
    const int64_t S = c->net->n_samples, lag = c->rate_lag;
    physics_scratch *r = calloc(1, sizeof(physics_scratch));
    if (!r) return NULL;
    r->rate_lag = lag;
    r->network = al_scratch_new(c->net);
    r->rows_x = malloc(2 * TILE * sizeof(float));
    r->draws = malloc((size_t)(2 * S * 4 * TILE) * sizeof(float));
    if (c->p[P_MIRROR] != 0.0f && !(r->rows_m = malloc(2 * TILE * sizeof(float)))) {
        physics_free(r);
        return NULL;
    }
    r->by_draw = malloc((size_t)(N_COEF * S * TILE) * sizeof(float));
    r->coef = malloc((size_t)(N_COEF * S * TILE) * sizeof(float));
    r->per_row = malloc(3 * TILE * sizeof(float));
    r->noise = malloc((size_t)(2 * S * TILE) * sizeof(float));
    r->noise_t = malloc((size_t)(2 * S * TILE) * sizeof(float));
    r->hist = malloc((size_t)(2 * (lag + TILE) * S) * sizeof(float));
    r->step = malloc((size_t)(2 * S) * sizeof(float));
    r->path = calloc(2 * TILE, sizeof(float));
    r->sums = malloc((size_t)(3 * S) * sizeof(double));
    r->row = malloc(TILE * sizeof(int32_t));
    r->brake = malloc(TILE);
    if (!r->network || !r->rows_x || !r->draws || !r->by_draw || !r->coef || !r->per_row || !r->noise ||
        !r->noise_t || !r->hist || !r->step || !r->path || !r->sums || !r->row || !r->brake) {
        physics_free(r);
        return NULL;
    }
    return r;
}

/* tanh through expf, which glibc's libmvec vectorises (it has no tanhf): a loop calling tanhf ran
 * scalar, expf included (perf: __expf_fma, __tanhf and __expm1f were a fifth of a free run). */
static inline float tanh_via_exp(float z) { return 1.0f - 2.0f / (expf(2.0f * z) + 1.0f); }

/* (S, TILE) -> (TILE, S) for the first n_rows columns. */
static void to_row_major(const float *restrict from, float *restrict to, int64_t S, int64_t n_rows) {
    for (int64_t j = 0; j < n_rows; ++j)
        for (int64_t s = 0; s < S; ++s) to[j * S + s] = from[s * TILE + j];
}

/* One draw's coefficients of n rows from its raw outputs zs (4, TILE) and variances vs (4, TILE),
 * vectorised over rows (every pointer restrict: with them unknown GCC left the loop scalar, expf and
 * all); its aleatoric variances are added to ale_v, ale_w. */
static void draw_coefficients(int64_t n, const float *p, const float *restrict zs, const float *restrict vs,
                              const float *restrict phys, float *restrict vss, float *restrict av,
                              float *restrict rw, float *restrict aw, float *restrict sdv, float *restrict sdw,
                              float *restrict ale_v, float *restrict ale_w) {
    const float inv_tv = -p[P_DT] / p[P_SPEED_LAG], inv_tw = -p[P_DT] / p[P_YAW_LAG];
    const float log_factor = p[P_LOG_LAG_FACTOR], bound_v = p[P_SPEED_BOUND], bound_w = p[P_YAW_BOUND];
    const float cap_v = p[P_VAR_CAP_V], cap_w = p[P_VAR_CAP_W], std_v = p[P_STD_V], std_w = p[P_STD_W];
    for (int64_t j = 0; j < n; ++j) {
        vss[j] = phys[j] + bound_v * tanh_via_exp(zs[j]);
        rw[j] = bound_w * tanh_via_exp(zs[TILE + j]);
        /* a_v = exp(-dt / (t_v exp(log_factor tanh z))) */
        av[j] = expf(inv_tv * expf(-log_factor * tanh_via_exp(zs[2 * TILE + j])));
        aw[j] = expf(inv_tw * expf(-log_factor * tanh_via_exp(zs[3 * TILE + j])));
        sdv[j] = sqrtf(fminf(vs[j], cap_v)) * std_v;
        sdw[j] = sqrtf(fminf(vs[TILE + j], cap_w)) * std_w;
        ale_v[j] += sdv[j] * sdv[j];
        ale_w[j] += sdw[j] * sdw[j];
    }
}

/* The mirror-symmetric correction at the tile's n_rows distinct rows: the network on (tau, delta^2), each
 * draw's yaw residual (output 1) times delta / the steering limit. */
static void symmetric_outputs(const al_network *net, physics_scratch *r, const float *p, int64_t n_rows,
                              al_outputs *out) {
    const int64_t S = net->n_samples;
    const float *delta = r->rows_x + TILE;
    for (int64_t j = 0; j < n_rows; ++j) {
        r->rows_m[j] = r->rows_x[j];
        r->rows_m[TILE + j] = delta[j] * delta[j];
    }
    al_network_rows(net, r->network, 0, n_rows, r->rows_m, TILE, 0, out);
    for (int64_t s = 0; s < S; ++s) {
        float *restrict z = r->draws + (s * 4 + 1) * TILE;
        for (int64_t j = 0; j < n_rows; ++j) z[j] *= delta[j] * p[P_MIRROR];
    }
}

/* Each draw's coefficients of the tile's n_rows distinct rows from the correction's outputs, gated. */
static void row_coefficients(const physics_context *c, physics_scratch *r, int64_t n_rows) {
    const float *p = c->p;
    const int64_t S = c->net->n_samples;
    float *z = r->draws;
    const float *zvar = r->draws + S * 4 * TILE;
    const float keep = p[P_GATE];
    if (keep != 1.0f) { /* each output moves by -(1 - keep) x its mean over draws */
        float *mean = r->by_draw;  /* (4, TILE) scratch, overwritten below */
        for (int64_t k = 0; k < 4 * TILE; ++k) mean[k] = 0.0f;
        for (int64_t s = 0; s < S; ++s)
            for (int64_t k = 0; k < 4; ++k)
                for (int64_t j = 0; j < n_rows; ++j) mean[k * TILE + j] += z[(s * 4 + k) * TILE + j];
        const float shift = (1.0f - keep) / (float)S;
        for (int64_t s = 0; s < S; ++s)
            for (int64_t k = 0; k < 4; ++k)
                for (int64_t j = 0; j < n_rows; ++j) z[(s * 4 + k) * TILE + j] -= shift * mean[k * TILE + j];
    }
    float *phys = r->path; /* (TILE) the bare steady speed per row; the path buffer is free here */
    float *turn = r->per_row, *ale_v = turn + TILE, *ale_w = ale_v + TILE;
    for (int64_t j = 0; j < n_rows; ++j) {
        const float tau = r->rows_x[j], delta = r->rows_x[TILE + j];
        const float tan_d = tanf(delta);
        const float gain = tau >= 0.0f ? p[P_SPEED_GAIN] : p[P_REVERSE_GAIN];
        const float sign = (float)((tau > 0.0f) - (tau < 0.0f));
        phys[j] = sign * gain * table_speed(p, tau) / (1.0f + p[P_SCRUB] * tan_d * tan_d);
        turn[j] = tan_d / (p[P_WHEELBASE] * p[P_UNDERSTEER]);
        r->brake[j] = tau == 0.0f;
        ale_v[j] = ale_w[j] = 0.0f;
    }
    for (int64_t s = 0; s < S; ++s) {
        float *by = r->by_draw + s * TILE;
        draw_coefficients(n_rows, p, z + s * 4 * TILE, zvar + s * 4 * TILE, phys, by + C_VSS * S * TILE,
                          by + C_AV * S * TILE, by + C_RW * S * TILE, by + C_AW * S * TILE, by + C_SDV * S * TILE,
                          by + C_SDW * S * TILE, ale_v, ale_w);
    }
    const float inv_s = 1.0f / (float)S;
    for (int64_t j = 0; j < n_rows; ++j) {
        ale_v[j] *= inv_s;
        ale_w[j] *= inv_s;
    }
    for (int k = 0; k < N_COEF; ++k) to_row_major(r->by_draw + k * S * TILE, r->coef + k * S * TILE, S, n_rows);
}

/* The step of every draw from the draws' common past (their average), as the step proper computes
 * it from each draw's own: a draw's deviation there from the average draw is its correction's alone.
 * Adds (spread - 1) times that deviation to each draw's next rates (mv, mw): the draws' differing
 * pasts are carried forward as they are, not widened again at every step. */
static void widen_draws(int64_t S, const float *pv, const float *pw, const float *vss, const float *av,
                        const float *rw, const float *aw, int brake, float brake_step, float tj, float cap,
                        float spread, float *mv, float *mw) {
    double past_v = 0.0, past_w = 0.0;
    for (int64_t s = 0; s < S; ++s) {
        past_v += pv[s];
        past_w += pw[s];
    }
    const float cpv = (float)(past_v / (double)S), cpw = (float)(past_w / (double)S);
    double mean_v = 0.0, mean_w = 0.0;
    for (int pass = 0; pass < 2; ++pass) { /* the first pass averages, the second widens */
        const float off_v = (float)(mean_v / (double)S), off_w = (float)(mean_w / (double)S);
        for (int64_t s = 0; s < S; ++s) {
            const float v = brake ? cpv - copysignf(fminf(fabsf(cpv), brake_step), cpv)
                                  : vss[s] + (cpv - vss[s]) * av[s];
            const float w_ss = fmaxf(-cap, fminf(cap, v * tj + rw[s]));
            const float w = w_ss + (cpw - w_ss) * aw[s];
            if (pass == 0) {
                mean_v += v;
                mean_w += w;
            } else {
                mv[s] += (spread - 1.0f) * (v - off_v);
                mw[s] += (spread - 1.0f) * (w - off_w);
            }
        }
    }
}

/* All S free runs of maneuver m, tile by tile. */
static void physics_maneuver(void *context, void *scratch, int64_t m) {
    const physics_context *c = context;
    physics_scratch *r = scratch;
    const float *p = c->p;
    const int64_t S = c->net->n_samples, T = c->n_steps, M = c->n_maneuvers, lag = c->rate_lag;
    const float brake_step = p[P_BRAKE_DECEL] * p[P_DT], cap = p[P_YAW_CAP], spread = p[P_SPREAD];
    const float inv_s = 1.0f / (float)S;
    al_outputs out = {0};
    out.means = r->draws;
    out.variances = r->draws + S * 4 * TILE;
    out.ld_draws = TILE;
    out.spread = 1.0f;
    float *hist_v = r->hist, *hist_w = r->hist + (lag + TILE) * S;
    for (int64_t b = 0; b < lag; ++b) /* before the first step: the start rates */
        for (int64_t s = 0; s < S; ++s) {
            hist_v[b * S + s] = c->start[(s * 2) * M + m];
            hist_w[b * S + s] = c->start[(s * 2 + 1) * M + m];
        }
    for (int64_t k = 0; k < 3 * S; ++k) r->sums[k] = 0.0;
    const float *turn = r->per_row, *ale_v = turn + TILE, *ale_w = ale_v + TILE;
    float *mv = r->step, *mw = mv + S;
    const float *noise_v = r->noise_t, *noise_w = r->noise_t + S * TILE;
    for (int64_t t0 = 0; t0 < T; t0 += TILE) {
        const int64_t n = T - t0 < TILE ? T - t0 : TILE;
        const int32_t n_rows = al_tile_rows(c->controls + 2 * (m * T + t0), n, r->rows_x, r->row);
        if (p[P_MIRROR] != 0.0f)
            symmetric_outputs(c->net, r, p, n_rows, &out);
        else
            al_network_rows(c->net, r->network, 0, n_rows, r->rows_x, TILE, 0, &out);
        row_coefficients(c, r, n_rows);
        for (int64_t s = 0; s < S; ++s) {
            const uint64_t key = c->keys[s];
            al_tile_noise((uint32_t)(t0 / TILE), (uint32_t)m, (uint32_t)key, (uint32_t)(key >> 32),
                          r->noise + s * TILE, r->noise + (S + s) * TILE);
        }
        to_row_major(r->noise, r->noise_t, S, n);
        to_row_major(r->noise + S * TILE, r->noise_t + S * TILE, S, n);
        for (int64_t i = 0; i < n; ++i) {
            const int32_t j = r->row[i];
            const float *restrict vss = r->coef + (C_VSS * TILE + j) * S, *restrict av = r->coef + (C_AV * TILE + j) * S;
            const float *restrict rw = r->coef + (C_RW * TILE + j) * S, *restrict aw = r->coef + (C_AW * TILE + j) * S;
            const float *restrict sdv = r->coef + (C_SDV * TILE + j) * S, *restrict sdw = r->coef + (C_SDW * TILE + j) * S;
            const float *restrict pv = hist_v + i * S, *restrict pw = hist_w + i * S;
            float *restrict nv = hist_v + (i + lag) * S, *restrict nw = hist_w + (i + lag) * S;
            const float tj = turn[j];
            if (r->brake[j]) {
                for (int64_t s = 0; s < S; ++s) {
                    const float fall = fminf(fabsf(pv[s]), brake_step);
                    mv[s] = pv[s] - copysignf(fall, pv[s]);
                }
            } else {
                for (int64_t s = 0; s < S; ++s) mv[s] = vss[s] + (pv[s] - vss[s]) * av[s];
            }
            float sum_v = 0.0f, sum_w = 0.0f;
            for (int64_t s = 0; s < S; ++s) {
                const float w_ss = fmaxf(-cap, fminf(cap, mv[s] * tj + rw[s]));
                mw[s] = w_ss + (pw[s] - w_ss) * aw[s];
            }
            if (spread != 1.0f) /* widen each draw's correction, not its past (surrogate.widened_step) */
                widen_draws(S, pv, pw, vss, av, rw, aw, r->brake[j], brake_step, tj, cap, spread, mv, mw);
            for (int64_t s = 0; s < S; ++s) {
                sum_v += mv[s];
                sum_w += mw[s];
            }
            const float cv = sum_v * inv_s, cw = sum_w * inv_s;
            float epi_v = 0.0f, epi_w = 0.0f;
            const float *restrict zv = noise_v + i * S, *restrict zw = noise_w + i * S;
            for (int64_t s = 0; s < S; ++s) {
                const float dv = mv[s] - cv, dw = mw[s] - cw;
                epi_v += dv * dv;
                epi_w += dw * dw;
                nv[s] = cv + dv + sdv[s] * zv[s];
                nw[s] = cw + dw + sdw[s] * zw[s];
            }
            const int64_t at = 2 * (m * T + t0 + i);
            c->centre[at] = cv;
            c->centre[at + 1] = cw;
            c->aleatoric[at] = ale_v[j];
            c->aleatoric[at + 1] = ale_w[j];
            c->epistemic[at] = epi_v * inv_s;
            c->epistemic[at + 1] = epi_w * inv_s;
        }
        float *path_v = r->path, *path_w = r->path + TILE;
        for (int64_t s = 0; s < S; ++s) { /* each draw's tile back to (S, 2, M, T), and its pose */
            float *v_at = c->rates + (s * 2 * M + m) * T + t0, *w_at = v_at + M * T;
            for (int64_t i = 0; i < n; ++i) {
                path_v[i] = hist_v[(i + lag) * S + s];
                path_w[i] = hist_w[(i + lag) * S + s];
            }
            for (int64_t i = n; i < TILE; ++i) path_v[i] = path_w[i] = 0.0f;
            memcpy(v_at, path_v, (size_t)n * sizeof(float));
            memcpy(w_at, path_w, (size_t)n * sizeof(float));
            if (c->x) {
                const int64_t o = (s * M + m) * T + t0;
                al_pose_tile(n, c->pose_dt, c->arm, c->yaw0[m], path_v, path_w, NULL, r->sums + 3 * s, c->x + o,
                             c->y + o, c->yaw + o);
            }
        }
        /* the last `lag` steps become the next tile's past */
        memmove(hist_v, hist_v + n * S, (size_t)(lag * S) * sizeof(float));
        memmove(hist_w, hist_w + n * S, (size_t)(lag * S) * sizeof(float));
    }
}

/* S sampled free runs of maneuvers [0, n_maneuvers) on up to n_threads threads (a maneuver at a time).
 *
 * `net` is the correction (S draws, 4 raw outputs, their standardised variances), read on the
 * controls (n_maneuvers, n_steps, 2) float32 that each step's model reads; `p` holds P_COUNT
 * parameters (see the enum). start (S, 2, n_maneuvers) holds the rates before the first step, read
 * until `rate_lag` steps have run; keys[s] is draw s's noise key. Writes the sampled rates
 * (S, 2, n_maneuvers, n_steps) and the per-step moments over draws (n_maneuvers, n_steps, 2). With
 * x not NULL, also each draw's pose x, y, yaw (S, n_maneuvers, n_steps) integrated at pose_dt from
 * the headings yaw0 (n_maneuvers), x and y those of the point `arm` ahead of the rear axle.
 * Returns 0, or -1 when out of memory. */
int al_physics_rollout(const al_network *net, const float *p, int64_t n_maneuvers, int64_t n_steps,
                       int64_t rate_lag, const float *controls, const float *start, const uint64_t *keys,
                       float *rates, float *centre, float *aleatoric, float *epistemic, float pose_dt, float arm,
                       const float *yaw0, float *x, float *y, float *yaw, int64_t n_threads) {
    if (rate_lag < 1) return -1;
    physics_context context = {net,   p,    n_maneuvers, n_steps,   rate_lag, controls, start, keys, rates,
                               centre, aleatoric, epistemic, pose_dt, arm, yaw0, x, y, yaw};
    al_job job = {physics_scratch_new, physics_free, physics_maneuver, &context, n_maneuvers, 0, 0};
    return al_run_parallel(&job, n_threads);
}

/* ----- the kinematic core's bare free runs, in double, for its identification ----------------------
 * The twin of single_track.run_single_track's NumPy loop (`single_track_step` without a correction): an
 * identification runs it a few hundred times a fit on arrays (parameter sets x logs) too small for
 * NumPy's per-call cost to pay. `car` holds K_COUNT figures (the enum); parameter set p of `sets`
 * (n_sets x 7, single_track.PARAMETERS' order, as P_SPEED_GAIN... above) steps run m of `controls`
 * (n_runs, n_steps, 2) from start (n_runs, 2), each step reading its own control. Writes rates
 * (n_sets, n_runs, n_steps, 2), the first step the start's. */
enum { K_WHEELBASE, K_YAW_CAP, K_TABLE, K_COUNT = K_TABLE + N_TABLE };

int al_kinematic_car_count(void) { return K_COUNT; }

/* `table_speed` in double, the table (N_TABLE speeds) given and the throttle limit 1 (single_track's). */
static double table_speed_double(const double *table, double throttle) {
    double x = fabs(throttle);
    if (x > 1.0) x = 1.0;
    x *= 10.0;
    double i = floor(x);
    if (i > 9.0) i = 9.0;
    const int k = (int)i;
    return table[k] + (x - i) * (table[k + 1] - table[k]);
}

void al_kinematic_rate_runs(const double *car, const double *sets, int64_t n_sets, int64_t n_runs,
                            int64_t n_steps, const double *controls, const double *start, double dt,
                            double *rates) {
    const double *table = car + K_TABLE, cap = car[K_YAW_CAP];
    for (int64_t p = 0; p < n_sets; ++p) {
        const double *q = sets + 7 * p;
        const double gain_f = q[0], gain_r = q[1], scrub = q[3], turn = car[K_WHEELBASE] * q[4], brake = q[6] * dt;
        const double a_v = exp(-dt / q[2]), a_w = exp(-dt / q[5]);
        for (int64_t m = 0; m < n_runs; ++m) {
            const double *u = controls + 2 * n_steps * m;
            double *out = rates + 2 * n_steps * (p * n_runs + m);
            double v = start[2 * m], w = start[2 * m + 1];
            out[0] = v;
            out[1] = w;
            for (int64_t k = 1; k < n_steps; ++k) {
                const double tau = u[2 * k], tan_d = tan(u[2 * k + 1]);
                if (tau == 0.0) { /* brakes */
                    const double fall = fabs(v) < brake ? fabs(v) : brake;
                    v = v > 0.0 ? v - fall : (v < 0.0 ? v + fall : v);
                } else {
                    const double speed = table_speed_double(table, tau);
                    const double v_ss = (tau > 0.0 ? gain_f : -gain_r) * speed / (1.0 + scrub * tan_d * tan_d);
                    v = v_ss + (v - v_ss) * a_v;
                }
                double w_ss = v * tan_d / turn;
                w_ss = w_ss > cap ? cap : (w_ss < -cap ? -cap : w_ss);
                w = w_ss + (w - w_ss) * a_w;
                out[2 * k] = v;
                out[2 * k + 1] = w;
            }
        }
    }
}
