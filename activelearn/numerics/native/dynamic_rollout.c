/* Free runs of the dynamic single track's rates, in double precision, many parameter sets at once.
 *
 * The twin of `dynamic_track.rate_runs` (activelearn/numerics/models/dynamic_track.py; the equations
 * are in its module docstring): B lanes, each a (parameter set, run) pair with its own per-set
 * figures (grip, brake, axle stiffnesses, yaw inertia, drive), step the bicycle through a run's
 * controls in `substeps` explicit or implicit-damping substeps per step. It is what an identification
 * spends its time on: a least-squares search evaluates 1 + 5 parameter sets (the finite-difference
 * Jacobian's) on every restarted 3-s window of the logs, a thousand times a campaign.
 *
 * Lanes go in blocks of LANES, stored side by side, so each substep's arithmetic is one vectorised
 * pass over a block (libmvec's atan, sin, cos, tan, tanh, expm1 under -ffast-math); blocks are shared
 * out to threads. Conditions are written as selects so the passes stay branch-free.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "network.h"

#define LANES 8
#define BLOCKS_PER_CHUNK 4

/* The car's figures shared by every lane (dynamic_track.py's NATIVE_CAR, same order). */
enum {
    C_GRAVITY,
    C_MASS,
    C_LF,
    C_LR,
    C_CG_HEIGHT,
    C_SHAPE, /* magic formula C; 0: the linear tyre capped at mu F_z */
    C_CURVATURE,
    C_STEERING_LIMIT,
    C_STEERING_RATE,
    C_REAR_DRIVE_SHARE,
    C_MOTOR, /* 1: the motor law; 0: the speed table and its lag */
    C_POWER_LIMIT_SPEED,
    C_SPEED_TIME_CONSTANT,
    C_BLEND_SPEED,
    C_COUNT
};

/* Each lane's figures (dynamic_track.py's NATIVE_SET, same order): what the identified scales move. */
enum {
    S_FRICTION,
    S_BRAKE,
    S_STIFFNESS_FRONT,
    S_STIFFNESS_REAR,
    S_YAW_INERTIA,
    S_TOP_SPEED,
    S_REVERSE_TOP_SPEED,
    S_MAX_ACCELERATION,
    S_TABLE_GAIN,
    S_COUNT
};

int al_dynamic_car_count(void) { return C_COUNT; }
int al_dynamic_set_count(void) { return S_COUNT; }

static inline double clip(double x, double low, double high) { return x < low ? low : (x > high ? high : x); }
static inline double sign(double x) { return (double)(x > 0.0) - (double)(x < 0.0); }

/* The speed table at |throttle| (np.interp: linear between points, flat beyond the ends). */
static double table_speed(const double *grid, const double *speed, int64_t n, double throttle) {
    const double x = clip(fabs(throttle), grid[0], grid[n - 1]);
    int64_t i = 0;
    while (i < n - 2 && grid[i + 1] <= x) ++i;
    return speed[i] + (x - grid[i]) / (grid[i + 1] - grid[i]) * (speed[i + 1] - speed[i]);
}

typedef struct {
    const double *car, *sets, *grid, *speed;
    int64_t n_table, n_lanes, n_runs, n_steps, substeps, implicit;
    const double *controls, *start;
    double dt;
    double *rates;
} dynamic_context;

static void *dynamic_scratch(void *context) { return context; } /* nothing per thread */
static void dynamic_free(void *scratch) { (void)scratch; }

/* One block's lanes and the car's figures derived once. */
typedef struct {
    double mu[LANES], brake[LANES], cf0[LANES], cr0[LANES], inertia[LANES], top[LANES], reverse[LANES];
    double a_max[LANES], vx[LANES], vy[LANES], r[LANES], delta[LANES];
    double tau[LANES], target[LANES], drive[LANES]; /* this step's controls; drive: the table's speed */
} block;

typedef struct {
    double g, m, lf, lr, hcg, L, shape, curvature, static_f, static_r, blend, floor_speed, share, h, turn;
    double vsw, lag;
} figures;

/* One substep of every lane of a block. `motor`, `linear` and `implicit` are constants at each call
 * (always inlined), so each variant's lane loop has no branch and vectorises with libmvec. */
static inline __attribute__((always_inline)) void substep(block *b, const figures *f, const int motor,
                                                          const int linear, const int implicit) {
    const double g = f->g, m = f->m, lf = f->lf, lr = f->lr, L = f->L, h = f->h, floor_speed = f->floor_speed;
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) {
        const double delta = b->delta[l] + clip(b->target[l] - b->delta[l], -f->turn, f->turn);
        const double vx0 = b->vx[l], vy0 = b->vy[l], r0 = b->r[l], tau = b->tau[l], mu = b->mu[l];
        const double grip = mu * g, speed_x = fabs(vx0);
        double a;
        if (motor) {
            const double top_speed = tau > 0.0 ? b->top[l] : b->reverse[l];
            const double limit = b->a_max[l] * f->vsw / fmax(speed_x, f->vsw);
            a = clip(b->a_max[l] * (tau - vx0 / top_speed), -limit, limit);
        } else {
            a = (b->drive[l] - vx0) / f->lag;
        }
        const double stop_rate = fmin(speed_x / h, b->brake[l]); /* brakes to rest, not past it */
        a = clip(tau == 0.0 ? -sign(vx0) * stop_rate : a, -grip, grip);
        const double load_f = fmax(m * (g * lr - a * f->hcg) / L, 0.0);
        const double load_r = fmax(m * (g * lf + a * f->hcg) / L, 0.0);
        /* cos from sin (|delta| is within the lock, below pi/2): GCC would fuse a sin and cos into a
         * sincos, which does not vectorise */
        const double sn = sin(delta), cs = sqrt(1.0 - sn * sn);
        const double front_y = vy0 + lf * r0;
        const double long_f = vx0 * cs + front_y * sn, lat_f = front_y * cs - vx0 * sn;
        const double alpha_f = atan(-lat_f / fmax(fabs(long_f), floor_speed));
        const double alpha_r = atan(-(vy0 - lr * r0) / fmax(speed_x, floor_speed));
        const double cap_f = mu * load_f, cap_r = mu * load_r;
        double f_f, f_r;
        if (linear) {
            f_f = clip(b->cf0[l] * load_f / f->static_f * alpha_f, -cap_f, cap_f);
            f_r = clip(b->cr0[l] * load_r / f->static_r * alpha_r, -cap_r, cap_r);
        } else {
            double xf = b->cf0[l] / f->static_f / (f->shape * mu) * alpha_f;
            double xr = b->cr0[l] / f->static_r / (f->shape * mu) * alpha_r;
            xf -= f->curvature * (xf - atan(xf));
            xr -= f->curvature * (xr - atan(xr));
            f_f = cap_f * sin(f->shape * atan(xf));
            f_r = cap_r * sin(f->shape * atan(xr));
        }
        const double drive_r = m * a * f->share; /* the drive's share of the rear friction circle */
        const double room = sqrt(fmax(cap_r * cap_r - drive_r * drive_r, 0.0));
        f_r = clip(f_r, -room, room);
        const double dvx = a - f_f * sn / m, dvy = (f_f * cs + f_r) / m;
        const double dr = (lf * f_f * cs - lr * f_r) / b->inertia[l];
        double vx, vy, r;
        if (implicit) { /* dynamic_step(implicit=True): exponential tyre damping */
            const double speed = fmax(speed_x, floor_speed);
            const double c_f = b->cf0[l] * load_f / f->static_f, c_r = b->cr0[l] * load_r / f->static_r;
            const double x_lat = fmax(h * (c_f + c_r) / (m * speed), 1e-300);
            const double x_yaw = fmax(h * (lf * lf * c_f + lr * lr * c_r) / (b->inertia[l] * speed), 1e-300);
            vy = vy0 + h * (dvy - vx0 * r0) * (-expm1(-x_lat) / x_lat);
            vx = vx0 + h * (dvx + vy * r0);
            r = r0 + h * dr * (-expm1(-x_yaw) / x_yaw);
        } else {
            vx = vx0 + h * (dvx + vy0 * r0);
            vy = vy0 + h * (dvy - vx0 * r0);
            r = r0 + h * dr;
        }
        const double w = 0.5 * (1.0 + tanh((fabs(vx) - f->blend) / (0.25 * f->blend)));
        const double r_kin = vx * tan(delta) / L;
        b->r[l] = w * r + (1.0 - w) * r_kin;
        b->vy[l] = w * vy + (1.0 - w) * lr * r_kin;
        b->vx[l] = vx, b->delta[l] = delta;
    }
}

#define SUBSTEPS(MOTOR, LINEAR, IMPLICIT)                                         \
    static void substeps_##MOTOR##LINEAR##IMPLICIT(block *b, const figures *f, int64_t n) { \
        for (int64_t i = 0; i < n; ++i) substep(b, f, MOTOR, LINEAR, IMPLICIT);   \
    }
SUBSTEPS(0, 0, 0)
SUBSTEPS(0, 0, 1)
SUBSTEPS(0, 1, 0)
SUBSTEPS(0, 1, 1)
SUBSTEPS(1, 0, 0)
SUBSTEPS(1, 0, 1)
SUBSTEPS(1, 1, 0)
SUBSTEPS(1, 1, 1)
static void (*const SUBSTEP_VARIANTS[8])(block *, const figures *, int64_t) = {
    substeps_000, substeps_001, substeps_010, substeps_011, substeps_100, substeps_101, substeps_110, substeps_111};

/* The car's shared figures as a substep reads them, for steps of dt in `substeps` substeps. */
static figures figures_of(const double *k, double dt, int64_t substeps) {
    figures f;
    f.g = k[C_GRAVITY], f.m = k[C_MASS], f.lf = k[C_LF], f.lr = k[C_LR], f.hcg = k[C_CG_HEIGHT];
    f.L = f.lf + f.lr, f.shape = k[C_SHAPE], f.curvature = k[C_CURVATURE];
    f.static_f = f.m * f.g * f.lr / f.L, f.static_r = f.m * f.g * f.lf / f.L;
    f.blend = k[C_BLEND_SPEED], f.floor_speed = 0.5 * f.blend, f.share = k[C_REAR_DRIVE_SHARE];
    f.h = dt / (double)substeps, f.turn = k[C_STEERING_RATE] * f.h;
    f.vsw = k[C_POWER_LIMIT_SPEED], f.lag = k[C_SPEED_TIME_CONSTANT];
    return f;
}

typedef void (*substep_run)(block *, const figures *, int64_t);

static substep_run substeps_for(const double *k, int64_t implicit) {
    return SUBSTEP_VARIANTS[4 * (k[C_MOTOR] != 0.0) + 2 * (k[C_SHAPE] == 0.0) + (implicit != 0)];
}

/* Lane l of a block takes parameter set `s`'s figures (its table gain into gain[l]). */
static void load_figures(block *b, double *gain, int l, const double *s) {
    b->mu[l] = s[S_FRICTION], b->brake[l] = s[S_BRAKE], b->cf0[l] = s[S_STIFFNESS_FRONT];
    b->cr0[l] = s[S_STIFFNESS_REAR], b->inertia[l] = s[S_YAW_INERTIA], b->top[l] = s[S_TOP_SPEED];
    b->reverse[l] = s[S_REVERSE_TOP_SPEED], b->a_max[l] = s[S_MAX_ACCELERATION], gain[l] = s[S_TABLE_GAIN];
}

/* Lane l's controls for the coming step: throttle, the steering target within the lock, and for a
 * table car the table's speed (it depends on the control alone: once a step, not a substep). */
static void load_controls(block *b, const double *gain, int l, const dynamic_context *c, double tau,
                          double steering) {
    const double *k = c->car;
    b->tau[l] = tau;
    b->target[l] = clip(steering, -k[C_STEERING_LIMIT], k[C_STEERING_LIMIT]);
    b->drive[l] = k[C_MOTOR] != 0.0 ? 0.0 : sign(tau) * table_speed(c->grid, c->speed, c->n_table, tau) * gain[l];
}

/* One block of up to LANES lanes through all steps. */
static void dynamic_block(const dynamic_context *c, int64_t first) {
    const int64_t n = c->n_lanes - first < LANES ? c->n_lanes - first : LANES;
    const int64_t T = c->n_steps;
    const figures f = figures_of(c->car, c->dt, c->substeps);
    const substep_run run_substeps = substeps_for(c->car, c->implicit);
    block b;
    double gain[LANES];
    for (int l = 0; l < LANES; ++l) { /* lanes past the end repeat the last one, unwritten */
        const int64_t lane = first + (l < n ? l : n - 1);
        const double *x0 = c->start + lane * 4;
        load_figures(&b, gain, l, c->sets + lane * S_COUNT);
        b.vx[l] = x0[0], b.vy[l] = x0[1], b.r[l] = x0[2], b.delta[l] = x0[3];
    }
    for (int64_t l = 0; l < n; ++l) {
        double *out = c->rates + (first + l) * T * 2;
        out[0] = b.vx[l], out[1] = b.r[l];
    }
    for (int64_t step = 1; step < T; ++step) {
        for (int l = 0; l < LANES; ++l) {
            const int64_t run = (first + (l < n ? l : n - 1)) % c->n_runs;
            const double *u = c->controls + (run * T + step - 1) * 2;
            load_controls(&b, gain, l, c, u[0], u[1]);
        }
        run_substeps(&b, &f, c->substeps);
        for (int64_t l = 0; l < n; ++l) {
            double *out = c->rates + ((first + l) * T + step) * 2;
            out[0] = b.vx[l], out[1] = b.r[l];
        }
    }
}

static void dynamic_chunk(void *context, void *scratch, int64_t chunk) {
    (void)scratch;
    const dynamic_context *c = context;
    for (int64_t b = 0; b < BLOCKS_PER_CHUNK; ++b) {
        const int64_t first = (chunk * BLOCKS_PER_CHUNK + b) * LANES;
        if (first >= c->n_lanes) return;
        dynamic_block(c, first);
    }
}

/* Rates (v_x, r) of n_lanes free runs on up to n_threads threads. Lane b is parameter set b's figures
 * (sets, n_lanes x S_COUNT) on run b % n_runs of controls (n_runs, n_steps, 2), from start (n_lanes, 4)
 * = (v_x, v_y, r, delta_w); `car` holds C_COUNT shared figures, grid and speed the speed table's
 * n_table points. Writes rates (n_lanes, n_steps, 2), the first step the start's. Returns 0, or -1 if a
 * thread failed. */
int al_dynamic_rate_runs(const double *car, const double *sets, const double *grid, const double *speed,
                         int64_t n_table, int64_t n_lanes, int64_t n_runs, int64_t n_steps, const double *controls,
                         const double *start, double dt, int64_t substeps, int64_t implicit, double *rates,
                         int64_t n_threads) {
    if (n_lanes <= 0 || n_steps <= 0) return 0;
    if (n_runs <= 0 || substeps < 1 || n_table < 2) return -1;
    dynamic_context context = {car,      sets,     grid, speed, n_table, n_lanes, n_runs, n_steps, substeps,
                               implicit, controls, start, dt,    rates};
    const int64_t per_chunk = LANES * BLOCKS_PER_CHUNK;
    al_job job = {dynamic_scratch, dynamic_free, dynamic_chunk, &context, (n_lanes + per_chunk - 1) / per_chunk,
                  0, 0};
    return al_run_parallel(&job, n_threads);
}

/* ----- the physics kind's free runs on the dynamic core ------------------------------------------
 * The twin of DynamicPhysicsModel's torch loop (dynamic_physics.py, `free_run_step`): S draws, each
 * with its own figures (its posterior draw of the scales) and its correction's raw outputs at each
 * step's control row, step (v_x, v_y, r, delta_w) from the state `rate_lag` steps back; the bounded
 * correction moves v_x and r towards their residuals at the car's lags; with `widen` each draw's
 * correction is spread about the draws' mean from their common past; then the moments over draws and
 * each draw's sensor noise. One maneuver is a chunk: its S draws are ceil(S / LANES) blocks. */

/* The correction's limits (dynamic_physics.py's CorrectionLimits, `native_limits`, same order). */
enum { L_SPEED_BOUND, L_YAW_BOUND, L_YAW_CAP, L_SPEED_LAG, L_YAW_LAG, L_LOG_FACTOR, L_COUNT };

int al_dynamic_limit_count(void) { return L_COUNT; }

typedef struct {
    dynamic_context core; /* car, sets (S of them), table, dt, substeps; n_runs = M, n_steps = T */
    const double *limits;
    int64_t n_samples, n_rows, rate_lag, widen;
    double spread;
    const float *controls; /* (M, T, 2): the control each step reads */
    const int64_t *index;  /* (M, T): each step's control row among the n_rows distinct ones */
    const float *z, *noise_std, *start, *start_hidden;
    const uint64_t *keys; /* each draw's noise key (the counter-based noise of static_rollout.c) */
    float *states, *rates, *hidden, *centre, *aleatoric, *epistemic;
    double *residuals; /* (S, 2, n_rows): each draw's correction at each row (residual_chunk) */
} free_run_context;

typedef struct {
    block *blocks; /* ceil(S / LANES) of each: the draws' own step, */
    block *common; /* and their step from the draws' mean past (`widen`) */
    double *gain, *v, *w, *cv, *cw;
    float *zv, *zw; /* each draw's noise over the current tile of steps (S x al_tile()) */
} free_run_scratch;

static void free_run_free(void *scratch) {
    free_run_scratch *r = scratch;
    if (!r) return;
    free(r->blocks), free(r->common), free(r->gain), free(r->v), free(r->w), free(r->cv), free(r->cw);
    free(r->zv), free(r->zw);
    free(r);
}

static void *free_run_scratch_new(void *context) {
    const free_run_context *c = context;
    const int64_t n_blocks = (c->n_samples + LANES - 1) / LANES, lanes = n_blocks * LANES;
    free_run_scratch *r = calloc(1, sizeof *r);
    if (!r) return NULL;
    r->blocks = malloc((size_t)n_blocks * sizeof(block)), r->common = malloc((size_t)n_blocks * sizeof(block));
    r->gain = malloc((size_t)lanes * sizeof(double));
    r->v = malloc((size_t)lanes * sizeof(double)), r->w = malloc((size_t)lanes * sizeof(double));
    r->cv = malloc((size_t)lanes * sizeof(double)), r->cw = malloc((size_t)lanes * sizeof(double));
    r->zv = malloc((size_t)(c->n_samples * al_tile()) * sizeof(float));
    r->zw = malloc((size_t)(c->n_samples * al_tile()) * sizeof(float));
    if (!r->blocks || !r->common || !r->gain || !r->v || !r->w || !r->cv || !r->cw || !r->zv || !r->zw) {
        free_run_free(r);
        return NULL;
    }
    for (int64_t i = 0; i < lanes; ++i) { /* lanes past the S draws repeat the last draw, unwritten */
        const int64_t s = i < c->n_samples ? i : c->n_samples - 1;
        load_figures(&r->blocks[i / LANES], r->gain + (i / LANES) * LANES, (int)(i % LANES),
                     c->core.sets + s * S_COUNT);
    }
    memcpy(r->common, r->blocks, (size_t)n_blocks * sizeof(block)); /* the same draws' figures */
    return r;
}

/* corrected_step's correction on a block's stepped lanes: v and w of draws [first, first + LANES), each
 * draw's residuals at the step's control row taken from `residuals` (S, 2, n_rows). */
static void correct(const free_run_context *c, const block *b, int64_t first, int64_t row, double *v, double *w) {
    const int64_t S = c->n_samples, U = c->n_rows;
    const double cap = c->limits[L_YAW_CAP];
    for (int l = 0; l < LANES; ++l) {
        const int64_t s = first + l < S ? first + l : S - 1;
        v[first + l] = b->vx[l] + c->residuals[s * 2 * U + row];
        w[first + l] = clip(b->r[l] + c->residuals[(s * 2 + 1) * U + row], -cap, cap);
    }
}

/* Each draw's step residuals on v_x and r at every control row (corrected_step's
 * share x bound x tanh(z), the share from the lag e^(log_factor tanh(z_lag)) x the car's), vectorised
 * over rows: per step and lane the correction is then an add. One draw a chunk. */
static void residual_chunk(void *context, void *scratch, int64_t s) {
    (void)scratch;
    const free_run_context *c = context;
    const double *q = c->limits, dt = c->core.dt;
    const int64_t U = c->n_rows;
    const float *z = c->z + s * 4 * U; /* (4, U): speed, yaw rate, their lags */
    double *rv = c->residuals + s * 2 * U, *rw = rv + U;
    for (int64_t i = 0; i < U; ++i) {
        const double lag_v = q[L_SPEED_LAG] * exp(q[L_LOG_FACTOR] * tanh((double)z[2 * U + i]));
        const double lag_w = q[L_YAW_LAG] * exp(q[L_LOG_FACTOR] * tanh((double)z[3 * U + i]));
        rv[i] = -expm1(-dt / lag_v) * q[L_SPEED_BOUND] * tanh((double)z[i]);
        rw[i] = -expm1(-dt / lag_w) * q[L_YAW_BOUND] * tanh((double)z[U + i]);
    }
}

static void free_run_maneuver(void *context, void *scratch, int64_t m) {
    const free_run_context *c = context;
    free_run_scratch *r = scratch;
    const int64_t S = c->n_samples, M = c->core.n_runs, T = c->core.n_steps, lag = c->rate_lag;
    const int64_t n_blocks = (S + LANES - 1) / LANES, plane = M * T; /* (S, 2, M, T): a rate's plane */
    const figures f = figures_of(c->core.car, c->core.dt, c->core.substeps);
    const substep_run run_substeps = substeps_for(c->core.car, c->core.implicit);
    const int64_t tile = al_tile();
    for (int64_t k = 0; k < T; ++k) {
        if (k % tile == 0) /* the next tile's noise, each draw's from its key */
            for (int64_t s = 0; s < S; ++s)
                al_tile_noise((uint32_t)(k / tile), (uint32_t)m, (uint32_t)(c->keys[s] & 0xFFFFFFFFu),
                              (uint32_t)(c->keys[s] >> 32), r->zv + s * tile, r->zw + s * tile);
        const float *u = c->controls + (m * T + k) * 2;
        const int64_t row = c->index[m * T + k];
        double mean[4] = {0.0, 0.0, 0.0, 0.0}; /* the draws' mean past (v_x, v_y, r, delta_w) */
        for (int64_t bi = 0; bi < n_blocks; ++bi) {
            block *b = &r->blocks[bi];
            for (int l = 0; l < LANES; ++l) {
                const int64_t s = bi * LANES + l < S ? bi * LANES + l : S - 1;
                double past[4];
                if (k >= lag) {
                    const int64_t at = s * 2 * plane + m * T + k - lag;
                    past[0] = c->states[at], past[2] = c->states[at + plane];
                    past[1] = c->hidden[at], past[3] = c->hidden[at + plane];
                } else {
                    const int64_t at = s * 2 * M + m;
                    past[0] = c->start[at], past[2] = c->start[at + M];
                    past[1] = c->start_hidden[at], past[3] = c->start_hidden[at + M];
                }
                b->vx[l] = past[0], b->vy[l] = past[1], b->r[l] = past[2], b->delta[l] = past[3];
                if (bi * LANES + l < S)
                    for (int i = 0; i < 4; ++i) mean[i] += past[i];
                load_controls(b, r->gain + bi * LANES, l, &c->core, u[0], u[1]);
            }
            run_substeps(b, &f, c->core.substeps);
            correct(c, b, bi * LANES, row, r->v, r->w);
        }
        if (c->widen) { /* surrogate.widened_step: each draw's correction spread, not its past */
            double common_v = 0.0, common_w = 0.0;
            for (int64_t bi = 0; bi < n_blocks; ++bi) {
                block *b = &r->common[bi];
                for (int l = 0; l < LANES; ++l) {
                    b->vx[l] = mean[0] / S, b->vy[l] = mean[1] / S, b->r[l] = mean[2] / S, b->delta[l] = mean[3] / S;
                    load_controls(b, r->gain + bi * LANES, l, &c->core, u[0], u[1]);
                }
                run_substeps(b, &f, c->core.substeps);
                correct(c, b, bi * LANES, row, r->cv, r->cw);
            }
            for (int64_t s = 0; s < S; ++s) common_v += r->cv[s], common_w += r->cw[s];
            for (int64_t s = 0; s < S; ++s) {
                r->v[s] += (c->spread - 1.0) * (r->cv[s] - common_v / S);
                r->w[s] += (c->spread - 1.0) * (r->cw[s] - common_w / S);
            }
        }
        double centre_v = 0.0, centre_w = 0.0;
        for (int64_t s = 0; s < S; ++s) centre_v += r->v[s], centre_w += r->w[s];
        centre_v /= S, centre_w /= S;
        double alea_v = 0.0, alea_w = 0.0, epi_v = 0.0, epi_w = 0.0;
        for (int64_t s = 0; s < S; ++s) {
            const int64_t at = s * 2 * plane + m * T + k;
            const double std_v = c->noise_std[s * 2 * c->n_rows + row];
            const double std_w = c->noise_std[(s * 2 + 1) * c->n_rows + row];
            c->states[at] = (float)r->v[s], c->states[at + plane] = (float)r->w[s];
            c->rates[at] = (float)(r->v[s] + std_v * r->zv[s * tile + k % tile]);
            c->rates[at + plane] = (float)(r->w[s] + std_w * r->zw[s * tile + k % tile]);
            const block *b = &r->blocks[s / LANES];
            c->hidden[at] = (float)b->vy[s % LANES], c->hidden[at + plane] = (float)b->delta[s % LANES];
            alea_v += std_v * std_v, alea_w += std_w * std_w;
            epi_v += (r->v[s] - centre_v) * (r->v[s] - centre_v), epi_w += (r->w[s] - centre_w) * (r->w[s] - centre_w);
        }
        float *out = c->centre + (m * T + k) * 2;
        out[0] = (float)centre_v, out[1] = (float)centre_w;
        out = c->aleatoric + (m * T + k) * 2;
        out[0] = (float)(alea_v / S), out[1] = (float)(alea_w / S);
        out = c->epistemic + (m * T + k) * 2;
        out[0] = (float)(epi_v / S), out[1] = (float)(epi_w / S);
    }
}

/* S free runs of the physics kind on the dynamic core for maneuvers [0, n_maneuvers), on up to
 * n_threads threads (a maneuver at a time), its steps implicit (`dynamic_step(implicit=True)`).
 *
 * `car` (C_COUNT), sets (S, S_COUNT) each draw's figures, grid and speed the speed table; `limits`
 * (L_COUNT) the correction's bounds; controls (M, T, 2) the control each step reads, index (M, T) its
 * row among the n_rows distinct ones; z (S, 4, n_rows) the correction's raw outputs (speed, yaw rate,
 * their lags; gated), noise_std (S, 2, n_rows) the sensors' noise sizes and keys (S) each draw's
 * noise key (its normals drawn here, al_tile_noise); start and start_hidden (S, 2, M) the (v_x, r) and (v_y, delta_w) before the first step, read
 * until `rate_lag` steps have run. Writes each draw's rates without noise (states) and with it (rates),
 * its (v_y, delta_w) after each step (hidden), all (S, 2, M, T), and the moments over draws (centre,
 * aleatoric, epistemic; each (M, T, 2)). Returns 0, or -1 when out of memory. */
int al_dynamic_free_runs(const double *car, const double *sets, const double *grid, const double *speed,
                         int64_t n_table, const double *limits, int64_t n_samples, int64_t n_maneuvers,
                         int64_t n_steps, int64_t n_rows, double dt, int64_t substeps, int64_t rate_lag,
                         int64_t widen, double spread, const float *controls, const int64_t *index, const float *z,
                         const float *noise_std, const uint64_t *keys, const float *start, const float *start_hidden,
                         float *states, float *rates, float *hidden, float *centre, float *aleatoric,
                         float *epistemic, int64_t n_threads) {
    if (n_maneuvers <= 0 || n_steps <= 0) return 0;
    if (n_samples <= 0 || rate_lag < 1 || substeps < 1 || n_table < 2) return -1;
    free_run_context context = {
        {car, sets, grid, speed, n_table, n_samples, n_maneuvers, n_steps, substeps, 1, NULL, NULL, dt, NULL},
        limits, n_samples, n_rows, rate_lag, widen, spread, controls, index, z, noise_std, start, start_hidden,
        keys, states, rates, hidden, centre, aleatoric, epistemic, NULL};
    context.residuals = malloc((size_t)(n_samples * 2 * n_rows) * sizeof(double));
    if (!context.residuals) return -1;
    al_job residuals = {dynamic_scratch, dynamic_free, residual_chunk, &context, n_samples, 0, 0};
    int status = al_run_parallel(&residuals, n_threads);
    if (status == 0) {
        al_job job = {free_run_scratch_new, free_run_free, free_run_maneuver, &context, n_maneuvers, 0, 0};
        status = al_run_parallel(&job, n_threads);
    }
    free(context.residuals);
    return status;
}
