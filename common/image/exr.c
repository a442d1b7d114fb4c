#include "common/image/exr.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <OpenEXR/openexr.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"

/*
 * Our own stream over a file descriptor for both directions: writing through
 * it lets us fsync the temp file before the rename, and reading through it
 * keeps the context's user data ours. OpenEXRCore reports the detail of an
 * error through a callback rather than a return value, so the last message
 * is kept here and copied into the pt_error.
 */
typedef struct exr_stream {
    int fd;
    int64_t size; /* bytes in the file (read) */
    int io_errno; /* errno of the last failed read or write, else 0 */
} exr_stream;

/* The callback has no user pointer we may rely on during context creation,
 * and contexts never cross threads here, so the last message is per thread. */
static _Thread_local char exr_last_msg[256];

static void on_exr_error(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    snprintf(exr_last_msg, sizeof exr_last_msg, "%s",
             msg ? msg : exr_get_error_code_as_string(code));
}

static int64_t stream_read(exr_const_context_t ctxt, void *user, void *buffer, uint64_t sz,
                           uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)ctxt;
    (void)error_cb;
    exr_stream *s = user;
    uint64_t done = 0;
    if (offset > INT64_MAX || sz > INT64_MAX)
        return -1;
    while (done < sz) {
        ssize_t r = pread(s->fd, (char *)buffer + done, sz - done, (off_t)(offset + done));
        if (r < 0) {
            if (errno == EINTR)
                continue;
            s->io_errno = errno;
            return -1;
        }
        if (r == 0)
            break; /* end of file: a short read, which the library reports */
        done += (uint64_t)r;
    }
    return (int64_t)done;
}

static int64_t stream_size(exr_const_context_t ctxt, void *user)
{
    (void)ctxt;
    return ((exr_stream *)user)->size;
}

static int64_t stream_write(exr_const_context_t ctxt, void *user, const void *buffer, uint64_t sz,
                            uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)ctxt;
    (void)error_cb;
    exr_stream *s = user;
    uint64_t done = 0;
    if (offset > INT64_MAX || sz > INT64_MAX)
        return -1;
    while (done < sz) {
        ssize_t w = pwrite(s->fd, (const char *)buffer + done, sz - done, (off_t)(offset + done));
        if (w < 0) {
            if (errno == EINTR)
                continue;
            s->io_errno = errno;
            return -1;
        }
        done += (uint64_t)w;
    }
    return (int64_t)done;
}

/* Maps a failed OpenEXRCore call to a pt_error naming the file. */
static pt_status exr_fail(pt_error *err, const exr_stream *s, exr_result_t rv, const char *path,
                          const char *what)
{
    pt_status code = PT_ERR_FORMAT;
    if (rv == EXR_ERR_OUT_OF_MEMORY)
        code = PT_ERR_NOMEM;
    else if (rv == EXR_ERR_FILE_ACCESS || rv == EXR_ERR_WRITE_IO ||
             (rv == EXR_ERR_READ_IO && s->io_errno != 0))
        code = PT_ERR_IO;
    /* The library's own message, when it gave one, says which field or chunk. */
    const char *lp = exr_last_msg[0] ? " (" : "", *rp = exr_last_msg[0] ? ")" : "";
    if (code == PT_ERR_IO && s->io_errno) {
        errno = s->io_errno;
        return pt_error_errno(err, code, "EXR %s: %s: %s%s%s%s", path, what,
                              exr_get_error_code_as_string(rv), lp, exr_last_msg, rp);
    }
    return pt_error_set(err, code, "EXR %s: %s: %s%s%s%s", path, what,
                        exr_get_error_code_as_string(rv), lp, exr_last_msg, rp);
}

static void stream_init(exr_context_initializer_t *init, exr_stream *s)
{
    exr_context_initializer_t d = EXR_DEFAULT_CONTEXT_INITIALIZER;
    *init = d;
    init->error_handler_fn = on_exr_error;
    /* The library's allocations go through our hook too, so the
     * allocation-failure tests reach its paths as well. */
    init->alloc_fn = pt_malloc;
    init->free_fn = pt_free;
    init->user_data = s;
    exr_last_msg[0] = '\0';
}

/* Channel names in the order OpenEXR keeps them (sorted by name, bytewise),
 * and the plane each one comes from. */
static const char *const channel_names[6] = {"A", "B", "G", "R", "samples", "variance"};

static float *plane_of(const pt_image *img, const char *name)
{
    if (!strcmp(name, "A"))
        return img->a;
    if (!strcmp(name, "R"))
        return img->r;
    if (!strcmp(name, "G"))
        return img->g;
    if (!strcmp(name, "B"))
        return img->b;
    if (!strcmp(name, "samples"))
        return img->samples;
    if (!strcmp(name, "variance"))
        return img->variance;
    return pt_image_find_plane(img, name);
}

/* Declares the part, channels and attributes of the file being written. */
/* OpenEXR's framesPerSecond is a rational: the NTSC rates as N x 1000 / 1001
 * (as ImfFramesPerSecond's), a whole rate as R/1, anything else to 1/1000. */
static exr_attr_rational_t fps_rational(double fps)
{
    exr_attr_rational_t r = {0, 1};
    if (!(fps > 0.0) || fps > 1e6)
        return r;
    double ntsc = fps * 1.001;
    if (fabs(ntsc - round(ntsc)) < 1e-3 && fabs(fps - round(fps)) > 1e-3) {
        r.num = (int32_t)(round(ntsc) * 1000.0);
        r.denom = 1001;
    } else if (fabs(fps - round(fps)) < 1e-9) {
        r.num = (int32_t)round(fps);
    } else {
        r.num = (int32_t)round(fps * 1000.0);
        r.denom = 1000;
    }
    return r;
}

static exr_result_t define_part(exr_context_t ctx, const pt_image *img, const pt_exr_meta *meta)
{
    int part = 0;
    exr_result_t rv = exr_add_part(ctx, NULL, EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(ctx, part, (int32_t)img->width,
                                                 (int32_t)img->height, EXR_COMPRESSION_ZIP);
    /* A (coverage) only for a transparent film: without it, the file is as
     * it always was. */
    for (int c = img->has_alpha ? 0 : 1; c < 6 && rv == EXR_ERR_SUCCESS; c++) {
        /* Colour is perceptually logarithmic, alpha, counts and variances are
         * not; the flag only guides lossy codecs, and ZIP is lossless. */
        exr_perceptual_treatment_t pt =
            c >= 1 && c < 4 ? EXR_PERCEPTUALLY_LOGARITHMIC : EXR_PERCEPTUALLY_LINEAR;
        rv = exr_add_channel(ctx, part, channel_names[c], EXR_PIXEL_FLOAT, pt, 1, 1);
    }
    /* The named planes (render passes), under their own names; OpenEXR
     * keeps the list sorted, so a layer's channels sit together. */
    for (uint32_t i = 0; i < img->n_planes && rv == EXR_ERR_SUCCESS; i++)
        rv = exr_add_channel(ctx, part, img->planes[i].name, EXR_PIXEL_FLOAT,
                             EXR_PERCEPTUALLY_LINEAR, 1, 1);
    char software[80], samples[24];
    if (meta && meta->software[0])
        snprintf(software, sizeof software, "%s", meta->software);
    else
        snprintf(software, sizeof software, "ptfarm %s", PT_VERSION);
    /* OpenEXR 3.1 has no 64-bit integer attribute: the total goes as decimal text. */
    snprintf(samples, sizeof samples, "%" PRIu64, meta ? meta->total_samples : 0);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_attr_set_string(ctx, part, "software", software);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_attr_set_string(ctx, part, "ptfarm.samples", samples);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_attr_set_double(ctx, part, "ptfarm.renderSeconds",
                                 meta ? meta->render_seconds : 0.0);
    if (rv == EXR_ERR_SUCCESS && meta)
        rv = exr_attr_set_string(ctx, part, "ptfarm.sceneHash", meta->scene_hash);
    if (rv == EXR_ERR_SUCCESS && meta)
        rv = exr_attr_set_string(ctx, part, "ptfarm.jobId", meta->job_id);
    for (uint32_t i = 0; rv == EXR_ERR_SUCCESS && meta && i < meta->nattrs; i++)
        rv = exr_attr_set_string(ctx, part, meta->attrs[i].name, meta->attrs[i].value);
    if (rv == EXR_ERR_SUCCESS && meta && meta->has_frame) {
        exr_attr_rational_t fps = fps_rational(meta->fps);
        rv = exr_attr_set_int(ctx, part, "ptfarm.frame", meta->frame);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_double(ctx, part, "ptfarm.time", meta->time);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_rational(ctx, part, "framesPerSecond", &fps);
    }
    return rv;
}

/* Encodes every scanline chunk straight from the planar arrays. */
static exr_result_t write_chunks(exr_context_t ctx, const pt_image *img)
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(ctx, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (lines < 1)
        return EXR_ERR_INVALID_ARGUMENT;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int started = 0;
    int32_t stride = (int32_t)(img->width * sizeof(float));
    for (int32_t y = 0; y < (int32_t)img->height && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t cinfo;
        rv = exr_write_scanline_chunk_info(ctx, 0, y, &cinfo);
        if (rv != EXR_ERR_SUCCESS)
            break;
        rv = started ? exr_encoding_update(ctx, 0, &cinfo, &enc)
                     : exr_encoding_initialize(ctx, 0, &cinfo, &enc);
        if (rv != EXR_ERR_SUCCESS)
            break;
        for (int c = 0; c < enc.channel_count; c++) {
            exr_coding_channel_info_t *ch = &enc.channels[c];
            const float *plane = plane_of(img, ch->channel_name);
            if (!plane) {
                rv = EXR_ERR_INVALID_ARGUMENT;
                break;
            }
            ch->user_pixel_stride = (int32_t)sizeof(float);
            ch->user_line_stride = stride;
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = EXR_PIXEL_FLOAT;
            ch->encode_from_ptr = (const uint8_t *)(plane + (size_t)cinfo.start_y * img->width);
        }
        if (rv == EXR_ERR_SUCCESS && !started)
            rv = exr_encoding_choose_default_routines(ctx, 0, &enc);
        started = 1;
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_encoding_run(ctx, 0, &enc);
    }
    if (started) {
        exr_result_t rd = exr_encoding_destroy(ctx, &enc);
        if (rv == EXR_ERR_SUCCESS)
            rv = rd;
    }
    return rv;
}

pt_status pt_exr_write(const char *path, const pt_image *img, const pt_exr_meta *meta,
                       pt_error *err)
{
    if (!path || !img || img->width == 0 || img->height == 0 || img->width > PT_IMAGE_MAX_SIDE ||
        img->height > PT_IMAGE_MAX_SIDE)
        return pt_error_set(err, PT_ERR_ARG, "EXR %s: no image or a bad size",
                            path ? path : "(null)");
    pt_status st = PT_OK;
    exr_context_t ctx = NULL;
    exr_stream s = {.fd = -1};
    exr_context_initializer_t init;
    exr_result_t rv;
    pt_temp tmp;
    stream_init(&init, &s);
    init.write_fn = stream_write;

    /* An unpredictable name opened exclusively, never through a link
     * (common/base/fsutil.h), so a file planted in the output folder is not
     * written to. */
    if ((st = pt_temp_open(path, 0644, &tmp, err)) != PT_OK)
        return st;
    s.fd = tmp.fd;
    if ((rv = exr_start_write(&ctx, tmp.path, EXR_WRITE_FILE_DIRECTLY, &init)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot start writing");
        goto fail;
    }
    if ((rv = define_part(ctx, img, meta)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot define the header");
        goto fail;
    }
    if ((rv = exr_write_header(ctx)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot write the header");
        goto fail;
    }
    if ((rv = write_chunks(ctx, img)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot write the pixels");
        goto fail;
    }
    /* exr_finish writes the chunk offset table: the file is complete only after it. */
    rv = exr_finish(&ctx);
    ctx = NULL;
    if (rv != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot finish");
        goto fail;
    }
    /* fsync, rename over whatever is at path (a link is replaced, not
     * followed), fsync of the folder; the temporary goes on failure. */
    return pt_temp_commit(&tmp, path, err);

fail:
    if (ctx)
        exr_finish(&ctx);
    pt_temp_abort(&tmp);
    return st;
}

/* Copies an optional string attribute into dst (truncated to fit). */
static void meta_string(exr_const_context_t ctx, const char *name, char *dst, size_t cap)
{
    int32_t len = 0;
    const char *str = NULL;
    if (exr_attr_get_string(ctx, 0, name, &len, &str) == EXR_ERR_SUCCESS && str && len >= 0) {
        size_t n = (size_t)len < cap - 1 ? (size_t)len : cap - 1;
        memcpy(dst, str, n);
        dst[n] = '\0';
    }
}

static void read_meta(exr_const_context_t ctx, pt_exr_meta *meta)
{
    memset(meta, 0, sizeof *meta);
    meta_string(ctx, "software", meta->software, sizeof meta->software);
    meta_string(ctx, "ptfarm.sceneHash", meta->scene_hash, sizeof meta->scene_hash);
    meta_string(ctx, "ptfarm.jobId", meta->job_id, sizeof meta->job_id);
    double secs = 0.0;
    if (exr_attr_get_double(ctx, 0, "ptfarm.renderSeconds", &secs) == EXR_ERR_SUCCESS)
        meta->render_seconds = secs;
    int32_t frame = 0;
    if (exr_attr_get_int(ctx, 0, "ptfarm.frame", &frame) == EXR_ERR_SUCCESS) {
        exr_attr_rational_t fps = {0, 1};
        meta->has_frame = 1;
        meta->frame = frame;
        if (exr_attr_get_double(ctx, 0, "ptfarm.time", &secs) == EXR_ERR_SUCCESS)
            meta->time = secs;
        if (exr_attr_get_rational(ctx, 0, "framesPerSecond", &fps) == EXR_ERR_SUCCESS &&
            fps.denom > 0)
            meta->fps = (double)fps.num / (double)fps.denom;
    }
    char digits[24] = "";
    meta_string(ctx, "ptfarm.samples", digits, sizeof digits);
    if (digits[0] >= '0' && digits[0] <= '9') {
        char *end = NULL;
        errno = 0;
        unsigned long long v = strtoull(digits, &end, 10);
        if (errno == 0 && *end == '\0')
            meta->total_samples = v;
    }
}

/* Decodes every scanline chunk of part 0 into img, whose top row is data
 * window row min_y. Channels other than ours are decoded into scratch: the
 * specialised unpackers of OpenEXRCore 3.1 (four half channels, say) assume
 * every channel has a destination and crash on one that is skipped. */
static exr_result_t read_chunks(exr_const_context_t ctx, int32_t min_y, pt_image *img)
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(ctx, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (lines < 1 || lines > 4096)
        return EXR_ERR_FILE_BAD_HEADER;
    /* One chunk of one channel, 4 bytes a sample at most. */
    uint8_t *scratch = pt_malloc_array((size_t)img->width * (size_t)lines, sizeof(float));
    if (!scratch)
        return EXR_ERR_OUT_OF_MEMORY;
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    int started = 0;
    int32_t stride = (int32_t)(img->width * sizeof(float));
    int64_t end_y = (int64_t)min_y + img->height;
    for (int64_t y = min_y; y < end_y && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t cinfo;
        rv = exr_read_scanline_chunk_info(ctx, 0, (int)y, &cinfo);
        if (rv != EXR_ERR_SUCCESS)
            break;
        /* Never trust the chunk to stay inside the image we allocated. */
        int64_t row = (int64_t)cinfo.start_y - min_y;
        if (row < 0 || cinfo.height < 1 || cinfo.height > lines ||
            row + cinfo.height > (int64_t)img->height || cinfo.width != (int32_t)img->width) {
            rv = EXR_ERR_CORRUPT_CHUNK;
            break;
        }
        rv = started ? exr_decoding_update(ctx, 0, &cinfo, &dec)
                     : exr_decoding_initialize(ctx, 0, &cinfo, &dec);
        if (rv != EXR_ERR_SUCCESS)
            break;
        for (int c = 0; c < dec.channel_count; c++) {
            exr_coding_channel_info_t *ch = &dec.channels[c];
            float *plane = plane_of(img, ch->channel_name);
            if (ch->height > cinfo.height || ch->width > (int32_t)img->width ||
                ch->bytes_per_element < 1 || ch->bytes_per_element > 4) {
                rv = EXR_ERR_CORRUPT_CHUNK;
                break;
            }
            if (plane && (ch->height != cinfo.height || ch->width != (int32_t)img->width)) {
                rv = EXR_ERR_CORRUPT_CHUNK; /* ours are never subsampled (checked before) */
                break;
            }
            if (plane) {
                ch->user_bytes_per_element = (int16_t)sizeof(float);
                ch->user_data_type = EXR_PIXEL_FLOAT;
                ch->user_pixel_stride = (int32_t)sizeof(float);
                ch->user_line_stride = stride;
                ch->decode_to_ptr = (uint8_t *)(plane + (size_t)row * img->width);
            } else {
                ch->user_bytes_per_element = ch->bytes_per_element;
                ch->user_data_type = ch->data_type;
                ch->user_pixel_stride = ch->bytes_per_element;
                ch->user_line_stride = ch->bytes_per_element * (int32_t)img->width;
                ch->decode_to_ptr = scratch;
            }
        }
        if (rv == EXR_ERR_SUCCESS && !started)
            rv = exr_decoding_choose_default_routines(ctx, 0, &dec);
        started = 1;
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_decoding_run(ctx, 0, &dec);
    }
    if (started) {
        exr_result_t rd = exr_decoding_destroy(ctx, &dec);
        if (rv == EXR_ERR_SUCCESS)
            rv = rd;
    }
    pt_free(scratch);
    return rv;
}

static pt_status exr_read(const char *path, int follow, int layers, pt_image **out,
                          pt_exr_meta *meta, const char *attr, char **attr_out, pt_error *err)
{
    if (!path)
        return pt_error_set(err, PT_ERR_ARG, "EXR read: no path");
    pt_status st = PT_OK;
    exr_context_t ctx = NULL;
    pt_image *img = NULL;
    exr_stream s = {.fd = -1};
    exr_context_initializer_t init;
    exr_result_t rv;
    stream_init(&init, &s);
    init.read_fn = stream_read;
    init.size_fn = stream_size;
    init.max_image_width = PT_IMAGE_MAX_SIDE;
    init.max_image_height = PT_IMAGE_MAX_SIDE;
    /* A truncated file is an error, not something to guess around. */
    init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;

    pt_error oerr = {0};
    if ((st = pt_open_regular(path, follow, &s.fd, &oerr)) != PT_OK) {
        pt_error_set(err, st, "EXR %s", oerr.msg);
        if (err)
            err->sys_errno = oerr.sys_errno;
        return st;
    }
    struct stat sb;
    if (fstat(s.fd, &sb) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "EXR %s: stat", path);
        goto fail;
    }
    s.size = (int64_t)sb.st_size;
    if ((rv = exr_start_read(&ctx, path, &init)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "not a readable OpenEXR file");
        goto fail;
    }
    int parts = 0;
    exr_storage_t storage = EXR_STORAGE_LAST_TYPE;
    if ((rv = exr_get_count(ctx, &parts)) != EXR_ERR_SUCCESS || parts < 1 ||
        (rv = exr_get_storage(ctx, 0, &storage)) != EXR_ERR_SUCCESS) {
        st = rv ? exr_fail(err, &s, rv, path, "no image part")
                : pt_error_set(err, PT_ERR_FORMAT, "EXR %s: no image part", path);
        goto fail;
    }
    if (storage != EXR_STORAGE_SCANLINE) {
        st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: part 0 is %s; only scanline images are read",
                          path, storage == EXR_STORAGE_TILED ? "tiled" : "deep");
        goto fail;
    }
    exr_attr_box2i_t dw;
    if ((rv = exr_get_data_window(ctx, 0, &dw)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "no data window");
        goto fail;
    }
    int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
    if (w < 1 || h < 1 || w > PT_IMAGE_MAX_SIDE || h > PT_IMAGE_MAX_SIDE) {
        st = pt_error_set(err, w < 1 || h < 1 ? PT_ERR_FORMAT : PT_ERR_LIMIT,
                          "EXR %s: data window %" PRId64 "x%" PRId64 " is empty or over the cap",
                          path, w, h);
        goto fail;
    }
    /* Deflate, the strongest of the lossless codecs, expands a byte to at
     * most 1032; at 6 bytes a pixel (half R, G, B) that is 172 pixels a
     * byte. A header claiming more pixels than its file can hold is refused
     * before the allocation, so that a few hundred hostile bytes cannot make
     * the reader ask for gigabytes (a map arrives from clients). */
    if (out && (uint64_t)w * (uint64_t)h > (uint64_t)s.size * PT_EXR_MAX_PIXELS_PER_BYTE + 65536) {
        st = pt_error_set(err, PT_ERR_FORMAT,
                          "EXR %s: %" PRId64 "x%" PRId64 " pixels cannot be in %" PRId64 " bytes",
                          path, w, h, s.size);
        goto fail;
    }
    const exr_attr_chlist_t *chl = NULL;
    if ((rv = exr_get_channels(ctx, 0, &chl)) != EXR_ERR_SUCCESS || !chl) {
        st = rv ? exr_fail(err, &s, rv, path, "no channel list")
                : pt_error_set(err, PT_ERR_FORMAT, "EXR %s: no channel list", path);
        goto fail;
    }
    int have_rgb = 0;
    uint32_t has_alpha = 0, extra = 0;
    for (int i = 0; i < chl->num_channels; i++) {
        const exr_attr_chlist_entry_t *e = &chl->entries[i];
        const char *name = e->name.str ? e->name.str : "";
        int ours = !strcmp(name, "R") || !strcmp(name, "G") || !strcmp(name, "B") ||
                   !strcmp(name, "samples") || !strcmp(name, "variance") || !strcmp(name, "A");
        if (!ours && layers && e->x_sampling == 1 && e->y_sampling == 1 &&
            strlen(name) < PT_IMAGE_PLANE_NAME && extra < PT_IMAGE_MAX_PLANES)
            extra++; /* read into a named plane (the rest are skipped) */
        if (!ours)
            continue;
        has_alpha |= !strcmp(name, "A");
        if (e->x_sampling != 1 || e->y_sampling != 1) {
            st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: channel %s is subsampled", path, name);
            goto fail;
        }
        have_rgb += !strcmp(name, "R") || !strcmp(name, "G") || !strcmp(name, "B");
    }
    if (have_rgb != 3) {
        st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: channels R, G and B are required", path);
        goto fail;
    }
    /* Each named plane takes as much memory again as a base one: the same
     * bound on the file's pixels, over all the planes read. */
    if (out && extra > 0 &&
        (uint64_t)w * (uint64_t)h * (extra + 6) >
            ((uint64_t)s.size * PT_EXR_MAX_PIXELS_PER_BYTE + 65536) * 6) {
        st = pt_error_set(err, PT_ERR_FORMAT,
                          "EXR %s: %u layers' channels of %" PRId64 "x%" PRId64
                          " pixels cannot be in %" PRId64 " bytes",
                          path, extra, w, h, s.size);
        goto fail;
    }
    pt_error ierr = {0};
    if (out && (st = pt_image_new((uint32_t)w, (uint32_t)h, &img, &ierr)) != PT_OK) {
        pt_error_set(err, st, "EXR %s: %s", path, ierr.msg);
        goto fail;
    }
    for (int i = 0; img && extra > 0 && i < chl->num_channels; i++) {
        const exr_attr_chlist_entry_t *e = &chl->entries[i];
        const char *name = e->name.str ? e->name.str : "";
        if (plane_of(img, name) || e->x_sampling != 1 || e->y_sampling != 1 ||
            strlen(name) >= PT_IMAGE_PLANE_NAME || img->n_planes >= PT_IMAGE_MAX_PLANES)
            continue;
        /* A name the image refuses (a control byte) is skipped, not fatal. */
        pt_status pst = pt_image_add_plane(img, name, NULL, &ierr);
        if (pst == PT_ERR_NOMEM) {
            st = pt_error_set(err, pst, "EXR %s: %s", path, ierr.msg);
            goto fail;
        }
    }
    if (img)
        img->has_alpha = has_alpha;
    if (out && (rv = read_chunks(ctx, dw.min.y, img)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot decode the pixels");
        goto fail;
    }
    if (meta)
        read_meta(ctx, meta);
    if (attr) {
        int32_t alen = 0;
        const char *str = NULL;
        if (exr_attr_get_string(ctx, 0, attr, &alen, &str) != EXR_ERR_SUCCESS || !str || alen < 0) {
            st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: no string attribute %s", path, attr);
            goto fail;
        }
        char *copy = pt_malloc((size_t)alen + 1);
        if (!copy) {
            st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: attribute %s: out of memory", path, attr);
            goto fail;
        }
        memcpy(copy, str, (size_t)alen);
        copy[alen] = '\0';
        *attr_out = copy;
    }
    exr_finish(&ctx);
    close(s.fd);
    if (out)
        *out = img;
    return PT_OK;

fail:
    pt_image_free(img);
    if (ctx)
        exr_finish(&ctx);
    close(s.fd);
    return st;
}

pt_status pt_exr_read(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err)
{
    return exr_read(path, 1, 0, out, meta, NULL, NULL, err);
}

pt_status pt_exr_read_attr(const char *path, const char *name, char **out, pt_error *err)
{
    return exr_read(path, 1, 0, NULL, NULL, name, out, err);
}

pt_status pt_exr_read_layers(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err)
{
    return exr_read(path, 1, 1, out, meta, NULL, NULL, err);
}

pt_status pt_exr_read_nofollow(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err)
{
    return exr_read(path, 0, 0, out, meta, NULL, NULL, err);
}
