/* gsz.decoder._native: the octree traversal (OCTREE.md §4) shared by octree_decode.c and
 * octree_encode.c -- its tables, the binary decoder it draws bits from in decode mode, the
 * output it records in encode mode, and the helper thread that may join it. */
#ifndef GSZ_OCTREE_H
#define GSZ_OCTREE_H

#include "gsz_common.h"

#define NUM_T 27
#define SELF_T 13
#define NUM_SIB 4
#define NUM_LB 4
#define NUM_COARSE (8 * 27 * 27 * NUM_SIB)
#define NUM_FINE (8 * 7 * 7 * 21 * 21 * NUM_SIB * NUM_LB)
#define NUM_DIRECT (8 * 4 * NUM_LB)   /* direct-flag contexts (OCTREE.md §4.1) */
#define MAX_CHUNK 65536
/* the largest point count the native traversal takes (its node indices are int32) */
#define OCT_MAX_POINTS (INT32_MAX / 2)

/* C11 atomics let a helper thread join the traversal (see Phase below) */
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


#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility push(hidden)
#endif

typedef struct {
    /* per child k: the parent-level offsets t whose node holds 26-neighbours of child k */
    int nt[8];
    int t[8][NUM_T];
    unsigned kmask_f[8][NUM_T], kmask_o[8][NUM_T];   /* known neighbour bits (< k), face / other */
    int ucnt_f[8][NUM_T], ucnt_o[8][NUM_T];          /* unknown neighbours (>= k) in that node */
    int child_par[8][NUM_T], child_idx[8][NUM_T];    /* neighbour table derivation */
    uint8_t cp8[8][NUM_T], ci8[8][NUM_T];            /* the same as bytes */
    /* child k's 26-neighbours among the children of its parent's neighbours: the nno[k]
     * parent-level offsets nto[k][q] (its octant, the parent included) and, per offset, the
     * child bits that are neighbours of child k (nmask; child k itself excluded) */
    int nno[8];
    uint8_t nto[8][8], nmask[8][NUM_T];
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

/* Direct coding (scheme 1, OCTREE.md §4.1): from level `from` on, nodes holding one voxel
 * leave the tree with their remaining Morton bits.  from = 0: scheme 0 (none).  Decode mode
 * reads those bits from the raw section; encode mode takes the flags (one byte per node of
 * every level >= from, in tree order) and the values (level order) it is given. */
typedef struct {
    int from;
    const uint8_t *raw;
    int64_t raw_len, raw_pos;
    const uint8_t *kflags;
    int64_t kflags_len, kflags_off;
    const uint64_t *kvals;
    int64_t kvals_len, kvals_off;
} DirectIn;

/* Growable byte output (encoder mode: the coded bits and their model ids). */
typedef struct {
    uint8_t *bits, *models;
    int64_t len, cap;
} SymOut;

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
#define CTX_BLOCK 2048      /* nodes per context block */
#define BUILD_BLOCK 1024    /* parents per neighbour-table block */

enum { PHASE_CTX = 1, PHASE_BUILD = 2, PHASE_ROWS = 3 };

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
    /* PHASE_BUILD: children of parents [r0, r1): codes and neighbour rows, or (prow) codes and
     * each child's parent row, parents then being the rows (ranks) of the nodes in the tree */
    const int64_t *start;
    const uint64_t *codes;
    uint64_t *ncodes;
    int32_t *nnbr;
    int32_t *prow;
    int64_t total;
    int last, ranks;
    /* the level's nodes in the tree (direct coding): row r holds node keep[r] (NULL: node r);
     * PHASE_CTX: compact = rows are the plane's positions (crow NULL) or crow[i] */
    const int32_t *keep, *crow;
    int compact;
    /* PHASE_ROWS: rows of the level's nodes in the tree from their parents' (parent level's
     * rows `nbr`, start `start`; this level's codes, child parent rows prow, count total) */
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

/* The tables passed from Python (decoder/native.py::octree_tables), as int64 arrays:
 * plan_known / plan_unknown [2, 8, 27], child_par / child_idx [8, 27], p16 [65536], freq0
 * [num_models]. */
typedef struct {
    const int64_t *plan_known, *plan_unknown, *child_par, *child_idx, *p16, *freq0;
    int64_t num_models;
    int prec;
    int64_t chunk_min, chunk_max, count_limit, mix_weight;
} OctTableArgs;

/* octree_walk.c */
void octree_static_init(void);
/* Check the tables and derive the traversal's (ctx_lut, p16m); on failure a ValueError or
 * MemoryError in *e.  oct_tables_free releases what was derived (also after a failure). */
int oct_tables_build(OctTables *tb, const OctTableArgs *a, Err *e);
void oct_tables_free(OctTables *tb);
void helper_init(Helper *h);
void helper_loop(Helper *h);
void helper_close(Helper *h);
int oct_walk(const OctTables *tb, int depth, int64_t num_points, int mode, BinDec *dec,
             const uint8_t *known, const int64_t *known_sizes, int64_t known_len, DirectIn *di,
             SymOut *out, Helper *h, uint64_t **codes_out, int64_t *count_out, Err *e);

/* octree_decode.c */
/* Decode the traversal from a payload `body` (4*lanes state bytes, then the 16-bit words),
 * checking ENTROPY.md §4.4's end conditions; *codes_out (free()) the leaf Morton codes.
 * Closes the helper `h` when the traversal ends.  Runs without the GIL. */
int octree_decode_run(const OctTables *tb, int depth, int64_t num_points, int64_t num_symbols,
                      int64_t lanes, const uint8_t *body, int64_t body_len, DirectIn *di, Helper *h,
                      uint64_t **codes_out, int64_t *count_out, Err *e);

/* octree_encode.c */
/* The traversal over known occupancy bytes: the coded bits and their model ids in *out, the
 * leaf codes in *codes_out (free() both).  Runs without the GIL. */
int octree_encode_run(const OctTables *tb, int depth, int64_t num_points, const uint8_t *known,
                      int64_t known_len, const int64_t *sizes, int64_t nsizes, DirectIn *di,
                      SymOut *out, uint64_t **codes_out, int64_t *count_out, Err *e);

/* ------------------------------------------------------------------ the binary decoder
 * (inline: the traversal calls it once per decision) */
/* One decision (ENTROPY.md §4.3 specialised to two symbols: value 0 owns slots [0, f0),
 * value 1 slots [f0, 2^n)); the bit, or -1 (error set). */
static inline int oct_bin_decode(BinDec *d, const OctTables *tb, int64_t model, Err *e)
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

/* The same step for `len` decisions with models `models`, bits to `bits`: the caller checked
 * that enough symbols and words are left (at most one word per symbol), so no per-symbol
 * checks. */
static inline void oct_bin_decode_chunk(BinDec *d, const OctTables *tb, const uint8_t *models,
                                        uint8_t *bits, int64_t len)
{
    uint64_t *restrict st = d->st;
    const uint8_t *restrict words = d->words;
    const unsigned pn = (unsigned)tb->prec;
    const uint64_t ptot = (uint64_t)1 << pn, pmask = ptot - 1;
    const int64_t lanes = d->lanes;
    int64_t lane = d->lane, w = d->wpos;
    for (int64_t i = 0; i < len; i++) {
        uint64_t x = st[lane];
        const uint64_t z = x & pmask, f0 = (uint64_t)tb->freq0[models[i]];
        const uint64_t bit = z >= f0;
        const uint64_t f = bit ? ptot - f0 : f0, c = bit ? f0 : 0;
        x = f * (x >> pn) + (z - c);
        const uint64_t need = x < 65536u;
        x = (x << (need << 4)) | (rd_u16(words + 2 * w) & (0 - need));
        w += (int64_t)need;
        st[lane] = x;
        lane = lane + 1 == lanes ? 0 : lane + 1;
        bits[i] = (uint8_t)bit;
    }
    d->lane = lane;
    d->wpos = w;
    d->pos += len;
}

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility pop
#endif

#endif
