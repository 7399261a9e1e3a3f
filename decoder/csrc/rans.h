/* gsz.decoder._native: rANS (ENTROPY.md §3-4) -- model-set parsing (model_set.c), the native
 * decoding tables and decode loops (rans_decode.c), the encoders (rans_encode.c). */
#ifndef GSZ_RANS_H
#define GSZ_RANS_H

#include "gsz_common.h"

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility push(hidden)
#endif

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
/* the largest model precision n (ENTROPY.md 3.2): a model's LUT has at most 2^16 slots */
#define MAX_PREC_BITS 16

/* A model set's parameters (int64 arrays of M models; nbins / bins / levels: the COARSE
 * models' present-bin counts, bins and level codes, concatenated in model order). */
typedef struct {
    const int64_t *type, *lo, *span, *prec, *group, *bshift, *centre, *rl, *rr;
    const int64_t *nbins, *bins, *levels;
    int64_t M, ncoarse, nball;
} MsetParams;

/* The compact tables of one model set, as described above (lut_base / sym_base: int64 [M]). */
typedef struct {
    uint16_t *lut;
    uint32_t *fc;
    int32_t *val;
    int64_t *lut_base, *sym_base;
    uint8_t *mprec;
} MsetTables;

/* The same tables as the decode loops read them (lut NULL, lut_len 0: made without a LUT;
 * the block decoder then makes each model's LUT as it needs it). */
typedef struct {
    const uint16_t *lut;
    const uint32_t *fc;
    const int32_t *val;
    const int64_t *lbase, *sbase;
    const uint8_t *mprec;
    int64_t lut_len, nsym, nmodels;
} RTab;

/* Decoder state of one payload: lane states (int64, the RansDecoder's array), the words. */
typedef struct {
    int64_t *st;
    int64_t lanes, lane;
    const uint8_t *words;
    int64_t nwords, w;
} RState;

/* A quantised channel set's block layout and, for dequantisation, its groups' parameters. */
typedef struct {
    const int64_t *tab;                      /* model id per (channel, block) [C*B] */
    int64_t C, L, B;
    const double *steps, *lo;                /* [C*B], NULL: no dequantisation */
    const int64_t *qmax;
    int64_t *iout;                           /* [C*L] without dequantisation */
    double *fout;                            /* [C*L] with */
    uint16_t *uout;                          /* [C*L] symbols checked against qmax, not
                                                dequantised (steps NULL, iout NULL) */
} RBlocks;

/* model_set.c: the 12 arrays of model_set_parse (9 of M models, counts, bins, levels). */
typedef struct {
    int64_t *arr[12];
    int64_t len[12];
} MsetParsed;

/* 1 parsed and valid, 0 any violation, -1 out of memory; mset_parsed_free in every case. */
int model_set_parse_run(const uint8_t *b, int64_t n, MsetParsed *out);
void mset_parsed_free(MsetParsed *out);
/* gsz.decoder.rans.read_varints: the new position, -1 truncated, -2 a varint over 9 bytes. */
int64_t read_varints_run(const uint8_t *buf, int64_t len, int64_t pos, int64_t count, int64_t *out);

/* rans_decode.c */
/* Pass 1 over a model set: validate, count LUT slots and present values (<= max_lut). */
int rans_tables_count(const MsetParams *p, int64_t max_lut, int64_t *lut_total,
                      int64_t *sym_total, Err *e);
/* Pass 2: fill the tables (sized by rans_tables_count). */
int rans_tables_fill(const MsetParams *p, const MsetTables *o, Err *e);
/* count symbols with models mids into out (s->lane set by the caller). */
int rans_decode_run(const RTab *t, RState *s, const int64_t *mids, int64_t *out, int64_t count,
                    Err *e);
int rans_decode_blocks_run(const RTab *t, RState *s, const RBlocks *b, Err *e);
/* Whether the block loop may use AVX2 where the CPU has it: on 0 no, 1 yes, -1 ask; returns the
 * setting before the call (0 on builds without the AVX2 loop).  Called once at module init. */
int rans_simd(int on);

/* rans_encode.c: the encoders' final lane states and words (words in wb[wi..n)). */
typedef struct {
    uint64_t *st;
    uint16_t *wb;
    int64_t lanes, wi, n;
} REnc;

/* Symbol j has frequency f[g], cumulative frequency c[g] and precision p[g] with g = idx[j]
 * (idx NULL: g = j), 0 <= g < ne; idx holds int32 (idx_bytes 4) or int64 (8) entries. */
int rans_encode_run(const int64_t *f, const int64_t *c, const uint8_t *p, int64_t ne,
                    const void *idx, int idx_bytes, int64_t n, int64_t lanes, REnc *o, Err *e);
int bank_encode_run(const uint8_t *bits, const uint8_t *models, int64_t n, const int64_t *f0,
                    int64_t nm, int prec, int64_t lanes, REnc *o, Err *e);
void renc_free(REnc *o);
/* The payload (varint lanes, varint word count, lane states, words) and its size. */
int64_t rans_payload_size(const REnc *o);
void rans_payload_write(const REnc *o, uint8_t *dst);

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility pop
#endif

#endif
