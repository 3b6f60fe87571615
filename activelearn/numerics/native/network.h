/* The sampled-network kernel's types and entry points (network.c), shared with static_rollout.c. */
#ifndef ACTIVELEARN_NETWORK_H
#define ACTIVELEARN_NETWORK_H

#include <stdint.h>

enum { ACT_NONE = 0, ACT_RELU, ACT_TANH, ACT_SIGMOID, ACT_ELU, ACT_SELU, ACT_SOFTPLUS };

/* One layer: weight (in, out) row-major (torch's layout) and bias (out), or S of each back to back
 * when per_sample. */
typedef struct {
    int64_t n_in, n_out, per_sample, activation;
    const float *weight, *bias;
} al_layer;

typedef struct {
    int64_t n_layers, n_samples, n_inputs, n_outputs;
    const al_layer *layers;
    const float *x_mean, *x_std; /* input standardisation */
    int64_t gaussian_head;       /* last layer gives (mean, raw scale): var = (softplus(raw) + min_std)^2 */
    float min_std;
    const float *head_var; /* otherwise: a fixed standardised variance per output (zeros: none) */
} al_network;

/* Where results go. Any pointer may be NULL. Per-draw arrays are (S, n_outputs, ld_draws) and
 * moment arrays (n_outputs, ld_moments), row-major, starting at the block's first row. The draws
 * are mapped to out_mean + out_std * (centre + spread * (m - centre)), their variances scaled by
 * out_std^2; the moments are taken over the mapped draws. */
typedef struct {
    float *means, *variances;
    int64_t ld_draws;
    float *centre, *aleatoric, *epistemic;
    int64_t ld_moments;
    const float *out_mean, *out_std;
    float spread;
} al_outputs;

/* Scratch memory for one thread's tiles of a network. */
typedef struct al_scratch al_scratch;
al_scratch *al_scratch_new(const al_network *net);
void al_scratch_free(al_scratch *scratch);

/* Evaluate every draw on rows [begin, end) and write what `out` asks for (at those rows). x holds
 * n_inputs rows of stride ld_x (one set shared by every draw), or S such sets back to back, each
 * n_inputs * ld_x floats, when x_per_sample. */
void al_network_rows(const al_network *net, al_scratch *scratch, int64_t begin, int64_t end, const float *x,
                     int64_t ld_x, int64_t x_per_sample, const al_outputs *out);

/* al_network_rows over all n_rows on up to n_threads threads: 0, or -1 if scratch memory ran out. */
int al_network_forward(const al_network *net, int64_t n_rows, const float *x, int64_t ld_x,
                       int64_t x_per_sample, const al_outputs *out, int64_t n_threads);

/* Chunks of work shared out to threads: run_chunk(context, scratch, chunk) for chunk in [0, n_chunks),
 * each worker thread with its own scratch from make_scratch (NULL: out of memory). */
#define AL_MAX_THREADS 256
typedef struct {
    void *(*make_scratch)(void *context);
    void (*free_scratch)(void *scratch);
    void (*run_chunk)(void *context, void *scratch, int64_t chunk);
    void *context;
    int64_t n_chunks;
    int64_t next;   /* the next chunk to take (atomic) */
    int failed;     /* set when a worker could not get scratch memory */
} al_job;

/* Runs a job on the calling thread and up to n_threads - 1 more: 0, or -1 if a worker failed. */
int al_run_parallel(al_job *job, int64_t n_threads);

/* The distinct consecutive rows of a tile's n <= 512 control rows u (n, 2): written in column layout
 * to rows_x (2, 512), each step's row index to row; returns their count (static_rollout.c). */
int32_t al_tile_rows(const float *u, int64_t n, float *rows_x, int32_t *row);

/* The steps of one tile of noise and rollout (512; static_rollout.c's TILE, counter_noise.TILE). */
int al_tile(void);

/* Standard normal (v, w) noise of steps [tile * 512, tile * 512 + 512) of maneuver m under a draw's
 * 64-bit key (key0 low word, key1 high word): counter-based, so it depends on nothing else
 * (static_rollout.c; the NumPy reference is activelearn/numerics/counter_noise.py). */
void al_tile_noise(uint32_t tile, uint32_t m, uint32_t key0, uint32_t key1, float *zv, float *zw);

/* The planar pose of one draw over one tile of n <= 512 steps from its rates vt, wt and, unless NULL,
 * the rear axle's lateral speed lt (512 each, zero beyond n), `sums` (w, v cos yaw - lat sin yaw,
 * v sin yaw + lat cos yaw) carried from tile to tile (static_rollout.c). */
void al_pose_tile(int64_t n, float dt, float arm, float start_yaw, const float *vt, const float *wt,
                  const float *lt, double sums[3], float *x, float *y, float *yaw);

#endif
