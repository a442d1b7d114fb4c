#include "common/render/guide_run.h"

#include <string.h>

#include "common/base/alloc.h"
#include "common/render/guide_sched.h"

pt_status pt_guide_run_new(pt_guide_run *run, pt_vec3 lo, pt_vec3 hi, uint32_t spp,
                           uint32_t threads, int record_last, pt_error *err)
{
    memset(run, 0, sizeof *run);
    run->spp = spp;
    run->threads = threads;
    run->record_last = record_last;
    run->stats = pt_calloc(threads, sizeof *run->stats);
    run->gd = pt_calloc(threads, sizeof *run->gd);
    if (!run->stats || !run->gd)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for %u threads' guiding", threads);
    pt_guide_grow_bounds(&lo, &hi);
    return pt_guide_new_uniform(lo, hi, &run->guide, err);
}

static void free_stats(pt_guide_run *run)
{
    for (uint32_t i = 0; run->stats && i < run->threads; i++) {
        pt_guide_stats_free(run->stats[i]);
        run->stats[i] = NULL;
    }
}

pt_status pt_guide_run_begin(pt_guide_run *run, pt_error *err)
{
    run->s0 = run->pass == 0 ? 0 : run->s1;
    if (run->s0 >= run->spp)
        return PT_OK;
    run->s1 = pt_guide_pass_end(run->pass, run->spp);
    int record = run->record_last || !pt_guide_pass_last(run->pass, run->spp);
    for (uint32_t i = 0; i < run->threads; i++) {
        pt_status st = pt_guide_stats_new(run->guide, &run->stats[i], err);
        if (st != PT_OK)
            return st;
        run->gd[i] = (pt_render_guiding){run->guide, pt_guide_pass_prob(run->pass),
                                         record ? run->stats[i] : NULL};
    }
    return PT_OK;
}

pt_status pt_guide_run_merge(pt_guide_run *run, pt_error *err)
{
    if (run->threads == 0 || !run->gd[0].stats)
        return PT_OK; /* the last pass recorded nothing */
    for (uint32_t i = 1; i < run->threads; i++) {
        pt_status st = pt_guide_stats_merge(run->stats[0], run->stats[i], err);
        if (st != PT_OK)
            return st;
    }
    return PT_OK;
}

pt_status pt_guide_run_end(pt_guide_run *run, pt_guide **kept, pt_error *err)
{
    int last = pt_guide_pass_last(run->pass, run->spp);
    if (!last || kept) {
        pt_guide *next = NULL;
        if (!last) {
            pt_status st = pt_guide_build(run->guide, run->stats[0],
                                          pt_guide_split_count(run->pass), &next, err);
            if (st != PT_OK)
                return st;
        }
        if (kept)
            *kept = run->guide;
        else
            pt_guide_free(run->guide);
        run->guide = next;
    }
    free_stats(run);
    run->pass++;
    return PT_OK;
}

void pt_guide_run_free(pt_guide_run *run)
{
    free_stats(run);
    pt_free(run->stats);
    pt_free(run->gd);
    pt_guide_free(run->guide);
    memset(run, 0, sizeof *run);
}
