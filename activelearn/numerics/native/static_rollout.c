/* Fused sampled trajectories of a static surrogate: network, noise, rates and pose in one pass per tile.
 *
 * For every tile of TILE steps of a maneuver, the sampled network (network.c) is evaluated on the
 * tile's distinct control rows for all S draws while they are in cache; then each draw's tile gets
 * its aleatoric noise (Philox4x32-10 counters, Box-Muller), its sampled rates and its integrated
 * planar pose, all in L1. The unfused version wrote every draw's rates per distinct row (137 MB
 * for 256 maneuvers of 90 s with S = 32) and read them back; torch before it made some fifteen
 * passes over multi-MB arrays.
 *
 * The noise of step t of maneuver m is a pure function of (key, m, t), so it does not depend on
 * the padding, the other maneuvers or the thread that computes it. The Python reference in
 * activelearn/numerics/counter_noise.py draws the same numbers (up to the last bit of log/sin/cos).
 *
 * Built with -O3 -ffast-math so that GCC vectorises logf/sinf/cosf through glibc's libmvec; the
 * prefix sums of the pose accumulate in double, as torch's cumsum does.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "network.h"

#define TILE 512
#define HALF (TILE / 2)
#define LANES 4
#define QUARTER (TILE / LANES)

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u

#define TWO_PI 6.28318530717958647692f
#define TWO_POW_M24 5.9604644775390625e-08f /* 2^-24 */

int al_tile(void) { return TILE; }

/* Philox4x32-10 (Salmon et al. 2011): the counter (c0..c3) becomes its random words under key (k0, k1). */
static inline void philox(uint32_t *c0, uint32_t *c1, uint32_t *c2, uint32_t *c3, uint32_t k0, uint32_t k1) {
    for (int round = 0; round < 10; ++round) {
        const uint64_t p0 = (uint64_t)PHILOX_M0 * *c0;
        const uint64_t p1 = (uint64_t)PHILOX_M1 * *c2;
        const uint32_t n0 = (uint32_t)(p1 >> 32) ^ *c1 ^ k0;
        const uint32_t n2 = (uint32_t)(p0 >> 32) ^ *c3 ^ k1;
        *c1 = (uint32_t)p1;
        *c3 = (uint32_t)p0;
        *c0 = n0;
        *c2 = n2;
        k0 += PHILOX_W0;
        k1 += PHILOX_W1;
    }
}

/* Exposed for the known-answer test. */
void al_philox4x32_10(const uint32_t counter[4], const uint32_t key[2], uint32_t out[4]) {
    uint32_t c0 = counter[0], c1 = counter[1], c2 = counter[2], c3 = counter[3];
    philox(&c0, &c1, &c2, &c3, key[0], key[1]);
    out[0] = c0;
    out[1] = c1;
    out[2] = c2;
    out[3] = c3;
}

/* Standard normal noise of tile `tile` of maneuver m: zv[l], zw[l] for l in [0, TILE).
 * Counter (tile*HALF + p, m) gives steps p (words 0, 1) and HALF + p (words 2, 3).
 * Box-Muller on 24-bit uniforms: the radius's uniform lies in (0, 1], so its log is finite.
 * sin and cos run in separate loops: in one loop GCC merges them into a sincos it cannot vectorise. */
static void tile_noise(uint32_t tile, uint32_t m, uint32_t key0, uint32_t key1, float *restrict zv,
                       float *restrict zw) {
    float radius[TILE], angle[TILE];
    for (uint32_t p = 0; p < HALF; ++p) {
        uint32_t c0 = tile * HALF + p, c1 = m, c2 = 0, c3 = 0;
        philox(&c0, &c1, &c2, &c3, key0, key1);
        radius[p] = (float)(int32_t)((c0 >> 8) + 1) * TWO_POW_M24;
        angle[p] = (float)(int32_t)(c1 >> 8) * (TWO_PI * TWO_POW_M24);
        radius[HALF + p] = (float)(int32_t)((c2 >> 8) + 1) * TWO_POW_M24;
        angle[HALF + p] = (float)(int32_t)(c3 >> 8) * (TWO_PI * TWO_POW_M24);
    }
    for (int l = 0; l < TILE; ++l) radius[l] = sqrtf(-2.0f * logf(radius[l]));
    for (int l = 0; l < TILE; ++l) zv[l] = radius[l] * cosf(angle[l]);
    for (int l = 0; l < TILE; ++l) zw[l] = radius[l] * sinf(angle[l]);
}

/* Distinct consecutive control rows of a tile: skidpads and straights hold one row for the whole tile. */
int32_t al_tile_rows(const float *u, int64_t n, float *rows_x, int32_t *row) {
    int32_t n_rows = 0;
    for (int64_t i = 0; i < n; ++i) {
        if (i == 0 || u[2 * i] != u[2 * i - 2] || u[2 * i + 1] != u[2 * i - 1]) {
            rows_x[n_rows] = u[2 * i];
            rows_x[TILE + n_rows] = u[2 * i + 1];
            ++n_rows;
        }
        row[i] = n_rows - 1;
    }
    return n_rows;
}

/* tile_noise for the other kernels (physics_rollout.c): one trajectory's noise of one tile. */
void al_tile_noise(uint32_t tile, uint32_t m, uint32_t key0, uint32_t key1, float *zv, float *zw) {
    tile_noise(tile, m, key0, key1, zv, zw);
}

/* Exclusive prefix sums of a tile in double: sums[i] = sum(values[:i]); returns the tile's total.
 * Four running sums over the tile's quarters, joined afterwards: with one, every step would wait
 * for the add before it (the loop's cost was that latency chain). */
static double exclusive_prefix(const float *restrict values, double *restrict sums) {
    double part[LANES] = {0.0};
    for (int i = 0; i < QUARTER; ++i)
        for (int k = 0; k < LANES; ++k) {
            sums[k * QUARTER + i] = part[k];
            part[k] += (double)values[k * QUARTER + i];
        }
    double offset = 0.0;
    for (int k = 0; k < LANES; ++k) {
        for (int i = 0; i < QUARTER; ++i) sums[k * QUARTER + i] += offset;
        offset += part[k];
    }
    return offset;
}

/* The planar pose of one draw over one tile of `n` steps from its sampled rates vt, wt (TILE each,
 * zero beyond n) and, where `lt` is not NULL, the rear axle's lateral speed (TILE, to the left: a
 * dynamic core's sideslip). `sums` carries the running sums of w, v cos(yaw) - lat sin(yaw) and
 * v sin(yaw) + lat cos(yaw) from tile to tile. Writes n steps at x, y, yaw. The pose is torch's
 * reference (`integrate_pose`): yaw[t] = yaw0 + dt * sum(w[:t]), x[t] = dt * sum(v cos yaw [:t]) +
 * arm * (cos yaw[t] - cos yaw0), likewise y with sin, with the sums in double: the sums move the rear
 * axle, and the logged point sits `arm` ahead of it. */
void al_pose_tile(int64_t n, float dt, float arm, float start_yaw, const float *restrict vt,
                  const float *restrict wt, const float *restrict lt, double sums_carried[3], float *restrict x,
                  float *restrict y, float *restrict yaw) {
    float yt[TILE], c[TILE], s[TILE], cos_yaw[TILE], sin_yaw[TILE];
    double sums[TILE];
    const double total_w = exclusive_prefix(wt, sums);
    for (int i = 0; i < TILE; ++i) yt[i] = start_yaw + dt * (float)(sums_carried[0] + sums[i]);
    sums_carried[0] += total_w;
    for (int i = 0; i < TILE; ++i) cos_yaw[i] = cosf(yt[i]);
    for (int i = 0; i < TILE; ++i) sin_yaw[i] = sinf(yt[i]);
    for (int i = 0; i < TILE; ++i) c[i] = cos_yaw[i] * vt[i];
    for (int i = 0; i < TILE; ++i) s[i] = sin_yaw[i] * vt[i];
    if (lt)
        for (int i = 0; i < TILE; ++i) c[i] -= sin_yaw[i] * lt[i], s[i] += cos_yaw[i] * lt[i];
    const float cos0 = arm * cosf(start_yaw), sin0 = arm * sinf(start_yaw);
    const double total_x = exclusive_prefix(c, sums);
    for (int64_t i = 0; i < n; ++i) x[i] = (float)(sums_carried[1] + sums[i]) * dt + (arm * cos_yaw[i] - cos0);
    sums_carried[1] += total_x;
    const double total_y = exclusive_prefix(s, sums);
    for (int64_t i = 0; i < n; ++i) y[i] = (float)(sums_carried[2] + sums[i]) * dt + (arm * sin_yaw[i] - sin0);
    sums_carried[2] += total_y;
    memcpy(yaw, yt, (size_t)n * sizeof(float));
}

/* Sampled rates and pose of one draw over one tile of `n` steps of a maneuver (zero-padded to TILE).
 *
 * mean_v/var_v/mean_w/var_w hold this draw's mean and aleatoric variance per distinct control row
 * and row[i] is the row of step i. Writes n steps at v, w and the pose (`al_pose_tile`). */
static void trajectory_tile(int64_t n, uint32_t tile, uint32_t m, uint32_t k0, uint32_t k1, float dt,
                            float arm, float start_yaw, const float *restrict mean_v, const float *restrict var_v,
                            const float *restrict mean_w, const float *restrict var_w,
                            const int32_t *restrict row, double sums_carried[3], float *restrict v,
                            float *restrict w, float *restrict x, float *restrict y, float *restrict yaw) {
    float zv[TILE], zw[TILE], vt[TILE], wt[TILE], var_vt[TILE], var_wt[TILE];
    tile_noise(tile, m, k0, k1, zv, zw);
    for (int64_t i = 0; i < n; ++i) { /* gather this draw's moments of each step's row */
        const int32_t r = row[i];
        vt[i] = mean_v[r];
        wt[i] = mean_w[r];
        var_vt[i] = var_v[r];
        var_wt[i] = var_w[r];
    }
    for (int64_t i = n; i < TILE; ++i) vt[i] = wt[i] = var_vt[i] = var_wt[i] = 0.0f;
    for (int i = 0; i < TILE; ++i) vt[i] += sqrtf(var_vt[i]) * zv[i];
    for (int i = 0; i < TILE; ++i) wt[i] += sqrtf(var_wt[i]) * zw[i];
    al_pose_tile(n, dt, arm, start_yaw, vt, wt, NULL, sums_carried, x, y, yaw);
    memcpy(v, vt, (size_t)n * sizeof(float));
    memcpy(w, wt, (size_t)n * sizeof(float));
}

typedef struct {
    const al_network *net;
    al_outputs map; /* the draws' mapping to outputs; the rest is filled per worker */
    int64_t n_steps, yaw0_stride, ld_sample;
    float dt, arm;
    const float *controls, *yaw0;
    const uint64_t *keys;
    float *v, *w, *x, *y, *yaw, *centre, *aleatoric, *epistemic;
} rollout_context;

typedef struct {
    al_scratch *network;
    float *rows_x;  /* a tile's distinct control rows, column layout (2, TILE) */
    float *draws;   /* (2 [mean, var], S, 2, TILE) */
    float *moments; /* (3, 2, TILE) */
    int32_t *row;   /* each step's distinct row */
    double *sums;   /* (S, 3) running sums of w, v cos(yaw), v sin(yaw) */
} rollout_scratch;

static void rollout_free(void *scratch) {
    rollout_scratch *r = scratch;
    if (!r) return;
    al_scratch_free(r->network);
    free(r->rows_x);
    free(r->draws);
    free(r->moments);
    free(r->row);
    free(r->sums);
    free(r);
}

static void *rollout_scratch_new(void *context) {
    const al_network *net = ((rollout_context *)context)->net;
    const int64_t S = net->n_samples;
    rollout_scratch *r = calloc(1, sizeof(rollout_scratch));
    if (!r) return NULL;
    r->network = al_scratch_new(net);
    r->rows_x = malloc(2 * TILE * sizeof(float));
    r->draws = malloc((size_t)(4 * S * TILE) * sizeof(float));
    r->moments = malloc(3 * 2 * TILE * sizeof(float));
    r->row = malloc(TILE * sizeof(int32_t));
    r->sums = malloc((size_t)(3 * S) * sizeof(double));
    if (!r->network || !r->rows_x || !r->draws || !r->moments || !r->row || !r->sums) {
        rollout_free(r);
        return NULL;
    }
    return r;
}

/* All S trajectories of maneuver m, tile by tile. */
static void rollout_maneuver(void *context, void *scratch, int64_t m) {
    const rollout_context *c = context;
    rollout_scratch *r = scratch;
    const int64_t S = c->net->n_samples, T = c->n_steps;
    float *draw_means = r->draws, *draw_vars = r->draws + 2 * S * TILE;
    al_outputs out = c->map;
    out.means = draw_means;
    out.variances = draw_vars;
    out.ld_draws = TILE;
    out.centre = r->moments;
    out.aleatoric = r->moments + 2 * TILE;
    out.epistemic = r->moments + 4 * TILE;
    out.ld_moments = TILE;
    const float start_yaw = c->yaw0[m * c->yaw0_stride];
    for (int64_t k = 0; k < 3 * S; ++k) r->sums[k] = 0.0;
    for (int64_t t0 = 0; t0 < T; t0 += TILE) {
        const int64_t n = T - t0 < TILE ? T - t0 : TILE;
        const int64_t at = m * T + t0;
        const int32_t n_rows = al_tile_rows(c->controls + 2 * at, n, r->rows_x, r->row);
        al_network_rows(c->net, r->network, 0, n_rows, r->rows_x, TILE, 0, &out);
        for (int64_t i = 0; i < n; ++i)
            for (int j = 0; j < 2; ++j) {
                const int64_t to = 2 * (at + i) + j, from = j * TILE + r->row[i];
                c->centre[to] = out.centre[from];
                c->aleatoric[to] = out.aleatoric[from];
                c->epistemic[to] = out.epistemic[from];
            }
        for (int64_t s = 0; s < S; ++s) {
            const float *mean = draw_means + 2 * s * TILE, *var = draw_vars + 2 * s * TILE;
            const int64_t o = s * c->ld_sample + at;
            trajectory_tile(n, (uint32_t)(t0 / TILE), (uint32_t)m, (uint32_t)c->keys[s],
                            (uint32_t)(c->keys[s] >> 32), c->dt, c->arm, start_yaw, mean, var, mean + TILE, var + TILE,
                            r->row, r->sums + 3 * s, c->v + o, c->w + o, c->x + o, c->y + o, c->yaw + o);
        }
    }
}

/* S sampled trajectories of maneuvers [0, n_maneuvers) of a static surrogate, network included, on
 * up to n_threads threads (one maneuver at a time each).
 *
 * For every tile of TILE steps of a maneuver, the network (`net`, S draws, outputs mapped by
 * `map`'s out_mean/out_std/spread) is evaluated once on the tile's distinct consecutive control
 * rows, while they are in cache; then each draw's tile is noised and integrated. controls is
 * (n_maneuvers, n_steps, 2) float32 (throttle, steering); keys[s] is draw s's 64-bit noise key (the
 * noise of step t of maneuver m depends only on (key, m, t)). Sampled paths v, w, x, y, yaw are
 * (S, n_maneuvers, n_steps) with draw stride ld_sample; x and y are those of a point `arm` metres ahead
 * of the rear axle (the logged pose; 0 puts it on the axle). The per-step moments over draws (centre,
 * aleatoric, epistemic) are (n_maneuvers, n_steps, 2). Returns 0, or -1 when out of memory. */
int al_static_rollout(const al_network *net, const al_outputs *map, int64_t n_maneuvers, int64_t n_steps,
                      float dt, float arm, const float *controls, const float *yaw0, int64_t yaw0_stride,
                      const uint64_t *keys, int64_t ld_sample, float *v, float *w, float *x, float *y, float *yaw,
                      float *centre, float *aleatoric, float *epistemic, int64_t n_threads) {
    rollout_context context = {net, *map, n_steps, yaw0_stride, ld_sample, dt, arm, controls, yaw0, keys,
                               v, w, x, y, yaw, centre, aleatoric, epistemic};
    al_job job = {rollout_scratch_new, rollout_free, rollout_maneuver, &context, n_maneuvers, 0, 0};
    return al_run_parallel(&job, n_threads);
}
