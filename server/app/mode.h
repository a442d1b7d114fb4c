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
#ifndef PT_SERVER_MODE_H
#define PT_SERVER_MODE_H

#include "server/core.h"

extern const srv_mode srv_mode_one_job;
extern const srv_mode srv_mode_queue;

/* The mode cfg asks for. */
const srv_mode *srv_mode_for(const srv_config *cfg);

#endif
