/*
 * gsz.decoder._native -- the module: every py_* function parses and checks its Python
 * arguments (buffer protocol only, no NumPy headers), calls its stage (releasing the GIL
 * around the loops) and turns the result or the stage's Err into Python objects.  The stages
 * themselves are the other files of this folder (see gsz_common.h).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "gsz_common.h"
#include "octree.h"
#include "rans.h"
#include "stages.h"

static PyObject *FormatError = NULL;   /* gsz.decoder.errors.GszFormatError */

/* ------------------------------------------------------------------ errors and buffers */
static PyObject *raise_err(const Err *e)
{
    if (e->failed == ERR_NOMEM) return PyErr_NoMemory();
    if (e->failed == ERR_VALUE) {
        PyErr_SetString(PyExc_ValueError, e->msg);
        return NULL;
    }
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
/* itemsize ITEM_4_OR_8: 4- or 8-byte elements (the caller reads v->itemsize) */
#define ITEM_4_OR_8 (-48)

static int getbuf(PyObject *o, Py_buffer *v, Py_ssize_t itemsize, char kind, int writable,
                  const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(o, v, flags) < 0) return -1;
    char k = fmt_kind(v);
    int kind_ok = (kind == 'x') ? (k == 'i' || k == 'u') : (k == kind);
    int size_ok = itemsize == ITEM_4_OR_8 ? (v->itemsize == 4 || v->itemsize == 8)
                                          : v->itemsize == itemsize;
    if (!size_ok || !kind_ok) {
        if (itemsize == ITEM_4_OR_8)
            PyErr_Format(PyExc_TypeError, "%s: expected a contiguous buffer of 4- or 8-byte "
                         "integer elements", what);
        else
            PyErr_Format(PyExc_TypeError, "%s: expected a contiguous buffer of %zd-byte %s elements",
                         what, itemsize, kind == 'f' ? "float" : "integer");
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

static void release_views(Py_buffer *views, int n)
{
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

/* ================================================================== octree */
/* Parse and check the tables passed from Python (decoder/native.py::octree_tables). */
static int load_tables(OctTables *tb, PyObject *tables, Py_buffer *views, int *nviews)
{
    PyObject *plan_known, *plan_unknown, *child_par, *child_idx, *p16, *freq0;
    long long cmin, cmax, climit, mix;
    int prec;
    *nviews = 0;
    tb->ctx_lut = NULL;
    tb->p16m = NULL;
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
    const OctTableArgs a = {views[0].buf, views[1].buf, views[2].buf, views[3].buf, views[4].buf,
                            views[5].buf, (int64_t)(views[5].len / 8), prec, cmin, cmax, climit,
                            mix};
    Err e = {0};
    if (oct_tables_build(tb, &a, &e) < 0) {
        raise_err(&e);
        return -1;
    }
    return 0;
}

static void release_tables(OctTables *tb, Py_buffer *views, int n)
{
    oct_tables_free(tb);
    release_views(views, n);
}

#define HELPER_CAPSULE "gsz.decoder._native.octree_helper"

typedef struct {
    Helper h;
    int used;            /* handed to an octree_decode already */
} HelperBox;

static void helper_capsule_free(PyObject *cap)
{
    HelperBox *b = PyCapsule_GetPointer(cap, HELPER_CAPSULE);
    if (b) { free(b->h.done_buf); free(b); }
}

PyDoc_STRVAR(octree_helper_doc,
"octree_helper() -> helper\n\n"
"A fresh helper slot for one octree_decode(): another thread calling octree_help(helper)\n"
"joins that traversal (context ids and neighbour rows) until it ends or octree_helper_close()\n"
"is called.  Same output with or without a helper.");

static PyObject *py_octree_helper(PyObject *self, PyObject *noargs)
{
    HelperBox *b = calloc(1, sizeof *b);
    if (!b) return PyErr_NoMemory();
    helper_init(&b->h);
    PyObject *cap = PyCapsule_New(b, HELPER_CAPSULE, helper_capsule_free);
    if (!cap) free(b);
    return cap;
}

PyDoc_STRVAR(octree_help_doc,
"octree_help(helper)\n\n"
"Work on the traversal the helper was given to (without the GIL) until it ends or the helper\n"
"is closed; returns at once when it already is.  Returns immediately on builds without C11\n"
"atomics.");

static PyObject *py_octree_help(PyObject *self, PyObject *arg)
{
    HelperBox *b = PyCapsule_GetPointer(arg, HELPER_CAPSULE);
    if (!b) return NULL;
    Py_BEGIN_ALLOW_THREADS
    helper_loop(&b->h);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyDoc_STRVAR(octree_helper_close_doc,
"octree_helper_close(helper)\n\n"
"Let every octree_help(helper) return (idempotent; octree_decode does it when it ends).");

static PyObject *py_octree_helper_close(PyObject *self, PyObject *arg)
{
    HelperBox *b = PyCapsule_GetPointer(arg, HELPER_CAPSULE);
    if (!b) return NULL;
    helper_close(&b->h);
    Py_RETURN_NONE;
}

/* codes as little-endian uint64 bytes */
static PyObject *codes_bytes(const uint64_t *codes, int64_t count)
{
    const uint16_t one = 1;
    uint8_t little;
    memcpy(&little, &one, 1);
    PyObject *res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * 8));
    if (res && count) {
        uint8_t *o = (uint8_t *)PyBytes_AS_STRING(res);
        if (little == 1) {
            memcpy(o, codes, (size_t)count * 8);
        } else {
            for (int64_t i = 0; i < count; i++)
                for (int b = 0; b < 8; b++) o[8 * i + b] = (uint8_t)(codes[i] >> (8 * b));
        }
    }
    return res;
}

PyDoc_STRVAR(octree_decode_doc,
"octree_decode(tables, depth, num_points, num_symbols, lanes, body, helper=None, direct_from=0,\n"
"              raw=b'') -> bytes\n\n"
"Decode the octree traversal (OCTREE.md §4) from a rANS payload whose lane count `lanes`\n"
"and word count were validated by the caller; `body` holds the 4*lanes state bytes followed\n"
"by the 16-bit words.  Returns the leaf Morton codes as little-endian uint64 bytes.  Checks\n"
"the end conditions of ENTROPY.md §4.4.  Raises GszFormatError on corrupt input.  `helper`:\n"
"an unused octree_helper() that another thread may join with octree_help(); it is closed\n"
"when the traversal ends.  direct_from > 0: scheme 1 (OCTREE.md §4.1), `raw` its raw section.");

static PyObject *py_octree_decode(PyObject *self, PyObject *args)
{
    PyObject *tables, *body_obj, *helper_obj = Py_None, *raw_obj = NULL;
    int depth, direct_from = 0;
    long long num_points, num_symbols, lanes;
    if (!PyArg_ParseTuple(args, "OiLLLO|OiO", &tables, &depth, &num_points, &num_symbols, &lanes,
                          &body_obj, &helper_obj, &direct_from, &raw_obj))
        return NULL;
    Py_buffer raw = {0};
    if (raw_obj && getbuf(raw_obj, &raw, 1, 'x', 0, "octree raw section") < 0) return NULL;
    DirectIn di = {0};
    di.from = direct_from;
    di.raw = raw.buf;
    di.raw_len = raw_obj ? (int64_t)raw.len : 0;
    HelperBox *hb = NULL;
    if (helper_obj != Py_None) {
        hb = PyCapsule_GetPointer(helper_obj, HELPER_CAPSULE);
        if (!hb) return NULL;
        if (hb->used) {
            PyErr_SetString(PyExc_ValueError, "octree_decode: this helper was used already");
            if (raw_obj) PyBuffer_Release(&raw);
            return NULL;
        }
        hb->used = 1;
    }
    Helper local;
    helper_init(&local);
    Helper *h = hb ? &hb->h : &local;
    OctTables tb;
    Py_buffer views[6], body;
    int nviews;
    if (load_tables(&tb, tables, views, &nviews) < 0 || getbuf(body_obj, &body, 1, 'x', 0, "octree payload") < 0) {
        release_tables(&tb, views, nviews);
        helper_close(h);
        if (raw_obj) PyBuffer_Release(&raw);
        return NULL;
    }
    Err e = {0};
    uint64_t *codes = NULL;
    int64_t count = 0;
    Py_BEGIN_ALLOW_THREADS
    octree_decode_run(&tb, depth, num_points, num_symbols, lanes, body.buf, (int64_t)body.len, &di,
                      h, &codes, &count, &e);
    Py_END_ALLOW_THREADS
    helper_close(h);
    PyBuffer_Release(&body);
    if (raw_obj) PyBuffer_Release(&raw);
    release_tables(&tb, views, nviews);
    if (!hb) free(local.done_buf);
    if (e.failed) { free(codes); return raise_err(&e); }
    PyObject *res = codes_bytes(codes, count);
    free(codes);
    return res;
}

PyDoc_STRVAR(octree_encode_doc,
"octree_encode(tables, depth, num_points, known, known_sizes, direct_from=0, flags=b'',\n"
"              values=b'') -> (bits, models, codes)\n\n"
"Run the traversal with the known occupancy bytes (`known`: every level's bytes concatenated,\n"
"`known_sizes`: int64 node count per level).  Returns the coded bits and their bank model ids\n"
"(uint8 bytes each, in coding order) and the leaf Morton codes (uint64 LE bytes).  direct_from\n"
"> 0: scheme 1 (OCTREE.md §4.1) with the direct flags (uint8, every node of each level from\n"
"direct_from on) and the direct nodes' values (uint64, level order).");

static PyObject *py_octree_encode(PyObject *self, PyObject *args)
{
    PyObject *tables, *known_obj, *sizes_obj, *flags_obj = NULL, *vals_obj = NULL;
    int depth, direct_from = 0;
    long long num_points;
    if (!PyArg_ParseTuple(args, "OiLOO|iOO", &tables, &depth, &num_points, &known_obj, &sizes_obj,
                          &direct_from, &flags_obj, &vals_obj))
        return NULL;
    OctTables tb;
    Py_buffer views[6], known, sizes, flags = {0}, vals = {0};
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
    if ((flags_obj && getbuf(flags_obj, &flags, 1, 'x', 0, "direct flags") < 0)
        || (vals_obj && getbuf(vals_obj, &vals, 8, 'u', 0, "direct values") < 0)) {
        if (flags.obj) PyBuffer_Release(&flags);
        PyBuffer_Release(&known);
        PyBuffer_Release(&sizes);
        release_tables(&tb, views, nviews);
        return NULL;
    }
    DirectIn di = {0};
    di.from = direct_from;
    di.kflags = flags.buf;
    di.kflags_len = flags_obj ? (int64_t)flags.len : 0;
    di.kvals = vals.buf;
    di.kvals_len = vals_obj ? (int64_t)(vals.len / 8) : 0;
    Err e = {0};
    uint64_t *codes = NULL;
    int64_t count = 0;
    SymOut out = {0};
    Py_BEGIN_ALLOW_THREADS
    octree_encode_run(&tb, depth, num_points, known.buf, (int64_t)known.len, sizes.buf,
                      (int64_t)(sizes.len / 8), &di, &out, &codes, &count, &e);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&known);
    PyBuffer_Release(&sizes);
    if (flags_obj) PyBuffer_Release(&flags);
    if (vals_obj) PyBuffer_Release(&vals);
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

/* ================================================================== rANS encoders */
/* The payload bytes of a finished encoder (rans_payload_write). */
static PyObject *payload_bytes(const REnc *o)
{
    PyObject *res = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)rans_payload_size(o));
    if (res) rans_payload_write(o, (uint8_t *)PyBytes_AS_STRING(res));
    return res;
}

PyDoc_STRVAR(rans_encode_doc,
"rans_encode(freq, cum, shift, lanes[, index]) -> bytes\n\n"
"ENTROPY.md §4 payload of symbols given, in stream order, by their frequency freq (int64),\n"
"cumulative frequency cum (int64) and model precision shift (uint8), over `lanes` interleaved\n"
"lanes: byte-identical to gsz.encoder.rans._payload.  With `index` (int32 or int64, one per\n"
"symbol) the three arrays are tables and symbol j takes their entry index[j] (no per-symbol\n"
"copies).");

static PyObject *py_rans_encode(PyObject *self, PyObject *args)
{
    PyObject *freq_obj, *cum_obj, *shift_obj, *index_obj = Py_None;
    long long lanes;
    if (!PyArg_ParseTuple(args, "OOOL|O", &freq_obj, &cum_obj, &shift_obj, &lanes, &index_obj))
        return NULL;
    Py_buffer fb, cb, sb, ib = {0};
    if (getbuf(freq_obj, &fb, 8, 'i', 0, "freq") < 0) return NULL;
    if (getbuf(cum_obj, &cb, 8, 'i', 0, "cum") < 0) { PyBuffer_Release(&fb); return NULL; }
    if (getbuf(shift_obj, &sb, 1, 'x', 0, "shift") < 0) {
        PyBuffer_Release(&fb); PyBuffer_Release(&cb); return NULL;
    }
    const int indexed = index_obj != Py_None;
    /* int32 entries where the caller has them: half the memory of a 54 M-symbol channel set */
    if (indexed && getbuf(index_obj, &ib, ITEM_4_OR_8, 'i', 0, "index") < 0) {
        PyBuffer_Release(&fb); PyBuffer_Release(&cb); PyBuffer_Release(&sb); return NULL;
    }
    const int ibytes = indexed ? (int)ib.itemsize : 8;
    const int64_t ne = fb.len / 8, n = indexed ? ib.len / ibytes : ne;
    PyObject *res = NULL;
    REnc enc = {0};
    Err e = {0};
    if (cb.len / 8 != ne || sb.len != ne || lanes < 1 || lanes > (n > 1 ? n : 1)) {
        PyErr_SetString(PyExc_ValueError, "rans_encode: inconsistent arguments");
    } else {
        const void *idx = indexed ? ib.buf : NULL;
        Py_BEGIN_ALLOW_THREADS
        rans_encode_run(fb.buf, cb.buf, sb.buf, ne, idx, ibytes, n, lanes, &enc, &e);
        Py_END_ALLOW_THREADS
        res = e.failed ? raise_err(&e) : payload_bytes(&enc);
    }
    renc_free(&enc);
    PyBuffer_Release(&fb); PyBuffer_Release(&cb); PyBuffer_Release(&sb);
    if (indexed) PyBuffer_Release(&ib);
    return res;
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
    REnc enc = {0};
    Err e = {0};
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
        Py_BEGIN_ALLOW_THREADS
        bank_encode_run(bits.buf, models.buf, n, f0, nm, prec, lanes, &enc, &e);
        Py_END_ALLOW_THREADS
        res = e.failed ? raise_err(&e) : payload_bytes(&enc);
    }
    renc_free(&enc);
    PyBuffer_Release(&bits); PyBuffer_Release(&models); PyBuffer_Release(&freq);
    return res;
}

/* ================================================================== rANS decoding */
PyDoc_STRVAR(rans_tables_doc,
"rans_tables(types, lo, span, prec, group, binshift, centre, rl, rr, nbins, bins, levels,\n"
"            max_lut, with_lut=True) -> (lut, fc, val, lut_base, sym_base, mprec)\n\n"
"Build the compact native decoding tables of a ModelSet (int64 parameter arrays; nbins /\n"
"bins / levels: the COARSE models' present-bin counts, bins and level codes, concatenated in\n"
"model order).  Same weights and normalisation as gsz.decoder.rans (ENTROPY.md 3.3-3.5).\n"
"Re-checks every parameter it relies on; raises GszFormatError when one is out of range or\n"
"the LUT would exceed max_lut.  with_lut=False: lut is None (the LUT is still counted against\n"
"max_lut); such tables serve rans_decode_blocks, which makes each model's LUT when it needs it.");

static PyObject *py_rans_tables(PyObject *self, PyObject *args)
{
    PyObject *o[12];
    long long max_lut;
    int with_lut = 1;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOL|p", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6],
                          &o[7], &o[8], &o[9], &o[10], &o[11], &max_lut, &with_lut))
        return NULL;
    Py_buffer v[12];
    int nv = 0;
    for (; nv < 12; nv++)
        if (getbuf(o[nv], &v[nv], 8, 'i', 0, "rans_tables argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    const MsetParams p = {v[0].buf, v[1].buf, v[2].buf, v[3].buf, v[4].buf, v[5].buf, v[6].buf,
                          v[7].buf, v[8].buf, v[9].buf, v[10].buf, v[11].buf, v[0].len / 8,
                          v[9].len / 8, v[10].len / 8};
    Err e = {0};
    for (int i = 1; i < 9; i++)
        if (v[i].len != v[0].len) fail(&e, "rANS model set: parameter arrays differ in length");
    if (v[11].len != v[10].len) fail(&e, "rANS model set: coarse code arrays differ in length");
    int64_t lut_total = 0, sym_total = 0;
    if (!e.failed) rans_tables_count(&p, max_lut, &lut_total, &sym_total, &e);
    /* the tables are written straight into the bytes objects returned (no copy) */
    PyObject *bo[6] = {NULL, NULL, NULL, NULL, NULL, NULL}, *res = NULL;
    if (!e.failed) {
        const Py_ssize_t sizes[6] = {(Py_ssize_t)(with_lut ? lut_total * 2 : 0), (Py_ssize_t)(sym_total * 4),
                                     (Py_ssize_t)(sym_total * 4), (Py_ssize_t)(p.M * 8),
                                     (Py_ssize_t)(p.M * 8), (Py_ssize_t)p.M};
        for (int i = 0; i < 6; i++) {
            bo[i] = PyBytes_FromStringAndSize(NULL, sizes[i]);
            if (!bo[i]) { fail_nomem(&e); break; }
        }
    }
    if (!e.failed) {
        const MsetTables out = {with_lut ? (uint16_t *)PyBytes_AS_STRING(bo[0]) : NULL,
                                (uint32_t *)PyBytes_AS_STRING(bo[1]),
                                (int32_t *)PyBytes_AS_STRING(bo[2]),
                                (int64_t *)PyBytes_AS_STRING(bo[3]),
                                (int64_t *)PyBytes_AS_STRING(bo[4]),
                                (uint8_t *)PyBytes_AS_STRING(bo[5])};
        Py_BEGIN_ALLOW_THREADS
        rans_tables_fill(&p, &out, &e);
        Py_END_ALLOW_THREADS
    }
    if (!e.failed) res = PyTuple_Pack(6, with_lut ? bo[0] : Py_None, bo[1], bo[2], bo[3], bo[4], bo[5]);
    for (int i = 0; i < 6; i++) Py_XDECREF(bo[i]);
    release_views(v, nv);
    if (e.failed) return raise_err(&e);
    return res;
}

/* The compact tables of rans_tables() with the buffers they are read from. */
typedef struct {
    RTab t;
    Py_buffer v[6];
    int nv;
} RTabViews;

static void rtab_release(RTabViews *t)
{
    release_views(t->v, t->nv);
    t->nv = 0;
}

static int rtab_load(RTabViews *t, PyObject *tables)
{
    PyObject *o[6];
    t->nv = 0;
    if (!PyArg_ParseTuple(tables, "OOOOOO;rANS tables", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5]))
        return -1;
    /* v[0]: the LUT, or None (tables made without it) -- an empty view then */
    const int has_lut = o[0] != Py_None;
    if (!has_lut) memset(&t->v[0], 0, sizeof t->v[0]);
    for (t->nv = has_lut ? 0 : 1; t->nv < 6; t->nv++)
        if (getbuf(o[t->nv], &t->v[t->nv], 1, 'x', 0, "rANS tables") < 0) {
            rtab_release(t);
            return -1;
        }
    RTab *r = &t->t;
    r->lut = has_lut ? t->v[0].buf : NULL;
    r->fc = t->v[1].buf;
    r->val = t->v[2].buf;
    r->lbase = t->v[3].buf;
    r->sbase = t->v[4].buf;
    r->mprec = t->v[5].buf;
    r->lut_len = t->v[0].len / 2;
    r->nsym = t->v[1].len / 4;
    r->nmodels = t->v[5].len;
    if (t->v[2].len / 4 != r->nsym || t->v[3].len / 8 != r->nmodels || t->v[4].len / 8 != r->nmodels) {
        PyErr_SetString(PyExc_ValueError, "rANS tables: inconsistent sizes");
        rtab_release(t);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(rans_decode_doc,
"rans_decode(mids, out, states, words, wpos, pos, tables) -> wpos\n\n"
"Decode len(mids) symbols (ENTROPY.md 4.3) of an interleaved rANS payload with the tables of\n"
"rans_tables(): symbol j (global index pos + j) on lane (pos + j) %% L, L = len(states)\n"
"(int64, updated in place); `words` = the payload's 16-bit words (LE bytes), wpos = words\n"
"consumed so far.  Writes the decoded values (int64) to `out`; returns the new wpos.  Raises\n"
"GszFormatError on a bad model id or an exhausted word stream.");

static PyObject *py_rans_decode(PyObject *self, PyObject *args)
{
    PyObject *o_mids, *o_out, *o_st, *o_words, *tables;
    long long wpos, pos;
    if (!PyArg_ParseTuple(args, "OOOOLLO", &o_mids, &o_out, &o_st, &o_words, &wpos, &pos, &tables))
        return NULL;
    RTabViews t;
    if (rtab_load(&t, tables) < 0) return NULL;
    PyObject *objs[4] = {o_mids, o_out, o_st, o_words};
    const int wr[4] = {0, 1, 1, 0};
    const Py_ssize_t isz[4] = {8, 8, 8, 1};
    Py_buffer v[4];
    int nv = 0;
    for (; nv < 4; nv++)
        if (getbuf(objs[nv], &v[nv], isz[nv], 'x', wr[nv], "rans_decode argument") < 0) {
            release_views(v, nv);
            rtab_release(&t);
            return NULL;
        }
    const int64_t count = v[0].len / 8;
    RState s = {v[2].buf, v[2].len / 8, 0, v[3].buf, v[3].len / 2, wpos};
    Err e = {0};
    if (v[1].len / 8 != count || s.lanes < 1 || wpos < 0 || wpos > s.nwords || pos < 0)
        fail(&e, "rans_decode: inconsistent arguments");
    if (!e.failed && count) {
        s.lane = pos % s.lanes;
        Py_BEGIN_ALLOW_THREADS
        rans_decode_run(&t.t, &s, v[0].buf, v[1].buf, count, &e);
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    rtab_release(&t);
    if (e.failed) return raise_err(&e);
    return PyLong_FromLongLong(s.w);
}

PyDoc_STRVAR(rans_decode_blocks_doc,
"rans_decode_blocks(states, words, wpos, pos, tables, model_table, C, L, B, out,\n"
"                   steps=None, lo=None, qmax=None) -> wpos\n\n"
"Decode the C*L symbols of a quantised channel set (GSZ.md §5): symbol c*L + i uses model\n"
"model_table[c*B + b] (int64), b the block of element i under split_lengths(L, B).  Without\n"
"steps and qmax: the values go to `out` (int64 [C*L]).  With steps, lo (float64 [C*B]) and qmax\n"
"(int64 [C*B], 2^q - 1): `out` (float64 [C*L]) receives lo + step * k (TRANSFORMS.md §3, the\n"
"same two roundings as gsz.decoder.quant.dequantize_groups).  With qmax alone: `out` (uint16\n"
"[C*L]) receives the symbols k.  With qmax, a symbol outside 0..qmax is an error.");

static PyObject *py_rans_decode_blocks(PyObject *self, PyObject *args)
{
    PyObject *o_st, *o_words, *tables, *o_tab, *o_out, *o_steps = Py_None, *o_lo = Py_None,
             *o_qmax = Py_None;
    long long wpos, pos, C, L, B;
    if (!PyArg_ParseTuple(args, "OOLLOOLLLO|OOO", &o_st, &o_words, &wpos, &pos, &tables, &o_tab,
                          &C, &L, &B, &o_out, &o_steps, &o_lo, &o_qmax))
        return NULL;
    /* deq: float64 out with steps and lo; sym16: uint16 out, qmax alone; else int64 out */
    const int deq = o_steps != Py_None, sym16 = !deq && o_qmax != Py_None;
    if (!deq && o_lo != Py_None) {
        PyErr_SetString(PyExc_TypeError, "rans_decode_blocks: lo without steps");
        return NULL;
    }
    RTabViews t;
    if (rtab_load(&t, tables) < 0) return NULL;
    PyObject *objs[7] = {o_st, o_words, o_tab, o_out, sym16 ? o_qmax : o_steps, o_lo, o_qmax};
    const int wr[7] = {1, 0, 0, 1, 0, 0, 0};
    const Py_ssize_t isz[7] = {8, 1, 8, sym16 ? 2 : 8, 8, 8, 8};
    const char kind[7] = {'x', 'x', 'i', deq ? 'f' : sym16 ? 'u' : 'i', sym16 ? 'i' : 'f', 'f', 'i'};
    const int nwant = deq ? 7 : sym16 ? 5 : 4;
    Py_buffer v[7];
    int nv = 0;
    for (; nv < nwant; nv++)
        if (getbuf(objs[nv], &v[nv], isz[nv], kind[nv], wr[nv], "rans_decode_blocks argument") < 0) {
            release_views(v, nv);
            rtab_release(&t);
            return NULL;
        }
    RState s = {v[0].buf, v[0].len / 8, 0, v[1].buf, v[1].len / 2, wpos};
    Err e = {0};
    if (C < 1 || L < 0 || B < 1 || C > 255 || B > 65535 || v[2].len / 8 != C * B
        || v[3].len / v[3].itemsize != C * L || s.lanes < 1 || wpos < 0 || wpos > s.nwords || pos < 0
        || (deq && (v[4].len / 8 != C * B || v[5].len / 8 != C * B || v[6].len / 8 != C * B))
        || (sym16 && v[4].len / 8 != C * B))
        fail(&e, "rans_decode_blocks: inconsistent arguments");
    if (!e.failed && C * L > 0) {
        const RBlocks bl = {v[2].buf, C, L, B, deq ? v[4].buf : NULL, deq ? v[5].buf : NULL,
                            deq ? v[6].buf : sym16 ? v[4].buf : NULL,
                            deq || sym16 ? NULL : v[3].buf, deq ? v[3].buf : NULL,
                            sym16 ? v[3].buf : NULL};
        s.lane = pos % s.lanes;
        Py_BEGIN_ALLOW_THREADS
        rans_decode_blocks_run(&t.t, &s, &bl, &e);
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    rtab_release(&t);
    if (e.failed) return raise_err(&e);
    return PyLong_FromLongLong(s.w);
}

PyDoc_STRVAR(rans_simd_doc,
"rans_simd(on=None) -> bool\n\n"
"Whether rans_decode_blocks may use its AVX2 loop (where the CPU has AVX2); on=False / True\n"
"sets it (True only takes where the CPU has AVX2).  Returns the setting before the call.  The\n"
"two loops give the same values; the switch is for tests and benchmarks.");

/* on=None -> -1 (ask only), else 0 / 1; -2 on a Python error */
static int simd_arg(PyObject *args)
{
    PyObject *on = Py_None;
    if (!PyArg_ParseTuple(args, "|O", &on)) return -2;
    if (on == Py_None) return -1;
    const int v = PyObject_IsTrue(on);
    return v < 0 ? -2 : v;
}

static PyObject *py_rans_simd(PyObject *self, PyObject *args)
{
    const int v = simd_arg(args);
    if (v == -2) return NULL;
    return PyBool_FromLong(rans_simd(v) > 0);
}

PyDoc_STRVAR(klt_simd_doc,
"klt_simd(level=None) -> int\n\n"
"The widest loop sh_assemble's KLT product may use: 0 portable, 1 AVX2/FMA, 2 AVX-512 (padded\n"
"widths 24 and 48), capped at what the CPU has; True: the widest it has, False: 0, None: only\n"
"ask.  Returns the level before the call.  Every loop gives the same bits (exact integer\n"
"sums); for tests and benchmarks.");

static PyObject *py_klt_simd(PyObject *self, PyObject *args)
{
    PyObject *on = Py_None;
    if (!PyArg_ParseTuple(args, "|O", &on)) return NULL;
    int v = -1;
    if (PyBool_Check(on)) v = on == Py_True ? 1000 : 0;
    else if (on != Py_None) {
        const long l = PyLong_AsLong(on);
        if (l == -1 && PyErr_Occurred()) return NULL;
        if (l < 0) {
            PyErr_SetString(PyExc_ValueError, "klt_simd: level must be 0 or more");
            return NULL;
        }
        v = l > 1000 ? 1000 : (int)l;
    }
    return PyLong_FromLong(klt_simd(v));
}

/* ================================================================== model sets, varints */
PyDoc_STRVAR(read_varints_doc,
"read_varints(buf, pos, count, out) -> int\n\n"
"gsz.decoder.rans.read_varints in C: the first `count` terminating bytes (< 0x80) within\n"
"buf[pos : pos + 9 * count] end the `count` unsigned LEB128 varints, written to out (int64\n"
"[count]); returns the position after them, -1 when fewer terminators are found there\n"
"(truncated) or -2 when one varint is longer than 9 bytes (same decision order as NumPy's).");

static PyObject *py_read_varints(PyObject *self, PyObject *args)
{
    PyObject *o_buf, *o_out;
    long long pos, count;
    if (!PyArg_ParseTuple(args, "OLLO", &o_buf, &pos, &count, &o_out)) return NULL;
    Py_buffer vb, vo;
    if (getbuf(o_buf, &vb, 1, 'x', 0, "buf") < 0) return NULL;
    if (getbuf(o_out, &vo, 8, 'i', 1, "out") < 0) { PyBuffer_Release(&vb); return NULL; }
    long long res = 0;
    if (pos < 0 || count < 0 || pos > vb.len || vo.len / 8 != count) {
        PyBuffer_Release(&vb); PyBuffer_Release(&vo);
        PyErr_SetString(PyExc_ValueError, "read_varints: inconsistent arguments");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    res = read_varints_run(vb.buf, (int64_t)vb.len, pos, count, vo.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&vb);
    PyBuffer_Release(&vo);
    return PyLong_FromLongLong(res);
}

PyDoc_STRVAR(model_set_parse_doc,
"model_set_parse(body) -> (types, lo, span, prec, group, binshift, centre, rl, rr, counts,\n"
"                          bins, levels) | None\n\n"
"The body of a model set (ENTROPY.md 3.1-3.2, after zstd) parsed and checked in C: the same\n"
"accept/reject decision and the same int64 arrays as gsz.decoder.rans.read_model_set and\n"
"ModelSet.validate (bins / levels flat, in model order).  Returns None on ANY violation; the\n"
"caller then runs the Python parser, whose message is the normative one.");

static PyObject *py_model_set_parse(PyObject *self, PyObject *arg)
{
    Py_buffer vb;
    if (getbuf(arg, &vb, 1, 'x', 0, "body") < 0) return NULL;
    MsetParsed mp;
    const int rc = model_set_parse_run(vb.buf, (int64_t)vb.len, &mp);
    PyBuffer_Release(&vb);
    PyObject *res = NULL;
    if (rc < 0) {
        PyErr_NoMemory();
    } else if (rc == 0) {
        res = Py_None;
        Py_INCREF(res);
    } else {
        PyObject *items[12] = {NULL};
        int ok = 1;
        for (int i = 0; i < 12 && ok; i++) {
            items[i] = PyBytes_FromStringAndSize((const char *)mp.arr[i], (Py_ssize_t)(mp.len[i] * 8));
            if (!items[i]) ok = 0;
        }
        if (ok) res = PyTuple_Pack(12, items[0], items[1], items[2], items[3], items[4], items[5],
                                   items[6], items[7], items[8], items[9], items[10], items[11]);
        for (int i = 0; i < 12; i++) Py_XDECREF(items[i]);
    }
    mset_parsed_free(&mp);
    return res;
}

/* ================================================================== inverse RAHT */
#define RAHT_TREE_CAPSULE "gsz.decoder._native.raht_tree"

static void rtree_capsule_free(PyObject *cap)
{
    rtree_free(PyCapsule_GetPointer(cap, RAHT_TREE_CAPSULE));
}

PyDoc_STRVAR(raht_tree_doc,
"raht_tree(codes, depth, weights=None) -> tree\n\n"
"The RAHT tree (TRANSFORMS.md §2) of the N leaves with Morton codes `codes` (uint64, strictly\n"
"ascending, < 2^(3 depth)), as an opaque object for raht_apply(): the same sibling pairs in the\n"
"same order as gsz.decoder.raht.build_raht_tree, with the butterfly gains computed as there.\n"
"weights: None or int64 [N] leaf weights in 1..65535 (an RWGT chunk, TRANSFORMS.md §2.5).");

static PyObject *py_raht_tree(PyObject *self, PyObject *args)
{
    PyObject *o_codes, *o_w = Py_None;
    int depth;
    if (!PyArg_ParseTuple(args, "Oi|O", &o_codes, &depth, &o_w)) return NULL;
    Py_buffer vc, vw;
    if (getbuf(o_codes, &vc, 8, 'x', 0, "codes") < 0) return NULL;
    const int has_w = o_w != Py_None;
    if (has_w && getbuf(o_w, &vw, 8, 'i', 0, "weights") < 0) { PyBuffer_Release(&vc); return NULL; }
    const int64_t n = vc.len / 8;
    Err e = {0};
    RTree *t = NULL;
    if (n < 1 || n > INT32_MAX || depth < 1 || depth > 21 || (has_w && vw.len / 8 != n)) {
        fail(&e, "RAHT inverse: inconsistent shapes");
    } else {
        Py_BEGIN_ALLOW_THREADS
        rtree_build(vc.buf, n, depth, has_w ? vw.buf : NULL, &t, &e);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vc);
    if (has_w) PyBuffer_Release(&vw);
    if (e.failed) return raise_err(&e);
    PyObject *cap = PyCapsule_New(t, RAHT_TREE_CAPSULE, rtree_capsule_free);
    if (!cap) rtree_free(t);
    return cap;
}

PyDoc_STRVAR(raht_apply_doc,
"raht_apply(tree, dc, ac, c0, c1, out, half=False)\n\n"
"Inverse RAHT of channels c0..c1-1 over a raht_tree(): dc float64 [C], ac float64 [C, N-1]\n"
"(channel-major, stream/level order), out float64 [c1 - c0, N] (written, channel-major).  Same\n"
"float64 operations in the same order as gsz.decoder.raht.raht_inverse (bit-identical).  With\n"
"half: every output value x is then replaced by 0.5 * x (0 when x is not finite), the half\n"
"angles of gsz.decoder.rotation.euler_to_quaternion.");

static PyObject *py_raht_apply(PyObject *self, PyObject *args)
{
    PyObject *o_tree, *o_dc, *o_ac, *o_out;
    long long c0, c1;
    int half = 0;
    if (!PyArg_ParseTuple(args, "OOOLLO|p", &o_tree, &o_dc, &o_ac, &c0, &c1, &o_out, &half))
        return NULL;
    RTree *t = PyCapsule_GetPointer(o_tree, RAHT_TREE_CAPSULE);
    if (!t) return NULL;
    Py_buffer vdc, vac, vout;
    if (getbuf(o_dc, &vdc, 8, 'f', 0, "dc") < 0) return NULL;
    if (getbuf(o_ac, &vac, 8, 'f', 0, "ac") < 0) { PyBuffer_Release(&vdc); return NULL; }
    if (getbuf(o_out, &vout, 8, 'f', 1, "out") < 0) { PyBuffer_Release(&vdc); PyBuffer_Release(&vac); return NULL; }
    const int64_t n = t->n, nch = vdc.len / 8, k = c1 - c0;
    int ok = nch >= 1 && c0 >= 0 && c1 <= nch && k >= 1 && vac.len / 8 == nch * (n - 1)
             && vout.len / 8 == k * n;
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
        raht_inverse(t, vdc.buf, vac.buf, c0, k, vout.buf, half);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vdc); PyBuffer_Release(&vac); PyBuffer_Release(&vout);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "raht_apply: inconsistent shapes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* ================================================================== attribute assembly */
PyDoc_STRVAR(planes_to_f32_doc,
"planes_to_f32(src, p0, p1, out) -> bool\n\n"
"out[i, k] = float32(src[p0 + k, i]) for the planes p0..p1-1 of src (float64 [P, M],\n"
"channel-major) into out (float32 [M, p1 - p0]), NumPy's astype rounding; returns True when\n"
"every value written is finite.");

static PyObject *py_planes_to_f32(PyObject *self, PyObject *args)
{
    PyObject *o_src, *o_out;
    long long p0, p1;
    if (!PyArg_ParseTuple(args, "OLLO", &o_src, &p0, &p1, &o_out)) return NULL;
    Py_buffer vs, vo;
    if (getbuf(o_src, &vs, 8, 'f', 0, "src") < 0) return NULL;
    if (getbuf(o_out, &vo, 4, 'f', 1, "out") < 0) { PyBuffer_Release(&vs); return NULL; }
    const int64_t k = p1 - p0, M = k > 0 ? (vo.len / 4) / k : 0;
    const int ok = k >= 1 && p0 >= 0 && vo.len / 4 == k * M && M > 0 && (vs.len / 8) % M == 0
                   && p1 <= (vs.len / 8) / M;
    int finite = 1;
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
        finite = planes_to_f32_run((const double *)vs.buf + p0 * M, M, k, vo.buf);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vs);
    PyBuffer_Release(&vo);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "planes_to_f32: inconsistent shapes");
        return NULL;
    }
    return PyBool_FromLong(finite);
}

PyDoc_STRVAR(quat_from_trig_doc,
"quat_from_trig(c, s, q) -> bool\n\n"
"Quaternions (w, x, y, z) as float32 [M, 4] from c = cos and s = sin of the half angles\n"
"(float64 [3, M]: roll, pitch, yaw): TRANSFORMS.md §1, products left to right, one rounding\n"
"per operation, sign flipped when w < 0, then rounded to float32.  Returns True when every\n"
"component is finite.");

static PyObject *py_quat_from_trig(PyObject *self, PyObject *args)
{
    PyObject *o[3];
    if (!PyArg_ParseTuple(args, "OOO", &o[0], &o[1], &o[2])) return NULL;
    const Py_ssize_t isz[3] = {8, 8, 4};
    Py_buffer v[3];
    int nv = 0;
    for (; nv < 3; nv++)
        if (getbuf(o[nv], &v[nv], isz[nv], 'f', nv == 2, "quat_from_trig argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    const int64_t M = v[2].len / 16;
    int ok = v[0].len / 8 == 3 * M && v[1].len / 8 == 3 * M;
    int finite = 1;
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
        finite = quat_from_trig_run(v[0].buf, v[1].buf, M, v[2].buf);
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "quat_from_trig: inconsistent shapes");
        return NULL;
    }
    return PyBool_FromLong(finite);
}

PyDoc_STRVAR(voxel_positions_doc,
"voxel_positions(codes, depth, ox, oy, oz, side, out) -> bool\n\n"
"Decoded centres (GSZ.md §6) of the voxels with Morton codes `codes` (uint64 [M]):\n"
"origin + (ijk + 0.5) * (side / 2^depth) in float64, rounded to float32 into out [M, 3].\n"
"Returns True when every coordinate is finite.");

static PyObject *py_voxel_positions(PyObject *self, PyObject *args)
{
    PyObject *o_codes, *o_out;
    int depth;
    double org[3], side;
    if (!PyArg_ParseTuple(args, "OiddddO", &o_codes, &depth, &org[0], &org[1], &org[2], &side, &o_out))
        return NULL;
    Py_buffer vc, vo;
    if (getbuf(o_codes, &vc, 8, 'x', 0, "codes") < 0) return NULL;
    if (getbuf(o_out, &vo, 4, 'f', 1, "out") < 0) { PyBuffer_Release(&vc); return NULL; }
    const int64_t M = vc.len / 8;
    const int ok = vo.len / 4 == 3 * M && depth >= 1 && depth <= 21;
    int finite = 1;
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
        finite = voxel_positions_run(vc.buf, M, depth, org, side, vo.buf);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vc);
    PyBuffer_Release(&vo);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "voxel_positions: inconsistent arguments");
        return NULL;
    }
    return PyBool_FromLong(finite);
}

PyDoc_STRVAR(sh_assemble_doc,
"sh_assemble(flags, kept, steps, lo, idx, codebook, out, classes=None, colour=0, klt=None,\n"
"            refine=None)\n\n"
"SH rest vectors (GSZ.md §8) as float32 out [M, D]: Gaussian i takes the next kept vector\n"
"when flags[i] == 1 (flags: int64 [M], or None when P = 0), else codeword idx[next] of\n"
"codebook (float64 [D, K]).  kept: the kept set's symbols, uint16 [D, P] channel-major, in B\n"
"blocks per channel (split_lengths) dequantised as lo + step * k with steps, lo float64 [D, B].\n"
"classes (int64 [P], SHCL): each kept vector's class in point order; the set then stores them\n"
"class by class.  colour 1 (SHXF, §8.2): every row's triplets turned from luma/chroma to RGB;\n"
"klt (float64 [D, D] integers, SHXF bit 2, or None): every row turned by the exact KLT inverse\n"
"(the codewords only when idx is not empty), a stored value beyond +-256 raising GszFormatError.\n"
"refine (int64 [P], SHRF, or None): stored kept vector j is the residual of codeword refine[j],\n"
"added back in float32 before the colour transform.\n"
"A flag other than 0/1, a kept count other than P or an index >= K raises\n"
"GszFormatError.  Returns whether every value written to out is finite.");

static PyObject *py_sh_assemble(PyObject *self, PyObject *args)
{
    PyObject *o[10] = {NULL, NULL, NULL, NULL, NULL, NULL, NULL, Py_None, Py_None, Py_None};
    int colour = 0;
    if (!PyArg_ParseTuple(args, "OOOOOOO|OiOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &colour, &o[8], &o[9]))
        return NULL;
    if (colour != 0 && colour != 1) {
        PyErr_SetString(PyExc_ValueError, "sh_assemble: colour must be 0 or 1");
        return NULL;
    }
    const int has_flags = o[0] != Py_None, has_classes = o[7] != Py_None, has_klt = o[8] != Py_None,
              has_refine = o[9] != Py_None;
    if (has_klt && colour) {
        PyErr_SetString(PyExc_ValueError, "sh_assemble: colour 1 and a KLT exclude each other");
        return NULL;
    }
    /* flags, kept, steps, lo, idx, codebook, out, classes, klt, refine */
    const Py_ssize_t isz[10] = {8, 2, 8, 8, 8, 8, 4, 8, 8, 8};
    const char kind[10] = {'i', 'u', 'f', 'f', 'i', 'f', 'f', 'i', 'f', 'i'};
    Py_buffer v[10];
    memset(v, 0, sizeof v);
    int nv = 0, ok = 1;
    for (; nv < 10; nv++) {
        if ((nv == 0 && !has_flags) || (nv == 7 && !has_classes) || (nv == 8 && !has_klt)
            || (nv == 9 && !has_refine)) continue;
        if (getbuf(o[nv], &v[nv], isz[nv], kind[nv], nv == 6, "sh_assemble argument") < 0) { ok = 0; break; }
    }
    if (!ok) {
        for (int i = 0; i < nv; i++) if (v[i].obj) PyBuffer_Release(&v[i]);
        return NULL;
    }
    const int64_t nidx = v[4].len / 8;
    const int64_t M = has_flags ? v[0].len / 8 : nidx;
    Err e = {0};
    int finite = 0;
    const int64_t D = M ? (v[6].len / 4) / M : 0;
    const int64_t P = D ? v[1].len / 2 / D : 0, B = D ? v[2].len / 8 / D : 0;
    if (M == 0 || v[6].len / 4 != D * M || D < 1 || v[1].len / 2 % D || v[5].len / 8 % D
        || B < 1 || v[2].len / 8 != D * B || v[3].len / 8 != D * B)
        fail(&e, "sh_assemble: inconsistent shapes");
    if (!e.failed && has_classes && v[7].len / 8 != P)
        fail(&e, "sh_assemble: classes length is not the kept count");
    if (!e.failed && has_klt && v[8].len / 8 != D * D)
        fail(&e, "sh_assemble: the KLT matrix is not D x D");
    if (!e.failed && has_refine && v[9].len / 8 != P)
        fail(&e, "sh_assemble: refine length is not the kept count");
    if (!e.failed) {
        const int64_t K = v[5].len / 8 / D;
        Py_BEGIN_ALLOW_THREADS
        sh_assemble_run(has_flags ? v[0].buf : NULL, v[1].buf, v[2].buf, v[3].buf, B,
                        has_classes ? v[7].buf : NULL, P, v[4].buf, nidx, v[5].buf, K, M, D,
                        colour, has_klt ? v[8].buf : NULL, has_refine ? v[9].buf : NULL, v[6].buf,
                        &finite, &e);
        Py_END_ALLOW_THREADS
    }
    for (int i = 0; i < 10; i++) if (v[i].obj) PyBuffer_Release(&v[i]);
    if (e.failed) return raise_err(&e);
    return PyBool_FromLong(finite);
}

PyDoc_STRVAR(all_finite_doc,
"all_finite(a) -> bool\n\nTrue when every element of the float32 buffer `a` is finite.");

static PyObject *py_all_finite(PyObject *self, PyObject *arg)
{
    Py_buffer v;
    if (getbuf(arg, &v, 4, 'f', 0, "all_finite argument") < 0) return NULL;
    int finite;
    Py_BEGIN_ALLOW_THREADS
    finite = all_finite_run(v.buf, (int64_t)(v.len / 4));
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&v);
    return PyBool_FromLong(finite);
}

/* ================================================================== rate model (encoder) */
PyDoc_STRVAR(rate_group_stats_doc,
"rate_group_stats(srt, blen, log_tab, q_first, hi, rho_min, rho_max,\n"
"                 out_k, out_payload, out_gap, out_gap2, out_level, out_laplace, out_binned)\n\n"
"gsz.encoder.rate.group_stats' loop over bit-widths q_first..hi for one channel's part of\n"
"equal blocks: srt float32 [nb, blen] (each block sorted ascending), log_tab float64 with\n"
"log_tab[i] = np.log2(max(i, 1)) for i < len(log_tab) (at least max(blen, 65536) + 1\n"
"entries), out_* float64 [nb, 16] (out_binned [nb, 16, 5]) written at columns q_first-1..hi-1\n"
"(binned only where q - h >= q_first).  Same arithmetic as the NumPy reference, up to\n"
"last-bit differences of log2/pow in the payload, laplace and binned sums.");

static PyObject *py_rate_group_stats(PyObject *self, PyObject *args)
{
    PyObject *o[9];
    long long blen;
    int q_first, hi;
    double rho_min, rho_max;
    if (!PyArg_ParseTuple(args, "OLOiiddOOOOOOO", &o[0], &blen, &o[1], &q_first, &hi, &rho_min,
                          &rho_max, &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8]))
        return NULL;
    Py_buffer v[9];
    int nv = 0;
    for (; nv < 9; nv++) {
        const int out = nv >= 2;
        if (getbuf(o[nv], &v[nv], nv == 0 ? 4 : 8, 'f', out, "rate_group_stats argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    }
    const int64_t tab_len = v[1].len / 8;
    const int64_t nb = blen > 0 ? (int64_t)(v[0].len / 4) / blen : 0;
    int ok = blen > 0 && blen <= INT32_MAX && nb > 0 && nb * blen == (int64_t)(v[0].len / 4)
             && tab_len > blen && tab_len > 65536
             && 1 <= q_first && q_first <= hi && hi <= RATE_BITS
             && rho_min > 0.0 && rho_min <= rho_max && rho_max < 1.0;
    for (int i = 2; ok && i < 9; i++)
        if (v[i].len / 8 != nb * RATE_BITS * (i == 8 ? RATE_SHIFTS : 1)) ok = 0;
    if (!ok) {
        release_views(v, nv);
        PyErr_SetString(PyExc_ValueError, "rate_group_stats: inconsistent arguments");
        return NULL;
    }
    const RateOut out = {v[2].buf, v[3].buf, v[4].buf, v[5].buf, v[6].buf, v[7].buf, v[8].buf};
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = rate_group_stats_run(v[0].buf, nb, blen, v[1].buf, q_first, hi, rho_min, rho_max, &out);
    Py_END_ALLOW_THREADS
    release_views(v, nv);
    if (rc < 0) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

/* Channels c and length of x float32 [C, L] (v[0]) with mins / maxs float32 [C, B] (v[1], v[2])
 * and B = nb blocks: the group count C * B, or -1 when the three do not fit together. */
static int64_t group_shape(const Py_buffer *v, int64_t nb, int64_t *c, int64_t *length)
{
    const int64_t groups = (int64_t)(v[1].len / 4), values = (int64_t)(v[0].len / 4);
    *c = nb > 0 ? groups / nb : 0;
    *length = *c > 0 ? values / *c : 0;
    const int ok = nb >= 1 && *c >= 1 && *c * nb == groups && (int64_t)(v[2].len / 4) == groups
                   && *c * *length == values;
    return ok ? groups : -1;
}

PyDoc_STRVAR(loss_all_bits_doc,
"loss_all_bits(x, num_blocks, mins, maxs, lo, hi, out)\n\n"
"gsz.kernels.quantize_cpu.loss_all_bits in C: x float32 [C, L], mins/maxs float32 [C, B]\n"
"(B = num_blocks, blocks split_lengths(L, B)), out float64 [C, B, 16] written at columns\n"
"lo-1..hi-1 with each group's squared quantisation error at that width (the torch path's\n"
"arithmetic; its sums agree to ~1e-15 relative).");

static PyObject *py_loss_all_bits(PyObject *self, PyObject *args)
{
    PyObject *o[4];
    long long nb;
    int lo, hi;
    if (!PyArg_ParseTuple(args, "OLOOiiO", &o[0], &nb, &o[1], &o[2], &lo, &hi, &o[3]))
        return NULL;
    Py_buffer v[4];
    int nv = 0;
    for (; nv < 4; nv++) {
        if (getbuf(o[nv], &v[nv], nv == 3 ? 8 : 4, 'f', nv == 3, "loss_all_bits argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    }
    int64_t c, length;
    const int64_t groups = group_shape(v, nb, &c, &length);
    if (groups < 0 || (int64_t)(v[3].len / 8) != groups * RATE_BITS
        || lo < 1 || lo > hi || hi > RATE_BITS) {
        release_views(v, nv);
        PyErr_SetString(PyExc_ValueError, "loss_all_bits: inconsistent arguments");
        return NULL;
    }
    const float *x = v[0].buf, *mins = v[1].buf, *maxs = v[2].buf;
    double *out = v[3].buf;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t ci = 0; ci < c; ci++)
        loss_all_bits_run(x + ci * length, length, nb, mins + ci * nb, maxs + ci * nb, lo, hi,
                          out + ci * nb * RATE_BITS);
    Py_END_ALLOW_THREADS
    release_views(v, nv);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(quantize_groups_doc,
"quantize_groups(x, num_blocks, mins, maxs, bits, out)\n\n"
"gsz.kernels.quantize_cpu.quantize in C: x float32 [C, L], mins/maxs float32 [C, B], bits int64\n"
"[C, B] in 1..16, out int32 [C, L] (blocks split_lengths(L, B)): the normative symbols,\n"
"bit-identical to the torch reference.");

static PyObject *py_quantize_groups(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    long long nb;
    if (!PyArg_ParseTuple(args, "OLOOOO", &o[0], &nb, &o[1], &o[2], &o[3], &o[4])) return NULL;
    Py_buffer v[5];
    int nv = 0;
    static const Py_ssize_t size[5] = {4, 4, 4, 8, 4};
    static const char kind[5] = {'f', 'f', 'f', 'i', 'i'};
    for (; nv < 5; nv++) {
        if (getbuf(o[nv], &v[nv], size[nv], kind[nv], nv == 4, "quantize_groups argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    }
    int64_t c, length;
    const int64_t groups = group_shape(v, nb, &c, &length);
    int ok = groups >= 0 && (int64_t)(v[3].len / 8) == groups && v[4].len == v[0].len;
    const int64_t *bits = v[3].buf;
    for (int64_t g = 0; ok && g < groups; g++)
        if (bits[g] < 1 || bits[g] > RATE_BITS) ok = 0;
    if (!ok) {
        release_views(v, nv);
        PyErr_SetString(PyExc_ValueError, "quantize_groups: inconsistent arguments");
        return NULL;
    }
    const float *x = v[0].buf, *mins = v[1].buf, *maxs = v[2].buf;
    int32_t *sym = v[4].buf;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t ci = 0; ci < c; ci++)
        quantize_row_run(x + ci * length, length, nb, mins + ci * nb, maxs + ci * nb,
                         bits + ci * nb, sym + ci * length);
    Py_END_ALLOW_THREADS
    release_views(v, nv);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(sh_requant_rows_doc,
"sh_requant_rows(sh, order, group, cw_row, books, lo, step, top, out)\n\n"
"The size search's decoded SH rest rows (gsz.encoder.pipeline ShPayloads.decoded_rows): sh\n"
"float32 [N, D], order int64 [n], group/cw_row int32 [n], books float32 [C, D], lo/step/top\n"
"float64 [G, D], out float32 [n, D]; row i is sh[order[i]] quantised again with group[i]'s\n"
"parameters where group[i] >= 0, else books[cw_row[i]], bit-identical to the NumPy rows.");

static PyObject *py_sh_requant_rows(PyObject *self, PyObject *args)
{
    PyObject *o[9];
    if (!PyArg_ParseTuple(args, "OOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8])) return NULL;
    Py_buffer v[9];
    int nv = 0;
    static const Py_ssize_t size[9] = {4, 8, 4, 4, 4, 8, 8, 8, 4};
    static const char kind[9] = {'f', 'i', 'i', 'i', 'f', 'f', 'f', 'f', 'f'};
    for (; nv < 9; nv++) {
        if (getbuf(o[nv], &v[nv], size[nv], kind[nv], nv == 8, "sh_requant_rows argument") < 0) {
            release_views(v, nv);
            return NULL;
        }
    }
    const int64_t n = v[1].len / 8;
    const int64_t d = n ? (v[8].len / 4) / n : 0;
    int ok = v[2].len / 4 == n && v[3].len / 4 == n && (int64_t)(v[8].len / 4) == n * d
             && (d == 0 || ((v[0].len / 4) % d == 0 && (v[4].len / 4) % d == 0
                            && (v[5].len / 8) % d == 0))
             && v[6].len == v[5].len && v[7].len == v[5].len;
    int rc = 0;
    if (ok && n && d) {
        Py_BEGIN_ALLOW_THREADS
        rc = sh_requant_rows(v[0].buf, (v[0].len / 4) / d, d, v[1].buf, v[2].buf, v[3].buf, n,
                             v[4].buf, (v[4].len / 4) / d, v[5].buf, v[6].buf, v[7].buf,
                             (v[5].len / 8) / d, v[8].buf);
        Py_END_ALLOW_THREADS
    }
    release_views(v, nv);
    if (!ok || rc < 0) {
        PyErr_SetString(PyExc_ValueError, ok ? "sh_requant_rows: an index out of range"
                                             : "sh_requant_rows: inconsistent arguments");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* ================================================================== module */
static PyMethodDef methods[] = {
    {"octree_decode", py_octree_decode, METH_VARARGS, octree_decode_doc},
    {"octree_encode", py_octree_encode, METH_VARARGS, octree_encode_doc},
    {"octree_helper", py_octree_helper, METH_NOARGS, octree_helper_doc},
    {"octree_help", py_octree_help, METH_O, octree_help_doc},
    {"octree_helper_close", py_octree_helper_close, METH_O, octree_helper_close_doc},
    {"bank_encode", py_bank_encode, METH_VARARGS, bank_encode_doc},
    {"rans_encode", py_rans_encode, METH_VARARGS, rans_encode_doc},
    {"rans_decode", py_rans_decode, METH_VARARGS, rans_decode_doc},
    {"raht_tree", py_raht_tree, METH_VARARGS, raht_tree_doc},
    {"raht_apply", py_raht_apply, METH_VARARGS, raht_apply_doc},
    {"rans_tables", py_rans_tables, METH_VARARGS, rans_tables_doc},
    {"rans_decode_blocks", py_rans_decode_blocks, METH_VARARGS, rans_decode_blocks_doc},
    {"planes_to_f32", py_planes_to_f32, METH_VARARGS, planes_to_f32_doc},
    {"quat_from_trig", py_quat_from_trig, METH_VARARGS, quat_from_trig_doc},
    {"rans_simd", py_rans_simd, METH_VARARGS, rans_simd_doc},
    {"klt_simd", py_klt_simd, METH_VARARGS, klt_simd_doc},
    {"voxel_positions", py_voxel_positions, METH_VARARGS, voxel_positions_doc},
    {"sh_assemble", py_sh_assemble, METH_VARARGS, sh_assemble_doc},
    {"all_finite", py_all_finite, METH_O, all_finite_doc},
    {"read_varints", py_read_varints, METH_VARARGS, read_varints_doc},
    {"model_set_parse", py_model_set_parse, METH_O, model_set_parse_doc},
    {"loss_all_bits", py_loss_all_bits, METH_VARARGS, loss_all_bits_doc},
    {"quantize_groups", py_quantize_groups, METH_VARARGS, quantize_groups_doc},
    {"rate_group_stats", py_rate_group_stats, METH_VARARGS, rate_group_stats_doc},
    {"sh_requant_rows", py_sh_requant_rows, METH_VARARGS, sh_requant_rows_doc},
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
    raht_static_init();
    octree_static_init();
    rans_simd(-1);
    klt_simd(-1);
    PyObject *m = PyModule_Create(&moddef);
    if (!m) return NULL;
    if (PyModule_AddIntConstant(m, "ABI", GSZ_NATIVE_ABI) < 0
        || PyModule_AddIntConstant(m, "NUM_COARSE", NUM_COARSE) < 0
        || PyModule_AddIntConstant(m, "NUM_FINE", NUM_FINE) < 0
        || PyModule_AddIntConstant(m, "MAX_POINTS", OCT_MAX_POINTS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
