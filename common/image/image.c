#include "common/image/image.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include <stb/stb_image_write.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"

/* Caps on image size: 65536 per side and 2^28 pixels (1 GiB per float plane
 * at the cap is already more than any render this farm makes). */
pt_status pt_image_check_size(const char *what, uint32_t width, uint32_t height, pt_error *err)
{
    if (width == 0 || height == 0)
        return pt_error_set(err, PT_ERR_ARG, "%s size %ux%u: both sides must be > 0", what, width,
                            height);
    if (width > PT_IMAGE_MAX_SIDE || height > PT_IMAGE_MAX_SIDE ||
        (uint64_t)width * height > PT_IMAGE_MAX_PIXELS)
        return pt_error_set(err, PT_ERR_LIMIT,
                            "%s size %ux%u is over the cap (%u per side, %u pixels)", what, width,
                            height, PT_IMAGE_MAX_SIDE, PT_IMAGE_MAX_PIXELS);
    return PT_OK;
}

/* The struct and the five planes live in one block, struct first, planes
 * after it rounded up to the alignment of double so the floats are aligned. */
pt_status pt_image_new(uint32_t width, uint32_t height, pt_image **out, pt_error *err)
{
    pt_status st = pt_image_check_size("image", width, height, err);
    if (st != PT_OK)
        return st;
    uint64_t pixels = (uint64_t)width * height;
    size_t head = (sizeof(pt_image) + sizeof(double) - 1) / sizeof(double) * sizeof(double);
    size_t planes, total;
    if (__builtin_mul_overflow((size_t)pixels, 6 * sizeof(float), &planes) ||
        __builtin_add_overflow(head, planes, &total))
        return pt_error_set(err, PT_ERR_LIMIT, "image size %ux%u overflows memory", width, height);
    unsigned char *block = pt_calloc(1, total);
    if (!block)
        return pt_error_set(err, PT_ERR_NOMEM, "image %ux%u: out of memory", width, height);
    pt_image *img = (pt_image *)block;
    float *p = (float *)(block + head);
    img->width = width;
    img->height = height;
    img->r = p;
    img->g = p + pixels;
    img->b = p + 2 * pixels;
    img->samples = p + 3 * pixels;
    img->variance = p + 4 * pixels;
    img->a = p + 5 * pixels;
    *out = img;
    return PT_OK;
}

void pt_image_free(pt_image *img)
{
    if (!img)
        return;
    for (uint32_t i = 0; i < img->n_planes; i++)
        pt_free(img->planes[i].data);
    pt_free(img);
}

float *pt_image_find_plane(const pt_image *img, const char *name)
{
    for (uint32_t i = 0; i < img->n_planes; i++)
        if (!strcmp(img->planes[i].name, name))
            return img->planes[i].data;
    return NULL;
}

pt_status pt_image_add_plane(pt_image *img, const char *name, float **out, pt_error *err)
{
    size_t len = strlen(name);
    int ok = len > 0 && len < PT_IMAGE_PLANE_NAME;
    for (size_t i = 0; ok && i < len; i++)
        ok = name[i] > ' ' && name[i] < 0x7f;
    static const char *const own[] = {"R", "G", "B", "A", "samples", "variance"};
    for (size_t i = 0; ok && i < sizeof own / sizeof own[0]; i++)
        ok = strcmp(name, own[i]) != 0;
    if (!ok)
        return pt_error_set(err, PT_ERR_ARG,
                            "image plane name '%.40s' is not 1 to %d printable "
                            "bytes other than a base channel's",
                            name, PT_IMAGE_PLANE_NAME - 1);
    float *d = pt_image_find_plane(img, name);
    if (!d) {
        if (img->n_planes >= PT_IMAGE_MAX_PLANES)
            return pt_error_set(err, PT_ERR_LIMIT, "image plane %s: more than %d planes", name,
                                PT_IMAGE_MAX_PLANES);
        /* The size was checked when the image was made. */
        d = pt_calloc((size_t)img->width * img->height, sizeof *d);
        if (!d)
            return pt_error_set(err, PT_ERR_NOMEM, "image plane %s: out of memory", name);
        pt_image_plane *pl = &img->planes[img->n_planes++];
        memcpy(pl->name, name, len + 1);
        pl->data = d;
    }
    if (out)
        *out = d;
    return PT_OK;
}

/* stb's PNG bytes, gathered in memory for one atomic write. */
typedef struct png_buf {
    unsigned char *data;
    size_t len, cap;
    int failed;
} png_buf;

static void png_append(void *ctx, void *data, int size)
{
    png_buf *b = ctx;
    if (b->failed || size <= 0)
        return;
    if (b->len + (size_t)size > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        while (cap < b->len + (size_t)size)
            cap *= 2;
        unsigned char *n = pt_realloc(b->data, cap);
        if (!n) {
            b->failed = 1;
            return;
        }
        b->data = n;
        b->cap = cap;
    }
    memcpy(b->data + b->len, data, (size_t)size);
    b->len += (size_t)size;
}

pt_image_format pt_image_format_of(const char *path)
{
    size_t n = strlen(path);
    if (n > 4 && strcasecmp(path + n - 4, ".exr") == 0)
        return PT_IMAGE_FORMAT_EXR;
    if (n > 4 && strcasecmp(path + n - 4, ".png") == 0)
        return PT_IMAGE_FORMAT_PNG;
    return PT_IMAGE_FORMAT_NONE;
}

void pt_png_preview_path(const char *exr_path, char *out, size_t n)
{
    size_t len = strlen(exr_path);
    if (len > 4 && strcmp(exr_path + len - 4, ".exr") == 0)
        snprintf(out, n, "%.*s.png", (int)(len - 4), exr_path);
    else
        snprintf(out, n, "%s.png", exr_path);
}

pt_status pt_png_write_preview(const char *path, const pt_image *img, const pt_view *view,
                               pt_error *err)
{
    if (!path || !img || img->width == 0 || img->height == 0 || img->width > PT_IMAGE_MAX_SIDE ||
        img->height > PT_IMAGE_MAX_SIDE)
        return pt_error_set(err, PT_ERR_ARG, "PNG preview %s: no image or a bad size",
                            path ? path : "(null)");
    size_t n = (size_t)img->width * img->height;
    int ch = img->has_alpha ? 4 : 3;
    unsigned char *px = pt_malloc_array(n, (size_t)ch);
    png_buf png = {0};
    pt_status st = PT_OK;
    if (!px) {
        st = pt_error_set(err, PT_ERR_NOMEM, "PNG preview %s: out of memory", path);
        goto fail;
    }
    for (size_t i = 0; i < n; i++) {
        float rgb[3] = {img->r[i], img->g[i], img->b[i]};
        unsigned char *o = px + (size_t)ch * i;
        if (ch == 4) {
            /* PNG's alpha is straight: the film's RGB is premultiplied by
             * the coverage, so it is divided out before the view. */
            float a = img->a[i];
            if (!(a > 0.0f))
                a = 0.0f;
            if (a > 1.0f)
                a = 1.0f;
            for (int k = 0; k < 3; k++)
                rgb[k] = a > 0.0f ? rgb[k] / a : 0.0f;
            o[3] = (unsigned char)(a * 255.0f + 0.5f);
        }
        pt_view_pixel(view, rgb, o);
    }
    if (!stbi_write_png_to_func(png_append, &png, (int)img->width, (int)img->height, ch, px,
                                (int)img->width * ch) ||
        png.failed) {
        st = pt_error_set(err, PT_ERR_NOMEM, "PNG preview %s: cannot encode", path);
        goto fail;
    }
    st = pt_write_file_atomic(path, png.data, png.len, err);
fail:
    pt_free(png.data);
    pt_free(px);
    return st;
}

pt_status pt_png_encode_rgb8(const uint8_t *rgb, uint32_t width, uint32_t height, uint8_t **out,
                             size_t *len, pt_error *err)
{
    if (!rgb || width == 0 || height == 0 || width > PT_IMAGE_MAX_SIDE ||
        height > PT_IMAGE_MAX_SIDE)
        return pt_error_set(err, PT_ERR_ARG, "PNG: no pixels or a bad size");
    png_buf png = {0};
    if (!stbi_write_png_to_func(png_append, &png, (int)width, (int)height, 3, rgb,
                                (int)width * 3) ||
        png.failed) {
        pt_free(png.data);
        return pt_error_set(err, PT_ERR_NOMEM, "PNG: cannot encode %ux%u", width, height);
    }
    *out = png.data;
    *len = png.len;
    return PT_OK;
}
