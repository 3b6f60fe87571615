/* Sampled free runs of the physics-structured surrogate whose correction reads the control alone.
 *
 * The twin of PhysicsModel's torch path (activelearn/numerics/models/physics.py): the correction is a
 * function of the operating point (throttle, steering), so, per tile of TILE steps of a maneuver, the
 * sampled correction network (network.c) is evaluated once on the tile's distinct control rows; each
 * draw's bounded steady states, lags and noise level follow per row, and the recurrence left per
 * step and draw is the single track's few flops:
 *
 *   v' = v_ss + (v - v_ss) a_v             (throttle 0 brakes: |v| falls by brake_decel dt)
 *   w' = w_ss + (w - w_ss) a_w,            w_ss = clip(v' tan(delta) / (L understeer) + r_w, +-cap)
 *
 * from the rates `rate_lag` steps back. The per-step spread over draws (the epistemic scale), the
 * moments over draws and each draw's aleatoric noise (the counter-based noise of static_rollout.c,
 * so a draw's noise depends only on its key, the maneuver and the step) are added per step.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

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
} physics_context;

typedef struct {
    al_scratch *network;
    float *rows_x;  /* a tile's distinct control rows, column layout (2, TILE) */
    float *draws;   /* (2 [mean, var], S, 4, TILE): the correction's raw outputs */
    float *coef;    /* (7, S, TILE): v_ss, a_v, 1/(L f) tan(delta), r_w, a_w, noise std v, w */
    float *noise;   /* (S, 2, TILE) */
    float *step;    /* (4, S): means v, w this step */
    int32_t *row;   /* each step's distinct row */
    uint8_t *brake; /* each distinct row: throttle 0 */
} physics_scratch;

static void physics_free(void *scratch) {
    physics_scratch *r = scratch;
    if (!r) return;
    al_scratch_free(r->network);
    free(r->rows_x);
    free(r->draws);
    free(r->coef);
    free(r->noise);
    free(r->step);
    free(r->row);
    free(r->brake);
    free(r);
}

static void *physics_scratch_new(void *context) {
    const al_network *net = ((physics_context *)context)->net;
    const int64_t S = net->n_samples;
    physics_scratch *r = calloc(1, sizeof(physics_scratch));
    if (!r) return NULL;
    r->network = al_scratch_new(net);
    r->rows_x = malloc(2 * TILE * sizeof(float));
    r->draws = malloc((size_t)(2 * S * 4 * TILE) * sizeof(float));
    r->coef = malloc((size_t)(7 * S * TILE) * sizeof(float));
    r->noise = malloc((size_t)(2 * S * TILE) * sizeof(float));
    r->step = malloc((size_t)(4 * S) * sizeof(float));
    r->row = malloc(TILE * sizeof(int32_t));
    r->brake = malloc(TILE);
    if (!r->network || !r->rows_x || !r->draws || !r->coef || !r->noise || !r->step || !r->row || !r->brake) {
        physics_free(r);
        return NULL;
    }
    return r;
}

/* Each draw's coefficients of the tile's n_rows distinct rows from the correction's outputs. */
static void row_coefficients(const physics_context *c, physics_scratch *r, int64_t n_rows) {
    const float *p = c->p;
    const int64_t S = c->net->n_samples;
    const float *z = r->draws, *zvar = r->draws + S * 4 * TILE;
    float *vss = r->coef, *av = vss + S * TILE, *turn = av + S * TILE, *rw = turn + S * TILE;
    float *aw = rw + S * TILE, *sdv = aw + S * TILE, *sdw = sdv + S * TILE;
    for (int64_t j = 0; j < n_rows; ++j) {
        const float tau = r->rows_x[j], delta = r->rows_x[TILE + j];
        const float tan_d = tanf(delta);
        const float gain = tau >= 0.0f ? p[P_SPEED_GAIN] : p[P_REVERSE_GAIN];
        const float sign = (float)((tau > 0.0f) - (tau < 0.0f));
        const float v_phys = sign * gain * table_speed(p, tau) / (1.0f + p[P_SCRUB] * tan_d * tan_d);
        const float per_speed = tan_d / (p[P_WHEELBASE] * p[P_UNDERSTEER]);
        r->brake[j] = tau == 0.0f;
        for (int64_t s = 0; s < S; ++s) {
            const float *zs = z + s * 4 * TILE, *vs = zvar + s * 4 * TILE;
            const int64_t o = s * TILE + j;
            vss[o] = v_phys + p[P_SPEED_BOUND] * tanhf(zs[j]);
            rw[o] = p[P_YAW_BOUND] * tanhf(zs[TILE + j]);
            av[o] = expf(-p[P_DT] / (p[P_SPEED_LAG] * expf(p[P_LOG_LAG_FACTOR] * tanhf(zs[2 * TILE + j]))));
            aw[o] = expf(-p[P_DT] / (p[P_YAW_LAG] * expf(p[P_LOG_LAG_FACTOR] * tanhf(zs[3 * TILE + j]))));
            turn[o] = per_speed;
            sdv[o] = sqrtf(fminf(vs[j], p[P_VAR_CAP_V])) * p[P_STD_V];
            sdw[o] = sqrtf(fminf(vs[TILE + j], p[P_VAR_CAP_W])) * p[P_STD_W];
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
    const float *vss = r->coef, *av = vss + S * TILE, *turn = av + S * TILE, *rw = turn + S * TILE;
    const float *aw = rw + S * TILE, *sdv = aw + S * TILE, *sdw = sdv + S * TILE;
    float *mv = r->step, *mw = mv + S;
    for (int64_t t0 = 0; t0 < T; t0 += TILE) {
        const int64_t n = T - t0 < TILE ? T - t0 : TILE;
        const int32_t n_rows = al_tile_rows(c->controls + 2 * (m * T + t0), n, r->rows_x, r->row);
        al_network_rows(c->net, r->network, 0, n_rows, r->rows_x, TILE, 0, &out);
        row_coefficients(c, r, n_rows);
        for (int64_t s = 0; s < S; ++s) {
            const uint64_t key = c->keys[s];
            al_tile_noise((uint32_t)(t0 / TILE), (uint32_t)m, (uint32_t)key, (uint32_t)(key >> 32),
                          r->noise + 2 * s * TILE, r->noise + (2 * s + 1) * TILE);
        }
        for (int64_t i = 0; i < n; ++i) {
            const int64_t k = t0 + i;
            const int32_t j = r->row[i];
            float sum_v = 0.0f, sum_w = 0.0f, var_v = 0.0f, var_w = 0.0f;
            for (int64_t s = 0; s < S; ++s) {
                const float *v_at = c->rates + (s * 2 * M + m) * T, *w_at = v_at + M * T;
                const float v = k >= lag ? v_at[k - lag] : c->start[(s * 2) * M + m];
                const float w = k >= lag ? w_at[k - lag] : c->start[(s * 2 + 1) * M + m];
                const int64_t o = s * TILE + j;
                float v1;
                if (r->brake[j]) {
                    const float fall = fminf(fabsf(v), brake_step);
                    v1 = v - (v > 0.0f ? fall : (v < 0.0f ? -fall : 0.0f));
                } else {
                    v1 = vss[o] + (v - vss[o]) * av[o];
                }
                const float w_ss = fmaxf(-cap, fminf(cap, v1 * turn[o] + rw[o]));
                mv[s] = v1;
                mw[s] = w_ss + (w - w_ss) * aw[o];
                sum_v += mv[s];
                sum_w += mw[s];
                var_v += sdv[o] * sdv[o];
                var_w += sdw[o] * sdw[o];
            }
            const float cv = sum_v * inv_s, cw = sum_w * inv_s;
            float epi_v = 0.0f, epi_w = 0.0f;
            for (int64_t s = 0; s < S; ++s) {
                const float dv = spread * (mv[s] - cv), dw = spread * (mw[s] - cw);
                epi_v += dv * dv;
                epi_w += dw * dw;
                const int64_t o = s * TILE + j;
                float *v_at = c->rates + (s * 2 * M + m) * T, *w_at = v_at + M * T;
                v_at[k] = cv + dv + sdv[o] * r->noise[2 * s * TILE + i];
                w_at[k] = cw + dw + sdw[o] * r->noise[(2 * s + 1) * TILE + i];
            }
            const int64_t at = 2 * (m * T + k);
            c->centre[at] = cv;
            c->centre[at + 1] = cw;
            c->aleatoric[at] = var_v * inv_s;
            c->aleatoric[at + 1] = var_w * inv_s;
            c->epistemic[at] = epi_v * inv_s;
            c->epistemic[at + 1] = epi_w * inv_s;
        }
    }
}

/* S sampled free runs of maneuvers [0, n_maneuvers) on up to n_threads threads (a maneuver at a time).
 *
 * `net` is the correction (S draws, 4 raw outputs, their standardised variances), read on the
 * controls (n_maneuvers, n_steps, 2) float32 that each step's model reads; `p` holds P_COUNT
 * parameters (see the enum). start (S, 2, n_maneuvers) holds the rates before the first step, read
 * until `rate_lag` steps have run; keys[s] is draw s's noise key. Writes the sampled rates
 * (S, 2, n_maneuvers, n_steps) and the per-step moments over draws (n_maneuvers, n_steps, 2).
 * Returns 0, or -1 when out of memory. */
int al_physics_rollout(const al_network *net, const float *p, int64_t n_maneuvers, int64_t n_steps,
                       int64_t rate_lag, const float *controls, const float *start, const uint64_t *keys,
                       float *rates, float *centre, float *aleatoric, float *epistemic, int64_t n_threads) {
    physics_context context = {net,   p,     n_maneuvers, n_steps, rate_lag,  controls,
                               start, keys,  rates,       centre,  aleatoric, epistemic};
    al_job job = {physics_scratch_new, physics_free, physics_maneuver, &context, n_maneuvers, 0, 0};
    return al_run_parallel(&job, n_threads);
}
