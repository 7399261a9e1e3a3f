/*
 * gsz.decoder._native -- what every stage of the C accelerator shares: the error record that
 * crosses the GIL-free loops, the large-buffer allocator, little-endian and varint readers,
 * the byte popcount.
 *
 * Layout (like zstd's lib/common + lib/decompress): this header and common.c; one file per
 * stage -- octree_walk.c (the traversal both directions share), octree_decode.c,
 * octree_encode.c, rans_decode.c, rans_encode.c, model_set.c, raht.c, assemble.c, rate.c --
 * none of which uses the Python C API; module.c parses the Python arguments, releases the GIL
 * around the stage calls and builds the results.
 *
 * The NumPy modules stay the normative reference (format_spec/OCTREE.md, ENTROPY.md,
 * TRANSFORMS.md); the stages implement exactly the same integer arithmetic, scalar instead of
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
 * Compile without floating-point contraction (-ffp-contract=off, see setup.py): the inverse
 * RAHT must round exactly like NumPy's separate multiply and add.
 */
#ifndef GSZ_COMMON_H
#define GSZ_COMMON_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Bumped whenever a signature changes, so a stale build is ignored (decoder/native.py). */
#define GSZ_NATIVE_ABI 20

/* the stages' functions are internal to the extension: not exported from the shared object */
#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility push(hidden)
#endif

/* ------------------------------------------------------------------ errors without the GIL */
enum { ERR_NONE = 0, ERR_FORMAT = 1, ERR_NOMEM = 2, ERR_VALUE = 3 };

typedef struct {
    int failed;      /* ERR_NONE, or the exception to raise: GszFormatError, MemoryError, ValueError */
    char msg[240];
} Err;

/* Record a GszFormatError (the first failure wins); returns -1. */
int fail(Err *e, const char *msg);
/* Record a MemoryError; returns -1. */
int fail_nomem(Err *e);
/* Record a ValueError (a caller's inconsistent arguments, not corrupt data); returns -1. */
int fail_value(Err *e, const char *msg);

/* malloc for large work buffers (free() releases it); see common.c. */
void *big_alloc(size_t size);

/* ------------------------------------------------------------------ readers */
static inline uint32_t rd_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static inline uint32_t rd_u16(const uint8_t *p) { return (uint32_t)p[0] | ((uint32_t)p[1] << 8); }

/* one unsigned LEB128 varint (ENTROPY.md §2) of at most 9 bytes from b[*p..n); -1 when
 * truncated or too long */
static inline int rd_varint9(const uint8_t *b, int64_t n, int64_t *p, int64_t *out)
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

/* bit counts of a byte (a table: portable, and faster than a popcount call on CPUs where the
 * compiler may not assume the POPCNT instruction) */
extern const uint8_t POP8[256];

static inline int popcount8(unsigned v) { return POP8[v & 0xFFu]; }

#if defined(__GNUC__) && !defined(_WIN32)
#pragma GCC visibility pop
#endif

#endif
