#include "common/image/metrics.h"

#include <math.h>
#include <stddef.h>

/* One pass over img against either ref (when not NULL) or the constant c. */
static void compare(const pt_image *img, const pt_image *ref, double c, pt_metrics *m)
{
    const float *x[3] = {img->r, img->g, img->b};
    const float *r[3] = {NULL, NULL, NULL};
    if (ref) {
        r[0] = ref->r;
        r[1] = ref->g;
        r[2] = ref->b;
    }
    size_t n = (size_t)img->width * img->height;
    double se = 0.0, rel = 0.0;
    uint64_t compared = 0, bad = 0;
    for (size_t i = 0; i < n; i++)
        for (int ch = 0; ch < 3; ch++) {
            double xv = x[ch][i], rv = ref ? r[ch][i] : c;
            if (!isfinite(xv) || !isfinite(rv)) {
                bad++;
                continue;
            }
            double d = xv - rv;
            se += d * d;
            rel += d * d / (rv * rv + PT_METRICS_REL_EPS);
            compared++;
        }
    pt_metrics_mean(img, m->mean);
    m->compared = compared;
    m->nonfinite = bad;
    m->rmse = compared ? sqrt(se / (double)compared) : NAN;
    m->rel_mse = compared ? rel / (double)compared : NAN;
}

pt_status pt_metrics_compare(const pt_image *img, const pt_image *ref, pt_metrics *out,
                             pt_error *err)
{
    if (img->width != ref->width || img->height != ref->height)
        return pt_error_set(err, PT_ERR_ARG, "image is %ux%u but the reference is %ux%u",
                            img->width, img->height, ref->width, ref->height);
    pt_metrics m;
    compare(img, ref, 0.0, &m);
    *out = m;
    return PT_OK;
}

pt_status pt_metrics_compare_constant(const pt_image *img, double value, pt_metrics *out,
                                      pt_error *err)
{
    if (!isfinite(value))
        return pt_error_set(err, PT_ERR_ARG, "constant reference %g is not finite", value);
    pt_metrics m;
    compare(img, NULL, value, &m);
    *out = m;
    return PT_OK;
}

uint64_t pt_metrics_mean(const pt_image *img, double mean[3])
{
    const float *x[3] = {img->r, img->g, img->b};
    size_t n = (size_t)img->width * img->height;
    uint64_t bad = 0;
    for (int ch = 0; ch < 3; ch++) {
        double s = 0.0;
        size_t k = 0;
        for (size_t i = 0; i < n; i++) {
            if (!isfinite(x[ch][i])) {
                bad++;
                continue;
            }
            s += x[ch][i];
            k++;
        }
        mean[ch] = k ? s / (double)k : 0.0;
    }
    return bad;
}
