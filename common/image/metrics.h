/*
 * metrics.h - image error metrics: how far a render is from a reference.
 *
 * Compares the R, G, B planes of a pt_image with a reference image or with a
 * constant (the white furnace: every pixel is E / (1 - rho)). Sums run in
 * double over every pixel and channel, in row-major order, so the result is
 * deterministic.
 *
 *   RMSE   = sqrt(mean over values of (x - r)^2)
 *   relMSE = mean over values of (x - r)^2 / (r^2 + PT_METRICS_REL_EPS)
 *
 * relMSE is the relative MSE of the adaptive-rendering and denoising
 * literature (Rousselle, Knaus and Zwicker's papers and their successors);
 * papers use an epsilon between 1e-3 and 1e-2, this project 1e-2. It keeps
 * black reference pixels from dominating: there the error is judged on an
 * absolute scale, (x - r)^2 / 1e-2. A value is skipped, and
 * counted in `nonfinite`, when either x or r is NaN or Inf: one bad pixel
 * must not turn the whole score into NaN, and the count says it happened.
 * Pure functions; thread-safe; nothing is allocated.
 */
#ifndef PT_COMMON_IMAGE_METRICS_H
#define PT_COMMON_IMAGE_METRICS_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/image/image.h"

/* relMSE's epsilon added to the squared reference (linear radiance units^2). */
#define PT_METRICS_REL_EPS 1e-2

typedef struct pt_metrics {
    double rmse;        /* root mean squared error over the values compared */
    double rel_mse;     /* relative MSE, see above */
    double mean[3];     /* mean R, G, B of the image over its finite values */
    uint64_t compared;  /* values (pixel x channel) that entered rmse and rel_mse */
    uint64_t nonfinite; /* values skipped: NaN/Inf in the image or the reference */
} pt_metrics;

/* Compares img with ref (same width and height, R, G, B only). Returns
 * PT_ERR_ARG when the sizes differ. When nothing could be compared (every
 * value non-finite), rmse and rel_mse are NaN. out is untouched on failure. */
pt_status pt_metrics_compare(const pt_image *img, const pt_image *ref, pt_metrics *out,
                             pt_error *err);

/* Compares img with a reference whose every value is `value` (e.g. the white
 * furnace's E / (1 - rho)). Returns PT_ERR_ARG when value is not finite. */
pt_status pt_metrics_compare_constant(const pt_image *img, double value, pt_metrics *out,
                                      pt_error *err);

/* Mean R, G, B of img over its finite values (0 for a channel with none);
 * returns the number of non-finite values seen. */
uint64_t pt_metrics_mean(const pt_image *img, double mean[3]);

#endif
