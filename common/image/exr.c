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

/* Declares the part, channels and attributes of the file being written. */
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

/* Points channel ch of a chunk at the caller's pixels for its rows from
 * row (counted from the data window's top); EXR_ERR_INVALID_ARGUMENT for a
 * channel the caller has no pixels for. */
typedef exr_result_t (*exr_bind_fn)(const void *user, exr_coding_channel_info_t *ch, size_t row);

/* Encodes every scanline chunk of part 0 (rows min_y .. min_y + height - 1),
 * each channel straight from where bind points it. */
static exr_result_t encode_chunks(exr_context_t ctx, int64_t min_y, int64_t height,
                                  exr_bind_fn bind, const void *user)
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(ctx, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (lines < 1)
        return EXR_ERR_INVALID_ARGUMENT;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int started = 0;
    for (int64_t y = min_y; y < min_y + height && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t cinfo;
        rv = exr_write_scanline_chunk_info(ctx, 0, (int)y, &cinfo);
        if (rv != EXR_ERR_SUCCESS)
            break;
        rv = started ? exr_encoding_update(ctx, 0, &cinfo, &enc)
                     : exr_encoding_initialize(ctx, 0, &cinfo, &enc);
        if (rv != EXR_ERR_SUCCESS)
            break;
        size_t row = (size_t)((int64_t)cinfo.start_y - min_y);
        for (int c = 0; c < enc.channel_count && rv == EXR_ERR_SUCCESS; c++)
            rv = bind(user, &enc.channels[c], row);
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

/* Writes path as one file. A temporary with an unpredictable name, opened
 * exclusively and never through a link (common/base/fsutil.h), so a file
 * planted in the output folder is not written to; define declares part 0,
 * pixels encodes its chunks; then fsync, a rename over whatever is at path
 * (a link is replaced, not followed) and fsync of the folder. The temporary
 * goes on failure. */
static pt_status write_file(const char *path, exr_result_t (*define)(exr_context_t, const void *),
                            exr_result_t (*pixels)(exr_context_t, const void *), const void *user,
                            pt_error *err)
{
    pt_status st = PT_OK;
    exr_context_t ctx = NULL;
    exr_stream s = {.fd = -1};
    exr_context_initializer_t init;
    exr_result_t rv;
    pt_temp tmp;
    stream_init(&init, &s);
    init.write_fn = stream_write;
    if ((st = pt_temp_open(path, 0644, &tmp, err)) != PT_OK)
        return st;
    s.fd = tmp.fd;
    if ((rv = exr_start_write(&ctx, tmp.path, EXR_WRITE_FILE_DIRECTLY, &init)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot start writing");
        goto fail;
    }
    if ((rv = define(ctx, user)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot define the header");
        goto fail;
    }
    if ((rv = exr_write_header(ctx)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &s, rv, path, "cannot write the header");
        goto fail;
    }
    if ((rv = pixels(ctx, user)) != EXR_ERR_SUCCESS) {
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
    return pt_temp_commit(&tmp, path, err);

fail:
    if (ctx)
        exr_finish(&ctx);
    pt_temp_abort(&tmp);
    return st;
}

/* pt_exr_write's image and header, for write_file. */
typedef struct image_out {
    const pt_image *img;
    const pt_exr_meta *meta;
} image_out;

static exr_result_t bind_plane(const void *user, exr_coding_channel_info_t *ch, size_t row)
{
    const pt_image *img = ((const image_out *)user)->img;
    const float *plane = plane_of(img, ch->channel_name);
    if (!plane)
        return EXR_ERR_INVALID_ARGUMENT;
    ch->user_pixel_stride = (int32_t)sizeof(float);
    ch->user_line_stride = (int32_t)(img->width * sizeof(float));
    ch->user_bytes_per_element = (int16_t)sizeof(float);
    ch->user_data_type = EXR_PIXEL_FLOAT;
    ch->encode_from_ptr = (const uint8_t *)(plane + row * img->width);
    return EXR_ERR_SUCCESS;
}

static exr_result_t image_define(exr_context_t ctx, const void *user)
{
    const image_out *o = user;
    return define_part(ctx, o->img, o->meta);
}

static exr_result_t image_pixels(exr_context_t ctx, const void *user)
{
    return encode_chunks(ctx, 0, ((const image_out *)user)->img->height, bind_plane, user);
}

pt_status pt_exr_write(const char *path, const pt_image *img, const pt_exr_meta *meta,
                       pt_error *err)
{
    if (!path || !img || img->width == 0 || img->height == 0 || img->width > PT_IMAGE_MAX_SIDE ||
        img->height > PT_IMAGE_MAX_SIDE)
        return pt_error_set(err, PT_ERR_ARG, "EXR %s: no image or a bad size",
                            path ? path : "(null)");
    image_out o = {img, meta};
    return write_file(path, image_define, image_pixels, &o, err);
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

/* An EXR opened for reading every channel of part 0, its layout checked. */
typedef struct exr_src {
    exr_context_t ctx;
    exr_stream s;
    exr_attr_box2i_t dw;
    uint32_t w, h;
    const exr_attr_chlist_t *chl;
} exr_src;

static void src_close(exr_src *src)
{
    if (src->ctx)
        exr_finish(&src->ctx);
    if (src->s.fd >= 0)
        close(src->s.fd);
    src->s.fd = -1;
}

/* Opens path (through a link at its last component only when follow) and
 * checks its layout: part 0 a scanline image, a data window within the caps,
 * a channel list. max_pixels is 0 when only the header will be read; else
 * the pixels will be decoded, and the window must hold at most max_pixels
 * and be possible in the file's bytes. */
static pt_status src_open(const char *path, int follow, uint64_t max_pixels, exr_src *src,
                          pt_error *err)
{
    memset(src, 0, sizeof *src);
    src->s.fd = -1;
    if (!path)
        return pt_error_set(err, PT_ERR_ARG, "EXR read: no path");
    exr_context_initializer_t init;
    exr_result_t rv;
    pt_status st;
    stream_init(&init, &src->s);
    init.read_fn = stream_read;
    init.size_fn = stream_size;
    init.max_image_width = PT_IMAGE_MAX_SIDE;
    init.max_image_height = PT_IMAGE_MAX_SIDE;
    /* A truncated file is an error, not something to guess around. */
    init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;
    pt_error oerr = {0};
    if ((st = pt_open_regular(path, follow, &src->s.fd, &oerr)) != PT_OK) {
        pt_error_set(err, st, "EXR %s", oerr.msg);
        if (err)
            err->sys_errno = oerr.sys_errno;
        src->s.fd = -1;
        return st;
    }
    struct stat sb;
    if (fstat(src->s.fd, &sb) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "EXR %s: stat", path);
        goto fail;
    }
    src->s.size = (int64_t)sb.st_size;
    if ((rv = exr_start_read(&src->ctx, path, &init)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &src->s, rv, path, "not a readable OpenEXR file");
        goto fail;
    }
    int parts = 0;
    exr_storage_t storage = EXR_STORAGE_LAST_TYPE;
    if ((rv = exr_get_count(src->ctx, &parts)) != EXR_ERR_SUCCESS || parts < 1 ||
        (rv = exr_get_storage(src->ctx, 0, &storage)) != EXR_ERR_SUCCESS) {
        st = rv ? exr_fail(err, &src->s, rv, path, "no image part")
                : pt_error_set(err, PT_ERR_FORMAT, "EXR %s: no image part", path);
        goto fail;
    }
    if (storage != EXR_STORAGE_SCANLINE) {
        st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: part 0 is %s; only scanline images are read",
                          path, storage == EXR_STORAGE_TILED ? "tiled" : "deep");
        goto fail;
    }
    if ((rv = exr_get_data_window(src->ctx, 0, &src->dw)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &src->s, rv, path, "no data window");
        goto fail;
    }
    int64_t w = (int64_t)src->dw.max.x - src->dw.min.x + 1,
            h = (int64_t)src->dw.max.y - src->dw.min.y + 1;
    if (w < 1 || h < 1 || w > PT_IMAGE_MAX_SIDE || h > PT_IMAGE_MAX_SIDE ||
        (max_pixels && (uint64_t)w * (uint64_t)h > max_pixels)) {
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
    if (max_pixels &&
        (uint64_t)w * (uint64_t)h > (uint64_t)src->s.size * PT_EXR_MAX_PIXELS_PER_BYTE + 65536) {
        st = pt_error_set(err, PT_ERR_FORMAT,
                          "EXR %s: %" PRId64 "x%" PRId64 " pixels cannot be in %" PRId64 " bytes",
                          path, w, h, src->s.size);
        goto fail;
    }
    if ((rv = exr_get_channels(src->ctx, 0, &src->chl)) != EXR_ERR_SUCCESS || !src->chl ||
        src->chl->num_channels < 1) {
        st = rv ? exr_fail(err, &src->s, rv, path, "no channel list")
                : pt_error_set(err, PT_ERR_FORMAT, "EXR %s: no channel list", path);
        goto fail;
    }
    src->w = (uint32_t)w;
    src->h = (uint32_t)h;
    return PT_OK;
fail:
    src_close(src);
    return st;
}

/* src_open for reading or copying every channel: none may be subsampled. */
static pt_status src_open_full(const char *path, exr_src *src, pt_error *err)
{
    pt_status st = src_open(path, 1, PT_IMAGE_MAX_PIXELS, src, err);
    for (int i = 0; st == PT_OK && i < src->chl->num_channels; i++) {
        const exr_attr_chlist_entry_t *e = &src->chl->entries[i];
        if (e->x_sampling != 1 || e->y_sampling != 1) {
            st = pt_error_set(err, PT_ERR_FORMAT, "EXR %s: channel %s is subsampled", path,
                              e->name.str ? e->name.str : "");
            src_close(src);
        }
    }
    return st;
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
    exr_src src;
    pt_status st = src_open(path, follow, out ? UINT64_MAX : 0, &src, err);
    if (st != PT_OK)
        return st;
    exr_context_t ctx = src.ctx;
    int64_t w = src.w, h = src.h;
    const exr_attr_chlist_t *chl = src.chl;
    pt_image *img = NULL;
    exr_result_t rv;
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
            ((uint64_t)src.s.size * PT_EXR_MAX_PIXELS_PER_BYTE + 65536) * 6) {
        st = pt_error_set(err, PT_ERR_FORMAT,
                          "EXR %s: %u layers' channels of %" PRId64 "x%" PRId64
                          " pixels cannot be in %" PRId64 " bytes",
                          path, extra, w, h, src.s.size);
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
    if (out && (rv = read_chunks(ctx, src.dw.min.y, img)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &src.s, rv, path, "cannot decode the pixels");
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
    src_close(&src);
    if (out)
        *out = img;
    return PT_OK;

fail:
    pt_image_free(img);
    src_close(&src);
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

/* ---- named channels ---- */

static int chl_index(const exr_attr_chlist_t *chl, const char *name)
{
    for (int i = 0; i < chl->num_channels; i++)
        if (chl->entries[i].name.str && !strcmp(chl->entries[i].name.str, name))
            return i;
    return -1;
}

static int pixel_bytes(exr_pixel_type_t t)
{
    return t == EXR_PIXEL_HALF ? 2 : 4;
}

/* Decodes every chunk: channel i of the list into dst[i] (rows of w
 * elements, float when as_float[i], else its own type), or nowhere when
 * dst[i] is NULL. */
static exr_result_t src_decode(exr_src *src, uint8_t *const dst[], const int as_float[])
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(src->ctx, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (lines < 1 || lines > 256)
        return EXR_ERR_INVALID_ATTR;
    /* Channels we do not keep still decode somewhere: one chunk's rows. */
    uint8_t *scratch = pt_malloc_array((size_t)lines * src->w, 4);
    if (!scratch)
        return EXR_ERR_OUT_OF_MEMORY;
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    int started = 0;
    int64_t end_y = (int64_t)src->dw.min.y + src->h;
    for (int64_t y = src->dw.min.y; y < end_y && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t cinfo;
        rv = exr_read_scanline_chunk_info(src->ctx, 0, (int)y, &cinfo);
        if (rv != EXR_ERR_SUCCESS)
            break;
        int64_t row = (int64_t)cinfo.start_y - src->dw.min.y;
        if (row < 0 || cinfo.height < 1 || cinfo.height > lines ||
            row + cinfo.height > (int64_t)src->h || cinfo.width != (int32_t)src->w) {
            rv = EXR_ERR_CORRUPT_CHUNK;
            break;
        }
        rv = started ? exr_decoding_update(src->ctx, 0, &cinfo, &dec)
                     : exr_decoding_initialize(src->ctx, 0, &cinfo, &dec);
        if (rv != EXR_ERR_SUCCESS)
            break;
        for (int c = 0; c < dec.channel_count; c++) {
            exr_coding_channel_info_t *ch = &dec.channels[c];
            int i = chl_index(src->chl, ch->channel_name ? ch->channel_name : "");
            if (i < 0 || ch->height != cinfo.height || ch->width != (int32_t)src->w ||
                ch->bytes_per_element < 1 || ch->bytes_per_element > 4) {
                rv = EXR_ERR_CORRUPT_CHUNK;
                break;
            }
            int16_t bpe = dst[i] && as_float[i] ? 4 : ch->bytes_per_element;
            ch->user_bytes_per_element = bpe;
            ch->user_data_type = dst[i] && as_float[i] ? EXR_PIXEL_FLOAT : ch->data_type;
            ch->user_pixel_stride = bpe;
            ch->user_line_stride = bpe * (int32_t)src->w;
            ch->decode_to_ptr = dst[i] ? dst[i] + (size_t)row * src->w * (size_t)bpe : scratch;
        }
        if (rv == EXR_ERR_SUCCESS && !started)
            rv = exr_decoding_choose_default_routines(src->ctx, 0, &dec);
        started = 1;
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_decoding_run(src->ctx, 0, &dec);
    }
    if (started) {
        exr_result_t rd = exr_decoding_destroy(src->ctx, &dec);
        if (rv == EXR_ERR_SUCCESS)
            rv = rd;
    }
    pt_free(scratch);
    return rv;
}

pt_status pt_exr_read_channels(const char *path, unsigned n, const char *const names[],
                               float *planes[], uint32_t *width, uint32_t *height, pt_error *err)
{
    if (n > PT_EXR_MAX_CHANNELS || (n && (!names || !planes)))
        return pt_error_set(err, PT_ERR_ARG, "EXR read: %u channels asked, at most %u", n,
                            PT_EXR_MAX_CHANNELS);
    exr_src src;
    pt_status st = src_open_full(path, &src, err);
    if (st != PT_OK)
        return st;
    int nch = src.chl->num_channels;
    uint8_t **dst = pt_calloc((size_t)nch, sizeof *dst);
    int *as_float = pt_calloc((size_t)nch, sizeof *as_float);
    float **got = pt_calloc(n ? n : 1, sizeof *got);
    if (!dst || !as_float || !got) {
        st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: out of memory", path);
        goto done;
    }
    size_t npix = (size_t)src.w * src.h;
    for (unsigned i = 0; i < n; i++) {
        int c = names[i] ? chl_index(src.chl, names[i]) : -1;
        if (c < 0)
            continue;
        if (!dst[c]) {
            dst[c] = pt_malloc_array(npix, sizeof(float));
            if (!dst[c]) {
                st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: out of memory for %ux%u", path, src.w,
                                  src.h);
                goto done;
            }
            as_float[c] = 1;
        }
    }
    exr_result_t rv = src_decode(&src, dst, as_float);
    if (rv != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &src.s, rv, path, "cannot decode the pixels");
        goto done;
    }
    /* A name asked twice gets its own copy, so each plane is freed once. */
    for (unsigned i = 0; i < n; i++) {
        int c = names[i] ? chl_index(src.chl, names[i]) : -1;
        if (c < 0)
            continue;
        if (dst[c]) {
            got[i] = (float *)(void *)dst[c];
            dst[c] = NULL;
            continue;
        }
        unsigned j = 0;
        while (j < i && !(got[j] && !strcmp(names[j], names[i])))
            j++;
        got[i] = pt_malloc_array(npix, sizeof(float));
        if (!got[i]) {
            st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: out of memory", path);
            goto done;
        }
        memcpy(got[i], got[j], npix * sizeof(float));
    }
    for (unsigned i = 0; i < n; i++)
        planes[i] = got[i];
    *width = src.w;
    *height = src.h;
done:
    if (st != PT_OK && got)
        for (unsigned i = 0; i < n; i++)
            pt_free(got[i]);
    if (dst)
        for (int c = 0; c < nch; c++)
            pt_free(dst[c]);
    pt_free(dst);
    pt_free(as_float);
    pt_free(got);
    src_close(&src);
    return st;
}

/* The header of dst: src's required attributes (ZIP compression), src's
 * channels but the replaced ones, the new ones, then every other attribute
 * of src. */
static exr_result_t define_copy(exr_context_t ctx, const exr_src *src, unsigned n,
                                const char *const names[], const int keep[])
{
    int part = 0;
    exr_attr_box2i_t disp;
    float par = 1.0f, sww = 1.0f;
    exr_attr_v2f_t swc = {{{0.0f, 0.0f}}};
    exr_lineorder_t lo = EXR_LINEORDER_INCREASING_Y;
    exr_result_t rv = exr_add_part(ctx, NULL, EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_get_display_window(src->ctx, 0, &disp);
    if (rv == EXR_ERR_SUCCESS) {
        /* Optional in practice: the library's defaults where src lacks them. */
        exr_get_pixel_aspect_ratio(src->ctx, 0, &par);
        exr_get_screen_window_center(src->ctx, 0, &swc);
        exr_get_screen_window_width(src->ctx, 0, &sww);
        exr_get_lineorder(src->ctx, 0, &lo);
        if (lo != EXR_LINEORDER_INCREASING_Y && lo != EXR_LINEORDER_DECREASING_Y)
            lo = EXR_LINEORDER_INCREASING_Y;
        rv = exr_initialize_required_attr(ctx, part, &disp, &src->dw, par, &swc, sww, lo,
                                          EXR_COMPRESSION_ZIP);
    }
    for (int i = 0; i < src->chl->num_channels && rv == EXR_ERR_SUCCESS; i++) {
        const exr_attr_chlist_entry_t *e = &src->chl->entries[i];
        if (keep[i])
            rv = exr_add_channel(ctx, part, e->name.str, e->pixel_type, e->p_linear ? 1 : 0, 1, 1);
    }
    for (unsigned i = 0; i < n && rv == EXR_ERR_SUCCESS; i++)
        rv = exr_add_channel(ctx, part, names[i], EXR_PIXEL_FLOAT, EXR_PERCEPTUALLY_LOGARITHMIC, 1,
                             1);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_copy_unset_attributes(ctx, part, src->ctx, 0);
    return rv;
}

/* pt_exr_write_with_channels' source, its kept planes and the new ones. */
typedef struct copy_out {
    const exr_src *src;
    uint8_t *const *kept;
    const int *keep;
    unsigned n;
    const char *const *names;
    const float *const *planes;
} copy_out;

static exr_result_t bind_copy(const void *user, exr_coding_channel_info_t *ch, size_t row)
{
    const copy_out *o = user;
    const uint8_t *from = NULL;
    int16_t bpe = 4;
    exr_pixel_type_t type = EXR_PIXEL_FLOAT;
    for (unsigned i = 0; i < o->n && !from; i++)
        if (!strcmp(o->names[i], ch->channel_name))
            from = (const uint8_t *)o->planes[i];
    if (!from) {
        int i = chl_index(o->src->chl, ch->channel_name);
        if (i < 0 || !o->kept[i])
            return EXR_ERR_INVALID_ARGUMENT;
        from = o->kept[i];
        type = o->src->chl->entries[i].pixel_type;
        bpe = (int16_t)pixel_bytes(type);
    }
    ch->user_pixel_stride = bpe;
    ch->user_line_stride = bpe * (int32_t)o->src->w;
    ch->user_bytes_per_element = bpe;
    ch->user_data_type = (uint16_t)type;
    ch->encode_from_ptr = from + row * o->src->w * (size_t)bpe;
    return EXR_ERR_SUCCESS;
}

static exr_result_t copy_define(exr_context_t ctx, const void *user)
{
    const copy_out *o = user;
    return define_copy(ctx, o->src, o->n, o->names, o->keep);
}

static exr_result_t copy_pixels(exr_context_t ctx, const void *user)
{
    const copy_out *o = user;
    return encode_chunks(ctx, o->src->dw.min.y, o->src->h, bind_copy, user);
}

pt_status pt_exr_write_with_channels(const char *src_path, const char *dst_path, unsigned n,
                                     const char *const names[], const float *const planes[],
                                     pt_error *err)
{
    if (!dst_path || n > PT_EXR_MAX_CHANNELS || (n && (!names || !planes)))
        return pt_error_set(err, PT_ERR_ARG, "EXR write: no path or bad channels");
    for (unsigned i = 0; i < n; i++)
        if (!names[i] || !names[i][0] || !planes[i])
            return pt_error_set(err, PT_ERR_ARG, "EXR %s: channel %u has no name or pixels",
                                dst_path, i);
    exr_src src;
    pt_status st = src_open_full(src_path, &src, err);
    if (st != PT_OK)
        return st;
    int nch = src.chl->num_channels;
    exr_result_t rv;
    uint8_t **kept = pt_calloc((size_t)nch, sizeof *kept);
    int *keep = pt_calloc((size_t)nch, sizeof *keep),
        *as_float = pt_calloc((size_t)nch, sizeof *as_float);
    if (!kept || !keep || !as_float) {
        st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: out of memory", src_path);
        goto done;
    }
    for (int i = 0; i < nch; i++) {
        const exr_attr_chlist_entry_t *e = &src.chl->entries[i];
        keep[i] = 1;
        for (unsigned j = 0; j < n; j++)
            keep[i] &= strcmp(names[j], e->name.str ? e->name.str : "") != 0;
        if (!keep[i])
            continue;
        kept[i] = pt_malloc_array((size_t)src.w * src.h, (size_t)pixel_bytes(e->pixel_type));
        if (!kept[i]) {
            st = pt_error_set(err, PT_ERR_NOMEM, "EXR %s: out of memory", src_path);
            goto done;
        }
    }
    if ((rv = src_decode(&src, kept, as_float)) != EXR_ERR_SUCCESS) {
        st = exr_fail(err, &src.s, rv, src_path, "cannot decode the pixels");
        goto done;
    }
    copy_out o = {&src, kept, keep, n, names, planes};
    st = write_file(dst_path, copy_define, copy_pixels, &o, err);
done:
    if (kept)
        for (int i = 0; i < nch; i++)
            pt_free(kept[i]);
    pt_free(kept);
    pt_free(keep);
    pt_free(as_float);
    src_close(&src);
    return st;
}
