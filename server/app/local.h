/*
 * local.h - ptworker processes this coordinator starts itself (--local N).
 *
 * srv_local_start spawns N ptworker children (the one beside this program,
 * or cfg->worker_bin) that connect to 127.0.0.1:PORT with the token file, if
 * any, and share a cache folder made for them under $TMPDIR; their stdout
 * goes to /dev/null. srv_local_reap collects the ones that exited (logging
 * how); srv_local_stop sends SIGTERM to the rest, waits for them (killing
 * any still there after a grace period) and removes the cache. The children
 * are ordinary workers to the loop: nothing here knows about connections or
 * jobs.
 *
 * Threads: called only from the event-loop thread.
 */
#ifndef PT_SERVER_LOCAL_H
#define PT_SERVER_LOCAL_H

#include <stdint.h>
#include <sys/types.h>

#include "common/base/error.h"
#include "server/config.h"

typedef struct srv_local {
    pid_t *children; /* 0 once reaped */
    uint32_t nchildren, alive;
    uint32_t stop_ms; /* srv_local_stop's wait before SIGKILL */
    char cache_dir[256];
} srv_local;

/* Starts cfg->local_workers ptworkers serving 127.0.0.1:port. PT_ERR_IO
 * naming the program or folder that failed; the children started so far stay
 * in l for srv_local_stop. */
pt_status srv_local_start(srv_local *l, const srv_config *cfg, uint16_t port, pt_error *err);

/* Collects the children that exited: without waiting, logging each, or
 * (wait_all) waiting for every one, silently. */
void srv_local_reap(srv_local *l, int wait_all);

/* How long srv_local_stop waits by default for the children after SIGTERM
 * before it sends SIGKILL to the ones left (ptserve --local-stop-timeout). */
#define SRV_DEFAULT_LOCAL_STOP_MS 10000u

/* Stops and reaps every child (SIGTERM, then SIGKILL to any still there
 * after cfg->local_stop_ms, logged), removes the cache folder and frees l's
 * memory. Accepts an l that started nothing. */
void srv_local_stop(srv_local *l);

#endif
