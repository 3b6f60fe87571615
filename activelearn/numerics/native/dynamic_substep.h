/* The dynamic single track's substep over a block of lanes, in one precision: a template that
 * dynamic_rollout.c includes twice, once in double (an identification's rate runs, whose
 * finite-difference Jacobian needs it) and once in float (the physics kind's free runs, whose states
 * are float32 as the torch twin's: twice the lanes a vector).
 *
 * Before each inclusion define REAL (float or double), LANES (lanes a block) and NAME(x) (a suffix for
 * every name defined here, e.g. x##_f); <tgmath.h> makes sin, atan, ... the precision's own. Every
 * literal goes through K() so that no expression is promoted to double in the float variant.
 */
#define K(x) ((REAL)(x))

static inline REAL NAME(clip)(REAL x, REAL low, REAL high) { return x < low ? low : (x > high ? high : x); }

static inline REAL NAME(sign)(REAL x) { return (REAL)(x > K(0)) - (REAL)(x < K(0)); }

/* The speed table at |throttle| (np.interp: linear between points, flat beyond the ends). */
static REAL NAME(table_speed)(const double *grid, const double *speed, int64_t n, double throttle) {
    const double x = fmin(fmax(fabs(throttle), grid[0]), grid[n - 1]);
    int64_t i = 0;
    while (i < n - 2 && grid[i + 1] <= x) ++i;
    return (REAL)(speed[i] + (x - grid[i]) / (grid[i + 1] - grid[i]) * (speed[i + 1] - speed[i]));
}

/* One block's lanes: their figures, state and this step's controls. */
typedef struct {
    REAL mu[LANES], brake[LANES], a_max[LANES];
    /* derived once from the figures (divisions out of the substep): the axles' cornering stiffness per
     * newton of load, their magic formula's B per newton, 1 / yaw inertia, 1 / top speeds */
    REAL k_f[LANES], k_r[LANES], b_f[LANES], b_r[LANES], inv_inertia[LANES], inv_top[LANES], inv_reverse[LANES];
    /* with the kinematic core below the blend speed: its understeer (forward, reverse), scrub, and the share
     * of the way to the kinematic yaw rate a substep makes, 1 - exp(-h / yaw lag) */
    REAL understeer[LANES], reverse_understeer[LANES], scrub[LANES], follow[LANES];
    REAL vx[LANES], vy[LANES], r[LANES], delta[LANES];
    REAL tau[LANES], target[LANES], drive[LANES]; /* this step's controls; drive: the table's speed */
} NAME(block);

/* The car's shared figures as a substep reads them. */
typedef struct {
    REAL g, m, lf, lr, hcg, L, shape, curvature, blend, floor_speed, share, h, turn;
    REAL vsw, lag, tiny, room_floor, half_track;
    REAL phi_peak; /* |phi| where the magic formula peaks, C atan phi = pi / 2 (C <= 1: never, a large number) */
    int kinematic_core; /* C_KINEMATIC_CORE: a runtime choice between two lane loops (`substep`) */
} NAME(figures);

/* Lane l's drive: the motor law on v_x (`motor`) or the lag to the speed table's speed, m/s². */
static inline __attribute__((always_inline)) REAL NAME(drive)(const NAME(block) *b, const int l,
                                                              const NAME(figures) *f, const int motor) {
    const REAL vx0 = b->vx[l], tau = b->tau[l];
    if (!motor) return (b->drive[l] - vx0) / f->lag;
    const REAL inv_top = tau > K(0) ? b->inv_top[l] : b->inv_reverse[l];
    const REAL limit = b->a_max[l] * f->vsw / fmax(fabs(vx0), f->vsw);
    return NAME(clip)(b->a_max[l] * (tau - vx0 * inv_top), -limit, limit);
}

/* Lane l's wheel angle `delta` (its sin and cos) and each axle's slip angle from its velocity in its
 * wheel frame, the forward speed floored (dynamic_track._slip_angles). cos from sin (|delta| is within
 * the lock, below pi/2): GCC would fuse a sin and cos into a sincos, which does not vectorise; tan is
 * their ratio. */
static inline __attribute__((always_inline)) void NAME(slip_angles)(const NAME(block) *b, const int l,
                                                                    const NAME(figures) *f, const REAL delta,
                                                                    REAL *sn, REAL *cs, REAL *alpha_f,
                                                                    REAL *alpha_r) {
    const REAL vx0 = b->vx[l], vy0 = b->vy[l], r0 = b->r[l];
    *sn = sin(delta), *cs = sqrt(K(1) - *sn * *sn);
    const REAL front_y = vy0 + f->lf * r0;
    const REAL long_f = vx0 * *cs + front_y * *sn, lat_f = front_y * *cs - vx0 * *sn;
    *alpha_f = atan(-lat_f / fmax(fabs(long_f), f->floor_speed));
    *alpha_r = atan(-(vy0 - f->lr * r0) / fmax(fabs(vx0), f->floor_speed));
}

/* The simplified magic formula's share of the grip at B alpha: sin(C atan(B alpha - E (B alpha - atan B alpha)))
 * (`curved`: E is not 0). */
static inline __attribute__((always_inline)) REAL NAME(magic)(REAL b_alpha, const NAME(figures) *f, const int curved) {
    if (curved) b_alpha -= f->curvature * (b_alpha - atan(b_alpha));
    return sin(f->shape * atan(b_alpha));
}

/* Lane l's axle's damping slope per newton of load at slip angle alpha (dynamic_track._damping_slopes): the
 * linear tyre's stiffness k within its cap, the magic formula's k cos(C atan phi) phi' / (1 + phi^2) (b: its
 * B), 0 past the peak. The cosine from `s`, the formula's sine at alpha: a cos beside that sin would fuse into
 * a sincos, which does not vectorise (3.8x the free runs' time). */
static inline __attribute__((always_inline)) REAL NAME(damping_slope)(REAL k, REAL b, REAL alpha, REAL s, REAL mu,
                                                                      const NAME(figures) *f, const int linear,
                                                                      const int curved) {
    if (linear) return fabs(k * alpha) < mu ? k : K(0);
    const REAL x = b * alpha;
    REAL phi = x, dphi = K(1);
    if (curved) phi = x - f->curvature * (x - atan(x)), dphi = K(1) - f->curvature + f->curvature / (K(1) + x * x);
    const REAL cosine = fabs(phi) < f->phi_peak ? sqrt(fmax(K(1) - s * s, K(0))) : K(0);
    return k * cosine / (K(1) + phi * phi) * dphi;
}

/* Lane l's axles' damping slopes per newton of load: `damping_slope`'s with `tangent`, else their
 * cornering stiffness (s_f, s_r: the magic formula's sines at alpha_f, alpha_r). */
static inline __attribute__((always_inline)) void NAME(dampings)(const NAME(block) *b, const int l,
                                                                 const NAME(figures) *f, const REAL alpha_f,
                                                                 const REAL alpha_r, const REAL s_f,
                                                                 const REAL s_r, const int linear,
                                                                 const int curved, const int tangent,
                                                                 REAL *slope_f, REAL *slope_r) {
    const REAL mu = b->mu[l];
    *slope_f = tangent ? NAME(damping_slope)(b->k_f[l], b->b_f[l], alpha_f, s_f, mu, f, linear, curved) : b->k_f[l];
    *slope_r = tangent ? NAME(damping_slope)(b->k_r[l], b->b_r[l], alpha_r, s_r, mu, f, linear, curved) : b->k_r[l];
}

/* The blend's weight at `speed` (dynamic_track._blend_weight): 1 dynamic, 0 kinematic. */
static inline __attribute__((always_inline)) REAL NAME(blend_weight)(const NAME(figures) *f, const REAL speed) {
    return K(0.5) * (K(1) + tanh((speed - f->blend) / (K(0.25) * f->blend)));
}

/* v_x's rate with the body frame's `turn` (v_y r): dvx's, or with `kinematic` the drive's `a`, the tyres'
 * and turn's terms weighed by w0 and the scrub's drag by 1 - w0 (dynamic_track._advance's `forward`). */
static inline __attribute__((always_inline)) REAL NAME(forward)(const int kinematic, const REAL dvx, const REAL turn,
                                                                const REAL a, const REAL w0, const REAL scrub) {
    return kinematic ? a + w0 * ((dvx - a) + turn) - (K(1) - w0) * scrub : dvx + turn;
}

/* The end of lane l's substep: the state moved by its rates of change dvx, dvy, dr (the forces over m and
 * I_z, without the body frame's turn), explicitly or with the tyres' damping exponential and the turn
 * semi-implicit (dynamic_step(implicit=True)), then blended into the kinematic state below the blend
 * speed, weighed by |v_x| or, with `ground`, the speed over ground; the wheels' angle set to `delta`.
 * `slope_f`, `slope_r`: the axles' damping per newton of load (their stiffness k, or `damping_slope`'s). */
static inline __attribute__((always_inline)) void NAME(advance)(NAME(block) *b, const int l,
                                                                const NAME(figures) *f, const int implicit,
                                                                const int ground, const REAL dvx,
                                                                const REAL dvy, const REAL dr,
                                                                const REAL load_f, const REAL load_r,
                                                                const REAL slope_f, const REAL slope_r,
                                                                const REAL delta, const REAL sn, const REAL cs,
                                                                const int kinematic, const REAL a,
                                                                const REAL inverse_lag) {
    const REAL m = f->m, lf = f->lf, lr = f->lr, h = f->h;
    const REAL vx0 = b->vx[l], vy0 = b->vy[l], r0 = b->r[l];
    /* `kinematic` (dynamic_track._advance's `drive`): v_x's tyre and turn terms weigh w at the substep's
     * start, the scrub's drag s tan^2 delta v_x / T_v (a: the drive's acceleration in dvx) 1 - w */
    REAL w0 = K(1), scrub = K(0);
    if (kinematic) {
        const REAL speed0 = ground ? sqrt(vx0 * vx0 + vy0 * vy0) : fabs(vx0);
        w0 = NAME(blend_weight)(f, speed0);
        scrub = b->scrub[l] * (sn * sn) / (cs * cs) * vx0 * inverse_lag;
    }
    REAL vx, vy, r;
    if (implicit) {
        const REAL speed = fmax(fabs(vx0), f->floor_speed);
        const REAL c_f = slope_f * load_f, c_r = slope_r * load_r;
        const REAL x_lat = fmax(h * (c_f + c_r) / (m * speed), f->tiny);
        const REAL x_yaw = fmax(h * (lf * lf * c_f + lr * lr * c_r) * b->inv_inertia[l] / speed, f->tiny);
        vy = vy0 + h * (dvy - vx0 * r0) * (-expm1(-x_lat) / x_lat);
        vx = vx0 + h * NAME(forward)(kinematic, dvx, vy * r0, a, w0, scrub);
        r = r0 + h * dr * (-expm1(-x_yaw) / x_yaw);
    } else {
        vx = vx0 + h * NAME(forward)(kinematic, dvx, vy0 * r0, a, w0, scrub);
        vy = vy0 + h * (dvy - vx0 * r0);
        r = r0 + h * dr;
    }
    const REAL speed = ground ? sqrt(vx * vx + vy * vy) : fabs(vx);
    const REAL w = NAME(blend_weight)(f, speed);
    REAL r_kin = vx * sn / (cs * f->L);
    if (kinematic) { /* the kinematic core's turn, reached with its yaw lag from the substep's start */
        const REAL understeer = vx >= K(0) ? b->understeer[l] : b->reverse_understeer[l];
        r_kin = r0 + b->follow[l] * (vx * sn / (cs * f->L * understeer) - r0);
    }
    b->r[l] = w * r + (K(1) - w) * r_kin;
    b->vy[l] = w * vy + (K(1) - w) * lr * r_kin;
    b->vx[l] = vx, b->delta[l] = delta;
}

/* One wheel's forces within its friction circle (Kamm's): where the longitudinal and lateral forces it
 * asks for exceed mu F_z, both scaled back onto the circle, their direction kept. */
static inline __attribute__((always_inline)) void NAME(circle)(REAL f_long, REAL f_lat, REAL cap, REAL tiny,
                                                               REAL *x, REAL *y) {
    const REAL scale = fmin(cap / fmax(sqrt(f_long * f_long + f_lat * f_lat), tiny), K(1));
    *x = f_long * scale, *y = f_lat * scale;
}

/* One substep of lane l under the forces of four wheels (dynamic_track._wheel_substep and
 * _wheel_forces): each wheel's load with the longitudinal and the lateral transfer (a rigid body on four
 * equal contacts), its own friction circle, the yaw moment of unequal wheel forces; `passes` fixed-point
 * passes of the loads on the accelerations the forces give (a constant at each call: the pass loop
 * unrolls); the kinematic blend by the speed over ground. The same constants as `lane_step`. */
static inline __attribute__((always_inline)) void NAME(wheel_step)(NAME(block) *b, const int l,
                                                                   const NAME(figures) *f, const int motor,
                                                                   const int linear, const int implicit,
                                                                   const int curved, const int passes) {
    const REAL g = f->g, m = f->m, lf = f->lf, lr = f->lr, L = f->L, h = f->h;
    const REAL delta = b->delta[l] + NAME(clip)(b->target[l] - b->delta[l], -f->turn, f->turn);
    const REAL vx0 = b->vx[l], r0 = b->r[l], tau = b->tau[l], mu = b->mu[l];
    const REAL grip = mu * g, speed_x = fabs(vx0);
    REAL demand = NAME(drive)(b, l, f, motor); /* not within the grip: each wheel's circle caps its share */
    const REAL stop_rate = fmin(speed_x / h, b->brake[l]);
    const int braking = tau == K(0);
    demand = braking ? -NAME(sign)(vx0) * stop_rate : demand;
    REAL sn, cs, alpha_f, alpha_r;
    NAME(slip_angles)(b, l, f, delta, &sn, &cs, &alpha_f, &alpha_r);
    REAL unit_f, unit_r, s_f = K(0), s_r = K(0); /* each axle's lateral force per newton of load, pure
                                                   * slip; the magic formula's sine */
    if (linear) {
        unit_f = NAME(clip)(b->k_f[l] * alpha_f, -mu, mu);
        unit_r = NAME(clip)(b->k_r[l] * alpha_r, -mu, mu);
    } else {
        s_f = NAME(magic)(b->b_f[l] * alpha_f, f, curved), s_r = NAME(magic)(b->b_r[l] * alpha_r, f, curved);
        unit_f = mu * s_f, unit_r = mu * s_r;
    }
    const REAL drive_f = m * demand * K(0.5) * (K(1) - f->share), drive_r = m * demand * K(0.5) * f->share;
    REAL ax = NAME(clip)(demand, -grip, grip), ay = vx0 * r0, load_f = K(0), load_r = K(0);
    REAL x_fl = K(0), x_fr = K(0), x_rl = K(0), x_rr = K(0), y_fl = K(0), y_fr = K(0), y_rl = K(0), y_rr = K(0);
#pragma GCC unroll 8 /* whole: the lane loop vectorises only around straight code */
    for (int pass = 0; pass < passes; ++pass) {
        load_f = fmax(m * (g * lr - ax * f->hcg) / L, K(0));
        load_r = fmax(m * (g * lf + ax * f->hcg) / L, K(0));
        const REAL shift = m * ay * f->hcg / (K(4) * f->half_track); /* to the outside of the turn */
        const REAL fl = fmax(K(0.5) * load_f - shift, K(0)), fr = fmax(K(0.5) * load_f + shift, K(0));
        const REAL rl = fmax(K(0.5) * load_r - shift, K(0)), rr = fmax(K(0.5) * load_r + shift, K(0));
        const REAL total = fl + fr + rl + rr; /* at least m g */
        NAME(circle)(braking ? m * demand * fl / total : drive_f, unit_f * fl, mu * fl, f->tiny, &x_fl, &y_fl);
        NAME(circle)(braking ? m * demand * fr / total : drive_f, unit_f * fr, mu * fr, f->tiny, &x_fr, &y_fr);
        NAME(circle)(braking ? m * demand * rl / total : drive_r, unit_r * rl, mu * rl, f->tiny, &x_rl, &y_rl);
        NAME(circle)(braking ? m * demand * rr / total : drive_r, unit_r * rr, mu * rr, f->tiny, &x_rr, &y_rr);
        const REAL x_f = x_fl + x_fr, y_f = y_fl + y_fr;
        ax = (x_f * cs - y_f * sn + (x_rl + x_rr)) / m;
        ay = (x_f * sn + y_f * cs + (y_rl + y_rr)) / m;
    }
    const REAL x_f = x_fl + x_fr, y_f = y_fl + y_fr, y_r = y_rl + y_rr;
    const REAL moment = f->half_track * ((x_fr - x_fl) * cs + (x_rr - x_rl) + (y_fl - y_fr) * sn);
    const REAL dr = (lf * (y_f * cs + x_f * sn) - lr * y_r + moment) * b->inv_inertia[l];
    REAL slope_f, slope_r;
    NAME(dampings)(b, l, f, alpha_f, alpha_r, s_f, s_r, linear, curved, implicit == 2, &slope_f, &slope_r);
    NAME(advance)(b, l, f, implicit, 1, ax, ay, dr, load_f, load_r, slope_f, slope_r, delta, sn, cs, 0, K(0),
                  K(0));
}

/* One substep of lane l of a block. `motor`, `linear`, `implicit`, `curved` (the magic formula's
 * curvature E is not 0: two more atan a substep) and `law` (the slip law: 0 the rear drive's share of
 * its axle's circle, 1 combined slip, 2 and up the wheels' forces, `wheel_step`, with
 * WHEEL_PASS_CHOICES[law - 2] passes of their loads) are constants at each call
 * (always inlined), so each variant's lane loop (`substep`, `substep_pair`) has no branch and vectorises
 * with libmvec. */
static inline __attribute__((always_inline)) void NAME(lane_step)(NAME(block) *b, const int l,
                                                                  const NAME(figures) *f, const int motor,
                                                                  const int linear, const int implicit,
                                                                  const int curved, const int law,
                                                                  const int kinematic) {
    const REAL g = f->g, m = f->m, lf = f->lf, lr = f->lr, L = f->L, h = f->h;
    const int combined = law == 1;
    if (law >= 2) {
        NAME(wheel_step)(b, l, f, motor, linear, implicit, curved, WHEEL_PASS_CHOICES[law - 2]);
        return;
    }
    {
        const REAL delta = b->delta[l] + NAME(clip)(b->target[l] - b->delta[l], -f->turn, f->turn);
        const REAL vx0 = b->vx[l], tau = b->tau[l], mu = b->mu[l];
        const REAL grip = mu * g, speed_x = fabs(vx0);
        REAL a = NAME(drive)(b, l, f, motor);
        const REAL stop_rate = fmin(speed_x / h, b->brake[l]); /* brakes to rest, not past it */
        a = NAME(clip)(tau == K(0) ? -NAME(sign)(vx0) * stop_rate : a, -grip, grip);
        const REAL load_f = fmax(m * (g * lr - a * f->hcg) / L, K(0));
        const REAL load_r = fmax(m * (g * lf + a * f->hcg) / L, K(0));
        REAL sn, cs, alpha_f, alpha_r;
        NAME(slip_angles)(b, l, f, delta, &sn, &cs, &alpha_f, &alpha_r);
        const REAL cap_f = mu * load_f, cap_r = mu * load_r;
        REAL f_f, f_r, s_f = K(0), s_r = K(0);
        if (linear) {
            f_f = NAME(clip)(b->k_f[l] * load_f * alpha_f, -cap_f, cap_f);
            f_r = NAME(clip)(b->k_r[l] * load_r * alpha_r, -cap_r, cap_r);
        } else {
            s_f = NAME(magic)(b->b_f[l] * alpha_f, f, curved), s_r = NAME(magic)(b->b_r[l] * alpha_r, f, curved);
            f_f = cap_f * s_f, f_r = cap_r * s_r;
        }
        REAL room;
        if (combined) { /* the longitudinal force's share of each axle's friction circle, the brake's by
                         * load; at a grip-limited stop a share is the whole circle: the room keeps
                         * C_ROOM_FLOOR of it, away from the root's infinite slope */
            const REAL braking = (REAL)(tau == K(0)), by_load = load_r / (load_f + load_r); /* >= m g */
            const REAL share_r = f->share + braking * (by_load - f->share);
            const REAL drive_r = fabs(m * a * share_r), drive_f = fabs(m * a * (K(1) - share_r));
            const REAL floor_r = f->room_floor * cap_r, floor_f = f->room_floor * cap_f;
            const REAL room_f = sqrt(fmax((cap_f - drive_f) * (cap_f + drive_f), floor_f * floor_f));
            room = sqrt(fmax((cap_r - drive_r) * (cap_r + drive_r), floor_r * floor_r));
            f_f = NAME(clip)(f_f, -room_f, room_f);
        } else {
            const REAL drive_r = m * a * f->share; /* the drive's share of the rear friction circle */
            room = sqrt(fmax(cap_r * cap_r - drive_r * drive_r, K(0)));
        }
        f_r = NAME(clip)(f_r, -room, room);
        const REAL dvx = a - f_f * sn / m, dvy = (f_f * cs + f_r) / m;
        const REAL dr = (lf * f_f * cs - lr * f_r) * b->inv_inertia[l];
        REAL slope_f, slope_r;
        NAME(dampings)(b, l, f, alpha_f, alpha_r, s_f, s_r, linear, curved, implicit == 2, &slope_f, &slope_r);
        const REAL inverse_lag = motor ? b->a_max[l] * (tau > K(0) ? b->inv_top[l] : b->inv_reverse[l])
                                       : K(1) / f->lag; /* 1 / the drive's time constant */
        NAME(advance)(b, l, f, implicit, 0, dvx, dvy, dr, load_f, load_r, slope_f, slope_r, delta, sn, cs,
                      kinematic, a, inverse_lag);
    }
}

/* One substep of every lane of a block. */
static inline __attribute__((always_inline)) void NAME(substep)(NAME(block) *b, const NAME(figures) *f,
                                                                const int motor, const int linear,
                                                                const int implicit, const int curved,
                                                                const int law) {
    if (law < 2 && f->kinematic_core) {
#pragma GCC ivdep
        for (int l = 0; l < LANES; ++l) NAME(lane_step)(b, l, f, motor, linear, implicit, curved, law, 1);
        return;
    }
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) NAME(lane_step)(b, l, f, motor, linear, implicit, curved, law, 0);
}

/* Two blocks' substeps in one lane loop: two independent chains of transcendental calls in each vector
 * pass, so that one's latency hides the other's. */
static inline __attribute__((always_inline)) void NAME(substep_pair)(NAME(block) *a, NAME(block) *b,
                                                                     const NAME(figures) *f, const int motor,
                                                                     const int linear, const int implicit,
                                                                     const int curved, const int law) {
    if (law < 2 && f->kinematic_core) {
#pragma GCC ivdep
        for (int l = 0; l < LANES; ++l) {
            NAME(lane_step)(a, l, f, motor, linear, implicit, curved, law, 1);
            NAME(lane_step)(b, l, f, motor, linear, implicit, curved, law, 1);
        }
        return;
    }
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) {
        NAME(lane_step)(a, l, f, motor, linear, implicit, curved, law, 0);
        NAME(lane_step)(b, l, f, motor, linear, implicit, curved, law, 0);
    }
}

#define NAME_SUBSTEPS(MOTOR, LINEAR, IMPLICIT, CURVED, LAW)                                                \
    static void NAME(substeps_##MOTOR##LINEAR##IMPLICIT##CURVED##LAW)(NAME(block) * b, NAME(block) * pair,     \
                                                                       const NAME(figures) * f, int64_t n) {  \
        if (pair)                                                                                           \
            for (int64_t i = 0; i < n; ++i) NAME(substep_pair)(b, pair, f, MOTOR, LINEAR, IMPLICIT, CURVED, LAW); \
        else                                                                                                \
            for (int64_t i = 0; i < n; ++i) NAME(substep)(b, f, MOTOR, LINEAR, IMPLICIT, CURVED, LAW);         \
    }
/* nine variants of a drive law and a slip law: tyre x step (explicit, implicit, implicit at the tangent
 * slope) x curvature (a linear tyre has none) */
#define NAME_SUBSTEPS_OF(MOTOR, LAW)                                                                      \
    NAME_SUBSTEPS(MOTOR, 0, 0, 0, LAW) NAME_SUBSTEPS(MOTOR, 0, 0, 1, LAW)                                 \
    NAME_SUBSTEPS(MOTOR, 0, 1, 0, LAW) NAME_SUBSTEPS(MOTOR, 0, 1, 1, LAW)                                 \
    NAME_SUBSTEPS(MOTOR, 0, 2, 0, LAW) NAME_SUBSTEPS(MOTOR, 0, 2, 1, LAW)                                 \
    NAME_SUBSTEPS(MOTOR, 1, 0, 0, LAW) NAME_SUBSTEPS(MOTOR, 1, 1, 0, LAW) NAME_SUBSTEPS(MOTOR, 1, 2, 0, LAW)
NAME_SUBSTEPS_OF(0, 0)
NAME_SUBSTEPS_OF(1, 0)
NAME_SUBSTEPS_OF(0, 1)
NAME_SUBSTEPS_OF(1, 1)
NAME_SUBSTEPS_OF(0, 2)
NAME_SUBSTEPS_OF(1, 2)
NAME_SUBSTEPS_OF(0, 3)
NAME_SUBSTEPS_OF(1, 3)
#undef NAME_SUBSTEPS_OF
#undef NAME_SUBSTEPS

typedef void (*NAME(substep_run))(NAME(block) *, NAME(block) *, const NAME(figures) *, int64_t);

/* The variants by [law][motor][linear][step][curved] (a linear tyre's curved entry is its plain one). */
#define NAME_BY_CURVE(M, LI, I, LAW) {NAME(substeps_##M##LI##I##0##LAW), NAME(substeps_##M##LI##I##1##LAW)}
#define NAME_BY_CURVE_LINEAR(M, I, LAW) {NAME(substeps_##M##1##I##0##LAW), NAME(substeps_##M##1##I##0##LAW)}
#define NAME_BY_STEP(M, LAW)                                                                               \
    {{NAME_BY_CURVE(M, 0, 0, LAW), NAME_BY_CURVE(M, 0, 1, LAW), NAME_BY_CURVE(M, 0, 2, LAW)},              \
     {NAME_BY_CURVE_LINEAR(M, 0, LAW), NAME_BY_CURVE_LINEAR(M, 1, LAW), NAME_BY_CURVE_LINEAR(M, 2, LAW)}}
#define NAME_BY_MOTOR(LAW) {NAME_BY_STEP(0, LAW), NAME_BY_STEP(1, LAW)}

/* The variant for the car's drive, tyre and slip law and the step's kind: explicit, implicit, or implicit
 * damping at the tyres' local slope (`implicit` and the car's C_TANGENT_DAMPING); NULL where the car's
 * C_WHEEL_FORCES asks for passes the kernel has no variant of. */
static NAME(substep_run) NAME(substeps_for)(const double *k, int64_t implicit) {
    static const NAME(substep_run) variants[2 + WHEEL_PASS_COUNT][2][2][3][2] = {
        NAME_BY_MOTOR(0), NAME_BY_MOTOR(1), NAME_BY_MOTOR(2), NAME_BY_MOTOR(3)};
    const int linear = k[C_SHAPE] == 0.0, curved = k[C_CURVATURE] != 0.0;
    int law = k[C_COMBINED_SLIP] != 0.0;
    if (k[C_WHEEL_FORCES] != 0.0) {
        if (k[C_KINEMATIC_CORE] != 0.0) return NULL; /* the kinematic branch is the axles' step's */
        law = -1;
        for (int i = 0; i < WHEEL_PASS_COUNT; ++i)
            if (k[C_WHEEL_FORCES] == (double)WHEEL_PASS_CHOICES[i]) law = 2 + i;
        if (law < 0) return NULL;
    }
    const int step = implicit == 0 ? 0 : (k[C_TANGENT_DAMPING] != 0.0 ? 2 : 1);
    return variants[law][k[C_MOTOR] != 0.0][linear][step][curved];
}
#undef NAME_BY_MOTOR
#undef NAME_BY_STEP
#undef NAME_BY_CURVE_LINEAR
#undef NAME_BY_CURVE

/* The car's shared figures as a substep reads them, for steps of dt in `substeps` substeps. */
static NAME(figures) NAME(figures_of)(const double *k, double dt, int64_t substeps) {
    NAME(figures) f;
    const double L = k[C_LF] + k[C_LR], h = dt / (double)substeps;
    f.g = (REAL)k[C_GRAVITY], f.m = (REAL)k[C_MASS], f.lf = (REAL)k[C_LF], f.lr = (REAL)k[C_LR];
    f.hcg = (REAL)k[C_CG_HEIGHT], f.L = (REAL)L, f.shape = (REAL)k[C_SHAPE], f.curvature = (REAL)k[C_CURVATURE];
    f.blend = (REAL)k[C_BLEND_SPEED], f.floor_speed = (REAL)(0.5 * k[C_BLEND_SPEED]);
    f.share = (REAL)k[C_REAR_DRIVE_SHARE], f.h = (REAL)h, f.turn = (REAL)(k[C_STEERING_RATE] * h);
    f.vsw = (REAL)k[C_POWER_LIMIT_SPEED], f.lag = (REAL)k[C_SPEED_TIME_CONSTANT];
    f.room_floor = (REAL)k[C_ROOM_FLOOR], f.half_track = (REAL)(0.5 * k[C_TRACK]);
    f.tiny = sizeof(REAL) == sizeof(float) ? (REAL)1e-30 : (REAL)1e-300; /* (1 - e^-x) / x at x = 0 */
    f.phi_peak = k[C_SHAPE] > 1.0 ? (REAL)tan(M_PI / (2.0 * k[C_SHAPE])) : (REAL)1e30;
    f.kinematic_core = k[C_KINEMATIC_CORE] != 0.0;
    return f;
}

/* Lane l of a block takes parameter set `s`'s figures (its table gain into gain[l]); `k` the car's, `h` the
 * substep (s). */
static void NAME(load_figures)(NAME(block) *b, REAL *gain, int l, const double *s, const double *k, double h) {
    const double L = k[C_LF] + k[C_LR], weight = k[C_MASS] * k[C_GRAVITY];
    const double k_f = s[S_STIFFNESS_FRONT] / (weight * k[C_LR] / L);
    const double k_r = s[S_STIFFNESS_REAR] / (weight * k[C_LF] / L);
    b->mu[l] = (REAL)s[S_FRICTION], b->brake[l] = (REAL)s[S_BRAKE], b->a_max[l] = (REAL)s[S_MAX_ACCELERATION];
    b->k_f[l] = (REAL)k_f, b->k_r[l] = (REAL)k_r;
    b->b_f[l] = (REAL)(k_f / (k[C_SHAPE] * s[S_FRICTION])), b->b_r[l] = (REAL)(k_r / (k[C_SHAPE] * s[S_FRICTION]));
    b->inv_inertia[l] = (REAL)(1.0 / s[S_YAW_INERTIA]), b->inv_top[l] = (REAL)(1.0 / s[S_TOP_SPEED]);
    b->inv_reverse[l] = (REAL)(1.0 / s[S_REVERSE_TOP_SPEED]);
    b->understeer[l] = (REAL)s[S_UNDERSTEER], b->reverse_understeer[l] = (REAL)s[S_REVERSE_UNDERSTEER];
    b->scrub[l] = (REAL)s[S_SCRUB], b->follow[l] = (REAL)(-expm1(-h / s[S_YAW_LAG]));
    gain[l] = (REAL)s[S_TABLE_GAIN];
}

#undef K
