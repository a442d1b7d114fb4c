/*
 * guide_run.h - the training passes of a guided render on one machine
 * (ptworker --guiding on, ptbench-guide-probe): the guide each pass samples,
 * per-thread statistics, their merge and the next pass's build, in the
 * farm's schedule (guide_sched.h), so that every such program learns the
 * distributions the coordinator would from the same samples.
 *
 *     pt_guide_run run;
 *     pt_guide_run_new(&run, lo, hi, spp, threads, 0, &err);
 *     while (pt_guide_run_begin(&run, &err) == PT_OK && run.s0 < run.spp) {
 *         ... thread i renders samples [run.s0, run.s1) with run.gd[i] ...
 *         pt_guide_run_merge(&run, &err);   (run.stats[0]: the pass's sums)
 *         pt_guide_run_end(&run, NULL, &err); (the next pass's guide)
 *     }
 *     pt_guide_run_free(&run);
 *
 * Not thread-safe: one thread drives the passes between the renders.
 */
#ifndef PT_COMMON_RENDER_GUIDE_RUN_H
#define PT_COMMON_RENDER_GUIDE_RUN_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"
#include "common/render/guide.h"
#include "common/render/render.h"

typedef struct pt_guide_run {
    uint32_t spp, threads;
    int record_last;        /* the last pass records too (a probe reads it) */
    uint32_t pass, s0, s1;  /* the pass begun: samples [s0, s1) of every pixel */
    pt_guide *guide;        /* the distribution it samples */
    pt_guide_stats **stats; /* per thread; after pt_guide_run_merge stats[0] sums them */
    pt_render_guiding *gd;  /* per thread, for pt_render_tile_guided */
} pt_guide_run;

/* A run of spp samples per pixel on threads threads over the scene's bounds
 * [lo, hi] (grown here as the farm grows them); pass 0 is next. record_last:
 * the last pass records statistics (ptworker's does not: nothing is built
 * from them). PT_ERR_NOMEM; *run is freeable either way. */
pt_status pt_guide_run_new(pt_guide_run *run, pt_vec3 lo, pt_vec3 hi, uint32_t spp,
                           uint32_t threads, int record_last, pt_error *err);

/* Begins the next pass: s0, s1, fresh statistics and gd. s0 == spp when
 * every pass is done. */
pt_status pt_guide_run_begin(pt_guide_run *run, pt_error *err);

/* Adds every thread's statistics of the pass into stats[0]: integer sums,
 * the same in any order (nothing for a last pass that records nothing). */
pt_status pt_guide_run_merge(pt_guide_run *run, pt_error *err);

/* Ends the pass: builds the next pass's guide from stats[0] (none after the
 * last pass) and frees the pass's statistics. kept NULL: the pass's guide is
 * freed once the next is built (the last pass's stays run->guide, freed
 * with the run); else every pass's, the last one's too, is the caller's in
 * *kept (a tool that renders a pass's samples again later). */
pt_status pt_guide_run_end(pt_guide_run *run, pt_guide **kept, pt_error *err);

void pt_guide_run_free(pt_guide_run *run);

#endif
