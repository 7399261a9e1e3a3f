/* gsz.decoder._native: float32 assembly of the decoded fields -- attribute planes, quaternions
 * from half-angle trig, voxel centres, SH rest vectors -- with the finiteness checks. */
#include <math.h>
#include <string.h>
#include <stdlib.h>
#include "stages.h"

int planes_to_f32_run(const double *src, int64_t M, int64_t k, float *out)
{
    uint32_t bad = 0;
    for (int64_t c = 0; c < k; c++) {
        const double *s = src + c * M;
        float *o = out + c;
        for (int64_t i = 0; i < M; i++) {
            const float f = (float)s[i];
            uint32_t u;
            memcpy(&u, &f, 4);
            bad |= (u & 0x7F800000u) == 0x7F800000u;
            o[i * k] = f;
        }
    }
    return !bad;
}

int quat_from_trig_run(const double *c, const double *s, int64_t M, float *q)
{
    int bad = 0;
    /* |w|, |x|, |y|, |z| <= 1 for finite c, s; a non-finite input makes them non-finite */
    for (int64_t i = 0; i < M; i++) {
        const double cr = c[i], cp = c[M + i], cy = c[2 * M + i];
        const double sr = s[i], sp = s[M + i], sy = s[2 * M + i];
        const double a = cr * cp, b = sr * sp, d = sr * cp, f = cr * sp;
        const double t0 = a * cy, t1 = b * sy, t2 = d * cy, t3 = f * sy;
        const double t4 = f * cy, t5 = d * sy, t6 = a * sy, t7 = b * cy;
        double w = t0 + t1, x = t2 - t3, y = t4 + t5, z = t6 - t7;
        if (w < 0) { w = -w; x = -x; y = -y; z = -z; }
        q[4 * i] = (float)w;
        q[4 * i + 1] = (float)x;
        q[4 * i + 2] = (float)y;
        q[4 * i + 3] = (float)z;
        bad |= !(isfinite(q[4 * i]) && isfinite(q[4 * i + 1]) && isfinite(q[4 * i + 2])
                 && isfinite(q[4 * i + 3]));
    }
    return !bad;
}

static inline uint64_t compact3(uint64_t v)
{
    v &= 0x1249249249249249ULL;
    v = (v | (v >> 2)) & 0x10C30C30C30C30C3ULL;
    v = (v | (v >> 4)) & 0x100F00F00F00F00FULL;
    v = (v | (v >> 8)) & 0x1F0000FF0000FFULL;
    v = (v | (v >> 16)) & 0x1F00000000FFFFULL;
    v = (v | (v >> 32)) & 0x1FFFFFULL;
    return v;
}

int voxel_positions_run(const uint64_t *codes, int64_t M, int depth, const double org[3],
                        double side, float *out)
{
    uint32_t bad = 0;
    const double pitch = side / (double)((int64_t)1 << depth);
    for (int64_t i = 0; i < M; i++) {
        const uint64_t ijk[3] = {compact3(codes[i] >> 2), compact3(codes[i] >> 1), compact3(codes[i])};
        for (int a = 0; a < 3; a++) {
            const double t = ((double)ijk[a] + 0.5) * pitch;
            const float f = (float)(org[a] + t);
            uint32_t u;
            memcpy(&u, &f, 4);
            bad |= (u & 0x7F800000u) == 0x7F800000u;
            out[3 * i + a] = f;
        }
    }
    return !bad;
}

/* exponent all ones = inf or nan (a bit test: no branch, no libm) */
static inline uint32_t f32_finite(float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    return (u & 0x7F800000u) != 0x7F800000u;
}

int all_finite_run(const uint32_t *p, int64_t n)
{
    uint32_t bad = 0;
    /* exponent all ones = inf or nan; branch-free so the loop vectorises */
    for (int64_t i = 0; i < n; i++) bad |= ((p[i] & 0x7F800000u) == 0x7F800000u);
    return !bad;
}

/* SHXF transform 1 (GSZ.md §8.2): stored (a, b, c) triplets back to (R, G, B) in place, bit for
 * bit as gsz.decoder.sh.luma_chroma_to_rgb (float64, no FMA: setup.py builds with
 * -ffp-contract=off); returns 1 when a result is not finite.  Here n triplets whose a, b and c
 * are the columns a, b, c (a component-major tile: stride SH_TILE between them). */
static const double LC_S3 = 0x1.279a74590331dp-1, LC_S2 = 0x1.6a09e667f3bccp-1, LC_S6 = 0x1.a20bd700c2c3fp-2;

static inline uint32_t luma_chroma_cols(float *restrict a, float *restrict b, float *restrict c,
                                        int64_t n)
{
    uint32_t bad = 0;
    for (int64_t t = 0; t < n; t++) {
        const double x = (double)a[t] * LC_S3, y = (double)b[t] * LC_S2, z = (double)c[t] * LC_S6;
        const float r = (float)((x + y) + z), g = (float)((x - y) + z), bl = (float)(x - 2.0 * z);
        a[t] = r;
        b[t] = g;
        c[t] = bl;
        bad |= !f32_finite(r) | !f32_finite(g) | !f32_finite(bl);
    }
    return bad;
}

/* The same on one row of D = 3K floats (a codeword): its triplets one at a time. */
static inline uint32_t luma_chroma_row(float *v, int64_t D)
{
    uint32_t bad = 0;
    for (int64_t j = 0; j + 2 < D; j += 3) bad |= luma_chroma_cols(v + j, v + j + 1, v + j + 2, 1);
    return bad;
}

/* SHXF bit 2 (GSZ.md §8.2, 1.8): stored vectors in the file's own axes back to RGB, bit for bit
 * as gsz.decoder.sh.klt_to_rgb: a stored value y as the integer rint(y * 2^24) (ties to even:
 * adding and taking away 1.5 * 2^52 rounds a double below 2^51 to an integer in the default
 * rounding mode), the product with the integer matrix m (float64 [D, D], row d: stored
 * component d's share of each RGB component) summed in doubles -- every product and partial
 * sum an integer below 2^53, so exact in any order, with or without fused multiply-adds --
 * times 2^-38, rounded once to f32.  A stored value at or beyond 256 (or not finite) makes the
 * part invalid: the functions return 1 and write nothing they were not already writing. */
#define KLT_MAX_ABS 256.0
#define KLT_RANGE_MESSAGE "KLT-coded SH value outside +-256 (corrupt parameters)"
static const double KLT_IN = 0x1p24, KLT_OUT = 0x1p-38, KLT_ROUND = 0x1.8p52;

/* rint(v * 2^24), ties to even (|v| < 256: below 2^51) */
static inline double klt_round(float v)
{
    return ((double)v * KLT_IN + KLT_ROUND) - KLT_ROUND;
}

/* Whether any of n floats is at or beyond the KLT's range (or not finite). */
static inline uint32_t klt_far(const float *c, int64_t n)
{
    uint32_t far = 0;
    for (int64_t t = 0; t < n; t++) far |= !(fabs((double)c[t]) < KLT_MAX_ABS);
    return far;
}

static inline double klt_int(float v, uint32_t *far)
{
    *far |= klt_far(&v, 1);
    return klt_round(v);
}

/* One row of D floats (a codeword) in place; y: D doubles of scratch. */
static uint32_t klt_row(float *v, int64_t D, const double *m, double *y)
{
    uint32_t far = 0;
    for (int64_t d = 0; d < D; d++) y[d] = klt_int(v[d], &far);
    if (far) return 1;
    for (int64_t j = 0; j < D; j++) {
        double acc = 0.0;
        for (int64_t d = 0; d < D; d++) acc += y[d] * m[d * D + j];
        v[j] = (float)(acc * KLT_OUT);
    }
    return 0;
}

/* Kept vectors per cache-friendly step of the transposed copy: the [D, P] channel set is read
 * column by column into a component-major tile of D x SH_TILE floats (23 KB for 45
 * components, L1-resident), whose full-length loops the compiler vectorises; each tile row is
 * then written to its output row whole (the rows lie anywhere in the output: a component at a
 * time touched each row's page D times per tile). */
#define SH_TILE 128
/* most SH importance classes (gsz.decoder.sh.MAX_SH_CLASSES) */
#define SH_MAX_CLASSES 16

/* col[0..n) = float(step * k + l0) of the symbols src[0..n), bit for bit as the NumPy path (the
 * product rounded, then the sum: -ffp-contract=off); returns 1 when one is not finite.  n =
 * SH_TILE (a constant trip count) is the vectorised case. */
static inline uint32_t dequant_col(const uint16_t *restrict src, double st, double l0,
                                   float *restrict col, int64_t n)
{
    uint32_t bad = 0;
    for (int64_t t = 0; t < n; t++) {
        const double prod = st * (double)src[t];
        const float f = (float)(prod + l0);
        col[t] = f;
        bad |= !f32_finite(f);
    }
    return bad;
}

/* The tile's product: column j of the tile = (sum over d of y[d] * m[d][j]) * 2^-38.  Exact
 * integer sums, so the AVX2/FMA build of the same loops (chosen at run time where the CPU has
 * it: 4 doubles a step and fused multiply-adds, ~3x the SSE2 baseline) gives the same bits. */
#define KLT_PRODUCT_BODY                                                                       \
    {                                                                                          \
        double acc[SH_TILE];                                                                   \
        for (int64_t j = 0; j < D; j++) {                                                      \
            for (int64_t t = 0; t < SH_TILE; t++) acc[t] = 0.0;                                \
            for (int64_t d = 0; d < D; d++) {                                                  \
                const double mj = m[d * D + j];                                                \
                const double *yd = y + d * SH_TILE;                                            \
                for (int64_t t = 0; t < SH_TILE; t++) acc[t] += yd[t] * mj;                    \
            }                                                                                  \
            float *col = tile + j * SH_TILE;                                                   \
            for (int64_t t = 0; t < SH_TILE; t++) col[t] = (float)(acc[t] * KLT_OUT);          \
        }                                                                                      \
    }
typedef void (*klt_product_fn)(float *restrict, int64_t, const double *restrict, const double *restrict);
static void klt_product_base(float *restrict tile, int64_t D, const double *restrict m,
                             const double *restrict y) KLT_PRODUCT_BODY
#if defined(__GNUC__) && defined(__x86_64__)
__attribute__((target("avx2,fma")))
static void klt_product_avx2(float *restrict tile, int64_t D, const double *restrict m,
                             const double *restrict y) KLT_PRODUCT_BODY
#endif

static klt_product_fn klt_product(void)
{
#if defined(__GNUC__) && defined(__x86_64__)
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return klt_product_avx2;
#endif
    return klt_product_base;
}

/* The KLT of a component-major tile's first n vectors in place (klt_row's arithmetic, run over
 * all SH_TILE columns -- a constant trip count the compiler vectorises; the columns past n are
 * scratch, earlier tiles' values or zeros); y: D x SH_TILE doubles of scratch. */
static uint32_t klt_tile(float *restrict tile, int64_t n, int64_t D, const double *restrict m,
                         double *restrict y)
{
    uint32_t far = 0;
    for (int64_t d = 0; d < D; d++) {
        const float *c = tile + d * SH_TILE;
        double *yd = y + d * SH_TILE;
        far |= n == SH_TILE ? klt_far(c, SH_TILE) : klt_far(c, n);
        for (int64_t t = 0; t < SH_TILE; t++) yd[t] = klt_round(c[t]);
    }
    if (far) return 1;
    klt_product()(tile, D, m, y);
    return 0;
}

/* Stored kept vectors [t0, t1) of block b (t1 - t0 <= SH_TILE): dequantised into the tile,
 * colour-transformed (luma/chroma, or the KLT m when not NULL: a value out of its range sets
 * *far and leaves the tile unwritten), written to their output rows at[t]. */
static uint32_t kept_tile(const uint16_t *kept, int64_t P, const double *steps, const double *lo,
                          int64_t B, int64_t b, int64_t D, int colour, const double *m, double *y,
                          uint32_t *far, const int64_t *at, int64_t t0, int64_t t1, float *tile, float *out)
{
    uint32_t bad = 0;
    const int64_t n = t1 - t0;
    for (int64_t d = 0; d < D; d++) {
        const uint16_t *src = kept + d * P + t0;
        const double st = steps[d * B + b], l0 = lo[d * B + b];
        float *col = tile + d * SH_TILE;
        bad |= n == SH_TILE ? dequant_col(src, st, l0, col, SH_TILE) : dequant_col(src, st, l0, col, n);
    }
    if (colour)
        for (int64_t j = 0; j + 2 < D; j += 3) {
            float *a = tile + j * SH_TILE;
            bad |= n == SH_TILE ? luma_chroma_cols(a, a + SH_TILE, a + 2 * SH_TILE, SH_TILE)
                                : luma_chroma_cols(a, a + SH_TILE, a + 2 * SH_TILE, n);
        }
    if (m && klt_tile(tile, n, D, m, y)) {
        *far = 1;
        return bad;
    }
    for (int64_t t = 0; t < n; t++) {
        float *row = out + at[t0 + t] * D;
        for (int64_t d = 0; d < D; d++) row[d] = tile[d * SH_TILE + t];
    }
    return bad;
}

int sh_assemble_run(const int64_t *flags, const uint16_t *kept, const double *steps,
                    const double *lo, int64_t B, const int64_t *classes, int64_t P,
                    const int64_t *idx, int64_t nidx, const double *cb, int64_t K, int64_t M,
                    int64_t D, int colour, const double *klt, float *out, int *finite, Err *e)
{
    /* the codebook as rows (a codeword is one contiguous copy) and the output row of every kept
     * vector; the [D, P] kept symbols are then dequantised tile by tile (reading them row by row,
     * one Gaussian at a time, strides P values per component: D streams that miss the cache) */
    float *rows = malloc((size_t)(K ? K : 1) * (size_t)(D ? D : 1) * sizeof *rows);
    int64_t *at = malloc((size_t)(P ? P : 1) * sizeof *at);
    /* per codeword: has a non-finite component (the finiteness of the output is collected as
     * it is written: no second pass over the largest output field) */
    uint8_t *rbad = malloc((size_t)(K ? K : 1));
    /* zeroed: the KLT reads a partial tile's scratch columns too */
    float *tile = calloc((size_t)SH_TILE * (size_t)(D ? D : 1), sizeof *tile);
    double *ky = klt ? malloc((size_t)SH_TILE * (size_t)(D ? D : 1) * sizeof *ky) : NULL;
    if (!rows || !at || !rbad || !tile || (klt && !ky)) {
        free(rows); free(at); free(rbad); free(tile); free(ky);
        return fail_nomem(e);
    }
    uint32_t far = 0;       /* a KLT-coded value out of range (GSZ.md §8.2): the part is invalid */
    for (int64_t j = 0; j < K; j++) {
        uint32_t bad = 0;
        for (int64_t d = 0; d < D; d++) {
            const float f = (float)cb[d * K + j];
            rows[j * D + d] = f;
            bad |= !f32_finite(f);
        }
        if (colour) bad |= luma_chroma_row(rows + j * D, D);   /* once per codeword */
        /* the KLT once per codeword, where indices use the codebook (as the NumPy path) */
        if (klt && nidx) far |= klt_row(rows + j * D, D, klt, ky);
        rbad[j] = (uint8_t)bad;
    }
    uint32_t bad = 0;
    int64_t kp = 0, ip = 0;
    int rc = 0;
    for (int64_t i = 0; i < M && !rc; i++) {
        const int64_t f = flags ? flags[i] : 0;
        if (f == 1) {
            if (kp >= P) rc = fail(e, "SHVQ chunk: more kept flags set than kept vectors");
            else at[kp++] = i;
        } else if (f == 0) {
            if (ip >= nidx) { rc = fail(e, "SHVQ chunk: fewer codeword indices than Gaussians"); break; }
            const int64_t j = idx[ip++];
            if (j < 0 || j >= K) rc = fail(e, "SHVQ chunk: codeword index out of range");
            else {
                memcpy(out + i * D, rows + j * D, (size_t)D * sizeof *out);
                bad |= rbad[j];
            }
        } else {
            rc = fail(e, "SHVQ chunk: kept flag outside 0/1");
        }
    }
    if (!rc && (kp != P || ip != nidx)) rc = fail(e, "SHVQ chunk: kept flags do not match the kept count");
    if (!rc && far) rc = fail(e, KLT_RANGE_MESSAGE);        /* a codeword's, after the stream checks */
    if (!rc && classes) {
        /* SHCL (GSZ.md §8.1): the vectors are stored class by class, Morton order within a class
         * (gsz.decoder.sh.class_order, a stable sort), so the kept vector of point-order rank r
         * is stored at its class's start + its rank within the class: a counting sort */
        int64_t next[SH_MAX_CLASSES] = {0};
        for (int64_t r = 0; r < P && !rc; r++) {
            if (classes[r] < 0 || classes[r] >= SH_MAX_CLASSES) rc = fail(e, "sh_assemble: class outside 0..15");
            else next[classes[r]]++;
        }
        int64_t run = 0;
        for (int q = 0; q < SH_MAX_CLASSES; q++) { const int64_t c = next[q]; next[q] = run; run += c; }
        int64_t *by = rc ? NULL : malloc((size_t)(P ? P : 1) * sizeof *by);
        if (!rc && !by) rc = fail_nomem(e);
        if (!rc) {
            for (int64_t r = 0; r < P; r++) by[next[classes[r]]++] = at[r];
            free(at);
            at = by;
        }
    }
    if (!rc) {
        /* block b of every channel covers stored vectors [s, s + len) (quant.split_lengths:
         * the first P mod B blocks hold one more); lo + step * k rounds as dequantize_groups'
         * float64 result, then to float32 as the NumPy path's float32 rows */
        const int64_t base = P / B, extra = P % B;
        int64_t s0 = 0;
        for (int64_t b = 0; b < B; b++) {
            const int64_t s1 = s0 + base + (b < extra);
            for (int64_t t0 = s0; t0 < s1; t0 += SH_TILE) {
                const int64_t t1 = t0 + SH_TILE < s1 ? t0 + SH_TILE : s1;
                bad |= kept_tile(kept, P, steps, lo, B, b, D, colour, klt, ky, &far, at, t0, t1, tile, out);
                if (far) break;
            }
            s0 = s1;
            if (far) break;
        }
        if (far) rc = fail(e, KLT_RANGE_MESSAGE);
    }
    free(rows);
    free(at);
    free(rbad);
    free(tile);
    free(ky);
    *finite = !bad;
    return rc;
}
