/* gsz.decoder._native: octree decoding -- the binary rANS decoder over the bank models that
 * feeds the traversal (octree_walk.c) its bits, and the payload's start and end conditions
 * (ENTROPY.md §4). */
#include "octree.h"

/* One decision (ENTROPY.md §4.3 specialised to two symbols: value 0 owns slots [0, f0),
 * value 1 slots [f0, 2^n)); the bit, or -1 (error set). */
int oct_bin_decode(BinDec *d, const OctTables *tb, int64_t model, Err *e)
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
void oct_bin_decode_chunk(BinDec *d, const OctTables *tb, const uint8_t *models, uint8_t *bits,
                          int64_t len)
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

/* ENTROPY.md §4.4: every symbol decoded, every word read, every lane back at 2^16. */
static void oct_end_conditions(const BinDec *d, Err *e)
{
    if (d->pos != d->nsym) fail(e, "rANS: symbols left undecoded");
    else if (d->wpos != d->nwords) fail(e, "rANS: words left unread");
    else {
        for (int64_t l = 0; l < d->lanes; l++)
            if (d->st[l] != 65536u) { fail(e, "rANS: final states differ from 2**16 (corrupt payload)"); break; }
    }
}

int octree_decode_run(const OctTables *tb, int depth, int64_t num_points, int64_t num_symbols,
                      int64_t lanes, const uint8_t *body, int64_t body_len, Helper *h,
                      uint64_t **codes_out, int64_t *count_out, Err *e)
{
    BinDec d;
    memset(&d, 0, sizeof d);
    *codes_out = NULL;
    *count_out = 0;
    if (lanes < 1 || lanes > (num_symbols > 1 ? num_symbols : 1) || num_symbols < 0
        || 4 * lanes > body_len || (body_len - 4 * lanes) % 2)
        return fail(e, "rANS: lane count or payload length invalid");
    d.st = malloc((size_t)lanes * sizeof *d.st);
    if (!d.st) return fail_nomem(e);
    d.lanes = lanes;
    d.words = body + 4 * lanes;
    d.nwords = (body_len - 4 * lanes) / 2;
    d.nsym = num_symbols;
    for (int64_t l = 0; l < lanes; l++) {
        d.st[l] = rd_u32(body + 4 * l);
        if (d.st[l] < 65536u) fail(e, "rANS: initial state below 2**16");
    }
    if (!e->failed) {
        const int wrc = oct_walk(tb, depth, num_points, 0, &d, NULL, NULL, 0, NULL, h, codes_out,
                                 count_out, e);
        helper_close(h);        /* the helper's thread can go on with its own work */
        if (wrc == 0) oct_end_conditions(&d, e);
    }
    free(d.st);
    return e->failed ? -1 : 0;
}
