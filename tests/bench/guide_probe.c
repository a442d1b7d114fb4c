/*
 * guide_probe.c - what path guiding learns at chosen surface points: a
 * diagnosis tool, outside the render loop (docs/bench/guiding.md, "What the
 * guide learns in the NVIDIA Cornell box").
 *
 *   ptbench-guide-probe SCENE SPP W H THREADS TARGET[,BLOCKER] PX,PY,PZ,NX,NY,NZ...
 *
 * renders SCENE guided as ptworker --guiding on does (the passes of
 * guide_sched.h, the statistics merged, each pass's guide built from the
 * pass before), and after each pass prints, at every probe point P with
 * normal N: its spatial leaf's depth, size and records in the pass; the
 * share of the pass's recorded energy (fixed-point L / p) at P's cell whose
 * quadtree leaf points into TARGET (xlo,ylo,zlo,xhi,yhi,zhi: a box, such
 * as the slit between a light and the ceiling); the probability that the
 * pass's guide (the one it sampled) and the cosine give TARGET, by 2^20
 * samples of each; the mean guide pdf over the cosine pdf in TARGET's
 * directions; and the quadtree depth there. TARGET may name a second box,
 * a blocker (the light below the slit): a ray that enters it first misses
 * TARGET. Nothing else occludes.
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/guide_run.h"
#include "common/render/render.h"
#include "common/scene/scene.h"

#define MAX_PROBES 16
#define PROBE_SAMPLES (1u << 20)

typedef struct probe {
    pt_vec3 p, n;
} probe;

typedef struct box {
    float lo[3], hi[3];
    int has_blocker; /* blo, bhi: a box in front of it (the light) */
    float blo[3], bhi[3];
} box;

typedef struct job {
    const pt_renderer *r;
    pt_rect rows;
    uint32_t s0, s1;
    pt_pixel_acc *acc;
    pt_render_guiding gd;
} job;

static void *run_job(void *arg)
{
    job *j = arg;
    pt_render_tile_guided(j->r, j->rows, j->s0, j->s1, j->acc, NULL, &j->gd);
    return NULL;
}

/* Where the ray p + t d (t > 0) enters the box lo, hi (slabs); INFINITY
 * when it misses. */
static float enter(const float lo[3], const float hi[3], pt_vec3 p, pt_vec3 d)
{
    float o[3] = {p.x, p.y, p.z}, v[3] = {d.x, d.y, d.z}, t0 = 1e-4f, t1 = INFINITY;
    for (int a = 0; a < 3; a++) {
        if (fabsf(v[a]) < 1e-12f) {
            if (o[a] < lo[a] || o[a] > hi[a])
                return INFINITY;
            continue;
        }
        float ta = (lo[a] - o[a]) / v[a], tb = (hi[a] - o[a]) / v[a];
        if (ta > tb) {
            float t = ta;
            ta = tb;
            tb = t;
        }
        t0 = ta > t0 ? ta : t0;
        t1 = tb < t1 ? tb : t1;
    }
    return t0 <= t1 ? t0 : INFINITY;
}

/* 1 when the ray p + t d meets the target before its blocker. */
static int hits(const box *b, pt_vec3 p, pt_vec3 d)
{
    float t = enter(b->lo, b->hi, p, d);
    return isfinite(t) && !(b->has_blocker && enter(b->blo, b->bhi, p, d) < t);
}

/* A tiny deterministic generator for the probes' samples. */
static float rnd(uint64_t *s)
{
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return (float)(*s >> 40) * 0x1p-24f;
}

/* The depth of the quadtree leaf at cell holding dir. */
static uint32_t qdepth(const pt_guide *g, uint32_t cell, pt_vec3 dir)
{
    uint32_t d;
    pt_guide_qleaf(g, cell, dir, &d);
    return d;
}

/* The recorded energy at the tree rooted at n (square x0, y0, size s) whose
 * leaves' centres point into b from p: *in, and all of it: *all. */
static void stat_energy(const pt_guide *g, const pt_guide_stats *st, uint32_t n, float x0, float y0,
                        float s, const box *b, pt_vec3 p, double *in, double *all)
{
    uint32_t c = g->qnode[n].child;
    if (!c) {
        double e = (double)st->sum[n];
        *all += e;
        /* The leaf points into b when any of 5 x 5 directions over it does. */
        int any = 0;
        for (int i = 0; i < 5 && !any; i++)
            for (int k = 0; k < 5 && !any; k++)
                any = hits(
                    b, p,
                    pt_guide_square_to_dir(x0 + s * (i + 0.5f) / 5.0f, y0 + s * (k + 0.5f) / 5.0f));
        if (any)
            *in += e;
        return;
    }
    float h = 0.5f * s;
    for (uint32_t q = 0; q < 4; q++)
        stat_energy(g, st, c + q, x0 + (float)(q & 1) * h, y0 + (float)(q >> 1) * h, h, b, p, in,
                    all);
}

static void probe_guide(const pt_guide *g, const pt_guide_stats *st, const probe *pr, const box *b,
                        uint32_t pass)
{
    uint32_t depth;
    pt_vec3 ext;
    uint32_t leaf = pt_guide_leaf_box(g, pr->p, &depth, &ext);
    uint32_t cell = pt_guide_cell(g, pr->p, pr->n);
    uint64_t seed = 12345;
    /* The cosine's and the guide's probability of the target. */
    pt_vec3 n = pr->n, t = fabsf(n.x) > 0.5f ? pt_v3(0, 1, 0) : pt_v3(1, 0, 0);
    pt_vec3 bx = pt_v3_norm(pt_v3_cross(t, n)), by = pt_v3_cross(n, bx);
    uint32_t cos_in = 0, g_in = 0;
    double ratio = 0.0, dsum = 0.0;
    int learned = pt_guide_learned(g, cell);
    for (uint32_t i = 0; i < PROBE_SAMPLES; i++) {
        float u1 = rnd(&seed), u2 = rnd(&seed);
        float r = sqrtf(u1), phi = 6.2831853f * u2;
        float z = sqrtf(fmaxf(0.0f, 1.0f - u1));
        pt_vec3 d =
            pt_v3_add(pt_v3_add(pt_v3_scale(bx, r * cosf(phi)), pt_v3_scale(by, r * sinf(phi))),
                      pt_v3_scale(n, z));
        if (hits(b, pr->p, d)) {
            cos_in++;
            ratio += pt_guide_pdf(g, cell, d) / (z / 3.14159265f);
            dsum += qdepth(g, cell, d);
        }
        if (learned) {
            float u[2] = {rnd(&seed), rnd(&seed)}, pdf;
            pt_vec3 w = pt_guide_sample(g, cell, u, &pdf);
            if (pt_v3_dot(w, n) > 0.0f && hits(b, pr->p, w))
                g_in++;
        }
    }
    double in = 0.0, all = 0.0;
    if (st)
        stat_energy(g, st, g->snode[leaf].tree + cell % PT_GUIDE_FACES, 0.0f, 0.0f, 1.0f, b, pr->p,
                    &in, &all);
    printf("pass %u  p (%.2f %.2f %.2f) n (%.0f %.0f %.0f): leaf depth %u (%.2f x %.2f x %.2f), "
           "%llu records; target: %.4f of the energy recorded, P(cos) %.5f, P(guide) %.5f%s, "
           "guide/cos pdf %.2f, qdepth %.1f\n",
           pass, (double)pr->p.x, (double)pr->p.y, (double)pr->p.z, (double)pr->n.x,
           (double)pr->n.y, (double)pr->n.z, depth, (double)ext.x, (double)ext.y, (double)ext.z,
           st ? (unsigned long long)st->count[leaf] : 0ull, all > 0.0 ? in / all : 0.0,
           (double)cos_in / PROBE_SAMPLES, (double)g_in / PROBE_SAMPLES,
           learned ? "" : " (not learned)", cos_in ? ratio / cos_in : 0.0,
           cos_in ? dsum / cos_in : 0.0);
}

int main(int argc, char **argv)
{
    if (argc < 8) {
        fprintf(stderr,
                "usage: %s SCENE SPP W H THREADS xlo,ylo,zlo,xhi,yhi,zhi "
                "px,py,pz,nx,ny,nz...\n",
                argv[0]);
        return 2;
    }
    uint32_t spp = (uint32_t)atoi(argv[2]), w = (uint32_t)atoi(argv[3]),
             h = (uint32_t)atoi(argv[4]), nt = (uint32_t)atoi(argv[5]);
    box b;
    int nb = sscanf(argv[6], "%f,%f,%f,%f,%f,%f,%f,%f,%f,%f,%f,%f", &b.lo[0], &b.lo[1], &b.lo[2],
                    &b.hi[0], &b.hi[1], &b.hi[2], &b.blo[0], &b.blo[1], &b.blo[2], &b.bhi[0],
                    &b.bhi[1], &b.bhi[2]);
    b.has_blocker = nb == 12;
    if ((nb != 6 && nb != 12) || !spp || !w || !h || !nt || nt > 64) {
        fprintf(stderr, "guide_probe: bad arguments\n");
        return 2;
    }
    probe pr[MAX_PROBES];
    uint32_t np = 0;
    for (int i = 7; i < argc && np < MAX_PROBES; i++, np++) {
        float v[6];
        if (sscanf(argv[i], "%f,%f,%f,%f,%f,%f", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) != 6) {
            fprintf(stderr, "guide_probe: bad probe %s\n", argv[i]);
            return 2;
        }
        pr[np].p = pt_v3(v[0], v[1], v[2]);
        pr[np].n = pt_v3_norm(pt_v3(v[3], v[4], v[5]));
    }
    pt_error err = {0};
    pt_scene_opts so = {0};
    pt_scene *s = NULL;
    if (pt_scene_load(argv[1], &so, &s, &err) != PT_OK) {
        fprintf(stderr, "guide_probe: %s\n", err.msg);
        return 1;
    }
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = 1;
    p.guiding = 1;
    pt_renderer *r = NULL;
    if (pt_renderer_new(s, &p, &r, &err) != PT_OK) {
        fprintf(stderr, "guide_probe: %s\n", err.msg);
        return 1;
    }
    printf("bounds (%.3f %.3f %.3f) - (%.3f %.3f %.3f), variant %s\n", (double)s->bounds_min.x,
           (double)s->bounds_min.y, (double)s->bounds_min.z, (double)s->bounds_max.x,
           (double)s->bounds_max.y, (double)s->bounds_max.z, pt_renderer_variant(r));
    pt_guide_run run;
    pt_pixel_acc *acc = pt_calloc((size_t)w * h, sizeof *acc);
    job *jobs = pt_calloc(nt, sizeof *jobs);
    pthread_t *th = pt_calloc(nt, sizeof *th);
    /* Every pass records, the last too: the probes read its statistics. */
    pt_status st = pt_guide_run_new(&run, s->bounds_min, s->bounds_max, spp, nt, 1, &err);
    if (!acc || !jobs || !th || st != PT_OK)
        return 1;
    while ((st = pt_guide_run_begin(&run, &err)) == PT_OK && run.s0 < spp) {
        const pt_guide *g = run.guide;
        for (uint32_t i = 0; i < nt; i++) {
            jobs[i] = (job){r,      {0, h * i / nt, w, h * (i + 1) / nt}, run.s0,
                            run.s1, acc + (size_t)w * (h * i / nt),       run.gd[i]};
            pthread_create(&th[i], NULL, run_job, &jobs[i]);
        }
        for (uint32_t i = 0; i < nt; i++)
            pthread_join(th[i], NULL);
        if ((st = pt_guide_run_merge(&run, &err)) != PT_OK)
            break;
        const pt_guide_stats *sum = run.stats[0];
        uint64_t recs = 0;
        for (uint32_t i = 0; i < sum->nsnode; i++)
            recs += sum->count[i];
        printf("pass %u [%u, %u): guide of %u spatial and %u directional nodes sampled with "
               "probability %.2f; %llu records\n",
               run.pass, run.s0, run.s1, g->nsnode, g->nqnode, (double)run.gd[0].prob,
               (unsigned long long)recs);
        for (uint32_t i = 0; i < np; i++)
            probe_guide(g, sum, &pr[i], &b, run.pass);
        if ((st = pt_guide_run_end(&run, NULL, &err)) != PT_OK)
            break;
    }
    if (st != PT_OK) {
        fprintf(stderr, "guide_probe: %s\n", err.msg);
        return 1;
    }
    pt_guide_run_free(&run);
    pt_free(acc);
    pt_free(jobs);
    pt_free(th);
    pt_renderer_free(r);
    pt_scene_free(s);
    return 0;
}
