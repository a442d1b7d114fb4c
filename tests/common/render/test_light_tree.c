/*
 * test_light_tree.c - the light tree (common/render/light_tree.c) and NEE
 * through it (common/render/light.c).
 *
 * - The pmf sums to at most 1 over the lights at every shading point (within
 *   double rounding, 1e-9), and to more than 0.9 here: the rest is the chance
 *   of a walk that ends at a node whose children both have importance 0 (no
 *   light chosen, no bias).
 * - Chi-square goodness of fit of the lights the tree samples (and of the
 *   walks that choose none) against its own pmf, at several shading points,
 *   without and with a receiver normal (200,000 draws, p > 1e-3; bins
 *   expected below 5 pooled), and the pmf the sampler returns has the bits
 *   of pt_light_tree_pmf.
 * - Conservative bounds: every light that can light a point (some vertex in
 *   front of it, and above the receiver's tangent plane) has a pmf above 0
 *   there, else NEE would lose its light.
 * - The receiver's side: lights whose bounds lie wholly below the receiver's
 *   tangent plane get pmf 0 (through pt_lights, pdf 0); NEE's irradiance
 *   estimate with the normal still equals Lambert's closed form within a
 *   z-test, at under 2/3 the variance without it; the MIS weights of a
 *   light sample and of the same direction found by the BSDF sum to 1.
 * - Through pt_lights, with an environment too: pt_lights_pdf at a sample's
 *   point equals the sample's pdf (the bits that the MIS weight of a BSDF hit
 *   needs), and the same build twice gives the same bits.
 * - Images: EmissiveStrengthTest (five emissive cubes, 60 light triangles), a
 *   ring of 48 small lights over a floor, the ring with 48 brighter lights
 *   under the floor (the tree with the floor's normal gives them nothing,
 *   the choice by power most of its samples), and the ring with 18 point and spot
 *   lights (in the tree) and a directional one, rendered with the tree and with
 *   the power-proportional choice, agree per 8 x 8 block: the difference of
 *   the block means over its standard error, the pixels' own sample variances
 *   (conservative under the sampler's stratification), stays under the
 *   two-sided normal quantile for a family-wise false alarm of 1e-3 over all
 *   blocks and channels (Bonferroni).
 * - One step chooses among four nodes: four lights two levels deep get
 *   pmfs in proportion to their own importances; pt_light_tree_sample_n
 *   gives pt_light_tree_sample's bits.
 * - Coarse nodes: coplanar lights seen from far are chosen by power alone
 *   (pmf and sampler), from close by by the tree.
 * - Bad input (counts, NaN, zero power) and allocation failure.
 * - The default (PT_LIGHT_SELECT_AUTO) takes the tree from PT_LIGHT_TREE_MIN
 *   to PT_LIGHT_TREE_AUTO_MAX lights spread over PT_LIGHT_TREE_MIN_SPREAD of
 *   the scene or more, the alias table by power outside that;
 *   PT_LIGHT_SELECT_TREE takes the tree whatever the count.
 */
#include "common/render/light_tree.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/blocks.h"
#include "tests/common/render/paired.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define NL 300
/* No receiver normal: no bound by the receiver's side. */
#define NO_N pt_v3(0.0f, 0.0f, 0.0f)
#define P_MIN 1e-3

static uint64_t rng_state;

static double rnd(void)
{
    return rng_f53(&rng_state);
}

static pt_vec3 rnd_dir(void)
{
    double z = 2.0 * rnd() - 1.0, phi = 2.0 * 3.14159265358979323846 * rnd();
    double r = sqrt(fmax(0.0, 1.0 - z * z));
    return pt_v3((float)(r * cos(phi)), (float)(r * sin(phi)), (float)z);
}

/* NL random triangles in a 20-unit box, random sizes, normals and powers;
 * every third two-sided. Their vertices go to v (3 per light). */
static void random_lights(pt_light_tree_item *it, pt_vec3 *v, int n)
{
    for (int i = 0; i < n; i++) {
        pt_vec3 c = pt_v3((float)(20 * rnd() - 10), (float)(20 * rnd() - 10), (float)(20 * rnd()));
        float sz = (float)(0.05 + 0.5 * rnd());
        pt_vec3 a = pt_v3_add(c, pt_v3_scale(rnd_dir(), sz));
        pt_vec3 b = pt_v3_add(c, pt_v3_scale(rnd_dir(), sz));
        pt_vec3 d = pt_v3_add(c, pt_v3_scale(rnd_dir(), sz));
        v[3 * i] = a;
        v[3 * i + 1] = b;
        v[3 * i + 2] = d;
        it[i].lo = pt_v3(fminf(fminf(a.x, b.x), d.x), fminf(fminf(a.y, b.y), d.y),
                         fminf(fminf(a.z, b.z), d.z));
        it[i].hi = pt_v3(fmaxf(fmaxf(a.x, b.x), d.x), fmaxf(fmaxf(a.y, b.y), d.y),
                         fmaxf(fmaxf(a.z, b.z), d.z));
        it[i].axis = pt_v3_norm(pt_v3_cross(pt_v3_sub(b, a), pt_v3_sub(d, a)));
        it[i].cos_o = 1.0f;
        it[i].power = (float)(0.1 + 10.0 * rnd() * rnd());
        it[i].two_sided = i % 3 == 0;
    }
}

static const pt_vec3 points[] = {{0, 0, 0}, {3, -2, 10}, {-9, 9, 19}, {0.5f, 0.5f, 5}, {30, 0, 2}};
#define NPOINTS (int)(sizeof points / sizeof points[0])

static void test_pmf_sums_and_sides(void)
{
    rng_state = 1;
    static pt_light_tree_item it[NL];
    static pt_vec3 v[3 * NL];
    random_lights(it, v, NL);
    pt_light_tree *t = NULL;
    pt_error err = {0};
    CHECKF(pt_light_tree_new(it, NL, &t, &err) == PT_OK, "%s", err.msg);
    if (!t)
        return;
    CHECK(pt_light_tree_nodes(t) == 2 * NL - 1);
    /* Balanced enough: well under the 64 branch bits. */
    CHECKF(pt_light_tree_depth(t) < 40, "depth %u", pt_light_tree_depth(t));
    int missed = 0;
    /* without a receiver normal, then with one: a light that can light p
     * must also have a vertex above p's tangent plane */
    for (int k = 0; k < 2 * NPOINTS; k++) {
        pt_vec3 p = points[k % NPOINTS], n = k < NPOINTS ? NO_N : rnd_dir();
        double sum = 0.0;
        int any = 0;
        for (uint32_t i = 0; i < NL; i++) {
            double q = pt_light_tree_pmf(t, p, n, i);
            sum += q;
            /* a vertex above the plane (any, without a normal) that the
             * light's emitting side faces */
            int front = 0, back = 0;
            for (int c = 0; c < 3; c++) {
                pt_vec3 vc = v[3 * i + c];
                int above = k < NPOINTS || pt_v3_dot(n, pt_v3_sub(vc, p)) > 1e-4f;
                float facing = pt_v3_dot(it[i].axis, pt_v3_sub(p, vc));
                front |= above && facing > 1e-4f;
                back |= above && facing < -1e-4f;
            }
            int lights_p = front || (it[i].two_sided && back);
            any |= lights_p;
            if (lights_p && !(q > 0.0))
                missed++;
        }
        /* with a normal, walks that end at nodes below the plane choose
         * nothing: more of them */
        CHECKF(sum < 1.0 + 1e-9 && (k < NPOINTS ? sum > 0.9 : !any || sum > 0.0),
               "point %d: pmfs sum to %.12f", k, sum);
    }
    CHECKF(missed == 0, "%d lights that light a point have pmf 0 there", missed);
    CHECK(pt_light_tree_pmf(t, points[0], NO_N, NL) == 0.0);
    pt_light_tree_free(t);
}

static void test_chi2(void)
{
    rng_state = 2;
    static pt_light_tree_item it[NL];
    static pt_vec3 v[3 * NL];
    random_lights(it, v, NL);
    pt_light_tree *t = NULL;
    CHECK(pt_light_tree_new(it, NL, &t, NULL) == PT_OK);
    if (!t)
        return;
    const int n = 200000;
    /* without a receiver normal, then with one (the bound by the side of
     * its tangent plane in every importance) */
    for (int k = 0; k < 2 * NPOINTS; k++) {
        pt_vec3 p = points[k % NPOINTS], nrm = k < NPOINTS ? NO_N : rnd_dir();
        /* bin NL: no light chosen */
        static double obs[NL + 1], expd[NL + 1];
        memset(obs, 0, sizeof obs);
        int bad_pmf = 0;
        for (int s = 0; s < n; s++) {
            double q;
            uint32_t l = pt_light_tree_sample(t, p, nrm, rnd(), &q);
            if (l >= NL) {
                bad_pmf += l != UINT32_MAX || q != 0.0;
                obs[NL] += 1;
                continue;
            }
            obs[l] += 1;
            bad_pmf += q != pt_light_tree_pmf(t, p, nrm, l);
        }
        double sum = 0.0;
        for (uint32_t i = 0; i < NL; i++) {
            expd[i] = n * pt_light_tree_pmf(t, p, nrm, i);
            sum += expd[i];
        }
        expd[NL] = fmax(0.0, n - sum);
        double chi;
        int dof;
        double pv = stats_chi2_gof(obs, expd, NL + 1, 5.0, &chi, &dof);
        CHECKF(pv > P_MIN, "point %d: chi2 %.1f dof %d p %.3g", k, chi, dof, pv);
        CHECKF(bad_pmf == 0, "point %d: %d samples whose pmf is not pt_light_tree_pmf's", k,
               bad_pmf);
        printf("tree choice at point %d%s: chi2 %.1f dof %d p %.3f\n", k % NPOINTS,
               k < NPOINTS ? "" : " with a normal", chi, dof, pv);
    }
    /* The same items, the same tree: the same bits. */
    pt_light_tree *t2 = NULL;
    CHECK(pt_light_tree_new(it, NL, &t2, NULL) == PT_OK);
    int same = t2 != NULL;
    for (int k = 0; k < NPOINTS && t2; k++)
        for (uint32_t i = 0; i < NL; i++)
            same &= pt_light_tree_pmf(t, points[k], NO_N, i) ==
                    pt_light_tree_pmf(t2, points[k], NO_N, i);
    CHECK(same);
    pt_light_tree_free(t2);
    pt_light_tree_free(t);
}

/* ---- a scene of many small lights over a floor ------------------------------------------- */

#define RING 48

/* Finishes b into *s at scale 1 when ok, else frees it: whether all went well. */
static int finish_scene(pt_scene_builder *b, int ok, pt_scene **s, pt_error *err)
{
    pt_scene_opts o = {0};
    o.scale = 1.0f;
    if (!ok) {
        pt_scene_builder_free(b);
        return 0;
    }
    return pt_scene_builder_finish(b, &o, s, err) == PT_OK;
}

/* A floor of [-4, 4]^2 at z = 0 under RING small triangles of varied colour,
 * strength and height facing down (odd ones two-sided), seen from above;
 * with punct, also 12 point lights (every third with a range), 6 spot lights
 * and a directional light; with below, also RING brighter ones under the
 * floor facing up, which light only its underside (unseen). */
static pt_scene *ring_scene(int punct, int below)
{
    pt_scene_builder *b = NULL;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.8f;
    m.metallic = 0.0f;
    m.double_sided = 1;
    uint32_t mat;
    const float fl[12] = {-4, -4, 0, 4, -4, 0, 4, 4, 0, -4, 4, 0};
    const uint32_t fi[6] = {0, 1, 2, 0, 2, 3};
    int ok =
        pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK &&
        pt_scene_builder_add_mesh(b, "floor", fl, NULL, NULL, 4, fi, 2, NULL, mat, &err) == PT_OK;
    for (uint32_t i = 0; i < RING && ok; i++) {
        float e = 2.0f + 30.0f * (float)(i % 7);
        m.emissive[0] = e * (float)(1 + i % 3);
        m.emissive[1] = e;
        m.emissive[2] = e * (float)(1 + i % 2);
        m.double_sided = (int)(i % 2);
        double a = 2.0 * 3.14159265358979323846 * i / RING;
        float rad = 1.0f + 2.5f * (float)(i % 4) / 3.0f, h = 0.3f + 0.4f * (float)(i % 5);
        float cx = rad * (float)cos(a), cy = rad * (float)sin(a), w = 0.08f;
        /* wound to face -z */
        const float tv[9] = {cx - w, cy - w, h, cx - w, cy + w, h, cx + w, cy, h};
        ok = pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK &&
             pt_scene_builder_add_mesh(b, "light", tv, NULL, NULL, 3, NULL, 1, NULL, mat, &err) ==
                 PT_OK;
    }
    for (uint32_t i = 0; i < RING && ok && below; i++) {
        float e = 50.0f + 20.0f * (float)(i % 5);
        m.emissive[0] = m.emissive[1] = m.emissive[2] = e;
        m.double_sided = 0;
        double a = 2.0 * 3.14159265358979323846 * (i + 0.5) / RING;
        float rad = 0.5f + 3.0f * (float)(i % 6) / 5.0f, h = -0.2f - 0.3f * (float)(i % 4);
        float cx = rad * (float)cos(a), cy = rad * (float)sin(a), w = 0.1f;
        /* wound to face +z */
        const float tv[9] = {cx - w, cy - w, h, cx + w, cy, h, cx - w, cy + w, h};
        ok = pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK &&
             pt_scene_builder_add_mesh(b, "under", tv, NULL, NULL, 3, NULL, 1, NULL, mat, &err) ==
                 PT_OK;
    }
    for (int i = 0; i < 19 && ok && punct; i++) {
        pt_punctual l = {0};
        double a = 0.7 * i, rad = 0.5 + 0.2 * i;
        double pos[3] = {rad * cos(a), rad * sin(a), 0.4 + 0.1 * (i % 6)};
        l.type = i < 12 ? PT_PUNCTUAL_POINT : i < 18 ? PT_PUNCTUAL_SPOT : PT_PUNCTUAL_DIRECTIONAL;
        l.intensity = pt_v3(10.0f * (float)(1 + i % 4), 15.0f, 10.0f * (float)(1 + i % 3));
        l.range = i % 3 == 0 && i < 12 ? 2.0f : 0.0f;
        l.direction = i < 18 ? pt_v3(0, 0, -1) : pt_v3_norm(pt_v3(0.3f, 0.2f, -1));
        l.cos_inner = 0.9f;
        l.cos_outer = 0.7f;
        snprintf(l.name, sizeof l.name, "light %d", i);
        ok = pt_scene_builder_add_punctual(b, &l, pos, &err) == PT_OK;
    }
    pt_camera cam = {0};
    cam.yfov = 0.9f;
    cam.znear = 0.01f;
    cam.position = pt_v3(0, -5.0f, 7.0f);
    cam.forward = pt_v3_norm(pt_v3(0, 5.0f, -7.0f));
    cam.right = pt_v3_norm(pt_v3_cross(cam.forward, pt_v3(0, 0, 1)));
    cam.up = pt_v3_cross(cam.right, cam.forward);
    ok = ok && pt_scene_builder_add_camera(b, &cam, &err) == PT_OK;
    ok = finish_scene(b, ok, &s, &err);
    CHECKF(ok, "ring scene: %s", err.msg);
    return s;
}

/* Through pt_lights: sample pdf against pt_lights_pdf at its point, with an
 * environment as a second class. */
static void test_lights_pdf(void)
{
    pt_scene *rs = ring_scene(0, 0);
    if (!rs)
        return;
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.2f, 0.2f, 0.2f), &env, NULL) == PT_OK);
    for (int with_env = 0; with_env < 2; with_env++) {
        pt_lights *L = NULL;
        CHECK(pt_lights_new_select(rs, with_env ? env : NULL, PT_ENV_MIS, PT_LIGHT_SELECT_AUTO, &L,
                                   NULL) == PT_OK);
        if (!L)
            continue;
        CHECK(pt_lights_has_tree(L));
        rng_state = 5;
        int tested = 0, bad = 0;
        for (int i = 0; i < 20000; i++) {
            pt_vec3 p = pt_v3((float)(8 * rnd() - 4), (float)(8 * rnd() - 4), (float)(2 * rnd()));
            float u[3] = {(float)rnd(), (float)rnd(), (float)rnd()};
            pt_light_sample ls;
            if (!pt_lights_sample(L, rs, p, NO_N, u, &ls) || ls.delta != PT_LIGHT_AREA)
                continue;
            tested++;
            float q = pt_lights_pdf(L, rs, ls.tri, p, NO_N, ls.position, ls.normal);
            bad += q != ls.pdf;
        }
        CHECKF(tested > 1000 && bad == 0, "env %d: %d of %d pdfs differ", with_env, bad, tested);
        pt_lights_free(L);
    }
    pt_lights *L = NULL;
    CHECK(pt_lights_new_select(rs, NULL, PT_ENV_MIS, PT_LIGHT_SELECT_POWER, &L, NULL) == PT_OK);
    CHECK(L && !pt_lights_has_tree(L));
    pt_lights_free(L);
    pt_env_free(env);
    pt_scene_free(rs);
}

static void test_images(void)
{
    pt_scene *rs = ring_scene(0, 0);
    if (rs) {
        int d = blocks_differing(rs, NULL, PT_LIGHT_SELECT_TREE, PT_LIGHT_SELECT_POWER,
                                 "ring of 48 lights", NULL);
        CHECKF(d == 0, "ring: %d blocks differ", d);
        pt_scene_free(rs);
    }
    /* lights under the floor: the tree gives them no probability from its
     * top (the receiver's normal), the choice by power spends samples on
     * them; both converge to the same image, the tree's with less
     * variance */
    rs = ring_scene(0, 1);
    if (rs) {
        double vr = 0.0;
        int d = blocks_differing(rs, NULL, PT_LIGHT_SELECT_TREE, PT_LIGHT_SELECT_POWER,
                                 "ring over 48 lights under the floor", &vr);
        CHECKF(d == 0, "ring over lights: %d blocks differ", d);
        pt_scene_free(rs);
    }
    /* point and spot lights in the tree, a directional one in its class */
    rs = ring_scene(1, 0);
    if (rs) {
        pt_lights *L = NULL;
        CHECK(pt_lights_new_select(rs, NULL, PT_ENV_MIS, PT_LIGHT_SELECT_TREE, &L, NULL) == PT_OK);
        CHECK(L && pt_lights_has_tree(L) && pt_lights_punctual_count(L) == 19);
        pt_lights_free(L);
        int d = blocks_differing(rs, NULL, PT_LIGHT_SELECT_TREE, PT_LIGHT_SELECT_POWER,
                                 "ring with 18 point and spot lights", NULL);
        CHECKF(d == 0, "ring with punctual lights: %d blocks differ", d);
        pt_scene_free(rs);
    }

    pt_scene *s = load_shared_asset("EmissiveStrengthTest/EmissiveStrengthTest.glb", "emissive");
    if (s) {
        pt_env *env = NULL;
        CHECK(pt_env_uniform(pt_v3(0.1f, 0.1f, 0.1f), &env, NULL) == PT_OK);
        int d = blocks_differing(s, env, PT_LIGHT_SELECT_TREE, PT_LIGHT_SELECT_POWER,
                                 "EmissiveStrengthTest", NULL);
        CHECKF(d == 0, "EmissiveStrengthTest: %d blocks differ", d);
        pt_env_free(env);
        pt_scene_free(s);
    }
}

/* 64 coplanar triangles facing +z in a unit square: seen from far above,
 * the root is coarse and the choice is by power alone, the same in the pmf;
 * seen from close by, it is not (a near triangle gets more than its power's
 * share). */
static void test_coarse(void)
{
    enum { N = 64 };
    pt_light_tree_item it[N];
    for (int i = 0; i < N; i++) {
        float x = (float)(i % 8) / 8.0f, y = (float)(i / 8) / 8.0f;
        it[i].lo = pt_v3(x, y, 0);
        it[i].hi = pt_v3(x + 0.1f, y + 0.1f, 0);
        it[i].axis = pt_v3(0, 0, 1);
        it[i].cos_o = 1.0f;
        it[i].power = (float)(1 + i % 5);
        it[i].two_sided = 0;
    }
    double total = 0.0;
    for (int i = 0; i < N; i++)
        total += it[i].power;
    pt_light_tree *t = NULL;
    CHECK(pt_light_tree_new(it, N, &t, NULL) == PT_OK);
    if (!t)
        return;
    int far_off = 0;
    for (int i = 0; i < N; i++)
        far_off += fabs(pt_light_tree_pmf(t, pt_v3(0.5f, 0.5f, 100), NO_N, (uint32_t)i) -
                        it[i].power / total) > 1e-12;
    CHECKF(far_off == 0, "far: %d pmfs are not the power's share", far_off);
    double near = pt_light_tree_pmf(t, pt_v3(0.05f, 0.05f, 0.05f), NO_N, 0);
    CHECKF(near > 3.0 * it[0].power / total, "near: pmf %g, power share %g", near,
           it[0].power / total);
    /* the sampler agrees at both */
    rng_state = 4;
    int bad = 0;
    for (int k = 0; k < 20000; k++) {
        pt_vec3 p = k % 2 ? pt_v3(0.5f, 0.5f, 100) : pt_v3(0.05f, 0.05f, 0.05f);
        double q;
        uint32_t l = pt_light_tree_sample(t, p, NO_N, rnd(), &q);
        bad += l >= N || q != pt_light_tree_pmf(t, p, NO_N, l);
    }
    CHECK(bad == 0);
    pt_light_tree_free(t);
}

static void test_errors(void)
{
    pt_light_tree_item it[4];
    pt_vec3 v[12];
    rng_state = 9;
    random_lights(it, v, 4);
    pt_light_tree *t = NULL;
    pt_error err = {0};
    CHECK(pt_light_tree_new(it, 1, &t, &err) == PT_ERR_ARG && !t);
    CHECK(pt_light_tree_new(it, 0, &t, &err) == PT_ERR_ARG && !t);
    CHECK(pt_light_tree_new(NULL, 4, &t, &err) == PT_ERR_ARG && !t);
    it[2].power = NAN;
    CHECK(pt_light_tree_new(it, 4, &t, &err) == PT_ERR_ARG && !t);
    it[2].power = 0.0f;
    CHECK(pt_light_tree_new(it, 4, &t, &err) == PT_ERR_ARG && !t);
    it[2].power = 1.0f;
    it[1].lo.y = INFINITY;
    CHECK(pt_light_tree_new(it, 4, &t, &err) == PT_ERR_ARG && !t);
    it[1].lo.y = it[1].hi.y;
    /* two equal lights: one split by count */
    pt_light_tree_item same[2] = {it[0], it[0]};
    CHECK(pt_light_tree_new(same, 2, &t, &err) == PT_OK);
    CHECK(pt_light_tree_pmf(t, pt_v3(0, 0, 50), NO_N, 0) == 0.5 ||
          pt_light_tree_pmf(t, pt_v3(0, 0, 50), NO_N, 0) == 0.0);
    pt_light_tree_free(t);
    pt_light_tree_free(NULL);
    /* allocation failure at every allocation: no leak, no crash */
    int64_t live = pt_alloc_live();
    for (uint64_t k = 1; k < 20; k++) {
        t = NULL;
        pt_alloc_fail_at(k);
        pt_status st = pt_light_tree_new(it, 4, &t, &err);
        pt_alloc_fail_at(0);
        CHECK(st == PT_OK || (st == PT_ERR_NOMEM && !t));
        pt_light_tree_free(t);
    }
    CHECK(pt_alloc_live() == live);
}

/* A strip of n small emissive triangles, one mesh; with floor > 0, over a
 * square floor of that half-side at z = 0. */
static pt_scene *strip_scene(uint32_t n, float floor)
{
    pt_scene_builder *b = NULL;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material m = pt_material_default();
    m.emissive[0] = m.emissive[1] = m.emissive[2] = 1.0f;
    uint32_t mat;
    float *v = pt_calloc((size_t)n * 9, sizeof *v);
    int ok = v && pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK;
    for (uint32_t i = 0; ok && i < n; i++) {
        float x = 0.1f * (float)i;
        const float tv[9] = {x, 0, 1, x + 0.05f, 0, 1, x, 0.05f, 1};
        memcpy(v + 9 * i, tv, sizeof tv);
    }
    ok = ok && pt_scene_builder_add_mesh(b, "strip", v, NULL, NULL, 3 * n, NULL, n, NULL, mat,
                                         &err) == PT_OK;
    if (ok && floor > 0.0f) {
        pt_material fm = pt_material_default();
        const float fl[12] = {-floor, -floor, 0, floor,  -floor, 0,
                              floor,  floor,  0, -floor, floor,  0};
        const uint32_t fi[6] = {0, 1, 2, 0, 2, 3};
        ok = pt_scene_builder_add_material(b, &fm, &mat, &err) == PT_OK &&
             pt_scene_builder_add_mesh(b, "floor", fl, NULL, NULL, 4, fi, 2, NULL, mat, &err) ==
                 PT_OK;
    }
    ok = finish_scene(b, ok, &s, &err);
    CHECKF(ok, "strip of %u lights: %s", n, err.msg);
    pt_free(v);
    return s;
}

static void test_auto_range(void)
{
    const uint32_t counts[] = {PT_LIGHT_TREE_MIN - 1, PT_LIGHT_TREE_MIN, PT_LIGHT_TREE_AUTO_MAX,
                               PT_LIGHT_TREE_AUTO_MAX + 1, 1000};
    for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++) {
        pt_scene *s = strip_scene(counts[i], 0.0f);
        if (!s)
            continue;
        int want = counts[i] >= PT_LIGHT_TREE_MIN && counts[i] <= PT_LIGHT_TREE_AUTO_MAX;
        pt_lights *a = NULL, *t = NULL;
        CHECK(pt_lights_new_select(s, NULL, 0, PT_LIGHT_SELECT_AUTO, &a, NULL) == PT_OK);
        CHECK(pt_lights_new_select(s, NULL, 0, PT_LIGHT_SELECT_TREE, &t, NULL) == PT_OK);
        CHECKF(a && pt_lights_has_tree(a) == want, "%u lights: auto %s the tree", counts[i],
               want ? "without" : "with");
        CHECKF(t && pt_lights_has_tree(t), "%u lights: no tree when asked for", counts[i]);
        pt_lights_free(a);
        pt_lights_free(t);
        pt_scene_free(s);
    }
    /* 32 lights over a floor 20 wide: gathered in 3.2 of the scene's 28,
     * a spread under PT_LIGHT_TREE_MIN_SPREAD, so the choice by power; over
     * a floor 4 wide they spread over most of it, and the tree chooses */
    const float floors[2] = {10.0f, 2.0f};
    for (int k = 0; k < 2; k++) {
        pt_scene *s = strip_scene(32, floors[k]);
        if (!s)
            continue;
        pt_lights *a = NULL, *t = NULL;
        CHECK(pt_lights_new_select(s, NULL, 0, PT_LIGHT_SELECT_AUTO, &a, NULL) == PT_OK);
        CHECK(pt_lights_new_select(s, NULL, 0, PT_LIGHT_SELECT_TREE, &t, NULL) == PT_OK);
        CHECKF(a && pt_lights_has_tree(a) == (k == 1), "32 lights over a floor %g wide: auto %s",
               2.0 * floors[k], k == 1 ? "without the tree" : "with the tree");
        CHECK(t && pt_lights_has_tree(t));
        pt_lights_free(a);
        pt_lights_free(t);
        pt_scene_free(s);
    }
}

/* Four small triangles in two clusters far apart, seen from the origin: the
 * tree is two levels deep and a walk chooses among the four leaves in one
 * step, so each light's pmf is its own importance over the four's sum,
 * power x cos(theta') / d^2 (light_tree.h). theta' is theta_w, the tilt,
 * less the cone's stored half-angle (at most acos(32766 / 32767) = 7.9e-3
 * for a triangle's, rounded to 16 bits) and the leaf's angular radius
 * (asin(r / d) < 1.4e-3): delta < 9.3e-3, a relative change of cos of at
 * most delta x tan(theta_w) + delta^2 / 2 < 3.5e-2 at the steepest tilt
 * here (75 degrees), and the shares, normalized, move by at most twice
 * that: 7e-2. A walk that chose a cluster first, by the cluster's bound
 * (its summed power, its merged cone), gives the tilted lights shares
 * 20-27 % off. */
static void test_four_at_once(void)
{
    enum { N = 4 };
    const pt_vec3 pos[N] = {{-3, 0.3f, 6}, {-3, -0.3f, 6}, {3, 0.3f, 6}, {3, -0.3f, 6}};
    const float tilt[N] = {0.0f, 75.0f, 0.0f, 60.0f}; /* degrees from facing the origin */
    const float power[N] = {1.0f, 2.0f, 1.5f, 1.0f};
    pt_light_tree_item it[N];
    double imp[N], sum = 0.0;
    for (int i = 0; i < N; i++) {
        pt_vec3 to_p = pt_v3_norm(pt_v3_scale(pos[i], -1.0f));
        /* the normal: to_p turned by tilt towards a side */
        pt_vec3 side = pt_v3_norm(pt_v3_cross(to_p, pt_v3(0, 1, 0)));
        double a = tilt[i] * 3.14159265358979323846 / 180.0;
        it[i].axis = pt_v3_norm(
            pt_v3_add(pt_v3_scale(to_p, (float)cos(a)), pt_v3_scale(side, (float)sin(a))));
        it[i].lo = pt_v3_sub(pos[i], pt_v3(0.005f, 0.005f, 0.005f));
        it[i].hi = pt_v3_add(pos[i], pt_v3(0.005f, 0.005f, 0.005f));
        it[i].cos_o = 1.0f;
        it[i].power = power[i];
        it[i].two_sided = 0;
        double d2 = (double)pt_v3_dot(pos[i], pos[i]);
        imp[i] = power[i] * cos(a) / d2;
        sum += imp[i];
    }
    pt_light_tree *t = NULL;
    CHECK(pt_light_tree_new(it, N, &t, NULL) == PT_OK);
    if (!t)
        return;
    CHECKF(pt_light_tree_depth(t) == 2, "depth %u", pt_light_tree_depth(t));
    for (int i = 0; i < N; i++) {
        double q = pt_light_tree_pmf(t, pt_v3(0, 0, 0), NO_N, (uint32_t)i), e = imp[i] / sum;
        CHECKF(fabs(q - e) < 7e-2 * e, "light %d: pmf %.5f, importance share %.5f", i, q, e);
    }
    pt_light_tree_free(t);
}

/* pt_light_tree_sample_n gives pt_light_tree_sample's bits, for counts
 * below, at and past the walks it interleaves. */
static void test_sample_n(void)
{
    rng_state = 7;
    static pt_light_tree_item it[NL];
    static pt_vec3 v[3 * NL];
    random_lights(it, v, NL);
    pt_light_tree *t = NULL;
    CHECK(pt_light_tree_new(it, NL, &t, NULL) == PT_OK);
    if (!t)
        return;
    enum { M = 101 };
    pt_vec3 p[M], nrm[M];
    double u[M], q[M];
    uint32_t l[M];
    int bad = 0;
    for (int i = 0; i < M; i++) {
        p[i] = pt_v3((float)(30 * rnd() - 15), (float)(30 * rnd() - 15), (float)(25 * rnd() - 2));
        u[i] = rnd();
        nrm[i] = i % 3 == 0 ? NO_N : rnd_dir(); /* with a receiver normal, or none */
    }
    const uint32_t counts[] = {0, 1, 15, 16, 17, M};
    for (size_t c = 0; c < sizeof counts / sizeof counts[0]; c++) {
        pt_light_tree_sample_n(t, counts[c], p, nrm, u, l, q);
        for (uint32_t i = 0; i < counts[c]; i++) {
            double q1;
            uint32_t l1 = pt_light_tree_sample(t, p[i], nrm[i], u[i], &q1);
            bad += l1 != l[i] || memcmp(&q1, &q[i], sizeof q1) != 0;
        }
    }
    CHECKF(bad == 0, "%d batched choices differ from single ones", bad);
    pt_light_tree_free(t);
}

/* The receiver's side: 256 small lights that emit all around (a cone of pi,
 * so that only the receiver can rule one out) in a 10-unit box, seen from
 * points with random normals. A light whose leaf sphere (the box's centre
 * and half-diagonal) lies wholly below the tangent plane gets pmf 0, exactly;
 * one wholly above gets more than 0; and the lights above take more of the
 * probability than they do without a normal. */
static void test_receiver_side(void)
{
    enum { N = 256 };
    rng_state = 21;
    static pt_light_tree_item it[N];
    for (int i = 0; i < N; i++) {
        pt_vec3 c =
            pt_v3((float)(10 * rnd() - 5), (float)(10 * rnd() - 5), (float)(10 * rnd() - 5));
        float h = (float)(0.01 + 0.1 * rnd());
        it[i].lo = pt_v3_sub(c, pt_v3(h, h, h));
        it[i].hi = pt_v3_add(c, pt_v3(h, h, h));
        it[i].axis = pt_v3(0, 0, 1);
        it[i].cos_o = -1.0f;
        it[i].power = (float)(0.5 + 5.0 * rnd());
        it[i].two_sided = 0;
    }
    pt_light_tree *t = NULL;
    CHECK(pt_light_tree_new(it, N, &t, NULL) == PT_OK);
    if (!t)
        return;
    int below_chosen = 0, above_missed = 0, below_count = 0, gained = 0;
    const int points_n = 40;
    for (int k = 0; k < points_n; k++) {
        pt_vec3 p = pt_v3((float)(4 * rnd() - 2), (float)(4 * rnd() - 2), (float)(4 * rnd() - 2));
        pt_vec3 n = rnd_dir();
        double up_n = 0.0, up_0 = 0.0;
        for (uint32_t i = 0; i < N; i++) {
            pt_vec3 c = pt_v3_scale(pt_v3_add(it[i].lo, it[i].hi), 0.5f);
            float r = 0.5f * pt_v3_len(pt_v3_sub(it[i].hi, it[i].lo));
            float h = pt_v3_dot(n, pt_v3_sub(c, p)); /* the centre's height over the plane */
            double q = pt_light_tree_pmf(t, p, n, i), q0 = pt_light_tree_pmf(t, p, NO_N, i);
            if (h < -(r + 1e-3f)) {
                below_count++;
                below_chosen += q != 0.0;
            } else if (h > r + 1e-3f) {
                above_missed += !(q > 0.0);
                up_n += q;
                up_0 += q0;
            }
        }
        gained += up_n > up_0;
    }
    CHECKF(below_count > 1000 && below_chosen == 0,
           "%d of %d lights below the receiver's plane have pmf > 0", below_chosen, below_count);
    CHECKF(above_missed == 0, "%d lights above the receiver's plane have pmf 0", above_missed);
    CHECKF(gained == points_n, "the lights above gain probability at %d of %d points", gained,
           points_n);
    pt_light_tree_free(t);
}

/* A scene for the receiver's side through pt_lights: SIDES small triangles
 * spread over the plane z = 0 facing down and SIDES twice as bright in a
 * tight group under it facing up, each its own material; a receiver at the
 * origin with normal +z sees only those over it. (The tree bounds a node by
 * the sphere around its box: a group spread wide under the plane, whose
 * sphere crosses it, is ruled out only leaf by leaf, and walks that reach
 * it choose nothing.) */
#define SIDES 24
static pt_scene *sides_scene(void)
{
    pt_scene_builder *b = NULL;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material m = pt_material_default();
    int ok = 1;
    for (uint32_t i = 0; i < 2 * SIDES && ok; i++) {
        int under = i >= SIDES;
        uint32_t j = i % SIDES, mat;
        m.emissive[0] = m.emissive[1] = m.emissive[2] = (under ? 4.0f : 2.0f) * (float)(1 + j % 3);
        double a = 2.0 * 3.14159265358979323846 * (j + 0.25 * under) / SIDES;
        float rad = 0.6f + 1.5f * (float)(j % 4) / 3.0f, h = 0.5f + 0.4f * (float)(j % 5);
        if (under) { /* a tight group: its bounding sphere lies below the plane */
            rad = 0.2f + 0.4f * (float)(j % 4) / 3.0f;
            h = 1.8f + 0.1f * (float)(j % 5);
        }
        float cx = rad * (float)cos(a), cy = rad * (float)sin(a), w = 0.15f;
        float z = under ? -h : h;
        /* over: wound to face -z; under: +z */
        const float dn[9] = {cx - w, cy - w, z, cx - w, cy + w, z, cx + w, cy, z};
        const float up[9] = {cx - w, cy - w, z, cx + w, cy, z, cx - w, cy + w, z};
        ok = pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK &&
             pt_scene_builder_add_mesh(b, "light", under ? up : dn, NULL, NULL, 3, NULL, 1, NULL,
                                       mat, &err) == PT_OK;
    }
    ok = finish_scene(b, ok, &s, &err);
    CHECKF(ok, "sides scene: %s", err.msg);
    return s;
}

/* Irradiance at p (normal n) from a uniform Lambertian triangle of radiance
 * le wholly above p's plane: le |n . Phi|, Phi = 1/2 sum over the edges of
 * theta_e u_e, theta_e the angle the edge subtends at p and u_e the unit
 * normal of the plane through p and the edge (Lambert's formula; Arvo 1994,
 * "The irradiance Jacobian for partially occluded polyhedral sources"). */
static double triangle_irradiance(const double v[3][3], const double p[3], const double n[3],
                                  double le)
{
    double phi[3] = {0, 0, 0};
    for (int e = 0; e < 3; e++) {
        double a[3], b[3];
        for (int c = 0; c < 3; c++) {
            a[c] = v[e][c] - p[c];
            b[c] = v[(e + 1) % 3][c] - p[c];
        }
        double x[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                       a[0] * b[1] - a[1] * b[0]};
        double lx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        double th = atan2(lx, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
        for (int c = 0; c < 3; c++)
            phi[c] += 0.5 * th * x[c] / lx;
    }
    return le * fabs(n[0] * phi[0] + n[1] * phi[1] + n[2] * phi[2]);
}

/* NEE through the tree with the receiver's normal, at a point of the plane
 * z = 0 of sides_scene facing +z: the lights under the plane get pdf 0 (they
 * do without the normal); the irradiance estimate, the mean of L cos / pdf,
 * equals the closed form within a z-test with the normal and without, and
 * with the normal at under 2/3 the variance (without it, the lights under
 * the plane take about 2/3 of the choices, by their power, and add nothing).
 * And at random points and normals the MIS weights of a light sample (power
 * heuristic against a cosine BSDF's pdf) and of the same direction found by
 * the BSDF (with pt_lights_pdf's pdf) sum to 1: the two pdfs are one
 * function of the same inputs, which the normal changes. */
static void test_receiver_estimate(void)
{
    pt_scene *s = sides_scene();
    if (!s)
        return;
    pt_lights *L = NULL;
    CHECK(pt_lights_new_select(s, NULL, 0, PT_LIGHT_SELECT_TREE, &L, NULL) == PT_OK);
    if (!L || !pt_lights_has_tree(L)) {
        CHECK(0);
        pt_lights_free(L);
        pt_scene_free(s);
        return;
    }
    const pt_vec3 p = pt_v3(0.05f, -0.1f, 0.0f), n = pt_v3(0, 0, 1);
    const double pd[3] = {p.x, p.y, p.z}, nd[3] = {0, 0, 1};
    double want = 0.0;
    int under_pdf = 0, under_pdf0 = 0;
    for (uint32_t tri = 0; tri < s->num_triangles; tri++) {
        double v[3][3];
        pt_vec3 c = pt_v3(0, 0, 0);
        for (int k = 0; k < 3; k++) {
            const float *x = &s->positions[3 * (size_t)s->indices[3 * tri + k]];
            for (int a = 0; a < 3; a++)
                v[k][a] = x[a];
            c = pt_v3_add(c, pt_v3_scale(pt_v3(x[0], x[1], x[2]), 1.0f / 3.0f));
        }
        int under = v[0][2] < 0.0;
        pt_vec3 nl = pt_v3(0, 0, under ? 1.0f : -1.0f);
        float q = pt_lights_pdf(L, s, tri, p, n, c, nl);
        float q0 = pt_lights_pdf(L, s, tri, p, NO_N, c, nl);
        if (under) {
            under_pdf += q != 0.0f;
            under_pdf0 += q0 > 0.0f;
        } else {
            /* its radiance towards -z, where it faces */
            double le = pt_emitted(s, tri, 1.0f / 3.0f, 1.0f / 3.0f, nl).x;
            want += triangle_irradiance(v, pd, nd, le);
        }
    }
    CHECKF(under_pdf == 0, "%d lights under the receiver have pdf > 0", under_pdf);
    CHECKF(under_pdf0 == SIDES, "without a normal %d of %d lights under it have pdf > 0",
           under_pdf0, SIDES);

    enum { M = 200000 };
    double mean[2], var[2];
    for (int with_n = 0; with_n < 2; with_n++) {
        rng_state = 31 + (uint64_t)with_n;
        double sum = 0.0, sq = 0.0;
        for (int i = 0; i < M; i++) {
            float u[3] = {(float)rnd(), (float)rnd(), (float)rnd()};
            pt_light_sample ls;
            double x = 0.0;
            if (pt_lights_sample(L, s, p, with_n ? n : NO_N, u, &ls) && ls.pdf > 0.0f) {
                double cosr = (double)pt_v3_dot(n, ls.wi);
                x = cosr > 0.0 ? (double)ls.radiance.x * cosr / (double)ls.pdf : 0.0;
            }
            sum += x;
            sq += x * x;
        }
        mean[with_n] = sum / M;
        var[with_n] = fmax(sq / M - mean[with_n] * mean[with_n], 0.0);
        double z = fabs(mean[with_n] - want) / sqrt(var[with_n] / M), zc = z_crit(1e-3, 2);
        CHECKF(z < zc, "%s normal: irradiance %.6f, closed form %.6f (z %.2f, limit %.2f)",
               with_n ? "with a" : "without a", mean[with_n], want, z, zc);
        printf("irradiance %s normal: %.6f +- %.6f, closed form %.6f, z %.2f\n",
               with_n ? "with a" : "without a", mean[with_n], sqrt(var[with_n] / M), want, z);
    }
    CHECKF(var[1] < (2.0 / 3.0) * var[0], "variance with the normal %.5g, without %.5g", var[1],
           var[0]);
    printf("irradiance variance with / without the normal: %.3f\n", var[1] / var[0]);

    /* MIS weights at random points and normals */
    rng_state = 33;
    int tested = 0, bad_sum = 0, differs = 0;
    for (int i = 0; i < 20000; i++) {
        pt_vec3 q = pt_v3((float)(4 * rnd() - 2), (float)(4 * rnd() - 2), (float)(2 * rnd() - 1));
        pt_vec3 qn = rnd_dir();
        float u[3] = {(float)rnd(), (float)rnd(), (float)rnd()};
        pt_light_sample ls;
        if (!pt_lights_sample(L, s, q, qn, u, &ls) || !(ls.pdf > 0.0f))
            continue;
        float cosr = pt_v3_dot(qn, ls.wi);
        if (!(cosr > 0.0f))
            continue;
        tested++;
        double bp = (double)cosr / 3.14159265358979323846;
        double lp = ls.pdf, lb = pt_lights_pdf(L, s, ls.tri, q, qn, ls.position, ls.normal);
        double w_light = lp * lp / (lp * lp + bp * bp), w_bsdf = bp * bp / (bp * bp + lb * lb);
        bad_sum += !(fabs(w_light + w_bsdf - 1.0) < 1e-6);
        differs += pt_lights_pdf(L, s, ls.tri, q, NO_N, ls.position, ls.normal) != ls.pdf;
    }
    CHECKF(tested > 5000 && bad_sum == 0, "MIS weights: %d of %d sums are not 1", bad_sum, tested);
    CHECKF(differs > tested / 10, "the normal changed %d of %d light pdfs", differs, tested);
    pt_lights_free(L);
    pt_scene_free(s);
}

int main(void)
{
    test_pmf_sums_and_sides();
    test_chi2();
    test_four_at_once();
    test_sample_n();
    test_receiver_side();
    test_receiver_estimate();
    test_lights_pdf();
    test_coarse();
    test_errors();
    test_images();
    test_auto_range();
    return check_report();
}
