/*
 * serve.h - the coordinator: one event loop that serves workers for a job.
 *
 * Loads and packs the scene, listens, authenticates workers (HELLO,
 * CHALLENGE, AUTH, WELCOME), leases tasks in pass order, merges results
 * (server/sched/job.h), serves the scene bundle in chunks, expires leases, and
 * writes progressive EXRs off the loop (server/sched/writer.h). With local_workers
 * it also spawns that many ptworker processes on loopback and reaps them.
 * In one-job mode it renders one scene and exits; in queue mode it keeps a
 * render queue that clients (ptctl) fill, durable in a state folder
 * (server/store/state.h), and runs until it is stopped.
 *
 * app/serve.c only sets up, wires and dispatches. The parts, a folder per
 * layer, calls going down and anything upward a callback or an event that
 * serve.c installs at setup (docs/ARCHITECTURE.md):
 * - net/: loop.h (the descriptors it waits on, connections, handshake,
 *   limits on peers, role sessions), io.h (the I/O threads that read
 *   workers), peerlimits.h, clients.h and authlimit.h (identities and the
 *   backoff of wrong tokens);
 * - sched/: queue.h (jobs, leases, merges and the scheduler's events),
 *   frames.h (frame ranges), job.h (one job's scheduling and merging),
 *   adder.h and writer.h (the merge and image threads);
 * - store/: state.h (the state folder);
 * - api/: workers.h and requests.h (what workers and clients send),
 *   upload.h (scene verification off the loop), http.h (the dashboard);
 * - app/: mode.h (the two modes as data), local.h (local workers);
 * - here, under all: config.h, core.h (the server's state), log.h.
 * Threads: srv_serve runs the loop on the calling thread; call it once at a
 * time per process (it installs SIGINT and SIGTERM handlers).
 */
#ifndef PT_SERVER_SERVE_H
#define PT_SERVER_SERVE_H

#include "server/config.h"
#include "server/sched/job.h" /* the defaults and caps of srv_config.job's fields */

/* Runs the coordinator. One-job mode: exit status 0 when the image is
 * complete, 130 when interrupted, 1 on error. Queue mode: serves until SIGINT
 * or SIGTERM (then checkpoints the running jobs and exits 0), 1 on error. */
int srv_serve(const srv_config *cfg);

#endif
