/*
 * ptworker - renders for ptfarm.
 *
 * `ptworker --scene SCENE -o OUT.exr --spp N ...` renders one image on this
 * machine (worker/standalone.c). `ptworker --server HOST:PORT ...` is a farm
 * worker: it renders tasks for a ptserve coordinator until stopped
 * (worker/client.c). The two modes share --threads; every other option
 * belongs to one of them, and mixing them is bad usage (exit status 2).
 */
#include <errno.h>
#include <float.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <unistd.h>

#include "common/base/frames.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/render/options.h"
#include "common/render/portal.h"
#include "common/render/render.h"
#include "common/render/tile.h"
#include "common/scene/anim.h"
#include "common/scene/motion.h"
#include "common/scene/scene.h"
#include "protocol/msg.h"
#include "worker/client.h"
#include "worker/standalone.h"

static void usage(FILE *f)
{
    fprintf(
        f,
        "usage: ptworker --scene SCENE -o OUT.exr|OUT.png [options]    (standalone)\n"
        "       ptworker --server HOST:PORT [options]                  (farm worker)\n"
        "       ptworker --list SCENE      (its cameras, animations, variants, lights)\n"
        "\n"
        "examples:\n"
        "  ptworker --scene scenes/cornell_box.gltf --spp 256 -o cornell.png\n"
        "  ptworker --scene helmet.glb --env studio.hdr --res 1280x720 --spp 512 -o helmet.exr\n"
        "  ptworker --scene sofa.glb --env studio.hdr --view agx --exposure -1 -o sofa.png\n"
        "  ptworker --server farm:7878 --token-file farm.token     (join a farm)\n"
        "\n"
        "Standalone: renders a glTF 2.0 scene (.gltf or .glb) with the ptfarm path tracer\n"
        "on this machine and writes an OpenEXR image (R, G, B, samples, variance) plus an\n"
        "sRGB PNG preview beside it.\n"
        "\n"
        "Lights: emissive triangles and KHR_lights_punctual lights. A light's number is\n"
        "used on the scale of emission, with no 683 lm/W or 4 pi factor: a point or spot\n"
        "light of intensity I gives irradiance I/d^2 at distance d, a directional light of\n"
        "intensity E gives irradiance E (glTF gives emission no unit; see README).\n"
        "\n"
        "Scene limits (both modes; ptserve checks uploads the same way): at most\n"
        "%u triangles and 3 times as many vertices, every instance of a mesh\n"
        "counted (an EXT_mesh_gpu_instancing mesh once, with at most %u instances\n"
        "of about 500 bytes); images of at most %llu texels (%u a side) and %llu\n"
        "texels over all textures; PNG data no longer than an image's size needs;\n"
        "with --time, --frame or --shutter, %llu morph target deltas (vertices x\n"
        "targets, every instance). They are read from the files before anything is\n"
        "built or decoded; a scene past them is refused. --shutter stops doubling\n"
        "its time steps at %llu triangles x steps. A worker needs 170 to 500 bytes\n"
        "a triangle and 4 a texel (docs/OPERATIONS.md, Limits).\n",
        PT_SCENE_MAX_TRIANGLES, PT_SCENE_MAX_INSTANCES,
        (unsigned long long)PT_SCENE_MAX_IMAGE_TEXELS, PT_SCENE_MAX_TEXTURE_DIM,
        (unsigned long long)PT_SCENE_MAX_TEXELS, (unsigned long long)PT_ANIM_MAX_MORPH_DELTAS,
        (unsigned long long)PT_MOTION_MAX_TRIANGLE_STEPS);
    fprintf(f,
            "\n"
            "Farm worker: connects to a ptserve coordinator, renders the tasks it hands out\n"
            "and sends the results back, until SIGTERM or SIGINT. Scenes are fetched by\n"
            "content hash and kept in the cache folder. A lost connection is retried with\n"
            "backoff (0.2 s doubling to 10 s); a refused token, build or protocol version\n"
            "ends the worker. A link that goes silent (cable, host or firewall) counts as\n"
            "lost after --link-timeout: the worker drops its tasks, which the coordinator\n"
            "requeues, and reconnects. It also denoises regions of frames the coordinator\n"
            "hands it.\n"
            "\n"
            "standalone options:\n"
            "  --scene PATH       the scene to render (required)\n"
            "  -o, --output PATH  the image to write (required), its format by its name:\n"
            "                     NAME.exr (OpenEXR, linear; an sRGB preview NAME.png\n"
            "                     beside it) or NAME.png (8-bit sRGB alone). Checked, with\n"
            "                     --env, before the scene is loaded\n"
            "  --spp N            samples per pixel (default 64)\n"
            "  --res WxH          image size (default 512 wide, height from the camera)\n"
            "  --seed S           random seed (default 0); same seed, same image\n"
            "  --threads T        render threads (default: all cores; both modes)\n"
            "  --max-depth D      bounce cap (default 1024); Russian roulette ends paths\n"
            "  --camera NAME      the camera to render: its name, its node's name or its\n"
            "                     index (default: the scene's first; with none, a view\n"
            "                     that frames the scene as posed, fitted to the image)\n"
            "  --camera-from X,Y,Z  a camera of your own at X,Y,Z (world coordinates, +Y\n"
            "  --camera-at X,Y,Z    up) looking at the point given; 40 degrees high unless\n"
            "  --fov DEG            --fov (0 to 180) or --ortho WIDTH (an orthographic view\n"
            "  --ortho WIDTH        WIDTH wide, its height from the image). Not with --camera\n"
            "  --variant NAME     a KHR_materials_variants variant: mapped primitives take\n"
            "                     its material (default: each primitive's own)\n"
            "  --time T           pose the scene's glTF animation at T seconds (>= 0):\n"
            "                     nodes, skins, morph targets, cameras and lights move\n"
            "  --frame F          the same at frame F, T = F / fps\n"
            "  --fps R            frames per second for --frame and --shutter (default 24)\n"
            "  --animation NAME   the animation to play, by name or index, or all (every\n"
            "                     channel of every animation at once); default: the\n"
            "                     first (said once when the file has several);\n"
            "                     without --time, --frame or --animation a scene renders\n"
            "                     as its still: its nodes' own transforms, no skinning\n"
            "  --tile N           tile side in pixels (default 32)\n"
            "  --chunk N          samples per chunk (default 16; rounded up to a multiple\n"
            "                     of 16, the blocks samples are summed in)\n"
            "  --target-error E   adaptive sampling: a tile stops once the RMS relative\n"
            "                     error of its pixel means is <= E (e.g. 0.01); off by default\n"
            "  --min-gain G       adaptive sampling for the lowest mean error: a tile stops\n"
            "                     once one more sample per pixel would lower the mean\n"
            "                     squared error of its pixels (R, G, B, absolute) by\n"
            "                     <= G; a tile then gets samples in proportion to its\n"
            "                     noise (e.g. 1e-6; smaller is longer); judged from the\n"
            "                     second chunk on, a tile of black samples only from the\n"
            "                     first; off by default; not with --target-error\n"
            "  --min-spp N        adaptive sampling: samples before a tile may stop\n"
            "                     (default: one chunk)\n"
            "  --env PATH         environment light: an equirectangular map, Radiance .hdr\n"
            "                     or OpenEXR (R, G, B); row 0 is straight up (+Y), the\n"
            "                     middle column the -Z direction\n"
            "  --env-strength S   the map's factor (default 1)\n"
            "  --env-rotate DEG   turn the map about +Y (default 0)\n"
            "  --background R,G,B a uniform environment of this radiance instead\n"
            "  --passes LIST      render passes written as layers of the EXR, a comma-\n"
            "                     separated list of albedo (albedo.R/G/B: of the first\n"
            "                     non-specular surface), normal (N.X/Y/Z: its shading\n"
            "                     normal, world space), depth (depth.Z: camera distance\n"
            "                     of the first hit), emission (emission.R/G/B), halves\n"
            "                     (halfA/halfB.R/G/B: the beauty over even and odd\n"
            "                     sample indices), cryptomatte (CryptoObject00-03 and\n"
            "                     CryptoMaterial00-03 with their manifests), or all;\n"
            "                     each of the first four with its variance\n"
            "                     (NAME.variance). The beauty keeps its bits\n"
            "  --transparent      camera rays that leave the scene add nothing (the\n"
            "                     environment still lights the scene), and the EXR gets\n"
            "                     an A channel: the pixel's coverage, RGB premultiplied;\n"
            "                     the PNG gets alpha (straight, the coverage)\n"
            "  --exposure EV      the PNG's exposure in stops: radiance x 2^EV (default 0;\n"
            "                     -20 to 20); the EXR stays linear\n"
            "  --view V           the PNG's view transform: standard (clamp + sRGB, the\n"
            "                     default), filmic (Hable's curve: bright areas roll off)\n"
            "                     or agx (Blender 4's AgX: bright colours desaturate)\n"
            "  --guiding on|off|auto  path guiding, experimental (default off): the light\n"
            "                     arriving at diffuse and rough surfaces is learned in\n"
            "                     passes of 16, 32, 64... spp and half of their directions\n"
            "                     drawn from it; on: wherever a material is glossy; auto:\n"
            "                     where the scene has glass (off with adaptive sampling,\n"
            "                     which on refuses); the farm's image is this one, bit for\n"
            "                     bit; not yet faster on the scenes measured\n"
            "                     (docs/bench/guiding.md)\n"
            "  --bdpt[=auto|on|off]  bidirectional path tracing: each sample also\n"
            "                     traces a path from the lights and joins the two at every\n"
            "                     vertex (light reaching a room indirectly, through a gap\n"
            "                     or off the ceiling, converges many times sooner); scenes\n"
            "                     lit by emissive surfaces, point, spot and directional\n"
            "                     lights and --env/--background, with opaque materials;\n"
            "                     the passes and --denoise take it. --bdpt alone is on;\n"
            "                     auto (the default) takes it where a scene lit by its\n"
            "                     emissive surfaces alone sends a quarter or more of their\n"
            "                     light into pockets (a lamp under the ceiling, inside a\n"
            "                     fitting) and says so; ptserve and ptctl submit take it\n"
            "                     too (docs/bench/bdpt.md)\n"
            "  --denoise          denoise the finished image (NFOR, guided by the passes\n"
            "                     albedo, normal, depth and halves, which it turns on):\n"
            "                     the EXR gets the layer denoised.R/G/B beside the\n"
            "                     untouched beauty, the PNG shows it; 2 spp or more\n"
            "  --max-denoise-mb N the memory --denoise may take (default: what the frame\n"
            "                     needs, about 0.42 KiB a pixel; at least 32): a larger\n"
            "                     frame is denoised in regions, the same bits\n"
            "  --clamp-direct X   clamp each sample's light that reaches the camera or the\n"
            "                     first surface it sees to R+G+B <= X, as Cycles' Clamp\n"
            "                     Direct (biased: fewer fireflies, darker highlights;\n"
            "                     default 0, off); ptserve and ptctl submit take it too\n"
            "  --clamp-indirect X the same for light after more bounces (Cycles' Clamp\n"
            "                     Indirect; 10 is a common start); counted in the summary\n"
            "  --shutter O,C      motion blur: the shutter opens and closes at these\n"
            "                     fractions of a frame (0,0.5: a 180-degree shutter;\n"
            "                     default off): what the scene's animation moves in\n"
            "                     [t + O/fps, t + C/fps] blurs (t: the frame's time)\n"
            "  --list SCENE       print what SCENE offers these options and exit: its\n"
            "                     cameras (names, nodes, indices), lights, animations,\n"
            "                     variants and the glTF extensions it uses\n"
            "  -q, --quiet        no progress line\n"
            "  -h, --help         this text\n"
            "  --version          the version and renderer build id\n"
            "\n"
            "farm worker options:\n"
            "  --server HOST:PORT the coordinator to work for ([V6]:PORT for IPv6)\n"
            "  --threads T        render threads (default: all cores)\n"
            "  --prefetch N       tasks asked for beyond T, so no thread idles while a\n"
            "                     result is in flight (default T; T + N <= %u)\n"
            "  --token-file F     the farm's shared token (default: none, for a coordinator\n"
            "                     that requires no token); at least 16 bytes, mode 0600;\n"
            "                     the coordinator must prove it too, or ptworker exits 1\n"
            "  --cache-dir D      where fetched scenes are kept (default: $XDG_CACHE_HOME/ptfarm\n"
            "                     or ~/.cache/ptfarm); several workers may share one\n"
            "  --name NAME        how the coordinator calls this worker (default HOST:PID,\n"
            "                     at most %u bytes)\n"
            "  --link-timeout SEC a connection whose sent data stays unacknowledged, or\n"
            "                     whose idle link answers no keepalive probe, this long is\n"
            "                     dropped and retried (default %u, %u to %u); keep it near\n"
            "                     ptserve's --lease-timeout\n"
            "\n"
            "exit status: standalone: 0 image written, 1 render or I/O error;\n"
            "             farm worker: 0 stopped by a signal, 1 refused by the coordinator or\n"
            "             a local error (token file, cache folder); 2 bad usage\n",
            PROTO_MAX_SLOTS, PROTO_MAX_NAME, WRK_LINK_TIMEOUT_MS / 1000u,
            WRK_LINK_TIMEOUT_MIN_MS / 1000u, WRK_LINK_TIMEOUT_MAX_MS / 1000u);
}

/* --list: after the portals, the ones that look wound the wrong way (as a
 * render warns of them). */
static void list_portals(const pt_scene *scene, FILE *out, void *ctx)
{
    (void)ctx;
    char note[512];
    if (pt_portal_check_text(scene, note, sizeof note))
        fprintf(out, "  %s\n", note);
}

/* An option's value through common/base/opt.h: -1 after saying why. */
static int bad_value(pt_status st, const pt_error *err)
{
    if (st == PT_OK)
        return 0;
    fprintf(stderr, "ptworker: %s\n", err->msg);
    return -1;
}

/* --link-timeout: seconds, fractions allowed, within the client's bounds; to milliseconds. */
static int parse_link_timeout(const char *s, uint32_t *ms, pt_error *err)
{
    double sec = 0;
    if (bad_value(pt_opt_seconds("--link-timeout", s, WRK_LINK_TIMEOUT_MIN_MS / 1000.0,
                                 WRK_LINK_TIMEOUT_MAX_MS / 1000.0, &sec, err),
                  err))
        return -1;
    *ms = (uint32_t)(sec * 1000.0 + 0.5);
    return 0;
}

int main(int argc, char **argv)
{
    wrk_standalone_opts o = {0};
    pt_render_opts ro;
    pt_render_opts_init(&ro);
    wrk_client_opts net = {0};
    uint32_t prefetch = 0;
    int has_prefetch = 0;
    /* Animation: --time, or --frame over --fps (default 24). */
    double anim_time = 0.0, anim_frame = 0.0;
    int has_time = 0, has_frame = 0;
    uint32_t max_denoise_mb = 0; /* --max-denoise-mb; 0: no limit */
    /* Which options were given, to refuse mixing the modes. */
    char standalone_opt[40] = "", farm_opt[40] = "";
    enum {
        OPT_SCENE = 256,
        OPT_THREADS,
        OPT_TIME,
        OPT_FRAME,
        OPT_LIST,
        OPT_MAX_DENOISE,
        OPT_SERVER, /* the farm worker's, from here on */
        OPT_PREFETCH,
        OPT_TOKEN,
        OPT_CACHE,
        OPT_NAME,
        OPT_LINK_TIMEOUT
    };
    static const struct option own[] = {
        {"scene", required_argument, NULL, OPT_SCENE},
        {"max-denoise-mb", required_argument, NULL, OPT_MAX_DENOISE},
        {"output", required_argument, NULL, 'o'},
        {"threads", required_argument, NULL, OPT_THREADS},
        {"time", required_argument, NULL, OPT_TIME},
        {"frame", required_argument, NULL, OPT_FRAME},
        {"list", required_argument, NULL, OPT_LIST},
        {"quiet", no_argument, NULL, 'q'},
        {"server", required_argument, NULL, OPT_SERVER},
        {"prefetch", required_argument, NULL, OPT_PREFETCH},
        {"token-file", required_argument, NULL, OPT_TOKEN},
        {"cache-dir", required_argument, NULL, OPT_CACHE},
        {"name", required_argument, NULL, OPT_NAME},
        {"link-timeout", required_argument, NULL, OPT_LINK_TIMEOUT},
        {"help", no_argument, NULL, 'h'},
        {"version", no_argument, NULL, 'V'},
    };
    /* Its own options, then every render option of the shared table
     * (common/render/options.h), then the end. */
    enum { NOWN = sizeof own / sizeof own[0] };
    struct option longopts[NOWN + PT_ROPT_COUNT + 1];
    /* Progressive saves are the coordinator's: no --denoise-progressive. */
    pt_render_getopt_table(own, NOWN, PT_ROPT_ALL & ~PT_ROPT(PT_ROPT_DENOISE_PROGRESSIVE),
                           longopts);
    int c, li = 0;
    pt_error err = {0};
    while ((c = getopt_long(argc, argv, "o:qh", longopts, &li)) != -1) {
        int bad = 0;
        switch (c) {
        case OPT_SCENE:
            o.scene_path = optarg;
            break;
        case 'o':
            o.out_path = optarg;
            break;
        case OPT_THREADS:
            bad = bad_value(pt_opt_u32("--threads", optarg, 1, 1024, &o.threads, &err), &err);
            break;
        case OPT_TIME:
            bad = bad_value(pt_opt_double("--time", optarg, 0.0, 1e9, &anim_time, &err), &err);
            has_time = 1;
            break;
        case OPT_FRAME:
            bad = bad_value(pt_opt_double("--frame", optarg, 0.0, 1e9, &anim_frame, &err), &err);
            has_frame = 1;
            break;
        case OPT_LIST:
            /* What the scene offers the options above; nothing rendered. */
            if (pt_scene_list(optarg, stdout, list_portals, NULL, &err) != PT_OK) {
                fprintf(stderr, "ptworker: %s\n", err.msg);
                return 1;
            }
            return 0;
        case 'q':
            o.quiet = 1;
            break;
        case OPT_SERVER:
            net.server = optarg;
            break;
        case OPT_PREFETCH:
            bad = bad_value(pt_opt_u32("--prefetch", optarg, 0, PROTO_MAX_SLOTS, &prefetch, &err),
                            &err);
            has_prefetch = 1;
            break;
        case OPT_TOKEN:
            net.token_file = optarg;
            break;
        case OPT_CACHE:
            net.cache_dir = optarg;
            break;
        case OPT_NAME:
            net.name = optarg;
            break;
        case OPT_LINK_TIMEOUT:
            bad = parse_link_timeout(optarg, &net.link_timeout_ms, &err);
            break;
        case OPT_MAX_DENOISE:
            /* 32 MiB holds regions of 32 pixels of any frame (crops of 224). */
            bad = bad_value(
                pt_opt_u32("--max-denoise-mb", optarg, 32, 1u << 22, &max_denoise_mb, &err), &err);
            break;
        case 'h':
            usage(stdout);
            return 0;
        case 'V':
            return pt_version_print("ptworker");
        default:
            if (!pt_render_opt_is(c)) {
                usage(stderr);
                return 2;
            }
            bad = bad_value(pt_render_opt_set(&ro, c, optarg, &err), &err);
        }
        if (bad)
            return 2;
        int farm = c >= OPT_SERVER && c <= OPT_LINK_TIMEOUT;
        char *seen = farm ? farm_opt : c != OPT_THREADS ? standalone_opt : NULL;
        if (seen && c == 'o')
            snprintf(seen, 40, "-o");
        else if (seen && c == 'q')
            snprintf(seen, 40, "-q");
        else if (seen)
            snprintf(seen, 40, "--%s", longopts[li].name);
    }
    if (optind < argc) {
        fprintf(stderr, "ptworker: unexpected argument '%s'\n", argv[optind]);
        usage(stderr);
        return 2;
    }
    if (net.server || farm_opt[0]) {
        if (!net.server) {
            fprintf(stderr, "ptworker: %s needs --server\n", farm_opt);
            usage(stderr);
            return 2;
        }
        if (standalone_opt[0]) {
            fprintf(stderr, "ptworker: %s is a standalone option; not with --server\n",
                    standalone_opt);
            return 2;
        }
        if (net.name && (!net.name[0] || strlen(net.name) > PROTO_MAX_NAME)) {
            fprintf(stderr, "ptworker: --name: 1 to %u bytes\n", PROTO_MAX_NAME);
            return 2;
        }
        net.threads = o.threads;
        if (net.threads == 0) {
            long n = sysconf(_SC_NPROCESSORS_ONLN);
            net.threads = n > 0 ? (uint32_t)n : 1;
            if (net.threads > PROTO_MAX_SLOTS / 2)
                net.threads = PROTO_MAX_SLOTS / 2;
        }
        net.prefetch = has_prefetch ? prefetch : net.threads;
        if (!has_prefetch && net.threads + net.prefetch > PROTO_MAX_SLOTS)
            net.prefetch = PROTO_MAX_SLOTS - net.threads;
        if (net.threads + net.prefetch > PROTO_MAX_SLOTS) {
            fprintf(stderr, "ptworker: --threads + --prefetch is %u, over %u\n",
                    net.threads + net.prefetch, PROTO_MAX_SLOTS);
            return 2;
        }
        return wrk_client_run(&net);
    }
    if (!o.scene_path || !o.out_path) {
        fprintf(stderr, "ptworker: --scene and -o are required (or --server HOST:PORT)\n");
        usage(stderr);
        return 2;
    }
    if (bad_value(pt_render_opts_finish(&ro, &err), &err))
        return 2;
    int given_fps = (ro.given & PT_ROPT(PT_ROPT_FPS)) != 0;
    int given_shutter = (ro.given & PT_ROPT(PT_ROPT_SHUTTER)) != 0;
    if (has_time && has_frame) {
        fprintf(stderr, "ptworker: --time and --frame both give the time; give one\n");
        return 2;
    }
    if (given_fps && !has_frame && !given_shutter) {
        fprintf(stderr, "ptworker: --fps needs --frame or --shutter\n");
        return 2;
    }
    /* The shared options into the standalone render's. */
    o.spp = ro.spp;
    o.width = ro.width;
    o.height = ro.height;
    o.seed = ro.seed;
    o.max_depth = ro.max_depth;
    o.camera = ro.camera;
    o.variant = ro.variant;
    o.animation = ro.animation;
    o.tile = ro.tile;
    o.chunk = ro.chunk;
    o.target_error = ro.target_error;
    o.min_gain = ro.min_gain;
    o.guiding = (int)ro.guiding;
    o.bdpt = ro.bdpt;
    if (o.guiding && (o.target_error > 0.0 || o.min_gain > 0.0)) {
        /* A tile's adaptive stop would depend on the pass it is in: auto
         * leaves guiding off, on is refused. */
        if (o.guiding == PT_GUIDING_ON) {
            fprintf(stderr, "ptworker: --guiding on does not combine with --target-error or "
                            "--min-gain yet\n");
            return 2;
        }
        o.guiding = PT_GUIDING_OFF;
    }
    o.min_spp = ro.min_spp;
    o.env_path = ro.env_path;
    o.env_strength = (float)ro.env_strength;
    o.env_rotate = (float)ro.env_rotate;
    o.has_background = (ro.given & PT_ROPT(PT_ROPT_BACKGROUND)) != 0;
    for (int k = 0; k < 3; k++)
        o.background[k] = (float)ro.background[k];
    o.transparent = (ro.given & PT_ROPT(PT_ROPT_TRANSPARENT)) != 0;
    o.has_shutter = given_shutter;
    o.shutter[0] = ro.shutter[0];
    o.shutter[1] = ro.shutter[1];
    o.view = ro.view;
    o.fps = ro.fps;
    o.passes = ro.passes;
    o.clamp_direct = ro.clamp_direct;
    o.clamp_indirect = ro.clamp_indirect;
    o.denoise = ro.denoise;
    o.denoise_max = (uint64_t)max_denoise_mb << 20;
    if (max_denoise_mb && !ro.denoise) {
        fprintf(stderr, "ptworker: --max-denoise-mb bounds --denoise, which was not given\n");
        return 2;
    }
    if (ro.animation)
        o.animate = 1;
    if (has_time || has_frame) {
        o.animate = 1;
        o.time = has_time ? anim_time : anim_frame / ro.fps;
    }
    if (o.chunk != pt_chunk_whole_blocks(o.chunk)) {
        fprintf(stderr,
                "ptworker: --chunk %u rounded up to %u: samples are summed in blocks of %u\n",
                o.chunk, pt_chunk_whole_blocks(o.chunk), PT_SAMPLE_BLOCK);
        o.chunk = pt_chunk_whole_blocks(o.chunk);
    }
    if (o.min_spp == 0)
        o.min_spp = o.chunk > 1 ? o.chunk : 2;
    return wrk_standalone_run(&o);
}
