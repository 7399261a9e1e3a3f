/* gsz.decoder._native: the smaller stages -- inverse RAHT (raht.c), float32 assembly
 * (assemble.c), the encoder's rate statistics (rate.c). */
#ifndef GSZ_STAGES_H
#define GSZ_STAGES_H

#include "gsz_common.h"

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility push(hidden)
#endif

/* ------------------------------------------------------------------ raht.c (TRANSFORMS.md §2) */
typedef struct { int32_t left, right; double g1, g2; } RPair;

typedef struct {
    int64_t n;            /* leaves */
    int nlev;             /* non-empty binary levels */
    int64_t *lvl_start;   /* [nlev + 1]: pairs of non-empty level L (finest first) */
    RPair *pairs;         /* [n - 1] */
    double *sqrtw;        /* [n] sqrt(leaf weight) of a weighted tree (RWGT), else NULL */
} RTree;

void raht_static_init(void);
/* The tree of n leaves with strictly ascending Morton codes c0 (< 2^(3 depth)). */
int rtree_build(const uint64_t *c0, int64_t n, int depth, const int64_t *leafw, RTree **out, Err *e);
void rtree_free(RTree *t);
/* Inverse RAHT of channels c0..c0+k-1: dc [C], ac [C, n-1], out v [k, n] (see raht_apply). */
void raht_inverse(const RTree *t, const double *dc, const double *ac, int64_t c0, int64_t k,
                  double *v, int half);

/* ------------------------------------------------------------------ assemble.c (float32 out) */
/* Each returns 1 when every value written is finite. */
int planes_to_f32_run(const double *src, int64_t M, int64_t k, float *out);
int quat_from_trig_run(const double *c, const double *s, int64_t M, float *q);
int voxel_positions_run(const uint64_t *codes, int64_t M, int depth, const double org[3],
                        double side, float *out);
int all_finite_run(const uint32_t *p, int64_t n);
/* The widest loop the KLT product may use (on: 0 portable, 1 AVX2/FMA, 2 AVX-512, capped at
 * what the CPU has; -1 ask only); returns the level before.  All give the same bits (exact
 * integer sums). */
int klt_simd(int on);
/* SH rest vectors (flags NULL when no vector is kept; kept: uint16 symbols [D, P] dequantised
 * with steps / lo [D, B]; classes NULL without SHCL); GszFormatError on a bad flag / index.
 * *finite: whether every value written is finite. */
int sh_assemble_run(const int64_t *flags, const uint16_t *kept, const double *steps,
                    const double *lo, int64_t B, const int64_t *classes, int64_t P,
                    const int64_t *idx, int64_t nidx, const double *cb, int64_t K, int64_t M,
                    int64_t D, int colour, const double *klt, const int64_t *ridx, float *out,
                    int *finite, Err *e);

/* ------------------------------------------------------------------ rate.c (encoder) */
#define RATE_BITS 16                 /* gsz.decoder.quant.MAX_BITS: the out arrays' q axis */
#define RATE_SHIFTS 5                /* rate.MAX_BINSHIFT: the binned candidates' h = 1..5 */

typedef struct {
    double *k, *payload, *gap, *gap2, *level, *laplace, *binned;
} RateOut;

/* group_stats' loop over q_first..hi for nb sorted blocks of blen values; -1 out of memory. */
int rate_group_stats_run(const float *x, int64_t nb, int64_t blen, const double *tab,
                         int q_first, int hi, double rho_min, double rho_max, const RateOut *o);

/* loss_all_bits of one channel row x [length] cut into nb blocks (split_lengths): out [nb, 16]
 * written at columns lo-1..hi-1. */
void loss_all_bits_run(const float *x, int64_t length, int64_t nb, const float *mins,
                       const float *maxs, int lo, int hi, double *out);

/* quantize of one channel row x [length] cut into nb blocks at widths bits [nb] (1..16). */
void quantize_row_run(const float *x, int64_t length, int64_t nb, const float *mins,
                      const float *maxs, const int64_t *bits, int32_t *sym);

/* The size search's decoded SH rest rows (ShPayloads.decoded_rows): -1 on an index out of range. */
int sh_requant_rows(const float *sh, int64_t num_sh, int64_t d, const int64_t *order,
                    const int32_t *group, const int32_t *cw_row, int64_t n, const float *books,
                    int64_t num_books, const double *lo, const double *step, const double *top,
                    int64_t num_groups, float *out);

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility pop
#endif

#endif
