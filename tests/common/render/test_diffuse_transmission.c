/*
 * test_diffuse_transmission.c - KHR_materials_diffuse_transmission
 * (bsdf.h's transmitting diffuse lobe, closure.c's pt_closure_add_base_dt,
 * and the integrator's two-sided scattering for it).
 *
 * - A slab's transmittance: a thin sheet (2000 x 2000) of base colour rho,
 *   diffuse transmission t and colour c, no specular (specularFactor 0, so
 *   no Fresnel weight), under a black emitter of radiance L (2000 x 2000)
 *   one unit above it, facing down. Seen from below, the sheet's radiance
 *   is t c L (a Lambertian transmitter under a hemisphere of radiance L);
 *   seen from above, (1 - t) rho L: the light it reflects up is absorbed by
 *   the black emitter and the light it sends down escapes. The emitter
 *   misses about (1 / 1000)^2 of the sheet's hemisphere. Each channel's
 *   mean over 8 x 8 pixels x 256 samples is within 5 standard errors (from
 *   the samples) + 1e-4 of those.
 * - White furnace: a white dielectric (specular 1) with dt 0.3, 0.7 and 1
 *   at incidences 0..85 degrees: the mean sampled weight over both
 *   hemispheres is at most 1 within 5 standard errors, never negative, and
 *   each sampled weight equals eval / pdf at its direction.
 * - Chi-square of the sampling against the pdf over the whole sphere
 *   (dir_chi2.h) for dt 0.5 over a glossy base.
 * - A builder material with diffuseTransmissionFactor 2 is refused.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/closure.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"

#define PI_D 3.14159265358979323846
#define N_CHI2_TESTS 1
#include "tests/common/render/dir_chi2.h"

static const float RHO = 0.7f, T = 0.6f, L = 2.0f;
static const float C[3] = {0.9f, 0.5f, 0.2f};

static pt_scene *slab(float cam_z, float dir_z)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = RHO;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.diffuse_transmission = T;
    memcpy(m.diffuse_transmission_color, C, sizeof C);
    pt_material e = pt_material_default();
    e.base_color[0] = e.base_color[1] = e.base_color[2] = 0.0f;
    e.metallic = e.specular = 0.0f;
    e.emissive[0] = e.emissive[1] = e.emissive[2] = L;
    uint32_t mi = 0, ei = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &e, &ei, &err) == PT_OK);
    const float F = 1000.0f;
    const float sheet[12] = {-F, -F, 0, F, -F, 0, F, F, 0, -F, F, 0};
    /* Wound so that its normal, and its emission, point down. */
    const float lamp[12] = {-F, -F, 1, -F, F, 1, F, F, 1, F, -F, 1};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "sheet", sheet, NULL, NULL, 4, idx, 2, NULL, mi, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "lamp", lamp, NULL, NULL, 4, idx, 2, NULL, ei, &err) ==
          PT_OK);
    pt_camera cam = {0};
    cam.position = pt_v3(0, 0, cam_z);
    cam.forward = pt_v3(0, 0, dir_z);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3_cross(cam.right, cam.forward);
    cam.yfov = 0.3f;
    cam.aspect = 1.0f;
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void expect_radiance(const char *what, pt_scene *s, const double want[3])
{
    if (!s)
        return;
    CHECK(s->features & PT_FEAT_DIFFUSE_TRANSMISSION);
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = 8;
    p.seed = 4;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
    const int n = 8 * 8 * 256;
    for (int i = 0; r && i < n; i++) {
        pt_render_stats st = {0};
        int cov = 0;
        pt_vec3 v = pt_render_sample(r, (uint32_t)(i % 64) % 8, (uint32_t)(i % 64) / 8,
                                     (uint32_t)(i / 64), &st, &cov);
        const double va[3] = {v.x, v.y, v.z};
        for (int c = 0; c < 3; c++) {
            sum[c] += va[c];
            sq[c] += va[c] * va[c];
        }
    }
    for (int c = 0; r && c < 3; c++) {
        double m = sum[c] / n, se = sqrt(fmax(sq[c] / n - m * m, 0.0) / (n - 1));
        CHECKF(fabs(m - want[c]) <= 5.0 * se + 1e-4, "%s: channel %d is %g, want %g (se %g)", what,
               c, m, want[c], se);
    }
    pt_renderer_free(r);
    pt_scene_free(s);
}

static void slab_transmittance(void)
{
    const double below[3] = {T * C[0] * L, T * C[1] * L, T * C[2] * L};
    const double above[3] = {(1.0 - T) * RHO * L, (1.0 - T) * RHO * L, (1.0 - T) * RHO * L};
    expect_radiance("from below", slab(-0.5f, 1.0f), below);
    expect_radiance("from above", slab(0.5f, -1.0f), above);
}

static pt_closure dt_closure(const pt_bsdf *b, float dt, pt_vec3 col, pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_base_dt(&c, b, dt, pt_v3_scale(col, dt));
    return c;
}

static void furnace(void)
{
    pt_bsdf b = pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, 0.4f, 1.0f, pt_v3(1, 1, 1));
    const float dts[3] = {0.3f, 0.7f, 1.0f};
    pcg32 rng = pcg32_make(13, 5);
    const int n = 20000;
    for (int k = 0; k < 3; k++)
        for (int deg = 0; deg <= 85; deg += 17) {
            pt_closure c = dt_closure(&b, dts[k], pt_v3(1, 1, 1), dir_at((float)deg, 0.4f));
            double s = 0.0, sq = 0.0;
            int bad = 0, inconsistent = 0, below = 0;
            for (int i = 0; i < n; i++) {
                const float u[3] = {pcg32_float(&rng), pcg32_float(&rng), pcg32_float(&rng)};
                pt_vec3 wi;
                float pdf;
                pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
                bad += !(w.y >= 0.0f);
                s += w.y;
                sq += (double)w.y * w.y;
                if (pdf > 0.0f) {
                    below += wi.z < 0.0f;
                    float ep;
                    pt_vec3 f = pt_closure_eval(&c, wi, &ep);
                    if (!(fabsf(f.y / ep - w.y) <= 1e-4f * fmaxf(1.0f, w.y)))
                        inconsistent++;
                }
            }
            double m = s / n, se = sqrt(fmax(sq / n - m * m, 0.0) / (n - 1));
            CHECK(bad == 0 && inconsistent == 0 && below > 0);
            CHECKF(m <= 1.0 + 5.0 * se, "dt %g at %d deg: albedo %g (se %g)", (double)dts[k], deg,
                   m, se);
        }
}

static void chi2(void)
{
    pt_bsdf b = pt_bsdf_setup(pt_v3(0.6f, 0.6f, 0.6f), 0.0f, 0.3f, 1.0f, pt_v3(1, 1, 1));
    pt_closure c = dt_closure(&b, 0.5f, pt_v3(0.8f, 0.6f, 0.4f), dir_at(35.0f, 0.2f));
    binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, closure_pdf_fn, &c};
    chi2_run("diffuse transmission 0.5 over a glossy base, 35 deg", &bn, closure_sample_fn, &c,
             300000, 51);
}

static void refused(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.diffuse_transmission = 2.0f;
    uint32_t idx;
    CHECK(pt_scene_builder_add_material(b, &m, &idx, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "diffuseTransmissionFactor 2"));
    pt_scene_builder_free(b);
}

int main(void)
{
    slab_transmittance();
    furnace();
    chi2();
    refused();
    return check_report();
}
