/* gsz.decoder._native: float32 assembly of the decoded fields -- attribute planes, quaternions
 * from half-angle trig, voxel centres, SH rest vectors -- with the finiteness checks. */
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

int all_finite_run(const uint32_t *p, int64_t n)
{
    uint32_t bad = 0;
    /* exponent all ones = inf or nan; branch-free so the loop vectorises */
    for (int64_t i = 0; i < n; i++) bad |= ((p[i] & 0x7F800000u) == 0x7F800000u);
    return !bad;
}

/* Kept vectors per cache-friendly step of the transposed copy: the [D, P] channel set is read
 * column by column, so one step reads D runs of SH_TILE values and writes SH_TILE rows. */
#define SH_TILE 256

int sh_assemble_run(const int64_t *flags, const double *kept, const int64_t *order, int64_t P,
                    const int64_t *idx, int64_t nidx, const double *cb, int64_t K, int64_t M,
                    int64_t D, float *out, Err *e)
{
    /* the codebook as rows (a codeword is one contiguous copy) and the output row of every kept
     * vector; the [D, P] kept set is then copied tile by tile (reading it row by row, one
     * Gaussian at a time, strides P values per component: D streams that miss the cache) */
    float *rows = malloc((size_t)(K ? K : 1) * (size_t)(D ? D : 1) * sizeof *rows);
    int64_t *at = malloc((size_t)(P ? P : 1) * sizeof *at);
    if (!rows || !at) { free(rows); free(at); return fail_nomem(e); }
    for (int64_t j = 0; j < K; j++)
        for (int64_t d = 0; d < D; d++) rows[j * D + d] = (float)cb[d * K + j];
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
            else memcpy(out + i * D, rows + j * D, (size_t)D * sizeof *out);
        } else {
            rc = fail(e, "SHVQ chunk: kept flag outside 0/1");
        }
    }
    if (!rc && (kp != P || ip != nidx)) rc = fail(e, "SHVQ chunk: kept flags do not match the kept count");
    if (!rc && order) {
        /* stored vector t is the kept vector of point-order rank order[t] (SHCL, GSZ.md §8.1):
         * its output row is at[order[t]], so the copy below stays one sequential read */
        int64_t *by = malloc((size_t)(P ? P : 1) * sizeof *by);
        if (!by) rc = fail_nomem(e);
        for (int64_t t = 0; t < P && !rc; t++) {
            if (order[t] < 0 || order[t] >= P) rc = fail(e, "sh_assemble: order outside 0..P-1");
            else by[t] = at[order[t]];
        }
        if (!rc) memcpy(at, by, (size_t)P * sizeof *at);
        free(by);
    }
    if (!rc) {
        for (int64_t t0 = 0; t0 < P; t0 += SH_TILE) {
            const int64_t t1 = t0 + SH_TILE < P ? t0 + SH_TILE : P;
            for (int64_t d = 0; d < D; d++) {
                const double *src = kept + d * P;
                for (int64_t t = t0; t < t1; t++) out[at[t] * D + d] = (float)src[t];
            }
        }
    }
    free(rows);
    free(at);
    return rc;
}
