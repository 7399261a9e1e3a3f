/* gsz.decoder._native: the normative octree traversal (decoder/octree.py::walk_octree,
 * OCTREE.md §4) in both directions -- bits drawn from a binary rANS decoder
 * (octree_decode.c) or read from known occupancy bytes and recorded (octree_encode.c) -- with
 * the helper thread that may compute its context ids and neighbour rows. */
#include "octree.h"

/* CHILD_RANK[v * 8 + j]: the rank of child j among the children present in occupancy v (the
 * bits below j), or 2^30 (more than any node count) when child j is absent */
static int32_t CHILD_RANK[256 * 8];

static void child_rank_init(void)
{
    for (unsigned v = 0; v < 256; v++)
        for (unsigned j = 0; j < 8; j++)
            CHILD_RANK[v * 8 + j] = ((v >> j) & 1u) ? popcount8(v & ((1u << j) - 1u)) : (1 << 30);
}

/* coarse context part of a fine one: fine acc = kn_f*3087 + unk_f*441 + kn_o*21 + unk_o ->
 * (kn_f + kn_o)*27 + unk_f + unk_o */
static uint16_t FINE_TO_COARSE[7 * 7 * 21 * 21];

static void fine_to_coarse_init(void)
{
    for (int a = 0; a < 7 * 7 * 21 * 21; a++) {
        const int kf = a / 3087, uf = (a % 3087) / 441, ko = (a % 441) / 21, uo = a % 21;
        FINE_TO_COARSE[a] = (uint16_t)((kf + ko) * 27 + uf + uo);
    }
}

void octree_static_init(void)
{
    child_rank_init();
    fine_to_coarse_init();
}

/* Counts of one fine context, with the chunk-local cache of its model and the bookkeeping of
 * the per-level halving, in one 16-byte record (one cache miss per decision instead of four). */
typedef struct {
    uint32_t n0, n1;     /* adjacent: (&n0)[bit] is the count of `bit` */
    uint32_t stamp;      /* chunk whose model is cached in `model` (0: none) */
    uint8_t model;
    uint8_t listed;      /* level + 1 of the halving list this context is on (0: none) */
    uint16_t cix;        /* the coarse context (a function of the fine one), set with `model` */
} FineCtx;

/* Growable list of context ids (the fine contexts to look at when halving). */
typedef struct {
    int32_t *v;
    int64_t len, cap;
} IdList;

static int idlist_push(IdList *l, int32_t id, Err *e)
{
    if (l->len == l->cap) {
        int64_t cap = l->cap ? 2 * l->cap : 4096;
        int32_t *v = realloc(l->v, (size_t)cap * sizeof *v);
        if (!v) return fail_nomem(e);
        l->v = v;
        l->cap = cap;
    }
    l->v[l->len++] = id;
    return 0;
}

static void ctx_block(const Phase *p, int64_t a, int64_t b)
{
    const OctTables *tb = p->tb;
    const int k = p->k;
    const int *tk = tb->t[k];
    const int t0 = tk[0], t1 = tk[1], t2 = tk[2], t3 = tk[3], t4 = tk[4], t5 = tk[5],
              t6 = tk[6], t7 = tk[7];
    const uint32_t *lut = tb->ctx_lut + (size_t)k * 8 * 256;
    const unsigned below = (1u << k) - 1u;
    const int32_t fine_k = k * (7 * 7 * 21 * 21), fine_lb = p->lb * (NUM_FINE / NUM_LB);
    const uint8_t *occ = p->occ;
    const int32_t *nbr = p->nbr, *coded = p->coded, *crow = p->crow;
    const int compact = p->compact;
    int32_t *restrict fix = p->fix;
    for (int64_t i = a; i < b; i++) {
        const int64_t node = coded ? coded[i] : i;
        /* rows of a level with direct nodes are those of its tree nodes only (see walk_level) */
        const int64_t row = crow ? crow[i] : compact ? i : node;
        const int32_t *nb = nbr + row * NUM_T;
        /* 8 octant nodes (padded with zero-contribution entries), unrolled with their offsets
         * in registers */
        const uint32_t acc = lut[occ[nb[t0]]] + lut[256 + occ[nb[t1]]]
                             + lut[512 + occ[nb[t2]]] + lut[768 + occ[nb[t3]]]
                             + lut[1024 + occ[nb[t4]]] + lut[1280 + occ[nb[t5]]]
                             + lut[1536 + occ[nb[t6]]] + lut[1792 + occ[nb[t7]]];
        int sib = popcount8(occ[node] & below);
        if (sib > NUM_SIB - 1) sib = NUM_SIB - 1;
        /* the fine context id is (((((k*7 + kn_f)*7 + unk_f)*21 + kn_o)*21 + unk_o)*4 + sib)*4
         * + lb (OCTREE.md); its record is stored level-bucket-major so that the contexts of one
         * level share cache lines (the coarse id follows from it: FINE_TO_COARSE) */
        fix[i] = fine_lb + (fine_k + (int32_t)(acc & 0xFFFF)) * NUM_SIB + sib;
    }
}

/* PHASE_BUILD in prow mode: the children of the tree nodes of rows [j0, j1) -- codes, and
 * (unless last) each child's parent row, from which PHASE_ROWS derives the rows of the
 * children left in the tree once their level's direct flags are known. */
static void prow_block(const Phase *p, int64_t j0, int64_t j1)
{
    const uint8_t *occ = p->occ;
    const int32_t *keep = p->keep;
    const uint64_t *codes = p->codes;
    uint64_t *ncodes = p->ncodes;
    int32_t *prow = p->last ? NULL : p->prow;
    int64_t c = p->start[keep ? keep[j0] : j0] >> 8;
    for (int64_t j = j0; j < j1; j++) {
        const int64_t r = keep ? keep[j] : j;
        const unsigned o = occ[r];
        for (int k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            ncodes[c] = (codes[r] << 3) | (uint64_t)k;
            if (prow) prow[c] = (int32_t)j;
            c++;
        }
    }
}

/* PHASE_ROWS: the neighbour rows of this level's tree nodes of rows [a, b) (node keep[j], or
 * j), each derived from its parent's row as build_block does. */
static void rows_block(const Phase *p, int64_t a, int64_t b)
{
    const OctTables *tb = p->tb;
    const int32_t *keep = p->keep, *prow = p->prow, *nbr = p->nbr;
    const int64_t *start = p->start;
    const uint64_t *codes = p->codes;
    int32_t *nnbr = p->nnbr;
    const int32_t absent = (int32_t)p->total;
    for (int64_t j = a; j < b; j++) {
        const int64_t i = keep ? keep[j] : j;
        const int k = (int)(codes[i] & 7);
        const int32_t *nb = nbr + (int64_t)prow[i] * NUM_T;
        const uint8_t *cpk = tb->cp8[k], *cik = tb->ci8[k];
        int32_t *dst = nnbr + j * NUM_T;
        for (int t = 0; t < NUM_T; t++) {
            const int64_t kv = start[nb[cpk[t]]];
            const int32_t idx = (int32_t)(kv >> 8) + CHILD_RANK[((int32_t)(kv & 0xFF) << 3) + cik[t]];
            dst[t] = idx < absent ? idx : absent;
        }
        dst[SELF_T] = (int32_t)i;
    }
}

static void build_block(const Phase *p, int64_t r0, int64_t r1)
{
    const OctTables *tb = p->tb;
    const uint8_t *occ = p->occ;
    const int32_t *nbr = p->nbr;
    const int64_t *start = p->start;
    const uint64_t *codes = p->codes;
    uint64_t *ncodes = p->ncodes;
    int32_t *nnbr = p->nnbr;
    const int32_t absent = (int32_t)p->total;
    const int last = p->last;
    int64_t c = start[r0] >> 8;
    for (int64_t r = r0; r < r1; r++) {
        const unsigned o = occ[r];
        const int32_t *nb = nbr + r * NUM_T;
        int32_t base[NUM_T];     /* first-child index of the parent's 27 neighbours */
        int32_t rrow[NUM_T];     /* their occupancy's row in CHILD_RANK */
        if (!last) {
            for (int t = 0; t < NUM_T; t++) {
                const int64_t kv = start[nb[t]];
                base[t] = (int32_t)(kv >> 8);
                rrow[t] = (int32_t)((kv & 0xFF) << 3);
            }
        }
        for (int k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            ncodes[c] = (codes[r] << 3) | (uint64_t)k;
            if (!last) {
                /* neighbour t of child k: child ci of the parent's neighbour cp, i.e. its first
                 * child + the rank of bit ci, or absent (CHILD_RANK >= 2^30) */
                int32_t *dst = nnbr + c * NUM_T;
                const uint8_t *cpk = tb->cp8[k], *cik = tb->ci8[k];
                for (int t = 0; t < NUM_T; t++) {
                    const int q = cpk[t];
                    const int32_t idx = base[q] + CHILD_RANK[rrow[q] + cik[t]];
                    dst[t] = idx < absent ? idx : absent;
                }
                dst[SELF_T] = (int32_t)c;
            }
            c++;
        }
    }
}

static void run_block(const Phase *p, int64_t b)
{
    const int64_t a = b * p->block, e = a + p->block < p->items ? a + p->block : p->items;
    if (p->kind == PHASE_CTX) ctx_block(p, a, e);
    else if (p->kind == PHASE_ROWS) rows_block(p, a, e);
    else if (p->ranks) prow_block(p, a, e);
    else build_block(p, a, e);
}

/* The next phase's description (to fill before phase_publish), or NULL when out of memory. */
static Phase *phase_next(Helper *h, int kind, int64_t items, int64_t block)
{
    Phase *p = &h->desc[(h->seq + 1) & 1];
    p->kind = kind;
    p->items = items;
    p->block = block;
    p->nblocks = (items + block - 1) / block;
#if GSZ_HELPER
    const int slot = (int)((h->seq + 1) & 1);
    if ((size_t)p->nblocks > h->done_cap[slot]) {
        /* both slots live in one allocation: [slot 0 | slot 1] */
        size_t c0 = h->done_cap[0], c1 = h->done_cap[1];
        if (slot == 0) c0 = (size_t)p->nblocks * 2; else c1 = (size_t)p->nblocks * 2;
        uint8_t *nb = malloc(c0 + c1 + 2);
        if (!nb) return NULL;
        /* the other slot's flags are not in use (its phase is complete) */
        free(h->done_buf);
        h->done_buf = nb;
        h->done_cap[0] = c0;
        h->done_cap[1] = c1;
        h->desc[0].done = (_Atomic uint8_t *)nb;
        h->desc[1].done = (_Atomic uint8_t *)(nb + c0 + 1);
    }
    for (int64_t b = 0; b < p->nblocks; b++) atomic_store_explicit(&p->done[b], 0, memory_order_relaxed);
    atomic_store_explicit(&p->ndone, 0, memory_order_relaxed);
#endif
    return p;
}

static void phase_publish(Helper *h)
{
    h->seq++;
#if GSZ_HELPER
    atomic_store_explicit(&h->claim, (uint64_t)h->seq << 32, memory_order_release);
#endif
}

#if GSZ_HELPER
/* Claim and run one block of phase `seq` (description p); 1 if one was run, 0 if none was
 * left. */
static int claim_one(Helper *h, uint32_t seq, const Phase *p)
{
    uint64_t c = atomic_load_explicit(&h->claim, memory_order_acquire);
    for (;;) {
        if ((uint32_t)(c >> 32) != seq) return 0;
        const int64_t b = (int64_t)(c & 0xFFFFFFFFu);
        if (b >= p->nblocks) return 0;
        if (atomic_compare_exchange_weak_explicit(&h->claim, &c, c + 1, memory_order_acq_rel,
                                                  memory_order_acquire)) {
            run_block(p, b);
            atomic_store_explicit(&p->done[b], 1, memory_order_release);
            atomic_fetch_add_explicit((_Atomic int64_t *)&p->ndone, 1, memory_order_release);
            return 1;
        }
    }
}
#endif

/* The traversal's thread: make block b of the current phase done (running blocks itself while
 * any are unclaimed; without atomics it simply runs block b). */
static void phase_need(Helper *h, int64_t b)
{
    Phase *p = &h->desc[h->seq & 1];
#if GSZ_HELPER
    while (!atomic_load_explicit(&p->done[b], memory_order_acquire))
        if (!claim_one(h, h->seq, p)) cpu_relax();
#else
    run_block(p, b);
#endif
}

/* The traversal's thread: every block of the current phase done, and no helper still inside
 * one (the phase's description and flags may be reused after this).  all = run the blocks not
 * yet run (without atomics: the blocks phase_need did not run). */
static void phase_finish(Helper *h, int all)
{
    Phase *p = &h->desc[h->seq & 1];
#if GSZ_HELPER
    (void)all;
    while (claim_one(h, h->seq, p)) {}
    while (atomic_load_explicit(&p->ndone, memory_order_acquire) < p->nblocks) cpu_relax();
#else
    if (all)
        for (int64_t b = 0; b < p->nblocks; b++) run_block(p, b);
#endif
}

/* The traversal's thread, when it ends (also on an error in the middle of a phase): no block
 * can be claimed any more, and the blocks already claimed are finished (they read buffers the
 * traversal is about to free). */
static void phase_close(Helper *h)
{
#if GSZ_HELPER
    if (!h->seq) return;
    Phase *p = &h->desc[h->seq & 1];
    const uint64_t old = atomic_exchange_explicit(&h->claim, ((uint64_t)h->seq << 32) | 0xFFFFFFFFu,
                                                  memory_order_acq_rel);
    int64_t claimed = (int64_t)(old & 0xFFFFFFFFu);
    if ((uint32_t)(old >> 32) != h->seq) claimed = 0;
    if (claimed > p->nblocks) claimed = p->nblocks;
    while (atomic_load_explicit(&p->ndone, memory_order_acquire) < claimed) cpu_relax();
#else
    (void)h;
#endif
}

/* The helper's loop (octree_help): blocks of whatever phase is published, until closed. */
void helper_loop(Helper *h)
{
#if GSZ_HELPER
    unsigned idle = 0;
    while (!atomic_load_explicit(&h->closed, memory_order_acquire)) {
        const uint64_t c = atomic_load_explicit(&h->claim, memory_order_acquire);
        const uint32_t seq = (uint32_t)(c >> 32);
        if (seq && claim_one(h, seq, &h->desc[seq & 1])) {
            idle = 0;
            continue;
        }
        if (++idle < 4096) cpu_relax();
        else { yield_cpu(); idle = 0; }
    }
#else
    (void)h;
#endif
}

void helper_close(Helper *h)
{
#if GSZ_HELPER
    atomic_store_explicit(&h->closed, 1, memory_order_release);
#else
    (void)h;
#endif
}


void helper_init(Helper *h)
{
    memset(h, 0, sizeof *h);
#if GSZ_HELPER
    atomic_init(&h->claim, 0);
    atomic_init(&h->closed, 0);
    atomic_init(&h->desc[0].ndone, 0);
    atomic_init(&h->desc[1].ndone, 0);
#endif
}

/* Room for `extra` more recorded decisions (encoder mode). */
static int symout_reserve(SymOut *o, int64_t extra, Err *e)
{
    if (o->len + extra <= o->cap) return 0;
    int64_t cap = o->cap ? o->cap : 1 << 16;
    while (cap < o->len + extra) cap *= 2;
    uint8_t *b = realloc(o->bits, (size_t)cap);
    if (!b) return fail_nomem(e);
    o->bits = b;
    uint8_t *m = realloc(o->models, (size_t)cap);
    if (!m) return fail_nomem(e);
    o->models = m;
    o->cap = cap;
    return 0;
}

/* Make *p hold at least `need` bytes (contents not kept); buffers are reused across levels so
 * that their pages are faulted in once, not once per level. */
static int ensure(void **p, size_t *cap, size_t need, Err *e)
{
    if (need <= *cap) return 0;
    free(*p);
    *p = big_alloc(need);
    if (!*p) { *cap = 0; return fail_nomem(e); }
    *cap = need;
    return 0;
}

/* The traversal's state: counts, contexts and the per-level buffers (see oct_walk). */
typedef struct {
    uint32_t *cc;            /* coarse context counts, pairs (n0, n1) */
    FineCtx *ff;             /* fine contexts */
    uint8_t *ff_touched;     /* pages of ff written to so far (see walk_init) */
    uintptr_t ff_page0;
    uint64_t *codes, *ncodes;
    int32_t *nbr, *nnbr, *coded, *fixa;
    int64_t *start;
    uint8_t *occ;    /* per node: during the bit-planes 0x80 (present) | child bits of the
                      * finished bit-planes (occ[n] = 0: absent); after them the occupancy */
    uint8_t *pbit;   /* the bits of the current bit-plane, merged into occ after it (child 7:
                      * after the level) */
    uint8_t *mbuf, *bbuf;    /* models and decoded bits of one chunk */
    uint32_t stamp;
    IdList list, carry;
    size_t cap_codes, cap_ncodes, cap_nbr, cap_nnbr, cap_occ, cap_coded, cap_start, cap_pbit,
           cap_fix;
    /* direct coding (scheme 1) */
    uint8_t *par_pop;        /* per node of the level: its parent's child count */
    int32_t *keep;           /* the level's nodes left in the tree (when some went direct) */
    uint64_t *pts;           /* the direct points' leaf codes, level after level */
    int64_t npts;
    uint32_t dcnt[2 * NUM_DIRECT];
    uint8_t *dmark;          /* per node of the level: went direct */
    int32_t *prow;           /* per node of the level: its parent's row (levels >= the direct one) */
    int32_t *crow;           /* bit-plane 7's coded nodes' rows (a level with direct nodes) */
    size_t cap_pop, cap_keep, cap_pts, cap_dmark, cap_prow, cap_crow;
} Walk;

/* The buffers of level 0 (the root, no neighbours) and the counts. */
static int walk_init(Walk *w, const OctTables *tb, Err *e)
{
    w->cc = calloc(2 * (size_t)NUM_COARSE, sizeof *w->cc);
    w->ff = calloc((size_t)NUM_FINE, sizeof *w->ff);     /* pages are touched only where used */
    /* pages of ff written to so far: the first access to a page must be a write.  A read
     * maps the kernel's shared zero page, and the write after it replaces that mapping, which
     * costs a TLB shootdown (an inter-processor interrupt, expensive in a VM) whenever another
     * thread of the process runs -- measured ~870 per flowers decode, ~10 % of the traversal. */
    w->ff_page0 = (uintptr_t)w->ff >> 12;
    w->ff_touched = calloc(((size_t)NUM_FINE * sizeof *w->ff >> 15) + 2, 1);
    if (ensure((void **)&w->codes, &w->cap_codes, sizeof *w->codes, e) < 0
        || ensure((void **)&w->nbr, &w->cap_nbr, NUM_T * sizeof *w->nbr, e) < 0)
        return -1;
    w->mbuf = malloc((size_t)tb->chunk_max);
    w->bbuf = malloc((size_t)tb->chunk_max);
    if (!w->cc || !w->ff || !w->ff_touched || !w->codes || !w->nbr || !w->mbuf || !w->bbuf)
        return fail_nomem(e);
    w->codes[0] = 0;
    for (int t = 0; t < NUM_T; t++) w->nbr[t] = 1;   /* n = 1: absent */
    w->nbr[SELF_T] = 0;
    return 0;
}

static void walk_free(Walk *w)
{
    free(w->cc); free(w->ff); free(w->codes); free(w->ncodes); free(w->nbr); free(w->nnbr);
    free(w->occ); free(w->pbit); free(w->coded); free(w->start); free(w->fixa);
    free(w->ff_touched); free(w->mbuf); free(w->bbuf); free(w->list.v); free(w->carry.v);
    free(w->par_pop); free(w->keep); free(w->pts); free(w->dmark); free(w->prow); free(w->crow);
}

/* The models of chunk [s, end) of bit-plane k into mbuf, all from the counts before the
 * chunk; lists each fine context used for the level's halving. */
static int walk_chunk_models(Walk *w, const OctTables *tb, int64_t s, int64_t end, int k, int lb,
                             uint8_t tag, Err *e)
{
    const int32_t coarse_k = k * (27 * 27), fine_k = k * (7 * 7 * 21 * 21);
    const int32_t fine_lb = lb * (NUM_FINE / NUM_LB);
    const int32_t *fixa = w->fixa;
    const uint32_t *cc = w->cc;
    FineCtx *ff = w->ff;
    uint8_t *ff_touched = w->ff_touched, *mbuf = w->mbuf;
    const uintptr_t ff_page0 = w->ff_page0;
    const uint32_t stamp = ++w->stamp;
    for (int64_t i = s; i < end; i++) {
        const int32_t fix = fixa[i];
        FineCtx *fc = ff + fix;
        const uintptr_t pg = ((uintptr_t)fc >> 12) - ff_page0;
        if (!(ff_touched[pg >> 3] & (1u << (pg & 7)))) {
            ff_touched[pg >> 3] |= (uint8_t)(1u << (pg & 7));
            *(volatile uint8_t *)fc = 0;    /* the page's first access: a write */
        }
        if (fc->stamp != stamp) {
            /* the model is a function of the fine context (which fixes the coarse one) and of
             * the counts, which are frozen during a chunk: computed once per chunk and context */
            const int32_t u = (fix - fine_lb) >> 2;
            const int32_t cix = (coarse_k + FINE_TO_COARSE[u - fine_k]) * NUM_SIB
                                + (fix & (NUM_SIB - 1));
            const uint64_t c0 = cc[2 * cix], c1 = cc[2 * cix + 1];
            const uint64_t pc = ((2 * c1 + 1) << 16) / (2 * (c0 + c1) + 2);
            const uint64_t f0 = fc->n0, f1 = fc->n1;
            const uint64_t mw = (uint64_t)tb->mix_weight;
            const uint64_t pf = ((f1 << 16) + mw * pc) / (f0 + f1 + mw);
            if (pf > 65535) return fail(e, "octree: probability out of range");
            fc->model = tb->p16m[pf];    /* < num_models (checked) */
            fc->stamp = stamp;
            fc->cix = (uint16_t)cix;
            if (fc->listed != tag) {
                fc->listed = tag;
                if (idlist_push(&w->list, fix, e) < 0) return -1;
            }
        }
        mbuf[i - s] = fc->model;
    }
    return 0;
}

/* The bits of chunk [s, end) (from bbuf when `fast` decoded them already, else from the
 * decoder or the known bytes, recorded), then the count updates. */
static int walk_chunk_bits(Walk *w, const OctTables *tb, int64_t s, int64_t end, int k, int mode,
                           int fast, BinDec *dec, const uint8_t *kn, const int32_t *coded,
                           SymOut *out, Err *e)
{
    const int32_t *fixa = w->fixa;
    const uint8_t *mbuf = w->mbuf, *bbuf = w->bbuf;
    uint8_t *pbit = w->pbit;
    uint32_t *cc = w->cc;
    FineCtx *ff = w->ff;
    for (int64_t i = s; i < end; i++) {
        const int64_t node = coded ? coded[i] : i;
        int bit;
        if (fast) {
            bit = bbuf[i - s];
        } else if (mode == 0) {
            bit = oct_bin_decode(dec, tb, mbuf[i - s], e);
            if (bit < 0) return -1;
        } else {
            bit = (kn[node] >> k) & 1;
            out->bits[out->len] = (uint8_t)bit;
            out->models[out->len] = mbuf[i - s];
            out->len++;
        }
        pbit[node] = (uint8_t)bit;
        FineCtx *fc = ff + fixa[i];
        cc[2 * fc->cix + bit]++;
        (&fc->n0)[bit]++;       /* n0 or n1, without a branch */
    }
    return 0;
}

/* Bit-plane k (child k of every node in the tree -- `keep`, nkeep of them, or all n when keep
 * is NULL --, child 7 only where not implied) of a level of n nodes. */
static int walk_plane(Walk *w, const OctTables *tb, int64_t n, const int32_t *keep, int64_t nkeep,
                      int k, int lb, uint8_t tag, int mode, BinDec *dec, const uint8_t *kn,
                      SymOut *out, Helper *h, Err *e)
{
    int64_t cnt = keep ? nkeep : n;
    const int32_t *coded = keep, *crow = NULL;
    if (k == 7) {
        /* a node with no child among 0..6 has child 7 for free (not coded) */
        cnt = 0;
        for (int64_t j = 0; j < (keep ? nkeep : n); j++) {
            const int64_t i = keep ? keep[j] : j;
            if (w->occ[i] & 0x7F) {
                if (keep) w->crow[cnt] = (int32_t)j;       /* its row: its rank in keep */
                w->coded[cnt++] = (int32_t)i;
                w->pbit[i] = 0;
            } else {
                w->pbit[i] = 1;
            }
        }
        coded = w->coded;
        crow = keep ? w->crow : NULL;
    }
    /* the bit-plane's context ids, as blocks (computed ahead by a helper, if any) */
    Phase *ph = phase_next(h, PHASE_CTX, cnt, CTX_BLOCK);
    if (!ph) return fail_nomem(e);
    ph->tb = tb;
    ph->occ = w->occ;
    ph->nbr = w->nbr;
    ph->coded = coded;
    ph->crow = crow;
    ph->compact = keep != NULL;
    ph->fix = w->fixa;
    ph->k = k;
    ph->lb = lb;
    phase_publish(h);
    int64_t s = 0, ready = 0;
    while (s < cnt) {
        int64_t step = s > tb->chunk_min ? s : tb->chunk_min;
        if (step > tb->chunk_max) step = tb->chunk_max;
        const int64_t end = s + step < cnt ? s + step : cnt;
        while (ready < end) {
            phase_need(h, ready / CTX_BLOCK);
            ready = (ready / CTX_BLOCK + 1) * CTX_BLOCK;
        }
        if (walk_chunk_models(w, tb, s, end, k, lb, tag, e) < 0) return -1;
        /* enough symbols and words left for the whole chunk (at most one word per symbol):
         * decoded in one loop without the per-symbol checks */
        const int fast = mode == 0 && dec->pos + (end - s) <= dec->nsym
                         && dec->wpos + (end - s) <= dec->nwords;
        if (fast) oct_bin_decode_chunk(dec, tb, w->mbuf, w->bbuf, end - s);
        if (walk_chunk_bits(w, tb, s, end, k, mode, fast, dec, kn, coded, out, e) < 0) return -1;
        s = end;
    }
    phase_finish(h, 0);     /* every block was needed (ready >= cnt) */
    if (k < 7) {
        if (keep)
            for (int64_t j = 0; j < nkeep; j++) w->occ[keep[j]] |= (uint8_t)(w->pbit[keep[j]] << k);
        else
            for (int64_t i = 0; i < n; i++) w->occ[i] |= (uint8_t)(w->pbit[i] << k);
    }
    return 0;
}

/* After a level: halve every coarse pair, and the listed fine contexts, above the limit. */
static int walk_halve(Walk *w, const OctTables *tb, uint8_t tag, Err *e)
{
    uint32_t *cc = w->cc;
    for (int64_t i = 0; i < NUM_COARSE; i++) {
        const uint32_t a = cc[2 * i], b = cc[2 * i + 1];
        if ((int64_t)a + (int64_t)b > tb->count_limit) {
            cc[2 * i] = (a + 1) >> 1;
            cc[2 * i + 1] = (b + 1) >> 1;
        }
    }
    w->carry.len = 0;
    for (int64_t i = 0; i < w->list.len; i++) {
        FineCtx *fc = w->ff + w->list.v[i];
        if ((int64_t)fc->n0 + (int64_t)fc->n1 > tb->count_limit) {
            fc->n0 = (fc->n0 + 1) >> 1;
            fc->n1 = (fc->n1 + 1) >> 1;
            if ((int64_t)fc->n0 + (int64_t)fc->n1 > tb->count_limit) {
                /* still above the limit: halved again after the next level */
                fc->listed = (uint8_t)(tag + 1);
                if (idlist_push(&w->carry, w->list.v[i], e) < 0) return -1;
            }
        }
    }
    { IdList tmp = w->list; w->list = w->carry; w->carry = tmp; }
    return 0;
}

/* The next phase of blocks over the walk's level buffers (PHASE_BUILD or PHASE_ROWS): the
 * description with the buffers filled in, or NULL when out of memory. */
static Phase *walk_phase(const Walk *w, const OctTables *tb, Helper *h, int kind, int64_t items)
{
    Phase *ph = phase_next(h, kind, items, BUILD_BLOCK);
    if (!ph) return NULL;
    ph->tb = tb;
    ph->occ = w->occ;
    ph->nbr = w->nbr;
    ph->start = w->start;
    ph->codes = w->codes;
    ph->ncodes = w->ncodes;
    ph->nnbr = w->nnbr;
    ph->prow = w->prow;
    return ph;
}

/* The next level: children in Morton order (node-major, child index ascending); start[i] =
 * (index of node i's first child) << 8 | occupancy of node i (start[n] = 0: the absent node
 * has no children), one load per neighbour when building the rows.  *n becomes its size. */
static int walk_next_level(Walk *w, const OctTables *tb, Helper *h, int level, int depth,
                           int64_t num_points, const DirectIn *di, const int32_t *keep,
                           int64_t nkeep, int64_t *n, Err *e)
{
    const int64_t nd = w->npts;
    const int64_t nn = *n;
    int64_t total = 0;
    if (ensure((void **)&w->start, &w->cap_start, ((size_t)nn + 1) * sizeof *w->start, e) < 0)
        return -1;
    for (int64_t i = 0; i < nn; i++) {
        w->start[i] = (total << 8) | w->occ[i];
        total += popcount8(w->occ[i]);          /* popcount8 looks at bits 0..7 only */
    }
    w->start[nn] = 0;
    if (total + nd > num_points) {
        if (nd)
            snprintf(e->msg, sizeof e->msg, "octree level %d decodes to %lld nodes and %lld direct "
                     "points, more than the %lld points declared", level + 1, (long long)total,
                     (long long)nd, (long long)num_points);
        else
            snprintf(e->msg, sizeof e->msg, "octree level %d decodes to %lld nodes, more than the "
                     "%lld points declared", level + 1, (long long)total, (long long)num_points);
        e->failed = ERR_FORMAT;
        return -1;
    }
    const int last = (level + 1 == depth);
    /* from the direct level on, a level's rows are made once its direct flags are known, for
     * the nodes left in the tree only (walk_level): here only each child's parent row */
    const int ranks = di->from && level + 1 >= di->from;
    if (ensure((void **)&w->ncodes, &w->cap_ncodes, (size_t)total * sizeof *w->ncodes + 8, e) < 0)
        return -1;
    if (!last && !ranks && ensure((void **)&w->nnbr, &w->cap_nnbr,
                                  (size_t)total * NUM_T * sizeof *w->nnbr + 4, e) < 0)
        return -1;
    if (!last && ranks && ensure((void **)&w->prow, &w->cap_prow, (size_t)total * sizeof *w->prow + 4, e) < 0)
        return -1;
    Phase *ph = walk_phase(w, tb, h, PHASE_BUILD, ranks && keep ? nkeep : nn);
    if (!ph) return fail_nomem(e);
    ph->keep = keep;
    ph->ranks = ranks;
    ph->total = total;
    ph->last = last;
    phase_publish(h);
    phase_finish(h, 1);
    { uint64_t *t = w->codes; w->codes = w->ncodes; w->ncodes = t; }
    { size_t ct = w->cap_codes; w->cap_codes = w->cap_ncodes; w->cap_ncodes = ct; }
    if (!last && !ranks) {
        int32_t *t = w->nbr; w->nbr = w->nnbr; w->nnbr = t;
        size_t ct = w->cap_nbr; w->cap_nbr = w->cap_nnbr; w->cap_nnbr = ct;
    }
    *n = total;
    return 0;
}

/* The direct flags of a level of nn nodes (OCTREE.md §4.1), then the direct nodes' remaining
 * bits (raw section, or the encoder's values): their points go to w->pts, their one child is
 * known (occ, pbit), dmark[i] = 1.  w->keep lists the nodes left in the tree; *nkeep = -1 when
 * none went direct. */
static int walk_direct(Walk *w, const OctTables *tb, int level, int depth, int lb, int64_t nn,
                       int mode, BinDec *dec, DirectIn *di, SymOut *out, uint8_t *dmark,
                       int64_t *nkeep, Err *e)
{
    const int first = level == di->from;
    int32_t *coded = w->coded, *ctx = w->fixa;
    const uint8_t *kf = NULL;
    if (mode == 1) {
        if (di->kflags_off + nn > di->kflags_len)
            return fail(e, "octree encoder: direct flags do not match the traversal");
        kf = di->kflags + di->kflags_off;
        di->kflags_off += nn;
    }
    memset(dmark, 0, (size_t)nn);
    int64_t cnt = 0;
    for (int64_t i = 0; i < nn; i++) {
        const int pp = w->par_pop[i];
        if (!first && pp <= 1) continue;       /* holds what its parent held: two voxels or more */
        /* its present 26-neighbours: the children of its parent's octant (parent level: rows
         * w->nbr, occupancy in the low byte of w->start) that neighbour child k */
        const int k = (int)(w->codes[i] & 7);
        const int32_t *pnb = w->nbr + (int64_t)w->prow[i] * NUM_T;
        const uint8_t *mk = tb->nmask[k];
        int present = 0;
        for (int q = 0; q < tb->nno[k]; q++) {
            const int o = tb->nto[k][q];
            present += POP8[(unsigned)(w->start[pnb[o]] & 0xFF) & mk[o]];
        }
        coded[cnt] = (int32_t)i;
        ctx[cnt++] = ((present < 7 ? present : 7) * 4 + (pp < 4 ? pp : 4) - 1) * NUM_LB + lb;
    }
    uint8_t *mbuf = w->mbuf;
    for (int64_t s = 0; s < cnt;) {
        int64_t step = s > tb->chunk_min ? s : tb->chunk_min;
        if (step > tb->chunk_max) step = tb->chunk_max;
        const int64_t end = s + step < cnt ? s + step : cnt;
        for (int64_t j = s; j < end; j++) {        /* models from the counts before the chunk */
            const uint64_t c0 = w->dcnt[2 * ctx[j]], c1 = w->dcnt[2 * ctx[j] + 1];
            mbuf[j - s] = tb->p16m[((2 * c1 + 1) << 16) / (2 * (c0 + c1) + 2)];
        }
        for (int64_t j = s; j < end; j++) {
            int bit;
            if (mode == 0) {
                bit = oct_bin_decode(dec, tb, mbuf[j - s], e);
                if (bit < 0) return -1;
            } else {
                bit = kf[coded[j]] & 1;
                out->bits[out->len] = (uint8_t)bit;
                out->models[out->len] = mbuf[j - s];
                out->len++;
            }
            dmark[coded[j]] = (uint8_t)bit;
        }
        for (int64_t j = s; j < end; j++) w->dcnt[2 * ctx[j] + dmark[coded[j]]]++;
        s = end;
    }
    for (int c = 0; c < NUM_DIRECT; c++) {
        const uint32_t a = w->dcnt[2 * c], b = w->dcnt[2 * c + 1];
        if ((int64_t)a + (int64_t)b > tb->count_limit) {
            w->dcnt[2 * c] = (a + 1) >> 1;
            w->dcnt[2 * c + 1] = (b + 1) >> 1;
        }
    }
    int64_t nd = 0;
    for (int64_t i = 0; i < nn; i++) nd += dmark[i];
    *nkeep = -1;
    if (!nd) return 0;
    const int wb = 3 * (depth - level);
    const int64_t nbytes = (nd * wb + 7) / 8;
    const uint8_t *src = NULL;
    if (mode == 0) {
        if (nbytes > di->raw_len - di->raw_pos) {
            snprintf(e->msg, sizeof e->msg, "octree payload: the direct points of level %d need %lld "
                     "bytes, %lld left in the raw section", level, (long long)nbytes,
                     (long long)(di->raw_len - di->raw_pos));
            e->failed = ERR_FORMAT;
            return -1;
        }
        src = di->raw + di->raw_pos;
        const int used = (int)((nd * wb) & 7);
        if (used && (src[nbytes - 1] >> used)) {
            snprintf(e->msg, sizeof e->msg, "octree payload: non-zero padding after the direct "
                     "points of level %d", level);
            e->failed = ERR_FORMAT;
            return -1;
        }
        di->raw_pos += nbytes;
    } else if (di->kvals_off + nd > di->kvals_len) {
        return fail(e, "octree encoder: direct values do not match the traversal");
    }
    if ((size_t)(w->npts + nd) > w->cap_pts) {     /* grows, keeping the earlier levels' points */
        size_t cap = w->cap_pts ? 2 * w->cap_pts : 4096;
        while (cap < (size_t)(w->npts + nd)) cap *= 2;
        uint64_t *q = realloc(w->pts, cap * sizeof *q);
        if (!q) return fail_nomem(e);
        w->pts = q;
        w->cap_pts = cap;
    }
    if (ensure((void **)&w->keep, &w->cap_keep, (size_t)nn * sizeof *w->keep, e) < 0) return -1;
    int64_t p = 0, kept = 0;
    for (int64_t i = 0; i < nn; i++) {
        if (!dmark[i]) { w->keep[kept++] = (int32_t)i; continue; }
        uint64_t v = 0;
        if (mode == 0)
            for (int b = 0; b < wb; b++, p++) v |= (uint64_t)((src[p >> 3] >> (p & 7)) & 1) << b;
        else
            v = di->kvals[di->kvals_off++];
        const unsigned child = (unsigned)(v >> (wb - 3)) & 7u;
        w->pts[w->npts++] = (w->codes[i] << wb) | v;
        w->occ[i] = (uint8_t)(0x80 | ((1u << child) & 0x7Fu));
        w->pbit[i] = (uint8_t)(child == 7);
    }
    *nkeep = kept;
    return 0;
}

/* One level's bit-planes (after its direct flags, from level di->from on), then its halving
 * and the next level's nodes. */
static int walk_level(Walk *w, const OctTables *tb, int level, int depth, int64_t num_points,
                      int mode, BinDec *dec, const uint8_t *kn, DirectIn *di, SymOut *out,
                      Helper *h, int64_t *n, Err *e)
{
    const int64_t nn = *n;
    const int lb = (depth - 1 - level) < (NUM_LB - 1) ? (depth - 1 - level) : (NUM_LB - 1);
    const uint8_t tag = (uint8_t)(level + 1);
    if (ensure((void **)&w->occ, &w->cap_occ, (size_t)nn + 1, e) < 0
        || ensure((void **)&w->pbit, &w->cap_pbit, (size_t)nn, e) < 0
        || ensure((void **)&w->coded, &w->cap_coded, (size_t)nn * sizeof *w->coded, e) < 0
        || ensure((void **)&w->fixa, &w->cap_fix, (size_t)nn * sizeof *w->fixa, e) < 0)
        return -1;
    memset(w->occ, 0x80, (size_t)nn);            /* present, no child known yet */
    w->occ[nn] = 0;                              /* the absent neighbour */
    int64_t nkeep = -1;
    uint8_t *dmark = NULL;
    if (di->from && level >= di->from) {
        if (ensure((void **)&w->dmark, &w->cap_dmark, (size_t)nn + 1, e) < 0
            || ensure((void **)&w->crow, &w->cap_crow, (size_t)nn * sizeof *w->crow + 4, e) < 0)
            return -1;
        dmark = w->dmark;
        if (walk_direct(w, tb, level, depth, lb, nn, mode, dec, di, out, dmark, &nkeep, e) < 0)
            return -1;
        /* the rows of the nodes left in the tree (row j: node keep[j]), from their parents'
         * (w->nbr, w->start and w->prow still describe the parent level); a direct node's row
         * would never be read, and the first direct levels hold mostly direct nodes */
        const int64_t rows = nkeep >= 0 ? nkeep : nn;
        if (ensure((void **)&w->nnbr, &w->cap_nnbr, (size_t)rows * NUM_T * sizeof *w->nnbr + 4, e) < 0)
            return -1;
        Phase *ph = walk_phase(w, tb, h, PHASE_ROWS, rows);
        if (!ph) return fail_nomem(e);
        ph->keep = nkeep >= 0 ? w->keep : NULL;
        ph->total = nn;
        phase_publish(h);
        phase_finish(h, 1);
        int32_t *t = w->nbr; w->nbr = w->nnbr; w->nnbr = t;
        size_t ct = w->cap_nbr; w->cap_nbr = w->cap_nnbr; w->cap_nnbr = ct;
    }
    const int32_t *keep = nkeep >= 0 ? w->keep : NULL;
    for (int k = 0; k < 8; k++)
        if (walk_plane(w, tb, nn, keep, nkeep, k, lb, tag, mode, dec, kn, out, h, e) < 0) return -1;
    for (int64_t i = 0; i < nn; i++)
        w->occ[i] = (uint8_t)((w->occ[i] & 0x7F) | (w->pbit[i] << 7));
    if (keep)       /* a direct node has no children in the tree */
        for (int64_t i = 0; i < nn; i++) if (dmark[i]) w->occ[i] = 0;
    if (walk_halve(w, tb, tag, e) < 0) return -1;
    return walk_next_level(w, tb, h, level, depth, num_points, di, keep, nkeep, n, e);
}

/* par_pop of the level just built: each node's parent's child count. */
static int walk_par_pop(Walk *w, int64_t parents, int64_t n, Err *e)
{
    if (ensure((void **)&w->par_pop, &w->cap_pop, (size_t)n + 1, e) < 0) return -1;
    int64_t c = 0;
    for (int64_t r = 0; r < parents; r++) {
        const int pc = popcount8((unsigned)(w->start[r] & 0xFF));
        for (int j = 0; j < pc; j++) w->par_pop[c++] = (uint8_t)pc;
    }
    return c == n ? 0 : fail(e, "octree: child count mismatch");
}

/* Merge the ascending runs a[0..na) and b[0..nb) into out. */
static void merge_codes(const uint64_t *a, int64_t na, const uint64_t *b, int64_t nb, uint64_t *out)
{
    int64_t i = 0, j = 0, o = 0;
    while (i < na && j < nb) out[o++] = a[i] < b[j] ? a[i++] : b[j++];
    while (i < na) out[o++] = a[i++];
    while (j < nb) out[o++] = b[j++];
}

/*
 * The normative traversal (decoder/octree.py::walk_octree).  mode 0: bits from `dec`; mode 1:
 * bits from the known occupancy bytes `known` (levels concatenated, level l holding
 * known_sizes[l] nodes), recorded into `out`.  On success *codes_out holds the leaf Morton codes
 * (ascending) and *count_out their number (== num_points).  `h`: the phase state (a helper may
 * be attached to it, see above).
 *
 * Representation: the nodes of a level are 0..n-1 in Morton order; nbr[27 * i + t] is the
 * index of node i's neighbour at offset t, or n when there is none -- occ[n] is a permanent 0
 * byte, so an absent neighbour reads as an empty node without a branch.  (An offset-major
 * layout, 27 planes of n entries, so that a bit-plane would read only its octant's 8 planes,
 * was 40 % slower: the next level's rows then gather from 27 pages per parent.)
 *
 * Halving (after each level, every context with n0 + n1 > COUNT_LIMIT) looks only at the fine
 * contexts that can exceed the limit: those used during the level, and those that still
 * exceeded it after the previous halving.  Both are kept in a list, each context once.
 */
int oct_walk(const OctTables *tb, int depth, int64_t num_points, int mode, BinDec *dec,
             const uint8_t *known, const int64_t *known_sizes, int64_t known_len, DirectIn *di,
             SymOut *out, Helper *h, uint64_t **codes_out, int64_t *count_out, Err *e)
{
    int64_t level_start[24] = {0};   /* where each level's direct points begin in w.pts */
    int rc = -1;
    Walk w;
    memset(&w, 0, sizeof w);
    int64_t n = 1, known_off = 0;
    *codes_out = NULL;
    *count_out = 0;
    if (depth < 1 || depth > 21) { fail(e, "octree depth outside [1, 21]"); goto done; }
    if (tb->chunk_max > MAX_CHUNK || tb->chunk_min < 1 || tb->chunk_min > tb->chunk_max) {
        fail(e, "octree: unsupported chunk schedule");
        goto done;
    }
    if (num_points == 0) { rc = 0; goto done; }
    if (num_points < 0 || num_points > OCT_MAX_POINTS) {
        fail(e, "octree point count outside the native decoder's range");
        goto done;
    }
    if (di->from && (di->from < 1 || di->from >= depth)) { fail(e, "octree: direct level out of range"); goto done; }
    if (walk_init(&w, tb, e) < 0) goto done;
    int levels = 0;
    for (int level = 0; level < depth && n > 0; level++) {
        const uint8_t *kn = NULL;
        if (mode == 1) {
            if (known_sizes[level] != n || known_off + n > known_len) {
                fail(e, "octree encoder: occupancy levels do not match the traversal");
                goto done;
            }
            kn = known + known_off;
            known_off += n;
            if (symout_reserve(out, 9 * n, e) < 0) goto done;
        }
        level_start[level] = w.npts;
        const int64_t parents = n;
        if (walk_level(&w, tb, level, depth, num_points, mode, dec, kn, di, out, h, &n, e) < 0)
            goto done;
        levels = level + 1;
        if (di->from && level + 1 >= di->from && level + 1 < depth && walk_par_pop(&w, parents, n, e) < 0)
            goto done;
    }
    if (n + w.npts != num_points) {
        snprintf(e->msg, sizeof e->msg, "octree decodes to %lld points, header declares %lld",
                 (long long)(n + w.npts), (long long)num_points);
        e->failed = ERR_FORMAT;
        goto done;
    }
    if (w.npts) {
        /* the tree's leaves and each level's direct points are ascending runs: merged */
        uint64_t *a = malloc((size_t)num_points * sizeof *a), *b = malloc((size_t)num_points * sizeof *b);
        if (!a || !b) { free(a); free(b); fail_nomem(e); goto done; }
        memcpy(a, w.codes, (size_t)n * sizeof *a);
        int64_t na = n;
        level_start[levels] = w.npts;
        for (int l = 0; l < levels; l++) {
            const int64_t g = level_start[l + 1] - level_start[l];
            if (!g) continue;
            merge_codes(a, na, w.pts + level_start[l], g, b);
            na += g;
            uint64_t *t = a; a = b; b = t;
        }
        free(b);
        free(w.codes);
        w.codes = a;
    }
    *codes_out = w.codes;
    w.codes = NULL;
    *count_out = num_points;
    rc = 0;
done:
    phase_close(h);
    walk_free(&w);
    return rc;
}

/* Context ranges and derived tables of one octant k (see oct_tables_build). */
static int oct_tables_octant(OctTables *tb, const OctTableArgs *a, int k, Err *e)
{
    const int64_t *pk = a->plan_known, *pu = a->plan_unknown, *cp = a->child_par, *ci = a->child_idx;
    tb->nt[k] = 0;
    for (int t = 0; t < NUM_T; t++) {
        int64_t kf = pk[(0 * 8 + k) * 27 + t], ko = pk[(1 * 8 + k) * 27 + t];
        int64_t uf = pu[(0 * 8 + k) * 27 + t], uo = pu[(1 * 8 + k) * 27 + t];
        int64_t par = cp[k * 27 + t], idx = ci[k * 27 + t];
        if (kf < 0 || kf > 255 || ko < 0 || ko > 255 || uf < 0 || uf > 8 || uo < 0 || uo > 8
            || par < 0 || par >= NUM_T || idx < 0 || idx > 7)
            return fail_value(e, "octree plan table out of range");
        tb->kmask_f[k][t] = (unsigned)kf;
        tb->kmask_o[k][t] = (unsigned)ko;
        tb->ucnt_f[k][t] = (int)uf;
        tb->ucnt_o[k][t] = (int)uo;
        tb->child_par[k][t] = (int)par;
        tb->child_idx[k][t] = (int)idx;
        tb->cp8[k][t] = (uint8_t)par;
        tb->ci8[k][t] = (uint8_t)idx;
        if (kf | ko | uf | uo) tb->t[k][tb->nt[k]++] = t;
    }
    memset(tb->nmask[k], 0, sizeof tb->nmask[k]);
    tb->nno[k] = 0;
    for (int t = 0; t < NUM_T; t++) {
        if (t == SELF_T) continue;
        const int o = tb->cp8[k][t];
        if (!tb->nmask[k][o]) {
            if (tb->nno[k] == 8) return fail_value(e, "octree plan: a child's neighbours span more than 8 nodes");
            tb->nto[k][tb->nno[k]++] = (uint8_t)o;
        }
        tb->nmask[k][o] |= (uint8_t)(1u << tb->ci8[k][t]);
    }
    /* the context ranges (kn_f + unk_f <= 6, kn_o + unk_o <= 20) hold for every occupancy,
     * so the count arrays are never indexed out of range */
    int sf = 0, so = 0;
    for (int t = 0; t < NUM_T; t++) {
        sf += popcount8(tb->kmask_f[k][t]) + tb->ucnt_f[k][t];
        so += popcount8(tb->kmask_o[k][t]) + tb->ucnt_o[k][t];
    }
    unsigned bits7 = 0;
    for (int t = 0; t < NUM_T; t++) bits7 |= tb->kmask_f[k][t] | tb->kmask_o[k][t];
    if (sf > 6 || so > 20 || tb->nt[k] > 8 || (bits7 & 0x80))
        return fail_value(e, "octree plan table exceeds the context ranges");
    return 0;
}

/* ctx_lut: per octant k and octant node q, the context contribution of every context byte. */
static void oct_ctx_lut(OctTables *tb)
{
    /* pad every octant list to 8 entries: the node itself with an all-zero LUT block */
    for (int k = 0; k < 8; k++)
        for (int q = tb->nt[k]; q < 8; q++) tb->t[k][q] = SELF_T;
    for (int k = 0; k < 8; k++)
        for (int q = 0; q < tb->nt[k]; q++) {
            const int t = tb->t[k][q];
            for (unsigned w = 0; w < 256; w++) {
                const int present = (w >> 7) & 1;
                const unsigned kf = (unsigned)popcount8(w & tb->kmask_f[k][t]);
                const unsigned ko = (unsigned)popcount8(w & tb->kmask_o[k][t]);
                const unsigned uf = (unsigned)(present * tb->ucnt_f[k][t]);
                const unsigned uo = (unsigned)(present * tb->ucnt_o[k][t]);
                const unsigned fine = kf * (7 * 21 * 21) + uf * (21 * 21) + ko * 21 + uo;
                const unsigned coarse = (kf + ko) * 27 + uf + uo;
                tb->ctx_lut[(k * 8 + q) * 256 + w] = fine | (coarse << 16);
            }
        }
}

int oct_tables_build(OctTables *tb, const OctTableArgs *a, Err *e)
{
    tb->ctx_lut = NULL;
    tb->p16m = NULL;
    tb->p16_to_model = a->p16;
    tb->freq0 = a->freq0;
    tb->num_models = (int)a->num_models;
    tb->prec = a->prec;
    tb->chunk_min = a->chunk_min;
    tb->chunk_max = a->chunk_max;
    tb->count_limit = a->count_limit;
    tb->mix_weight = a->mix_weight;
    if (a->prec < 1 || a->prec > 16 || tb->num_models < 1 || tb->num_models > 256
        || a->mix_weight < 1)
        return fail_value(e, "octree bank parameters out of range");
    for (int m = 0; m < tb->num_models; m++)
        if (tb->freq0[m] < 1 || tb->freq0[m] >= ((int64_t)1 << a->prec))
            return fail_value(e, "octree bank frequency out of range");
    for (int k = 0; k < 8; k++)
        if (oct_tables_octant(tb, a, k, e) < 0) return -1;
    tb->ctx_lut = calloc(8 * 8 * 256, sizeof *tb->ctx_lut);
    if (!tb->ctx_lut) return fail_nomem(e);
    oct_ctx_lut(tb);
    tb->p16m = malloc(65536);
    if (!tb->p16m) return fail_nomem(e);
    for (int i = 0; i < 65536; i++) {
        if (tb->p16_to_model[i] < 0 || tb->p16_to_model[i] >= tb->num_models)
            return fail_value(e, "P16_TO_MODEL entry out of range");
        tb->p16m[i] = (uint8_t)tb->p16_to_model[i];
    }
    return 0;
}

void oct_tables_free(OctTables *tb)
{
    free(tb->ctx_lut);
    tb->ctx_lut = NULL;
    free(tb->p16m);
    tb->p16m = NULL;
}
