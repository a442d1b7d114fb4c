/*
 * workers.h - what a connected, authenticated worker asks and sends.
 *
 * WORK_REQUEST adds free slots (capped at PROTO_MAX_SLOTS) that the queue
 * fills with tasks (server/queue.h); SCENE_GET is answered with a chunk of
 * the bundle of the active job with that hash; HEARTBEAT extends the
 * worker's leases; RESULT is decoded into s->scratch, validated against the
 * job's lease (srv_job_validate), logged durably (when there is a state
 * folder) and only then merged, so the results log holds every result the
 * film holds. A result that is malformed or inconsistent with its task is
 * the worker's fault (ERROR, closed); a late or duplicate one is dropped.
 *
 * Threads: called only from the event-loop thread.
 */
#ifndef PT_SERVER_WORKERS_H
#define PT_SERVER_WORKERS_H

#include "protocol/frame.h"
#include "server/core.h"

/* Serves one whole frame from a ready worker. */
void srv_workers_dispatch(srv_server *s, srv_conn *c, const proto_frame *f);

#endif
