/*
 * test_dispersion.c - KHR_materials_dispersion (common/render/dielectric.h).
 *
 * - The ior per channel follows the extension's formula, n(lambda) = n_d +
 *   (n_d - 1) (dispersion / 20) (523655 / lambda^2 - 1.5168), computed
 *   here in double at 611, 549 and 464 nm (within 1e-5).
 * - A prism's per-channel deviation: a ray through a 60 degree prism of
 *   ior 1.5 and dispersion 2 (Abbe number 10), entering at 50 degrees, is
 *   refracted by the smooth interface's sampling at both faces with each
 *   channel picked in turn; the angle between the ray in and out is
 *   theta1 + asin(n sin(A - asin(sin theta1 / n))) - A for that channel's
 *   n (within 1e-4 rad), blue deviates more than green more than red, and
 *   the weight is carried by the picked channel alone.
 * - Energy of the smooth interface: over uniform u[0] the mean weight of
 *   each channel is F + (1 - F) / eta^2 for its own eta (entering at 30
 *   and 70 degrees, from outside and from inside), within 5 standard
 *   errors (from the samples).
 * - The rough dispersive interface: chi-square of the closure's sampling
 *   against its pdf over the sphere (dir_chi2.h), and every sampled weight
 *   equal to eval / pdf at its direction.
 * - Through the integrator (paired.h): a glass sphere (ior 1.5, a closed
 *   volume) before a lamp's edge renders differently with dispersion 3 than
 *   without (colour fringes), and the same with dispersion 0.
 * - A negative dispersion is refused by the builder.
 */
#include "common/render/dielectric.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/closure.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/paired.h"

#define PI_D 3.14159265358979323846
#define N_CHI2_TESTS 1
#include "tests/common/render/dir_chi2.h"

static const double LAMBDA[3] = {611.0, 549.0, 464.0};

static double ior_at(double nd, double disp, double lambda)
{
    return fmax(nd + (nd - 1.0) * (disp / 20.0) * (523655.0 / (lambda * lambda) - 1.5168), 1.0);
}

static void formula(void)
{
    float n3[3];
    pt_dispersion_ior(1.5f, 2.0f, n3);
    for (int c = 0; c < 3; c++)
        CHECKF(fabs(n3[c] - ior_at(1.5, 2.0, LAMBDA[c])) < 1e-5, "channel %d: ior %g, want %g", c,
               (double)n3[c], ior_at(1.5, 2.0, LAMBDA[c]));
    CHECK(n3[2] > n3[1] && n3[1] > n3[0]);
    pt_dispersion_ior(1.5f, 0.0f, n3);
    CHECK(n3[0] == 1.5f && n3[1] == 1.5f && n3[2] == 1.5f);
}

static pt_dielectric_lobe smooth_lobe(float ior, float disp, int inverted)
{
    pt_glass g = pt_glass_setup(pt_v3(1, 1, 1), 0.0f, 0.0f, 1.0f, pt_v3(1, 1, 1), 1.0f,
                                inverted ? 1.0f / ior : ior, 0);
    float n3[3];
    pt_dispersion_ior(ior, disp, n3);
    pt_glass_disperse(&g, n3, inverted);
    return pt_glass_interface(&g);
}

static pt_vec3 to_local(pt_vec3 t, pt_vec3 b, pt_vec3 n, pt_vec3 w)
{
    return pt_v3(pt_v3_dot(w, t), pt_v3_dot(w, b), pt_v3_dot(w, n));
}

static pt_vec3 to_world(pt_vec3 t, pt_vec3 b, pt_vec3 n, pt_vec3 w)
{
    return pt_v3_add(pt_v3_add(pt_v3_scale(t, w.x), pt_v3_scale(b, w.y)), pt_v3_scale(n, w.z));
}

static void prism(void)
{
    const double A = 60.0 * PI_D / 180.0, th1 = 50.0 * PI_D / 180.0, disp = 2.0;
    const float h = (float)(A / 2);
    /* Apex up in the xz plane: the left face's outward normal and the
     * direction along it towards the apex, the right face's likewise. */
    pt_vec3 nl = pt_v3(-cosf(h), 0, sinf(h)), tl = pt_v3(sinf(h), 0, cosf(h));
    pt_vec3 nr = pt_v3(cosf(h), 0, sinf(h)), tr = pt_v3(sinf(h), 0, -cosf(h));
    pt_vec3 yb = pt_v3(0, 1, 0);
    pt_vec3 d0 = pt_v3_add(pt_v3_scale(nl, -(float)cos(th1)), pt_v3_scale(tl, (float)sin(th1)));
    pt_dielectric_lobe in = smooth_lobe(1.5f, (float)disp, 0);
    pt_dielectric_lobe out = smooth_lobe(1.5f, (float)disp, 1);
    double dev[3];
    for (int c = 0; c < 3; c++) {
        const float u[3] = {((float)c + 0.99f) / 3.0f, 0.5f, 0.5f};
        pt_vec3 wi, w;
        float pdf;
        int r =
            pt_dielectric_sample(&in, to_local(tl, yb, nl, pt_v3_neg(d0)), u, 1.0f, &wi, &w, &pdf);
        CHECK(r == PT_DIELECTRIC_DELTA && wi.z < 0.0f);
        const float wa[3] = {w.x, w.y, w.z};
        for (int k = 0; k < 3; k++)
            CHECK((k == c) == (wa[k] > 0.0f));
        pt_vec3 d1 = to_world(tl, yb, nl, wi);
        /* The right face seen from inside: its inward normal is z. */
        pt_vec3 zin = pt_v3_neg(nr);
        r = pt_dielectric_sample(&out, to_local(tr, yb, zin, pt_v3_neg(d1)), u, 1.0f, &wi, &w,
                                 &pdf);
        CHECK(r == PT_DIELECTRIC_DELTA && wi.z < 0.0f);
        pt_vec3 d2 = to_world(tr, yb, zin, wi);
        dev[c] = acos(fmin(1.0, (double)pt_v3_dot(d0, d2)));
        double n = ior_at(1.5, disp, LAMBDA[c]);
        double th2 = asin(sin(th1) / n), th4 = asin(n * sin(A - th2));
        double want = th1 + th4 - A;
        CHECKF(fabs(dev[c] - want) < 1e-4, "channel %d: deviation %.6f rad, want %.6f", c, dev[c],
               want);
    }
    printf("prism: deviation R %.4f, G %.4f, B %.4f rad\n", dev[0], dev[1], dev[2]);
    CHECK(dev[2] > dev[1] && dev[1] > dev[0]);
}

static void smooth_energy(void)
{
    pcg32 rng = pcg32_make(17, 6);
    const int n = 30000;
    for (int inv = 0; inv < 2; inv++)
        for (int k = 0; k < 2; k++) {
            const float deg[2] = {30.0f, 70.0f};
            pt_dielectric_lobe l = smooth_lobe(1.5f, 3.0f, inv);
            pt_vec3 wo = dir_at(deg[k], 0.0f);
            double s[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
            for (int i = 0; i < n; i++) {
                const float u[3] = {pcg32_float(&rng), 0.5f, 0.5f};
                pt_vec3 wi, w = pt_v3(0, 0, 0);
                float pdf;
                if (pt_dielectric_sample(&l, wo, u, 1.0f, &wi, &w, &pdf) != PT_DIELECTRIC_DELTA)
                    w = pt_v3(0, 0, 0);
                const double wa[3] = {w.x, w.y, w.z};
                for (int c = 0; c < 3; c++) {
                    s[c] += wa[c];
                    sq[c] += wa[c] * wa[c];
                }
            }
            for (int c = 0; c < 3; c++) {
                double eta = l.eta3[c];
                double F = pt_fresnel_dielectric(wo.z, (float)eta);
                double want = F + (1.0 - F) / (eta * eta);
                double m = s[c] / n, se = sqrt(fmax(sq[c] / n - m * m, 0.0) / (n - 1));
                CHECKF(fabs(m - want) <= 5.0 * se + 1e-6,
                       "%s at %g deg, channel %d: mean weight %g, want %g (se %g)",
                       inv ? "inside" : "outside", (double)deg[k], c, m, want, se);
            }
        }
}

static void rough(void)
{
    pt_glass g =
        pt_glass_setup(pt_v3(0.9f, 0.9f, 0.9f), 0.0f, 0.4f, 1.0f, pt_v3(1, 1, 1), 1.0f, 1.5f, 0);
    float n3[3];
    pt_dispersion_ior(1.5f, 4.0f, n3);
    pt_glass_disperse(&g, n3, 0);
    pt_closure c;
    pt_closure_init(&c, dir_at(40.0f, 0.3f));
    pt_closure_add_glass(&c, &g);
    binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, closure_pdf_fn, &c};
    chi2_run("rough dispersive glass, 40 deg", &bn, closure_sample_fn, &c, 300000, 61);
    pcg32 rng = pcg32_make(19, 7);
    int taken;
    int inconsistent = closure_weights_differ(&c, &rng, 20000, &taken);
    CHECK(taken > 10000 && inconsistent == 0);
}

/* A glass sphere (radius 1) before the edge of a lamp, seen from z = 5. */
static pt_scene *sphere_scene(float dispersion)
{
    enum { LAT = 32, LON = 64 };
    static float pos[(LAT + 1) * (LON + 1) * 3];
    static uint32_t idx[LAT * LON * 6];
    for (int i = 0; i <= LAT; i++)
        for (int j = 0; j <= LON; j++) {
            double th = PI_D * i / LAT, ph = 2.0 * PI_D * j / LON;
            float *p = &pos[3 * (i * (LON + 1) + j)];
            p[0] = (float)(sin(th) * cos(ph));
            p[1] = (float)(sin(th) * sin(ph));
            p[2] = (float)cos(th);
        }
    int t = 0;
    for (int i = 0; i < LAT; i++)
        for (int j = 0; j < LON; j++) {
            uint32_t a = (uint32_t)(i * (LON + 1) + j), b = a + 1, c = a + LON + 1, d = c + 1;
            const uint32_t q[6] = {a, c, b, b, c, d};
            memcpy(&idx[6 * t++], q, sizeof q);
        }
    pt_scene_builder *bl = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&bl, &err) == PT_OK);
    pt_material g = pt_material_default();
    g.metallic = 0.0f;
    g.roughness = 0.0f;
    g.transmission = 1.0f;
    g.thickness = 1.0f;
    g.dispersion = dispersion;
    pt_material e = pt_material_default();
    e.base_color[0] = e.base_color[1] = e.base_color[2] = 0.0f;
    e.metallic = e.specular = 0.0f;
    e.emissive[0] = e.emissive[1] = e.emissive[2] = 5.0f;
    e.double_sided = 1;
    uint32_t gi = 0, ei = 0;
    CHECK(pt_scene_builder_add_material(bl, &g, &gi, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(bl, &e, &ei, &err) == PT_OK);
    CHECKF(pt_scene_builder_add_mesh(bl, "sphere", pos, pos, NULL, (LAT + 1) * (LON + 1), idx,
                                     LAT * LON * 2, NULL, gi, &err) == PT_OK,
           "%s", err.msg);
    /* The lamp covers x > 0 behind the sphere. */
    const float lamp[12] = {0, -10, -3, 10, -10, -3, 10, 10, -3, 0, 10, -3};
    const uint32_t qi[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(bl, "lamp", lamp, NULL, NULL, 4, qi, 2, NULL, ei, &err) ==
          PT_OK);
    pt_camera cam = {0};
    cam.position = pt_v3(0, 0, 5);
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = 0.5f;
    cam.aspect = 1.0f;
    CHECK(pt_scene_builder_add_camera(bl, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(bl, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void rendered(void)
{
    pt_scene *d = sphere_scene(3.0f), *plain = sphere_scene(0.0f), *zero = sphere_scene(0.0f);
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(0.05f, 0.05f, 0.05f), &env, &err) == PT_OK);
    if (d && plain && zero && env) {
        CHECK((d->features & PT_FEAT_DISPERSION) && !(plain->features & PT_FEAT_DISPERSION));
        int n = paired_differing(d, plain, env, 24, 32);
        int n0 = paired_differing(zero, plain, env, 24, 32);
        printf("glass sphere: %d pixel channels differ with dispersion 3, %d with 0\n", n, n0);
        CHECK(n > 10);
        CHECK(n0 == 0);
    }
    pt_env_free(env);
    pt_scene_free(d);
    pt_scene_free(plain);
    pt_scene_free(zero);
}

static void refused(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.dispersion = -1.0f;
    uint32_t idx;
    CHECK(pt_scene_builder_add_material(b, &m, &idx, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "dispersion -1"));
    pt_scene_builder_free(b);
}

int main(void)
{
    formula();
    prism();
    smooth_energy();
    rough();
    rendered();
    refused();
    return check_report();
}
