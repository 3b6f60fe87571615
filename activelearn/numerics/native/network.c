/* S sampled weight sets of a layer stack evaluated in tiles of rows: per-draw moments and their mix.
 *
 * What `StackModel.columns_forward` computes with torch, in one pass per tile of TILE_ROWS rows
 * whose activations stay in L1: standardise the inputs, run the layers shared by every draw once,
 * run the rest once per draw (sampled weights, or shared weights on per-draw activations), apply
 * the head, then write each draw's mean and variance (optionally mapped to physical units and
 * widened by the epistemic scale) and/or the moments over draws. torch instead writes each layer's
 * (S x width x rows) output to memory and reads it back for the activation, the next layer and
 * the head; for S = 32 draws of a 16-unit layer that is several MB per 4 096 rows.
 *
 * Activations are column layout: unit i of a tile is TILE_ROWS contiguous floats, i.e. ROW_VECS
 * vectors of VL lanes (GCC/Clang vector extensions: AVX-512, AVX2 or SSE as -march=native gives).
 * Each row's arithmetic does not depend on the tile it falls in or the thread that runs it: the
 * sum over a layer's inputs runs in input order in every lane. Rows past the end of the input are
 * zero-padded and never written out.
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "network.h"

#if defined(__AVX512F__)
#define VL 16
#elif defined(__AVX__)
#define VL 8
#else
#define VL 4
#endif
#define TILE_ROWS 64
#define ROW_VECS (TILE_ROWS / VL)
#define UNIT_BLOCK 4 /* output units per register block */
#if VL == 16          /* row vectors per register block: UNIT_BLOCK x VEC_BLOCK accumulators, */
#define VEC_BLOCK 4   /* 16 of AVX-512's 32 registers, 8 of AVX2's or SSE's 16 */
#else
#define VEC_BLOCK 2
#endif

typedef float vf __attribute__((vector_size(VL * sizeof(float))));
typedef int32_t vi __attribute__((vector_size(VL * sizeof(int32_t))));

static inline vf splat(float value) { return (vf){} + value; }

/* max(a, 0) lane by lane: the comparison gives an all-ones mask where a > 0. */
static inline vf relu_vec(vf a) { return (vf)((vi)a & (a > splat(0.0f))); }

/* o = act(h W + b) over a tile, W (n_in, n_out) row-major as torch stores it: h is n_in x ROW_VECS
 * vectors, o is n_out x ROW_VECS. UNIT_BLOCK x VEC_BLOCK accumulators stay in registers while the
 * inputs stream past; the empty asm pins each loaded input vector in a register (GCC otherwise
 * folds a reload into every FMA, and the loads, not the FMAs, bound the loop: 2.3 ms against
 * 3.2 ms for the default hybrid's 2 700 rows x 32 draws). relu is applied in registers; other
 * activations get a pass of their own (`activate`). */
static void layer_tile(int64_t n_in, int64_t n_out, const float *restrict W, const float *restrict b,
                       int relu, const vf *restrict h, vf *restrict o) {
    int64_t j = 0;
    for (; j + UNIT_BLOCK <= n_out; j += UNIT_BLOCK) {
        for (int g = 0; g < ROW_VECS; g += VEC_BLOCK) {
            vf acc[UNIT_BLOCK][VEC_BLOCK];
            for (int q = 0; q < UNIT_BLOCK; ++q)
                for (int v = 0; v < VEC_BLOCK; ++v) acc[q][v] = splat(b[j + q]);
            for (int64_t i = 0; i < n_in; ++i) {
                vf x[VEC_BLOCK];
                for (int v = 0; v < VEC_BLOCK; ++v) {
                    x[v] = h[i * ROW_VECS + g + v];
                    __asm__("" : "+v"(x[v]));
                }
                const float *w = W + i * n_out + j;
                for (int q = 0; q < UNIT_BLOCK; ++q)
                    for (int v = 0; v < VEC_BLOCK; ++v) acc[q][v] += w[q] * x[v];
            }
            for (int q = 0; q < UNIT_BLOCK; ++q)
                for (int v = 0; v < VEC_BLOCK; ++v)
                    o[(j + q) * ROW_VECS + g + v] = relu ? relu_vec(acc[q][v]) : acc[q][v];
        }
    }
    for (; j < n_out; ++j) {
        vf acc[ROW_VECS];
        for (int v = 0; v < ROW_VECS; ++v) acc[v] = splat(b[j]);
        for (int64_t i = 0; i < n_in; ++i)
            for (int v = 0; v < ROW_VECS; ++v) acc[v] += W[i * n_out + j] * h[i * ROW_VECS + v];
        for (int v = 0; v < ROW_VECS; ++v) o[j * ROW_VECS + v] = relu ? relu_vec(acc[v]) : acc[v];
    }
}

/* torch's softplus (beta 1; its threshold 20 changes nothing in float), as max(x, 0) + log(1 + y) with
 * y = e^-|x| in (0, 1]. log(1 + y) = 2 atanh(t), t = y / (2 + y) <= 1/3, by its odd series to t^13 (within
 * 2e-8): libmvec vectorises expf but has no log1pf, and its logf was a fifth of a physics free run. */
static inline float softplus(float x) {
    const float y = expf(-fabsf(x)), t = y / (2.0f + y), t2 = t * t;
    const float series = 1.0f + t2 * (1.0f / 3 + t2 * (1.0f / 5 + t2 * (1.0f / 7 +
                                      t2 * (1.0f / 9 + t2 * (1.0f / 11 + t2 * (1.0f / 13))))));
    return fmaxf(x, 0.0f) + 2.0f * t * series;
}

/* Activations other than relu (applied in layer_tile), in place over n floats. */
static void activate(int64_t code, float *restrict h, int64_t n) {
    const float selu_alpha = 1.6732632423543772848170429916717f;
    const float selu_scale = 1.0507009873554804934193349852946f;
    switch (code) {
    case ACT_TANH:
        for (int64_t k = 0; k < n; ++k) h[k] = tanhf(h[k]);
        break;
    case ACT_SIGMOID:
        for (int64_t k = 0; k < n; ++k) h[k] = 1.0f / (1.0f + expf(-h[k]));
        break;
    case ACT_ELU:
        for (int64_t k = 0; k < n; ++k) h[k] = h[k] > 0.0f ? h[k] : expm1f(h[k]);
        break;
    case ACT_SELU:
        for (int64_t k = 0; k < n; ++k)
            h[k] = selu_scale * (h[k] > 0.0f ? h[k] : selu_alpha * expm1f(h[k]));
        break;
    case ACT_SOFTPLUS:
        for (int64_t k = 0; k < n; ++k) h[k] = softplus(h[k]);
        break;
    default:
        break;
    }
}

/* Layers [first, last) on a tile: ping-pong between buf_a and buf_b; returns the buffer holding the
 * output. `sample` picks the weights of per-sample layers. The last network layer gets no activation. */
static const vf *run_layers(const al_network *net, int64_t first, int64_t last, int64_t sample,
                            const vf *h, vf *buf_a, vf *buf_b) {
    for (int64_t k = first; k < last; ++k) {
        const al_layer *layer = &net->layers[k];
        const float *W = layer->weight, *b = layer->bias;
        if (layer->per_sample) {
            W += sample * layer->n_out * layer->n_in;
            b += sample * layer->n_out;
        }
        vf *out = (h == buf_a) ? buf_b : buf_a;
        const int64_t activation = k == net->n_layers - 1 ? ACT_NONE : layer->activation;
        layer_tile(layer->n_in, layer->n_out, W, b, activation == ACT_RELU, h, out);
        if (activation != ACT_RELU) activate(activation, (float *)out, layer->n_out * TILE_ROWS);
        h = out;
    }
    return h;
}

/* Standardised inputs of a tile: rows [0, n) of x (n_inputs rows of stride ld_x), zero-padded. */
static void load_inputs(const al_network *net, const float *x, int64_t ld_x, int64_t n, vf *out) {
    float *o = (float *)out;
    for (int64_t i = 0; i < net->n_inputs; ++i) {
        const float mean = net->x_mean[i], std = net->x_std[i];
        for (int64_t r = 0; r < n; ++r) o[i * TILE_ROWS + r] = (x[i * ld_x + r] - mean) / std;
        for (int64_t r = n; r < TILE_ROWS; ++r) o[i * TILE_ROWS + r] = 0.0f;
    }
}

/* Head of one draw on a tile: means (n_outputs x TILE_ROWS) and variances, standardised. */
static void head(const al_network *net, const float *restrict h, float *restrict mean, float *restrict var) {
    const int64_t o = net->n_outputs;
    memcpy(mean, h, (size_t)(o * TILE_ROWS) * sizeof(float));
    if (net->gaussian_head) {
        const float *raw = h + o * TILE_ROWS;
        for (int64_t k = 0; k < o * TILE_ROWS; ++k) {
            const float std = softplus(raw[k]) + net->min_std;
            var[k] = std * std;
        }
    } else {
        for (int64_t j = 0; j < o; ++j)
            for (int64_t r = 0; r < TILE_ROWS; ++r) var[j * TILE_ROWS + r] = net->head_var[j];
    }
}

static int64_t max_width(const al_network *net) {
    int64_t width = net->n_inputs;
    for (int64_t k = 0; k < net->n_layers; ++k)
        if (net->layers[k].n_out > width) width = net->layers[k].n_out;
    return width;
}

/* Maps a tile's draws to outputs and writes its n valid rows, at row0, to the requested arrays. */
static void write_tile(const al_network *net, const al_outputs *out, float *restrict means,
                       float *restrict vars, int64_t row0, int64_t n) {
    const int64_t S = net->n_samples, o = net->n_outputs;
    const float inv_s = 1.0f / (float)S;
    float centre[TILE_ROWS], alea[TILE_ROWS], epi[TILE_ROWS];
    for (int64_t j = 0; j < o; ++j) {
        const float loc = out->out_mean ? out->out_mean[j] : 0.0f;
        const float scale = out->out_std ? out->out_std[j] : 1.0f;
        if (out->spread != 1.0f) { /* the widening needs the centre before the draws are mapped */
            for (int64_t r = 0; r < TILE_ROWS; ++r) centre[r] = 0.0f;
            for (int64_t s = 0; s < S; ++s) {
                const float *m = means + (s * o + j) * TILE_ROWS;
                for (int64_t r = 0; r < TILE_ROWS; ++r) centre[r] += m[r];
            }
            for (int64_t r = 0; r < TILE_ROWS; ++r) centre[r] *= inv_s;
        }
        /* Map every draw: m' = loc + scale * (c + spread (m - c)); v' = scale^2 v. */
        for (int64_t s = 0; s < S; ++s) {
            float *m = means + (s * o + j) * TILE_ROWS, *v = vars + (s * o + j) * TILE_ROWS;
            if (out->spread != 1.0f)
                for (int64_t r = 0; r < TILE_ROWS; ++r) m[r] = centre[r] + out->spread * (m[r] - centre[r]);
            if (loc != 0.0f || scale != 1.0f) {
                for (int64_t r = 0; r < TILE_ROWS; ++r) m[r] = loc + m[r] * scale;
                for (int64_t r = 0; r < TILE_ROWS; ++r) v[r] *= scale * scale;
            }
            if (out->means) memcpy(out->means + (s * o + j) * out->ld_draws + row0, m, (size_t)n * sizeof(float));
            if (out->variances)
                memcpy(out->variances + (s * o + j) * out->ld_draws + row0, v, (size_t)n * sizeof(float));
        }
        if (!(out->centre || out->aleatoric || out->epistemic)) continue;
        /* Moments over the mapped draws, two-pass as torch's mean of squared deviations. */
        for (int64_t r = 0; r < TILE_ROWS; ++r) centre[r] = alea[r] = epi[r] = 0.0f;
        for (int64_t s = 0; s < S; ++s) {
            const float *m = means + (s * o + j) * TILE_ROWS, *v = vars + (s * o + j) * TILE_ROWS;
            for (int64_t r = 0; r < TILE_ROWS; ++r) {
                centre[r] += m[r];
                alea[r] += v[r];
            }
        }
        for (int64_t r = 0; r < TILE_ROWS; ++r) centre[r] *= inv_s;
        for (int64_t s = 0; s < S; ++s) {
            const float *m = means + (s * o + j) * TILE_ROWS;
            for (int64_t r = 0; r < TILE_ROWS; ++r) epi[r] += (m[r] - centre[r]) * (m[r] - centre[r]);
        }
        const int64_t at = j * out->ld_moments + row0;
        for (int64_t r = 0; r < n; ++r) {
            if (out->centre) out->centre[at + r] = centre[r];
            if (out->aleatoric) out->aleatoric[at + r] = alea[r] * inv_s;
            if (out->epistemic) out->epistemic[at + r] = epi[r] * inv_s;
        }
    }
}

struct al_scratch {
    vf *inputs, *prefix_a, *prefix_b, *buf_a, *buf_b;
    float *means, *vars;
};

void al_scratch_free(al_scratch *scratch) {
    if (!scratch) return;
    free(scratch->inputs);
    free(scratch->prefix_a);
    free(scratch->prefix_b);
    free(scratch->buf_a);
    free(scratch->buf_b);
    free(scratch->means);
    free(scratch->vars);
    free(scratch);
}

al_scratch *al_scratch_new(const al_network *net) {
    const size_t unit = TILE_ROWS * sizeof(float), width = (size_t)max_width(net);
    const size_t draws = (size_t)(net->n_samples * net->n_outputs);
    al_scratch *scratch = calloc(1, sizeof(al_scratch));
    if (!scratch) return NULL;
    scratch->inputs = aligned_alloc(64, (size_t)net->n_inputs * unit);
    scratch->prefix_a = aligned_alloc(64, width * unit);
    scratch->prefix_b = aligned_alloc(64, width * unit);
    scratch->buf_a = aligned_alloc(64, width * unit);
    scratch->buf_b = aligned_alloc(64, width * unit);
    scratch->means = aligned_alloc(64, draws * unit);
    scratch->vars = aligned_alloc(64, draws * unit);
    if (!scratch->inputs || !scratch->prefix_a || !scratch->prefix_b || !scratch->buf_a || !scratch->buf_b ||
        !scratch->means || !scratch->vars) {
        al_scratch_free(scratch);
        return NULL;
    }
    return scratch;
}

void al_network_rows(const al_network *net, al_scratch *scratch, int64_t begin, int64_t end, const float *x,
                     int64_t ld_x, int64_t x_per_sample, const al_outputs *out) {
    const int64_t S = net->n_samples, o = net->n_outputs;
    const size_t unit = TILE_ROWS * sizeof(float);
    /* Layers before the first per-sample one take the same input for every draw: run them once. */
    int64_t shared = 0;
    if (!x_per_sample)
        while (shared < net->n_layers && !net->layers[shared].per_sample) ++shared;
    float *means = scratch->means, *vars = scratch->vars;
    for (int64_t row0 = begin; row0 < end; row0 += TILE_ROWS) {
        const int64_t n = end - row0 < TILE_ROWS ? end - row0 : TILE_ROWS;
        const vf *common = NULL;
        if (!x_per_sample) {
            load_inputs(net, x + row0, ld_x, n, scratch->inputs);
            common = run_layers(net, 0, shared, 0, scratch->inputs, scratch->prefix_a, scratch->prefix_b);
        }
        for (int64_t s = 0; s < S; ++s) {
            float *m = means + s * o * TILE_ROWS, *v = vars + s * o * TILE_ROWS;
            if (shared == net->n_layers && s > 0) { /* nothing sampled: every draw is the first */
                memcpy(m, means, (size_t)o * unit);
                memcpy(v, vars, (size_t)o * unit);
                continue;
            }
            const vf *h = common;
            if (x_per_sample) {
                load_inputs(net, x + s * net->n_inputs * ld_x + row0, ld_x, n, scratch->inputs);
                h = scratch->inputs;
            }
            h = run_layers(net, shared, net->n_layers, s, h, scratch->buf_a, scratch->buf_b);
            head(net, (const float *)h, m, v);
        }
        write_tile(net, out, means, vars, row0, n);
    }
}

/* ----- threads ---------------------------------------------------------------------------------
 * Workers take chunks from a shared counter until none are left, so a core slowed by the host
 * does not hold the others up. Threads are started per call (tens of microseconds): Python-level
 * dispatch of the same work cost ~0.4 ms of a 2 700-row predict. Each worker has its own scratch. */

static void *run_worker(void *arg) {
    al_job *job = arg;
    void *scratch = job->make_scratch(job->context);
    if (!scratch) {
        __atomic_store_n(&job->failed, 1, __ATOMIC_RELAXED);
        return NULL;
    }
    for (;;) {
        const int64_t chunk = __atomic_fetch_add(&job->next, 1, __ATOMIC_RELAXED);
        if (chunk >= job->n_chunks) break;
        job->run_chunk(job->context, scratch, chunk);
    }
    job->free_scratch(scratch);
    return NULL;
}

int al_run_parallel(al_job *job, int64_t n_threads) {
    pthread_t threads[AL_MAX_THREADS];
    if (n_threads > job->n_chunks) n_threads = job->n_chunks;
    if (n_threads > AL_MAX_THREADS) n_threads = AL_MAX_THREADS;
    int64_t started = 0;
    for (int64_t t = 1; t < n_threads; ++t) /* the calling thread is the first worker */
        if (pthread_create(&threads[started], NULL, run_worker, job) == 0) ++started;
    run_worker(job); /* if some threads failed to start, the rest take their chunks */
    for (int64_t t = 0; t < started; ++t) pthread_join(threads[t], NULL);
    return job->failed ? -1 : 0;
}

/* ----- al_network_forward ---------------------------------------------------------------------- */

#define FORWARD_CHUNK_TILES 8 /* 512 rows per chunk */

typedef struct {
    const al_network *net;
    int64_t n_rows, ld_x, x_per_sample;
    const float *x;
    const al_outputs *out;
} forward_context;

static void *forward_scratch(void *context) { return al_scratch_new(((forward_context *)context)->net); }

static void forward_free(void *scratch) { al_scratch_free(scratch); }

static void forward_chunk(void *context, void *scratch, int64_t chunk) {
    const forward_context *c = context;
    const int64_t begin = chunk * FORWARD_CHUNK_TILES * TILE_ROWS;
    const int64_t end = begin + FORWARD_CHUNK_TILES * TILE_ROWS < c->n_rows ? begin + FORWARD_CHUNK_TILES * TILE_ROWS
                                                                              : c->n_rows;
    al_network_rows(c->net, scratch, begin, end, c->x, c->ld_x, c->x_per_sample, c->out);
}

int al_network_forward(const al_network *net, int64_t n_rows, const float *x, int64_t ld_x,
                       int64_t x_per_sample, const al_outputs *out, int64_t n_threads) {
    if (n_rows <= 0) return 0;
    forward_context context = {net, n_rows, ld_x, x_per_sample, x, out};
    const int64_t chunk_rows = FORWARD_CHUNK_TILES * TILE_ROWS;
    al_job job = {forward_scratch, forward_free, forward_chunk, &context, (n_rows + chunk_rows - 1) / chunk_rows, 0, 0};
    return al_run_parallel(&job, n_threads);
}
