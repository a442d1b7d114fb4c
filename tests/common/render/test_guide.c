/*
 * test_guide.c - the SD-tree of path guiding (common/render/guide.h).
 *
 * - The equal-area map: a direction comes back from its square point, and
 *   uniform points of the square are uniform on the sphere (the mean of z
 *   and z^2: 0 and 1/3 within 5 standard errors).
 * - Cells: the normal's face picks one of a leaf's quadtrees; what is
 *   learned at a floor is not sampled at a wall.
 * - Learning: directions recorded with a peaked radiance (1 + 200 max(0,
 *   d.a)^40, a lobe of about 0.1 sr, sampled uniformly so a record is L /
 *   (1 / 4 pi)) over three passes give a guide whose pdf towards a is more
 *   than 20 times its pdf away from it, and whose quadtree has split.
 * - Sampling: chi-square goodness of fit of 200,000 samples of that guide in
 *   32 x 32 bins of the square against the probabilities its own leaves give
 *   them (each leaf's share spread over its square, overlaps computed
 *   exactly); the leaves' shares sum to 1 and the pdf, integrated on a grid
 *   over the sphere, to 1; a sample's pdf is pt_guide_pdf of its direction.
 * - Exact merging: the same records split over three statistics in two
 *   different ways, merged in different orders, give identical sums and
 *   guides identical to the byte.
 * - Space: a leaf with more records than the split count becomes two, and
 *   points on the two sides of the middle find different leaves; random
 *   points, and points on the split planes, find the leaf a plain walk
 *   (bounds halved at each node's midpoint) finds.
 * - Known leaves: records made with the quadtree leaf pt_guide_pdf_leaf
 *   found (pt_guide_stats_add) sum to the same statistics as
 *   pt_guide_stats_record's, its pdf is pt_guide_pdf's and its leaf
 *   pt_guide_qleaf's.
 * - Passes: pt_guide_pass_end cuts [0, spp) into passes that follow on from
 *   each other, of 16, 32, 64... spp, the last one running to spp when what
 *   is left after a pass is shorter than the pass after it would be.
 * - Hostile trees: a child before its parent, a child shared by two nodes, a
 *   NaN energy, a leaf's tree out of range and a node outside every tree
 *   are each refused by pt_guide_check.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/guide.h"
#include "tests/check.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

static uint64_t rng = 0x2545f4914f6cdd1dull;
static double rnd(void)
{
    return rng_f53(&rng);
}

static pt_vec3 uniform_dir(void)
{
    double z = 1.0 - 2.0 * rnd(), r = sqrt(fmax(0.0, 1.0 - z * z)), a = 2.0 * PI_D * rnd();
    return pt_v3((float)(r * cos(a)), (float)(r * sin(a)), (float)z);
}

static const pt_vec3 PEAK = {0.48f, -0.6f, 0.64f};
static const pt_vec3 UP = {0.1f, 0.2f, 0.97f}; /* the surface normal of the learning tests */

static double radiance(pt_vec3 d)
{
    double c = fmax(0.0, pt_v3_dot(d, PEAK));
    return 1.0 + 200.0 * pow(c, 40.0);
}

static void equal_area(void)
{
    double mz = 0.0, mz2 = 0.0, worst = 0.0;
    const int N = 100000;
    for (int i = 0; i < N; i++) {
        pt_vec3 d = uniform_dir();
        float u, v;
        pt_guide_dir_to_square(d, &u, &v);
        pt_vec3 back = pt_guide_square_to_dir(u, v);
        worst = fmax(worst, pt_v3_len(pt_v3_sub(back, d)));
        pt_vec3 e = pt_guide_square_to_dir((float)rnd(), (float)rnd());
        mz += e.z;
        mz2 += (double)e.z * e.z;
    }
    mz /= N;
    mz2 /= N;
    CHECKF(worst < 1e-3, "a direction comes back %g away", worst);
    /* z uniform on [-1, 1]: variance 1/3, and z^2's variance 4/45. */
    CHECKF(fabs(mz) < 5.0 * sqrt(1.0 / 3.0 / N), "mean z %g", mz);
    CHECKF(fabs(mz2 - 1.0 / 3.0) < 5.0 * sqrt(4.0 / 45.0 / N), "mean z^2 %g", mz2);
}

/* Records n uniform directions of the peaked radiance at leaf 0 into s. */
static void record_peak(pt_guide_stats *s, const pt_guide *g, int n, uint64_t seed)
{
    uint64_t keep = rng;
    rng = seed;
    for (int i = 0; i < n; i++) {
        pt_vec3 d = uniform_dir();
        pt_guide_stats_record(s, g, pt_guide_cell(g, pt_v3(0, 0, 0), UP), d,
                              (float)(radiance(d) * 4.0 * PI_D));
    }
    rng = keep;
}

static pt_guide *learn(int passes)
{
    pt_error err = {0};
    pt_guide *g = NULL;
    CHECK(pt_guide_new_uniform(pt_v3(-1, -1, -1), pt_v3(1, 1, 1), &g, &err) == PT_OK);
    for (int p = 0; g && p < passes; p++) {
        pt_guide_stats *s = NULL;
        CHECK(pt_guide_stats_new(g, &s, &err) == PT_OK);
        if (!s)
            break;
        record_peak(s, g, 50000, 1000 + (uint64_t)p);
        pt_guide *ng = NULL;
        CHECKF(pt_guide_build(g, s, UINT64_MAX, &ng, &err) == PT_OK, "%s", err.msg);
        pt_guide_stats_free(s);
        pt_guide_free(g);
        g = ng;
        if (g)
            CHECKF(pt_guide_check(g, &err) == PT_OK, "pass %d: %s", p, err.msg);
    }
    return g;
}

/* Adds each leaf's share of the tree at n (square [x0, x0 + size)^2,
 * probability prob) to the bins it overlaps. */
static void leaf_mass(const pt_guide *g, uint32_t n, double x0, double y0, double size, double prob,
                      double *bins, int nb, double *total)
{
    const pt_guide_qnode *q = &g->qnode[n];
    if (!q->child) {
        *total += prob;
        int b0 = (int)floor(x0 * nb), b1 = (int)ceil((x0 + size) * nb);
        int c0 = (int)floor(y0 * nb), c1 = (int)ceil((y0 + size) * nb);
        for (int by = c0; by < c1 && by < nb; by++)
            for (int bx = b0; bx < b1 && bx < nb; bx++) {
                double ox = fmin(x0 + size, (bx + 1.0) / nb) - fmax(x0, (double)bx / nb);
                double oy = fmin(y0 + size, (by + 1.0) / nb) - fmax(y0, (double)by / nb);
                if (ox > 0.0 && oy > 0.0)
                    bins[by * nb + bx] += prob * ox * oy / (size * size);
            }
        return;
    }
    /* The sampler's choices (guide.c): the column, then the row in it. */
    double e[4];
    for (int i = 0; i < 4; i++)
        e[i] = g->qnode[q->child + (uint32_t)i].energy;
    double left = e[0] + e[2], right = e[1] + e[3], tot = left + right;
    double px = tot > 0.0 ? left / tot : 0.5;
    double py[2] = {tot > 0.0 && left > 0.0 ? e[0] / left : 0.5,
                    tot > 0.0 && right > 0.0 ? e[1] / right : 0.5};
    double h = size / 2.0;
    for (int qy = 0; qy < 2; qy++)
        for (int qx = 0; qx < 2; qx++) {
            double p = (qx ? 1.0 - px : px) * (qy ? 1.0 - py[qx] : py[qx]);
            leaf_mass(g, q->child + (uint32_t)(qx + 2 * qy), x0 + qx * h, y0 + qy * h, h, prob * p,
                      bins, nb, total);
        }
}

static void learning_and_sampling(void)
{
    pt_guide *g = learn(3);
    if (!g)
        return;
    uint32_t leaf = pt_guide_cell(g, pt_v3(0, 0, 0), UP);
    float towards = pt_guide_pdf(g, leaf, PEAK);
    float away = pt_guide_pdf(g, leaf, pt_v3_neg(PEAK));
    CHECKF(towards > 20.0f * away, "pdf towards the peak %g, away %g", towards, away);
    CHECKF(g->nqnode > 1, "the quadtree did not split (%u nodes)", g->nqnode);
    printf("learned: %u directional nodes, pdf towards the peak %.3g, away %.3g\n", g->nqnode,
           (double)towards, (double)away);

    enum { NB = 32 };
    static double expd[NB * NB], obs[NB * NB];
    double total = 0.0;
    leaf_mass(g, g->snode[leaf / PT_GUIDE_FACES].tree + leaf % PT_GUIDE_FACES, 0.0, 0.0, 1.0, 1.0,
              expd, NB, &total);
    CHECKF(fabs(total - 1.0) < 1e-9, "the leaves' shares sum to %.12f", total);
    const int N = 200000;
    int pdf_bad = 0;
    for (int i = 0; i < N; i++) {
        float u[2] = {(float)rnd(), (float)rnd()}, pdf;
        pt_vec3 d = pt_guide_sample(g, leaf, u, &pdf);
        float su, sv;
        pt_guide_dir_to_square(d, &su, &sv);
        int bx = (int)(su * NB), by = (int)(sv * NB);
        bx = bx < 0 ? 0 : (bx >= NB ? NB - 1 : bx);
        by = by < 0 ? 0 : (by >= NB ? NB - 1 : by);
        obs[by * NB + bx] += 1.0;
        float p2 = pt_guide_pdf(g, leaf, d);
        pdf_bad += !(fabsf(p2 - pdf) <= 1e-3f * pdf);
    }
    for (int b = 0; b < NB * NB; b++)
        expd[b] *= N;
    double stat;
    int dof;
    double p = stats_chi2_gof(obs, expd, NB * NB, 5.0, &stat, &dof);
    CHECKF(p > 1e-3, "chi-square %.1f, %d dof, p = %.2e", stat, dof, p);
    /* A point on a leaf's edge may round into its neighbour: rare. */
    CHECKF(pdf_bad < N / 1000, "%d samples' pdf differs from pt_guide_pdf", pdf_bad);
    printf("sampling: chi-square %.1f, %d dof, p = %.3f\n", stat, dof, p);

    /* The pdf over the sphere: dw = 4 pi du dv on the square. */
    const int G = 1024;
    double integral = 0.0;
    for (int j = 0; j < G; j++)
        for (int i = 0; i < G; i++) {
            pt_vec3 d = pt_guide_square_to_dir((float)((i + 0.5) / G), (float)((j + 0.5) / G));
            integral += pt_guide_pdf(g, leaf, d);
        }
    integral *= 4.0 * PI_D / ((double)G * G);
    CHECKF(fabs(integral - 1.0) < 2e-2, "the pdf integrates to %.5f", integral);
    pt_guide_free(g);
}

static int same_guide(const pt_guide *a, const pt_guide *b)
{
    return a->nsnode == b->nsnode && a->nqnode == b->nqnode &&
           memcmp(a->snode, b->snode, a->nsnode * sizeof *a->snode) == 0 &&
           memcmp(a->qnode, b->qnode, a->nqnode * sizeof *a->qnode) == 0;
}

static void exact_merge(void)
{
    pt_guide *g = learn(1);
    if (!g)
        return;
    pt_error err = {0};
    /* The same 30,000 records as [10k, 10k, 10k] and as [1k, 25k, 4k]. */
    pt_guide_stats *a[3] = {NULL, NULL, NULL}, *b[3] = {NULL, NULL, NULL}, *c = NULL;
    CHECK(pt_guide_stats_new(g, &c, &err) == PT_OK);
    int pdf_differs = 0, qleaf_differs = 0;
    for (int i = 0; i < 3; i++) {
        CHECK(pt_guide_stats_new(g, &a[i], &err) == PT_OK);
        CHECK(pt_guide_stats_new(g, &b[i], &err) == PT_OK);
    }
    if (!a[2] || !b[2] || !c)
        return;
    uint64_t keep = rng;
    rng = 77;
    static const int split_b[3] = {1000, 25000, 4000};
    int k = 0, which_b = 0, left_b = split_b[0];
    for (int i = 0; i < 30000; i++) {
        pt_vec3 d = uniform_dir();
        pt_vec3 p = pt_v3((float)rnd() - 0.5f, (float)rnd() - 0.5f, (float)rnd() - 0.5f);
        float v = (float)(radiance(d) * 4.0 * PI_D * (0.5 + rnd()));
        uint32_t leaf = pt_guide_cell(g, p, uniform_dir());
        pt_guide_stats_record(a[i / 10000], g, leaf, d, v);
        while (left_b == 0)
            left_b = split_b[++which_b];
        pt_guide_stats_record(b[which_b], g, leaf, d, v);
        uint32_t qleaf;
        float pdf = pt_guide_pdf_leaf(g, leaf, d, &qleaf);
        pdf_differs += pdf != pt_guide_pdf(g, leaf, d);
        qleaf_differs += pt_guide_qleaf(g, leaf, d, NULL) != qleaf;
        pt_guide_stats_add(c, leaf, qleaf, v);
        /* Records of 0 are counted, hostile ones dropped, alike. */
        if (i % 97 == 0) {
            pt_guide_stats_record(b[which_b], g, leaf, d, 0.0f);
            pt_guide_stats_record(b[which_b], g, leaf, d, NAN);
            pt_guide_stats_record(a[i / 10000], g, leaf, d, 0.0f);
            pt_guide_stats_add(c, leaf, qleaf, 0.0f);
            pt_guide_stats_add(c, leaf, qleaf, -1.0f);
            pt_guide_stats_add(c, leaf, qleaf, INFINITY);
        }
        left_b--;
        k++;
    }
    rng = keep;
    CHECK(pt_guide_stats_merge(a[0], a[1], &err) == PT_OK);
    CHECK(pt_guide_stats_merge(a[0], a[2], &err) == PT_OK);
    CHECK(pt_guide_stats_merge(b[2], b[0], &err) == PT_OK);
    CHECK(pt_guide_stats_merge(b[2], b[1], &err) == PT_OK);
    CHECK(memcmp(a[0]->sum, b[2]->sum, g->nqnode * sizeof *a[0]->sum) == 0);
    CHECK(memcmp(a[0]->count, b[2]->count, g->nsnode * sizeof *a[0]->count) == 0);
    CHECK(memcmp(c->sum, b[2]->sum, g->nqnode * sizeof *c->sum) == 0);
    CHECK(memcmp(c->count, b[2]->count, g->nsnode * sizeof *c->count) == 0);
    CHECKF(pdf_differs == 0, "%d pdfs of pt_guide_pdf_leaf differ", pdf_differs);
    CHECKF(qleaf_differs == 0, "%d leaves of pt_guide_qleaf differ", qleaf_differs);
    pt_guide *ga = NULL, *gb = NULL;
    CHECK(pt_guide_build(g, a[0], 5000, &ga, &err) == PT_OK);
    CHECK(pt_guide_build(g, b[2], 5000, &gb, &err) == PT_OK);
    CHECK(ga && gb && same_guide(ga, gb));
    /* 30,000 records over the split count of 5,000: the root splits, and the
     * two sides of the middle (x, the first axis after the root's 0 is
     * y) find different leaves. */
    if (ga) {
        CHECKF(ga->snode[0].child != 0, "the spatial root did not split");
        uint32_t l0 = pt_guide_leaf(ga, pt_v3(0, -0.5f, 0)),
                 l1 = pt_guide_leaf(ga, pt_v3(0, 0.5f, 0));
        CHECKF(l0 != l1, "both sides of the split find leaf %u", l0);
        CHECK(pt_guide_check(ga, &err) == PT_OK);
    }
    /* Statistics of another guide do not merge. */
    if (ga) {
        pt_guide_stats *other = NULL;
        CHECK(pt_guide_stats_new(ga, &other, &err) == PT_OK);
        if (other)
            CHECK(pt_guide_stats_merge(a[0], other, &err) == PT_ERR_ARG);
        pt_guide_stats_free(other);
    }
    pt_guide_free(ga);
    pt_guide_free(gb);
    for (int i = 0; i < 3; i++) {
        pt_guide_stats_free(a[i]);
        pt_guide_stats_free(b[i]);
    }
    pt_guide_stats_free(c);
    pt_guide_free(g);
    (void)k;
}

/* The spatial leaf of p by a plain walk: bounds halved at each node's
 * midpoint, p < mid going to the first child. */
static uint32_t plain_leaf(const pt_guide *g, pt_vec3 p)
{
    float lo[3] = {g->lo.x, g->lo.y, g->lo.z}, hi[3] = {g->hi.x, g->hi.y, g->hi.z};
    float q[3] = {p.x, p.y, p.z};
    uint32_t n = 0;
    while (g->snode[n].child) {
        uint32_t a = g->snode[n].axis;
        float mid = 0.5f * (lo[a] + hi[a]);
        if (q[a] < mid) {
            hi[a] = mid;
            n = g->snode[n].child;
        } else {
            lo[a] = mid;
            n = g->snode[n].child + 1;
        }
    }
    return n;
}

/* A guide split a few levels deep; random points, points on its split
 * planes and points outside its bounds find plain_leaf's leaf. */
static void space(void)
{
    pt_guide *g = learn(1);
    if (!g)
        return;
    pt_error err = {0};
    pt_guide_stats *s = NULL;
    CHECK(pt_guide_stats_new(g, &s, &err) == PT_OK);
    if (!s) {
        pt_guide_free(g);
        return;
    }
    uint64_t keep = rng;
    rng = 991;
    /* Two builds, the records crowded towards one corner: the second
     * splits the leaves there deeper than the others. */
    pt_guide *ng = NULL;
    for (int pass = 0; pass < 2 && s; pass++) {
        for (int i = 0; i < 200000; i++) {
            double t = rnd();
            pt_vec3 p = pt_v3((float)(t * t - 0.5), (float)(rnd() - 0.5), (float)(t * rnd() - 0.5));
            pt_guide_stats_record(s, g, pt_guide_cell(g, p, UP), uniform_dir(), 1.0f);
        }
        CHECK(pt_guide_build(g, s, 500 << (pass * 3), &ng, &err) == PT_OK);
        pt_guide_stats_free(s);
        s = NULL;
        pt_guide_free(g);
        g = ng;
        ng = NULL;
        if (g && pass == 0)
            CHECK(pt_guide_stats_new(g, &s, &err) == PT_OK);
    }
    ng = g;
    g = NULL;
    int wrong = 0, n = 0;
    for (int i = 0; ng && i < 100000; i++) {
        /* Points on dyadic planes of the bounds: on the splits themselves. */
        float x = (float)(rnd() * 1.2 - 0.6), y = (float)(rnd() * 1.2 - 0.6),
              z = (float)(rnd() * 1.2 - 0.6);
        if (i % 2)
            x = (float)(floor(x * 64.0) / 64.0);
        if (i % 3 == 0)
            z = (float)(floor(z * 64.0) / 64.0);
        pt_vec3 p = pt_v3(x, y, z);
        wrong += pt_guide_leaf(ng, p) != plain_leaf(ng, p);
        n++;
    }
    CHECKF(ng && ng->nsnode > 15, "the guide split into %u nodes only", ng ? ng->nsnode : 0);
    CHECKF(wrong == 0, "%d of %d points found another leaf than a plain walk's", wrong, n);
    printf("space: %u spatial nodes, %d points\n", ng ? ng->nsnode : 0, n);
    rng = keep;
    pt_guide_stats_free(s);
    pt_guide_free(ng);
    pt_guide_free(g);
}

static void cells(void)
{
    pt_guide *g = learn(2);
    if (!g)
        return;
    uint32_t up = pt_guide_cell(g, pt_v3(0, 0, 0), UP);
    uint32_t side = pt_guide_cell(g, pt_v3(0, 0, 0), pt_v3(1, 0, 0));
    CHECK(up / PT_GUIDE_FACES == side / PT_GUIDE_FACES && up != side);
    /* The side's tree saw nothing: uniform, 1 / (4 pi) everywhere. */
    float ps = pt_guide_pdf(g, side, PEAK), pu = pt_guide_pdf(g, up, PEAK);
    CHECKF(fabs(ps - 0.25 / PI_D) < 1e-5, "an unlearned cell's pdf %g", ps);
    CHECKF(pu > 10.0f * ps, "the learned cell's pdf towards the peak %g", pu);
    pt_guide_free(g);
}

static void hostile(void)
{
    pt_guide *g = learn(2);
    if (!g)
        return;
    pt_error err = {0};
    CHECK(pt_guide_check(g, &err) == PT_OK);
    uint32_t inner = 0;
    for (uint32_t i = 0; i < g->nqnode; i++)
        if (g->qnode[i].child) {
            inner = i;
            break;
        }
    CHECKF(g->qnode[inner].child != 0, "no inner node to corrupt");
    pt_guide_qnode saved = g->qnode[inner];

    g->qnode[inner].child = inner; /* its own child: a cycle */
    CHECK(pt_guide_check(g, &err) == PT_ERR_FORMAT);
    g->qnode[inner] = saved;

    g->qnode[g->nqnode - 1].energy = NAN;
    CHECK(pt_guide_check(g, &err) == PT_ERR_FORMAT);
    g->qnode[g->nqnode - 1].energy = 0.0f;

    uint32_t tree = g->snode[0].tree;
    g->snode[0].tree = g->nqnode;
    CHECK(pt_guide_check(g, &err) == PT_ERR_FORMAT);
    g->snode[0].tree = tree;

    /* Two inner nodes sharing children, or children past the end. */
    g->qnode[inner].child = g->nqnode - 2;
    CHECK(pt_guide_check(g, &err) == PT_ERR_FORMAT);
    g->qnode[inner] = saved;
    CHECK(pt_guide_check(g, &err) == PT_OK);
    printf("hostile: last refusal \"%s\"\n", err.msg);
    pt_guide_free(g);
}

static void passes(void)
{
    /* Examples of the rule, then the rule over every spp up to 5000. */
    static const uint32_t want256[] = {16, 48, 112, 256}, want100[] = {16, 100};
    for (uint32_t k = 0; k < 4; k++)
        CHECKF(pt_guide_pass_end(k, 256) == want256[k], "256 spp: pass %u ends at %u", k,
               pt_guide_pass_end(k, 256));
    for (uint32_t k = 0; k < 2; k++)
        CHECK(pt_guide_pass_end(k, 100) == want100[k]);
    CHECK(pt_guide_pass_end(0, 8) == 8 && pt_guide_pass_end(0, 16) == 16);
    CHECK(pt_guide_pass_end(40, 1u << 30) == 1u << 30);
    for (uint32_t spp = 1; spp <= 5000; spp++) {
        uint32_t s0 = 0, k = 0, len = 16;
        for (; s0 < spp; k++, len *= 2) {
            uint32_t s1 = pt_guide_pass_end(k, spp);
            /* A full pass, or the last one: at least a full pass unless
             * spp itself is shorter, and shorter than the next pass plus
             * this one. */
            int full = s1 == s0 + len,
                last = s1 == spp && (s1 - s0 >= len || s0 == 0) && s1 - s0 < 3 * len;
            if (!(s1 > s0 && (full || last))) {
                CHECKF(0, "spp %u: pass %u is [%u, %u)", spp, k, s0, s1);
                return;
            }
            s0 = s1;
        }
        CHECK(s0 == spp);
    }
    printf("passes: 256 spp in 16, 32, 64, 144\n");
}

int main(void)
{
    int64_t live = pt_alloc_live();
    passes();
    equal_area();
    learning_and_sampling();
    exact_merge();
    space();
    cells();
    hostile();
    CHECKF(pt_alloc_live() == live, "%lld allocations left", (long long)(pt_alloc_live() - live));
    return check_report();
}
