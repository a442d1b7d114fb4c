#include "common/render/passes.h"

#include <stdio.h>
#include <string.h>

static const struct {
    const char *name;
    uint32_t bit;
} pass_names[] = {
    {"albedo", PT_PASS_ALBEDO}, {"normal", PT_PASS_NORMAL},
    {"depth", PT_PASS_DEPTH},   {"emission", PT_PASS_EMISSION},
    {"halves", PT_PASS_HALVES}, {"cryptomatte", PT_PASS_CRYPTOMATTE},
};
#define NPASS (sizeof pass_names / sizeof pass_names[0])

pt_status pt_passes_parse(const char *opt, const char *text, uint32_t *mask, pt_error *err)
{
    uint32_t m = 0;
    size_t len = strlen(text);
    if (len == 0 || len > PT_PASSES_MAX_TEXT)
        goto bad;
    for (const char *p = text; *p;) {
        const char *end = strchr(p, ',');
        size_t n = end ? (size_t)(end - p) : strlen(p);
        uint32_t bit = 0;
        if (n == 3 && !strncmp(p, "all", 3))
            bit = PT_PASS_ALL;
        for (size_t k = 0; k < NPASS && !bit; k++)
            if (strlen(pass_names[k].name) == n && !strncmp(p, pass_names[k].name, n))
                bit = pass_names[k].bit;
        if (!bit)
            goto bad;
        m |= bit;
        if (!end)
            break;
        p = end + 1;
        if (!*p)
            goto bad; /* a trailing comma */
    }
    *mask = m;
    return PT_OK;
bad:
    return pt_error_set(err, PT_ERR_ARG,
                        "%s: '%.*s' is not a comma-separated list of albedo, normal, depth, "
                        "emission, halves, cryptomatte (or all)",
                        opt, (int)(len < 64 ? len : 64), text);
}

void pt_passes_text(uint32_t mask, char *out, size_t n)
{
    size_t used = 0;
    if (n == 0)
        return;
    out[0] = '\0';
    for (size_t k = 0; k < NPASS; k++) {
        if (!(mask & pass_names[k].bit))
            continue;
        int w = snprintf(out + used, n - used, "%s%s", used ? "," : "", pass_names[k].name);
        if (w < 0 || (size_t)w >= n - used)
            return;
        used += (size_t)w;
    }
}

/* Adds the plane name to img and sets *dst to it. */
static pt_status plane(pt_image *img, const char *name, float **dst, pt_error *err)
{
    return pt_image_add_plane(img, name, dst, err);
}

pt_status pt_passes_add_planes(pt_image *img, uint32_t mask, pt_pass_planes *pl, pt_error *err)
{
    static const char *const rgb[3] = {"R", "G", "B"}, *const xyz[3] = {"X", "Y", "Z"};
    memset(pl, 0, sizeof *pl);
    pt_status st = PT_OK;
    char name[PT_IMAGE_PLANE_NAME];
    for (int c = 0; c < 3 && st == PT_OK; c++) {
        if (mask & PT_PASS_ALBEDO) {
            snprintf(name, sizeof name, "albedo.%s", rgb[c]);
            st = plane(img, name, &pl->albedo[c], err);
        }
        if (st == PT_OK && (mask & PT_PASS_NORMAL)) {
            snprintf(name, sizeof name, "N.%s", xyz[c]);
            st = plane(img, name, &pl->normal[c], err);
        }
        if (st == PT_OK && (mask & PT_PASS_EMISSION)) {
            snprintf(name, sizeof name, "emission.%s", rgb[c]);
            st = plane(img, name, &pl->emission[c], err);
        }
        if (st == PT_OK && (mask & PT_PASS_HALVES)) {
            snprintf(name, sizeof name, "halfA.%s", rgb[c]);
            st = plane(img, name, &pl->half_a[c], err);
            snprintf(name, sizeof name, "halfB.%s", rgb[c]);
            if (st == PT_OK)
                st = plane(img, name, &pl->half_b[c], err);
        }
    }
    if (st == PT_OK && (mask & PT_PASS_ALBEDO))
        st = plane(img, "albedo.variance", &pl->albedo_var, err);
    if (st == PT_OK && (mask & PT_PASS_NORMAL))
        st = plane(img, "N.variance", &pl->normal_var, err);
    if (st == PT_OK && (mask & PT_PASS_EMISSION))
        st = plane(img, "emission.variance", &pl->emission_var, err);
    if (st == PT_OK && (mask & PT_PASS_DEPTH)) {
        st = plane(img, "depth.Z", &pl->depth, err);
        if (st == PT_OK)
            st = plane(img, "depth.variance", &pl->depth_var, err);
    }
    if (st == PT_OK && (mask & PT_PASS_CRYPTOMATTE)) {
        st = pt_crypto_add_planes(img, &pl->cm, err);
        pl->crypto = st == PT_OK;
    }
    return st;
}

/* The means of channels [k, k + nch) of p over n samples into dst[] (when
 * not NULL), and the variance of the mean averaged over the channels into
 * *var: (sum of squares - n sum of mean^2) / ((n - 1) n nch), clamped at 0
 * (the one-pass form cancels when the spread is tiny against the mean; it is
 * done in double, as the beauty's variance is). */
static void resolve_pass(const pt_pass_acc *p, int k, int q, int nch, double n, float *const *dst,
                         float *var, size_t i)
{
    double m2 = 0.0;
    for (int c = 0; c < nch; c++) {
        double m = pt_fixed_to_double(p->s[k + c]) / n;
        m2 += m * m;
        if (dst[c])
            dst[c][i] = (float)m;
    }
    if (!var)
        return;
    double v = 0.0;
    if (n >= 2.0) {
        v = (pt_ufixed_to_double(p->sq[q]) - n * m2) / ((n - 1.0) * n * nch);
        if (!(v > 0.0))
            v = 0.0;
    }
    var[i] = (float)v;
}

void pt_passes_resolve(const pt_pixel_acc *a, const pt_pass_acc *p, const pt_pass_planes *pl,
                       size_t i)
{
    if (a->n == 0) {
        float *const all[] = {pl->albedo[0],   pl->albedo[1],    pl->albedo[2],   pl->albedo_var,
                              pl->normal[0],   pl->normal[1],    pl->normal[2],   pl->normal_var,
                              pl->depth,       pl->depth_var,    pl->emission[0], pl->emission[1],
                              pl->emission[2], pl->emission_var, pl->half_a[0],   pl->half_a[1],
                              pl->half_a[2],   pl->half_b[0],    pl->half_b[1],   pl->half_b[2]};
        for (size_t k = 0; k < sizeof all / sizeof all[0]; k++)
            if (all[k])
                all[k][i] = 0.0f;
        if (pl->crypto)
            pt_crypto_resolve(p, 0, &pl->cm, i);
        return;
    }
    if (pl->crypto)
        pt_crypto_resolve(p, a->n, &pl->cm, i);
    double n = (double)a->n;
    resolve_pass(p, PT_PS_ALBEDO, PT_PQ_ALBEDO, 3, n, pl->albedo, pl->albedo_var, i);
    resolve_pass(p, PT_PS_NORMAL, PT_PQ_NORMAL, 3, n, pl->normal, pl->normal_var, i);
    resolve_pass(p, PT_PS_EMISSION, PT_PQ_EMISSION, 3, n, pl->emission, pl->emission_var, i);
    resolve_pass(p, PT_PS_DEPTH, PT_PQ_DEPTH, 1, n, &pl->depth, pl->depth_var, i);
    if (!pl->half_a[0])
        return;
    /* The odd half is the total less the even one: both exact integers. */
    uint32_t ne = p->n_even, no = a->n - p->n_even;
    for (int c = 0; c < 3; c++) {
        pt_i128 even = p->s[PT_PS_EVEN + c], odd = a->fsum[c] - even;
        pl->half_a[c][i] = ne ? (float)(pt_fixed_to_double(even) / ne) : 0.0f;
        pl->half_b[c][i] = no ? (float)(pt_fixed_to_double(odd) / no) : 0.0f;
    }
}
