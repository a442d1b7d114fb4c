/*
 * guide_sched.h - the schedule of path guiding's training passes, one for
 * every program: ptworker --guiding renders it on one machine, the farm's
 * coordinator (server/sched/job_guide.c) hands its passes out as tasks, and
 * both must learn the same distributions from the same samples for the
 * image to be the same bits.
 *
 * Pass k covers samples [pt_guide_pass_start(k), pt_guide_pass_end(k))
 * (guide.h): 16, 32, 64... samples per pixel (Mueller, Gross & Novak 2017
 * double them), each pass rendered with the distribution learned from the
 * pass before, the last running to spp when less than the next pass would
 * take is left after it. Pass 0 renders with a uniform guide
 * over the scene's bounds (grown by pt_guide_grow_bounds) and samples
 * nothing from it; later passes draw PT_GUIDE_PASS_PROB of a guided
 * vertex's directions from theirs. Pass k's statistics build pass k + 1's
 * distribution with the split threshold pt_guide_split_count(k).
 *
 * Pure inline functions; any thread.
 */
#ifndef PT_COMMON_RENDER_GUIDE_SCHED_H
#define PT_COMMON_RENDER_GUIDE_SCHED_H

#include <math.h>
#include <stdint.h>

#include "common/math/vec.h"
#include "common/render/guide.h" /* pt_guide_pass_end: where each pass ends */

#define PT_GUIDE_FIRST_PASS 16u /* samples of pass 0 */
/* A guided vertex's chance to sample the guide, pass 1 on. Where the guide
 * has not learned a caustic (its pdf there below the BSDF's, as at most of
 * the rough vertices that send the glass scenes' fireflies to a lamp through
 * glass or chrome: ptbench-paths --guiding on, docs/bench/guiding.md), the
 * one-sample mixture weighs those paths up to 1 / (1 - p) times the BSDF's
 * own weight: 2 at 0.5, 1.33 at 0.25, which lowered the error per sample of
 * the glass ball, TransmissionTest and ToyCar. */
#define PT_GUIDE_PASS_PROB 0.25f
/* Mueller et al.'s split threshold, c sqrt(2^k), with their c = 12000. It
 * was 3000, which did better on a 64 x 64 Cornell box (its passes hold few
 * records); at the benchmark's 128 x 128 the larger leaves give the same
 * error per sample on the NVIDIA Cornell box and the glass scenes, a guided
 * sample of the Cornell box costs 8 % less (docs/bench/guiding.md, "The
 * spatial split threshold") and a 1080p job's distribution is smaller. */
#define PT_GUIDE_SPLIT_C 12000.0

static inline uint32_t pt_guide_pass_start(uint32_t k, uint32_t spp)
{
    return k == 0 ? 0 : pt_guide_pass_end(k - 1, spp);
}

/* The pass that sample index s (< spp) belongs to. */
static inline uint32_t pt_guide_pass_of(uint32_t s, uint32_t spp)
{
    uint32_t k = 0;
    while (pt_guide_pass_end(k, spp) <= s && k < 31)
        k++;
    return k;
}

/* The chance a guided vertex of pass k draws from the guide. */
static inline float pt_guide_pass_prob(uint32_t k)
{
    return k == 0 ? 0.0f : PT_GUIDE_PASS_PROB;
}

/* The split threshold of the build after pass k. */
static inline uint64_t pt_guide_split_count(uint32_t k)
{
    return (uint64_t)(PT_GUIDE_SPLIT_C * sqrt((double)(1u << (k < 20 ? k : 20))));
}

/* The first guide's bounds from the scene's: a little larger, so that a
 * point on them is inside. */
static inline void pt_guide_grow_bounds(pt_vec3 *lo, pt_vec3 *hi)
{
    pt_vec3 ext = pt_v3_scale(pt_v3_sub(*hi, *lo), 1e-3f);
    ext = pt_v3_add(ext, pt_v3(1e-3f, 1e-3f, 1e-3f));
    *lo = pt_v3_sub(*lo, ext);
    *hi = pt_v3_add(*hi, ext);
}

#endif
