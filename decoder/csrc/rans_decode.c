/* gsz.decoder._native: rANS decoding (ENTROPY.md §3.3-4.4) -- a model set's compact decoding
 * tables (rans.h), the generic symbol loop and the per-block loop of quantised channel sets. */
#include "rans.h"

#include <string.h>

#if defined(__GNUC__) && defined(__x86_64__)
#define GSZ_RANS_AVX2 1
#include <immintrin.h>
#else
#define GSZ_RANS_AVX2 0
#endif

/* The d-th largest (1 <= d <= k) of k distinct keys.  Small k: a size-d min-heap; large k: an
 * MSB-first radix select (12-bit digits over the 60-bit keys, five linear passes). */
static uint64_t select_dth_largest(const uint64_t *key, int64_t k, int64_t d, uint32_t *hist,
                                   uint64_t *heap)
{
    if (k <= 32) {
        int64_t hn = 0;
        for (int64_t i = 0; i < k; i++) {
            const uint64_t v = key[i];
            if (hn < d) {
                int64_t j = hn++;
                while (j > 0 && heap[(j - 1) / 2] > v) { heap[j] = heap[(j - 1) / 2]; j = (j - 1) / 2; }
                heap[j] = v;
            } else if (v > heap[0]) {
                int64_t j = 0;
                for (;;) {
                    const int64_t l = 2 * j + 1, r = l + 1;
                    int64_t m = j;
                    uint64_t mv = v;
                    if (l < hn && heap[l] < mv) { m = l; mv = heap[l]; }
                    if (r < hn && heap[r] < mv) { m = r; }
                    if (m == j) break;
                    heap[j] = heap[m];
                    j = m;
                }
                heap[j] = v;
            }
        }
        return heap[0];
    }
    /* MSB-first radix select, 8-bit digits from the highest byte any key uses; after each pass
     * only the keys under the chosen prefix are kept (into `heap`, k entries of scratch), so
     * later passes are short; stops as soon as a single key is left (11-bit digits: slower) */
    uint64_t mx = 0;
    for (int64_t i = 0; i < k; i++) mx |= key[i];
    int shift = 0;
    while (shift < 56 && (mx >> (shift + 8))) shift += 8;
    const uint64_t *cur = key;
    int64_t need = d;
    for (;; shift -= 8) {
        memset(hist, 0, 256 * sizeof *hist);
        for (int64_t i = 0; i < k; i++) hist[(cur[i] >> shift) & 255]++;
        int dg = 255;
        for (; dg > 0; dg--) {
            if (need <= (int64_t)hist[dg]) break;
            need -= hist[dg];
        }
        /* keep the keys with digit dg (in place when already in the scratch buffer) */
        int64_t kk = 0;
        for (int64_t i = 0; i < k; i++)
            if ((int)((cur[i] >> shift) & 255) == dg) heap[kk++] = cur[i];
        cur = heap;
        k = kk;
        if (k == 1 || shift == 0) return cur[0];     /* distinct keys: shift 0 leaves one */
    }
}

/* One model's present-value count k (ENTROPY.md 3.3), its parameters checked; ci / bi walk the
 * COARSE arrays.  0 when the model is EMPTY, -1 on a violation. */
static int64_t mset_count_model(const MsetParams *p, int64_t m, int64_t *ci, int64_t *bi, Err *e)
{
    const int64_t t = p->type[m], n = p->prec[m], sp = p->span[m];
    if (t < 0 || t > 3) return fail(e, "rANS model set: unknown model type");
    if (t == 0) return 0;
    if (n < 0 || n > 16 || sp < 0 || sp > 65536)
        return fail(e, "rANS model set: precision or span out of range");
    if (p->lo[m] < -((int64_t)1 << 31) || p->lo[m] + sp >= ((int64_t)1 << 31))
        return fail(e, "rANS model set: value range outside [-2**31, 2**31)");
    int64_t k = 0;
    if (t == 1) {
        if (sp != 0 || n != 0) return fail(e, "rANS model set: single model with a span or precision");
        k = 1;
    } else if (t == 3) {
        if (p->centre[m] < 0 || p->centre[m] > sp || p->rl[m] < 0 || p->rl[m] > 255
            || p->rr[m] < 0 || p->rr[m] > 255)
            return fail(e, "rANS model set: laplace parameter out of range");
        k = sp + 1;
    } else {
        if (*ci >= p->ncoarse) return fail(e, "rANS model set: coarse code arrays missing");
        const int64_t nb = p->nbins[(*ci)++], h = p->bshift[m], g = p->group[m];
        if (h < 0 || h > 16 || g < 0 || g > 3 || nb < 1 || nb > p->nball - *bi)
            return fail(e, "rANS model set: coarse parameter out of range");
        const int64_t *bins = p->bins + *bi, *levels = p->levels + *bi;
        for (int64_t j = 0; j < nb; j++) {
            const int64_t b = bins[j], q = levels[j];
            if ((j == 0 && b != 0) || (j > 0 && b <= bins[j - 1]) || b > (sp >> h)
                || q < 1 || q > ((int64_t)25 << g))
                return fail(e, "rANS model set: coarse bins or levels invalid");
            const int64_t hi = ((b + 1) << h) < sp + 1 ? ((b + 1) << h) : sp + 1;
            k += hi - (b << h);
        }
        if (bins[nb - 1] != (sp >> h)) return fail(e, "rANS model set: coarse bins not covering the range");
        *bi += nb;
    }
    if (k < 1 || k > ((int64_t)1 << n)) return fail(e, "rANS model: more symbols than 2**n");
    return k;
}

int rans_tables_count(const MsetParams *p, int64_t max_lut, int64_t *lut_total,
                      int64_t *sym_total, Err *e)
{
    int64_t lt = 0, stot = 0, ci = 0, bi = 0;
    for (int64_t m = 0; m < p->M; m++) {
        const int64_t k = mset_count_model(p, m, &ci, &bi, e);
        if (k < 0) return -1;
        if (k == 0) continue;
        lt += (int64_t)1 << p->prec[m];
        stot += k;
        if (lt > max_lut) break;
    }
    *lut_total = lt;
    *sym_total = stot;
    if (lt > max_lut) return fail(e, "rANS: model set needs more LUT entries than this stream allows");
    if (ci != p->ncoarse || bi != p->nball)
        return fail(e, "rANS model set: coarse code arrays do not match the models");
    return 0;
}

/* Present values (offsets from lo) and their weights of model m (ENTROPY.md 3.3); returns
 * their number k.  ci / bi walk the COARSE arrays. */
static int64_t mset_weights(const MsetParams *p, int64_t m, int64_t *ci, int64_t *bi, int64_t *off,
                            int64_t *w)
{
    const int64_t t = p->type[m], sp = p->span[m];
    int64_t k = 0;
    if (t == 1) {
        off[0] = 0;
        w[0] = 1;
        k = 1;
    } else if (t == 2) {
        const int64_t nb = p->nbins[(*ci)++], h = p->bshift[m], g = p->group[m];
        for (int64_t j = 0; j < nb; j++) {
            const int64_t b = p->bins[*bi + j], qm = p->levels[*bi + j] - 1;
            const int64_t wt = (((int64_t)1 << g) + (qm & (((int64_t)1 << g) - 1))) << (qm >> g);
            const int64_t hi = ((b + 1) << h) < sp + 1 ? ((b + 1) << h) : sp + 1;
            for (int64_t x = b << h; x < hi; x++) { off[k] = x; w[k] = wt; k++; }
        }
        *bi += nb;
    } else {
        /* 3.5: sequential binary64 products, W_d = floor(v_d * 2^24) */
        const int64_t c = p->centre[m];
        k = sp + 1;
        for (int64_t i = 0; i < k; i++) off[i] = i;
        w[c] = (int64_t)1 << 24;
        for (int side = 0; side < 2; side++) {
            const int64_t u = side == 0 ? p->rl[m] : p->rr[m];
            const int64_t r = 65536 - (((16 + (u & 15)) << 16) >> ((u >> 4) + 5));
            const double rho = (double)r / 65536.0;
            const int64_t len = side == 0 ? c : sp - c;
            double vd = 1.0;
            for (int64_t d = 1; d <= len; d++) {
                vd = vd * rho;
                w[side == 0 ? c - d : c + d] = (int64_t)floor(vd * 16777216.0);
            }
        }
    }
    return k;
}

/* p[0..n) = v, four slots per store: a model's LUT is refilled once per block it decodes, and
 * slot by slot its 2^16 slots cost about as much as decoding the block. */
static inline void fill_u16(uint16_t *p, int64_t n, uint16_t v)
{
    const uint64_t pat = (uint64_t)v * 0x0001000100010001ull;
    int64_t z = 0;
    for (; z + 8 <= n; z += 8) {
        memcpy(p + z, &pat, 8);
        memcpy(p + z + 4, &pat, 8);
    }
    for (; z < n; z++) p[z] = v;
}

/* Scratch of rans_tables_fill (one model at a time: at most 2^16 + 1 present values). */
typedef struct {
    int64_t *w, *fr, *off;
    uint64_t *key, *heap;
    uint32_t *hist;
} MsetScratch;

/* Normalisation (3.4) of model m's k weights to 2^n and its table entries at lpos / spos. */
static int mset_normalise(const MsetParams *p, int64_t m, int64_t k, const MsetScratch *s,
                          const MsetTables *o, int64_t lpos, int64_t spos, Err *e)
{
    int64_t *w = s->w, *fr = s->fr;
    const int64_t T = (int64_t)1 << p->prec[m];
    int64_t W = 0;
    for (int64_t i = 0; i < k; i++) W += w[i];
    if (W == 0) {
        for (int64_t i = 0; i < k; i++) w[i] = 1;
        W = k;
    }
    const int64_t R = T - k;
    int64_t sumf = 0;
    for (int64_t i = 0; i < k; i++) {
        const int64_t prod = w[i] * R;          /* < 2^60 */
        fr[i] = 1 + prod / W;
        sumf += fr[i];
        /* remainder (< 2^44), then the complemented index: distinct keys whose
         * descending order is "largest remainder first, ties by lower index" */
        s->key[i] = ((uint64_t)(prod % W) << 16) | (uint64_t)(0xFFFF - i);
    }
    const int64_t dshort = T - sumf;
    if (dshort < 0 || dshort >= k) return fail(e, "rANS model: normalisation out of range");
    if (dshort > 0) {
        const uint64_t thr = select_dth_largest(s->key, k, dshort, s->hist, s->heap);
        for (int64_t i = 0; i < k; i++) fr[i] += s->key[i] >= thr;
    }
    int64_t cum = 0;
    for (int64_t i = 0; i < k; i++) {
        o->fc[spos + i] = ((uint32_t)cum << 16) | (uint32_t)(fr[i] - 1);
        o->val[spos + i] = (int32_t)(p->lo[m] + s->off[i]);
        if (o->lut) fill_u16(o->lut + lpos + cum, fr[i], (uint16_t)i);
        cum += fr[i];
    }
    return 0;
}

int rans_tables_fill(const MsetParams *p, const MsetTables *o, Err *e)
{
    MsetScratch s;
    s.w = malloc(65537 * sizeof *s.w);
    s.fr = malloc(65537 * sizeof *s.fr);
    s.off = malloc(65537 * sizeof *s.off);
    s.key = malloc(65537 * sizeof *s.key);
    s.heap = malloc(65537 * sizeof *s.heap);
    s.hist = malloc(4096 * sizeof *s.hist);
    if (!s.w || !s.fr || !s.off || !s.key || !s.heap || !s.hist) fail_nomem(e);
    int64_t lpos = 0, spos = 0, ci = 0, bi = 0;
    for (int64_t m = 0; !e->failed && m < p->M; m++) {
        o->lut_base[m] = lpos;
        o->sym_base[m] = spos;
        if (p->type[m] == 0) { o->mprec[m] = PREC_EMPTY; continue; }
        o->mprec[m] = (uint8_t)p->prec[m];
        const int64_t k = mset_weights(p, m, &ci, &bi, s.off, s.w);
        if (mset_normalise(p, m, k, &s, o, lpos, spos, e) < 0) break;
        lpos += (int64_t)1 << p->prec[m];
        spos += k;
    }
    free(s.w); free(s.fr); free(s.off); free(s.key); free(s.heap); free(s.hist);
    return e->failed ? -1 : 0;
}

/* One decode step (ENTROPY.md 4.3) with model m; the value in *out.  0 or -1 (error set). */
static inline int rans_step(const RTab *t, RState *s, int64_t m, int64_t *out, Err *e)
{
    if (m < 0 || m >= t->nmodels) return fail(e, "rANS: model id outside the model set");
    const unsigned n = t->mprec[m];
    if (n == PREC_EMPTY) return fail(e, "rANS: symbol refers to an empty model");
    uint64_t x = (uint64_t)s->st[s->lane];
    const uint64_t slot = x & (((uint64_t)1 << n) - 1);
    const int64_t li = t->lbase[m] + (int64_t)slot;
    if (li < 0 || li >= t->lut_len) return fail(e, "rANS: decoding table index out of range");
    const int64_t g = t->sbase[m] + t->lut[li];
    if (g < 0 || g >= t->nsym) return fail(e, "rANS: decoding table entry out of range");
    const uint32_t ent = t->fc[g];
    x = (uint64_t)((ent & 0xFFFF) + 1) * (x >> n) + slot - (ent >> 16);
    const uint64_t need = x < 65536u;      /* branch-free renormalisation, as in oct_bin_decode */
    if (s->w >= s->nwords) {
        if (need) return fail(e, "rANS: payload truncated (word stream exhausted)");
    } else {
        const uint64_t wv = rd_u16(s->words + 2 * s->w);
        x = (x << (need << 4)) | (wv & (0 - need));
        s->w += (int64_t)need;
    }
    s->st[s->lane] = (int64_t)x;
    if (++s->lane == s->lanes) s->lane = 0;
    *out = t->val[g];
    return 0;
}

int rans_decode_run(const RTab *t, RState *s, const int64_t *mids, int64_t *out, int64_t count,
                    Err *e)
{
    if (!t->lut) return fail(e, "rANS: per-symbol decoding needs tables made with their LUT");
    for (int64_t j = 0; j < count; j++)
        if (rans_step(t, s, mids[j], out + j, e) < 0) return -1;
    return 0;
}

typedef struct { int bad_k, bad_q, overrun; } BlockOut;

/* What a block's loop writes: int64 values, float64 dequantised values, or uint16 symbols
 * checked against 2^q - 1 (a kept SH set, dequantised later where it is transposed). */
enum { DEQ_RAW = 0, DEQ_FLOAT = 1, DEQ_SYM16 = 2 };

/* One block of a channel set: `len` symbols, all with one model (its LUT and present values
 * already offset to the model; klimit = how many present values follow).  Written branch-free
 * (renormalisation by arithmetic select); specialised on `deq` by the two wrappers below.
 * Problems are collected in *bo and reported after the block. */
static inline __attribute__((always_inline)) void
decode_block_body(const uint16_t *restrict lut, const uint32_t *restrict fc,
                  const int32_t *restrict val, int64_t klimit, unsigned n, RState *s, int64_t len,
                  double *restrict fout, int64_t *restrict iout, uint16_t *restrict uout,
                  double step, double l0, int64_t qm, const int deq, BlockOut *bo)
{
    static const uint8_t zero_word[2] = {0, 0};
    const uint64_t mask = ((uint64_t)1 << n) - 1;
    int64_t *restrict st = s->st;
    const int64_t lanes = s->lanes, nwords = s->nwords;
    const uint8_t *restrict words = nwords ? s->words : zero_word;
    const int64_t wlast = nwords ? nwords - 1 : 0;
    int64_t lane = s->lane, w = s->w;
    int bad_k = 0, bad_q = 0, over = 0;
    for (int64_t j = 0; j < len; j++) {
        uint64_t x = (uint64_t)st[lane];
        const uint64_t slot = x & mask;
        const int64_t kk = lut[slot];
        bad_k |= kk >= klimit;
        const int64_t ki = kk < klimit ? kk : 0;
        const uint32_t ent = fc[ki];
        x = (uint64_t)((ent & 0xFFFF) + 1) * (x >> n) + slot - (ent >> 16);
        /* renormalise: read the next word (clamped inside the stream) and take it or not */
        const uint64_t need = x < 65536u;
        const uint64_t wv = rd_u16(words + 2 * (w < wlast ? w : wlast));
        x = (x << (need << 4)) | (wv & (0 - need));
        over |= (int)(need & (uint64_t)(w >= nwords));
        w += (int64_t)need;
        st[lane] = (int64_t)x;
        lane = lane + 1 == lanes ? 0 : lane + 1;
        const int64_t value = val[ki];
        if (deq == DEQ_FLOAT) {
            bad_q |= (value < 0) | (value > qm);
            const double prod = step * (double)value;
            fout[j] = prod + l0;
        } else if (deq == DEQ_SYM16) {
            bad_q |= (value < 0) | (value > qm);
            uout[j] = (uint16_t)value;
        } else {
            iout[j] = value;
        }
    }
    s->lane = lane;
    s->w = w;
    bo->bad_k |= bad_k;
    bo->bad_q |= bad_q;
    bo->overrun |= over;
}

static __attribute__((noinline)) void
decode_block_deq(const uint16_t *lut, const uint32_t *fc, const int32_t *val, int64_t klimit,
                 unsigned n, RState *s, int64_t len, double *fout, double step, double l0,
                 int64_t qm, BlockOut *bo)
{
    decode_block_body(lut, fc, val, klimit, n, s, len, fout, NULL, NULL, step, l0, qm, DEQ_FLOAT, bo);
}

static __attribute__((noinline)) void
decode_block_sym16(const uint16_t *lut, const uint32_t *fc, const int32_t *val, int64_t klimit,
                   unsigned n, RState *s, int64_t len, uint16_t *uout, int64_t qm, BlockOut *bo)
{
    decode_block_body(lut, fc, val, klimit, n, s, len, NULL, NULL, uout, 0.0, 0.0, qm, DEQ_SYM16, bo);
}

static __attribute__((noinline)) void
decode_block_raw(const uint16_t *lut, const uint32_t *fc, const int32_t *val, int64_t klimit,
                 unsigned n, RState *s, int64_t len, int64_t *iout, BlockOut *bo)
{
    decode_block_body(lut, fc, val, klimit, n, s, len, NULL, iout, NULL, 0.0, 0.0, 0, DEQ_RAW, bo);
}

/* the shortest run decode_one_block hands to the fast loop (below it: the checked loop) */
#define FAST_MIN_RUN 256

/* One step of the fast loops (ENTROPY.md 4.3) on state x with a model's LUT and (cum, freq)
 * entries, renormalised from the word at *w with no bounds check (the caller's run has a word
 * left for every symbol it decodes); returns the new state and the present value's index in
 * *ki.  x or (x << 16 | next word) by masks: no branch (taken about every other symbol,
 * unpredictably) and no shift by a variable count (cl is the precision's). */
static inline __attribute__((always_inline)) uint64_t
fast_step(uint64_t x, const uint16_t *restrict lut, const uint32_t *restrict fc, uint64_t mask,
          unsigned n, const uint8_t *restrict words, int64_t *w, int64_t *ki)
{
    const uint64_t slot = x & mask;
    *ki = lut[slot];
    const uint32_t ent = fc[*ki];
    x = (uint64_t)((ent & 0xFFFF) + 1) * (x >> n) + slot - (ent >> 16);
    const uint64_t need = x < 65536u, take = 0 - need;
    x = (((x << 16) | rd_u16(words + 2 * *w)) & take) | (x & ~take);
    *w += (int64_t)need;
    return x;
}

/* A fast loop's symbol value out: float64 lo + step * k (two roundings) or the uint16 symbol k;
 * returns 1 when k lies outside 0..qmax (a negative value wraps above qmax). */
static inline __attribute__((always_inline)) uint32_t
fast_out(int32_t v, uint32_t qmax, int64_t j, double *restrict fout, uint16_t *restrict uout,
         double step, double l0, int deq)
{
    if (deq == DEQ_FLOAT) {
        const double prod = step * (double)v;
        fout[j] = prod + l0;
    } else {
        uout[j] = (uint16_t)v;
    }
    return (uint32_t)v > qmax;
}

/* decode_block_body for a block with at least `len` words left (a symbol reads at most one):
 * no clamp of the word position and no overrun flag, and the LUT's entries index the model's
 * present values by construction (rans_tables_fill), so only the symbols' range is checked.
 * Fewer live values: the loop keeps them in registers. */
static inline __attribute__((always_inline)) void
decode_block_fast_body(const uint16_t *restrict lut, const uint32_t *restrict fc,
                       const int32_t *restrict val, unsigned n, RState *s, int64_t len,
                       double *restrict fout, uint16_t *restrict uout, double step, double l0,
                       int64_t qm, const int deq, BlockOut *bo)
{
    const uint64_t mask = ((uint64_t)1 << n) - 1;
    int64_t *restrict st = s->st;
    const int64_t lanes = s->lanes;
    const uint8_t *restrict words = s->words;
    int64_t lane = s->lane, w = s->w;
    const uint32_t qmax = (uint32_t)qm;
    uint32_t bad_q = 0;
    for (int64_t j = 0; j < len; j++) {
        int64_t ki;
        st[lane] = (int64_t)fast_step((uint64_t)st[lane], lut, fc, mask, n, words, &w, &ki);
        lane = lane + 1 == lanes ? 0 : lane + 1;
        bad_q |= fast_out(val[ki], qmax, j, fout, uout, step, l0, deq);
    }
    s->lane = lane;
    s->w = w;
    bo->bad_q |= (int)bad_q;
}

static __attribute__((noinline)) void
decode_block_deq_fast(const uint16_t *lut, const uint32_t *fc, const int32_t *val, unsigned n,
                      RState *s, int64_t len, double *fout, double step, double l0, int64_t qm,
                      BlockOut *bo)
{
    decode_block_fast_body(lut, fc, val, n, s, len, fout, NULL, step, l0, qm, DEQ_FLOAT, bo);
}

static __attribute__((noinline)) void
decode_block_sym16_fast(const uint16_t *lut, const uint32_t *fc, const int32_t *val, unsigned n,
                        RState *s, int64_t len, uint16_t *uout, int64_t qm, BlockOut *bo)
{
    decode_block_fast_body(lut, fc, val, n, s, len, NULL, uout, 0.0, 0.0, qm, DEQ_SYM16, bo);
}

#if GSZ_RANS_AVX2
/* 1: the AVX2 block loop may run (the CPU has AVX2), 0: not, -1: not yet asked */
static int rans_avx2 = -1;
/* For the lanes needing a word (bit i of an 8-bit mask), the index of the word lane i takes:
 * the words are handed out in lane order (ENTROPY.md 4.3's symbol order). */
static int32_t WORD_PERM[256][8];

int rans_simd(int on)
{
    if (rans_avx2 < 0) {
        for (int m = 0; m < 256; m++)
            for (int i = 0, k = 0; i < 8; i++) {
                WORD_PERM[m][i] = (m >> i) & 1 ? k : 0;
                k += (m >> i) & 1;
            }
        __builtin_cpu_init();
        rans_avx2 = __builtin_cpu_supports("avx2") ? 1 : 0;
    }
    const int was = rans_avx2;
    if (on == 0) rans_avx2 = 0;
    else if (on == 1) rans_avx2 = __builtin_cpu_supports("avx2") ? 1 : 0;
    return was;
}

/* decode_block_fast_body eight symbols at a time: eight consecutive lanes (no wrap) decode
 * together -- gathers of their LUT slots, (cum, freq) entries and values, one multiply -- and
 * the lanes that renormalise take the next words in lane order (a permutation by the mask of
 * lanes needing one).  The same integer steps as the scalar loop, so the same values; lanes
 * up to the wrap and the last symbols take the scalar step.  len <= words left (as for the
 * scalar fast loop); eight words are loaded at a time, so groups stop 8 words before the end.
 * lut has 2^n + 1 readable slots (a 4-byte gather at slot 2^n - 1). */
static __attribute__((target("avx2"), noinline)) void
decode_block_avx2(const uint16_t *lut, const uint32_t *fc, const int32_t *val, int64_t k, unsigned n,
                  RState *s, uint32_t *st32, int *live, int64_t len, double *fout,
                  uint16_t *uout, double step, double l0, int64_t qm, BlockOut *bo)
{
    const int64_t lanes = s->lanes, nwords = s->nwords;
    const uint8_t *words = s->words;
    int64_t lane = s->lane, w = s->w, j = 0;
    if (!*live) {               /* st32 keeps the states from block to block */
        for (int64_t i = 0; i < lanes; i++) st32[i] = (uint32_t)s->st[i];
        *live = 1;
    }
    const uint32_t mask = (uint32_t)(((uint64_t)1 << n) - 1), qmax = (uint32_t)qm;
    const __m256i vmask = _mm256_set1_epi32((int)mask), lo16 = _mm256_set1_epi32(0xFFFF),
                  one = _mm256_set1_epi32(1), zero = _mm256_setzero_si256(),
                  vq = _mm256_set1_epi32((int)qmax);
    const __m128i cnt = _mm_cvtsi32_si128((int)n);
    const __m256d vstep = _mm256_set1_pd(step), vl0 = _mm256_set1_pd(l0);
    /* a model of at most 8 present values (the 1-3 bit groups most of a kept SH set codes
     * with): its (cum, freq) entries and values in registers, a lane's value index the count
     * of cumulative frequencies at or below its slot (the LUT's entry), and no gathers */
    const int small = k >= 1 && k <= 8;
    __m256i fcv = zero, valv = zero, cm[7];
    if (small) {
        uint32_t tf[8] = {0};
        int32_t tv[8] = {0};
        for (int64_t i = 0; i < k; i++) {
            tf[i] = fc[i];
            tv[i] = val[i];
        }
        fcv = _mm256_loadu_si256((const __m256i *)tf);
        valv = _mm256_loadu_si256((const __m256i *)tv);
        for (int64_t i = 0; i < 7; i++)      /* slot > cum - 1 for the values 1..k-1; never past them */
            cm[i] = _mm256_set1_epi32(i + 1 < k ? (int)(fc[i + 1] >> 16) - 1 : 0x7FFFFFFF);
    }
    __m256i badv = zero;
    uint32_t bad_q = 0;
    while (j < len) {
        if (lane + 8 <= lanes && j + 8 <= len && w + 8 <= nwords) {
            __m256i x = _mm256_loadu_si256((const __m256i *)(st32 + lane));
            const __m256i slot = _mm256_and_si256(x, vmask);
            __m256i ent, v;
            if (small) {
                __m256i ki = zero;
                for (int i = 0; i < 7; i++) ki = _mm256_sub_epi32(ki, _mm256_cmpgt_epi32(slot, cm[i]));
                ent = _mm256_permutevar8x32_epi32(fcv, ki);
                v = _mm256_permutevar8x32_epi32(valv, ki);
            } else {
                const __m256i ki = _mm256_and_si256(_mm256_i32gather_epi32((const int *)lut, slot, 2), lo16);
                ent = _mm256_i32gather_epi32((const int *)fc, ki, 4);
                v = _mm256_i32gather_epi32((const int *)val, ki, 4);
            }
            const __m256i f = _mm256_add_epi32(_mm256_and_si256(ent, lo16), one);
            const __m256i c = _mm256_srli_epi32(ent, 16);
            x = _mm256_add_epi32(_mm256_mullo_epi32(f, _mm256_srl_epi32(x, cnt)), _mm256_sub_epi32(slot, c));
            const __m256i need = _mm256_cmpeq_epi32(_mm256_srli_epi32(x, 16), zero);
            const int m = _mm256_movemask_ps(_mm256_castsi256_ps(need));
            const __m256i w32 = _mm256_cvtepu16_epi32(_mm_loadu_si128((const __m128i *)(words + 2 * w)));
            const __m256i wl = _mm256_permutevar8x32_epi32(
                w32, _mm256_loadu_si256((const __m256i *)WORD_PERM[m]));
            x = _mm256_blendv_epi8(x, _mm256_or_si256(_mm256_slli_epi32(x, 16), wl), need);
            _mm256_storeu_si256((__m256i *)(st32 + lane), x);
            w += __builtin_popcount((unsigned)m);
            /* a value above qmax (or negative: above it as uint32) */
            badv = _mm256_or_si256(badv, _mm256_xor_si256(_mm256_cmpeq_epi32(_mm256_max_epu32(v, vq), vq),
                                                          _mm256_set1_epi32(-1)));
            if (fout) {
                const __m256d d0 = _mm256_cvtepi32_pd(_mm256_castsi256_si128(v));
                const __m256d d1 = _mm256_cvtepi32_pd(_mm256_extracti128_si256(v, 1));
                _mm256_storeu_pd(fout + j, _mm256_add_pd(_mm256_mul_pd(vstep, d0), vl0));
                _mm256_storeu_pd(fout + j + 4, _mm256_add_pd(_mm256_mul_pd(vstep, d1), vl0));
            } else {
                _mm_storeu_si128((__m128i *)(uout + j),
                                 _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1)));
            }
            lane += 8;
            if (lane == lanes) lane = 0;
            j += 8;
        } else {
            int64_t ki;
            st32[lane] = (uint32_t)fast_step(st32[lane], lut, fc, mask, n, words, &w, &ki);
            lane = lane + 1 == lanes ? 0 : lane + 1;
            bad_q |= fast_out(val[ki], qmax, j, fout, uout, step, l0, fout ? DEQ_FLOAT : DEQ_SYM16);
            j++;
        }
    }
    bad_q |= !_mm256_testz_si256(badv, badv);
    s->lane = lane;
    s->w = w;
    bo->bad_q |= (int)bad_q;
}
#else
int rans_simd(int on)
{
    (void)on;
    return 0;
}
#endif

/* Tables without a LUT (rans_tables(with_lut=False)): model m's LUT is made from its (cum,
 * freq) entries into one 2^16-slot buffer when a block needs it, and kept while the next
 * blocks use the same model.  A set's whole LUT is 2 bytes per slot of every model (100 MB
 * for a 1.2 M-Gaussian file's kept SH set): fresh pages and a pass over them per decode,
 * where one model's slots stay in the cache. */
typedef struct {
    uint16_t *buf;          /* 2^16 + 2 slots: the AVX2 loop's 4-byte gathers read one past */
    int64_t model;          /* whose LUT buf holds, -1 none */
    uint32_t *st32;         /* the lane states as uint32 for the AVX2 loop ([lanes], or NULL) */
    int st32_live;          /* st32 holds the states (s->st is stale) */
} LazyLut;

/* The lane states back to s->st where the AVX2 loop left them in st32 (before any other loop
 * and at the end of a channel set: converting per block was a tenth of the loop's time). */
static void states_home(LazyLut *z, RState *s)
{
    if (!z->st32_live) return;
    for (int64_t i = 0; i < s->lanes; i++) s->st[i] = (int64_t)z->st32[i];
    z->st32_live = 0;
}

static const uint16_t *lazy_lut(const RTab *t, LazyLut *z, int64_t m, unsigned n, Err *e)
{
    if (z->model == m) return z->buf;
    const int64_t sb = t->sbase[m];
    int64_t k = (m + 1 < t->nmodels ? t->sbase[m + 1] : t->nsym) - sb;
    const int64_t T = (int64_t)1 << n;
    if (k < 1 || k > T || sb + k > t->nsym) {
        fail(e, "rANS: decoding table index out of range");
        return NULL;
    }
    const uint32_t *fc = t->fc + sb;
    int64_t cum = 0;
    for (int64_t i = 0; i < k; i++) {
        const int64_t c = fc[i] >> 16, f = (int64_t)(fc[i] & 0xFFFF) + 1;
        if (c != (cum & 0xFFFF) || cum + f > T) {
            fail(e, "rANS: decoding table entry out of range");
            return NULL;
        }
        fill_u16(z->buf + cum, f, (uint16_t)i);
        cum += f;
    }
    if (cum != T) {
        fail(e, "rANS: decoding table entry out of range");
        return NULL;
    }
    z->model = m;
    return z->buf;
}

/* Block b of channel c (len symbols from element i0 on): one model for the whole block,
 * checked once, then a tight loop. */
static int decode_one_block(const RTab *t, LazyLut *z, RState *s, const RBlocks *bl, int64_t c,
                            int64_t b, int64_t i0, int64_t len, Err *e)
{
    const int64_t g = c * bl->B + b, m = bl->tab[g];
    if (m < 0 || m >= t->nmodels) return fail(e, "rANS: model id outside the model set");
    const unsigned n = t->mprec[m];
    if (n == PREC_EMPTY) return fail(e, "rANS: symbol refers to an empty model");
    const uint64_t mask = ((uint64_t)1 << n) - 1;
    const int64_t lb = t->lbase[m], sb = t->sbase[m];
    if (sb < 0 || sb >= t->nsym || (t->lut && (lb < 0 || lb + (int64_t)mask >= t->lut_len)))
        return fail(e, "rANS: decoding table index out of range");
    BlockOut bo = {0, 0, 0};
    const uint16_t *lut = t->lut ? t->lut + lb : lazy_lut(t, z, m, n, e);
    if (!lut) return -1;
    const uint32_t *fc = t->fc + sb;
    const int32_t *val = t->val + sb;
    const int64_t at = c * bl->L + i0;
    int64_t done = 0;
    if (bl->steps || bl->uout) {
        /* runs of at most as many symbols as words are left go without the word checks (near
         * the stream's end the runs shrink; the last few symbols take the checked loop) */
        for (;;) {
            int64_t f = len - done;
            if (f > s->nwords - s->w) f = s->nwords - s->w;
            if (f < FAST_MIN_RUN && f < len - done) break;
            if (f <= 0) break;
#if GSZ_RANS_AVX2
            if (z->st32)
                decode_block_avx2(lut, fc, val, (m + 1 < t->nmodels ? t->sbase[m + 1] : t->nsym) - sb, n, s,
                                  z->st32, &z->st32_live, f,
                                  bl->steps ? bl->fout + at + done : NULL,
                                  bl->steps ? NULL : bl->uout + at + done,
                                  bl->steps ? bl->steps[g] : 0.0, bl->steps ? bl->lo[g] : 0.0,
                                  bl->qmax[g], &bo);
            else
#endif
            if (bl->steps)
                decode_block_deq_fast(lut, fc, val, n, s, f, bl->fout + at + done, bl->steps[g],
                                      bl->lo[g], bl->qmax[g], &bo);
            else
                decode_block_sym16_fast(lut, fc, val, n, s, f, bl->uout + at + done, bl->qmax[g], &bo);
            done += f;
        }
    }
    const int64_t rest = len - done;
    if (rest) states_home(z, s);
    if (rest && bl->steps)
        decode_block_deq(lut, fc, val, t->nsym - sb, n, s, rest, bl->fout + at + done, bl->steps[g],
                         bl->lo[g], bl->qmax[g], &bo);
    else if (rest && bl->uout)
        decode_block_sym16(lut, fc, val, t->nsym - sb, n, s, rest, bl->uout + at + done, bl->qmax[g], &bo);
    else if (rest)
        decode_block_raw(lut, fc, val, t->nsym - sb, n, s, rest, bl->iout + at + done, &bo);
    if (bo.overrun) return fail(e, "rANS: payload truncated (word stream exhausted)");
    if (bo.bad_k) fail(e, "rANS: decoding table entry out of range");
    if (!e->failed && bo.bad_q) fail(e, "quantisation symbol outside 0..2^q - 1 of its group");
    return e->failed ? -1 : 0;
}

int rans_decode_blocks_run(const RTab *t, RState *s, const RBlocks *bl, Err *e)
{
    const int64_t base = bl->L / bl->B, extra = bl->L % bl->B;
    LazyLut z = {NULL, -1, NULL, 0};
    if (!t->lut && !(z.buf = malloc((((size_t)1 << MAX_PREC_BITS) + 2) * sizeof *z.buf)))
        return fail_nomem(e);
#if GSZ_RANS_AVX2
    if (z.buf && rans_avx2 > 0 && s->lanes >= 8 && (bl->steps || bl->uout)) {
        if (!(z.st32 = malloc((size_t)s->lanes * sizeof *z.st32))) {
            free(z.buf);
            return fail_nomem(e);
        }
    }
#endif
    int rc = 0;
    for (int64_t c = 0; c < bl->C && !rc; c++) {
        int64_t i = 0;
        for (int64_t b = 0; b < bl->B; b++) {
            /* split_lengths: the first L mod B blocks hold one element more */
            const int64_t len = base + (b < extra);
            i += len;
            if (len == 0) continue;
            if (decode_one_block(t, &z, s, bl, c, b, i - len, len, e) < 0) { rc = -1; break; }
        }
    }
    states_home(&z, s);
    free(z.buf);
    free(z.st32);
    return rc;
}
