#include "server/sched/queue_impl.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/base/text.h"
#include "common/image/exr.h"
#include "common/render/adaptive.h"
#include "common/render/crypto.h"
#include "common/render/film.h"
#include "common/render/guide_sched.h"
#include "protocol/frame.h"
#include "server/sched/dnshare.h"

#define MAX_FINISHED 1000 /* ended jobs kept in the queue's history */

int srv_entry_active(const srv_entry *j)
{
    return j->rec.state == PROTO_JOB_QUEUED || j->rec.state == PROTO_JOB_RUNNING;
}

srv_entry *srv_queue_find_any(srv_server *s, uint64_t id)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.id == id)
            return j;
    return NULL;
}

srv_entry *srv_queue_find(srv_server *s, uint64_t id)
{
    srv_entry *j = srv_queue_find_any(s, id);
    return j && !j->parent ? j : NULL;
}

void srv_queue_insert(srv_server *s, srv_entry *j)
{
    srv_entry **p = &s->jobs;
    while (*p && ((*p)->rec.priority > j->rec.priority ||
                  ((*p)->rec.priority == j->rec.priority && (*p)->rec.id < j->rec.id)))
        p = &(*p)->next;
    j->next = *p;
    *p = j;
    s->njobs++;
}

uint64_t queue_pixel_bytes(const proto_result *r)
{
    return (uint64_t)r->npixels * (sizeof(pt_pixel_acc) + (r->pass ? sizeof(pt_pass_acc) : 0));
}

/* Lets go of p, a result of j that waited for its commit: merged (the job
 * may have taken its pixels) or dropped. */
void queue_pending_fini(srv_entry *j, srv_pending *p)
{
    /* What was counted: the job may have taken the pixels and their passes
     * (r.pass NULL then), which queue_pixel_bytes would count short. */
    j->pend_bytes -= p->bytes;
    proto_result_fini(&p->r);
}

/* Drops j's results that wait for a group commit (never merged: their
 * records are gone, or the job is). */
void queue_drop_pending(srv_entry *j)
{
    for (uint32_t i = 0; i < j->npend; i++)
        queue_pending_fini(j, &j->pend[i]);
    j->npend = 0;
}

uint64_t srv_queue_pending_bytes(const srv_server *s)
{
    uint64_t n = 0;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        n += j->pend_bytes;
    return n;
}

/* What a client is shown of a failed write: "state folder full (No space
 * left on device)". Never the error's text, which names server paths. */
void queue_disk_reason(const char *folder, const pt_error *err, char *out, size_t cap)
{
    int e = err->sys_errno;
    const char *what = e == ENOSPC ? "full" : e == EDQUOT ? "over its quota" : "cannot be written";
    snprintf(out, cap, "%s %s (%s)", folder, what, e ? strerror(e) : pt_status_str(err->code));
}

static void free_run(srv_entry *j)
{
    pt_free(j->pending_rec);
    j->pending_rec = NULL;
    queue_drop_pending(j);
    pt_free(j->pend);
    j->pend = NULL;
    j->pend_cap = 0;
    j->paused = j->pending_ckpt = j->pending_sync = j->final_writing = j->final_pending = 0;
    srv_writer_free(j->writer);
    j->writer = NULL;
    srv_job_free(j->job);
    j->job = NULL;
    pt_bundle_free(j->bundle);
    j->bundle = NULL;
}

void srv_entry_free(srv_entry *j)
{
    if (!j)
        return;
    free_run(j);
    if (j->crypto)
        pt_crypto_meta_fini(j->crypto);
    pt_free(j->crypto);
    pt_free(j->frames); /* a range's bookkeeping (server/sched/frames.h): plain memory */
    j->frames = NULL;
    pt_free(j);
}

/* An ended job of the history; not a frame (srv_frames_round frees those)
 * nor a range whose frames are not freed yet. */
static int prunable(const srv_server *s, const srv_entry *j)
{
    return !srv_entry_active(j) && !j->parent && !(j->frames && s->ranges->at(j, 0));
}

void srv_queue_prune(srv_server *s)
{
    uint32_t ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        ended += prunable(s, j);
    while (ended > MAX_FINISHED) {
        srv_entry **oldest = NULL;
        for (srv_entry **p = &s->jobs; *p; p = &(*p)->next)
            if (prunable(s, *p) && (!oldest || (*p)->rec.id < (*oldest)->rec.id))
                oldest = p;
        srv_entry *j = *oldest;
        *oldest = j->next;
        srv_entry_free(j);
        s->njobs--;
        ended--;
    }
}

pt_status srv_queue_journal(srv_server *s, pt_error *err)
{
    return s->mode->durability->journal(s, err);
}

pt_status queue_journal_folder(srv_server *s, pt_error *err)
{
    srv_job_record **recs = pt_malloc_array(s->njobs ? s->njobs : 1, sizeof *recs);
    if (!recs)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (!j->parent) /* a frame's record is its range's */
            recs[n++] = &j->rec;
    pt_status st = srv_state_save_queue(s->state, recs, n, s->next_job_id, err);
    pt_free(recs);
    return st;
}

/* Writes the queue file; a failure is logged when the file was saved before
 * (once per streak: srv_queue_tick tries again until it succeeds). */
static pt_status journal_or_log(srv_server *s)
{
    pt_error err = {0};
    int was_unsaved = s->mode->durability->unsaved(s);
    pt_status st = srv_queue_journal(s, &err);
    if (st != PT_OK)
        s->counters.state_write_errors++;
    if (st != PT_OK && !was_unsaved)
        srv_log("error: cannot write the queue: %s; trying again every %d s", err.msg,
                DISK_RETRY_MS / 1000);
    return st;
}

double srv_entry_seconds(const srv_entry *j, uint64_t now)
{
    if (!srv_entry_active(j))
        return j->rec.seconds;
    return j->seconds_before + (j->t_started ? (double)(now - j->t_started) / 1000.0 : 0.0);
}

/* each_worker's walk that counts the workers holding a lease of job. */
typedef struct owner_count {
    const srv_job *job;
    uint32_t n;
} owner_count;

static void count_owner(void *ctx, uint64_t owner)
{
    owner_count *oc = ctx;
    oc->n += srv_job_owner_active(oc->job, owner) != 0;
}

/* The workers connected that hold a lease of j. */
static uint32_t job_workers(const srv_server *s, const srv_entry *j)
{
    owner_count oc = {j->job, 0};
    if (!j->job || !s->events || !s->events->each_worker)
        return 0;
    s->events->each_worker((srv_server *)s, count_owner, &oc);
    return oc.n;
}

/* The estimated relative error of the job's image as last resolved for its
 * writer (a progressive save, or the final image once flushed); -1 when
 * unknown. Not measured here: it is a pass over every pixel (57 ms on a
 * 2048x2048 film), which the loop would pay for each status, watch or
 * dashboard request and at each job's end. */
static double job_error(const srv_entry *j)
{
    double e = j->writer ? srv_writer_error(j->writer) : -1.0;
    return isfinite(e) ? e : -1.0;
}

void srv_queue_info(const srv_server *s, const srv_entry *j, proto_job_info *m)
{
    uint64_t now = pt_now_ms();
    const srv_job_record *r = &j->rec;
    memset(m, 0, sizeof *m);
    m->job_id = r->id;
    m->state = r->state;
    m->priority = r->priority;
    snprintf(m->name, sizeof m->name, "%s", r->name);
    snprintf(m->owner, sizeof m->owner, "%s", r->owner);
    snprintf(m->scene, sizeof m->scene, "%s", r->scene);
    snprintf(m->output, sizeof m->output, "%s", r->output);
    m->width = r->params.width;
    m->height = r->params.height;
    m->spp = r->params.spp;
    m->samples_total = (uint64_t)r->params.width * r->params.height * r->params.spp;
    m->tiles = srv_job_params_tiles(&r->params);
    m->passes = srv_job_params_passes(&r->params);
    m->error = -1.0;
    if (j->job) {
        m->samples_done = srv_job_samples_merged(j->job);
        m->passes_done = srv_job_passes_done(j->job);
        m->tiles_stopped = srv_job_tiles_stopped(j->job);
        m->workers = job_workers(s, j);
        m->error = job_error(j);
        m->capped = srv_job_paths_capped(j->job);
        m->clamped = srv_job_clamped(j->job);
        m->rejected = j->rejected;
    } else if (r->state == PROTO_JOB_DONE) {
        m->samples_done = r->samples_done;
        m->passes_done = m->passes;
        m->error = r->error;
    } else {
        m->samples_done = r->samples_done;
        m->error = r->samples_done ? r->error : -1.0;
    }
    if (!j->job) {
        m->capped = r->capped;
        m->clamped = r->clamped;
        m->rejected = r->rejected;
    }
    /* The pass being rendered, its distribution learned from the samples
     * before it (job_guide.c); a job not running shows none. */
    m->guided = r->params.guiding != 0;
    m->bdpt = (r->params.film_flags & PROTO_FILM_BDPT) != 0;
    if (m->guided && j->job) {
        m->guide_pass = srv_job_guide_pass(j->job);
        m->guide_spp = pt_guide_pass_start(m->guide_pass, r->params.spp);
    }
    m->seconds = srv_entry_seconds(j, now);
    m->rate = j->rate;
    m->submitted = r->submitted;
    if (r->state == PROTO_JOB_QUEUED) {
        uint32_t pos = 0;
        for (const srv_entry *q = s->jobs; q; q = q->next) {
            if (q->rec.state == PROTO_JOB_QUEUED)
                pos++;
            if (q == j)
                break;
        }
        m->queue_pos = pos;
    }
    if (r->frames.step)
        s->ranges->info(s, j, m);
    if (j->paused)
        snprintf(m->message, sizeof m->message, "paused: %s; retrying", j->pause_reason);
    else if (j->final_pending)
        snprintf(m->message, sizeof m->message, "writing: cannot write the image: %s; retrying",
                 j->out_reason);
    else if (j->final_writing && j->writer && srv_writer_denoising(j->writer) >= 0)
        snprintf(m->message, sizeof m->message, "denoising the image: %d %%",
                 srv_writer_denoising(j->writer) / 10);
    else if (j->final_writing)
        snprintf(m->message, sizeof m->message, "writing the image");
    else if (j->save_fails_logged)
        snprintf(m->message, sizeof m->message,
                 "rendering; cannot save the progressive image: %s; retrying", j->out_reason);
    else
        snprintf(m->message, sizeof m->message, "%s", r->message);
}

/* A queued job with Cryptomatte: the manifests its upload check kept in the
 * state folder (a frame: its range's, read once for the range), for its
 * image's header. A job without them (a file lost or damaged) writes the
 * layers without a manifest, which the specification allows, and says so. */
static void load_manifests(srv_server *s, srv_entry *j)
{
    srv_entry *owner = j->parent ? j->parent : j;
    if (owner->crypto ||
        !(proto_film_passes(srv_job_params_of(j->job)->film_flags) & PT_PASS_CRYPTOMATTE))
        return;
    char *text = NULL;
    pt_error err = {0};
    pt_crypto_meta *m = pt_calloc(1, sizeof *m);
    pt_status st = m ? s->mode->durability->load_manifests(s, owner->rec.id, &text, &err)
                     : pt_error_set(&err, PT_ERR_NOMEM, "out of memory");
    if (st == PT_OK && !text) {
        pt_free(m);
        return;
    }
    if (st == PT_OK)
        st = pt_crypto_meta_from_text(m, text, &err);
    pt_free(text);
    if (st != PT_OK) {
        srv_log("job %llu: its image gets no Cryptomatte manifest: %s",
                (unsigned long long)owner->rec.id, err.msg);
        pt_free(m);
        return;
    }
    owner->crypto = m;
}

void srv_entry_save_image(srv_entry *j, int final)
{
    srv_job_settle(j->job); /* the image holds every sample counted merged */
    pt_exr_meta meta = {0};
    meta.total_samples = srv_job_samples_merged(j->job); /* the writer's resolve recounts */
    meta.render_seconds = srv_entry_seconds(j, pt_now_ms());
    pt_hash_hex(j->rec.hash, meta.scene_hash);
    snprintf(meta.job_id, sizeof meta.job_id, "%llu", (unsigned long long)j->rec.id);
    if (j->parent) {
        meta.has_frame = 1;
        meta.frame = j->frame;
        meta.fps = j->parent->rec.fps;
        meta.time = pt_frames_time(j->frame, meta.fps);
    }
    const srv_entry *owner = j->parent ? j->parent : j;
    if (owner->crypto) {
        meta.attrs = owner->crypto->attrs;
        meta.nattrs = owner->crypto->nattrs;
    }
    srv_writer_submit(j->writer, &meta, final);
    j->t_last_save = pt_now_ms();
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = meta.total_samples;
}

/* Job j ended before it was done: the layers above tell every worker, so
 * each drops the tasks of it that it has not started and its threads go to
 * the next job at once (their results would be dropped anyway). */
void queue_announce_job_end(srv_server *s, const srv_entry *j)
{
    if (s->events && s->events->job_ended)
        s->events->job_ended(s, j);
}

void queue_release_owner(void *ctx, uint64_t owner)
{
    owner_release *r = ctx;
    r->n += srv_job_release_owner(r->job, owner);
}

/* The note a job that ends done keeps when some of its samples were
 * rejected: its image holds fewer samples than it asked for, which status,
 * JSON and the log then say (after any note it has already). */
static void note_rejected(srv_entry *j)
{
    uint64_t merged = j->rec.samples_done, rejected = j->rec.rejected;
    size_t n = strlen(j->rec.message);
    snprintf(j->rec.message + n, sizeof j->rec.message - n,
             "%s%llu samples were rejected (%.2f%%: NaN or Inf, or results that held no "
             "sample); the image holds the %llu others",
             n ? "; " : "", (unsigned long long)rejected,
             100.0 * (double)rejected / (double)(merged + rejected), (unsigned long long)merged);
}

void srv_queue_end_job(srv_server *s, srv_entry *j, uint8_t state, const char *message)
{
    uint64_t now = pt_now_ms();
    pt_error err = {0};
    /* A job none of whose samples survived has no image worth the name: it
     * fails, with the reason, rather than end done and black. */
    if (state == PROTO_JOB_DONE && j->job && !j->parent && !j->rec.frames.step && j->rejected > 0 &&
        srv_job_samples_merged(j->job) == 0) {
        state = PROTO_JOB_FAILED;
        message = "every sample was rejected (NaN or Inf, or workers that rendered nothing)";
    }
    if (state != PROTO_JOB_DONE && j->rec.frames.step)
        s->ranges->end(s, j, state, message); /* a range's frames end with it */
    if (state == PROTO_JOB_DONE && j->job) {
        /* The writer thread writes the image (a second or so for a large
         * one) while the loop goes on serving the other jobs' workers;
         * srv_queue_tick comes back once it is on disk. */
        if (!j->final_writing) {
            srv_entry_save_image(j, 1);
            j->final_writing = 1;
        }
        if (!srv_writer_idle(j->writer))
            return;
        j->final_writing = 0;
        if (srv_writer_share(j->writer)) {
            queue_announce_job_end(s, j); /* workers drop the regions they still hold */
            uint64_t owner;
            while (srv_dnshare_take_liar(srv_writer_share(j->writer), &owner))
                if (s->events && s->events->owner_lied)
                    s->events->owner_lied(s, owner,
                                          "a region it denoised differs from the coordinator's");
        }
        if (srv_writer_flush(j->writer, &err) != PT_OK) {
            if (err.code == PT_ERR_IO) {
                /* A full output folder: every sample stays merged, the job
                 * stays RUNNING ("writing") and the image is tried again. */
                j->t_retry = now + DISK_RETRY_MS;
                queue_disk_reason("output folder", &err, j->out_reason, sizeof j->out_reason);
                if (!j->final_pending)
                    srv_log("job %llu: rendered, but cannot write its image: %s; its samples are "
                            "kept and the image is tried again every %d s",
                            (unsigned long long)j->rec.id, err.msg, DISK_RETRY_MS / 1000);
                j->final_pending = 1;
                return;
            }
            state = PROTO_JOB_FAILED;
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "cannot write the image: %s", err.msg);
            srv_queue_end_job(s, j, state, msg);
            return;
        }
        if (j->final_pending)
            srv_log("job %llu: its image is written at last", (unsigned long long)j->rec.id);
        /* Recorded in its range before the queue file is written below, and
         * that before the frame's files go: never rendered again. */
        if (j->parent)
            s->ranges->note_done(j);
    }
    j->rec.seconds = srv_entry_seconds(j, now);
    if (j->job) {
        j->rec.samples_done = srv_job_samples_merged(j->job);
        j->rec.error = job_error(j);
        j->rec.capped = srv_job_paths_capped(j->job);
        j->rec.clamped = srv_job_clamped(j->job);
        j->rec.rejected = j->rejected;
    }
    if (state != PROTO_JOB_DONE && j->t_started)
        queue_announce_job_end(s, j);
    j->rec.state = state;
    if (message || state != PROTO_JOB_DONE) /* a done job keeps a note (server/api/workers.h) */
        snprintf(j->rec.message, sizeof j->rec.message, "%s", message ? message : "");
    else if (j->rec.rejected > 0)
        note_rejected(j);
    free_run(j);
    pt_status st = journal_or_log(s);
    /* A failed job's files stay for the operator to look at; an ended one's
     * go once the queue says it ended. */
    if (state != PROTO_JOB_FAILED && st == PT_OK)
        s->mode->durability->forget(s, j->rec.id);
    if (state == PROTO_JOB_DONE && j->parent) {
        if (!s->cfg->quiet)
            srv_log("job %llu frame %u done: %llu samples in %.1f s; %s",
                    (unsigned long long)j->parent->rec.id, j->frame,
                    (unsigned long long)j->rec.samples_done, j->rec.seconds, j->out_path);
    } else if (state == PROTO_JOB_DONE) {
        srv_log("job %llu done: %llu samples in %.1f s; %s", (unsigned long long)j->rec.id,
                (unsigned long long)j->rec.samples_done, j->rec.seconds, j->out_path);
        if (j->rec.rejected > 0)
            srv_log("job %llu: %llu samples were rejected; its image holds fewer than asked for",
                    (unsigned long long)j->rec.id, (unsigned long long)j->rec.rejected);
    } else if (!j->parent || state != PROTO_JOB_CANCELLED) { /* a cancelled frame: its range says */
        char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
        srv_log("job %llu %s%s%s", (unsigned long long)j->rec.id, proto_job_state_name(state),
                j->rec.message[0] ? ": " : "", pt_text_shown(j->rec.message, text, sizeof text));
    }
    if (s->events && s->events->job_changed)
        s->events->job_changed(s, j);
}

/* The render seconds job j had when it was last recorded: its checkpoint's
 * (ckpt), or its last saved image's when that is later. A checkpoint is
 * written only once the results log has grown (srv_queue_tick) or at a clean
 * stop, but the image every save interval, so after a kill -9 the image is
 * usually the newer record. Results log records carry no time, so the time
 * between the later of the two and a crash is not counted. An image of
 * another job or scene (a reused output name) is not trusted. */
static double resumed_seconds(const srv_entry *j, double ckpt)
{
    pt_exr_meta meta;
    /* Only a regular file: a link or a FIFO planted in the output folder is
     * not read (a FIFO would block the loop). */
    if (pt_exr_read_nofollow(j->out_path, NULL, &meta, NULL) != PT_OK)
        return ckpt;
    char id[64], hash[65];
    snprintf(id, sizeof id, "%llu", (unsigned long long)j->rec.id);
    pt_hash_hex(j->rec.hash, hash);
    if (strcmp(meta.job_id, id) != 0 || strcmp(meta.scene_hash, hash) != 0 ||
        (j->parent && (!meta.has_frame || meta.frame != (int32_t)j->frame)) ||
        !(meta.render_seconds > ckpt) || meta.render_seconds > 1e12)
        return ckpt;
    return meta.render_seconds;
}

pt_status queue_restore_folder(srv_server *s, srv_entry *j, pt_error *err)
{
    srv_ckpt_extra x;
    uint32_t replayed;
    int torn;
    pt_status st = srv_state_restore(s->state, j->job, &x, &replayed, &torn, err);
    if (st != PT_OK)
        return st;
    j->seconds_before = resumed_seconds(j, x.seconds);
    j->rejected = x.rejected;
    j->rays = x.rays;
    if (torn)
        srv_log("job %llu: dropped the incomplete last record of its results log (a "
                "write cut short by a crash; it was never merged)",
                (unsigned long long)j->rec.id);
    if (srv_job_tasks_merged(j->job) > 0)
        srv_log("job %llu resumed: %llu samples merged (%u from its results log)",
                (unsigned long long)j->rec.id, (unsigned long long)srv_job_samples_merged(j->job),
                replayed);
    return PT_OK;
}

/* The per-run seed of verification's picks, made at its first use. */
static uint64_t verify_seed(srv_server *s)
{
    if (!s->verify_seed) {
        uint8_t b[PROTO_NONCE_SIZE];
        if (proto_auth_nonce(b, NULL) == PT_OK)
            memcpy(&s->verify_seed, b, sizeof s->verify_seed);
        s->verify_seed |= 1; /* made once, even without randomness */
    }
    return s->verify_seed;
}

int srv_entry_ready(srv_server *s, srv_entry *j)
{
    if (j->job)
        return 1;
    if (j->rec.frames.step)
        return s->ranges->ready(s, j);
    pt_error err = {0};
    pt_status st = srv_job_new(j->rec.id, &j->rec.params, j->rec.hash, &j->job, &err);
    if (st == PT_OK)
        srv_job_set_adder(j->job, s->adder);
    if (st == PT_OK)
        st = s->mode->durability->restore(s, j, &err);
    if (st == PT_OK && !j->writer)
        load_manifests(s, j);
    if (st == PT_OK && !j->writer)
        st = srv_writer_new(j->out_path, srv_job_film(j->job),
                            (srv_job_params_of(j->job)->film_flags & PROTO_FILM_TRANSPARENT) != 0,
                            &s->cfg->view, &j->writer, &err);
    if (st == PT_OK) {
        uint32_t ff = srv_job_params_of(j->job)->film_flags;
        srv_writer_set_denoise(j->writer,
                               !(ff & PROTO_FILM_DENOISE)              ? 0
                               : (ff & PROTO_FILM_DENOISE_PROGRESSIVE) ? SRV_WRITER_DENOISE_ALL
                                                                       : SRV_WRITER_DENOISE_FINAL,
                               s->cfg->max_denoise);
        if ((ff & PROTO_FILM_DENOISE) && s->cfg->denoise_share && !srv_writer_share(j->writer))
            st = srv_writer_share_denoise(j->writer, s->cfg->denoise_side, j->rec.id,
                                          verify_seed(s), s->cfg->verify_fraction, &err);
    }
    if (st != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        return 0;
    }
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = srv_job_samples_merged(j->job);
    j->t_last_save = pt_now_ms();
    j->rate_t = pt_now_ms();
    j->rate_samples = j->saved_samples;
    return 1;
}

/* Leases the first task the queue has for owner: the first job in queue order
 * with a task to hand out, so when the running job has nothing left for an
 * idle worker (its last pass), the next job starts. */
/* The lease policy of every job (server/sched/job.h): hard deadlines no sooner
 * than the lease timeout, FIRST_FACTOR times it before a job's first result
 * (the first tasks of a worker also load the scene), DEADLINE_FACTOR times
 * the observed quantile for a task's size after; backup copies of leases
 * BACKUP_FACTOR times older than the median. */
#define FIRST_FACTOR 10u
#define DEADLINE_FACTOR 8.0
#define BACKUP_FACTOR 3.0

static void set_policy(srv_server *s, srv_entry *j)
{
    uint64_t first = (uint64_t)s->cfg->lease_ms * FIRST_FACTOR;
    srv_lease_policy pol = {.floor_ms = s->cfg->lease_ms,
                            .first_ms = first > UINT32_MAX ? UINT32_MAX : (uint32_t)first,
                            .factor = DEADLINE_FACTOR,
                            .backup_factor = BACKUP_FACTOR,
                            .verify_fraction = s->cfg->verify_fraction,
                            .verify_seed = verify_seed(s),
                            .task_ms = s->cfg->task_ms};
    /* Test hook (tests/integration/test_guiding_farm.sh): with
     * PTSERVE_TEST_LEASE_GATE=SPP:FILE, no task of a job starting at SPP
     * samples or later is leased until FILE exists: a job held mid-render
     * however loaded the machine, for a kill at a known point. Unset in
     * production. */
    const char *e = getenv("PTSERVE_TEST_LEASE_GATE");
    char *rest = NULL;
    unsigned long long spp = e ? strtoull(e, &rest, 10) : 0;
    if (e && rest != e && *rest == ':' && rest[1] && spp > 0 && spp <= UINT32_MAX) {
        pol.hold_spp = (uint32_t)spp;
        pol.hold_gate = rest + 1;
    }
    srv_job_set_policy(j->job, &pol);
}

/* Leases a task of j (a still, or a frame of a range) to owner. */
static int lease_from(srv_server *s, srv_entry *j, uint64_t owner, uint64_t now, proto_task *t)
{
    if (!srv_entry_active(j) || j->paused || !j->job)
        return 0;
    if (!j->t_started)
        set_policy(s, j);
    if (!srv_job_lease(j->job, owner, now, s->cfg->lease_ms, t))
        return 0;
    s->counters.tasks_leased++;
    if (!j->t_started)
        j->t_started = now;
    return 1;
}

/* A range's task: of its earliest frame that has one to hand out, so early
 * frames finish first (server/sched/frames.h). */
static int lease_frames(srv_server *s, srv_entry *p, uint64_t owner, uint64_t now, proto_task *t)
{
    srv_entry *f;
    for (uint32_t i = 0; (f = s->ranges->at(p, i)); i++)
        if (lease_from(s, f, owner, now, t)) {
            s->ranges->pose(f, t);
            if (!p->t_started)
                p->t_started = now;
            return 1;
        }
    return 0;
}

int srv_queue_lease(srv_server *s, uint64_t owner, uint64_t now, proto_task *t)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        /* A frame is leased through its range, in the range's place. */
        if (j->parent || !srv_entry_active(j) || j->paused || !srv_entry_ready(s, j))
            continue;
        if (!(j->rec.frames.step ? lease_frames(s, j, owner, now, t)
                                 : lease_from(s, j, owner, now, t)))
            continue;
        if (j->rec.state == PROTO_JOB_QUEUED) {
            j->rec.state = PROTO_JOB_RUNNING;
            journal_or_log(s);
            if (s->mode->logs_starts) {
                char scene[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_PATH)];
                srv_log("job %llu started (%s, %ux%u, %u spp)", (unsigned long long)j->rec.id,
                        pt_text_shown(j->rec.scene, scene, sizeof scene), j->rec.params.width,
                        j->rec.params.height, j->rec.params.spp);
            }
        }
        return 1;
    }
    return 0;
}

uint32_t srv_queue_release_owner(srv_server *s, uint64_t owner)
{
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job)
            n += srv_job_release_owner(j->job, owner);
    s->counters.tasks_requeued += n;
    return n;
}

int srv_queue_end_complete(srv_server *s)
{
    int ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j) && !j->final_writing && !j->final_pending &&
            srv_job_complete(j->job)) {
            srv_queue_end_job(s, j, PROTO_JOB_DONE, NULL);
            ended += !srv_entry_active(j); /* not while its image is written */
        }
    /* Frames done make room for the next ones, and end their range. */
    return ended + s->ranges->round(s);
}

void srv_queue_unlink(srv_server *s, srv_entry *j)
{
    for (srv_entry **q = &s->jobs; *q; q = &(*q)->next)
        if (*q == j) {
            *q = j->next;
            s->njobs--;
            return;
        }
}

srv_entry *srv_queue_find_scene(srv_server *s, const uint8_t hash[32])
{
    pt_error err = {0};
    srv_entry *j = s->jobs;
    /* A frame's bundle is its range's (jobs/ID/bundle of the range's id). */
    while (j && !(srv_entry_active(j) && !j->parent && memcmp(hash, j->rec.hash, 32) == 0))
        j = j->next;
    if (j && !j->bundle && s->mode->durability->load_bundle(s, j, &err) != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        j = NULL;
    }
    return j && j->bundle ? j : NULL;
}

int srv_queue_find_guide(srv_server *s, const uint8_t hash[32], const uint8_t **data, size_t *len)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_job_guide_bytes(j->job, hash, data, len))
            return 1;
    return 0;
}

typedef struct expiry {
    srv_server *s;
    uint64_t now;
} expiry;

static void on_missed(void *ctx, uint64_t owner, uint64_t task)
{
    expiry *e = ctx;
    (void)task;
    if (e->s->events && e->s->events->owner_missed)
        e->s->events->owner_missed(e->s, owner, e->now);
}

/* Leases are checked at most this often, not every loop round: each check
 * walks every lease of every job, thousands on a big farm, and deadlines are
 * at least a --lease-timeout (seconds) away. */
#define EXPIRE_MS 50

int srv_queue_expire(srv_server *s, uint64_t now)
{
    if (now - s->t_expire < EXPIRE_MS && now >= s->t_expire)
        return 0;
    /* Workers not read (srv_loop_hold) are not silent: their heartbeats
     * wait behind the hold, and are read in the lease timeout after it. */
    if (s->log_held || (s->t_released && now - s->t_released < s->cfg->lease_ms))
        return 0;
    s->t_expire = now;
    expiry e = {s, now};
    for (srv_entry *j = s->jobs; j; j = j->next) {
        uint32_t n;
        if (j->job && srv_entry_active(j) &&
            (n = srv_job_expire(j->job, now, NULL, on_missed, &e))) {
            s->counters.tasks_expired += n;
            srv_log("job %llu: %u leases expired; tasks requeued", (unsigned long long)j->rec.id,
                    n);
        }
    }
    return 1;
}

pt_status queue_load_bundle_folder(srv_server *s, srv_entry *j, pt_error *err)
{
    return srv_state_load_bundle(s->state, j->rec.id, j->rec.hash, &j->bundle, err);
}

pt_status queue_load_manifests_folder(srv_server *s, uint64_t id, char **text, pt_error *err)
{
    return srv_state_load_manifests(s->state, id, text, err);
}

/* ---- one job: nothing kept (srv_durability_none) ---- */

static pt_status none_journal(srv_server *s, pt_error *err)
{
    (void)s;
    (void)err;
    return PT_OK;
}

static int none_unsaved(const srv_server *s)
{
    (void)s;
    return 0;
}

static void none_forget(srv_server *s, uint64_t id)
{
    (void)s;
    (void)id;
}

/* A fresh job starts from nothing; the bundle is in memory from setup. */
static pt_status none_entry(srv_server *s, srv_entry *j, pt_error *err)
{
    (void)s;
    (void)j;
    (void)err;
    return PT_OK;
}

static pt_status none_manifests(srv_server *s, uint64_t id, char **text, pt_error *err)
{
    (void)s;
    (void)id;
    (void)err;
    *text = NULL;
    return PT_OK;
}

static void none_tick_job(srv_server *s, srv_entry *j, uint64_t now)
{
    (void)s;
    (void)j;
    (void)now;
}

static void none_tick(srv_server *s, uint64_t now)
{
    (void)s;
    (void)now;
}

const srv_durability srv_durability_none = {
    .journal = none_journal,
    .unsaved = none_unsaved,
    .forget = none_forget,
    .restore = none_entry,
    .load_bundle = none_entry,
    .load_manifests = none_manifests,
    .tick_job = none_tick_job,
    .tick = none_tick,
};

void srv_queue_free(srv_server *s)
{
    while (s->jobs) {
        srv_entry *j = s->jobs;
        s->jobs = j->next;
        srv_entry_free(j);
    }
    s->njobs = 0;
    s->single = NULL;
    srv_state_close(s->state);
    s->state = NULL;
}

int srv_queue_may_change(const srv_entry *j, const char *who, int admin)
{
    return admin || strcmp(j->rec.owner, who) == 0;
}

void srv_queue_cancel(srv_server *s, srv_entry *j, const char *by)
{
    if (!srv_entry_active(j))
        return;
    char msg[PROTO_MAX_ERROR_TEXT + 1];
    snprintf(msg, sizeof msg, "cancelled by %s", by);
    srv_queue_end_job(s, j, PROTO_JOB_CANCELLED, msg);
}

int srv_queue_set_priority(srv_server *s, srv_entry *j, int32_t priority, const char *by)
{
    if (!srv_entry_active(j) || j->rec.priority == priority)
        return 0;
    j->rec.priority = priority;
    srv_queue_unlink(s, j);
    srv_queue_insert(s, j);
    pt_error err = {0};
    if (srv_queue_journal(s, &err) != PT_OK)
        srv_log("job %llu: priority %d not saved: %s", (unsigned long long)j->rec.id, priority,
                err.msg);
    srv_log("job %llu: priority %d, set by %s", (unsigned long long)j->rec.id, priority, by);
    return 1;
}
