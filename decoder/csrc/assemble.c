/* gsz.decoder._native: float32 assembly of the decoded fields -- attribute planes, quaternions
 * from half-angle trig, voxel centres, SH rest vectors -- with the finiteness checks. */
#include <math.h>
#include <string.h>
#include <stdlib.h>
#include "stages.h"

/* a cache-line prefetch (w = 1: for writing) where the compiler has one; elsewhere nothing */
#if defined(__GNUC__)
#define GSZ_PREFETCH(p, w) __builtin_prefetch((p), (w), 3)
#else
#define GSZ_PREFETCH(p, w) ((void)(p))
#endif

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
/* the padded matrix's most columns: D = 45 at SH degree 3, the format's largest */
#define KLT_MAX_JP 48
#if defined(__GNUC__) && defined(__x86_64__)
#define GSZ_KLT_AVX2 1
#include <immintrin.h>
#else
#define GSZ_KLT_AVX2 0
#endif
#define KLT_RANGE_MESSAGE "KLT-coded SH value outside +-256 (corrupt parameters)"
static const double KLT_IN = 0x1p24, KLT_OUT = 0x1p-38, KLT_ROUND = 0x1.8p52;

/* rint(v * 2^24), ties to even (|v| < 256: below 2^51) */
static inline double klt_round(float v)
{
    return ((double)v * KLT_IN + KLT_ROUND) - KLT_ROUND;
}

/* rint(v * 2^24), and *far set when v is at or beyond the KLT's range (or not finite) */
static inline double klt_int(float v, uint32_t *far)
{
    *far |= !(fabs((double)v) < KLT_MAX_ABS);
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
/* tiles ahead whose kept symbols kept_tile prefetches (1 and 4 measured slower) */
#define TILES_AHEAD 2
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

/* The codeword of each of the tile's n vectors added to its dequantised residual (SHRF, GSZ.md
 * §8.3): tile[d][t] = tile[d][t] + cbf[r[t]][d], one float32 sum each.  cbf is the float32
 * codebook row-major: a vector's word is D contiguous floats (3 cache lines at D = 45), where a
 * component-major gather would touch a line per component. */
static uint32_t add_codewords(float *restrict tile, const float *restrict cbf, const int64_t *restrict r,
                              int64_t n, int64_t D)
{
    uint32_t bad = 0;
    for (int64_t t = 0; t < n; t++) {
        const float *w = cbf + r[t] * D;
        for (int64_t d = 0; d < D; d++) {
            const float f = tile[d * SH_TILE + t] + w[d];
            tile[d * SH_TILE + t] = f;
            bad |= !f32_finite(f);
        }
    }
    return bad;
}

/* The tile's product straight to the output rows: row at[t] = (sum over d of y[d][t] * m[d][j])
 * * 2^-38 for the tile's first n vectors.  m is the matrix padded to Jp (a multiple of 12)
 * columns with zeros.  Exact integer sums, so any order, fused or not, gives the same bits. */
/* vectors ahead whose output rows the products (and the row copy) prefetch: in class order
 * (SHCL) the rows lie anywhere in the output, and a row's first write waited for its lines */
#define ROWS_AHEAD 16

/* Prefetch for writing the output rows of vectors [k0, k1) (a row of D floats spans up to
 * four cache lines: its first line, every 64 bytes on, and its last byte). */
static inline void prefetch_rows(const float *out, const int64_t *at, int64_t k0, int64_t k1, int64_t D)
{
    for (int64_t k = k0; k < k1; k++) {
        const char *row = (const char *)(out + at[k] * D);
        for (int64_t o = 0; o < D * 4; o += 64) GSZ_PREFETCH(row + o, 1);
        GSZ_PREFETCH(row + D * 4 - 1, 1);
    }
}

typedef void (*klt_product_fn)(float *restrict, const int64_t *restrict, int64_t, int64_t, int64_t,
                               const double *restrict, const double *restrict);
static void klt_product_base(float *restrict out, const int64_t *restrict at, int64_t n, int64_t D,
                             int64_t Jp, const double *restrict m, const double *restrict y)
{
    /* four vectors at a time, their accumulators rows the inner loop runs along (vectorised) */
    double acc[4][KLT_MAX_JP];
    for (int64_t t0 = 0; t0 < n; t0 += 4) {
        prefetch_rows(out, at, t0 + ROWS_AHEAD, t0 + ROWS_AHEAD + 4 < n ? t0 + ROWS_AHEAD + 4 : n, D);
        for (int k = 0; k < 4; k++)
            for (int64_t j = 0; j < Jp; j++) acc[k][j] = 0.0;
        for (int64_t d = 0; d < D; d++) {
            const double *yd = y + t0 * D + d * 4, *md = m + d * Jp;
            const double y0 = yd[0], y1 = yd[1], y2 = yd[2], y3 = yd[3];
            for (int64_t j = 0; j < Jp; j++) {
                const double mj = md[j];
                acc[0][j] += y0 * mj;
                acc[1][j] += y1 * mj;
                acc[2][j] += y2 * mj;
                acc[3][j] += y3 * mj;
            }
        }
        for (int k = 0; k < 4 && t0 + k < n; k++) {
            float *row = out + at[t0 + k] * D;
            for (int64_t j = 0; j < D; j++) row[j] = (float)(acc[k][j] * KLT_OUT);
        }
    }
}
#if GSZ_KLT_AVX2
/* Register-blocked: 4 vectors x 12 columns of accumulators (12 ymm) per pass over d, so each
 * step loads 3 matrix vectors and 4 broadcasts for 12 fused multiply-adds (the tile-wide loop it
 * replaced stored its accumulators every step: 1.8x slower at D = 45). */
__attribute__((target("avx2,fma")))
static inline void klt_store_rows(float *restrict out, const int64_t *restrict at, int64_t t0, int64_t n,
                                  int64_t D, int64_t j0, int64_t w, const __m256d *r)
{
    const __m256d sc = _mm256_set1_pd(KLT_OUT);
    for (int k = 0; k < 4 && t0 + k < n; k++) {
        float *row = out + at[t0 + k] * D + j0;
        const __m128 f0 = _mm256_cvtpd_ps(_mm256_mul_pd(r[3 * k], sc)),
                     f1 = _mm256_cvtpd_ps(_mm256_mul_pd(r[3 * k + 1], sc)),
                     f2 = _mm256_cvtpd_ps(_mm256_mul_pd(r[3 * k + 2], sc));
        if (w == 12) {
            _mm_storeu_ps(row, f0);
            _mm_storeu_ps(row + 4, f1);
            _mm_storeu_ps(row + 8, f2);
        } else {            /* the last, partial column block (D = 9, 45) */
            float buf[12];
            _mm_storeu_ps(buf, f0);
            _mm_storeu_ps(buf + 4, f1);
            _mm_storeu_ps(buf + 8, f2);
            for (int64_t j = 0; j < w; j++) row[j] = buf[j];
        }
    }
}
__attribute__((target("avx2,fma")))
static void klt_product_avx2(float *restrict out, const int64_t *restrict at, int64_t n, int64_t D,
                             int64_t Jp, const double *restrict m, const double *restrict y)
{
    /* the twelve accumulators as named values: an array of them stays on the stack at -O2 */
#define KLT_FMA3(b, a0, a1, a2)                                                                \
    a0 = _mm256_fmadd_pd(b, m0, a0);                                                           \
    a1 = _mm256_fmadd_pd(b, m1, a1);                                                           \
    a2 = _mm256_fmadd_pd(b, m2, a2)
    for (int64_t t0 = 0; t0 < n; t0 += 4) {
        const double *yb = y + t0 * D;
        prefetch_rows(out, at, t0 + ROWS_AHEAD, t0 + ROWS_AHEAD + 4 < n ? t0 + ROWS_AHEAD + 4 : n, D);
        for (int64_t j0 = 0; j0 < Jp; j0 += 12) {
            __m256d a00 = _mm256_setzero_pd(), a01 = a00, a02 = a00, a10 = a00, a11 = a00, a12 = a00,
                    a20 = a00, a21 = a00, a22 = a00, a30 = a00, a31 = a00, a32 = a00;
            for (int64_t d = 0; d < D; d++) {
                const double *md = m + d * Jp + j0, *yd = yb + d * 4;
                const __m256d m0 = _mm256_loadu_pd(md), m1 = _mm256_loadu_pd(md + 4),
                              m2 = _mm256_loadu_pd(md + 8);
                KLT_FMA3(_mm256_broadcast_sd(yd), a00, a01, a02);
                KLT_FMA3(_mm256_broadcast_sd(yd + 1), a10, a11, a12);
                KLT_FMA3(_mm256_broadcast_sd(yd + 2), a20, a21, a22);
                KLT_FMA3(_mm256_broadcast_sd(yd + 3), a30, a31, a32);
            }
            const __m256d r[12] = {a00, a01, a02, a10, a11, a12, a20, a21, a22, a30, a31, a32};
            klt_store_rows(out, at, t0, n, D, j0, D - j0 < 12 ? D - j0 : 12, r);
        }
    }
#undef KLT_FMA3
}
/* The same with 8-double vectors: 4 vectors x 24 columns (12 zmm) per pass over d, for a padded
 * width that is a multiple of 24 (D = 24 and 45; D = 9 takes the AVX2 loop). */
__attribute__((target("avx512f,avx512vl,fma")))
static void klt_product_avx512(float *restrict out, const int64_t *restrict at, int64_t n, int64_t D,
                               int64_t Jp, const double *restrict m, const double *restrict y)
{
#define KLT_FMA3(b, a0, a1, a2)                                                                \
    a0 = _mm512_fmadd_pd(b, m0, a0);                                                           \
    a1 = _mm512_fmadd_pd(b, m1, a1);                                                           \
    a2 = _mm512_fmadd_pd(b, m2, a2)
    const __m512d sc = _mm512_set1_pd(KLT_OUT);
    for (int64_t t0 = 0; t0 < n; t0 += 4) {
        const double *yb = y + t0 * D;
        prefetch_rows(out, at, t0 + ROWS_AHEAD, t0 + ROWS_AHEAD + 4 < n ? t0 + ROWS_AHEAD + 4 : n, D);
        for (int64_t j0 = 0; j0 < Jp; j0 += 24) {
            __m512d a00 = _mm512_setzero_pd(), a01 = a00, a02 = a00, a10 = a00, a11 = a00, a12 = a00,
                    a20 = a00, a21 = a00, a22 = a00, a30 = a00, a31 = a00, a32 = a00;
            for (int64_t d = 0; d < D; d++) {
                const double *md = m + d * Jp + j0, *yd = yb + d * 4;
                const __m512d m0 = _mm512_loadu_pd(md), m1 = _mm512_loadu_pd(md + 8),
                              m2 = _mm512_loadu_pd(md + 16);
                KLT_FMA3(_mm512_set1_pd(yd[0]), a00, a01, a02);
                KLT_FMA3(_mm512_set1_pd(yd[1]), a10, a11, a12);
                KLT_FMA3(_mm512_set1_pd(yd[2]), a20, a21, a22);
                KLT_FMA3(_mm512_set1_pd(yd[3]), a30, a31, a32);
            }
            const __m512d r[12] = {a00, a01, a02, a10, a11, a12, a20, a21, a22, a30, a31, a32};
            const int64_t w = D - j0 < 24 ? D - j0 : 24;
            /* lanes of the row's columns j0 + [0, w): the padding columns are never written */
            const __mmask8 k2 = (__mmask8)(w >= 24 ? 0xFF : w <= 16 ? 0 : (1u << (w - 16)) - 1u),
                           k1 = (__mmask8)(w >= 16 ? 0xFF : w <= 8 ? 0 : (1u << (w - 8)) - 1u),
                           k0 = (__mmask8)(w >= 8 ? 0xFF : (1u << w) - 1u);
            for (int k = 0; k < 4 && t0 + k < n; k++) {
                float *row = out + at[t0 + k] * D + j0;
                _mm256_mask_storeu_ps(row, k0, _mm512_cvtpd_ps(_mm512_mul_pd(r[3 * k], sc)));
                _mm256_mask_storeu_ps(row + 8, k1, _mm512_cvtpd_ps(_mm512_mul_pd(r[3 * k + 1], sc)));
                _mm256_mask_storeu_ps(row + 16, k2, _mm512_cvtpd_ps(_mm512_mul_pd(r[3 * k + 2], sc)));
            }
        }
    }
#undef KLT_FMA3
}
#endif

/* The widest product the KLT may use: 0 the portable loop, 1 AVX2/FMA, 2 AVX-512 (for padded
 * widths of 24 and 48; 12 takes AVX2); -1: not yet asked.  All give the same bits. */
static int klt_level = -1;

static int klt_cpu_level(void)
{
#if GSZ_KLT_AVX2
    __builtin_cpu_init();
    if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) return 0;
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") ? 2 : 1;
#else
    return 0;
#endif
}

int klt_simd(int on)
{
    if (klt_level < 0) klt_level = klt_cpu_level();
    const int was = klt_level, best = klt_cpu_level();
    if (on >= 0) klt_level = on < best ? on : best;
    return was;
}

static klt_product_fn klt_product(int64_t Jp)
{
#if GSZ_KLT_AVX2
    if (klt_level >= 2 && Jp % 24 == 0) return klt_product_avx512;
    if (klt_level >= 1) return klt_product_avx2;
#endif
    (void)Jp;
    return klt_product_base;
}

/* One lane of klt_fill: stored value f (a residual: plus its codeword component w, one float32
 * sum checked for finiteness into *nf) -> *y = rint(f * 2^24); returns 1 out of range. */
static inline uint32_t klt_fill_one(float f, const float *w, double *y, uint32_t *nf)
{
    if (w) {
        f = f + *w;
        *nf |= !f32_finite(f);
    }
    *y = klt_round(f);
    return !(fabs((double)f) < KLT_MAX_ABS);
}

/* The product's integers of a component-major tile's first n vectors (klt_row's arithmetic):
 * y[t / 4][d][t % 4] = rint(v * 2^24), v = tile[d][t], or with cbf (SHRF, GSZ.md §8.3) v plus
 * component d of codeword r[t] of the float32 codebook rows cbf (one float32 sum, checked for
 * finiteness into *nf); the last 4-vector block's lanes past n are 0.  Returns 1 when a value is
 * at or beyond the range (or not finite).  Lanes from t0 on: the portable loop, and the SIMD
 * loop's tail. */
static uint32_t klt_fill_base(const float *restrict tile, const float *restrict cbf, const int64_t *restrict r,
                              int64_t t0, int64_t n, int64_t D, double *restrict y, uint32_t *nf)
{
    uint32_t far = 0;
    for (; t0 < n; t0 += 4) {
        double *yb = y + t0 * D;
        for (int64_t q = 0; q < 4; q++) {
            const int64_t t = t0 + q;
            const float *w = cbf && t < n ? cbf + r[t] * D : NULL;
            for (int64_t d = 0; d < D; d++) {
                if (t < n) far |= klt_fill_one(tile[d * SH_TILE + t], w ? w + d : NULL, yb + d * 4 + q, nf);
                else yb[d * 4 + q] = 0.0;
            }
        }
    }
    return far;
}
#if GSZ_KLT_AVX2
/* The same, 4 vectors' component d at once: their 4 tile values are contiguous, and so are the
 * 4 integers the product reads (the scalar loop's strided stores ran as long as the product). */
__attribute__((target("avx2,fma")))
static uint32_t klt_fill_avx2(const float *restrict tile, const float *restrict cbf, const int64_t *restrict r,
                              int64_t n, int64_t D, double *restrict y, uint32_t *nf)
{
    const __m128 lim = _mm_set1_ps((float)KLT_MAX_ABS), sign = _mm_set1_ps(-0.0f);
    const __m128i expo = _mm_set1_epi32(0x7F800000);
    const __m256d in = _mm256_set1_pd(KLT_IN), rnd = _mm256_set1_pd(KLT_ROUND);
    int inrange = 0xF, finite = 0xF;
    int64_t t0 = 0;
    for (; t0 + 4 <= n; t0 += 4) {
        double *yb = y + t0 * D;
        const float *w0 = cbf ? cbf + r[t0] * D : NULL, *w1 = cbf ? cbf + r[t0 + 1] * D : NULL,
                    *w2 = cbf ? cbf + r[t0 + 2] * D : NULL, *w3 = cbf ? cbf + r[t0 + 3] * D : NULL;
        for (int64_t d0 = 0; d0 < D; d0 += 4) {
            /* the 4 codewords' components d0..d0+3: 4 row loads turned into 4 component columns */
            __m128 wc[4] = {_mm_setzero_ps(), _mm_setzero_ps(), _mm_setzero_ps(), _mm_setzero_ps()};
            const int64_t nd = D - d0 < 4 ? D - d0 : 4;
            if (cbf && nd == 4) {
                wc[0] = _mm_loadu_ps(w0 + d0);
                wc[1] = _mm_loadu_ps(w1 + d0);
                wc[2] = _mm_loadu_ps(w2 + d0);
                wc[3] = _mm_loadu_ps(w3 + d0);
                _MM_TRANSPOSE4_PS(wc[0], wc[1], wc[2], wc[3]);
            } else if (cbf) {
                for (int64_t i = 0; i < nd; i++) wc[i] = _mm_set_ps(w3[d0 + i], w2[d0 + i], w1[d0 + i], w0[d0 + i]);
            }
            for (int64_t i = 0; i < nd; i++) {
                const int64_t d = d0 + i;
                __m128 f = _mm_loadu_ps(tile + d * SH_TILE + t0);
                if (cbf) {
                    f = _mm_add_ps(f, wc[i]);
                    finite &= ~_mm_movemask_ps(_mm_castsi128_ps(
                        _mm_cmpeq_epi32(_mm_and_si128(_mm_castps_si128(f), expo), expo)));
                }
                inrange &= _mm_movemask_ps(_mm_cmp_ps(_mm_andnot_ps(sign, f), lim, _CMP_LT_OQ));
                const __m256d v = _mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(_mm256_cvtps_pd(f), in), rnd), rnd);
                _mm256_storeu_pd(yb + d * 4, v);
            }
        }
    }
    *nf |= finite != 0xF;
    return (inrange != 0xF) | (t0 < n ? klt_fill_base(tile, cbf, r, t0, n, D, y, nf) : 0);
}
#endif

/* The KLT of a component-major tile's first n vectors (with cbf: each plus its codeword r[t],
 * klt_fill), written to their output rows at[t] (the tile's columns past n are never read into
 * a row); y: D x SH_TILE doubles of scratch (klt_fill's layout: the product reads a 4-vector
 * block contiguously), m the matrix padded to Jp columns.  Returns 1 (writing no row) when a
 * value is out of range; *nf |= a codeword sum not finite. */
static uint32_t klt_tile(const float *restrict tile, const float *restrict cbf, const int64_t *restrict r,
                         int64_t n, int64_t D, int64_t Jp, const double *restrict m, double *restrict y,
                         const int64_t *restrict at, float *restrict out, uint32_t *nf)
{
#if GSZ_KLT_AVX2
    const uint32_t far = klt_level >= 1 ? klt_fill_avx2(tile, cbf, r, n, D, y, nf)
                                        : klt_fill_base(tile, cbf, r, 0, n, D, y, nf);
#else
    const uint32_t far = klt_fill_base(tile, cbf, r, 0, n, D, y, nf);
#endif
    if (far) return 1;
    klt_product(Jp)(out, at, n, D, Jp, m, y);
    return 0;
}

/* Stored kept vectors [t0, t1) of block b (t1 - t0 <= SH_TILE): dequantised into the tile,
 * colour-transformed (luma/chroma, or the KLT m when not NULL -- padded to Jp columns: a value
 * out of its range sets *far and writes no row), written to their output rows at[t]. */
static uint32_t kept_tile(const uint16_t *kept, int64_t P, const double *steps, const double *lo,
                          int64_t B, int64_t b, int64_t D, int colour, const double *m, int64_t Jp,
                          double *y, uint32_t *far, const int64_t *at, int64_t t0, int64_t t1,
                          const int64_t *ridx, const float *cbf, float *tile, float *out)
{
    uint32_t bad = 0;
    const int64_t n = t1 - t0;
    for (int64_t d = 0; d < D; d++) {
        const uint16_t *src = kept + d * P + t0;
        const double st = steps[d * B + b], l0 = lo[d * B + b];
        float *col = tile + d * SH_TILE;
        /* this component's symbols TILES_AHEAD tiles on: D streams P apart, which the
         * hardware's prefetchers lose (the loads waited on half the dequantisation's time) */
        if (t0 + (TILES_AHEAD + 1) * SH_TILE <= P)
            for (int64_t o = 0; o < SH_TILE * 2; o += 64)
                GSZ_PREFETCH((const char *)(src + TILES_AHEAD * SH_TILE) + o, 0);
        bad |= n == SH_TILE ? dequant_col(src, st, l0, col, SH_TILE) : dequant_col(src, st, l0, col, n);
    }
    if (m) {            /* the KLT (never with luma/chroma), SHRF's codeword sums on the way */
        *far |= klt_tile(tile, ridx ? cbf : NULL, ridx ? ridx + t0 : NULL, n, D, Jp, m, y, at + t0, out, &bad);
        return bad;
    }
    if (ridx)           /* SHRF: the residuals' codewords added back before any colour transform */
        bad |= add_codewords(tile, cbf, ridx + t0, n, D);
    if (colour)
        for (int64_t j = 0; j + 2 < D; j += 3) {
            float *a = tile + j * SH_TILE;
            bad |= n == SH_TILE ? luma_chroma_cols(a, a + SH_TILE, a + 2 * SH_TILE, SH_TILE)
                                : luma_chroma_cols(a, a + SH_TILE, a + 2 * SH_TILE, n);
        }
    for (int64_t t = 0; t < n; t++) {
        if ((t & 3) == 0)
            prefetch_rows(out, at + t0, t + ROWS_AHEAD, t + ROWS_AHEAD + 4 < n ? t + ROWS_AHEAD + 4 : n, D);
        float *row = out + at[t0 + t] * D;
        for (int64_t d = 0; d < D; d++) row[d] = tile[d * SH_TILE + t];
    }
    return bad;
}

int sh_assemble_run(const int64_t *flags, const uint16_t *kept, const double *steps,
                    const double *lo, int64_t B, const int64_t *classes, int64_t P,
                    const int64_t *idx, int64_t nidx, const double *cb, int64_t K, int64_t M,
                    int64_t D, int colour, const double *klt, const int64_t *ridx, float *out,
                    int *finite, Err *e)
{
    for (int64_t j = 0; ridx && j < P; j++)
        if (ridx[j] < 0 || ridx[j] >= K) return fail(e, "SHRF chunk: codeword index out of range");
    /* with SHRF: the codebook rounded to float32 once, a word's D components contiguous (the
     * rows below before their colour transform) */
    float *cbf = ridx ? malloc((size_t)(K ? K : 1) * (size_t)(D ? D : 1) * sizeof *cbf) : NULL;
    if (ridx && !cbf) return fail_nomem(e);
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
    /* the matrix padded with zero columns to a multiple of 12 (the product's column block;
     * D = 9, 24 and 45 of SH degrees 1-3 pad to 12, 24 and 48) */
    const int64_t Jp = (D + 11) / 12 * 12;
    double *kp_m = klt ? calloc((size_t)(D ? D : 1) * (size_t)(Jp ? Jp : 1), sizeof *kp_m) : NULL;
    if (!rows || !at || !rbad || !tile || (klt && (!ky || !kp_m))) {
        free(rows); free(at); free(rbad); free(tile); free(ky); free(kp_m); free(cbf);
        return fail_nomem(e);
    }
    if (klt && Jp > KLT_MAX_JP) {
        free(rows); free(at); free(rbad); free(tile); free(ky); free(kp_m); free(cbf);
        return fail(e, "sh_assemble: KLT matrix larger than 45 x 45");
    }
    for (int64_t d = 0; klt && d < D; d++) memcpy(kp_m + d * Jp, klt + d * D, (size_t)D * sizeof *kp_m);
    uint32_t far = 0;       /* a KLT-coded value out of range (GSZ.md §8.2): the part is invalid */
    for (int64_t j = 0; j < K; j++) {
        uint32_t bad = 0;
        for (int64_t d = 0; d < D; d++) {
            const float f = (float)cb[d * K + j];
            rows[j * D + d] = f;
            bad |= !f32_finite(f);
        }
        if (cbf) memcpy(cbf + j * D, rows + j * D, (size_t)D * sizeof *cbf);
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
                bad |= kept_tile(kept, P, steps, lo, B, b, D, colour, kp_m, Jp, ky, &far, at, t0, t1, ridx, cbf,
                                 tile, out);
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
    free(kp_m);
    free(cbf);
    *finite = !bad;
    return rc;
}
