/*
 * exr.h - OpenEXR output and input through OpenEXRCore (OpenEXR 3's C API).
 *
 * Channels written: R, G, B (mean radiance), "samples" (per-pixel sample count)
 * and "variance" (variance of the pixel mean, luminance), and A (coverage; RGB
 * premultiplied by it) when the image has_alpha, all FLOAT, scanline,
 * ZIP compression; then the image's named planes (render passes: "albedo.R",
 * "N.X", ...), FLOAT, under their names. Header attributes: "ptfarm.samples" (total samples, as a
 * decimal string), "ptfarm.renderSeconds" (double), "ptfarm.sceneHash"
 * (string), "ptfarm.jobId" (string), and the standard "software" string; a
 * frame of an animation also "ptfarm.frame" (int, the frame number),
 * "ptfarm.time" (double, seconds into the animation) and the standard
 * "framesPerSecond" (rational: R/1 for a whole rate, else R x 1000 / 1000,
 * or 24000/1001-style for the NTSC rates).
 * Writes are atomic: a temp file in the same folder, fsync, rename, so a
 * reader never sees a torn file.
 *
 * Threads: any thread may call them on its own images and paths (the
 * coordinator's writer thread, a worker's main thread, the tests).
 */
#ifndef PT_COMMON_IMAGE_EXR_H
#define PT_COMMON_IMAGE_EXR_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/image/image.h"

/* A string attribute written into the header as it is (Cryptomatte's
 * cryptomatte/<key>/...). */
typedef struct pt_exr_attr {
    const char *name, *value;
} pt_exr_attr;

typedef struct pt_exr_meta {
    uint64_t total_samples;
    double render_seconds;
    char scene_hash[65];
    char job_id[64];
    char software[64]; /* "ptfarm <version>" when empty on write */
    int has_frame;     /* a frame of an animation: the three below are written */
    int32_t frame;
    double time;              /* seconds */
    double fps;               /* read back from the rational */
    const pt_exr_attr *attrs; /* written only: nattrs more string attributes */
    uint32_t nattrs;
} pt_exr_meta;

pt_status pt_exr_write(const char *path, const pt_image *img, const pt_exr_meta *meta,
                       pt_error *err);

/* The most pixels pt_exr_read decodes per byte of file: more than a
 * lossless codec can pack (see exr.c), so a header that claims them is
 * refused before any pixel memory is taken. */
#define PT_EXR_MAX_PIXELS_PER_BYTE 256u

/* Reads a file written by pt_exr_write (or any scanline/tiled EXR with R, G,
 * B; samples, variance and A planes are zero when absent, has_alpha says
 * whether A was there). meta may be NULL.
 * out NULL reads the header alone (meta, after the same checks of the
 * layout), decoding no pixel. A data window of more than
 * PT_EXR_MAX_PIXELS_PER_BYTE pixels per byte of the file (plus 65536) is
 * PT_ERR_FORMAT. */
pt_status pt_exr_read(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err);

/* pt_exr_read that also reads every other channel that is not subsampled
 * and has a name of at most 31 bytes (the first PT_IMAGE_MAX_PLANES of them,
 * in the file's order: sorted by name) into the image's named planes,
 * converted to float: the render passes of a ptfarm EXR, for ptdenoise and
 * the tests. The bound on pixels per byte holds over all the planes read. */
pt_status pt_exr_read_layers(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err);

/* The string attribute `name` of the file's header into *out (pt_malloc'd,
 * NUL-terminated): PT_OK, or PT_ERR_FORMAT when there is none (or not a
 * string), or the errors of pt_exr_read's header. */
pt_status pt_exr_read_attr(const char *path, const char *name, char **out, pt_error *err);

/* pt_exr_read that refuses a symbolic link at path's last component
 * (PT_ERR_FORMAT), for images in a folder that others may write to: the
 * output folder the dashboard and a restart read from. Neither read opens
 * anything but a regular file, and a FIFO never blocks them. */
pt_status pt_exr_read_nofollow(const char *path, pt_image **out, pt_exr_meta *meta, pt_error *err);

/* Named channels (layers), for the passes: "albedo.R", "N.X", "denoised.G".
 *
 * pt_exr_read_channels reads the channels names[0..n-1] of part 0 of path
 * (a scanline EXR, any pixel type) as float planes of *width x *height:
 * planes[i] is pt_malloc'd (pt_free), or NULL when the file has no channel
 * names[i]. The same checks of the layout as pt_exr_read (and a channel
 * that is subsampled is PT_ERR_FORMAT); on failure nothing is allocated and
 * the out-parameters are untouched. n at most PT_EXR_MAX_CHANNELS. */
#define PT_EXR_MAX_CHANNELS 1024u
pt_status pt_exr_read_channels(const char *path, unsigned n, const char *const names[],
                               float *planes[], uint32_t *width, uint32_t *height, pt_error *err);

/* Writes dst (atomically, as pt_exr_write) as a copy of src with n float
 * channels added: every channel of src in its own pixel type, bit for bit,
 * and every header attribute of src, plus names[i] from planes[i] (src's
 * size; a channel of src with the same name is replaced). ZIP compression.
 * dst may be src. */
pt_status pt_exr_write_with_channels(const char *src, const char *dst, unsigned n,
                                     const char *const names[], const float *const planes[],
                                     pt_error *err);

#endif
