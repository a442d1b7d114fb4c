/*
 * workers.h - what a connected, authenticated worker asks and sends.
 *
 * WORK_REQUEST adds free slots (capped at PROTO_MAX_SLOTS) that the queue
 * fills with tasks (server/sched/queue.h); SCENE_GET is answered with a chunk of
 * the bundle of the active job with that hash; HEARTBEAT moves the heartbeat
 * deadline of the worker's leases (never their hard deadline, server/sched/job.h);
 * RESULT is decoded (into s->scratch, or with merge threads and no state
 * folder into a buffer the job takes for its add, server/sched/adder.h), validated
 * against the job's lease (srv_job_validate), logged durably (when there is a
 * state folder) and only then merged, so the results log holds every result
 * the film holds. A
 * result that is malformed, implausible or inconsistent with its task is the
 * worker's fault (ERROR, closed); a late or duplicate one is dropped. The
 * answer to a verification copy is compared, never logged or merged.
 *
 * Blocking: a worker that misses deadlines in SRV_MAX_MISSES expiry rounds
 * with no result in between (a result that holds no sample, every one
 * "rejected", while its job has merged real samples counts as a miss, not a
 * result), or whose result a verification shows false, is
 * blocked: its leases and held results are requeued, it is sent ERROR and
 * closed, and a worker of that name, or from that address (loopback aside:
 * the coordinator's own local workers share it), is refused at HELLO for the
 * coordinator's life. Each block is logged with its reason; a job that had
 * results of a liar merged says how many in its message.
 *
 * Threads: called only from the event-loop thread.
 */
#ifndef PT_SERVER_WORKERS_H
#define PT_SERVER_WORKERS_H

#include "protocol/frame.h"
#include "server/core.h"
#include "server/net/loop.h"

#define SRV_MAX_MISSES 3

/* What the worker session keeps of one worker, beside its transport
 * (srv_conn.session, made at WELCOME, freed when the connection is). */
typedef struct srv_worker_conn {
    uint32_t want;      /* free slots it asked tasks for */
    uint32_t misses;    /* deadline misses since its last result */
    uint32_t empties;   /* of them, results that held no sample */
    uint64_t missed_at; /* when the last one was counted */
    /* results merged, their samples, when the last one was (0: none) */
    uint64_t tasks_done, samples_done, t_result;
    int dn_verified; /* a denoised region of it was taken, to be verified (dnshare.h) */
} srv_worker_conn;

/* c's worker state; NULL unless c is a ready worker. */
srv_worker_conn *srv_worker_of(const srv_conn *c);

/* The loop's session of workers (srv_loop_set_session): the handlers below. */
extern const srv_session srv_workers_session;

/* Serves one whole frame from a ready worker. */
void srv_workers_dispatch(srv_server *s, srv_conn *c, const proto_frame *f);

/* Serves a RESULT frame f already decoded into r (by an I/O thread,
 * server/net/io.h; its pixels its own): as srv_workers_dispatch would, without
 * decoding it again; checked: its pixels passed srv_job_pixels_plausible.
 * f's payload is needed only in queue mode (the results log writes the
 * frame as received). own: NULL, or the pt_malloc'd buffer holding that whole
 * frame, which the results log may take instead of a copy (*own is then
 * NULL). Takes r's pixels: r is left empty. */
void srv_workers_result(srv_server *s, srv_conn *c, const proto_frame *f, proto_result *r,
                        int checked, uint8_t **own);

/* Leases tasks (srv_queue_lease) to every ready worker that asked for
 * some, and feeds the clients' fetches (server/api/requests.h) while going over
 * the connections (srv_loop_each_for_hand_out). */
void srv_workers_hand_out(srv_server *s);

/* The scheduler's events (srv_sched_events) that workers hear of: a job
 * ended early (JOB_END to every ready worker), a result merged (its
 * worker's counts), and the walk over the ready workers. */
void srv_workers_job_ended(srv_server *s, const srv_entry *j);
void srv_workers_merged(srv_server *s, uint64_t owner, uint64_t merged, uint64_t now);
void srv_workers_each(srv_server *s, void (*fn)(void *ctx, uint64_t owner), void *ctx);

/* A lease of worker connection owner passed a deadline at now (ms): counts a
 * miss, one per expiry round (srv_sched_events.owner_missed). Blocks nobody
 * (the caller may be iterating a job); srv_workers_enforce does. */
void srv_workers_missed(srv_server *s, uint64_t owner, uint64_t now);

/* Blocks worker connection owner, found lying (srv_sched_events.owner_lied),
 * when it is still connected. */
void srv_workers_lied(srv_server *s, uint64_t owner, const char *why);

/* Blocks each worker with SRV_MAX_MISSES misses. O(1) unless a worker
 * reached them since the last call (then it walks the connections). */
void srv_workers_enforce(srv_server *s);

/* Blocks worker c (see the file comment) for why, logged and sent to it. */
void srv_workers_block(srv_server *s, srv_conn *c, const char *why);

/* At HELLO: 1 when c (its name set, its role a worker) is blocked; it was
 * then sent ERROR and is closing. */
int srv_workers_refused(srv_server *s, srv_conn *c);

#endif
