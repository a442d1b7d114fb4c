#include "server/serve.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/film.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "server/core.h"
#include "server/local.h"
#include "server/loop.h"
#include "server/queue.h"
#include "server/requests.h"
#include "server/upload.h"

/* ---- mode.h -------------------------------------------------------------- */

/*
 * mode.h - the coordinator's two modes, as data (srv_mode, server/core.h).
 *
 * One job (cfg->scene_path set): the scene is loaded once to refuse a broken
 * one before any worker starts, packed into a bundle and rendered to
 * cfg->out_path; no clients, no state folder; a progress line each second;
 * the loop ends when the image is complete, on a signal, or when every local
 * worker has exited first; the exit status is 0 (complete), 130
 * (interrupted) or 1.
 *
 * Queue (cfg->state_dir set): the queue is loaded from the state folder and
 * its running jobs resumed from their checkpoints and results logs; clients
 * fill it; each round's results are fdatasync'd after the leases are sent
 * (group commit) and complete jobs end at once; on a signal every running
 * job is checkpointed and its image saved, and the exit status is 0.
 *
 * Threads: called only from the event-loop thread.
 */

extern const srv_mode srv_mode_one_job;
extern const srv_mode srv_mode_queue;

/* The mode cfg asks for. */
const srv_mode *srv_mode_for(const srv_config *cfg);

/* ---- queue --------------------------------------------------------------- */

#define CKPT_MIN_LOG (16u << 20) /* checkpoint once a job's results log passes this */
#define MAX_FINISHED 1000        /* ended jobs kept in the queue's history */

int srv_entry_active(const srv_entry *j)
{
    return j->rec.state == PROTO_JOB_QUEUED || j->rec.state == PROTO_JOB_RUNNING;
}

srv_entry *srv_queue_find(srv_server *s, uint64_t id)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.id == id)
            return j;
    return NULL;
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

static void free_run(srv_entry *j)
{
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
    pt_free(j);
}

void srv_queue_prune(srv_server *s)
{
    uint32_t ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        ended += !srv_entry_active(j);
    while (ended > MAX_FINISHED) {
        srv_entry **oldest = NULL;
        for (srv_entry **p = &s->jobs; *p; p = &(*p)->next)
            if (!srv_entry_active(*p) && (!oldest || (*p)->rec.id < (*oldest)->rec.id))
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
    if (!s->state)
        return PT_OK;
    srv_job_record **recs = pt_malloc_array(s->njobs ? s->njobs : 1, sizeof *recs);
    if (!recs)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        recs[n++] = &j->rec;
    pt_status st = srv_state_save_queue(s->state, recs, n, s->next_job_id, err);
    pt_free(recs);
    return st;
}

static void journal_or_log(srv_server *s)
{
    pt_error err = {0};
    if (srv_queue_journal(s, &err) != PT_OK)
        srv_log("error: cannot write the queue: %s", err.msg);
}

double srv_entry_seconds(const srv_entry *j, uint64_t now)
{
    if (!srv_entry_active(j))
        return j->rec.seconds;
    return j->seconds_before + (j->t_started ? (double)(now - j->t_started) / 1000.0 : 0.0);
}

static uint32_t job_workers(const srv_server *s, const srv_entry *j)
{
    uint32_t n = 0;
    if (!j->job)
        return 0;
    for (const srv_conn *c = s->conns; c; c = c->next)
        if (c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER &&
            srv_job_owner_active(j->job, c->id))
            n++;
    return n;
}

/* The estimated relative error of the job's image so far; -1 when unknown. */
static double job_error(const srv_job *job)
{
    const pt_film *f = srv_job_film(job);
    double e = pt_tile_rel_error(f->px, f->width, f->width, f->height);
    return isfinite(e) ? e : -1.0;
}

void srv_queue_info(const srv_server *s, const srv_entry *j, proto_job_info *m)
{
    uint64_t now = srv_now_ms();
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
        m->error = job_error(j->job);
    } else if (r->state == PROTO_JOB_DONE) {
        m->samples_done = r->samples_done;
        m->passes_done = m->passes;
        m->error = r->error;
    } else {
        m->samples_done = r->samples_done;
        m->error = r->samples_done ? r->error : -1.0;
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
    snprintf(m->message, sizeof m->message, "%s", r->message);
}

void srv_entry_save_image(srv_entry *j)
{
    pt_image *img = NULL;
    const pt_film *film = srv_job_film(j->job);
    if (pt_image_new(film->width, film->height, &img, NULL) != PT_OK) {
        srv_log("out of memory for a progressive image of job %llu; will try again",
                (unsigned long long)j->rec.id);
        return;
    }
    pt_film_resolve(film, img);
    pt_exr_meta meta = {0};
    meta.total_samples = pt_film_total_samples(film);
    meta.render_seconds = srv_entry_seconds(j, srv_now_ms());
    pt_hash_hex(j->rec.hash, meta.scene_hash);
    snprintf(meta.job_id, sizeof meta.job_id, "%llu", (unsigned long long)j->rec.id);
    srv_writer_submit(j->writer, img, &meta);
    j->t_last_save = srv_now_ms();
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = meta.total_samples;
}

void srv_entry_checkpoint(srv_server *s, srv_entry *j)
{
    if (!s->state || !j->job)
        return;
    srv_ckpt_extra x = {srv_entry_seconds(j, srv_now_ms()), j->rejected, j->rays};
    pt_error err = {0};
    if (srv_state_checkpoint(s->state, j->job, &x, &err) != PT_OK)
        srv_log("error: job %llu: cannot write its checkpoint: %s (its results log still holds "
                "every merged task)",
                (unsigned long long)j->rec.id, err.msg);
}

/* Tells every worker that job j ended before it was done, so each drops the
 * tasks of it that it has not started and its threads go to the next job at
 * once (their results would be dropped anyway). */
static void announce_job_end(srv_server *s, const srv_entry *j)
{
    proto_job_ref ref = {j->rec.id};
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->role != PROTO_ROLE_WORKER || c->state != SRV_C_READY || c->closing)
            continue;
        size_t mark;
        if (srv_conn_frame_open(c, PROTO_MSG_JOB_END, &mark))
            srv_conn_frame_close(c, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL));
        srv_conn_update_events(s, c);
    }
}

void srv_queue_end_job(srv_server *s, srv_entry *j, uint8_t state, const char *message)
{
    uint64_t now = srv_now_ms();
    pt_error err = {0};
    if (state == PROTO_JOB_DONE && j->job) {
        srv_entry_save_image(j);
        if (srv_writer_flush(j->writer, &err) != PT_OK) {
            state = PROTO_JOB_FAILED;
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "cannot write the image: %s", err.msg);
            srv_queue_end_job(s, j, state, msg);
            return;
        }
    }
    j->rec.seconds = srv_entry_seconds(j, now);
    if (j->job) {
        j->rec.samples_done = srv_job_samples_merged(j->job);
        j->rec.error = job_error(j->job);
    }
    if (state != PROTO_JOB_DONE && j->t_started)
        announce_job_end(s, j);
    j->rec.state = state;
    snprintf(j->rec.message, sizeof j->rec.message, "%s", message ? message : "");
    free_run(j);
    pt_status st = srv_queue_journal(s, &err);
    if (st != PT_OK)
        srv_log("error: cannot write the queue: %s", err.msg);
    /* A failed job's files stay for the operator to look at; an ended one's
     * go once the queue says it ended. */
    if (s->state && state != PROTO_JOB_FAILED && st == PT_OK)
        srv_state_forget_job(s->state, j->rec.id);
    if (state == PROTO_JOB_DONE)
        srv_log("job %llu done: %llu samples in %.1f s; %s", (unsigned long long)j->rec.id,
                (unsigned long long)j->rec.samples_done, j->rec.seconds, j->out_path);
    else
        srv_log("job %llu %s%s%s", (unsigned long long)j->rec.id, proto_job_state_name(state),
                j->rec.message[0] ? ": " : "", j->rec.message);
    srv_requests_notify_watchers(s, j);
}

int srv_entry_ready(srv_server *s, srv_entry *j)
{
    if (j->job)
        return 1;
    pt_error err = {0};
    pt_status st = srv_job_new(j->rec.id, &j->rec.params, j->rec.hash, &j->job, &err);
    if (st == PT_OK && s->state) {
        srv_ckpt_extra x;
        uint32_t replayed;
        int torn;
        st = srv_state_restore(s->state, j->job, &x, &replayed, &torn, &err);
        if (st == PT_OK) {
            j->seconds_before = x.seconds;
            j->rejected = x.rejected;
            j->rays = x.rays;
            if (torn)
                srv_log("job %llu: dropped the incomplete last record of its results log (a "
                        "write cut short by a crash; it was never merged)",
                        (unsigned long long)j->rec.id);
            if (srv_job_tasks_merged(j->job) > 0)
                srv_log("job %llu resumed: %llu samples merged (%u from its results log)",
                        (unsigned long long)j->rec.id,
                        (unsigned long long)srv_job_samples_merged(j->job), replayed);
        }
    }
    if (st == PT_OK && !j->writer)
        st = srv_writer_new(j->out_path, &j->writer, &err);
    if (st != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        return 0;
    }
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = srv_job_samples_merged(j->job);
    j->t_last_save = srv_now_ms();
    j->rate_t = srv_now_ms();
    j->rate_samples = j->saved_samples;
    return 1;
}

/* Leases the first task the queue has for owner: the first job in queue order
 * with a task to hand out, so when the running job has nothing left for an
 * idle worker (its last pass), the next job starts. */
static int lease_any(srv_server *s, uint64_t owner, uint64_t now, proto_task *t)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!srv_entry_active(j) || !srv_entry_ready(s, j))
            continue;
        if (!srv_job_lease(j->job, owner, now, s->cfg->lease_ms, t))
            continue;
        if (!j->t_started)
            j->t_started = now;
        if (j->rec.state == PROTO_JOB_QUEUED) {
            j->rec.state = PROTO_JOB_RUNNING;
            journal_or_log(s);
            if (s->mode->logs_starts)
                srv_log("job %llu started (%s, %ux%u, %u spp)", (unsigned long long)j->rec.id,
                        j->rec.scene, j->rec.params.width, j->rec.params.height, j->rec.params.spp);
        }
        return 1;
    }
    return 0;
}

void srv_queue_hand_out(srv_server *s)
{
    uint64_t now = srv_now_ms();
    int dry = 0; /* the queue had nothing to lease: skip the other workers */
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->state != SRV_C_READY || c->closing)
            continue;
        if (c->fetch)
            srv_requests_pump_fetch(s, c);
        while (!dry && c->role == PROTO_ROLE_WORKER && c->want > 0 && srv_conn_has_room(c)) {
            proto_task t;
            if (!lease_any(s, c->id, now, &t)) {
                dry = 1;
                break;
            }
            size_t mark;
            if (!srv_conn_frame_open(c, PROTO_MSG_TASK, &mark) ||
                !srv_conn_frame_close(c, mark, proto_msg_encode_task(&c->out, &t, NULL))) {
                srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
                break;
            }
            c->want--;
        }
        srv_conn_update_events(s, c);
    }
}

void srv_queue_release_owner(srv_server *s, const srv_conn *c, int report)
{
    if (c->state != SRV_C_READY || c->role != PROTO_ROLE_WORKER)
        return;
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job)
            n += srv_job_release_owner(j->job, c->id);
    if (n && report)
        srv_log("worker %s left; %u leased tasks requeued", c->name, n);
}

int srv_queue_end_complete(srv_server *s)
{
    int ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j) && srv_job_complete(j->job)) {
            srv_queue_end_job(s, j, PROTO_JOB_DONE, NULL);
            ended++;
        }
    return ended;
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
    while (j && !(srv_entry_active(j) && memcmp(hash, j->rec.hash, 32) == 0))
        j = j->next;
    if (j && !j->bundle && s->state &&
        srv_state_load_bundle(s->state, j->rec.id, j->rec.hash, &j->bundle, &err) != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        j = NULL;
    }
    return j && j->bundle ? j : NULL;
}

pt_status srv_queue_log_result(srv_server *s, const srv_entry *j, const uint8_t *payload,
                               size_t len, pt_error *err)
{
    if (!s->state)
        return PT_OK;
    return srv_state_log_result(s->state, j->rec.id, payload, len, err);
}

void srv_queue_expire(srv_server *s, uint64_t now)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j) && srv_job_expire(j->job, now, NULL) > 0)
            srv_log("job %llu: leases expired; tasks requeued", (unsigned long long)j->rec.id);
}

void srv_queue_tick(srv_server *s, uint64_t now)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        uint64_t merged = srv_job_samples_merged(j->job);
        int pass_done = srv_job_passes_done(j->job) > j->saved_passes;
        if ((pass_done || merged > j->saved_samples) &&
            (double)(now - j->t_last_save) >= s->cfg->save_interval * 1000.0 &&
            !srv_job_complete(j->job))
            srv_entry_save_image(j);
        if (now - j->rate_t >= 1000) {
            j->rate = (double)(merged - j->rate_samples) * 1000.0 / (double)(now - j->rate_t);
            j->rate_t = now;
            j->rate_samples = merged;
        }
        /* Checkpoint cost stays proportional to what the log has taken in. */
        if (s->state) {
            const pt_film *f = srv_job_film(j->job);
            uint64_t film_bytes = (uint64_t)f->width * f->height * PROTO_RESULT_PIXEL_SIZE;
            uint64_t limit = film_bytes > CKPT_MIN_LOG ? film_bytes : CKPT_MIN_LOG;
            if (srv_state_log_bytes(s->state, j->rec.id) >= limit)
                srv_entry_checkpoint(s, j);
        }
    }
}

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

/* ---- mode ---------------------------------------------------------------- */

/* ---- one job ----------------------------------------------------------------------- */

static void format_eta(double sec, char *buf, size_t n)
{
    if (!(sec >= 0) || sec > 360000)
        snprintf(buf, n, "--");
    else if (sec >= 3600)
        snprintf(buf, n, "%dh%02dm", (int)(sec / 3600), (int)(sec / 60) % 60);
    else if (sec >= 60)
        snprintf(buf, n, "%dm%02ds", (int)(sec / 60), (int)sec % 60);
    else
        snprintf(buf, n, "%.0fs", sec);
}

static void print_progress(srv_server *s, uint64_t now)
{
    const srv_entry *j = s->single;
    const srv_job_params *p = &j->rec.params;
    double el = (double)(now - s->t_start) / 1000.0;
    uint64_t done = srv_job_samples_merged(j->job);
    double total = (double)p->width * p->height * p->spp;
    double rate = el > 0 ? (double)done / el : 0;
    char eta[32];
    format_eta(rate > 0 ? (total - (double)done) / rate : -1, eta, sizeof eta);
    fprintf(stderr, "\rptserve: pass %u/%u  %.1f/%u spp  %.3g samples/s  %u workers  ETA %s\033[K",
            srv_job_passes_done(j->job), srv_job_passes(j->job),
            (double)done / ((double)p->width * p->height), p->spp, rate, s->nworkers, eta);
}

static pt_status setup_single(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    /* Load once here so a broken scene fails before any worker starts. */
    pt_scene_opts so = {0};
    so.camera_name = cfg->job.camera[0] ? cfg->job.camera : NULL;
    pt_scene *scene = NULL;
    if ((st = pt_scene_load(cfg->scene_path, &so, &scene, err)) != PT_OK)
        return st;
    srv_job_params jp = cfg->job;
    if (jp.width == 0) {
        float aspect = scene->camera.aspect > 0 ? scene->camera.aspect : 1.0f;
        jp.width = 512;
        jp.height = (uint32_t)(512.0f / aspect + 0.5f);
        if (jp.height == 0)
            jp.height = 1;
    }
    uint32_t ntris = scene->num_triangles;
    pt_scene_free(scene);
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    srv_queue_insert(s, j);
    s->single = j;
    if ((st = pt_bundle_pack(cfg->scene_path, &j->bundle, err)) != PT_OK)
        return st;
    j->rec.id = j->rec.seq = 1;
    j->rec.state = PROTO_JOB_QUEUED;
    j->rec.error = -1.0;
    j->rec.params = jp;
    pt_hex_decode(j->bundle->hash, j->rec.hash, 32);
    const char *base = strrchr(cfg->scene_path, '/');
    snprintf(j->rec.scene, sizeof j->rec.scene, "%s", base ? base + 1 : cfg->scene_path);
    snprintf(j->out_path, sizeof j->out_path, "%s", cfg->out_path);
    if (!srv_entry_ready(s, j))
        return pt_error_set(err, PT_ERR_IO, "%s", j->rec.message);
    if (!cfg->quiet)
        srv_log("%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u", cfg->scene_path,
                ntris, jp.width, jp.height, jp.spp, srv_job_passes(j->job), jp.chunk, jp.tile);
    return PT_OK;
}

/* The final image and the summary. Returns the exit status. */
static int finish_single(srv_server *s)
{
    const srv_config *cfg = s->cfg;
    srv_entry *j = s->single;
    pt_error err = {0};
    if (!j->job)
        return 1;
    srv_entry_save_image(j);
    pt_status st = srv_writer_flush(j->writer, &err);
    if (!cfg->quiet)
        print_progress(s, srv_now_ms());
    fputc('\n', stderr);
    double secs = (double)(srv_now_ms() - s->t_start) / 1000.0;
    uint64_t samples = srv_job_samples_merged(j->job);
    const srv_job_params *p = &j->rec.params;
    if (st != PT_OK) {
        fprintf(stderr, "ptserve: cannot write %s: %s\n", cfg->out_path, err.msg);
        return 1;
    }
    if (srv_job_complete(j->job)) {
        uint64_t tasks = srv_job_tasks_total(j->job);
        fprintf(stderr,
                "ptserve: done in %.2fs: %llu samples (%.4g samples/s), %llu rejected "
                "samples (NaN/Inf); wrote %s\n",
                secs, (unsigned long long)samples, (double)samples / secs,
                (unsigned long long)j->rejected, cfg->out_path);
        fprintf(stderr,
                "ptserve: wire: %llu bytes in, %llu out (scene %zu); %.3f bytes per "
                "sample, %.0f per task\n",
                (unsigned long long)s->bytes_in, (unsigned long long)s->bytes_out,
                j->bundle ? j->bundle->size : 0,
                (double)(s->bytes_in + s->bytes_out) / (double)samples,
                (double)(s->bytes_in + s->bytes_out) / (double)tasks);
        return 0;
    }
    if (srv_loop_stopped()) {
        fprintf(stderr, "ptserve: interrupted after %.2fs; %s holds %llu of %llu samples\n", secs,
                cfg->out_path, (unsigned long long)samples,
                (unsigned long long)p->width * p->height * p->spp);
        return 130;
    }
    return 1;
}

static int single_over(const srv_server *s)
{
    return !s->single->job || srv_job_complete(s->single->job);
}

static void single_after_leases(srv_server *s)
{
    (void)s; /* nothing is durable, and the loop ends with the job */
}

static void single_tick(srv_server *s, uint64_t now)
{
    if (s->single->job && !s->cfg->quiet && now - s->t_last_print >= 1000) {
        s->t_last_print = now;
        print_progress(s, now);
    }
}

static int single_local_gone(srv_server *s)
{
    if (srv_job_complete(s->single->job))
        return 0;
    fprintf(stderr, "\nptserve: all %u local workers exited before the image was complete\n",
            s->local.nchildren);
    return 1;
}

const srv_mode srv_mode_one_job = {
    .name = "one job",
    .serves_clients = 0,
    .logs_starts = 0,
    .setup = setup_single,
    .over = single_over,
    .after_leases = single_after_leases,
    .tick = single_tick,
    .local_gone = single_local_gone,
    .finish = finish_single,
};

/* ---- the queue --------------------------------------------------------------------- */

static pt_status setup_queue(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    if ((st = srv_state_open(cfg->state_dir, &s->state, err)) != PT_OK)
        return st;
    if (cfg->output_dir)
        snprintf(s->out_dir, sizeof s->out_dir, "%s", cfg->output_dir);
    else
        snprintf(s->out_dir, sizeof s->out_dir, "%s/output", cfg->state_dir);
    char tmp[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s/tmp", cfg->state_dir);
    pt_remove_tree(tmp); /* uploads a crash left half-verified */
    if ((st = pt_mkdirs(s->out_dir, 0, err)) != PT_OK || (st = pt_mkdirs(tmp, 1, err)) != PT_OK)
        return st;
    srv_job_record *recs;
    uint32_t n;
    if ((st = srv_state_load_queue(s->state, &recs, &n, &s->next_job_id, err)) != PT_OK)
        return st;
    uint32_t counts[6] = {0};
    for (uint32_t i = 0; i < n; i++) {
        srv_entry *j = pt_calloc(1, sizeof *j);
        if (!j) {
            pt_free(recs);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        j->rec = recs[i];
        snprintf(j->out_path, sizeof j->out_path, "%s/%s", s->out_dir, j->rec.output);
        srv_queue_insert(s, j);
        counts[j->rec.state]++;
    }
    pt_free(recs);
    if (!cfg->quiet || counts[PROTO_JOB_RUNNING] || counts[PROTO_JOB_QUEUED])
        srv_log("state %s: %u jobs queued, %u running, %u ended; images go to %s", cfg->state_dir,
                counts[PROTO_JOB_QUEUED], counts[PROTO_JOB_RUNNING],
                counts[PROTO_JOB_DONE] + counts[PROTO_JOB_CANCELLED] + counts[PROTO_JOB_FAILED],
                s->out_dir);
    /* Resume the running jobs now: their checkpoints are checked at start. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.state == PROTO_JOB_RUNNING)
            srv_entry_ready(s, j);
    return PT_OK;
}

/* Every running job checkpointed, its image saved. */
static int finish_queue(srv_server *s)
{
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        srv_entry_checkpoint(s, j);
        srv_entry_save_image(j);
        pt_error err = {0};
        if (srv_writer_flush(j->writer, &err) != PT_OK)
            srv_log("job %llu: cannot write its image: %s", (unsigned long long)j->rec.id, err.msg);
        n++;
    }
    srv_log("stopped; %u running jobs checkpointed", n);
    return 0;
}

static int queue_over(const srv_server *s)
{
    (void)s; /* until a signal */
    return 0;
}

static void queue_after_leases(srv_server *s)
{
    pt_error err = {0};
    /* Leases need no disk: they leave before the group commit, so workers do
     * not wait on it for their next tasks. Then the results logged in this
     * round reach the disk. */
    srv_loop_flush_all(s);
    if (srv_state_sync(s->state, &err) != PT_OK)
        srv_log("error: %s", err.msg);
    if (srv_queue_end_complete(s))
        srv_queue_hand_out(s); /* the workers the ended jobs left waiting */
}

static void queue_tick(srv_server *s, uint64_t now)
{
    (void)s;
    (void)now;
}

static int queue_local_gone(srv_server *s)
{
    if (!s->local_gone_logged) {
        srv_log("all %u local workers exited; waiting for remote ones", s->local.nchildren);
        s->local_gone_logged = 1;
    }
    return 0;
}

const srv_mode srv_mode_queue = {
    .name = "queue",
    .serves_clients = 1,
    .logs_starts = 1,
    .setup = setup_queue,
    .over = queue_over,
    .after_leases = queue_after_leases,
    .tick = queue_tick,
    .local_gone = queue_local_gone,
    .finish = finish_queue,
};

const srv_mode *srv_mode_for(const srv_config *cfg)
{
    return cfg->scene_path ? &srv_mode_one_job : &srv_mode_queue;
}

/* Everything before the loop: the token, the decode buffer, the mode's jobs,
 * the listening socket and the local workers, in that order (a broken scene
 * or state folder fails before anything listens or starts). */
static pt_status setup(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    s->next_job_id = 1;
    if (cfg->token_path) {
        int loose = 0;
        if ((st = proto_token_load(cfg->token_path, s->token, sizeof s->token, &s->token_len,
                                   &loose, err)) != PT_OK)
            return st;
        if (loose)
            srv_log("warning: %s is readable by other users", cfg->token_path);
    }
    s->scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *s->scratch);
    if (!s->scratch)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    if ((st = s->mode->setup(s, err)) != PT_OK)
        return st;
    if ((st = srv_loop_open(s, err)) != PT_OK)
        return st;
    s->t_start = s->t_last_print = srv_now_ms();
    if (cfg->local_workers && (st = srv_local_start(&s->local, cfg, s->port, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* The timers, once per round: leases, connections, jobs, watchers, then
 * what the mode shows. */
static void timers(srv_server *s)
{
    uint64_t now = srv_now_ms();
    srv_queue_expire(s, now);
    srv_loop_timers(s, now);
    srv_queue_tick(s, now);
    srv_requests_tick(s, now);
    s->mode->tick(s, now);
}

int srv_serve(const srv_config *cfg)
{
    srv_server s;
    memset(&s, 0, sizeof s);
    s.cfg = cfg;
    s.mode = srv_mode_for(cfg);
    s.lfd = s.ep = s.sigpipe[0] = s.sigpipe[1] = s.verifypipe[0] = s.verifypipe[1] = -1;
    pt_error err = {0};
    int rc = 1;
    if (setup(&s, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        goto done;
    }
    while (!srv_loop_stopped() && !s.mode->over(&s)) {
        srv_loop_poll(&s, 100);
        srv_queue_hand_out(&s);
        s.mode->after_leases(&s);
        timers(&s);
        /* Flush, then free closed connections outside their callbacks. */
        srv_loop_sweep(&s);
        if (s.local.nchildren) {
            srv_local_reap(&s.local, 0);
            if (s.local.alive == 0 && s.mode->local_gone(&s))
                break;
        }
    }
    rc = s.mode->finish(&s);
done:
    srv_upload_close(&s);
    srv_local_stop(&s.local);
    srv_loop_close(&s);
    srv_queue_free(&s);
    pt_free(s.scratch);
    return rc;
}
