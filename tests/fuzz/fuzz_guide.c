/*
 * fuzz_guide.c - libFuzzer target for a path-guiding distribution's bytes
 * (proto_guide_decode, protocol/guide.c): what a worker receives in
 * GUIDE_CHUNK frames and a coordinator reads back from a checkpoint, then
 * pt_guide_check, as both run it before a distribution is sampled.
 *
 * Input: the bytes. Invariants: a refusal is PT_ERR_FORMAT with a message
 * and allocates nothing; a decoded guide encodes back to the same bytes; a
 * guide that passes pt_guide_check samples every face of its first leaf to
 * unit directions whose pdf is finite and > 0, and pt_guide_pdf of each
 * agrees with the pdf the sample gave; pt_guide_pdf_leaf gives the same pdf
 * and a quadtree leaf of the guide, and a record there (pt_guide_stats_add)
 * sums as pt_guide_stats_record's; a point outside the bounds or NaN finds
 * a spatial leaf (pt_guide_prefetch reads its cell safely). Seeds (corpus/fuzz_guide/, written
 * by gen_corpus): a first pass's uniform guide, one built from statistics,
 * and three refused (cut, a bad magic, a tree with a shared child).
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/guide.h"
#include "protocol/guide.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int64_t live = pt_alloc_live();
    pt_guide *g = NULL;
    pt_error err = {0};
    pt_status st = proto_guide_decode(data, size, &g, &err);
    fuzz_note("guide", st, &err);
    FUZZ_CHECK(st == PT_OK || ((st == PT_ERR_FORMAT || st == PT_ERR_NOMEM) && err.msg[0]));
    if (st != PT_OK) {
        FUZZ_CHECK(pt_alloc_live() == live);
        return 0;
    }
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_GUIDE_BYTES);
    FUZZ_CHECK(proto_guide_encode(&w, g, &err) == PT_OK && w.len == size &&
               memcmp(w.buf, data, size) == 0);
    proto_writer_fini(&w);
    pt_guide_stats *sa = NULL, *sb = NULL;
    if (pt_guide_check(g, &err) == PT_OK && pt_guide_stats_new(g, &sa, &err) == PT_OK &&
        pt_guide_stats_new(g, &sb, &err) == PT_OK) {
        pt_vec3 mid = pt_v3_scale(pt_v3_add(g->lo, g->hi), 0.5f);
        static const pt_vec3 normals[PT_GUIDE_FACES] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                                        {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
        for (uint32_t f = 0; f < PT_GUIDE_FACES; f++) {
            uint32_t cell = pt_guide_cell(g, mid, normals[f]);
            const float u[2] = {0.3f, 0.7f};
            float pdf = 0.0f;
            pt_vec3 d = pt_guide_sample(g, cell, u, &pdf);
            FUZZ_CHECK(fabsf(pt_v3_len(d) - 1.0f) < 1e-3f);
            FUZZ_CHECK(isfinite(pdf) && pdf > 0.0f);
            float back = pt_guide_pdf(g, cell, d);
            FUZZ_CHECK(isfinite(back) && fabsf(back - pdf) <= 1e-2f * pdf + 1e-6f);
            uint32_t ql = 0;
            FUZZ_CHECK(pt_guide_pdf_leaf(g, cell, d, &ql) == back);
            FUZZ_CHECK(ql < g->nqnode && g->qnode[ql].child == 0);
            pt_guide_stats_add(sa, cell, ql, 2.5f);
            pt_guide_stats_record(sb, g, cell, d, 2.5f);
        }
        FUZZ_CHECK(memcmp(sa->sum, sb->sum, g->nqnode * sizeof *sa->sum) == 0);
        FUZZ_CHECK(memcmp(sa->count, sb->count, g->nsnode * sizeof *sa->count) == 0);
        const pt_vec3 odd[3] = {{NAN, 0, 0}, {1e30f, -1e30f, 0}, {-INFINITY, NAN, INFINITY}};
        for (int i = 0; i < 3; i++) {
            uint32_t cell = pt_guide_cell(g, odd[i], normals[i]);
            FUZZ_CHECK(cell / PT_GUIDE_FACES < g->nsnode && !g->snode[cell / PT_GUIDE_FACES].child);
            pt_guide_prefetch(g, cell);
        }
    }
    pt_guide_stats_free(sa);
    pt_guide_stats_free(sb);
    pt_guide_free(g);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
