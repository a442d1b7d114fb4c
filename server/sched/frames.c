#include "server/sched/frames.h"

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/frames.h"
#include "server/sched/queue.h"

struct srv_frames {
    uint32_t count; /* frames in the range */
    uint32_t next;  /* the next index to start: every one below is started or done */
    srv_entry *win[SRV_FRAMES_AHEAD]; /* the frames rendering, in frame order */
    uint32_t nwin;
    int any_done;
    uint32_t last_done; /* the number of the frame done last (for viewers) */
};

uint64_t srv_frame_job_id(uint64_t job, uint32_t number)
{
    return SRV_FRAME_ID_BASE + job * 1000000ull + number;
}

srv_entry *srv_frames_at(const srv_entry *p, uint32_t i)
{
    return p->frames && i < p->frames->nwin ? p->frames->win[i] : NULL;
}

void srv_frames_pose(const srv_entry *f, proto_task *t)
{
    const srv_entry *p = f->parent;
    t->animate = 1;
    t->time = pt_frames_time(f->frame, p->rec.fps);
    snprintf(t->animation, sizeof t->animation, "%s", p->rec.animation);
}

static int is_done(const srv_job_record *r, uint32_t idx)
{
    if (idx < r->frames_done)
        return 1;
    for (uint32_t k = 0; k < r->ndone_ahead; k++)
        if (r->done_ahead[k] == idx)
            return 1;
    return 0;
}

void srv_frames_note_done(srv_entry *f)
{
    srv_entry *p = f->parent;
    srv_job_record *r = &p->rec;
    int64_t idx = pt_frames_index(&r->frames, f->frame);
    if (idx < 0 || is_done(r, (uint32_t)idx))
        return;
    if ((uint32_t)idx == r->frames_done) {
        r->frames_done++;
        /* Frames that finished ahead of it join the done prefix. */
        for (int moved = 1; moved;) {
            moved = 0;
            for (uint32_t k = 0; k < r->ndone_ahead; k++)
                if (r->done_ahead[k] == r->frames_done) {
                    r->done_ahead[k] = r->done_ahead[--r->ndone_ahead];
                    r->frames_done++;
                    moved = 1;
                    break;
                }
        }
    } else if (r->ndone_ahead < SRV_FRAMES_AHEAD) {
        /* Always room: no frame SRV_FRAMES_AHEAD or more past the first
         * one not done is started. */
        r->done_ahead[r->ndone_ahead++] = (uint32_t)idx;
    }
    if (f->job) {
        r->samples_done += srv_job_samples_merged(f->job);
        r->capped += srv_job_paths_capped(f->job);
        r->clamped += srv_job_clamped(f->job);
        r->rejected += f->rejected;
    }
    /* Journaled with the frame: a restart's range counts on from here. */
    r->seconds = srv_entry_seconds(p, pt_now_ms());
    if (p->frames) {
        p->frames->any_done = 1;
        p->frames->last_done = f->frame;
    }
}

/* A frame of p: a still of its own in the queue's list (see frames.h). */
static srv_entry *new_frame(srv_server *s, srv_entry *p, uint32_t number, pt_error *err)
{
    srv_entry *f = pt_calloc(1, sizeof *f);
    if (!f) {
        pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        return NULL;
    }
    f->rec = p->rec;
    f->rec.id = srv_frame_job_id(p->rec.id, number);
    f->rec.state = PROTO_JOB_RUNNING; /* the range's state is the one journaled */
    memset(&f->rec.frames, 0, sizeof f->rec.frames);
    f->rec.frames_done = f->rec.ndone_ahead = 0;
    f->rec.samples_done = f->rec.capped = f->rec.clamped = f->rec.rejected = 0;
    f->rec.message[0] = '\0';
    f->parent = p;
    f->frame = number;
    if (srv_frames_path(p, number, f->out_path, sizeof f->out_path, err) != PT_OK) {
        pt_free(f);
        return NULL;
    }
    srv_queue_insert(s, f);
    return f;
}

uint32_t srv_frames_in_flight(const srv_caps *caps, uint32_t width, uint32_t height,
                              uint32_t film_flags)
{
    uint64_t px = (uint64_t)width * height, n = px ? caps->max_pixels / px : SRV_FRAMES_AHEAD;
    uint64_t film = srv_film_bytes(width, height, film_flags);
    if (caps->max_film && film && caps->max_film / film < n)
        n = caps->max_film / film;
    return n < 1 ? 1 : n > SRV_FRAMES_AHEAD ? SRV_FRAMES_AHEAD : (uint32_t)n;
}

/* Starts p's next frames, up to srv_frames_in_flight rendering and none
 * that far past the first not done. Returns 0 when one could not be made (p
 * is then ended FAILED, or will be by the round: a frame that failed). */
static int fill_window(srv_server *s, srv_entry *p)
{
    struct srv_frames *fr = p->frames;
    const srv_job_params *jp = &p->rec.params;
    uint32_t ahead = srv_frames_in_flight(&s->cfg->caps, jp->width, jp->height, jp->film_flags);
    while (fr->nwin < ahead && fr->next < fr->count && fr->next < p->rec.frames_done + ahead) {
        uint32_t idx = fr->next++;
        if (is_done(&p->rec, idx))
            continue;
        pt_error err = {0};
        srv_entry *f = new_frame(s, p, pt_frames_number(&p->rec.frames, idx), &err);
        if (!f) {
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "%s", err.msg);
            srv_queue_end_job(s, p, PROTO_JOB_FAILED, msg);
            return 0;
        }
        fr->win[fr->nwin++] = f;
        if (!srv_entry_ready(s, f))
            return 0;
    }
    return 1;
}

int srv_frames_ready(srv_server *s, srv_entry *p)
{
    if (!p->frames) {
        if (p->rec.id >= SRV_FRAME_MAX_JOB) {
            srv_queue_end_job(s, p, PROTO_JOB_FAILED, "job id too large for a frame range");
            return 0;
        }
        p->frames = pt_calloc(1, sizeof *p->frames);
        if (!p->frames) {
            srv_queue_end_job(s, p, PROTO_JOB_FAILED, "out of memory");
            return 0;
        }
        p->frames->count = pt_frames_count(&p->rec.frames);
        p->frames->next = p->rec.frames_done;
        p->seconds_before = p->rec.seconds; /* as of its last frame done */
        if (!p->t_started)
            p->rate_t = pt_now_ms();
    }
    return fill_window(s, p);
}

static void forget_frame(srv_server *s, const srv_job_record *r, uint32_t idx)
{
    s->mode->durability->forget(s, srv_frame_job_id(r->id, pt_frames_number(&r->frames, idx)));
}

void srv_frames_forget_done(srv_server *s, const srv_entry *p)
{
    const srv_job_record *r = &p->rec;
    for (uint32_t i = 0; i < r->frames_done; i++)
        forget_frame(s, r, i);
    for (uint32_t k = 0; k < r->ndone_ahead; k++)
        forget_frame(s, r, r->done_ahead[k]);
}

void srv_frames_end(srv_server *s, srv_entry *p, uint8_t state, const char *message)
{
    srv_entry *f;
    for (uint32_t i = 0; (f = srv_frames_at(p, i)); i++)
        if (srv_entry_active(f))
            srv_queue_end_job(s, f, state, message);
}

int srv_frames_round(srv_server *s)
{
    int ended = 0;
    for (srv_entry *p = s->jobs; p; p = p->next) {
        struct srv_frames *fr = p->frames;
        if (!fr)
            continue;
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        int failed = 0;
        uint32_t k = 0;
        for (uint32_t i = 0; i < fr->nwin; i++) {
            srv_entry *f = fr->win[i];
            if (srv_entry_active(f)) {
                fr->win[k++] = f;
                continue;
            }
            if (f->rec.state == PROTO_JOB_FAILED && !failed) {
                snprintf(msg, sizeof msg, "frame %u: %.900s", f->frame, f->rec.message);
                failed = 1;
            }
            srv_queue_unlink(s, f);
            srv_entry_free(f);
        }
        fr->nwin = k;
        if (!srv_entry_active(p))
            continue;
        if (failed) {
            srv_queue_end_job(s, p, PROTO_JOB_FAILED, msg);
            ended = 1;
        } else if (p->rec.frames_done >= fr->count) {
            srv_queue_end_job(s, p, PROTO_JOB_DONE, NULL);
            ended = 1;
        } else if (p->t_started || p->rec.state == PROTO_JOB_RUNNING) {
            fill_window(s, p);
        }
    }
    return ended;
}

/* each_worker's walk that counts the workers holding a task of a frame of
 * range p. */
typedef struct range_owners {
    const srv_entry *p;
    uint32_t n;
} range_owners;

static void count_owner(void *ctx, uint64_t owner)
{
    range_owners *ro = ctx;
    const srv_entry *f;
    for (uint32_t i = 0; (f = srv_frames_at(ro->p, i)); i++)
        if (f->job && srv_job_owner_active(f->job, owner)) {
            ro->n++;
            return;
        }
}

void srv_frames_info(const srv_server *s, const srv_entry *p, proto_job_info *m)
{
    const srv_job_record *r = &p->rec;
    uint64_t per = (uint64_t)r->params.width * r->params.height * r->params.spp;
    uint32_t count = pt_frames_count(&r->frames);
    m->frame_first = r->frames.first;
    m->frame_last = r->frames.last;
    m->frame_step = r->frames.step;
    m->frames_done = r->frames_done + r->ndone_ahead;
    m->samples_total = per * count;
    m->samples_done = r->samples_done;
    m->capped = r->capped;
    m->clamped = r->clamped;
    m->rejected = r->rejected;
    m->error = -1.0;
    if (!srv_entry_active(p)) {
        m->passes_done = r->state == PROTO_JOB_DONE ? m->passes : 0;
        return;
    }
    m->passes_done = 0;
    m->rate = 0;
    const srv_entry *f;
    for (uint32_t i = 0; (f = srv_frames_at(p, i)); i++) {
        if (!f->job || !srv_entry_active(f))
            continue;
        uint64_t merged = srv_job_samples_merged(f->job);
        m->samples_done += merged;
        m->capped += srv_job_paths_capped(f->job);
        m->clamped += srv_job_clamped(f->job);
        m->rejected += f->rejected;
        m->rate += f->rate;
        if (i == 0) { /* the earliest frame's passes */
            m->passes_done = srv_job_passes_done(f->job);
            m->tiles_stopped = srv_job_tiles_stopped(f->job);
        }
        if (!f->t_started && !merged)
            continue; /* not started: queued */
        m->frames_rendering++;
        if (m->nshown < PROTO_MAX_FRAMES_SHOWN) {
            m->shown[m->nshown].frame = f->frame;
            m->shown[m->nshown].samples_done = merged;
            m->shown[m->nshown].samples_total = per;
            m->nshown++;
        }
    }
    /* Workers holding a task of any of its frames, each counted once. */
    range_owners ro = {p, 0};
    if (s->events && s->events->each_worker)
        s->events->each_worker((srv_server *)s, count_owner, &ro);
    m->workers = ro.n;
}

const srv_range_ops srv_frames_ops = {
    srv_frames_ready, srv_frames_at,    srv_frames_pose, srv_frames_note_done,
    srv_frames_end,   srv_frames_round, srv_frames_info,
};

pt_status srv_frames_path(const srv_entry *p, uint32_t number, char *out, size_t cap, pt_error *err)
{
    if (pt_frames_index(&p->rec.frames, number) < 0)
        return pt_error_set(err, PT_ERR_ARG, "job %llu renders no frame %u (frames %u-%u:%u)",
                            (unsigned long long)p->rec.id, number, p->rec.frames.first,
                            p->rec.frames.last, p->rec.frames.step);
    return pt_frames_name(p->out_path, number, out, cap, err);
}

void srv_frames_latest(const srv_entry *p, char *out, size_t cap)
{
    const srv_entry *f = srv_frames_at(p, 0);
    out[0] = '\0';
    if (f && srv_entry_active(f))
        snprintf(out, cap, "%s", f->out_path);
    else if (p->frames && p->frames->any_done)
        srv_frames_path(p, p->frames->last_done, out, cap, NULL);
    else if (p->rec.frames_done > 0)
        srv_frames_path(p, pt_frames_number(&p->rec.frames, p->rec.frames_done - 1), out, cap,
                        NULL);
}
