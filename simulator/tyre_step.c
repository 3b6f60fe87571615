/* The 'mujoco-tyres' cars' stepping loop in C: the tyre step of `simulator.tyre_car.TyreCar.tyre_forces`
 * and the MuJoCo step of each run, every physics step, without a Python call between them.
 *
 * Each step does what `TyreCar.rollout`'s NumPy path does through `mujoco.rollout` (the reference): the
 * tyre forces from the current state; the state set, the solver's warm start zeroed (every step starts
 * cold) and the warnings cleared; the commands and the chassis' applied force set; one mj_step; then the
 * state memory the step carries (the steering angle, the lagged loads from the touch sensors, the front
 * hinges' Ackermann angles, the rear wheels' rolled angles, zero hinge speeds). The same equations in the
 * same order, so a run differs from the reference only by float rounding (libm's atan, sin and tan
 * against NumPy's). Compiled without -ffast-math and without FMA contraction: the same answer on every
 * x86-64 machine with the same MuJoCo.
 *
 * Runs are independent: threads take whole runs from a shared counter, each stepping with its own mjData,
 * so a run's result does not depend on its batch or the thread count.
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>

#include <mujoco/mujoco.h>

/* One car: where the step reads and writes in a FULLPHYSICS state vector and in the sensor data, and the
 * tyre and drivetrain figures (the twin's scales applied). Mirrored by `simulator.tyre_kernel._Car`. */
typedef struct {
  int64_t nstate, nsens, nu, nv, xfrc;   /* xfrc: the chassis' offset in xfrc_applied */
  int64_t quat, vel, omega, delta;       /* first index in the state (quat 4, vel 3, omega 3) */
  int64_t loads[4], touch[4], steer[2], spin[2], kin[4];
  double centres[4][3], ipos[3];         /* wheel centres and the chassis CoM, body frame */
  double wheelbase, half_track, wheel_radius, fade_speed;
  double friction, shape, curvature, stiffness[4];
  double max_acceleration, top_speed, reverse_top_speed, power_limit_speed;
  double mass_nominal, brake_deceleration, drive_share[4];
  double steering_limit, steering_step, spin_factor;  /* rate x dt; dt / wheel radius */
} al_tyre_car;

/* NumPy's maximum and minimum: NaN in either gives NaN (a diverging run stays visible). */
static inline double np_max(double a, double b) { return (a >= b || a != a) ? a : b; }
static inline double np_min(double a, double b) { return (a <= b || a != a) ? a : b; }

/* tan of the front wheels' angles (true Ackermann) for a bicycle angle. */
static void ackermann(const al_tyre_car* c, double delta, double tangents[2]) {
  double t = tan(delta), length = c->wheelbase, half = c->half_track;
  tangents[0] = length * t / (length - half * t);
  tangents[1] = length * t / (length + half * t);
}

/* The tyre step of one state: the chassis' force and torque (world frame, about its CoM), the next
 * steering angle and the rear wheels' next angles. */
static void tyre_step(const al_tyre_car* c, const double* s, double throttle, double command,
                      double out[6], double* next_delta, double spin[2]) {
  const double* q = s + c->quat;
  double w = q[0], x = q[1], y = q[2], z = q[3];
  double r[3][3] = {
      {w * w + x * x - y * y - z * z, 2 * x * y - 2 * w * z, 2 * x * z + 2 * w * y},
      {2 * x * y + 2 * w * z, w * w - x * x + y * y - z * z, 2 * y * z - 2 * w * x},
      {2 * x * z - 2 * w * y, 2 * y * z + 2 * w * x, w * w - x * x - y * y + z * z},
  };
  const double* v = s + c->vel;
  const double* wb = s + c->omega;
  double om[3], ip[3];
  for (int k = 0; k < 3; k++) {
    om[k] = r[k][0] * wb[0] + r[k][1] * wb[1] + r[k][2] * wb[2];
    ip[k] = r[k][0] * c->ipos[0] + r[k][1] * c->ipos[1] + r[k][2] * c->ipos[2];
  }
  double delta = s[c->delta];
  double tangents[4] = {0.0, 0.0, 0.0, 0.0};
  ackermann(c, delta, tangents);
  /* longitudinal: the motor law on the car's forward speed, or the brake at throttle 0 */
  double speed = v[0] * r[0][0] + v[1] * r[1][0] + v[2] * r[2][0];
  double a_max = c->max_acceleration;
  double top = throttle > 0 ? c->top_speed : c->reverse_top_speed;
  double limit = a_max * c->power_limit_speed / np_max(fabs(speed), c->power_limit_speed);
  double accel = np_min(np_max(a_max * (throttle - speed / top), -limit), limit);
  double load[4], total = 0.0;
  for (int i = 0; i < 4; i++) {
    load[i] = np_max(s[c->loads[i]], 0.0);
    total += load[i];
  }
  double brake_force = c->mass_nominal * c->brake_deceleration / (total > 0 ? total : 1.0);
  double fade_rate = 1.0 / (0.1 * c->fade_speed);
  double drive = c->mass_nominal * accel;
  double sums[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  double v_long[4];
  for (int i = 0; i < 4; i++) {
    const double* p = c->centres[i];
    double cw[3];
    for (int k = 0; k < 3; k++) cw[k] = r[k][0] * p[0] + r[k][1] * p[1] + r[k][2] * p[2];
    double ux = v[0] + om[1] * cw[2] - om[2] * cw[1];
    double uy = v[1] + om[2] * cw[0] - om[0] * cw[2];
    double cs = 1.0 / sqrt(1.0 + tangents[i] * tangents[i]);
    double sn = tangents[i] * cs;
    double hx = r[0][0] * cs + r[0][1] * sn;
    double hy = r[1][0] * cs + r[1][1] * sn;
    double norm = hypot(hx, hy);
    hx /= norm;
    hy /= norm;
    v_long[i] = ux * hx + uy * hy;
    double v_lat = uy * hx - ux * hy;
    double alpha = atan(-v_lat / np_max(fabs(v_long[i]), c->fade_speed));
    double grip = c->friction * load[i];
    double fade = np_min(np_max(v_long[i] * fade_rate, -1.0), 1.0);
    double f_long = throttle == 0.0 ? -brake_force * load[i] * fade : drive * c->drive_share[i];
    double b_alpha = c->stiffness[i] * alpha;
    if (c->curvature != 0.0) b_alpha = b_alpha - c->curvature * (b_alpha - atan(b_alpha));
    double f_lat = grip * sin(c->shape * atan(b_alpha));
    double demand = hypot(f_long, f_lat);
    double scale = demand > grip ? grip / (demand > 0 ? demand : 1.0) : 1.0;
    f_long *= scale;
    f_lat *= scale;
    double fx = f_long * hx - f_lat * hy;
    double fy = f_long * hy + f_lat * hx;
    double arm_x = cw[0] - ip[0], arm_y = cw[1] - ip[1], arm_z = cw[2] - ip[2];
    double az = arm_z - c->wheel_radius;
    sums[0] += fx;
    sums[1] += fy;
    sums[3] += az * fy;
    sums[4] += az * fx;
    sums[5] += arm_x * fy - arm_y * fx;
  }
  out[0] = sums[0];
  out[1] = sums[1];
  out[2] = 0.0;
  out[3] = -sums[3];
  out[4] = sums[4];
  out[5] = sums[5];
  /* the rack's end stop and rate limit; the rear wheels roll */
  double target = np_min(np_max(command, -c->steering_limit), c->steering_limit);
  *next_delta = delta + np_min(np_max(target - delta, -c->steering_step), c->steering_step);
  spin[0] = s[c->spin[0]] + v_long[2] * c->spin_factor;
  spin[1] = s[c->spin[1]] + v_long[3] * c->spin_factor;
}

/* Step one run `nstep` physics steps from `init`, writing each step's state and sensor data. */
static void run_one(const mjModel* m, mjData* d, const al_tyre_car* c, int64_t nstep, const double* init,
                    const double* control, double* states, double* sens) {
  double current[c->nstate];
  memcpy(current, init, sizeof(double) * c->nstate);
  for (int64_t t = 0; t < nstep; t++) {
    const double* command = control + t * c->nu;
    double force[6], next_delta, spin[2], tangents[2];
    tyre_step(c, current, command[0], command[1], force, &next_delta, spin);
    mj_setState(m, d, current, mjSTATE_FULLPHYSICS);
    memset(d->qacc_warmstart, 0, sizeof(mjtNum) * c->nv);
    for (int i = 0; i < mjNWARNING; i++) d->warning[i].number = 0;
    memset(d->ctrl, 0, sizeof(mjtNum) * c->nu);
    d->ctrl[0] = command[0];
    d->ctrl[1] = command[1];
    memset(d->xfrc_applied, 0, sizeof(mjtNum) * 6 * m->nbody);
    memcpy(d->xfrc_applied + c->xfrc, force, sizeof force);
    mj_step(m, d);
    mj_getState(m, d, current, mjSTATE_FULLPHYSICS);
    current[c->delta] = next_delta;
    for (int i = 0; i < 4; i++) current[c->loads[i]] = d->sensordata[c->touch[i]];
    ackermann(c, next_delta, tangents);
    current[c->steer[0]] = atan(tangents[0]);
    current[c->steer[1]] = atan(tangents[1]);
    current[c->spin[0]] = spin[0];
    current[c->spin[1]] = spin[1];
    for (int i = 0; i < 4; i++) current[c->kin[i]] = 0.0;
    memcpy(states + t * c->nstate, current, sizeof(double) * c->nstate);
    memcpy(sens + t * c->nsens, d->sensordata, sizeof(mjtNum) * c->nsens);
  }
}

typedef struct {
  const mjModel* m;
  mjData* d;
  const al_tyre_car* car;
  int64_t nb, nstep;
  const double *init, *control;
  double *states, *sens;
  int64_t* next; /* shared: the next run to take */
} al_job;

static void* work(void* arg) {
  al_job* job = (al_job*)arg;
  const al_tyre_car* c = job->car;
  for (;;) {
    int64_t b = __atomic_fetch_add(job->next, 1, __ATOMIC_RELAXED);
    if (b >= job->nb) return NULL;
    run_one(job->m, job->d, c, job->nstep, job->init + b * c->nstate, job->control + b * job->nstep * c->nu,
            job->states + b * job->nstep * c->nstate, job->sens + b * job->nstep * c->nsens);
  }
}

/* Step nb runs: init (nb, nstate), control (nb, nstep, nu) -> states (nb, nstep, nstate), sens (nb, nstep,
 * nsens). `datas` holds `threads` mjData of the model; the calling thread is one of them. Returns 0, or
 * -1 when a thread could not be started (the runs it would have taken are stepped by the others). */
int al_tyre_rollout(const mjModel* m, mjData** datas, int64_t threads, const al_tyre_car* car, int64_t nb,
                    int64_t nstep, const double* init, const double* control, double* states, double* sens) {
  if (threads > nb) threads = nb;
  if (threads < 1) threads = 1;
  int64_t next = 0;
  al_job jobs[threads];
  pthread_t ids[threads];
  int started[threads];
  int status = 0;
  for (int64_t i = 0; i < threads; i++) {
    jobs[i] = (al_job){m, datas[i], car, nb, nstep, init, control, states, sens, &next};
    started[i] = 0;
  }
  for (int64_t i = 1; i < threads; i++) {
    started[i] = pthread_create(&ids[i], NULL, work, &jobs[i]) == 0;
    if (!started[i]) status = -1;
  }
  work(&jobs[0]);
  for (int64_t i = 1; i < threads; i++)
    if (started[i]) pthread_join(ids[i], NULL);
  return status;
}

/* sizeof(al_tyre_car): the Python mirror checks its layout against it. */
int64_t al_tyre_car_size(void) { return (int64_t)sizeof(al_tyre_car); }
