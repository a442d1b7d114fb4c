/*
 * test_iridescence.c - KHR_materials_iridescence (common/render/thinfilm.h).
 *
 * - The film's reflectance against Airy's summation computed here: for
 *   films of index 1.3 and 1.8, 150, 300 and 550 nm thick, over a
 *   dielectric (F0 0.04) and a grey metal (F0 0.8) base, at normal
 *   incidence and at cos 0.5 and 0.2. The interfaces are the extension's
 *   (Schlick reflectances, phase shifts 0 or pi); the reflectance spectrum
 *   is the closed form of Airy's series, |r12 + t12 t21 r23 e^{i delta} /
 *   (1 - r21 r23 e^{i delta})|^2, integrated in wavenumber against the
 *   extension's matching functions (the Gaussians whose transforms
 *   evalSensitivity gives) by Simpson's rule, and its phase average (the
 *   constant term) by the trapezoid rule over a period. pt_thinfilm_xyz
 *   must match the XYZ integral and pt_thinfilm_fresnel the colour the
 *   extension makes of it (the constant term grey, the rest through XYZ to
 *   Rec.709), within the bound on the harmonics m >= 3 that the model
 *   drops, 2 |C_m| summed as a geometric series, times the matching
 *   functions' integrals (and the matrix's largest row for RGB), plus
 *   1e-4 for float rounding, and for XYZ C0 times the distance of the
 *   functions' integrals from 1 (the model takes them as 1). A film 0 nm
 *   thick reflects the bare base's 0.04; past total internal reflection
 *   into the film, everything.
 * - At normal incidence a smooth black dielectric under the film reflects
 *   the film's Fresnel at cos 1: every sampled weight of the closure is
 *   pt_thinfilm_fresnel(1, ...) within 1e-3 (not the bare 0.04).
 * - White furnace: a white rough dielectric and a rough metal under films
 *   of 150, 300 and 550 nm, at incidences 0..85 degrees: the mean weight
 *   f cos / pdf of 20000 samples is at most 1 within 5 standard errors
 *   (from the samples), never negative or NaN, and every sampled weight
 *   equals eval / pdf at its direction.
 * - Chi-square of the closure's sampling against its pdf (dir_chi2.h) for
 *   the film over a glossy dielectric at 40 degrees and a metal at 70.
 * - Over glass (ior 1.5): a smooth filmed interface's mean sampled weight
 *   per channel is F + (1 - F) / eta^2 with F the film's reflectance, at 0
 *   and 60 degrees, within 5 standard errors; the rough one passes a
 *   chi-square and the sampling contract.
 * - Through the integrator, a smooth black dielectric under a 300 nm film,
 *   and a thin glass sheet under it before a black wall, seen head-on under
 *   a uniform environment of 1, show the film's Fresnel at cos 1 (see
 *   rendered).
 * - Over anisotropy (over_anisotropy): equal to the anisotropic lobe at
 *   film strength 0, to the filmed isotropic lobe at anisotropy 0, a white
 *   furnace at most 1, eval / pdf consistency and a chi-square.
 * - A builder material with iridescenceFactor 2 or a negative thickness is
 *   refused with an error that names the field.
 * - IridescenceSuzanne (../shared/scenes) loads with no warning about the
 *   extension, its three materials (two opaque, one glass) are
 *   iridescent, and it renders with no NaN/Inf
 *   (skipped without ../shared; a failure under CI=true).
 */
#include "common/render/thinfilm.h"

#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/closure.h"
#include "common/render/dielectric.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/paired.h"
#include "tests/common/render/sample_mean.h"

#define PI_D 3.14159265358979323846
#define N_CHI2_TESTS 4
#include "tests/common/render/dir_chi2.h"

/* ---- Airy's summation ---------------------------------------------------- */

static double schlick_d(double f0, double c)
{
    double m = 1.0 - c;
    return f0 + (1.0 - f0) * m * m * m * m * m;
}

/* The extension's matching function j (0..2: X, Y, Z) in wavenumber x
 * (1/m): Gaussians whose transforms are evalSensitivity's terms,
 * val sqrt(2 pi var) cos(pos k + s) exp(-var k^2) = the transform of
 * (val / sqrt 2) exp(-(x - pos)^2 / (4 var)), over 1.0685e-7. */
static double cmf(int j, double x)
{
    static const double val[3] = {5.4856e-13, 4.4201e-13, 5.2481e-13};
    static const double pos[3] = {1.6810e+06, 1.7953e+06, 2.2084e+06};
    static const double var[3] = {4.3278e+09, 9.3046e+09, 6.6121e+09};
    double g = val[j] / sqrt(2.0) * exp(-(x - pos[j]) * (x - pos[j]) / (4.0 * var[j]));
    if (j == 0)
        g +=
            9.7470e-14 / sqrt(2.0) * exp(-(x - 2.2399e+06) * (x - 2.2399e+06) / (4.0 * 4.5282e+09));
    return g / 1.0685e-7;
}

typedef struct airy {
    double r12, r23, phi12, phi23, opd; /* interfaces; OPD in nm */
    double tail;                        /* sum over m >= 3 of 2 |C_m| */
} airy;

static airy airy_setup(double eta2, double cos1, double d, double f0)
{
    airy a;
    double cos2 = sqrt(1.0 - (1.0 / (eta2 * eta2)) * (1.0 - cos1 * cos1));
    double sf = sqrt(f0), n3 = (1.0 + sf) / (1.0 - sf);
    a.r12 = schlick_d(pow((eta2 - 1.0) / (eta2 + 1.0), 2.0), cos1);
    a.r23 = schlick_d(pow((n3 - eta2) / (n3 + eta2), 2.0), cos2);
    a.phi12 = eta2 < 1.0 ? PI_D : 0.0;
    a.phi23 = n3 < eta2 ? PI_D : 0.0;
    a.opd = 2.0 * eta2 * d * cos2;
    double t = 1.0 - a.r12, r123 = sqrt(a.r12 * a.r23);
    double rs = t * t * a.r23 / (1.0 - a.r12 * a.r23);
    a.tail = 2.0 * fabs(rs - t) * pow(r123, 3.0) / (1.0 - r123);
    return a;
}

/* The film's reflectance at phase delta: the closed form of the series of
 * amplitudes r12 + t12 t21 r23 e^{i delta} sum_k (r21 r23 e^{i delta})^k. */
static double airy_r(const airy *a, double delta)
{
    double complex r12 = sqrt(a->r12) * cexp(I * a->phi12);
    double complex r21 = sqrt(a->r12) * cexp(I * (PI_D - a->phi12));
    double complex r23 = sqrt(a->r23) * cexp(I * a->phi23);
    double complex e = cexp(I * delta);
    double complex amp = r12 + (1.0 - a->r12) * r23 * e / (1.0 - r21 * r23 * e);
    double re = creal(amp), im = cimag(amp);
    return re * re + im * im;
}

/* XYZ of the spectrum and of the matching functions alone (Simpson). */
static void airy_xyz(const airy *a, double xyz[3], double ones[3])
{
    const double lo = 2.0e5, hi = 3.8e6;
    const int n = 72000; /* even; a step of 50/m against periods >= 5e5/m */
    const double h = (hi - lo) / n;
    for (int j = 0; j < 3; j++)
        xyz[j] = ones[j] = 0.0;
    for (int k = 0; k <= n; k++) {
        double x = lo + h * k, w = (k == 0 || k == n) ? 1.0 : (k % 2 ? 4.0 : 2.0);
        double r = airy_r(a, 2.0 * PI_D * a->opd * 1e-9 * x);
        for (int j = 0; j < 3; j++) {
            double g = cmf(j, x) * w * h / 3.0;
            xyz[j] += r * g;
            ones[j] += g;
        }
    }
}

/* The constant term: the reflectance averaged over a period of delta. */
static double airy_dc(const airy *a)
{
    const int n = 4096;
    double s = 0.0;
    for (int k = 0; k < n; k++)
        s += airy_r(a, 2.0 * PI_D * k / n);
    return s / n;
}

static const double M[3][3] = {{3.2404542, -1.5371385, -0.4985314},
                               {-0.9692660, 1.8760108, 0.0415560},
                               {0.0556434, -0.2040259, 1.0572252}};

static void against_airy(void)
{
    const float etas[2] = {1.3f, 1.8f}, ds[3] = {150.0f, 300.0f, 550.0f};
    const float f0s[2] = {0.04f, 0.8f}, coss[3] = {1.0f, 0.5f, 0.2f};
    double row = 0.0;
    for (int i = 0; i < 3; i++)
        row = fmax(row, fabs(M[i][0]) + fabs(M[i][1]) + fabs(M[i][2]));
    int checked = 0;
    double worst = 0.0;
    for (int e = 0; e < 2; e++)
        for (int f = 0; f < 2; f++)
            for (int k = 0; k < 3; k++)
                for (int c = 0; c < 3; c++) {
                    airy a = airy_setup(etas[e], coss[c], ds[k], f0s[f]);
                    double xyz[3], ones[3], dc = airy_dc(&a);
                    airy_xyz(&a, xyz, ones);
                    double gmax = fmax(ones[0], fmax(ones[1], ones[2]));
                    float got_dc;
                    pt_vec3 gx = pt_thinfilm_xyz(1.0f, etas[e], coss[c], ds[k], f0s[f], &got_dc);
                    pt_vec3 gr = pt_thinfilm_fresnel(1.0f, etas[e], coss[c], ds[k],
                                                     pt_v3(f0s[f], f0s[f], f0s[f]));
                    const double gxa[3] = {gx.x, gx.y, gx.z}, gra[3] = {gr.x, gr.y, gr.z};
                    double tol_x = a.tail * gmax + 1e-4;
                    double tol_r = row * a.tail * gmax + 1e-4;
                    CHECKF(fabs(got_dc - dc) < 1e-5, "eta %g f0 %g d %g cos %g: C0 %g, Airy %g",
                           etas[e], f0s[f], ds[k], coss[c], got_dc, dc);
                    for (int j = 0; j < 3; j++) {
                        double osc[3];
                        for (int i = 0; i < 3; i++)
                            osc[i] = xyz[i] - dc * ones[i];
                        double rgb = dc + M[j][0] * osc[0] + M[j][1] * osc[1] + M[j][2] * osc[2];
                        rgb = fmax(rgb, 0.0);
                        worst = fmax(worst, fabs(gra[j] - rgb) / tol_r);
                        /* The model's constant term is C0, not C0 x the
                         * matching function's integral. */
                        double tx = tol_x + dc * fabs(ones[j] - 1.0);
                        CHECKF(fabs(gxa[j] - xyz[j]) <= tx,
                               "eta %g f0 %g d %g cos %g: XYZ[%d] %g, Airy %g (tol %g)", etas[e],
                               f0s[f], ds[k], coss[c], j, gxa[j], xyz[j], tx);
                        CHECKF(fabs(gra[j] - rgb) <= tol_r,
                               "eta %g f0 %g d %g cos %g: RGB[%d] %g, Airy %g (tol %g)", etas[e],
                               f0s[f], ds[k], coss[c], j, gra[j], rgb, tol_r);
                    }
                    checked++;
                }
    printf("Airy: %d films, the largest RGB error %.3f of its bound\n", checked, worst);
    /* Past total internal reflection into the film (a film of index < 1
     * seen at grazing) everything is reflected. */
    pt_vec3 tir = pt_thinfilm_fresnel(1.0f, 0.8f, 0.1f, 300.0f, pt_v3(0.04f, 0.04f, 0.04f));
    CHECK(tir.x == 1.0f && tir.y == 1.0f && tir.z == 1.0f);
    /* A film 0 nm thick is no film: the base's own Fresnel, 0.04 at cos 1. */
    pt_vec3 none = pt_thinfilm_fresnel(1.0f, 1.8f, 1.0f, 0.0f, pt_v3(0.04f, 0.04f, 0.04f));
    CHECKF(fabsf(none.y - 0.04f) < 2e-3f, "a 0 nm film reflects %g", (double)none.y);
}

/* ---- the closure --------------------------------------------------------- */

static pt_closure irid_closure(const pt_bsdf *b, const pt_irid *film, pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_base_irid(&c, b, film);
    return c;
}

static void normal_incidence(void)
{
    pt_bsdf b = pt_bsdf_setup(pt_v3(0, 0, 0), 0.0f, 0.0f, 1.0f, pt_v3(1, 1, 1));
    pt_irid film = {1.0f, 1.8f, 300.0f};
    pt_vec3 wo = pt_v3(0, 0, 1);
    pt_closure c = irid_closure(&b, &film, wo);
    pt_vec3 want = pt_thinfilm_fresnel(1.0f, 1.8f, 1.0f, 300.0f, b.f0);
    CHECKF(fabsf(want.x - want.z) > 0.02f, "the film is not coloured: %g %g", (double)want.x,
           (double)want.z);
    pcg32 rng = pcg32_make(3, 1);
    int bad = 0;
    for (int i = 0; i < 2000; i++) {
        const float u[3] = {pcg32_float(&rng), pcg32_float(&rng), pcg32_float(&rng)};
        pt_vec3 wi;
        float pdf;
        pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
        if (!(pdf > 0.0f))
            continue;
        if (!(fabsf(w.x - want.x) < 1e-3f && fabsf(w.y - want.y) < 1e-3f &&
              fabsf(w.z - want.z) < 1e-3f))
            bad++;
    }
    CHECKF(bad == 0, "%d weights are not the film's Fresnel", bad);
}

static void furnace(void)
{
    const pt_bsdf bases[2] = {
        pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, 0.5f, 1.0f, pt_v3(1, 1, 1)),
        pt_bsdf_setup(pt_v3(0.95f, 0.9f, 0.85f), 1.0f, 0.3f, 1.0f, pt_v3(1, 1, 1))};
    const float ds[3] = {150.0f, 300.0f, 550.0f};
    pcg32 rng = pcg32_make(9, 2);
    const int n = 20000;
    for (int bi = 0; bi < 2; bi++)
        for (int k = 0; k < 3; k++)
            for (int deg = 0; deg <= 85; deg += 17) {
                double th = deg * PI_D / 180.0;
                pt_vec3 wo = pt_v3((float)sin(th), 0.0f, (float)cos(th));
                pt_irid film = {1.0f, 1.8f, ds[k]};
                pt_closure c = irid_closure(&bases[bi], &film, wo);
                double s[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
                int bad = 0, inconsistent = 0;
                for (int i = 0; i < n; i++) {
                    const float u[3] = {pcg32_float(&rng), pcg32_float(&rng), pcg32_float(&rng)};
                    pt_vec3 wi;
                    float pdf;
                    pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
                    const double wa[3] = {w.x, w.y, w.z};
                    for (int j = 0; j < 3; j++) {
                        bad += !(wa[j] >= 0.0);
                        s[j] += wa[j];
                        sq[j] += wa[j] * wa[j];
                    }
                    if (pdf > 0.0f) {
                        float ep;
                        pt_vec3 f = pt_closure_eval(&c, wi, &ep);
                        if (!(fabsf(f.y / ep - w.y) <= 1e-4f * fmaxf(1.0f, w.y)))
                            inconsistent++;
                    }
                }
                CHECK(bad == 0 && inconsistent == 0);
                for (int j = 0; j < 3; j++) {
                    double m = s[j] / n, se = sqrt(fmax(sq[j] / n - m * m, 0.0) / (n - 1));
                    CHECKF(m <= 1.0 + 5.0 * se, "base %d d %g at %d deg: albedo[%d] %g (se %g)", bi,
                           (double)ds[k], deg, j, m, se);
                }
            }
}

/* Chi-square of the closure's sampling against its pdf (dir_chi2.h), the
 * film over a glossy white dielectric and over a metal. */
static void chi2(void)
{
    pt_irid film = {0.7f, 1.5f, 400.0f};
    pt_bsdf b1 = pt_bsdf_setup(pt_v3(0.8f, 0.8f, 0.8f), 0.0f, 0.3f, 1.0f, pt_v3(1, 1, 1));
    pt_bsdf b2 = pt_bsdf_setup(pt_v3(0.9f, 0.7f, 0.4f), 1.0f, 0.5f, 1.0f, pt_v3(1, 1, 1));
    pt_closure c1 = irid_closure(&b1, &film, dir_at(40.0f, 0.0f));
    pt_closure c2 = irid_closure(&b2, &film, dir_at(70.0f, 1.6f));
    binning bn1 = {pt_frame_from_normal(pt_v3(-c1.wo.x, -c1.wo.y, c1.wo.z)), 1.5, closure_pdf_fn,
                   &c1};
    binning bn2 = {pt_frame_from_normal(pt_v3(-c2.wo.x, -c2.wo.y, c2.wo.z)), 1.5, closure_pdf_fn,
                   &c2};
    chi2_run("film over a glossy dielectric, 40 deg", &bn1, closure_sample_fn, &c1, 300000, 31);
    chi2_run("film over a metal, 70 deg", &bn2, closure_sample_fn, &c2, 300000, 32);
}

/* ---- the film over glass ------------------------------------------------- */

static pt_glass film_glass(float rough, int thin)
{
    pt_glass g =
        pt_glass_setup(pt_v3(1, 1, 1), 0.0f, rough, 1.0f, pt_v3(1, 1, 1), 1.0f, 1.5f, thin);
    pt_glass_film(&g, 1.0f, 1.8f, 300.0f, 1.5f);
    return g;
}

/* A smooth filmed interface from outside: the mean sampled weight of each
 * channel is F + (1 - F) / eta^2, F = the film's reflectance over glass of
 * ior 1.5 (its F0 0.04). */
static void glass_energy(void)
{
    pcg32 rng = pcg32_make(23, 8);
    const int n = 30000;
    for (int k = 0; k < 2; k++) {
        const float deg[2] = {0.0f, 60.0f};
        pt_glass g = film_glass(0.0f, 0);
        pt_closure c;
        pt_closure_init(&c, dir_at(deg[k], 0.0f));
        pt_closure_add_glass(&c, &g);
        double s[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
        for (int i = 0; i < n; i++) {
            const float u[3] = {pcg32_float(&rng), pcg32_float(&rng), pcg32_float(&rng)};
            pt_vec3 wi;
            float pdf;
            int delta = 0;
            pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, &delta);
            const double wa[3] = {w.x, w.y, w.z};
            for (int j = 0; j < 3; j++) {
                s[j] += wa[j];
                sq[j] += wa[j] * wa[j];
            }
        }
        float cz = c.wo.z;
        float fe = pt_fresnel_dielectric(cz, 1.5f);
        pt_vec3 ff = pt_thinfilm_fresnel(1.0f, 1.8f, cz, 300.0f, pt_v3(0.04f, 0.04f, 0.04f));
        const double fa[3] = {ff.x, ff.y, ff.z};
        for (int j = 0; j < 3; j++) {
            double want = fa[j] + (1.0 - fa[j]) / (1.5 * 1.5);
            double m = s[j] / n, se = sqrt(fmax(sq[j] / n - m * m, 0.0) / (n - 1));
            CHECKF(fabs(m - want) <= 5.0 * se + 1e-5,
                   "film on glass at %g deg, channel %d: %g, want %g (se %g; bare F %g)",
                   (double)deg[k], j, m, want, se, (double)fe);
        }
    }
}

/* The rough filmed interface: chi-square and the sampling contract. */
static void glass_rough(void)
{
    pt_glass g = film_glass(0.4f, 0);
    pt_closure c;
    pt_closure_init(&c, dir_at(35.0f, 0.7f));
    pt_closure_add_glass(&c, &g);
    binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, closure_pdf_fn, &c};
    chi2_run("film over rough glass, 35 deg", &bn, closure_sample_fn, &c, 300000, 33);
    pcg32 rng = pcg32_make(29, 9);
    int taken;
    int bad = closure_weights_differ(&c, &rng, 20000, &taken);
    CHECK(taken > 10000 && bad == 0);
}

/* ---- the scene ----------------------------------------------------------- */

static void refused(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    uint32_t idx;
    m.iridescence = 2.0f;
    CHECK(pt_scene_builder_add_material(b, &m, &idx, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "iridescenceFactor 2"));
    m.iridescence = 1.0f;
    m.irid_thickness_min = -1.0f;
    CHECK(pt_scene_builder_add_material(b, &m, &idx, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "iridescenceThicknessMinimum -1"));
    m.irid_thickness_min = 100.0f;
    m.iridescence_ior = 0.5f;
    CHECK(pt_scene_builder_add_material(b, &m, &idx, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "iridescenceIor 0.5"));
    pt_scene_builder_free(b);
}

/* Through the integrator: a smooth black dielectric quad under the film,
 * seen head-on through a narrow camera under a uniform environment of
 * radiance 1, shows the film's Fresnel at cos 1 (its reflectance; the
 * camera's rays are within 0.03 rad of the normal, where the Fresnel moves
 * by less than 2e-3), each channel within 5 standard errors (from the
 * samples) + 2e-3. */
static void rendered_one(int glass)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    m.metallic = 0.0f;
    m.roughness = 0.0f;
    m.iridescence = 1.0f;
    m.iridescence_ior = 1.8f;
    m.irid_thickness_max = 300.0f;
    if (glass)
        m.transmission = 1.0f; /* a thin sheet: thickness 0 */
    uint32_t mi = 0, bi = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    pt_material black = pt_material_default();
    black.base_color[0] = black.base_color[1] = black.base_color[2] = 0.0f;
    black.metallic = black.specular = 0.0f;
    CHECK(pt_scene_builder_add_material(b, &black, &bi, &err) == PT_OK);
    const float q[12] = {-10, -10, 0, 10, -10, 0, 10, 10, 0, -10, 10, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "quad", q, NULL, NULL, 4, idx, 2, NULL, mi, &err) == PT_OK);
    /* Behind a glass sheet: black, so that only the reflection is seen. */
    const float q2[12] = {-10, -10, -1, 10, -10, -1, 10, 10, -1, -10, 10, -1};
    if (glass)
        CHECK(pt_scene_builder_add_mesh(b, "back", q2, NULL, NULL, 4, idx, 2, NULL, bi, &err) ==
              PT_OK);
    pt_camera cam = {0};
    cam.position = pt_v3(0, 0, 5);
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = 0.05f;
    cam.aspect = 1.0f;
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = 8;
    p.env = env;
    pt_renderer *r = NULL;
    if (s)
        CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    double mean[3], se[3];
    if (r)
        sample_mean(r, 8, 64, mean, se);
    pt_vec3 want = pt_thinfilm_fresnel(1.0f, 1.8f, 1.0f, 300.0f, pt_v3(0.04f, 0.04f, 0.04f));
    const double wa[3] = {want.x, want.y, want.z};
    for (int c = 0; r && c < 3; c++)
        CHECKF(fabs(mean[c] - wa[c]) <= 5.0 * se[c] + 2e-3,
               "%s: channel %d: %g, the film's Fresnel %g", glass ? "glass" : "opaque", c, mean[c],
               wa[c]);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(s);
}

static void rendered(void)
{
    rendered_one(0);
    rendered_one(1);
}

static void suzanne(void)
{
    pt_scene *s = load_shared_asset("IridescenceSuzanne/IridescenceSuzanne.glb", "iridescence");
    if (!s)
        return;
    CHECK(s->features & PT_FEAT_IRIDESCENCE);
    int irid = 0;
    for (uint32_t i = 0; i < s->num_materials; i++)
        irid += (s->materials[i].ext & PT_MATX_IRIDESCENCE) != 0;
    CHECK(irid == 3);
    render_smoke(s);
    pt_scene_free(s);
}

/* The film over an anisotropic lobe (KHR_materials_iridescence with
 * KHR_materials_anisotropy, pt_closure_add_base_irid_aniso). */
static pt_closure irid_aniso_closure(const pt_bsdf *b, const pt_irid *film, float strength,
                                     pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_base_irid_aniso(&c, b, film, strength, cosf(0.6f), sinf(0.6f));
    return c;
}

/*
 * Iridescence over anisotropy: the closure has the filmed anisotropic lobe
 * and the filmed diffuse; at film strength 0 its value is the anisotropic
 * lobe's, bit for bit (the mix with weight 0), and at anisotropy 0 the
 * filmed isotropic lobe's within 1e-4 (the same D and G2 by another
 * formula); its white furnace over a white dielectric and a metal is at
 * most 1 within 5 standard errors, every sampled weight is eval / pdf, and
 * its sampling passes the chi-square test against its pdf.
 */
static void over_anisotropy(void)
{
    const pt_bsdf b = pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, 0.4f, 1.0f, pt_v3(1, 1, 1));
    const pt_bsdf metal =
        pt_bsdf_setup(pt_v3(0.95f, 0.9f, 0.85f), 1.0f, 0.35f, 1.0f, pt_v3(1, 1, 1));
    pt_irid film = {1.0f, 1.8f, 300.0f}, none = {0.0f, 1.8f, 300.0f};
    pt_vec3 wo = dir_at(35.0f, 0.3f);
    pt_closure ci = irid_aniso_closure(&b, &film, 0.8f, wo);
    CHECK(ci.n_lobes == 2 && ci.lobe[0].kind == PT_LOBE_SPECULAR_ANISO_IRID &&
          ci.lobe[1].kind == PT_LOBE_DIFFUSE_IRID);
    pt_closure c0 = irid_aniso_closure(&b, &none, 0.8f, wo), ca;
    pt_closure_init(&ca, wo);
    pt_closure_add_base_aniso(&ca, &b, 0.8f, cosf(0.6f), sinf(0.6f));
    pt_closure cs = irid_aniso_closure(&b, &film, 0.0f, wo), cr;
    pt_closure_init(&cr, wo);
    pt_closure_add_base_irid(&cr, &b, &film);
    pcg32 rng = pcg32_make(21, 4);
    int same = 0, close = 0;
    for (int i = 0; i < 2000; i++) {
        pt_vec3 wi = dir_at(85.0f * pcg32_float(&rng), 6.2831853f * pcg32_float(&rng));
        float s1, s2, s3, s4;
        pt_vec3 a = pt_irid_aniso_eval(&c0.lobe[0].p.irid_aniso, wo, wi, 1.0f, &s1);
        pt_vec3 e = pt_aniso_eval(&ca.lobe[0].p.aniso, wo, wi, 1.0f, &s2);
        same += memcmp(&a, &e, sizeof a) == 0 && s1 == s2;
        pt_vec3 f = pt_irid_aniso_eval(&cs.lobe[0].p.irid_aniso, wo, wi, 1.0f, &s3);
        pt_vec3 g = pt_irid_specular_eval(&cr.lobe[0].p.irid_specular, wo, wi, 1.0f, &s4);
        close += fabsf(f.x - g.x) <= 1e-4f * fmaxf(g.x, 1e-3f) &&
                 fabsf(f.z - g.z) <= 1e-4f * fmaxf(g.z, 1e-3f) &&
                 fabsf(s3 - s4) <= 1e-4f * fmaxf(s4, 1e-3f);
    }
    CHECKF(same == 2000, "%d of 2000 equal to the anisotropic lobe at film strength 0", same);
    CHECKF(close == 2000, "%d of 2000 close to the filmed isotropic lobe at anisotropy 0", close);
    const pt_bsdf *bases[2] = {&b, &metal};
    const int n = 20000;
    for (int bi = 0; bi < 2; bi++)
        for (int deg = 0; deg <= 85; deg += 17) {
            pt_closure c = irid_aniso_closure(bases[bi], &film, 0.8f, dir_at((float)deg, 0.3f));
            double s = 0.0, sq = 0.0;
            int bad = 0, inconsistent = 0;
            for (int i = 0; i < n; i++) {
                const float u[3] = {pcg32_float(&rng), pcg32_float(&rng), pcg32_float(&rng)};
                pt_vec3 wi;
                float pdf;
                pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
                float wm = fmaxf(w.x, fmaxf(w.y, w.z));
                bad += !(w.x >= 0.0f && w.y >= 0.0f && w.z >= 0.0f);
                s += wm;
                sq += (double)wm * wm;
                if (pdf > 0.0f) {
                    float ep;
                    pt_vec3 f = pt_closure_eval(&c, wi, &ep);
                    if (!(fabsf(f.y / ep - w.y) <= 1e-4f * fmaxf(1.0f, w.y)))
                        inconsistent++;
                }
            }
            double m = s / n, se = sqrt(fmax(sq / n - m * m, 0.0) / (n - 1));
            CHECKF(bad == 0 && inconsistent == 0, "base %d at %d deg: %d bad, %d inconsistent", bi,
                   deg, bad, inconsistent);
            CHECKF(m <= 1.0 + 5.0 * se, "base %d at %d deg: albedo %g (se %g)", bi, deg, m, se);
        }
    binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, closure_pdf_fn, &ci};
    chi2_run("film over anisotropy 0.8, 35 deg", &bn, closure_sample_fn, &ci, 300000, 51);
}

int main(void)
{
    over_anisotropy();
    against_airy();
    normal_incidence();
    furnace();
    chi2();
    glass_energy();
    glass_rough();
    rendered();
    refused();
    suzanne();
    return check_report();
}
