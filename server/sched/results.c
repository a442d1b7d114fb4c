#include "server/sched/queue_impl.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/base/text.h"
#include "common/image/exr.h"
#include "common/render/adaptive.h"
#include "common/render/film.h"
#include "protocol/frame.h"

static pt_status checkpoint_quiet(srv_server *s, srv_entry *j, pt_error *err)
{
    if (!j->job)
        return PT_OK;
    srv_ckpt_extra x = {srv_entry_seconds(j, pt_now_ms()), j->rejected, j->rays};
    double t0 = pt_now_s();
    pt_status st = srv_state_checkpoint(s->state, j->job, &x, err);
    srv_histogram_add(&s->counters.checkpoint, pt_now_s() - t0);
    queue_drop_pending(j); /* its records went with the log; never merged */
    if (st != PT_OK)
        s->counters.state_write_errors++;
    return st;
}

/* Starts j's checkpoint off the loop (server/store/state.h): a snapshot of the job
 * now, its results log rotated, and the records of the results not merged
 * yet logged again in the new log (the snapshot does not hold them), to be
 * merged once that log is durable. */
void queue_checkpoint_start(srv_server *s, srv_entry *j)
{
    pt_error err = {0};
    double t0 = pt_now_s();
    srv_job *snap = srv_job_snapshot(j->job);
    if (!snap) {
        srv_log("error: job %llu: out of memory for a checkpoint; trying again later",
                (unsigned long long)j->rec.id);
        return;
    }
    srv_ckpt_extra x = {srv_entry_seconds(j, pt_now_ms()), j->rejected, j->rays};
    pt_status st = srv_state_checkpoint_start(s->state, snap, &x, &err);
    if (st == PT_OK) {
        /* Each encoded again (the same sums; checkpoints are rare, results
         * are decoded once). */
        uint32_t k = 0;
        proto_writer w;
        proto_writer_init(&w, PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD);
        for (uint32_t i = 0; i < j->npend; i++) {
            srv_pending *p = &j->pend[i];
            p->commit = srv_state_commit_next(s->state);
            size_t mark;
            proto_writer_reset(&w);
            if (proto_frame_begin(&w, PROTO_MSG_RESULT, &mark, &err) == PT_OK &&
                proto_msg_encode_result(&w, &p->r, &err) == PT_OK &&
                proto_frame_end(&w, mark, &err) == PT_OK &&
                srv_state_log_result(s->state, j->rec.id, w.buf, w.len, &err) == PT_OK)
                j->pend[k++] = *p;
            else
                queue_pending_fini(j, p); /* never merged; its task is leased again */
        }
        proto_writer_fini(&w);
        j->npend = k;
    }
    srv_histogram_add(&s->counters.checkpoint, pt_now_s() - t0);
    if (st != PT_OK && st != PT_AGAIN) {
        s->counters.state_write_errors++;
        if (st == PT_ERR_IO) {
            j->pending_ckpt = 1;
            queue_pause_job(s, j, "cannot write its checkpoint", &err);
        } else {
            srv_log("error: job %llu: cannot write its checkpoint: %s",
                    (unsigned long long)j->rec.id, err.msg);
        }
    }
}

pt_status srv_entry_checkpoint(srv_server *s, srv_entry *j, pt_error *err)
{
    pt_status st = checkpoint_quiet(s, j, err);
    if (st != PT_OK)
        srv_log("error: job %llu: cannot write its checkpoint: %s (its results log still holds "
                "every merged task)",
                (unsigned long long)j->rec.id, err->msg);
    return st;
}

/* The state folder cannot take j's writes: no task of j is leased until the
 * failed write succeeds (srv_queue_tick tries it again). Its leases are
 * requeued and the workers told to drop its tasks (JOB_END), since results
 * that cannot be logged could not be merged. Logged once per pause. */
void queue_pause_job(srv_server *s, srv_entry *j, const char *what, const pt_error *err)
{
    uint64_t now = pt_now_ms();
    j->t_retry = now + DISK_RETRY_MS;
    if (j->paused)
        return;
    j->paused = 1;
    j->t_paused = now;
    queue_disk_reason("state folder", err, j->pause_reason, sizeof j->pause_reason);
    owner_release r = {j->job, 0};
    if (j->job && s->events && s->events->each_worker)
        s->events->each_worker(s, queue_release_owner, &r);
    uint32_t n = r.n;
    s->counters.tasks_requeued += n;
    if (j->t_started)
        queue_announce_job_end(s, j);
    srv_log("job %llu paused: %s: %s; %u leased tasks requeued; trying again every %d s",
            (unsigned long long)j->rec.id, what, err->msg, n, DISK_RETRY_MS / 1000);
}

/* Keeps r, a logged result of j that owns its pixels, to merge once the
 * commit that holds its record has returned; takes the pixels (r's are then
 * NULL, not owned). */
static pt_status push_pending(srv_server *s, srv_entry *j, uint64_t owner, proto_result *r,
                              uint64_t arrived)
{
    assert(r->owns_pixels);
    if (j->npend == j->pend_cap) {
        srv_pending *n = pt_grow_array(j->pend, &j->pend_cap, sizeof *n, 16);
        if (!n)
            return PT_ERR_NOMEM;
        j->pend = n;
    }
    uint64_t bytes = queue_pixel_bytes(r);
    j->pend[j->npend++] =
        (srv_pending){*r, owner, srv_state_commit_next(s->state), arrived, 0, bytes};
    j->pend_bytes += bytes;
    r->pixels = NULL;
    r->owns_pixels = 0;
    r->guide = NULL; /* the guiding statistics go with the pending result too */
    r->owns_guide = 0;
    return PT_OK;
}

static void resume(srv_server *s, srv_entry *j, uint64_t now);

/* Tries the write that paused j again; resumes j when it succeeds. */
void queue_retry_paused(srv_server *s, srv_entry *j, uint64_t now)
{
    if (now < j->t_retry)
        return;
    j->t_retry = now + DISK_RETRY_MS;
    pt_error err = {0};
    if (j->pending_sync) {
        /* Synced again by the next group commit; srv_queue_committed resumes
         * the job when that succeeds. */
        srv_state_log_resync(s->state, j->rec.id, &err);
        return;
    }
    if (j->pending_rec) {
        if (srv_state_log_result(s->state, j->rec.id, j->pending_rec, j->pending_len, &err) !=
            PT_OK)
            return;
        /* Logged: merged once durable, as a restart's replay would (its
         * lease is gone; should its task have been merged meanwhile, it is a
         * duplicate). It was decoded when it came (a record that no longer
         * decodes is not possible; it would be dropped, as at a replay). */
        proto_result r;
        if (proto_msg_decode_result(j->pending_rec + PROTO_FRAME_HEADER,
                                    j->pending_len - PROTO_FRAME_OVERHEAD, NULL, 0, &r,
                                    &err) == PT_OK &&
            push_pending(s, j, 0, &r, now) != PT_OK) {
            proto_result_fini(&r);
            return;
        }
        pt_free(j->pending_rec);
        j->pending_rec = NULL;
    }
    if (j->pending_ckpt) {
        if (checkpoint_quiet(s, j, &err) != PT_OK)
            return;
        j->pending_ckpt = 0;
    }
    resume(s, j, now);
}

static void resume(srv_server *s, srv_entry *j, uint64_t now)
{
    (void)s;
    j->paused = 0;
    j->pause_reason[0] = '\0';
    srv_log("job %llu resumed: the state folder takes its writes again (paused %.1f s)",
            (unsigned long long)j->rec.id, (double)(now - j->t_paused) / 1000.0);
}
pt_status srv_queue_log_result(srv_server *s, srv_entry *j, uint64_t owner, int lease_index,
                               proto_result *r, const uint8_t *frame, size_t len, uint8_t **own,
                               uint64_t arrived, pt_error *err)
{
    if (j->paused)
        return pt_error_set(err, PT_ERR_IO, "job %llu is paused", (unsigned long long)j->rec.id);
    uint64_t commit = srv_state_commit_next(s->state);
    pt_status st = own && *own ? srv_state_log_result_take(s->state, j->rec.id, own, len, err)
                               : srv_state_log_result(s->state, j->rec.id, frame, len, err);
    if (st == PT_OK) {
        st = push_pending(s, j, owner, r, arrived);
        if (st != PT_OK)
            return pt_error_set(err, st, "out of memory for a result");
        srv_pending *p = &j->pend[j->npend - 1];
        p->commit = commit;
        p->ticket = srv_job_answered(j->job, lease_index);
        return PT_OK;
    }
    s->counters.state_write_errors++;
    if (st != PT_ERR_IO)
        return st;
    /* Kept for the retry: logged and merged once the folder takes writes. */
    if (own && *own) {
        j->pending_rec = *own;
        *own = NULL;
    } else if ((j->pending_rec = pt_malloc(len ? len : 1)) != NULL) {
        memcpy(j->pending_rec, frame, len);
    }
    if (j->pending_rec)
        j->pending_len = len;
    queue_pause_job(s, j, "cannot write its results log", err);
    return st;
}

static void on_commit(void *ctx, uint64_t id, pt_status st, const pt_error *err)
{
    srv_server *s = ctx;
    srv_entry *j = srv_queue_find_any(s, id); /* a frame's too */
    if (!j || !j->job)
        return;
    if (st != PT_OK) {
        s->counters.state_write_errors++;
        /* The log is cut back to its last good commit; its records since
         * are kept and written again by the retry (server/store/state.h), unless
         * memory was short, and then they are gone, never merged. */
        if (st == PT_ERR_NOMEM)
            queue_drop_pending(j);
        j->pending_sync = 1;
        queue_pause_job(s, j, "cannot make its results log durable", err);
        return;
    }
    j->committed = srv_state_commit_next(s->state) - 1;
    if (j->pending_sync) {
        j->pending_sync = 0;
        if (j->paused && !j->pending_rec && !j->pending_ckpt)
            resume(s, j, pt_now_ms());
    }
}

void srv_queue_verify_summary(const srv_entry *j)
{
    srv_verify_stats v = srv_job_verify_stats(j->job);
    uint64_t total = srv_job_samples_merged(j->job);
    /* Verified: compared with a second render. A task picked that no other
     * worker rendered was not verified, and is counted apart. */
    uint64_t compared = v.matched + v.mismatched;
    srv_log("job %llu: verified %llu of %llu tasks (%llu picked, %llu never compared: no other "
            "worker rendered them; %llu matched, %llu mismatched, %llu liars): "
            "%llu extra samples, %.2f%% of %llu; %llu backup copies, %llu expired leases, %llu "
            "results refused",
            (unsigned long long)j->rec.id, (unsigned long long)compared,
            (unsigned long long)srv_job_tasks_total(j->job), (unsigned long long)v.picked,
            (unsigned long long)(v.picked > compared ? v.picked - compared : 0),
            (unsigned long long)v.matched, (unsigned long long)v.mismatched,
            (unsigned long long)v.liars, (unsigned long long)(v.samples + v.backup_samples),
            total ? 100.0 * (double)(v.samples + v.backup_samples) / (double)total : 0.0,
            (unsigned long long)total, (unsigned long long)v.backups, (unsigned long long)v.expired,
            (unsigned long long)v.refused);
}

srv_outcome srv_queue_merge(srv_server *s, srv_entry *j, uint64_t owner, int lease_index,
                            proto_result *r, uint64_t arrived, pt_error *err)
{
    uint64_t before = srv_job_samples_merged(j->job);
    double t0 = pt_now_s();
    srv_outcome o = lease_index >= 0
                        ? srv_job_result_validated(j->job, lease_index, r, arrived, err)
                        : srv_job_replay(j->job, r, err);
    srv_histogram_add(&s->counters.merge, pt_now_s() - t0);
    uint64_t merged = srv_job_samples_merged(j->job) - before;
    s->counters.samples_merged += merged;
    if (o != SRV_MERGED)
        return o;
    if (s->events && s->events->result_merged)
        s->events->result_merged(s, owner, merged, pt_now_ms());
    j->rejected += r->rejected;
    s->counters.samples_rejected += r->rejected;
    j->rays += r->rays;
    if (srv_job_complete(j->job))
        srv_queue_verify_summary(j);
    return o;
}

/* Merges p's result, held until its log record was durable: through the
 * lease it was judged the answer to when it arrived, while that lease is
 * live (nothing it was judged by has changed since), else judged anew. */
static void merge_logged(srv_server *s, srv_entry *j, srv_pending *p)
{
    pt_error err = {0};
    uint64_t owner = p->owner; /* a connection id, maybe gone now */
    proto_result *r = &p->r;
    srv_outcome o = SRV_MERGED;
    int li = srv_job_ticket_lease(j->job, p->ticket);
    /* Its pixels were checked whole when it arrived and have not changed. */
    if (li < 0)
        o = srv_job_validate_checked(j->job, owner, r, &li, &err);
    /* Its lease may have gone since it arrived (expired, its worker left or
     * the job paused): it is still a render of its task, and durable, so it
     * is merged as a restart's replay would (a duplicate changes nothing). */
    if (o == SRV_MERGED || o == SRV_NOT_LEASED)
        srv_queue_merge(s, j, owner, o == SRV_MERGED ? li : -1, r, p->arrived, &err);
}

/* Merges j's results whose records the commit done made durable (those of a
 * failed commit wait for the retry's). */
static void merge_durable(srv_server *s, srv_entry *j, uint64_t done)
{
    uint32_t k = 0, i = 0;
    for (; i < j->npend && j->pend[i].commit <= done && j->committed >= j->pend[i].commit; i++) {
        srv_pending *p = &j->pend[i];
        if (j->job && srv_entry_active(j))
            merge_logged(s, j, p);
        queue_pending_fini(j, p); /* unless the job took its pixels */
    }
    for (; i < j->npend; i++)
        j->pend[k++] = j->pend[i];
    j->npend = k;
}

void srv_queue_committed(srv_server *s, int wait)
{
    uint64_t done;
    /* One commit is in flight at a time: once it is collected there is no
     * other to ask for (asking would only read the eventfd again). */
    if (srv_state_commit_collect(s->state, wait, &done, on_commit, s))
        for (srv_entry *j = s->jobs; j; j = j->next)
            if (j->npend)
                merge_durable(s, j, done);
}

void srv_queue_commit_all(srv_server *s)
{
    srv_queue_committed(s, 1); /* the commit in flight */
    if (srv_state_commit_start(s->state))
        srv_queue_committed(s, 1); /* the rest */
}

/* The progressive saves' outcome, logged once per streak of failures. */
static void note_saves(srv_entry *j)
{
    unsigned long fails;
    pt_error err = {0};
    if (srv_writer_last(j->writer, &fails, &err) != PT_OK) {
        if (!j->save_fails_logged)
            srv_log("job %llu: cannot save its progressive image: %s; its samples are kept and "
                    "the save is tried again",
                    (unsigned long long)j->rec.id, err.msg);
        queue_disk_reason("output folder", &err, j->out_reason, sizeof j->out_reason);
        j->save_fails_logged = fails;
    } else if (j->save_fails_logged) {
        srv_log("job %llu: its progressive image is saved again", (unsigned long long)j->rec.id);
        j->save_fails_logged = 0;
    }
}

/* The queue file written again after a failure; a checkpoint's outcome. */
static void folder_tick(srv_server *s, uint64_t now)
{
    if (srv_state_queue_unsaved(s->state) && now >= s->queue_retry) {
        s->queue_retry = now + DISK_RETRY_MS;
        pt_error err = {0};
        if (srv_queue_journal(s, &err) == PT_OK)
            srv_log("the queue file is written again");
    }
    uint64_t id;
    pt_status cst;
    pt_error err = {0};
    if (srv_state_checkpoint_collect(s->state, &id, &cst, &err) && cst != PT_OK) {
        srv_entry *j = srv_queue_find_any(s, id);
        s->counters.state_write_errors++;
        if (j && j->job && srv_entry_active(j) && err.code == PT_ERR_IO) {
            j->pending_ckpt = 1;
            queue_pause_job(s, j, "cannot write its checkpoint", &err);
        } else {
            srv_log("error: job %llu: cannot write its checkpoint: %s", (unsigned long long)id,
                    err.msg);
        }
    }
}

/* Checkpoint cost stays proportional to what the log has taken in. */
static void folder_tick_job(srv_server *s, srv_entry *j, uint64_t now)
{
    (void)now;
    if (j->paused || srv_state_checkpoint_busy(s->state))
        return;
    /* srv_job_film settles: the loop waits here, once a round, for the
     * merge threads' adds in flight. That wait is their flow control, not
     * an accident: without it the adds' ring fills and the loop does the
     * adds itself (farm_scale.sh, unpaced, chunk 64: 5.8-9.0 loop us per
     * result with it, 19-20 without). */
    const pt_film *f = srv_job_film(j->job);
    uint64_t film_bytes = (uint64_t)f->width * f->height * sizeof(pt_pixel_acc);
    if (srv_state_log_bytes(s->state, j->rec.id) >= srv_state_ckpt_limit(s->state, film_bytes))
        queue_checkpoint_start(s, j);
}

static int folder_unsaved(const srv_server *s)
{
    return srv_state_queue_unsaved(s->state);
}

static void folder_forget(srv_server *s, uint64_t id)
{
    srv_state_forget_job(s->state, id);
}

const srv_durability srv_durability_folder = {
    .journal = queue_journal_folder,
    .unsaved = folder_unsaved,
    .forget = folder_forget,
    .restore = queue_restore_folder,
    .load_bundle = queue_load_bundle_folder,
    .load_manifests = queue_load_manifests_folder,
    .tick_job = folder_tick_job,
    .tick = folder_tick,
};

void srv_queue_tick(srv_server *s, uint64_t now)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        if (j->paused)
            queue_retry_paused(s, j, now);
        if (j->final_writing || j->final_pending) {
            if (j->final_writing ? srv_writer_idle(j->writer) : now >= j->t_retry)
                srv_queue_end_job(s, j, PROTO_JOB_DONE, NULL);
            continue;
        }
        note_saves(j);
        uint64_t merged = srv_job_samples_merged(j->job);
        int pass_done = srv_job_passes_done(j->job) > j->saved_passes;
        if ((pass_done || merged > j->saved_samples) &&
            (double)(now - j->t_last_save) >= s->cfg->save_interval * 1000.0 &&
            !srv_job_complete(j->job)) {
            double t0 = pt_now_s();
            srv_entry_save_image(j, 0);
            srv_histogram_add(&s->counters.save, pt_now_s() - t0);
        }
        if (now - j->rate_t >= 1000) {
            j->rate = (double)(merged - j->rate_samples) * 1000.0 / (double)(now - j->rate_t);
            j->rate_t = now;
            j->rate_samples = merged;
        }
        s->mode->durability->tick_job(s, j, now);
    }
    s->mode->durability->tick(s, now);
}
