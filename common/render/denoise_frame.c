#include "common/render/denoise_frame.h"

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/denoise.h"

/* The plane `name` of img into *out, or the refusal naming it. */
static pt_status need(const pt_image *img, const char *name, const float **out, pt_error *err)
{
    *out = pt_image_find_plane(img, name);
    if (*out)
        return PT_OK;
    return pt_error_set(err, PT_ERR_FORMAT,
                        "the frame has no %s: the denoiser needs the passes albedo, normal, "
                        "depth and halves",
                        name);
}

pt_status pt_denoise_frame(pt_image *img, unsigned threads, float despeckle, float *out[3],
                           pt_error *err)
{
    pt_denoise_frame_opts o = {.despeckle = despeckle};
    return pt_denoise_frame_until(img, threads, &o, out, NULL, err);
}

pt_status pt_denoise_frame_until(pt_image *img, unsigned threads, const pt_denoise_frame_opts *o,
                                 float *out[3], uint32_t *side, pt_error *err)
{
    static const char *const rgb[3] = {"R", "G", "B"}, *const xyz[3] = {"X", "Y", "Z"};
    pt_denoise_input in = {.width = img->width,
                           .height = img->height,
                           .despeckle = o->despeckle,
                           .cancel = o->cancel,
                           .progress = o->progress};
    pt_status st = PT_OK;
    char name[PT_IMAGE_PLANE_NAME];
    for (int c = 0; c < 3 && st == PT_OK; c++) {
        snprintf(name, sizeof name, "halfA.%s", rgb[c]);
        st = need(img, name, &in.half_a[c], err);
        snprintf(name, sizeof name, "halfB.%s", rgb[c]);
        if (st == PT_OK)
            st = need(img, name, &in.half_b[c], err);
        snprintf(name, sizeof name, "albedo.%s", rgb[c]);
        if (st == PT_OK)
            st = need(img, name, &in.albedo[c], err);
        snprintf(name, sizeof name, "N.%s", xyz[c]);
        if (st == PT_OK)
            st = need(img, name, &in.normal[c], err);
    }
    if (st == PT_OK)
        st = need(img, "albedo.variance", &in.albedo_var, err);
    if (st == PT_OK)
        st = need(img, "N.variance", &in.normal_var, err);
    if (st == PT_OK)
        st = need(img, "depth.Z", &in.depth, err);
    if (st == PT_OK)
        st = need(img, "depth.variance", &in.depth_var, err);
    if (st != PT_OK)
        return st;
    in.color[0] = img->r;
    in.color[1] = img->g;
    in.color[2] = img->b;
    in.variance = img->variance;
    size_t n = (size_t)img->width * img->height;
    /* Each half needs a sample: a pixel with fewer than 2 has an empty one. */
    for (size_t i = 0; i < n; i++)
        if (!(img->samples[i] >= 2.0f))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "pixel (%zu, %zu) has %g samples; the denoiser's half buffers "
                                "need 2 or more",
                                i % img->width, i / img->width, (double)img->samples[i]);
    float *res[3] = {NULL, NULL, NULL};
    for (int c = 0; c < 3; c++)
        if (!(res[c] = pt_malloc_array(n, sizeof(float)))) {
            st = pt_error_set(err, PT_ERR_NOMEM, "out of memory for the denoised frame");
            goto done;
        }
    uint32_t cut = 0;
    if (o->denoise) {
        if ((st = pt_denoise_check(&in, err)) == PT_OK)
            st = o->denoise(o->ctx, &in, res, &cut, err);
    } else {
        st = pt_denoise_within(&in, threads, o->max_bytes, res, &cut, err);
    }
    if (side)
        *side = cut;
    if (st != PT_OK)
        goto done;
    for (int c = 0; c < 3; c++) {
        float *pl;
        snprintf(name, sizeof name, "denoised.%s", rgb[c]);
        if ((st = pt_image_add_plane(img, name, &pl, err)) != PT_OK)
            goto done;
        memcpy(pl, res[c], n * sizeof(float));
        if (out)
            out[c] = pl;
    }
done:
    for (int c = 0; c < 3; c++)
        pt_free(res[c]);
    return st;
}
