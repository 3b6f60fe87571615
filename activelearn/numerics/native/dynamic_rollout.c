/* Free runs of the dynamic single track's rates, many parameter sets at once (double precision), and
 * the physics kind's free runs on it (float, the pose integrated too).
 *
 * The twin of `dynamic_track.rate_runs` (activelearn/numerics/models/dynamic_track.py; the equations
 * are in its module docstring): B lanes, each a (parameter set, run) pair with its own per-set
 * figures (grip, brake, axle stiffnesses, yaw inertia, drive), step the bicycle through a run's
 * controls in `substeps` explicit or implicit-damping substeps per step. It is what an identification
 * spends its time on: a least-squares search evaluates 1 + 5 parameter sets (the finite-difference
 * Jacobian's) on every restarted 3-s window of the logs, a thousand times a campaign.
 *
 * Lanes go in blocks, stored side by side, so each substep's arithmetic is one vectorised pass over a
 * block (libmvec's atan, sin, tanh, expm1 under -ffast-math); blocks are shared out to threads.
 * Conditions are written as selects so the passes stay branch-free. The substep is
 * dynamic_substep.h's, included once per precision.
 */
#include <tgmath.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "network.h"

#define LANES_D 8  /* a rate run's block: doubles */
#define LANES_F 16 /* a free run's block: floats */
#define BLOCKS_PER_CHUNK 4
#define OUT_FIELDS 5 /* a free run's tile buffer: rates (v, r), states (v, r), v_y */

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
    C_COMBINED_SLIP, /* 1: both axles' friction circles share the longitudinal force; 0: the rear drive's */
    C_ROOM_FLOOR,    /* with it, the share of a circle a lateral force keeps at a grip-limited stop */
    C_WHEEL_FORCES,  /* n > 0: the forces of four wheels, each in its own circle, n passes of their loads
                      * (one of WHEEL_PASS_CHOICES; overrides C_COMBINED_SLIP); 0: the axles' */
    C_TRACK,         /* m, with them: the wheels' lateral spacing */
    C_TANGENT_DAMPING, /* 1: the implicit step damps at the tyres' local slope (0 past the peak) */
    C_KINEMATIC_CORE,  /* 1: below the blend speed the kinematic core's turn, lag and scrub (not with the
                        * wheels' forces) */
    C_COUNT
};

/* The wheels' forces' fixed-point passes of their loads that the kernel has a variant of
 * (dynamic_track.py's WHEEL_PASS_CHOICES; C_WHEEL_FORCES holds the car's count, 0 without the wheels). */
#define WHEEL_PASS_COUNT 2
static const int WHEEL_PASS_CHOICES[WHEEL_PASS_COUNT] = {3, 5};
int al_dynamic_wheel_pass_choice(int i) { return i >= 0 && i < WHEEL_PASS_COUNT ? WHEEL_PASS_CHOICES[i] : 0; }

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
    S_UNDERSTEER, /* with C_KINEMATIC_CORE: the kinematic branch's understeer, scrub, yaw lag (s) and */
    S_SCRUB,      /* understeer in reverse */
    S_YAW_LAG,
    S_REVERSE_UNDERSTEER,
    S_COUNT
};

int al_dynamic_car_count(void) { return C_COUNT; }
int al_dynamic_set_count(void) { return S_COUNT; }

typedef struct {
    const double *car, *sets, *grid, *speed;
    int64_t n_table, n_lanes, n_runs, n_steps, substeps, implicit;
    const double *controls, *start;
    double dt;
    double *rates;
} dynamic_context;

static void *dynamic_scratch(void *context) { return context; } /* nothing per thread */
static void dynamic_free(void *scratch) { (void)scratch; }

#define REAL double
#define LANES LANES_D
#define NAME(x) x##_d
#include "dynamic_substep.h"
#undef REAL
#undef LANES
#undef NAME
#define REAL float
#define LANES LANES_F
#define NAME(x) x##_f
#include "dynamic_substep.h"
#undef REAL
#undef LANES
#undef NAME

/* Lane l's controls for the coming step: throttle, the steering target within the lock, and for a
 * table car the table's speed (it depends on the control alone: once a step, not a substep). */
static void load_controls(block_d *b, const double *gain, int l, const dynamic_context *c, double tau,
                          double steering) {
    const double *k = c->car, lock = k[C_STEERING_LIMIT];
    b->tau[l] = tau;
    b->target[l] = clip_d(steering, -lock, lock);
    b->drive[l] = k[C_MOTOR] != 0.0 ? 0.0 : sign_d(tau) * table_speed_d(c->grid, c->speed, c->n_table, tau) * gain[l];
}

/* One or two blocks of up to LANES_D lanes each, from lane `first`, through all steps; two step in one
 * lane loop (`substep_pair`: the two chains of transcendental calls hide each other's latency). */
static void dynamic_blocks(const dynamic_context *c, int64_t first, int count) {
    const int64_t T = c->n_steps;
    const figures_d f = figures_of_d(c->car, c->dt, c->substeps);
    const substep_run_d run_substeps = substeps_for_d(c->car, c->implicit);
    block_d b[2];
    double gain[2][LANES_D];
    int64_t n[2];
    for (int k = 0; k < count; ++k) {
        const int64_t at = first + k * LANES_D;
        n[k] = c->n_lanes - at < LANES_D ? c->n_lanes - at : LANES_D;
        for (int l = 0; l < LANES_D; ++l) { /* lanes past the end repeat the last one, unwritten */
            const int64_t lane = at + (l < n[k] ? l : n[k] - 1);
            const double *x0 = c->start + lane * 4;
            load_figures_d(&b[k], gain[k], l, c->sets + lane * S_COUNT, c->car, f.h);
            b[k].vx[l] = x0[0], b[k].vy[l] = x0[1], b[k].r[l] = x0[2], b[k].delta[l] = x0[3];
        }
        for (int64_t l = 0; l < n[k]; ++l) {
            double *out = c->rates + (at + l) * T * 2;
            out[0] = b[k].vx[l], out[1] = b[k].r[l];
        }
    }
    for (int64_t step = 1; step < T; ++step) {
        for (int k = 0; k < count; ++k)
            for (int l = 0; l < LANES_D; ++l) {
                const int64_t run = (first + k * LANES_D + (l < n[k] ? l : n[k] - 1)) % c->n_runs;
                const double *u = c->controls + (run * T + step - 1) * 2;
                load_controls(&b[k], gain[k], l, c, u[0], u[1]);
            }
        run_substeps(&b[0], count == 2 ? &b[1] : NULL, &f, c->substeps);
        for (int k = 0; k < count; ++k)
            for (int64_t l = 0; l < n[k]; ++l) {
                double *out = c->rates + ((first + k * LANES_D + l) * T + step) * 2;
                out[0] = b[k].vx[l], out[1] = b[k].r[l];
            }
    }
}

static void dynamic_chunk(void *context, void *scratch, int64_t chunk) {
    (void)scratch;
    const dynamic_context *c = context;
    for (int64_t b = 0; b < BLOCKS_PER_CHUNK; b += 2) { /* BLOCKS_PER_CHUNK is even: blocks go in pairs */
        const int64_t first = (chunk * BLOCKS_PER_CHUNK + b) * LANES_D;
        if (first >= c->n_lanes) return;
        dynamic_blocks(c, first, first + LANES_D < c->n_lanes ? 2 : 1);
    }
}

/* Rates (v_x, r) of n_lanes free runs on up to n_threads threads. Lane b is parameter set b's figures
 * (sets, n_lanes x S_COUNT) on run b % n_runs of controls (n_runs, n_steps, 2), from start (n_lanes, 4)
 * = (v_x, v_y, r, delta_w); `car` holds C_COUNT shared figures, grid and speed the speed table's
 * n_table points. Writes rates (n_lanes, n_steps, 2), the first step the start's. Returns 0, -1 if a
 * thread failed, or -2 if the car's wheel passes have no variant. */
int al_dynamic_rate_runs(const double *car, const double *sets, const double *grid, const double *speed,
                         int64_t n_table, int64_t n_lanes, int64_t n_runs, int64_t n_steps, const double *controls,
                         const double *start, double dt, int64_t substeps, int64_t implicit, double *rates,
                         int64_t n_threads) {
    if (n_lanes <= 0 || n_steps <= 0) return 0;
    if (n_runs <= 0 || substeps < 1 || n_table < 2) return -1;
    if (!substeps_for_d(car, implicit)) return -2; /* no variant of the car's wheel passes */
    dynamic_context context = {car,      sets,     grid, speed, n_table, n_lanes, n_runs, n_steps, substeps,
                               implicit, controls, start, dt,    rates};
    const int64_t per_chunk = LANES_D * BLOCKS_PER_CHUNK;
    al_job job = {dynamic_scratch, dynamic_free, dynamic_chunk, &context, (n_lanes + per_chunk - 1) / per_chunk,
                  0, 0};
    return al_run_parallel(&job, n_threads);
}

/* ----- the physics kind's free runs on the dynamic core ------------------------------------------
 * The twin of DynamicPhysicsModel's torch loop (dynamic_physics.py, `free_run_step`), in float (the
 * states are float32 there too): S draws, each with its own figures (its posterior draw of the scales) and its
 * correction's raw outputs at each step's control row, step (v_x, v_y, r, delta_w) from the state
 * `rate_lag` steps back; the bounded correction moves v_x and r towards their residuals at the car's
 * lags; with `widen` each draw's correction is spread about the draws' mean from their common past;
 * then the moments over draws and each draw's sensor noise; then, asked for, each draw's pose
 * (`_free_run_pose`). One maneuver is a chunk: its S draws are ceil(S / LANES_F) blocks. */

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
    float *rates, *centre, *aleatoric, *epistemic;
    double *residuals; /* (S, 2, n_rows): each draw's correction at each row (residual_chunk) */
    /* the pose (NULL x: none): the log's dt, the lever arm, each maneuver's heading (M); with
     * `discrepancy` not NULL, each draw's sizes of v and r (S, 2) of the model discrepancy its rates carry
     * for the fan about the mean path, an OU process of `correlation_time` s (`discrepancy_paths`) */
    float pose_dt, arm;
    double correlation_time;
    const float *yaw0;
    const double *discrepancy;
    float *x, *y, *yaw;
} free_run_context;

typedef struct {
    block_f *blocks; /* ceil(S / LANES_F) of each: the draws' own step, */
    block_f *common; /* and their step from the draws' mean past (`widen`) */
    float *gain;
    double *v, *w, *cv, *cw;
    float *zv, *zw;   /* each draw's noise over the current tile of steps (S x al_tile()) */
    float *ring;      /* (rate_lag, 4, lanes): each draw's (v_x, v_y, r, delta_w) of the last rate_lag steps */
    float *out;       /* (OUT_FIELDS, al_tile(), S): the tile's rates with the noise (v, r) and without, v_y */
    float *track;     /* (3, S, T): the maneuver's rates without noise (v, r) and v_y, for its pose */
    float *path;      /* (5, al_tile()): a draw's v, w, rear-axle slip and discrepancy noise over a tile */
    float *wide;      /* (3, S, T): the draws' poses with the discrepancy (where it is asked for) */
    double *mean;     /* (6, T): the poses' means over draws, without and with the discrepancy */
} free_run_scratch;

static void free_run_free(void *scratch) {
    free_run_scratch *r = scratch;
    if (!r) return;
    free(r->blocks), free(r->common), free(r->gain), free(r->v), free(r->w), free(r->cv), free(r->cw);
    free(r->zv), free(r->zw), free(r->ring), free(r->out), free(r->track), free(r->path), free(r->wide);
    free(r->mean);
    free(r);
}

static void *free_run_scratch_new(void *context) {
    const free_run_context *c = context;
    const int64_t S = c->n_samples, T = c->core.n_steps, tile = al_tile();
    const int64_t n_blocks = (S + LANES_F - 1) / LANES_F, lanes = n_blocks * LANES_F;
    free_run_scratch *r = calloc(1, sizeof *r);
    if (!r) return NULL;
    r->blocks = malloc((size_t)n_blocks * sizeof(block_f)), r->common = malloc((size_t)n_blocks * sizeof(block_f));
    r->gain = malloc((size_t)lanes * sizeof(float));
    r->v = malloc((size_t)lanes * sizeof(double)), r->w = malloc((size_t)lanes * sizeof(double));
    r->cv = malloc((size_t)lanes * sizeof(double)), r->cw = malloc((size_t)lanes * sizeof(double));
    r->zv = malloc((size_t)(S * tile) * sizeof(float)), r->zw = malloc((size_t)(S * tile) * sizeof(float));
    r->ring = malloc((size_t)(c->rate_lag * 4 * lanes) * sizeof(float));
    r->out = malloc((size_t)(OUT_FIELDS * tile * S) * sizeof(float));
    r->track = c->x ? malloc((size_t)(3 * S * T) * sizeof(float)) : NULL;
    r->path = malloc((size_t)(5 * tile) * sizeof(float));
    r->wide = c->discrepancy ? malloc((size_t)(3 * S * T) * sizeof(float)) : NULL;
    r->mean = malloc((size_t)(6 * T) * sizeof(double));
    if (!r->blocks || !r->common || !r->gain || !r->v || !r->w || !r->cv || !r->cw || !r->zv || !r->zw ||
        !r->ring || !r->out || (c->x && !r->track) || !r->path || (c->discrepancy && !r->wide) || !r->mean) {
        free_run_free(r);
        return NULL;
    }
    for (int64_t i = 0; i < lanes; ++i) { /* lanes past the S draws repeat the last draw, unwritten */
        const int64_t s = i < S ? i : S - 1;
        load_figures_f(&r->blocks[i / LANES_F], r->gain + (i / LANES_F) * LANES_F, (int)(i % LANES_F),
                       c->core.sets + s * S_COUNT, c->core.car, c->core.dt / (double)c->core.substeps);
    }
    memcpy(r->common, r->blocks, (size_t)n_blocks * sizeof(block_f)); /* the same draws' figures */
    return r;
}

/* corrected_step's correction on a block's stepped lanes: v and w of draws [first, first + LANES_F),
 * each draw's residuals at the step's control row taken from `residuals` (S, 2, n_rows). */
static void correct(const free_run_context *c, const block_f *b, int64_t first, int64_t row, double *v, double *w) {
    const int64_t S = c->n_samples, U = c->n_rows;
    const double cap = c->limits[L_YAW_CAP];
    for (int l = 0; l < LANES_F; ++l) {
        const int64_t s = first + l < S ? first + l : S - 1;
        v[first + l] = b->vx[l] + c->residuals[s * 2 * U + row];
        w[first + l] = clip_d(b->r[l] + c->residuals[(s * 2 + 1) * U + row], -cap, cap);
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

/* The key of draw s's model discrepancy: its noise key with the top bit set (the keys are below 2^62),
 * so its normals are a Philox stream of their own (`discrepancy_paths`' `DISCREPANCY_KEY_BIT`). */
static uint64_t discrepancy_key(uint64_t key) { return key | (UINT64_C(1) << 63); }

/* One draw's pose over maneuver m from its rates and its rear axle's slip v_y - l_r r, tile by tile
 * (al_pose_tile), into x, y, yaw (each T, contiguous). With `widened` its rates carry the model
 * discrepancy: an Ornstein-Uhlenbeck process from zero, its normals from the draw's discrepancy key. */
static void draw_pose(const free_run_context *c, free_run_scratch *r, int64_t s, int64_t m, int widened,
                      float *x, float *y, float *yaw) {
    const int64_t S = c->n_samples, T = c->core.n_steps, tile = al_tile();
    const float lr = (float)c->core.car[C_LR];
    const float *v = r->track + s * T, *w = v + S * T, *vy = w + S * T;
    float *pv = r->path, *pw = pv + tile, *pl = pw + tile, *zv = pl + tile, *zw = zv + tile;
    const uint64_t key = discrepancy_key(c->keys[s]);
    double keep = 0.0, shock = 0.0, dv = 0.0, dw = 0.0; /* the process and its state */
    if (widened) keep = exp(-(double)c->pose_dt / c->correlation_time), shock = sqrt(1.0 - keep * keep);
    double sums[3] = {0.0, 0.0, 0.0};
    for (int64_t t0 = 0; t0 < T; t0 += tile) {
        const int64_t n = T - t0 < tile ? T - t0 : tile;
        for (int64_t i = 0; i < n; ++i) {
            pv[i] = v[t0 + i], pw[i] = w[t0 + i];
            pl[i] = vy[t0 + i] - lr * w[t0 + i];
        }
        if (widened) {
            al_tile_noise((uint32_t)(t0 / tile), (uint32_t)m, (uint32_t)(key & 0xFFFFFFFFu), (uint32_t)(key >> 32),
                          zv, zw);
            for (int64_t i = 0; i < n; ++i) {
                if (t0 + i > 0) dv = keep * dv + shock * zv[i], dw = keep * dw + shock * zw[i];
                pv[i] += (float)(c->discrepancy[2 * s] * dv), pw[i] += (float)(c->discrepancy[2 * s + 1] * dw);
            }
        }
        for (int64_t i = n; i < tile; ++i) pv[i] = pw[i] = pl[i] = 0.0f;
        al_pose_tile(n, c->pose_dt, c->arm, c->yaw0[m], pv, pw, pl, sums, x + t0, y + t0, yaw + t0);
    }
}

/* Every draw's pose over maneuver m (`_free_run_pose`): the core's rates and slip integrated; with the
 * discrepancy, the draws' poses with it, moved so that their mean over draws is the core's (the
 * discrepancy widens the fan, not the path). */
static void maneuver_pose(const free_run_context *c, free_run_scratch *r, int64_t m) {
    const int64_t S = c->n_samples, M = c->core.n_runs, T = c->core.n_steps;
    for (int64_t s = 0; s < S; ++s) {
        const int64_t o = (s * M + m) * T;
        draw_pose(c, r, s, m, 0, c->x + o, c->y + o, c->yaw + o);
    }
    if (!c->discrepancy) return;
    double *mean = r->mean; /* x, y, yaw without, then with the discrepancy */
    memset(mean, 0, (size_t)(6 * T) * sizeof(double));
    for (int64_t s = 0; s < S; ++s) {
        const int64_t o = (s * M + m) * T;
        float *wx = r->wide + s * T, *wy = wx + S * T, *wyaw = wy + S * T;
        draw_pose(c, r, s, m, 1, wx, wy, wyaw);
        const float *part[6] = {c->x + o, c->y + o, c->yaw + o, wx, wy, wyaw};
        for (int j = 0; j < 6; ++j)
            for (int64_t k = 0; k < T; ++k) mean[j * T + k] += part[j][k];
    }
    for (int64_t s = 0; s < S; ++s) {
        const int64_t o = (s * M + m) * T;
        float *out[3] = {c->x + o, c->y + o, c->yaw + o};
        for (int j = 0; j < 3; ++j) {
            const float *wide = r->wide + (j * S + s) * T;
            for (int64_t k = 0; k < T; ++k)
                out[j][k] = (float)(wide[k] + (mean[j * T + k] - mean[(3 + j) * T + k]) / (double)S);
        }
    }
}

/* Every lane of a block takes the step's controls, the same for every draw of a maneuver
 * (`load_controls`'). */
static void block_controls(block_f *b, const float *gain, const dynamic_context *c, double tau, double steering) {
    const double *k = c->car, lock = k[C_STEERING_LIMIT];
    const float target = (float)clip_d(steering, -lock, lock);
    const float drive =
        k[C_MOTOR] != 0.0 ? 0.0f : sign_f((float)tau) * table_speed_f(c->grid, c->speed, c->n_table, tau);
    for (int l = 0; l < LANES_F; ++l) b->tau[l] = (float)tau, b->target[l] = target, b->drive[l] = drive * gain[l];
}

/* The tile of steps [t0, t0 + n) of maneuver m from the scratch's `out` (step by step, the draws side
 * by side) to the rates (S, 2, M, T) and, for the pose, to the maneuver's track (3, S, T). */
static void flush_tile(const free_run_context *c, free_run_scratch *r, int64_t m, int64_t t0, int64_t n) {
    const int64_t S = c->n_samples, M = c->core.n_runs, T = c->core.n_steps, plane = M * T, tile = al_tile();
    for (int f = 0; f < OUT_FIELDS; ++f) {
        if (f >= 2 && !c->x) break;
        for (int64_t s = 0; s < S; ++s) {
            float *into = f < 2 ? c->rates + (s * 2 + f) * plane + m * T : r->track + ((f - 2) * S + s) * T;
            const float *from = r->out + f * tile * S + s;
            for (int64_t i = 0; i < n; ++i) into[t0 + i] = from[i * S];
        }
    }
}

/* The substeps of n blocks, two at a time in one lane loop (`substep_pair`), the odd one alone. */
static void step_blocks(block_f *blocks, int64_t n, substep_run_f run, const figures_f *f, int64_t substeps) {
    for (int64_t bi = 0; bi + 1 < n; bi += 2) run(&blocks[bi], &blocks[bi + 1], f, substeps);
    if (n % 2) run(&blocks[n - 1], NULL, f, substeps);
}

static void free_run_maneuver(void *context, void *scratch, int64_t m) {
    const free_run_context *c = context;
    free_run_scratch *r = scratch;
    const int64_t S = c->n_samples, M = c->core.n_runs, T = c->core.n_steps, lag = c->rate_lag;
    const int64_t n_blocks = (S + LANES_F - 1) / LANES_F, lanes = n_blocks * LANES_F;
    const figures_f f = figures_of_f(c->core.car, c->core.dt, c->core.substeps);
    const substep_run_f run_substeps = substeps_for_f(c->core.car, c->core.implicit);
    const int64_t tile = al_tile();
    for (int64_t i = 0; i < lanes; ++i) { /* every slot of the ring starts as the state before step 0 */
        const int64_t at = (i < S ? i : S - 1) * 2 * M + m;
        for (int64_t j = 0; j < lag; ++j) {
            float *slot = r->ring + j * 4 * lanes;
            slot[i] = c->start[at], slot[lanes + i] = c->start_hidden[at];
            slot[2 * lanes + i] = c->start[at + M], slot[3 * lanes + i] = c->start_hidden[at + M];
        }
    }
    for (int64_t k = 0; k < T; ++k) {
        const int64_t j = k % tile;
        if (j == 0) /* the next tile's noise, each draw's from its key */
            for (int64_t s = 0; s < S; ++s)
                al_tile_noise((uint32_t)(k / tile), (uint32_t)m, (uint32_t)(c->keys[s] & 0xFFFFFFFFu),
                              (uint32_t)(c->keys[s] >> 32), r->zv + s * tile, r->zw + s * tile);
        const float *u = c->controls + (m * T + k) * 2;
        const int64_t row = c->index[m * T + k];
        float *past = r->ring + (k % lag) * 4 * lanes; /* the state `lag` steps back, then this step's */
        double mean[4] = {0.0, 0.0, 0.0, 0.0};        /* the draws' mean past (v_x, v_y, r, delta_w) */
        for (int i = 0; i < 4; ++i)
            for (int64_t s = 0; s < S; ++s) mean[i] += past[i * lanes + s];
        for (int64_t bi = 0; bi < n_blocks; ++bi) {
            block_f *b = &r->blocks[bi];
            float *const fields[4] = {b->vx, b->vy, b->r, b->delta};
            for (int i = 0; i < 4; ++i) memcpy(fields[i], past + i * lanes + bi * LANES_F, sizeof(float) * LANES_F);
            block_controls(b, r->gain + bi * LANES_F, &c->core, u[0], u[1]);
        }
        step_blocks(r->blocks, n_blocks, run_substeps, &f, c->core.substeps);
        for (int64_t bi = 0; bi < n_blocks; ++bi) correct(c, &r->blocks[bi], bi * LANES_F, row, r->v, r->w);
        if (c->widen) { /* surrogate.widened_step: each draw's correction spread, not its past */
            double common_v = 0.0, common_w = 0.0;
            for (int64_t bi = 0; bi < n_blocks; ++bi) {
                block_f *b = &r->common[bi];
                for (int l = 0; l < LANES_F; ++l) {
                    b->vx[l] = (float)(mean[0] / S), b->vy[l] = (float)(mean[1] / S);
                    b->r[l] = (float)(mean[2] / S), b->delta[l] = (float)(mean[3] / S);
                }
                block_controls(b, r->gain + bi * LANES_F, &c->core, u[0], u[1]);
            }
            step_blocks(r->common, n_blocks, run_substeps, &f, c->core.substeps);
            for (int64_t bi = 0; bi < n_blocks; ++bi) correct(c, &r->common[bi], bi * LANES_F, row, r->cv, r->cw);
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
        float *out = r->out + j * S; /* field f of draw s at out[f * tile * S + s] */
        const int64_t field = tile * S, U = c->n_rows;
        for (int64_t bi = 0; bi < n_blocks; ++bi) {
            const block_f *b = &r->blocks[bi];
            const int64_t first = bi * LANES_F, n = S - first < LANES_F ? S - first : LANES_F;
            for (int64_t l = 0; l < n; ++l) {
                const int64_t s = first + l;
                const double std_v = c->noise_std[s * 2 * U + row], std_w = c->noise_std[(s * 2 + 1) * U + row];
                const float v = (float)r->v[s], w = (float)r->w[s];
                out[s] = (float)(r->v[s] + std_v * r->zv[s * tile + j]);
                out[field + s] = (float)(r->w[s] + std_w * r->zw[s * tile + j]);
                out[2 * field + s] = v, out[3 * field + s] = w, out[4 * field + s] = b->vy[l];
                past[s] = v, past[lanes + s] = b->vy[l], past[2 * lanes + s] = w, past[3 * lanes + s] = b->delta[l];
                alea_v += std_v * std_v, alea_w += std_w * std_w;
                epi_v += (r->v[s] - centre_v) * (r->v[s] - centre_v);
                epi_w += (r->w[s] - centre_w) * (r->w[s] - centre_w);
            }
        }
        float *moment = c->centre + (m * T + k) * 2;
        moment[0] = (float)centre_v, moment[1] = (float)centre_w;
        moment = c->aleatoric + (m * T + k) * 2;
        moment[0] = (float)(alea_v / S), moment[1] = (float)(alea_w / S);
        moment = c->epistemic + (m * T + k) * 2;
        moment[0] = (float)(epi_v / S), moment[1] = (float)(epi_w / S);
        if (j == tile - 1 || k == T - 1) flush_tile(c, r, m, k - j, j + 1);
    }
    if (c->x) maneuver_pose(c, r, m);
}

/* S free runs of the physics kind on the dynamic core for maneuvers [0, n_maneuvers), on up to
 * n_threads threads (a maneuver at a time), its steps implicit (`dynamic_step(implicit=True)`).
 *
 * `car` (C_COUNT), sets (S, S_COUNT) each draw's figures, grid and speed the speed table; `limits`
 * (L_COUNT) the correction's bounds; controls (M, T, 2) the control each step reads, index (M, T) its
 * row among the n_rows distinct ones; z (S, 4, n_rows) the correction's raw outputs (speed, yaw rate,
 * their lags; gated), noise_std (S, 2, n_rows) the sensors' noise sizes and keys (S) each draw's
 * noise key (its normals drawn here, al_tile_noise); start and start_hidden (S, 2, M) the (v_x, r) and
 * (v_y, delta_w) before the first step, read until `rate_lag` steps have run. Writes each draw's rates
 * with the noise (S, 2, M, T) and the moments over draws (centre, aleatoric, epistemic; each (M, T, 2));
 * the rates without it and v_y stay in the worker's scratch, a maneuver at a time, for the pose. With x not
 * NULL, also each draw's pose x, y, yaw (S, M, T) integrated at pose_dt from the headings yaw0 (M,), the
 * point `arm` ahead of the rear axle, its rates carrying the model discrepancy where `discrepancy`
 * (S, 2: each draw's sizes of v and r) is not NULL, an OU process of `correlation_time` s
 * (`maneuver_pose`). Returns 0, -1 when out of memory, or -2 if the car's wheel passes have no variant. */
int al_dynamic_free_runs(const double *car, const double *sets, const double *grid, const double *speed,
                         int64_t n_table, const double *limits, int64_t n_samples, int64_t n_maneuvers,
                         int64_t n_steps, int64_t n_rows, double dt, int64_t substeps, int64_t rate_lag,
                         int64_t widen, double spread, const float *controls, const int64_t *index, const float *z,
                         const float *noise_std, const uint64_t *keys, const float *start, const float *start_hidden,
                         float *rates, float *centre, float *aleatoric, float *epistemic, float pose_dt,
                         float arm, double correlation_time, const float *yaw0, const double *discrepancy,
                         float *x, float *y, float *yaw, int64_t n_threads) {
    if (n_maneuvers <= 0 || n_steps <= 0) return 0;
    if (n_samples <= 0 || rate_lag < 1 || substeps < 1 || n_table < 2) return -1;
    if (!substeps_for_f(car, 1)) return -2; /* no variant of the car's wheel passes */
    free_run_context context = {
        {car, sets, grid, speed, n_table, n_samples, n_maneuvers, n_steps, substeps, 1, NULL, NULL, dt, NULL},
        limits, n_samples, n_rows, rate_lag, widen, spread, controls, index, z, noise_std, start, start_hidden,
        keys, rates, centre, aleatoric, epistemic, NULL, pose_dt, arm, correlation_time, yaw0, discrepancy, x, y,
        yaw};
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
