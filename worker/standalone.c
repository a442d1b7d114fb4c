#include "worker/standalone.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/fsutil.h"
#include "common/image/denoise.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/render/adaptive.h"
#include "common/render/bdpt_auto.h"
#include "common/render/denoise_frame.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/guide_run.h"
#include "common/render/options.h"
#include "common/render/passes.h"
#include "common/render/portal.h"
#include "common/render/render.h"
#include "common/render/tile.h"
#include "common/scene/scene.h"

typedef struct job {
    const wrk_standalone_opts *o;
    const pt_renderer *r;
    pt_film *film;
    pt_rect *tiles;
    uint32_t num_tiles;
    atomic_uint next_tile;
    atomic_uint tiles_done;
    atomic_uint running;       /* render threads not yet finished */
    atomic_uint tiles_stopped; /* by adaptive sampling */
    atomic_uint_fast64_t samples_done;
    pt_render_stats *thread_stats; /* one per thread, summed at the end */
    /* Path guiding (--guiding on): the pass's samples [pass0, pass1) of
     * every tile, each thread guided by gd[thread] (its own statistics). */
    const pt_render_guiding *gd;
    uint32_t pass0, pass1;
} job;

typedef struct thread_arg {
    job *j;
    uint32_t index;
} thread_arg;

/* sum += chunk, pixel by pixel, and the passes' sums too (psum NULL: none). */
static void add_chunk(pt_pixel_acc *sum, const pt_pixel_acc *chunk, pt_pass_acc *psum,
                      const pt_pass_acc *pchunk, uint32_t npx)
{
    for (uint32_t i = 0; i < npx; i++)
        pt_pixel_acc_add(&sum[i], &chunk[i]);
    for (uint32_t i = 0; psum && i < npx; i++)
        pt_pass_acc_add(&psum[i], &pchunk[i]);
}

static void *render_thread(void *p)
{
    thread_arg *a = p;
    job *j = a->j;
    uint32_t max_px = j->o->tile * j->o->tile;
    /* The coordinator's rule (server/sched/job.c), on the same sums. */
    const pt_adaptive rule = {j->o->target_error, j->o->min_gain, j->o->min_spp};
    pt_pixel_acc *chunk = pt_malloc_array(max_px, sizeof *chunk);
    pt_pixel_acc *sum = pt_malloc_array(max_px, sizeof *sum);
    /* The passes' sums beside the beauty's, when asked for. */
    int passes = j->o->passes != 0;
    pt_pass_acc *pchunk = passes ? pt_malloc_array(max_px, sizeof *pchunk) : NULL;
    pt_pass_acc *psum = passes ? pt_malloc_array(max_px, sizeof *psum) : NULL;
    if (!chunk || !sum || (passes && (!pchunk || !psum))) {
        /* Reported by the main thread as a missing tile count. */
        pt_free(pchunk);
        pt_free(psum);
        pt_free(chunk);
        pt_free(sum);
        atomic_fetch_sub(&j->running, 1);
        return NULL;
    }
    for (;;) {
        uint32_t t = atomic_fetch_add(&j->next_tile, 1);
        if (t >= j->num_tiles)
            break;
        pt_rect rc = j->tiles[t];
        uint32_t tw = rc.x1 - rc.x0, npx = tw * (rc.y1 - rc.y0);
        memset(sum, 0, npx * sizeof *sum);
        if (psum)
            memset(psum, 0, npx * sizeof *psum);
        if (j->gd) {
            /* A guided pass: its samples in chunks, no adaptive stop. */
            for (uint32_t s0 = j->pass0; s0 < j->pass1; s0 += j->o->chunk) {
                uint32_t s1 = s0 + j->o->chunk < j->pass1 ? s0 + j->o->chunk : j->pass1;
                pt_render_tile_passes(j->r, rc, s0, s1, chunk, pchunk, &j->thread_stats[a->index],
                                      &j->gd[a->index]);
                add_chunk(sum, chunk, psum, pchunk, npx);
                atomic_fetch_add(&j->samples_done, (uint64_t)npx * (s1 - s0));
            }
            pt_film_add_tile_passes(j->film, rc, sum, psum);
            atomic_fetch_add(&j->tiles_done, 1);
            continue;
        }
        for (uint32_t s0 = 0; s0 < j->o->spp; s0 += j->o->chunk) {
            uint32_t s1 = s0 + j->o->chunk < j->o->spp ? s0 + j->o->chunk : j->o->spp;
            pt_render_tile_passes(j->r, rc, s0, s1, chunk, pchunk, &j->thread_stats[a->index],
                                  NULL);
            add_chunk(sum, chunk, psum, pchunk, npx);
            atomic_fetch_add(&j->samples_done, (uint64_t)npx * (s1 - s0));
            if (s1 < j->o->spp && pt_tile_stops(sum, tw, chunk, tw, tw, rc.y1 - rc.y0, s1, &rule)) {
                atomic_fetch_add(&j->samples_done, (uint64_t)npx * (j->o->spp - s1));
                atomic_fetch_add(&j->tiles_stopped, 1);
                break;
            }
        }
        pt_film_add_tile_passes(j->film, rc, sum, psum);
        atomic_fetch_add(&j->tiles_done, 1);
    }
    pt_free(pchunk);
    pt_free(psum);
    pt_free(chunk);
    pt_free(sum);
    atomic_fetch_sub(&j->running, 1);
    return NULL;
}

/* 1 when a file can be written at path: a temporary is made beside it and
 * removed, as the final write will make one (so the folder exists, is a
 * folder and is writable); else says why on stderr. */
static int writable(const char *what, const char *path)
{
    pt_temp t;
    pt_error err = {0};
    if (pt_temp_open(path, 0644, &t, &err) != PT_OK) {
        fprintf(stderr, "ptworker: %s %s: cannot be written: %s\n", what, path, err.msg);
        return 0;
    }
    pt_temp_abort(&t);
    return 1;
}

/* Whatever would fail once the image is rendered is checked before the
 * scene is loaded: the output's format (by its name), that it and its PNG
 * preview can be written, that the environment map can be read. A render
 * of 40 minutes is not lost to a folder that does not exist. Returns 0, or
 * the exit status: 2 for a name of no known format, 1 for the rest. */
static int check_before(const wrk_standalone_opts *o)
{
    if (pt_image_format_of(o->out_path) == PT_IMAGE_FORMAT_NONE) {
        fprintf(stderr, "ptworker: -o %s: " PT_IMAGE_FORMATS "\n", o->out_path);
        return 2;
    }
    if (!writable("-o", o->out_path))
        return 1;
    if (pt_image_format_of(o->out_path) == PT_IMAGE_FORMAT_EXR) {
        char png[4096];
        pt_png_preview_path(o->out_path, png, sizeof png);
        if (!writable("the preview", png))
            return 1;
    }
    if (o->env_path) {
        int fd;
        pt_error err = {0};
        if (pt_open_regular(o->env_path, 1, &fd, &err) != PT_OK) {
            fprintf(stderr, "ptworker: --env: %s\n", err.msg);
            return 1;
        }
        close(fd);
    }
    return 0;
}

/* Starts n render threads on j, prints progress towards total samples (out
 * of j->samples_done, since t_render) until they end, and joins them.
 * Returns the threads started (0: none could be). */
static uint32_t run_threads(job *j, uint32_t n, pthread_t *threads, thread_arg *args,
                            uint64_t total, double t_render, double *last_print)
{
    atomic_store(&j->next_tile, 0);
    atomic_store(&j->running, n);
    uint32_t started = 0;
    for (; started < n; started++) {
        args[started] = (thread_arg){j, started};
        if (pthread_create(&threads[started], NULL, render_thread, &args[started]) != 0)
            break;
    }
    atomic_fetch_sub(&j->running, n - started);
    if (started == 0)
        return 0;
    while (atomic_load(&j->running) > 0) {
        struct timespec ts = {0, 100 * 1000 * 1000};
        nanosleep(&ts, NULL);
        double el = pt_now_s() - t_render;
        if (!j->o->quiet && el - *last_print >= 1.0) {
            *last_print = el;
            uint64_t done_s = atomic_load(&j->samples_done);
            double rate = done_s / el;
            char eta[32];
            pt_format_eta(rate > 0 ? (double)(total - done_s) / rate : -1, eta, sizeof eta);
            fprintf(stderr, "\rptworker: %5.1f%%  %.2f spp  %.3g samples/s  ETA %s   ",
                    100.0 * (double)done_s / (double)total,
                    (double)done_s * (double)j->o->spp / (double)total, rate, eta);
        }
    }
    for (uint32_t i = 0; i < started; i++)
        pthread_join(threads[i], NULL);
    return started;
}

/* --denoise on a thread of its own, while the progress line runs
 * (pt_run_reported). */
typedef struct denoise_job {
    pt_image *img;
    unsigned threads;
    pt_denoise_frame_opts o;
    float **den;
    uint32_t side;
    pt_error *err;
    pt_status st;
} denoise_job;

static int denoise_run(void *arg)
{
    denoise_job *j = arg;
    j->st = pt_denoise_frame_until(j->img, j->threads, &j->o, j->den, &j->side, j->err);
    return 0;
}

/* Renders every pass of a guided image (--guiding on): pass 0 records into
 * statistics of a uniform guide without sampling it; each later pass samples
 * the guide built from the pass before, PT_GUIDE_PASS_PROB of a guided
 * vertex's directions from it. Returns 0, or -1 after printing why. */
static int run_guided(job *j, const pt_scene *scene, uint32_t n, pthread_t *threads,
                      thread_arg *args, uint64_t total, double t_render, uint32_t *passes)
{
    pt_error err = {0};
    pt_guide_run run;
    double last_print = 0.0;
    int rc = -1;
    pt_status st =
        pt_guide_run_new(&run, scene->bounds_min, scene->bounds_max, j->o->spp, n, 0, &err);
    while (st == PT_OK && (st = pt_guide_run_begin(&run, &err)) == PT_OK && run.s0 < run.spp) {
        j->gd = run.gd;
        j->pass0 = run.s0;
        j->pass1 = run.s1;
        if (run_threads(j, n, threads, args, total, t_render, &last_print) != n) {
            fprintf(stderr, "ptworker: cannot start render threads\n");
            goto done;
        }
        st = pt_guide_run_merge(&run, &err);
        if (st == PT_OK)
            st = pt_guide_run_end(&run, NULL, &err);
    }
    if (st != PT_OK) {
        fprintf(stderr, "ptworker: guiding: %s\n", err.msg);
        goto done;
    }
    *passes = run.pass;
    rc = 0;
done:
    pt_guide_run_free(&run);
    j->gd = NULL;
    return rc;
}

int wrk_standalone_run(const wrk_standalone_opts *o)
{
    pt_error err = {0};
    pt_scene *scene = NULL;
    pt_renderer *r = NULL;
    pt_film *film = NULL;
    pt_env *env = NULL;
    pt_image *img = NULL;
    pt_rect *tiles = NULL;
    pthread_t *threads = NULL;
    thread_arg *args = NULL;
    pt_render_stats *tstats = NULL;
    pt_pass_planes planes;
    pt_crypto_meta cmeta = {0};
    int rc = 1;
    double t0 = pt_now_s();
    int early = check_before(o);
    if (early)
        return early;

    pt_scene_opts so = {0};
    so.camera_name = o->camera;
    so.variant = o->variant;
    so.animate = o->animate;
    so.time = o->time;
    so.animation = o->animation;
    if (o->has_shutter && (o->shutter[0] > 0.0 || o->shutter[1] > 0.0)) {
        /* The frame at o->time (0 without --time or --frame), its shutter in
         * seconds of animation; the still is the pose at the opening (a
         * closed shutter, open == close, is that still alone). */
        so.animate = 1;
        so.shutter_open = o->time + o->shutter[0] / o->fps;
        so.shutter_close = o->time + o->shutter[1] / o->fps;
        so.time = so.shutter_open;
    }
    if (pt_scene_load(o->scene_path, &so, &scene, &err) != PT_OK) {
        fprintf(stderr, "ptworker: %s\n", err.msg);
        goto done;
    }
    if (o->has_shutter && o->shutter[1] > o->shutter[0] && !(scene->features & PT_FEAT_MOTION) &&
        !o->quiet)
        fprintf(stderr, "ptworker: --shutter: nothing in the scene moves while the shutter is "
                        "open; the image is the still\n");
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = o->width;
    p.height = o->height;
    if (p.width == 0) {
        /* The --res cap bounds a height from an extreme aspect too. */
        p.width = 512;
        p.height = pt_camera_height(scene->camera.aspect, p.width, PT_RENDER_MAX_SIDE);
    }
    p.seed = o->seed;
    p.max_depth = o->max_depth;
    if (o->env_path) {
        if (pt_env_load(o->env_path, o->env_strength, o->env_rotate, &env, &err) != PT_OK) {
            fprintf(stderr, "ptworker: --env: %s\n", err.msg);
            goto done;
        }
    } else if (o->has_background &&
               pt_env_uniform(pt_v3(o->background[0], o->background[1], o->background[2]), &env,
                              &err) != PT_OK) {
        fprintf(stderr, "ptworker: --background: %s\n", err.msg);
        goto done;
    }
    p.env = env;
    p.transparent = o->transparent ? 1u : 0u;
    p.clamp_direct = o->clamp_direct;
    p.clamp_indirect = o->clamp_indirect;
    p.passes = o->passes;
    /* Guiding samples glossy closures only (main refuses on with adaptive
     * sampling; auto is then off: a tile's stop would depend on its pass). */
    p.guiding =
        pt_guide_enabled((uint32_t)o->guiding, scene) &&
                !(o->guiding == PT_GUIDING_AUTO && (o->target_error > 0.0 || o->min_gain > 0.0))
            ? 1u
            : 0u;
    if (o->guiding == PT_GUIDING_ON && !p.guiding && !o->quiet)
        fprintf(stderr, "ptworker: --guiding: every material is Lambert; nothing to guide\n");
    if (o->guiding == PT_GUIDING_AUTO && !o->quiet)
        fprintf(stderr, "ptworker: --guiding auto: %s\n",
                p.guiding ? "on (glass in the scene)" : "off");
    if (pt_render_check_lit(scene, env != NULL, o->scene_path, &err) != PT_OK) {
        /* It would render black: say how to light it instead. */
        fprintf(stderr, "ptworker: %s\n", err.msg);
        goto done;
    }
    char note[512];
    if (pt_portal_check_text(scene, note, sizeof note))
        fprintf(stderr, "ptworker: %s\n", note);
    p.bdpt = o->bdpt == PT_BDPT_ON ? 1u : 0u;
    if (o->bdpt == PT_BDPT_AUTO) {
        int on = 0;
        double share = -1.0;
        if (pt_bdpt_auto(scene, env != NULL, p.guiding != 0,
                         p.clamp_direct > 0.0f || p.clamp_indirect > 0.0f, &on, &share,
                         &err) != PT_OK) {
            fprintf(stderr, "ptworker: --bdpt auto: %s\n", err.msg);
            goto done;
        }
        p.bdpt = on ? 1u : 0u;
        if (on && !o->quiet)
            fprintf(stderr, "ptworker: " PT_BDPT_AUTO_ON "\n", 100.0 * share);
    }
    if (pt_renderer_new(scene, &p, &r, &err) != PT_OK ||
        pt_film_new(p.width, p.height, &film, &err) != PT_OK ||
        (o->passes && pt_film_enable_passes(film, o->passes, &err) != PT_OK) ||
        pt_image_new(p.width, p.height, &img, &err) != PT_OK ||
        (o->passes && pt_passes_add_planes(img, o->passes, &planes, &err) != PT_OK)) {
        fprintf(stderr, "ptworker: %s\n", err.msg);
        goto done;
    }
    double t_load = pt_now_s() - t0;

    uint32_t tx = (p.width + o->tile - 1) / o->tile, ty = (p.height + o->tile - 1) / o->tile;
    uint32_t nt = tx * ty;
    uint32_t nthreads = o->threads;
    if (nthreads == 0) {
        long n = sysconf(_SC_NPROCESSORS_ONLN);
        nthreads = n > 0 ? (uint32_t)n : 1;
    }
    tiles = pt_malloc_array(nt, sizeof *tiles);
    threads = pt_malloc_array(nthreads, sizeof *threads);
    args = pt_malloc_array(nthreads, sizeof *args);
    tstats = pt_calloc(nthreads, sizeof *tstats);
    if (!tiles || !threads || !args || !tstats) {
        fprintf(stderr, "ptworker: out of memory\n");
        goto done;
    }
    for (uint32_t y = 0; y < ty; y++)
        for (uint32_t x = 0; x < tx; x++) {
            pt_rect *t = &tiles[y * tx + x];
            t->x0 = x * o->tile;
            t->y0 = y * o->tile;
            t->x1 = t->x0 + o->tile < p.width ? t->x0 + o->tile : p.width;
            t->y1 = t->y0 + o->tile < p.height ? t->y0 + o->tile : p.height;
        }

    job j = {.o = o, .r = r, .film = film, .tiles = tiles, .num_tiles = nt, .thread_stats = tstats};
    atomic_init(&j.next_tile, 0);
    atomic_init(&j.tiles_done, 0);
    atomic_init(&j.samples_done, 0);
    atomic_init(&j.running, nthreads);
    atomic_init(&j.tiles_stopped, 0);
    if (!o->quiet)
        fprintf(stderr, "ptworker: %s: %u triangles, %ux%u, %u spp, %u threads (loaded in %.2fs)\n",
                o->scene_path, scene->num_triangles, p.width, p.height, o->spp, nthreads, t_load);
    double t_render = pt_now_s();
    uint64_t total = (uint64_t)p.width * p.height * o->spp;
    uint32_t passes = 1;
    if (p.guiding) {
        if (run_guided(&j, scene, nthreads, threads, args, total, t_render, &passes) != 0)
            goto done;
    } else {
        double last_print = 0.0;
        if (run_threads(&j, nthreads, threads, args, total, t_render, &last_print) == 0) {
            fprintf(stderr, "ptworker: cannot start render threads\n");
            goto done;
        }
    }
    double secs = pt_now_s() - t_render;
    if (atomic_load(&j.tiles_done) != nt * passes) {
        fprintf(stderr, "\nptworker: %u of %u tiles failed (out of memory)\n",
                nt * passes - atomic_load(&j.tiles_done), nt * passes);
        goto done;
    }

    pt_render_stats st = {0};
    for (uint32_t i = 0; i < nthreads; i++) {
        st.samples += tstats[i].samples;
        st.rejected += tstats[i].rejected;
        st.rays += tstats[i].rays;
        st.capped += tstats[i].capped;
        st.clamped += tstats[i].clamped;
        st.crossings += tstats[i].crossings;
        st.dropped += tstats[i].dropped;
        st.chains += tstats[i].chains;
    }
    pt_exr_meta meta = {0};
    if (o->passes & PT_PASS_CRYPTOMATTE) {
        if (pt_crypto_meta_init(&cmeta, scene, &err) != PT_OK) {
            fprintf(stderr, "\nptworker: %s\n", err.msg);
            goto done;
        }
        meta.attrs = cmeta.attrs;
        meta.nattrs = cmeta.nattrs;
    }
    meta.total_samples = pt_film_resolve(film, img);
    img->has_alpha = p.transparent;
    meta.render_seconds = secs;
    snprintf(meta.scene_hash, sizeof meta.scene_hash, "%s", scene->hash);
    /* --denoise: the denoised layer beside the beauty, and the preview of it. */
    pt_image shown = *img;
    double t_denoise = 0.0;
    if (o->denoise) {
        float *den[3];
        double td = pt_now_s();
        atomic_uint progress;
        atomic_init(&progress, 0);
        denoise_job dj = {
            img,
            nthreads,
            {.despeckle = PT_DENOISE_DESPECKLE, .max_bytes = o->denoise_max, .progress = &progress},
            den,
            0,
            &err,
            PT_OK};
        pt_progress_line line = {"ptworker: denoising", 0};
        if (o->quiet)
            denoise_run(&dj);
        else
            pt_run_reported(denoise_run, &dj, &progress, pt_progress_line_report, &line);
        pt_progress_line_end(&line);
        uint32_t side = dj.side;
        if (dj.st != PT_OK) {
            fprintf(stderr, "\nptworker: --denoise: %s\n", err.msg);
            goto done;
        }
        if (side && !o->quiet)
            fprintf(stderr, "ptworker: denoised in regions of %u pixels (--max-denoise-mb)\n",
                    side);
        t_denoise = pt_now_s() - td;
        shown = *img;
        shown.r = den[0];
        shown.g = den[1];
        shown.b = den[2];
    }
    /* An .exr with its preview beside it, or a .png alone (check_before). */
    int exr = pt_image_format_of(o->out_path) == PT_IMAGE_FORMAT_EXR;
    char png[4096];
    if (exr)
        pt_png_preview_path(o->out_path, png, sizeof png);
    else
        snprintf(png, sizeof png, "%s", o->out_path);
    if ((exr && pt_exr_write(o->out_path, img, &meta, &err) != PT_OK) ||
        pt_png_write_preview(png, &shown, &o->view, &err) != PT_OK) {
        fprintf(stderr, "\nptworker: %s\n", err.msg);
        goto done;
    }
    if (!o->quiet)
        fputc('\n', stderr);
    fprintf(stderr,
            "ptworker: rendered %s in %.2fs: %.4g samples/s, %.4g rays/s, %llu rejected samples "
            "(NaN/Inf)\nptworker: wrote %s%s%s\n",
            o->scene_path, secs, (double)st.samples / secs, (double)st.rays / secs,
            (unsigned long long)st.rejected, o->out_path, exr ? " and " : "", exr ? png : "");
    if (o->denoise)
        fprintf(stderr, "ptworker: denoised in %.2fs (NFOR; the layer denoised.R/G/B%s)\n",
                t_denoise, exr ? ", and the PNG" : "");
    if (o->target_error > 0.0 || o->min_gain > 0.0)
        fprintf(stderr,
                "ptworker: adaptive sampling stopped %u of %u tiles early; %.2f spp on "
                "average\n",
                atomic_load(&j.tiles_stopped), nt,
                (double)st.samples / ((double)p.width * p.height));
    if (st.chains > 0)
        fprintf(
            stderr,
            "ptworker: %llu light paths through or off smooth glass or metal connected to a light "
            "(manifold NEE)\n",
            (unsigned long long)st.chains);
    if (p.clamp_direct > 0.0f || p.clamp_indirect > 0.0f)
        fprintf(stderr,
                "ptworker: %llu contributions clamped (--clamp-direct %g, --clamp-indirect "
                "%g; 0 is off)\n",
                (unsigned long long)st.clamped, (double)p.clamp_direct, (double)p.clamp_indirect);
    if (st.dropped > 0)
        fprintf(stderr,
                "ptworker: %llu shadow rays met more than %u thin glass walls and were "
                "blocked (%llu walls crossed)\n",
                (unsigned long long)st.dropped, PT_SHADOW_CROSSINGS,
                (unsigned long long)st.crossings);
    if (st.capped > 0)
        fprintf(stderr,
                "ptworker: %llu paths reached the depth cap of %u; raise --max-depth if this "
                "matters\n",
                (unsigned long long)st.capped, p.max_depth);
    rc = 0;
done:
    pt_crypto_meta_fini(&cmeta);
    pt_free(tstats);
    pt_free(args);
    pt_free(threads);
    pt_free(tiles);
    pt_image_free(img);
    pt_film_free(film);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(scene);
    return rc;
}
