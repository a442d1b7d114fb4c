#include "server/sched/job_impl.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/render.h"

/* ---- merging ---- */

/* A tile's samples as the passes count them: spp once stopped. */
static uint32_t tile_done_samples(const srv_job *j, uint32_t tile)
{
    return j->tiles[tile].stopped ? j->p.spp : j->tiles[tile].merged;
}

/* The samples every tile needs for the next pass to be done. */
static uint32_t next_level(const srv_job *j)
{
    uint64_t l = (uint64_t)(j->passes_done + 1) * j->p.chunk;
    return l < j->p.spp ? (uint32_t)l : j->p.spp;
}

/* Counts passes done from scratch, from the tiles' samples (one pass of the
 * tiles per pass done, so a few per job). */
void job_passes_recount(srv_job *j)
{
    while (j->passes_done < j->npasses) {
        uint32_t l = next_level(j);
        j->at_level = 0;
        for (uint32_t t = 0; t < j->ntiles; t++)
            j->at_level += tile_done_samples(j, t) >= l;
        if (j->at_level < j->ntiles)
            return;
        j->passes_done++;
    }
}

/* A tile went from `from` to `to` samples (as tile_done_samples counts). */
static void tile_moved(srv_job *j, uint32_t from, uint32_t to)
{
    if (j->passes_done >= j->npasses)
        return;
    uint32_t l = next_level(j);
    if (from < l && to >= l && ++j->at_level == j->ntiles) {
        j->passes_done++;
        job_passes_recount(j);
    }
}

static void held_remove(srv_job *j, uint32_t i)
{
    j->held[i] = j->held[--j->nheld];
    if (i < j->nheld)
        j->tasks[j->held[i].task].held = i;
}

/* Adaptive sampling stopped tile: its later tasks are done without work;
 * leased ones lose their lease, held ones their pixels, and nothing more of
 * it is cut. */
static void stop_tile(srv_job *j, uint32_t tile)
{
    tile_state *ts = &j->tiles[tile];
    for (uint32_t t = ts->head; t != NONE;) {
        task *k = &j->tasks[t];
        uint32_t next = k->next;
        if (k->state == T_LEASED) {
            job_drop_copies(j, t);
        } else if (k->state == T_HELD) {
            pt_free(j->held[k->held].px);
            held_remove(j, k->held);
        }
        k->state = T_SKIPPED;
        j->merged++;
        t = next;
    }
    ts->head = ts->tail = NONE;
    j->uncut -= (uint64_t)job_tile_pixels(j, tile) * (j->p.spp - ts->frontier);
    ts->frontier = j->p.spp;
    ts->stopped = 1;
    j->stopped++;
    j->tiles_done++;
    tile_moved(j, ts->merged, j->p.spp);
}

/* Adds task t, the first unmerged of its tile, to the film: px holds its
 * sums, samples in all (the sum of their n). owned: px is the job's to
 * free (pt_malloc), so the add may go to the adder's threads. */
static void merge_now(srv_job *j, uint32_t t, pt_pixel_acc *px, uint64_t samples, int owned)
{
    task *k = &j->tasks[t];
    tile_state *ts = &j->tiles[k->tile];
    pt_rect r = job_tile_rect(j, k->tile);
    /* Only at a decision point, which no task crosses (max_end): the
     * decision sees the same sums however the samples before were split
     * (with the min gain, the task is the chunk before the point). It reads
     * the tile's sums, so the adds in flight land first. */
    int decide =
        job_decision_point(j, k->s1) && (j->p.min_gain <= 0.0 || k->s1 - k->s0 == j->p.chunk);
    if (j->adder && owned && !decide) {
        srv_adder_post(j->adder, &j->adds, j->film, r, px);
        owned = 0;
    } else {
        if (decide)
            job_settle(j);
        uint64_t added = pt_film_add_tile(j->film, r, px);
        assert(added == samples); /* validated: n sums to the samples less rejections */
        (void)added;
    }
    j->samples += samples;
    k->state = T_MERGED;
    j->merged++;
    uint32_t from = ts->merged;
    ts->merged = k->s1;
    ts->head = k->next;
    if (ts->head == NONE)
        ts->tail = NONE;
    if (ts->merged == j->p.spp)
        j->tiles_done++;
    tile_moved(j, from, ts->merged);
    job_guide_tile_moved(j, from, ts->merged);
    pt_adaptive rule = {j->p.target_error, j->p.min_gain, j->p.min_spp};
    uint32_t tw = r.x1 - r.x0;
    if (decide && pt_tile_stops(&j->film->px[(size_t)r.y0 * j->p.width + r.x0], j->p.width, px, tw,
                                tw, r.y1 - r.y0, k->s1, &rule))
        stop_tile(j, k->tile);
    if (owned)
        pt_free(px);
}

/* Merges the held tasks of a tile that have become next in line. */
static void merge_held(srv_job *j, uint32_t tile)
{
    for (;;) {
        uint32_t t = j->tiles[tile].head;
        if (t == NONE || j->tasks[t].state != T_HELD)
            return;
        held h = j->held[j->tasks[t].held];
        held_remove(j, j->tasks[t].held);
        merge_now(j, t, h.px, h.samples, 1);
    }
}

/* The largest sum n samples can give, in fixed point: n x the cap per sample,
 * with room for each block's rounding (a double sum of 16 samples is within
 * 2^-48 of its exact value, and rounding to fixed point adds at most half a
 * unit). At most 2^32 x 4.3e27 x (1 + 2^-40) + 2^32, below 2^127 (tile.h). */
static pt_i128 acc_cap(uint32_t n)
{
    pt_i128 per = (pt_i128)(PT_MAX_SAMPLE_RADIANCE * PT_FIXED_ONE * (1.0 + 0x1p-40)) + 1;
    return per * n;
}

/* Sums non-negative and within the cap for n samples (radiance is never
 * negative: emission, base colour and textures are bounded and non-negative,
 * see common/scene/scene.c), a pixel with no samples all zero, counts
 * consistent. The sum of squares is unsigned and saturates (tile.h): any
 * value is possible but 0 is the only one for no samples. */
int job_acc_sane(const pt_pixel_acc *a, uint32_t max_n)
{
    pt_i128 cap = acc_cap(a->n);
    for (int c = 0; c < 3; c++)
        if (!(a->fsum[c] >= 0 && a->fsum[c] <= cap))
            return 0;
    return (a->n > 0 || a->fsum_sq == 0) && a->n <= max_n && a->hits <= a->n;
}

/* Each pixel's count must be the task's samples less those rejected (a NaN,
 * Inf or over-the-cap sample is not counted, render.h), the rejections must
 * add up to what the result reports, and the sums must be non-negative and at
 * most n x PT_MAX_SAMPLE_RADIANCE (acc_sane). A pixel with no samples then has
 * zero sums. */
static int pixels_plausible(const proto_result *r, uint32_t samples, pt_error *err)
{
    uint64_t missing = 0;
    for (uint32_t i = 0; i < r->npixels; i++) {
        const pt_pixel_acc *a = &r->pixels[i];
        if (a->n > samples || !job_acc_sane(a, samples)) {
            pt_error_set(err, PT_ERR_PROTO,
                         "result for task %llu: pixel %u (%u samples of %u, sums %.3g %.3g %.3g) "
                         "is not a plausible render",
                         (unsigned long long)r->task_id, i, a->n, samples, pt_acc_sum(a, 0),
                         pt_acc_sum(a, 1), pt_acc_sum(a, 2));
            return 0;
        }
        missing += samples - a->n;
    }
    if (missing != r->rejected) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: its pixels lack %llu samples in all (of %u each), but "
                     "it reports %llu rejected",
                     (unsigned long long)r->task_id, (unsigned long long)missing, samples,
                     (unsigned long long)r->rejected);
        return 0;
    }
    if (r->capped > (uint64_t)r->npixels * samples) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: %llu paths at the depth cap, more than its samples",
                     (unsigned long long)r->task_id, (unsigned long long)r->capped);
        return 0;
    }
    return 1;
}

/* A result counts clamped contributions only when its job clamps, and at
 * most two per vertex of each sample's path (its emission and its light
 * sample, common/render/render.c), max_depth + 2 vertices with the camera's. */
static int clamps_plausible(const srv_job *j, const proto_result *r, pt_error *err)
{
    if (r->clamped == 0)
        return 1;
    if (!(j->p.clamp[0] > 0.0f || j->p.clamp[1] > 0.0f)) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: clamped samples of a job without clamps",
                     (unsigned long long)r->task_id);
        return 0;
    }
    uint64_t most = (uint64_t)r->npixels * (r->s1 - r->s0) * 2u * ((uint64_t)j->p.max_depth + 2u);
    if (r->clamped > most) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: %llu contributions clamped, more than its paths hold",
                     (unsigned long long)r->task_id, (unsigned long long)r->clamped);
        return 0;
    }
    return 1;
}

/* A result carries pass sums exactly when its job asks for passes: the film
 * reads a tile's passes after its pixels, so a result without them would
 * be read past its end. (Their values are sums like any: n_even <= n was
 * checked as it was decoded.) */
static int passes_match(const srv_job *j, const proto_result *r, pt_error *err)
{
    if ((r->pass != NULL) == (j->film->pass != NULL))
        return 1;
    pt_error_set(err, PT_ERR_PROTO, "result for task %llu %s pass sums; the job %s",
                 (unsigned long long)r->task_id, r->pass ? "has" : "lacks",
                 r->pass ? "asks for none" : "asks for passes");
    return 0;
}

/* Checks r against the task it names; need_lease: the owner must hold it.
 * On SRV_MERGED or SRV_CHECK *lease_index receives the lease (-1 when none
 * was needed). */

/* Checks a leased result r against its task: on SRV_MERGED or SRV_CHECK
 * *lease_index receives owner's lease. */
static srv_outcome validate_result(const srv_job *j, uint64_t owner, const proto_result *r,
                                   int pixels_checked, int *lease_index, pt_error *err)
{
    if (r->job_id != j->id) {
        pt_error_set(err, PT_ERR_PROTO, "result for job %llu, not the running job %llu",
                     (unsigned long long)r->job_id, (unsigned long long)j->id);
        return SRV_NOT_LEASED;
    }
    /* Past the most tasks the job can have: the peer made it up. Short of
     * it, perhaps a task not cut yet: never leased to it, but no proof of
     * malice. */
    if (r->task_id >= (uint64_t)j->ntiles * j->npasses && r->task_id >= j->ntasks) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which does not exist",
                     (unsigned long long)r->task_id);
        return SRV_INVALID;
    }
    if (r->task_id >= j->ntasks) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)r->task_id);
        return SRV_NOT_LEASED;
    }
    uint32_t t = (uint32_t)r->task_id;
    const task *k = &j->tasks[t];
    int li = job_find_lease(j, t, owner);
    int verify = li >= 0 && j->leases[li].kind == L_VERIFY;
    if (!verify && (k->state == T_MERGED || k->state == T_HELD || k->state == T_SKIPPED))
        return SRV_DUPLICATE;
    if (li < 0) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)t);
        return SRV_NOT_LEASED;
    }
    pt_rect rc = job_tile_rect(j, k->tile);
    if (memcmp(&rc, &r->tile, sizeof rc) != 0 || r->s0 != k->s0 || r->s1 != k->s1 ||
        r->npixels != (rc.x1 - rc.x0) * (rc.y1 - rc.y0)) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu does not match the task's tile or samples",
                     (unsigned long long)t);
        return SRV_INVALID;
    }
    /* Checked for its own range, which is the task's (just above). */
    if (!pixels_checked && !pixels_plausible(r, k->s1 - k->s0, err))
        return SRV_INVALID;
    if (!passes_match(j, r, err) || !clamps_plausible(j, r, err) || !job_guide_result_ok(j, r, err))
        return SRV_INVALID;
    *lease_index = li;
    return verify ? SRV_CHECK : SRV_MERGED;
}

srv_outcome srv_job_validate(const srv_job *j, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 0, lease_index, err);
}

srv_outcome srv_job_validate_checked(const srv_job *j, uint64_t owner, const proto_result *r,
                                     int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 1, lease_index, err);
}

int srv_job_pixels_plausible(const proto_result *r, pt_error *err)
{
    return r->s1 > r->s0 && pixels_plausible(r, r->s1 - r->s0, err);
}

static void pixels_hash(const proto_result *r, uint8_t out[32])
{
    /* pt_pixel_acc has no implicit padding, so the bytes are the result's
     * values (camera hits included) and nothing else; nor has pt_pass_acc
     * (its pad is 0): the passes' hash is chained after the pixels'. */
    pt_sha256((const uint8_t *)r->pixels, (size_t)r->npixels * sizeof *r->pixels, out);
    if (r->pass) {
        size_t n = (size_t)r->npixels * sizeof *r->pass;
        uint8_t *both = pt_malloc(32 + n);
        if (!both) {
            memset(out, 0xff, 32); /* never a match: the check is judged again */
            return;
        }
        memcpy(both, out, 32);
        memcpy(both + 32, r->pass, n);
        pt_sha256(both, 32 + n, out);
        pt_free(both);
    }
}

static void add_check(srv_job *j, uint32_t t, uint64_t owner, const proto_result *r)
{
    if (j->nchecks == j->checks_cap) {
        check *n = pt_grow_array(j->checks, &j->checks_cap, sizeof *n, 32);
        if (!n)
            return; /* this task goes unverified; nothing else is lost */
        j->checks = n;
    }
    check *c = &j->checks[j->nchecks++];
    memset(c, 0, sizeof *c);
    c->task = t;
    c->lease = NONE;
    c->owner[0] = owner;
    pixels_hash(r, c->hash[0]);
    c->stage = C_WANT_B;
    j->vs.picked++;
}

/* Check i's live copy, or NONE. */
static uint32_t check_lease(const srv_job *j, uint32_t i)
{
    const check *c = &j->checks[i];
    if (c->stage != C_LEASED_B && c->stage != C_LEASED_C)
        return NONE;
    const lease *l = &j->leases[c->lease];
    return l->live && l->kind == L_VERIFY && l->check == i ? c->lease : NONE;
}

/* Ends check i: its lease goes, the last check takes its place. */
static void free_check(srv_job *j, uint32_t i)
{
    uint32_t s = check_lease(j, i);
    if (s != NONE)
        job_remove_lease(j, s);
    uint32_t last = --j->nchecks;
    if (i == last)
        return;
    j->checks[i] = j->checks[last];
    const check *c = &j->checks[i];
    if (c->stage == C_LEASED_B || c->stage == C_LEASED_C) {
        lease *l = &j->leases[c->lease];
        if (l->live && l->kind == L_VERIFY && l->check == last)
            l->check = i;
    }
}

/* Learns how long a task took (ms per pixel-sample) and the quantiles the
 * deadlines and backups use. */
/* The first index of sorted[0, n) whose value is not below x. */
static uint32_t lower_bound(const double *sorted, uint32_t n, double x)
{
    uint32_t lo = 0, hi = n;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (sorted[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

static void observe(srv_job *j, double ms_per_sample)
{
    /* The window stays sorted as it slides: the value leaving the ring is
     * taken out and the new one put in, two moves of at most 2 KiB, where
     * sorting the window again cost tens of microseconds of the event loop
     * per result. */
    uint32_t n = j->ntimes;
    if (n == TIMES) {
        uint32_t k = lower_bound(j->sorted, n, j->times[j->times_at]);
        memmove(&j->sorted[k], &j->sorted[k + 1], (n - k - 1) * sizeof *j->sorted);
        n--;
    }
    uint32_t k = lower_bound(j->sorted, n, ms_per_sample);
    memmove(&j->sorted[k + 1], &j->sorted[k], (n - k) * sizeof *j->sorted);
    j->sorted[k] = ms_per_sample;
    j->ntimes = ++n;
    j->times[j->times_at] = ms_per_sample;
    j->times_at = (j->times_at + 1) % TIMES;
    const double *v = j->sorted;
    j->t_high = v[(uint32_t)(SRV_DEADLINE_QUANTILE * (n - 1) + 0.5)];
    j->t_mid = v[(n - 1) / 2];
    /* A zero time (a task done within the clock's millisecond) still says
     * that something was observed. */
    if (j->t_high <= 0.0)
        j->t_high = 1e-12;
    if (j->t_mid <= 0.0)
        j->t_mid = 1e-12;
}

/* What an accepted result of lease li (or -1: a replay) teaches: the task's
 * time, who delivered it, and whether it is picked for verification. Then
 * every copy's lease goes: the first result wins. */

/* What an accepted result of lease li (or -1: a replay) of task t teaches:
 * the task's time (the job's quantiles and its owner's speed), who delivered
 * it, and whether it is picked for verification. Then every copy's lease
 * goes: the first result wins. */
static void note_accepted(srv_job *j, uint32_t t, int li, const proto_result *r, uint64_t now_ms)
{
    if (li < 0) {
        job_drop_copies(j, t); /* a replay while leased (a paused job's last result) */
        return;
    }
    lease l = j->leases[li];
    uint32_t copies = job_task_copies(j, t);
    if (copies > 1)
        j->vs.backup_samples += (uint64_t)job_task_work(j, t) * (copies - 1);
    job_drop_copies(j, t);
    owner_stat *o = &j->owners[l.owner_ix];
    if (now_ms >= l.start && now_ms > 0) {
        /* A task done within the clock's millisecond counts as half of one. */
        double ms = now_ms > l.start ? (double)(now_ms - l.start) : 0.5;
        double v = ms / job_task_work(j, t);
        observe(j, (double)(now_ms - l.start) / job_task_work(j, t));
        o->ms_ps = o->ms_ps > 0.0 ? (1.0 - SPEED_WEIGHT) * o->ms_ps + SPEED_WEIGHT * v : v;
    }
    o->merged++;
    /* What its pixels hold, without a walk: validated, they lack exactly the
     * samples the result reports rejected (pixels_plausible). */
    o->samples += (uint64_t)r->npixels * (r->s1 - r->s0) - r->rejected;
    /* Each owner's first result in a job is checked too: at a fraction of
     * 0.02 a job of 64 tasks had a 27 % chance of no check at all, and a
     * worker that lied from its first result could go unchecked. */
    if (srv_verify_picked(j->pol.verify_seed, j->id, t, j->pol.verify_fraction) ||
        (j->pol.verify_fraction > 0.0 && o->merged == 1))
        add_check(j, t, l.owner, r);
}

/* Merges or holds r, the result of task t (validated); li: its lease or -1.
 * take: r's pixels are pt_malloc'ed and the caller gives them up; the job
 * has them once this returns SRV_MERGED. */
static srv_outcome merge_task(srv_job *j, uint32_t t, int li, const proto_result *r, int take,
                              uint64_t now_ms, pt_error *err)
{
    uint32_t tile = j->tasks[t].tile;
    /* Validated: each pixel lacks exactly the samples reported rejected. */
    uint64_t samples = (uint64_t)r->npixels * (r->s1 - r->s0) - r->rejected;
    if (j->tiles[tile].head == t) {
        pt_pixel_acc *px = r->pixels;
        int own = take;
        if (r->pass && !take) {
            /* The film reads a tile's passes after its pixels: one block. */
            if (!(px = pt_malloc(job_px_bytes(j, r->npixels))))
                goto nomem;
            memcpy(px, r->pixels, (size_t)r->npixels * sizeof *px);
            memcpy(px + r->npixels, r->pass, (size_t)r->npixels * sizeof *r->pass);
            own = 1;
        }
        note_accepted(j, t, li, r, now_ms);
        j->capped += r->capped;
        j->clamped += r->clamped;
        /* Before the merge, which may end the pass and build the next
         * distribution from the statistics. */
        job_guide_accept(j, r);
        merge_now(j, t, px, samples, own);
        merge_held(j, tile);
        return SRV_MERGED;
    }
    /* Early: hold a copy until the tile's earlier samples are merged. */
    if (j->nheld == j->held_cap) {
        held *n = pt_grow_array(j->held, &j->held_cap, sizeof *n, 32);
        if (!n)
            goto nomem;
        j->held = n;
    }
    pt_pixel_acc *copy = r->pixels;
    if (!take) {
        /* The pixels, then their passes (job_px_bytes), as the film reads them. */
        if (!(copy = pt_malloc(job_px_bytes(j, r->npixels))))
            goto nomem;
        memcpy(copy, r->pixels, (size_t)r->npixels * sizeof *copy);
        if (r->pass)
            memcpy(copy + r->npixels, r->pass, (size_t)r->npixels * sizeof *r->pass);
    }
    j->held[j->nheld] = (held){t, li >= 0 ? j->leases[li].owner : 0, copy, samples};
    j->tasks[t].held = j->nheld++;
    note_accepted(j, t, li, r, now_ms);
    j->capped += r->capped;
    j->clamped += r->clamped;
    job_guide_accept(j, r);
    j->tasks[t].state = T_HELD;
    return SRV_MERGED;
nomem:
    /* Keep the lease: the task is requeued when it expires, nothing is lost. */
    pt_error_set(err, PT_ERR_NOMEM, "out of memory holding task %llu", (unsigned long long)t);
    return SRV_NOT_LEASED;
}

srv_outcome srv_job_result(srv_job *j, uint64_t owner, const proto_result *r, pt_error *err)
{
    int li;
    srv_outcome o = validate_result(j, owner, r, 0, &li, err);
    if (o == SRV_CHECK) {
        srv_verdict v;
        srv_job_check(j, li, r, &v);
        return SRV_CHECK;
    }
    return o == SRV_MERGED ? merge_task(j, j->leases[li].task, li, r, 0, 0, err) : o;
}

/* merge_task, taking r's pixels when r owns them. */
static srv_outcome merge_taking(srv_job *j, uint32_t t, int li, proto_result *r, uint64_t now_ms,
                                pt_error *err)
{
    srv_outcome o = merge_task(j, t, li, r, r->owns_pixels, now_ms, err);
    if (r->owns_pixels && o == SRV_MERGED) {
        r->pixels = NULL;
        r->pass = NULL; /* in the same block */
        r->owns_pixels = 0;
    }
    return o;
}

srv_outcome srv_job_result_validated(srv_job *j, int lease_index, proto_result *r, uint64_t now_ms,
                                     pt_error *err)
{
    return merge_taking(j, j->leases[lease_index].task, lease_index, r, now_ms, err);
}

/* 1 when [s0, s1) may be one task: within spp, crossing no decision point,
 * and (min gain) ending at one only as the chunk before it. */
static int cut_ok(const srv_job *j, uint32_t s0, uint32_t s1)
{
    return s0 < s1 && s1 <= job_max_end(j, s0) &&
           (!job_decision_point(j, s1) || j->p.min_gain <= 0.0 || s1 - s0 == j->p.chunk) &&
           (!job_forced_end(j, s0) || s1 == job_forced_end(j, s0));
}

/* Cuts [from, to) of tile into pending tasks (requeued), linked after
 * `after` (NONE: at the tail). -1 without memory or when the range cannot be
 * cut at valid points. */
static int cut_pending(srv_job *j, uint32_t tile, uint32_t from, uint32_t to, uint32_t after)
{
    while (from < to) {
        uint32_t e = job_max_end(j, from);
        if (e > to)
            e = to;
        if (!cut_ok(j, from, e))
            return -1;
        uint32_t t = job_task_add(j, tile, from, e, after);
        if (t == NONE)
            return -1;
        job_requeue_push(j, t);
        after = after == NONE ? NONE : t;
        from = e;
    }
    return 0;
}

/* The task of tile that samples [s0, s1) are, for a result without a lease
 * (a replay, a checkpoint's held result): the task cut so, else one made by
 * cutting a pending task or the tile's uncut samples (the rest pending).
 * SRV_MERGED with *out, or SRV_DUPLICATE (merged already), or SRV_INVALID
 * (the range does not fit what is cut; err says why). */
srv_outcome job_locate(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t *out,
                       pt_error *err)
{
    tile_state *ts = &j->tiles[tile];
    if (s0 < s1 && s1 <= j->p.spp && (ts->stopped || s1 <= ts->merged))
        return SRV_DUPLICATE;
    if (s0 >= s1 || s1 > j->p.spp || s0 < ts->merged || !cut_ok(j, s0, s1))
        goto misfit;
    for (uint32_t t = ts->head; t != NONE; t = j->tasks[t].next) {
        task k = j->tasks[t];
        if (k.s0 == s0 && k.s1 == s1) {
            *out = t;
            return SRV_MERGED;
        }
        if (k.s1 <= s0)
            continue;
        if (k.s0 > s0 || s1 > k.s1 || k.state != T_PENDING || (k.s0 < s0 && !cut_ok(j, k.s0, s0)) ||
            (s1 < k.s1 && !cut_ok(j, s1, k.s1)))
            goto misfit;
        /* Split the pending task: it keeps its start, the rest is pending. */
        uint32_t n = t;
        if (k.s0 < s0) {
            j->tasks[t].s1 = s0;
            if ((n = job_task_add(j, tile, s0, s1, t)) == NONE)
                goto nomem;
        } else {
            j->tasks[t].s1 = s1;
        }
        if (s1 < k.s1) {
            uint32_t r = job_task_add(j, tile, s1, k.s1, n);
            if (r == NONE)
                goto nomem;
            job_requeue_push(j, r);
        }
        *out = n;
        return SRV_MERGED;
    }
    if (s0 < ts->frontier)
        goto misfit;
    if (cut_pending(j, tile, ts->frontier, s0, NONE) != 0)
        goto misfit;
    uint32_t t = job_task_add(j, tile, s0, s1, NONE);
    if (t == NONE)
        goto nomem;
    j->uncut -= (uint64_t)job_tile_pixels(j, tile) * (s1 - ts->frontier);
    ts->frontier = s1;
    j->heap_dirty = 1;
    *out = t;
    return SRV_MERGED;
misfit:
    pt_error_set(err, PT_ERR_PROTO, "samples %u to %u of tile %u do not fit the job's tasks", s0,
                 s1, tile);
    return SRV_INVALID;
nomem:
    pt_error_set(err, PT_ERR_NOMEM, "out of memory for the tasks of tile %u", tile);
    return SRV_INVALID;
}

/* The tile whose rectangle r is, or NONE. */
static uint32_t tile_of(const srv_job *j, pt_rect r)
{
    if (r.x0 % j->p.tile || r.y0 % j->p.tile || r.x0 >= j->p.width || r.y0 >= j->p.height)
        return NONE;
    uint32_t t = (r.y0 / j->p.tile) * j->tiles_x + r.x0 / j->p.tile;
    pt_rect e = job_tile_rect(j, t);
    return memcmp(&e, &r, sizeof e) == 0 ? t : NONE;
}

uint64_t srv_job_answered(srv_job *j, int lease_index)
{
    if (lease_index < 0 || (uint32_t)lease_index >= j->lease_slots || !j->leases[lease_index].live)
        return 0;
    lease *l = &j->leases[lease_index];
    l->answered = 1;
    return (uint64_t)l->gen << 32 | (uint32_t)lease_index;
}

int srv_job_ticket_lease(const srv_job *j, uint64_t ticket)
{
    uint32_t li = (uint32_t)ticket, gen = (uint32_t)(ticket >> 32);
    /* A live lease is of a task that is leased (merging a task or stopping
     * its tile drops its copies; a leased task is never cut again), so the
     * slot's generation is all that tells it from a later lease. */
    if (gen == 0 || li >= j->lease_slots || !j->leases[li].live || j->leases[li].gen != gen)
        return -1;
    return (int)li;
}

srv_outcome srv_job_replay(srv_job *j, proto_result *r, pt_error *err)
{
    /* A pass that ended during the replay has its distribution before the
     * next pass's results are judged. */
    job_guide_settle(j);
    if (r->job_id != j->id) {
        pt_error_set(err, PT_ERR_PROTO, "result for job %llu, not the running job %llu",
                     (unsigned long long)r->job_id, (unsigned long long)j->id);
        return SRV_NOT_LEASED;
    }
    uint32_t tile = tile_of(j, r->tile), t;
    if (tile == NONE || r->npixels != job_tile_pixels(j, tile)) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu: its tile is not one of the job's",
                     (unsigned long long)r->task_id);
        return SRV_INVALID;
    }
    srv_outcome o = job_locate(j, tile, r->s0, r->s1, &t, err);
    if (o != SRV_MERGED)
        return o;
    uint8_t st = j->tasks[t].state;
    if (st == T_MERGED || st == T_HELD || st == T_SKIPPED)
        return SRV_DUPLICATE;
    job_guide_logged_last(j, r);
    if (!pixels_plausible(r, r->s1 - r->s0, err) || !passes_match(j, r, err) ||
        !clamps_plausible(j, r, err) || !job_guide_result_ok(j, r, err))
        return SRV_INVALID;
    return merge_taking(j, t, -1, r, 0, err);
}

void srv_job_check(srv_job *j, int li, const proto_result *r, srv_verdict *v)
{
    lease l = j->leases[li];
    job_remove_lease(j, (uint32_t)li);
    memset(v, 0, sizeof *v);
    v->task = l.task;
    v->kind = SRV_V_UNRESOLVED;
    j->vs.samples += (uint64_t)job_task_work(j, l.task);
    check *c = &j->checks[l.check];
    uint8_t h[32];
    pixels_hash(r, h);
    if (c->stage == C_LEASED_B) {
        if (memcmp(h, c->hash[0], 32) == 0) {
            owner_stat *o = job_owner_entry(j, c->owner[0]);
            if (o)
                o->verified++;
            v->kind = SRV_V_MATCH;
            v->honest = c->owner[0];
            j->vs.matched++;
            free_check(j, l.check);
        } else {
            c->owner[1] = l.owner;
            memcpy(c->hash[1], h, 32);
            c->stage = C_WANT_C;
            v->kind = SRV_V_MISMATCH;
            j->vs.mismatched++;
        }
        return;
    }
    if (memcmp(h, c->hash[0], 32) == 0) {
        v->kind = SRV_V_LIAR;
        v->liar = c->owner[1];
        v->honest = c->owner[0];
    } else if (memcmp(h, c->hash[1], 32) == 0) {
        v->kind = SRV_V_LIAR;
        v->liar = c->owner[0];
        v->honest = c->owner[1];
    }
    j->vs.liars += v->kind == SRV_V_LIAR;
    free_check(j, l.check);
}

void srv_job_forget_owner(srv_job *j, uint64_t owner, uint64_t *merged, uint64_t *samples)
{
    srv_job_release_owner(j, owner);
    for (uint32_t i = 0; i < j->nheld;) {
        if (j->held[i].owner != owner) {
            i++;
            continue;
        }
        uint32_t t = j->held[i].task;
        pt_free(j->held[i].px);
        held_remove(j, i);
        j->tasks[t].state = T_PENDING;
        job_requeue_push(j, t);
    }
    for (uint32_t i = 0; i < j->nchecks;) {
        check *c = &j->checks[i];
        if (c->owner[0] == owner) {
            free_check(j, i);
            continue;
        }
        /* Its answer as the second render counts for nothing: ask again. */
        if ((c->stage == C_WANT_C || c->stage == C_LEASED_C) && c->owner[1] == owner)
            c->stage -= 2;
        i++;
    }
    owner_stat *o = job_owner_entry(j, owner);
    if (merged)
        *merged = o ? o->merged - o->verified : 0;
    if (samples)
        *samples = o ? o->samples : 0;
}

srv_verify_stats srv_job_verify_stats(const srv_job *j)
{
    return j->vs;
}

void srv_job_refused(srv_job *j)
{
    j->vs.refused++;
}

int srv_job_owner_active(const srv_job *j, uint64_t owner)
{
    const owner_stat *o = job_owner_find(j, owner);
    return o && o->nleases > 0;
}
