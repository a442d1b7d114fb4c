#include "server/app/mode.h"

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/crypto.h"
#include "common/render/env.h"
#include "common/render/guide_sched.h"
#include "common/render/options.h"
#include "common/render/portal.h"
#include "common/render/render.h"
#include "common/render/tile.h"
#include "common/scene/anim.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "server/api/workers.h"
#include "server/app/local.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

/* ---- one job ----------------------------------------------------------------------- */

/* A frame range's line: frames done, the earliest rendering and its pass. */
static void print_frames_progress(srv_server *s, uint64_t now)
{
    const srv_entry *p = s->single;
    proto_job_info m;
    srv_queue_info(s, p, &m);
    double el = (double)(now - s->t_start) / 1000.0;
    double rate = el > 0 ? (double)m.samples_done / el : 0;
    char eta[32];
    pt_format_eta(rate > 0 ? ((double)m.samples_total - (double)m.samples_done) / rate : -1, eta,
                  sizeof eta);
    const srv_entry *f = srv_frames_at(p, 0);
    fprintf(stderr, "\rptserve: frames %u/%u done, %u rendering", m.frames_done,
            pt_frames_count(&p->rec.frames), m.frames_rendering);
    if (f && f->job)
        fprintf(stderr, "  frame %u pass %u/%u", f->frame, srv_job_passes_done(f->job),
                srv_job_passes(f->job));
    fprintf(stderr, "  %.3g samples/s  %u workers  ETA %s\033[K", rate, s->nworkers, eta);
}

static void print_progress(srv_server *s, uint64_t now)
{
    const srv_entry *j = s->single;
    if (j->frames) {
        print_frames_progress(s, now);
        return;
    }
    const srv_job_params *p = &j->rec.params;
    double el = (double)(now - s->t_start) / 1000.0;
    uint64_t done = srv_job_samples_merged(j->job);
    double total = (double)p->width * p->height * p->spp;
    double rate = el > 0 ? (double)done / el : 0;
    char eta[32];
    pt_format_eta(rate > 0 ? (total - (double)done) / rate : -1, eta, sizeof eta);
    fprintf(stderr, "\rptserve: pass %u/%u  %.1f/%u spp  %.3g samples/s  %u workers  ETA %s\033[K",
            srv_job_passes_done(j->job), srv_job_passes(j->job),
            (double)done / ((double)p->width * p->height), p->spp, rate, s->nworkers, eta);
}

static pt_status setup_single(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    /* An output folder that is missing or not writable fails now, not after
     * the render (a still) or never (a frame range retries its saves): a
     * temporary file is made where the images will go and removed. */
    pt_temp probe;
    if ((st = pt_temp_open(cfg->out_path, 0644, &probe, err)) != PT_OK)
        return st;
    pt_temp_abort(&probe);
    /* So does a map that cannot be opened: it is decoded below, after the
     * scene, but a missing file is known now. */
    if (cfg->env_path) {
        int fd;
        pt_error e = {0};
        if ((st = pt_open_regular(cfg->env_path, 1, &fd, &e)) != PT_OK)
            return pt_error_set(err, st, "--env: %s", e.msg);
        close(fd);
    }
    /* Load once here so a broken scene fails before any worker starts. */
    pt_scene_opts so = {0};
    so.camera_name = cfg->job.camera[0] ? cfg->job.camera : NULL;
    so.variant = cfg->job.variant[0] ? cfg->job.variant : NULL;
    if (cfg->frames.step) {
        /* Posed at the first frame: an animation the scene lacks fails now. */
        so.animate = 1;
        so.time = pt_frames_time(cfg->frames.first, cfg->fps);
        so.animation = cfg->animation;
    }
    pt_scene *scene = NULL;
    pt_anim *anim = NULL;
    /* A range's rig too, to see all its frames' poses (below). */
    st = cfg->frames.step ? pt_anim_load(cfg->scene_path, &so, &scene, &anim, err)
                          : pt_scene_load(cfg->scene_path, &so, &scene, err);
    if (st != PT_OK)
        return st;
    srv_job_params jp = cfg->job;
    if (jp.width == 0) {
        /* 512 wide at the camera's aspect, as a submitted job (server/api/requests.c);
         * the height within --res's cap. */
        jp.width = 512;
        jp.height = pt_camera_height(scene->camera.aspect, jp.width, PT_RENDER_MAX_SIDE);
    }
    /* A range without a camera of the file's is seen from one place that
     * holds every frame's pose; the placement travels as the job's camera. */
    if (cfg->frames.step && !jp.camera[0]) {
        st = pt_anim_range_view(anim, scene, &so, &cfg->frames, cfg->fps,
                                (float)jp.width / (float)jp.height, jp.camera, sizeof jp.camera,
                                err);
        if (st == PT_OK && jp.camera[0])
            srv_log("frames %u-%u are framed together: --camera '%s'", cfg->frames.first,
                    cfg->frames.last, jp.camera);
    }
    pt_anim_free(anim);
    if (st != PT_OK) {
        pt_scene_free(scene);
        return st;
    }
    uint32_t ntris = scene->num_triangles;
    /* A map is decoded once here, as an upload's is, so a bad one fails now
     * with its reason, not on every worker. */
    if (cfg->env_path) {
        pt_env *env = NULL;
        if ((st = pt_env_load(cfg->env_path, jp.env.strength, jp.env.rotate_deg, &env, err)) !=
            PT_OK) {
            pt_scene_free(scene);
            return st;
        }
        pt_env_free(env);
        snprintf(jp.env.name, sizeof jp.env.name, "%s", PT_BUNDLE_ENV_NAME);
    }
    /* Guiding, resolved against the scene as ptworker resolves it, from the
     * bounds ptworker grows (guide_sched.h). */
    if (pt_guide_enabled(cfg->guiding, scene)) {
        pt_vec3 lo = scene->bounds_min, hi = scene->bounds_max;
        pt_guide_grow_bounds(&lo, &hi);
        jp.guiding = 1;
        const float box[6] = {lo.x, lo.y, lo.z, hi.x, hi.y, hi.z};
        memcpy(jp.guide_box, box, sizeof box);
    } else if (cfg->guiding == PT_GUIDING_ON) {
        srv_log("--guiding: every material is Lambert; nothing to guide");
    }
    st = pt_render_check_lit(scene, proto_env_any(&jp.env), cfg->scene_path, err);
    /* --bdpt where it cannot render is refused; without --bdpt or
     * --bdpt=off, auto decides once for the job from the scene
     * (bdpt_auto.h). */
    const int clamped = jp.clamp[0] > 0.0f || jp.clamp[1] > 0.0f;
    int bdpt = 0;
    double share = -1.0;
    if (st == PT_OK &&
        (st = pt_bdpt_resolve(scene, proto_bdpt_of_film(jp.film_flags), proto_env_any(&jp.env),
                              jp.guiding != 0, clamped, &bdpt, &share, err)) == PT_OK &&
        bdpt && !(jp.film_flags & PROTO_FILM_BDPT)) {
        jp.film_flags |= PROTO_FILM_BDPT;
        srv_log(PT_BDPT_AUTO_ON, 100.0 * share);
    }
    char note[512];
    if (st == PT_OK && pt_portal_check_text(scene, note, sizeof note))
        srv_log("%s", note);
    /* Cryptomatte's manifests come from the names of the scene loaded here. */
    pt_crypto_meta *crypto = NULL;
    if (st == PT_OK && (proto_film_passes(jp.film_flags) & PT_PASS_CRYPTOMATTE)) {
        if (!(crypto = pt_calloc(1, sizeof *crypto)))
            st = pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        else if ((st = pt_crypto_meta_init(crypto, scene, err)) != PT_OK) {
            pt_free(crypto);
            crypto = NULL;
        }
    }
    pt_scene_free(scene);
    if (st != PT_OK)
        return st;
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j) {
        if (crypto)
            pt_crypto_meta_fini(crypto);
        pt_free(crypto);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    }
    j->crypto = crypto;
    srv_queue_insert(s, j);
    s->single = j;
    if ((st = pt_bundle_pack_env(cfg->scene_path, cfg->env_path, &j->bundle, err)) != PT_OK)
        return st;
    j->rec.id = j->rec.seq = 1;
    j->rec.state = PROTO_JOB_QUEUED;
    j->rec.error = -1.0;
    j->rec.params = jp;
    pt_hex_decode(j->bundle->hash, j->rec.hash, 32);
    const char *base = strrchr(cfg->scene_path, '/');
    snprintf(j->rec.scene, sizeof j->rec.scene, "%s", base ? base + 1 : cfg->scene_path);
    snprintf(j->out_path, sizeof j->out_path, "%s", cfg->out_path);
    if (cfg->frames.step) {
        j->rec.frames = cfg->frames;
        j->rec.fps = cfg->fps;
        snprintf(j->rec.animation, sizeof j->rec.animation, "%s",
                 cfg->animation ? cfg->animation : "");
    }
    if (!srv_entry_ready(s, j))
        return pt_error_set(err, PT_ERR_IO, "%s", j->rec.message);
    if (!cfg->quiet && cfg->frames.step)
        srv_log("%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u; frames %u-%u:%u "
                "(%u) at %g fps into %s",
                cfg->scene_path, ntris, jp.width, jp.height, jp.spp, srv_job_params_passes(&jp),
                jp.chunk, jp.tile, cfg->frames.first, cfg->frames.last, cfg->frames.step,
                pt_frames_count(&cfg->frames), cfg->fps, cfg->out_path);
    else if (!cfg->quiet)
        srv_log("%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u", cfg->scene_path,
                ntris, jp.width, jp.height, jp.spp, srv_job_passes(j->job), jp.chunk, jp.tile);
    return PT_OK;
}

/* A frame range's end: the frames rendering saved as they are (when
 * interrupted), and the summary. */
static int finish_frames(srv_server *s)
{
    srv_entry *p = s->single;
    pt_error err = {0};
    srv_entry *f;
    for (uint32_t i = 0; (f = srv_frames_at(p, i)); i++)
        if (f->job && srv_entry_active(f)) {
            srv_entry_save_image(f, srv_job_complete(f->job));
            if (srv_writer_flush(f->writer, &err) != PT_OK)
                fprintf(stderr, "\nptserve: cannot write %s: %s", f->out_path, err.msg);
        }
    if (!s->cfg->quiet)
        print_progress(s, pt_now_ms());
    fputc('\n', stderr);
    double secs = (double)(pt_now_ms() - s->t_start) / 1000.0;
    uint32_t count = pt_frames_count(&p->rec.frames);
    if (p->rec.state == PROTO_JOB_DONE) {
        fprintf(stderr,
                "ptserve: done in %.2fs: %u frames, %llu samples (%.4g samples/s); wrote %s\n",
                secs, count, (unsigned long long)p->rec.samples_done,
                (double)p->rec.samples_done / secs, s->cfg->out_path);
        return 0;
    }
    if (p->rec.state == PROTO_JOB_FAILED) {
        fprintf(stderr, "ptserve: %s\n", p->rec.message);
        return 1;
    }
    if (srv_loop_stopped()) {
        fprintf(stderr, "ptserve: interrupted after %.2fs; %u of %u frames done\n", secs,
                p->rec.frames_done + p->rec.ndone_ahead, count);
        return 130;
    }
    return 1;
}

/* The final image and the summary. Returns the exit status. */
static int finish_single(srv_server *s)
{
    const srv_config *cfg = s->cfg;
    srv_entry *j = s->single;
    pt_error err = {0};
    if (j->rec.frames.step)
        return finish_frames(s);
    if (!j->job)
        return 1;
    srv_entry_save_image(j, srv_job_complete(j->job));
    pt_status st = srv_writer_flush(j->writer, &err);
    if (!cfg->quiet)
        print_progress(s, pt_now_ms());
    fputc('\n', stderr);
    double secs = (double)(pt_now_ms() - s->t_start) / 1000.0;
    uint64_t samples = srv_job_samples_merged(j->job);
    const srv_job_params *p = &j->rec.params;
    if (st != PT_OK) {
        fprintf(stderr, "ptserve: cannot write %s: %s\n", cfg->out_path, err.msg);
        return 1;
    }
    if (srv_job_complete(j->job) && samples == 0 && j->rejected > 0) {
        fprintf(stderr,
                "ptserve: every sample was rejected (%llu: NaN or Inf, or workers that rendered "
                "nothing); %s holds no image\n",
                (unsigned long long)j->rejected, cfg->out_path);
        return 1;
    }
    if (srv_job_complete(j->job)) {
        uint64_t tasks = srv_job_tasks_total(j->job);
        fprintf(stderr,
                "ptserve: done in %.2fs: %llu samples (%.4g samples/s), %llu rejected "
                "samples (NaN/Inf); wrote %s\n",
                secs, (unsigned long long)samples, (double)samples / secs,
                (unsigned long long)j->rejected, cfg->out_path);
        if (srv_job_paths_capped(j->job) > 0)
            fprintf(stderr,
                    "ptserve: %llu paths reached the depth cap of %u; raise --max-depth if this "
                    "matters\n",
                    (unsigned long long)srv_job_paths_capped(j->job), cfg->job.max_depth);
        if (srv_job_clamped(j->job) > 0)
            fprintf(stderr,
                    "ptserve: %llu contributions clamped (--clamp-direct %g, --clamp-indirect "
                    "%g)\n",
                    (unsigned long long)srv_job_clamped(j->job), (double)cfg->job.clamp[0],
                    (double)cfg->job.clamp[1]);
        fprintf(stderr,
                "ptserve: wire: %llu bytes in, %llu out (scene %zu); %.3f bytes per "
                "sample, %.0f per task\n",
                (unsigned long long)s->bytes_in, (unsigned long long)s->bytes_out,
                j->bundle ? j->bundle->size : 0,
                (double)(s->bytes_in + s->bytes_out) / (double)samples,
                (double)(s->bytes_in + s->bytes_out) / (double)tasks);
        return 0;
    }
    if (srv_loop_stopped()) {
        fprintf(stderr, "ptserve: interrupted after %.2fs; %s holds %llu of %llu samples\n", secs,
                cfg->out_path, (unsigned long long)samples,
                (unsigned long long)p->width * p->height * p->spp);
        return 130;
    }
    return 1;
}

static int single_over(const srv_server *s)
{
    if (s->single->rec.frames.step)
        return !srv_entry_active(s->single);
    return !s->single->job || srv_job_complete(s->single->job);
}

static void single_after_leases(srv_server *s)
{
    /* Nothing is durable, and the loop ends with a still; a frame range's
     * done frames are written and the next ones started. */
    if (s->single->rec.frames.step && srv_queue_end_complete(s))
        srv_workers_hand_out(s);
}

static void single_tick(srv_server *s, uint64_t now)
{
    if ((s->single->job || s->single->frames) && !s->cfg->quiet && now - s->t_last_print >= 1000) {
        s->t_last_print = now;
        print_progress(s, now);
    }
}

static int single_local_gone(srv_server *s)
{
    if (s->single->rec.frames.step ? !srv_entry_active(s->single)
                                   : srv_job_complete(s->single->job))
        return 0;
    fprintf(stderr, "\nptserve: all %u local workers exited before the image was complete\n",
            s->local->nchildren);
    return 1;
}

static uint64_t single_backlog(const srv_server *s)
{
    (void)s; /* nothing is logged */
    return 0;
}

const srv_mode srv_mode_one_job = {
    .name = "one job",
    .backlog = single_backlog,
    .serves_clients = 0,
    .logs_starts = 0,
    .durable = 0,
    .durability = &srv_durability_none,
    .setup = setup_single,
    .over = single_over,
    .after_leases = single_after_leases,
    .tick = single_tick,
    .local_gone = single_local_gone,
    .finish = finish_single,
};

/* ---- the queue --------------------------------------------------------------------- */

/* The group commit's completions (server/store/state.h) are ready. */
static void on_commits(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    srv_queue_committed(s, 0);
}

static pt_status setup_queue(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    if ((st = srv_state_open(cfg->state_dir, &srv_job_state_codec, &s->state, err)) != PT_OK ||
        (st = srv_loop_add_fd(s, srv_state_commit_fd(s->state), on_commits, NULL, NULL, err)) !=
            PT_OK)
        return st;
    if (cfg->output_dir)
        snprintf(s->out_dir, sizeof s->out_dir, "%s", cfg->output_dir);
    else
        snprintf(s->out_dir, sizeof s->out_dir, "%s/output", cfg->state_dir);
    char tmp[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s/tmp", cfg->state_dir);
    pt_remove_tree(tmp); /* uploads a crash left half-verified */
    if ((st = pt_mkdirs(s->out_dir, 0, err)) != PT_OK || (st = pt_mkdirs(tmp, 1, err)) != PT_OK)
        return st;
    srv_job_record *recs;
    uint32_t n;
    if ((st = srv_state_load_queue(s->state, &recs, &n, &s->next_job_id, err)) != PT_OK)
        return st;
    uint32_t counts[6] = {0};
    for (uint32_t i = 0; i < n; i++) {
        srv_entry *j = pt_calloc(1, sizeof *j);
        if (!j) {
            pt_free(recs);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        j->rec = recs[i];
        snprintf(j->out_path, sizeof j->out_path, "%s/%s", s->out_dir, j->rec.output);
        srv_queue_insert(s, j);
        counts[j->rec.state]++;
    }
    pt_free(recs);
    if (!cfg->quiet || counts[PROTO_JOB_RUNNING] || counts[PROTO_JOB_QUEUED])
        srv_log("state %s: %u jobs queued, %u running, %u ended; images go to %s", cfg->state_dir,
                counts[PROTO_JOB_QUEUED], counts[PROTO_JOB_RUNNING],
                counts[PROTO_JOB_DONE] + counts[PROTO_JOB_CANCELLED] + counts[PROTO_JOB_FAILED],
                s->out_dir);
    /* Resume the running jobs now: their checkpoints are checked at start. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.state == PROTO_JOB_RUNNING) {
            if (j->rec.frames.step)
                srv_frames_forget_done(s, j);
            srv_entry_ready(s, j);
        }
    return PT_OK;
}

/* Every running job checkpointed, its image saved. */
static int finish_queue(srv_server *s)
{
    uint32_t n = 0;
    srv_queue_commit_all(s); /* the results logged are merged first */
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        pt_error err = {0};
        srv_entry_checkpoint(s, j, &err); /* logged; the results log holds the rest */
        srv_entry_save_image(j, srv_job_complete(j->job));
        if (srv_writer_flush(j->writer, &err) != PT_OK)
            srv_log("job %llu: cannot write its image: %s", (unsigned long long)j->rec.id, err.msg);
        n++;
    }
    srv_log("stopped; %u running jobs checkpointed", n);
    return 0;
}

static int queue_over(const srv_server *s)
{
    (void)s; /* until a signal */
    return 0;
}

static void queue_after_leases(srv_server *s)
{
    /* Leases leave first. Then the results logged in this round go to the
     * commit thread, unless a commit is in flight (they join the next one,
     * started when it returns): the loop never waits on the disk, and the
     * results are merged when their commit returns (srv_queue_committed). */
    srv_loop_flush_all(s);
    srv_state_commit_start(s->state);
    if (srv_queue_end_complete(s))
        srv_workers_hand_out(s); /* the workers the ended jobs left waiting */
}

static void queue_tick(srv_server *s, uint64_t now)
{
    (void)s;
    (void)now;
}

static int queue_local_gone(srv_server *s)
{
    if (!s->local_gone_logged) {
        srv_log("all %u local workers exited; waiting for remote ones", s->local->nchildren);
        s->local_gone_logged = 1;
    }
    return 0;
}

/* The records not durable yet, and the decoded results that wait with them. */
static uint64_t queue_backlog(const srv_server *s)
{
    return srv_state_unsynced(s->state) + srv_queue_pending_bytes(s);
}

const srv_mode srv_mode_queue = {
    .name = "queue",
    .backlog = queue_backlog,
    .serves_clients = 1,
    .logs_starts = 1,
    .durable = 1,
    .durability = &srv_durability_folder,
    .setup = setup_queue,
    .over = queue_over,
    .after_leases = queue_after_leases,
    .tick = queue_tick,
    .local_gone = queue_local_gone,
    .finish = finish_queue,
};

const srv_mode *srv_mode_for(const srv_config *cfg)
{
    return cfg->scene_path ? &srv_mode_one_job : &srv_mode_queue;
}
