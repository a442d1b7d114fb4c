#include "server/api/workers.h"

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/text.h"
#include "protocol/msg.h"
#include "server/api/requests.h"
#include "server/net/loop.h"
#include "server/sched/dnshare.h"
#include "server/sched/job.h"
#include "server/sched/queue.h"

/* One chunk message of type (SCENE_CHUNK's layout): len bytes (at most
 * PROTO_MAX_SCENE_CHUNK) at offset of data of size bytes named by hash. */
static void send_piece(srv_server *s, srv_conn *c, uint16_t type, const uint8_t hash[32],
                       const uint8_t *piece, size_t len, uint64_t offset, uint64_t size)
{
    proto_scene_chunk ch;
    memcpy(ch.hash, hash, 32);
    ch.offset = offset;
    ch.total = size;
    ch.len = (uint32_t)len;
    ch.data = piece;
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, type, &mark, NULL);
    if (st == PT_OK)
        st = proto_frame_finish(&c->out, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL),
                                NULL);
    srv_conn_queued(s, c, st);
}

/* Sends the piece of data (size bytes, named by hash) from offset on in one
 * chunk message of type, or an error when offset is past its end; what
 * names the data in that error. */
static void send_chunk(srv_server *s, srv_conn *c, uint16_t type, const uint8_t hash[32],
                       const uint8_t *data, size_t size, uint64_t offset, const char *what)
{
    if (offset > size) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s offset %llu is past its end (%zu)", what,
                            (unsigned long long)offset, size);
        return;
    }
    size_t left = size - (size_t)offset;
    send_piece(s, c, type, hash, data + offset,
               left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK, offset, size);
}

static void on_scene_get(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SCENE_GET: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find_scene(s, g.hash);
    if (!j) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no scene with that hash");
        return;
    }
    send_chunk(s, c, PROTO_MSG_SCENE_CHUNK, j->rec.hash, j->bundle->data, j->bundle->size, g.offset,
               "scene");
}

/* GUIDE_GET: a piece of a guided job's distribution, by hash (GUIDE in
 * protocol/msg.h), as SCENE_GET hands out a scene. */
static void on_guide_get(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad GUIDE_GET: %s", err.msg);
        return;
    }
    const uint8_t *data = NULL;
    size_t size = 0;
    if (!srv_queue_find_guide(s, g.hash, &data, &size)) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no guiding distribution with that hash");
        return;
    }
    send_chunk(s, c, PROTO_MSG_GUIDE_CHUNK, g.hash, data, size, g.offset, "guide");
}

/* ---- denoising shared with the workers (server/sched/dnshare.h) ---- */

/* The next open share after *it (NULL: from the first job), or NULL: the
 * shares of entries whose finished image is with their writer. */
static srv_dnshare *share_next(srv_server *s, srv_entry **it)
{
    if (!s->cfg->denoise_share)
        return NULL;
    for (srv_entry *j = *it ? (*it)->next : s->jobs; j; j = j->next)
        if (j->final_writing && j->writer && srv_writer_share(j->writer)) {
            *it = j;
            return srv_writer_share(j->writer);
        }
    return NULL;
}

/* DENOISE_GET: a piece of a region's crop, by hash. A hash no share holds
 * now (the writer finished the frame first) gets no answer: JOB_END follows
 * once the image is written (srv_queue_end_job). */
static void on_denoise_get(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad DENOISE_GET: %s", err.msg);
        return;
    }
    uint8_t *buf = pt_malloc(PROTO_MAX_SCENE_CHUNK);
    if (!buf) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory for a DENOISE_CHUNK");
        return;
    }
    srv_entry *it = NULL;
    for (srv_dnshare *d; (d = share_next(s, &it));) {
        size_t len;
        uint64_t total, job;
        if (!srv_dnshare_chunk(d, g.hash, g.offset, buf, PROTO_MAX_SCENE_CHUNK, &len, &total, &job))
            continue;
        if (g.offset > total)
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "region offset %llu is past its end (%llu)",
                                (unsigned long long)g.offset, (unsigned long long)total);
        else
            send_piece(s, c, PROTO_MSG_DENOISE_CHUNK, g.hash, buf, len, g.offset, total);
        break;
    }
    pt_free(buf);
}

static void on_denoise_result(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_denoise_result r;
    pt_error err = {0};
    if (proto_msg_decode_denoise_result(f->payload, f->len, &r, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad DENOISE_RESULT: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find_any(s, r.job_id);
    srv_dnshare *d = j && j->final_writing && j->writer ? srv_writer_share(j->writer) : NULL;
    if (!d)
        return; /* late: the image is written */
    srv_worker_conn *w = c->session;
    int got = srv_dnshare_result(d, c->id, !w->dn_verified, &r, &err);
    if (got == SRV_DNSHARE_TAKEN)
        w->dn_verified = 1; /* its first is verified; the rest as --verify-fraction says */
    if (got == SRV_DNSHARE_INVALID) {
        s->counters.results_rejected++;
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
    }
}

/* Leases regions to c's free slots, one held at a time. */
static void lease_regions(srv_server *s, srv_conn *c, srv_worker_conn *w)
{
    if (!(c->caps & PROTO_CAP_DENOISE) || w->want == 0 || !srv_conn_has_room(c))
        return;
    srv_entry *it = NULL;
    for (srv_dnshare *d; (d = share_next(s, &it));)
        if (srv_dnshare_held(d, c->id))
            return;
    it = NULL;
    for (srv_dnshare *d; (d = share_next(s, &it));) {
        proto_denoise_task t;
        if (!srv_dnshare_lease(d, c->id, s->cfg->lease_ms, &t))
            continue;
        size_t mark;
        pt_status st = proto_frame_begin(&c->out, PROTO_MSG_DENOISE_TASK, &mark, NULL);
        if (st == PT_OK)
            st = proto_frame_finish(&c->out, mark, proto_msg_encode_denoise_task(&c->out, &t, NULL),
                                    NULL);
        if (srv_conn_queued(s, c, st))
            w->want--;
        else
            srv_dnshare_release(d, c->id);
        return;
    }
}

/* Workers a share found lying are blocked at once, as a render's liar is
 * (those found as the frame ends: srv_queue_end_job). */
static void block_share_liars(srv_server *s)
{
    srv_entry *it = NULL;
    for (srv_dnshare *d; (d = share_next(s, &it));) {
        uint64_t owner;
        while (srv_dnshare_take_liar(d, &owner))
            srv_workers_lied(s, owner, "a region it denoised differs from the coordinator's");
    }
}

void srv_workers_lied(srv_server *s, uint64_t owner, const char *why)
{
    srv_conn *liar = srv_conn_find(s, owner);
    if (liar && !liar->closing)
        srv_workers_block(s, liar, why);
}

/* The address part of a peer's "host:port". */
static void peer_host(const srv_conn *c, char *out, size_t size)
{
    snprintf(out, size, "%s", c->peer);
    char *colon = strrchr(out, ':');
    if (colon)
        *colon = '\0';
}

static int loopback(const char *host)
{
    return strncmp(host, "127.", 4) == 0 || strcmp(host, "::1") == 0 ||
           strncmp(host, "::ffff:127.", 11) == 0;
}

int srv_workers_refused(srv_server *s, srv_conn *c)
{
    char host[64];
    peer_host(c, host, sizeof host);
    for (uint32_t i = 0; i < s->nblocked; i++) {
        const srv_blocked *b = &s->blocked[i];
        int by_name = strcmp(b->name, c->name) == 0;
        if (by_name || (b->addr[0] && strcmp(b->addr, host) == 0)) {
            srv_conn_send_error(s, c, PROTO_E_AUTH, "worker %s is blocked: %s",
                                by_name ? "name" : "address", b->why);
            return 1;
        }
    }
    return 0;
}

void srv_workers_block(srv_server *s, srv_conn *c, const char *why)
{
    char text[PT_TEXT_ESCAPED_SIZE(96)];
    if (s->nblocked < SRV_MAX_BLOCKED) {
        srv_blocked *b = &s->blocked[s->nblocked++];
        snprintf(b->name, sizeof b->name, "%s", c->name);
        char host[64];
        peer_host(c, host, sizeof host);
        snprintf(b->addr, sizeof b->addr, "%s", loopback(host) ? "" : host);
        snprintf(b->why, sizeof b->why, "%s", why);
    } else {
        srv_log("the list of blocked workers is full (%u); worker %s is closed but not "
                "remembered",
                SRV_MAX_BLOCKED, c->shown);
    }
    srv_log("worker %s from %s blocked: %s", c->shown, c->peer,
            pt_text_shown(why, text, sizeof text));
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        uint64_t merged = 0, samples = 0;
        srv_job_forget_owner(j->job, c->id, &merged, &samples);
        if (merged == 0)
            continue;
        /* Merged sums cannot be taken out of the film bit-exactly: say so. */
        snprintf(j->rec.message, sizeof j->rec.message,
                 "worker %.64s blocked (%.80s): %llu of its results (of %llu samples) were "
                 "merged unverified",
                 c->name, why, (unsigned long long)merged, (unsigned long long)samples);
        srv_log("job %llu: %llu results of blocked worker %s were merged unverified (%llu "
                "samples)",
                (unsigned long long)j->rec.id, (unsigned long long)merged, c->shown,
                (unsigned long long)samples);
    }
    srv_conn_send_error(s, c, PROTO_E_AUTH, "this worker is blocked: %s", why);
}

/* A miss sets s->enforce_due once a worker reaches SRV_MAX_MISSES: only then
 * does srv_workers_enforce walk the connections, not once per loop round. */
void srv_workers_missed(srv_server *s, uint64_t owner, uint64_t now)
{
    srv_conn *c = srv_conn_find(s, owner);
    srv_worker_conn *w = c ? srv_worker_of(c) : NULL;
    if (!w || c->closing || w->missed_at == now)
        return;
    w->missed_at = now;
    if (++w->misses >= SRV_MAX_MISSES)
        s->enforce_due = 1;
}

void srv_workers_enforce(srv_server *s)
{
    if (!s->enforce_due)
        return;
    s->enforce_due = 0;
    for (srv_conn *c = s->conns; c; c = c->next) {
        const srv_worker_conn *w = srv_worker_of(c);
        if (w && !c->closing && w->misses >= SRV_MAX_MISSES) {
            char why[160];
            if (w->empties)
                snprintf(why, sizeof why,
                         "returned results that held no sample (%u) or missed lease deadlines "
                         "%u times in a row",
                         w->empties, w->misses);
            else
                snprintf(why, sizeof why, "missed lease deadlines %u times in a row", w->misses);
            srv_workers_block(s, c, why);
        }
    }
}

static void on_verdict(srv_server *s, srv_entry *j, const srv_verdict *v)
{
    switch (v->kind) {
    case SRV_V_MATCH:
        break;
    case SRV_V_MISMATCH:
        srv_log("job %llu: task %llu: a verification copy differs; a third render decides",
                (unsigned long long)j->rec.id, (unsigned long long)v->task);
        break;
    case SRV_V_UNRESOLVED:
        srv_log("job %llu: task %llu: three renders differ; no worker can be blamed",
                (unsigned long long)j->rec.id, (unsigned long long)v->task);
        break;
    case SRV_V_LIAR: {
        srv_conn *liar = srv_conn_find(s, v->liar);
        char why[96];
        snprintf(why, sizeof why, "its result for task %llu of job %llu differs from two others",
                 (unsigned long long)v->task, (unsigned long long)j->rec.id);
        if (liar && !liar->closing)
            srv_workers_block(s, liar, why);
        else {
            for (srv_entry *e = s->jobs; e; e = e->next)
                if (e->job && srv_entry_active(e))
                    srv_job_forget_owner(e->job, v->liar, NULL, NULL);
            srv_log("job %llu: connection %llu (gone) lied: %s", (unsigned long long)j->rec.id,
                    (unsigned long long)v->liar, why);
        }
        break;
    }
    }
}

/* A merged result clears its worker's misses, unless it held no sample at
 * all (every one "rejected") while the job has merged samples that were
 * not: that is a worker that renders nothing, and it counts as a missed
 * deadline, so SRV_MAX_MISSES of them in a row block it. A scene whose
 * samples are all NaN blocks no one: then no result of the job holds one. */
static void judge_rendered(srv_server *s, srv_conn *c, const srv_entry *j, const proto_result *r)
{
    srv_worker_conn *w = c->session; /* a ready worker's result */
    uint64_t asked = (uint64_t)r->npixels * (r->s1 - r->s0);
    if (asked == 0 || r->rejected < asked || srv_job_samples_merged(j->job) == 0) {
        w->misses = w->empties = 0;
        return;
    }
    srv_log("worker %s: a result of job %llu holds no sample (all %llu rejected)", c->shown,
            (unsigned long long)j->rec.id, (unsigned long long)asked);
    /* Each one counts, however many arrive in one millisecond. */
    w->empties++;
    if (++w->misses >= SRV_MAX_MISSES)
        s->enforce_due = 1;
}

static void on_result(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_result r;
    pt_error err = {0};
    /* Into a buffer of its own when something keeps the pixels: the result
     * waiting for its record to be durable (queue mode), or the job for a
     * merge thread's add. */
    pt_pixel_acc *buf = s->adder || s->mode->durable ? NULL : s->scratch;
    if (proto_msg_decode_result(f->payload, f->len, buf, PROTO_MAX_TILE_PIXELS, &r, &err) !=
        PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad RESULT: %s", err.msg);
        return;
    }
    srv_workers_result(s, c, f, &r, 0, NULL);
}

void srv_workers_result(srv_server *s, srv_conn *c, const proto_frame *f, proto_result *rp,
                        int checked, uint8_t **own)
{
    proto_result r = *rp; /* the caller's is left empty: this one is fini'd here */
    rp->pixels = NULL;
    rp->owns_pixels = 0;
    rp->guide = NULL;
    rp->owns_guide = 0;
    pt_error err = {0};
    srv_entry *j = srv_queue_find_any(s, r.job_id); /* a frame's too */
    if (!j || !srv_entry_active(j) || !j->job || j->paused) {
        proto_result_fini(&r); /* a job that ended (cancelled) or paused: nothing to do */
        return;
    }
    int lease_index;
    srv_outcome o = checked ? srv_job_validate_checked(j->job, c->id, &r, &lease_index, &err)
                            : srv_job_validate(j->job, c->id, &r, &lease_index, &err);
    if (o == SRV_CHECK) {
        /* A verification copy: compared, never logged or merged. */
        srv_verdict v;
        srv_job_check(j->job, lease_index, &r, &v);
        judge_rendered(s, c, j, &r);
        proto_result_fini(&r);
        on_verdict(s, j, &v);
        if (srv_entry_active(j) && j->job && srv_job_complete(j->job))
            srv_queue_verify_summary(j);
        return;
    }
    /* Durable before merged: the log holds every result the film holds. In
     * queue mode the result is logged now (its frame as received, whose
     * checksum was checked) and merged by srv_queue_committed once the group
     * commit that holds its record has returned. */
    if (o == SRV_MERGED && s->mode->durable) {
        judge_rendered(s, c, j, &r);
        srv_queue_log_result(s, j, c->id, lease_index, &r, f->payload - PROTO_FRAME_HEADER,
                             (size_t)f->len + PROTO_FRAME_OVERHEAD, own, pt_now_ms(), &err);
        proto_result_fini(&r); /* a failure is logged once, by the queue */
        return;
    }
    if (o == SRV_MERGED)
        o = srv_queue_merge(s, j, c->id, lease_index, &r, pt_now_ms(), &err);
    switch (o) {
    case SRV_MERGED:
        judge_rendered(s, c, j, &r);
        break;
    case SRV_DUPLICATE: { /* late, but rendered: it is working */
        srv_worker_conn *w = c->session;
        w->misses = w->empties = 0;
        break;
    }
    case SRV_NOT_LEASED: {
        s->counters.results_rejected++;
        char text[PT_TEXT_ESCAPED_SIZE(sizeof err.msg)];
        srv_log("worker %s: %s; dropped", c->shown, pt_text_shown(err.msg, text, sizeof text));
        break;
    }
    case SRV_INVALID:
        s->counters.results_rejected++;
        srv_job_refused(j->job);
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
        break;
    case SRV_CHECK:
        break;
    }
    proto_result_fini(&r);
}

static void on_heartbeat(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_heartbeat *hb = s->hb; /* large: the server's buffer */
    pt_error err = {0};
    if (proto_msg_decode_heartbeat(f->payload, f->len, hb, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HEARTBEAT: %s", err.msg);
        return;
    }
    uint64_t now = pt_now_ms();
    /* Task ids are per job; touching only leases this owner holds is safe
     * even when two of its jobs share an id. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j))
            for (uint32_t i = 0; i < hb->count; i++)
                srv_job_heartbeat(j->job, c->id, hb->task_ids[i], now, s->cfg->lease_ms);
}

void srv_workers_dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    switch (f->type) {
    case PROTO_MSG_WORK_REQUEST: {
        proto_work_request w;
        pt_error err = {0};
        if (proto_msg_decode_work_request(f->payload, f->len, &w, &err) != PT_OK) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad WORK_REQUEST: %s", err.msg);
            return;
        }
        srv_worker_conn *wc = c->session;
        wc->want += w.slots;
        if (wc->want > PROTO_MAX_SLOTS)
            wc->want = PROTO_MAX_SLOTS;
        break;
    }
    case PROTO_MSG_SCENE_GET:
        on_scene_get(s, c, f);
        break;
    case PROTO_MSG_GUIDE_GET:
        on_guide_get(s, c, f);
        break;
    case PROTO_MSG_RESULT:
        on_result(s, c, f);
        break;
    case PROTO_MSG_DENOISE_GET:
        on_denoise_get(s, c, f);
        break;
    case PROTO_MSG_DENOISE_RESULT:
        on_denoise_result(s, c, f);
        break;
    case PROTO_MSG_HEARTBEAT:
        on_heartbeat(s, c, f);
        break;
    case PROTO_MSG_ERROR:
        srv_conn_peer_error(s, c, f, "worker");
        break;
    default:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a worker",
                            proto_msg_type_name(f->type));
    }
}

/* The pixel check the I/O threads make (srv_job_pixels_plausible). */
static int plausible(const proto_result *r)
{
    return srv_job_pixels_plausible(r, NULL);
}

/* A worker leaving: its leases go back to the queue; report: log how many. */
static void on_leave(srv_server *s, srv_conn *c, int report)
{
    if (c->role != PROTO_ROLE_WORKER)
        return;
    uint32_t n = srv_queue_release_owner(s, c->id);
    srv_entry *it = NULL;
    for (srv_dnshare *d; (d = share_next(s, &it));)
        srv_dnshare_release(d, c->id);
    if (n && report)
        srv_log("worker %s left; %u leased tasks requeued", c->shown, n);
}

/* hand_out_to's state over one hand-out. */
typedef struct hand_out {
    uint64_t now;
    int dry; /* the queue had nothing to lease: skip the other workers */
} hand_out;

/* Serves c's free slots and pending fetch; 1 when c still wants tasks that
 * the queue had none of. */
static int hand_out_to(srv_server *s, srv_conn *c, void *ctx)
{
    hand_out *h = ctx;
    if (c->state != SRV_C_READY || c->closing)
        return 0;
    srv_worker_conn *w = srv_worker_of(c);
    if (!w)
        srv_requests_pump_fetch(s, c); /* a client's (nothing unless it fetches) */
    while (!h->dry && w && w->want > 0 && srv_conn_has_room(c)) {
        proto_task t;
        if (!srv_queue_lease(s, c->id, h->now, &t)) {
            h->dry = 1;
            break;
        }
        size_t mark;
        pt_status st = proto_frame_begin(&c->out, PROTO_MSG_TASK, &mark, NULL);
        if (st == PT_OK)
            st = proto_frame_finish(&c->out, mark, proto_msg_encode_task(&c->out, &t, NULL), NULL);
        if (!srv_conn_queued(s, c, st))
            break;
        w->want--;
    }
    if (w && h->dry)
        lease_regions(s, c, w);
    srv_conn_update_events(s, c);
    return h->dry && w && w->want > 0;
}

void srv_workers_hand_out(srv_server *s)
{
    hand_out h = {pt_now_ms(), 0};
    block_share_liars(s);
    srv_loop_each_for_hand_out(s, hand_out_to, &h);
}

/* ---- what the scheduler tells (srv_sched_events) ---- */

void srv_workers_job_ended(srv_server *s, const srv_entry *j)
{
    proto_job_ref ref = {j->rec.id};
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->role != PROTO_ROLE_WORKER || c->state != SRV_C_READY || c->closing)
            continue;
        size_t mark;
        if (proto_frame_begin(&c->out, PROTO_MSG_JOB_END, &mark, NULL) == PT_OK)
            proto_frame_finish(&c->out, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL), NULL);
        srv_conn_update_events(s, c);
    }
}

void srv_workers_merged(srv_server *s, uint64_t owner, uint64_t merged, uint64_t now)
{
    srv_conn *c = srv_conn_find(s, owner);
    srv_worker_conn *w = c ? srv_worker_of(c) : NULL;
    if (w) {
        w->tasks_done++;
        w->samples_done += merged;
        w->t_result = now;
    }
}

void srv_workers_each(srv_server *s, void (*fn)(void *ctx, uint64_t owner), void *ctx)
{
    for (const srv_conn *c = s->conns; c; c = c->next)
        if (c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER && !c->closing)
            fn(ctx, c->id);
}

static void *open_worker(srv_server *s, srv_conn *c)
{
    (void)s;
    (void)c;
    return pt_calloc(1, sizeof(srv_worker_conn));
}

static void worker_gone(srv_server *s, srv_conn *c)
{
    (void)s;
    pt_free(c->session);
    c->session = NULL;
}

srv_worker_conn *srv_worker_of(const srv_conn *c)
{
    return c->state == SRV_C_READY && c->ops == &srv_workers_session ? c->session : NULL;
}

const srv_session srv_workers_session = {
    .open = open_worker,
    .on_frame = srv_workers_dispatch,
    .on_result = srv_workers_result,
    .check_result = plausible,
    .refused = srv_workers_refused,
    .on_leave = on_leave,
    .on_gone = worker_gone,
};
