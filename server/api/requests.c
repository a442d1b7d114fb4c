#include "server/api/requests.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/frames.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/text.h"
#include "common/render/tile.h"
#include "common/scene/scene.h"
#include "protocol/msg.h"
#include "server/api/client.h"
#include "server/api/upload.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/job.h"
#include "server/sched/queue.h"

#define WATCH_MS 1000     /* JOB_INFO to watchers this often */
#define WATCH_TICK_MS 100 /* ... give or take this */
#define MAX_FETCH ((size_t)4 << 30)

static void send_job_info(srv_server *s, srv_conn *c, const srv_entry *j)
{
    srv_client_conn *cl = c->session; /* a ready client's */
    proto_job_info m;
    srv_queue_info(s, j, &m);
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_JOB_INFO, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_job_info(&c->out, &m, NULL), NULL);
    cl->watch_t = pt_now_ms();
    if (!srv_entry_active(j) && cl->watch == j->rec.id)
        cl->watch = 0;
}

void srv_requests_notify_watchers(srv_server *s, const srv_entry *j)
{
    for (srv_conn *c = s->conns; c; c = c->next) {
        const srv_client_conn *cl = srv_client_of(c);
        if (cl && cl->watch == j->rec.id && !c->closing)
            send_job_info(s, c, j);
    }
}

static void fetch_end(srv_conn *c)
{
    srv_client_conn *cl = srv_client_of(c);
    if (!cl)
        return;
    if (cl->fetch)
        close(cl->fetch_fd);
    cl->fetch = 0;
}

void srv_requests_pump_fetch(srv_server *s, srv_conn *c)
{
    uint8_t *chunk = s->fetch_chunk;
    srv_client_conn *cl = srv_client_of(c);
    while (cl && cl->fetch && !c->closing && srv_conn_has_room(c)) {
        proto_scene_chunk ch;
        memcpy(ch.hash, cl->fetch_hash, 32);
        ch.offset = cl->fetch_off;
        ch.total = cl->fetch_len;
        size_t left = cl->fetch_len - cl->fetch_off;
        ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
        /* The open file is the image as it was hashed: the writer renames
         * a new one into place, never writes into this one. */
        ssize_t got = pread(cl->fetch_fd, chunk, ch.len, (off_t)cl->fetch_off);
        if (got != (ssize_t)ch.len) {
            fetch_end(c);
            srv_conn_send_error(s, c, PROTO_E_INTERNAL, "the image could not be read");
            return;
        }
        ch.data = chunk;
        size_t mark;
        pt_status st = proto_frame_begin(&c->out, PROTO_MSG_IMAGE, &mark, NULL);
        if (st == PT_OK)
            st = proto_frame_finish(&c->out, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL),
                                    NULL);
        if (!srv_conn_queued(s, c, st))
            break;
        cl->fetch_off += ch.len;
        if (cl->fetch_off == cl->fetch_len)
            fetch_end(c);
    }
}

/* A file name from untrusted text: [A-Za-z0-9._-] kept, the rest '_', no
 * leading dot, at most 64 characters; "job" when nothing is left. */
static void sanitise(const char *in, char *out, size_t cap)
{
    size_t n = 0;
    for (const char *p = in; *p && n + 1 < cap && n < 64; p++) {
        char ch = *p;
        int ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
                 ch == '-' || ch == '_' || (ch == '.' && n > 0);
        out[n++] = ok ? ch : '_';
    }
    out[n] = '\0';
    if (n == 0)
        snprintf(out, cap, "job");
}

/* Unfinished jobs of one identity (c->name after WELCOME: the
 * --clients-file NAME, not whatever a HELLO declared). */
static uint32_t owner_unfinished(const srv_server *s, const char *owner)
{
    uint32_t n = 0;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        n += srv_entry_active(j) && !j->parent && strcmp(j->rec.owner, owner) == 0;
    return n;
}

/* Uploads in progress or being checked: those of identity name, and all. */
static void count_uploads(const srv_server *s, const char *name, uint32_t *mine, uint32_t *all)
{
    *mine = *all = 0;
    for (const srv_conn *c = s->conns; c; c = c->next) {
        const srv_client_conn *cl = srv_client_of(c);
        if (!c->closing && (c->uploading || (cl && cl->verifying))) {
            (*all)++;
            *mine += strcmp(c->name, name) == 0;
        }
    }
}

/* Checks a SUBMIT's settings against this server's caps and the ranges
 * every renderer takes; 1 when refused (c was sent why). */
static int submit_refused(srv_server *s, srv_conn *c, const proto_submit *m)
{
    const srv_caps *cap = &s->cfg->caps;
    if (m->bundle_size > cap->max_scene) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "scene of %llu bytes is over this server's limit "
                            "of %llu",
                            (unsigned long long)m->bundle_size, (unsigned long long)cap->max_scene);
        return 1;
    }
    if (m->spp > cap->max_spp) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "%u samples per pixel is over this server's limit "
                            "of %u",
                            m->spp, cap->max_spp);
        return 1;
    }
    if (m->width > cap->max_side || m->height > cap->max_side ||
        (uint64_t)m->width * m->height > cap->max_pixels) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "resolution %ux%u is over this server's limit (%u "
                            "per side, %llu pixels)",
                            m->width, m->height, cap->max_side,
                            (unsigned long long)cap->max_pixels);
        return 1;
    }
    uint64_t film = srv_film_bytes(m->width, m->height, m->film_flags);
    if (cap->max_film && film > cap->max_film) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "a %ux%u film%s takes %llu MiB on the coordinator, over this "
                            "server's limit of %llu MiB (ptserve --max-film-mb)",
                            m->width, m->height,
                            proto_film_passes(m->film_flags) ? " with render passes" : "",
                            (unsigned long long)((film + (1u << 20) - 1) >> 20),
                            (unsigned long long)(cap->max_film >> 20));
        return 1;
    }
    if (m->max_depth > PT_RENDER_MAX_DEPTH || (m->min_spp && m->min_spp < 2) ||
        m->min_spp > m->spp) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "max depth %u or min spp %u is out of range",
                            m->max_depth, m->min_spp);
        return 1;
    }
    if (m->target_error > 0.0 && m->min_gain > 0.0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "target error and min gain are two adaptive "
                            "rules; a job takes one");
        return 1;
    }
    /* Guided passes are learned from whole passes of every tile, in one
     * pose (auto leaves guiding off there: server/api/upload.c). */
    if (m->guiding == PROTO_GUIDING_ON && (m->target_error > 0.0 || m->min_gain > 0.0 ||
                                           m->frame_step || m->shutter[1] > m->shutter[0])) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "guiding on does not combine with adaptive sampling, a frame range "
                            "or a shutter yet");
        return 1;
    }
    /* The map must be the one file the bundle keeps for it: the server opens
     * no other path a client names (server/api/upload.c decodes it). */
    if (m->env.name[0] && strcmp(m->env.name, PT_BUNDLE_ENV_NAME) != 0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "environment map '%s': a submitted map must be the bundle's "
                            "'" PT_BUNDLE_ENV_NAME "' (ptctl submit --env puts it there)",
                            m->env.name);
        return 1;
    }
    /* ptworker --scene's and ptserve's ranges for the same options. */
    if (m->env.strength > 1e20f || m->env.rotate_deg < -1e6f || m->env.rotate_deg > 1e6f ||
        m->env.rgb[0] > 1e20f || m->env.rgb[1] > 1e20f || m->env.rgb[2] > 1e20f) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "environment strength %g, rotation %g or background colour is out "
                            "of range (strength and colour <= 1e20, |rotation| <= 1e6)",
                            (double)m->env.strength, (double)m->env.rotate_deg);
        return 1;
    }
    /* A range's shape is the decoder's (pt_frames_check); its rate is
     * ptctl's: a rate of 5e-324 put its frames at an infinite time, which no
     * TASK can carry, and its workers reconnected in a loop. */
    if (m->frame_step && !(m->fps >= PT_FRAMES_MIN_FPS && m->fps <= PT_FRAMES_MAX_FPS)) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%g frames per second is out of range [%g, %g]",
                            m->fps, PT_FRAMES_MIN_FPS, PT_FRAMES_MAX_FPS);
        return 1;
    }
    return 0;
}

static void on_submit(srv_server *s, srv_conn *c, const proto_frame *f)
{
    pt_error err = {0};
    proto_submit m;
    if (c->uploading) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "SUBMIT during an upload");
        return;
    }
    if (!s->mode->durable) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "this coordinator renders one job and takes no SUBMIT (a queue is "
                            "ptserve --state-dir)");
        return;
    }
    if (proto_msg_decode_submit(f->payload, f->len, &m, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SUBMIT: %s", err.msg);
        return;
    }
    if (strchr(m.name, '/') || strchr(m.name, '\\') || m.name[0] == '.' || strstr(m.name, "..")) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "job name '%s' is not a plain name (no '/', "
                            "'\\', '..' or leading '.')",
                            m.name);
        return;
    }
    for (const char *p = m.name; *p; p++)
        if ((unsigned char)*p < 0x20 || *p == 0x7f) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "job name has control characters");
            return;
        }
    const srv_caps *cap = &s->cfg->caps;
    if (submit_refused(s, c, &m))
        return;
    if (owner_unfinished(s, c->name) >= cap->max_queued) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "%s already has %u unfinished jobs, this "
                            "server's limit",
                            c->name, cap->max_queued);
        return;
    }
    if (s->njobs >= SRV_MAX_JOBS) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "the queue is full (%u jobs)", SRV_MAX_JOBS);
        return;
    }
    uint32_t mine, all;
    count_uploads(s, c->name, &mine, &all);
    if (mine >= SRV_MAX_UPLOADS_PER_CLIENT || all >= SRV_MAX_UPLOADS) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "too many uploads in progress (%u of yours, at most %u; %u in all, at "
                            "most %u); try again when one is done",
                            mine, SRV_MAX_UPLOADS_PER_CLIENT, all, SRV_MAX_UPLOADS);
        return;
    }
    char part[PATH_MAX];
    srv_upload_part_path(s, c, part, sizeof part);
    int fd = open(part, O_RDWR | O_CREAT | O_TRUNC | O_NOFOLLOW | O_CLOEXEC, 0600);
    if (fd < 0) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot store the upload: %s", strerror(errno));
        return;
    }
    srv_client_conn *cl = c->session;
    cl->up_fd = fd;
    cl->up_open = 1;
    cl->up = m;
    c->uploading = 1;
    c->up_total = m.bundle_size;
    c->up_len = 0;
    c->t_progress = pt_now_ms();
}

/* A submitted job's params: the server's defaults (tile, chunk, max and RR
 * depth) with what the client asked for; no width: 512 wide at the camera's
 * aspect, the height within the cap. */
static void submitted_params(const srv_config *cfg, const srv_upload *k, srv_job_params *out)
{
    const proto_submit *m = &k->m;
    srv_job_params p = cfg->job;
    p.spp = m->spp;
    p.seed = m->seed;
    if (m->max_depth)
        p.max_depth = m->max_depth;
    p.target_error = m->target_error;
    p.min_gain = m->min_gain;
    p.film_flags = m->film_flags;
    p.min_spp = m->min_spp ? m->min_spp : (p.chunk > 1 ? p.chunk : 2);
    p.width = m->width;
    p.height = m->height;
    snprintf(p.camera, sizeof p.camera, "%s", k->look[0] ? k->look : m->camera);
    snprintf(p.variant, sizeof p.variant, "%s", m->variant);
    p.shutter[0] = m->shutter[0];
    p.shutter[1] = m->shutter[1];
    p.clamp[0] = m->clamp[0];
    p.clamp[1] = m->clamp[1];
    p.guiding = k->guided;
    memcpy(p.guide_box, k->guide_box, sizeof p.guide_box);
    p.env = m->env;
    if (p.width == 0) {
        p.width = 512;
        p.height = pt_camera_height(k->aspect, p.width, cfg->caps.max_side);
    }
    *out = p;
}

/* The image's file name in the output folder: ID-NAME.exr, NAME the job's
 * name or else the scene's without its extension, sanitised. */
static void output_name(srv_job_record *r)
{
    char stem[PROTO_MAX_PATH + 1], safe[80];
    snprintf(stem, sizeof stem, "%s", r->name[0] ? r->name : r->scene);
    char *dot = strrchr(stem, '.');
    if (!r->name[0] && dot && dot != stem)
        *dot = '\0';
    sanitise(stem, safe, sizeof safe);
    if (!r->frames.step) {
        snprintf(r->output, sizeof r->output, "%llu-%s.exr", (unsigned long long)r->id, safe);
        return;
    }
    /* A frame range: ID-NAME.####.exr, as many '#' as its last frame has
     * digits, at least 4 (server/sched/frames.h names each frame's file). */
    char hashes[16];
    int width = snprintf(hashes, sizeof hashes, "%u", r->frames.last);
    width = width < 4 ? 4 : width;
    memset(hashes, '#', (size_t)width);
    hashes[width] = '\0';
    snprintf(r->output, sizeof r->output, "%llu-%s.%s.exr", (unsigned long long)r->id, safe,
             hashes);
}

void srv_requests_verified(srv_server *s, srv_conn *c, srv_upload *k)
{
    pt_error err = {0};
    pt_status st;
    const proto_submit *m = &k->m;
    srv_client_conn *cl = c->session;
    cl->verifying = 0;
    if (!k->ok) {
        srv_conn_send_error(s, c, k->code, "%s", k->msg);
        return;
    }
    pt_bundle *b = k->bundle;
    k->bundle = NULL;
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j) {
        pt_bundle_free(b);
        s->mode->durability->forget(s, k->job_id);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    srv_job_record *r = &j->rec;
    r->id = r->seq = k->job_id;
    r->state = PROTO_JOB_QUEUED;
    r->error = -1.0;
    r->priority = m->priority;
    snprintf(r->name, sizeof r->name, "%s", m->name);
    snprintf(r->owner, sizeof r->owner, "%s", c->name);
    snprintf(r->scene, sizeof r->scene, "%s", k->scene);
    snprintf(r->message, sizeof r->message, "%s", k->note);
    r->submitted = (uint64_t)time(NULL);
    srv_job_params p;
    submitted_params(s->cfg, k, &p);
    uint32_t ntris = k->ntris;
    r->params = p;
    memcpy(r->hash, m->bundle_hash, 32);
    r->bundle_size = b->size;
    r->frames = (pt_frames){m->frame_first, m->frame_last, m->frame_step};
    r->fps = m->fps;
    snprintf(r->animation, sizeof r->animation, "%s", m->animation);
    output_name(r);
    if (k->look[0])
        srv_log("job %llu: frames %u-%u are framed together: --camera '%s'",
                (unsigned long long)r->id, r->frames.first, r->frames.last, k->look);
    snprintf(j->out_path, sizeof j->out_path, "%s/%s", s->out_dir, r->output);
    srv_job *probe = NULL;
    if ((st = srv_job_new(r->id, &p, r->hash, &probe, &err)) != PT_OK) {
        pt_free(j);
        pt_bundle_free(b);
        s->mode->durability->forget(s, k->job_id);
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "%s", err.msg);
        return;
    }
    srv_job_free(probe);
    j->bundle = b;
    srv_queue_insert(s, j);
    srv_queue_prune(s);
    if (srv_queue_journal(s, &err) != PT_OK) {
        /* Not durable, so not accepted. */
        srv_queue_unlink(s, j);
        s->mode->durability->forget(s, r->id);
        srv_entry_free(j);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot write the queue: %s", err.msg);
        return;
    }
    char scene[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_PATH)], range[64] = "";
    if (r->frames.step)
        snprintf(range, sizeof range, ", frames %u-%u:%u at %g fps", r->frames.first,
                 r->frames.last, r->frames.step, r->fps);
    srv_log("job %llu queued from %s: %s (%u triangles), %ux%u, %u spp%s, priority %d",
            (unsigned long long)r->id, c->shown, pt_text_shown(r->scene, scene, sizeof scene),
            ntris, p.width, p.height, p.spp, range, r->priority);
    proto_job_ref ref = {r->id};
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_SUBMITTED, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL), NULL);
}

static void on_upload(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_chunk ch;
    pt_error err = {0};
    srv_client_conn *cl = c->session;
    if (!c->uploading) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "UPLOAD without a SUBMIT");
        return;
    }
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &ch, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad UPLOAD: %s", err.msg);
        return;
    }
    if (memcmp(ch.hash, cl->up.bundle_hash, 32) != 0 || ch.total != c->up_total ||
        ch.offset != c->up_len || ch.len == 0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "UPLOAD of %u bytes at %llu of %llu does not "
                            "continue the announced scene (%zu of %llu bytes so far)",
                            ch.len, (unsigned long long)ch.offset, (unsigned long long)ch.total,
                            c->up_len, (unsigned long long)c->up_total);
        return;
    }
    /* To disk as it arrives (page cache first): no upload is held in
     * memory. A full disk ends the upload with the reason. */
    if (pt_write_all(cl->up_fd, ch.data, ch.len) != 0) {
        int e = errno;
        srv_upload_drop(s, c);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot store the upload: %s", strerror(e));
        return;
    }
    c->up_len += ch.len;
    if (c->up_len == c->up_total)
        srv_upload_start(s, c);
}

static int read_job_ref(srv_server *s, srv_conn *c, const proto_frame *f, srv_entry **out)
{
    proto_job_ref ref;
    pt_error err = {0};
    if (proto_msg_decode_job_ref(f->payload, f->len, &ref, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad %s: %s", proto_msg_type_name(f->type),
                            err.msg);
        return 0;
    }
    *out = srv_queue_find(s, ref.job_id);
    if (!*out) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no job %llu", (unsigned long long)ref.job_id);
        return 0;
    }
    return 1;
}

static void on_list(srv_server *s, srv_conn *c, const proto_frame *f)
{
    if (f->len != 0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad LIST: trailing bytes");
        return;
    }
    uint32_t n = s->njobs < PROTO_MAX_JOBS ? s->njobs : PROTO_MAX_JOBS;
    proto_job_info *infos = pt_malloc_array(n ? n : 1, sizeof *infos);
    if (!infos) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    uint32_t k = 0;
    for (srv_entry *j = s->jobs; j && k < n; j = j->next)
        if (!j->parent) /* a frame: its range shows it */
            srv_queue_info(s, j, &infos[k++]);
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, PROTO_MSG_JOB_LIST, &mark, NULL);
    if (st == PT_OK)
        st = proto_frame_finish(&c->out, mark, proto_msg_encode_job_list(&c->out, infos, k, NULL),
                                NULL);
    srv_conn_queued(s, c, st);
    pt_free(infos);
}

static void on_fetch(srv_server *s, srv_conn *c, srv_entry *j, const char *path)
{
    srv_client_conn *cl = c->session;
    pt_error err = {0};
    if (cl->fetch) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "FETCH while a fetch is in progress");
        return;
    }
    int fd = -1;
    struct stat sb;
    /* Not through a link planted in the output folder, a regular file only;
     * streamed from the open file, so no fetch holds a copy of the image. */
    if (pt_open_regular(path, 0, &fd, &err) != PT_OK) {
        if (err.sys_errno == ENOENT)
            srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "job %llu has no image yet (%s)",
                                (unsigned long long)j->rec.id, proto_job_state_name(j->rec.state));
        else if (err.code == PT_ERR_FORMAT)
            srv_conn_send_error(s, c, PROTO_E_INTERNAL,
                                "job %llu: its image in the output folder is not a regular file "
                                "(a link?); not sent",
                                (unsigned long long)j->rec.id);
        else
            srv_conn_send_error(s, c, PROTO_E_INTERNAL, "%s", err.msg);
        return;
    }
    if (fstat(fd, &sb) != 0 || sb.st_size == 0 || (uint64_t)sb.st_size > MAX_FETCH) {
        close(fd);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "job %llu: its image file is empty or too big",
                            (unsigned long long)j->rec.id);
        return;
    }
    if (pt_sha256_fd(fd, &cl->fetch_hash[0], &err) != PT_OK) {
        close(fd);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "job %llu: its image could not be read",
                            (unsigned long long)j->rec.id);
        return;
    }
    cl->fetch = 1;
    cl->fetch_fd = fd;
    cl->fetch_len = (size_t)sb.st_size;
    cl->fetch_off = 0;
    srv_requests_pump_fetch(s, c);
}

static void on_fetch_frame(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_fetch_frame m;
    pt_error err = {0};
    if (proto_msg_decode_fetch_frame(f->payload, f->len, &m, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad FETCH_FRAME: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find(s, m.job_id);
    if (!j) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no job %llu", (unsigned long long)m.job_id);
        return;
    }
    if (!j->rec.frames.step) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND,
                            "job %llu is a still, not a frame range (fetch it without --frame)",
                            (unsigned long long)m.job_id);
        return;
    }
    char path[PATH_MAX];
    if (srv_frames_path(j, m.frame, path, sizeof path, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "%s", err.msg);
        return;
    }
    on_fetch(s, c, j, path);
}

/* 1 when c may change job j (cancel it): c owns it or is an admin (every
 * client is, without --clients-file). Otherwise c is told whose job it is
 * and closed, and it returns 0. */
static int may_change(srv_server *s, srv_conn *c, const srv_entry *j, const char *verb)
{
    if (srv_queue_may_change(j, c->name, c->admin))
        return 1;
    srv_conn_send_error(s, c, PROTO_E_DENIED,
                        "job %llu belongs to %s: only its owner or an admin (the shared "
                        "token) may %s it, and you are %s",
                        (unsigned long long)j->rec.id, j->rec.owner, verb, c->name);
    return 0;
}

void srv_requests_dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    srv_entry *j;
    srv_client_conn *cl = c->session;
    if (cl->verifying) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s before the answer to its SUBMIT",
                            proto_msg_type_name(f->type));
        return;
    }
    switch (f->type) {
    case PROTO_MSG_SUBMIT:
        on_submit(s, c, f);
        break;
    case PROTO_MSG_UPLOAD:
        on_upload(s, c, f);
        break;
    case PROTO_MSG_LIST:
        on_list(s, c, f);
        break;
    case PROTO_MSG_STATUS:
        if (read_job_ref(s, c, f, &j))
            send_job_info(s, c, j);
        break;
    case PROTO_MSG_WATCH:
        if (read_job_ref(s, c, f, &j)) {
            cl->watch = j->rec.id;
            send_job_info(s, c, j);
        }
        break;
    case PROTO_MSG_CANCEL:
        if (read_job_ref(s, c, f, &j) && may_change(s, c, j, "cancel")) {
            srv_queue_cancel(s, j, c->name);
            send_job_info(s, c, j);
        }
        break;
    case PROTO_MSG_FETCH:
        if (read_job_ref(s, c, f, &j)) {
            char path[PATH_MAX];
            /* A frame range's latest image: the earliest frame rendering, or
             * the last one done (FETCH_FRAME names one). */
            if (j->rec.frames.step)
                srv_frames_latest(j, path, sizeof path);
            else
                snprintf(path, sizeof path, "%s", j->out_path);
            on_fetch(s, c, j, path);
        }
        break;
    case PROTO_MSG_FETCH_FRAME:
        on_fetch_frame(s, c, f);
        break;
    case PROTO_MSG_ERROR:
        srv_conn_peer_error(s, c, f, "client");
        break;
    default:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a client",
                            proto_msg_type_name(f->type));
    }
}

void srv_requests_tick(srv_server *s, uint64_t now)
{
    /* A walk over every connection: every WATCH_TICK_MS, not every round (a
     * farm's loop turns thousands of rounds a second over its workers). */
    if (now - s->t_watch < WATCH_TICK_MS && now >= s->t_watch)
        return;
    s->t_watch = now;
    for (srv_conn *c = s->conns; c; c = c->next) {
        srv_client_conn *cl = srv_client_of(c);
        if (!cl || c->closing || !cl->watch || now - cl->watch_t < WATCH_MS)
            continue;
        srv_entry *j = srv_queue_find(s, cl->watch);
        if (j)
            send_job_info(s, c, j);
        else
            cl->watch = 0;
    }
}

void srv_requests_conn_gone(srv_server *s, srv_conn *c)
{
    if (c->uploading)
        srv_log("client %s left during an upload (%zu of %llu bytes); nothing was queued", c->shown,
                c->up_len, (unsigned long long)c->up_total);
    srv_upload_drop(s, c);
    fetch_end(c);
    pt_free(c->session);
    c->session = NULL;
}

static void *open_client(srv_server *s, srv_conn *c)
{
    (void)s;
    (void)c;
    return pt_calloc(1, sizeof(srv_client_conn));
}

const srv_session srv_requests_session = {
    .open = open_client,
    .on_frame = srv_requests_dispatch,
    .on_gone = srv_requests_conn_gone,
};
