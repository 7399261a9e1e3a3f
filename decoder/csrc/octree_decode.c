/* gsz.decoder._native: octree decoding -- the payload's lanes and start states, the traversal
 * (octree_walk.c) drawing its bits from the binary decoder of octree.h, and the end conditions
 * (ENTROPY.md §4). */
#include "octree.h"

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
                      int64_t lanes, const uint8_t *body, int64_t body_len, DirectIn *di, Helper *h,
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
        const int wrc = oct_walk(tb, depth, num_points, 0, &d, NULL, NULL, 0, di, NULL, h, codes_out,
                                 count_out, e);
        helper_close(h);        /* the helper's thread can go on with its own work */
        if (wrc == 0) oct_end_conditions(&d, e);
        if (wrc == 0 && !e->failed && di->from && di->raw_pos != di->raw_len) {
            snprintf(e->msg, sizeof e->msg, "octree payload: %lld bytes of the raw section left unread",
                     (long long)(di->raw_len - di->raw_pos));
            e->failed = ERR_FORMAT;
        }
    }
    free(d.st);
    return e->failed ? -1 : 0;
}
