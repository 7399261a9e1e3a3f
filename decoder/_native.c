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

/* Bumped whenever a signature changes, so a stale build is ignored (decoder/native.py). */
#define GSZ_NATIVE_ABI 1

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
    /* ctx_lut[(k * 8 + q) * 512 + w]: contribution of the q-th node of child k's octant, whose
     * 9-bit occupancy word is w (bit 8 = node present, bits 0..7 = child bits decoded so far),
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
    if (x < 65536u) {
        if (d->wpos >= d->nwords) return fail(e, "rANS: payload truncated (word stream exhausted)");
        x = (x << 16) | rd_u16(d->words + 2 * d->wpos);
        d->wpos++;
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
    uint32_t n0, n1;
    uint32_t stamp;      /* chunk whose model is cached in `model` (0: none) */
    uint8_t model;
    uint8_t listed;      /* level + 1 of the halving list this context is on (0: none) */
    uint16_t pad;
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

/*
 * The normative traversal (decoder/octree.py::walk_octree).  mode 0: bits from `dec`; mode 1:
 * bits from the known occupancy bytes `known` (levels concatenated, level l holding
 * known_sizes[l] nodes), recorded into `out`.  On success *codes_out holds the leaf Morton codes
 * (ascending) and *count_out their number (== num_points).
 *
 * Representation: the nodes of a level are 0..n-1 in Morton order; nbr[27 * i + t] is the
 * index of node i's neighbour at offset t, or n when there is none -- occ[n] is a permanent 0
 * byte, so an absent neighbour reads as an empty node without a branch.
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
    *p = malloc(need);
    if (!*p) { *cap = 0; return fail_nomem(e); }
    *cap = need;
    return 0;
}

static int walk(const OctTables *tb, int depth, int64_t num_points, int mode, BinDec *dec,
                const uint8_t *known, const int64_t *known_sizes, int64_t known_len, SymOut *out,
                uint64_t **codes_out, int64_t *count_out, Err *e)
{
    int rc = -1;
    uint32_t *cc = NULL;
    FineCtx *ff = NULL;
    uint64_t *codes = NULL, *ncodes = NULL;
    int32_t *nbr = NULL, *nnbr = NULL, *coded = NULL, *start = NULL;
    uint16_t *occ = NULL;    /* per node: 0x100 (present) | child bits decoded so far; occ[n] = 0 */
    int64_t n = 1, known_off = 0;
    int32_t *cbuf_c = NULL, *cbuf_f = NULL;     /* contexts and models of one chunk */
    uint8_t *mbuf = NULL;
    uint32_t stamp = 0;
    IdList list = {0}, carry = {0};
    size_t cap_codes = 0, cap_ncodes = 0, cap_nbr = 0, cap_nnbr = 0, cap_occ = 0, cap_coded = 0,
           cap_start = 0;

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
    if (ensure((void **)&codes, &cap_codes, sizeof *codes, e) < 0
        || ensure((void **)&nbr, &cap_nbr, NUM_T * sizeof *nbr, e) < 0)
        goto done;
    cbuf_c = malloc((size_t)tb->chunk_max * sizeof *cbuf_c);
    cbuf_f = malloc((size_t)tb->chunk_max * sizeof *cbuf_f);
    mbuf = malloc((size_t)tb->chunk_max);
    if (!cc || !ff || !codes || !nbr || !cbuf_c || !cbuf_f || !mbuf) { fail_nomem(e); goto done; }
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
        if (ensure((void **)&occ, &cap_occ, ((size_t)n + 1) * sizeof *occ, e) < 0
            || ensure((void **)&coded, &cap_coded, (size_t)n * sizeof *coded, e) < 0)
            goto done;
        for (int64_t i = 0; i < n; i++) occ[i] = 0x100;
        occ[n] = 0;                                  /* the absent neighbour */
        for (int k = 0; k < 8; k++) {
            int64_t cnt = n;
            if (k == 7) {
                /* a node with no child among 0..6 has child 7 for free (not coded) */
                cnt = 0;
                for (int64_t i = 0; i < n; i++) {
                    if (occ[i] & 0x7F) coded[cnt++] = (int32_t)i;
                    else occ[i] |= 0x80;
                }
            }
            const int nt = tb->nt[k];
            const int *tk = tb->t[k];
            const uint32_t *lut = tb->ctx_lut + (size_t)k * 8 * 512;
            const unsigned below = (1u << k) - 1u;
            const int32_t fine_k = k * (7 * 7 * 21 * 21), coarse_k = k * (27 * 27);
            const int32_t fine_lb = lb * (NUM_FINE / NUM_LB);
            int64_t s = 0;
            while (s < cnt) {
                int64_t step = s > tb->chunk_min ? s : tb->chunk_min;
                if (step > tb->chunk_max) step = tb->chunk_max;
                const int64_t end = s + step < cnt ? s + step : cnt;
                /* models of the chunk, all from the counts before the chunk */
                stamp++;
                for (int64_t i = s; i < end; i++) {
                    const int64_t node = (k == 7) ? coded[i] : i;
                    const int32_t *nb = nbr + node * NUM_T;
                    uint32_t acc = 0;
                    for (int q = 0; q < nt; q++) acc += lut[q * 512 + occ[nb[tk[q]]]];
                    int sib = popcount8(occ[node] & below);
                    if (sib > NUM_SIB - 1) sib = NUM_SIB - 1;
                    const int32_t cix = (coarse_k + (int32_t)(acc >> 16)) * NUM_SIB + sib;
                    /* the fine context id is (((((k*7 + kn_f)*7 + unk_f)*21 + kn_o)*21 + unk_o)*4
                     * + sib)*4 + lb (OCTREE.md); its record is stored level-bucket-major so that
                     * the contexts of one level share cache lines */
                    const int32_t fix = fine_lb + (fine_k + (int32_t)(acc & 0xFFFF)) * NUM_SIB + sib;
                    FineCtx *fc = ff + fix;
                    if (fc->stamp != stamp) {
                        /* the model is a function of the fine context (which fixes the coarse
                         * one) and of the counts, which are frozen during a chunk: computed
                         * once per chunk and context */
                        const uint64_t c0 = cc[2 * cix], c1 = cc[2 * cix + 1];
                        const uint64_t pc = ((2 * c1 + 1) << 16) / (2 * (c0 + c1) + 2);
                        const uint64_t f0 = fc->n0, f1 = fc->n1;
                        const uint64_t mw = (uint64_t)tb->mix_weight;
                        const uint64_t pf = ((f1 << 16) + mw * pc) / (f0 + f1 + mw);
                        if (pf > 65535) { fail(e, "octree: probability out of range"); goto done; }
                        fc->model = (uint8_t)tb->p16_to_model[pf];   /* < num_models (checked) */
                        fc->stamp = stamp;
                        if (fc->listed != tag) {
                            fc->listed = tag;
                            if (idlist_push(&list, fix, e) < 0) goto done;
                        }
                    }
                    cbuf_c[i - s] = cix;
                    cbuf_f[i - s] = fix;
                    mbuf[i - s] = fc->model;
                }
                /* the chunk's bits, then the count updates */
                for (int64_t i = s; i < end; i++) {
                    const int64_t node = (k == 7) ? coded[i] : i;
                    int bit;
                    if (mode == 0) {
                        bit = bin_decode(dec, tb, mbuf[i - s], e);
                        if (bit < 0) goto done;
                    } else {
                        bit = (kn[node] >> k) & 1;
                        out->bits[out->len] = (uint8_t)bit;
                        out->models[out->len] = mbuf[i - s];
                        out->len++;
                    }
                    occ[node] |= (uint16_t)(bit << k);
                    cc[2 * cbuf_c[i - s] + bit]++;
                    if (bit) ff[cbuf_f[i - s]].n1++;
                    else ff[cbuf_f[i - s]].n0++;
                }
                s = end;
            }
        }
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

        /* the next level: children in Morton order (node-major, child index ascending) */
        int64_t total = 0;
        if (ensure((void **)&start, &cap_start, ((size_t)n + 1) * sizeof *start, e) < 0) goto done;
        for (int64_t i = 0; i < n; i++) {
            start[i] = (int32_t)total;
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
        const int32_t absent = (int32_t)total;
        int64_t c = 0;
        for (int64_t r = 0; r < n; r++) {
            const unsigned o = occ[r] & 0xFFu;
            const int32_t *nb = nbr + r * NUM_T;
            unsigned pv[NUM_T];      /* occupancy of the parent's 27 neighbours (0 if absent) */
            int32_t ps[NUM_T];       /* their first-child index */
            if (!last) {
                for (int t = 0; t < NUM_T; t++) {
                    pv[t] = occ[nb[t]] & 0xFFu;
                    ps[t] = start[nb[t]];
                }
            }
            for (int k = 0; k < 8; k++) {
                if (!((o >> k) & 1)) continue;
                ncodes[c] = (codes[r] << 3) | (uint64_t)k;
                if (!last) {
                    int32_t *dst = nnbr + c * NUM_T;
                    const int *cp = tb->child_par[k], *ci = tb->child_idx[k];
                    for (int t = 0; t < NUM_T; t++) {
                        const unsigned v = pv[cp[t]];
                        const int j = ci[t];
                        const int32_t idx = ps[cp[t]] + popcount8(v & ((1u << j) - 1u));
                        dst[t] = ((v >> j) & 1) ? idx : absent;
                    }
                    dst[SELF_T] = (int32_t)c;
                }
                c++;
            }
        }
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
    free(cc); free(ff); free(codes); free(ncodes); free(nbr); free(nnbr);
    free(occ); free(coded); free(start);
    free(cbuf_c); free(cbuf_f); free(mbuf); free(list.v); free(carry.v);
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
            if (kf | ko | uf | uo) tb->t[k][tb->nt[k]++] = t;
        }
        /* the context ranges (kn_f + unk_f <= 6, kn_o + unk_o <= 20) hold for every occupancy,
         * so the count arrays are never indexed out of range */
        int sf = 0, so = 0;
        for (int t = 0; t < NUM_T; t++) {
            sf += popcount8(tb->kmask_f[k][t]) + tb->ucnt_f[k][t];
            so += popcount8(tb->kmask_o[k][t]) + tb->ucnt_o[k][t];
        }
        if (sf > 6 || so > 20 || tb->nt[k] > 8) {
            PyErr_SetString(PyExc_ValueError, "octree plan table exceeds the context ranges");
            return -1;
        }
    }
    tb->ctx_lut = malloc(8 * 8 * 512 * sizeof *tb->ctx_lut);
    if (!tb->ctx_lut) { PyErr_NoMemory(); return -1; }
    for (int k = 0; k < 8; k++)
        for (int q = 0; q < tb->nt[k]; q++) {
            const int t = tb->t[k][q];
            for (unsigned w = 0; w < 512; w++) {
                const int present = (w >> 8) & 1;
                const unsigned kf = (unsigned)popcount8(w & tb->kmask_f[k][t]);
                const unsigned ko = (unsigned)popcount8(w & tb->kmask_o[k][t]);
                const unsigned uf = (unsigned)(present * tb->ucnt_f[k][t]);
                const unsigned uo = (unsigned)(present * tb->ucnt_o[k][t]);
                const unsigned fine = kf * (7 * 21 * 21) + uf * (21 * 21) + ko * 21 + uo;
                const unsigned coarse = (kf + ko) * 27 + uf + uo;
                tb->ctx_lut[(k * 8 + q) * 512 + w] = fine | (coarse << 16);
            }
        }
    for (int i = 0; i < 65536; i++) {
        if (tb->p16_to_model[i] < 0 || tb->p16_to_model[i] >= tb->num_models) {
            PyErr_SetString(PyExc_ValueError, "P16_TO_MODEL entry out of range");
            return -1;
        }
    }
    return 0;
}

static void release_tables(OctTables *tb, Py_buffer *views, int n)
{
    free(tb->ctx_lut);
    tb->ctx_lut = NULL;
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

static void release_views(Py_buffer *views, int n)
{
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

PyDoc_STRVAR(octree_decode_doc,
"octree_decode(tables, depth, num_points, num_symbols, lanes, body) -> bytes\n\n"
"Decode the octree traversal (OCTREE.md §4) from a rANS payload whose lane count `lanes`\n"
"and word count were validated by the caller; `body` holds the 4*lanes state bytes followed\n"
"by the 16-bit words.  Returns the leaf Morton codes as little-endian uint64 bytes.  Checks\n"
"the end conditions of ENTROPY.md §4.4.  Raises GszFormatError on corrupt input.");

static PyObject *py_octree_decode(PyObject *self, PyObject *args)
{
    PyObject *tables, *body_obj;
    int depth;
    long long num_points, num_symbols, lanes;
    if (!PyArg_ParseTuple(args, "OiLLLO", &tables, &depth, &num_points, &num_symbols, &lanes,
                          &body_obj))
        return NULL;
    OctTables tb;
    Py_buffer views[6], body;
    int nviews;
    if (load_tables(&tb, tables, views, &nviews) < 0) { release_tables(&tb, views, nviews); return NULL; }
    if (getbuf(body_obj, &body, 1, 'x', 0, "octree payload") < 0) {
        release_tables(&tb, views, nviews);
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
        if (walk(&tb, depth, num_points, 0, &d, NULL, NULL, 0, NULL, &codes, &count, &e) == 0) {
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
    free(d.st);
    PyBuffer_Release(&body);
    release_tables(&tb, views, nviews);
    if (e.failed) { free(codes); return raise_err(&e); }
    PyObject *res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * 8));
    if (res && count) {
        uint8_t *o = (uint8_t *)PyBytes_AS_STRING(res);
        for (int64_t i = 0; i < count; i++)
            for (int b = 0; b < 8; b++) o[8 * i + b] = (uint8_t)(codes[i] >> (8 * b));
    }
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
    if (num_points > 0 && sizes.len / 8 != depth) {
        fail(&e, "octree encoder: one occupancy level per depth needed");
    } else {
        Py_BEGIN_ALLOW_THREADS
        walk(&tb, depth, num_points, 1, NULL, known.buf, sizes.buf, (int64_t)known.len, &out,
             &codes, &count, &e);
        Py_END_ALLOW_THREADS
    }
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
            uint64_t x = st[lane];
            if (x >= (f << (32 - prec))) {
                wb[--wi] = (uint16_t)(x & 0xFFFF);
                x >>= 16;
            }
            st[lane] = ((x / f) << prec) + (x % f) + c;
            if (--lane < 0) lane = lanes - 1;
        }
        Py_END_ALLOW_THREADS
        if (bad) { PyErr_SetString(PyExc_ValueError, "bank_encode: bit or model id out of range"); ok = 0; }
    }
    if (ok) {
        const int64_t nw = n - wi;
        uint8_t head[20];
        int hl = put_varint(head, (uint64_t)lanes);
        hl += put_varint(head + hl, (uint64_t)nw);
        res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(hl + 4 * lanes + 2 * nw));
        if (res) {
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
                o[2 * i] = wb[wi + i] & 0xFF;
                o[2 * i + 1] = wb[wi + i] >> 8;
            }
        }
    }
    free(st); free(wb);
    PyBuffer_Release(&bits); PyBuffer_Release(&models); PyBuffer_Release(&freq);
    return res;
}

/* ================================================================== generic rANS (ENTROPY.md §4.3) */
PyDoc_STRVAR(rans_decode_doc,
"rans_decode(mids, out, states, words, wpos, pos, lut, lut_base, mask, prec, value) -> wpos\n\n"
"Decode len(mids) symbols of an interleaved rANS payload with the tables of\n"
"gsz.decoder.rans.ModelSet.build(): symbol j (global index pos + j) on lane (pos + j) %% L,\n"
"L = len(states) (int64, updated in place); `words` = the payload's 16-bit words (LE bytes),\n"
"wpos = words consumed so far.  Writes the decoded values (int64) to `out`; returns the new\n"
"wpos.  Raises GszFormatError on a bad model id or an exhausted word stream.");

static PyObject *py_rans_decode(PyObject *self, PyObject *args)
{
    PyObject *o_mids, *o_out, *o_st, *o_words, *o_lut, *o_base, *o_mask, *o_prec, *o_value;
    long long wpos, pos;
    if (!PyArg_ParseTuple(args, "OOOOLLOOOOO", &o_mids, &o_out, &o_st, &o_words, &wpos, &pos,
                          &o_lut, &o_base, &o_mask, &o_prec, &o_value))
        return NULL;
    PyObject *objs[9] = {o_mids, o_out, o_st, o_words, o_lut, o_base, o_mask, o_prec, o_value};
    const Py_ssize_t isz[9] = {8, 8, 8, 1, 8, 8, 8, 8, 8};
    const int wr[9] = {0, 1, 1, 0, 0, 0, 0, 0, 0};
    Py_buffer v[9];
    int nv = 0;
    for (; nv < 9; nv++)
        if (getbuf(objs[nv], &v[nv], isz[nv], 'x', wr[nv], "rans_decode argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    const int64_t count = v[0].len / 8, lanes = v[2].len / 8, nwords = v[3].len / 2;
    const int64_t lut_len = v[4].len / 8, nmodels = v[5].len / 8, nvalues = v[8].len / 8;
    Err e = {0};
    if (v[1].len / 8 != count || v[6].len / 8 != nmodels || v[7].len / 8 != nmodels
        || lanes < 1 || wpos < 0 || wpos > nwords || pos < 0) {
        fail(&e, "rans_decode: inconsistent arguments");
    }
    if (!e.failed && count) {
        const int64_t *mids = v[0].buf, *lut = v[4].buf, *base = v[5].buf, *mask = v[6].buf;
        const int64_t *prec = v[7].buf, *value = v[8].buf;
        int64_t *out = v[1].buf, *st = v[2].buf;
        const uint8_t *words = v[3].buf;
        Py_BEGIN_ALLOW_THREADS
        int64_t lane = pos % lanes, w = wpos;
        for (int64_t j = 0; j < count; j++) {
            const int64_t m = mids[j];
            if (m < 0 || m >= nmodels) { fail(&e, "rANS: model id outside the model set"); break; }
            const int64_t mk = mask[m], n = prec[m];
            if (mk < 0) { fail(&e, "rANS: symbol refers to an empty model"); break; }
            if (n < 0 || n > 16) { fail(&e, "rANS: precision above 16"); break; }
            uint64_t x = (uint64_t)st[lane];
            const int64_t idx = base[m] + (int64_t)(x & (uint64_t)mk);
            if (base[m] < 0 || idx >= lut_len) { fail(&e, "rANS: decoding table index out of range"); break; }
            const int64_t ent = lut[idx];
            const int64_t g = ent >> 33;
            if (g < 0 || g >= nvalues) { fail(&e, "rANS: decoding table entry out of range"); break; }
            x = (uint64_t)((ent >> 16) & 0x1FFFF) * (x >> n) + (uint64_t)(ent & 0xFFFF);
            if (x < 65536u) {
                if (w >= nwords) { fail(&e, "rANS: payload truncated (word stream exhausted)"); break; }
                x = (x << 16) | rd_u16(words + 2 * w);
                w++;
            }
            st[lane] = (int64_t)x;
            out[j] = value[g];
            if (++lane == lanes) lane = 0;
        }
        wpos = w;
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    if (e.failed) return raise_err(&e);
    return PyLong_FromLongLong(wpos);
}

/* ================================================================== inverse RAHT (TRANSFORMS.md §2) */
PyDoc_STRVAR(raht_inverse_doc,
"raht_inverse(codes, depth, dc, ac, out)\n\n"
"Inverse RAHT of C channels over the N leaves with Morton codes `codes` (uint64, strictly\n"
"ascending, < 2^(3 depth)): dc float64 [C], ac float64 [C, N-1] (channel-major, stream/level\n"
"order), out float64 [N, C] (written).  Same tree and the same float64 operations in the same\n"
"order as gsz.decoder.raht (build_raht_tree + raht_inverse), so the result is bit-identical.");

typedef struct { int32_t left, right; double wl, wr; } Pair;

static PyObject *py_raht_inverse(PyObject *self, PyObject *args)
{
    PyObject *o_codes, *o_dc, *o_ac, *o_out;
    int depth;
    if (!PyArg_ParseTuple(args, "OiOOO", &o_codes, &depth, &o_dc, &o_ac, &o_out)) return NULL;
    Py_buffer vc, vdc, vac, vout;
    if (getbuf(o_codes, &vc, 8, 'x', 0, "codes") < 0) return NULL;
    if (getbuf(o_dc, &vdc, 8, 'f', 0, "dc") < 0) { PyBuffer_Release(&vc); return NULL; }
    if (getbuf(o_ac, &vac, 8, 'f', 0, "ac") < 0) { PyBuffer_Release(&vc); PyBuffer_Release(&vdc); return NULL; }
    if (getbuf(o_out, &vout, 8, 'f', 1, "out") < 0) {
        PyBuffer_Release(&vc); PyBuffer_Release(&vdc); PyBuffer_Release(&vac); return NULL;
    }
    const int64_t n = vc.len / 8, nch = vdc.len / 8;
    Err e = {0};
    if (n < 1 || n > INT32_MAX || nch < 1 || depth < 1 || depth > 21
        || vac.len / 8 != nch * (n - 1) || vout.len / 8 != nch * n)
        fail(&e, "RAHT inverse: inconsistent shapes");
    uint64_t *code = NULL;
    int32_t *slot = NULL;
    int64_t *wt = NULL, *lvl_start = NULL;
    Pair *pairs = NULL;
    if (!e.failed) {
        code = malloc((size_t)n * sizeof *code);
        slot = malloc((size_t)n * sizeof *slot);
        wt = malloc((size_t)n * sizeof *wt);
        pairs = malloc((size_t)(n > 1 ? n - 1 : 1) * sizeof *pairs);
        lvl_start = malloc((size_t)(3 * depth + 2) * sizeof *lvl_start);
        if (!code || !slot || !wt || !pairs || !lvl_start) fail_nomem(&e);
    }
    if (!e.failed) {
        const uint64_t *c0 = vc.buf;
        const double *dc = vdc.buf, *ac = vac.buf;
        double *v = vout.buf;
        Py_BEGIN_ALLOW_THREADS
        for (int64_t i = 0; i < n; i++) {
            if (i && c0[i] <= c0[i - 1]) { fail(&e, "Morton codes must be strictly ascending (sorted, unique)"); break; }
            code[i] = c0[i];
            slot[i] = (int32_t)i;
            wt[i] = 1;
        }
        if (!e.failed && (c0[n - 1] >> (3 * depth)))
            fail(&e, "Morton code exceeds 3*depth bits");
        /* bottom-up: the sibling pairs of every level, finest first */
        int64_t len = n, np_ = 0;
        int nlev = 0;
        for (int level = 0; !e.failed && level < 3 * depth && len > 1; level++) {
            const int64_t first = np_;
            int64_t o = 0;
            for (int64_t i = 0; i < len; ) {
                if (i + 1 < len && (code[i] >> 1) == (code[i + 1] >> 1)) {
                    pairs[np_].left = slot[i];
                    pairs[np_].right = slot[i + 1];
                    pairs[np_].wl = (double)wt[i];
                    pairs[np_].wr = (double)wt[i + 1];
                    np_++;
                    code[o] = code[i] >> 1;
                    slot[o] = slot[i];
                    wt[o] = wt[i] + wt[i + 1];
                    i += 2;
                } else {
                    code[o] = code[i] >> 1;
                    slot[o] = slot[i];
                    wt[o] = wt[i];
                    i += 1;
                }
                o++;
            }
            if (np_ > first) lvl_start[nlev++] = first;
            len = o;
        }
        lvl_start[nlev] = np_;
        if (!e.failed && (len != 1 || np_ != n - 1)) fail(&e, "RAHT tree did not reduce to a single root");
        if (!e.failed) {
            for (int64_t c = 0; c < nch; c++) v[c] = dc[c];
            /* top-down, coarsest level first; AC coefficients of a level are contiguous in the
             * stream (coarsest level first, ascending slot within a level) */
            int64_t acpos = 0;
            for (int L = nlev - 1; L >= 0; L--) {
                const int64_t a = lvl_start[L], b = lvl_start[L + 1];
                for (int64_t p = a; p < b; p++, acpos++) {
                    const Pair *pr = &pairs[p];
                    const double s = sqrt(pr->wl + pr->wr);
                    const double g1 = sqrt(pr->wl) / s, g2 = sqrt(pr->wr) / s;
                    double *lo = v + (int64_t)pr->left * nch, *hi = v + (int64_t)pr->right * nch;
                    for (int64_t c = 0; c < nch; c++) {
                        const double low = lo[c], high = ac[c * (n - 1) + acpos];
                        const double t1 = g1 * low, t2 = g2 * high;
                        const double t3 = g2 * low, t4 = g1 * high;
                        lo[c] = t1 - t2;
                        hi[c] = t3 + t4;
                    }
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    free(code); free(slot); free(wt); free(pairs); free(lvl_start);
    PyBuffer_Release(&vc); PyBuffer_Release(&vdc); PyBuffer_Release(&vac); PyBuffer_Release(&vout);
    if (e.failed) return raise_err(&e);
    Py_RETURN_NONE;
}

/* ================================================================== module */
static PyMethodDef methods[] = {
    {"octree_decode", py_octree_decode, METH_VARARGS, octree_decode_doc},
    {"octree_encode", py_octree_encode, METH_VARARGS, octree_encode_doc},
    {"bank_encode", py_bank_encode, METH_VARARGS, bank_encode_doc},
    {"rans_decode", py_rans_decode, METH_VARARGS, rans_decode_doc},
    {"raht_inverse", py_raht_inverse, METH_VARARGS, raht_inverse_doc},
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
