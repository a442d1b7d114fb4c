/*
 * test_coatnormal.c - KHR_materials_clearcoat's clearcoatNormalTexture
 * through the whole integrator, against closed-form answers.
 *
 * The scenes follow test_normalmap.c: a large plane (normal +z) seen
 * straight down (wo = +z) by a camera whose field of view is so narrow that
 * the pixel sees one point; a one-texel clear coat normal map (linear bytes
 * c) tilts the coat's normal to nc = normalize((2 c / 255 - 1) * (s, s, 1))
 * in the frame (tangent, bitangent, +z), computed here in double. The coat
 * is smooth (clearcoatRoughness 0: GGX alpha 1e-3) and of factor 1.
 *
 * - Mirror: a black base and a small emissive square (radiance LE, 5 degrees
 *   across as seen from the point) centred on the mirror direction of wo
 *   about nc, r = 2 nc.z nc - z. The coat reflects Fc(nc.z) LE (the smooth
 *   lobe's albedo is 1 within 1e-3): the mean of all samples within 5
 *   standard errors (from the samples' squared luminance) plus 1e-3
 *   relative. A coat on the base's normal reflects the view straight up,
 *   into the black: 0. With tangents given and generated, a mirrored UV
 *   layout (u = -x), and a scale.
 * - Base: a Lambert base (albedo RHO) with its own normal map nb, under one
 *   directional light straight down (irradiance E): NEE alone, so exact to
 *   1e-4 relative. The reading is (1 - Fc(nc.z)) RHO / pi E nb.z: the base
 *   keeps its normal (nb.z, not nc.z) and the coat's Fresnel reads its own
 *   (the smooth coat's lobe, 40 degrees or more off, adds nothing). At an
 *   80 degree coat tilt the view's reflection would go below the surface:
 *   the coat normal is bent as the base's (render.c valid_reflection) to
 *   nc.z = sqrt((1 + t) / 2), t = 0.01, so Fc = Fc(0.7106), not Fc(cos 80).
 * - Base map only: a coat without its own map keeps the interpolated normal
 *   under a normal-mapped base, as KHR_materials_clearcoat says
 *   (coat_ignores_the_base_map).
 * test_layers.c loads ClearCoatTest (coat normal maps) with no warning.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/normal_texel.h"

#define RHO 0.5
#define E_IRR 2.0
#define LE 3.0
#define PI_D 3.14159265358979323846

typedef struct setup {
    uint8_t cc[3];  /* the coat normal map's texel; cc[2] == 0: none */
    float cc_scale; /* clearcoatNormalTexture.scale */
    uint8_t cb[3];  /* the base normal map's texel; cb[2] == 0: none */
    int tangents;   /* 1: given TANGENT, 0: generated */
    int mirror;     /* 1: u = -x (tangent -x, w = -1) */
    int black;      /* base black, an emitter on r; else RHO and the sun */
    double r[3];    /* the emitter's direction from the point */
    double v[3];    /* the direction to the camera; 0: straight up */
} setup;

static const float PX = 0.3f, PY = 0.2f;

static pt_scene *build(const setup *su)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    float a = su->black ? 0.0f : (float)RHO;
    m.base_color[0] = m.base_color[1] = m.base_color[2] = a;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    m.clearcoat = 1.0f;
    m.clearcoat_roughness = 0.0f;
    if (su->cc[2])
        m.clearcoat_normal_tex = (int32_t)one_texel(b, su->cc);
    m.clearcoat_normal_scale = su->cc_scale;
    if (su->cb[2])
        m.normal_tex = (int32_t)one_texel(b, su->cb);
    uint32_t mi;
    CHECKF(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK, "%s", err.msg);
    const float P = 100.0f;
    const float pos[12] = {-P, -P, 0, P, -P, 0, P, P, 0, -P, P, 0};
    float uv[8], tan[16];
    float sx = su->mirror ? -1.0f : 1.0f;
    for (int i = 0; i < 4; i++) {
        uv[2 * i] = 0.5f + sx * pos[3 * i] / (2 * P);
        uv[2 * i + 1] = 0.5f - pos[3 * i + 1] / (2 * P);
        tan[4 * i] = sx;
        tan[4 * i + 1] = tan[4 * i + 2] = 0.0f;
        tan[4 * i + 3] = sx;
    }
    pt_mesh_extra ex = {NULL, su->tangents ? tan : NULL, NULL};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECKF(pt_scene_builder_add_mesh_extra(b, "plane", pos, NULL, uv, &ex, 4, idx, 2, NULL, mi,
                                           &err) == PT_OK,
           "%s", err.msg);
    if (su->black) {
        /* A square of side 2 D tan(2.5 deg) at distance D along r, facing
         * the point. */
        pt_material lamp = pt_material_default();
        lamp.metallic = 0.0f;
        lamp.specular = 0.0f;
        lamp.base_color[0] = lamp.base_color[1] = lamp.base_color[2] = 0.0f;
        lamp.emissive[0] = lamp.emissive[1] = lamp.emissive[2] = (float)LE;
        lamp.double_sided = 1;
        uint32_t ml;
        CHECK(pt_scene_builder_add_material(b, &lamp, &ml, &err) == PT_OK);
        pt_vec3 r = pt_v3_norm(pt_v3((float)su->r[0], (float)su->r[1], (float)su->r[2]));
        pt_frame fr = pt_frame_from_normal(r);
        const float D = 5.0f, h = D * tanf(2.5f * (float)PI_D / 180.0f);
        pt_vec3 c = pt_v3_add(pt_v3(PX, PY, 0.0f), pt_v3_scale(r, D));
        float lp[12];
        const float sgn[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (int i = 0; i < 4; i++) {
            pt_vec3 v = pt_v3_add(
                c, pt_v3_add(pt_v3_scale(fr.t, sgn[i][0] * h), pt_v3_scale(fr.b, sgn[i][1] * h)));
            lp[3 * i] = v.x;
            lp[3 * i + 1] = v.y;
            lp[3 * i + 2] = v.z;
        }
        CHECK(pt_scene_builder_add_mesh(b, "lamp", lp, NULL, NULL, 4, idx, 2, NULL, ml, &err) ==
              PT_OK);
    } else {
        pt_punctual l;
        memset(&l, 0, sizeof l);
        l.type = PT_PUNCTUAL_DIRECTIONAL;
        l.direction = pt_v3(0, 0, -1);
        l.intensity = pt_v3((float)E_IRR, (float)E_IRR, (float)E_IRR);
        snprintf(l.name, sizeof l.name, "sun");
        const double lp[3] = {0, 0, 0};
        CHECKF(pt_scene_builder_add_punctual(b, &l, lp, &err) == PT_OK, "%s", err.msg);
    }
    pt_camera cam = {0};
    pt_vec3 v = pt_v3(0, 0, 1);
    if (su->v[2] > 0.0)
        v = pt_v3_norm(pt_v3((float)su->v[0], (float)su->v[1], (float)su->v[2]));
    pt_frame cf = pt_frame_from_normal(v);
    cam.position = pt_v3_add(pt_v3(PX, PY, 0.0f), pt_v3_scale(v, 10.0f));
    cam.forward = pt_v3_neg(v);
    cam.right = su->v[2] > 0.0 ? cf.t : pt_v3(1, 0, 0);
    cam.up = su->v[2] > 0.0 ? pt_v3_cross(cam.right, cam.forward) : pt_v3(0, 1, 0);
    cam.yfov = 1e-4f;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* Renders a 2 x 2 image of s at spp and returns the mean green and its
 * standard error (from the squared luminance: the scenes are grey). */
static double render(const pt_scene *s, uint32_t spp, double *se)
{
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = 2;
    p.seed = 5;
    pt_renderer *r = NULL;
    pt_error err = {0};
    *se = NAN;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return NAN;
    pt_pixel_acc acc[4];
    pt_render_stats st = {0};
    pt_render_tile(r, (pt_rect){0, 0, 2, 2}, 0, spp, acc, &st);
    CHECK(st.rejected == 0);
    double sum = 0.0, sq = 0.0, n = 0.0;
    for (int i = 0; i < 4; i++) {
        sum += pt_acc_sum(&acc[i], 1);
        sq += pt_acc_sum_sq(&acc[i]);
        n += acc[i].n;
    }
    double mean = sum / n;
    *se = sqrt(fmax(sq / n - mean * mean, 0.0) / n);
    pt_renderer_free(r);
    return mean;
}

/* The coat's Fresnel (factor 1, F0 0.04) at cosine c. */
static double fc(double c)
{
    return 0.04 + 0.96 * pow(1.0 - c, 5.0);
}

static void mirror_direction(void)
{
    struct {
        double deg, az, scale;
    } maps[] = {{15, 0, 1}, {20, 2.2, 1}, {12, 4.0, 1.4}};
    for (size_t k = 0; k < sizeof maps / sizeof maps[0]; k++)
        for (int tangents = 0; tangents < 2; tangents++)
            for (int mirror = 0; mirror < 2; mirror++) {
                setup su;
                memset(&su, 0, sizeof su);
                texel_for(maps[k].deg, maps[k].az, su.cc);
                su.cc_scale = (float)maps[k].scale;
                su.tangents = tangents;
                su.mirror = mirror;
                su.black = 1;
                double n[3];
                mapped(su.cc, su.cc_scale, n);
                double nw[3] = {mirror ? -n[0] : n[0], n[1], n[2]};
                for (int i = 0; i < 3; i++)
                    su.r[i] = 2.0 * nw[2] * nw[i] - (i == 2 ? 1.0 : 0.0);
                pt_scene *s = build(&su);
                if (!s)
                    continue;
                CHECK((s->features & PT_FEAT_NORMAL_MAP) && s->tangents);
                double se, got = render(s, 4096, &se);
                double want = fc(nw[2]) * LE;
                CHECKF(fabs(got - want) <= 5.0 * se + 1e-3 * want,
                       "coat map %zu, %s tangents, mirror %d: %.6f +- %.6f, want %.6f", k,
                       tangents ? "given" : "generated", mirror, got, se, want);
                pt_scene_free(s);
            }
}

static void base_keeps_its_normal(void)
{
    const double f = RHO / PI_D * E_IRR;
    struct {
        double cdeg, caz, bdeg, baz;
    } maps[] = {{40, 2.2, 25, 0.7}, {80, 1.0, 0, 0}, {50, 0.3, 30, 3.5}};
    for (size_t k = 0; k < sizeof maps / sizeof maps[0]; k++)
        for (int tangents = 0; tangents < 2; tangents++) {
            setup su;
            memset(&su, 0, sizeof su);
            texel_for(maps[k].cdeg, maps[k].caz, su.cc);
            su.cc_scale = 1.0f;
            double nb[3] = {0, 0, 1}, nc[3];
            if (maps[k].bdeg > 0.0) {
                texel_for(maps[k].bdeg, maps[k].baz, su.cb);
                mapped(su.cb, 1.0, nb);
            }
            mapped(su.cc, 1.0, nc);
            su.tangents = tangents;
            /* The view's reflection about nc: below the surface by t = 0.01
             * or more, the normal is bent to reflect it at t. */
            double cz = nc[2];
            if (2.0 * cz * cz - 1.0 < 0.01)
                cz = sqrt((1.0 + 0.01) / 2.0);
            pt_scene *s = build(&su);
            if (!s)
                continue;
            double se, got = render(s, 16, &se);
            double want = (1.0 - fc(cz)) * f * nb[2];
            CHECKF(fabs(got - want) <= 1e-4 * want,
                   "coat %g deg, base %g deg, %s tangents: %.8f, want %.8f", maps[k].cdeg,
                   maps[k].bdeg, tangents ? "given" : "generated", got, want);
            pt_scene_free(s);
        }
}

/* A coat without a clearcoatNormalTexture over a normal-mapped base keeps
 * the interpolated normal (KHR_materials_clearcoat): seen from v, 30 degrees
 * off the plane's normal, over a black base whose map tilts 15 degrees, it
 * reflects the emitter on v's mirror direction about +z, Fc(v.z) LE. A coat
 * on the base's mapped normal would reflect 30 degrees away from it: 0. */
static void coat_ignores_the_base_map(void)
{
    const double az[] = {0.7, 2.5};
    for (size_t k = 0; k < sizeof az / sizeof az[0]; k++)
        for (int tangents = 0; tangents < 2; tangents++) {
            setup su;
            memset(&su, 0, sizeof su);
            texel_for(15.0, az[k], su.cb);
            su.tangents = tangents;
            su.black = 1;
            const double t = 30.0 * PI_D / 180.0;
            su.v[0] = sin(t);
            su.v[2] = cos(t);
            su.r[0] = -su.v[0];
            su.r[2] = su.v[2];
            pt_scene *s = build(&su);
            if (!s)
                continue;
            CHECK((s->features & PT_FEAT_NORMAL_MAP) && s->tangents);
            double se, got = render(s, 4096, &se);
            double want = fc(su.v[2]) * LE;
            CHECKF(fabs(got - want) <= 5.0 * se + 1e-3 * want,
                   "base map at azimuth %g, %s tangents: %.6f +- %.6f, want %.6f", az[k],
                   tangents ? "given" : "generated", got, se, want);
            pt_scene_free(s);
        }
}

int main(void)
{
    coat_ignores_the_base_map();
    base_keeps_its_normal();
    mirror_direction();
    return check_report();
}
