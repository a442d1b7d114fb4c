#include "common/image/envmap.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/image/exr.h"
#include "common/image/image.h"

static int is_radiance(const uint8_t *d, size_t n)
{
    return (n >= 10 && memcmp(d, "#?RADIANCE", 10) == 0) || (n >= 6 && memcmp(d, "#?RGBE", 6) == 0);
}

static int is_exr(const uint8_t *d, size_t n)
{
    return n >= 4 && d[0] == 0x76 && d[1] == 0x2f && d[2] == 0x31 && d[3] == 0x01;
}

/* The checks every map passes, whatever it was read from. */
static pt_status check_map(const pt_envmap *m, const char *name, pt_error *err)
{
    if (m->width == 0 || m->height == 0)
        return pt_error_set(err, PT_ERR_FORMAT, "%s: the map is empty (%ux%u)", name, m->width,
                            m->height);
    if (m->width > PT_ENVMAP_MAX_SIDE || m->height > PT_ENVMAP_MAX_SIDE)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: %ux%u is over the cap of %u a side", name,
                            m->width, m->height, PT_ENVMAP_MAX_SIDE);
    uint64_t w = m->width, h2 = 2u * (uint64_t)m->height;
    if (w + 1 < h2 || w > h2 + 1)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: %ux%u is not an equirectangular map (width twice the height)",
                            name, m->width, m->height);
    size_t n = (size_t)m->width * m->height * 3;
    for (size_t i = 0; i < n; i++) {
        float v = m->rgb[i];
        if (!(v >= 0.0f && v <= PT_ENVMAP_MAX_VALUE)) {
            size_t px = i / 3;
            return pt_error_set(
                err, PT_ERR_FORMAT, "%s: pixel (%zu, %zu) has %g, not a radiance in [0, %g]", name,
                px % m->width, px / m->width, (double)v, (double)PT_ENVMAP_MAX_VALUE);
        }
    }
    return PT_OK;
}

/* A cursor over the bytes; the decoder never reads past end. */
typedef struct cursor {
    const uint8_t *p, *end;
} cursor;

/* The next header line (without its '\n') into line; 0 at the end of the
 * bytes or for a line longer than cap - 1. */
static int next_line(cursor *c, char *line, size_t cap)
{
    size_t n = 0;
    while (c->p < c->end && *c->p != '\n') {
        if (n + 1 >= cap)
            return 0;
        line[n++] = (char)*c->p++;
    }
    if (c->p >= c->end)
        return 0;
    c->p++;
    line[n] = '\0';
    return 1;
}

/* One scanline of w RGBE texels into out (4 bytes each): the "new" run-
 * length form (2, 2, w >> 8, w & 255, then each channel's runs) or flat
 * texels. Returns NULL when the bytes end early or a run overflows the
 * line. Ward, "Real Pixels", Graphics Gems II (1991), and the Radiance
 * source's file format notes. */
static const char *scanline(cursor *c, uint32_t w, uint8_t *out)
{
    if (c->end - c->p < 4)
        return "the pixels end early";
    const uint8_t *q = c->p;
    if (w < 8 || w > 0x7fff || q[0] != 2 || q[1] != 2 || (q[2] & 0x80) ||
        (((uint32_t)q[2] << 8) | q[3]) != w) {
        if ((size_t)(c->end - c->p) < (size_t)w * 4)
            return "the pixels end early";
        memcpy(out, c->p, (size_t)w * 4);
        c->p += (size_t)w * 4;
        return NULL;
    }
    c->p += 4;
    for (int ch = 0; ch < 4; ch++) {
        uint32_t x = 0;
        while (x < w) {
            if (c->p >= c->end)
                return "the pixels end early";
            uint32_t count = *c->p++;
            if (count > 128) {
                count -= 128;
                if (count > w - x)
                    return "a run overflows its scanline";
                if (c->p >= c->end)
                    return "the pixels end early";
                uint8_t v = *c->p++;
                for (uint32_t k = 0; k < count; k++)
                    out[4 * (x + k) + (uint32_t)ch] = v;
            } else {
                if (count == 0 || count > w - x)
                    return "a run overflows its scanline";
                if ((uint32_t)(c->end - c->p) < count)
                    return "the pixels end early";
                for (uint32_t k = 0; k < count; k++)
                    out[4 * (x + k) + (uint32_t)ch] = c->p[k];
                c->p += count;
            }
            x += count;
        }
    }
    return NULL;
}

pt_status pt_envmap_decode(const uint8_t *data, size_t n, const char *name, pt_envmap *out,
                           pt_error *err)
{
    memset(out, 0, sizeof *out);
    if (is_exr(data, n))
        return pt_error_set(err, PT_ERR_FORMAT, "%s: an EXR map is read from its file", name);
    if (!is_radiance(data, n))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: not an environment map (a Radiance .hdr or an OpenEXR file)",
                            name);
    if (n > PT_ENVMAP_MAX_BYTES)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: %zu bytes is over the cap", name, n);
    cursor c = {data, data + n};
    char line[256];
    int lines = 0;
    for (;;) {
        if (!next_line(&c, line, sizeof line) || ++lines > 1000)
            return pt_error_set(err, PT_ERR_FORMAT, "%s: the Radiance header does not end", name);
        if (line[0] == '\0')
            break;
        if (strncmp(line, "FORMAT=", 7) == 0 && strcmp(line + 7, "32-bit_rle_rgbe") != 0)
            return pt_error_set(err, PT_ERR_FORMAT, "%s: FORMAT=%.40s is not 32-bit_rle_rgbe", name,
                                line + 7);
    }
    unsigned long h = 0, w = 0;
    char tail;
    if (!next_line(&c, line, sizeof line) || sscanf(line, "-Y %lu +X %lu%c", &h, &w, &tail) != 2)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: the resolution line is not '-Y HEIGHT +X WIDTH' (the only "
                            "orientation read)",
                            name);
    pt_envmap m = {(uint32_t)(w > PT_ENVMAP_MAX_SIDE ? PT_ENVMAP_MAX_SIDE + 1 : w),
                   (uint32_t)(h > PT_ENVMAP_MAX_SIDE ? PT_ENVMAP_MAX_SIDE + 1 : h), NULL};
    if (m.width == 0 || m.height == 0 || m.width > PT_ENVMAP_MAX_SIDE ||
        m.height > PT_ENVMAP_MAX_SIDE)
        return check_map(&m, name, err);
    /* Each texel takes at least 4 bytes flat or about 4/127 in runs: a
     * size that cannot be in the file is refused before the allocation. */
    if ((uint64_t)m.width * m.height > (uint64_t)(c.end - c.p) * 32 + 1024)
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %ux%u texels cannot fit in %zu bytes", name,
                            m.width, m.height, n);
    size_t count = (size_t)m.width * m.height;
    m.rgb = pt_malloc_array(count * 3, sizeof *m.rgb);
    uint8_t *row = pt_malloc_array(m.width, 4);
    if (!m.rgb || !row) {
        pt_free(row);
        pt_envmap_free(&m);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory for %ux%u", name, m.width,
                            m.height);
    }
    for (uint32_t y = 0; y < m.height; y++) {
        const char *why = scanline(&c, m.width, row);
        if (why) {
            pt_free(row);
            pt_envmap_free(&m);
            return pt_error_set(err, PT_ERR_FORMAT, "%s: scanline %u: %s", name, y, why);
        }
        float *dst = m.rgb + (size_t)y * m.width * 3;
        for (uint32_t x = 0; x < m.width; x++) {
            const uint8_t *t = row + 4 * (size_t)x;
            /* mantissa x 2^(exponent - 136); exponent 0 is black. */
            float f = t[3] ? ldexpf(1.0f, (int)t[3] - 136) : 0.0f;
            dst[3 * x] = (float)t[0] * f;
            dst[3 * x + 1] = (float)t[1] * f;
            dst[3 * x + 2] = (float)t[2] * f;
        }
    }
    pt_free(row);
    pt_status st = check_map(&m, name, err);
    if (st != PT_OK) {
        pt_envmap_free(&m);
        return st;
    }
    *out = m;
    return PT_OK;
}

static pt_status read_exr(const char *path, pt_envmap *out, pt_error *err)
{
    pt_image *img = NULL;
    pt_status st = pt_exr_read(path, &img, NULL, err);
    if (st != PT_OK)
        return st;
    pt_envmap m = {img->width, img->height, NULL};
    size_t n = (size_t)img->width * img->height;
    m.rgb = pt_malloc_array(n * 3, sizeof *m.rgb);
    if (!m.rgb) {
        pt_image_free(img);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    }
    for (size_t i = 0; i < n; i++) {
        m.rgb[3 * i] = img->r[i];
        m.rgb[3 * i + 1] = img->g[i];
        m.rgb[3 * i + 2] = img->b[i];
    }
    pt_image_free(img);
    if ((st = check_map(&m, path, err)) != PT_OK) {
        pt_envmap_free(&m);
        return st;
    }
    *out = m;
    return PT_OK;
}

pt_status pt_envmap_read(const char *path, pt_envmap *out, pt_error *err)
{
    memset(out, 0, sizeof *out);
    uint8_t *data = NULL;
    size_t n = 0;
    pt_status st = pt_read_file(path, PT_ENVMAP_MAX_BYTES, &data, &n, err);
    if (st != PT_OK)
        return st;
    if (is_exr(data, n)) {
        pt_free(data);
        return read_exr(path, out, err);
    }
    st = pt_envmap_decode(data, n, path, out, err);
    pt_free(data);
    return st;
}

void pt_envmap_free(pt_envmap *m)
{
    if (m) {
        pt_free(m->rgb);
        m->rgb = NULL;
    }
}
