#include "server/workers.h"

#include <stdio.h>
#include <string.h>

#include "common/base/text.h"
#include "protocol/msg.h"
#include "server/job.h"
#include "server/loop.h"
#include "server/queue.h"

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
    const pt_bundle *b = j->bundle;
    if (g.offset > b->size) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "scene offset %llu is past its end (%zu)",
                            (unsigned long long)g.offset, b->size);
        return;
    }
    proto_scene_chunk ch;
    memcpy(ch.hash, j->rec.hash, 32);
    ch.offset = g.offset;
    ch.total = b->size;
    size_t left = b->size - (size_t)g.offset;
    ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
    ch.data = b->data + g.offset;
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, PROTO_MSG_SCENE_CHUNK, &mark, NULL);
    if (st == PT_OK)
        st = proto_frame_finish(&c->out, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL),
                                NULL);
    srv_conn_queued(s, c, st);
}

static void on_result(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_result r;
    pt_error err = {0};
    if (proto_msg_decode_result(f->payload, f->len, s->scratch, PROTO_MAX_TILE_PIXELS, &r, &err) !=
        PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad RESULT: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find(s, r.job_id);
    if (!j || !srv_entry_active(j) || !j->job || j->paused) {
        proto_result_fini(&r); /* a job that ended (cancelled) or paused: nothing to do */
        return;
    }
    int lease_index;
    srv_outcome o = srv_job_validate(j->job, c->id, &r, &lease_index, &err);
    /* Durable before merged: the log holds every result the film holds. */
    if (o == SRV_MERGED && srv_queue_log_result(s, j, f->payload, f->len, &err) != PT_OK) {
        proto_result_fini(&r); /* not merged; the failure is logged once, by the queue */
        return;
    }
    if (o == SRV_MERGED)
        o = srv_job_result_validated(j->job, lease_index, &r, &err);
    switch (o) {
    case SRV_MERGED:
        j->rejected += r.rejected;
        j->rays += r.rays;
        break;
    case SRV_DUPLICATE:
        break;
    case SRV_NOT_LEASED: {
        char text[PT_TEXT_ESCAPED_SIZE(sizeof err.msg)];
        srv_log("worker %s: %s; dropped", c->shown, pt_text_shown(err.msg, text, sizeof text));
        break;
    }
    case SRV_INVALID:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
        break;
    }
    proto_result_fini(&r);
}

static void on_heartbeat(srv_server *s, srv_conn *c, const proto_frame *f)
{
    static proto_heartbeat hb; /* large; the loop is single-threaded */
    pt_error err = {0};
    if (proto_msg_decode_heartbeat(f->payload, f->len, &hb, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HEARTBEAT: %s", err.msg);
        return;
    }
    uint64_t now = pt_now_ms();
    /* Task ids are per job; extending only leases this owner holds is safe
     * even when two of its jobs share an id. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j))
            for (uint32_t i = 0; i < hb.count; i++)
                srv_job_heartbeat(j->job, c->id, hb.task_ids[i], now, s->cfg->lease_ms);
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
        c->want += w.slots;
        if (c->want > PROTO_MAX_SLOTS)
            c->want = PROTO_MAX_SLOTS;
        break;
    }
    case PROTO_MSG_SCENE_GET:
        on_scene_get(s, c, f);
        break;
    case PROTO_MSG_RESULT:
        on_result(s, c, f);
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
