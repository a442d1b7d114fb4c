/*
 * ptbench-paths - which paths make an image's fireflies.
 *
 *   ptbench-paths SCENE --reference REF.exr [--env HDR | --background R,G,B]
 *                 [--camera NAME | --camera-from X,Y,Z --camera-at X,Y,Z [--fov DEG]]
 *                 [--res WxH] [--spp N] [--seed S] [--max-depth D]
 *                 [--worst FRACTION] [--top K] [--pixel X,Y] [--guiding on|off]
 *
 * Renders SCENE sample by sample (pt_render_sample_guided, one thread:
 * the samples ptworker --guiding off takes, or with --guiding on those of
 * ptworker --guiding on, pass by pass, each pass's records building the
 * next pass's guide through guide_run.h, every guide kept so that a logged
 * sample is rendered again with its own), scores each pixel's mean
 * against REF as relMSE counts it (common/image/metrics.h) and takes the
 * worst FRACTION of pixels (default 0.001). For each of them it renders its
 * K largest samples (by luminance) again with the path log on and prints
 * every event of the path (common/render/path_trace.h): each bounce's
 * material, lobe, pdf and weight, each light sample's pdfs and MIS weight and
 * what it added, each emitter or environment hit with its MIS weight. Last,
 * a table of the events that carried those samples' radiance, grouped by
 * the technique and the lobes the path took, weighed by their share of the
 * worst pixels' squared error, and the same shares by technique (NEE; a
 * BSDF-sampled hit; a caustic, a BSDF-sampled hit through smooth bounces
 * after a rough one), the BSDF hits no rough bounce came before (seen
 * from the camera directly or through smooth bounces only: no light sample
 * or guide reaches them), the caustics by the smooth bounces between their
 * last rough vertex and the light (1, 2, 3 or more) and by what that vertex
 * has on its camera side (the camera, a rough vertex, smooth bounces), and
 * by the number of
 * bounces before the light was found. --pixel X,Y renders that
 * pixel alone (its share is then of its own squared error): a glint that a
 * few of many samples find, seen at the reference's sample count. Guided,
 * the log shows each guided vertex (its chance to draw from the guide, the
 * guide's and the BSDF's pdfs at the direction taken, which of them drew
 * it), and the summary splits the caustics' share by the rough vertex they
 * left from: not offered the guide, in pass 0, offered with probability 0,
 * or guided, by the guide's pdf over the BSDF's there.
 *
 * Built with its own copy of render.c and closure.c compiled with
 * PT_PATH_TRACE (tests/bench/CMakeLists.txt): the log costs the renderer
 * that users run nothing. The reference must come from another seed.
 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/error.h"
#include "common/base/opt.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/metrics.h"
#include "common/render/closure.h"
#include "common/render/env.h"
#include "common/render/guide.h"
#include "common/render/guide_run.h"
#include "common/render/guide_sched.h"
#include "common/render/light.h"
#include "common/render/path_trace.h"
#include "common/render/render.h"
#include "common/scene/scene.h"

#define MAX_EVENTS 256
/* A bounce whose pdf at its direction is at least this counts as smooth
 * (a near-mirror lobe: GGX alpha below about 0.03) in the summary. */
#define SMOOTH_PDF 100.0f
#define MAX_TOP 16

typedef struct event {
    int kind;
    uint32_t depth;
    int32_t mat, lobe;
    int delta;
    float a, b, c;
    pt_vec3 v;
} event;

static _Thread_local event ev[MAX_EVENTS];
static _Thread_local uint32_t nev;
static _Thread_local int32_t last_lobe = -1;

void pt_trace_event(int kind, uint32_t depth, int32_t mat, int32_t lobe, int delta, float a,
                    float b, float c, pt_vec3 v)
{
    if (kind == PT_TRACE_BOUNCE) {
        lobe = last_lobe;
        last_lobe = -1;
        /* A direction the guide drew: no lobe was sampled. */
        if (nev > 0 && ev[nev - 1].kind == PT_TRACE_GUIDE && ev[nev - 1].delta)
            lobe = -2;
    }
    if (nev < MAX_EVENTS)
        ev[nev++] = (event){kind, depth, mat, lobe, delta, a, b, c, v};
}

void pt_trace_lobe(uint32_t kind)
{
    last_lobe = (int32_t)kind;
}

static const char *lobe_name(int32_t k)
{
    if (k == -1)
        return "lambert"; /* a Lambert variant: no closure */
    if (k == -2)
        return "guide"; /* drawn from the guide (--guiding on) */
    static const char *names[] = {"diffuse",      "specular",       "dielectric",
                                  "sheen",        "coat",           "specular-irid",
                                  "diffuse-irid", "specular-aniso", "diffuse-transmit",
                                  "aniso-irid",   "dt-irid"};
    if (k < 0 || k >= (int32_t)(sizeof names / sizeof names[0]))
        return "?";
    return names[k];
}

static const char *light_name(int32_t k)
{
    switch (k) {
    case PT_LIGHT_AREA:
        return "emitter";
    case PT_LIGHT_AT:
        return "point";
    case PT_LIGHT_FAR:
        return "directional";
    case PT_LIGHT_ENV:
        return "env";
    }
    return "?";
}

typedef struct sample_rec {
    uint32_t index;
    float lum;
} sample_rec;

typedef struct pixel_rec {
    double sum[3];
    sample_rec top[MAX_TOP];
    uint32_t ntop;
    double err;
    uint32_t i;
} pixel_rec;

/* --pixel: the first bounce's environment light samples by their pdf, in
 * bands (the sun's core texels, their fringe, the sky): how many were taken,
 * how many reached the light, and what they added. */
#define NBANDS 3
static const float band_min[NBANDS] = {3000.0f, 100.0f, 0.0f};
static const char *band_name[NBANDS] = {"pdf >= 3000", "100 .. 3000", "< 100"};
typedef struct band {
    uint64_t taken, unblocked;
    double added;
} band;

static void tally_nee(band *b)
{
    for (uint32_t k = 0; k < nev; k++) {
        const event *e = &ev[k];
        if (e->kind != PT_TRACE_NEE || e->depth != 0 || e->lobe != PT_LIGHT_ENV)
            continue;
        int i = 0;
        while (i < NBANDS - 1 && !(e->a >= band_min[i]))
            i++;
        b[i].taken++;
        for (uint32_t j = k + 1; j < nev; j++)
            if (ev[j].kind == PT_TRACE_SHADOW && ev[j].v.x == e->v.x && ev[j].v.y == e->v.y &&
                ev[j].v.z == e->v.z) {
                b[i].unblocked++;
                b[i].added += pt_luminance(e->v);
                break;
            }
        return;
    }
}

static int cmp_err_desc(const void *a, const void *b)
{
    double x = ((const pixel_rec *)a)->err, y = ((const pixel_rec *)b)->err;
    return (x < y) - (x > y);
}

/* The path signature that carried a contribution: its lobes from the camera
 * up to the event, then the technique. */
#define MAX_SIGS 256
typedef struct sig {
    char text[200];
    double share;
    uint32_t count;
} sig;
static sig sigs[MAX_SIGS];
static uint32_t nsigs;
/* The same shares by technique: NEE; a BSDF-sampled hit; a BSDF-sampled
 * hit after a rough bounce and then a smooth one (a caustic). */
static double by_kind[3];
/* The BSDF hits no rough bounce came before: the light seen from the
 * camera directly (by_camera[0]) or through smooth bounces only
 * (by_camera[1]), which no light sample and no guide can reach (only more
 * of the pixel's positions resolve them). */
static double by_camera[2];
/* The caustics by the smooth bounces between their last rough vertex and
 * the light: 1, 2, 3 or more (a manifold walk through one or two smooth
 * interfaces reaches the first two). */
#define CHAIN_BINS 3
static double by_chain[CHAIN_BINS];
/* And by what their last rough vertex D has on its camera side, which
 * decides the estimator that could sample them other than by chance
 * (docs/bench/issue30.md, "Which estimator could take what is left"): the
 * camera itself (light tracing joins D to the camera), a rough vertex
 * (bidirectional path tracing joins the two), or smooth bounces (E S+ D S+
 * L: no join of two rough vertices samples it; only merging light and
 * camera paths near D, or a chain solved through the smooth bounces). A
 * thin wall crossed straight counts as nothing: a join crosses it too. */
#define SIDE_BINS 3
static double by_side[SIDE_BINS];
/* And by the bounces before the event that added it: 0 to 4, 5 to 8, 9 and
 * more. */
#define DEPTH_BINS 7
static double by_depth[DEPTH_BINS];
/* --guiding on: the caustics' shares (by_kind[2]) by the rough vertex the
 * path left towards the light from (its last rough bounce): not offered the
 * guide (not guidable, or past the path's first guided vertices); in pass
 * 0, which draws nothing from its guide; offered with probability 0 later
 * (its cell unlearned or its lobes too narrow); guided, by the guide's pdf
 * over the BSDF's at the direction taken: below 0.5, 0.5 to 2, 2 to 10, 10
 * and above. */
#define GUIDE_BINS 7
static double by_guide[GUIDE_BINS];
static const char *guide_bin_name[GUIDE_BINS] = {"not offered the guide",
                                                 "pass 0",
                                                 "probability 0",
                                                 "guide/BSDF pdf < 0.5",
                                                 "0.5 .. 2",
                                                 "2 .. 10",
                                                 ">= 10"};
static uint32_t log_pass; /* the pass of the sample being classified */

static int guide_bin(const event *g)
{
    if (!g)
        return 0;
    if (!(g->a > 0.0f))
        return log_pass == 0 ? 1 : 2;
    float ratio = g->c > 0.0f ? g->b / g->c : INFINITY;
    return ratio < 0.5f ? 3 : ratio < 2.0f ? 4 : ratio < 10.0f ? 5 : 6;
}

static void add_depth(uint32_t bounces, double share)
{
    by_depth[bounces <= 4 ? bounces : bounces <= 8 ? 5 : 6] += share;
}

static void add_sig(const char *text, double share)
{
    for (uint32_t i = 0; i < nsigs; i++)
        if (!strcmp(sigs[i].text, text)) {
            sigs[i].share += share;
            sigs[i].count++;
            return;
        }
    if (nsigs < MAX_SIGS) {
        snprintf(sigs[nsigs].text, sizeof sigs[nsigs].text, "%s", text);
        sigs[nsigs].share = share;
        sigs[nsigs].count = 1;
        nsigs++;
    }
}

static int cmp_sig_desc(const void *a, const void *b)
{
    double x = ((const sig *)a)->share, y = ((const sig *)b)->share;
    return (x < y) - (x > y);
}

static void print_events(const pt_scene *s)
{
    for (uint32_t k = 0; k < nev; k++) {
        const event *e = &ev[k];
        const char *mat =
            e->mat >= 0 && (uint32_t)e->mat < s->num_materials ? s->materials[e->mat].name : "-";
        float lum = pt_luminance(e->v);
        switch (e->kind) {
        case PT_TRACE_BOUNCE:
            printf("      d%u bounce  %-24s %-16s%s pdf %.4g wo.z %.3f wi.z %.3f weight %.4g\n",
                   e->depth, mat, lobe_name(e->lobe), e->delta ? " delta" : "", e->a, e->b, e->c,
                   lum);
            break;
        case PT_TRACE_NEE:
            printf("      d%u nee     %-24s %-16s light pdf %.4g bsdf pdf %.4g mis %.4f -> %.4g\n",
                   e->depth, mat, light_name(e->lobe), e->a, e->b, e->c, lum);
            break;
        case PT_TRACE_SHADOW:
            printf("      d%u   unblocked, adds %.4g\n", e->depth, lum);
            break;
        case PT_TRACE_EMIT:
            printf("      d%u emitter %-24s bsdf pdf %.4g light pdf %.4g mis %.4f adds %.4g\n",
                   e->depth, mat, e->a, e->b, e->c, lum);
            break;
        case PT_TRACE_ENV:
            printf("      d%u env hit bsdf pdf %.4g env pdf %.4g mis %.4f adds %.4g\n", e->depth,
                   e->a, e->b, e->c, lum);
            break;
        case PT_TRACE_GUIDE:
            printf("      d%u guided  %-24s %-16s prob %.3g guide pdf %.4g bsdf pdf %.4g\n",
                   e->depth, mat, e->delta ? "from the guide" : "from the BSDF", e->a, e->b, e->c);
            break;
        }
    }
}

/* A BSDF hit's share into by_camera or by_chain (smooth: the smooth
 * bounces since the last rough one, or since the camera). */
static void add_hit(int rough, uint32_t bounces, uint32_t smooth, double share)
{
    if (rough && smooth > 0)
        by_chain[smooth < CHAIN_BINS ? smooth - 1 : CHAIN_BINS - 1] += share;
    else if (!rough)
        by_camera[bounces > 0] += share;
}

/* Adds each contributing event's share (its part of the sample's luminance
 * times the sample's share) to the signature table. */
static void classify(const pt_scene *s, double share, float total)
{
    char path[200] = "";
    size_t len = 0, nee_len = 0;
    const event *nee = NULL;
    /* A rough bounce, then only smooth ones since it (smooth_run of them):
     * light found now is a caustic's (no light sample can reach it through
     * the smooth ones). */
    int rough = 0;
    uint32_t bounces = 0, nee_bounces = 0, smooth_run = 0;
    /* The vertex before the current one (0 the camera, 1 rough, 2 smooth)
     * and, for the caustic, the last rough vertex's (side). */
    int before = 0, side = 0;
    /* The GUIDE event before the next bounce, and the last rough bounce's. */
    const event *guided = NULL, *leave = NULL;
    for (uint32_t k = 0; k < nev; k++) {
        const event *e = &ev[k];
        const char *mat =
            e->mat >= 0 && (uint32_t)e->mat < s->num_materials ? s->materials[e->mat].name : "-";
        char text[400];
        float lum = pt_luminance(e->v);
        switch (e->kind) {
        case PT_TRACE_BOUNCE:
            if (len < sizeof path - 1)
                len += (size_t)snprintf(path + len, sizeof path - len, "%s:%s%s > ", mat,
                                        lobe_name(e->lobe),
                                        e->delta             ? "(delta)"
                                        : e->a >= SMOOTH_PDF ? "(smooth)"
                                                             : "");
            if (len >= sizeof path)
                len = sizeof path - 1;
            bounces++;
            if (!e->delta && e->a < SMOOTH_PDF) {
                rough = 1;
                leave = guided;
                smooth_run = 0;
                side = before;
                before = 1;
            } else {
                smooth_run++;
                /* straight through a thin wall: wi = -wo */
                if (!(e->delta && e->c == -e->b))
                    before = 2;
            }
            guided = NULL;
            break;
        case PT_TRACE_GUIDE:
            guided = e;
            break;
        case PT_TRACE_NEE:
            nee = e;
            nee_len = len;
            nee_bounces = bounces;
            break;
        case PT_TRACE_SHADOW:
            if (nee && total > 0.0f) {
                const char *nm = nee->mat >= 0 && (uint32_t)nee->mat < s->num_materials
                                     ? s->materials[nee->mat].name
                                     : "-";
                /* The bounces logged so far include the one after this NEE
                 * vertex; the NEE is at nee->depth. */
                snprintf(text, sizeof text, "%.*s| NEE %s at %s", (int)nee_len, path,
                         light_name(nee->lobe), nm);
                add_sig(text, share * lum / total);
                by_kind[0] += share * lum / total;
                add_depth(nee_bounces, share * lum / total);
            }
            break;
        case PT_TRACE_EMIT:
            snprintf(text, sizeof text, "%s| BSDF hit emitter %s", path, mat);
            if (total > 0.0f) {
                add_sig(text, share * lum / total);
                int caustic = rough && smooth_run > 0;
                by_kind[caustic ? 2 : 1] += share * lum / total;
                add_hit(rough, bounces, smooth_run, share * lum / total);
                if (caustic) {
                    by_guide[guide_bin(leave)] += share * lum / total;
                    by_side[side] += share * lum / total;
                }
                add_depth(bounces, share * lum / total);
            }
            break;
        case PT_TRACE_ENV:
            snprintf(text, sizeof text, "%s| BSDF hit env", path);
            if (total > 0.0f) {
                add_sig(text, share * lum / total);
                int caustic = rough && smooth_run > 0;
                by_kind[caustic ? 2 : 1] += share * lum / total;
                add_hit(rough, bounces, smooth_run, share * lum / total);
                if (caustic) {
                    by_guide[guide_bin(leave)] += share * lum / total;
                    by_side[side] += share * lum / total;
                }
                add_depth(bounces, share * lum / total);
            }
            break;
        }
    }
}

static void usage(void)
{
    fprintf(stderr, "usage: ptbench-paths SCENE --reference REF.exr [--env HDR | --background "
                    "R,G,B]\n"
                    "       [--camera NAME | --camera-from X,Y,Z --camera-at X,Y,Z [--fov DEG]]\n"
                    "       [--res WxH] [--spp N] [--seed S] [--max-depth D] [--worst F] [--top "
                    "K] [--pixel X,Y]\n"
                    "       [--guiding on|off]\n");
}

int main(int argc, char **argv)
{
    const char *scene_path = NULL, *ref_path = NULL, *env_path = NULL, *camera = NULL;
    uint32_t w = 128, h = 128, spp = 256, seed = 1, max_depth = PT_RENDER_DEFAULT_MAX_DEPTH,
             top = 4;
    double worst = 0.001, bg[3];
    int has_bg = 0, guiding = 0;
    long pix_x = -1, pix_y = -1; /* --pixel: that pixel alone */
    pt_error err = {0};
    pt_status st = PT_OK;
    /* A view of one's own, as ptworker takes it (the benchmark's view of a
     * scene without a camera). */
    pt_camera_look_opts look = {0};
    char look_text[sizeof((pt_camera *)0)->name];
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (a[0] != '-') {
            scene_path = a;
            continue;
        }
        if (!v) {
            usage();
            return 2;
        }
        i++;
        if (!strcmp(a, "--reference"))
            ref_path = v;
        else if (!strcmp(a, "--env"))
            env_path = v;
        else if (!strcmp(a, "--background")) {
            st = pt_opt_rgb(a, v, 1e6, bg, &err);
            has_bg = 1;
        } else if (!strcmp(a, "--camera"))
            camera = v;
        else if (!strcmp(a, "--camera-from") || !strcmp(a, "--camera-at") || !strcmp(a, "--fov"))
            st = pt_camera_look_option(&look, a, v, &err);
        else if (!strcmp(a, "--res"))
            st = pt_opt_res(a, v, 16384, &w, &h, &err);
        else if (!strcmp(a, "--spp"))
            st = pt_opt_u32(a, v, 1, 1u << 20, &spp, &err);
        else if (!strcmp(a, "--seed"))
            st = pt_opt_u32(a, v, 0, UINT32_MAX, &seed, &err);
        else if (!strcmp(a, "--max-depth"))
            st = pt_opt_u32(a, v, 1, 1u << 16, &max_depth, &err);
        else if (!strcmp(a, "--top"))
            st = pt_opt_u32(a, v, 1, MAX_TOP, &top, &err);
        else if (!strcmp(a, "--pixel")) {
            char *end;
            pix_x = strtol(v, &end, 10);
            if (*end == ',')
                pix_y = strtol(end + 1, &end, 10);
            if (*end != '\0' || pix_x < 0 || pix_y < 0) {
                fprintf(stderr, "ptbench-paths: --pixel wants X,Y (integers >= 0), not %s\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--guiding")) {
            if (strcmp(v, "on") && strcmp(v, "off")) {
                fprintf(stderr, "ptbench-paths: --guiding wants on or off, not %s\n", v);
                return 2;
            }
            guiding = !strcmp(v, "on");
        } else if (!strcmp(a, "--worst"))
            st = pt_opt_double(a, v, 0.0, 1.0, &worst, &err);
        else {
            usage();
            return 2;
        }
        if (st != PT_OK) {
            fprintf(stderr, "ptbench-paths: %s\n", err.msg);
            return 2;
        }
    }
    if (!scene_path || !ref_path || (env_path && has_bg)) {
        usage();
        return 2;
    }
    int placed = 0;
    if (pt_camera_look_finish(&look, camera, look_text, sizeof look_text, &placed, &err) != PT_OK) {
        fprintf(stderr, "ptbench-paths: %s\n", err.msg);
        return 2;
    }
    if (placed)
        camera = look_text;

    int rc = 1;
    pt_scene *scene = NULL;
    pt_env *env = NULL;
    pt_renderer *r = NULL;
    pt_image *ref = NULL;
    pixel_rec *px = NULL;
    band bands[NBANDS] = {{0}};
    /* --guiding on: each pass's guide (guide_sched.h), kept to render the
     * logged samples again with the guide they were drawn with. */
    enum { MAX_PASSES = 32 };
    pt_guide *guides[MAX_PASSES] = {NULL};
    pt_guide_run run;
    memset(&run, 0, sizeof run);
    pt_scene_opts so = {0};
    so.camera_name = camera;
    if (pt_exr_read(ref_path, &ref, NULL, &err) != PT_OK ||
        pt_scene_load(scene_path, &so, &scene, &err) != PT_OK ||
        (env_path && pt_env_load(env_path, 1.0f, 0.0f, &env, &err) != PT_OK) ||
        (has_bg &&
         pt_env_uniform(pt_v3((float)bg[0], (float)bg[1], (float)bg[2]), &env, &err) != PT_OK)) {
        fprintf(stderr, "ptbench-paths: %s\n", err.msg);
        goto done;
    }
    if (ref->width != w || ref->height != h) {
        fprintf(stderr, "ptbench-paths: the reference is %ux%u, --res %ux%u\n", ref->width,
                ref->height, w, h);
        goto done;
    }
    if (pix_x >= 0 && (pix_x >= (long)w || pix_y >= (long)h)) {
        fprintf(stderr, "ptbench-paths: --pixel %ld,%ld is outside the %ux%u image\n", pix_x, pix_y,
                w, h);
        goto done;
    }
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = seed;
    p.max_depth = max_depth;
    p.env = env;
    p.guiding = (uint32_t)guiding;
    if (pt_renderer_new(scene, &p, &r, &err) != PT_OK) {
        fprintf(stderr, "ptbench-paths: %s\n", err.msg);
        goto done;
    }
    size_t n = (size_t)w * h;
    if (!(px = pt_calloc(n, sizeof *px))) {
        fprintf(stderr, "ptbench-paths: out of memory\n");
        goto done;
    }
    /* The first guide as ptworker makes it (pt_guide_run_new's bounds). */
    if (guiding &&
        pt_guide_run_new(&run, scene->bounds_min, scene->bounds_max, spp, 1, 0, &err) != PT_OK) {
        fprintf(stderr, "ptbench-paths: %s\n", err.msg);
        goto done;
    }
    /* The image, keeping each pixel's largest samples: pass by pass as
     * ptworker --guiding on renders it (one pass [0, spp) unguided), each
     * pass's records building the next pass's guide, each pass's guide
     * kept. */
    for (uint32_t pass = 0, s0 = 0; s0 < spp; pass++) {
        uint32_t s1 = spp;
        if (guiding) {
            if (pass + 1 >= MAX_PASSES || pt_guide_run_begin(&run, &err) != PT_OK) {
                fprintf(stderr, "ptbench-paths: %s\n",
                        pass + 1 >= MAX_PASSES ? "too many passes" : err.msg);
                goto done;
            }
            s1 = run.s1;
        }
        for (uint32_t y = 0; y < h; y++)
            for (uint32_t x = 0; x < w; x++) {
                pixel_rec *pr = &px[(size_t)y * w + x];
                pr->i = y * w + x;
                if (pix_x >= 0 && (x != (uint32_t)pix_x || y != (uint32_t)pix_y))
                    continue;
                for (uint32_t k = s0; k < s1; k++) {
                    nev = 0;
                    pt_vec3 L =
                        pt_render_sample_guided(r, x, y, k, NULL, NULL, guiding ? run.gd : NULL);
                    if (pix_x >= 0)
                        tally_nee(bands);
                    if (!(isfinite(L.x) && isfinite(L.y) && isfinite(L.z)))
                        continue; /* the film drops these too */
                    pr->sum[0] += L.x;
                    pr->sum[1] += L.y;
                    pr->sum[2] += L.z;
                    float lum = pt_luminance(L);
                    uint32_t j;
                    if (pr->ntop < top)
                        j = pr->ntop++;
                    else if (lum > pr->top[top - 1].lum)
                        j = top - 1;
                    else
                        continue;
                    pr->top[j] = (sample_rec){k, lum};
                    while (j > 0 && pr->top[j - 1].lum < pr->top[j].lum) {
                        sample_rec t = pr->top[j - 1];
                        pr->top[j - 1] = pr->top[j];
                        pr->top[j] = t;
                        j--;
                    }
                }
            }
        if (guiding && pt_guide_run_end(&run, &guides[pass], &err) != PT_OK) {
            fprintf(stderr, "ptbench-paths: %s\n", err.msg);
            goto done;
        }
        s0 = s1;
    }
    /* Each pixel's squared error as relMSE counts it. */
    const float *rc3[3] = {ref->r, ref->g, ref->b};
    double total = 0.0;
    for (size_t i = 0; i < n; i++) {
        double e = 0.0;
        for (int c = 0; c < 3; c++) {
            double m = px[i].sum[c] / spp, rv = rc3[c][i];
            double v = (m - rv) * (m - rv) / (rv * rv + PT_METRICS_REL_EPS);
            e += isfinite(v) ? v : 0.0;
        }
        if (pix_x >= 0 && px[i].i != (uint32_t)pix_y * w + (uint32_t)pix_x)
            e = 0.0; /* --pixel: not rendered */
        px[i].err = e;
        total += e;
    }
    qsort(px, n, sizeof *px, cmp_err_desc);
    size_t nw = (size_t)ceil(worst * (double)n);
    if (pix_x >= 0)
        nw = 1;
    if (nw < 1)
        nw = 1;
    double wsum = 0.0;
    for (size_t i = 0; i < nw; i++)
        wsum += px[i].err;
    printf("relMSE %.6g, worst %zu pixels hold %.4f of it\n", total / (3.0 * (double)n), nw,
           total > 0.0 ? wsum / total : 0.0);
    for (size_t i = 0; i < nw; i++) {
        pixel_rec *pr = &px[i];
        uint32_t x = pr->i % w, y = pr->i / w;
        float ref_lum = pt_luminance(pt_v3(ref->r[pr->i], ref->g[pr->i], ref->b[pr->i]));
        float mean_lum = pt_luminance(
            pt_v3((float)(pr->sum[0] / spp), (float)(pr->sum[1] / spp), (float)(pr->sum[2] / spp)));
        double share = total > 0.0 ? pr->err / total : 0.0;
        printf("pixel %u,%u: mean %.4g ref %.4g, share of the squared error %.4f\n", x, y, mean_lum,
               ref_lum, share);
        /* The pixel's excess over the reference, spread over its top samples
         * by their luminance above the reference. */
        double excess = 0.0;
        for (uint32_t k = 0; k < pr->ntop; k++)
            excess += fmax(pr->top[k].lum - ref_lum, 0.0);
        for (uint32_t k = 0; k < pr->ntop; k++) {
            nev = 0;
            last_lobe = -1;
            uint32_t pass = guiding ? pt_guide_pass_of(pr->top[k].index, spp) : 0;
            pt_render_guiding gd = {guides[pass], pt_guide_pass_prob(pass), NULL};
            log_pass = pass;
            pt_vec3 L = pt_render_sample_guided(r, x, y, pr->top[k].index, NULL, NULL,
                                                guiding ? &gd : NULL);
            float lum = pt_luminance(L);
            printf("    sample %u: L %.4g %.4g %.4g (lum %.4g, /spp %.4g)\n", pr->top[k].index, L.x,
                   L.y, L.z, lum, lum / spp);
            print_events(scene);
            double sshare =
                excess > 0.0 ? share * fmax(pr->top[k].lum - ref_lum, 0.0) / excess : 0.0;
            classify(scene, sshare, lum);
        }
    }
    qsort(sigs, nsigs, sizeof sigs[0], cmp_sig_desc);
    printf("\nshare of the whole image's squared error, by the path that carried it:\n");
    for (uint32_t i = 0; i < nsigs && i < 40; i++)
        printf("  %.4f  %4u  %s\n", sigs[i].share, sigs[i].count, sigs[i].text);
    printf("by technique: NEE %.4f, BSDF hit %.4f, BSDF hit through a smooth bounce after a "
           "rough one (caustic) %.4f\n",
           by_kind[0], by_kind[1], by_kind[2]);
    printf("BSDF hits with no rough bounce before them: seen directly %.4f, through smooth "
           "bounces only %.4f\n",
           by_camera[0], by_camera[1]);
    printf("caustics by the smooth bounces from their last rough vertex to the light: 1 %.4f, "
           "2 %.4f, 3+ %.4f\n",
           by_chain[0], by_chain[1], by_chain[2]);
    printf("caustics by their last rough vertex's camera side: the camera (light tracing) "
           "%.4f, a rough vertex (BDPT's joins) %.4f, smooth bounces (merging) %.4f\n",
           by_side[0], by_side[1], by_side[2]);
    printf("by bounces before the light was found: 0 %.4f, 1 %.4f, 2 %.4f, 3 %.4f, 4 %.4f, "
           "5-8 %.4f, 9+ %.4f\n",
           by_depth[0], by_depth[1], by_depth[2], by_depth[3], by_depth[4], by_depth[5],
           by_depth[6]);
    if (guiding) {
        printf("caustics by the rough vertex they left from:");
        for (int i = 0; i < GUIDE_BINS; i++)
            printf("%s %s %.4f", i ? "," : "", guide_bin_name[i], by_guide[i]);
        printf("\n");
    }
    if (pix_x >= 0) {
        printf("the first bounce's environment light samples, of %u:\n", spp);
        for (int i = 0; i < NBANDS; i++)
            printf("  light pdf %-12s taken %8llu  unblocked %8llu  adds %.4g per sample\n",
                   band_name[i], (unsigned long long)bands[i].taken,
                   (unsigned long long)bands[i].unblocked, bands[i].added / spp);
    }
    rc = 0;
done:
    pt_guide_run_free(&run);
    for (uint32_t i = 0; i < MAX_PASSES; i++)
        pt_guide_free(guides[i]);
    pt_free(px);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(scene);
    pt_image_free(ref);
    return rc;
}
