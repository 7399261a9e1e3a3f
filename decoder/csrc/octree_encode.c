/* gsz.decoder._native: octree encoding -- the traversal (octree_walk.c) over the known
 * occupancy bytes, recording every coded bit with the bank model it is coded with (the rANS
 * payload itself is rans_encode.c's bank_encode). */
#include "octree.h"

int octree_encode_run(const OctTables *tb, int depth, int64_t num_points, const uint8_t *known,
                      int64_t known_len, const int64_t *sizes, int64_t nsizes, DirectIn *di,
                      SymOut *out, uint64_t **codes_out, int64_t *count_out, Err *e)
{
    *codes_out = NULL;
    *count_out = 0;
    if (num_points > 0 && nsizes != depth)
        return fail(e, "octree encoder: one occupancy level per depth needed");
    Helper local;        /* no helper thread joins an encode: the traversal runs every block */
    helper_init(&local);
    const int rc = oct_walk(tb, depth, num_points, 1, NULL, known, sizes, known_len, di, out, &local,
                            codes_out, count_out, e);
    free(local.done_buf);
    return rc;
}
