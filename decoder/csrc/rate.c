/* gsz.decoder._native: the encoder's rate model -- per-block symbol statistics at every
 * bit-width for gsz.encoder.rate.group_stats. */
#include "stages.h"

/* ================================================================== rate model (encoder) */
/*
 * The per-part loop of gsz.encoder.rate.group_stats: statistics of a block's quantised symbols
 * at every bit-width, from the block's values sorted once (the sort stays in NumPy).  The
 * NumPy code in rate.py is the reference; this is the same float64 arithmetic per run, in the
 * same order (bincount sums in run order, the same association of every expression), with
 * the run structure walked block by block instead of as flat arrays.
 *
 * Not every result is bit-identical: NumPy evaluates log2 and pow with its own SIMD kernels
 * (SVML on AVX-512 machines) which differ from libm's in the last bit now and then; the
 * payload, LAPLACE and binned sums therefore agree to ~1e-15 relative, not exactly.  The log2
 * of integers (gap, level, the level codes' count octaves) comes from a table NumPy computed
 * (`log_tab`), so those sums, like k and gap2, are exact.
 */
#define RATE_SLOTS (RATE_SHIFTS + 1) /* runs kept: this q and the 5 below it */
#define RATE_MEMO 64                 /* run lengths whose per-run term is cached */

/* The normative quantiser (gsz.decoder.quant) on a value minus its block minimum:
 * min(rint(d / s), levels).  d >= 0 and s > 0, so d / s is in [0, 2^52) and adding and
 * subtracting 2^52 rounds it to an integer in the current (nearest-even) mode, exactly as
 * rint does -- without the sign and range branches of the inlined rint, which kept the scan
 * below from running branch-free. */
static inline double rate_sym(double d, double s, double levels)
{
    const double k = (d / s + 0x1p52) - 0x1p52;
    return k < levels ? k : levels;
}

/* Runs of one block's symbols at one step: run i has symbol sym[i] and length cnt[i]; returns
 * the run count.  The values are sorted and the quantiser is monotone, so the symbols are
 * non-decreasing: at low bit-widths a block of thousands of values has a handful of runs,
 * found by galloping + bisection in O(runs * log(length)) quantiser evaluations instead of
 * one per value.  Both scans evaluate the same expression, so they find the same runs; the
 * linear one is faster where runs are short, so it has no data-dependent branch (run starts
 * are written unconditionally and the run index advances by the comparison). */
static int64_t rate_runs(const double *d, int64_t n, double s, double levels, int gallop,
                         int32_t *sym, int32_t *cnt)
{
    int64_t r = 0;
    double v = rate_sym(d[0], s, levels);
    if (!gallop) {
        sym[0] = (int32_t)v;
        cnt[0] = 0;
        r = 1;
        for (int64_t j = 1; j < n; j++) {
            const double w = rate_sym(d[j], s, levels);
            sym[r] = (int32_t)w;          /* index r <= j < n: scratch until w starts a run */
            cnt[r] = (int32_t)j;
            r += w != v;
            v = w;
        }
        /* run starts -> run lengths, in place (cnt[i + 1] is still a start when cnt[i] is set) */
        for (int64_t i = 0; i + 1 < r; i++) cnt[i] = cnt[i + 1] - cnt[i];
        cnt[r - 1] = (int32_t)(n - cnt[r - 1]);
        return r;
    }
    int64_t j = 0;
    while (j < n) {
        /* invariant: the value at a has symbol v; b is n or the first probe with another */
        int64_t a = j, b, step = 1;
        for (;;) {
            b = a + step;
            if (b >= n) { b = n; break; }
            if (rate_sym(d[b], s, levels) != v) break;
            a = b;
            step <<= 1;
        }
        while (b - a > 1) {
            const int64_t m = a + (b - a) / 2;
            if (rate_sym(d[m], s, levels) == v) a = m; else b = m;
        }
        sym[r] = (int32_t)v;
        cnt[r++] = (int32_t)(b - j);
        j = b;
        if (j < n) v = rate_sym(d[j], s, levels);
    }
    return r;
}

static int rate_ceil_log2(int64_t x)
{
    int e = 0;
    while (((int64_t)1 << e) < x) e++;
    return e;
}

/* Sum over runs of c * (prec - log2(max(1 + a * (c / div), 1))): the coder-normalised payload
 * of one table (exact COARSE: a = T - K, div = N; binned: a = T - K * 2^h, div = N * 2^h).  At
 * high bit-widths most runs are a few values long, so the term of short runs is computed once
 * per table (memo) -- the same value, added in the same run order.  The max(., 1) is a no-op
 * where a >= 0 (all callers) and mirrors the reference's np.maximum. */
static double rate_table_bits(const int32_t *cnt, int64_t runs, double prec, double a, double div,
                              double *memo)
{
    for (int i = 0; i < RATE_MEMO; i++) memo[i] = -1.0;   /* terms are >= 0 */
    double sum = 0.0;
    for (int64_t i = 0; i < runs; i++) {
        const int32_t c = cnt[i];
        double t = c < RATE_MEMO ? memo[c] : -1.0;
        if (t < 0.0) {
            const double f = 1.0 + a * ((double)c / div);
            t = (double)c * (prec - log2(f > 1.0 ? f : 1.0));
            if (c < RATE_MEMO) memo[c] = t;
        }
        sum += t;
    }
    return sum;
}

/* rate._laplace_core for one group allowed LAPLACE (span + 1 <= T, K > 1): two-sided
 * geometric around the first most frequent value, each side's ratio from its mean distance.
 * The count sums are exact integers in float64, so only the rest needs the reference's order. */
static double rate_laplace(const int32_t *sym, const int32_t *cnt, int64_t runs, double prec,
                           double tot, double rho_min, double rho_max)
{
    int32_t maxc = 0;
    double centre = 0.0;
    for (int64_t i = 0; i < runs; i++)
        if (cnt[i] > maxc) { maxc = cnt[i]; centre = (double)sym[i]; }
    const double span = (double)sym[runs - 1];      /* the minimum maps to symbol 0 */
    double n_l = 0.0, n_r = 0.0, s_l = 0.0, s_r = 0.0;
    for (int64_t i = 0; i < runs; i++) {
        const double dd = (double)sym[i] - centre, c = (double)cnt[i];
        if (dd < 0) { n_l += c; s_l += c * -dd; }
        else if (dd > 0) { n_r += c; s_r += c * dd; }
    }
    double rho_l = 1.0 - n_l / (s_l > 1e-300 ? s_l : 1e-300);
    double rho_r = 1.0 - n_r / (s_r > 1e-300 ? s_r : 1e-300);
    rho_l = rho_l < rho_min ? rho_min : (rho_l > rho_max ? rho_max : rho_l);
    rho_r = rho_r < rho_min ? rho_min : (rho_r > rho_max ? rho_max : rho_r);
    const double dl = centre, dr = span - centre;
    const double w_sum = 1.0 + rho_l * (1.0 - pow(rho_l, dl)) / (1.0 - rho_l)
                       + rho_r * (1.0 - pow(rho_r, dr)) / (1.0 - rho_r);
    const double a = tot - (span + 1.0);
    double bits = 0.0;
    for (int64_t i = 0; i < runs; i++) {
        const double dd = (double)sym[i] - centre;
        const double p = pow(dd < 0 ? rho_l : rho_r, fabs(dd)) / w_sum;
        const double f = 1.0 + a * p;
        bits += (double)cnt[i] * (prec - log2(f > 1.0 ? f : 1.0));
    }
    return bits;
}


/* Every statistic of one block r at bit-widths q_first..hi (see group_stats). */
static void rate_block(const float *x, int64_t blen, const double *tab, int q_first, int hi,
                       double rho_min, double rho_max, int64_t r, const RateOut *o, double *d,
                       int32_t *sym, int32_t *cnt)
{
    const double m = (double)x[0], span = (double)x[blen - 1] - m;
    for (int64_t j = 0; j < blen; j++) d[j] = (double)x[j] - m;
    const int pn = rate_ceil_log2(blen);
    const double nblk = (double)blen;
    int64_t kk_of[RATE_BITS + 1] = {0};
    double memo[RATE_MEMO];
    for (int q = q_first; q <= hi; q++) {
        const double levels = (double)((1 << q) - 1);
        const double s = span > 0 ? span / levels : 1.0;
        /* a block has at most 2^q runs and about twice the runs of q - 1 */
        int64_t guess = (int64_t)1 << q;
        if (q > q_first && 2 * kk_of[q - 1] < guess) guess = 2 * kk_of[q - 1];
        int32_t *c_q = cnt + (q % RATE_SLOTS) * blen;
        const int64_t kk = rate_runs(d, blen, s, levels, 16 * guess < blen, sym, c_q);
        kk_of[q] = kk;
        /* the fitter's precision rule n = min(16, max(ceil log2 K, ceil log2 N, 1)) */
        int pi = rate_ceil_log2(kk);
        if (pi < pn) pi = pn;
        if (pi < 1) pi = 1;
        if (pi > 16) pi = 16;
        const double prec = (double)pi, tot = (double)(1 << pi), dk = (double)kk;
        const int64_t cell = r * RATE_BITS + (q - 1);
        o->k[cell] = dk;
        o->payload[cell] = kk > 1 ? rate_table_bits(c_q, kk, prec, tot - dk, nblk, memo) : 0.0;
        double gap = 0.0, gap2 = 0.0, level = 0.0;
        for (int64_t i = 1; i < kk; i++) {
            const int32_t step = sym[i] - sym[i - 1];
            gap += tab[1 + step];
            gap2 += step > 128 ? 1.0 : 0.0;
            /* COARSE level codes step twice per octave of count */
            const double t = fabs(rint(2.0 * (tab[c_q[i]] - tab[c_q[i - 1]])));
            level += tab[1 + (int64_t)t];
        }
        o->gap[cell] = gap;
        o->gap2[cell] = gap2;
        o->level[cell] = level;
        o->laplace[cell] = (kk > 1 && (double)sym[kk - 1] + 1.0 <= tot)
                         ? rate_laplace(sym, c_q, kk, prec, tot, rho_min, rho_max) : INFINITY;
        /* binned by 2^h: the bins ~ the (q - h)-bit grid's runs, scored at this q's precision;
         * cells whose q - h was not computed keep the caller's +inf */
        for (int h = 1; h <= RATE_SHIFTS && q - h >= q_first; h++) {
            const double kv = (double)kk_of[q - h] * (double)(1 << h);
            const int32_t *c_h = cnt + ((q - h) % RATE_SLOTS) * blen;
            o->binned[cell * RATE_SHIFTS + (h - 1)] =
                (kv <= tot && kk > 1)
                ? rate_table_bits(c_h, kk_of[q - h], prec, tot - kv, nblk * (double)(1 << h), memo)
                : INFINITY;
        }
    }
}

int rate_group_stats_run(const float *x, int64_t nb, int64_t blen, const double *tab,
                         int q_first, int hi, double rho_min, double rho_max, const RateOut *o)
{
    /* per block: its values minus the minimum, this q's run symbols, the run lengths of the
     * last RATE_SLOTS bit-widths (the binned candidates read q - 1 .. q - 5) */
    double *d = big_alloc((size_t)blen * sizeof *d);
    int32_t *sym = big_alloc((size_t)blen * sizeof *sym);
    int32_t *cnt = big_alloc((size_t)blen * RATE_SLOTS * sizeof *cnt);
    const int ok = d && sym && cnt;
    if (ok)
        for (int64_t r = 0; r < nb; r++)
            rate_block(x + r * blen, blen, tab, q_first, hi, rho_min, rho_max, r, o, d, sym, cnt);
    free(d); free(sym); free(cnt);
    return ok ? 0 : -1;
}

/* ================================================================== loss table (encoder) */
/* gsz.kernels.quantize_cpu.loss_all_bits for one channel row: per block, the squared error
 * of the normative quantiser (gsz.decoder.quant: float64 step from the float32 min/max,
 * round half to even, clamp) at every width lo..hi, summed in value order.  The same float64
 * operations per value as the torch reference; only the order of the final sum differs
 * (torch's dot product), so the two agree to ~1e-15 relative. */
void loss_all_bits_run(const float *x, int64_t length, int64_t nb, const float *mins,
                       const float *maxs, int lo, int hi, double *out)
{
    const int64_t base = length / nb, extra = length % nb;
    for (int64_t b = 0; b < nb; b++) {
        const int64_t start = b * base + (b < extra ? b : extra), n = base + (b < extra);
        const float *v = x + start;
        const double m = (double)mins[b], span = (double)maxs[b] - m;
        for (int q = lo; q <= hi; q++) {
            const double levels = (double)((1 << q) - 1);
            const double s = span > 0 ? span / levels : 1.0;
            double acc = 0.0;
            for (int64_t j = 0; j < n; j++) {
                const double d = (double)v[j] - m;     /* >= 0: m is the block's minimum */
                const double e = d - rate_sym(d, s, levels) * s;
                acc += e * e;
            }
            out[b * RATE_BITS + (q - 1)] = acc;
        }
    }
}

/* gsz.kernels.quantize_cpu.quantize for one channel row: symbols min(max(rint((x - m) / s), 0),
 * 2^q - 1) per block at its width bits[b], the same float64 operations as the torch reference
 * (so the same symbols, bit for bit). */
void quantize_row_run(const float *x, int64_t length, int64_t nb, const float *mins,
                      const float *maxs, const int64_t *bits, int32_t *sym)
{
    const int64_t base = length / nb, extra = length % nb;
    for (int64_t b = 0; b < nb; b++) {
        const int64_t start = b * base + (b < extra ? b : extra), n = base + (b < extra);
        const double m = (double)mins[b], span = (double)maxs[b] - m;
        const double levels = (double)((1 << bits[b]) - 1);
        const double s = span > 0 ? span / levels : 1.0;
        for (int64_t j = start; j < start + n; j++) {
            /* rate_sym's rounding is exact for d >= 0; below 0 it gives some k <= 0, as rint */
            const double k = rate_sym((double)x[j] - m, s, levels);
            sym[j] = (int32_t)(k > 0.0 ? k : 0.0);
        }
    }
}

/* The size search's decoded SH rest, rows [0, n) of an output range: row i is voxel order[i];
 * with group[i] >= 0 its kept vector quantised again with that group's float64 parameters
 * (gsz.kernels.quantize_cpu's k = min(max(rint((x - lo) / step), 0), top), then the decoder's
 * step * k + lo, rounded once to float32: the operations and roundings of the NumPy rows it
 * replaces), else codeword cw_row[i] of books.  One pass per row instead of a dozen NumPy
 * passes over float64 temporaries (the judge reads every candidate's rows once per view). */
int sh_requant_rows(const float *sh, int64_t num_sh, int64_t d, const int64_t *order,
                    const int32_t *group, const int32_t *cw_row, int64_t n, const float *books,
                    int64_t num_books, const double *lo, const double *step, const double *top,
                    int64_t num_groups, float *out)
{
    for (int64_t i = 0; i < n; i++) {
        float *o = out + i * d;
        const int64_t g = group[i];
        if (g >= 0) {
            const int64_t r = order[i];
            if (g >= num_groups || r < 0 || r >= num_sh) return -1;
            const float *x = sh + r * d;
            const double *m = lo + g * d, *s = step + g * d, *t = top + g * d;
            for (int64_t c = 0; c < d; c++) {
                double v = ((double)x[c] - m[c]) / s[c];
                v = rint(v);
                v = (v > 0.0 || v != v) ? v : 0.0;       /* np.maximum(v, 0): -0.0 -> 0.0 */
                v = (v < t[c] || v != v) ? v : t[c];     /* np.minimum(v, top) */
                v *= s[c];
                v += m[c];
                o[c] = (float)v;
            }
        } else {
            const int64_t w = cw_row[i];
            if (w < 0 || w >= num_books) return -1;
            memcpy(o, books + w * d, (size_t)d * sizeof(float));
        }
    }
    return 0;
}
