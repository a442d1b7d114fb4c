/*
 * test_exr_channels.c - named channels (layers) in exr.c:
 * pt_exr_write_with_channels copies a file bit for bit with its header
 * attributes and adds, or replaces, float channels; pt_exr_read_channels
 * reads them back, NULL for an absent name, the same plane twice for a name
 * asked twice; a half-float channel is kept in its type; refusals (no file,
 * not an EXR, a truncated file, bad arguments) leave nothing behind; every
 * allocation failure is survived without a leak.
 */
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <OpenEXR/openexr.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "tests/check.h"

static char dir[] = "/tmp/pt_exr_channels_XXXXXX";
static char base_path[256], out_path[256];

enum { W = 37, H = 21 };

static void write_base(void)
{
    pt_image *img = NULL;
    CHECK(pt_image_new(W, H, &img, NULL) == PT_OK);
    for (size_t i = 0; i < (size_t)W * H; i++) {
        img->r[i] = (float)i * 0.5f;
        img->g[i] = (float)i * 0.25f + 1.0f;
        img->b[i] = 1.0f / (float)(i + 1);
        img->samples[i] = 16.0f;
        img->variance[i] = 1e-3f * (float)(i % 7);
    }
    pt_exr_meta meta = {.total_samples = 16u * W * H, .render_seconds = 2.5};
    snprintf(meta.job_id, sizeof meta.job_id, "job-layers");
    snprintf(meta.scene_hash, sizeof meta.scene_hash, "abc123");
    pt_error err = {0};
    CHECKF(pt_exr_write(base_path, img, &meta, &err) == PT_OK, "%s", err.msg);
    pt_image_free(img);
}

static float value(int plane, size_t i)
{
    return (float)plane * 100.0f + (float)i * 0.125f;
}

static void test_add_and_read(void)
{
    static float planes[3][W * H];
    for (int p = 0; p < 3; p++)
        for (size_t i = 0; i < (size_t)W * H; i++)
            planes[p][i] = value(p, i);
    const char *names[3] = {"albedo.R", "N.X", "depth.Z"};
    const float *in[3] = {planes[0], planes[1], planes[2]};
    pt_error err = {0};
    CHECKF(pt_exr_write_with_channels(base_path, out_path, 3, names, in, &err) == PT_OK, "%s",
           err.msg);

    /* The beauty and the attributes as they were. */
    pt_image *a = NULL, *b = NULL;
    pt_exr_meta ma, mb;
    CHECK(pt_exr_read(base_path, &a, &ma, NULL) == PT_OK);
    CHECK(pt_exr_read(out_path, &b, &mb, NULL) == PT_OK);
    if (a && b) {
        size_t n = (size_t)W * H * sizeof(float);
        CHECK(!memcmp(a->r, b->r, n) && !memcmp(a->g, b->g, n) && !memcmp(a->b, b->b, n));
        CHECK(!memcmp(a->samples, b->samples, n) && !memcmp(a->variance, b->variance, n));
        CHECK(mb.total_samples == ma.total_samples && mb.render_seconds == 2.5);
        CHECK(!strcmp(mb.job_id, "job-layers") && !strcmp(mb.scene_hash, "abc123"));
    }
    pt_image_free(a);
    pt_image_free(b);

    const char *ask[5] = {"N.X", "missing.R", "depth.Z", "N.X", "R"};
    float *got[5] = {0};
    uint32_t w = 0, h = 0;
    CHECKF(pt_exr_read_channels(out_path, 5, ask, got, &w, &h, &err) == PT_OK, "%s", err.msg);
    CHECK(w == W && h == H);
    CHECK(got[1] == NULL);
    CHECK(got[0] && got[3] && got[0] != got[3]);
    int same = got[0] && got[2] && got[3] && got[4];
    for (size_t i = 0; same && i < (size_t)W * H; i++)
        same = got[0][i] == value(1, i) && got[3][i] == value(1, i) && got[2][i] == value(2, i) &&
               got[4][i] == (float)i * 0.5f;
    CHECK(same);
    for (int i = 0; i < 5; i++)
        pt_free(got[i]);

    /* Replacing a channel: the new plane wins, the rest stays. */
    static float zero[W * H];
    const char *rn[1] = {"N.X"};
    const float *rp[1] = {zero};
    CHECK(pt_exr_write_with_channels(out_path, out_path, 1, rn, rp, &err) == PT_OK);
    const char *ask2[2] = {"N.X", "albedo.R"};
    float *got2[2] = {0};
    CHECK(pt_exr_read_channels(out_path, 2, ask2, got2, &w, &h, &err) == PT_OK);
    CHECK(got2[0] && got2[1] && got2[0][5] == 0.0f && got2[1][5] == value(0, 5));
    pt_free(got2[0]);
    pt_free(got2[1]);
}

/* A file with a HALF channel (written here through OpenEXRCore): the copy
 * keeps it HALF, bit for bit. */
static void test_half_kept(void)
{
    char half_path[256], copy_path[256];
    snprintf(half_path, sizeof half_path, "%s/half.exr", dir);
    snprintf(copy_path, sizeof copy_path, "%s/half_copy.exr", dir);
    exr_context_t ctx = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    int part = 0;
    uint16_t px[4 * 3];
    for (int i = 0; i < 12; i++)
        px[i] = (uint16_t)(0x3c00 + i); /* 1.0 and the halves just above */
    CHECK(exr_start_write(&ctx, half_path, EXR_WRITE_FILE_DIRECTLY, &init) == EXR_ERR_SUCCESS);
    CHECK(exr_add_part(ctx, NULL, EXR_STORAGE_SCANLINE, &part) == EXR_ERR_SUCCESS);
    CHECK(exr_initialize_required_attr_simple(ctx, part, 4, 3, EXR_COMPRESSION_NONE) ==
          EXR_ERR_SUCCESS);
    const char *chn[3] = {"B", "G", "R"};
    for (int c = 0; c < 3; c++)
        CHECK(exr_add_channel(ctx, part, chn[c], EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LOGARITHMIC, 1,
                              1) == EXR_ERR_SUCCESS);
    CHECK(exr_write_header(ctx) == EXR_ERR_SUCCESS);
    int32_t lines = 1;
    exr_get_scanlines_per_chunk(ctx, part, &lines);
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    for (int y = 0; y < 3; y += lines) {
        exr_chunk_info_t ci;
        CHECK(exr_write_scanline_chunk_info(ctx, part, y, &ci) == EXR_ERR_SUCCESS);
        CHECK((y ? exr_encoding_update(ctx, part, &ci, &enc)
                 : exr_encoding_initialize(ctx, part, &ci, &enc)) == EXR_ERR_SUCCESS);
        for (int c = 0; c < enc.channel_count; c++) {
            enc.channels[c].user_pixel_stride = 2;
            enc.channels[c].user_line_stride = 8;
            enc.channels[c].user_bytes_per_element = 2;
            enc.channels[c].user_data_type = EXR_PIXEL_HALF;
            enc.channels[c].encode_from_ptr = (const uint8_t *)(px + y * 4);
        }
        if (!y)
            CHECK(exr_encoding_choose_default_routines(ctx, part, &enc) == EXR_ERR_SUCCESS);
        CHECK(exr_encoding_run(ctx, part, &enc) == EXR_ERR_SUCCESS);
    }
    exr_encoding_destroy(ctx, &enc);
    CHECK(exr_finish(&ctx) == EXR_ERR_SUCCESS);

    static const float extra[12] = {0};
    const char *n1[1] = {"denoised.R"};
    const float *p1[1] = {extra};
    pt_error err = {0};
    CHECKF(pt_exr_write_with_channels(half_path, copy_path, 1, n1, p1, &err) == PT_OK, "%s",
           err.msg);
    exr_context_t rd = NULL;
    exr_context_initializer_t rinit = EXR_DEFAULT_CONTEXT_INITIALIZER;
    CHECK(exr_start_read(&rd, copy_path, &rinit) == EXR_ERR_SUCCESS);
    const exr_attr_chlist_t *chl = NULL;
    if (rd && exr_get_channels(rd, 0, &chl) == EXR_ERR_SUCCESS && chl) {
        CHECK(chl->num_channels == 4);
        for (int i = 0; i < chl->num_channels; i++)
            CHECK(chl->entries[i].pixel_type == (strcmp(chl->entries[i].name.str, "denoised.R")
                                                     ? EXR_PIXEL_HALF
                                                     : EXR_PIXEL_FLOAT));
    }
    exr_finish(&rd);
    const char *rn[1] = {"G"};
    float *g[1] = {0};
    uint32_t w, h;
    CHECK(pt_exr_read_channels(copy_path, 1, rn, g, &w, &h, &err) == PT_OK);
    CHECK(g[0] && w == 4 && h == 3 && g[0][0] == 1.0f && g[0][11] > 1.0f);
    pt_free(g[0]);
    unlink(half_path);
    unlink(copy_path);
}

static void test_refusals(void)
{
    pt_error err = {0};
    const char *names[1] = {"R"};
    float *got[1] = {0};
    uint32_t w = 7, h = 7;
    char path[256];
    snprintf(path, sizeof path, "%s/none.exr", dir);
    CHECK(pt_exr_read_channels(path, 1, names, got, &w, &h, &err) == PT_ERR_IO);
    CHECK(strstr(err.msg, "none.exr") != NULL && w == 7 && got[0] == NULL);
    snprintf(path, sizeof path, "%s/junk.exr", dir);
    FILE *f = fopen(path, "wb");
    if (f) {
        fputs("no exr here", f);
        fclose(f);
    }
    CHECK(pt_exr_read_channels(path, 1, names, got, &w, &h, &err) == PT_ERR_FORMAT);
    CHECK(got[0] == NULL);
    /* Cut short: the pixels cannot be decoded. */
    struct stat sb;
    CHECK(stat(out_path, &sb) == 0);
    snprintf(path, sizeof path, "%s/cut.exr", dir);
    FILE *in = fopen(out_path, "rb"), *out = fopen(path, "wb");
    if (in && out) {
        char buf[65536];
        size_t n = fread(buf, 1, sizeof buf, in);
        fwrite(buf, 1, n > 2000 ? n - 2000 : n / 2, out);
    }
    if (in)
        fclose(in);
    if (out)
        fclose(out);
    CHECK(pt_exr_read_channels(path, 1, names, got, &w, &h, &err) != PT_OK);
    CHECK(got[0] == NULL);
    char dst[256];
    snprintf(dst, sizeof dst, "%s/never.exr", dir);
    const float *planes[1] = {NULL};
    CHECK(pt_exr_write_with_channels(out_path, dst, 1, names, planes, &err) == PT_ERR_ARG);
    CHECK(pt_exr_write_with_channels(path, dst, 0, NULL, NULL, &err) != PT_OK);
    CHECK(access(dst, F_OK) != 0);
    CHECK(pt_exr_read_channels(out_path, PT_EXR_MAX_CHANNELS + 1, names, got, &w, &h, &err) ==
          PT_ERR_ARG);
}

static void test_alloc_failures(void)
{
    const char *names[3] = {"albedo.R", "G", "albedo.R"};
    static float plane[W * H];
    const float *planes[1] = {plane};
    char dst[256];
    snprintf(dst, sizeof dst, "%s/alloc.exr", dir);
    int64_t live = pt_alloc_live();
    int read_ok = 0, write_ok = 0;
    for (uint64_t k = 1; k < 2000 && !(read_ok && write_ok); k++) {
        float *got[3] = {0};
        uint32_t w, h;
        pt_alloc_fail_at(k);
        pt_status rs =
            read_ok ? PT_OK : pt_exr_read_channels(out_path, 3, names, got, &w, &h, NULL);
        pt_status ws = write_ok
                           ? PT_OK
                           : pt_exr_write_with_channels(out_path, dst, 1, names + 1, planes, NULL);
        pt_alloc_fail_at(0);
        for (int i = 0; i < 3; i++)
            pt_free(got[i]);
        read_ok |= rs == PT_OK;
        write_ok |= ws == PT_OK;
        CHECKF(pt_alloc_live() == live, "allocation %llu left %lld blocks", (unsigned long long)k,
               (long long)(pt_alloc_live() - live));
    }
    CHECK(read_ok && write_ok);
}

int main(void)
{
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    snprintf(base_path, sizeof base_path, "%s/base.exr", dir);
    snprintf(out_path, sizeof out_path, "%s/out.exr", dir);
    write_base();
    test_add_and_read();
    test_half_kept();
    test_refusals();
    test_alloc_failures();
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    return check_report();
}
