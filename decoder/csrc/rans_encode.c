/* gsz.decoder._native: rANS encoding (ENTROPY.md §4, run backwards) of generic symbols and of
 * the octree's binary decisions, byte-identical to gsz.encoder.rans._payload. */
#include "rans.h"

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

/* Lane states (all 2^16) and room for one word per symbol. */
static int renc_alloc(REnc *o, int64_t n, int64_t lanes, int big, Err *e)
{
    o->n = n;
    o->lanes = lanes;
    o->wi = n;
    o->st = malloc((size_t)lanes * sizeof *o->st);
    o->wb = big ? big_alloc((size_t)(n ? n : 1) * sizeof *o->wb)
                : malloc((size_t)(n ? n : 1) * sizeof *o->wb);
    if (!o->st || !o->wb) return fail_nomem(e);
    for (int64_t l = 0; l < lanes; l++) o->st[l] = 65536u;
    return 0;
}

void renc_free(REnc *o)
{
    free(o->st);
    free(o->wb);
    o->st = NULL;
    o->wb = NULL;
}

int rans_encode_run(const int64_t *f, const int64_t *c, const uint8_t *p, int64_t ne,
                    const void *idx, int idx_bytes, int64_t n, int64_t lanes, REnc *o, Err *e)
{
    if (renc_alloc(o, n, lanes, 1, e) < 0) return -1;
    uint64_t *st = o->st;
    int64_t lane = n ? (n - 1) % lanes : 0;
    const int32_t *idx32 = idx_bytes == 4 ? idx : NULL;
    const int64_t *idx64 = idx_bytes == 8 ? idx : NULL;
    for (int64_t j = n - 1; j >= 0; j--) {
        const int64_t g = idx32 ? (int64_t)idx32[j] : idx64 ? idx64[j] : j;
        if (g < 0 || g >= ne) return fail_value(e, "rans_encode: symbol entry out of range");
        /* a symbol of a valid model: prec <= 16 (0: a SINGLE model, f = 1), 1 <= f, c + f <= 2^prec */
        if (p[g] > 16 || f[g] < 1 || c[g] < 0 || c[g] + f[g] > ((int64_t)1 << p[g]))
            return fail_value(e, "rans_encode: symbol frequency out of range");
        st[lane] = rans_put(st[lane], (uint64_t)f[g], (uint64_t)c[g], p[g], o->wb, &o->wi);
        if (--lane < 0) lane = lanes - 1;
    }
    return 0;
}

int bank_encode_run(const uint8_t *bits, const uint8_t *models, int64_t n, const int64_t *f0,
                    int64_t nm, int prec, int64_t lanes, REnc *o, Err *e)
{
    if (renc_alloc(o, n, lanes, 0, e) < 0) return -1;
    uint64_t *st = o->st;
    const uint64_t total = (uint64_t)1 << prec;
    int64_t lane = (n - 1) % lanes;
    for (int64_t j = n - 1; j >= 0; j--) {
        const unsigned b = bits[j], m = models[j];
        if (b > 1 || m >= nm) return fail_value(e, "bank_encode: bit or model id out of range");
        const uint64_t fz = (uint64_t)f0[m];
        const uint64_t f = b ? total - fz : fz, c = b ? fz : 0;
        st[lane] = rans_put(st[lane], f, c, (unsigned)prec, o->wb, &o->wi);
        if (--lane < 0) lane = lanes - 1;
    }
    return 0;
}

int64_t rans_payload_size(const REnc *o)
{
    uint8_t head[20];
    const int hl = put_varint(head, (uint64_t)o->lanes) + put_varint(head, (uint64_t)(o->n - o->wi));
    return hl + 4 * o->lanes + 2 * (o->n - o->wi);
}

void rans_payload_write(const REnc *o, uint8_t *dst)
{
    const int64_t lanes = o->lanes, nw = o->n - o->wi;
    const uint16_t *w = o->wb + o->wi;
    dst += put_varint(dst, (uint64_t)lanes);
    dst += put_varint(dst, (uint64_t)nw);
    for (int64_t l = 0; l < lanes; l++) {
        const uint64_t x = o->st[l];
        dst[4 * l] = x & 0xFF; dst[4 * l + 1] = (x >> 8) & 0xFF;
        dst[4 * l + 2] = (x >> 16) & 0xFF; dst[4 * l + 3] = (x >> 24) & 0xFF;
    }
    dst += 4 * lanes;
    for (int64_t i = 0; i < nw; i++) {
        dst[2 * i] = w[i] & 0xFF;
        dst[2 * i + 1] = w[i] >> 8;
    }
}
