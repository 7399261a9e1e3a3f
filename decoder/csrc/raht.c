/* gsz.decoder._native: inverse RAHT (TRANSFORMS.md §2) -- the tree built once per geometry,
 * applied per channel group. */
#include "stages.h"

/*
 * The tree (gsz.decoder.raht.build_raht_tree) is built once per geometry by raht_tree() and
 * applied per channel group by raht_apply(), so that two threads can transform disjoint channel
 * groups of one tree at the same time.
 *
 * Bottom-up construction one octree level (three binary levels) per pass: the nodes of a level
 * are grouped by parent (code >> 3, consecutive since the codes ascend); inside a group the
 * children k = code & 7 merge at binary level 3j (k, k ^ 1), 3j + 1 (k >> 1 pairs) and 3j + 2
 * (k >> 2 pairs), the merged node keeping its left (= lower) slot and the summed weight.  The
 * pairs of one binary level come out in node order, i.e. ascending slot, exactly the order the
 * NumPy builder produces level by level; a first pass counts them so every binary level's
 * pairs are written straight to their place.
 */

void rtree_free(RTree *t)
{
    if (!t) return;
    free(t->lvl_start);
    free(t->pairs);
    free(t->sqrtw);
    free(t);
}


/* Per occupancy byte o of a parent: its sibling pairs at the three binary levels.  The present
 * children in k order have ranks 0..popcount(o)-1; a pair at binary level b joins the child
 * ranges [k, k + 2^b) and [k + 2^b, k + 2^(b+1)) when both hold a child: entry = b | lr << 2
 * | rr << 5 | re << 8 with the ranks lr (first child of the left range), rr (first of the
 * right range) and re (one past the right range's last).  RAHT_NP[o]: number of entries,
 * RAHT_CNT[o]: pairs per binary level (bits 0-7, 8-15, 16-23). */
static uint16_t RAHT_ENT[256][7];
static uint8_t RAHT_NP[256];
static uint32_t RAHT_CNT[256];

static void raht_pairs8_init(void)
{
    for (unsigned o = 0; o < 256; o++) {
        unsigned rank[9];
        rank[0] = 0;
        for (int k = 0; k < 8; k++) rank[k + 1] = rank[k] + ((o >> k) & 1u);
        unsigned np = 0, cnt = 0;
        for (int b = 0; b < 3; b++) {
            const int step = 1 << b;
            for (int k = 0; k < 8; k += 2 * step) {
                const unsigned lr = rank[k], rr = rank[k + step], re = rank[k + 2 * step];
                if (rr > lr && re > rr) {
                    RAHT_ENT[o][np++] = (uint16_t)(b | (lr << 2) | (rr << 5) | (re << 8));
                    cnt += 1u << (8 * b);
                }
            }
        }
        RAHT_NP[o] = (uint8_t)np;
        RAHT_CNT[o] = cnt;
    }
}

/* butterfly gains of a pair (NumPy: a = sqrt(wl + wr), g1 = sqrt(wl) / a, g2 = sqrt(wr) / a) */
#define GTAB 16
typedef struct { double g1, g2; } Gain;

static inline Gain gain_of(int64_t wl, int64_t wr)
{
    const double a = sqrt((double)wl + (double)wr);
    Gain g = {sqrt((double)wl) / a, sqrt((double)wr) / a};
    return g;
}

static inline void emit_pair(RPair *p, int32_t l, int32_t r, int64_t wl, int64_t wr,
                             const Gain *gtab)
{
    p->left = l;
    p->right = r;
    const Gain g = (wl <= GTAB && wr <= GTAB) ? gtab[(wl - 1) * GTAB + (wr - 1)] : gain_of(wl, wr);
    p->g1 = g.g1;
    p->g2 = g.g2;
}

int rtree_build(const uint64_t *c0, int64_t n, int depth, const int64_t *leafw, RTree **out, Err *e)
{
    *out = NULL;
    uint64_t *code = NULL;
    int32_t *slot = NULL, *gstart = NULL;
    int64_t *wt = NULL;
    uint8_t *gocc = NULL;
    RTree *t = calloc(1, sizeof *t);
    if (!t) return fail_nomem(e);
    t->n = n;
    code = big_alloc((size_t)n * sizeof *code);
    slot = big_alloc((size_t)n * sizeof *slot);
    wt = big_alloc((size_t)n * sizeof *wt);
    gstart = big_alloc((size_t)(n + 1) * sizeof *gstart);
    gocc = big_alloc((size_t)n);
    t->pairs = big_alloc((size_t)(n > 1 ? n - 1 : 1) * sizeof *t->pairs);
    t->lvl_start = malloc((size_t)(3 * depth + 2) * sizeof *t->lvl_start);
    if (!code || !slot || !wt || !gstart || !gocc || !t->pairs || !t->lvl_start) {
        fail_nomem(e);
        goto fail;
    }
    for (int64_t i = 1; i < n; i++) {
        if (c0[i] <= c0[i - 1]) { fail(e, "Morton codes must be strictly ascending (sorted, unique)"); goto fail; }
    }
    if (c0[n - 1] >> (3 * depth)) { fail(e, "Morton code exceeds 3*depth bits"); goto fail; }
    Gain gtab[GTAB * GTAB];
    for (int a = 1; a <= GTAB; a++)
        for (int b = 1; b <= GTAB; b++) gtab[(a - 1) * GTAB + (b - 1)] = gain_of(a, b);
    for (int64_t i = 0; i < n; i++) { slot[i] = (int32_t)i; wt[i] = 1; }
    if (leafw) {                     /* integer leaf weights (TRANSFORMS.md §2.5): exact sums */
        t->sqrtw = big_alloc((size_t)n * sizeof *t->sqrtw);
        if (!t->sqrtw) { fail_nomem(e); goto fail; }
        for (int64_t i = 0; i < n; i++) {
            if (leafw[i] < 1 || leafw[i] > 65535) { fail(e, "RAHT leaf weights must lie in 1..65535"); goto fail; }
            wt[i] = leafw[i];
            t->sqrtw[i] = sqrt((double)leafw[i]);
        }
    }
    const uint64_t *cur = c0;        /* the codes of the current level (the input at first) */
    int64_t len = n, np_ = 0;
    int nlev = 0;
    for (int j = 0; j < depth && len > 1; j++) {
        /* pass 1: the parents (code[g] = their codes, written in place: g <= i), their
         * occupancy bytes and first child, and the pairs per binary level */
        int64_t g = 0;
        uint32_t cnt_lo = 0;
        int64_t cnt[3] = {0, 0, 0};
        for (int64_t i = 0; i < len; ) {
            const uint64_t p = cur[i] >> 3;
            unsigned o = 1u << (cur[i] & 7u);
            gstart[g] = (int32_t)i;
            i++;
            while (i < len && (cur[i] >> 3) == p) { o |= 1u << (cur[i] & 7u); i++; }
            code[g] = p;
            gocc[g] = (uint8_t)o;
            g++;
            cnt_lo += RAHT_CNT[o];
            if ((g & 31) == 0) {     /* flush the packed 8-bit counters before they overflow */
                cnt[0] += cnt_lo & 0xFF; cnt[1] += (cnt_lo >> 8) & 0xFF; cnt[2] += cnt_lo >> 16;
                cnt_lo = 0;
            }
        }
        cnt[0] += cnt_lo & 0xFF; cnt[1] += (cnt_lo >> 8) & 0xFF; cnt[2] += cnt_lo >> 16;
        gstart[g] = (int32_t)len;
        cur = code;
        if (np_ + cnt[0] + cnt[1] + cnt[2] > n - 1) { fail(e, "RAHT tree did not reduce to a single root"); goto fail; }
        RPair *dst[3];
        {
            int64_t at = np_;
            for (int b = 0; b < 3; b++) {
                dst[b] = t->pairs + at;
                if (cnt[b]) t->lvl_start[nlev++] = at;
                at += cnt[b];
            }
        }
        /* pass 2: the pairs of every parent, then its slot (first child's) and weight (sum),
         * in place (parent q <= its first child) */
        for (int64_t q = 0; q < g; q++) {
            const int64_t i0 = gstart[q], i1 = gstart[q + 1];
            const unsigned o = gocc[q];
            const int32_t s0 = slot[i0];
            if (i1 - i0 == 1) {          /* a single child: no pair, passes up unchanged */
                slot[q] = s0;
                wt[q] = wt[i0];
                continue;
            }
            int64_t W[9];                /* prefix sums of the children's weights */
            W[0] = 0;
            for (int64_t r = 0; r < i1 - i0; r++) W[r + 1] = W[r] + wt[i0 + r];
            const int np8 = RAHT_NP[o];
            for (int x = 0; x < np8; x++) {
                const unsigned en = RAHT_ENT[o][x];
                const unsigned b = en & 3u, lr = (en >> 2) & 7u, rr = (en >> 5) & 7u, re = en >> 8;
                emit_pair(dst[b]++, slot[i0 + lr], slot[i0 + rr], W[rr] - W[lr], W[re] - W[rr], gtab);
            }
            slot[q] = s0;
            wt[q] = W[i1 - i0];
        }
        np_ += cnt[0] + cnt[1] + cnt[2];
        len = g;
    }
    t->lvl_start[nlev] = np_;
    t->nlev = nlev;
    if (len != 1 || np_ != n - 1) { fail(e, "RAHT tree did not reduce to a single root"); goto fail; }
    free(code); free(slot); free(wt); free(gstart); free(gocc);
    *out = t;
    return 0;
fail:
    free(code); free(slot); free(wt); free(gstart); free(gocc);
    rtree_free(t);
    return -1;
}

void raht_static_init(void)
{
    raht_pairs8_init();
}

void raht_inverse(const RTree *t, const double *dc, const double *ac, int64_t c0, int64_t k,
                  double *v, int half)
{
    const int64_t n = t->n;
    for (int64_t c = 0; c < k; c++) v[c * n] = dc[c0 + c];
    /* top-down, coarsest level first; the AC coefficients of a level are contiguous in the
     * stream (coarsest level first, ascending slot within a level) */
    for (int64_t c = 0; c < k; c++) {
        double *restrict vc = v + c * n;
        const double *restrict acc = ac + (c0 + c) * (n - 1);
        int64_t acpos = 0;
        for (int L = t->nlev - 1; L >= 0; L--) {
            const RPair *pr = t->pairs + t->lvl_start[L], *pe = t->pairs + t->lvl_start[L + 1];
            for (; pr < pe; pr++, acpos++) {
                const double low = vc[pr->left], high = acc[acpos];
                const double t1 = pr->g1 * low, t2 = pr->g2 * high;
                const double t3 = pr->g2 * low, t4 = pr->g1 * high;
                vc[pr->left] = t1 - t2;
                vc[pr->right] = t3 + t4;
            }
        }
        if (t->sqrtw)                /* the leaves' values: v / sqrt(w), as NumPy's v /= scale */
            for (int64_t i = 0; i < n; i++) vc[i] = vc[i] / t->sqrtw[i];
    }
    if (half)
        for (int64_t i = 0; i < k * n; i++) v[i] = 0.5 * (isfinite(v[i]) ? v[i] : 0.0);
}
