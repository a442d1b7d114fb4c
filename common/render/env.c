#include "common/render/env.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"

#define PI_F 3.14159265358979323846f
#define PI_D 3.14159265358979323846

/* A distribution over the map (env.h) whose density in (u, v) is, in each
 * cell between four texel centres, the bilinear interpolant of a value per
 * texel (`corner`), times sin(theta) at the cell's centre row. The cells:
 * column x spans texel centres x and x + 1 (wrapping), row r (0 .. h) texel
 * rows r - 1 and r, clamped: rows 0 and h are the half-height cells at the
 * poles, where the lookup is constant in v. */
/* Buckets of the cut-point tables (Chen & Asau 1974, "On Generating Random
 * Variates from an Empirical Distribution"): the marginal's and each row's. */
#define ROW_CUTS 256u
#define COL_CUTS 64u

typedef struct env_dist {
    double *row_cdf; /* h + 2: the marginal over cell rows, 0 .. 1 */
    double *col_cdf; /* (h + 1) * (w + 1): per cell row, 0 .. 1 (uniform for a black row) */
    /* Cut points: the interval a number in [j / M, (j + 1) / M) falls in
     * lies between entries j and j + 1 (find_cut): ROW_CUTS + 1 of the
     * marginal's, COL_CUTS + 1 per cell row of the rows'. */
    uint32_t *row_cut, *col_cut;
    float *corner; /* w * h: the value per texel the density interpolates (the
                      compensated one's: NULL once built, then only in px) */
    /* The corners as sampling and pdfs read them: corner (stride 1), or
     * beside each texel's colour (pt_env.px, stride 4). */
    const float *cv;
    uint32_t cs;
    float *row_sin; /* h + 1: sin(theta) at each cell row's centre */
    double norm;    /* w * h / the cells' total weight: pdf(u, v) = norm sin f(u, v) */
    double total;   /* the cells' total weight */
    int black;      /* nothing to sample */
} env_dist;

struct pt_env {
    uint32_t w, h;
    /* w * h texels of 4 floats: the colour (strength applied) and the
     * compensated distribution's corner, which NEE's samples and the pdf of
     * a ray that leaves the scene read with the colour: one line for both. */
    float *px;
    env_dist full;   /* corners: the texel's luminance */
    env_dist comp;   /* the same less the sphere's mean (MIS compensation) */
    float rot;       /* rotate_deg in turns, in [0, 1) */
    double mean_lum; /* over the sphere */
    /* The split (env.h): the sun's texels' support lies within the cone
     * about sun_axis whose half-angle's sine is -sun_lim; a receiver with
     * n . sun_axis <= sun_lim sees none of it and samples full_rest or
     * comp_rest, the distributions with the sun's texels at 0. */
    int split;      /* PT_ENV_FULL's */
    int split_comp; /* PT_ENV_MIS's: the compensated rest lies away from the sun */
    pt_vec3 sun_axis;
    float sun_lim;
    env_dist full_rest, comp_rest;
};

static void dist_free(env_dist *d)
{
    pt_free(d->row_cdf);
    pt_free(d->col_cdf);
    pt_free(d->row_cut);
    pt_free(d->col_cut);
    pt_free(d->corner);
    pt_free(d->row_sin);
}

void pt_env_free(pt_env *env)
{
    if (!env)
        return;
    pt_free(env->px);
    dist_free(&env->full);
    dist_free(&env->comp);
    dist_free(&env->full_rest);
    dist_free(&env->comp_rest);
    pt_free(env);
}

/* The direction v of cell row r's centre (rows 0 and h: the half-height
 * cells at the poles). */
static inline double cell_row_v(uint32_t r, uint32_t h)
{
    return r == 0 ? 0.25 / h : (r == h ? 1.0 - 0.25 / h : (double)r / h);
}

/* The corners of d's interpolant in cell (x, r): k[0], k[1] on texel row
 * r - 1 at columns x, x + 1 (wrapping), k[2], k[3] on row r (rows clamped). */
static inline void cell_corners(const float *corner, uint32_t stride, uint32_t w, uint32_t h,
                                uint32_t x, uint32_t r, float k[4])
{
    uint32_t y0 = r == 0 ? 0 : r - 1, y1 = r >= h ? h - 1 : r, x1 = x + 1 == w ? 0 : x + 1;
    const float *c0 = corner + (size_t)y0 * w * stride, *c1 = corner + (size_t)y1 * w * stride;
    k[0] = c0[(size_t)x * stride];
    k[1] = c0[(size_t)x1 * stride];
    k[2] = c1[(size_t)x * stride];
    k[3] = c1[(size_t)x1 * stride];
}

/* The index i in [lo, hi] with cdf[i] <= x < cdf[i + 1] (hi when none),
 * skipping empty intervals; find_interval over all n intervals (cdf[0] = 0,
 * cdf[n] = 1). */
static inline uint32_t search_interval(const double *cdf, uint32_t lo, uint32_t hi, double x)
{
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (x < cdf[mid + 1])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

static uint32_t find_interval(const double *cdf, uint32_t n, double x)
{
    return search_interval(cdf, 0, n - 1, x);
}

/* cut[0 .. m]: the interval (find_interval over cdf's n) of j / m for each
 * j, and n - 1 at m. */
static void cuts_build(const double *cdf, uint32_t n, uint32_t *cut, uint32_t m)
{
    for (uint32_t j = 0; j < m; j++)
        cut[j] = find_interval(cdf, n, (double)j / (double)m);
    cut[m] = n - 1;
}

/* find_interval(cdf, n, x) for x in [0, 1), by cuts_build's cut over m
 * buckets: the interval is monotone in x, so x's lies between its bucket's
 * two cut points, and the search there gives the same index in a step or
 * two where the whole array's took log2 n dependent loads. */
static inline uint32_t find_cut(const double *cdf, const uint32_t *cut, uint32_t m, double x)
{
    double s = x * (double)m;
    uint32_t j = s > 0.0 ? (s < (double)m ? (uint32_t)s : m - 1) : 0;
    return search_interval(cdf, cut[j], cut[j + 1], x);
}

/* The distribution whose density interpolates corner (>= 0, w * h,
 * row-major; kept); sums in double. A cell's weight is the integral of its
 * interpolant, the mean of its four corners times its height (1/2 at the
 * poles), times sin(theta) at its centre row. Returns 0 when out of memory. */
static int dist_build(env_dist *d, float *corner, uint32_t w, uint32_t h)
{
    d->corner = corner;
    d->cv = corner;
    d->cs = 1;
    d->row_cdf = pt_malloc_array((size_t)h + 2, sizeof *d->row_cdf);
    d->col_cdf = pt_malloc_array((size_t)(h + 1) * (w + 1), sizeof *d->col_cdf);
    d->row_sin = pt_malloc_array((size_t)h + 1, sizeof *d->row_sin);
    d->row_cut = pt_malloc_array(ROW_CUTS + 1, sizeof *d->row_cut);
    d->col_cut = pt_malloc_array((size_t)(h + 1) * (COL_CUTS + 1), sizeof *d->col_cut);
    if (!d->corner || !d->row_cdf || !d->col_cdf || !d->row_sin || !d->row_cut || !d->col_cut)
        return 0;
    double total = 0.0;
    d->row_cdf[0] = 0.0;
    for (uint32_t r = 0; r <= h; r++) {
        double height = r == 0 || r == h ? 0.5 : 1.0;
        d->row_sin[r] = (float)sin(PI_D * cell_row_v(r, h));
        double k = 0.25 * height * (double)d->row_sin[r];
        double *cdf = d->col_cdf + (size_t)r * (w + 1);
        cdf[0] = 0.0;
        for (uint32_t x = 0; x < w; x++) {
            float c[4];
            cell_corners(corner, 1, w, h, x, r, c);
            double m = (double)c[0] + c[1] + c[2] + c[3];
            cdf[x + 1] = cdf[x] + k * m;
        }
        double row = cdf[w];
        for (uint32_t x = 1; x <= w; x++)
            cdf[x] = row > 0.0 ? cdf[x] / row : (double)x / (double)w;
        cdf[w] = 1.0;
        total += row;
        d->row_cdf[r + 1] = total;
    }
    d->black = !(total > 0.0) || !isfinite(total);
    d->total = d->black ? 0.0 : total;
    d->norm = d->black ? 0.0 : (double)w * h / total;
    for (uint32_t r = 0; r <= h && !d->black; r++)
        d->row_cdf[r + 1] /= total;
    d->row_cdf[h + 1] = 1.0;
    cuts_build(d->row_cdf, h + 1, d->row_cut, ROW_CUTS);
    for (uint32_t r = 0; r <= h; r++)
        cuts_build(d->col_cdf + (size_t)r * (w + 1), w, d->col_cut + (size_t)r * (COL_CUTS + 1),
                   COL_CUTS);
    return 1;
}

/* Column x wrapped into [0, w): one step either way without a division
 * (what a lookup at u in [0, 1] needs), any x with one. */
static inline int64_t wrap_x(int64_t x, int64_t w)
{
    if (x < 0)
        x += w;
    else if (x >= w)
        x -= w;
    if (x < 0 || x >= w)
        x = ((x % w) + w) % w;
    return x;
}

/* Texel (x, y)'s luminance; x wraps, y is clamped (the bilinear lookup's
 * neighbours, pt_env_eval). */
static double lum_at(const pt_env *e, int64_t x, int64_t y)
{
    int64_t w = e->w, h = e->h;
    x = ((x % w) + w) % w;
    y = y < 0 ? 0 : (y >= h ? h - 1 : y);
    const float *c = &e->px[4 * ((size_t)y * e->w + (size_t)x)];
    return pt_luminance(pt_v3(c[0], c[1], c[2]));
}

/* Direction of map point (u, v) (env.h's orientation). */
static pt_vec3 uv_dir(const pt_env *e, double u, double v)
{
    double theta = PI_D * v, phi = 2.0 * PI_D * (u - 0.5 - (double)e->rot);
    double st = sin(theta);
    return pt_v3((float)(st * sin(phi)), (float)cos(theta), (float)(-st * cos(phi)));
}

/* The split's rule (env.h): a sun texel is one brighter than SUN_LUM times
 * the sphere's mean luminance; the map splits when those texels' support
 * fits in a cone of half-angle SUN_MAX_HALF and they hold SUN_SHARE or more
 * of the full distribution's weight. */
#define SUN_LUM 16.0
#define SUN_MAX_HALF 0.5 /* radians, about 29 degrees */
#define SUN_SHARE 0.2
#define COMP_AWAY 0.5

/* The share of d's weight in the cells whose centre's direction is on the
 * far side of the plane through the centre normal to axis. */
static double share_away(const pt_env *e, const env_dist *d, pt_vec3 axis)
{
    uint32_t w = e->w, h = e->h;
    double away = 0.0;
    for (uint32_t r = 0; r <= h; r++) {
        double v = cell_row_v(r, h);
        double pr = d->row_cdf[r + 1] - d->row_cdf[r];
        const double *cdf = d->col_cdf + (size_t)r * (w + 1);
        if (!(pr > 0.0))
            continue;
        for (uint32_t x = 0; x < w; x++) {
            pt_vec3 dir = uv_dir(e, ((double)x + 1.0) / w, v);
            if (pt_v3_dot(dir, axis) < 0.0f)
                away += pr * (cdf[x + 1] - cdf[x]);
        }
    }
    return away;
}

/* Splits e's map into the sun and the rest (env.h) when the rule above
 * says so; e->full and e->comp are built. Returns 0 when out of memory. */
static int split_build(pt_env *e)
{
    uint32_t w = e->w, h = e->h;
    size_t n = (size_t)w * h;
    const float *fc = e->full.corner;
    double thr = SUN_LUM * e->mean_lum, ax = 0.0, ay = 0.0, az = 0.0;
    size_t count = 0;
    if (e->full.black || !(thr > 0.0))
        return 1;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            double l = fc[(size_t)y * w + x];
            if (!(l > thr))
                continue;
            double v = ((double)y + 0.5) / h;
            pt_vec3 d = uv_dir(e, ((double)x + 0.5) / w, v);
            double k = l * sin(PI_D * v);
            ax += k * d.x;
            ay += k * d.y;
            az += k * d.z;
            count++;
        }
    double len = sqrt(ax * ax + ay * ay + az * az);
    if (count == 0 || count > n / 8 || !(len > 0.0) || !isfinite(len))
        return 1;
    pt_vec3 axis = pt_v3((float)(ax / len), (float)(ay / len), (float)(az / len));
    /* The cone: the widest angle from the axis to a sun texel's centre,
     * plus the reach of its support (the cells it is a corner of, one texel
     * centre on every side): at most pi / h in theta and 2 pi / w in phi,
     * an arc of sin(theta) 2 pi / w <= 2 pi / w along a parallel, so by the
     * triangle inequality 2 pi / w + pi / h in all; 1e-3 more for the
     * float directions and normals. */
    double widest = 0.0;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            if (!((double)fc[(size_t)y * w + x] > thr))
                continue;
            pt_vec3 d = uv_dir(e, ((double)x + 0.5) / w, ((double)y + 0.5) / h);
            double c = (double)d.x * axis.x + (double)d.y * axis.y + (double)d.z * axis.z;
            double a = acos(c < -1.0 ? -1.0 : (c > 1.0 ? 1.0 : c));
            widest = a > widest ? a : widest;
        }
    double half = widest + 2.0 * PI_D / w + PI_D / h + 1e-3;
    if (!(half <= SUN_MAX_HALF))
        return 1;
    float *fr = pt_malloc_array(n, sizeof *fr);
    if (!fr)
        return 0;
    for (size_t i = 0; i < n; i++)
        fr[i] = (double)fc[i] > thr ? 0.0f : fc[i];
    if (!dist_build(&e->full_rest, fr, w, h))
        return 0;
    double rest_share = e->full_rest.total / e->full.total;
    if (!(rest_share <= 1.0 - SUN_SHARE)) {
        dist_free(&e->full_rest);
        memset(&e->full_rest, 0, sizeof e->full_rest);
        return 1;
    }
    /* The rest's own MIS compensation: its luminance less its own mean
     * over the sphere (the sun's share of the mean taken out), 0 where
     * negative; where that leaves nothing, the rest's full corners. */
    double rest_mean = e->mean_lum * rest_share, comp_total = 0.0;
    float *cr = pt_malloc_array(n, sizeof *cr);
    if (!cr)
        return 0;
    for (size_t i = 0; i < n; i++) {
        double k = (double)fr[i] - rest_mean;
        cr[i] = k > 0.0 ? (float)k : 0.0f;
        comp_total += cr[i];
    }
    if (!(comp_total > 1e-6 * rest_mean * (double)n))
        memcpy(cr, fr, n * sizeof *cr);
    if (!dist_build(&e->comp_rest, cr, w, h))
        return 0;
    /* Under MIS a receiver that hides the sun samples the compensated
     * rest, whose every sample above its tangent plane costs a shadow ray
     * that BSDF sampling, which MIS weighs fully where the map is no
     * brighter than its mean, mostly did not need; where that rest lies
     * mostly on the sun's side of the sky (the park map's sunlit haze and
     * ground: 85 % for a receiver facing straight away from the sun), the
     * receiver sees little of it and the split costs more shadow rays than
     * it saves variance (docs/bench/helmet_park.md). The compensated rest
     * splits only when half its weight or more lies away from the sun. */
    e->split_comp = !e->comp_rest.black && share_away(e, &e->comp_rest, axis) >= COMP_AWAY;
    if (!e->split_comp) {
        dist_free(&e->comp_rest);
        memset(&e->comp_rest, 0, sizeof e->comp_rest);
    }
    e->split = 1;
    e->sun_axis = axis;
    e->sun_lim = -(float)sin(half);
    return 1;
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
    e->px = pt_malloc_array(n * 4, sizeof *e->px);
    if (!e->px) {
        pt_env_free(e);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a %ux%u environment", w, h);
    }
    double turns = fmod((double)rotate_deg / 360.0, 1.0);
    e->rot = (float)(turns < 0.0 ? turns + 1.0 : turns);
    if (e->rot >= 1.0f)
        e->rot = 0.0f;
    for (size_t i = 0; i < n * 3; i++) {
        float c = e->px[4 * (i / 3) + i % 3] = map->rgb[i] * strength;
        if (!isfinite(c) || c < 0.0f) {
            pt_env_free(e);
            return pt_error_set(err, PT_ERR_ARG,
                                "environment strength %g makes a texel overflow a float",
                                (double)strength);
        }
    }
    /* The mean luminance over the sphere: the integral of the bilinear
     * interpolant over a texel's rectangle weighs the 3 x 3 texels around it
     * by (1/8, 3/4, 1/8) in each direction; times the texel's solid angle,
     * (2 pi / w) (pi / h) sin(theta at its centre). */
    static const double k3[3] = {0.125, 0.75, 0.125};
    double lum_sphere = 0.0;
    for (uint32_t y = 0; y < h; y++) {
        double s = sin(PI_D * ((double)y + 0.5) / (double)h);
        for (uint32_t x = 0; x < w; x++) {
            double m = 0.0;
            for (int j = 0; j < 3; j++)
                for (int i = 0; i < 3; i++)
                    m += k3[j] * k3[i] * lum_at(e, (int64_t)x + i - 1, (int64_t)y + j - 1);
            lum_sphere += m * s;
        }
    }
    e->mean_lum = lum_sphere * (2.0 * PI_D / w) * (PI_D / h) / (4.0 * PI_D);
    /* The full distribution interpolates each texel's luminance as the
     * lookup interpolates its colour: within a cell its density is the
     * lookup's luminance (times sin(theta) at the cell's centre row, not at
     * the point), so a light sample's luminance over its pdf is the same
     * wherever it lands but for that ratio of sines. A sun of a few texels
     * spreads over their neighbours' cells, whose lookup falls to a small
     * fraction of the sun across each; a distribution constant over each
     * texel (the lookup's mean there) gave samples on the side nearer the
     * sun up to four times their share. The compensated corners (Karlik,
     * Sik, Vevoda, Skrivan, Krivanek 2019, "MIS Compensation: Optimizing
     * Sampling Techniques in Multiple Importance Sampling", SIGGRAPH Asia)
     * are the texel's luminance less the sphere's mean, 0 where that is
     * negative: where the map is no brighter than its mean, BSDF sampling,
     * which MIS weighs fully there, finds it better; NEE's samples go to the
     * bright parts. A map with nothing above its mean (a uniform one) keeps
     * the full corners. */
    float *fc = pt_malloc_array(n, sizeof *fc), *cc = pt_malloc_array(n, sizeof *cc);
    int ok = fc && cc;
    double comp_total = 0.0;
    for (size_t i = 0; ok && i < n; i++) {
        const float *c = &e->px[4 * i];
        double l = pt_luminance(pt_v3(c[0], c[1], c[2]));
        double k = l - e->mean_lum;
        fc[i] = (float)l;
        cc[i] = k > 0.0 ? (float)k : 0.0f;
        comp_total += cc[i];
    }
    /* A compensated share under 1e-6 of the map is left to the full one:
     * rounding, not light. */
    if (ok && !(comp_total > 1e-6 * e->mean_lum * (double)n))
        memcpy(cc, fc, n * sizeof *cc);
    ok = ok && dist_build(&e->full, fc, w, h);
    if (!e->full.corner)
        pt_free(fc);
    ok = ok && dist_build(&e->comp, cc, w, h);
    if (!e->comp.corner)
        pt_free(cc);
    if (ok) {
        /* Built: its corners are read beside the colours from now on, and
         * its own array is not kept twice. */
        for (size_t i = 0; i < n; i++)
            e->px[4 * i + 3] = cc[i];
        e->comp.cv = e->px + 3;
        e->comp.cs = 4;
        pt_free(e->comp.corner);
        e->comp.corner = NULL;
    }
    ok = ok && split_build(e);
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

/* The cell of d under (u, v) and where in it: column x (texel centres x
 * and x + 1, wrapping), row r (texel rows r - 1 and r, clamped), s and t in
 * [0, 1] from the first centre to the second. */
static void cell_of(const pt_env *e, float u, float v, uint32_t *x, uint32_t *r, float *s, float *t)
{
    float fx = u * (float)e->w - 0.5f, fy = v * (float)e->h - 0.5f;
    float x0 = floorf(fx), y0 = floorf(fy);
    *s = fx - x0;
    *t = fy - y0;
    int64_t xi = (int64_t)x0, w = e->w;
    *x = (uint32_t)wrap_x(xi, w);
    int64_t ri = (int64_t)y0 + 1;
    *r = (uint32_t)(ri < 0 ? 0 : (ri > (int64_t)e->h ? (int64_t)e->h : ri));
}

/* The interpolant of d's corners in cell (x, r) at (s, t). */
static float cell_value(const env_dist *d, const pt_env *e, uint32_t x, uint32_t r, float s,
                        float t)
{
    float k[4];
    cell_corners(d->cv, d->cs, e->w, e->h, x, r, k);
    return (1.0f - t) * ((1.0f - s) * k[0] + s * k[1]) + t * ((1.0f - s) * k[2] + s * k[3]);
}

/* A sample of the density on [0, 1] that is linear from p0 at 0 to p1 at 1
 * (both >= 0, not both 0) by inverting its distribution function with uniform
 * xi, in the form that stays accurate where p0 and p1 are close (Pharr,
 * Jakob & Humphreys, "Physically Based Rendering", 4th ed., A.4.2). */
static double sample_linear(double xi, double p0, double p1)
{
    if (p0 == p1 || xi <= 0.0)
        return xi;
    double x = xi * (p0 + p1) / (p0 + sqrt((1.0 - xi) * p0 * p0 + xi * p1 * p1));
    return x < 1.0 ? x : nextafter(1.0, 0.0);
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
    int64_t xs[2] = {wrap_x(x0, w), wrap_x(x0 + 1, w)};
    int64_t ys[2] = {y0 < 0 ? 0 : (y0 >= h ? h - 1 : y0),
                     y0 + 1 >= h ? h - 1 : (y0 + 1 < 0 ? 0 : y0 + 1)};
    float k[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    float r = 0.0f, g = 0.0f, b = 0.0f;
    for (int i = 0; i < 4; i++) {
        const float *c = &e->px[4 * ((size_t)ys[i >> 1] * e->w + (size_t)xs[i & 1])];
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

/* The distribution `which` for a receiver with normal n (env.h): the
 * rest's where the sun is wholly below n's tangent plane. */
static const env_dist *dist_of(const pt_env *env, int which, pt_vec3 n)
{
    if (which == PT_ENV_MIS)
        return env->split_comp && pt_v3_dot(n, env->sun_axis) <= env->sun_lim ? &env->comp_rest
                                                                              : &env->comp;
    return env->split && pt_v3_dot(n, env->sun_axis) <= env->sun_lim ? &env->full_rest : &env->full;
}

int pt_env_splits(const pt_env *env, int which)
{
    return which == PT_ENV_MIS ? env->split_comp : env->split;
}

int pt_env_sun(const pt_env *env, pt_vec3 *axis, float *sin_half)
{
    if (!env->split)
        return 0;
    *axis = env->sun_axis;
    *sin_half = -env->sun_lim;
    return 1;
}

float pt_env_pdf(const pt_env *env, pt_vec3 dir, int which, pt_vec3 n)
{
    const env_dist *d = dist_of(env, which, n);
    if (d->black)
        return 0.0f;
    float u, v;
    dir_to_uv(env, dir, &u, &v);
    float sn = sinf(PI_F * v);
    if (!(sn > 0.0f))
        return 0.0f;
    uint32_t x, r;
    float s, t;
    cell_of(env, u, v, &x, &r, &s, &t);
    float f = cell_value(d, env, x, r, s, t);
    return (float)(d->norm * (double)d->row_sin[r] * (double)f / (2.0 * PI_D * PI_D * sn));
}

int pt_env_sample(const pt_env *env, const float u[2], int which, pt_vec3 n, pt_vec3 *dir,
                  pt_vec3 *radiance, float *pdf)
{
    const env_dist *d = dist_of(env, which, n);
    *pdf = 0.0f;
    if (d->black)
        return 0;
    /* The cell row by the marginal, then the column in it; each number's
     * remainder places the point in the cell by the interpolant: t by its
     * mean over s (linear in t; uniform over the half of a pole's cell that
     * lies on the sphere, where it is constant in t), then s given t. */
    uint32_t w = env->w, h = env->h;
    double rv = u[1];
    uint32_t r = find_cut(d->row_cdf, d->row_cut, ROW_CUTS, rv);
    double r0 = d->row_cdf[r], r1 = d->row_cdf[r + 1];
    double fy = r1 > r0 ? (rv - r0) / (r1 - r0) : 0.5;
    const double *cdf = d->col_cdf + (size_t)r * (w + 1);
    double ru = u[0];
    uint32_t x = find_cut(cdf, d->col_cut + (size_t)r * (COL_CUTS + 1), COL_CUTS, ru);
    double c0 = cdf[x], c1 = cdf[x + 1];
    double fx = c1 > c0 ? (ru - c0) / (c1 - c0) : 0.5;
    float k[4];
    cell_corners(d->cv, d->cs, w, h, x, r, k);
    double a = k[0], b = k[1], c = k[2], e = k[3];
    double t;
    if (r == 0)
        t = 0.5 + 0.5 * fy;
    else if (r == h)
        t = 0.5 * fy;
    else
        t = sample_linear(fy, a + b, c + e);
    double p0 = (1.0 - t) * a + t * c, p1 = (1.0 - t) * b + t * e;
    if (!(p0 + p1 > 0.0))
        return 0;
    double s = sample_linear(fx, p0, p1);
    double uu = ((double)x + 0.5 + s) / w, vv = ((double)r - 0.5 + t) / h;
    if (uu >= 1.0)
        uu -= 1.0;
    double theta = PI_D * vv, phi = 2.0 * PI_D * (uu - 0.5 - (double)env->rot);
    double st = sin(theta);
    if (!(st > 0.0))
        return 0;
    *dir = pt_v3((float)(st * sin(phi)), (float)cos(theta), (float)(-st * cos(phi)));
    /* The lookup a BSDF-sampled ray along it reads (pt_env_eval), at the
     * sampled point itself rather than at the point the float direction
     * maps back to: the same function, without the arc tangent and cosine
     * of the way back, and where the pdf was taken. */
    *radiance = lookup(env, (float)uu, (float)vv);
    double f = (1.0 - s) * p0 + s * p1;
    *pdf = (float)(d->norm * (double)d->row_sin[r] * f / (2.0 * PI_D * PI_D * st));
    return isfinite(*pdf) && *pdf > 0.0f;
}

double pt_env_mean_luminance(const pt_env *env)
{
    return env->mean_lum;
}
