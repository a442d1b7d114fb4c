#include "common/render/env.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"

#define PI_F 3.14159265358979323846f
#define PI_D 3.14159265358979323846

struct pt_env {
    uint32_t w, h;
    float *rgb;       /* w * h * 3, strength applied */
    double *row_cdf;  /* h + 1: the marginal over rows, 0 .. 1 */
    double *col_cdf;  /* h * (w + 1): per row, 0 .. 1 (uniform for a black row) */
    float *texel_pdf; /* w * h: the density over [0,1)^2 of each texel's rectangle */
    float rot;        /* rotate_deg in turns, in [0, 1) */
    double mean_lum;  /* over the sphere */
    int black;        /* nothing to sample */
};

void pt_env_free(pt_env *env)
{
    if (!env)
        return;
    pt_free(env->rgb);
    pt_free(env->row_cdf);
    pt_free(env->col_cdf);
    pt_free(env->texel_pdf);
    pt_free(env);
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
    e->row_cdf = pt_malloc_array((size_t)h + 1, sizeof *e->row_cdf);
    e->col_cdf = pt_malloc_array((size_t)h * (w + 1), sizeof *e->col_cdf);
    e->texel_pdf = pt_malloc_array(n, sizeof *e->texel_pdf);
    if (!e->rgb || !e->row_cdf || !e->col_cdf || !e->texel_pdf) {
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
            pt_env_free(e);
            return pt_error_set(err, PT_ERR_ARG,
                                "environment strength %g makes a texel overflow a float",
                                (double)strength);
        }
    }
    /* Weights lum x sin(theta at the row's centre); sums in double. */
    double total = 0.0, lum_sphere = 0.0;
    e->row_cdf[0] = 0.0;
    for (uint32_t y = 0; y < h; y++) {
        double s = sin(PI_D * ((double)y + 0.5) / (double)h);
        double *cdf = e->col_cdf + (size_t)y * (w + 1);
        cdf[0] = 0.0;
        for (uint32_t x = 0; x < w; x++) {
            const float *c = &e->rgb[3 * ((size_t)y * w + x)];
            double lum = pt_luminance(pt_v3(c[0], c[1], c[2]));
            cdf[x + 1] = cdf[x] + lum * s;
        }
        double row = cdf[w];
        lum_sphere += row;
        for (uint32_t x = 1; x <= w; x++)
            cdf[x] = row > 0.0 ? cdf[x] / row : (double)x / (double)w;
        cdf[w] = 1.0;
        total += row;
        e->row_cdf[y + 1] = total;
    }
    /* Solid angle of texel (x, y): (2 pi / w) (pi / h) sin(theta). */
    e->mean_lum = lum_sphere * (2.0 * PI_D / w) * (PI_D / h) / (4.0 * PI_D);
    e->black = !(total > 0.0) || !isfinite(total);
    for (uint32_t y = 0; y < h; y++) {
        double s = sin(PI_D * ((double)y + 0.5) / (double)h);
        for (uint32_t x = 0; x < w; x++) {
            const float *c = &e->rgb[3 * ((size_t)y * w + x)];
            double wgt = pt_luminance(pt_v3(c[0], c[1], c[2])) * s;
            e->texel_pdf[(size_t)y * w + x] = e->black ? 0.0f : (float)(wgt / total * (double)n);
        }
        if (!e->black)
            e->row_cdf[y + 1] /= total;
    }
    e->row_cdf[h] = 1.0;
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

pt_vec3 pt_env_eval(const pt_env *env, pt_vec3 dir)
{
    float u, v;
    dir_to_uv(env, dir, &u, &v);
    const float *c = &env->rgb[3 * texel_of(env, u, v)];
    return pt_v3(c[0], c[1], c[2]);
}

float pt_env_pdf(const pt_env *env, pt_vec3 dir)
{
    if (env->black)
        return 0.0f;
    float u, v;
    dir_to_uv(env, dir, &u, &v);
    float s = sinf(PI_F * v);
    if (!(s > 0.0f))
        return 0.0f;
    return env->texel_pdf[texel_of(env, u, v)] / (2.0f * PI_F * PI_F * s);
}

int pt_env_sample(const pt_env *env, const float u[2], pt_vec3 *dir, pt_vec3 *radiance, float *pdf)
{
    *pdf = 0.0f;
    if (env->black)
        return 0;
    /* The row by the marginal, then the column in it; each number's
     * remainder places the point inside the texel. */
    double rv = u[1];
    uint32_t y = find_interval(env->row_cdf, env->h, rv);
    double r0 = env->row_cdf[y], r1 = env->row_cdf[y + 1];
    double fy = r1 > r0 ? (rv - r0) / (r1 - r0) : 0.5;
    const double *cdf = env->col_cdf + (size_t)y * (env->w + 1);
    double ru = u[0];
    uint32_t x = find_interval(cdf, env->w, ru);
    double c0 = cdf[x], c1 = cdf[x + 1];
    double fx = c1 > c0 ? (ru - c0) / (c1 - c0) : 0.5;
    float tp = env->texel_pdf[(size_t)y * env->w + x];
    if (!(tp > 0.0f))
        return 0;
    double uu = ((double)x + fx) / env->w, vv = ((double)y + fy) / env->h;
    double theta = PI_D * vv, phi = 2.0 * PI_D * (uu - 0.5 - (double)env->rot);
    double st = sin(theta);
    if (!(st > 0.0))
        return 0;
    *dir = pt_v3((float)(st * sin(phi)), (float)cos(theta), (float)(-st * cos(phi)));
    const float *c = &env->rgb[3 * ((size_t)y * env->w + x)];
    *radiance = pt_v3(c[0], c[1], c[2]);
    *pdf = (float)(tp / (2.0 * PI_D * PI_D * st));
    return isfinite(*pdf) && *pdf > 0.0f;
}

double pt_env_mean_luminance(const pt_env *env)
{
    return env->mean_lum;
}
