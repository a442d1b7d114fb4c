/*
 * test_light.c - emissive triangles as lights (common/render/light.c).
 *
 * Statistical tests with chi-square p-values (threshold 1e-3, fixed seeds):
 * the choice of triangle follows the power computed here independently, the
 * point is uniform in area, the sampled directions follow the solid-angle pdf
 * the module reports (integrated numerically over (cos theta, phi) bins), and
 * that pdf integrates to the visible share of the power (Monte Carlo, within
 * 4 standard errors). A textured emitter's power is its texture's mean over
 * its own UV footprint: a triangle over black texels is no light. Then the
 * contract's edges: pt_lights_pdf equals the
 * sample's pdf, back faces of single-sided emitters, scenes without emitters,
 * bad input and allocation failure.
 *
 * Scenes are built by hand (pt_scene is a plain struct).
 */
#include "common/render/light.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "tests/check.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846
/* No receiver normal: a light tree sets no bound by the receiver's side. */
#define NO_N pt_v3(0.0f, 0.0f, 0.0f)

/* ---- small helpers ------------------------------------------------------------------ */

static uint64_t rng_state;

static uint64_t rng_next(void)
{
    return rng_u64(&rng_state);
}

static float rnd(void)
{
    return (float)(rng_next() >> 40) * 0x1p-24f;
}

static void rnd3(float u[3])
{
    u[0] = rnd();
    u[1] = rnd();
    u[2] = rnd();
}

/* Pearson's chi-square test of observed counts against expected counts.
 * Bins expecting fewer than 5 are pooled into one (and that pool, if still
 * under 5, into the smallest bin) so the chi-square approximation holds.
 * Returns the p-value; *stat and *dof report the test. */
static double chi2_test(const double *obs, const double *expd, int n, double *stat, int *dof)
{
    double pool_o = 0, pool_e = 0, chi = 0;
    int bins = 0, smallest = -1;
    for (int i = 0; i < n; i++) {
        if (expd[i] < 5.0) {
            pool_o += obs[i];
            pool_e += expd[i];
        } else {
            bins++;
            if (smallest < 0 || expd[i] < expd[smallest])
                smallest = i;
        }
    }
    for (int i = 0; i < n; i++) {
        if (expd[i] < 5.0)
            continue;
        double o = obs[i], e = expd[i];
        if (i == smallest && pool_e < 5.0) {
            o += pool_o;
            e += pool_e;
        }
        chi += (o - e) * (o - e) / e;
    }
    if (pool_e >= 5.0) {
        chi += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        bins++;
    }
    *stat = chi;
    *dof = bins - 1;
    if (bins < 2)
        return 1.0;
    return stats_gamma_q(0.5 * (bins - 1), 0.5 * chi);
}

#define P_MIN 1e-3

/* ---- hand-built scenes ---------------------------------------------------------------- */

#define MAX_V 128
#define MAX_T 32
#define MAX_M 8

typedef struct tscene {
    pt_scene s;
    float pos[3 * MAX_V];
    float uv[2 * MAX_V];
    uint32_t idx[3 * MAX_T];
    uint32_t tmat[MAX_T];
    pt_material mats[MAX_M];
    pt_texture tex[1];
    uint8_t texels[16];
} tscene;

static void ts_init(tscene *t)
{
    memset(t, 0, sizeof *t);
    t->s.positions = t->pos;
    t->s.uvs = t->uv;
    t->s.indices = t->idx;
    t->s.tri_material = t->tmat;
    t->s.materials = t->mats;
    t->s.textures = t->tex;
}

static uint32_t ts_material(tscene *t, float r, float g, float b, int double_sided, int tex)
{
    uint32_t i = t->s.num_materials++;
    pt_material *m = &t->mats[i];
    m->base_color[0] = m->base_color[1] = m->base_color[2] = m->base_color[3] = 1.0f;
    m->base_color_tex = m->metal_rough_tex = -1;
    m->emissive[0] = r;
    m->emissive[1] = g;
    m->emissive[2] = b;
    m->emissive_tex = tex;
    m->double_sided = double_sided;
    return i;
}

static uint32_t ts_vert(tscene *t, pt_vec3 p, float u, float v)
{
    uint32_t i = t->s.num_vertices++;
    t->pos[3 * i] = p.x;
    t->pos[3 * i + 1] = p.y;
    t->pos[3 * i + 2] = p.z;
    t->uv[2 * i] = u;
    t->uv[2 * i + 1] = v;
    return i;
}

/* Adds triangle (a, b, c), wound so that its front faces `towards`. */
static uint32_t ts_tri(tscene *t, pt_vec3 a, pt_vec3 b, pt_vec3 c, uint32_t mat, pt_vec3 towards)
{
    pt_vec3 n = pt_v3_cross(pt_v3_sub(b, a), pt_v3_sub(c, a));
    pt_vec3 ctr = pt_v3_scale(pt_v3_add(pt_v3_add(a, b), c), 1.0f / 3.0f);
    if (pt_v3_dot(n, pt_v3_sub(towards, ctr)) < 0.0f) {
        pt_vec3 tmp = b;
        b = c;
        c = tmp;
    }
    uint32_t i = t->s.num_triangles++;
    t->idx[3 * i] = ts_vert(t, a, 0, 0);
    t->idx[3 * i + 1] = ts_vert(t, b, 1, 0);
    t->idx[3 * i + 2] = ts_vert(t, c, 0, 1);
    t->tmat[i] = mat;
    return i;
}

static void tri_verts(const pt_scene *s, uint32_t tri, pt_vec3 v[3])
{
    for (int k = 0; k < 3; k++) {
        const float *p = &s->positions[3 * s->indices[3 * tri + k]];
        v[k] = pt_v3(p[0], p[1], p[2]);
    }
}

/* Area and unit normal in double, independent of the module's arithmetic. */
static double tri_area(const pt_scene *s, uint32_t tri, double n[3])
{
    pt_vec3 v[3];
    tri_verts(s, tri, v);
    double e1[3] = {v[1].x - v[0].x, v[1].y - v[0].y, v[1].z - v[0].z};
    double e2[3] = {v[2].x - v[0].x, v[2].y - v[0].y, v[2].z - v[0].z};
    double c[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
    double l = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    if (n && l > 0)
        for (int k = 0; k < 3; k++)
            n[k] = c[k] / l;
    return 0.5 * l;
}

/* Barycentrics (b1, b2) of x in the plane of tri, in double. */
static void barycentrics(const pt_scene *s, uint32_t tri, pt_vec3 x, double *b1, double *b2)
{
    pt_vec3 v[3];
    tri_verts(s, tri, v);
    double e1[3] = {v[1].x - v[0].x, v[1].y - v[0].y, v[1].z - v[0].z};
    double e2[3] = {v[2].x - v[0].x, v[2].y - v[0].y, v[2].z - v[0].z};
    double w[3] = {x.x - v[0].x, x.y - v[0].y, x.z - v[0].z};
    double d11 = 0, d12 = 0, d22 = 0, w1 = 0, w2 = 0;
    for (int k = 0; k < 3; k++) {
        d11 += e1[k] * e1[k];
        d12 += e1[k] * e2[k];
        d22 += e2[k] * e2[k];
        w1 += w[k] * e1[k];
        w2 += w[k] * e2[k];
    }
    double den = d11 * d22 - d12 * d12;
    *b1 = (d22 * w1 - d12 * w2) / den;
    *b2 = (d11 * w2 - d12 * w1) / den;
}

/* Moeller & Trumbore 1997 ray/triangle test in double; distance or -1. */
static double ray_tri(const pt_scene *s, uint32_t tri, const double o[3], const double d[3])
{
    pt_vec3 v[3];
    tri_verts(s, tri, v);
    double e1[3] = {v[1].x - v[0].x, v[1].y - v[0].y, v[1].z - v[0].z};
    double e2[3] = {v[2].x - v[0].x, v[2].y - v[0].y, v[2].z - v[0].z};
    double pv[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2],
                    d[0] * e2[1] - d[1] * e2[0]};
    double det = e1[0] * pv[0] + e1[1] * pv[1] + e1[2] * pv[2];
    if (fabs(det) < 1e-300)
        return -1;
    double tv[3] = {o[0] - v[0].x, o[1] - v[0].y, o[2] - v[0].z};
    double u = (tv[0] * pv[0] + tv[1] * pv[1] + tv[2] * pv[2]) / det;
    if (u < 0 || u > 1)
        return -1;
    double qv[3] = {tv[1] * e1[2] - tv[2] * e1[1], tv[2] * e1[0] - tv[0] * e1[2],
                    tv[0] * e1[1] - tv[1] * e1[0]};
    double w = (d[0] * qv[0] + d[1] * qv[1] + d[2] * qv[2]) / det;
    if (w < 0 || u + w > 1)
        return -1;
    double t = (e2[0] * qv[0] + e2[1] * qv[1] + e2[2] * qv[2]) / det;
    return t > 0 ? t : -1;
}

static double luminance_d(double r, double g, double b)
{
    return 0.2126 * r + 0.7152 * g + 0.0722 * b;
}

/* The power of each triangle as the module documents it (up to the common
 * factor pi), computed here from the scene data; tex_mean is the known mean
 * of the test texture. */
static void expected_pmf(const pt_scene *s, double tex_mean, double *pmf)
{
    double total = 0;
    for (uint32_t i = 0; i < s->num_triangles; i++) {
        const pt_material *m = &s->materials[s->tri_material[i]];
        double k = m->emissive_tex >= 0 ? tex_mean : 1.0;
        double p = tri_area(s, i, NULL) * k *
                   luminance_d(m->emissive[0], m->emissive[1], m->emissive[2]) *
                   (m->double_sided ? 2.0 : 1.0);
        pmf[i] = p;
        total += p;
    }
    for (uint32_t i = 0; i < s->num_triangles; i++)
        pmf[i] /= total;
}

/*
 * The main test scene, around the shading point at the origin:
 *   0: single-sided, white x 2, above (z = 1), facing the origin
 *   1: double-sided, orange, at x = 1.5, wound to face away from the origin
 *   2: single-sided, white x an sRGB texture with one white texel of four
 *      (mean 0.25 in linear), below (y = -1)
 *   3, 4: a single-sided blue quad at x = -1.2
 *   5: not emissive
 *   6: emissive but of zero area (collinear): never a light
 */
static void build_main(tscene *t)
{
    ts_init(t);
    pt_vec3 o = pt_v3(0, 0, 0);
    uint32_t m0 = ts_material(t, 2, 2, 2, 0, -1);
    uint32_t m1 = ts_material(t, 2.0f, 0.8f, 0.4f, 1, -1);
    uint32_t m2 = ts_material(t, 1, 1, 1, 0, 0);
    uint32_t m3 = ts_material(t, 0.3f, 0.6f, 0.9f, 0, -1);
    uint32_t m4 = ts_material(t, 0, 0, 0, 1, -1);
    uint32_t m5 = ts_material(t, 1, 0, 0, 0, -1);
    ts_tri(t, pt_v3(-0.6f, -0.5f, 1), pt_v3(0.7f, -0.4f, 1.1f), pt_v3(0.1f, 0.6f, 0.9f), m0, o);
    ts_tri(t, pt_v3(1.5f, -0.3f, -0.4f), pt_v3(1.6f, 0.5f, -0.2f), pt_v3(1.4f, 0.1f, 0.6f), m1,
           pt_v3(5, 0, 0));
    ts_tri(t, pt_v3(-0.8f, -1, -0.5f), pt_v3(0.5f, -1.1f, -0.6f), pt_v3(0, -0.9f, 0.7f), m2, o);
    ts_tri(t, pt_v3(-1.2f, -0.4f, -0.5f), pt_v3(-1.2f, 0.6f, -0.5f), pt_v3(-1.2f, 0.6f, 0.3f), m3,
           o);
    ts_tri(t, pt_v3(-1.2f, -0.4f, -0.5f), pt_v3(-1.2f, 0.6f, 0.3f), pt_v3(-1.2f, -0.4f, 0.3f), m3,
           o);
    ts_tri(t, pt_v3(0, 2, 0), pt_v3(1, 2, 0), pt_v3(0, 2, 1), m4, o);
    ts_tri(t, pt_v3(0, -3, 0), pt_v3(1, -3, 0), pt_v3(2, -3, 0), m5, o);

    /* 2x2 sRGB texture: top-left texel white, the rest black. */
    memset(t->texels, 0, sizeof t->texels);
    for (int k = 0; k < 16; k++)
        t->texels[k] = (k < 4 || k % 4 == 3) ? 255 : 0;
    t->tex[0].width = t->tex[0].height = 2;
    t->tex[0].rgba = t->texels;
    t->tex[0].srgb = 1;
    t->tex[0].wrap_s = t->tex[0].wrap_t = PT_WRAP_REPEAT;
    t->s.num_textures = 1;
}

/* Triangle 2's emission over its UV footprint: UVs (0,0), (1,0), (0,1) are
 * texel coordinates (-0.5,-0.5), (1.5,-0.5), (-0.5,1.5), which cover the
 * centres of texels (0,0) (white), (1,0) and (0,1) (black, on the edge x +
 * y = 1): a mean of 1/3, where the whole texture's is 1/4. */
#define MAIN_TEX_MEAN (1.0 / 3.0)
#define MAIN_NUM_LIGHTS 5

/* ---- the choice of triangle ------------------------------------------------------------ */

static void test_choice(void)
{
    rng_state = 1; /* each test its own stream */
    tscene t;
    build_main(&t);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    CHECK(pt_lights_count(L) == MAIN_NUM_LIGHTS);

    double pmf[MAX_T], obs[MAX_T] = {0}, expd[MAX_T];
    expected_pmf(&t.s, MAIN_TEX_MEAN, pmf);
    const int n = 200000;
    pt_vec3 p = pt_v3(0, 0, 0);
    int other = 0;
    for (int i = 0; i < n; i++) {
        float u[3];
        rnd3(u);
        pt_light_sample s;
        pt_lights_sample(L, &t.s, p, NO_N, u, &s);
        if (s.tri < t.s.num_triangles)
            obs[s.tri] += 1;
        else
            other++;
    }
    for (uint32_t i = 0; i < t.s.num_triangles; i++)
        expd[i] = n * pmf[i];
    double chi;
    int dof;
    double pv = chi2_test(obs, expd, (int)t.s.num_triangles, &chi, &dof);
    CHECKF(pv > P_MIN, "triangle choice: chi2 %.2f, dof %d, p %.3g", chi, dof, pv);
    CHECK(other == 0);
    CHECK(obs[5] == 0 && obs[6] == 0); /* not lights */
    printf("triangle choice: chi2 %.2f dof %d p %.3f\n", chi, dof, pv);

    /* The choice is a pure function of u[0]: the same u, the same light. And
     * u[0] just below 1 stays in range. */
    float u[3] = {0.37f, 0.5f, 0.5f};
    pt_light_sample a, b;
    pt_lights_sample(L, &t.s, p, NO_N, u, &a);
    pt_lights_sample(L, &t.s, p, NO_N, u, &b);
    CHECK(a.tri == b.tri && a.pdf == b.pdf);
    u[0] = 0x1.fffffep-1f;
    pt_lights_sample(L, &t.s, p, NO_N, u, &a);
    CHECK(a.tri < 5);
    pt_lights_free(L);
}

/* Many lights with powers spread over decades: Vose's table must still be
 * exact. 64 triangles with power proportional to 1 + i^2. */
static void test_choice_many(void)
{
    rng_state = 2;
    static tscene t; /* large: keep it off the stack */
    ts_init(&t);
    uint32_t m = ts_material(&t, 1, 1, 1, 0, -1);
    double pmf[MAX_T], obs[MAX_T] = {0}, expd[MAX_T];
    for (int i = 0; i < MAX_T; i++) {
        float sz = sqrtf(1.0f + (float)(i * i));
        float x = 3.0f * (float)i;
        ts_tri(&t, pt_v3(x, 0, 5), pt_v3(x + sz, 0, 5), pt_v3(x, sz, 5), m, pt_v3(0, 0, 0));
    }
    expected_pmf(&t.s, 1.0, pmf);
    pt_lights *L = NULL;
    /* By power: from PT_LIGHT_TREE_MIN lights on the default is the light
     * tree (test_light_tree.c). */
    CHECK(pt_lights_new_select(&t.s, NULL, 0, PT_LIGHT_SELECT_POWER, &L, NULL) == PT_OK);
    if (!L)
        return;
    const int n = 200000;
    for (int i = 0; i < n; i++) {
        float u[3];
        rnd3(u);
        pt_light_sample s;
        pt_lights_sample(L, &t.s, pt_v3(0, 0, 0), NO_N, u, &s);
        if (s.tri < MAX_T)
            obs[s.tri] += 1;
    }
    for (int i = 0; i < MAX_T; i++)
        expd[i] = n * pmf[i];
    double chi;
    int dof;
    double pv = chi2_test(obs, expd, MAX_T, &chi, &dof);
    CHECKF(pv > P_MIN, "many lights: chi2 %.2f, dof %d, p %.3g", chi, dof, pv);
    printf("many lights choice: chi2 %.2f dof %d p %.3f\n", chi, dof, pv);
    pt_lights_free(L);
}

/* ---- uniform area sampling ----------------------------------------------------------------- */

static void test_area_uniform(void)
{
    rng_state = 3;
    tscene t;
    ts_init(&t);
    uint32_t m = ts_material(&t, 1, 1, 1, 1, -1);
    /* A skewed, obtuse triangle in general position. */
    ts_tri(&t, pt_v3(0.2f, -0.3f, 2.0f), pt_v3(3.1f, 0.4f, 2.6f), pt_v3(-0.9f, 1.7f, 1.5f), m,
           pt_v3(0, 0, 0));
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    /* 8 x 8 = 64 congruent sub-triangles: cell (i, j) of the grid in
     * (b1, b2) scaled by 8, its lower half (i + j <= 7) or its upper half
     * (i + j <= 6). Bins [0, 64) are lower halves, [64, 128) upper ones;
     * the cells that do not exist expect 0. */
    enum { M = 8, NB = 2 * M * M };
    double obs[NB] = {0}, expd[NB];
    const int n = 128000;
    int outside = 0;
    for (int k = 0; k < n; k++) {
        float u[3];
        rnd3(u);
        pt_light_sample s;
        if (!pt_lights_sample(L, &t.s, pt_v3(0, 0, 0), NO_N, u, &s))
            continue;
        double b1, b2;
        barycentrics(&t.s, 0, s.position, &b1, &b2);
        if (b1 < -1e-5 || b2 < -1e-5 || b1 + b2 > 1 + 1e-5) {
            outside++;
            continue;
        }
        double x = fmin(fmax(b1 * M, 0), M - 1e-9), y = fmin(fmax(b2 * M, 0), M - 1e-9);
        int i = (int)x, j = (int)y;
        int upper = (x - i) + (y - j) > 1.0;
        if (i + j > M - 1 || (upper && i + j > M - 2))
            upper = 0, i = i + j > M - 1 ? i - 1 : i; /* rounding past the hypotenuse */
        obs[(upper ? M * M : 0) + i * M + j] += 1;
    }
    for (int b = 0; b < NB; b++) {
        int up = b >= M * M, i = (b % (M * M)) / M, j = b % M;
        expd[b] = i + j <= M - 1 - up ? (double)n / (M * M) : 0.0;
    }
    double chi;
    int dof;
    double pv = chi2_test(obs, expd, NB, &chi, &dof);
    CHECK(outside == 0);
    CHECKF(pv > P_MIN, "area sampling: chi2 %.2f, dof %d, p %.3g", chi, dof, pv);
    printf("area sampling: chi2 %.2f dof %d p %.3f\n", chi, dof, pv);
    pt_lights_free(L);
}

/* ---- solid-angle pdf ---------------------------------------------------------------------- */

/* Density of sampled directions from p along unit d: the sampler ignores
 * occlusion, so every light that d crosses contributes its pdf. */
static double direction_pdf(const pt_lights *L, const pt_scene *s, pt_vec3 p, const double d[3])
{
    double o[3] = {p.x, p.y, p.z}, sum = 0;
    for (uint32_t i = 0; i < s->num_triangles; i++) {
        double t = ray_tri(s, i, o, d);
        if (t <= 0)
            continue;
        double n[3];
        tri_area(s, i, n);
        pt_vec3 hit =
            pt_v3((float)(o[0] + t * d[0]), (float)(o[1] + t * d[1]), (float)(o[2] + t * d[2]));
        sum += pt_lights_pdf(L, s, i, p, NO_N, hit, pt_v3((float)n[0], (float)n[1], (float)n[2]));
    }
    return sum;
}

static void sph_dir(double cos_t, double phi, double d[3])
{
    double st = sqrt(fmax(0.0, 1.0 - cos_t * cos_t));
    d[0] = st * cos(phi);
    d[1] = st * sin(phi);
    d[2] = cos_t;
}

/* Chi-square of sampled directions against the pdf integrated over
 * (cos theta, phi) bins, from p; returns the integral of the pdf. */
static double directions_chi2(const pt_lights *L, const pt_scene *s, pt_vec3 p, const char *what)
{
    enum { NT = 24, NP = 48, SUB = 512, NB = NT * NP };
    static double obs[NB], expd[NB];
    const int n = 300000;
    const double n_samples = n;
    memset(obs, 0, sizeof obs);
    int accepted = 0;
    for (int k = 0; k < n; k++) {
        float u[3];
        rnd3(u);
        pt_light_sample ls;
        if (!pt_lights_sample(L, s, p, NO_N, u, &ls))
            continue;
        accepted++;
        double z = ls.wi.z, phi = atan2(ls.wi.y, ls.wi.x);
        int i = (int)((z + 1.0) * 0.5 * NT), j = (int)((phi + PI_D) / (2 * PI_D) * NP);
        i = i < 0 ? 0 : i >= NT ? NT - 1 : i;
        j = j < 0 ? 0 : j >= NP ? NP - 1 : j;
        obs[i * NP + j] += 1;
    }
    /* The pdf integrated over each bin, by the change of variables to the
     * light's area (dw = |cos theta_light| / d^2 dA): the bins' edges then cut
     * a fine grid of SUB^2 sub-triangles per light (midpoint rule at their
     * centroids) instead of a grid in angle cutting the lights' edges, where
     * a thin sliver of light could fall between grid points. */
    memset(expd, 0, sizeof expd);
    double integral = 0;
    for (uint32_t k = 0; k < s->num_triangles; k++) {
        pt_vec3 v[3];
        double nrm[3];
        double area = tri_area(s, k, nrm);
        tri_verts(s, k, v);
        pt_vec3 nf = pt_v3((float)nrm[0], (float)nrm[1], (float)nrm[2]);
        double da = area / ((double)SUB * SUB);
        for (int i = 0; i < SUB; i++) {
            for (int j = 0; j < SUB - i; j++) {
                for (int up = 0; up < 2 && (up == 0 || i + j < SUB - 1); up++) {
                    double b1 = (i + (up ? 2.0 : 1.0) / 3.0) / SUB,
                           b2 = (j + (up ? 2.0 : 1.0) / 3.0) / SUB;
                    double b0 = 1 - b1 - b2, x[3], d[3];
                    x[0] = b0 * v[0].x + b1 * v[1].x + b2 * v[2].x;
                    x[1] = b0 * v[0].y + b1 * v[1].y + b2 * v[2].y;
                    x[2] = b0 * v[0].z + b1 * v[1].z + b2 * v[2].z;
                    d[0] = x[0] - p.x;
                    d[1] = x[1] - p.y;
                    d[2] = x[2] - p.z;
                    double d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], dl = sqrt(d2);
                    double cosl = fabs(nrm[0] * d[0] + nrm[1] * d[1] + nrm[2] * d[2]) / dl;
                    float pdf = pt_lights_pdf(L, s, k, p, NO_N,
                                              pt_v3((float)x[0], (float)x[1], (float)x[2]), nf);
                    if (!(pdf > 0.0f))
                        continue;
                    double w = pdf * cosl / d2 * da;
                    int bi = (int)((d[2] / dl + 1.0) * 0.5 * NT);
                    int bj = (int)((atan2(d[1], d[0]) + PI_D) / (2 * PI_D) * NP);
                    bi = bi < 0 ? 0 : bi >= NT ? NT - 1 : bi;
                    bj = bj < 0 ? 0 : bj >= NP ? NP - 1 : bj;
                    expd[bi * NP + bj] += n_samples * w;
                    integral += w;
                }
            }
        }
    }
    double chi;
    int dof;
    double pv = chi2_test(obs, expd, NB, &chi, &dof);
    CHECKF(pv > P_MIN, "%s: directions chi2 %.2f, dof %d, p %.3g", what, chi, dof, pv);
    /* Samples that come back impossible are exactly the missing mass. */
    CHECKF(fabs(accepted / (double)n - integral) <
               4.0 * sqrt(fmax(0.0, integral * (1 - integral)) / n) + 1e-3,
           "%s: accepted %.4f, integral %.4f", what, accepted / (double)n, integral);
    printf("%s: directions chi2 %.2f dof %d p %.3f, integral %.4f\n", what, chi, dof, pv, integral);
    return integral;
}

/* MC estimate of the pdf's integral over the sphere (uniform directions):
 * the mean and its standard error. */
static void pdf_integral_mc(const pt_lights *L, const pt_scene *s, pt_vec3 p, int n, double *mean,
                            double *se)
{
    double sum = 0, sum2 = 0;
    for (int k = 0; k < n; k++) {
        double d[3];
        sph_dir(1.0 - 2.0 * rnd(), 2 * PI_D * rnd(), d);
        double f = 4 * PI_D * direction_pdf(L, s, p, d);
        sum += f;
        sum2 += f * f;
    }
    *mean = sum / n;
    *se = sqrt(fmax(0.0, sum2 / n - *mean * *mean) / (n - 1));
}

static void test_solid_angle_pdf(void)
{
    rng_state = 4;
    tscene t;
    build_main(&t);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    double pmf[MAX_T];
    expected_pmf(&t.s, MAIN_TEX_MEAN, pmf);

    /* From the origin every light is visible: the pdf integrates to 1. */
    double integral = directions_chi2(L, &t.s, pt_v3(0, 0, 0), "origin");
    CHECKF(fabs(integral - 1.0) < 5e-3, "numerical integral %.5f", integral);
    double mean, se;
    pdf_integral_mc(L, &t.s, pt_v3(0, 0, 0), 400000, &mean, &se);
    CHECKF(fabs(mean - 1.0) < 4 * se, "MC integral %.4f +- %.4f", mean, se);
    printf("origin: MC integral of the pdf %.4f +- %.4f\n", mean, se);

    /* From above light 0 (single-sided, facing down) its share is missing. */
    pt_vec3 q = pt_v3(0.1f, 0.0f, 1.6f);
    integral = directions_chi2(L, &t.s, q, "above light 0");
    CHECKF(fabs(integral - (1.0 - pmf[0])) < 5e-3, "numerical integral %.5f, expected %.5f",
           integral, 1.0 - pmf[0]);
    pdf_integral_mc(L, &t.s, q, 400000, &mean, &se);
    CHECKF(fabs(mean - (1.0 - pmf[0])) < 4 * se, "MC integral %.4f +- %.4f, expected %.4f", mean,
           se, 1.0 - pmf[0]);
    printf("above light 0: MC integral %.4f +- %.4f (expected %.4f)\n", mean, se, 1.0 - pmf[0]);
    pt_lights_free(L);
}

/* ---- pdf, radiance and sample agree --------------------------------------------------------- */

static void test_pdf_consistency(void)
{
    rng_state = 5;
    tscene t;
    build_main(&t);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    double pmf[MAX_T];
    expected_pmf(&t.s, MAIN_TEX_MEAN, pmf);
    int ok = 0, zero = 0, bad_eq = 0, bad_formula = 0, bad_rad = 0, bad_zero = 0;
    for (int k = 0; k < 20000; k++) {
        pt_vec3 p = pt_v3(4 * rnd() - 2, 4 * rnd() - 2, 4 * rnd() - 2);
        float u[3];
        rnd3(u);
        pt_light_sample s;
        int r = pt_lights_sample(L, &t.s, p, NO_N, u, &s);
        if (!r) {
            zero++;
            bad_zero += s.pdf != 0.0f || pt_v3_max_comp(s.radiance) != 0.0f;
            continue;
        }
        ok++;
        /* pt_lights_pdf for the same point is the same number. */
        float pdf = pt_lights_pdf(L, &t.s, s.tri, p, NO_N, s.position, s.normal);
        bad_eq += pdf != s.pdf;
        /* ... and the documented formula, evaluated here in double. */
        double n[3];
        double area = tri_area(&t.s, s.tri, n);
        double d[3] = {(double)s.position.x - p.x, (double)s.position.y - p.y,
                       (double)s.position.z - p.z};
        double d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double cosl = fabs(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / sqrt(d2);
        double want = pmf[s.tri] / area * d2 / cosl;
        /* float rounding of the cosine grows as 1/cos at grazing angles */
        if (!(fabs(s.pdf - want) <= (1e-4 + 1e-5 / cosl) * want))
            bad_formula++;
        /* direction and distance */
        bad_formula +=
            fabs(pt_v3_len(s.wi) - 1.0f) > 1e-5f || fabs(s.dist - sqrt(d2)) > 1e-5 * s.dist;
        /* radiance: the factor, times the texture at the interpolated UVs */
        double b1, b2;
        barycentrics(&t.s, s.tri, s.position, &b1, &b2);
        pt_vec3 want_rad = pt_emitted(&t.s, s.tri, (float)b1, (float)b2, pt_v3_neg(s.wi));
        bad_rad += pt_v3_len(pt_v3_sub(want_rad, s.radiance)) > 1e-3f;
        if (t.s.materials[t.s.tri_material[s.tri]].emissive_tex < 0) {
            const float *e = t.s.materials[t.s.tri_material[s.tri]].emissive;
            bad_rad += s.radiance.x != e[0] || s.radiance.y != e[1] || s.radiance.z != e[2];
        }
    }
    CHECKF(bad_eq == 0, "%d of %d pdfs differ from pt_lights_pdf", bad_eq, ok);
    CHECKF(bad_formula == 0, "%d of %d pdfs differ from the formula", bad_formula, ok);
    CHECKF(bad_rad == 0, "%d of %d radiances wrong", bad_rad, ok);
    CHECKF(bad_zero == 0, "%d of %d failed samples with pdf or radiance", bad_zero, zero);
    CHECK(ok > 1000 && zero > 1000); /* both cases exercised */

    /* Not a light, or out of range: 0. */
    CHECK(pt_lights_pdf(L, &t.s, 5, pt_v3(0, 0, 0), NO_N, pt_v3(0.2f, 2, 0.2f), pt_v3(0, -1, 0)) ==
          0.0f);
    CHECK(pt_lights_pdf(L, &t.s, 6, pt_v3(0, 0, 0), NO_N, pt_v3(1, -3, 0), pt_v3(0, 0, 1)) == 0.0f);
    CHECK(pt_lights_pdf(L, &t.s, 1000, pt_v3(0, 0, 0), NO_N, pt_v3(1, 1, 1), pt_v3(0, 0, 1)) ==
          0.0f);
    pt_lights_free(L);
}

/* ---- sides ------------------------------------------------------------------------------- */

static void test_sides(void)
{
    rng_state = 6;
    tscene t;
    build_main(&t);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    double n0[3], n1[3];
    tri_area(&t.s, 0, n0);
    tri_area(&t.s, 1, n1);
    CHECK(n0[2] < -0.9); /* light 0 faces down, towards the origin */

    /* Behind light 0: every sample of it is impossible, and says so. */
    pt_vec3 above = pt_v3(0.1f, 0.0f, 1.6f);
    int light0 = 0, bad = 0;
    for (int k = 0; k < 5000; k++) {
        float u[3];
        rnd3(u);
        pt_light_sample s;
        int r = pt_lights_sample(L, &t.s, above, NO_N, u, &s);
        if (s.tri != 0)
            continue;
        light0++;
        bad += r != 0 || s.pdf != 0.0f || pt_v3_max_comp(s.radiance) != 0.0f;
        bad += pt_lights_pdf(L, &t.s, 0, above, NO_N, s.position, s.normal) != 0.0f;
    }
    CHECK(light0 > 100 && bad == 0);

    /* pt_emitted: single-sided only in front, double-sided both ways. */
    pt_vec3 down = pt_v3(0, 0, -1), up = pt_v3(0, 0, 1);
    CHECK(pt_emitted(&t.s, 0, 0.3f, 0.3f, down).x == 2.0f);
    CHECK(pt_v3_max_comp(pt_emitted(&t.s, 0, 0.3f, 0.3f, up)) == 0.0f);
    pt_vec3 w1 = pt_v3((float)n1[0], (float)n1[1], (float)n1[2]);
    CHECK(pt_emitted(&t.s, 1, 0.3f, 0.3f, w1).x == 2.0f);
    CHECK(pt_emitted(&t.s, 1, 0.3f, 0.3f, pt_v3_neg(w1)).x == 2.0f);
    CHECK(pt_v3_max_comp(pt_emitted(&t.s, 5, 0.3f, 0.3f, up)) == 0.0f); /* not emissive */
    /* The textured light (vertex uvs (0,0), (1,0), (0,1), so uv = (b1, b2)):
     * uv (0.25, 0.25) is the centre of the white texel, (0.75, 0.25) the
     * centre of a black one. */
    pt_vec3 toward0 = pt_v3(0, 1, 0);
    pt_vec3 e = pt_emitted(&t.s, 2, 0.25f, 0.25f, toward0);
    CHECKF(fabsf(e.x - 1.0f) < 1e-5f, "textured emission %g", e.x);
    e = pt_emitted(&t.s, 2, 0.75f, 0.25f, toward0);
    CHECK(pt_v3_max_comp(e) < 1e-5f);

    /* Light 1 is double-sided and wound away from the origin: seen from the
     * origin (its back) it is a valid sample with a positive pdf. */
    int light1 = 0;
    bad = 0;
    for (int k = 0; k < 5000; k++) {
        float u[3];
        rnd3(u);
        pt_light_sample s;
        int r = pt_lights_sample(L, &t.s, pt_v3(0, 0, 0), NO_N, u, &s);
        if (s.tri != 1)
            continue;
        light1++;
        bad += !r || !(s.pdf > 0.0f) || s.radiance.x != 2.0f;
    }
    CHECK(light1 > 100 && bad == 0);

    /* A point in the plane of a light (grazing): pdf 0, never Inf or NaN. */
    pt_vec3 v[3];
    tri_verts(&t.s, 0, v);
    pt_vec3 inplane = pt_v3_add(v[0], pt_v3_scale(pt_v3_sub(v[0], v[1]), 1.0f));
    float pdf = pt_lights_pdf(L, &t.s, 0, inplane, NO_N, pt_v3_scale(pt_v3_add(v[0], v[2]), 0.5f),
                              pt_v3((float)n0[0], (float)n0[1], (float)n0[2]));
    CHECK(isfinite(pdf));
    pt_lights_free(L);
}

/* ---- scenes without emitters, bad input, allocation failure ---------------------------------- */

/* pt_lights_sample_n gives pt_lights_sample's results bit for bit: points all
 * around the lights (both sides of the single-sided ones, on a light's
 * vertex, not finite), every length of a batch around its 8-lane steps,
 * with the alias table and with the light tree, and a scene without
 * lights. */
static void check_sample_n(const pt_lights *L, const pt_scene *s, const char *what)
{
    enum { N = 77 };
    pt_vec3 p[N], nrm[N];
    float u[N][3];
    pt_light_sample a[N], b;
    int ok[N];
    int bad = 0, valid = 0;
    for (int round = 0; round < 40; round++) {
        for (int i = 0; i < N; i++) {
            p[i] = pt_v3(4.0f * rnd() - 2.0f, 4.0f * rnd() - 2.0f, 4.0f * rnd() - 2.0f);
            rnd3(u[i]);
            /* a receiver normal, or none (every fourth) */
            float un[3];
            rnd3(un);
            nrm[i] =
                i % 4 == 0 ? NO_N : pt_v3_norm(pt_v3(un[0] - 0.5f, un[1] - 0.5f, un[2] - 0.5f));
        }
        p[3] = pt_v3(-0.6f, -0.5f, 1); /* light 0's first vertex */
        u[3][1] = u[3][2] = 0.0f;
        p[5] = pt_v3(NAN, 0, 0);
        p[6] = pt_v3(INFINITY, 0, 0);
        p[7] = pt_v3(0.1f, 0.0f, 1.6f); /* behind light 0 */
        u[8][0] = 0x1.fffffep-1f;
        for (uint32_t n = 0; n <= N; n += (n < 18 ? 1 : 19)) {
            memset(a, 0xa5, sizeof a);
            pt_lights_sample_n(L, s, n, p, nrm, (const float(*)[3])u, a, ok);
            for (uint32_t i = 0; i < n; i++) {
                int r = pt_lights_sample(L, s, p[i], nrm[i], u[i], &b);
                bad += r != ok[i] || memcmp(&a[i], &b, sizeof b) != 0;
                valid += r;
            }
        }
    }
    CHECKF(bad == 0, "%s: %d batched light samples differ from single ones", what, bad);
    CHECK(valid > 0 || pt_lights_count(L) == 0);
}

static void test_sample_n(void)
{
    rng_state = 8;
    tscene t;
    build_main(&t);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (L)
        check_sample_n(L, &t.s, "main scene");
    pt_lights_free(L);
    /* through the light tree: the batched walks (pt_light_tree_sample_n) */
    L = NULL;
    CHECK(pt_lights_new_select(&t.s, NULL, 0, PT_LIGHT_SELECT_TREE, &L, NULL) == PT_OK);
    CHECK(pt_lights_has_tree(L));
    if (L)
        check_sample_n(L, &t.s, "main scene, light tree");
    pt_lights_free(L);

    ts_init(&t);
    uint32_t m = ts_material(&t, 0, 0, 0, 0, -1);
    ts_tri(&t, pt_v3(0, 0, 1), pt_v3(1, 0, 1), pt_v3(0, 1, 1), m, pt_v3(0, 0, 0));
    L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (L)
        check_sample_n(L, &t.s, "no lights");
    pt_lights_free(L);
}

/* Many textured lights (past the count from which pt_lights_sample_n
 * prefetches), on both coordinate sets, one under a texture transform, with
 * random vertex coordinates and texels: every sample's radiance is the
 * emission at its point that pt_emitted computes from the scene's own
 * indices and coordinates, bit for bit (the lights keep a copy of each
 * light's coordinates), batched or not. The barycentrics are the sampler's
 * (Heitz 2019's map, as light.c draws them). */
static void test_emission_copy(void)
{
    enum { NT = 700, NV = 3 * NT, TW = 16 };
    pt_scene s;
    memset(&s, 0, sizeof s);
    float *pos = calloc(3 * NV, sizeof *pos), *uv0 = calloc(2 * NV, sizeof *uv0),
          *uv1 = calloc(2 * NV, sizeof *uv1);
    uint32_t *idx = calloc(3 * NT, sizeof *idx), *tmat = calloc(NT, sizeof *tmat);
    uint8_t *texels = malloc(4 * TW * TW);
    pt_material mats[2];
    pt_texture tex;
    if (!pos || !uv0 || !uv1 || !idx || !tmat || !texels) {
        CHECK(0);
        goto done;
    }
    rng_state = 31;
    for (int i = 0; i < 4 * TW * TW; i++)
        texels[i] = (uint8_t)(rnd() * 256.0f);
    memset(&tex, 0, sizeof tex);
    tex.width = tex.height = TW;
    tex.rgba = texels;
    tex.srgb = 1;
    memset(mats, 0, sizeof mats);
    for (int k = 0; k < 2; k++) {
        mats[k].base_color_tex = mats[k].metal_rough_tex = -1;
        mats[k].emissive[0] = 1.0f + k;
        mats[k].emissive[1] = 0.5f;
        mats[k].emissive[2] = 2.0f;
        mats[k].emissive_tex = 0;
        mats[k].double_sided = 1;
        for (int sl = 0; sl < PT_SLOT_COUNT; sl++)
            mats[k].tex_xf[sl] = pt_tex_xform_identity();
    }
    const float off[2] = {0.25f, -0.5f}, scale[2] = {1.5f, 0.75f};
    mats[1].tex_xf[PT_SLOT_EMISSIVE] = pt_tex_xform_make(off, 0.3f, scale, 1);
    for (int t = 0; t < NT; t++) {
        float x = (float)(t % 30) * 0.1f, y = (float)(t / 30) * 0.1f;
        const float p[9] = {x, y, 0.0f, x + 0.08f, y, 0.01f, x, y + 0.08f, -0.01f};
        for (int c = 0; c < 3; c++) {
            memcpy(&pos[3 * (3 * t + c)], &p[3 * c], 3 * sizeof(float));
            for (int a = 0; a < 2; a++) {
                uv0[2 * (3 * t + c) + a] = 3.0f * rnd() - 1.0f;
                uv1[2 * (3 * t + c) + a] = 3.0f * rnd() - 1.0f;
            }
            /* Corners in another order than the vertices, so that a copy
             * by vertex instead of by index would show. */
            idx[3 * t + c] = (uint32_t)(3 * t + (c + t) % 3);
        }
        tmat[t] = (uint32_t)(t % 2);
    }
    s.num_vertices = NV;
    s.num_triangles = NT;
    s.positions = pos;
    s.uvs = uv0;
    s.uvs1 = uv1;
    s.indices = idx;
    s.tri_material = tmat;
    s.num_materials = 2;
    s.materials = mats;
    s.num_textures = 1;
    s.textures = &tex;
    s.bounds_max = pt_v3(3, 3, 1);
    s.bounds_min = pt_v3(0, 0, -1);
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&s, &L, NULL) == PT_OK);
    if (!L)
        goto done;
    CHECK(pt_lights_count(L) == NT);
    enum { N = 64 };
    int bad = 0, valid = 0;
    for (int round = 0; round < 200; round++) {
        pt_vec3 p[N], nrm[N];
        float u[N][3];
        pt_light_sample a[N], b;
        int ok[N];
        for (int i = 0; i < N; i++) {
            p[i] = pt_v3(3.0f * rnd(), 3.0f * rnd(), 1.0f + rnd());
            rnd3(u[i]);
            nrm[i] = pt_v3(0.0f, 0.0f, -1.0f); /* facing the lights */
        }
        pt_lights_sample_n(L, &s, N, p, nrm, (const float(*)[3])u, a, ok);
        for (int i = 0; i < N; i++) {
            int r = pt_lights_sample(L, &s, p[i], nrm[i], u[i], &b);
            bad += r != ok[i] || memcmp(&a[i], &b, sizeof b) != 0;
            if (!r)
                continue;
            int upper = u[i][2] > u[i][1];
            float h1 = 0.5f * u[i][1], h2 = 0.5f * u[i][2];
            float b1 = upper ? h1 : u[i][1] - h2, b2 = upper ? u[i][2] - h1 : h2;
            pt_vec3 want = pt_emitted(&s, b.tri, b1, b2, pt_v3_neg(b.wi));
            bad += memcmp(&want, &b.radiance, sizeof want) != 0;
            valid++;
        }
    }
    CHECKF(bad == 0 && valid > 10000, "%d of %d textured light samples differ from pt_emitted", bad,
           valid);
    pt_lights_free(L);
done:
    free(pos);
    free(uv0);
    free(uv1);
    free(idx);
    free(tmat);
    free(texels);
}

static void test_no_emitters_and_errors(void)
{
    tscene t;
    ts_init(&t);
    uint32_t m = ts_material(&t, 0, 0, 0, 0, -1);
    ts_tri(&t, pt_v3(0, 0, 1), pt_v3(1, 0, 1), pt_v3(0, 1, 1), m, pt_v3(0, 0, 0));
    pt_lights *L = NULL;
    pt_error err;
    CHECK(pt_lights_new(&t.s, &L, &err) == PT_OK);
    CHECK(L && pt_lights_count(L) == 0);
    float u[3] = {0.5f, 0.5f, 0.5f};
    pt_light_sample s;
    CHECK(pt_lights_sample(L, &t.s, pt_v3(0, 0, 0), NO_N, u, &s) == 0);
    CHECK(s.pdf == 0.0f);
    CHECK(pt_lights_pdf(L, &t.s, 0, pt_v3(0, 0, 0), NO_N, pt_v3(0.2f, 0.2f, 1), pt_v3(0, 0, -1)) ==
          0.0f);
    pt_lights_free(L);
    pt_lights_free(NULL);
    CHECK(pt_lights_count(NULL) == 0);

    /* No triangles at all. */
    pt_scene empty;
    memset(&empty, 0, sizeof empty);
    CHECK(pt_lights_new(&empty, &L, &err) == PT_OK);
    CHECK(pt_lights_count(L) == 0);
    pt_lights_free(L);

    /* Bad input: a material index or emissive texture out of range. */
    pt_lights *sentinel = (pt_lights *)&t;
    L = sentinel;
    t.tmat[0] = 7;
    CHECK(pt_lights_new(&t.s, &L, &err) == PT_ERR_FORMAT && L == sentinel);
    t.tmat[0] = m;
    t.mats[m].emissive[0] = 1.0f;
    t.mats[m].emissive_tex = 3;
    CHECK(pt_lights_new(&t.s, &L, &err) == PT_ERR_FORMAT && L == sentinel);
    CHECK(pt_lights_new(NULL, &L, &err) == PT_ERR_ARG);

    /* Allocation failure at every step: an error, nothing leaked, then it
     * succeeds. */
    build_main(&t);
    int64_t live = pt_alloc_live();
    int failures = 0;
    for (uint64_t n = 1; n < 64; n++) {
        L = sentinel;
        pt_alloc_fail_at(n);
        pt_status st = pt_lights_new(&t.s, &L, &err);
        pt_alloc_fail_at(0);
        if (st == PT_OK) {
            CHECK(pt_lights_count(L) == MAIN_NUM_LIGHTS);
            pt_lights_free(L);
            break;
        }
        failures++;
        CHECK(st == PT_ERR_NOMEM && L == sentinel);
        CHECK(pt_alloc_live() == live);
    }
    CHECK(failures >= 4);
    CHECK(pt_alloc_live() == live);
}

/* Two triangles under one emissive texture whose only white texel is (0,0):
 * one maps into that texel, the other into the black texel (1,1). Chosen by
 * their footprints, only the first is a light; by the texture's mean both
 * would be, equally. */
static void test_footprint(void)
{
    static tscene t;
    build_main(&t);
    t.s.num_triangles = 0;
    t.s.num_vertices = 0;
    uint32_t m2 = 2; /* white x the texture */
    const float uv[2][3][2] = {{{0.05f, 0.05f}, {0.45f, 0.05f}, {0.05f, 0.45f}},
                               {{0.55f, 0.55f}, {0.95f, 0.55f}, {0.55f, 0.95f}}};
    for (int k = 0; k < 2; k++) {
        float x = 2.0f * (float)k;
        uint32_t tri =
            ts_tri(&t, pt_v3(x, 0, 1), pt_v3(x + 1, 0, 1), pt_v3(x, 1, 1), m2, pt_v3(0, 0, 0));
        for (int c = 0; c < 3; c++) {
            uint32_t v = t.idx[3 * tri + c];
            /* the vertex's corner of the UV triangle, by its position */
            float px = t.pos[3 * v] - x, py = t.pos[3 * v + 1];
            int corner = px > 0.5f ? 1 : py > 0.5f ? 2 : 0;
            t.uv[2 * v] = uv[k][corner][0];
            t.uv[2 * v + 1] = uv[k][corner][1];
        }
    }
    pt_lights *L = NULL;
    CHECK(pt_lights_new(&t.s, &L, NULL) == PT_OK);
    if (!L)
        return;
    CHECKF(pt_lights_count(L) == 1, "%u lights, expected the one over the white texel",
           pt_lights_count(L));
    CHECK(pt_lights_pdf(L, &t.s, 1, pt_v3(2.2f, 0.2f, 0), NO_N, pt_v3(2.2f, 0.2f, 1),
                        pt_v3(0, 0, -1)) == 0.0f);
    CHECK(pt_lights_pdf(L, &t.s, 0, pt_v3(0.2f, 0.2f, 0), NO_N, pt_v3(0.2f, 0.2f, 1),
                        pt_v3(0, 0, -1)) > 0.0f);
    pt_lights_free(L);
}

int main(void)
{
    test_footprint();
    test_choice();
    test_choice_many();
    test_area_uniform();
    test_solid_angle_pdf();
    test_pdf_consistency();
    test_sides();
    test_sample_n();
    test_emission_copy();
    test_no_emitters_and_errors();
    return check_report();
}
