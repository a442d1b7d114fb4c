/*
 * test_env.c - the environment light: its map reader, its sampler and the
 * integrator under it.
 *
 * - Sampling: chi-square goodness of fit of pt_env_sample's directions,
 *   binned by this test's own (u, v) of each direction (so the orientation
 *   is checked too), against the density the map defines - in each cell
 *   between four texel centres the bilinear interpolant of the texels'
 *   luminance times sin(theta) at the cell's centre row, integrated here
 *   from the map read independently - on the three shared maps (one with
 *   66 % of its energy in 52 texels), at a rotation, and on a small map in
 *   4 x 4 bins a texel (how a cell's samples spread between its texels).
 *   The pdf and radiance a sample reports equal pt_env_pdf's and
 *   pt_env_eval's of its direction (within the float direction's rounding:
 *   the sample reads them at the point it sampled), and the pdf integrates
 *   to 1 over the sphere (a midpoint sum on a grid).
 * - The split by the receiver's normal (env.h): chi-square of the park
 *   map's samples for a receiver facing away from its sun against the
 *   rest's density (full and compensated), and facing it against the whole
 *   map's; on random normals a sample's pdf is pt_env_pdf's with the same
 *   normal (NEE's and the BSDF hit's MIS weights sum to 1), the pdf
 *   integrates to 1, and where the sun's cone is below the tangent plane
 *   the pdf leaves it and puts half its mass above the plane; a Lambert
 *   plane facing away from a one-texel sun under a sky reads its closed
 *   form by NEE alone, MIS and BSDF sampling, NEE at the standard error
 *   predicted for the rest alone (3 times lower than the whole map's) and
 *   MIS at under half BSDF sampling's. Only the park map splits.
 * - A one-texel sun: NEE's luminance over pdf is constant within the sin
 *   ratio across a cell and float rounding (relative standard deviation
 *   under 1e-3; a density constant over each texel gives 1.04), and its
 *   mean is the texel's value times its solid angle. A Lambert plane under
 *   it, NEE alone, has the closed-form radiance rho / pi times the tent's
 *   integral of cos(theta), with a standard error under 1e-3 of it at 64 spp
 *   (8e-3 with a density constant over each texel).
 * - Closed forms: a Lambert plane of albedo rho under a uniform environment
 *   of radiance L (a convex object sees only the sky) has radiance rho L; a
 *   camera ray that leaves the scene sees L itself.
 * - Estimators: on a plane with an occluder under the park map (the hard
 *   sun), NEE alone, BSDF sampling alone and their MIS combination agree
 *   within their combined standard errors.
 * - Bad maps: missing, truncated, not an image, a value over the cap (what
 *   RGBE can say instead of NaN), NaN and 1e38 in an EXR, 0 x 0, not 2:1:
 *   each a clear error.
 * Tolerances are 5 standard errors of the estimate unless a value is exact.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/image/envmap.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/env_mean.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

static char tmp[256];

/* A deterministic uniform generator (splitmix64) for the test's own draws. */
static uint64_t rng = 0x9e3779b97f4a7c15ull;
static double rnd(void)
{
    return rng_f53(&rng);
}

/* This test's (u, v) of a direction: env.h's formula, written again. */
static void uv_of(pt_vec3 d, double rot_deg, double *u, double *v)
{
    double phi = atan2(d.x, -d.z);
    double uu = 0.5 + phi / (2.0 * PI_D) + rot_deg / 360.0;
    uu -= floor(uu);
    *u = uu;
    *v = acos(fmax(-1.0, fmin(1.0, d.y))) / PI_D;
}

/* Texel (x, y)'s luminance, x wrapped, y clamped. */
static double map_lum(const pt_envmap *map, long x, long y)
{
    long w = (long)map->width, h = (long)map->height;
    x = ((x % w) + w) % w;
    y = y < 0 ? 0 : (y >= h ? h - 1 : y);
    const float *c = &map->rgb[3 * ((size_t)y * map->width + (size_t)x)];
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

/* The density env.h defines for distribution `which`, integrated over each
 * of bu x bv bins of (u, v) (unrotated) into expd (normalised to 1): in
 * the cell between four texel centres (column x: centres x and x + 1,
 * wrapping; row r: texel rows r - 1 and r, clamped, rows 0 and h the poles'
 * half cells), the bilinear interpolant of the corners - each texel's
 * luminance, for PT_ENV_MIS less the sphere's mean, 0 where negative -
 * times sin(theta) at the cell's centre row. A bilinear function's integral
 * over a rectangle is its value at the centre times the area, so each cell
 * is cut into k x k squares (k even, bins lying on their edges) and each
 * square's integral goes to the bin holding it. */
static double env_density_bins_rest(const pt_envmap *map, double thr, double mean, int which,
                                    int bu, int bv, double *expd);
static void env_density_bins(const pt_envmap *map, double mean, int which, int bu, int bv,
                             double *expd)
{
    env_density_bins_rest(map, INFINITY, mean, which, bu, bv, expd);
}

/* The same for the map with the texels brighter than thr at 0 (a split's
 * rest, env.h), less mean for PT_ENV_MIS; returns the density's integral
 * before normalising (the cells' total weight). */
static double env_density_bins_rest(const pt_envmap *map, double thr, double mean, int which,
                                    int bu, int bv, double *expd)
{
    uint32_t w = map->width, h = map->height;
    int k = 2 * (bu / (int)w > 1 ? bu / (int)w : 1);
    int kv = 2 * (bv / (int)h > 1 ? bv / (int)h : 1);
    k = k > kv ? k : kv;
    memset(expd, 0, (size_t)bu * bv * sizeof *expd);
    double total = 0.0;
    for (uint32_t r = 0; r <= h; r++) {
        long y0 = (long)r - 1, y1 = (long)r;
        double vc = r == 0 ? 0.25 / h : (r == h ? 1.0 - 0.25 / h : (double)r / h);
        double sr = sin(PI_D * vc);
        for (uint32_t x = 0; x < w; x++) {
            double c[4];
            for (int i = 0; i < 4; i++) {
                double l = map_lum(map, (long)x + (i & 1), i < 2 ? y0 : y1);
                l = l > thr ? 0.0 : l;
                c[i] = which == PT_ENV_MIS ? fmax(l - mean, 0.0) : l;
            }
            for (int j = 0; j < k; j++) {
                double t = (j + 0.5) / k;
                double v = ((double)r - 0.5 + t) / h;
                if (v < 0.0 || v > 1.0)
                    continue; /* the half of a pole's cell beyond it */
                for (int i = 0; i < k; i++) {
                    double s = (i + 0.5) / k;
                    double u = ((double)x + 0.5 + s) / w;
                    u -= floor(u);
                    double f =
                        (1 - t) * ((1 - s) * c[0] + s * c[1]) + t * ((1 - s) * c[2] + s * c[3]);
                    int b = (int)(v * bv) * bu + (int)(u * bu);
                    expd[b] += f * sr;
                    total += f * sr;
                }
            }
        }
    }
    for (int b = 0; b < bu * bv; b++)
        expd[b] /= total;
    return total;
}

/* Chi-square of n samples of env (built from map, rotated) by distribution
 * `which` against the density env.h defines (env_density_bins), computed
 * here from the map, in bu x bv bins of (u, v). The sphere's mean luminance
 * is the mean over it of the bilinear lookup's luminance: over a texel's
 * rectangle, the 3 x 3 texels around it weighed (1/8, 3/4, 1/8) in each
 * direction (the integral of the tent), times sin(theta at its centre). */
static void chi2_env_n(const char *what, const pt_envmap *map, double rot_deg, int which, int BU,
                       int BV, pt_vec3 n, int rest);
static void chi2_env(const char *what, const pt_envmap *map, double rot_deg, int which, int BU,
                     int BV)
{
    chi2_env_n(what, map, rot_deg, which, BU, BV, pt_v3(0.0f, 0.0f, 0.0f), 0);
}

/* The same for a receiver with normal n, sampled by pt_env_sample; rest:
 * the test expects the split's rest (env.h) - the texels brighter than 16
 * times the sphere's mean at 0, the compensation by the rest's own mean
 * (the mean times the rest's share of the full density's integral), the
 * rest's full corners where that leaves nothing - and 1 from
 * pt_env_splits; else the whole map's density. */
static void chi2_env_n(const char *what, const pt_envmap *map, double rot_deg, int which, int BU,
                       int BV, pt_vec3 n, int rest)
{
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(map, 1.0f, (float)rot_deg, &env, &err) == PT_OK, "%s", err.msg);
    if (!env)
        return;
    double *expd = calloc((size_t)BU * BV, sizeof *expd),
           *obs = calloc((size_t)BU * BV, sizeof *obs);
    CHECK(expd && obs);
    if (!expd || !obs) {
        free(expd);
        free(obs);
        pt_env_free(env);
        return;
    }
    uint32_t w = map->width, h = map->height;
    static const double k3[3] = {0.125, 0.75, 0.125};
    double sphere = 0.0;
    for (uint32_t y = 0; y < h; y++) {
        double sn = sin(PI_D * (y + 0.5) / h);
        for (uint32_t x = 0; x < w; x++) {
            double m = 0.0;
            for (int j = 0; j < 3; j++)
                for (int i = 0; i < 3; i++)
                    m += k3[j] * k3[i] * map_lum(map, (long)x + i - 1, (long)y + j - 1);
            sphere += m * sn;
        }
    }
    /* Over the sphere's 4 pi, a texel's solid angle (2 pi / w) (pi / h)
     * sin(theta at its centre) as env.h has it. */
    double mean = sphere * (2.0 * PI_D / w) * (PI_D / h) / (4.0 * PI_D);
    CHECKF(fabs(pt_env_mean_luminance(env) - mean) <= 1e-3 * mean + 1e-9,
           "%s: mean luminance %g, want %g", what, pt_env_mean_luminance(env), mean);
    if (!rest) {
        env_density_bins(map, mean, which, BU, BV, expd);
    } else {
        CHECKF(pt_env_splits(env, which), "%s: the map is not split", what);
        double thr = 16.0 * mean;
        double full = env_density_bins_rest(map, INFINITY, mean, PT_ENV_FULL, BU, BV, expd);
        double part = env_density_bins_rest(map, thr, mean, PT_ENV_FULL, BU, BV, expd);
        if (which == PT_ENV_MIS &&
            !(env_density_bins_rest(map, thr, mean * part / full, PT_ENV_MIS, BU, BV, expd) > 0.0))
            env_density_bins_rest(map, thr, mean, PT_ENV_FULL, BU, BV, expd);
        printf("%s: the rest holds %.4f of the full density\n", what, part / full);
    }
    const int N = 400000;
    int pdf_bad = 0, rad_bad = 0;
    for (int i = 0; i < N; i++) {
        float u[2] = {(float)rnd(), (float)rnd()}, pdf;
        pt_vec3 d, rad;
        if (!pt_env_sample(env, u, which, n, &d, &rad, &pdf))
            continue;
        double uu, vv;
        uv_of(d, rot_deg, &uu, &vv);
        int bu = (int)(uu * BU), bv = (int)(vv * BV);
        bu = bu < 0 ? 0 : bu >= BU ? BU - 1 : bu;
        bv = bv < 0 ? 0 : bv >= BV ? BV - 1 : bv;
        obs[bv * BU + bu] += 1.0;
        float p2 = pt_env_pdf(env, d, which, n);
        /* The sample reads the lookup at the point it sampled; the
         * direction, rounded to floats, maps back to within a few float
         * steps of it, where the lookup differs by at most its slope (the
         * brightest of the texels around) times that step. */
        pt_vec3 look = pt_env_eval(env, d);
        long tx = (long)floor(uu * map->width - 0.5), ty = (long)floor(vv * map->height - 0.5);
        double top = 0.0;
        for (int j = 0; j < 2; j++)
            for (int k = 0; k < 2; k++)
                top = fmax(top, map_lum(map, tx + k, ty + j));
        if (!(fabs(pt_luminance(look) - pt_luminance(rad)) <= 1e-3 * top + 1e-9))
            rad_bad++;
        if (!(fabsf(p2 - pdf) <= 1e-3f * pdf))
            pdf_bad++;
    }
    for (int b = 0; b < BU * BV; b++)
        expd[b] *= N;
    double stat, p;
    int dof;
    p = stats_chi2_gof(obs, expd, BU * BV, 5.0, &stat, &dof);
    CHECKF(p > 1e-3, "%s: chi-square %.1f with %d degrees of freedom, p = %.2e", what, stat, dof,
           p);
    /* A direction on a cell's edge may round into its neighbour, and one
     * near a pole maps back less precisely (acos): rare. */
    CHECKF(pdf_bad < N / 10000, "%s: %d samples' pdf differs from pt_env_pdf", what, pdf_bad);
    CHECKF(rad_bad < N / 10000, "%s: %d samples' radiance differs from pt_env_eval", what, rad_bad);
    printf("%s: chi-square %.1f, %d dof, p = %.3f\n", what, stat, dof, p);
    free(expd);
    free(obs);

    /* The pdf integrates to 1 over the sphere: dw = 2 pi^2 sin(theta) du dv,
     * summed at the midpoints of a grid of 4 x 4 points a texel (whose
     * squares do not straddle the cells' edges at the texel centres), each
     * direction mapped back by pt_env_pdf itself (a Monte Carlo estimate
     * cannot see a hot sun's few texels). The grid is offset by the
     * rotation so its points keep their place in the texels. */
    const uint32_t gu = 4 * w, gv = 4 * h;
    double integral = 0.0;
    for (uint32_t j = 0; j < gv; j++) {
        double v = (j + 0.5) / gv, th = PI_D * v, st = sin(th);
        for (uint32_t i = 0; i < gu; i++) {
            double u = (i + 0.5) / gu, phi = 2.0 * PI_D * (u - 0.5 - rot_deg / 360.0);
            pt_vec3 d = pt_v3((float)(st * sin(phi)), (float)cos(th), (float)(-st * cos(phi)));
            integral += pt_env_pdf(env, d, which, n) * 2.0 * PI_D * PI_D * st;
        }
    }
    integral /= (double)gu * gv;
    CHECKF(fabs(integral - 1.0) < 1e-3, "%s: the pdf integrates to %.6f", what, integral);
    pt_env_free(env);
}

/* The lookup is bilinear between texel centres, wraps in u and is clamped
 * at the poles: a 4 x 2 map of distinct texels read at a centre, halfway
 * between two centres in u (across the seam too) and in v. */
static void bilinear_lookup(void)
{
    enum { W = 4, H = 2 };
    float px[W * H * 3];
    for (int i = 0; i < W * H; i++) {
        px[3 * i] = (float)(1 + i);
        px[3 * i + 1] = (float)(10 + 3 * i);
        px[3 * i + 2] = (float)(100 - 7 * i);
    }
    pt_envmap m = {W, H, px};
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_new(&m, 1.0f, 0.0f, &env, &err) == PT_OK);
    if (!env)
        return;
    struct {
        double u, v;
        int a, b, c, d; /* texels averaged (a == b == c == d: one) */
    } at[] = {
        {1.5 / W, 0.5 / H, 1, 1, 1, 1}, /* a centre */
        {2.0 / W, 0.5 / H, 1, 2, 1, 2}, /* between columns 1 and 2 */
        {0.0, 1.5 / H, 7, 4, 7, 4},     /* across the seam: columns 3 and 0 */
        {0.5 / W, 1.0 / H, 0, 0, 4, 4}, /* between the rows */
        {2.5 / W, 0.1 / H, 2, 2, 2, 2}, /* nearer the pole than the centre: clamped */
    };
    for (size_t k = 0; k < sizeof at / sizeof *at; k++) {
        double th = PI_D * at[k].v, phi = 2.0 * PI_D * (at[k].u - 0.5);
        pt_vec3 d =
            pt_v3((float)(sin(th) * sin(phi)), (float)cos(th), (float)(-sin(th) * cos(phi)));
        pt_vec3 got = pt_env_eval(env, d);
        const int t[4] = {at[k].a, at[k].b, at[k].c, at[k].d};
        for (int c = 0; c < 3; c++) {
            double want = 0.0;
            for (int i = 0; i < 4; i++)
                want += 0.25 * px[3 * t[i] + c];
            double g = c == 0 ? got.x : (c == 1 ? got.y : got.z);
            CHECKF(fabs(g - want) < 1e-4 * fabs(want) + 1e-4, "lookup %zu channel %d: %g, want %g",
                   k, c, g, want);
        }
    }
    pt_env_free(env);
}

/* Within a texel: a 16 x 8 map of random texels, a few of them hot (one in
 * the row beside a pole's), sampled into 4 x 4 bins a texel, so the chi-square sees
 * how each cell's samples spread between its four texel centres. */
static void sampling_within_texels(void)
{
    enum { W = 16, H = 8 };
    float px[W * H * 3];
    for (int i = 0; i < W * H * 3; i++)
        px[i] = (float)(0.05 + rnd());
    const int hot[][2] = {{3, 3}, {4, 3}, {11, 5}, {7, 1}};
    for (size_t k = 0; k < sizeof hot / sizeof *hot; k++)
        for (int c = 0; c < 3; c++)
            px[3 * (hot[k][1] * W + hot[k][0]) + c] = 500.0f * (float)(c + 1);
    pt_envmap m = {W, H, px};
    chi2_env("16 x 8 map, full, 4 x 4 bins a texel", &m, 0.0, PT_ENV_FULL, 4 * W, 4 * H);
    chi2_env("16 x 8 map, compensated, 4 x 4 bins a texel", &m, 0.0, PT_ENV_MIS, 4 * W, 4 * H);
}

/* The environment of map m at strength 1, unrotated; NULL after a failed
 * check. */
static pt_env *new_env(const pt_envmap *m)
{
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(m, 1.0f, 0.0f, &env, &err) == PT_OK, "%s", err.msg);
    return env;
}

/* A black SUN_W x SUN_H map but for one texel (sx, sy) of radiance rgb:
 * a sun of a single texel. NULL after a failed check. */
enum { SUN_W = 512, SUN_H = 256 };
static pt_env *one_texel_sun(int sx, int sy, const float rgb[3])
{
    static float px[SUN_W * SUN_H * 3];
    memset(px, 0, sizeof px);
    for (int c = 0; c < 3; c++)
        px[3 * (sy * SUN_W + sx) + c] = rgb[c];
    return new_env(&(pt_envmap){SUN_W, SUN_H, px});
}

/* A sun of one texel: NEE by the full distribution of a black map with one
 * hot texel at the equator. The density follows the lookup's luminance
 * across each cell, so a sample's luminance over its pdf is the same
 * wherever it lands but for sin(theta) over sin(theta at its cell row's
 * centre): within the cells around the texel (theta within 1.5 texels,
 * 1.5 pi / h, of the equator) that ratio is within cos(1.5 pi / h) of 1, a
 * relative spread of 1.7e-4 at h = 256, and for the float direction's
 * rounding, a relative error of about u w 2^-24 / (1 - s) in the lookup
 * where the tent falls to 0 at s = 1 and the density with it: a relative
 * standard deviation of about 1e-4. The test asks for under 1e-3.
 * Their mean, the map's integral, is the texel's value times its solid
 * angle 2 pi^2 / (w h) sin(theta) (the bilinear tent's integral: the
 * texel's value over one texel's area). A density constant over each texel,
 * its mean there, puts samples of the texels beside the sun uniformly over
 * them, where the lookup falls from half the sun's luminance to nothing. */
static void sun_ratio(void)
{
    const int W = SUN_W, H = SUN_H, sx = 200, sy = H / 2;
    const float sun[3] = {4e4f, 3.5e4f, 2.5e4f};
    pt_env *env = one_texel_sun(sx, sy, sun);
    if (!env)
        return;
    double sum = 0.0, sum2 = 0.0;
    const int N = 100000;
    int n = 0;
    for (int i = 0; i < N; i++) {
        float u[2] = {(float)rnd(), (float)rnd()}, pdf;
        pt_vec3 d, rad;
        if (!pt_env_sample(env, u, PT_ENV_FULL, pt_v3(0.0f, 0.0f, 0.0f), &d, &rad, &pdf))
            continue;
        double q = pt_luminance(rad) / pdf;
        sum += q;
        sum2 += q * q;
        n++;
    }
    CHECKF(n == N, "sun: %d of %d samples failed", N - n, N);
    double mq = sum / n, rsd = sqrt(fmax(sum2 / n - mq * mq, 0.0)) / mq;
    CHECKF(rsd < 1e-3, "sun: luminance / pdf has a relative standard deviation of %.3g", rsd);
    double lum = 0.2126 * sun[0] + 0.7152 * sun[1] + 0.0722 * sun[2];
    double want = lum * 2.0 * PI_D * PI_D / ((double)W * H) * sin(PI_D * (sy + 0.5) / H);
    CHECKF(fabs(sum / n - want) <= 1e-3 * want, "sun: the estimate %g, want %g", sum / n, want);
    printf("sun: luminance / pdf, relative standard deviation %.3g, estimate %g of %g\n", rsd,
           sum / n, want);
    pt_env_free(env);
}

/* The direction of map's brightest texel's centre (uv_of's inverse). */
static pt_vec3 brightest_dir(const pt_envmap *map, double rot_deg)
{
    long bx = 0, by = 0;
    for (long y = 0; y < (long)map->height; y++)
        for (long x = 0; x < (long)map->width; x++)
            if (map_lum(map, x, y) > map_lum(map, bx, by)) {
                bx = x;
                by = y;
            }
    double u = (bx + 0.5) / map->width, th = PI_D * (by + 0.5) / map->height;
    double phi = 2.0 * PI_D * (u - 0.5 - rot_deg / 360.0);
    return pt_v3((float)(sin(th) * sin(phi)), (float)cos(th), (float)(-sin(th) * cos(phi)));
}

/* The split by the receiver's normal (env.h) on random normals: for each,
 * a sample's pdf is pt_env_pdf's with the same normal (what makes NEE's
 * and the BSDF hit's MIS weights sum to 1), the pdf integrates to 1 over
 * the sphere, and where the sun's cone is wholly below the tangent plane
 * it is 0 on the sun's texels, so that all of it lies where the rest can
 * send light: on a 128 x 64 map, a uniform sky of 1 and one texel of 4e4
 * (85 % of the light). */
static void split_normals(void)
{
    enum { W = 128, H = 64 };
    static float px[W * H * 3];
    for (int i = 0; i < W * H * 3; i++)
        px[i] = 1.0f;
    const int sx = 40, sy = 48;
    for (int c = 0; c < 3; c++)
        px[3 * (sy * W + sx) + c] = 4e4f;
    pt_envmap m = {W, H, px};
    pt_env *env = new_env(&m);
    if (!env)
        return;
    CHECK(pt_env_splits(env, PT_ENV_FULL));
    pt_vec3 sun = brightest_dir(&m, 0.0);
    int hidden = 0, bad_pdf = 0;
    for (int k = 0; k < 24; k++) {
        /* A uniform normal on the sphere; every fourth one the sun's opposite. */
        double z = 2.0 * rnd() - 1.0, a = 2.0 * PI_D * rnd(), r = sqrt(fmax(0.0, 1.0 - z * z));
        pt_vec3 n = pt_v3((float)(r * cos(a)), (float)z, (float)(r * sin(a)));
        if (k % 4 == 0)
            n = pt_v3_neg(sun);
        int which = k & 1 ? PT_ENV_MIS : PT_ENV_FULL;
        for (int i = 0; i < 2000; i++) {
            float u[2] = {(float)rnd(), (float)rnd()}, pdf;
            pt_vec3 d, rad;
            if (!pt_env_sample(env, u, which, n, &d, &rad, &pdf))
                continue;
            if (!(fabsf(pt_env_pdf(env, d, which, n) - pdf) <= 1e-3f * pdf))
                bad_pdf++;
        }
        /* The sun's cone (its texel and the cells around it) is wholly
         * below the plane when n . sun < -sin(angle to the support's edge
         * + margin); the pdf there is then 0. */
        double integral = 0.0, on_sun = 0.0, above = 0.0, sun_area = 0.0;
        const int G = 4;
        for (int j = 0; j < G * H; j++) {
            double v = (j + 0.5) / (G * H), th = PI_D * v, st = sin(th);
            for (int i = 0; i < G * W; i++) {
                double u = (i + 0.5) / (G * W), phi = 2.0 * PI_D * (u - 0.5);
                pt_vec3 d = pt_v3((float)(st * sin(phi)), (float)cos(th), (float)(-st * cos(phi)));
                double p = pt_env_pdf(env, d, which, n) * 2.0 * PI_D * PI_D * st;
                integral += p;
                if (fabs(u * W - (sx + 0.5)) < 1.0 && fabs(v * H - (sy + 0.5)) < 1.0) {
                    on_sun += p;
                    sun_area += 2.0 * PI_D * PI_D * st;
                }
                if (pt_v3_dot(d, n) > 0.0f)
                    above += p;
            }
        }
        integral /= (double)G * G * W * H;
        on_sun /= (double)G * G * W * H;
        above /= (double)G * G * W * H;
        sun_area /= (double)G * G * W * H;
        CHECKF(fabs(integral - 1.0) < 1e-3, "normal %d: the pdf integrates to %.6f", k, integral);
        double half = 2.0 * PI_D / W + PI_D / H + 1e-3;
        if (!pt_env_splits(env, which)) {
            /* The compensated rest of a uniform sky is the sky itself, half
             * of it away from the sun: the rule's edge either way. */
        } else if (pt_v3_dot(n, sun) < -sin(half + 0.01)) {
            hidden++;
            /* Around the sun's texel (its cells) the rest's density is
             * the interpolant of the sky's corners and the sun's 0: at
             * most the uniform rest's, 1 / (4 pi) of the solid angle (the
             * whole map's gives the sun 85 %). */
            CHECKF(on_sun <= 1.01 * sun_area / (4.0 * PI_D),
                   "normal %d: %.3g of the pdf on the hidden sun, over %.3g", k, on_sun,
                   sun_area / (4.0 * PI_D));
            /* The uniform rest: half its mass on the receiver's side. */
            CHECKF(fabs(above - 0.5) < 0.02, "normal %d: %.4f of the pdf above the plane", k,
                   above);
        } else if (pt_v3_dot(n, sun) > 0.0f) {
            CHECKF(on_sun > 0.5, "normal %d: the visible sun has %.3g of the pdf", k, on_sun);
        }
    }
    /* A direction on a cell's edge may round into its neighbour: rare. */
    CHECKF(bad_pdf < 24 * 2000 / 10000, "%d samples' pdf differs from pt_env_pdf with their normal",
           bad_pdf);
    CHECK(hidden >= 6);
    printf("split: %d of 24 normals with the sun hidden\n", hidden);
    pt_env_free(env);
}

static void sampling(void)
{
    const char *maps[] = {"studio_small_03_1k.hdr", "rooitou_park_1k.hdr",
                          "potsdamer_platz_1k.hdr"};
    char path[512];
    struct stat sb;
    snprintf(path, sizeof path, "%s/../envs", PT_SHARED_SCENES);
    if (stat(path, &sb) != 0) {
        CHECK_SKIP("shared environment maps not found; the chi-square tests");
        CHECK(!check_shared_required());
        return;
    }
    for (size_t i = 0; i < sizeof maps / sizeof *maps; i++) {
        snprintf(path, sizeof path, "%s/../envs/%s", PT_SHARED_SCENES, maps[i]);
        pt_envmap m;
        pt_error err = {0};
        CHECKF(pt_envmap_read(path, &m, &err) == PT_OK, "%s", err.msg);
        if (!m.rgb)
            continue;
        CHECK(m.width == 1024 && m.height == 512);
        pt_env *e = NULL;
        if (pt_env_new(&m, 1.0f, 0.0f, &e, &err) == PT_OK)
            printf("%s: full %s, compensated %s\n", maps[i],
                   pt_env_splits(e, PT_ENV_FULL) ? "split" : "not split",
                   pt_env_splits(e, PT_ENV_MIS) ? "split" : "not split");
        /* The park's sun holds 68 % of its light; its compensated rest
         * lies on the sun's side (85 %). */
        CHECK(e && pt_env_splits(e, PT_ENV_FULL) == (i == 1) && !pt_env_splits(e, PT_ENV_MIS));
        pt_env_free(e);
        char name[128];
        snprintf(name, sizeof name, "%s, full", maps[i]);
        chi2_env(name, &m, 0.0, PT_ENV_FULL, 64, 32);
        snprintf(name, sizeof name, "%s, compensated", maps[i]);
        chi2_env(name, &m, 0.0, PT_ENV_MIS, 64, 32);
        if (i == 1) {
            chi2_env("rooitou_park rotated 37 deg", &m, 37.0, PT_ENV_MIS, 64, 32);
            /* The low sun (its brightest texel) behind the receiver: the
             * rest alone; in front of it, the whole map. */
            pt_vec3 sun = brightest_dir(&m, 0.0);
            chi2_env_n("rooitou_park, full, sun behind", &m, 0.0, PT_ENV_FULL, 64, 32,
                       pt_v3_neg(sun), 1);
            /* Its compensated rest (the sunlit haze and ground) lies on
             * the sun's side: the compensated distribution is not split. */
            chi2_env_n("rooitou_park, compensated, sun behind", &m, 0.0, PT_ENV_MIS, 64, 32,
                       pt_v3_neg(sun), 0);
            chi2_env_n("rooitou_park, compensated, sun in front", &m, 0.0, PT_ENV_MIS, 64, 32, sun,
                       0);
        }
        pt_envmap_free(&m);
    }
}

/* ---- the integrator ---------------------------------------------------------------- */

/* A Lambert plane of albedo rho (and a box on it when occluder), a camera
 * above looking down with field of view yfov. */
static pt_scene *plane_scene(float rho, int occluder, float yfov)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = rho;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    uint32_t mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    const float P = 50.0f;
    float plane[12] = {-P, 0, -P, P, 0, -P, P, 0, P, -P, 0, P};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, mat, &err) ==
          PT_OK);
    if (occluder) {
        /* A tilted panel over part of the view: shadows and interreflection. */
        float q[12] = {-1, 0.5f, -1, 1, 1.5f, -1, 1, 1.5f, 1, -1, 0.5f, 1};
        CHECK(pt_scene_builder_add_mesh(b, "panel", q, NULL, NULL, 4, idx, 2, NULL, mat, &err) ==
              PT_OK);
    }
    pt_camera cam = {0};
    cam.position = pt_v3(0, 10, 0);
    cam.forward = pt_v3(0, -1, 0);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 0, -1);
    cam.yfov = yfov;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void uniform_sky(void)
{
    const float rho = 0.6f, L = 1.5f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(L, L, L), &env, &err) == PT_OK);
    pt_scene *s = plane_scene(rho, 0, 0.5f);
    double se;
    double m = render_mean(s, env, PT_LIGHT_MIS, 16, 256, &se);
    CHECKF(fabs(m - rho * L) < 5.0 * se + 1e-6 && se < 0.003 * rho * L,
           "plane under a uniform sky: %.5f, expected %.5f (se %.2e)", m, (double)(rho * L), se);
    printf("plane under a uniform sky: %.5f (exact %.5f), standard error %.2e\n", m,
           (double)(rho * L), se);
    pt_scene_free(s);
    /* A camera looking away from the plane sees the sky itself, exactly. */
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material mt = pt_material_default();
    uint32_t mat;
    CHECK(pt_scene_builder_add_material(b, &mt, &mat, &err) == PT_OK);
    float tri[9] = {0, -5, 0, 1, -5, 0, 0, -5, 1};
    CHECK(pt_scene_builder_add_mesh(b, "below", tri, NULL, NULL, 3, NULL, 1, NULL, mat, &err) ==
          PT_OK);
    pt_camera cam = {0};
    cam.forward = pt_v3(0, 1, 0);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 0, 1);
    cam.yfov = 0.5f;
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    CHECK(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK);
    m = render_mean(s, env, PT_LIGHT_MIS, 4, 16, &se);
    CHECKF(fabs(m - L) < 1e-6, "the sky seen directly: %.7f, expected %.7f", m, (double)L);
    pt_scene_free(s);
    pt_env_free(env);
}

static void strategies_agree(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/../envs/rooitou_park_1k.hdr", PT_SHARED_SCENES);
    pt_envmap m;
    pt_error err = {0};
    if (pt_envmap_read(path, &m, &err) != PT_OK) {
        CHECK_SKIP("shared environment maps not found; the strategies");
        CHECK(!check_shared_required());
        return;
    }
    pt_env *env = NULL;
    CHECK(pt_env_new(&m, 1.0f, 0.0f, &env, &err) == PT_OK);
    pt_envmap_free(&m);
    pt_scene *s = plane_scene(0.5f, 1, 0.6f);
    double se_m, se_n, se_b;
    double mis = render_mean(s, env, PT_LIGHT_MIS, 16, 512, &se_m);
    double nee = render_mean(s, env, PT_LIGHT_NEE_ONLY, 16, 512, &se_n);
    double bsdf = render_mean(s, env, PT_LIGHT_BSDF_ONLY, 16, 2048, &se_b);
    printf("park: MIS %.5f (se %.1e), NEE %.5f (se %.1e), BSDF %.5f (se %.1e)\n", mis, se_m, nee,
           se_n, bsdf, se_b);
    CHECKF(fabs(mis - nee) < 5.0 * sqrt(se_m * se_m + se_n * se_n), "MIS %.5f vs NEE %.5f", mis,
           nee);
    CHECKF(fabs(mis - bsdf) < 5.0 * sqrt(se_m * se_m + se_b * se_b), "MIS %.5f vs BSDF %.5f", mis,
           bsdf);
    CHECKF(fabs(nee - bsdf) < 5.0 * sqrt(se_n * se_n + se_b * se_b), "NEE %.5f vs BSDF %.5f", nee,
           bsdf);
    /* The check means something only if the errors are small against the value. */
    CHECKF(se_m < 0.01 * mis && se_n < 0.01 * nee, "standard errors too large");
    pt_scene_free(s);
    pt_env_free(env);
}

/* A Lambert plane (normal +Y, albedo rho) lit by a one-texel sun of a
 * black map, NEE alone: its radiance is rho / pi times the irradiance, the
 * integral of the bilinear tent around the texel times cos(theta) over the
 * sphere, computed here on a fine grid. Each light sample's luminance over
 * its pdf is constant but for sin(theta) across a cell (sun_ratio), so a
 * sample's value varies only with cos(theta) over the tent, +-1 texel
 * (pi / h) around theta0: a relative spread of tan(theta0) pi / h, 1.2 %
 * at h = 256 and 45 degrees, a standard deviation under half that. Over
 * 16 x 16 pixels of 64 samples the mean's standard error is then under
 * 0.6 % / 128 = 5e-5 of it; the test asks for 1e-3. A density constant over
 * each texel gives a sample's value a relative standard deviation of about
 * 1 (sun_ratio): 8e-3. */
static void sun_plane(void)
{
    const int W = SUN_W, H = SUN_H, sx = 300, sy = 64;
    const float V = 2e4f, rho = 0.5f;
    pt_env *env = one_texel_sun(sx, sy, (const float[3]){V, V, V});
    if (!env)
        return;
    /* The tent: (1 - |du|) (1 - |dv|) in texels around the texel's centre;
     * dw = 2 pi^2 sin(theta) du dv, cos(theta) towards the plane's normal. */
    const int K = 256;
    double irr = 0.0;
    for (int j = 0; j < 2 * K; j++) {
        double dv = (j + 0.5) / K - 1.0, v = (sy + 0.5 + dv) / H, th = PI_D * v;
        for (int i = 0; i < 2 * K; i++) {
            double du = (i + 0.5) / K - 1.0;
            irr += V * (1.0 - fabs(du)) * (1.0 - fabs(dv)) * cos(th) * sin(th);
        }
    }
    irr *= 2.0 * PI_D * PI_D / ((double)W * H) / ((double)K * K);
    double want = rho / PI_D * irr;
    pt_scene *s = plane_scene(rho, 0, 0.6f);
    double se = 0.0;
    double got = render_mean(s, env, PT_LIGHT_NEE_ONLY, 16, 64, &se);
    printf("sun plane: %.6f (se %.2e), want %.6f\n", got, se, want);
    CHECKF(se < 1e-3 * want, "sun plane: standard error %.2e of %.6f", se, got);
    CHECKF(fabs(got - want) < 5.0 * se + 1e-4 * want, "sun plane: %.6f, want %.6f", got, want);
    pt_scene_free(s);
    pt_env_free(env);
}

/* The bilinear lookup's luminance at (u, v) (env.h), written again. */
static double lookup_lum(const pt_envmap *map, double u, double v)
{
    double fx = u * map->width - 0.5, fy = v * map->height - 0.5;
    long x0 = (long)floor(fx), y0 = (long)floor(fy);
    double s = fx - x0, t = fy - y0;
    return (1 - t) * ((1 - s) * map_lum(map, x0, y0) + s * map_lum(map, x0 + 1, y0)) +
           t * ((1 - s) * map_lum(map, x0, y0 + 1) + s * map_lum(map, x0 + 1, y0 + 1));
}

/* A Lambert plane (normal +Y, albedo rho) facing away from a one-texel sun
 * (85 % of the map's light, 44 degrees below the horizon) under a sky of 1
 * with a patch of 3 x 3 texels of 30 at 35 degrees from the zenith, on a
 * 128 x 64 map. Its radiance is rho / pi times the integral of the lookup
 * times cos(theta) over the upper hemisphere (computed here on a grid of
 * 8 x 8 points a texel); the sun adds nothing. NEE alone: a sample of a
 * density proportional to the lookup L, of total Phi, weighs
 * rho / pi cos Phi wherever it lands, so its variance is
 * (rho / pi)^2 Phi int L cos^2 - mean^2 over the upper hemisphere: with the
 * split (the rest alone: Phi the sky's) its standard error over 16 x 16
 * pixels of 64 samples is predicted below; the whole map's Phi is 6.7 times
 * larger, its standard error 2.4 times. The test asks for under their
 * geometric mean. Under MIS the unsplit compensated distribution is the
 * sun alone but for 0.4 %, so BSDF sampling finds the patch by chance, as
 * it does alone (a standard error 0.68 times BSDF sampling's alone); the
 * rest's compensation (its own mean, about 1) is the patch alone, which
 * NEE then finds every time (0.05 times): the test asks MIS for under half
 * BSDF sampling's standard error. */
static void sun_behind(void)
{
    enum { W = 128, H = 64 };
    static float px[W * H * 3];
    const int sx = 40, sy = 48;
    const float rho = 0.5f;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            float l =
                x == sx && y == sy ? 4e4f : (abs(x - 80) <= 1 && abs(y - 12) <= 1 ? 30.0f : 1.0f);
            for (int c = 0; c < 3; c++)
                px[3 * (y * W + x) + c] = l;
        }
    pt_envmap m = {W, H, px};
    pt_env *env = new_env(&m);
    if (!env)
        return;
    CHECK(pt_env_splits(env, PT_ENV_FULL) && pt_env_splits(env, PT_ENV_MIS));
    const int G = 8;
    double irr = 0.0, m2 = 0.0, phi_all = 0.0, phi_sun = 0.0;
    for (int j = 0; j < G * H; j++) {
        double v = (j + 0.5) / (G * H), th = PI_D * v;
        double dw = 2.0 * PI_D * PI_D * sin(th) / ((double)G * G * W * H);
        for (int i = 0; i < G * W; i++) {
            double u = (i + 0.5) / (G * W), l = lookup_lum(&m, u, v);
            phi_all += l * dw;
            if (fabs(u * W - (sx + 0.5)) < 1.0 && fabs(v * H - (sy + 0.5)) < 1.0)
                phi_sun += (l - 1.0) * dw; /* the sun's tent over the sky */
            if (th < 0.5 * PI_D) {
                irr += l * cos(th) * dw;
                m2 += l * cos(th) * cos(th) * dw;
            }
        }
    }
    double want = rho / PI_D * irr, N = 16.0 * 16.0 * 64.0;
    double phi_rest = phi_all - phi_sun;
    double se_split = sqrt(fmax((rho / PI_D) * (rho / PI_D) * phi_rest * m2 - want * want, 0) / N);
    double se_whole = sqrt(fmax((rho / PI_D) * (rho / PI_D) * phi_all * m2 - want * want, 0) / N);
    pt_scene *s = plane_scene(rho, 0, 0.6f);
    double se_n, se_m, se_b;
    double nee = render_mean(s, env, PT_LIGHT_NEE_ONLY, 16, 64, &se_n);
    double mis = render_mean(s, env, PT_LIGHT_MIS, 16, 64, &se_m);
    double bsdf = render_mean(s, env, PT_LIGHT_BSDF_ONLY, 16, 64, &se_b);
    printf("sun behind: want %.5f; NEE %.5f (se %.2e, predicted %.2e split, %.2e whole), "
           "MIS %.5f (se %.2e), BSDF %.5f (se %.2e)\n",
           want, nee, se_n, se_split, se_whole, mis, se_m, bsdf, se_b);
    CHECKF(fabs(nee - want) < 5.0 * se_n + 1e-4 * want, "sun behind: NEE %.5f, want %.5f", nee,
           want);
    CHECKF(fabs(mis - want) < 5.0 * se_m + 1e-4 * want, "sun behind: MIS %.5f, want %.5f", mis,
           want);
    CHECKF(fabs(bsdf - want) < 5.0 * se_b + 1e-4 * want, "sun behind: BSDF %.5f, want %.5f", bsdf,
           want);
    CHECKF(se_n < sqrt(se_split * se_whole), "sun behind: NEE's standard error %.2e, over %.2e",
           se_n, sqrt(se_split * se_whole));
    CHECKF(se_m < 0.5 * se_b, "sun behind: MIS's standard error %.2e, BSDF sampling's %.2e", se_m,
           se_b);
    pt_scene_free(s);
    pt_env_free(env);
}

/* ---- bad maps ------------------------------------------------------------------------ */

static void write_bytes(const char *name, const void *d, size_t n)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    FILE *f = fopen(p, "wb");
    CHECK(f && fwrite(d, 1, n, f) == n);
    if (f)
        fclose(f);
}

static void expect_bad(const char *name, const char *word)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    pt_envmap m;
    pt_error err = {0};
    int64_t live = pt_alloc_live();
    pt_status st = pt_envmap_read(p, &m, &err);
    CHECKF(st != PT_OK && m.rgb == NULL, "%s: read", name);
    CHECKF(strstr(err.msg, word) != NULL, "%s: message lacks '%s': %s", name, word, err.msg);
    CHECKF(pt_alloc_live() == live, "%s: leaked", name);
}

/* A flat (not run-length) Radiance file of w x h texels, all (r, g, b, e). */
static size_t rgbe_file(uint8_t *buf, size_t cap, int w, int h, const uint8_t px[4])
{
    int n = snprintf((char *)buf, cap, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    size_t at = (size_t)n;
    for (int i = 0; i < w * h && at + 4 <= cap; i++, at += 4)
        memcpy(buf + at, px, 4);
    return at;
}

static void bad_maps(void)
{
    static uint8_t buf[1 << 16];
    const uint8_t grey[4] = {128, 128, 128, 129}, huge[4] = {255, 255, 255, 255};
    expect_bad("missing.hdr", "missing.hdr");
    size_t n = rgbe_file(buf, sizeof buf, 8, 4, grey);
    write_bytes("good.hdr", buf, n);
    pt_envmap m;
    pt_error err = {0};
    char p[512];
    snprintf(p, sizeof p, "%s/good.hdr", tmp);
    CHECKF(pt_envmap_read(p, &m, &err) == PT_OK && m.width == 8 && m.height == 4, "%s", err.msg);
    if (m.rgb)
        CHECK(fabsf(m.rgb[0] - 1.0f) < 1e-6f); /* 128/256 * 2^(129-128) */
    pt_envmap_free(&m);
    write_bytes("cut.hdr", buf, n - 40);
    expect_bad("cut.hdr", "cut.hdr");
    write_bytes("text.hdr", "hello, not an image\n", 20);
    expect_bad("text.hdr", "not an environment map");
    n = rgbe_file(buf, sizeof buf, 8, 4, huge);
    write_bytes("huge.hdr", buf, n);
    expect_bad("huge.hdr", "not a radiance in");
    n = rgbe_file(buf, sizeof buf, 0, 0, grey);
    write_bytes("empty.hdr", buf, n);
    expect_bad("empty.hdr", "empty.hdr");
    n = rgbe_file(buf, sizeof buf, 4, 4, grey);
    write_bytes("square.hdr", buf, n);
    expect_bad("square.hdr", "not an equirectangular map");
    /* EXR: NaN and 1e38 through OpenEXRCore. */
    pt_image *img = NULL;
    CHECK(pt_image_new(8, 4, &img, NULL) == PT_OK);
    const float bad[2] = {NAN, 1e38f};
    const char *names[2] = {"nan.exr", "big.exr"};
    for (int k = 0; k < 2 && img; k++) {
        img->g[5] = bad[k];
        snprintf(p, sizeof p, "%s/%s", tmp, names[k]);
        CHECK(pt_exr_write(p, img, NULL, &err) == PT_OK);
        expect_bad(names[k], "pixel (5, 0)");
    }
    pt_image_free(img);
}

int main(void)
{
    bilinear_lookup();
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_env_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    int64_t live0 = pt_alloc_live();
    bad_maps();
    uniform_sky();
    strategies_agree();
    sampling_within_texels();
    sun_ratio();
    sun_plane();
    split_normals();
    sun_behind();
    sampling();
    CHECK(pt_alloc_live() == live0);
    if (pt_remove_tree(tmp) != 0)
        return 1;
    return check_report();
}
