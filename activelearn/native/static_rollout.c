/* Fused sampled trajectory of a static surrogate: noise, rates and pose in one pass per tile.
 *
 * One call fills one trajectory (one posterior draw) over M maneuvers of T steps. For every tile
 * of TILE steps it draws the aleatoric noise (Philox4x32-10 counters, Box-Muller), forms the
 * sampled rates from the draw's per-row mean and variance, and integrates the planar pose, all while
 * the tile is in L1: the torch version made some fifteen passes over multi-MB arrays instead.
 *
 * The noise of step t of maneuver m is a pure function of (key, m, t), so it does not depend on
 * the padding, the other maneuvers or the thread that computes it. The Python reference in
 * activelearn/counter_noise.py draws the same numbers (up to the last bit of log/sin/cos).
 *
 * Built with -O3 -ffast-math so that GCC vectorises logf/sinf/cosf through glibc's libmvec; the
 * prefix sums of the pose accumulate in double, as torch's cumsum does.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

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

/* One sampled trajectory over M maneuvers of T steps (row-major (M, T) outputs).
 *
 * mean_v/var_v/mean_w/var_w: this draw's predicted means and aleatoric variances per distinct
 * control row; index[m*T + t] is the row step t of maneuver m uses. yaw0[m * yaw0_stride] is maneuver m's initial heading. The pose is
 * torch's reference (`_integrate`): yaw[t] = yaw0 + dt * sum(w[:t]), x[t] = dt * sum(v cos yaw [:t]),
 * likewise y, with the sums in double. A tile is computed in local buffers, zero-padded past the
 * last step, and copied out.
 */
void al_static_trajectory(int64_t n_maneuvers, int64_t n_steps, float dt, const float *restrict mean_v,
                          const float *restrict var_v, const float *restrict mean_w,
                          const float *restrict var_w, const int64_t *restrict index,
                          const float *restrict yaw0, int64_t yaw0_stride, uint32_t k0, uint32_t k1,
                          float *restrict v, float *restrict w, float *restrict x, float *restrict y,
                          float *restrict yaw) {
    float zv[TILE], zw[TILE], vt[TILE], wt[TILE], var_vt[TILE], var_wt[TILE], yt[TILE], c[TILE], s[TILE];
    double sums[TILE];
    for (int64_t m = 0; m < n_maneuvers; ++m) {
        const float start_yaw = yaw0[m * yaw0_stride];
        double sum_w = 0.0, sum_x = 0.0, sum_y = 0.0;
        for (int64_t t0 = 0; t0 < n_steps; t0 += TILE) {
            const int64_t n = n_steps - t0 < TILE ? n_steps - t0 : TILE;
            const int64_t at = m * n_steps + t0;
            tile_noise((uint32_t)(t0 / TILE), (uint32_t)m, k0, k1, zv, zw);
            for (int64_t i = 0; i < n; ++i) { /* gather this draw's moments of each step's row */
                const int64_t r = index[at + i];
                vt[i] = mean_v[r];
                wt[i] = mean_w[r];
                var_vt[i] = var_v[r];
                var_wt[i] = var_w[r];
            }
            for (int64_t i = n; i < TILE; ++i) vt[i] = wt[i] = var_vt[i] = var_wt[i] = 0.0f;
            for (int i = 0; i < TILE; ++i) vt[i] += sqrtf(var_vt[i]) * zv[i];
            for (int i = 0; i < TILE; ++i) wt[i] += sqrtf(var_wt[i]) * zw[i];
            const double total_w = exclusive_prefix(wt, sums);
            for (int i = 0; i < TILE; ++i) yt[i] = start_yaw + dt * (float)(sum_w + sums[i]);
            sum_w += total_w;
            for (int i = 0; i < TILE; ++i) c[i] = cosf(yt[i]) * vt[i];
            for (int i = 0; i < TILE; ++i) s[i] = sinf(yt[i]) * vt[i];
            const double total_x = exclusive_prefix(c, sums);
            for (int64_t i = 0; i < n; ++i) x[at + i] = (float)(sum_x + sums[i]) * dt;
            sum_x += total_x;
            const double total_y = exclusive_prefix(s, sums);
            for (int64_t i = 0; i < n; ++i) y[at + i] = (float)(sum_y + sums[i]) * dt;
            sum_y += total_y;
            memcpy(v + at, vt, (size_t)n * sizeof(float));
            memcpy(w + at, wt, (size_t)n * sizeof(float));
            memcpy(yaw + at, yt, (size_t)n * sizeof(float));
        }
    }
}
