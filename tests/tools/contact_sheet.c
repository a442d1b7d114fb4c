/*
 * ptcontact-sheet - lays images written by ptfarm out on one sRGB PNG, in
 * rows, for reviewing a sequence (a frame range's EXRs) at a glance.
 *
 *   ptcontact-sheet -o SHEET.png [--cols N] [--exposure EV] [--view V] A.exr ...
 *
 * Every image must have the size of the first. Frames are placed left to
 * right, top to bottom, in the order given, with a 4-pixel black gutter;
 * the PNG goes through the same view transform as every preview ptfarm
 * writes (pt_png_write_preview, common/image/view.h). Exit 0 on success, 2 on bad arguments or an
 * image that cannot be read, 1 when the PNG cannot be written.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/error.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/view.h"

enum { GUTTER = 4, MAX_FRAMES = 1024 };

static int usage(FILE *f, int rc)
{
    fprintf(f, "usage: ptcontact-sheet -o SHEET.png [--cols N] [--exposure EV]\n"
               "                       [--view " PT_VIEW_NAMES "] A.exr B.exr ...\n"
               "       ptcontact-sheet --version\n"
               "Lays the images out in rows of N (default: up to 4), in the order given,\n"
               "on one sRGB PNG. Every image must have the first one's size. --exposure\n"
               "(stops, default 0) and --view (default standard) are the previews' own.\n");
    return rc;
}

/* Copies frame k's RGB into its cell of the sheet. */
static void place(pt_image *sheet, const pt_image *img, uint32_t k, uint32_t cols)
{
    uint32_t x0 = (k % cols) * (img->width + GUTTER), y0 = (k / cols) * (img->height + GUTTER);
    for (uint32_t y = 0; y < img->height; y++) {
        size_t dst = (size_t)(y0 + y) * sheet->width + x0, src = (size_t)y * img->width;
        memcpy(sheet->r + dst, img->r + src, img->width * sizeof(float));
        memcpy(sheet->g + dst, img->g + src, img->width * sizeof(float));
        memcpy(sheet->b + dst, img->b + src, img->width * sizeof(float));
    }
}

int main(int argc, char **argv)
{
    if (argc == 2 && !strcmp(argv[1], "--version"))
        return pt_version_print("ptcontact-sheet");
    const char *out = NULL;
    uint32_t cols = 0;
    int first = 1;
    pt_error err = {0};
    pt_view view = {PT_VIEW_STANDARD, 0.0f};
    double ev = 0.0;
    while (first < argc && argv[first][0] == '-') {
        if (!strcmp(argv[first], "-h") || !strcmp(argv[first], "--help"))
            return usage(stdout, 0);
        if (!strcmp(argv[first], "-o") && first + 1 < argc) {
            out = argv[first + 1];
        } else if (!strcmp(argv[first], "--cols") && first + 1 < argc) {
            if (pt_opt_u32("--cols", argv[first + 1], 1, MAX_FRAMES, &cols, &err) != PT_OK) {
                fprintf(stderr, "ptcontact-sheet: %s\n", err.msg);
                return 2;
            }
        } else if (!strcmp(argv[first], "--exposure") && first + 1 < argc) {
            if (pt_opt_double("--exposure", argv[first + 1], -PT_VIEW_MAX_EV, PT_VIEW_MAX_EV, &ev,
                              &err) != PT_OK) {
                fprintf(stderr, "ptcontact-sheet: %s\n", err.msg);
                return 2;
            }
            view.exposure = (float)ev;
        } else if (!strcmp(argv[first], "--view") && first + 1 < argc) {
            if (pt_view_parse("--view", argv[first + 1], &view.kind, &err) != PT_OK) {
                fprintf(stderr, "ptcontact-sheet: %s\n", err.msg);
                return 2;
            }
        } else {
            return usage(stderr, 2);
        }
        first += 2;
    }
    uint32_t n = (uint32_t)(argc - first);
    if (!out || n == 0 || n > MAX_FRAMES)
        return usage(stderr, 2);
    if (cols == 0)
        cols = n < 4 ? n : 4;
    if (cols > n)
        cols = n;
    uint32_t rows = (n + cols - 1) / cols;

    pt_image *sheet = NULL, *img = NULL;
    int rc = 0;
    for (uint32_t k = 0; k < n && rc == 0; k++) {
        const char *path = argv[first + (int)k];
        if (pt_exr_read(path, &img, NULL, &err) != PT_OK) {
            fprintf(stderr, "ptcontact-sheet: %s\n", err.msg);
            rc = 2;
            break;
        }
        if (!sheet) {
            uint64_t w = (uint64_t)cols * img->width + (uint64_t)(cols - 1) * GUTTER;
            uint64_t h = (uint64_t)rows * img->height + (uint64_t)(rows - 1) * GUTTER;
            if (w > PT_IMAGE_MAX_SIDE || h > PT_IMAGE_MAX_SIDE ||
                pt_image_new((uint32_t)w, (uint32_t)h, &sheet, &err) != PT_OK) {
                fprintf(stderr, "ptcontact-sheet: a %llux%llu sheet: %s\n", (unsigned long long)w,
                        (unsigned long long)h, err.msg[0] ? err.msg : "too large");
                rc = 2;
            }
        } else if (img->width * (uint64_t)cols + (uint64_t)(cols - 1) * GUTTER != sheet->width ||
                   img->height * (uint64_t)rows + (uint64_t)(rows - 1) * GUTTER != sheet->height) {
            fprintf(stderr, "ptcontact-sheet: %s is %ux%u, not the first image's size\n", path,
                    img->width, img->height);
            rc = 2;
        }
        if (rc == 0)
            place(sheet, img, k, cols);
        pt_image_free(img);
        img = NULL;
    }
    if (rc == 0 && pt_png_write_preview(out, sheet, &view, &err) != PT_OK) {
        fprintf(stderr, "ptcontact-sheet: %s\n", err.msg);
        rc = 1;
    }
    pt_image_free(sheet);
    return rc;
}
