#define _GNU_SOURCE /* O_CLOEXEC, fdatasync */
#include "server/store/state_impl.h"

#include <assert.h>
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

/* ---- checkpoints ------------------------------------------------------------------- */

/* Serialises job into a checkpoint file at path, durably: a temporary file
 * beside it, renamed into place (gate: a test hook, waited for between). */
static pt_status write_ckpt(const char *path, const srv_job_codec *codec, const srv_job *job,
                            const srv_ckpt_extra *x, const char *gate, pt_error *err)
{
    proto_writer w;
    proto_writer_init(&w, MAX_CKPT_BYTES);
    st_begin_file(&w, CKPT_MAGIC);
    proto_w_f64(&w, x->seconds);
    proto_w_u64(&w, x->rejected);
    proto_w_u64(&w, x->rays);
    pt_status s = codec->save(job, &w, err);
    if (s == PT_OK && proto_writer_status(&w) == PT_OK)
        proto_w_u32(&w, proto_crc32c(0, w.buf, w.len));
    if (s == PT_OK && proto_writer_status(&w) != PT_OK)
        s = pt_error_set(err, proto_writer_status(&w), "%s: cannot serialise", path);
    pt_temp t;
    if (s == PT_OK && (s = pt_temp_open(path, 0644, &t, err)) == PT_OK) {
        if (pt_write_all(t.fd, w.buf, w.len) != 0) {
            s = pt_error_errno(err, PT_ERR_IO, "%s: write", path);
            pt_temp_abort(&t);
        } else {
            pt_wait_for_file(gate);
            s = pt_temp_commit(&t, path, err);
        }
    }
    proto_writer_fini(&w);
    return s;
}

/* Cuts the job's open log to its header (everything it held is in a
 * checkpoint now). */
static pt_status log_restart(srv_state *st, uint64_t id, pt_error *err)
{
    log_file *l = st_find_log(st, id);
    if (!l)
        return PT_OK;
    if (ftruncate(l->fd, LOG_HEADER) != 0 || fdatasync(l->fd) != 0)
        return pt_error_errno(err, PT_ERR_IO, "results log of job %llu: truncate",
                              (unsigned long long)id);
    l->bytes = l->durable = LOG_HEADER;
    st_rec_clear(&l->out);
    l->epoch = ++st->epochs;
    l->dirty = 0;
    l->cut = 0;
    return PT_OK;
}

pt_status srv_state_checkpoint(srv_state *st, const srv_job *job, const srv_ckpt_extra *x,
                               pt_error *err)
{
    assert(st->codec); /* srv_state_open's */
    uint64_t id = st->codec->id(job);
    if (st->ck.running)
        st_ckpt_join(st); /* its older snapshot must not land after this one */
    char p[PATH_MAX], old[PATH_MAX];
    pt_status s = st_job_file(st, id, "checkpoint", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    pthread_mutex_lock(&st->cm.mu); /* no fdatasync of the log during the truncate */
    while (st->cm.has_req)
        pthread_cond_wait(&st->cm.cv, &st->cm.mu);
    pthread_mutex_unlock(&st->cm.mu);
    if ((s = write_ckpt(p, st->codec, job, x, "", err)) != PT_OK)
        return s;
    /* Everything the logs held is in the checkpoint now: start afresh. */
    st_job_path(st, id, "results.old", old, sizeof old);
    if (unlink(old) != 0 && errno != ENOENT)
        return pt_error_errno(err, PT_ERR_IO, "%s", old);
    return log_restart(st, id, err);
}

static void *ckpt_main(void *arg)
{
    ckpt_work *ck = arg;
    ck->status = write_ckpt(ck->path, ck->codec, ck->snap, &ck->x, ck->gate, &ck->err);
    /* The records of the rotated log are in the checkpoint now. Should the
     * unlink not reach the disk, a restart replays them again: harmless. */
    if (ck->status == PT_OK && unlink(ck->old) != 0 && errno != ENOENT)
        ck->status = pt_error_errno(&ck->err, PT_ERR_IO, "%s", ck->old);
    atomic_store(&ck->done, 1);
    return NULL;
}

void st_ckpt_join(srv_state *st)
{
    if (!st->ck.running)
        return;
    pthread_join(st->ck.th, NULL);
    st->ck.running = 0;
    st->codec->free(st->ck.snap);
    st->ck.snap = NULL;
    if (st->ck.forget)
        st_remove_job(st, st->ck.id);
    st->ck.forget = 0;
}

int srv_state_checkpoint_busy(const srv_state *st)
{
    return st->ck.running;
}

pt_status srv_state_checkpoint_start(srv_state *st, srv_job *snap, const srv_ckpt_extra *x,
                                     pt_error *err)
{
    ckpt_work *ck = &st->ck;
    assert(st->codec); /* srv_state_open's */
    uint64_t id = st->codec->id(snap);
    pt_status s;
    if (ck->running) {
        st->codec->free(snap);
        return pt_error_set(err, PT_AGAIN, "a checkpoint is being written");
    }
    char cur[PATH_MAX];
    if ((s = st_job_file(st, id, "checkpoint", ck->path, sizeof ck->path, err)) != PT_OK) {
        st->codec->free(snap);
        return s;
    }
    st_job_path(st, id, "results.old", ck->old, sizeof ck->old);
    st_job_path(st, id, "results.log", cur, sizeof cur);
    /* An older rotated log still here means the checkpoint that was to
     * replace it failed: its records are not all in a checkpoint yet, so the
     * current log is not rotated over it; this checkpoint, when written,
     * holds both, and both go. */
    struct stat sb;
    int keep_old = lstat(ck->old, &sb) == 0;
    log_file *l = st_find_log(st, id);
    if (l && !keep_old) {
        /* The current log becomes results.old until the checkpoint that
         * holds its records is durable; records go to a fresh log meanwhile
         * (its header and folder entry are synced by the next group commit,
         * before any of its records is merged). */
        if (rename(cur, ck->old) != 0) {
            st->codec->free(snap);
            return pt_error_errno(err, PT_ERR_IO, "%s: rename", cur);
        }
        st_close_log(st, id);
        /* Should the new log not open, the next result's write tries again. */
        pt_error e2 = {0};
        (void)st_open_log(st, id, &l, &e2);
    }
    /* With keep_old, both stay until this checkpoint is durable: the thread
     * then takes results.old away, and the log's records stay (replayed as
     * duplicates at worst). */
    ck->id = id;
    ck->codec = st->codec;
    ck->snap = snap;
    ck->x = *x;
    ck->status = PT_OK;
    ck->forget = 0;
    memset(&ck->err, 0, sizeof ck->err);
    atomic_store(&ck->done, 0);
    if (pthread_create(&ck->th, NULL, ckpt_main, ck) != 0) {
        ck->snap = NULL;
        st->codec->free(snap);
        return pt_error_set(err, PT_ERR_IO, "cannot start the checkpoint thread");
    }
    ck->running = 1;
    return PT_OK;
}

int srv_state_checkpoint_collect(srv_state *st, uint64_t *id, pt_status *status, pt_error *err)
{
    ckpt_work *ck = &st->ck;
    if (!ck->running || !atomic_load(&ck->done))
        return 0;
    st_ckpt_join(st);
    *id = ck->id;
    *status = ck->status;
    if (ck->status != PT_OK && err)
        *err = ck->err;
    return 1;
}

/* A RESULT payload of protocol 2 (a log before STATE_FILM_VERSION: 60 bytes
 * of header, 36 per pixel) in protocol 3's layout (msg.h) into out, which
 * holds the largest RESULT: no paths capped (not counted then), every sample a
 * camera hit (those jobs are not transparent). Returns its length, or 0 when
 * pl is not of that shape (the decoder then names the fault). */
static size_t log_upgrade_record(const uint8_t *pl, size_t n, uint8_t *out)
{
    if (n < 60 || (n - 60) % 36 != 0 || (n - 60) / 36 > PROTO_MAX_TILE_PIXELS)
        return 0;
    size_t npx = (n - 60) / 36;
    memcpy(out, pl, 56);
    proto_put_u64(out + 56, 0);
    memcpy(out + 64, pl + 56, 4);
    for (size_t i = 0; i < npx; i++) {
        uint8_t *q = out + 68 + i * 40;
        memcpy(q, pl + 60 + i * 36, 36);
        memcpy(q + 36, pl + 60 + i * 36 + 32, 4);
    }
    return 68 + npx * 40;
}

/* A RESULT payload of protocol 3 (68 bytes of header, 40 per pixel with
 * double sums) in protocol 4's layout (msg.h), written into w (reset first);
 * px is scratch for PROTO_MAX_TILE_PIXELS pixels. Each double sum becomes
 * fixed point by the rounding a block's sum gets (pt_fixed_of): the same
 * bits on every coordinator, so resuming from an old log loses no work.
 * Returns the length, or 0 when pl is not of that shape or a sum is not one a
 * render gives (not finite, negative, above the cap), and the decoder then
 * names the fault. */
static size_t log_upgrade_fixed(const uint8_t *pl, size_t n, pt_pixel_acc *px, proto_writer *w)
{
    if (n < 68 || (n - 68) % 40 != 0 || (n - 68) / 40 > PROTO_MAX_TILE_PIXELS)
        return 0;
    proto_result m = {0};
    m.job_id = proto_get_u64(pl);
    m.task_id = proto_get_u64(pl + 8);
    m.tile = (pt_rect){proto_get_u32(pl + 16), proto_get_u32(pl + 20), proto_get_u32(pl + 24),
                       proto_get_u32(pl + 28)};
    m.s0 = proto_get_u32(pl + 32);
    m.s1 = proto_get_u32(pl + 36);
    m.rejected = proto_get_u64(pl + 40);
    m.rays = proto_get_u64(pl + 48);
    m.capped = proto_get_u64(pl + 56);
    m.npixels = (uint32_t)((n - 68) / 40);
    m.pixels = px;
    for (uint32_t i = 0; i < m.npixels; i++) {
        const uint8_t *q = pl + 68 + (size_t)i * 40;
        px[i].n = proto_get_u32(q + 32);
        px[i].hits = proto_get_u32(q + 36);
        for (int c = 0; c < 3; c++) {
            double d = proto_get_f64(q + 8 * c);
            if (!(d >= 0.0 && d <= PT_MAX_SAMPLE_RADIANCE * px[i].n))
                return 0;
            px[i].fsum[c] = pt_fixed_of(d);
        }
        double sq = proto_get_f64(q + 24);
        if (!(sq >= 0.0 && sq <= INFINITY))
            return 0;
        px[i].fsum_sq = pt_ufixed_of(sq);
    }
    proto_writer_reset(w);
    pt_error e = {0};
    if (proto_msg_encode_result(w, &m, &e) != PT_OK)
        return 0;
    return w->len;
}

/* Hands one RESULT payload of the log to the codec, which merges it into job. */
static pt_status replay_one(const srv_job_codec *codec, srv_job *job, const uint8_t *pl, size_t n,
                            pt_pixel_acc *buf, srv_ckpt_extra *x, uint32_t *replayed, const char *p,
                            size_t at, pt_error *err)
{
    proto_result r;
    pt_error e2 = {0};
    if (proto_msg_decode_result(pl, n, buf, PROTO_MAX_TILE_PIXELS, &r, &e2) != PT_OK)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: record at byte %zu is damaged (contents: %s); refusing to use it",
                            p, at, e2.msg);
    int merged = 0;
    pt_status s = codec->replay(job, &r, &merged, &e2);
    if (s == PT_OK && merged) {
        x->rejected += r.rejected;
        x->rays += r.rays;
        (*replayed)++;
    }
    proto_result_fini(&r);
    if (s != PT_OK)
        return pt_error_set(err, PT_ERR_FORMAT, "%s: record at byte %zu does not fit the job: %s",
                            p, at, e2.msg);
    return PT_OK;
}

/* The oldest protocol whose RESULT frames a log may hold: 3 (double sums,
 * upgraded to fixed point as read); from PROTO_FIXED_RESULT on the RESULT
 * layout is the current one (later versions changed only TASK and SUBMIT). */
#define LOG_OLDEST_PROTO 3u
#define PROTO_FIXED_RESULT 4u

/* Decodes the record at b[0, len) of a frames log: a RESULT frame of any
 * protocol from LOG_OLDEST_PROTO to PROTO_VERSION (proto_frame_decode takes
 * only the current one, and a log outlives a protocol bump). PT_AGAIN when
 * the bytes end inside it. */
static pt_status log_frame_decode(const uint8_t *b, size_t len, proto_frame *f, size_t *used,
                                  pt_error *err)
{
    if (len < PROTO_FRAME_HEADER)
        return PT_AGAIN;
    if (memcmp(b, PROTO_MAGIC, 4) != 0)
        return pt_error_set(err, PT_ERR_FORMAT, "not a frame (bad magic)");
    uint16_t version = proto_get_u16(b + 4), type = proto_get_u16(b + 6);
    uint32_t plen = proto_get_u32(b + 8);
    if (version < LOG_OLDEST_PROTO || version > PROTO_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "a frame of protocol %u; this ptserve reads logs of protocols %u to %u",
                            (unsigned)version, LOG_OLDEST_PROTO, PROTO_VERSION);
    if (type != PROTO_MSG_RESULT)
        return pt_error_set(err, PT_ERR_FORMAT, "not a RESULT (type %u)", (unsigned)type);
    if (plen > PROTO_MAX_PAYLOAD)
        return pt_error_set(err, PT_ERR_FORMAT, "payload length %u over the cap", (unsigned)plen);
    size_t total = (size_t)PROTO_FRAME_OVERHEAD + plen;
    if (len < total)
        return PT_AGAIN;
    if (proto_crc32c(0, b, PROTO_FRAME_HEADER + (size_t)plen) !=
        proto_get_u32(b + PROTO_FRAME_HEADER + plen))
        return pt_error_set(err, PT_ERR_FORMAT, "bad CRC");
    f->version = version;
    f->type = type;
    f->len = plen;
    f->payload = b + PROTO_FRAME_HEADER;
    *used = total;
    return PT_OK;
}

/* Replays the log at p (results.old or results.log) into job. A log of
 * records (PTRL, an older ptserve's: u32 length, u32 CRC32C, payload) or a
 * frames log holding protocol 3 frames (double sums) is rewritten as frames
 * of the current protocol once replayed, so that records appended later never
 * follow records of another layout; its older payloads are upgraded on the
 * way (log_upgrade_record, log_upgrade_fixed). A torn last record is cut off
 * (*torn). */
/* A results log being replayed: its bytes, how its records are read and
 * the log rewritten in the current format (up) when they are upgraded. */
typedef struct log_scan {
    const char *p; /* its path, for messages */
    const uint8_t *data;
    size_t len;
    int frames;      /* records are RESULT frames (FLOG_MAGIC), else length + CRC32C */
    int rewrite;     /* the log is rewritten in up */
    uint32_t logver; /* the header's format version */
    int *torn;
    proto_writer up, rec;
    pt_pixel_acc *buf;
    uint8_t *upbuf;
} log_scan;

/* The RESULT frame record at good of a frames log: its payload (upgraded to
 * fixed-point sums when older) in *pl, *n and the next record's offset in
 * *next. PT_AGAIN: the log ends before it (a write cut short, *torn set). */
static pt_status frame_record(log_scan *sc, size_t good, const uint8_t **pl, size_t *n,
                              size_t *next, pt_error *err)
{
    const uint8_t *data = sc->data;
    size_t len = sc->len;
    proto_frame f = {0};
    size_t used = 0;
    pt_error e2 = {0};
    pt_status fs = log_frame_decode(data + good, len - good, &f, &used, &e2);
    if (fs == PT_AGAIN) {
        *sc->torn = 1; /* the last write was cut short by the crash */
        return PT_AGAIN;
    }
    if (fs != PT_OK && len - good >= PROTO_FRAME_HEADER &&
        good + PROTO_FRAME_OVERHEAD + (size_t)proto_frame_payload_len(data + good) == len) {
        /* The last record, whole in length but not in content: the file
         * grew before its data reached the disk (a crash or a full disk
         * during the write). Never merged. */
        *sc->torn = 1;
        return PT_AGAIN;
    }
    if (fs != PT_OK)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: record at byte %zu is damaged (%s); refusing to use it", sc->p,
                            good, e2.msg);
    *pl = f.payload;
    *n = f.len;
    *next = good + used;
    if (f.version < PROTO_FIXED_RESULT) {
        /* Double sums: this record and every later one go into a rewritten
         * log, the records before it as they are. */
        if (!sc->rewrite) {
            proto_w_bytes(&sc->up, data + LOG_HEADER, good - LOG_HEADER);
            sc->rewrite = 1;
        }
        size_t k = log_upgrade_fixed(*pl, *n, sc->buf, &sc->rec);
        if (k == 0)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "%s: record at byte %zu is a protocol %u RESULT that cannot be "
                                "upgraded; refusing to use it",
                                sc->p, good, (unsigned)f.version);
        *pl = sc->rec.buf;
        *n = k;
    }
    if (sc->rewrite)
        proto_frame_encode(&sc->up, PROTO_MSG_RESULT, *pl, *n, NULL);
    return PT_OK;
}

/* The record at good of a log of length, CRC32C and payload (formats
 * before the frames log), as frame_record; the log is always rewritten. */
static pt_status crc_record(log_scan *sc, size_t good, const uint8_t **pl, size_t *n, size_t *next,
                            pt_error *err)
{
    const uint8_t *data = sc->data;
    size_t len = sc->len;
    if (len - good < 8 || len - good - 8 < proto_get_u32(data + good)) {
        *sc->torn = 1;
        return PT_AGAIN;
    }
    *n = proto_get_u32(data + good);
    *pl = data + good + 8;
    *next = good + 8 + *n;
    if (proto_crc32c(0, *pl, *n) != proto_get_u32(data + good + 4)) {
        if (*next == len) {
            *sc->torn = 1;
            return PT_AGAIN;
        }
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: record at byte %zu is damaged (checksum mismatch); refusing to "
                            "use it",
                            sc->p, good);
    }
    if (sc->logver < STATE_FIXED_VERSION) {
        size_t k = sc->logver < STATE_FILM_VERSION ? log_upgrade_record(*pl, *n, sc->upbuf) : 0;
        if (k) {
            *pl = sc->upbuf;
            *n = k;
        }
        if ((k = log_upgrade_fixed(*pl, *n, sc->buf, &sc->rec)) != 0) {
            *pl = sc->rec.buf;
            *n = k;
        }
    }
    proto_frame_encode(&sc->up, PROTO_MSG_RESULT, *pl, *n, NULL);
    return PT_OK;
}

static pt_status replay_log(const char *p, const srv_job_codec *codec, srv_job *job,
                            srv_ckpt_extra *x, uint32_t *replayed, int *torn, pt_error *err)
{
    uint64_t id = codec->id(job);
    uint8_t *data;
    size_t len;
    pt_status s = pt_read_file(p, (size_t)64 << 30, &data, &len, err);
    if (s != PT_OK)
        return (s == PT_ERR_IO && err->sys_errno == ENOENT) ? PT_OK : s;
    size_t good = 0;
    log_scan sc = {p, data, len, 0, 0, 0, torn, {0}, {0}, NULL, NULL};
    proto_writer_init(&sc.up, (size_t)64 << 30);
    proto_writer_init(&sc.rec, (size_t)1 << 30);
    if (len < LOG_HEADER) {
        *torn = len > 0; /* the header write itself was cut short */
    } else if ((proto_get_u32(data) != LOG_MAGIC && proto_get_u32(data) != FLOG_MAGIC) ||
               !st_version_read(proto_get_u32(data + 4)) || proto_get_u64(data + 8) != id) {
        pt_free(data);
        proto_writer_fini(&sc.up);
        proto_writer_fini(&sc.rec);
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: not the results log of job %llu (bad "
                            "header); refusing to use it",
                            p, (unsigned long long)id);
    } else {
        good = LOG_HEADER;
        sc.frames = proto_get_u32(data) == FLOG_MAGIC;
        sc.logver = proto_get_u32(data + 4);
        sc.rewrite = !sc.frames;
        sc.upbuf = pt_malloc(PROTO_RESULT_HEADER_SIZE +
                             (size_t)PROTO_RESULT_WIDE_PIXEL_SIZE * PROTO_MAX_TILE_PIXELS);
        proto_w_u32(&sc.up, FLOG_MAGIC);
        proto_w_u32(&sc.up, STATE_VERSION);
        proto_w_u64(&sc.up, id);
        sc.buf = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *sc.buf);
        if (!sc.buf || !sc.upbuf) {
            pt_free(sc.buf);
            pt_free(sc.upbuf);
            proto_writer_fini(&sc.up);
            proto_writer_fini(&sc.rec);
            pt_free(data);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        while (good < len && s == PT_OK) {
            const uint8_t *pl = NULL;
            size_t n = 0, next = good;
            pt_status rs = sc.frames ? frame_record(&sc, good, &pl, &n, &next, err)
                                     : crc_record(&sc, good, &pl, &n, &next, err);
            if (rs == PT_AGAIN)
                break;
            if (rs != PT_OK) {
                s = rs;
                break;
            }
            s = replay_one(codec, job, pl, n, sc.buf, x, replayed, p, good, err);
            if (s == PT_OK)
                good = next;
        }
        pt_free(sc.buf);
        pt_free(sc.upbuf);
    }
    pt_free(data);
    proto_writer_fini(&sc.rec);
    if (s == PT_OK && sc.rewrite) {
        /* Whole records only: a torn last one is left out. */
        s = proto_writer_status(&sc.up) != PT_OK
                ? pt_error_set(err, proto_writer_status(&sc.up), "%s: cannot upgrade", p)
                : pt_write_file_atomic(p, sc.up.buf, sc.up.len, err);
        proto_writer_fini(&sc.up);
        return s;
    }
    proto_writer_fini(&sc.up);
    if (s == PT_OK && *torn) {
        /* Cut the incomplete record off so new records follow whole ones. */
        if (truncate(p, (off_t)(good >= LOG_HEADER ? good : 0)) != 0)
            s = pt_error_errno(err, PT_ERR_IO, "%s: truncate", p);
    }
    return s;
}

pt_status srv_state_restore(srv_state *st, srv_job *job, srv_ckpt_extra *extra, uint32_t *replayed,
                            int *torn, pt_error *err)
{
    memset(extra, 0, sizeof *extra);
    *replayed = 0;
    *torn = 0;
    assert(st->codec); /* srv_state_open's */
    uint64_t id = st->codec->id(job);
    char p[PATH_MAX];
    st_job_path(st, id, "checkpoint", p, sizeof p);
    uint8_t *data;
    const uint8_t *body;
    size_t len;
    int missing;
    /* The checkpoint body carries its own version (the codec's load). */
    pt_status s =
        st_read_intact(p, CKPT_MAGIC, MAX_CKPT_BYTES, &data, &body, &len, NULL, &missing, err);
    if (s != PT_OK)
        return s;
    if (!missing) {
        if (len < 24) {
            pt_free(data);
            return pt_error_set(err, PT_ERR_FORMAT, "%s: truncated header", p);
        }
        extra->seconds = proto_get_f64(body);
        extra->rejected = proto_get_u64(body + 8);
        extra->rays = proto_get_u64(body + 16);
        pt_error e2 = {0};
        s = st->codec->load(job, body + 24, len - 24, &e2);
        pt_free(data);
        if (s != PT_OK)
            return pt_error_set(err, s, "%s: %s; refusing to use it", p, e2.msg);
        if (!(extra->seconds >= 0) || extra->seconds > 1e12)
            extra->seconds = 0;
    }
    /* A rotated log (results.old) is there when the checkpoint meant to
     * hold it was not written (a crash or a failure): its records come
     * before the current log's. Replay is idempotent, so records the
     * checkpoint already holds change nothing. */
    char old[PATH_MAX], cur[PATH_MAX];
    st_job_path(st, id, "results.old", old, sizeof old);
    st_job_path(st, id, "results.log", cur, sizeof cur);
    int torn_old = 0;
    if ((s = replay_log(old, st->codec, job, extra, replayed, &torn_old, err)) != PT_OK ||
        (s = replay_log(cur, st->codec, job, extra, replayed, torn, err)) != PT_OK)
        return s;
    *torn |= torn_old;
    struct stat sb;
    if (lstat(old, &sb) != 0)
        return PT_OK;
    /* Fold both into a checkpoint now, so that the next rotation finds no
     * results.old in its way. */
    if ((s = st_job_file(st, id, "checkpoint", p, sizeof p, err)) != PT_OK ||
        (s = write_ckpt(p, st->codec, job, extra, "", err)) != PT_OK)
        return s;
    if (unlink(old) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", old);
    if (lstat(cur, &sb) == 0 && sb.st_size > LOG_HEADER && truncate(cur, LOG_HEADER) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s: truncate", cur);
    return PT_OK;
}
