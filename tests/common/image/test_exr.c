/*
 * test_exr.c - pt_image, the PNG preview and OpenEXR write/read: bit-exact
 * round trips, metadata, atomic replacement, every reject path, hostile
 * files (truncated, garbage, bit flips) and allocation failure.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <OpenEXR/openexr.h>
#include <stb/stb_image.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "tests/check.h"

static char tmpdir[256];

static const char *path(const char *name)
{
    static char buf[4][512];
    static int k;
    k = (k + 1) % 4;
    snprintf(buf[k], sizeof buf[k], "%s/%s", tmpdir, name);
    return buf[k];
}

static uint64_t rng_state = 1;

static uint32_t rnd32(void)
{
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return (uint32_t)((z ^ (z >> 31)) >> 32);
}

/* Random finite floats of every magnitude, and the awkward values. */
static float rnd_value(void)
{
    static const float special[] = {0.0f,  -0.0f,   1e-45f,        1e-38f, 1.17549435e-38f,
                                    1e30f, -1e30f,  3.4028235e38f, -1.0f,  0.5f,
                                    1.0f,  -2.5e-7f};
    uint32_t pick = rnd32() % 4;
    if (pick == 0)
        return special[rnd32() % (sizeof special / sizeof special[0])];
    if (pick == 1)
        return (float)(rnd32() % 1000) * 0.01f;
    uint32_t bits;
    float f;
    do {
        bits = rnd32();
        memcpy(&f, &bits, sizeof f);
    } while (!isfinite(f));
    return f;
}

static pt_image *random_image(uint32_t w, uint32_t h)
{
    pt_image *img = NULL;
    if (pt_image_new(w, h, &img, NULL) != PT_OK)
        return NULL;
    float *planes[5] = {img->r, img->g, img->b, img->samples, img->variance};
    for (int c = 0; c < 5; c++)
        for (size_t i = 0; i < (size_t)w * h; i++)
            planes[c][i] = rnd_value();
    return img;
}

static int same_image(const pt_image *a, const pt_image *b)
{
    if (!a || !b || a->width != b->width || a->height != b->height)
        return 0;
    size_t bytes = (size_t)a->width * a->height * sizeof(float);
    return !memcmp(a->r, b->r, bytes) && !memcmp(a->g, b->g, bytes) && !memcmp(a->b, b->b, bytes) &&
           !memcmp(a->samples, b->samples, bytes) && !memcmp(a->variance, b->variance, bytes);
}

/* Entries of tmpdir whose name contains ".tmp." */
static int count_temp_files(void)
{
    DIR *d = opendir(tmpdir);
    int n = 0;
    if (!d)
        return -1;
    struct dirent *e;
    while ((e = readdir(d)) != NULL)
        n += strstr(e->d_name, ".tmp.") != NULL;
    closedir(d);
    return n;
}

static unsigned char *slurp(const char *p, size_t *len)
{
    FILE *f = fopen(p, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc(n > 0 ? (size_t)n : 1);
    if (buf && fread(buf, 1, (size_t)n, f) != (size_t)n) {
        free(buf);
        buf = NULL;
    }
    fclose(f);
    *len = (size_t)n;
    return buf;
}

static int spit(const char *p, const void *data, size_t len)
{
    FILE *f = fopen(p, "wb");
    if (!f)
        return -1;
    size_t w = fwrite(data, 1, len, f);
    return fclose(f) == 0 && w == len ? 0 : -1;
}

static void test_image_new(void)
{
    pt_image *img = NULL;
    pt_error err = {0};
    CHECK(pt_image_new(0, 1, &img, &err) == PT_ERR_ARG && img == NULL);
    CHECK(pt_image_new(65537, 1, &img, &err) == PT_ERR_LIMIT && img == NULL);
    CHECK(pt_image_new(1, 65537, &img, &err) == PT_ERR_LIMIT && img == NULL);
    CHECK(pt_image_new(65536, 4097, &img, &err) == PT_ERR_LIMIT && img == NULL);
    CHECK(pt_image_new(5, 3, &img, &err) == PT_OK && img != NULL);
    if (img) {
        int zero = 1;
        float *planes[5] = {img->r, img->g, img->b, img->samples, img->variance};
        for (int c = 0; c < 5; c++)
            for (int i = 0; i < 15; i++)
                zero &= planes[c][i] == 0.0f;
        CHECK(zero);
        /* Planes are disjoint and in order. */
        CHECK(img->g == img->r + 15 && img->variance == img->r + 60);
        CHECK(((uintptr_t)img->r % sizeof(float)) == 0);
    }
    pt_image_free(img);
    pt_image_free(NULL);
}

static void test_srgb(void)
{
    CHECK(pt_linear_to_srgb(0.0f) == 0.0f);
    CHECK(fabsf(pt_linear_to_srgb(1.0f) - 1.0f) < 1e-6f);
    /* The two pieces meet at the breakpoint (IEC 61966-2-1). */
    CHECK(fabsf(pt_linear_to_srgb(0.0031308f) - 0.04045f) < 1e-5f);
    CHECK(fabsf(pt_srgb_to_linear(0.5f) - 0.21404f) < 1e-5f);
    int inverse = 1;
    for (int i = 0; i <= 1000; i++) {
        float c = (float)i / 1000.0f;
        inverse &= fabsf(pt_srgb_to_linear(pt_linear_to_srgb(c)) - c) < 1e-5f;
    }
    CHECK(inverse);
}

static void test_png(void)
{
    const float lin[] = {0.0f, 1.0f, 0.2140f, NAN, -1.0f, 2.0f, INFINITY, 0.5f};
    const int want[] = {0, 255, 128, 0, 0, 255, 255, 188};
    const int n = (int)(sizeof lin / sizeof lin[0]);
    pt_image *img = NULL;
    pt_error err = {0};
    if (pt_image_new((uint32_t)n, 2, &img, NULL) != PT_OK) {
        CHECK(0);
        return;
    }
    for (int i = 0; i < n; i++) {
        img->r[i] = img->g[i] = img->b[i] = lin[i];
        img->r[n + i] = lin[i]; /* row 2: red only */
    }
    CHECK(pt_png_write_preview(path("p.png"), img, NULL, &err) == PT_OK);
    size_t len = 0;
    unsigned char *bytes = slurp(path("p.png"), &len);
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    CHECK(bytes && len > 8 && memcmp(bytes, sig, 8) == 0);
    free(bytes);
    int w = 0, h = 0, comp = 0;
    unsigned char *px = stbi_load(path("p.png"), &w, &h, &comp, 3);
    CHECK(px && w == n && h == 2 && comp == 3);
    if (px && w == n && h == 2) {
        for (int i = 0; i < n; i++) {
            CHECKF(abs(px[3 * i] - want[i]) <= 1 && px[3 * i] == px[3 * i + 1] &&
                       px[3 * i] == px[3 * i + 2],
                   "linear %g -> %d %d %d, want %d", lin[i], px[3 * i], px[3 * i + 1],
                   px[3 * i + 2], want[i]);
            const unsigned char *q = px + 3 * (n + i);
            CHECK(q[0] == px[3 * i] && q[1] == 0 && q[2] == 0);
        }
        CHECK(px[0] == 0 && px[3] == 255);
    }
    stbi_image_free(px);
    /* Replacing an existing preview, and no temp file left behind. */
    CHECK(pt_png_write_preview(path("p.png"), img, NULL, &err) == PT_OK);
    CHECK(count_temp_files() == 0);
    CHECK(pt_png_write_preview(path("no/such/dir/p.png"), img, NULL, &err) == PT_ERR_IO);
    CHECK(strstr(err.msg, "no/such/dir/p.png") != NULL);
    CHECK(count_temp_files() == 0);
    pt_image_free(img);
    unlink(path("p.png"));
}

static void test_round_trip(void)
{
    const uint32_t sizes[][2] = {{37, 19}, {1, 1}, {1, 40}, {300, 1}, {64, 33}, {123, 77}};
    for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++) {
        pt_image *a = random_image(sizes[s][0], sizes[s][1]), *b = NULL;
        pt_exr_meta m = {0}, back;
        memset(&back, 0x55, sizeof back);
        m.total_samples = 0xFFFFFFFFFFFFFFFFull - s;
        m.render_seconds = 1234.5678 + (double)s / 3.0;
        snprintf(m.scene_hash, sizeof m.scene_hash, "%064x", (unsigned)s + 0xabcdef);
        snprintf(m.job_id, sizeof m.job_id, "job-%zu", s);
        snprintf(m.software, sizeof m.software, "ptfarm test %zu", s);
        pt_error err = {0};
        pt_status st = pt_exr_write(path("rt.exr"), a, &m, &err);
        CHECKF(st == PT_OK, "%ux%u: %s", sizes[s][0], sizes[s][1], err.msg);
        st = pt_exr_read(path("rt.exr"), &b, &back, &err);
        CHECKF(st == PT_OK, "%ux%u: %s", sizes[s][0], sizes[s][1], err.msg);
        CHECKF(same_image(a, b), "%ux%u differs", sizes[s][0], sizes[s][1]);
        CHECK(back.total_samples == m.total_samples);
        CHECK(back.render_seconds == m.render_seconds);
        CHECK(!strcmp(back.scene_hash, m.scene_hash) && strlen(back.scene_hash) == 64);
        CHECK(!strcmp(back.job_id, m.job_id));
        CHECK(!strcmp(back.software, m.software));
        /* The header alone: the same attributes, no pixels decoded. */
        pt_exr_meta head;
        memset(&head, 0, sizeof head);
        CHECK(pt_exr_read(path("rt.exr"), NULL, &head, &err) == PT_OK);
        CHECK(head.render_seconds == m.render_seconds && !strcmp(head.job_id, m.job_id) &&
              !strcmp(head.scene_hash, m.scene_hash));
        pt_image_free(a);
        pt_image_free(b);
    }
    /* Default software name, NULL meta on write and on read. */
    pt_image *a = random_image(3, 2), *b = NULL;
    pt_exr_meta m = {0}, back;
    pt_error err = {0};
    CHECK(pt_exr_write(path("rt.exr"), a, &m, &err) == PT_OK);
    CHECK(pt_exr_read(path("rt.exr"), &b, &back, &err) == PT_OK);
    CHECK(!strncmp(back.software, "ptfarm ", 7) && strstr(back.software, PT_VERSION));
    CHECK(back.total_samples == 0 && back.job_id[0] == '\0');
    pt_image_free(b);
    b = NULL;
    CHECK(pt_exr_write(path("rt.exr"), a, NULL, &err) == PT_OK);
    CHECK(pt_exr_read(path("rt.exr"), &b, NULL, &err) == PT_OK && same_image(a, b));
    pt_image_free(a);
    pt_image_free(b);
    CHECK(count_temp_files() == 0);
    unlink(path("rt.exr"));
}

/* pt_exr_read follows a link and pt_exr_read_nofollow refuses it; neither
 * opens a FIFO, and neither blocks on one (the test would hang). */
static void test_links_and_fifos(void)
{
    pt_image *a = random_image(5, 4), *b = NULL;
    pt_error err = {0};
    CHECK(pt_exr_write(path("real.exr"), a, NULL, &err) == PT_OK);
    CHECK(symlink(path("real.exr"), path("link.exr")) == 0);
    CHECK(pt_exr_read(path("link.exr"), &b, NULL, &err) == PT_OK && same_image(a, b));
    pt_image_free(b);
    b = NULL;
    CHECK(pt_exr_read_nofollow(path("real.exr"), &b, NULL, &err) == PT_OK && same_image(a, b));
    pt_image_free(b);
    b = NULL;
    CHECK(pt_exr_read_nofollow(path("link.exr"), &b, NULL, &err) == PT_ERR_FORMAT && !b &&
          strstr(err.msg, "symbolic link"));
    CHECK(mkfifo(path("fifo.exr"), 0600) == 0);
    CHECK(pt_exr_read(path("fifo.exr"), &b, NULL, &err) == PT_ERR_FORMAT && !b &&
          strstr(err.msg, "not a regular file"));
    CHECK(pt_exr_read_nofollow(path("fifo.exr"), NULL, NULL, &err) == PT_ERR_FORMAT);
    CHECK(pt_exr_read_nofollow(path("none.exr"), NULL, NULL, &err) == PT_ERR_IO &&
          err.sys_errno == ENOENT);
    unlink(path("fifo.exr"));
    unlink(path("link.exr"));
    unlink(path("real.exr"));
    pt_image_free(a);
}

/* A reader racing a writer sees either image, whole, never a torn file. */
static void test_atomic_replace(void)
{
    pt_image *a = random_image(40, 40), *b = random_image(40, 40), *r = NULL;
    pt_exr_meta m = {0};
    pt_error err = {0};
    struct stat sb;
    CHECK(stat(path("at.exr"), &sb) != 0 && errno == ENOENT);
    CHECK(pt_exr_write(path("at.exr"), a, &m, &err) == PT_OK);
    CHECK(pt_exr_read(path("at.exr"), &r, NULL, &err) == PT_OK && same_image(r, a));
    pt_image_free(r);
    r = NULL;
    CHECK(pt_exr_write(path("at.exr"), b, &m, &err) == PT_OK);
    CHECK(pt_exr_read(path("at.exr"), &r, NULL, &err) == PT_OK && same_image(r, b));
    pt_image_free(r);
    r = NULL;
    CHECK(count_temp_files() == 0);

    fflush(NULL);
    pid_t pid = fork();
    if (pid == 0) {
        for (int i = 0; i < 40; i++)
            if (pt_exr_write(path("at.exr"), i % 2 ? b : a, &m, NULL) != PT_OK)
                _exit(1);
        _exit(0);
    }
    CHECK(pid > 0);
    int reads = 0, bad = 0, status = 0;
    for (;;) {
        pid_t done = waitpid(pid, &status, WNOHANG);
        pt_status st = pt_exr_read(path("at.exr"), &r, NULL, &err);
        reads++;
        if (st != PT_OK || !(same_image(r, a) || same_image(r, b))) {
            bad++;
            fprintf(stderr, "torn read: %s\n", st == PT_OK ? "pixels" : err.msg);
        }
        pt_image_free(r);
        r = NULL;
        if (done != 0)
            break;
    }
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    CHECKF(bad == 0, "%d of %d reads saw a torn file", bad, reads);
    CHECK(count_temp_files() == 0);
    pt_image_free(a);
    pt_image_free(b);
    unlink(path("at.exr"));
}

static void quiet(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    (void)code;
    (void)msg;
}

/* The sample custom_value(c, i) that write_custom stores for channel c (in
 * sorted order) at pixel i of the data window: exact in half and in float. */
static float custom_value(int c, size_t i)
{
    return 0.5f * (1.0f + (float)((i + 7u * c) % 1024) / 1024.0f);
}

/* Writes an EXR that pt_exr_write would not: the given storage, channels (in
 * sorted order) and pixel type, and the data window dw. Returns 0 on success. */
static int write_custom(const char *p, exr_storage_t storage, const char *const *names, int nch,
                        exr_pixel_type_t type, exr_attr_box2i_t dw)
{
    exr_context_t ctx = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = quiet;
    int32_t w = dw.max.x - dw.min.x + 1, h = dw.max.y - dw.min.y + 1;
    int bpe = type == EXR_PIXEL_HALF ? 2 : 4;
    size_t plane = (size_t)w * h * (size_t)bpe;
    unsigned char *buf = malloc(plane * (size_t)nch);
    exr_attr_box2i_t disp = {.min = {.x = 0, .y = 0}, .max = {.x = w - 1, .y = h - 1}};
    exr_attr_v2f_t center = {.x = 0.0f, .y = 0.0f};
    int part = 0;
    exr_result_t rv = buf ? EXR_ERR_SUCCESS : EXR_ERR_OUT_OF_MEMORY;
    for (int c = 0; buf && c < nch; c++)
        for (size_t i = 0; i < (size_t)w * h; i++) {
            float v = custom_value(c, i);
            /* Half 0x3800 is 0.5; the low ten bits are the mantissa. */
            uint16_t half = (uint16_t)(0x3800 + (i + 7u * c) % 1024);
            memcpy(buf + plane * c + (size_t)bpe * i, bpe == 2 ? (void *)&half : (void *)&v,
                   (size_t)bpe);
        }
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_start_write(&ctx, p, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_add_part(ctx, "x", storage, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr(ctx, part, &disp, &dw, 1.0f, &center, 1.0f,
                                          EXR_LINEORDER_INCREASING_Y, EXR_COMPRESSION_NONE);
    if (rv == EXR_ERR_SUCCESS && storage == EXR_STORAGE_TILED)
        rv = exr_set_tile_descriptor(ctx, part, 8, 8, EXR_TILE_ONE_LEVEL, EXR_TILE_ROUND_DOWN);
    for (int c = 0; c < nch && rv == EXR_ERR_SUCCESS; c++)
        rv = exr_add_channel(ctx, part, names[c], type, EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_write_header(ctx);
    int32_t lines = 1;
    if (rv == EXR_ERR_SUCCESS && storage == EXR_STORAGE_SCANLINE)
        rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int started = 0;
    int tiles_x = (w + 7) / 8,
        n_chunks = storage == EXR_STORAGE_TILED ? tiles_x * ((h + 7) / 8) : (h + lines - 1) / lines;
    for (int k = 0; k < n_chunks && rv == EXR_ERR_SUCCESS; k++) {
        exr_chunk_info_t cinfo;
        if (storage == EXR_STORAGE_TILED)
            rv = exr_write_tile_chunk_info(ctx, part, k % tiles_x, k / tiles_x, 0, 0, &cinfo);
        else
            rv = exr_write_scanline_chunk_info(ctx, part, dw.min.y + lines * k, &cinfo);
        if (rv == EXR_ERR_SUCCESS)
            rv = started ? exr_encoding_update(ctx, part, &cinfo, &enc)
                         : exr_encoding_initialize(ctx, part, &cinfo, &enc);
        for (int c = 0; rv == EXR_ERR_SUCCESS && c < enc.channel_count; c++) {
            enc.channels[c].user_pixel_stride = bpe;
            enc.channels[c].user_line_stride = bpe * w;
            enc.channels[c].user_bytes_per_element = (int16_t)bpe;
            enc.channels[c].user_data_type = (uint16_t)type;
            size_t rows = storage == EXR_STORAGE_TILED ? 0 : (size_t)(cinfo.start_y - dw.min.y);
            enc.channels[c].encode_from_ptr = buf + plane * c + rows * (size_t)(bpe * w);
        }
        if (rv == EXR_ERR_SUCCESS && !started)
            rv = exr_encoding_choose_default_routines(ctx, part, &enc);
        started = 1;
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_encoding_run(ctx, part, &enc);
    }
    if (started)
        exr_encoding_destroy(ctx, &enc);
    if (ctx) {
        exr_result_t rf = exr_finish(&ctx);
        if (rv == EXR_ERR_SUCCESS)
            rv = rf;
    }
    free(buf);
    return rv == EXR_ERR_SUCCESS ? 0 : -1;
}

/* Files from other writers: half channels, extra channels, an offset data
 * window are read; tiled parts and missing colour channels are refused. */
static void test_foreign_files(void)
{
    static const char *const rgba[] = {"A", "B", "G", "R"};
    static const char *const y_only[] = {"Y"};
    static const char *const rgb[] = {"B", "G", "R"};
    exr_attr_box2i_t dw = {.min = {.x = 10, .y = 5}, .max = {.x = 22, .y = 40}};
    pt_image *img = NULL;
    pt_exr_meta m;
    pt_error err = {0};
    CHECK(write_custom(path("half.exr"), EXR_STORAGE_SCANLINE, rgba, 4, EXR_PIXEL_HALF, dw) == 0);
    CHECKF(pt_exr_read(path("half.exr"), &img, &m, &err) == PT_OK, "%s", err.msg);
    if (img) {
        CHECK(img->width == 13 && img->height == 36);
        int ok = 1;
        for (size_t i = 0; i < 13 * 36; i++)
            ok &= img->r[i] == custom_value(3, i) && img->g[i] == custom_value(2, i) &&
                  img->b[i] == custom_value(1, i) && img->samples[i] == 0.0f &&
                  img->variance[i] == 0.0f;
        CHECK(ok);
        CHECK(m.total_samples == 0 && m.scene_hash[0] == '\0' && m.render_seconds == 0.0);
    }
    pt_image_free(img);
    img = NULL;

    CHECK(write_custom(path("y.exr"), EXR_STORAGE_SCANLINE, y_only, 1, EXR_PIXEL_FLOAT, dw) == 0);
    CHECK(pt_exr_read(path("y.exr"), &img, NULL, &err) == PT_ERR_FORMAT && img == NULL);
    CHECKF(strstr(err.msg, "R, G and B") != NULL && strstr(err.msg, "y.exr") != NULL, "%s",
           err.msg);

    CHECK(write_custom(path("tiled.exr"), EXR_STORAGE_TILED, rgb, 3, EXR_PIXEL_FLOAT, dw) == 0);
    CHECK(pt_exr_read(path("tiled.exr"), &img, NULL, &err) == PT_ERR_FORMAT && img == NULL);
    CHECKF(strstr(err.msg, "tiled") != NULL && strstr(err.msg, "tiled.exr") != NULL, "%s", err.msg);
    unlink(path("half.exr"));
    unlink(path("y.exr"));
    unlink(path("tiled.exr"));
}

typedef struct writer_arg {
    const char *target; /* path() is not thread-safe: resolved before the threads start */
    const pt_image *img;
    int failures;
} writer_arg;

static void *writer_thread(void *p)
{
    writer_arg *a = p;
    for (int i = 0; i < 10; i++)
        a->failures += pt_exr_write(a->target, a->img, NULL, NULL) != PT_OK;
    return NULL;
}

/* Two threads of one process writing one path never share a temp file. */
static void test_threads_one_path(void)
{
    pt_image *a = random_image(33, 17), *b = random_image(33, 17), *r = NULL;
    char target[512];
    snprintf(target, sizeof target, "%s", path("mt.exr"));
    writer_arg wa = {target, a, 0}, wb = {target, b, 0};
    pthread_t ta, tb;
    int started = pthread_create(&ta, NULL, writer_thread, &wa) == 0;
    started += pthread_create(&tb, NULL, writer_thread, &wb) == 0;
    CHECK(started == 2);
    if (started >= 1)
        pthread_join(ta, NULL);
    if (started == 2)
        pthread_join(tb, NULL);
    CHECK(wa.failures == 0 && wb.failures == 0);
    CHECK(pt_exr_read(path("mt.exr"), &r, NULL, NULL) == PT_OK);
    CHECK(same_image(r, a) || same_image(r, b));
    CHECK(count_temp_files() == 0);
    pt_image_free(r);
    pt_image_free(a);
    pt_image_free(b);
    unlink(path("mt.exr"));
}

static void test_write_errors(void)
{
    pt_image *a = random_image(4, 4);
    pt_error err = {0};
    CHECK(pt_exr_write(path("missing/dir/x.exr"), a, NULL, &err) == PT_ERR_IO);
    CHECKF(strstr(err.msg, "missing/dir/x.exr") != NULL, "%s", err.msg);
    CHECK(err.sys_errno == ENOENT);
    pt_image zero = {0};
    CHECK(pt_exr_write(path("z.exr"), &zero, NULL, &err) == PT_ERR_ARG);
    CHECK(pt_exr_write(path("z.exr"), NULL, NULL, &err) == PT_ERR_ARG);
    struct stat sb;
    CHECK(stat(path("z.exr"), &sb) != 0);
    /* A directory where the file should go: the rename fails, the temp file goes. */
    CHECK(mkdir(path("isdir.exr"), 0755) == 0);
    CHECK(pt_exr_write(path("isdir.exr"), a, NULL, &err) == PT_ERR_IO);
    CHECK(strstr(err.msg, "isdir.exr") != NULL);
    CHECK(count_temp_files() == 0);
    rmdir(path("isdir.exr"));
    pt_image_free(a);
}

static void expect_read_fails(const char *name, const char *what)
{
    pt_image *img = NULL;
    pt_exr_meta m;
    pt_error err = {0};
    int64_t live = pt_alloc_live();
    pt_status st = pt_exr_read(path(name), &img, &m, &err);
    CHECKF(st != PT_OK && img == NULL, "%s was accepted", what);
    CHECKF(st == PT_OK || strstr(err.msg, name) != NULL, "%s: message %s", what, err.msg);
    CHECKF(pt_alloc_live() == live, "%s leaked", what);
    pt_image_free(img);
}

static void test_hostile(void)
{
    pt_image *a = random_image(50, 37);
    pt_error err = {0};
    pt_image *img = NULL;
    CHECK(pt_exr_read(path("nope.exr"), &img, NULL, &err) == PT_ERR_IO && img == NULL);
    CHECK(strstr(err.msg, "nope.exr") != NULL && err.sys_errno == ENOENT);
    CHECK(pt_exr_read(tmpdir, &img, NULL, &err) != PT_OK && img == NULL);

    CHECK(pt_exr_write(path("good.exr"), a, NULL, &err) == PT_OK);
    size_t len = 0;
    unsigned char *good = slurp(path("good.exr"), &len);
    CHECK(good && len > 100);
    if (!good) {
        pt_image_free(a);
        return;
    }
    /* Every cut in the header and offset table, then a stride through the chunks. */
    int cuts = 0;
    for (size_t cut = 0; cut < len; cut += cut < 600 ? 1 : 97) {
        spit(path("cut.exr"), good, cut);
        char what[64];
        snprintf(what, sizeof what, "a copy cut at %zu of %zu", cut, len);
        expect_read_fails("cut.exr", what);
        cuts++;
    }
    for (size_t back = 1; back <= 8; back++) {
        spit(path("cut.exr"), good, len - back);
        expect_read_fails("cut.exr", "a copy missing its last bytes");
    }
    /* A data window far larger than the file can hold: refused before the
     * pixels are allocated (the old reader asked for 5 GiB here). */
    static const char dwin[] = "dataWindow\0box2i\0";
    unsigned char *big = malloc(len);
    size_t wat = 0;
    while (big && wat + sizeof dwin + 20 <= len && memcmp(good + wat, dwin, sizeof dwin - 1) != 0)
        wat++;
    CHECK(big && wat + sizeof dwin + 20 <= len);
    if (big && wat + sizeof dwin + 20 <= len) {
        memcpy(big, good, len);
        const int32_t window[4] = {0, 0, 16383, 16383}; /* xmin, ymin, xmax, ymax */
        memcpy(big + wat + sizeof dwin - 1 + 4, window, sizeof window);
        spit(path("big.exr"), big, len);
        img = NULL;
        pt_status st = pt_exr_read(path("big.exr"), &img, NULL, &err);
        CHECKF(st == PT_ERR_FORMAT && img == NULL && strstr(err.msg, "cannot be in") != NULL,
               "a 16384x16384 window in %zu bytes: %d %s", len, (int)st, err.msg);
        unlink(path("big.exr"));
    }
    free(big);
    /* Garbage, and garbage behind a valid magic number and version. */
    unsigned char junk[4096];
    for (int t = 0; t < 20; t++) {
        for (size_t i = 0; i < sizeof junk; i++)
            junk[i] = (unsigned char)rnd32();
        if (t % 2)
            memcpy(junk, good, 8);
        spit(path("junk.exr"), junk, 64 + (size_t)t * 200);
        expect_read_fails("junk.exr", "a garbage file");
    }
    /* Bit flips anywhere: any result but a crash or a leak. */
    unsigned char *flip = malloc(len);
    int64_t live = pt_alloc_live();
    int flips_ok = 1;
    for (int t = 0; t < 300 && flip; t++) {
        memcpy(flip, good, len);
        for (int k = 0; k < 1 + t % 4; k++) {
            size_t at = t < 150 ? rnd32() % (len < 400 ? len : 400) : rnd32() % len;
            flip[at] ^= (unsigned char)(1u << (rnd32() % 8));
        }
        spit(path("flip.exr"), flip, len);
        img = NULL;
        if (pt_exr_read(path("flip.exr"), &img, NULL, &err) == PT_OK)
            flips_ok &= img != NULL && img->width * img->height > 0;
        pt_image_free(img);
    }
    CHECK(flips_ok);
    CHECK(pt_alloc_live() == live);
    free(flip);
    free(good);
    unlink(path("good.exr"));
    unlink(path("cut.exr"));
    unlink(path("junk.exr"));
    unlink(path("flip.exr"));
    pt_image_free(a);
    CHECK(cuts > 600);
}

/* Fail the Nth allocation of a write and of a read until both succeed:
 * every failure is reported cleanly and leaks nothing. */
static void test_alloc_failure(void)
{
    pt_image *a = random_image(20, 35), *b = NULL;
    pt_exr_meta m = {0};
    snprintf(m.job_id, sizeof m.job_id, "7");
    pt_error err = {0};
    int64_t live = pt_alloc_live();
    int wrote = 0, leaks = 0, codes = 0;
    for (uint64_t k = 1; k < 1000 && !wrote; k++) {
        pt_alloc_fail_at(k);
        pt_status st = pt_exr_write(path("af.exr"), a, &m, &err);
        pt_alloc_fail_at(0);
        wrote = st == PT_OK;
        codes += !wrote && st != PT_ERR_NOMEM && st != PT_ERR_IO && st != PT_ERR_FORMAT;
        leaks += pt_alloc_live() != live;
    }
    CHECK(wrote);
    CHECK(leaks == 0 && codes == 0);
    CHECK(count_temp_files() == 0);
    int read = 0;
    leaks = codes = 0;
    for (uint64_t k = 1; k < 1000 && !read; k++) {
        pt_alloc_fail_at(k);
        pt_status st = pt_exr_read(path("af.exr"), &b, NULL, &err);
        pt_alloc_fail_at(0);
        read = st == PT_OK;
        codes += !read && (b != NULL || (st != PT_ERR_NOMEM && st != PT_ERR_FORMAT));
        if (!read)
            leaks += pt_alloc_live() != live;
    }
    CHECK(read && same_image(a, b));
    CHECK(leaks == 0 && codes == 0);
    pt_image_free(b);
    pt_image_free(a);
    unlink(path("af.exr"));
}

int main(void)
{
    const char *base = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/ptfarm-exr-XXXXXX", base && *base ? base : "/tmp");
    if (!mkdtemp(tmpdir)) {
        perror("mkdtemp");
        return 1;
    }
    test_image_new();
    test_srgb();
    test_png();
    test_round_trip();
    test_links_and_fifos();
    test_atomic_replace();
    test_threads_one_path();
    test_write_errors();
    test_foreign_files();
    test_hostile();
    test_alloc_failure();
    if (rmdir(tmpdir) != 0)
        fprintf(stderr, "leftover files in %s\n", tmpdir);
    CHECK(count_temp_files() <= 0);
    return check_report();
}
