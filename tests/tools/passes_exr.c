/*
 * ptpasses-exr - EXRs with the denoiser's passes, for the tests of ptdenoise
 * before (and besides) renders that carry them.
 *
 *   ptpasses-exr OUT.exr W H SIGMA SEED [TRUTH.exr] [--nan NAME | --set NAME=V | --drop NAME]
 *   ptpasses-exr --error DENOISED.exr TRUTH.exr
 *
 * The first form writes the synthetic render of tests/common/image/
 * denoise_scene.h (halves with noise of standard deviation SIGMA) in the
 * EXR convention: R, G, B, samples, variance, halfA.*, halfB.*, albedo.*,
 * N.*, depth.Z and the passes' variances; TRUTH.exr gets the noise-free
 * image. --nan NAME puts a NaN in channel NAME at pixel (1, 2), --set
 * NAME=V the value V there, --drop NAME leaves the channel out.
 * The second form prints the MSE of the beauty and of the denoised layer
 * against the truth and exits 0 when the denoised one is lower, 1 if not,
 * 2 on an unreadable file.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "tests/common/image/denoise_scene.h"

static int compare(const char *den_path, const char *truth_path)
{
    static const char *const names[6] = {"R", "G", "B", "denoised.R", "denoised.G", "denoised.B"};
    float *d[6] = {0}, *t[3] = {0};
    uint32_t w, h, tw, th;
    pt_error err = {0};
    if (pt_exr_read_channels(den_path, 6, names, d, &w, &h, &err) != PT_OK ||
        pt_exr_read_channels(truth_path, 3, names, t, &tw, &th, &err) != PT_OK) {
        fprintf(stderr, "ptpasses-exr: %s\n", err.msg);
        return 2;
    }
    int rc = 2;
    if (w != tw || h != th || !d[0] || !d[1] || !d[2] || !d[3] || !d[4] || !d[5] || !t[0] ||
        !t[1] || !t[2]) {
        fprintf(stderr, "ptpasses-exr: sizes or channels do not match\n");
    } else {
        double raw = 0, den = 0;
        size_t n = (size_t)w * h;
        for (int c = 0; c < 3; c++)
            for (size_t i = 0; i < n; i++) {
                raw += ((double)d[c][i] - t[c][i]) * ((double)d[c][i] - t[c][i]);
                den += ((double)d[3 + c][i] - t[c][i]) * ((double)d[3 + c][i] - t[c][i]);
            }
        printf("MSE raw %.4g denoised %.4g\n", raw / (3.0 * n), den / (3.0 * n));
        rc = den < raw ? 0 : 1;
    }
    for (int i = 0; i < 6; i++)
        pt_free(d[i]);
    for (int i = 0; i < 3; i++)
        pt_free(t[i]);
    return rc;
}

int main(int argc, char **argv)
{
    if (argc == 4 && !strcmp(argv[1], "--error"))
        return compare(argv[2], argv[3]);
    if (argc < 6) {
        fprintf(stderr, "usage: ptpasses-exr OUT.exr W H SIGMA SEED [TRUTH.exr] [--nan NAME | "
                        "--set NAME=V | --drop NAME]\n"
                        "       ptpasses-exr --error DENOISED.exr TRUTH.exr\n");
        return 2;
    }
    const char *out = argv[1], *truth_path = NULL, *nan_name = NULL, *drop = NULL;
    char set_name[64] = "";
    float set_value = 0.0f;
    uint32_t w = (uint32_t)atoi(argv[2]), h = (uint32_t)atoi(argv[3]);
    double sigma = atof(argv[4]);
    uint64_t seed = strtoull(argv[5], NULL, 10);
    for (int i = 6; i < argc; i++) {
        if (!strcmp(argv[i], "--nan") && i + 1 < argc) {
            nan_name = argv[++i];
        } else if (!strcmp(argv[i], "--drop") && i + 1 < argc) {
            drop = argv[++i];
        } else if (!strcmp(argv[i], "--set") && i + 1 < argc) {
            const char *eq = strchr(argv[++i], '=');
            if (!eq || (size_t)(eq - argv[i]) >= sizeof set_name)
                return 2;
            memcpy(set_name, argv[i], (size_t)(eq - argv[i]));
            set_name[eq - argv[i]] = '\0';
            set_value = strtof(eq + 1, NULL);
        } else {
            truth_path = argv[i];
        }
    }
    scene s;
    if (w < 4 || h < 4 || w > 4096 || h > 4096 || scene_alloc(&s, w, h) != 0)
        return 2;
    scene_truth(&s);
    scene_noise(&s, sigma, seed);
    size_t n = (size_t)w * h;
    pt_image *img = NULL;
    pt_error err = {0};
    if (pt_image_new(w, h, &img, &err) != PT_OK)
        return 2;
    for (size_t i = 0; i < n; i++) {
        img->r[i] = s.color[0][i];
        img->g[i] = s.color[1][i];
        img->b[i] = s.color[2][i];
        img->samples[i] = 64.0f;
        img->variance[i] = s.var[i];
    }
    pt_exr_meta meta = {.total_samples = 64u * n};
    snprintf(meta.job_id, sizeof meta.job_id, "synthetic-%llu", (unsigned long long)seed);
    const char *names[16] = {"halfA.R",  "halfA.G",         "halfA.B",  "halfB.R",
                             "halfB.G",  "halfB.B",         "albedo.R", "albedo.G",
                             "albedo.B", "albedo.variance", "N.X",      "N.Y",
                             "N.Z",      "N.variance",      "depth.Z",  "depth.variance"};
    float *planes[16] = {s.a[0],      s.a[1],       s.a[2],      s.b[0],
                         s.b[1],      s.b[2],       s.albedo[0], s.albedo[1],
                         s.albedo[2], s.albedo_var, s.normal[0], s.normal[1],
                         s.normal[2], s.normal_var, s.depth,     s.depth_var};
    const char *kept_names[16];
    const float *kept[16];
    unsigned nk = 0;
    for (int i = 0; i < 16; i++) {
        if (nan_name && !strcmp(nan_name, names[i]))
            planes[i][2 * w + 1] = NAN;
        if (!strcmp(set_name, names[i]))
            planes[i][2 * w + 1] = set_value;
        if (drop && !strcmp(drop, names[i]))
            continue;
        kept_names[nk] = names[i];
        kept[nk++] = planes[i];
    }
    if (nan_name && !strcmp(nan_name, "R"))
        img->r[2 * w + 1] = NAN;
    if (!strcmp(set_name, "samples"))
        img->samples[2 * w + 1] = set_value;
    int rc = 0;
    if (pt_exr_write(out, img, &meta, &err) != PT_OK ||
        pt_exr_write_with_channels(out, out, nk, kept_names, kept, &err) != PT_OK) {
        fprintf(stderr, "ptpasses-exr: %s\n", err.msg);
        rc = 1;
    }
    if (!rc && truth_path) {
        for (size_t i = 0; i < n; i++) {
            img->r[i] = s.truth[0][i];
            img->g[i] = s.truth[1][i];
            img->b[i] = s.truth[2][i];
        }
        if (pt_exr_write(truth_path, img, &meta, &err) != PT_OK) {
            fprintf(stderr, "ptpasses-exr: %s\n", err.msg);
            rc = 1;
        }
    }
    pt_image_free(img);
    scene_free(&s);
    return rc;
}
