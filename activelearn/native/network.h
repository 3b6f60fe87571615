/* The sampled-network kernel's types and entry points (network.c), shared with static_rollout.c. */
#ifndef ACTIVELEARN_NETWORK_H
#define ACTIVELEARN_NETWORK_H

#include <stdint.h>

enum { ACT_NONE = 0, ACT_RELU, ACT_TANH, ACT_SIGMOID, ACT_ELU, ACT_SELU, ACT_SOFTPLUS };

/* One layer: weight (out, in) row-major and bias (out), or S of each back to back when per_sample. */
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

/* Evaluate every draw on n_rows rows and write what `out` asks for. x holds n_inputs rows of stride
 * ld_x (one set shared by every draw), or S such sets back to back, each n_inputs * ld_x floats,
 * when x_per_sample. */
void al_network_rows(const al_network *net, al_scratch *scratch, int64_t n_rows, const float *x, int64_t ld_x,
                     int64_t x_per_sample, const al_outputs *out);

/* al_network_rows with its own scratch: 0, or -1 if the scratch could not be allocated. */
int al_network_forward(const al_network *net, int64_t n_rows, const float *x, int64_t ld_x,
                       int64_t x_per_sample, const al_outputs *out);

int al_tile_rows(void);

#endif
