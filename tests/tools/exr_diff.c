/*
 * ptexr-diff A.exr B.exr - compares two images written by ptfarm.
 *
 * Exit 0 when R, G, B, samples and A (when either file has it; both must)
 * are bit-identical, 1 when they differ
 * (the first differing pixel and the count are printed), 2 when a file
 * cannot be read or the sizes differ. Header attributes (render time, job
 * id) are not compared: they legitimately differ between runs.
 */
#include <stdio.h>
#include <string.h>

#include "common/base/version.h"
#include "common/image/exr.h"

int main(int argc, char **argv)
{
    if (argc == 2 && !strcmp(argv[1], "--version"))
        return pt_version_print("ptexr-diff");
    if (argc != 3 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        fprintf(argc == 3 ? stdout : stderr, "usage: ptexr-diff A.exr B.exr\n"
                                             "       ptexr-diff --version\n");
        return argc == 3 ? 0 : 2;
    }
    pt_image *a = NULL, *b = NULL;
    pt_error err = {0};
    if (pt_exr_read(argv[1], &a, NULL, &err) != PT_OK ||
        pt_exr_read(argv[2], &b, NULL, &err) != PT_OK) {
        fprintf(stderr, "ptexr-diff: %s\n", err.msg);
        pt_image_free(a);
        return 2;
    }
    int rc = 0;
    if (a->width != b->width || a->height != b->height) {
        fprintf(stderr, "ptexr-diff: sizes differ: %ux%u vs %ux%u\n", a->width, a->height, b->width,
                b->height);
        rc = 2;
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
            printf("identical: %ux%u, R G B samples%s bit for bit\n", a->width, a->height,
                   a->has_alpha ? " A" : "");
        }
    }
    pt_image_free(a);
    pt_image_free(b);
    return rc;
}
