/*
 * gsz.decoder._native -- optional C accelerator of the reference decoder (and of the octree
 * encoder's traversal).
 *
 * The NumPy modules stay the normative reference (format_spec/OCTREE.md, ENTROPY.md,
 * TRANSFORMS.md); this file implements exactly the same integer arithmetic, scalar instead of
 * vectorised, and must give bit-identical results (tests/test_native.py compares both paths).
 * Every table that defines the format (binary model bank frequencies, P16_TO_MODEL, the
 * neighbourhood plans) is computed in Python and passed in, so there is one source of truth.
 *
 * Security: the input bitstream is untrusted.  Python validates every header value before it
 * calls in (the same checks as the NumPy path); this code still bounds-checks every index and
 * count it reads, allocates only in proportion to data actually decoded (never to a declared
 * count), and reports every failure as gsz.decoder.errors.GszFormatError (MemoryError when an
 * allocation fails).  Hot loops run without the GIL.
 *
 * Only the CPython C API and the buffer protocol are used (no NumPy headers).  Compile without
 * floating-point contraction (-ffp-contract=off, see setup.py): the inverse RAHT must round
 * exactly like NumPy's separate multiply and add.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif

/* Bumped whenever a signature changes, so a stale build is ignored (decoder/native.py). */
#define GSZ_NATIVE_ABI 7

static PyObject *FormatError = NULL;   /* gsz.decoder.errors.GszFormatError */

/* ------------------------------------------------------------------ errors without the GIL */
typedef struct {
    int failed;      /* 0 ok, 1 format error, 2 out of memory */
    char msg[240];
} Err;

static int fail(Err *e, const char *msg)
{
    if (!e->failed) {
        e->failed = 1;
        snprintf(e->msg, sizeof e->msg, "%s", msg);
    }
    return -1;
}

static int fail_nomem(Err *e)
{
    if (!e->failed) e->failed = 2;
    return -1;
}

static PyObject *raise_err(const Err *e)
{
    if (e->failed == 2) return PyErr_NoMemory();
    PyErr_SetString(FormatError ? FormatError : PyExc_ValueError, e->msg);
    return NULL;
}

/* ------------------------------------------------------------------ buffers */
/* Kind of a buffer's element: 'i' signed int, 'u' unsigned int, 'f' float (from its format). */
static char fmt_kind(const Py_buffer *v)
{
    const char *f = v->format ? v->format : "B";
    char c = f[strlen(f) - 1];
    switch (c) {
    case 'b': case 'h': case 'i': case 'l': case 'q': case 'n': return 'i';
    case 'B': case 'H': case 'I': case 'L': case 'Q': case 'N': case 'c': case '?': return 'u';
    case 'f': case 'd': case 'e': return 'f';
    default: return '?';
    }
}

/* Acquire a C-contiguous buffer of `itemsize`-byte elements of kind `kind` ('i', 'u', 'f', or
 * 'x' = signed or unsigned integer).  Wrong types are programming errors (TypeError). */
static int getbuf(PyObject *o, Py_buffer *v, Py_ssize_t itemsize, char kind, int writable,
                  const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(o, v, flags) < 0) return -1;
    char k = fmt_kind(v);
    int kind_ok = (kind == 'x') ? (k == 'i' || k == 'u') : (k == kind);
    if (v->itemsize != itemsize || !kind_ok) {
        PyErr_Format(PyExc_TypeError, "%s: expected a contiguous buffer of %zd-byte %s elements",
                     what, itemsize, kind == 'f' ? "float" : "integer");
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

/* malloc for large work buffers (free() releases it).  On Linux, blocks of 4 MB and more are
 * 2 MB aligned and marked for transparent huge pages: the traversal's tables are written once
 * and streamed over, and on the project's VM faulting them in 4 kB pages cost ~20 % of the
 * geometry decode (0.185 s -> 0.152 s on the flowers scene). */
static void *big_alloc(size_t size)
{
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (size >= ((size_t)4 << 20)) {
        void *q = NULL;
        if (posix_memalign(&q, (size_t)2 << 20, size) != 0) return NULL;
        madvise(q, size, MADV_HUGEPAGE);        /* advisory: failure changes nothing */
        return q;
    }
#endif
    return malloc(size ? size : 1);
}

static inline uint32_t rd_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static inline uint32_t rd_u16(const uint8_t *p) { return (uint32_t)p[0] | ((uint32_t)p[1] << 8); }

/* bit counts of a byte (a table: portable, and faster than a popcount call on CPUs where the
 * compiler may not assume the POPCNT instruction) */
static const uint8_t POP8[256] = {
#define B2(n) n, n + 1, n + 1, n + 2
#define B4(n) B2(n), B2(n + 1), B2(n + 1), B2(n + 2)
#define B6(n) B4(n), B4(n + 1), B4(n + 1), B4(n + 2)
    B6(0), B6(1), B6(1), B6(2)
#undef B2
#undef B4
#undef B6
};

static inline int popcount8(unsigned v) { return POP8[v & 0xFFu]; }

/* CHILD_RANK[v * 8 + j]: the rank of child j among the children present in occupancy v (the
 * bits below j), or 2^30 (more than any node count) when child j is absent */
static int32_t CHILD_RANK[256 * 8];

static void child_rank_init(void)
{
    for (unsigned v = 0; v < 256; v++)
        for (unsigned j = 0; j < 8; j++)
            CHILD_RANK[v * 8 + j] = ((v >> j) & 1u) ? popcount8(v & ((1u << j) - 1u)) : (1 << 30);
}

/* ================================================================== octree (OCTREE.md §4) */
#define NUM_T 27
#define SELF_T 13
#define NUM_SIB 4
#define NUM_LB 4
#define NUM_COARSE (8 * 27 * 27 * NUM_SIB)
#define NUM_FINE (8 * 7 * 7 * 21 * 21 * NUM_SIB * NUM_LB)
#define MAX_CHUNK 65536

typedef struct {
    /* per child k: the parent-level offsets t whose node holds 26-neighbours of child k */
    int nt[8];
    int t[8][NUM_T];
    unsigned kmask_f[8][NUM_T], kmask_o[8][NUM_T];   /* known neighbour bits (< k), face / other */
    int ucnt_f[8][NUM_T], ucnt_o[8][NUM_T];          /* unknown neighbours (>= k) in that node */
    int child_par[8][NUM_T], child_idx[8][NUM_T];    /* neighbour table derivation */
    uint8_t cp8[8][NUM_T], ci8[8][NUM_T];            /* the same as bytes */
    uint8_t *p16m;                                   /* [65536] P16_TO_MODEL as bytes */
    /* ctx_lut[(k * 8 + q) * 256 + w]: contribution of the q-th node of child k's octant, whose
     * context byte is w (bit 7 = node present, bits 0..6 = child bits decoded so far; child 7
     * is never a known neighbour bit, k <= 7),
     * to the context: fine part  kn_f*3087 + unk_f*441 + kn_o*21 + unk_o  in bits 0..15 and
     * coarse part  (kn_f + kn_o)*27 + unk_f + unk_o  in bits 16..31.  Both context ids are linear
     * in the four counts (OCTREE.md §4), so summing the contributions gives them directly. */
    uint32_t *ctx_lut;
    int64_t chunk_min, chunk_max, count_limit, mix_weight;
    const int64_t *p16_to_model;                     /* [65536] */
    const int64_t *freq0;                            /* [num_models] frequency of a 0 */
    int num_models;
    int prec;                                        /* bank precision n */
} OctTables;

/* Binary rANS decoder over the bank models (ENTROPY.md §4.3 specialised to two symbols: value
 * 0 owns slots [0, f0), value 1 slots [f0, 2^n)). */
typedef struct {
    uint64_t *st;
    int64_t lanes, lane;
    const uint8_t *words;
    int64_t nwords, wpos;
    int64_t nsym, pos;
} BinDec;

static inline int bin_decode(BinDec *d, const OctTables *tb, int64_t model, Err *e)
{
    if (d->pos >= d->nsym) return fail(e, "octree payload: more binary decisions needed than the "
                                          "declared symbol count");
    uint64_t x = d->st[d->lane];
    const unsigned n = (unsigned)tb->prec;
    const uint64_t total = (uint64_t)1 << n;
    const uint64_t z = x & (total - 1);
    const uint64_t f0 = (uint64_t)tb->freq0[model];
    /* branch-free: the decoded bits are close to random for the branch predictor */
    const int bit = z >= f0;
    const uint64_t f = bit ? total - f0 : f0, c = bit ? f0 : 0;
    x = f * (x >> n) + (z - c);
    /* renormalisation without a branch (taken about every other decision, unpredictably):
     * the next word is read speculatively; a renormalisation past the last word is an error */
    const uint64_t need = x < 65536u;
    if (d->wpos >= d->nwords) {
        if (need) return fail(e, "rANS: payload truncated (word stream exhausted)");
    } else {
        const uint64_t wv = rd_u16(d->words + 2 * d->wpos);
        x = (x << (need << 4)) | (wv & (0 - need));
        d->wpos += (int64_t)need;
    }
    d->st[d->lane] = x;
    if (++d->lane == d->lanes) d->lane = 0;
    d->pos++;
    return bit;
}

/* Growable byte output (encoder mode: the coded bits and their model ids). */
typedef struct {
    uint8_t *bits, *models;
    int64_t len, cap;
} SymOut;

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

/* ------------------------------------------------------------------ helper thread
 * A second thread (the Python caller's, once its own work is done: octree_help) can join a
 * running traversal.  The traversal is split into *phases* of independent blocks that either
 * thread claims with one atomic operation: the context ids of a bit-plane (they depend only on
 * the bits of earlier bit-planes, so the whole bit-plane's can be computed ahead of its
 * decoding) and the next level's neighbour rows.  Without a helper the traversal claims every
 * block itself, in order, just before it needs it (the same work as one fused loop).  Only the
 * decoding, the model cache and the count updates stay on the traversal's thread, so the
 * result does not depend on who computed which block.
 *
 * claim = phase sequence number << 32 | next unclaimed block; a block is claimed by a
 * compare-and-swap that also checks the phase, so a thread holding an older phase's
 * description never claims a block of a newer one.  The descriptions are double-buffered
 * (phase s uses desc[s & 1]); the traversal publishes phase s + 1 only once every block of
 * phase s is done. */
#if !defined(__STDC_NO_ATOMICS__)
#include <stdatomic.h>
#define GSZ_HELPER 1
#if defined(__x86_64__) || defined(__i386__)
#define cpu_relax() __builtin_ia32_pause()
#else
#define cpu_relax() ((void)0)
#endif
#else
#define GSZ_HELPER 0
#endif
#if defined(__unix__) || defined(__APPLE__)
#include <sched.h>
#define yield_cpu() sched_yield()
#else
#define yield_cpu() ((void)0)
#endif

#define CTX_BLOCK 2048      /* nodes per context block */
#define BUILD_BLOCK 1024    /* parents per neighbour-table block */

enum { PHASE_CTX = 1, PHASE_BUILD = 2 };

typedef struct {
    int kind;
    int64_t items, block, nblocks;
    /* PHASE_CTX: fine context ids fix[i] of the cnt nodes of bit-plane k */
    const OctTables *tb;
    const uint8_t *occ;
    const int32_t *nbr;
    const int32_t *coded;        /* k == 7: the coded nodes, else NULL (all nodes) */
    int32_t *fix;
    int k, lb;
    /* PHASE_BUILD: children of parents [r0, r1): codes and neighbour rows */
    const int64_t *start;
    const uint64_t *codes;
    uint64_t *ncodes;
    int32_t *nnbr;
    int64_t total;
    int last;
#if GSZ_HELPER
    _Atomic uint8_t *done;       /* per block */
    _Atomic int64_t ndone;
#endif
} Phase;

typedef struct {
#if GSZ_HELPER
    _Atomic uint64_t claim;
    _Atomic int closed;
#endif
    Phase desc[2];
    uint32_t seq;
    void *done_buf;              /* the done flags of both descriptions */
    size_t done_cap[2];
} Helper;

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
    const int32_t *nbr = p->nbr, *coded = p->coded;
    int32_t *restrict fix = p->fix;
    for (int64_t i = a; i < b; i++) {
        const int64_t node = coded ? coded[i] : i;
        const int32_t *nb = nbr + node * NUM_T;
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
static void helper_loop(Helper *h)
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

static void helper_close(Helper *h)
{
#if GSZ_HELPER
    atomic_store_explicit(&h->closed, 1, memory_order_release);
#else
    (void)h;
#endif
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

static int walk(const OctTables *tb, int depth, int64_t num_points, int mode, BinDec *dec,
                const uint8_t *known, const int64_t *known_sizes, int64_t known_len, SymOut *out,
                Helper *h, uint64_t **codes_out, int64_t *count_out, Err *e)
{
    int rc = -1;
    uint32_t *cc = NULL;
    FineCtx *ff = NULL;
    uint64_t *codes = NULL, *ncodes = NULL;
    int32_t *nbr = NULL, *nnbr = NULL, *coded = NULL, *fixa = NULL;
    int64_t *start = NULL;
    uint8_t *occ = NULL;     /* per node: during the bit-planes 0x80 (present) | child bits
                              * of the finished bit-planes (occ[n] = 0: absent); after them the
                              * occupancy */
    uint8_t *pbit = NULL;    /* the bits of the current bit-plane, merged into occ after it
                              * (child 7: after the level) */
    int64_t n = 1, known_off = 0;
    uint8_t *mbuf = NULL, *bbuf = NULL;        /* models and decoded bits of one chunk */
    uint8_t *ff_touched = NULL;
    uint32_t stamp = 0;
    IdList list = {0}, carry = {0};
    size_t cap_codes = 0, cap_ncodes = 0, cap_nbr = 0, cap_nnbr = 0, cap_occ = 0, cap_coded = 0,
           cap_start = 0, cap_pbit = 0, cap_fix = 0;

    *codes_out = NULL;
    *count_out = 0;
    if (depth < 1 || depth > 21) { fail(e, "octree depth outside [1, 21]"); goto done; }
    if (tb->chunk_max > MAX_CHUNK || tb->chunk_min < 1 || tb->chunk_min > tb->chunk_max) {
        fail(e, "octree: unsupported chunk schedule");
        goto done;
    }
    if (num_points == 0) { rc = 0; goto done; }
    if (num_points < 0 || num_points > INT32_MAX / 2) {
        fail(e, "octree point count outside the native decoder's range");
        goto done;
    }
    cc = calloc(2 * (size_t)NUM_COARSE, sizeof *cc);
    ff = calloc((size_t)NUM_FINE, sizeof *ff);       /* pages are touched only where used */
    /* pages of ff written to so far: the first access to a page must be a write.  A read
     * maps the kernel's shared zero page, and the write after it replaces that mapping, which
     * costs a TLB shootdown (an inter-processor interrupt, expensive in a VM) whenever another
     * thread of the process runs -- measured ~870 per flowers decode, ~10 % of the traversal. */
    const uintptr_t ff_page0 = (uintptr_t)ff >> 12;
    ff_touched = calloc(((size_t)NUM_FINE * sizeof *ff >> 15) + 2, 1);
    if (ensure((void **)&codes, &cap_codes, sizeof *codes, e) < 0
        || ensure((void **)&nbr, &cap_nbr, NUM_T * sizeof *nbr, e) < 0)
        goto done;
    mbuf = malloc((size_t)tb->chunk_max);
    bbuf = malloc((size_t)tb->chunk_max);
    if (!cc || !ff || !ff_touched || !codes || !nbr || !mbuf || !bbuf) { fail_nomem(e); goto done; }
    codes[0] = 0;
    for (int t = 0; t < NUM_T; t++) nbr[t] = 1;      /* n = 1: absent */
    nbr[SELF_T] = 0;

    for (int level = 0; level < depth; level++) {
        const int lb = (depth - 1 - level) < (NUM_LB - 1) ? (depth - 1 - level) : (NUM_LB - 1);
        const uint8_t tag = (uint8_t)(level + 1);
        const uint8_t *kn = NULL;
        if (mode == 1) {
            if (known_sizes[level] != n || known_off + n > known_len) {
                fail(e, "octree encoder: occupancy levels do not match the traversal");
                goto done;
            }
            kn = known + known_off;
            known_off += n;
            if (symout_reserve(out, 8 * n, e) < 0) goto done;
        }
        if (ensure((void **)&occ, &cap_occ, (size_t)n + 1, e) < 0
            || ensure((void **)&pbit, &cap_pbit, (size_t)n, e) < 0
            || ensure((void **)&coded, &cap_coded, (size_t)n * sizeof *coded, e) < 0
            || ensure((void **)&fixa, &cap_fix, (size_t)n * sizeof *fixa, e) < 0)
            goto done;
        memset(occ, 0x80, (size_t)n);                /* present, no child known yet */
        occ[n] = 0;                                  /* the absent neighbour */
        for (int k = 0; k < 8; k++) {
            int64_t cnt = n;
            if (k == 7) {
                /* a node with no child among 0..6 has child 7 for free (not coded) */
                cnt = 0;
                for (int64_t i = 0; i < n; i++) {
                    if (occ[i] & 0x7F) { coded[cnt++] = (int32_t)i; pbit[i] = 0; }
                    else pbit[i] = 1;
                }
            }
            /* the bit-plane's context ids, as blocks (computed ahead by a helper, if any) */
            Phase *ph = phase_next(h, PHASE_CTX, cnt, CTX_BLOCK);
            if (!ph) { fail_nomem(e); goto done; }
            ph->tb = tb;
            ph->occ = occ;
            ph->nbr = nbr;
            ph->coded = k == 7 ? coded : NULL;
            ph->fix = fixa;
            ph->k = k;
            ph->lb = lb;
            phase_publish(h);
            const int32_t coarse_k = k * (27 * 27), fine_k = k * (7 * 7 * 21 * 21);
            const int32_t fine_lb = lb * (NUM_FINE / NUM_LB);
            int64_t s = 0, ready = 0;
            while (s < cnt) {
                int64_t step = s > tb->chunk_min ? s : tb->chunk_min;
                if (step > tb->chunk_max) step = tb->chunk_max;
                const int64_t end = s + step < cnt ? s + step : cnt;
                while (ready < end) {
                    phase_need(h, ready / CTX_BLOCK);
                    ready = (ready / CTX_BLOCK + 1) * CTX_BLOCK;
                }
                /* models of the chunk, all from the counts before the chunk */
                stamp++;
                for (int64_t i = s; i < end; i++) {
                    const int32_t fix = fixa[i];
                    FineCtx *fc = ff + fix;
                    const uintptr_t pg = ((uintptr_t)fc >> 12) - ff_page0;
                    if (!(ff_touched[pg >> 3] & (1u << (pg & 7)))) {
                        ff_touched[pg >> 3] |= (uint8_t)(1u << (pg & 7));
                        *(volatile uint8_t *)fc = 0;    /* the page's first access: a write */
                    }
                    if (fc->stamp != stamp) {
                        /* the model is a function of the fine context (which fixes the coarse
                         * one) and of the counts, which are frozen during a chunk: computed
                         * once per chunk and context */
                        const int32_t u = (fix - fine_lb) >> 2;
                        const int32_t cix = (coarse_k + FINE_TO_COARSE[u - fine_k]) * NUM_SIB
                                            + (fix & (NUM_SIB - 1));
                        const uint64_t c0 = cc[2 * cix], c1 = cc[2 * cix + 1];
                        const uint64_t pc = ((2 * c1 + 1) << 16) / (2 * (c0 + c1) + 2);
                        const uint64_t f0 = fc->n0, f1 = fc->n1;
                        const uint64_t mw = (uint64_t)tb->mix_weight;
                        const uint64_t pf = ((f1 << 16) + mw * pc) / (f0 + f1 + mw);
                        if (pf > 65535) { fail(e, "octree: probability out of range"); goto done; }
                        fc->model = tb->p16m[pf];    /* < num_models (checked) */
                        fc->stamp = stamp;
                        fc->cix = (uint16_t)cix;
                        if (fc->listed != tag) {
                            fc->listed = tag;
                            if (idlist_push(&list, fix, e) < 0) goto done;
                        }
                    }
                    mbuf[i - s] = fc->model;
                }
                /* the chunk's bits, then the count updates */
                const int fast = mode == 0 && dec->pos + (end - s) <= dec->nsym
                                 && dec->wpos + (end - s) <= dec->nwords;
                if (fast) {
                    /* enough symbols and words left for the whole chunk (at most one word per
                     * symbol): the same decode step without the per-symbol checks */
                    uint64_t *restrict st = dec->st;
                    const uint8_t *restrict words = dec->words;
                    const unsigned pn = (unsigned)tb->prec;
                    const uint64_t ptot = (uint64_t)1 << pn, pmask = ptot - 1;
                    const int64_t lanes = dec->lanes;
                    int64_t lane = dec->lane, w = dec->wpos;
                    for (int64_t i = s; i < end; i++) {
                        uint64_t x = st[lane];
                        const uint64_t z = x & pmask, f0 = (uint64_t)tb->freq0[mbuf[i - s]];
                        const uint64_t bit = z >= f0;
                        const uint64_t f = bit ? ptot - f0 : f0, c = bit ? f0 : 0;
                        x = f * (x >> pn) + (z - c);
                        const uint64_t need = x < 65536u;
                        x = (x << (need << 4)) | (rd_u16(words + 2 * w) & (0 - need));
                        w += (int64_t)need;
                        st[lane] = x;
                        lane = lane + 1 == lanes ? 0 : lane + 1;
                        bbuf[i - s] = (uint8_t)bit;
                    }
                    dec->lane = lane;
                    dec->wpos = w;
                    dec->pos += end - s;
                }
                for (int64_t i = s; i < end; i++) {
                    const int64_t node = (k == 7) ? coded[i] : i;
                    int bit;
                    if (fast) {
                        bit = bbuf[i - s];
                    } else if (mode == 0) {
                        bit = bin_decode(dec, tb, mbuf[i - s], e);
                        if (bit < 0) goto done;
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
                s = end;
            }
            phase_finish(h, 0);     /* every block was needed (ready >= cnt) */
            if (k < 7)
                for (int64_t i = 0; i < n; i++) occ[i] |= (uint8_t)(pbit[i] << k);
        }
        for (int64_t i = 0; i < n; i++) occ[i] = (uint8_t)((occ[i] & 0x7F) | (pbit[i] << 7));
        /* halving: every coarse pair, and the listed fine contexts */
        for (int64_t i = 0; i < NUM_COARSE; i++) {
            const uint32_t a = cc[2 * i], b = cc[2 * i + 1];
            if ((int64_t)a + (int64_t)b > tb->count_limit) {
                cc[2 * i] = (a + 1) >> 1;
                cc[2 * i + 1] = (b + 1) >> 1;
            }
        }
        carry.len = 0;
        for (int64_t i = 0; i < list.len; i++) {
            FineCtx *fc = ff + list.v[i];
            if ((int64_t)fc->n0 + (int64_t)fc->n1 > tb->count_limit) {
                fc->n0 = (fc->n0 + 1) >> 1;
                fc->n1 = (fc->n1 + 1) >> 1;
                if ((int64_t)fc->n0 + (int64_t)fc->n1 > tb->count_limit) {
                    /* still above the limit: halved again after the next level */
                    fc->listed = (uint8_t)(tag + 1);
                    if (idlist_push(&carry, list.v[i], e) < 0) goto done;
                }
            }
        }
        { IdList tmp = list; list = carry; carry = tmp; }

        /* the next level: children in Morton order (node-major, child index ascending);
         * start[i] = (index of node i's first child) << 8 | occupancy of node i (start[n] = 0:
         * the absent node has no children), one load per neighbour when building the rows */
        int64_t total = 0;
        if (ensure((void **)&start, &cap_start, ((size_t)n + 1) * sizeof *start, e) < 0) goto done;
        for (int64_t i = 0; i < n; i++) {
            start[i] = (total << 8) | occ[i];
            total += popcount8(occ[i]);          /* popcount8 looks at bits 0..7 only */
        }
        start[n] = 0;
        if (total > num_points) {
            snprintf(e->msg, sizeof e->msg, "octree level %d decodes to %lld nodes, more than the "
                     "%lld points declared", level + 1, (long long)total, (long long)num_points);
            e->failed = 1;
            goto done;
        }
        const int last = (level + 1 == depth);
        if (ensure((void **)&ncodes, &cap_ncodes, (size_t)total * sizeof *ncodes + 8, e) < 0)
            goto done;
        if (!last && ensure((void **)&nnbr, &cap_nnbr, (size_t)total * NUM_T * sizeof *nnbr + 4, e) < 0)
            goto done;
        Phase *ph = phase_next(h, PHASE_BUILD, n, BUILD_BLOCK);
        if (!ph) { fail_nomem(e); goto done; }
        ph->tb = tb;
        ph->occ = occ;
        ph->nbr = nbr;
        ph->start = start;
        ph->codes = codes;
        ph->ncodes = ncodes;
        ph->nnbr = nnbr;
        ph->total = total;
        ph->last = last;
        phase_publish(h);
        phase_finish(h, 1);
        { uint64_t *t = codes; codes = ncodes; ncodes = t; size_t ct = cap_codes; cap_codes = cap_ncodes; cap_ncodes = ct; }
        if (!last) { int32_t *t = nbr; nbr = nnbr; nnbr = t; size_t ct = cap_nbr; cap_nbr = cap_nnbr; cap_nnbr = ct; }
        n = total;
    }
    if (n != num_points) {
        snprintf(e->msg, sizeof e->msg, "octree decodes to %lld points, header declares %lld",
                 (long long)n, (long long)num_points);
        e->failed = 1;
        goto done;
    }
    *codes_out = codes;
    codes = NULL;
    *count_out = n;
    rc = 0;
done:
    phase_close(h);
    free(cc); free(ff); free(codes); free(ncodes); free(nbr); free(nnbr);
    free(occ); free(pbit); free(coded); free(start); free(fixa); free(ff_touched);
    free(mbuf); free(bbuf); free(list.v); free(carry.v);
    return rc;
}

/* Parse and check the tables passed from Python (decoder/native.py::octree_tables). */
static int load_tables(OctTables *tb, PyObject *tables, Py_buffer *views, int *nviews)
{
    PyObject *plan_known, *plan_unknown, *child_par, *child_idx, *p16, *freq0;
    long long cmin, cmax, climit, mix;
    int prec;
    *nviews = 0;
    tb->ctx_lut = NULL;
    tb->p16m = NULL;
    if (!PyArg_ParseTuple(tables, "OOOOOOiLLLL;octree tables", &plan_known, &plan_unknown,
                          &child_par, &child_idx, &p16, &freq0, &prec, &cmin, &cmax, &climit, &mix))
        return -1;
    PyObject *objs[6] = {plan_known, plan_unknown, child_par, child_idx, p16, freq0};
    const Py_ssize_t want[6] = {2 * 8 * 27, 2 * 8 * 27, 8 * 27, 8 * 27, 65536, -1};
    for (int i = 0; i < 6; i++) {
        if (getbuf(objs[i], &views[i], 8, 'i', 0, "octree table") < 0) return -1;
        (*nviews)++;
        if (want[i] >= 0 && views[i].len / 8 != want[i]) {
            PyErr_SetString(PyExc_ValueError, "octree table has the wrong size");
            return -1;
        }
    }
    const int64_t *pk = views[0].buf, *pu = views[1].buf, *cp = views[2].buf, *ci = views[3].buf;
    tb->p16_to_model = views[4].buf;
    tb->freq0 = views[5].buf;
    tb->num_models = (int)(views[5].len / 8);
    tb->prec = prec;
    tb->chunk_min = cmin;
    tb->chunk_max = cmax;
    tb->count_limit = climit;
    tb->mix_weight = mix;
    if (prec < 1 || prec > 16 || tb->num_models < 1 || tb->num_models > 256 || mix < 1) {
        PyErr_SetString(PyExc_ValueError, "octree bank parameters out of range");
        return -1;
    }
    for (int m = 0; m < tb->num_models; m++) {
        if (tb->freq0[m] < 1 || tb->freq0[m] >= ((int64_t)1 << prec)) {
            PyErr_SetString(PyExc_ValueError, "octree bank frequency out of range");
            return -1;
        }
    }
    for (int k = 0; k < 8; k++) {
        tb->nt[k] = 0;
        for (int t = 0; t < NUM_T; t++) {
            int64_t kf = pk[(0 * 8 + k) * 27 + t], ko = pk[(1 * 8 + k) * 27 + t];
            int64_t uf = pu[(0 * 8 + k) * 27 + t], uo = pu[(1 * 8 + k) * 27 + t];
            int64_t par = cp[k * 27 + t], idx = ci[k * 27 + t];
            if (kf < 0 || kf > 255 || ko < 0 || ko > 255 || uf < 0 || uf > 8 || uo < 0 || uo > 8
                || par < 0 || par >= NUM_T || idx < 0 || idx > 7) {
                PyErr_SetString(PyExc_ValueError, "octree plan table out of range");
                return -1;
            }
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
        /* the context ranges (kn_f + unk_f <= 6, kn_o + unk_o <= 20) hold for every occupancy,
         * so the count arrays are never indexed out of range */
        int sf = 0, so = 0;
        for (int t = 0; t < NUM_T; t++) {
            sf += popcount8(tb->kmask_f[k][t]) + tb->ucnt_f[k][t];
            so += popcount8(tb->kmask_o[k][t]) + tb->ucnt_o[k][t];
        }
        unsigned bits7 = 0;
        for (int t = 0; t < NUM_T; t++) bits7 |= tb->kmask_f[k][t] | tb->kmask_o[k][t];
        if (sf > 6 || so > 20 || tb->nt[k] > 8 || (bits7 & 0x80)) {
            PyErr_SetString(PyExc_ValueError, "octree plan table exceeds the context ranges");
            return -1;
        }
    }
    tb->ctx_lut = calloc(8 * 8 * 256, sizeof *tb->ctx_lut);
    if (!tb->ctx_lut) { PyErr_NoMemory(); return -1; }
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
    tb->p16m = malloc(65536);
    if (!tb->p16m) { PyErr_NoMemory(); return -1; }
    for (int i = 0; i < 65536; i++) {
        if (tb->p16_to_model[i] < 0 || tb->p16_to_model[i] >= tb->num_models) {
            PyErr_SetString(PyExc_ValueError, "P16_TO_MODEL entry out of range");
            return -1;
        }
        tb->p16m[i] = (uint8_t)tb->p16_to_model[i];
    }
    return 0;
}

static void release_tables(OctTables *tb, Py_buffer *views, int n)
{
    free(tb->ctx_lut);
    tb->ctx_lut = NULL;
    free(tb->p16m);
    tb->p16m = NULL;
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

static void release_views(Py_buffer *views, int n)
{
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

#define HELPER_CAPSULE "gsz.decoder._native.octree_helper"

typedef struct {
    Helper h;
    int used;            /* handed to an octree_decode already */
} HelperBox;

static void helper_capsule_free(PyObject *cap)
{
    HelperBox *b = PyCapsule_GetPointer(cap, HELPER_CAPSULE);
    if (b) { free(b->h.done_buf); free(b); }
}

PyDoc_STRVAR(octree_helper_doc,
"octree_helper() -> helper\n\n"
"A fresh helper slot for one octree_decode(): another thread calling octree_help(helper)\n"
"joins that traversal (context ids and neighbour rows) until it ends or octree_helper_close()\n"
"is called.  Same output with or without a helper.");

static PyObject *py_octree_helper(PyObject *self, PyObject *noargs)
{
    HelperBox *b = calloc(1, sizeof *b);
    if (!b) return PyErr_NoMemory();
#if GSZ_HELPER
    atomic_init(&b->h.claim, 0);
    atomic_init(&b->h.closed, 0);
    atomic_init(&b->h.desc[0].ndone, 0);
    atomic_init(&b->h.desc[1].ndone, 0);
#endif
    PyObject *cap = PyCapsule_New(b, HELPER_CAPSULE, helper_capsule_free);
    if (!cap) free(b);
    return cap;
}

PyDoc_STRVAR(octree_help_doc,
"octree_help(helper)\n\n"
"Work on the traversal the helper was given to (without the GIL) until it ends or the helper\n"
"is closed; returns at once when it already is.  Returns immediately on builds without C11\n"
"atomics.");

static PyObject *py_octree_help(PyObject *self, PyObject *arg)
{
    HelperBox *b = PyCapsule_GetPointer(arg, HELPER_CAPSULE);
    if (!b) return NULL;
    Py_BEGIN_ALLOW_THREADS
    helper_loop(&b->h);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyDoc_STRVAR(octree_helper_close_doc,
"octree_helper_close(helper)\n\n"
"Let every octree_help(helper) return (idempotent; octree_decode does it when it ends).");

static PyObject *py_octree_helper_close(PyObject *self, PyObject *arg)
{
    HelperBox *b = PyCapsule_GetPointer(arg, HELPER_CAPSULE);
    if (!b) return NULL;
    helper_close(&b->h);
    Py_RETURN_NONE;
}

static int little_endian(void)
{
    const uint16_t one = 1;
    uint8_t b;
    memcpy(&b, &one, 1);
    return b == 1;
}

/* codes as little-endian uint64 bytes */
static PyObject *codes_bytes(const uint64_t *codes, int64_t count)
{
    PyObject *res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * 8));
    if (res && count) {
        uint8_t *o = (uint8_t *)PyBytes_AS_STRING(res);
        if (little_endian()) {
            memcpy(o, codes, (size_t)count * 8);
        } else {
            for (int64_t i = 0; i < count; i++)
                for (int b = 0; b < 8; b++) o[8 * i + b] = (uint8_t)(codes[i] >> (8 * b));
        }
    }
    return res;
}

PyDoc_STRVAR(octree_decode_doc,
"octree_decode(tables, depth, num_points, num_symbols, lanes, body, helper=None) -> bytes\n\n"
"Decode the octree traversal (OCTREE.md §4) from a rANS payload whose lane count `lanes`\n"
"and word count were validated by the caller; `body` holds the 4*lanes state bytes followed\n"
"by the 16-bit words.  Returns the leaf Morton codes as little-endian uint64 bytes.  Checks\n"
"the end conditions of ENTROPY.md §4.4.  Raises GszFormatError on corrupt input.  `helper`:\n"
"an unused octree_helper() that another thread may join with octree_help(); it is closed\n"
"when the traversal ends.");

static PyObject *py_octree_decode(PyObject *self, PyObject *args)
{
    PyObject *tables, *body_obj, *helper_obj = Py_None;
    int depth;
    long long num_points, num_symbols, lanes;
    if (!PyArg_ParseTuple(args, "OiLLLO|O", &tables, &depth, &num_points, &num_symbols, &lanes,
                          &body_obj, &helper_obj))
        return NULL;
    HelperBox *hb = NULL;
    if (helper_obj != Py_None) {
        hb = PyCapsule_GetPointer(helper_obj, HELPER_CAPSULE);
        if (!hb) return NULL;
        if (hb->used) {
            PyErr_SetString(PyExc_ValueError, "octree_decode: this helper was used already");
            return NULL;
        }
        hb->used = 1;
    }
    Helper local;
    memset(&local, 0, sizeof local);
#if GSZ_HELPER
    atomic_init(&local.claim, 0);
    atomic_init(&local.closed, 0);
    atomic_init(&local.desc[0].ndone, 0);
    atomic_init(&local.desc[1].ndone, 0);
#endif
    Helper *h = hb ? &hb->h : &local;
    OctTables tb;
    Py_buffer views[6], body;
    int nviews;
    if (load_tables(&tb, tables, views, &nviews) < 0) {
        release_tables(&tb, views, nviews);
        helper_close(h);
        return NULL;
    }
    if (getbuf(body_obj, &body, 1, 'x', 0, "octree payload") < 0) {
        release_tables(&tb, views, nviews);
        helper_close(h);
        return NULL;
    }
    Err e = {0};
    uint64_t *codes = NULL;
    int64_t count = 0;
    BinDec d = {0};
    if (lanes < 1 || lanes > (num_symbols > 1 ? num_symbols : 1) || num_symbols < 0
        || 4 * lanes > (long long)body.len || ((long long)body.len - 4 * lanes) % 2) {
        fail(&e, "rANS: lane count or payload length invalid");
    } else {
        d.st = malloc((size_t)lanes * sizeof *d.st);
        if (!d.st) fail_nomem(&e);
    }
    if (!e.failed) {
        const uint8_t *b = body.buf;
        d.lanes = lanes;
        d.words = b + 4 * lanes;
        d.nwords = ((int64_t)body.len - 4 * lanes) / 2;
        d.nsym = num_symbols;
        for (int64_t l = 0; l < lanes; l++) {
            d.st[l] = rd_u32(b + 4 * l);
            if (d.st[l] < 65536u) fail(&e, "rANS: initial state below 2**16");
        }
    }
    if (!e.failed) {
        Py_BEGIN_ALLOW_THREADS
        const int wrc = walk(&tb, depth, num_points, 0, &d, NULL, NULL, 0, NULL, h, &codes, &count, &e);
        helper_close(h);        /* the helper's thread can go on with its own work */
        if (wrc == 0) {
            /* ENTROPY.md §4.4 end conditions */
            if (d.pos != d.nsym) fail(&e, "rANS: symbols left undecoded");
            else if (d.wpos != d.nwords) fail(&e, "rANS: words left unread");
            else {
                for (int64_t l = 0; l < d.lanes; l++)
                    if (d.st[l] != 65536u) { fail(&e, "rANS: final states differ from 2**16 (corrupt payload)"); break; }
            }
        }
        Py_END_ALLOW_THREADS
    }
    helper_close(h);
    free(d.st);
    PyBuffer_Release(&body);
    release_tables(&tb, views, nviews);
    if (!hb) free(local.done_buf);
    if (e.failed) { free(codes); return raise_err(&e); }
    PyObject *res = codes_bytes(codes, count);
    free(codes);
    return res;
}

PyDoc_STRVAR(octree_encode_doc,
"octree_encode(tables, depth, num_points, known, known_sizes) -> (bits, models, codes)\n\n"
"Run the traversal with the known occupancy bytes (`known`: every level's bytes concatenated,\n"
"`known_sizes`: int64 node count per level).  Returns the coded bits and their bank model ids\n"
"(uint8 bytes each, in coding order) and the leaf Morton codes (uint64 LE bytes).");

static PyObject *py_octree_encode(PyObject *self, PyObject *args)
{
    PyObject *tables, *known_obj, *sizes_obj;
    int depth;
    long long num_points;
    if (!PyArg_ParseTuple(args, "OiLOO", &tables, &depth, &num_points, &known_obj, &sizes_obj))
        return NULL;
    OctTables tb;
    Py_buffer views[6], known, sizes;
    int nviews;
    if (load_tables(&tb, tables, views, &nviews) < 0) { release_tables(&tb, views, nviews); return NULL; }
    if (getbuf(known_obj, &known, 1, 'x', 0, "occupancy bytes") < 0) {
        release_tables(&tb, views, nviews);
        return NULL;
    }
    if (getbuf(sizes_obj, &sizes, 8, 'i', 0, "level sizes") < 0) {
        PyBuffer_Release(&known);
        release_tables(&tb, views, nviews);
        return NULL;
    }
    Err e = {0};
    uint64_t *codes = NULL;
    int64_t count = 0;
    SymOut out = {0};
    Helper local;
    memset(&local, 0, sizeof local);
#if GSZ_HELPER
    atomic_init(&local.claim, 0);
    atomic_init(&local.closed, 0);
    atomic_init(&local.desc[0].ndone, 0);
    atomic_init(&local.desc[1].ndone, 0);
#endif
    if (num_points > 0 && sizes.len / 8 != depth) {
        fail(&e, "octree encoder: one occupancy level per depth needed");
    } else {
        Py_BEGIN_ALLOW_THREADS
        walk(&tb, depth, num_points, 1, NULL, known.buf, sizes.buf, (int64_t)known.len, &out,
             &local, &codes, &count, &e);
        Py_END_ALLOW_THREADS
    }
    free(local.done_buf);
    PyBuffer_Release(&known);
    PyBuffer_Release(&sizes);
    release_tables(&tb, views, nviews);
    PyObject *res = NULL;
    if (!e.failed) {
        PyObject *b = PyBytes_FromStringAndSize((const char *)out.bits, (Py_ssize_t)out.len);
        PyObject *m = PyBytes_FromStringAndSize((const char *)out.models, (Py_ssize_t)out.len);
        PyObject *c = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * 8));
        if (b && m && c) {
            uint8_t *o = (uint8_t *)PyBytes_AS_STRING(c);
            for (int64_t i = 0; i < count; i++)
                for (int k = 0; k < 8; k++) o[8 * i + k] = (uint8_t)(codes[i] >> (8 * k));
            res = PyTuple_Pack(3, b, m, c);
        }
        Py_XDECREF(b); Py_XDECREF(m); Py_XDECREF(c);
    }
    free(out.bits); free(out.models); free(codes);
    if (e.failed) return raise_err(&e);
    return res;
}

/* ------------------------------------------------------------------ binary rANS encoder */
static int put_varint(uint8_t *p, uint64_t v)
{
    int n = 0;
    do {
        uint8_t b = v & 0x7F;
        v >>= 7;
        p[n++] = b | (v ? 0x80 : 0);
    } while (v);
    return n;
}

/* One rANS encoder step (ENTROPY.md §4.2, run backwards): renormalise state x for a symbol of
 * frequency f at precision prec (emitting its low 16 bits below wb[*wi] when x >= f << (32 -
 * prec)), then push the symbol (cumulative frequency c).  Shared by every native encoder so
 * that they all make the bytes of gsz.encoder.rans._payload. */
static inline uint64_t rans_put(uint64_t x, uint64_t f, uint64_t c, unsigned prec,
                                uint16_t *wb, int64_t *wi)
{
    if (x >= (f << (32 - prec))) {
        wb[--*wi] = (uint16_t)(x & 0xFFFF);
        x >>= 16;
    }
    return ((x / f) << prec) + (x % f) + c;
}

/* The payload bytes: varint lanes, varint word count, the final lane states (uint32 LE), the
 * words in stream order (uint16 LE). */
static PyObject *rans_payload_bytes(const uint64_t *st, int64_t lanes, const uint16_t *w, int64_t nw)
{
    uint8_t head[20];
    int hl = put_varint(head, (uint64_t)lanes);
    hl += put_varint(head + hl, (uint64_t)nw);
    PyObject *res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(hl + 4 * lanes + 2 * nw));
    if (!res) return NULL;
    uint8_t *o = (uint8_t *)PyBytes_AS_STRING(res);
    memcpy(o, head, (size_t)hl);
    o += hl;
    for (int64_t l = 0; l < lanes; l++) {
        const uint64_t x = st[l];
        o[4 * l] = x & 0xFF; o[4 * l + 1] = (x >> 8) & 0xFF;
        o[4 * l + 2] = (x >> 16) & 0xFF; o[4 * l + 3] = (x >> 24) & 0xFF;
    }
    o += 4 * lanes;
    for (int64_t i = 0; i < nw; i++) {
        o[2 * i] = w[i] & 0xFF;
        o[2 * i + 1] = w[i] >> 8;
    }
    return res;
}

PyDoc_STRVAR(rans_encode_doc,
"rans_encode(freq, cum, shift, lanes) -> bytes\n\n"
"ENTROPY.md §4 payload of symbols given, in stream order, by their frequency freq (int64),\n"
"cumulative frequency cum (int64) and model precision shift (uint8), over `lanes` interleaved\n"
"lanes: byte-identical to gsz.encoder.rans._payload.");

static PyObject *py_rans_encode(PyObject *self, PyObject *args)
{
    PyObject *freq_obj, *cum_obj, *shift_obj;
    long long lanes;
    if (!PyArg_ParseTuple(args, "OOOL", &freq_obj, &cum_obj, &shift_obj, &lanes)) return NULL;
    Py_buffer fb, cb, sb;
    if (getbuf(freq_obj, &fb, 8, 'i', 0, "freq") < 0) return NULL;
    if (getbuf(cum_obj, &cb, 8, 'i', 0, "cum") < 0) { PyBuffer_Release(&fb); return NULL; }
    if (getbuf(shift_obj, &sb, 1, 'x', 0, "shift") < 0) {
        PyBuffer_Release(&fb); PyBuffer_Release(&cb); return NULL;
    }
    const int64_t n = fb.len / 8;
    PyObject *res = NULL;
    uint64_t *st = NULL;
    uint16_t *wb = NULL;
    int ok = 1;
    if (cb.len / 8 != n || sb.len != n || lanes < 1 || lanes > (n > 1 ? n : 1)) {
        PyErr_SetString(PyExc_ValueError, "rans_encode: inconsistent arguments");
        ok = 0;
    }
    if (ok) {
        st = malloc((size_t)lanes * sizeof *st);
        wb = big_alloc((size_t)(n ? n : 1) * sizeof *wb);
        if (!st || !wb) { PyErr_NoMemory(); ok = 0; }
    }
    int64_t wi = n, bad = 0;
    if (ok) {
        const int64_t *f = fb.buf, *c = cb.buf;
        const uint8_t *p = sb.buf;
        Py_BEGIN_ALLOW_THREADS
        for (int64_t l = 0; l < lanes; l++) st[l] = 65536u;
        int64_t lane = n ? (n - 1) % lanes : 0;
        for (int64_t j = n - 1; j >= 0; j--) {
            /* a symbol of a valid model: prec <= 16 (0: a SINGLE model, f = 1), 1 <= f, c + f <= 2^prec */
            if (p[j] > 16 || f[j] < 1 || c[j] < 0 || c[j] + f[j] > ((int64_t)1 << p[j])) {
                bad = 1;
                break;
            }
            st[lane] = rans_put(st[lane], (uint64_t)f[j], (uint64_t)c[j], p[j], wb, &wi);
            if (--lane < 0) lane = lanes - 1;
        }
        Py_END_ALLOW_THREADS
        if (bad) { PyErr_SetString(PyExc_ValueError, "rans_encode: symbol frequency out of range"); ok = 0; }
    }
    if (ok) res = rans_payload_bytes(st, lanes, wb + wi, n - wi);
    free(st); free(wb);
    PyBuffer_Release(&fb); PyBuffer_Release(&cb); PyBuffer_Release(&sb);
    return res;
}

PyDoc_STRVAR(bank_encode_doc,
"bank_encode(bits, models, freq0, prec, lanes) -> bytes\n\n"
"ENTROPY.md §4 payload of binary symbols (uint8 0/1) coded with the bank models `models`\n"
"(uint8 ids into freq0, the frequency of a 0 at precision prec), byte-identical to\n"
"gsz.encoder.rans.encode_symbols with the bank model set and the same lane count.");

static PyObject *py_bank_encode(PyObject *self, PyObject *args)
{
    PyObject *bits_obj, *models_obj, *freq_obj;
    int prec;
    long long lanes;
    if (!PyArg_ParseTuple(args, "OOOiL", &bits_obj, &models_obj, &freq_obj, &prec, &lanes))
        return NULL;
    Py_buffer bits, models, freq;
    if (getbuf(bits_obj, &bits, 1, 'x', 0, "bits") < 0) return NULL;
    if (getbuf(models_obj, &models, 1, 'x', 0, "models") < 0) { PyBuffer_Release(&bits); return NULL; }
    if (getbuf(freq_obj, &freq, 8, 'i', 0, "freq0") < 0) {
        PyBuffer_Release(&bits); PyBuffer_Release(&models); return NULL;
    }
    const int64_t n = bits.len, nm = freq.len / 8;
    const int64_t *f0 = freq.buf;
    PyObject *res = NULL;
    uint64_t *st = NULL;
    uint16_t *wb = NULL;
    int ok = 1;
    if (models.len != n || prec < 1 || prec > 16 || lanes < 1 || lanes > (n > 1 ? n : 1)) {
        PyErr_SetString(PyExc_ValueError, "bank_encode: inconsistent arguments");
        ok = 0;
    }
    for (int64_t m = 0; ok && m < nm; m++)
        if (f0[m] < 1 || f0[m] >= ((int64_t)1 << prec)) {
            PyErr_SetString(PyExc_ValueError, "bank_encode: frequency out of range");
            ok = 0;
        }
    if (ok) {
        st = malloc((size_t)lanes * sizeof *st);
        wb = malloc((size_t)(n ? n : 1) * sizeof *wb);
        if (!st || !wb) { PyErr_NoMemory(); ok = 0; }
    }
    int64_t wi = n;
    int bad = 0;
    if (ok) {
        const uint8_t *bp = bits.buf, *mp = models.buf;
        const uint64_t total = (uint64_t)1 << prec;
        Py_BEGIN_ALLOW_THREADS
        for (int64_t l = 0; l < lanes; l++) st[l] = 65536u;
        int64_t lane = (n - 1) % lanes;
        for (int64_t j = n - 1; j >= 0; j--) {
            const unsigned b = bp[j], m = mp[j];
            if (b > 1 || m >= nm) { bad = 1; break; }
            const uint64_t fz = (uint64_t)f0[m];
            const uint64_t f = b ? total - fz : fz, c = b ? fz : 0;
            st[lane] = rans_put(st[lane], f, c, (unsigned)prec, wb, &wi);
            if (--lane < 0) lane = lanes - 1;
        }
        Py_END_ALLOW_THREADS
        if (bad) { PyErr_SetString(PyExc_ValueError, "bank_encode: bit or model id out of range"); ok = 0; }
    }
    if (ok) res = rans_payload_bytes(st, lanes, wb + wi, n - wi);
    free(st); free(wb);
    PyBuffer_Release(&bits); PyBuffer_Release(&models); PyBuffer_Release(&freq);
    return res;
}

/* ================================================================== generic rANS (ENTROPY.md §4.3) */
/*
 * Native decoding tables of a model set (ENTROPY.md §3.3-3.4), compact:
 *   lut[lut_base[m] + z]  uint16  index k (within model m) of the present value owning slot z
 *   fc[sym_base[m] + k]   uint32  (c_k << 16) | (f_k - 1)      (f_k <= 2^16, c_k < 2^16)
 *   val[sym_base[m] + k]  int32   the value v_k (all values lie in [-2^31, 2^31))
 *   prec[m]               uint8   n_m, or 255 for an EMPTY model
 * 2 bytes per LUT slot and 8 per present value (the NumPy tables use 8 and 40).  Measured: the
 * decode step's dependent loads (lut, then fc) must stay in the L1/L2 caches; one 8-byte entry
 * per slot (a single load, but a 4x larger table) was 1.7x slower on the flowers scene.
 */
#define PREC_EMPTY 255

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

PyDoc_STRVAR(rans_tables_doc,
"rans_tables(types, lo, span, prec, group, binshift, centre, rl, rr, nbins, bins, levels,\n"
"            max_lut) -> (lut, fc, val, lut_base, sym_base, mprec)\n\n"
"Build the compact native decoding tables of a ModelSet (int64 parameter arrays; nbins /\n"
"bins / levels: the COARSE models' present-bin counts, bins and level codes, concatenated in\n"
"model order).  Same weights and normalisation as gsz.decoder.rans (ENTROPY.md 3.3-3.5).\n"
"Re-checks every parameter it relies on; raises GszFormatError when one is out of range or\n"
"the LUT would exceed max_lut.");

static PyObject *py_rans_tables(PyObject *self, PyObject *args)
{
    PyObject *o[12];
    long long max_lut;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOL", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6],
                          &o[7], &o[8], &o[9], &o[10], &o[11], &max_lut))
        return NULL;
    Py_buffer v[12];
    int nv = 0;
    for (; nv < 12; nv++)
        if (getbuf(o[nv], &v[nv], 8, 'i', 0, "rans_tables argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    const int64_t *type = v[0].buf, *lo = v[1].buf, *span = v[2].buf, *prec = v[3].buf;
    const int64_t *group = v[4].buf, *bshift = v[5].buf, *centre = v[6].buf, *rl = v[7].buf;
    const int64_t *rr = v[8].buf, *nbins = v[9].buf, *bins = v[10].buf, *levels = v[11].buf;
    const int64_t M = v[0].len / 8, ncoarse = v[9].len / 8, nball = v[10].len / 8;
    Err e = {0};
    PyObject *res = NULL;
    uint16_t *lut = NULL;
    uint32_t *hist = NULL, *fc = NULL;
    int32_t *val = NULL;
    int64_t *lut_base = NULL, *sym_base = NULL, *w = NULL, *fr = NULL, *off = NULL;
    uint64_t *key = NULL, *heap = NULL;
    uint8_t *mprec = NULL;
    for (int i = 1; i < 9; i++)
        if (v[i].len != v[0].len) fail(&e, "rANS model set: parameter arrays differ in length");
    if (v[11].len != v[10].len) fail(&e, "rANS model set: coarse code arrays differ in length");
    /* pass 1: validate, count LUT slots and present values (bounded by max_lut) */
    int64_t lut_total = 0, sym_total = 0, ci = 0, bi = 0;
    for (int64_t m = 0; !e.failed && m < M; m++) {
        const int64_t t = type[m], n = prec[m], sp = span[m];
        if (t < 0 || t > 3) { fail(&e, "rANS model set: unknown model type"); break; }
        if (t == 0) continue;
        if (n < 0 || n > 16 || sp < 0 || sp > 65536) {
            fail(&e, "rANS model set: precision or span out of range");
            break;
        }
        if (lo[m] < -((int64_t)1 << 31) || lo[m] + sp >= ((int64_t)1 << 31)) {
            fail(&e, "rANS model set: value range outside [-2**31, 2**31)");
            break;
        }
        int64_t k = 0;
        if (t == 1) {
            if (sp != 0 || n != 0) { fail(&e, "rANS model set: single model with a span or precision"); break; }
            k = 1;
        } else if (t == 3) {
            if (centre[m] < 0 || centre[m] > sp || rl[m] < 0 || rl[m] > 255 || rr[m] < 0 || rr[m] > 255) {
                fail(&e, "rANS model set: laplace parameter out of range");
                break;
            }
            k = sp + 1;
        } else {
            if (ci >= ncoarse) { fail(&e, "rANS model set: coarse code arrays missing"); break; }
            const int64_t nb = nbins[ci++], h = bshift[m], g = group[m];
            if (h < 0 || h > 16 || g < 0 || g > 3 || nb < 1 || nb > nball - bi) {
                fail(&e, "rANS model set: coarse parameter out of range");
                break;
            }
            for (int64_t j = 0; j < nb; j++) {
                const int64_t b = bins[bi + j], q = levels[bi + j];
                if ((j == 0 && b != 0) || (j > 0 && b <= bins[bi + j - 1]) || b > (sp >> h)
                    || q < 1 || q > ((int64_t)25 << g)) {
                    fail(&e, "rANS model set: coarse bins or levels invalid");
                    break;
                }
                const int64_t hi = ((b + 1) << h) < sp + 1 ? ((b + 1) << h) : sp + 1;
                k += hi - (b << h);
            }
            if (e.failed) break;
            if (bins[bi + nb - 1] != (sp >> h)) {
                fail(&e, "rANS model set: coarse bins not covering the range");
                break;
            }
            bi += nb;
        }
        if (k < 1 || k > ((int64_t)1 << n)) { fail(&e, "rANS model: more symbols than 2**n"); break; }
        lut_total += (int64_t)1 << n;
        sym_total += k;
        if (lut_total > max_lut) break;
    }
    if (!e.failed && lut_total > max_lut)
        fail(&e, "rANS: model set needs more LUT entries than this stream allows");
    if (!e.failed && (ci != ncoarse || bi != nball))
        fail(&e, "rANS model set: coarse code arrays do not match the models");
    /* the tables are written straight into the bytes objects returned (no copy) */
    PyObject *bo[6] = {NULL, NULL, NULL, NULL, NULL, NULL};
    if (!e.failed) {
        const Py_ssize_t sizes[6] = {(Py_ssize_t)(lut_total * 2), (Py_ssize_t)(sym_total * 4),
                                     (Py_ssize_t)(sym_total * 4), (Py_ssize_t)(M * 8),
                                     (Py_ssize_t)(M * 8), (Py_ssize_t)M};
        for (int i = 0; i < 6; i++) {
            bo[i] = PyBytes_FromStringAndSize(NULL, sizes[i]);
            if (!bo[i]) { fail_nomem(&e); break; }
        }
    }
    if (!e.failed) {
        lut = (uint16_t *)PyBytes_AS_STRING(bo[0]);
        fc = (uint32_t *)PyBytes_AS_STRING(bo[1]);
        val = (int32_t *)PyBytes_AS_STRING(bo[2]);
        lut_base = (int64_t *)PyBytes_AS_STRING(bo[3]);
        sym_base = (int64_t *)PyBytes_AS_STRING(bo[4]);
        mprec = (uint8_t *)PyBytes_AS_STRING(bo[5]);
        w = malloc(65537 * sizeof *w);
        fr = malloc(65537 * sizeof *fr);
        off = malloc(65537 * sizeof *off);
        key = malloc(65537 * sizeof *key);
        heap = malloc(65537 * sizeof *heap);
        hist = malloc(4096 * sizeof *hist);
        if (!w || !fr || !off || !key || !heap || !hist) fail_nomem(&e);
    }
    if (!e.failed) {
        Py_BEGIN_ALLOW_THREADS
        int64_t lpos = 0, spos = 0;
        ci = 0;
        bi = 0;
        for (int64_t m = 0; m < M; m++) {
            const int64_t t = type[m], n = prec[m], sp = span[m];
            lut_base[m] = lpos;
            sym_base[m] = spos;
            if (t == 0) { mprec[m] = PREC_EMPTY; continue; }
            mprec[m] = (uint8_t)n;
            /* present values (offsets from lo) and their weights, ENTROPY.md 3.3 */
            int64_t k = 0;
            if (t == 1) {
                off[0] = 0;
                w[0] = 1;
                k = 1;
            } else if (t == 2) {
                const int64_t nb = nbins[ci++], h = bshift[m], g = group[m];
                for (int64_t j = 0; j < nb; j++) {
                    const int64_t b = bins[bi + j], qm = levels[bi + j] - 1;
                    const int64_t wt = (((int64_t)1 << g) + (qm & (((int64_t)1 << g) - 1))) << (qm >> g);
                    const int64_t hi = ((b + 1) << h) < sp + 1 ? ((b + 1) << h) : sp + 1;
                    for (int64_t x = b << h; x < hi; x++) { off[k] = x; w[k] = wt; k++; }
                }
                bi += nb;
            } else {
                /* 3.5: sequential binary64 products, W_d = floor(v_d * 2^24) */
                const int64_t c = centre[m];
                k = sp + 1;
                for (int64_t i = 0; i < k; i++) off[i] = i;
                w[c] = (int64_t)1 << 24;
                for (int side = 0; side < 2; side++) {
                    const int64_t u = side == 0 ? rl[m] : rr[m];
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
            /* normalisation, 3.4 */
            const int64_t T = (int64_t)1 << n;
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
                key[i] = ((uint64_t)(prod % W) << 16) | (uint64_t)(0xFFFF - i);
            }
            const int64_t dshort = T - sumf;
            if (dshort < 0 || dshort >= k) { fail(&e, "rANS model: normalisation out of range"); break; }
            if (dshort > 0) {
                const uint64_t thr = select_dth_largest(key, k, dshort, hist, heap);
                for (int64_t i = 0; i < k; i++) fr[i] += key[i] >= thr;
            }
            int64_t cum = 0;
            for (int64_t i = 0; i < k; i++) {
                fc[spos + i] = ((uint32_t)cum << 16) | (uint32_t)(fr[i] - 1);
                val[spos + i] = (int32_t)(lo[m] + off[i]);
                for (int64_t z = 0; z < fr[i]; z++) lut[lpos + cum + z] = (uint16_t)i;
                cum += fr[i];
            }
            lpos += T;
            spos += k;
        }
        Py_END_ALLOW_THREADS
    }
    if (!e.failed) res = PyTuple_Pack(6, bo[0], bo[1], bo[2], bo[3], bo[4], bo[5]);
    for (int i = 0; i < 6; i++) Py_XDECREF(bo[i]);
    free(w); free(fr); free(off); free(key); free(heap); free(hist);
    release_views(v, nv);
    if (e.failed) return raise_err(&e);
    return res;
}

/* The compact tables of rans_tables() as used by the decode loops. */
typedef struct {
    const uint16_t *lut;
    const uint32_t *fc;
    const int32_t *val;
    const int64_t *lbase, *sbase;
    const uint8_t *mprec;
    int64_t lut_len, nsym, nmodels;
    Py_buffer v[6];
    int nv;
} RTab;

static void rtab_release(RTab *t)
{
    release_views(t->v, t->nv);
    t->nv = 0;
}

static int rtab_load(RTab *t, PyObject *tables)
{
    PyObject *o[6];
    t->nv = 0;
    if (!PyArg_ParseTuple(tables, "OOOOOO;rANS tables", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5]))
        return -1;
    for (; t->nv < 6; t->nv++)
        if (getbuf(o[t->nv], &t->v[t->nv], 1, 'x', 0, "rANS tables") < 0) {
            rtab_release(t);
            return -1;
        }
    t->lut = t->v[0].buf;
    t->fc = t->v[1].buf;
    t->val = t->v[2].buf;
    t->lbase = t->v[3].buf;
    t->sbase = t->v[4].buf;
    t->mprec = t->v[5].buf;
    t->lut_len = t->v[0].len / 2;
    t->nsym = t->v[1].len / 4;
    t->nmodels = t->v[5].len;
    if (t->v[2].len / 4 != t->nsym || t->v[3].len / 8 != t->nmodels || t->v[4].len / 8 != t->nmodels) {
        PyErr_SetString(PyExc_ValueError, "rANS tables: inconsistent sizes");
        rtab_release(t);
        return -1;
    }
    return 0;
}

/* Decoder state of one payload: lane states (int64, the RansDecoder's array), the words. */
typedef struct {
    int64_t *st;
    int64_t lanes, lane;
    const uint8_t *words;
    int64_t nwords, w;
} RState;

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
    const uint64_t need = x < 65536u;      /* branch-free renormalisation, as in bin_decode */
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

PyDoc_STRVAR(rans_decode_doc,
"rans_decode(mids, out, states, words, wpos, pos, tables) -> wpos\n\n"
"Decode len(mids) symbols (ENTROPY.md 4.3) of an interleaved rANS payload with the tables of\n"
"rans_tables(): symbol j (global index pos + j) on lane (pos + j) %% L, L = len(states)\n"
"(int64, updated in place); `words` = the payload's 16-bit words (LE bytes), wpos = words\n"
"consumed so far.  Writes the decoded values (int64) to `out`; returns the new wpos.  Raises\n"
"GszFormatError on a bad model id or an exhausted word stream.");

static PyObject *py_rans_decode(PyObject *self, PyObject *args)
{
    PyObject *o_mids, *o_out, *o_st, *o_words, *tables;
    long long wpos, pos;
    if (!PyArg_ParseTuple(args, "OOOOLLO", &o_mids, &o_out, &o_st, &o_words, &wpos, &pos, &tables))
        return NULL;
    RTab t;
    if (rtab_load(&t, tables) < 0) return NULL;
    PyObject *objs[4] = {o_mids, o_out, o_st, o_words};
    const int wr[4] = {0, 1, 1, 0};
    const Py_ssize_t isz[4] = {8, 8, 8, 1};
    Py_buffer v[4];
    int nv = 0;
    for (; nv < 4; nv++)
        if (getbuf(objs[nv], &v[nv], isz[nv], 'x', wr[nv], "rans_decode argument") < 0) {
            release_views(v, nv);
            rtab_release(&t);
            return NULL;
        }
    const int64_t count = v[0].len / 8;
    RState s = {v[2].buf, v[2].len / 8, 0, v[3].buf, v[3].len / 2, wpos};
    Err e = {0};
    if (v[1].len / 8 != count || s.lanes < 1 || wpos < 0 || wpos > s.nwords || pos < 0)
        fail(&e, "rans_decode: inconsistent arguments");
    if (!e.failed && count) {
        const int64_t *mids = v[0].buf;
        int64_t *out = v[1].buf;
        s.lane = pos % s.lanes;
        Py_BEGIN_ALLOW_THREADS
        for (int64_t j = 0; j < count; j++)
            if (rans_step(&t, &s, mids[j], out + j, &e) < 0) break;
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    rtab_release(&t);
    if (e.failed) return raise_err(&e);
    return PyLong_FromLongLong(s.w);
}

typedef struct { int bad_k, bad_q, overrun; } BlockOut;

/* One block of a channel set: `len` symbols, all with one model (its LUT and present values
 * already offset to the model; klimit = how many present values follow).  Written branch-free
 * (renormalisation by arithmetic select); specialised on `deq` by the two wrappers below.
 * Problems are collected in *bo and reported after the block. */
static inline __attribute__((always_inline)) void
decode_block_body(const uint16_t *restrict lut, const uint32_t *restrict fc,
                  const int32_t *restrict val, int64_t klimit, unsigned n, RState *s, int64_t len,
                  double *restrict fout, int64_t *restrict iout, double step, double l0,
                  int64_t qm, const int deq, BlockOut *bo)
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
        if (deq) {
            bad_q |= (value < 0) | (value > qm);
            const double prod = step * (double)value;
            fout[j] = prod + l0;
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
    decode_block_body(lut, fc, val, klimit, n, s, len, fout, NULL, step, l0, qm, 1, bo);
}

static __attribute__((noinline)) void
decode_block_raw(const uint16_t *lut, const uint32_t *fc, const int32_t *val, int64_t klimit,
                 unsigned n, RState *s, int64_t len, int64_t *iout, BlockOut *bo)
{
    decode_block_body(lut, fc, val, klimit, n, s, len, NULL, iout, 0.0, 0.0, 0, 0, bo);
}

PyDoc_STRVAR(rans_decode_blocks_doc,
"rans_decode_blocks(states, words, wpos, pos, tables, model_table, C, L, B, out,\n"
"                   steps=None, lo=None, qmax=None) -> wpos\n\n"
"Decode the C*L symbols of a quantised channel set (GSZ.md §5): symbol c*L + i uses model\n"
"model_table[c*B + b] (int64), b the block of element i under split_lengths(L, B).  Without\n"
"steps: the values go to `out` (int64 [C*L]).  With steps, lo (float64 [C*B]) and qmax (int64\n"
"[C*B], 2^q - 1): `out` (float64 [C*L]) receives lo + step * k (TRANSFORMS.md §3, the same two\n"
"roundings as gsz.decoder.quant.dequantize_groups), and a symbol outside 0..qmax is an error.");

static PyObject *py_rans_decode_blocks(PyObject *self, PyObject *args)
{
    PyObject *o_st, *o_words, *tables, *o_tab, *o_out, *o_steps = Py_None, *o_lo = Py_None,
             *o_qmax = Py_None;
    long long wpos, pos, C, L, B;
    if (!PyArg_ParseTuple(args, "OOLLOOLLLO|OOO", &o_st, &o_words, &wpos, &pos, &tables, &o_tab,
                          &C, &L, &B, &o_out, &o_steps, &o_lo, &o_qmax))
        return NULL;
    const int deq = o_steps != Py_None;
    RTab t;
    if (rtab_load(&t, tables) < 0) return NULL;
    PyObject *objs[7] = {o_st, o_words, o_tab, o_out, o_steps, o_lo, o_qmax};
    const int wr[7] = {1, 0, 0, 1, 0, 0, 0};
    const Py_ssize_t isz[7] = {8, 1, 8, 8, 8, 8, 8};
    const char kind[7] = {'x', 'x', 'i', deq ? 'f' : 'i', 'f', 'f', 'i'};
    Py_buffer v[7];
    int nv = 0;
    for (; nv < (deq ? 7 : 4); nv++)
        if (getbuf(objs[nv], &v[nv], isz[nv], kind[nv], wr[nv], "rans_decode_blocks argument") < 0) {
            release_views(v, nv);
            rtab_release(&t);
            return NULL;
        }
    RState s = {v[0].buf, v[0].len / 8, 0, v[1].buf, v[1].len / 2, wpos};
    Err e = {0};
    if (C < 1 || L < 0 || B < 1 || C > 255 || B > 65535 || v[2].len / 8 != C * B
        || v[3].len / 8 != C * L || s.lanes < 1 || wpos < 0 || wpos > s.nwords || pos < 0
        || (deq && (v[4].len / 8 != C * B || v[5].len / 8 != C * B || v[6].len / 8 != C * B)))
        fail(&e, "rans_decode_blocks: inconsistent arguments");
    if (!e.failed && C * L > 0) {
        const int64_t *tab = v[2].buf;
        const double *steps = deq ? v[4].buf : NULL, *lo = deq ? v[5].buf : NULL;
        const int64_t *qmax = deq ? v[6].buf : NULL;
        int64_t *iout = deq ? NULL : v[3].buf;
        double *fout = deq ? v[3].buf : NULL;
        const int64_t base = L / B, extra = L % B;
        s.lane = pos % s.lanes;
        Py_BEGIN_ALLOW_THREADS
        for (int64_t c = 0; c < C && !e.failed; c++) {
            int64_t i = 0;
            for (int64_t b = 0; b < B && !e.failed; b++) {
                /* split_lengths: the first L mod B blocks hold one element more */
                const int64_t len = base + (b < extra);
                const int64_t g = c * B + b, m = tab[g];
                i += len;
                if (len == 0) continue;
                /* one model for the whole block: check it once, then a tight loop */
                if (m < 0 || m >= t.nmodels) { fail(&e, "rANS: model id outside the model set"); break; }
                const unsigned n = t.mprec[m];
                if (n == PREC_EMPTY) { fail(&e, "rANS: symbol refers to an empty model"); break; }
                const uint64_t mask = ((uint64_t)1 << n) - 1;
                const int64_t lb = t.lbase[m], sb = t.sbase[m];
                if (lb < 0 || lb + (int64_t)mask >= t.lut_len || sb < 0 || sb >= t.nsym) {
                    fail(&e, "rANS: decoding table index out of range");
                    break;
                }
                BlockOut bo = {0, 0, 0};
                if (deq)
                    decode_block_deq(t.lut + lb, t.fc + sb, t.val + sb, t.nsym - sb, n, &s, len,
                                     fout + c * L + i - len, steps[g], lo[g], qmax[g], &bo);
                else
                    decode_block_raw(t.lut + lb, t.fc + sb, t.val + sb, t.nsym - sb, n, &s, len,
                                     iout + c * L + i - len, &bo);
                if (bo.overrun) { fail(&e, "rANS: payload truncated (word stream exhausted)"); break; }
                if (!e.failed && bo.bad_k) fail(&e, "rANS: decoding table entry out of range");
                const int64_t bad_q = bo.bad_q;
                if (!e.failed && bad_q)
                    fail(&e, "quantisation symbol outside 0..2^q - 1 of its group");
            }
        }
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    rtab_release(&t);
    if (e.failed) return raise_err(&e);
    return PyLong_FromLongLong(s.w);
}

/* ================================================================== inverse RAHT (TRANSFORMS.md §2) */
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
typedef struct { int32_t left, right; double g1, g2; } RPair;

typedef struct {
    int64_t n;            /* leaves */
    int nlev;             /* non-empty binary levels */
    int64_t *lvl_start;   /* [nlev + 1]: pairs of non-empty level L (finest first) */
    RPair *pairs;         /* [n - 1] */
} RTree;

#define RAHT_TREE_CAPSULE "gsz.decoder._native.raht_tree"

static void rtree_free(RTree *t)
{
    if (!t) return;
    free(t->lvl_start);
    free(t->pairs);
    free(t);
}

static void rtree_capsule_free(PyObject *cap)
{
    rtree_free(PyCapsule_GetPointer(cap, RAHT_TREE_CAPSULE));
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

static int rtree_build(const uint64_t *c0, int64_t n, int depth, RTree **out, Err *e)
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

PyDoc_STRVAR(raht_tree_doc,
"raht_tree(codes, depth) -> tree\n\n"
"The RAHT tree (TRANSFORMS.md §2) of the N leaves with Morton codes `codes` (uint64, strictly\n"
"ascending, < 2^(3 depth)), as an opaque object for raht_apply(): the same sibling pairs in the\n"
"same order as gsz.decoder.raht.build_raht_tree, with the butterfly gains computed as there.");

static PyObject *py_raht_tree(PyObject *self, PyObject *args)
{
    PyObject *o_codes;
    int depth;
    if (!PyArg_ParseTuple(args, "Oi", &o_codes, &depth)) return NULL;
    Py_buffer vc;
    if (getbuf(o_codes, &vc, 8, 'x', 0, "codes") < 0) return NULL;
    const int64_t n = vc.len / 8;
    Err e = {0};
    RTree *t = NULL;
    if (n < 1 || n > INT32_MAX || depth < 1 || depth > 21) {
        fail(&e, "RAHT inverse: inconsistent shapes");
    } else {
        Py_BEGIN_ALLOW_THREADS
        rtree_build(vc.buf, n, depth, &t, &e);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vc);
    if (e.failed) return raise_err(&e);
    PyObject *cap = PyCapsule_New(t, RAHT_TREE_CAPSULE, rtree_capsule_free);
    if (!cap) rtree_free(t);
    return cap;
}

PyDoc_STRVAR(raht_apply_doc,
"raht_apply(tree, dc, ac, c0, c1, out, half=False)\n\n"
"Inverse RAHT of channels c0..c1-1 over a raht_tree(): dc float64 [C], ac float64 [C, N-1]\n"
"(channel-major, stream/level order), out float64 [c1 - c0, N] (written, channel-major).  Same\n"
"float64 operations in the same order as gsz.decoder.raht.raht_inverse (bit-identical).  With\n"
"half: every output value x is then replaced by 0.5 * x (0 when x is not finite), the half\n"
"angles of gsz.decoder.rotation.euler_to_quaternion.");

static PyObject *py_raht_apply(PyObject *self, PyObject *args)
{
    PyObject *o_tree, *o_dc, *o_ac, *o_out;
    long long c0, c1;
    int half = 0;
    if (!PyArg_ParseTuple(args, "OOOLLO|p", &o_tree, &o_dc, &o_ac, &c0, &c1, &o_out, &half))
        return NULL;
    RTree *t = PyCapsule_GetPointer(o_tree, RAHT_TREE_CAPSULE);
    if (!t) return NULL;
    Py_buffer vdc, vac, vout;
    if (getbuf(o_dc, &vdc, 8, 'f', 0, "dc") < 0) return NULL;
    if (getbuf(o_ac, &vac, 8, 'f', 0, "ac") < 0) { PyBuffer_Release(&vdc); return NULL; }
    if (getbuf(o_out, &vout, 8, 'f', 1, "out") < 0) { PyBuffer_Release(&vdc); PyBuffer_Release(&vac); return NULL; }
    const int64_t n = t->n, nch = vdc.len / 8, k = c1 - c0;
    int ok = nch >= 1 && c0 >= 0 && c1 <= nch && k >= 1 && vac.len / 8 == nch * (n - 1)
             && vout.len / 8 == k * n;
    if (ok) {
        const double *dc = vdc.buf, *ac = vac.buf;
        double *v = vout.buf;
        Py_BEGIN_ALLOW_THREADS
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
        }
        if (half)
            for (int64_t i = 0; i < k * n; i++) v[i] = 0.5 * (isfinite(v[i]) ? v[i] : 0.0);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vdc); PyBuffer_Release(&vac); PyBuffer_Release(&vout);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "raht_apply: inconsistent shapes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* ================================================================== attribute assembly */
PyDoc_STRVAR(planes_to_f32_doc,
"planes_to_f32(src, p0, p1, out) -> bool\n\n"
"out[i, k] = float32(src[p0 + k, i]) for the planes p0..p1-1 of src (float64 [P, M],\n"
"channel-major) into out (float32 [M, p1 - p0]), NumPy's astype rounding; returns True when\n"
"every value written is finite.");

static PyObject *py_planes_to_f32(PyObject *self, PyObject *args)
{
    PyObject *o_src, *o_out;
    long long p0, p1;
    if (!PyArg_ParseTuple(args, "OLLO", &o_src, &p0, &p1, &o_out)) return NULL;
    Py_buffer vs, vo;
    if (getbuf(o_src, &vs, 8, 'f', 0, "src") < 0) return NULL;
    if (getbuf(o_out, &vo, 4, 'f', 1, "out") < 0) { PyBuffer_Release(&vs); return NULL; }
    const int64_t k = p1 - p0, M = k > 0 ? (vo.len / 4) / k : 0;
    const int ok = k >= 1 && p0 >= 0 && vo.len / 4 == k * M && M > 0 && (vs.len / 8) % M == 0
                   && p1 <= (vs.len / 8) / M;
    uint32_t bad = 0;
    if (ok) {
        const double *src = (const double *)vs.buf + p0 * M;
        float *out = vo.buf;
        Py_BEGIN_ALLOW_THREADS
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
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vs);
    PyBuffer_Release(&vo);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "planes_to_f32: inconsistent shapes");
        return NULL;
    }
    return PyBool_FromLong(!bad);
}

PyDoc_STRVAR(quat_from_trig_doc,
"quat_from_trig(c, s, q) -> bool\n\n"
"Quaternions (w, x, y, z) as float32 [M, 4] from c = cos and s = sin of the half angles\n"
"(float64 [3, M]: roll, pitch, yaw): TRANSFORMS.md §1, products left to right, one rounding\n"
"per operation, sign flipped when w < 0, then rounded to float32.  Returns True when every\n"
"component is finite.");

static PyObject *py_quat_from_trig(PyObject *self, PyObject *args)
{
    PyObject *o[3];
    if (!PyArg_ParseTuple(args, "OOO", &o[0], &o[1], &o[2])) return NULL;
    const Py_ssize_t isz[3] = {8, 8, 4};
    Py_buffer v[3];
    int nv = 0;
    for (; nv < 3; nv++)
        if (getbuf(o[nv], &v[nv], isz[nv], 'f', nv == 2, "quat_from_trig argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    const int64_t M = v[2].len / 16;
    int ok = v[0].len / 8 == 3 * M && v[1].len / 8 == 3 * M;
    int bad = 0;
    if (ok) {
        const double *c = v[0].buf, *s = v[1].buf;
        float *q = v[2].buf;
        Py_BEGIN_ALLOW_THREADS
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
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "quat_from_trig: inconsistent shapes");
        return NULL;
    }
    return PyBool_FromLong(!bad);
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

PyDoc_STRVAR(voxel_positions_doc,
"voxel_positions(codes, depth, ox, oy, oz, side, out) -> bool\n\n"
"Decoded centres (GSZ.md §6) of the voxels with Morton codes `codes` (uint64 [M]):\n"
"origin + (ijk + 0.5) * (side / 2^depth) in float64, rounded to float32 into out [M, 3].\n"
"Returns True when every coordinate is finite.");

static PyObject *py_voxel_positions(PyObject *self, PyObject *args)
{
    PyObject *o_codes, *o_out;
    int depth;
    double org[3], side;
    if (!PyArg_ParseTuple(args, "OiddddO", &o_codes, &depth, &org[0], &org[1], &org[2], &side, &o_out))
        return NULL;
    Py_buffer vc, vo;
    if (getbuf(o_codes, &vc, 8, 'x', 0, "codes") < 0) return NULL;
    if (getbuf(o_out, &vo, 4, 'f', 1, "out") < 0) { PyBuffer_Release(&vc); return NULL; }
    const int64_t M = vc.len / 8;
    const int ok = vo.len / 4 == 3 * M && depth >= 1 && depth <= 21;
    uint32_t bad = 0;
    if (ok) {
        const uint64_t *c = vc.buf;
        float *out = vo.buf;
        const double pitch = side / (double)((int64_t)1 << depth);
        Py_BEGIN_ALLOW_THREADS
        for (int64_t i = 0; i < M; i++) {
            const uint64_t ijk[3] = {compact3(c[i] >> 2), compact3(c[i] >> 1), compact3(c[i])};
            for (int a = 0; a < 3; a++) {
                const double t = ((double)ijk[a] + 0.5) * pitch;
                const float f = (float)(org[a] + t);
                uint32_t u;
                memcpy(&u, &f, 4);
                bad |= (u & 0x7F800000u) == 0x7F800000u;
                out[3 * i + a] = f;
            }
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vc);
    PyBuffer_Release(&vo);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "voxel_positions: inconsistent arguments");
        return NULL;
    }
    return PyBool_FromLong(!bad);
}

PyDoc_STRVAR(sh_assemble_doc,
"sh_assemble(flags, kept, idx, codebook, out)\n\n"
"SH rest vectors (GSZ.md §8) as float32 out [M, D]: Gaussian i takes the next kept vector\n"
"(kept: float64 [D, P], channel-major) when flags[i] == 1 (flags: int64 [M], or None when\n"
"P = 0), else codeword idx[next] of codebook (float64 [D, K]).  A flag other than 0/1, a\n"
"kept count other than P or an index >= K raises GszFormatError.");

static PyObject *py_sh_assemble(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    const int has_flags = o[0] != Py_None;
    const Py_ssize_t isz[5] = {8, 8, 8, 8, 4};
    const char kind[5] = {'i', 'f', 'i', 'f', 'f'};
    Py_buffer v[5];
    int nv = 0;
    for (; nv < 5; nv++) {
        if (nv == 0 && !has_flags) { memset(&v[0], 0, sizeof v[0]); continue; }
        if (getbuf(o[nv], &v[nv], isz[nv], kind[nv], nv == 4, "sh_assemble argument") < 0) {
            for (int i = has_flags ? 0 : 1; i < nv; i++) PyBuffer_Release(&v[i]);
            return NULL;
        }
    }
    const int64_t nidx = v[2].len / 8;
    const int64_t M = has_flags ? v[0].len / 8 : nidx;
    Err e = {0};
    int64_t D = M ? (v[4].len / 4) / M : 0;
    if (M == 0 || v[4].len / 4 != D * M || D < 1 || v[1].len / 8 % D || v[3].len / 8 % D)
        fail(&e, "sh_assemble: inconsistent shapes");
    if (!e.failed) {
        const int64_t P = v[1].len / 8 / D, K = v[3].len / 8 / D;
        const int64_t *flags = has_flags ? v[0].buf : NULL, *idx = v[2].buf;
        const double *kept = v[1].buf, *cb = v[3].buf;
        float *out = v[4].buf;
        Py_BEGIN_ALLOW_THREADS
        int64_t kp = 0, ip = 0;
        for (int64_t i = 0; i < M; i++) {
            float *dst = out + i * D;
            const int64_t f = flags ? flags[i] : 0;
            if (f == 1) {
                if (kp >= P) { fail(&e, "SHVQ chunk: more kept flags set than kept vectors"); break; }
                for (int64_t d = 0; d < D; d++) dst[d] = (float)kept[d * P + kp];
                kp++;
            } else if (f == 0) {
                if (ip >= nidx) { fail(&e, "SHVQ chunk: fewer codeword indices than Gaussians"); break; }
                const int64_t j = idx[ip++];
                if (j < 0 || j >= K) { fail(&e, "SHVQ chunk: codeword index out of range"); break; }
                for (int64_t d = 0; d < D; d++) dst[d] = (float)cb[d * K + j];
            } else {
                fail(&e, "SHVQ chunk: kept flag outside 0/1");
                break;
            }
        }
        if (!e.failed && (kp != P || ip != nidx)) fail(&e, "SHVQ chunk: kept flags do not match the kept count");
        Py_END_ALLOW_THREADS
    }
    for (int i = has_flags ? 0 : 1; i < 5; i++) PyBuffer_Release(&v[i]);
    if (e.failed) return raise_err(&e);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(all_finite_doc,
"all_finite(a) -> bool\n\nTrue when every element of the float32 buffer `a` is finite.");

static PyObject *py_all_finite(PyObject *self, PyObject *arg)
{
    Py_buffer v;
    if (getbuf(arg, &v, 4, 'f', 0, "all_finite argument") < 0) return NULL;
    const uint32_t *p = v.buf;
    const int64_t n = v.len / 4;
    uint32_t bad = 0;
    Py_BEGIN_ALLOW_THREADS
    /* exponent all ones = inf or nan; branch-free so the loop vectorises */
    for (int64_t i = 0; i < n; i++) bad |= ((p[i] & 0x7F800000u) == 0x7F800000u);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&v);
    return PyBool_FromLong(!bad);
}

/* ================================================================== varints (ENTROPY.md §2) */
PyDoc_STRVAR(read_varints_doc,
"read_varints(buf, pos, count, out) -> int\n\n"
"gsz.decoder.rans.read_varints in C: the first `count` terminating bytes (< 0x80) within\n"
"buf[pos : pos + 9 * count] end the `count` unsigned LEB128 varints, written to out (int64\n"
"[count]); returns the position after them, -1 when fewer terminators are found there\n"
"(truncated) or -2 when one varint is longer than 9 bytes (same decision order as NumPy's).");

static PyObject *py_read_varints(PyObject *self, PyObject *args)
{
    PyObject *o_buf, *o_out;
    long long pos, count;
    if (!PyArg_ParseTuple(args, "OLLO", &o_buf, &pos, &count, &o_out)) return NULL;
    Py_buffer vb, vo;
    if (getbuf(o_buf, &vb, 1, 'x', 0, "buf") < 0) return NULL;
    if (getbuf(o_out, &vo, 8, 'i', 1, "out") < 0) { PyBuffer_Release(&vb); return NULL; }
    long long res = 0;
    if (pos < 0 || count < 0 || pos > vb.len || vo.len / 8 != count) {
        PyBuffer_Release(&vb); PyBuffer_Release(&vo);
        PyErr_SetString(PyExc_ValueError, "read_varints: inconsistent arguments");
        return NULL;
    }
    const uint8_t *b = (const uint8_t *)vb.buf + pos;
    int64_t *out = vo.buf;
    const int64_t avail = (int64_t)vb.len - pos;
    const int64_t window = 9 * count < avail ? 9 * count : avail;
    Py_BEGIN_ALLOW_THREADS
    /* pass 1: the terminators and the longest varint */
    int64_t found = 0, i = 0, start = 0, longest = 0;
    for (; i < window && found < count; i++) {
        if (b[i] < 0x80) {
            if (i - start + 1 > longest) longest = i - start + 1;
            start = i + 1;
            found++;
        }
    }
    if (found < count) res = -1;
    else if (longest > 9) res = -2;
    else {
        int64_t j = 0;
        for (int64_t v = 0; v < count; v++) {
            uint64_t x = 0;
            int sh = 0;
            for (;;) {
                const uint8_t c = b[j++];
                x |= (uint64_t)(c & 0x7F) << sh;
                sh += 7;
                if (c < 0x80) break;
            }
            out[v] = (int64_t)x;
        }
        res = pos + j;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&vb);
    PyBuffer_Release(&vo);
    return PyLong_FromLongLong(res);
}

/* ================================================================== model sets (ENTROPY.md §3) */
PyDoc_STRVAR(model_set_parse_doc,
"model_set_parse(body) -> (types, lo, span, prec, group, binshift, centre, rl, rr, counts,\n"
"                          bins, levels) | None\n\n"
"The body of a model set (ENTROPY.md 3.1-3.2, after zstd) parsed and checked in C: the same\n"
"accept/reject decision and the same int64 arrays as gsz.decoder.rans.read_model_set and\n"
"ModelSet.validate (bins / levels flat, in model order).  Returns None on ANY violation; the\n"
"caller then runs the Python parser, whose message is the normative one.");

/* one unsigned LEB128 varint of at most 9 bytes; -1 when truncated or too long */
static inline int msp_varint(const uint8_t *b, int64_t n, int64_t *p, int64_t *out)
{
    uint64_t x = 0;
    for (int i = 0; i < 9; i++) {
        if (*p >= n) return -1;
        const uint8_t c = b[(*p)++];
        x |= (uint64_t)(c & 0x7F) << (7 * i);
        if (c < 0x80) { *out = (int64_t)x; return 0; }
    }
    return -1;
}

static inline int64_t msp_unzigzag(int64_t u) { return (int64_t)((uint64_t)u >> 1) ^ -(u & 1); }

static PyObject *py_model_set_parse(PyObject *self, PyObject *arg)
{
    Py_buffer vb;
    if (getbuf(arg, &vb, 1, 'x', 0, "body") < 0) return NULL;
    const uint8_t *b = vb.buf;
    const int64_t n = vb.len;
    int64_t p = 0, M = 0, ok = 0;
    int64_t *arr[12] = {NULL};
    int64_t nb_total = 0;
    PyObject *res = NULL;
    if (msp_varint(b, n, &p, &M) < 0 || M > ((int64_t)1 << 20) || M > n - p) goto done;
    for (int i = 0; i < 9; i++) {
        arr[i] = calloc((size_t)(M ? M : 1), sizeof(int64_t));
        if (!arr[i]) { PyErr_NoMemory(); goto done; }
    }
    int64_t *type = arr[0], *lo = arr[1], *span = arr[2], *prec = arr[3], *group = arr[4];
    int64_t *bsh = arr[5], *centre = arr[6], *rl = arr[7], *rr = arr[8];
    int64_t nonempty = 0, wide = 0, nco = 0, nlap = 0, v;
    for (int64_t m = 0; m < M; m++) {
        if (msp_varint(b, n, &p, &type[m]) < 0 || type[m] > 3) goto done;
        nonempty += type[m] != 0;
        wide += type[m] >= 2;
        nco += type[m] == 2;
        nlap += type[m] == 3;
    }
    /* the field arrays in the serialised order: lo (non-empty), span, precision (wide),
     * coarse shape, centre (laplace), then the two ratio byte arrays */
    for (int64_t m = 0; m < M; m++)
        if (type[m] != 0) { if (msp_varint(b, n, &p, &v) < 0) goto done; lo[m] = msp_unzigzag(v); }
    for (int64_t m = 0; m < M; m++)
        if (type[m] >= 2 && msp_varint(b, n, &p, &span[m]) < 0) goto done;
    for (int64_t m = 0; m < M; m++)
        if (type[m] >= 2 && msp_varint(b, n, &p, &prec[m]) < 0) goto done;
    for (int64_t m = 0; m < M; m++)
        if (type[m] == 2) {
            if (msp_varint(b, n, &p, &v) < 0) goto done;
            group[m] = v & 3;
            bsh[m] = v >> 2;
        }
    for (int64_t m = 0; m < M; m++)
        if (type[m] == 3 && msp_varint(b, n, &p, &centre[m]) < 0) goto done;
    for (int side = 0; side < 2; side++) {
        if (nlap > n - p) goto done;
        int64_t *r = side == 0 ? rl : rr;
        for (int64_t m = 0; m < M; m++)
            if (type[m] == 3) r[m] = b[p++];
    }
    for (int64_t m = 0; m < M; m++)
        if (span[m] > 65536 || prec[m] > 16 || bsh[m] > 16) goto done;
    arr[9] = malloc((size_t)(nco ? nco : 1) * sizeof(int64_t));
    if (!arr[9]) { PyErr_NoMemory(); goto done; }
    int64_t *counts = arr[9];
    for (int64_t m = 0, ci = 0; m < M; m++) {
        if (type[m] != 2) continue;
        if (msp_varint(b, n, &p, &counts[ci]) < 0) goto done;
        if (counts[ci] < 1 || counts[ci] > (span[m] >> bsh[m]) + 1) goto done;
        nb_total += counts[ci++];
    }
    /* every count <= 65537, so nb_total < 2^37; each gap/delta takes >= 1 byte */
    if (2 * nb_total > n - p) goto done;
    arr[10] = malloc((size_t)(nb_total ? nb_total : 1) * sizeof(int64_t));
    arr[11] = malloc((size_t)(nb_total ? nb_total : 1) * sizeof(int64_t));
    if (!arr[10] || !arr[11]) { PyErr_NoMemory(); goto done; }
    int64_t *bins = arr[10], *levels = arr[11];
    for (int64_t i = 0; i < nb_total; i++)
        if (msp_varint(b, n, &p, &bins[i]) < 0 || bins[i] > 65536) goto done;
    for (int64_t i = 0; i < nb_total; i++) {
        if (msp_varint(b, n, &p, &v) < 0) goto done;
        levels[i] = msp_unzigzag(v);
        if (levels[i] > 65536 || levels[i] < -65536) goto done;
    }
    if (p != n) goto done;
    /* running sums per model, then ModelSet.validate's checks */
    for (int64_t m = 0, ci = 0, i = 0; m < M; m++) {
        const int64_t t = type[m], sp = span[m], pr = prec[m];
        if (t != 0 && (lo[m] < -((int64_t)1 << 31) || lo[m] + sp >= ((int64_t)1 << 31))) goto done;
        if (t == 3 && (sp + 1 > ((int64_t)1 << pr) || centre[m] > sp)) goto done;
        if (t != 2) continue;
        const int64_t nb = counts[ci++], h = bsh[m], g = group[m];
        int64_t bprev = -1, qprev = 0, k = 0;
        for (int64_t j = 0; j < nb; j++, i++) {
            bprev += bins[i] + 1;
            qprev += levels[i];
            bins[i] = bprev;
            levels[i] = qprev;
            if (qprev < 1 || qprev > ((int64_t)25 << g)) goto done;
            const int64_t hi = ((bprev + 1) << h) < sp + 1 ? ((bprev + 1) << h) : sp + 1;
            k += hi - (bprev << h);
        }
        if (bins[i - nb] != 0 || bprev != (sp >> h) || k > ((int64_t)1 << pr)) goto done;
    }
    ok = 1;
done:
    PyBuffer_Release(&vb);
    if (ok) {
        const int64_t len[12] = {M, M, M, M, M, M, M, M, M, nco, nb_total, nb_total};
        PyObject *items[12] = {NULL};
        for (int i = 0; i < 12 && ok; i++) {
            items[i] = PyBytes_FromStringAndSize((const char *)arr[i], (Py_ssize_t)(len[i] * 8));
            if (!items[i]) ok = 0;
        }
        if (ok) res = PyTuple_Pack(12, items[0], items[1], items[2], items[3], items[4], items[5],
                                   items[6], items[7], items[8], items[9], items[10], items[11]);
        for (int i = 0; i < 12; i++) Py_XDECREF(items[i]);
    } else if (!PyErr_Occurred()) {
        res = Py_None;
        Py_INCREF(res);
    }
    for (int i = 0; i < 12; i++) free(arr[i]);
    return res;
}

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
#define RATE_BITS 16                 /* gsz.decoder.quant.MAX_BITS: the out arrays' q axis */
#define RATE_SHIFTS 5                /* rate.MAX_BINSHIFT: the binned candidates' h = 1..5 */
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

typedef struct {
    double *k, *payload, *gap, *gap2, *level, *laplace, *binned;
} RateOut;

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

PyDoc_STRVAR(rate_group_stats_doc,
"rate_group_stats(srt, blen, log_tab, q_first, hi, rho_min, rho_max,\n"
"                 out_k, out_payload, out_gap, out_gap2, out_level, out_laplace, out_binned)\n\n"
"gsz.encoder.rate.group_stats' loop over bit-widths q_first..hi for one channel's part of\n"
"equal blocks: srt float32 [nb, blen] (each block sorted ascending), log_tab float64 with\n"
"log_tab[i] = np.log2(max(i, 1)) for i < len(log_tab) (at least max(blen, 65536) + 1\n"
"entries), out_* float64 [nb, 16] (out_binned [nb, 16, 5]) written at columns q_first-1..hi-1\n"
"(binned only where q - h >= q_first).  Same arithmetic as the NumPy reference, up to\n"
"last-bit differences of log2/pow in the payload, laplace and binned sums.");

static PyObject *py_rate_group_stats(PyObject *self, PyObject *args)
{
    PyObject *o[9];
    long long blen;
    int q_first, hi;
    double rho_min, rho_max;
    if (!PyArg_ParseTuple(args, "OLOiiddOOOOOOO", &o[0], &blen, &o[1], &q_first, &hi, &rho_min,
                          &rho_max, &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8]))
        return NULL;
    Py_buffer v[9];
    int nv = 0;
    for (; nv < 9; nv++) {
        const int out = nv >= 2;
        if (getbuf(o[nv], &v[nv], nv == 0 ? 4 : 8, 'f', out, "rate_group_stats argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    }
    const int64_t tab_len = v[1].len / 8;
    const int64_t nb = blen > 0 ? (int64_t)(v[0].len / 4) / blen : 0;
    int ok = blen > 0 && blen <= INT32_MAX && nb > 0 && nb * blen == (int64_t)(v[0].len / 4)
             && tab_len > blen && tab_len > 65536
             && 1 <= q_first && q_first <= hi && hi <= RATE_BITS
             && rho_min > 0.0 && rho_min <= rho_max && rho_max < 1.0;
    for (int i = 2; ok && i < 9; i++)
        if (v[i].len / 8 != nb * RATE_BITS * (i == 8 ? RATE_SHIFTS : 1)) ok = 0;
    if (!ok) {
        release_views(v, nv);
        PyErr_SetString(PyExc_ValueError, "rate_group_stats: inconsistent arguments");
        return NULL;
    }
    /* per block: its values minus the minimum, this q's run symbols, the run lengths of the
     * last RATE_SLOTS bit-widths (the binned candidates read q - 1 .. q - 5) */
    double *d = big_alloc((size_t)blen * sizeof *d);
    int32_t *sym = big_alloc((size_t)blen * sizeof *sym);
    int32_t *cnt = big_alloc((size_t)blen * RATE_SLOTS * sizeof *cnt);
    if (!d || !sym || !cnt) {
        free(d); free(sym); free(cnt);
        release_views(v, nv);
        return PyErr_NoMemory();
    }
    const RateOut out = {v[2].buf, v[3].buf, v[4].buf, v[5].buf, v[6].buf, v[7].buf, v[8].buf};
    const float *x = v[0].buf;
    const double *tab = v[1].buf;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t r = 0; r < nb; r++)
        rate_block(x + r * blen, blen, tab, q_first, hi, rho_min, rho_max, r, &out, d, sym, cnt);
    Py_END_ALLOW_THREADS
    free(d); free(sym); free(cnt);
    release_views(v, nv);
    Py_RETURN_NONE;
}

/* ================================================================== module */
static PyMethodDef methods[] = {
    {"octree_decode", py_octree_decode, METH_VARARGS, octree_decode_doc},
    {"octree_encode", py_octree_encode, METH_VARARGS, octree_encode_doc},
    {"octree_helper", py_octree_helper, METH_NOARGS, octree_helper_doc},
    {"octree_help", py_octree_help, METH_O, octree_help_doc},
    {"octree_helper_close", py_octree_helper_close, METH_O, octree_helper_close_doc},
    {"bank_encode", py_bank_encode, METH_VARARGS, bank_encode_doc},
    {"rans_encode", py_rans_encode, METH_VARARGS, rans_encode_doc},
    {"rans_decode", py_rans_decode, METH_VARARGS, rans_decode_doc},
    {"raht_tree", py_raht_tree, METH_VARARGS, raht_tree_doc},
    {"raht_apply", py_raht_apply, METH_VARARGS, raht_apply_doc},
    {"rans_tables", py_rans_tables, METH_VARARGS, rans_tables_doc},
    {"rans_decode_blocks", py_rans_decode_blocks, METH_VARARGS, rans_decode_blocks_doc},
    {"planes_to_f32", py_planes_to_f32, METH_VARARGS, planes_to_f32_doc},
    {"quat_from_trig", py_quat_from_trig, METH_VARARGS, quat_from_trig_doc},
    {"voxel_positions", py_voxel_positions, METH_VARARGS, voxel_positions_doc},
    {"sh_assemble", py_sh_assemble, METH_VARARGS, sh_assemble_doc},
    {"all_finite", py_all_finite, METH_O, all_finite_doc},
    {"read_varints", py_read_varints, METH_VARARGS, read_varints_doc},
    {"model_set_parse", py_model_set_parse, METH_O, model_set_parse_doc},
    {"rate_group_stats", py_rate_group_stats, METH_VARARGS, rate_group_stats_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "gsz.decoder._native",
    "Optional C accelerator of the gsz reference decoder (bit-identical to the NumPy path).",
    -1, methods,
};

PyMODINIT_FUNC PyInit__native(void)
{
    PyObject *errors = PyImport_ImportModule("gsz.decoder.errors");
    if (!errors) return NULL;
    FormatError = PyObject_GetAttrString(errors, "GszFormatError");
    Py_DECREF(errors);
    if (!FormatError) return NULL;
    raht_pairs8_init();
    fine_to_coarse_init();
    child_rank_init();
    PyObject *m = PyModule_Create(&moddef);
    if (!m) return NULL;
    if (PyModule_AddIntConstant(m, "ABI", GSZ_NATIVE_ABI) < 0
        || PyModule_AddIntConstant(m, "NUM_COARSE", NUM_COARSE) < 0
        || PyModule_AddIntConstant(m, "NUM_FINE", NUM_FINE) < 0
        || PyModule_AddIntConstant(m, "MAX_POINTS", INT32_MAX / 2) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
