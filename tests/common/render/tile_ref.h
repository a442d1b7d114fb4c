/*
 * tile_ref.h - a tile's pixel sums as pt_render_tile documents them, built
 * from pt_render_sample one path at a time (test_render.c, test_bdpt.c):
 * per aligned block of PT_SAMPLE_BLOCK samples in sample order, then the
 * block sums in order. The rect's pixels in row order into ref[0 ..]; the
 * samples, rejected ones and rays into *rs.
 */
#ifndef PT_TESTS_COMMON_RENDER_TILE_REF_H
#define PT_TESTS_COMMON_RENDER_TILE_REF_H

#include <string.h>

#include "common/render/render.h"
#include "common/render/tile.h"

static inline void tile_ref(const pt_renderer *r, pt_rect rect, uint32_t s0, uint32_t s1,
                            pt_pixel_acc *ref, pt_render_stats *rs)
{
    uint32_t tw = rect.x1 - rect.x0, n = tw * (rect.y1 - rect.y0);
    memset(ref, 0, n * sizeof *ref);
    for (uint32_t k = 0; k < n; k++) {
        for (uint32_t b0 = s0; b0 < s1;) {
            uint32_t b1 = (b0 / PT_SAMPLE_BLOCK + 1) * PT_SAMPLE_BLOCK;
            b1 = b1 < s1 ? b1 : s1;
            pt_block_acc blk = {{0, 0, 0}, 0, 0, 0};
            for (uint32_t i = b0; i < b1; i++) {
                int cov = 0;
                if (!pt_block_acc_sample(
                        &blk, pt_render_sample(r, rect.x0 + k % tw, rect.y0 + k / tw, i, rs, &cov)))
                    rs->rejected++;
                else
                    blk.hits += (uint32_t)cov;
            }
            pt_pixel_acc_add_block(&ref[k], &blk);
            rs->samples += blk.n;
            b0 = b1;
        }
    }
}

#endif
