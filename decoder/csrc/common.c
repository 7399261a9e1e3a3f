/* gsz.decoder._native: the shared error record, allocator and tables (gsz_common.h). */
#include "gsz_common.h"

int fail(Err *e, const char *msg)
{
    if (!e->failed) {
        e->failed = ERR_FORMAT;
        snprintf(e->msg, sizeof e->msg, "%s", msg);
    }
    return -1;
}

int fail_nomem(Err *e)
{
    if (!e->failed) e->failed = ERR_NOMEM;
    return -1;
}

int fail_value(Err *e, const char *msg)
{
    if (!e->failed) {
        e->failed = ERR_VALUE;
        snprintf(e->msg, sizeof e->msg, "%s", msg);
    }
    return -1;
}

/* The traversal's large tables.  Not marked for transparent huge pages: with THP defrag
 * "madvise" the first touch of each 2 MB page may compact memory in the kernel, which in a
 * fresh process cost more (and far more unevenly) than the TLB misses it saves
 * (docs/design/memory.md, "Small pages"). */
void *big_alloc(size_t size)
{
    return malloc(size ? size : 1);
}

const uint8_t POP8[256] = {
#define B2(n) n, n + 1, n + 1, n + 2
#define B4(n) B2(n), B2(n + 1), B2(n + 1), B2(n + 2)
#define B6(n) B4(n), B4(n + 1), B4(n + 1), B4(n + 2)
    B6(0), B6(1), B6(1), B6(2)
#undef B2
#undef B4
#undef B6
};
