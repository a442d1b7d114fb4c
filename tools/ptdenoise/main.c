/*
 * ptdenoise - denoises a ptfarm EXR that carries the denoiser's passes.
 *
 *   ptdenoise IN.exr -o OUT.exr [--threads N] [--view V] [--exposure EV] [--no-preview]
 *             [--despeckle F] [--max-memory MIB]
 *   ptdenoise IN.exr -o OUT.png ...
 *
 * Reads the beauty (R, G, B, variance), the half buffers (halfA.*, halfB.*)
 * and the albedo, N and depth passes with their variances (the EXR
 * convention in docs/ARCHITECTURE.md, "Render passes and the denoiser"),
 * runs NFOR (common/image/denoise.h) and writes OUT.exr: every channel and
 * header attribute of IN.exr as it was, plus denoised.R/G/B, with a PNG
 * preview of the denoised layer beside it; or OUT.png, that preview alone.
 * Exit status: 0 done, 1 an error (a file without the passes or with a
 * pixel of fewer than 2 samples, NaN or absurd values, I/O; the reason on
 * stderr), 2 bad usage.
 */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/image/denoise.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/view.h"

enum { EXIT_ERROR = 1, EXIT_USAGE = 2 };

static void usage(FILE *f)
{
    fprintf(f, "usage: ptdenoise IN.exr -o OUT.exr|OUT.png [options]\n"
               "       ptdenoise --help | --version\n"
               "\n"
               "examples:\n"
               "  ptworker --scene helmet.glb --env studio.hdr --spp 64 \\\n"
               "      --passes albedo,normal,depth,halves -o helmet.exr\n"
               "  ptdenoise helmet.exr -o helmet_dn.exr     (the layer denoised.R/G/B added)\n"
               "  ptdenoise helmet.exr -o helmet_dn.png --view agx --exposure -1\n"
               "  ptctl fetch $id -o job.exr && ptdenoise job.exr -o job_dn.exr --threads 8\n"
               "  oiiotool helmet_dn.exr --ch denoised.R,denoised.G,denoised.B \\\n"
               "      --chnames R,G,B -o clean.exr          (the denoised layer alone)\n"
               "\n"
               "Denoises a ptfarm render with NFOR (Bitterli et al. 2016), guided by its\n"
               "half buffers and its albedo, normal and depth passes: render it with\n"
               "--denoise (or --passes albedo,normal,depth,halves).\n"
               "\n"
               "  -o OUT.exr          every channel and attribute of IN.exr, plus the layer\n"
               "                      denoised.R/G/B; a PNG preview of that layer beside it\n"
               "  -o OUT.png          the preview of the denoised layer alone\n"
               "  --threads N         threads (default: the processors online); the result\n"
               "                      is the same bits for any N\n"
               "  --view V            the preview's view transform: " PT_VIEW_NAMES
               " (default standard)\n"
               "  --exposure EV       the preview's exposure in stops (default 0; -20 to 20)\n"
               "  --no-preview        no PNG beside OUT.exr\n"
               "  --despeckle F       fireflies: a pixel of one half brighter than F times the\n"
               "                      brightest of the other half around it is scaled down to\n"
               "                      that, its light spread back over the same surface\n"
               "                      around it (the image's mean is kept), and a variance\n"
               "                      over 16 times its neighbours' median is capped\n"
               "                      (default 2; 0: off, pure NFOR)\n"
               "  --max-memory MIB    the denoiser's working memory at most MIB mebibytes\n"
               "                      (default: what the frame needs, about 0.4 KiB a\n"
               "                      pixel); a larger frame is denoised in regions, each\n"
               "                      from a crop 96 pixels wider on every side: the same\n"
               "                      bits, for more time\n"
               "  -h, --help          this help\n"
               "  --version           version and build id\n"
               "\n"
               "exit status: 0 done, 1 error (a file without the passes, NaN or absurd\n"
               "values, I/O; the reason on stderr), 2 bad usage\n");
}

/* pt_denoise_within on a thread of its own (pt_run_reported). */
typedef struct dn_job {
    const pt_denoise_input *in;
    unsigned threads;
    uint64_t max_bytes;
    uint32_t side;
    float *const *out;
    pt_error *err;
    pt_status st;
} dn_job;

static int dn_run(void *arg)
{
    dn_job *j = arg;
    j->st = pt_denoise_within(j->in, j->threads, j->max_bytes, j->out, &j->side, j->err);
    return 0;
}

/* The channels read, in this order: the input's planes. */
static const char *const CHANNELS[] = {
    "halfA.R", "halfA.G", "halfA.B",  "halfB.R",    "halfB.G",  "halfB.B",        "R",
    "G",       "B",       "variance", "albedo.R",   "albedo.G", "albedo.B",       "albedo.variance",
    "N.X",     "N.Y",     "N.Z",      "N.variance", "depth.Z",  "depth.variance", "samples",
    "A"};
/* All but the last are required; A (a transparent render's coverage) only
 * makes the preview RGBA. */
enum { NCH = sizeof CHANNELS / sizeof CHANNELS[0], NREQ = NCH - 1, CH_A = NCH - 1 };
_Static_assert(NCH == PT_DENOISE_PLANES + 2, "the input's planes, then samples and A");

int main(int argc, char **argv)
{
    enum {
        OPT_VERSION = 256,
        OPT_THREADS,
        OPT_VIEW,
        OPT_EXPOSURE,
        OPT_NO_PREVIEW,
        OPT_DESPECKLE,
        OPT_MAX_MEMORY
    };
    static const struct option longopts[] = {
        {"help", no_argument, NULL, 'h'},
        {"version", no_argument, NULL, OPT_VERSION},
        {"threads", required_argument, NULL, OPT_THREADS},
        {"view", required_argument, NULL, OPT_VIEW},
        {"exposure", required_argument, NULL, OPT_EXPOSURE},
        {"no-preview", no_argument, NULL, OPT_NO_PREVIEW},
        {"despeckle", required_argument, NULL, OPT_DESPECKLE},
        {"max-memory", required_argument, NULL, OPT_MAX_MEMORY},
        {NULL, 0, NULL, 0}};
    const char *out_path = NULL;
    uint32_t threads = 0;
    pt_view view = {PT_VIEW_STANDARD, 0.0f};
    int preview = 1, c;
    double despeckle = PT_DENOISE_DESPECKLE;
    uint32_t max_mib = 0; /* 0: no limit */
    pt_error err = {0};
    while ((c = getopt_long(argc, argv, "ho:", longopts, NULL)) != -1) {
        pt_status st = PT_OK;
        double ev;
        switch (c) {
        case 'h':
            usage(stdout);
            return 0;
        case OPT_VERSION:
            return pt_version_print("ptdenoise");
        case 'o':
            out_path = optarg;
            break;
        case OPT_THREADS:
            st = pt_opt_u32("--threads", optarg, 1, PT_DENOISE_MAX_THREADS, &threads, &err);
            break;
        case OPT_VIEW:
            st = pt_view_parse("--view", optarg, &view.kind, &err);
            break;
        case OPT_EXPOSURE:
            st = pt_opt_double("--exposure", optarg, -PT_VIEW_MAX_EV, PT_VIEW_MAX_EV, &ev, &err);
            view.exposure = (float)ev;
            break;
        case OPT_NO_PREVIEW:
            preview = 0;
            break;
        case OPT_DESPECKLE:
            st = pt_opt_double("--despeckle", optarg, 0.0, PT_DENOISE_DESPECKLE_MAX, &despeckle,
                               &err);
            if (st == PT_OK && despeckle > 0.0 && despeckle < 1.0)
                st = pt_error_set(&err, PT_ERR_ARG, "--despeckle: %s is not 0 or at least 1",
                                  optarg);
            break;
        case OPT_MAX_MEMORY:
            st = pt_opt_u32("--max-memory", optarg, 1, 1u << 24, &max_mib, &err);
            break;
        default:
            usage(stderr);
            return EXIT_USAGE;
        }
        if (st != PT_OK) {
            fprintf(stderr, "ptdenoise: %s\n", err.msg);
            return EXIT_USAGE;
        }
    }
    if (optind != argc - 1 || !out_path) {
        fprintf(stderr, "ptdenoise: %s\n",
                optind >= argc ? "no input EXR"
                : !out_path    ? "no -o OUT"
                               : "one input EXR only");
        usage(stderr);
        return EXIT_USAGE;
    }
    const char *in_path = argv[optind];
    pt_image_format fmt = pt_image_format_of(out_path);
    if (fmt == PT_IMAGE_FORMAT_NONE) {
        fprintf(stderr, "ptdenoise: -o %s: " PT_IMAGE_FORMATS "\n", out_path);
        return EXIT_USAGE;
    }
    if (threads == 0)
        threads = pt_denoise_default_threads();

    int rc = EXIT_ERROR;
    float *pl[NCH] = {0}, *out[3] = {0};
    uint32_t w = 0, h = 0;
    if (pt_exr_read_channels(in_path, NCH, CHANNELS, pl, &w, &h, &err) != PT_OK) {
        fprintf(stderr, "ptdenoise: %s\n", err.msg);
        goto done;
    }
    char missing[512] = "";
    for (int i = 0; i < NREQ; i++) {
        if (pl[i])
            continue;
        size_t len = strlen(missing);
        snprintf(missing + len, sizeof missing - len, "%s%s", len ? ", " : "", CHANNELS[i]);
    }
    if (missing[0]) {
        fprintf(stderr,
                "ptdenoise: %s has not the passes the denoiser needs (missing %s): render it "
                "with --denoise, or --passes albedo,normal,depth,halves\n",
                in_path, missing);
        goto done;
    }
    /* Each half needs a sample: a pixel with fewer than 2 has an empty one. */
    for (size_t i = 0; i < (size_t)w * h; i++) {
        if (pl[20][i] >= 2.0f)
            continue;
        fprintf(stderr,
                "ptdenoise: %s: pixel (%zu, %zu) has %g samples; the half buffers need 2 or "
                "more\n",
                in_path, i % w, i / w, (double)pl[20][i]);
        goto done;
    }
    pt_denoise_input in = {.width = w, .height = h, .despeckle = (float)despeckle};
    /* CHANNELS' first PT_DENOISE_PLANES are the input's planes in order. */
    pt_denoise_input_set_planes(&in, (const float *const *)pl);
    for (int k = 0; k < 3; k++) {
        out[k] = pt_malloc_array((size_t)w * h, sizeof(float));
        if (!out[k]) {
            fprintf(stderr, "ptdenoise: out of memory for %ux%u\n", w, h);
            goto done;
        }
    }
    double t0 = pt_now_s();
    atomic_uint progress;
    atomic_init(&progress, 0);
    in.progress = &progress;
    /* Within --max-memory: regions as large as fit, or the whole frame. */
    dn_job job = {&in, threads, (uint64_t)max_mib << 20, 0, out, &err, PT_OK};
    pt_progress_line line = {"ptdenoise:", 0};
    pt_run_reported(dn_run, &job, &progress, pt_progress_line_report, &line);
    pt_progress_line_end(&line);
    if (job.st != PT_OK) {
        fprintf(stderr, "ptdenoise: %s: %s\n", in_path, err.msg);
        goto done;
    }
    uint32_t side = job.side;
    double secs = pt_now_s() - t0;
    if (fmt == PT_IMAGE_FORMAT_EXR) {
        static const char *const names[3] = {"denoised.R", "denoised.G", "denoised.B"};
        const float *const planes[3] = {out[0], out[1], out[2]};
        if (pt_exr_write_with_channels(in_path, out_path, 3, names, planes, &err) != PT_OK) {
            fprintf(stderr, "ptdenoise: %s\n", err.msg);
            goto done;
        }
    }
    if (fmt == PT_IMAGE_FORMAT_PNG || preview) {
        char png[4096];
        if (fmt == PT_IMAGE_FORMAT_PNG)
            snprintf(png, sizeof png, "%s", out_path);
        else
            pt_png_preview_path(out_path, png, sizeof png);
        /* A transparent render's halves are premultiplied like its beauty:
         * the preview divides by the coverage, as ptworker's does. */
        pt_image img = {.width = w,
                        .height = h,
                        .r = out[0],
                        .g = out[1],
                        .b = out[2],
                        .a = pl[CH_A],
                        .has_alpha = pl[CH_A] != NULL};
        if (pt_png_write_preview(png, &img, &view, &err) != PT_OK) {
            fprintf(stderr, "ptdenoise: %s\n", err.msg);
            goto done;
        }
    }
    char how[96] = "";
    if (side)
        snprintf(how, sizeof how, " in regions of %u pixels (%llu MiB)", side,
                 (unsigned long long)(pt_denoise_region_bytes(w, h, side) >> 20));
    fprintf(stderr, "ptdenoise: %s -> %s: %ux%u denoised%s in %.2f s on %u threads\n", in_path,
            out_path, w, h, how, secs, threads);
    rc = 0;
done:
    for (int i = 0; i < NCH; i++)
        pt_free(pl[i]);
    for (int k = 0; k < 3; k++)
        pt_free(out[k]);
    return rc;
}
