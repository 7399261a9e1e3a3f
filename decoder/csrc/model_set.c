/* gsz.decoder._native: model sets (ENTROPY.md §3.1-3.2) parsed and checked -- the same accept /
 * reject decision and arrays as gsz.decoder.rans.read_model_set + ModelSet.validate -- and
 * the plain varint runs of gsz.decoder.rans.read_varints (§2). */
#include "rans.h"

int64_t read_varints_run(const uint8_t *buf, int64_t len, int64_t pos, int64_t count, int64_t *out)
{
    const uint8_t *b = buf + pos;
    const int64_t avail = len - pos;
    const int64_t window = 9 * count < avail ? 9 * count : avail;
    /* pass 1: the terminators and the longest varint */
    int64_t found = 0, i = 0, start = 0, longest = 0;
    for (; i < window && found < count; i++) {
        if (b[i] < 0x80) {
            if (i - start + 1 > longest) longest = i - start + 1;
            start = i + 1;
            found++;
        }
    }
    if (found < count) return -1;
    if (longest > 9) return -2;
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
    return pos + j;
}

static inline int64_t unzigzag(int64_t u) { return (int64_t)((uint64_t)u >> 1) ^ -(u & 1); }

/* The per-model field arrays after the type list, in the serialised order: lo (non-empty),
 * span, precision (wide), coarse shape, centre (laplace), then the two ratio byte arrays;
 * 1 ok, 0 violation. */
static int msp_fields(const uint8_t *b, int64_t n, int64_t *p, int64_t M, int64_t nlap,
                      int64_t **arr)
{
    int64_t *type = arr[0], *lo = arr[1], *span = arr[2], *prec = arr[3], *group = arr[4];
    int64_t *bsh = arr[5], *centre = arr[6], *rl = arr[7], *rr = arr[8];
    int64_t v;
    for (int64_t m = 0; m < M; m++)
        if (type[m] != 0) { if (rd_varint9(b, n, p, &v) < 0) return 0; lo[m] = unzigzag(v); }
    for (int64_t m = 0; m < M; m++)
        if (type[m] >= 2 && rd_varint9(b, n, p, &span[m]) < 0) return 0;
    for (int64_t m = 0; m < M; m++)
        if (type[m] >= 2 && rd_varint9(b, n, p, &prec[m]) < 0) return 0;
    for (int64_t m = 0; m < M; m++)
        if (type[m] == 2) {
            if (rd_varint9(b, n, p, &v) < 0) return 0;
            group[m] = v & 3;
            bsh[m] = v >> 2;
        }
    for (int64_t m = 0; m < M; m++)
        if (type[m] == 3 && rd_varint9(b, n, p, &centre[m]) < 0) return 0;
    for (int side = 0; side < 2; side++) {
        if (nlap > n - *p) return 0;
        int64_t *r = side == 0 ? rl : rr;
        for (int64_t m = 0; m < M; m++)
            if (type[m] == 3) r[m] = b[(*p)++];
    }
    for (int64_t m = 0; m < M; m++)
        if (span[m] > 65536 || prec[m] > 16 || bsh[m] > 16) return 0;
    return 1;
}

/* The COARSE bin counts, bins and level codes (arr[9..11], allocated here); 1 ok, 0
 * violation, -1 out of memory. */
static int msp_coarse(const uint8_t *b, int64_t n, int64_t *p, int64_t M, int64_t nco,
                      int64_t **arr, int64_t *nb_out)
{
    const int64_t *type = arr[0], *span = arr[2], *bsh = arr[5];
    int64_t nb_total = 0, v;
    arr[9] = malloc((size_t)(nco ? nco : 1) * sizeof(int64_t));
    if (!arr[9]) return -1;
    int64_t *counts = arr[9];
    for (int64_t m = 0, ci = 0; m < M; m++) {
        if (type[m] != 2) continue;
        if (rd_varint9(b, n, p, &counts[ci]) < 0) return 0;
        if (counts[ci] < 1 || counts[ci] > (span[m] >> bsh[m]) + 1) return 0;
        nb_total += counts[ci++];
    }
    /* every count <= 65537, so nb_total < 2^37; each gap/delta takes >= 1 byte */
    if (2 * nb_total > n - *p) return 0;
    arr[10] = malloc((size_t)(nb_total ? nb_total : 1) * sizeof(int64_t));
    arr[11] = malloc((size_t)(nb_total ? nb_total : 1) * sizeof(int64_t));
    if (!arr[10] || !arr[11]) return -1;
    int64_t *bins = arr[10], *levels = arr[11];
    for (int64_t i = 0; i < nb_total; i++)
        if (rd_varint9(b, n, p, &bins[i]) < 0 || bins[i] > 65536) return 0;
    for (int64_t i = 0; i < nb_total; i++) {
        if (rd_varint9(b, n, p, &v) < 0) return 0;
        levels[i] = unzigzag(v);
        if (levels[i] > 65536 || levels[i] < -65536) return 0;
    }
    *nb_out = nb_total;
    return 1;
}

/* Running sums per model (gaps -> bins, deltas -> levels), then ModelSet.validate's checks. */
static int msp_validate(int64_t M, int64_t **arr)
{
    const int64_t *type = arr[0], *lo = arr[1], *span = arr[2], *prec = arr[3], *group = arr[4];
    const int64_t *bsh = arr[5], *centre = arr[6], *counts = arr[9];
    int64_t *bins = arr[10], *levels = arr[11];
    for (int64_t m = 0, ci = 0, i = 0; m < M; m++) {
        const int64_t t = type[m], sp = span[m], pr = prec[m];
        if (t != 0 && (lo[m] < -((int64_t)1 << 31) || lo[m] + sp >= ((int64_t)1 << 31))) return 0;
        if (t == 3 && (sp + 1 > ((int64_t)1 << pr) || centre[m] > sp)) return 0;
        if (t != 2) continue;
        const int64_t nb = counts[ci++], h = bsh[m], g = group[m];
        int64_t bprev = -1, qprev = 0, k = 0;
        for (int64_t j = 0; j < nb; j++, i++) {
            bprev += bins[i] + 1;
            qprev += levels[i];
            bins[i] = bprev;
            levels[i] = qprev;
            if (qprev < 1 || qprev > ((int64_t)25 << g)) return 0;
            const int64_t hi = ((bprev + 1) << h) < sp + 1 ? ((bprev + 1) << h) : sp + 1;
            k += hi - (bprev << h);
        }
        if (bins[i - nb] != 0 || bprev != (sp >> h) || k > ((int64_t)1 << pr)) return 0;
    }
    return 1;
}

int model_set_parse_run(const uint8_t *b, int64_t n, MsetParsed *out)
{
    int64_t p = 0, M = 0, nb_total = 0;
    int64_t **arr = out->arr;
    memset(out, 0, sizeof *out);
    if (rd_varint9(b, n, &p, &M) < 0 || M > ((int64_t)1 << 20) || M > n - p) return 0;
    for (int i = 0; i < 9; i++) {
        arr[i] = calloc((size_t)(M ? M : 1), sizeof(int64_t));
        if (!arr[i]) return -1;
    }
    int64_t nco = 0, nlap = 0;
    for (int64_t m = 0; m < M; m++) {
        if (rd_varint9(b, n, &p, &arr[0][m]) < 0 || arr[0][m] > 3) return 0;
        nco += arr[0][m] == 2;
        nlap += arr[0][m] == 3;
    }
    if (!msp_fields(b, n, &p, M, nlap, arr)) return 0;
    const int rc = msp_coarse(b, n, &p, M, nco, arr, &nb_total);
    if (rc <= 0) return rc;
    if (p != n) return 0;
    if (!msp_validate(M, arr)) return 0;
    const int64_t len[12] = {M, M, M, M, M, M, M, M, M, nco, nb_total, nb_total};
    memcpy(out->len, len, sizeof len);
    return 1;
}

void mset_parsed_free(MsetParsed *out)
{
    for (int i = 0; i < 12; i++) {
        free(out->arr[i]);
        out->arr[i] = NULL;
    }
}
