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

/* Takes p (pt_malloc'd, n > 0 bytes) as the next record; 0, or -1 out of
 * memory (p stays the caller's). */
static int rec_take(rec_buf *r, uint8_t *p, size_t n)
{
    if (r->nseg == r->cap) {
        rec_seg *g = pt_grow_array(r->seg, &r->cap, sizeof *g, 64);
        if (!g)
            return -1;
        r->seg = g;
    }
    r->seg[r->nseg++] = (rec_seg){p, n};
    r->len += n;
    return 0;
}

/* Frees the records; the array stays for the next ones. */
void st_rec_clear(rec_buf *r)
{
    for (uint32_t i = 0; i < r->nseg; i++)
        pt_free(r->seg[i].p);
    r->nseg = 0;
    r->len = 0;
}

void st_rec_fini(rec_buf *r)
{
    st_rec_clear(r);
    pt_free(r->seg);
    *r = (rec_buf){0};
}

/* Moves src's records after dst's (src is left empty); 0, or -1 out of
 * memory (both unchanged). */
static int rec_join(rec_buf *dst, rec_buf *src)
{
    if (src->nseg == 0)
        return 0;
    if (src->nseg > UINT32_MAX - dst->nseg)
        return -1;
    uint32_t need = dst->nseg + src->nseg;
    if (need > dst->cap) {
        rec_seg *g = pt_realloc(dst->seg, (size_t)need * sizeof *g);
        if (!g)
            return -1;
        dst->seg = g;
        dst->cap = need;
    }
    memcpy(dst->seg + dst->nseg, src->seg, (size_t)src->nseg * sizeof *src->seg);
    dst->nseg = need;
    dst->len += src->len;
    src->nseg = 0;
    src->len = 0;
    return 0;
}

/* Writes every record to fd, in order; 0, or -1 with errno (some may be
 * written). */
int st_rec_write(int fd, const rec_buf *r)
{
    enum { IOV = 256 };
    uint32_t i = 0;
    size_t off = 0; /* into record i */
    while (i < r->nseg) {
        struct iovec iov[IOV];
        int k = 0;
        for (uint32_t j = i; j < r->nseg && k < IOV; j++, k++) {
            size_t skip = j == i ? off : 0;
            iov[k] = (struct iovec){r->seg[j].p + skip, r->seg[j].n - skip};
        }
        ssize_t w = writev(fd, iov, k);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0) {
            if (w == 0)
                errno = EIO;
            return -1;
        }
        for (size_t left = (size_t)w; left > 0;) {
            size_t rest = r->seg[i].n - off;
            if (left < rest) {
                off += left;
                break;
            }
            left -= rest;
            i++;
            off = 0;
        }
    }
    return 0;
}

/* ---- logs -------------------------------------------------------------------------- */

log_file *st_find_log(const srv_state *st, uint64_t id)
{
    for (uint32_t i = 0; i < st->nlogs; i++)
        if (st->logs[i].id == id)
            return &st->logs[i];
    return NULL;
}

void st_close_log(srv_state *st, uint64_t id)
{
    log_file *l = st_find_log(st, id);
    if (!l)
        return;
    if (l->fd >= 0)
        close(l->fd);
    st_rec_fini(&l->out);
    *l = st->logs[--st->nlogs];
}

/* Writes a new log's header (fd empty); its durability is left to the next
 * group commit (the file is then marked fresh). */
static int write_header(int fd, uint64_t id)
{
    uint8_t h[LOG_HEADER];
    proto_put_u32(h, FLOG_MAGIC);
    proto_put_u32(h + 4, STATE_VERSION);
    proto_put_u64(h + 8, id);
    return pt_write_all(fd, h, sizeof h);
}

/* Opens the job's log for appending, writing its header when it is new. */
pt_status st_open_log(srv_state *st, uint64_t id, log_file **out, pt_error *err)
{
    log_file *l = st_find_log(st, id);
    if (l) {
        *out = l;
        return PT_OK;
    }
    if (st->nlogs == st->logs_cap) {
        log_file *n = pt_grow_array(st->logs, &st->logs_cap, sizeof *n, 8);
        if (!n)
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        st->logs = n;
    }
    char p[PATH_MAX];
    /* The folder is made here too: a frame of a frame-range job has no
     * bundle of its own, so its first file may be its log. */
    pt_status ms = st_job_file(st, id, "results.log", p, sizeof p, err);
    if (ms != PT_OK)
        return ms;
    int fd = open(p, O_RDWR | O_CREAT | O_APPEND | O_NOFOLLOW | O_CLOEXEC, 0600);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", p);
    struct stat sb;
    if (fstat(fd, &sb) != 0) {
        close(fd);
        return pt_error_errno(err, PT_ERR_IO, "%s", p);
    }
    uint64_t bytes = (uint64_t)sb.st_size;
    if (bytes > 0 && bytes < LOG_HEADER && ftruncate(fd, 0) == 0)
        bytes = 0; /* a header a full disk cut short: the log held nothing */
    if (bytes > 0 && bytes < LOG_HEADER) {
        pt_status s = pt_error_errno(err, PT_ERR_IO, "%s: cannot cut its partial header", p);
        close(fd);
        return s;
    }
    uint8_t h[4];
    if (bytes >= LOG_HEADER && (pread(fd, h, 4, 0) != 4 || proto_get_u32(h) != FLOG_MAGIC)) {
        /* A log of records (an older ptserve's) is rewritten in frames when
         * it is replayed (srv_state_restore); never appended to. */
        close(fd);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: not a results log of frames", p);
    }
    int fresh = 0;
    if (bytes == 0) {
        if (write_header(fd, id) != 0) {
            pt_status s = pt_error_errno(err, PT_ERR_IO, "%s: cannot write its header", p);
            /* Records must not follow a header cut short: leave the log empty
             * (it holds nothing yet) for the next try. Should that fail too,
             * the next open finds a short file and refuses it (above). */
            int cut = ftruncate(fd, 0);
            (void)cut;
            close(fd);
            return s;
        }
        bytes = LOG_HEADER;
        fresh = 1;
    }
    l = &st->logs[st->nlogs++];
    *l = (log_file){id, fd, bytes, bytes, ++st->epochs, fresh, 0, fresh, {NULL, 0, 0, 0}};
    *out = l;
    return PT_OK;
}

/* Truncates the file to the records written (l->bytes less those still in
 * memory), dropping a partial record; l->cut says whether that is still to
 * do. Returns 0, or -1 with errno kept. */
int st_cut_back(log_file *l)
{
    int saved = errno;
    l->cut = 1;
    if (ftruncate(l->fd, (off_t)(l->bytes - l->out.len)) != 0)
        return -1;
    l->cut = 0;
    errno = saved;
    return 0;
}

/* A record the log cannot take: empty, or no memory for it. */
static pt_status record_refused(uint64_t id, size_t len, pt_error *err)
{
    return pt_error_set(err, len ? PT_ERR_NOMEM : PT_ERR_ARG, "results log of job %llu: %s",
                        (unsigned long long)id, len ? "out of memory" : "an empty record");
}

pt_status srv_state_log_result_take(srv_state *st, uint64_t id, uint8_t **frame, size_t len,
                                    pt_error *err)
{
    log_file *l;
    pt_status s = st_open_log(st, id, &l, err);
    if (s != PT_OK)
        return s;
    /* A write cut short (a full disk, a quota) leaves part of a record at the
     * end; the next record would follow it and the log would read as damaged
     * in its middle. So the log is cut back to its last whole record before
     * anything else is appended, and stays unwritten while that fails. */
    if (l->cut && st_cut_back(l) != 0)
        return pt_error_errno(
            err, PT_ERR_IO, "results log of job %llu: cannot cut it back to its last whole record",
            (unsigned long long)id);
    /* Kept in memory for the commit thread, which writes it before the
     * fdatasync: a write() of every record on the loop cost more than half
     * its time in queue mode (the copy into the page cache). A kill -9 loses
     * only records not durable, which were never merged. The frame's own
     * CRC32C, checked when it arrived, is the record's checksum. */
    if (len == 0 || rec_take(&l->out, *frame, len) != 0)
        return record_refused(id, len, err);
    *frame = NULL;
    l->bytes += len;
    l->dirty = 1;
    return PT_OK;
}

pt_status srv_state_log_result(srv_state *st, uint64_t id, const uint8_t *frame, size_t len,
                               pt_error *err)
{
    uint8_t *copy = len ? pt_malloc(len) : NULL;
    if (!copy)
        return record_refused(id, len, err);
    memcpy(copy, frame, len);
    pt_status s = srv_state_log_result_take(st, id, &copy, len, err);
    pt_free(copy); /* NULL once taken */
    return s;
}

uint64_t srv_state_unsynced(const srv_state *st)
{
    uint64_t n = 0;
    for (uint32_t i = 0; i < st->nlogs; i++)
        n += st->logs[i].bytes - st->logs[i].durable;
    return n;
}

uint64_t srv_state_log_bytes(const srv_state *st, uint64_t id)
{
    const log_file *l = st_find_log(st, id);
    return l ? l->bytes : 0;
}

uint64_t srv_state_ckpt_limit(const srv_state *st, uint64_t film_bytes)
{
    if (st->ckpt_log_bytes)
        return st->ckpt_log_bytes;
    uint64_t limit = SRV_CKPT_FILM_MULTIPLE * film_bytes;
    return limit > SRV_CKPT_MIN_LOG ? limit : SRV_CKPT_MIN_LOG;
}

/* ---- the group commit -------------------------------------------------------------- */

void *st_commit_main(void *arg)
{
    committer *cm = arg;
    long ps = sysconf(_SC_PAGESIZE);
    uint64_t page = ps > 0 ? (uint64_t)ps : 4096u;
    pthread_mutex_lock(&cm->mu);
    for (;;) {
        while (!cm->has_req && !cm->stop)
            pthread_cond_wait(&cm->cv, &cm->mu);
        if (!cm->has_req)
            break;
        pthread_mutex_unlock(&cm->mu);
        for (uint32_t i = 0; i < cm->n; i++) {
            commit_item *it = &cm->items[i];
            it->err = 0;
            it->step = "write";
            if (st_rec_write(it->fd, &it->in) != 0)
                it->err = errno ? errno : EIO;
            if (!it->err) {
                pt_wait_for_file(cm->gate);
                it->step = "fdatasync";
                if (cm->fail[0] && access(cm->fail, F_OK) == 0)
                    it->err = EIO;
                else if (fdatasync(it->fd) != 0 || (it->fresh && pt_fsync_dir_of(it->path) != 0))
                    it->err = errno ? errno : EIO;
            }
            if (!it->err) {
                st_rec_clear(&it->in); /* durable: off the loop's time */
                /* Its pages are read again only by a restart's replay (from
                 * the disk): dropped now, clean, rather than when the log is
                 * cut at a checkpoint or removed with its job, on the loop
                 * (a 500 MB log's pages were 3 % of a 1,024-spp job's loop
                 * time in queue mode). Whole pages only: the next record
                 * goes on in the last one. Advice: a failure changes nothing. */
                off_t whole = (off_t)(it->upto / page * page);
                if (whole > 0)
                    posix_fadvise(it->fd, 0, whole, POSIX_FADV_DONTNEED);
            }
            close(it->fd);
            it->fd = -1;
        }
        pthread_mutex_lock(&cm->mu);
        cm->has_req = 0;
        cm->ready = 1;
        pthread_cond_broadcast(&cm->cv);
        uint64_t one = 1;
        ssize_t w = write(cm->efd, &one, sizeof one);
        (void)w;
    }
    pthread_mutex_unlock(&cm->mu);
    return NULL;
}

int srv_state_commit_fd(const srv_state *st)
{
    return st->cm.efd;
}

uint64_t srv_state_commit_next(const srv_state *st)
{
    return st->cm.next;
}

int srv_state_commit_start(srv_state *st)
{
    committer *cm = &st->cm;
    if (cm->busy)
        return 0;
    uint32_t n = 0;
    for (uint32_t i = 0; i < st->nlogs; i++)
        n += st->logs[i].dirty;
    if (n == 0)
        return 0;
    if (n > cm->cap) {
        commit_item *items = pt_realloc(cm->items, n * sizeof *items);
        if (!items)
            return 0; /* tried again next round */
        memset(items + cm->cap, 0, (n - cm->cap) * sizeof *items);
        cm->items = items;
        cm->cap = n;
    }
    uint32_t k = 0;
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (!l->dirty)
            continue;
        commit_item *it = &cm->items[k];
        /* A dup, so that the log may be closed (its job ended) meanwhile. */
        it->fd = fcntl(l->fd, F_DUPFD_CLOEXEC, 0);
        if (it->fd < 0)
            continue; /* stays dirty: tried again next round */
        it->id = l->id;
        it->upto = l->bytes;
        it->epoch = l->epoch;
        it->fresh = l->fresh;
        it->err = 0;
        /* The log's records go to the thread; the item's emptied buffer
         * (from an earlier commit) takes the next ones. */
        rec_buf spare = it->in;
        it->in = l->out;
        l->out = spare;
        if (l->fresh)
            st_job_path(st, l->id, "results.log", it->path, sizeof it->path);
        l->dirty = 0;
        l->fresh = 0;
        k++;
    }
    if (k == 0)
        return 0;
    cm->n = k;
    cm->gen = cm->next++;
    cm->busy = 1;
    pthread_mutex_lock(&cm->mu);
    cm->has_req = 1;
    pthread_mutex_unlock(&cm->mu);
    /* After the unlock, so that the thread does not wake to a held lock;
     * only the loop thread, which is here, waits on cv besides it. */
    pthread_cond_broadcast(&cm->cv);
    return 1;
}

int srv_state_commit_busy(const srv_state *st)
{
    return st->cm.busy;
}

int srv_state_commit_collect(srv_state *st, int wait, uint64_t *done, srv_commit_fn fn, void *ctx)
{
    committer *cm = &st->cm;
    uint64_t v;
    ssize_t r = read(cm->efd, &v, sizeof v); /* the wake-up; the flag below says */
    (void)r;
    if (!cm->busy)
        return 0;
    pthread_mutex_lock(&cm->mu);
    while (wait && !cm->ready)
        pthread_cond_wait(&cm->cv, &cm->mu);
    int ready = cm->ready;
    cm->ready = 0;
    pthread_mutex_unlock(&cm->mu);
    if (!ready)
        return 0;
    cm->busy = 0;
    for (uint32_t i = 0; i < cm->n; i++) {
        commit_item *it = &cm->items[i];
        log_file *l = st_find_log(st, it->id);
        int current = l && l->epoch == it->epoch;
        if (current && it->err == 0 && it->upto > l->durable)
            l->durable = it->upto;
        pt_status outcome = it->err ? PT_ERR_IO : PT_OK;
        if (current && it->err != 0) {
            /* A write cut short, or a failed fdatasync, which may have dropped
             * any page written since the last good one (and a later one would
             * not say so): the file is cut back to what is known durable. The
             * batch's records go back in front of those logged since, to be
             * written again once srv_state_log_resync says to (not at once: a
             * full disk would make that a busy loop). Only when memory for
             * that is short are they dropped (PT_ERR_NOMEM: never merged). */
            if (rec_join(&it->in, &l->out) == 0) {
                rec_buf failed = it->in;
                it->in = l->out;
                l->out = failed;
            } else {
                l->bytes = l->durable;
                st_rec_clear(&l->out);
                outcome = PT_ERR_NOMEM;
            }
            st_cut_back(l);
            l->dirty = 0;
            l->fresh |= it->fresh;
        }
        st_rec_clear(&it->in);
        if (fn && current) {
            pt_error e = {0};
            if (it->err) {
                errno = it->err;
                pt_error_errno(&e, PT_ERR_IO, "results log of job %llu: %s",
                               (unsigned long long)it->id, it->step);
            }
            fn(ctx, it->id, outcome, &e);
        }
    }
    *done = cm->gen;
    return 1;
}

pt_status srv_state_sync(srv_state *st, pt_error *err)
{
    /* The batch in flight first (its outcome is left for the collect). */
    pthread_mutex_lock(&st->cm.mu);
    while (st->cm.has_req)
        pthread_cond_wait(&st->cm.cv, &st->cm.mu);
    pthread_mutex_unlock(&st->cm.mu);
    pt_status s = PT_OK;
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (!l->dirty)
            continue;
        /* A commit that failed and is not collected yet: its log is cut
         * back when it is, and nothing is written after its torn end. */
        int failed = 0;
        for (uint32_t k = 0; st->cm.busy && k < st->cm.n; k++)
            failed |= st->cm.items[k].id == l->id && st->cm.items[k].epoch == l->epoch &&
                      st->cm.items[k].err != 0;
        char p[PATH_MAX];
        st_job_path(st, l->id, "results.log", p, sizeof p);
        if (failed) {
            if (s == PT_OK)
                s = pt_error_set(err, PT_ERR_IO, "results log of job %llu: its commit failed",
                                 (unsigned long long)l->id);
            continue;
        }
        if (st_write_out(l) != 0 || fdatasync(l->fd) != 0 ||
            (l->fresh && pt_fsync_dir_of(p) != 0)) {
            if (s == PT_OK)
                s = pt_error_errno(err, PT_ERR_IO, "results log of job %llu: fdatasync",
                                   (unsigned long long)l->id);
            continue;
        }
        l->durable = l->bytes;
        l->dirty = l->fresh = 0;
    }
    return s;
}

pt_status srv_state_log_resync(srv_state *st, uint64_t id, pt_error *err)
{
    log_file *l = st_find_log(st, id);
    if (!l)
        return PT_OK;
    if (l->cut && st_cut_back(l) != 0)
        return pt_error_errno(
            err, PT_ERR_IO, "results log of job %llu: cannot cut it back to its last whole record",
            (unsigned long long)id);
    l->dirty = 1;
    return PT_OK;
}

/* Moves the job's folder to the trash, for the sweeper to remove (a rename:
 * the loop does not wait for the unlinks). Where the rename fails, the
 * folder is removed in place. */
void st_remove_job(srv_state *st, uint64_t id)
{
    char p[PATH_MAX], t[PATH_MAX + 32];
    st_job_path(st, id, NULL, p, sizeof p);
    snprintf(t, sizeof t, "%s/%llu", st->sw.trash, (unsigned long long)id);
    if (rename(p, t) == 0) {
        st_sweep_signal(&st->sw);
    } else if (errno != ENOENT) {
        pt_remove_tree(p);
        pt_fsync_dir_of(p);
    }
}

void srv_state_forget_job(srv_state *st, uint64_t id)
{
    st_close_log(st, id);
    if (st->ck.running && st->ck.id == id) {
        /* Its checkpoint is being written into the folder: the folder goes
         * when that is done (srv_state_checkpoint_collect), not under it. */
        st->ck.forget = 1;
        return;
    }
    st_remove_job(st, id);
}

/* Writes the log's records not handed to a commit, on the caller's thread
 * (no commit in flight). Returns 0, or -1 with errno: the file is cut back
 * to the records before them, which stay in memory to be written again. */
int st_write_out(log_file *l)
{
    if (l->out.len == 0)
        return 0;
    if (st_rec_write(l->fd, &l->out) == 0) {
        st_rec_clear(&l->out);
        return 0;
    }
    int e = errno;
    st_cut_back(l);
    errno = e;
    return -1;
}
