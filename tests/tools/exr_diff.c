/*
 * ptexr-diff [--base] A.exr B.exr - compares two images written by ptfarm.
 *
 * Exit 0 when R, G, B, samples and A (when either file has it; both must)
 * are bit-identical, and so is every other channel (the render passes'
 * layers: both files must have the same ones; --base compares the base
 * channels alone), 1 when they differ
 * (the first differing pixel and the count are printed), 2 when a file
 * cannot be read or the sizes differ. Header attributes (render time, job
 * id) are not compared: they legitimately differ between runs.
 *
 * ptexr-diff --z MAX A.exr B.exr: for two renders of one image whose
 * results may differ by float rounding (the same scene built another way),
 * a paired z-test instead: per channel (R, G, B), the pixel differences
 * d = a - b have mean 0 when both estimate the same image, and the pixels
 * are independent of each other (their own sample streams), so
 * z = mean(d) / (sd(d) / sqrt(n)) is standard normal for n in the
 * thousands, whatever the correlation of a and b within a pixel. Exit 0
 * when |z| <= MAX on every channel (and the samples agree), else 1; the z
 * values are printed. Identical images pass (sd 0, mean 0). A paired test
 * of images that differ only by rounding has a tiny sd, so that a rounding
 * bias (the same sign of a last bit in many pixels) would read as
 * significant: a mean difference within 1e-6 of the channel's mean (16
 * float ulps, far below any sample's weight) passes too.
 *
 * ptexr-diff --noise MAX A.exr B.exr C.exr: for B, a render of A's scene
 * with its geometry slightly perturbed (quantized), with A's seed, and C, a
 * render of A's scene with another seed: per channel (R, G, B), the ratio
 * r = rms(B - A) / rms(C - A). C - A is the difference of two independent
 * estimates, so rms(C - A)^2 is twice the per-pixel variance; B shares A's
 * random numbers, so B - A holds only the paths the perturbation turned
 * aside (each as far from A as an independent sample) and a bias as small
 * as the perturbation: r is near 0 for a small perturbation and near or
 * above 1 when the geometry is wrong. Exit 0 when r <= MAX on every channel
 * (and the samples agree), else 1; the ratios are printed.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/version.h"
#include "common/image/exr.h"

/* The named channels (render passes): the same names, the same bits.
 * Returns 0 or 1 after saying what differs. */
static int diff_planes(const pt_image *a, const pt_image *b)
{
    const pt_image *ab[2] = {a, b};
    for (int k = 0; k < 2; k++)
        for (uint32_t i = 0; i < ab[k]->n_planes; i++)
            if (!pt_image_find_plane(ab[1 - k], ab[k]->planes[i].name)) {
                printf("channel %s is only in %s\n", ab[k]->planes[i].name, k ? "B" : "A");
                return 1;
            }
    size_t n = (size_t)a->width * a->height;
    for (uint32_t i = 0; i < a->n_planes; i++) {
        const float *pa = a->planes[i].data, *pb = pt_image_find_plane(b, a->planes[i].name);
        size_t diff = 0, first = 0;
        for (size_t j = 0; j < n; j++)
            if (memcmp(&pa[j], &pb[j], sizeof(float)) != 0 && diff++ == 0)
                first = j;
        if (diff) {
            printf("%s: %zu of %zu pixels differ; first at (%zu, %zu): %.9g vs %.9g\n",
                   a->planes[i].name, diff, n, first % a->width, first / a->width, pa[first],
                   pb[first]);
            return 1;
        }
    }
    return 0;
}

/* --z: the paired z-test above. */
static int diff_z(const pt_image *a, const pt_image *b, double zmax)
{
    size_t n = (size_t)a->width * a->height;
    const float *pa[3] = {a->r, a->g, a->b}, *pb[3] = {b->r, b->g, b->b};
    int rc = 0;
    for (size_t i = 0; i < n; i++)
        if (a->samples[i] != b->samples[i]) {
            printf("pixel (%zu, %zu): %g vs %g samples\n", i % a->width, i / a->width,
                   a->samples[i], b->samples[i]);
            return 1;
        }
    for (int c = 0; c < 3; c++) {
        double sum = 0.0, sum2 = 0.0, level = 0.0;
        size_t nd = 0;
        for (size_t i = 0; i < n; i++) {
            double d = (double)pa[c][i] - (double)pb[c][i];
            level += 0.5 * (fabs((double)pa[c][i]) + fabs((double)pb[c][i])) / (double)n;
            sum += d;
            sum2 += d * d;
            nd += d != 0.0;
        }
        double mean = sum / (double)n, var = sum2 / (double)n - mean * mean;
        double se = sqrt(var > 0.0 ? var / (double)(n > 1 ? n - 1 : 1) : 0.0);
        double z = se > 0.0 ? mean / se : (mean == 0.0 ? 0.0 : INFINITY);
        printf("%c: %zu of %zu pixels differ, mean difference %.3g, z %.3f\n", "RGB"[c], nd, n,
               mean, z);
        if (!(fabs(z) <= zmax) && !(fabs(mean) <= 1e-6 * level))
            rc = 1;
    }
    return rc;
}

/* --noise: the ratio above. */
static int diff_noise(const pt_image *a, const pt_image *b, const pt_image *c, double rmax)
{
    size_t n = (size_t)a->width * a->height;
    const float *pa[3] = {a->r, a->g, a->b}, *pb[3] = {b->r, b->g, b->b},
                *pc[3] = {c->r, c->g, c->b};
    int rc = 0;
    for (size_t i = 0; i < n; i++)
        if (a->samples[i] != b->samples[i] || a->samples[i] != c->samples[i]) {
            printf("pixel (%zu, %zu): the sample counts differ\n", i % a->width, i / a->width);
            return 1;
        }
    for (int k = 0; k < 3; k++) {
        double db = 0.0, dc = 0.0;
        for (size_t i = 0; i < n; i++) {
            double x = (double)pb[k][i] - (double)pa[k][i], y = (double)pc[k][i] - (double)pa[k][i];
            db += x * x;
            dc += y * y;
        }
        double r = dc > 0.0 ? sqrt(db / dc) : (db > 0.0 ? INFINITY : 0.0);
        printf("%c: rms(B - A) %.3g, rms(C - A) %.3g, ratio %.4f\n", "RGB"[k], sqrt(db / (double)n),
               sqrt(dc / (double)n), r);
        if (!(r <= rmax))
            rc = 1;
    }
    return rc;
}

int main(int argc, char **argv)
{
    if (argc == 2 && !strcmp(argv[1], "--version"))
        return pt_version_print("ptexr-diff");
    if (argc >= 2 && !strcmp(argv[1], "--noise")) {
        char *end = NULL;
        double rmax = argc == 6 ? strtod(argv[2], &end) : 0.0;
        if (argc != 6 || *end || !(rmax > 0.0)) {
            fprintf(stderr, "usage: ptexr-diff --noise MAX A.exr B.exr C.exr (MAX > 0)\n");
            return 2;
        }
        pt_image *im[3] = {NULL, NULL, NULL};
        pt_error err = {0};
        int rc = 0;
        for (int k = 0; k < 3 && rc == 0; k++)
            if (pt_exr_read_layers(argv[3 + k], &im[k], NULL, &err) != PT_OK) {
                fprintf(stderr, "ptexr-diff: %s\n", err.msg);
                rc = 2;
            }
        for (int k = 1; k < 3 && rc == 0; k++)
            if (im[k]->width != im[0]->width || im[k]->height != im[0]->height) {
                fprintf(stderr, "ptexr-diff: sizes differ: %s\n", argv[3 + k]);
                rc = 2;
            }
        if (rc == 0)
            rc = diff_noise(im[0], im[1], im[2], rmax);
        for (int k = 0; k < 3; k++)
            pt_image_free(im[k]);
        return rc;
    }
    double zmax = -1.0;
    if (argc == 5 && !strcmp(argv[1], "--z")) {
        char *end;
        zmax = strtod(argv[2], &end);
        if (*end || !(zmax > 0.0)) {
            fprintf(stderr, "ptexr-diff: --z %s: not a positive number\n", argv[2]);
            return 2;
        }
        argv += 2;
        argc -= 2;
    }
    int base = argc == 4 && !strcmp(argv[1], "--base");
    if (base) {
        argv++;
        argc--;
    }
    if (argc != 3 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        fprintf(argc == 3 ? stdout : stderr, "usage: ptexr-diff [--base | --z MAX] A.exr B.exr\n"
                                             "       ptexr-diff --noise MAX A.exr B.exr C.exr\n"
                                             "       ptexr-diff --version\n");
        return argc == 3 ? 0 : 2;
    }
    pt_image *a = NULL, *b = NULL;
    pt_error err = {0};
    if (pt_exr_read_layers(argv[1], &a, NULL, &err) != PT_OK ||
        pt_exr_read_layers(argv[2], &b, NULL, &err) != PT_OK) {
        fprintf(stderr, "ptexr-diff: %s\n", err.msg);
        pt_image_free(a);
        return 2;
    }
    int rc = 0;
    if (a->width != b->width || a->height != b->height) {
        fprintf(stderr, "ptexr-diff: sizes differ: %ux%u vs %ux%u\n", a->width, a->height, b->width,
                b->height);
        rc = 2;
    } else if (zmax > 0.0) {
        rc = diff_z(a, b, zmax);
    } else if (a->has_alpha != b->has_alpha) {
        printf("one image has an A channel, the other not\n");
        rc = 1;
    } else {
        size_t n = (size_t)a->width * a->height, diff = 0, first = 0;
        const float *pa[5] = {a->r, a->g, a->b, a->samples, a->a},
                    *pb[5] = {b->r, b->g, b->b, b->samples, b->a};
        for (size_t i = 0; i < n; i++) {
            int d = 0;
            for (int c = 0; c < (a->has_alpha ? 5 : 4); c++)
                d |= memcmp(&pa[c][i], &pb[c][i], sizeof(float)) != 0;
            if (d && diff++ == 0)
                first = i;
        }
        if (diff) {
            size_t x = first % a->width, y = first / a->width;
            printf(
                "%zu of %zu pixels differ; first at (%zu, %zu): RGB %.9g %.9g %.9g (%g samples) vs "
                "%.9g %.9g %.9g (%g samples)\n",
                diff, n, x, y, a->r[first], a->g[first], a->b[first], a->samples[first],
                b->r[first], b->g[first], b->b[first], b->samples[first]);
            rc = 1;
        } else {
            rc = base ? 0 : diff_planes(a, b);
        }
        if (rc == 0 && (base || a->n_planes == 0))
            printf("identical: %ux%u, R G B samples%s bit for bit\n", a->width, a->height,
                   a->has_alpha ? " A" : "");
        else if (rc == 0)
            printf("identical: %ux%u, R G B samples%s bit for bit, and %u named channels\n",
                   a->width, a->height, a->has_alpha ? " A" : "", a->n_planes);
    }
    pt_image_free(a);
    pt_image_free(b);
    return rc;
}
