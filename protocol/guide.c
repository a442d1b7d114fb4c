#include "protocol/guide.h"

#include <string.h>

#include "common/base/alloc.h"

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
