#define _GNU_SOURCE /* O_CLOEXEC, fdatasync */
#include "server/store/state_impl.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/render.h"
#include "protocol/frame.h"
#include "protocol/wire.h"

pt_status srv_state_open(const char *dir, const srv_job_codec *codec, srv_state **out,
                         pt_error *err)
{
    if (strlen(dir) >= sizeof((srv_state *)0)->dir)
        return pt_error_set(err, PT_ERR_ARG, "state folder %s: path too long", dir);
    srv_state *st = pt_calloc(1, sizeof *st);
    if (!st)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    snprintf(st->dir, sizeof st->dir, "%s", dir);
    st->codec = codec;
    st->lock_fd = -1;
    st->cm.efd = -1;
    st->cm.next = 1;
    /* Test hooks (tests/integration/test_durable.sh): hold each fdatasync of
     * a group commit until a file exists, or fail it while another exists;
     * hold a checkpoint written but not yet renamed into place until a file
     * exists; write checkpoints past a small log. Unset in production. */
    const char *e;
    if ((e = getenv("PTSERVE_TEST_COMMIT_GATE")) != NULL)
        snprintf(st->cm.gate, sizeof st->cm.gate, "%s", e);
    if ((e = getenv("PTSERVE_TEST_COMMIT_FAIL")) != NULL)
        snprintf(st->cm.fail, sizeof st->cm.fail, "%s", e);
    if ((e = getenv("PTSERVE_TEST_CKPT_GATE")) != NULL)
        snprintf(st->ck.gate, sizeof st->ck.gate, "%s", e);
    if ((e = getenv("PTSERVE_TEST_CKPT_LOG_BYTES")) != NULL)
        st->ckpt_log_bytes = strtoull(e, NULL, 10);
    char p[PATH_MAX];
    pt_status s;
    st_path_of(st, st->sw.jobs, sizeof st->sw.jobs, "jobs");
    st_path_of(st, st->sw.trash, sizeof st->sw.trash, "trash");
    if ((s = pt_mkdirs(st->sw.jobs, 1, err)) != PT_OK ||
        (s = pt_mkdirs(st->sw.trash, 1, err)) != PT_OK)
        goto fail;
    st_path_of(st, p, sizeof p, "lock");
    st->lock_fd = open(p, O_RDWR | O_CREAT | O_NOFOLLOW | O_CLOEXEC, 0600);
    if (st->lock_fd < 0) {
        s = pt_error_errno(err, PT_ERR_IO, "state folder %s: cannot open its lock file", dir);
        goto fail;
    }
    if (flock(st->lock_fd, LOCK_EX | LOCK_NB) != 0) {
        s = pt_error_errno(err, PT_ERR_IO, "state folder %s is in use by another ptserve", dir);
        goto fail;
    }
    st->cm.efd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (st->cm.efd < 0) {
        s = pt_error_errno(err, PT_ERR_IO, "eventfd");
        goto fail;
    }
    if ((s = st_thread_start(&st->cm.th, &st->cm.mu, &st->cm.cv, st_commit_main, &st->cm, "commit",
                             err)) != PT_OK)
        goto fail;
    st->cm.started = 1;
    st->sw.work = 1; /* the sweeper starts with what a crash left in the trash */
    if ((s = st_thread_start(&st->sw.th, &st->sw.mu, &st->sw.cv, st_sweep_main, &st->sw, "sweeper",
                             err)) != PT_OK)
        goto fail;
    st->sw.started = 1;
    *out = st;
    return PT_OK;
fail:
    srv_state_close(st);
    return s;
}

void srv_state_close(srv_state *st)
{
    if (!st)
        return;
    st_ckpt_join(st);
    if (st->cm.started)
        st_thread_stop(st->cm.th, &st->cm.mu, &st->cm.cv, &st->cm.stop);
    if (st->sw.started) /* after the checkpoint's: it may have ended a job */
        st_thread_stop(st->sw.th, &st->sw.mu, &st->sw.cv, &st->sw.stop);
    for (uint32_t i = 0; i < st->cm.cap; i++)
        st_rec_fini(&st->cm.items[i].in);
    pt_free(st->cm.items);
    if (st->cm.efd >= 0)
        close(st->cm.efd);
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (l->fd >= 0) {
            /* Records not merged yet: a restart replays them. */
            if (st_write_out(l) == 0)
                fdatasync(l->fd);
            close(l->fd);
        }
        st_rec_fini(&l->out);
    }
    pt_free(st->logs);
    if (st->lock_fd >= 0)
        close(st->lock_fd);
    pt_free(st);
}
