/*
 * ptworker - renders for ptfarm.
 *
 * `ptworker --scene SCENE -o OUT.exr --spp N ...` renders one image on this
 * machine (worker/standalone.c).
 */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "worker/standalone.h"

static void usage(FILE *f)
{
    fprintf(f,
            "usage: ptworker --scene SCENE -o OUT.exr [options]\n"
            "\n"
            "Renders a glTF 2.0 scene (.gltf or .glb) with the ptfarm path tracer on this\n"
            "machine and writes an OpenEXR image (R, G, B, samples, variance) plus an sRGB\n"
            "PNG preview beside it.\n"
            "\n"
            "options:\n"
            "  --scene PATH       the scene to render (required)\n"
            "  -o, --output PATH  the EXR to write (required); the preview is PATH.png\n"
            "  --spp N            samples per pixel (default 64)\n"
            "  --res WxH          image size (default 512 wide, height from the camera)\n"
            "  --seed S           random seed (default 0); same seed, same image\n"
            "  --threads T        render threads (default: all cores)\n"
            "  --max-depth D      maximum bounces (default 16)\n"
            "  --camera NAME      the camera to render (default: the scene's first)\n"
            "  --tile N           tile side in pixels (default 32)\n"
            "  --chunk N          samples per chunk (default 16)\n"
            "  -q, --quiet        no progress line\n"
            "  -h, --help         this text\n"
            "\n"
            "exit status: 0 image written, 1 render or I/O error, 2 bad usage\n");
}

static int parse_u32(const char *opt, const char *s, uint32_t min, uint32_t max, uint32_t *out)
{
    char *end;
    errno = 0;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || end == s || *end || s[0] == '-' || v < min || v > max) {
        fprintf(stderr, "ptworker: %s: '%s' is not a whole number in [%u, %u]\n", opt, s, min,
                max);
        return -1;
    }
    *out = (uint32_t)v;
    return 0;
}

static int parse_res(const char *s, uint32_t *w, uint32_t *h)
{
    char buf[64];
    const char *x = strchr(s, 'x');
    if (!x || (size_t)(x - s) >= sizeof buf) {
        fprintf(stderr, "ptworker: --res: '%s' is not WIDTHxHEIGHT\n", s);
        return -1;
    }
    memcpy(buf, s, (size_t)(x - s));
    buf[x - s] = '\0';
    if (parse_u32("--res width", buf, 1, 16384, w) || parse_u32("--res height", x + 1, 1, 16384, h))
        return -1;
    return 0;
}

int main(int argc, char **argv)
{
    wrk_standalone_opts o = {0};
    o.spp = 64;
    o.max_depth = 16;
    o.tile = 32;
    o.chunk = 16;
    enum { OPT_SCENE = 256, OPT_SPP, OPT_RES, OPT_SEED, OPT_THREADS, OPT_DEPTH, OPT_CAMERA,
           OPT_TILE, OPT_CHUNK };
    static const struct option longopts[] = {
        {"scene", required_argument, NULL, OPT_SCENE},
        {"output", required_argument, NULL, 'o'},
        {"spp", required_argument, NULL, OPT_SPP},
        {"res", required_argument, NULL, OPT_RES},
        {"seed", required_argument, NULL, OPT_SEED},
        {"threads", required_argument, NULL, OPT_THREADS},
        {"max-depth", required_argument, NULL, OPT_DEPTH},
        {"camera", required_argument, NULL, OPT_CAMERA},
        {"tile", required_argument, NULL, OPT_TILE},
        {"chunk", required_argument, NULL, OPT_CHUNK},
        {"quiet", no_argument, NULL, 'q'},
        {"help", no_argument, NULL, 'h'},
        {NULL, 0, NULL, 0},
    };
    int c;
    while ((c = getopt_long(argc, argv, "o:qh", longopts, NULL)) != -1) {
        int bad = 0;
        switch (c) {
        case OPT_SCENE: o.scene_path = optarg; break;
        case 'o': o.out_path = optarg; break;
        case OPT_SPP: bad = parse_u32("--spp", optarg, 1, 1u << 24, &o.spp); break;
        case OPT_RES: bad = parse_res(optarg, &o.width, &o.height); break;
        case OPT_SEED: bad = parse_u32("--seed", optarg, 0, UINT32_MAX, &o.seed); break;
        case OPT_THREADS: bad = parse_u32("--threads", optarg, 1, 1024, &o.threads); break;
        case OPT_DEPTH: bad = parse_u32("--max-depth", optarg, 0, 1024, &o.max_depth); break;
        case OPT_CAMERA: o.camera = optarg; break;
        case OPT_TILE: bad = parse_u32("--tile", optarg, 1, 4096, &o.tile); break;
        case OPT_CHUNK: bad = parse_u32("--chunk", optarg, 1, 1u << 24, &o.chunk); break;
        case 'q': o.quiet = 1; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return 2;
        }
        if (bad)
            return 2;
    }
    if (optind < argc) {
        fprintf(stderr, "ptworker: unexpected argument '%s'\n", argv[optind]);
        usage(stderr);
        return 2;
    }
    if (!o.scene_path || !o.out_path) {
        fprintf(stderr, "ptworker: --scene and -o are required\n");
        usage(stderr);
        return 2;
    }
    return wrk_standalone_run(&o);
}
