#include "common/render/env.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"

#define PI_F 3.14159265358979323846f
#define PI_D 3.14159265358979323846

/* A piecewise-constant distribution over the map's texels (env.h). */
typedef struct env_dist {
    double *row_cdf;  /* h + 1: the marginal over rows, 0 .. 1 */
    double *col_cdf;  /* h * (w + 1): per row, 0 .. 1 (uniform for a black row) */
    float *texel_pdf; /* w * h: the density over [0,1)^2 of each texel's rectangle */
    int black;        /* nothing to sample */
} env_dist;

struct pt_env {
    uint32_t w, h;
    float *rgb;      /* w * h * 3, strength applied */
    env_dist full;   /* weights: the texel's mean luminance x sin(theta) */
    env_dist comp;   /* the same less the sphere's mean (MIS compensation) */
    float rot;       /* rotate_deg in turns, in [0, 1) */
    double mean_lum; /* over the sphere */
};

static void dist_free(env_dist *d)
{
    pt_free(d->row_cdf);
    pt_free(d->col_cdf);
    pt_free(d->texel_pdf);
}

void pt_env_free(pt_env *env)
{
    if (!env)
        return;
    pt_free(env->rgb);
    dist_free(&env->full);
    dist_free(&env->comp);
    pt_free(env);
}

/* The distribution with texel weights wgt (>= 0, w * h, row-major); sums in
 * double. Returns 0 when out of memory. */
static int dist_build(env_dist *d, const double *wgt, uint32_t w, uint32_t h)
{
    size_t n = (size_t)w * h;
    d->row_cdf = pt_malloc_array((size_t)h + 1, sizeof *d->row_cdf);
    d->col_cdf = pt_malloc_array((size_t)h * (w + 1), sizeof *d->col_cdf);
    d->texel_pdf = pt_malloc_array(n, sizeof *d->texel_pdf);
    if (!d->row_cdf || !d->col_cdf || !d->texel_pdf)
        return 0;
    double total = 0.0;
    d->row_cdf[0] = 0.0;
    for (uint32_t y = 0; y < h; y++) {
        double *cdf = d->col_cdf + (size_t)y * (w + 1);
        cdf[0] = 0.0;
        for (uint32_t x = 0; x < w; x++)
            cdf[x + 1] = cdf[x] + wgt[(size_t)y * w + x];
        double row = cdf[w];
        for (uint32_t x = 1; x <= w; x++)
            cdf[x] = row > 0.0 ? cdf[x] / row : (double)x / (double)w;
        cdf[w] = 1.0;
        total += row;
        d->row_cdf[y + 1] = total;
    }
    d->black = !(total > 0.0) || !isfinite(total);
    for (size_t i = 0; i < n; i++)
        d->texel_pdf[i] = d->black ? 0.0f : (float)(wgt[i] / total * (double)n);
    for (uint32_t y = 0; y < h && !d->black; y++)
        d->row_cdf[y + 1] /= total;
    d->row_cdf[h] = 1.0;
    return 1;
}

/* Texel (x, y)'s luminance; x wraps, y is clamped (the bilinear lookup's
 * neighbours, pt_env_eval). */
static double lum_at(const pt_env *e, int64_t x, int64_t y)
{
    int64_t w = e->w, h = e->h;
    x = ((x % w) + w) % w;
    y = y < 0 ? 0 : (y >= h ? h - 1 : y);
    const float *c = &e->rgb[3 * ((size_t)y * e->w + (size_t)x)];
    return pt_luminance(pt_v3(c[0], c[1], c[2]));
}

pt_status pt_env_new(const pt_envmap *map, float strength, float rotate_deg, pt_env **out,
                     pt_error *err)
{
    if (!(strength >= 0.0f) || !isfinite(strength))
        return pt_error_set(err, PT_ERR_ARG, "environment strength %g is not a finite value >= 0",
                            (double)strength);
    if (!isfinite(rotate_deg))
        return pt_error_set(err, PT_ERR_ARG, "environment rotation is not finite");
    if (!map || !map->rgb || map->width == 0 || map->height == 0)
        return pt_error_set(err, PT_ERR_ARG, "environment map is empty");
    uint32_t w = map->width, h = map->height;
    size_t n = (size_t)w * h;
    pt_env *e = pt_calloc(1, sizeof *e);
    if (!e)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the environment");
    e->w = w;
    e->h = h;
    e->rgb = pt_malloc_array(n * 3, sizeof *e->rgb);
    double *wgt = pt_malloc_array(n, sizeof *wgt);
    if (!e->rgb || !wgt) {
        pt_free(wgt);
        pt_env_free(e);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a %ux%u environment", w, h);
    }
    double turns = fmod((double)rotate_deg / 360.0, 1.0);
    e->rot = (float)(turns < 0.0 ? turns + 1.0 : turns);
    if (e->rot >= 1.0f)
        e->rot = 0.0f;
    for (size_t i = 0; i < n * 3; i++) {
        e->rgb[i] = map->rgb[i] * strength;
        if (!isfinite(e->rgb[i]) || e->rgb[i] < 0.0f) {
            pt_free(wgt);
            pt_env_free(e);
            return pt_error_set(err, PT_ERR_ARG,
                                "environment strength %g makes a texel overflow a float",
                                (double)strength);
        }
    }
    /* Each texel's mean luminance under the bilinear lookup: the integral
     * of the interpolant over the texel's rectangle weighs the 3 x 3 texels
     * around it by (1/8, 3/4, 1/8) in each direction. Every texel whose
     * lookup can be above 0 gets a weight above 0, so the full distribution
     * covers the whole lookup. Times sin(theta at the row's centre), and
     * the mean over the sphere (solid angle of texel (x, y): (2 pi / w)
     * (pi / h) sin(theta)). */
    static const double k3[3] = {0.125, 0.75, 0.125};
    double lum_sphere = 0.0;
    for (uint32_t y = 0; y < h; y++) {
        double s = sin(PI_D * ((double)y + 0.5) / (double)h);
        for (uint32_t x = 0; x < w; x++) {
            double m = 0.0;
            for (int j = 0; j < 3; j++)
                for (int i = 0; i < 3; i++)
                    m += k3[j] * k3[i] * lum_at(e, (int64_t)x + i - 1, (int64_t)y + j - 1);
            wgt[(size_t)y * w + x] = m;
            lum_sphere += m * s;
        }
    }
    e->mean_lum = lum_sphere * (2.0 * PI_D / w) * (PI_D / h) / (4.0 * PI_D);
    /* The compensated weights (Karlik, Sik, Vevoda, Skrivan, Krivanek 2019,
     * "MIS Compensation: Optimizing Sampling Techniques in Multiple
     * Importance Sampling", SIGGRAPH Asia): max(0, mean luminance - the
     * sphere's mean) x sin(theta). Where the map is no brighter than its
     * mean, BSDF sampling, which MIS weighs fully there, finds it better;
     * NEE's samples go to the bright parts. A map with nothing above its
     * mean (a uniform one) keeps the full weights. */
    double *cw = pt_malloc_array(n, sizeof *cw);
    int ok = cw != NULL;
    double comp_total = 0.0;
    for (uint32_t y = 0; ok && y < h; y++) {
        double s = sin(PI_D * ((double)y + 0.5) / (double)h);
        for (uint32_t x = 0; x < w; x++) {
            size_t i = (size_t)y * w + x;
            double c = wgt[i] - e->mean_lum;
            cw[i] = c > 0.0 ? c * s : 0.0;
            comp_total += cw[i];
            wgt[i] *= s;
        }
    }
    /* A compensated share under 1e-6 of the map is left to the full one:
     * rounding, not light. */
    if (ok && !(comp_total > 1e-6 * e->mean_lum * (double)n))
        memcpy(cw, wgt, n * sizeof *cw);
    ok = ok && dist_build(&e->full, wgt, w, h) && dist_build(&e->comp, cw, w, h);
    pt_free(wgt);
    pt_free(cw);
    if (!ok) {
        pt_env_free(e);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a %ux%u environment", w, h);
    }
    *out = e;
    return PT_OK;
}

pt_status pt_env_load(const char *path, float strength, float rotate_deg, pt_env **out,
                      pt_error *err)
{
    pt_envmap map;
    pt_status st = pt_envmap_read(path, &map, err);
    if (st != PT_OK)
        return st;
    st = pt_env_new(&map, strength, rotate_deg, out, err);
    pt_envmap_free(&map);
    return st;
}

pt_status pt_env_uniform(pt_vec3 color, pt_env **out, pt_error *err)
{
    if (!pt_isfinite3(color) || !(color.x >= 0.0f) || !(color.y >= 0.0f) || !(color.z >= 0.0f))
        return pt_error_set(err, PT_ERR_ARG, "background colour is not finite and >= 0");
    enum { W = 64, H = 32 };
    float local[W * H * 3];
    for (int i = 0; i < W * H; i++) {
        local[3 * i] = color.x;
        local[3 * i + 1] = color.y;
        local[3 * i + 2] = color.z;
    }
    pt_envmap m = {W, H, local};
    return pt_env_new(&m, 1.0f, 0.0f, out, err);
}

/* The index i with cdf[i] <= x < cdf[i + 1] among n intervals (cdf[0] = 0,
 * cdf[n] = 1); skips empty intervals. */
static uint32_t find_interval(const double *cdf, uint32_t n, double x)
{
    uint32_t lo = 0, hi = n - 1;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (x < cdf[mid + 1])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

/* (u, v) in [0,1)^2 of a unit direction. */
static void dir_to_uv(const pt_env *e, pt_vec3 d, float *u, float *v)
{
    float cy = d.y < -1.0f ? -1.0f : d.y > 1.0f ? 1.0f : d.y;
    float phi = atan2f(d.x, -d.z); /* (-pi, pi], 0 at -Z */
    float uu = 0.5f + phi / (2.0f * PI_F) + e->rot;
    uu -= floorf(uu);
    if (!(uu < 1.0f))
        uu = 0.0f;
    float vv = acosf(cy) / PI_F;
    *u = uu;
    *v = vv < 1.0f ? vv : nextafterf(1.0f, 0.0f);
}

static size_t texel_of(const pt_env *e, float u, float v)
{
    uint32_t x = (uint32_t)(u * (float)e->w), y = (uint32_t)(v * (float)e->h);
    if (x >= e->w)
        x = e->w - 1;
    if (y >= e->h)
        y = e->h - 1;
    return (size_t)y * e->w + x;
}

/* The bilinear lookup at (u, v) in [0,1]^2: texel centres at ((x + 0.5) / w,
 * (y + 0.5) / h), u wrapping around the sphere, v clamped at the poles. */
static pt_vec3 lookup(const pt_env *e, float u, float v)
{
    float fx = u * (float)e->w - 0.5f, fy = v * (float)e->h - 0.5f;
    float x0f = floorf(fx), y0f = floorf(fy);
    float ax = fx - x0f, ay = fy - y0f;
    int64_t w = e->w, h = e->h;
    int64_t x0 = (int64_t)x0f, y0 = (int64_t)y0f;
    int64_t xs[2] = {((x0 % w) + w) % w, (((x0 + 1) % w) + w) % w};
    int64_t ys[2] = {y0 < 0 ? 0 : (y0 >= h ? h - 1 : y0),
                     y0 + 1 >= h ? h - 1 : (y0 + 1 < 0 ? 0 : y0 + 1)};
    float k[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    float r = 0.0f, g = 0.0f, b = 0.0f;
    for (int i = 0; i < 4; i++) {
        const float *c = &e->rgb[3 * ((size_t)ys[i >> 1] * e->w + (size_t)xs[i & 1])];
        r += k[i] * c[0];
        g += k[i] * c[1];
        b += k[i] * c[2];
    }
    return pt_v3(r, g, b);
}

pt_vec3 pt_env_eval(const pt_env *env, pt_vec3 dir)
{
    float u, v;
    dir_to_uv(env, dir, &u, &v);
    return lookup(env, u, v);
}

static const env_dist *dist_of(const pt_env *env, int which)
{
    return which == PT_ENV_MIS ? &env->comp : &env->full;
}

float pt_env_pdf(const pt_env *env, pt_vec3 dir, int which)
{
    const env_dist *d = dist_of(env, which);
    if (d->black)
        return 0.0f;
    float u, v;
    dir_to_uv(env, dir, &u, &v);
    float s = sinf(PI_F * v);
    if (!(s > 0.0f))
        return 0.0f;
    return d->texel_pdf[texel_of(env, u, v)] / (2.0f * PI_F * PI_F * s);
}

int pt_env_sample(const pt_env *env, const float u[2], int which, pt_vec3 *dir, pt_vec3 *radiance,
                  float *pdf)
{
    const env_dist *d = dist_of(env, which);
    *pdf = 0.0f;
    if (d->black)
        return 0;
    /* The row by the marginal, then the column in it; each number's
     * remainder places the point inside the texel. */
    double rv = u[1];
    uint32_t y = find_interval(d->row_cdf, env->h, rv);
    double r0 = d->row_cdf[y], r1 = d->row_cdf[y + 1];
    double fy = r1 > r0 ? (rv - r0) / (r1 - r0) : 0.5;
    const double *cdf = d->col_cdf + (size_t)y * (env->w + 1);
    double ru = u[0];
    uint32_t x = find_interval(cdf, env->w, ru);
    double c0 = cdf[x], c1 = cdf[x + 1];
    double fx = c1 > c0 ? (ru - c0) / (c1 - c0) : 0.5;
    float tp = d->texel_pdf[(size_t)y * env->w + x];
    if (!(tp > 0.0f))
        return 0;
    double uu = ((double)x + fx) / env->w, vv = ((double)y + fy) / env->h;
    double theta = PI_D * vv, phi = 2.0 * PI_D * (uu - 0.5 - (double)env->rot);
    double st = sin(theta);
    if (!(st > 0.0))
        return 0;
    *dir = pt_v3((float)(st * sin(phi)), (float)cos(theta), (float)(-st * cos(phi)));
    /* The radiance the direction's own lookup gives, as a BSDF-sampled ray
     * along it would see. */
    *radiance = pt_env_eval(env, *dir);
    *pdf = (float)(tp / (2.0 * PI_D * PI_D * st));
    return isfinite(*pdf) && *pdf > 0.0f;
}

double pt_env_mean_luminance(const pt_env *env)
{
    return env->mean_lum;
}
