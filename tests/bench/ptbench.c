/*
 * ptbench - render time against image error.
 *
 *   ptbench SCENE (--reference REF.exr | --constant V) [--spp LIST | --time LIST]
 *           [--res WxH] [--threads T] [--seed S] [--max-depth D] [--reps R]
 *           [--label NAME] [--csv OUT.csv] [--plot OUT.png] [--plot-series IN.csv]...
 *   ptbench SCENE --reference REF.exr --spp LIST --bound [--min-spp M] [--tile T] [...]
 *   ptbench SCENE --reference REF.exr (--target-error LIST | --min-gain LIST)
 *           [--min-spp M] [--max-spp N] [--chunk C] [--tile T] [other options as above]
 *   ptbench error IMAGE.exr (REFERENCE.exr | --constant V) [--layer NAME]
 *   ptbench plot OUT.png [--y COLUMN] [--title TEXT] IN.csv...
 *   ptbench gain REFERENCE.exr [TILE [IMAGE.exr]]
 *
 * For each sample count of --spp (default 1,2,4,...,256) the whole image is
 * rendered in this process with T threads pulling 16x16 tiles, each tile
 * rendered as pt_render_tile(tile, 0, spp) into a film; the wall time of the
 * render alone is measured (scene load, acceleration build and scratch
 * allocation excluded; thread start included), the median over R repetitions
 * reported. The film is resolved to an image and scored against the reference
 * (common/image/metrics.h: RMSE, relMSE); efficiency = 1 / (MSE * seconds), which a
 * Monte Carlo estimator keeps constant as samples grow, so it compares
 * renderers independently of how long each ran.
 * With --time, each budget in seconds is filled by rendering the whole image
 * in passes of growing sample counts (doubling, then as many samples as the
 * measured rate predicts will fit) and the spp reached and the actual time are
 * reported; with R repetitions, the one with the median spp.
 * The reference must not share the benchmark's random numbers: render it with
 * another --seed, or the first samples of both agree and the error looks smaller
 * than it is. Its own noise adds its MSE to every row.
 * With --target-error, each row is an adaptive render to that target: every
 * tile is rendered in chunks of C samples and stops, as ptworker and ptserve
 * stop it (pt_tile_stops, common/render/film.h), once it has M samples and its
 * pt_tile_rel_error is at most the target, else at N samples; the spp column
 * is then the mean over pixels. --min-gain does the same with the
 * minimum-mean-error rule: a tile stops once its pt_tile_gain is at most the
 * row's value.
 * `gain` bounds what any adaptive sampler could win: from a converged
 * reference's samples and variance channels (luminance) it takes each pixel's
 * variance per sample s_i^2 and prints, for RMSE and for relMSE, how many times
 * fewer samples than uniform the best allocation would need for the same error
 * when it may choose the count of every pixel (n_i proportional to s_i) or only
 * of every TILE x TILE tile, and the share of uniform sampling's squared error
 * held by the worst 5 % of tiles. Equal cost per sample is assumed. That
 * variance is the error of independent samples; the sampler's scrambled Sobol
 * samples err less, and unevenly, so with IMAGE (a uniform render of the same
 * size with another seed) the bound per tile is also taken from IMAGE's
 * measured squared error (R, G, B, as the metrics count it), assuming that
 * each tile's error falls as 1/n.
 * --bound adds the same bound in CPU time after each --spp row, from that
 * render's squared error and each tile's CPU time (print_bound): the
 * samples an adaptive rule saves are not all as costly (black background).
 * `error` scores an existing EXR (from any renderer) the same way; `plot`
 * draws the CSVs of earlier runs, one series per label.
 */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/metrics.h"
#include "common/render/adaptive.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/bench/plot.h"

#define MAX_THREADS 64
#define MAX_ROWS 64
#define MAX_REPS 100
#define MAX_SERIES_FILES 16
#define PLOT_W 900
#define PLOT_H 600

/* ---- rendering ------------------------------------------------------------ */

typedef struct pass {
    const pt_renderer *r;
    pt_film *film;
    const pt_rect *tiles;
    uint32_t num_tiles, s0, s1;
    pt_adaptive rule; /* a rule on: adaptive (pt_tile_stops), s1 is the cap */
    uint32_t chunk;   /* adaptive: samples per chunk */
    atomic_uint next;
    pt_pixel_acc *scratch[MAX_THREADS]; /* tile*tile each, allocated once */
    pt_pixel_acc *sum[MAX_THREADS];     /* adaptive: the tile's sums so far */
    pt_render_stats stats[MAX_THREADS];
    double *tile_cpu; /* --bound: per tile, the CPU seconds of its uniform renders */
} pass;

typedef struct pass_arg {
    pass *ps;
    int id;
} pass_arg;

static void *pass_thread(void *p)
{
    pass_arg *a = p;
    pass *ps = a->ps;
    for (;;) {
        uint32_t t = atomic_fetch_add(&ps->next, 1);
        if (t >= ps->num_tiles)
            break;
        pt_rect rc = ps->tiles[t];
        if (!(ps->rule.target_error > 0.0) && !(ps->rule.min_gain > 0.0)) {
            double c0 = ps->tile_cpu ? pt_thread_cpu_s() : 0.0;
            pt_render_tile(ps->r, rc, ps->s0, ps->s1, ps->scratch[a->id], &ps->stats[a->id]);
            if (ps->tile_cpu)
                ps->tile_cpu[t] += pt_thread_cpu_s() - c0;
            /* Tiles are disjoint: threads add to the film without a lock. */
            pt_film_add_tile(ps->film, rc, ps->scratch[a->id]);
            continue;
        }
        /* ptworker's loop (worker/standalone.c): chunk by chunk until the tile stops. */
        uint32_t w = rc.x1 - rc.x0, npx = w * (rc.y1 - rc.y0);
        pt_pixel_acc *sum = ps->sum[a->id];
        memset(sum, 0, npx * sizeof *sum);
        for (uint32_t s0 = ps->s0; s0 < ps->s1; s0 += ps->chunk) {
            uint32_t s1 = s0 + ps->chunk < ps->s1 ? s0 + ps->chunk : ps->s1;
            pt_render_tile(ps->r, rc, s0, s1, ps->scratch[a->id], &ps->stats[a->id]);
            for (uint32_t i = 0; i < npx; i++)
                pt_pixel_acc_add(&sum[i], &ps->scratch[a->id][i]);
            if (s1 < ps->s1 &&
                pt_tile_stops(sum, w, ps->scratch[a->id], w, w, rc.y1 - rc.y0, s1, &ps->rule))
                break;
        }
        pt_film_add_tile(ps->film, rc, sum);
    }
    return NULL;
}

/* Renders samples [s0, s1) of every tile into the film (added to it). Returns
 * 0, or -1 when no thread could be started. */
static int run_pass(pass *ps, int threads, uint32_t s0, uint32_t s1)
{
    pthread_t th[MAX_THREADS];
    pass_arg args[MAX_THREADS];
    ps->s0 = s0;
    ps->s1 = s1;
    atomic_store(&ps->next, 0);
    int started = 0;
    for (; started < threads; started++) {
        args[started] = (pass_arg){ps, started};
        if (pthread_create(&th[started], NULL, pass_thread, &args[started]) != 0)
            break;
    }
    if (started == 0)
        return -1;
    for (int i = 0; i < started; i++)
        pthread_join(th[i], NULL);
    return 0;
}

static void reset(pass *ps, int threads)
{
    memset(ps->film->px, 0, (size_t)ps->film->width * ps->film->height * sizeof *ps->film->px);
    memset(ps->stats, 0, (size_t)threads * sizeof ps->stats[0]);
}

static pt_render_stats total_stats(const pass *ps, int threads)
{
    pt_render_stats st = {0};
    for (int i = 0; i < threads; i++) {
        st.samples += ps->stats[i].samples;
        st.rejected += ps->stats[i].rejected;
        st.rays += ps->stats[i].rays;
    }
    return st;
}

/* ---- results ---------------------------------------------------------------- */

typedef struct row {
    uint32_t spp;    /* uniform: per pixel; adaptive: the cap */
    double mean_spp; /* samples / pixels */
    double cpu;      /* CPU seconds of all threads (median) */
    double target;   /* adaptive: the target error, else 0 */
    double min_gain; /* adaptive: the minimum gain, else 0 */
    double seconds;
    pt_render_stats st;
    pt_metrics m;
} row;

typedef struct reference {
    const pt_image *img; /* NULL: the constant */
    double value;
} reference;

static pt_status score(const pt_image *img, const reference *ref, pt_metrics *m, pt_error *err)
{
    return ref->img ? pt_metrics_compare(img, ref->img, m, err)
                    : pt_metrics_compare_constant(img, ref->value, m, err);
}

static double efficiency(const row *r)
{
    return 1.0 / (r->m.rmse * r->m.rmse * r->seconds);
}

static void print_header(void)
{
    printf("%8s %10s %11s %11s %11s %11s %11s %9s %9s\n", "spp", "seconds", "samples/s", "rays/s",
           "RMSE", "relMSE", "efficiency", "mean", "cpu s");
}

static void print_row(const row *r)
{
    if (r->target > 0.0)
        printf("adaptive %g: ", r->target);
    if (r->min_gain > 0.0)
        printf("min gain %g: ", r->min_gain);
    printf("%8.2f %10.4f %11.4g %11.4g %11.4e %11.4e %11.4g %9.5f %9.4f\n", r->mean_spp, r->seconds,
           (double)r->st.samples / r->seconds, (double)r->st.rays / r->seconds, r->m.rmse,
           r->m.rel_mse, efficiency(r), (r->m.mean[0] + r->m.mean[1] + r->m.mean[2]) / 3.0, r->cpu);
}

static const char *basename_of(const char *path)
{
    const char *s = strrchr(path, '/');
    return s ? s + 1 : path;
}

/* Commas would split a CSV field: the label is written with them replaced. */
static void csv_safe(char *s)
{
    for (; *s; s++)
        if (*s == ',' || *s == '\n' || *s == '\r')
            *s = '_';
}

static int write_csv(const char *path, const char *label, const char *scene, uint32_t w, uint32_t h,
                     int threads, uint32_t seed, const row *rows, int n)
{
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "ptbench: %s: %s\n", path, strerror(errno));
        return -1;
    }
    fprintf(f, "label,scene,width,height,threads,seed,spp,seconds,samples_per_s,rays_per_s,"
               "rmse,relmse,efficiency,mean,nonfinite,rejected,target_error,mean_spp,cpu_seconds,"
               "min_gain\n");
    for (int i = 0; i < n; i++) {
        const row *r = &rows[i];
        fprintf(f,
                "%s,%s,%u,%u,%d,%u,%u,%.6g,%.6g,%.6g,%.6e,%.6e,%.6g,%.6g,%llu,%llu,%.6g,%.6g,%.6g,"
                "%.6g\n",
                label, scene, w, h, threads, seed, r->spp, r->seconds,
                (double)r->st.samples / r->seconds, (double)r->st.rays / r->seconds, r->m.rmse,
                r->m.rel_mse, efficiency(r), (r->m.mean[0] + r->m.mean[1] + r->m.mean[2]) / 3.0,
                (unsigned long long)r->m.nonfinite, (unsigned long long)r->st.rejected, r->target,
                r->mean_spp, r->cpu, r->min_gain);
    }
    if (fclose(f) != 0) {
        fprintf(stderr, "ptbench: %s: %s\n", path, strerror(errno));
        return -1;
    }
    return 0;
}

static void plot_init(plot *p)
{
    memset(p, 0, sizeof *p);
    snprintf(p->title, sizeof p->title, "RMSE AGAINST RENDER TIME");
    snprintf(p->xlabel, sizeof p->xlabel, "SECONDS");
    snprintf(p->ylabel, sizeof p->ylabel, "RMSE");
}

/* ---- argument parsing --------------------------------------------------------- */

/* "1,2,4" -> values; each in [lo, hi]; at most MAX_ROWS. Returns the count or -1. */
static int parse_list(const char *s, int as_double, double *out)
{
    char buf[1024];
    if (strlen(s) >= sizeof buf)
        return -1;
    strcpy(buf, s);
    int n = 0;
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        if (n == MAX_ROWS)
            return -1;
        if (as_double) {
            if (pt_opt_double("list", tok, -DBL_MAX, DBL_MAX, &out[n], NULL) != PT_OK ||
                out[n] <= 0)
                return -1;
        } else {
            uint32_t v;
            if (pt_opt_u32("list", tok, 1, 1u << 24, &v, NULL) != PT_OK)
                return -1;
            out[n] = v;
        }
        n++;
    }
    return n;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: ptbench SCENE (--reference REF.exr | --constant V) [options]\n"
               "       ptbench error IMAGE.exr (REFERENCE.exr | --constant V) [--layer NAME]\n"
               "       ptbench plot OUT.png [--y COLUMN] [--title TEXT] IN.csv...\n"
               "       ptbench gain REFERENCE.exr [TILE [IMAGE.exr]]\n"
               "  --spp LIST          sample counts per pixel (default 1,2,4,8,16,32,64,128,256)\n"
               "  --time LIST         time budgets in seconds instead: spp reached in each\n"
               "  --res WxH           image size (default: the reference's, else 128 wide)\n"
               "  --threads T         render threads (default 2)\n"
               "  --seed S            random seed (default 0; render the reference with another)\n"
               "  --max-depth D       maximum bounces (default 16, as Cycles is set in\n"
               "                      tests/bench/cycles)\n"
               "  --env PATH          environment map, as ptworker's (--env-strength S,\n"
               "                      --env-rotate DEG)\n"
               "  --reps R            repetitions; the median time is reported (default 1)\n"
               "  --light-select M    how NEE chooses an emissive triangle: auto (default: the\n"
               "                      light tree from 16 of them on), power or tree\n"
               "  --solid-angle on|off large near lights by solid angle where the scene is not\n"
               "                      Lambert-only, or by area everywhere (default off)\n"
               "  --label NAME        series name in CSV and plot (default: the scene's name)\n"
               "  --csv OUT.csv       write the table\n"
               "  --plot OUT.png      log-log plot of RMSE against seconds\n"
               "  --plot-series F.csv add an earlier run's CSV to the plot (repeatable)\n"
               "  --target-error LIST adaptive rows instead: one render to each target error\n"
               "  --min-gain LIST     adaptive rows with the minimum-mean-error rule: one\n"
               "                      render to each min gain (ptworker --min-gain)\n"
               "  --min-spp M         adaptive: samples before a tile may stop (default: chunk)\n"
               "  --max-spp N         adaptive: samples at most (default 1024)\n"
               "  --chunk C           adaptive: samples between decisions (default 16)\n"
               "  --tile T            tile side in pixels (default 16)\n"
               "  --bound             after each --spp row, what the best allocation to tiles\n"
               "                      could win in CPU time (with --min-spp: above that floor)\n"
               "  --version           the version and renderer build id\n");
}

/* ---- subcommands ---------------------------------------------------------------- */

/* The layer NAME.R/G/B of the EXR path into img's R, G, B (the same file:
 * the same size), for `ptbench error ... --layer denoised`. */
static pt_status read_layer(const char *path, const char *layer, pt_image *img, pt_error *err)
{
    char names[3][96];
    const char *np[3] = {names[0], names[1], names[2]};
    float *pl[3] = {0};
    uint32_t w, h;
    for (int c = 0; c < 3; c++)
        snprintf(names[c], sizeof names[c], "%s.%c", layer, "RGB"[c]);
    pt_status st = pt_exr_read_channels(path, 3, np, pl, &w, &h, err);
    if (st == PT_OK && (!pl[0] || !pl[1] || !pl[2]))
        st = pt_error_set(err, PT_ERR_FORMAT, "%s has no layer %s (%s, %s, %s)", path, layer,
                          names[0], names[1], names[2]);
    if (st == PT_OK) {
        size_t n = (size_t)w * h * sizeof(float);
        memcpy(img->r, pl[0], n);
        memcpy(img->g, pl[1], n);
        memcpy(img->b, pl[2], n);
    }
    for (int c = 0; c < 3; c++)
        pt_free(pl[c]);
    return st;
}

static double worst_share(const pt_image *img, const pt_image *ref);

static int cmd_error(int argc, char **argv)
{
    const char *layer = NULL;
    if (argc >= 6 && !strcmp(argv[argc - 2], "--layer")) {
        layer = argv[argc - 1];
        argc -= 2;
    }
    if (argc != 4 && !(argc == 5 && !strcmp(argv[3], "--constant"))) {
        usage(stderr);
        return 2;
    }
    pt_error err = {0};
    pt_image *img = NULL, *refimg = NULL;
    reference ref = {NULL, 0.0};
    int rc = 1;
    if (argc == 5 &&
        pt_opt_double("--constant", argv[4], -DBL_MAX, DBL_MAX, &ref.value, NULL) != PT_OK) {
        fprintf(stderr, "ptbench: --constant: '%s' is not a finite number\n", argv[4]);
        return 2;
    }
    if (pt_exr_read(argv[2], &img, NULL, &err) != PT_OK ||
        (argc == 4 && pt_exr_read(argv[3], &refimg, NULL, &err) != PT_OK)) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        goto done;
    }
    if (layer && read_layer(argv[2], layer, img, &err) != PT_OK) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        goto done;
    }
    ref.img = refimg;
    pt_metrics m;
    if (score(img, &ref, &m, &err) != PT_OK) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        goto done;
    }
    printf("RMSE     %.6e\nrelMSE   %.6e\nmean     %.6g %.6g %.6g\nnonfinite %llu\n", m.rmse,
           m.rel_mse, m.mean[0], m.mean[1], m.mean[2], (unsigned long long)m.nonfinite);
    if (refimg) {
        double share = worst_share(img, refimg);
        if (share < 0.0) {
            fprintf(stderr, "ptbench: out of memory\n");
            goto done;
        }
        printf("worst0.1%% %.4f\n", share);
    }
    rc = 0;
done:
    pt_image_free(img);
    pt_image_free(refimg);
    return rc;
}

static int cmp_double_desc(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x < y) - (x > y);
}

/* Adds to *s pixel i's squared error of meas against ref in R, G and B, as
 * the metrics count it (rel: relative), a value that is not finite counting 0. */
static void add_pixel_sq_error(const pt_image *meas, const pt_image *ref, size_t i, int rel,
                               double *s)
{
    const float *a[3] = {meas->r, meas->g, meas->b}, *b[3] = {ref->r, ref->g, ref->b};
    for (int c = 0; c < 3; c++) {
        double d = (double)a[c][i] - b[c][i], r = b[c][i];
        double v = d * d / (rel ? r * r + PT_METRICS_REL_EPS : 1.0);
        *s += isfinite(v) ? v : 0;
    }
}

/* The share of relMSE's sum that the worst 0.1 % of pixels (at least one)
 * carry: how much of an image's error is fireflies. -1 out of memory. */
static double worst_share(const pt_image *img, const pt_image *ref)
{
    size_t n = (size_t)img->width * img->height, k = (n + 999) / 1000;
    double *e = pt_malloc_array(n, sizeof *e), tot = 0.0, top = 0.0;
    if (!e)
        return -1.0;
    for (size_t i = 0; i < n; i++) {
        e[i] = 0.0;
        add_pixel_sq_error(img, ref, i, 1, &e[i]);
        tot += e[i];
    }
    qsort(e, n, sizeof *e, cmp_double_desc);
    for (size_t i = 0; i < k; i++)
        top += e[i];
    pt_free(e);
    return tot > 0.0 ? top / tot : 0.0;
}

/* The summed squared error (rel: relative) of the tile of size ts at (x0, y0)
 * of the reference img, and in *m its pixels: from img's variance per
 * sample, adding each pixel's square root to *px_sqrt, or with meas from
 * meas's difference from img (px_sqrt unused). */
static double tile_error(const pt_image *img, const pt_image *meas, int rel, uint32_t x0,
                         uint32_t y0, uint32_t ts, uint32_t *m, double *px_sqrt)
{
    uint32_t w = img->width, h = img->height;
    double s = 0;
    *m = 0;
    for (uint32_t y = y0; y < y0 + ts && y < h; y++)
        for (uint32_t x = x0; x < x0 + ts && x < w; x++, (*m)++) {
            size_t i = (size_t)y * w + x;
            if (meas) {
                add_pixel_sq_error(meas, img, i, rel, &s);
                continue;
            }
            double v = (double)img->variance[i] * img->samples[i];
            if (rel) {
                double mu = 0.2126 * img->r[i] + 0.7152 * img->g[i] + 0.0722 * img->b[i];
                v /= mu * mu + PT_METRICS_REL_EPS;
            }
            v = v > 0 && isfinite(v) ? v : 0;
            s += v;
            *px_sqrt += sqrt(v);
        }
    return s;
}

/* Uniform MSE over the best MSE for the same samples, per pixel and per tile:
 * minimising sum_t S_t / n_t (S_t the tile's summed variance per sample, n_t
 * its spp) under sum_t m_t n_t = N gives n_t ~ sqrt(S_t / m_t). */
static int cmd_gain(int argc, char **argv)
{
    uint32_t ts = 16;
    if (argc < 3 || argc > 5 ||
        (argc >= 4 && pt_opt_u32("TILE", argv[3], 1, PT_TILE_MAX, &ts, NULL) != PT_OK)) {
        usage(stderr);
        return 2;
    }
    pt_error err = {0};
    pt_image *img = NULL, *meas = NULL;
    if (pt_exr_read(argv[2], &img, NULL, &err) != PT_OK ||
        (argc == 5 && pt_exr_read(argv[4], &meas, NULL, &err) != PT_OK)) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        pt_image_free(img);
        return 1;
    }
    if (meas && (meas->width != img->width || meas->height != img->height)) {
        fprintf(stderr, "ptbench: %s and %s differ in size\n", argv[2], argv[4]);
        pt_image_free(meas);
        pt_image_free(img);
        return 1;
    }
    uint32_t w = img->width, h = img->height, tx = (w + ts - 1) / ts, ty = (h + ts - 1) / ts;
    double *tile_se = pt_malloc_array((size_t)tx * ty, sizeof *tile_se);
    if (!tile_se) {
        pt_image_free(img);
        fprintf(stderr, "ptbench: out of memory\n");
        return 1;
    }
    printf("ptbench: %s, %ux%u, %u-pixel tiles; samples uniform needs / best allocation's,\n"
           "at equal error (variance of luminance from the reference, equal cost per sample)\n",
           argv[2], w, h, ts);
    for (int rel = 0; rel < 2; rel++) {
        double px_sum = 0, px_sqrt = 0, t_sqrt = 0; /* px_sum is also the tiles' sum */
        for (uint32_t y0 = 0; y0 < h; y0 += ts)
            for (uint32_t x0 = 0; x0 < w; x0 += ts) {
                uint32_t m;
                double s = tile_error(img, NULL, rel, x0, y0, ts, &m, &px_sqrt);
                px_sum += s;
                t_sqrt += sqrt(m * s);
                tile_se[(y0 / ts) * tx + x0 / ts] = s;
            }
        double p = (double)w * h;
        qsort(tile_se, (size_t)tx * ty, sizeof *tile_se, cmp_double_desc);
        size_t worst = ((size_t)tx * ty + 19) / 20;
        double top = 0;
        for (size_t i = 0; i < worst; i++)
            top += tile_se[i];
        printf("%-7s per pixel %6.2fx   per tile %6.2fx   worst 5%% of tiles hold %4.1f%% of the "
               "squared error\n",
               rel ? "relMSE" : "RMSE", px_sqrt > 0 ? p * px_sum / (px_sqrt * px_sqrt) : 1.0,
               t_sqrt > 0 ? p * px_sum / (t_sqrt * t_sqrt) : 1.0,
               px_sum > 0 ? 100.0 * top / px_sum : 0.0);
    }
    if (meas)
        printf("from the measured error of %s (per tile, falling as 1/n):\n", argv[4]);
    for (int rel = 0; meas && rel < 2; rel++) {
        double t_sum = 0, t_sqrt = 0;
        for (uint32_t y0 = 0; y0 < h; y0 += ts)
            for (uint32_t x0 = 0; x0 < w; x0 += ts) {
                uint32_t m;
                double s = tile_error(img, meas, rel, x0, y0, ts, &m, NULL);
                t_sum += s;
                t_sqrt += sqrt(m * s);
            }
        double p = (double)w * h;
        printf("%-7s per tile %6.2fx\n", rel ? "relMSE" : "RMSE",
               t_sqrt > 0 ? p * t_sum / (t_sqrt * t_sqrt) : 1.0);
    }
    pt_free(tile_se);
    pt_image_free(meas);
    pt_image_free(img);
    return 0;
}

static int cmd_plot(int argc, char **argv)
{
    if (argc < 4) {
        usage(stderr);
        return 2;
    }
    static plot p;
    plot_init(&p);
    pt_error err = {0};
    /* --y COLUMN (default rmse) and --title TEXT before the CSVs */
    const char *ycol = "rmse";
    int i = 3;
    for (; i + 1 < argc && (!strcmp(argv[i], "--y") || !strcmp(argv[i], "--title")); i += 2) {
        if (!strcmp(argv[i], "--y")) {
            ycol = argv[i + 1];
            /* MSE-like columns fall as 1/time */
            p.squared = strstr(ycol, "mse") != NULL && strstr(ycol, "rmse") == NULL;
            snprintf(p.ylabel, sizeof p.ylabel, "%s", ycol);
            snprintf(p.title, sizeof p.title, "%s AGAINST RENDER TIME", ycol);
        } else {
            snprintf(p.title, sizeof p.title, "%s", argv[i + 1]);
        }
    }
    if (i >= argc) {
        usage(stderr);
        return 2;
    }
    for (; i < argc; i++)
        if (plot_read_csv(&p, argv[i], "seconds", ycol, &err) != PT_OK) {
            fprintf(stderr, "ptbench: %s\n", err.msg);
            return 1;
        }
    if (plot_write_png(&p, argv[2], PLOT_W, PLOT_H, &err) != PT_OK) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        return 1;
    }
    return 0;
}

typedef struct opts {
    const char *scene, *ref_path, *csv, *plot_path, *label;
    const char *series[MAX_SERIES_FILES];
    int num_series;
    int has_constant;
    double constant;
    double list[MAX_ROWS];
    int n, time_mode, adaptive; /* adaptive: 1 --target-error, 2 --min-gain */
    int bound;                  /* --bound: print_bound after each --spp row */
    uint32_t w, h, seed, max_depth, reps;
    uint32_t min_spp, max_spp, chunk, tile;
    int threads;
    const char *env_path; /* --env, as ptworker's */
    double env_strength, env_rotate;
    uint32_t light_select; /* PT_LIGHT_SELECT_* */
    int sa_on;             /* --solid-angle on */
} opts;

static int parse_opts(int argc, char **argv, opts *o)
{
    static const double default_spp[] = {1, 2, 4, 8, 16, 32, 64, 128, 256};
    memset(o, 0, sizeof *o);
    o->threads = 2;
    o->reps = 1;
    o->max_depth = 16;
    o->env_strength = 1.0;
    o->max_spp = 1024;
    o->chunk = 16;
    o->tile = 16;
    o->n = (int)(sizeof default_spp / sizeof default_spp[0]);
    memcpy(o->list, default_spp, sizeof default_spp);
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int bad = 0;
        uint32_t t;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        } else if (!strcmp(a, "--version")) {
            exit(pt_version_print("ptbench"));
        } else if (!strcmp(a, "--bound")) {
            o->bound = 1;
            continue;
        } else if (a[0] != '-') {
            if (o->scene)
                bad = 1;
            o->scene = a;
            continue;
        } else if (!v) {
            bad = 1;
        } else if (!strcmp(a, "--reference")) {
            o->ref_path = v;
        } else if (!strcmp(a, "--constant")) {
            o->has_constant = 1;
            bad = pt_opt_double(a, v, -DBL_MAX, DBL_MAX, &o->constant, NULL) != PT_OK;
        } else if (!strcmp(a, "--spp") || !strcmp(a, "--time") || !strcmp(a, "--target-error") ||
                   !strcmp(a, "--min-gain")) {
            o->time_mode = !strcmp(a, "--time");
            o->adaptive = !strcmp(a, "--target-error") ? 1 : !strcmp(a, "--min-gain") ? 2 : 0;
            o->n = parse_list(v, o->time_mode || o->adaptive, o->list);
            bad = o->n <= 0;
        } else if (!strcmp(a, "--res")) {
            bad = pt_opt_res(a, v, 16384, &o->w, &o->h, NULL) != PT_OK;
        } else if (!strcmp(a, "--threads")) {
            bad = pt_opt_u32(a, v, 1, MAX_THREADS, &t, NULL) != PT_OK;
            o->threads = (int)t;
        } else if (!strcmp(a, "--seed")) {
            bad = pt_opt_u32(a, v, 0, UINT32_MAX, &o->seed, NULL) != PT_OK;
        } else if (!strcmp(a, "--max-depth")) {
            bad = pt_opt_u32(a, v, 1, 1024, &o->max_depth, NULL) != PT_OK;
        } else if (!strcmp(a, "--reps")) {
            bad = pt_opt_u32(a, v, 1, MAX_REPS, &o->reps, NULL) != PT_OK;
        } else if (!strcmp(a, "--min-spp")) {
            bad = pt_opt_u32(a, v, 2, 1u << 24, &o->min_spp, NULL) != PT_OK;
        } else if (!strcmp(a, "--max-spp")) {
            bad = pt_opt_u32(a, v, 1, 1u << 24, &o->max_spp, NULL) != PT_OK;
        } else if (!strcmp(a, "--chunk")) {
            bad = pt_opt_u32(a, v, 1, 1u << 24, &o->chunk, NULL) != PT_OK;
        } else if (!strcmp(a, "--tile")) {
            bad = pt_opt_u32(a, v, 1, PT_TILE_MAX, &o->tile, NULL) != PT_OK;
        } else if (!strcmp(a, "--env")) {
            o->env_path = v;
        } else if (!strcmp(a, "--env-strength")) {
            bad = pt_opt_double(a, v, 0.0, 1e20, &o->env_strength, NULL) != PT_OK;
        } else if (!strcmp(a, "--env-rotate")) {
            bad = pt_opt_double(a, v, -1e6, 1e6, &o->env_rotate, NULL) != PT_OK;
        } else if (!strcmp(a, "--light-select")) {
            o->light_select = !strcmp(v, "auto")    ? PT_LIGHT_SELECT_AUTO
                              : !strcmp(v, "power") ? PT_LIGHT_SELECT_POWER
                              : !strcmp(v, "tree")  ? PT_LIGHT_SELECT_TREE
                                                    : UINT32_MAX;
            bad = o->light_select == UINT32_MAX;
        } else if (!strcmp(a, "--solid-angle")) {
            o->sa_on = !strcmp(v, "on");
            bad = !o->sa_on && strcmp(v, "off");
        } else if (!strcmp(a, "--label")) {
            o->label = v;
        } else if (!strcmp(a, "--csv")) {
            o->csv = v;
        } else if (!strcmp(a, "--plot")) {
            o->plot_path = v;
        } else if (!strcmp(a, "--plot-series")) {
            bad = o->num_series == MAX_SERIES_FILES;
            if (!bad)
                o->series[o->num_series++] = v;
        } else {
            bad = 1;
        }
        if (bad) {
            fprintf(stderr, "ptbench: bad argument '%s'%s%s (see --help)\n", a, v ? " " : "",
                    v ? v : "");
            return -1;
        }
        i++;
    }
    if (!o->scene || (!o->ref_path == !o->has_constant)) {
        fprintf(stderr, "ptbench: need a SCENE and one of --reference or --constant "
                        "(see --help)\n");
        return -1;
    }
    if (o->bound && (!o->ref_path || o->time_mode || o->adaptive)) {
        fprintf(stderr, "ptbench: --bound needs --reference and --spp rows (see --help)\n");
        return -1;
    }
    if (!o->min_spp && !o->bound) /* ptworker's default; --bound: no floor unless asked */
        o->min_spp = o->chunk > 1 ? o->chunk : 2;
    return 0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int cmp_row_spp(const void *a, const void *b)
{
    const row *x = a, *y = b;
    return (x->spp > y->spp) - (x->spp < y->spp);
}

static double median(double *v, uint32_t n)
{
    qsort(v, n, sizeof v[0], cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* One --spp row: R timed renders of [0, spp); the median time; the image of
 * the last (every repetition renders the same bits). */
static int bench_spp(pass *ps, const opts *o, uint32_t spp, row *out)
{
    double secs[MAX_REPS], cpu[MAX_REPS];
    for (uint32_t k = 0; k < o->reps; k++) {
        reset(ps, o->threads);
        double t0 = pt_now_s(), c0 = pt_cpu_s();
        if (run_pass(ps, o->threads, 0, spp) != 0)
            return -1;
        secs[k] = pt_now_s() - t0;
        cpu[k] = pt_cpu_s() - c0;
    }
    out->spp = spp;
    out->target = out->min_gain = 0.0;
    out->seconds = median(secs, o->reps);
    out->cpu = median(cpu, o->reps);
    out->st = total_stats(ps, o->threads);
    return 0;
}

/* One --time row: passes of growing sample counts until the next pass would
 * overrun the budget, as predicted from the rate measured so far. */
static int bench_time_once(pass *ps, const opts *o, double budget, row *out)
{
    reset(ps, o->threads);
    uint32_t s = 0;
    double t0 = pt_now_s(), c0 = pt_cpu_s(), el = 0.0;
    for (;;) {
        uint32_t chunk = s ? s : 1;
        if (s) {
            double per_spp = el / s, fit = floor((budget - el) / per_spp);
            if (fit < 1.0)
                break;
            if (fit < chunk)
                chunk = (uint32_t)fit;
        }
        if (s + chunk > (1u << 24))
            break;
        if (run_pass(ps, o->threads, s, s + chunk) != 0)
            return -1;
        s += chunk;
        el = pt_now_s() - t0;
    }
    out->spp = s;
    out->target = out->min_gain = 0.0;
    out->seconds = el;
    out->cpu = pt_cpu_s() - c0;
    out->st = total_stats(ps, o->threads);
    return 0;
}

/* One --target-error or --min-gain row (value): R timed adaptive renders (each
 * the same bits); the median time. */
static int bench_adaptive(pass *ps, const opts *o, double value, row *out)
{
    double secs[MAX_REPS], cpu[MAX_REPS];
    double target = o->adaptive == 1 ? value : 0.0, min_gain = o->adaptive == 2 ? value : 0.0;
    ps->rule = (pt_adaptive){target, min_gain, o->min_spp};
    ps->chunk = o->chunk;
    for (uint32_t k = 0; k < o->reps; k++) {
        reset(ps, o->threads);
        double t0 = pt_now_s(), c0 = pt_cpu_s();
        int bad = run_pass(ps, o->threads, 0, o->max_spp);
        secs[k] = pt_now_s() - t0;
        cpu[k] = pt_cpu_s() - c0;
        if (bad) {
            ps->rule = (pt_adaptive){0.0, 0.0, 0};
            return -1;
        }
    }
    ps->rule = (pt_adaptive){0.0, 0.0, 0};
    out->spp = o->max_spp;
    out->target = target;
    out->min_gain = min_gain;
    out->seconds = median(secs, o->reps);
    out->cpu = median(cpu, o->reps);
    out->st = total_stats(ps, o->threads);
    return 0;
}

/* --bound: what the best allocation of samples to tiles could win in time, from
 * a uniform render of spp samples (img, against the reference ref) and the CPU
 * seconds tile_cpu[t] of its tiles (summed over reps renders). Tile t's squared
 * error (R, G, B as the metrics count them; rel: relative) is taken to fall as
 * R_t / n, with R_t its squared error times spp, and its cost as c_t n, with
 * c_t its CPU seconds per sample per pixel. Spending n_t samples per pixel on
 * tile t costs sum_t c_t n_t for the error sum_t R_t / n_t; the least cost for
 * uniform sampling's error is at n_t ~ sqrt(R_t / c_t) (Lagrange, as Neyman's
 * allocation to strata of unequal cost: Cochran, Sampling Techniques, 3rd
 * ed., 1977, sec. 5.5), uniform / best = sum c * sum R / (sum sqrt(R c))^2.
 * Printed with it: the time that the samples' optimum n_t ~ sqrt(R_t / m_t)
 * (m_t pixels, equal cost) takes, which is what a rule blind to cost aims at;
 * with min_spp, the best allocation that gives every tile at least min_spp
 * samples (n_t = max(min_spp, lambda sqrt(R_t / c_t)), lambda by bisection to
 * uniform sampling's error); and the share of tiles without error. */
static int print_bound(const pt_image *img, const pt_image *ref, const pt_rect *tiles,
                       uint32_t num_tiles, const double *tile_cpu, uint32_t reps, uint32_t spp,
                       uint32_t min_spp)
{
    double *R = pt_malloc_array(num_tiles, sizeof *R);
    if (!R) {
        fprintf(stderr, "ptbench: out of memory\n");
        return -1;
    }
    for (int rel = 0; rel < 2; rel++) {
        double sum_c = 0, sum_r = 0, sum_rc = 0, sum_rm = 0, sum_crm = 0, zero_c = 0;
        uint32_t zero = 0;
        for (uint32_t t = 0; t < num_tiles; t++) {
            pt_rect rc = tiles[t];
            double se = 0, m = (double)(rc.x1 - rc.x0) * (rc.y1 - rc.y0);
            for (uint32_t y = rc.y0; y < rc.y1; y++)
                for (uint32_t x = rc.x0; x < rc.x1; x++)
                    add_pixel_sq_error(img, ref, (size_t)y * img->width + x, rel, &se);
            double c = tile_cpu[t] / reps / spp;
            R[t] = se * spp;
            sum_c += c;
            sum_r += R[t];
            sum_rc += sqrt(R[t] * c);
            sum_rm += sqrt(R[t] * m);
            sum_crm += c * sqrt(R[t] / m);
            if (R[t] == 0) {
                zero++;
                zero_c += c;
            }
        }
        const char *name = rel ? "relMSE" : "RMSE";
        if (!(sum_r > 0 && sum_c > 0)) {
            printf("bound %s: no error to allocate\n", name);
            continue;
        }
        double e_u = sum_r / spp, t_u = sum_c * spp;
        printf("bound %-6s %4u spp: CPU %.2fx at n ~ sqrt(R/c), %.2fx at n ~ sqrt(R) (samples "
               "%.2fx)",
               name, spp, sum_c * sum_r / (sum_rc * sum_rc), sum_c * sum_r / (sum_rm * sum_crm),
               (double)img->width * img->height * sum_r / (sum_rm * sum_rm));
        if (min_spp) {
            /* The error falls as lambda grows. The floor only adds samples, so
             * lambda without it (lam) reaches e_u already; at lam * e^-40 every
             * tile is at the floor, which errs more than e_u unless the floor
             * alone is as good as uniform sampling. */
            double lam = sum_rc / e_u, lo = log(lam) - 40.0, hi = log(lam), t_m = 0;
            if (sum_r / min_spp <= e_u)
                hi = lo;
            for (int it = 0; it < 200 && hi > lo; it++) {
                double mid = 0.5 * (lo + hi), l = exp(mid), e = 0;
                for (uint32_t t = 0; t < num_tiles; t++) {
                    double c = tile_cpu[t] / reps / spp, n = l * sqrt(R[t] / c);
                    e += R[t] / (n > min_spp ? n : min_spp);
                }
                if (e > e_u)
                    lo = mid;
                else
                    hi = mid;
            }
            for (uint32_t t = 0; t < num_tiles; t++) {
                double c = tile_cpu[t] / reps / spp, n = exp(hi) * sqrt(R[t] / c);
                t_m += c * (n > min_spp ? n : min_spp);
            }
            printf(", %.2fx with >= %u spp", t_u / t_m, min_spp);
        }
        printf("; tiles without error: %u of %u, %.0f%% of the CPU time\n", zero, num_tiles,
               100.0 * zero_c / sum_c);
    }
    pt_free(R);
    return 0;
}

static int cmd_bench(int argc, char **argv)
{
    opts o;
    if (parse_opts(argc, argv, &o) != 0)
        return 2;
    pt_error err = {0};
    pt_scene *scene = NULL;
    pt_renderer *r = NULL;
    pt_env *env = NULL;
    pt_film *film = NULL;
    pt_image *img = NULL, *refimg = NULL;
    pt_rect *tiles = NULL;
    static pass ps;
    static plot pl;
    static row rows[MAX_ROWS], reps[MAX_REPS];
    int rc = 1;

    reference ref = {NULL, o.constant};
    if (o.ref_path) {
        if (pt_exr_read(o.ref_path, &refimg, NULL, &err) != PT_OK) {
            fprintf(stderr, "ptbench: %s\n", err.msg);
            goto done;
        }
        ref.img = refimg;
        if (!o.w) {
            o.w = refimg->width;
            o.h = refimg->height;
        } else if (o.w != refimg->width || o.h != refimg->height) {
            fprintf(stderr, "ptbench: --res %ux%u but the reference %s is %ux%u\n", o.w, o.h,
                    o.ref_path, refimg->width, refimg->height);
            rc = 2;
            goto done;
        }
    }
    if (pt_scene_load(o.scene, NULL, &scene, &err) != PT_OK) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        goto done;
    }
    if (!o.w) {
        o.w = 128;
        o.h = pt_camera_height(scene->camera.aspect, o.w, 16384);
    }
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = o.w;
    p.height = o.h;
    p.seed = o.seed;
    p.max_depth = o.max_depth;
    p.light_select = o.light_select | (o.sa_on ? PT_LIGHT_SOLID_ANGLE : 0u);
    if (o.env_path) {
        if (pt_env_load(o.env_path, (float)o.env_strength, (float)o.env_rotate, &env, &err) !=
            PT_OK) {
            fprintf(stderr, "ptbench: --env: %s\n", err.msg);
            goto done;
        }
        p.env = env;
    }
    if (pt_renderer_new(scene, &p, &r, &err) != PT_OK ||
        pt_film_new(o.w, o.h, &film, &err) != PT_OK ||
        pt_image_new(o.w, o.h, &img, &err) != PT_OK) {
        fprintf(stderr, "ptbench: %s\n", err.msg);
        goto done;
    }
    const uint32_t ts = o.tile;
    uint32_t tx = (o.w + ts - 1) / ts, ty = (o.h + ts - 1) / ts;
    tiles = pt_malloc_array((size_t)tx * ty, sizeof *tiles);
    if (!tiles) {
        fprintf(stderr, "ptbench: out of memory\n");
        goto done;
    }
    for (uint32_t y = 0; y < ty; y++)
        for (uint32_t x = 0; x < tx; x++)
            tiles[y * tx + x] = (pt_rect){x * ts, y * ts, (x + 1) * ts < o.w ? (x + 1) * ts : o.w,
                                          (y + 1) * ts < o.h ? (y + 1) * ts : o.h};
    ps.r = r;
    ps.film = film;
    ps.tiles = tiles;
    ps.num_tiles = tx * ty;
    if (o.bound && !(ps.tile_cpu = pt_malloc_array(ps.num_tiles, sizeof *ps.tile_cpu))) {
        fprintf(stderr, "ptbench: out of memory\n");
        goto done;
    }
    for (int i = 0; i < o.threads; i++)
        if (!(ps.scratch[i] = pt_malloc_array(ts * ts, sizeof(pt_pixel_acc))) ||
            !(ps.sum[i] = pt_malloc_array(ts * ts, sizeof(pt_pixel_acc)))) {
            fprintf(stderr, "ptbench: out of memory\n");
            goto done;
        }

    char label[PLOT_MAX_LABEL];
    if (o.label) {
        snprintf(label, sizeof label, "%s", o.label);
    } else {
        snprintf(label, sizeof label, "%s", basename_of(o.scene));
        char *dot = strrchr(label, '.');
        if (dot && dot != label)
            *dot = '\0';
    }
    csv_safe(label);
    printf("ptbench: %s, %ux%u, %d threads, seed %u, max depth %u, variant %s, %u rep%s\n", o.scene,
           o.w, o.h, o.threads, o.seed, o.max_depth, pt_renderer_variant(r), o.reps,
           o.reps == 1 ? "" : "s");
    if (o.adaptive)
        printf("ptbench: adaptive, tile %u, chunk %u, min spp %u, max spp %u\n", o.tile, o.chunk,
               o.min_spp, o.max_spp);
    if (ref.img)
        printf("ptbench: reference %s\n", o.ref_path);
    else
        printf("ptbench: constant reference %g\n", ref.value);
    print_header();
    for (int i = 0; i < o.n; i++) {
        row *rw = &rows[i];
        int bad;
        if (o.time_mode) {
            for (uint32_t k = 0; k < o.reps; k++)
                if (bench_time_once(&ps, &o, o.list[i], &reps[k]) != 0)
                    goto nothreads;
            qsort(reps, o.reps, sizeof reps[0], cmp_row_spp);
            *rw = reps[o.reps / 2];
            /* The film holds the last repetition: render the chosen one's
             * samples again for its image (equal up to the rounding of sums). */
            bad = 0;
            if (o.reps > 1) {
                reset(&ps, o.threads);
                bad = run_pass(&ps, o.threads, 0, rw->spp);
            }
        } else if (o.adaptive) {
            bad = bench_adaptive(&ps, &o, o.list[i], rw);
        } else {
            if (ps.tile_cpu)
                memset(ps.tile_cpu, 0, ps.num_tiles * sizeof *ps.tile_cpu);
            bad = bench_spp(&ps, &o, (uint32_t)o.list[i], rw);
        }
        if (bad)
            goto nothreads;
        rw->mean_spp = (double)pt_film_total_samples(film) / ((double)o.w * o.h);
        pt_film_resolve(film, img);
        if (score(img, &ref, &rw->m, &err) != PT_OK) {
            fprintf(stderr, "ptbench: %s\n", err.msg);
            goto done;
        }
        print_row(rw);
        if (ps.tile_cpu && print_bound(img, refimg, tiles, ps.num_tiles, ps.tile_cpu, o.reps,
                                       (uint32_t)o.list[i], o.min_spp) != 0)
            goto done;
        fflush(stdout);
        if (rw->m.nonfinite || rw->st.rejected)
            fprintf(stderr, "ptbench: %llu non-finite values in the image, %llu rejected samples\n",
                    (unsigned long long)rw->m.nonfinite, (unsigned long long)rw->st.rejected);
    }
    if (o.csv &&
        write_csv(o.csv, label, basename_of(o.scene), o.w, o.h, o.threads, o.seed, rows, o.n) != 0)
        goto done;
    if (o.plot_path) {
        plot_init(&pl);
        for (int i = 0; i < o.num_series; i++)
            if (plot_read_csv(&pl, o.series[i], "seconds", "rmse", &err) != PT_OK) {
                fprintf(stderr, "ptbench: %s\n", err.msg);
                goto done;
            }
        plot_series *s = plot_series_get(&pl, label);
        for (int i = 0; s && i < o.n; i++)
            plot_series_add(s, rows[i].seconds, rows[i].m.rmse);
        if (!s || plot_write_png(&pl, o.plot_path, PLOT_W, PLOT_H, &err) != PT_OK) {
            fprintf(stderr, "ptbench: %s\n", s ? err.msg : "too many series to plot");
            goto done;
        }
    }
    rc = 0;
    goto done;
nothreads:
    fprintf(stderr, "ptbench: cannot start render threads\n");
done:
    for (int i = 0; i < MAX_THREADS; i++) {
        pt_free(ps.scratch[i]);
        pt_free(ps.sum[i]);
        ps.scratch[i] = ps.sum[i] = NULL;
    }
    pt_free(ps.tile_cpu);
    ps.tile_cpu = NULL;
    pt_free(tiles);
    pt_image_free(img);
    pt_image_free(refimg);
    pt_film_free(film);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(scene);
    return rc;
}

int main(int argc, char **argv)
{
    if (argc >= 2 && !strcmp(argv[1], "error"))
        return cmd_error(argc, argv);
    if (argc >= 2 && !strcmp(argv[1], "plot"))
        return cmd_plot(argc, argv);
    if (argc >= 2 && !strcmp(argv[1], "gain"))
        return cmd_gain(argc, argv);
    return cmd_bench(argc, argv);
}
