/*
 * ptbench-throughput - the renderer's samples/s and rays/s against the bare
 * ray-query rate of Embree on the same rays, measured side by side.
 *
 * For each repetition: (1) render the whole image with T threads and count
 * samples and rays; (2) replay a captured set of that render's own rays
 * (closest-hit and shadow, in the renderer's order) through the acceleration
 * structure alone with T threads. The ratio of (1)'s rays/s to (2)'s is the
 * renderer's throughput as a fraction of the ray-query ceiling; everything
 * else the renderer does (sampling, shading, BSDFs, lights, film) is the gap.
 * Repetitions alternate (1) and (2) so both see the same machine load;
 * medians are reported. The ratio is also given in CPU time (the process's,
 * all threads), which other programs on a shared machine inflate much less
 * than wall time when their load changes between (1) and (2). (3) In the
 * same repetitions, the same render through every less specialised integrator
 * variant (render.h: pt_render_params.extra_features; up to the general one),
 * so the speed-up of the variant chosen for the scene (pt_renderer_variant)
 * over each is measured side by side; a variant that shades in SIMD lanes
 * (pt_renderer_lanes) also against itself shading one path at a time.
 *
 * The log holds the rays in the order the renderer traces them (tiles in
 * order, each tile's paths in batches: render.c, trace_batch), so the replay
 * sees the same coherence as the render; --log-order path logs one path at a
 * time instead, sample by sample over the image, as the first measurements
 * did.
 *
 *   ptbench-throughput SCENE [--threads T] [--res WxH] [--spp N] [--reps R]
 *                      [--log-order render|path] [--csv FILE]
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/render/render.h"
#include "common/scene/accel.h"
#include "common/scene/scene.h"

typedef struct ray_rec {
    pt_vec3 o, d;
    float tfar;
    int occlusion;
} ray_rec;

typedef struct ray_log {
    ray_rec *rays;
    size_t n, cap;
} ray_log;

static void log_ray(void *user, pt_vec3 o, pt_vec3 d, float tfar, int occlusion)
{
    ray_log *l = user;
    if (l->n < l->cap)
        l->rays[l->n++] = (ray_rec){o, d, tfar, occlusion};
}

typedef struct shared {
    const pt_renderer *r;
    const pt_accel *accel;
    uint32_t width, height, spp, tile;
    atomic_uint next;
    atomic_size_t next_ray; /* replay: the next chunk of the log */
    const ray_log *log;
    pt_render_stats stats[64];
    uint64_t hits[64];
} shared;

typedef struct targ {
    shared *sh;
    int id, nthreads;
} targ;

static void *render_worker(void *p)
{
    targ *a = p;
    shared *sh = a->sh;
    uint32_t tx = (sh->width + sh->tile - 1) / sh->tile,
             ty = (sh->height + sh->tile - 1) / sh->tile;
    pt_pixel_acc *acc = pt_malloc_array((size_t)sh->tile * sh->tile, sizeof *acc);
    for (;;) {
        uint32_t t = atomic_fetch_add(&sh->next, 1);
        if (t >= tx * ty)
            break;
        pt_rect rc = {(t % tx) * sh->tile, (t / tx) * sh->tile, 0, 0};
        rc.x1 = rc.x0 + sh->tile < sh->width ? rc.x0 + sh->tile : sh->width;
        rc.y1 = rc.y0 + sh->tile < sh->height ? rc.y0 + sh->tile : sh->height;
        pt_render_tile(sh->r, rc, 0, sh->spp, acc, &sh->stats[a->id]);
    }
    pt_free(acc);
    return NULL;
}

static void *replay_worker(void *p)
{
    targ *a = p;
    shared *sh = a->sh;
    /* Chunks of the log taken in order as threads come free, as the render
     * takes tiles: a fixed split would leave a thread idle at the end and
     * understate the rate in wall time. */
    const size_t chunk = 4096;
    size_t n = sh->log->n;
    uint64_t hits = 0;
    for (;;) {
        size_t lo = atomic_fetch_add(&sh->next_ray, chunk);
        if (lo >= n)
            break;
        size_t hi = n - lo < chunk ? n : lo + chunk;
        for (size_t i = lo; i < hi; i++) {
            const ray_rec *r = &sh->log->rays[i];
            if (r->occlusion) {
                hits += pt_accel_occluded(sh->accel, r->o, r->d, r->tfar);
            } else {
                pt_hit h;
                hits += pt_accel_intersect(sh->accel, r->o, r->d, r->tfar, &h);
            }
        }
    }
    sh->hits[a->id] = hits;
    return NULL;
}

static void run_threads(int n, void *(*fn)(void *), shared *sh)
{
    pthread_t th[64];
    targ args[64];
    for (int i = 0; i < n; i++) {
        args[i] = (targ){sh, i, n};
        pthread_create(&th[i], NULL, fn, &args[i]);
    }
    for (int i = 0; i < n; i++)
        pthread_join(th[i], NULL);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

int main(int argc, char **argv)
{
    const char *scene_path = NULL, *csv = NULL;
    int per_path = 0;
    uint32_t w = 256, h = 256, spp = 8, nthreads = 2, nreps = 5;
    pt_status opt = PT_OK;
    pt_error opt_err = {0};
    for (int i = 1; i < argc && opt == PT_OK; i++) {
        if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            opt = pt_opt_u32("--threads", argv[++i], 1, 64, &nthreads, &opt_err);
        else if (!strcmp(argv[i], "--res") && i + 1 < argc)
            opt = pt_opt_res("--res", argv[++i], 16384, &w, &h, &opt_err);
        else if (!strcmp(argv[i], "--spp") && i + 1 < argc)
            opt = pt_opt_u32("--spp", argv[++i], 1, 1u << 24, &spp, &opt_err);
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            opt = pt_opt_u32("--reps", argv[++i], 1, 100, &nreps, &opt_err);
        else if (!strcmp(argv[i], "--log-order") && i + 1 < argc &&
                 (!strcmp(argv[i + 1], "render") || !strcmp(argv[i + 1], "path")))
            per_path = !strcmp(argv[++i], "path");
        else if (!strcmp(argv[i], "--csv") && i + 1 < argc)
            csv = argv[++i];
        else if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            printf("usage: ptbench-throughput SCENE [--threads T] [--res WxH] [--spp N] [--reps R] "
                   "[--log-order render|path] [--csv FILE] [--version]\n");
            return 0;
        } else if (!strcmp(argv[i], "--version"))
            return pt_version_print("ptbench-throughput");
        else if (argv[i][0] != '-' && !scene_path)
            scene_path = argv[i];
        else {
            fprintf(stderr, "ptbench-throughput: bad argument '%s' (see --help)\n", argv[i]);
            return 2;
        }
    }
    if (opt != PT_OK) {
        fprintf(stderr, "ptbench-throughput: %s (see --help)\n", opt_err.msg);
        return 2;
    }
    if (!scene_path) {
        fprintf(stderr, "ptbench-throughput: need a SCENE and sane options (see --help)\n");
        return 2;
    }
    int threads = (int)nthreads, reps = (int)nreps;
    pt_error err = {0};
    pt_scene *scene = NULL;
    pt_renderer *r = NULL, *alt[4] = {NULL, NULL, NULL, NULL};
    const char *alt_name[4];
    int nalt = 0;
    pt_accel *accel = NULL;
    if (pt_scene_load(scene_path, NULL, &scene, &err) != PT_OK) {
        fprintf(stderr, "ptbench-throughput: %s\n", err.msg);
        return 1;
    }
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    if (pt_renderer_new(scene, &p, &r, &err) != PT_OK ||
        pt_accel_new(scene, &accel, &err) != PT_OK) {
        fprintf(stderr, "ptbench-throughput: %s\n", err.msg);
        return 1;
    }
    /* The variants the scene could also run: assume textures, glossy lobes,
     * then everything (the general one); each distinct one once. */
    static const uint32_t extras[3] = {PT_FEAT_TEXTURES, PT_FEAT_GLOSSY, 0xffffffffu};
    for (int e = 0; e < 3; e++) {
        pt_render_params pe = p;
        pe.extra_features = extras[e];
        pt_renderer *v = NULL;
        if (pt_renderer_new(scene, &pe, &v, &err) != PT_OK) {
            fprintf(stderr, "ptbench-throughput: %s\n", err.msg);
            return 1;
        }
        int seen = !strcmp(pt_renderer_variant(v), pt_renderer_variant(r));
        for (int a = 0; a < nalt; a++)
            seen |= !strcmp(pt_renderer_variant(v), pt_renderer_variant(alt[a]));
        if (seen) {
            pt_renderer_free(v);
        } else {
            alt_name[nalt] = pt_renderer_variant(v);
            alt[nalt++] = v;
        }
    }
    /* A variant that shades in SIMD lanes, also one path at a time (what it
     * does where lanes are slow). */
    if (pt_renderer_lanes(r)) {
        pt_render_params ps = p;
        ps.scalar_shading = 1;
        if (pt_renderer_new(scene, &ps, &alt[nalt], &err) != PT_OK) {
            fprintf(stderr, "ptbench-throughput: %s\n", err.msg);
            return 1;
        }
        alt_name[nalt++] = "per-path shading";
    }

    /* Capture the render's rays (at most 16M), tile by tile in the order the
     * render threads take tiles, each tile's rays in the order the renderer
     * traces them (pt_render_tile_traced). */
    ray_log log = {0};
    log.cap = 16u << 20;
    log.rays = pt_malloc_array(log.cap, sizeof *log.rays);
    pt_ray_sink sink = {log_ray, &log};
    if (per_path) {
        /* --log-order path: one path at a time, sample by sample over the
         * whole image (the order of the earlier measurements). */
        pt_pixel_acc acc;
        for (uint32_t s = 0; s < spp && log.n < log.cap; s++)
            for (uint32_t y = 0; y < h && log.n < log.cap; y++)
                for (uint32_t x = 0; x < w && log.n < log.cap; x++)
                    pt_render_tile_traced(r, (pt_rect){x, y, x + 1, y + 1}, s, s + 1, &acc, &sink);
    } else {
        const uint32_t tile = 16, tx = (w + tile - 1) / tile, ty = (h + tile - 1) / tile;
        pt_pixel_acc *acc = pt_malloc_array((size_t)tile * tile, sizeof *acc);
        for (uint32_t t = 0; t < tx * ty && log.n < log.cap; t++) {
            pt_rect rc = {(t % tx) * tile, (t / tx) * tile, 0, 0};
            rc.x1 = rc.x0 + tile < w ? rc.x0 + tile : w;
            rc.y1 = rc.y0 + tile < h ? rc.y0 + tile : h;
            pt_render_tile_traced(r, rc, 0, spp, acc, &sink);
        }
        pt_free(acc);
    }
    size_t shadow = 0;
    for (size_t i = 0; i < log.n; i++)
        shadow += log.rays[i].occlusion;

    double sps[100], rps[100], eps[100], ratio[100], asps[4][100], speedup[4][100], cratio[100],
        csps[100];
    for (int k = 0; k < reps; k++) {
        shared sh = {
            .r = r, .accel = accel, .width = w, .height = h, .spp = spp, .tile = 16, .log = &log};
        atomic_init(&sh.next, 0);
        atomic_init(&sh.next_ray, 0);
        double c0 = pt_cpu_s();
        double t0 = pt_now_s();
        run_threads(threads, render_worker, &sh);
        double t_render = pt_now_s() - t0;
        double c_render = pt_cpu_s() - c0;
        uint64_t samples = 0, rays = 0;
        for (int i = 0; i < threads; i++) {
            samples += sh.stats[i].samples;
            rays += sh.stats[i].rays;
        }
        c0 = pt_cpu_s();
        t0 = pt_now_s();
        run_threads(threads, replay_worker, &sh);
        double t_replay = pt_now_s() - t0;
        double c_replay = pt_cpu_s() - c0;
        cratio[k] = (rays / c_render) / (log.n / c_replay);
        csps[k] = samples / c_render;
        sps[k] = samples / t_render;
        rps[k] = rays / t_render;
        eps[k] = log.n / t_replay;
        ratio[k] = rps[k] / eps[k];
        for (int a = 0; a < nalt; a++) {
            shared sg = {.r = alt[a],
                         .accel = accel,
                         .width = w,
                         .height = h,
                         .spp = spp,
                         .tile = 16,
                         .log = &log};
            atomic_init(&sg.next, 0);
            t0 = pt_now_s();
            run_threads(threads, render_worker, &sg);
            double t_alt = pt_now_s() - t0;
            uint64_t asamples = 0;
            for (int i = 0; i < threads; i++)
                asamples += sg.stats[i].samples;
            asps[a][k] = asamples / t_alt;
            speedup[a][k] = sps[k] / asps[a][k];
        }
    }
    double m_sps = median(sps, reps), m_rps = median(rps, reps), m_eps = median(eps, reps),
           m_ratio = median(ratio, reps);
    printf("scene            %s (%u triangles)\n", scene_path, scene->num_triangles);
    printf("setup            %ux%u, %u spp, %d threads, %d repetitions (medians)\n", w, h, spp,
           threads, reps);
    printf("renderer         %.4g samples/s, %.4g rays/s\n", m_sps, m_rps);
    printf("bare ray queries %.4g rays/s (%zu rays replayed, %.0f%% shadow)\n", m_eps, log.n,
           100.0 * shadow / (log.n ? log.n : 1));
    printf("ratio            %.3f of the ray-query ceiling\n", m_ratio);
    double m_cratio = median(cratio, reps), m_csps = median(csps, reps);
    printf("ratio (CPU time) %.3f of the ray-query ceiling; %.4g samples per CPU second\n",
           m_cratio, m_csps);
    printf("variant          %s%s, chosen for the scene: %.4g samples/s\n", pt_renderer_variant(r),
           pt_renderer_lanes(r) ? " (SIMD lanes)" : "", m_sps);
    for (int a = 0; a < nalt; a++)
        printf("  against %-18s %.4g samples/s: speed-up %.3f\n", alt_name[a],
               median(asps[a], reps), median(speedup[a], reps));
    if (!nalt)
        printf("  (the general variant: none less specialised)\n");
    if (csv) {
        FILE *f = fopen(csv, "a");
        if (f) {
            fprintf(f, "%s,%u,%u,%u,%d,%.6g,%.6g,%.6g,%.4f\n", scene_path, w, h, spp, threads,
                    m_sps, m_rps, m_eps, m_ratio);
            fclose(f);
        }
    }
    pt_free(log.rays);
    pt_accel_free(accel);
    pt_renderer_free(r);
    for (int a = 0; a < nalt; a++)
        pt_renderer_free(alt[a]);
    pt_scene_free(scene);
    return 0;
}
