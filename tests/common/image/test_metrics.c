/*
 * test_metrics.c - pt_metrics: RMSE and relMSE on known values, the constant
 * reference, non-finite values, and the size-mismatch reject path.
 */
#include <math.h>

#include "common/image/metrics.h"
#include "tests/check.h"

static pt_image *make(uint32_t w, uint32_t h, float r, float g, float b)
{
    pt_image *img = NULL;
    if (pt_image_new(w, h, &img, NULL) != PT_OK)
        return NULL;
    for (size_t i = 0; i < (size_t)w * h; i++) {
        img->r[i] = r;
        img->g[i] = g;
        img->b[i] = b;
    }
    return img;
}

static int near(double a, double b)
{
    return fabs(a - b) <= 1e-12 * (fabs(b) > 1 ? fabs(b) : 1);
}

static void test_identical(void)
{
    pt_image *a = make(4, 3, 0.25f, 0.5f, 2.0f), *b = make(4, 3, 0.25f, 0.5f, 2.0f);
    pt_metrics m;
    CHECK(pt_metrics_compare(a, b, &m, NULL) == PT_OK);
    CHECK(m.rmse == 0.0 && m.rel_mse == 0.0);
    CHECK(m.compared == 36 && m.nonfinite == 0);
    CHECK(m.mean[0] == 0.25 && m.mean[1] == 0.5 && m.mean[2] == 2.0);
    pt_image_free(a);
    pt_image_free(b);
}

/* Two pixels, hand-computed: differences (1, 0, 0) and (0, 0.5, -2) against
 * reference values (1, 2, 0) and (0, 1, 4). */
static void test_known_values(void)
{
    pt_image *x = make(2, 1, 0, 0, 0), *r = make(2, 1, 0, 0, 0);
    float xv[6] = {2, 2, 0, 0, 1.5f, 2}, rv[6] = {1, 2, 0, 0, 1, 4};
    for (int i = 0; i < 2; i++) {
        x->r[i] = xv[3 * i];
        x->g[i] = xv[3 * i + 1];
        x->b[i] = xv[3 * i + 2];
        r->r[i] = rv[3 * i];
        r->g[i] = rv[3 * i + 1];
        r->b[i] = rv[3 * i + 2];
    }
    pt_metrics m;
    CHECK(pt_metrics_compare(x, r, &m, NULL) == PT_OK);
    double mse = (1.0 + 0.25 + 4.0) / 6.0;
    CHECKF(near(m.rmse, sqrt(mse)), "rmse %.17g", m.rmse);
    double rel = (1.0 / (1.0 + 1e-2) + 0.25 / (1.0 + 1e-2) + 4.0 / (16.0 + 1e-2)) / 6.0;
    CHECKF(near(m.rel_mse, rel), "rel_mse %.17g vs %.17g", m.rel_mse, rel);
    CHECK(near(m.mean[0], 1.0) && near(m.mean[1], 1.75) && near(m.mean[2], 1.0));
    /* A black reference pixel is judged on the absolute scale 1/eps. */
    pt_image *black = make(1, 1, 0, 0, 0), *one = make(1, 1, 0.1f, 0.1f, 0.1f);
    CHECK(pt_metrics_compare(one, black, &m, NULL) == PT_OK);
    double d2 = (double)0.1f * (double)0.1f;
    CHECKF(near(m.rel_mse, d2 / PT_METRICS_REL_EPS), "black rel_mse %.17g", m.rel_mse);
    pt_image_free(black);
    pt_image_free(one);
    pt_image_free(x);
    pt_image_free(r);
}

static void test_constant(void)
{
    /* The furnace: every value should be 1; half the pixels are 1.5, half 0.5. */
    pt_image *x = make(8, 8, 1, 1, 1);
    for (size_t i = 0; i < 64; i++) {
        float v = i % 2 ? 1.5f : 0.5f;
        x->r[i] = x->g[i] = x->b[i] = v;
    }
    pt_metrics m, m2;
    CHECK(pt_metrics_compare_constant(x, 1.0, &m, NULL) == PT_OK);
    CHECK(near(m.rmse, 0.5));
    CHECK(near(m.rel_mse, 0.25 / (1.0 + 1e-2)));
    CHECK(near(m.mean[0], 1.0) && near(m.mean[1], 1.0) && near(m.mean[2], 1.0));
    /* The same as an image reference filled with the constant. */
    pt_image *ref = make(8, 8, 1, 1, 1);
    CHECK(pt_metrics_compare(x, ref, &m2, NULL) == PT_OK);
    CHECK(m.rmse == m2.rmse && m.rel_mse == m2.rel_mse && m.compared == m2.compared);
    pt_error err = {0};
    pt_metrics keep = {.rmse = -7};
    CHECK(pt_metrics_compare_constant(x, NAN, &keep, &err) == PT_ERR_ARG);
    CHECK(pt_metrics_compare_constant(x, INFINITY, &keep, &err) == PT_ERR_ARG);
    CHECK(keep.rmse == -7);
    pt_image_free(ref);
    pt_image_free(x);
}

static void test_nonfinite(void)
{
    pt_image *x = make(3, 1, 1, 1, 1), *r = make(3, 1, 1, 1, 1);
    x->r[0] = NAN;
    x->g[1] = INFINITY;
    r->b[2] = -INFINITY;
    x->b[0] = 3; /* one real error of 2 among the 6 values left */
    pt_metrics m;
    CHECK(pt_metrics_compare(x, r, &m, NULL) == PT_OK);
    CHECK(m.nonfinite == 3 && m.compared == 6);
    CHECK(near(m.rmse, sqrt(4.0 / 6.0)));
    double mean[3];
    CHECK(pt_metrics_mean(x, mean) == 2);
    CHECK(near(mean[0], 1.0) && near(mean[1], 1.0) && near(mean[2], 5.0 / 3.0));
    /* Nothing comparable: NaN scores, not a made-up zero. */
    pt_image *nan = make(2, 2, NAN, NAN, NAN);
    CHECK(pt_metrics_compare_constant(nan, 1.0, &m, NULL) == PT_OK);
    CHECK(m.compared == 0 && m.nonfinite == 12 && isnan(m.rmse) && isnan(m.rel_mse));
    pt_image_free(nan);
    pt_image_free(x);
    pt_image_free(r);
}

static void test_size_mismatch(void)
{
    pt_image *a = make(4, 4, 1, 1, 1), *b = make(4, 5, 1, 1, 1), *c = make(5, 4, 1, 1, 1);
    pt_error err = {0};
    pt_metrics m = {.rmse = -1};
    CHECK(pt_metrics_compare(a, b, &m, &err) == PT_ERR_ARG);
    CHECKF(err.code == PT_ERR_ARG && err.msg[0], "message '%s'", err.msg);
    CHECK(pt_metrics_compare(a, c, &m, NULL) == PT_ERR_ARG);
    CHECK(m.rmse == -1); /* untouched on failure */
    pt_image_free(a);
    pt_image_free(b);
    pt_image_free(c);
}

int main(void)
{
    test_identical();
    test_known_values();
    test_constant();
    test_nonfinite();
    test_size_mismatch();
    return check_report();
}
