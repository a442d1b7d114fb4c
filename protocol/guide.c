#include "protocol/guide.h"

#include <string.h>
#include <zlib.h>

#include "common/base/alloc.h"

/* deflate level of proto_guide_pack. */
#define PROTO_GUIDE_PACK_LEVEL 1

pt_status proto_guide_encode(proto_writer *w, const pt_guide *g, pt_error *err)
{
    if (!g->nsnode || g->nsnode > PROTO_MAX_GUIDE_NODES || g->nqnode < PT_GUIDE_FACES ||
        g->nqnode > PROTO_MAX_GUIDE_NODES)
        return pt_error_set(err, PT_ERR_ARG, "guide of %u+%u nodes", g->nsnode, g->nqnode);
    size_t start = w->len;
    proto_w_u32(w, PROTO_GUIDE_MAGIC);
    proto_w_u32(w, PROTO_GUIDE_VERSION);
    const pt_vec3 b[2] = {g->lo, g->hi};
    for (int k = 0; k < 2; k++) {
        proto_w_f32(w, b[k].x);
        proto_w_f32(w, b[k].y);
        proto_w_f32(w, b[k].z);
    }
    proto_w_u32(w, g->nsnode);
    proto_w_u32(w, g->nqnode);
    size_t bytes = (size_t)g->nsnode * 12 + (size_t)g->nqnode * 8;
    uint8_t *q = proto_w_reserve(w, bytes);
    if (!q) {
        pt_status st = proto_writer_status(w);
        w->len = start;
        return pt_error_set(err, st, "guide of %zu bytes", bytes);
    }
    for (uint32_t i = 0; i < g->nsnode; i++, q += 12) {
        proto_put_u32(q, g->snode[i].child);
        proto_put_u32(q + 4, g->snode[i].axis);
        proto_put_u32(q + 8, g->snode[i].tree);
    }
    for (uint32_t i = 0; i < g->nqnode; i++, q += 8) {
        proto_put_u32(q, g->qnode[i].child);
        proto_put_f32(q + 4, g->qnode[i].energy);
    }
    if (proto_writer_status(w) != PT_OK) {
        pt_status st = proto_writer_status(w);
        w->len = start;
        return pt_error_set(err, st, "guide of %zu bytes", bytes);
    }
    return PT_OK;
}

pt_status proto_guide_decode(const uint8_t *p, size_t len, pt_guide **out, pt_error *err)
{
    if (len < PROTO_GUIDE_HEADER)
        return pt_error_set(err, PT_ERR_FORMAT, "guide: %zu bytes, under its header", len);
    if (proto_get_u32(p) != PROTO_GUIDE_MAGIC || proto_get_u32(p + 4) != PROTO_GUIDE_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT, "guide: not a version %u guide",
                            PROTO_GUIDE_VERSION);
    uint32_t ns = proto_get_u32(p + 32), nq = proto_get_u32(p + 36);
    if (!ns || ns > PROTO_MAX_GUIDE_NODES || nq < PT_GUIDE_FACES || nq > PROTO_MAX_GUIDE_NODES)
        return pt_error_set(err, PT_ERR_FORMAT, "guide: %u spatial and %u directional nodes", ns,
                            nq);
    /* The counts are capped at 2^24: this cannot overflow. */
    size_t want = PROTO_GUIDE_HEADER + (size_t)ns * 12 + (size_t)nq * 8;
    if (len != want)
        return pt_error_set(err, PT_ERR_FORMAT, "guide: %zu bytes, its counts make %zu", len, want);
    pt_guide *g = pt_calloc(1, sizeof *g);
    if (g) {
        g->snode = pt_malloc_array(ns, sizeof *g->snode);
        g->qnode = pt_malloc_array(nq, sizeof *g->qnode);
    }
    if (!g || !g->snode || !g->qnode) {
        /* As pt_guide_free, which is the renderer's (ptcore): not linked here. */
        if (g) {
            pt_free(g->snode);
            pt_free(g->qnode);
        }
        pt_free(g);
        return pt_error_set(err, PT_ERR_NOMEM, "guide: out of memory for %u+%u nodes", ns, nq);
    }
    g->lo = pt_v3(proto_get_f32(p + 8), proto_get_f32(p + 12), proto_get_f32(p + 16));
    g->hi = pt_v3(proto_get_f32(p + 20), proto_get_f32(p + 24), proto_get_f32(p + 28));
    g->nsnode = ns;
    g->nqnode = nq;
    const uint8_t *q = p + PROTO_GUIDE_HEADER;
    for (uint32_t i = 0; i < ns; i++, q += 12) {
        g->snode[i].child = proto_get_u32(q);
        g->snode[i].axis = proto_get_u32(q + 4);
        g->snode[i].tree = proto_get_u32(q + 8);
    }
    for (uint32_t i = 0; i < nq; i++, q += 8) {
        g->qnode[i].child = proto_get_u32(q);
        g->qnode[i].energy = proto_get_f32(q + 4);
    }
    *out = g;
    return PT_OK;
}

pt_status proto_guide_stats_to_result(const pt_guide_stats *s, proto_result *r, pt_error *err)
{
    uint32_t nc = 0, nsum = 0;
    for (uint32_t i = 0; i < s->nsnode; i++)
        nc += s->count[i] != 0;
    for (uint32_t i = 0; i < s->nqnode; i++)
        nsum += s->sum[i] != 0;
    size_t n = (size_t)nc + nsum;
    proto_guide_entry *e = pt_malloc_array(n ? n : 1, sizeof *e);
    if (!e)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for %zu guiding entries", n);
    size_t k = 0;
    for (uint32_t i = 0; i < s->nsnode; i++)
        if (s->count[i])
            e[k++] = (proto_guide_entry){i, s->count[i]};
    for (uint32_t i = 0; i < s->nqnode; i++)
        if (s->sum[i])
            e[k++] = (proto_guide_entry){i, s->sum[i]};
    r->g_nsnode = s->nsnode;
    r->g_nqnode = s->nqnode;
    r->gcount = nc;
    r->gsum = nsum;
    r->guide = e;
    r->owns_guide = 1;
    return PT_OK;
}

static uint64_t sat_add(uint64_t a, uint64_t b)
{
    uint64_t r;
    return __builtin_add_overflow(a, b, &r) ? UINT64_MAX : r;
}

pt_status proto_guide_stats_add(pt_guide_stats *into, const proto_result *r, pt_error *err)
{
    if (!r->guide)
        return pt_error_set(err, PT_ERR_FORMAT, "no guiding statistics");
    if (r->g_nsnode != into->nsnode || r->g_nqnode != into->nqnode)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "guiding statistics for %u+%u nodes, the pass's guide has %u+%u",
                            r->g_nsnode, r->g_nqnode, into->nsnode, into->nqnode);
    /* The decoder checked nodes in range; an encoder's caller may not have. */
    for (uint32_t i = 0; i < r->gcount + r->gsum; i++)
        if (r->guide[i].node >= (i < r->gcount ? into->nsnode : into->nqnode))
            return pt_error_set(err, PT_ERR_FORMAT, "guiding entry %u out of range", i);
    for (uint32_t i = 0; i < r->gcount; i++)
        into->count[r->guide[i].node] = sat_add(into->count[r->guide[i].node], r->guide[i].value);
    for (uint32_t i = r->gcount; i < r->gcount + r->gsum; i++)
        into->sum[r->guide[i].node] = sat_add(into->sum[r->guide[i].node], r->guide[i].value);
    return PT_OK;
}

pt_status proto_guide_pack(const uint8_t *raw, size_t n, uint8_t **out, size_t *out_len,
                           pt_error *err)
{
    *out = NULL;
    *out_len = 0;
    if (n < PROTO_GUIDE_HEADER || n > PROTO_MAX_GUIDE_BYTES)
        return pt_error_set(err, PT_ERR_ARG, "guide of %zu bytes to pack", n);
    uLong bound = compressBound((uLong)n);
    uint8_t *buf = pt_malloc(PROTO_GUIDE_PACK_HEADER + (size_t)bound);
    if (!buf)
        return pt_error_set(err, PT_ERR_NOMEM, "packing a guide of %zu bytes", n);
    z_stream z;
    memset(&z, 0, sizeof z);
    /* Level 1: the distribution's child indices and energies compress about
     * as well at 6, at a fraction of the time (docs/bench/guide_transfer.md). */
    if (deflateInit(&z, PROTO_GUIDE_PACK_LEVEL) != Z_OK) {
        pt_free(buf);
        return pt_error_set(err, PT_ERR_NOMEM, "deflateInit failed");
    }
    z.next_in = (Bytef *)raw;
    z.avail_in = (uInt)n;
    z.next_out = buf + PROTO_GUIDE_PACK_HEADER;
    z.avail_out = (uInt)bound;
    int rc = deflate(&z, Z_FINISH);
    size_t zlen = (size_t)z.total_out;
    deflateEnd(&z);
    if (rc != Z_STREAM_END) {
        pt_free(buf);
        return pt_error_set(err, PT_ERR_NOMEM, "deflate failed (%d)", rc);
    }
    proto_put_u32(buf, PROTO_GUIDE_PACK_MAGIC);
    proto_put_u64(buf + 4, (uint64_t)n);
    *out_len = PROTO_GUIDE_PACK_HEADER + zlen;
    uint8_t *shrunk = pt_realloc(buf, *out_len);
    *out = shrunk ? shrunk : buf;
    return PT_OK;
}

pt_status proto_guide_unpack(const uint8_t *p, size_t len, uint8_t **out, size_t *out_len,
                             pt_error *err)
{
    *out = NULL;
    *out_len = 0;
    if (len < PROTO_GUIDE_PACK_HEADER)
        return pt_error_set(err, PT_ERR_FORMAT, "packed guide: %zu bytes, shorter than its header",
                            len);
    if (proto_get_u32(p) != PROTO_GUIDE_PACK_MAGIC)
        return pt_error_set(err, PT_ERR_FORMAT, "packed guide: bad magic");
    uint64_t n = proto_get_u64(p + 4);
    uint64_t stream = len - PROTO_GUIDE_PACK_HEADER;
    if (n < PROTO_GUIDE_HEADER || n > PROTO_MAX_GUIDE_BYTES)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "packed guide: %llu bytes declared (at least %u, at most %u)",
                            (unsigned long long)n, PROTO_GUIDE_HEADER, PROTO_MAX_GUIDE_BYTES);
    if (n > stream * PROTO_GUIDE_PACK_RATIO)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "packed guide: %llu bytes declared, more than %llu bytes of zlib data "
                            "can hold",
                            (unsigned long long)n, (unsigned long long)stream);
    uint8_t *buf = pt_malloc((size_t)n);
    if (!buf)
        return pt_error_set(err, PT_ERR_NOMEM, "unpacking a guide of %llu bytes",
                            (unsigned long long)n);
    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit(&z) != Z_OK) {
        pt_free(buf);
        return pt_error_set(err, PT_ERR_NOMEM, "inflateInit failed");
    }
    z.next_in = (Bytef *)(p + PROTO_GUIDE_PACK_HEADER);
    z.avail_in = (uInt)stream;
    z.next_out = buf;
    z.avail_out = (uInt)n;
    /* The output buffer is the declared length: a stream that would write
     * more stops with it full (Z_OK or Z_BUF_ERROR, never Z_STREAM_END). */
    int rc = inflate(&z, Z_FINISH);
    uint64_t got = z.total_out;
    uInt left = z.avail_in;
    const char *why = z.msg;
    inflateEnd(&z);
    pt_status st = PT_OK;
    if (rc == Z_MEM_ERROR)
        st = pt_error_set(err, PT_ERR_NOMEM, "unpacking a guide of %llu bytes",
                          (unsigned long long)n);
    else if (rc == Z_DATA_ERROR || rc == Z_NEED_DICT)
        st = pt_error_set(err, PT_ERR_FORMAT, "packed guide: corrupt zlib data (%s)",
                          why ? why : "a dictionary asked for");
    else if (rc != Z_STREAM_END)
        st = pt_error_set(err, PT_ERR_FORMAT,
                          got == n ? "packed guide: its data holds more than the %llu bytes "
                                     "declared"
                                   : "packed guide: its data ends before the %llu bytes declared",
                          (unsigned long long)n);
    else if (got != n)
        st = pt_error_set(err, PT_ERR_FORMAT, "packed guide: %llu bytes unpacked, %llu declared",
                          (unsigned long long)got, (unsigned long long)n);
    else if (left != 0)
        st = pt_error_set(err, PT_ERR_FORMAT, "packed guide: %u bytes after its zlib data", left);
    if (st != PT_OK) {
        pt_free(buf);
        return st;
    }
    *out = buf;
    *out_len = (size_t)n;
    return PT_OK;
}
