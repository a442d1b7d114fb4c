#define _GNU_SOURCE /* pipe2 */
#include "server/api/upload.h"

#include <fcntl.h>
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/frames.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/crypto.h"
#include "common/render/env.h"
#include "common/render/guide_sched.h"
#include "common/render/options.h"
#include "common/render/portal.h"
#include "common/render/render.h"
#include "common/scene/anim.h"
#include "common/scene/scene.h"
#include "server/api/client.h"
#include "server/log.h"
#include "server/net/loop.h"
#include "server/store/state.h"

static void verify_refuse(srv_upload *k, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void verify_refuse(srv_upload *k, uint16_t code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(k->msg, sizeof k->msg, fmt, ap);
    va_end(ap);
    k->code = code;
    k->ok = 0;
}

/* Removes every "dir/" from msg and calls dir itself "upload", so that a
 * message about the unpacked bundle names its files as the bundle does
 * ("scene.gltf: ..."), never by this server's paths. The loader names
 * external files by their URIs only (common/scene/gltf_import.cpp); this
 * covers the entry file and anything that names the folder. */
static void strip_folder(char *msg, const char *dir)
{
    static const char name[] = "upload";
    size_t dl = strlen(dir);
    char *p = msg;
    if (dl <= sizeof name)
        return;
    while ((p = strstr(p, dir)) != NULL) {
        if (p[dl] == '/') {
            memmove(p, p + dl + 1, strlen(p + dl + 1) + 1);
        } else {
            memcpy(p, name, sizeof name - 1);
            memmove(p + sizeof name - 1, p + dl, strlen(p + dl) + 1);
            p += sizeof name - 1;
        }
    }
}

/* The verification itself, on its own thread: touches nothing of the server's. */
static void verify_upload(srv_upload *k)
{
    pt_error err = {0};
    char hex[65], want[65];
    /* Read here, by one of the few check threads: while it arrived, the
     * upload was on disk only. */
    pt_status rd = pt_read_file(k->part, (size_t)k->m.bundle_size, &k->data, &k->len, &err);
    unlink(k->part);
    if (rd != PT_OK || k->len != k->m.bundle_size) {
        verify_refuse(k, PROTO_E_INTERNAL, "cannot read the stored upload back");
        return;
    }
    pt_sha256_hex(k->data, k->len, hex);
    pt_hash_hex(k->m.bundle_hash, want);
    if (strcmp(hex, want) != 0) {
        verify_refuse(k, PROTO_E_PROTOCOL,
                      "the scene's SHA-256 is %.16s..., not the %.16s... "
                      "SUBMIT announced",
                      hex, want);
        return;
    }
    pt_status st = pt_bundle_from_bytes(k->data, k->len, &k->bundle, &err);
    pt_free(k->data);
    k->data = NULL;
    if (st != PT_OK) {
        verify_refuse(k, PROTO_E_PROTOCOL, "bad scene bundle: %s", err.msg);
        return;
    }
    const proto_env *ev = &k->m.env;
    /* SUBMIT named PT_BUNDLE_ENV_NAME (server/api/requests.c); it is read at the
     * bundle's top, which is the entry file's folder, where workers look. */
    if (ev->name[0] &&
        (!pt_bundle_has_file(k->bundle, ev->name, NULL) || !pt_bundle_entry_at_top(k->bundle))) {
        verify_refuse(k, PROTO_E_PROTOCOL,
                      "environment map refused: the bundle holds no '%s' beside its entry file",
                      ev->name);
        return;
    }
    char entry[PATH_MAX], env_path[PATH_MAX + 32];
    pt_remove_tree(k->tmp);
    pt_scene *scene = NULL;
    const char *what = "scene refused";
    st = pt_bundle_unpack(k->bundle, k->tmp, entry, sizeof entry, &err);
    if (st == PT_OK) {
        pt_scene_opts so = {0};
        so.camera_name = k->m.camera[0] ? k->m.camera : NULL;
        /* An unknown variant fails the load, naming the scene's variants. */
        so.variant = k->m.variant[0] ? k->m.variant : NULL;
        /* A frame range is loaded posed at its first frame, so an animation
         * the scene lacks is refused here, naming the scene's animations. */
        if (k->m.frame_step) {
            so.animate = 1;
            so.time = pt_frames_time(k->m.frame_first, k->m.fps);
            so.animation = k->m.animation[0] ? k->m.animation : NULL;
        }
        pt_anim *anim = NULL;
        st = k->m.frame_step ? pt_anim_load(entry, &so, &scene, &anim, &err)
                             : pt_scene_load(entry, &so, &scene, &err);
        /* A range without a camera of the file's is seen from one place
         * that holds every frame's pose (its size as the job's will be:
         * given, or 512 wide at a framed view's aspect, square). */
        if (st == PT_OK && k->m.frame_step && !k->m.camera[0]) {
            pt_frames fr = {k->m.frame_first, k->m.frame_last, k->m.frame_step};
            float aspect =
                k->m.width && k->m.height ? (float)k->m.width / (float)k->m.height : 1.0f;
            st = pt_anim_range_view(anim, scene, &so, &fr, k->m.fps, aspect, k->look,
                                    sizeof k->look, &err);
        }
        pt_anim_free(anim);
    }
    if (st == PT_OK && ev->name[0]) {
        /* Decoded whole, every texel checked (common/image/envmap.h), so a
         * missing, truncated, non-image or absurd map is refused here, not
         * by every worker. The file is the bundle's own, just unpacked. */
        pt_env *env = NULL;
        snprintf(env_path, sizeof env_path, "%s/%s", k->tmp, ev->name);
        st = pt_env_load(env_path, ev->strength, ev->rotate_deg, &env, &err);
        pt_env_free(env);
        if (st != PT_OK)
            what = "environment map refused";
    }
    if (st == PT_OK && (st = pt_render_check_lit(scene, proto_env_any(ev), entry, &err)) != PT_OK)
        what = "scene refused";
    /* --bdpt where it cannot render (guiding as the job would resolve it,
     * below): refused here, not by every worker. Without --bdpt or
     * --bdpt=off, auto decides once for the job from the scene
     * (bdpt_auto.h): the job holds the answer from here on, in its
     * checkpoint too. */
    const int guided = pt_guide_enabled(k->m.guiding, scene);
    const int clamped = k->m.clamp[0] > 0.0f || k->m.clamp[1] > 0.0f;
    int bdpt = 0;
    double share = -1.0;
    if (st == PT_OK &&
        (st = pt_bdpt_resolve(scene, proto_bdpt_of_film(k->m.film_flags), proto_env_any(ev), guided,
                              clamped, &bdpt, &share, &err)) != PT_OK)
        what = "job refused";
    else if (st == PT_OK && bdpt && !(k->m.film_flags & PROTO_FILM_BDPT)) {
        k->m.film_flags |= PROTO_FILM_BDPT;
        srv_log("job %" PRIu64 ": " PT_BDPT_AUTO_ON, k->job_id, 100.0 * share);
    }
    /* A warning the job keeps as its message, which status shows its
     * client; a check that could not run is logged only. */
    int said = st == PT_OK ? pt_portal_check_text(scene, k->note, sizeof k->note) : 0;
    if (said)
        srv_log("job %" PRIu64 ": %s", k->job_id, k->note);
    if (said < 0)
        k->note[0] = '\0';
    pt_remove_tree(k->tmp);
    if (st != PT_OK) {
        pt_scene_free(scene);
        /* The client learns of its own files only: names inside the bundle. */
        strip_folder(err.msg, k->tmp);
        verify_refuse(k, st == PT_ERR_NOMEM ? PROTO_E_INTERNAL : PROTO_E_PROTOCOL, "%s: %s", what,
                      err.msg);
        return;
    }
    const char *base = strrchr(entry, '/');
    snprintf(k->scene, sizeof k->scene, "%.255s", base ? base + 1 : entry);
    k->ntris = scene->num_triangles;
    k->aspect = scene->camera.aspect;
    /* Guiding as ptworker resolves it (options.h), and the bounds it grows
     * (guide_sched.h); never with adaptive sampling, a range or a shutter. */
    const proto_submit *sm = &k->m;
    if (pt_guide_enabled(sm->guiding, scene) && !(sm->target_error > 0.0) &&
        !(sm->min_gain > 0.0) && !sm->frame_step && !(sm->shutter[1] > sm->shutter[0])) {
        pt_vec3 lo = scene->bounds_min, hi = scene->bounds_max;
        pt_guide_grow_bounds(&lo, &hi);
        const float box[6] = {lo.x, lo.y, lo.z, hi.x, hi.y, hi.z};
        k->guided = 1;
        memcpy(k->guide_box, box, sizeof box);
    }
    /* Cryptomatte's manifests name the scene's objects and materials, which
     * the coordinator only knows here: kept beside the bundle for the job's
     * writer. */
    char *manifests = NULL;
    if (proto_film_passes(k->m.film_flags) & PT_PASS_CRYPTOMATTE) {
        pt_crypto_meta cm;
        st = pt_crypto_meta_init(&cm, scene, &err);
        if (st == PT_OK) {
            st = pt_crypto_meta_text(&cm, &manifests, &err);
            pt_crypto_meta_fini(&cm);
        }
        if (st == PT_OK)
            st = srv_state_save_manifests(k->state, k->job_id, manifests, &err);
        pt_free(manifests);
        if (st != PT_OK) {
            pt_scene_free(scene);
            verify_refuse(k, PROTO_E_INTERNAL, "cannot store the Cryptomatte manifests: %s",
                          err.msg);
            return;
        }
    }
    pt_scene_free(scene);
    st = srv_state_save_bundle(k->state, k->job_id, k->bundle->data, k->bundle->size, &err);
    if (st != PT_OK) {
        verify_refuse(k, PROTO_E_INTERNAL, "cannot store the scene: %s", err.msg);
        return;
    }
    k->ok = 1;
}

static void *verify_thread(void *arg)
{
    srv_upload *k = arg;
    verify_upload(k);
    /* A blocking write of a pointer: atomic (under PIPE_BUF), never lost. */
    ssize_t r = write(k->wake_fd, &k, sizeof k);
    (void)r;
    return NULL;
}

static void upload_free(srv_upload *k)
{
    unlink(k->part); /* gone already once its check read it */
    pt_free(k->data);
    pt_bundle_free(k->bundle);
    pt_free(k);
}

/* Starts k's check on a thread of its own; the client is answered at
 * once when it cannot start. */
static void start_check(srv_server *s, srv_upload *k)
{
    k->next = s->verifications;
    s->verifications = k;
    if (pthread_create(&k->thread, NULL, verify_thread, k) != 0) {
        s->verifications = k->next;
        srv_conn *c = srv_conn_find(s, k->conn_id);
        if (c) {
            srv_client_conn *cl = srv_client_of(c);
            if (cl)
                cl->verifying = 0;
            srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot start checking the scene");
        }
        upload_free(k);
        return;
    }
    s->checks_running++;
}

void srv_upload_part_path(const srv_server *s, const srv_conn *c, char *out, size_t n)
{
    snprintf(out, n, "%s/tmp/part-%llu", srv_state_dir(s->state), (unsigned long long)c->id);
}

void srv_upload_drop(srv_server *s, srv_conn *c)
{
    srv_client_conn *cl = srv_client_of(c);
    if (cl && cl->up_open) {
        char part[PATH_MAX];
        srv_upload_part_path(s, c, part, sizeof part);
        close(cl->up_fd);
        unlink(part);
        cl->up_open = 0;
    }
    c->up_len = 0;
    c->up_total = 0;
    c->uploading = 0;
}

void srv_upload_start(srv_server *s, srv_conn *c)
{
    srv_client_conn *cl = c->session; /* a ready client's upload */
    srv_upload *k = pt_calloc(1, sizeof *k);
    if (!k) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    k->conn_id = c->id;
    k->job_id = s->next_job_id++;
    k->m = cl->up;
    /* The upload's file becomes the check's: renamed, so the connection's
     * end (srv_upload_drop) no longer removes it. */
    char part[PATH_MAX];
    srv_upload_part_path(s, c, part, sizeof part);
    snprintf(k->part, sizeof k->part, "%s/tmp/bundle-%llu", srv_state_dir(s->state),
             (unsigned long long)k->job_id);
    int moved = rename(part, k->part) == 0;
    srv_upload_drop(s, c);
    if (!moved) {
        k->part[0] = '\0';
        upload_free(k);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot keep the upload for its check");
        return;
    }
    k->state = s->state;
    snprintf(k->tmp, sizeof k->tmp, "%s/tmp/upload-%llu", srv_state_dir(s->state),
             (unsigned long long)k->job_id);
    k->wake_fd = s->verifypipe[1];
    cl->verifying = 1;
    if (s->checks_running < SRV_MAX_SCENE_CHECKS) {
        start_check(s, k);
        return;
    }
    srv_upload **q = &s->checks_waiting;
    while (*q)
        q = &(*q)->next;
    *q = k;
    srv_log("the scene of job %llu waits to be checked: %u checks run at once",
            (unsigned long long)k->job_id, SRV_MAX_SCENE_CHECKS);
}

void srv_upload_collect(srv_server *s)
{
    srv_upload *k;
    while (read(s->verifypipe[0], &k, sizeof k) == (ssize_t)sizeof k) {
        pthread_join(k->thread, NULL);
        for (srv_upload **q = &s->verifications; *q; q = &(*q)->next)
            if (*q == k) {
                *q = k->next;
                break;
            }
        s->checks_running--;
        srv_conn *c = srv_conn_find(s, k->conn_id);
        if (c) {
            s->verified(s, c, k);
        } else {
            if (k->ok)
                srv_state_forget_job(s->state, k->job_id);
            srv_log("a client left before its scene was checked; nothing was queued");
        }
        upload_free(k);
    }
    /* The next waiting checks; a client gone meanwhile is not checked. */
    while (s->checks_waiting && s->checks_running < SRV_MAX_SCENE_CHECKS) {
        srv_upload *w = s->checks_waiting;
        s->checks_waiting = w->next;
        if (!srv_conn_find(s, w->conn_id)) {
            srv_log("a client left before its scene was checked; nothing was queued");
            upload_free(w);
            continue;
        }
        start_check(s, w);
    }
}

void srv_upload_close(srv_server *s)
{
    while (s->checks_waiting) {
        srv_upload *w = s->checks_waiting;
        s->checks_waiting = w->next;
        upload_free(w);
    }
    while (s->verifications) {
        srv_upload *k = s->verifications;
        s->verifications = k->next;
        pthread_join(k->thread, NULL);
        if (k->ok)
            srv_state_forget_job(s->state, k->job_id);
        upload_free(k);
    }
    for (int i = 0; i < 2; i++)
        if (s->verifypipe[i] >= 0)
            close(s->verifypipe[i]);
    s->verifypipe[0] = s->verifypipe[1] = -1;
}

/* The verification pipe is readable (its srv_loop_source's function). */
static void on_verified(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    srv_upload_collect(s);
}

pt_status srv_upload_open(srv_server *s, srv_verified_fn verified, pt_error *err)
{
    s->verified = verified;
    /* The threads' end blocks (a pointer is never lost); the loop's does not. */
    if (pipe2(s->verifypipe, O_CLOEXEC) != 0 ||
        fcntl(s->verifypipe[0], F_SETFL, fcntl(s->verifypipe[0], F_GETFL) | O_NONBLOCK) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    return srv_loop_add_fd(s, s->verifypipe[0], on_verified, NULL, NULL, err);
}
