/*
 * requests.h - what a connected, authenticated client (ptctl) asks.
 *
 * SUBMIT is checked against the caps (resolution, spp, scene size, the
 * unfinished jobs of one client identity, the queue's size) and the job name
 * must be a plain name; UPLOAD chunks must continue the announced scene
 * exactly, and the buffer grows with what arrives, not with what was
 * announced. A complete upload goes to verification (server/api/upload.h); its
 * outcome comes back to srv_requests_verified, which queues the job (durable
 * before it is acknowledged with SUBMITTED) or refuses it. A client sends
 * nothing else until that answer. LIST, STATUS, WATCH (JOB_INFO now, then
 * every second and at the job's end), CANCEL (by the job's owner or an
 * admin only; a job's owner is its submitter's identity, server/net/loop.h's
 * srv_conn name, and admin its admin flag) and FETCH (the image file in
 * IMAGE chunks while the client's output has room) are served here. Images
 * are written only as ID-NAME.exr, NAME reduced to [A-Za-z0-9._-].
 *
 * Threads: called only from the event-loop thread.
 */
#ifndef PT_SERVER_REQUESTS_H
#define PT_SERVER_REQUESTS_H

#include <stdint.h>

#include "protocol/frame.h"
#include "server/core.h"
#include "server/net/loop.h"

/* The loop's session of clients (srv_loop_set_session): the handlers below. */
extern const srv_session srv_requests_session;

/* Serves one whole frame from a ready client. */
void srv_requests_dispatch(srv_server *s, srv_conn *c, const proto_frame *f);

/* Queues the job of a verified upload of c's, or sends c the refusal. */
void srv_requests_verified(srv_server *s, srv_conn *c, srv_upload *k);

/* Sends j's JOB_INFO to every client watching it (its end included). */
void srv_requests_notify_watchers(srv_server *s, const srv_entry *j);

/* Appends IMAGE frames of c's fetch in progress while c's output has room. */
void srv_requests_pump_fetch(srv_server *s, srv_conn *c);

/* JOB_INFO to each watcher whose last one is a second old (looked at every
 * 100 ms); now in ms. */
void srv_requests_tick(srv_server *s, uint64_t now);

/* Uploads in progress or being checked at once, per client identity and
 * in all: a SUBMIT past either is refused (PROTO_E_LIMIT). Each holds
 * disk, not memory (the upload's file), and a check (server/api/upload.h). */
#define SRV_MAX_UPLOADS_PER_CLIENT 4u
#define SRV_MAX_UPLOADS 16u

/* c is being freed: logs an upload it left unfinished, removes its upload,
 * ends its fetch and frees its client state (server/api/client.h). */
void srv_requests_conn_gone(srv_server *s, srv_conn *c);

#endif
