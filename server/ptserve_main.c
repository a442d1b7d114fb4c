/*
 * ptserve - the ptfarm coordinator.
 *
 *   ptserve [options] -o OUT.exr SCENE            serve workers that connect
 *   ptserve --local N [options] -o OUT.exr SCENE  and start N of them here
 *   ptserve --state-dir DIR [options]             a render queue that ptctl fills
 */
#include <float.h>
#include <getopt.h>
#include <stdio.h>
#include <string.h>

#include "common/base/frames.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "common/image/denoise.h"
#include "common/image/image.h"
#include "common/image/view.h"
#include "common/render/options.h"
#include "common/render/tile.h"
#include "common/scene/scene.h"
#include "server/app/local.h"
#include "server/net/io.h"
#include "server/sched/dnshare.h"
#include "server/serve.h"

static void usage(FILE *f)
{
    fprintf(
        f,
        "usage: ptserve [options] -o OUT.exr|OUT.png SCENE\n"
        "       ptserve --local N [options] -o OUT.exr|OUT.png SCENE\n"
        "       ptserve --local N --frames A-B[:STEP] [options] -o SHOT.####.exr SCENE\n"
        "       ptserve --state-dir DIR [--output-dir DIR] [options]\n"
        "\n"
        "examples:\n"
        "  ptserve --local 4 --spp 512 -o out.exr scene.gltf     (one machine, 4 workers)\n"
        "  ptserve --local 4 --spp 256 --view agx -o out.png scene.gltf   (a PNG alone)\n"
        "  ptserve --state-dir /var/lib/ptfarm --listen 0.0.0.0:7878 --token-file farm.token\n"
        "          --http 0.0.0.0:8080                          (a render queue, a dashboard)\n"
        "\n"
        "Coordinates a ptfarm render: splits each image into tiles x sample ranges,\n"
        "leases them to ptworker processes, merges their results in a fixed order (the\n"
        "image does not depend on how the work was split) and writes progressive\n"
        "OpenEXR images (R, G, B, samples, variance) plus a PNG preview.\n"
        "\n"
        "With a SCENE it renders that one scene to -o and exits 0 when the image is\n"
        "complete. With --state-dir and no SCENE it is a long-running render queue:\n"
        "clients submit jobs with ptctl; jobs run by priority, then submission order;\n"
        "the queue and a checkpoint of every running job live in the state folder, so\n"
        "after a crash or kill -9 a restart resumes them with no merged sample lost.\n"
        "\n"
        "queue mode:\n"
        "  --state-dir DIR        the queue, scenes, checkpoints and results logs (a\n"
        "                         result is merged once fdatasync'd; a job's log is\n"
        "                         folded into a checkpoint at 4x its film's size)\n"
        "  --max-log-mb N         results held in memory until their log is on disk:\n"
        "                         past N MiB (default 512), workers are not read until\n"
        "                         the disk is back under half of it\n"
        "  --output-dir DIR       where images are written (default DIR/output), as\n"
        "                         ID-NAME.exr with NAME reduced to [A-Za-z0-9._-]\n"
        "  --max-res N            longest image side a client may ask for (default 16384)\n"
        "  --max-pixels N         width x height a client may ask for (default 16777216)\n"
        "  --max-film-mb N        coordinator memory one job's film may take, its render\n"
        "                         passes included (72 bytes a pixel, 480 with passes;\n"
        "                         default 4096: a 3840x2160 frame with every pass)\n"
        "  --max-spp N            samples per pixel a client may ask for (default 65536)\n"
        "  --max-scene-mb N       scene upload size limit in MiB (default 512)\n"
        "  --max-queued N         unfinished jobs per client identity (default 64)\n"
        "  --clients-file PATH    per-client tokens, one 'NAME TOKEN' a line (# comments):\n"
        "                         a client proving one of them is NAME, whatever name it\n"
        "                         declares, and may cancel only its own jobs; the shared\n"
        "                         token (--token-file, required with this) is the admin's\n"
        "                         and the workers'. Without it every client is an admin\n"
        "                         (docs/OPERATIONS.md, \"Clients and admins\")\n"
        "  (--tile, --chunk and --max-depth set the defaults of submitted jobs, and\n"
        "  --task-time sizes every job's tasks; a\n"
        "  job's --env or --background is given to ptctl submit, and its map is\n"
        "  uploaded with the scene and checked before the job is queued)\n"
        "\n"
        "one-job mode:\n"
        "  -o, --output PATH      the image to write (required), its format by its name:\n"
        "                         NAME.exr (OpenEXR, linear; a preview NAME.png beside\n"
        "                         it) or NAME.png (8-bit, the preview alone). Checked,\n"
        "                         with --env and --frames' pattern, before the scene\n"
        "                         is loaded\n"
        "  --local N              start N ptworker processes on this machine\n"
        "  --worker-threads T     threads per local worker (default: cores / N)\n"
        "  --local-stop-timeout SEC  when ptserve stops, a local worker still running\n"
        "                         this long after SIGTERM is killed (default 10)\n"
        "  --listen HOST:PORT     where workers connect (default 127.0.0.1:7878; with\n"
        "                         --local, a free loopback port)\n"
        "  --token-file PATH      shared secret workers and clients must prove (mutual\n"
        "                         HMAC challenge); without it ptserve listens on loopback\n"
        "                         only. At least 16 bytes, mode 0600 (refused otherwise);\n"
        "                         make one with:\n"
        "                           " PROTO_TOKEN_HOWTO "\n"
        "                         After 5 wrong answers from one address, its handshakes\n"
        "                         are refused for 1 s, doubling per failure up to 60 s\n"
        "  --spp N                samples per pixel (default 64)\n"
        "  --res WxH              image size (default 512 wide, height from the camera)\n"
        "  --seed S               random seed (default 0)\n"
        "  --camera NAME          the camera to render: its name, its node's name or its\n"
        "                         index (default: the scene's first; with none, a view\n"
        "                         framing the scene as posed, fitted to the image)\n"
        "  --camera-from X,Y,Z    a camera of your own at X,Y,Z (world coordinates, +Y up)\n"
        "  --camera-at X,Y,Z      looking at this point; 40 degrees high unless --fov DEG\n"
        "  --fov DEG, --ortho W   (0 to 180) or --ortho W (orthographic, W wide); it\n"
        "                         travels with the job as its camera (queued jobs: ptctl\n"
        "                         submit --camera-from); not with --camera\n"
        "  --max-depth D          bounce cap (default 1024); Russian roulette ends paths\n"
        "  --target-error E       adaptive sampling: a tile stops once the RMS relative\n"
        "                         error of its pixel means is <= E (e.g. 0.01); off by default\n"
        "  --min-gain G           adaptive sampling for the lowest mean error: a tile\n"
        "                         stops once one more sample per pixel would lower the\n"
        "                         mean squared error of its pixels (R, G, B, absolute)\n"
        "                         by <= G; a tile then gets samples in proportion to its\n"
        "                         noise (e.g. 1e-6; smaller is longer); judged from the\n"
        "                         second chunk on, a tile of black samples only from\n"
        "                         the first; off by default; not with --target-error\n"
        "  --min-spp N            adaptive sampling: samples before a tile may stop\n"
        "                         (default: one chunk)\n"
        "  --env PATH             environment light: an equirectangular map (Radiance\n"
        "                         .hdr or OpenEXR, row 0 straight up, the middle column\n"
        "                         -Z); rays leaving the scene see it. It travels to the\n"
        "                         workers inside the scene bundle; refused at start when\n"
        "                         it cannot be read or holds NaN, Inf or absurd values\n"
        "  --env-strength S       the map's factor (default 1)\n"
        "  --env-rotate DEG       turn the map about +Y (default 0)\n"
        "  --background R,G,B     a uniform environment of this radiance instead\n"
        "                         (a scene with no emitter, no KHR_lights_punctual light\n"
        "                         and neither of these is refused: it would render black)\n"
        "  --transparent          camera rays that leave the scene add nothing, and the\n"
        "                         EXR gets an A channel (coverage; RGB premultiplied);\n"
        "                         one-job mode (queued jobs: ptctl submit --transparent)\n"
        "  --passes LIST          render passes as EXR layers: albedo, normal, depth,\n"
        "                         emission, halves, cryptomatte, or all (see ptworker\n"
        "                         --help); merged exactly like the beauty; one-job\n"
        "                         mode (queued jobs: ptctl submit --passes)\n"
        "  --denoise              denoise the finished image (NFOR, with the passes it\n"
        "                         needs) into the EXR's layer denoised.R/G/B, off the\n"
        "                         event loop; the preview shows it; one-job mode\n"
        "                         (queued jobs: ptctl submit --denoise)\n"
        "  --denoise-progressive  --denoise, and every progressive save denoised too,\n"
        "                         off the event loop; saves that come while one is\n"
        "                         denoised wait and only the newest is taken; the\n"
        "                         finished image stops a progressive one at once\n"
        "  --max-denoise-mb N     memory one frame's denoising may take (default: what\n"
        "                         it needs, about 0.42 KiB a pixel); a larger frame is\n"
        "                         denoised in regions, the same bits for more CPU. At\n"
        "                         least 32; both modes\n"
        "  --denoise-on-workers   share a finished frame's denoising with the workers:\n"
        "                         its regions are leased to them while the\n"
        "                         coordinator denoises the rest (and any region out\n"
        "                         too long); the same bits, each worker's first region\n"
        "                         and --verify-fraction of the others denoised again\n"
        "                         here; a queue's jobs\n"
        "  --denoise-region N     those regions' side in pixels (default 512; a\n"
        "                         multiple of 32, 32 to 1024)\n"
        "  --bdpt[=auto|on|off]   bidirectional path tracing, as ptworker --bdpt (the\n"
        "                         same bits; auto, the default, decided here once per\n"
        "                         job); one-job mode (queued jobs: ptctl submit --bdpt)\n"
        "  --guiding on|off|auto  path guiding learned by the farm (default off): as\n"
        "                         ptworker --guiding, whose image it gives bit for bit;\n"
        "                         one-job mode (queued jobs: ptctl submit --guiding)\n"
        "  --clamp-direct X       clamp each sample's light that reaches the camera or\n"
        "                         the first surface it sees to R+G+B <= X, as Cycles'\n"
        "                         Clamp Direct (biased; default 0, off); one-job mode\n"
        "                         (queued jobs: ptctl submit --clamp-direct)\n"
        "  --clamp-indirect X     the same for light after more bounces (Cycles' Clamp\n"
        "                         Indirect); the image is ptworker --clamp-* 's, bit for bit\n"
        "  --variant NAME         the KHR_materials_variants variant: mapped primitives\n"
        "                         take its material; one-job mode (queued jobs: ptctl\n"
        "                         submit --variant)\n"
        "  --frames A-B[:STEP]    render the frames A, A+STEP, ... B of the scene's\n"
        "                         animation as one job (at most 100000 frames, numbers\n"
        "                         0 to 999999): -o must have a '#' run, replaced by the\n"
        "                         zero-padded frame number (shot.####.exr: frame 7 is\n"
        "                         shot.0007.exr); early frames finish first; each frame\n"
        "                         is the same image as ptworker --scene ... --frame F\n"
        "  --animation NAME|INDEX|all  the animation played (default: the first, said\n"
        "                         once when there are several; all: every one at once);\n"
        "                         one-job mode (queued jobs: ptctl submit)\n"
        "  --shutter O,C          motion blur: the shutter opens and closes at these\n"
        "                         fractions of a frame (0,0.5: 180 degrees; default off);\n"
        "                         what the scene's animation moves then blurs; one-job\n"
        "                         mode (queued jobs: ptctl submit --shutter)\n"
        "  --fps R                frames per second of --frames and --shutter: frame F\n"
        "                         is at F / R seconds (default 24)\n"
        "  --tile N               tile side in pixels (default 32)\n"
        "  --task-time MS         size each task's samples so that it takes about MS\n"
        "                         on the worker that asks, from that worker's measured\n"
        "                         speed (default 2000): 16 samples first, then at most\n"
        "                         8 times a tile's samples, smaller again near the end\n"
        "  --chunk N              fixed tasks of N samples instead of --task-time; also\n"
        "                         the step at which adaptive sampling judges a tile\n"
        "                         (default 16), which an adaptive job's tasks never cross;\n"
        "                         rounded up to a multiple of 16\n"
        "  --save-interval SEC    progressive saves at most this often (default 5)\n"
        "  --lease-timeout SEC    requeue a task whose worker is silent this long (default 20);\n"
        "                         also the shortest hard deadline of a lease\n"
        "  --verify-fraction F    render this share of tasks twice on different workers and\n"
        "                         compare bit for bit; a worker found lying is blocked\n"
        "                         (default 0.02, 0: off)\n"
        "  --handshake-timeout SEC  drop a peer that has not authenticated by then (default 10)\n"
        "  --port-file PATH       write the port listened on to PATH\n"
        "\n"
        "previews (either mode; every job's PNG; the EXR stays linear):\n"
        "  --exposure EV          radiance x 2^EV before the view (default 0; -20 to 20)\n"
        "  --view V               standard (clamp + sRGB, the default), filmic (Hable's\n"
        "                         curve: bright areas roll off) or agx (Blender 4's AgX)\n"
        "\n"
        "dashboard (either mode; docs/OPERATIONS.md, \"Dashboard\"):\n"
        "  --http HOST:PORT       serve the web dashboard, a JSON API (/api/jobs,\n"
        "                         /api/workers) and Prometheus /metrics there; off by\n"
        "                         default. Loopback only without --token-file; with one,\n"
        "                         every request needs 'Authorization: Bearer TOKEN' or a\n"
        "                         login (the shared token, or a --clients-file token)\n"
        "  --http-port-file PATH  write the dashboard's port to PATH\n"
        "  --http-host NAMES      host names the dashboard answers to (comma-separated,\n"
        "                         e.g. farm.example.com); it always answers to IP\n"
        "                         addresses and localhost, and refuses other Host headers\n"
        "                         (DNS rebinding) with 421\n"
        "\n"
        "limits on peers (either mode; docs/OPERATIONS.md, \"Limits\"):\n"
        "  --max-input-mb N       input buffers past 64 KiB each, all peers together\n"
        "                         (default 512); a peer whose next frame would pass it\n"
        "                         is not read until memory frees (a frame is at most\n"
        "                         2.25 MiB from a worker, 1 MiB from a client)\n"
        "  --max-handshakes N     connections not yet authenticated (default 64; the\n"
        "                         other slots are for authenticated peers). Slots in all:\n"
        "                         the file descriptor limit (ulimit -n; the soft limit\n"
        "                         is raised to the hard one at start) less 128 for\n"
        "                         files, logged at start\n"
        "  --max-handshakes-per-ip N  of those, from one address (default 8)\n"
        "  --frame-grace SEC      a frame or an upload may take this long whatever its\n"
        "                         size; a peer silent this long mid-frame is closed\n"
        "                         (default 30)\n"
        "  --min-rate KIB         past the grace, a frame or upload must average this\n"
        "                         many KiB/s from its first byte, or the peer is closed\n"
        "                         (default 16)\n"
        "  --merge-threads N      threads that add results to the images (default 2;\n"
        "                         0: the event loop adds them itself); the loop still\n"
        "                         decides every merge, so images are the same bits\n"
        "  --io-threads N         threads that receive, check and decode the workers'\n"
        "                         frames once they have authenticated (default 2; 0:\n"
        "                         the event loop reads them itself)\n"
        "  --worker-bin PATH      the ptworker to start with --local (default: beside ptserve)\n"
        "  -q, --quiet            no progress line\n"
        "  -h, --help             this text\n"
        "  --version              the version and renderer build id\n"
        "\n"
        "\n"
        "exit status: 0 image complete (queue mode: stopped by SIGINT/SIGTERM after\n"
        "checkpointing), 1 error (reason on stderr), 2 bad usage, 130 one-job render\n"
        "interrupted (the last progressive EXR is valid)\n");
}

/* What main's checks need besides the configuration: options given and
 * values before they are converted. */
typedef struct parsed {
    double lease, handshake, grace, local_stop; /* seconds */
    int has_task_time, log_given, has_chunk, has_shutter, env_opts, placed;
    double shutter[2]; /* fractions of a frame */
} parsed;

enum {
    O_LOCAL = 256,
    O_WTHREADS,
    O_LISTEN,
    O_TOKEN,
    O_SAVE,
    O_LEASE,
    O_PORTFILE,
    O_WBIN,
    O_HANDSHAKE,
    O_STATE,
    O_OUTDIR,
    O_MAXRES,
    O_MAXPIX,
    O_MAXSPP,
    O_MAXSCENE,
    O_MAXQUEUED,
    O_FRAMES,
    O_CLIENTS,
    O_MAXINPUT,
    O_MAXHS,
    O_MAXHSIP,
    O_GRACE,
    O_MINRATE,
    O_VERIFY,
    O_HTTP,
    O_HTTPPORT,
    O_HTTPHOST,
    O_TASKTIME,
    O_MERGETHREADS,
    O_IOTHREADS,
    O_MAXLOG,
    O_MAXFILM,
    O_MAXDENOISE,
    O_DNWORKERS,
    O_DNREGION,
    O_LOCALSTOP
};
static const struct option own[] = {
    {"output", required_argument, NULL, 'o'},
    {"local", required_argument, NULL, O_LOCAL},
    {"worker-threads", required_argument, NULL, O_WTHREADS},
    {"local-stop-timeout", required_argument, NULL, O_LOCALSTOP},
    {"listen", required_argument, NULL, O_LISTEN},
    {"token-file", required_argument, NULL, O_TOKEN},
    {"clients-file", required_argument, NULL, O_CLIENTS},
    {"frames", required_argument, NULL, O_FRAMES},
    {"task-time", required_argument, NULL, O_TASKTIME},
    {"merge-threads", required_argument, NULL, O_MERGETHREADS},
    {"io-threads", required_argument, NULL, O_IOTHREADS},
    {"max-log-mb", required_argument, NULL, O_MAXLOG},
    {"save-interval", required_argument, NULL, O_SAVE},
    {"lease-timeout", required_argument, NULL, O_LEASE},
    {"port-file", required_argument, NULL, O_PORTFILE},
    {"handshake-timeout", required_argument, NULL, O_HANDSHAKE},
    {"verify-fraction", required_argument, NULL, O_VERIFY},
    {"worker-bin", required_argument, NULL, O_WBIN},
    {"state-dir", required_argument, NULL, O_STATE},
    {"output-dir", required_argument, NULL, O_OUTDIR},
    {"max-res", required_argument, NULL, O_MAXRES},
    {"max-pixels", required_argument, NULL, O_MAXPIX},
    {"max-film-mb", required_argument, NULL, O_MAXFILM},
    {"max-denoise-mb", required_argument, NULL, O_MAXDENOISE},
    {"denoise-on-workers", no_argument, NULL, O_DNWORKERS},
    {"denoise-region", required_argument, NULL, O_DNREGION},
    {"max-spp", required_argument, NULL, O_MAXSPP},
    {"max-scene-mb", required_argument, NULL, O_MAXSCENE},
    {"max-queued", required_argument, NULL, O_MAXQUEUED},
    {"max-input-mb", required_argument, NULL, O_MAXINPUT},
    {"max-handshakes", required_argument, NULL, O_MAXHS},
    {"max-handshakes-per-ip", required_argument, NULL, O_MAXHSIP},
    {"frame-grace", required_argument, NULL, O_GRACE},
    {"min-rate", required_argument, NULL, O_MINRATE},
    {"http", required_argument, NULL, O_HTTP},
    {"http-port-file", required_argument, NULL, O_HTTPPORT},
    {"http-host", required_argument, NULL, O_HTTPHOST},
    {"quiet", no_argument, NULL, 'q'},
    {"help", no_argument, NULL, 'h'},
    {"version", no_argument, NULL, 'V'},
};

/* The defaults of every option of ptserve's own. */
static void config_defaults(srv_config *c, parsed *x)
{
    memset(c, 0, sizeof *c);
    memset(x, 0, sizeof *x);
    c->task_ms = SRV_DEFAULT_TASK_MS;
    c->job.rr_depth = 3;
    c->save_interval = 5.0;
    c->merge_threads = SRV_DEFAULT_MERGE_THREADS;
    c->io_threads = SRV_DEFAULT_IO_THREADS;
    c->max_log_mem = SRV_DEFAULT_MAX_LOG_MEM;
    c->verify_fraction = 0.02;
    c->denoise_side = SRV_DNSHARE_SIDE;
    c->caps.max_side = PT_RENDER_MAX_SIDE;
    c->caps.max_pixels = 16777216;
    c->caps.max_spp = 65536;
    c->caps.max_scene = 512ull << 20;
    c->caps.max_film = 4096ull << 20;
    c->caps.max_queued = 64;
    proto_env_none(&c->job.env);
    x->lease = 20.0;
    x->handshake = 10.0;
    x->grace = 30.0;
    x->local_stop = SRV_DEFAULT_LOCAL_STOP_MS / 1000.0;
}

/* One of ptserve's own options (ch, its text optarg) into c and x. */
static pt_status own_option(int ch, srv_config *c, parsed *x, pt_error *err)
{
    pt_status st = PT_OK;
    uint32_t v;
    switch (ch) {
    case 'o':
        c->out_path = optarg;
        break;
    case O_LOCAL:
        st = pt_opt_u32("--local", optarg, 1, 256, &c->local_workers, err);
        break;
    case O_WTHREADS:
        st = pt_opt_u32("--worker-threads", optarg, 1, 1024, &c->worker_threads, err);
        break;
    case O_IOTHREADS:
        st = pt_opt_u32("--io-threads", optarg, 0, SRV_IO_MAX_THREADS, &c->io_threads, err);
        break;
    case O_MERGETHREADS:
        st =
            pt_opt_u32("--merge-threads", optarg, 0, SRV_ADDER_MAX_THREADS, &c->merge_threads, err);
        break;
    case O_LISTEN:
        c->listen = optarg;
        break;
    case O_TOKEN:
        c->token_path = optarg;
        break;
    case O_CLIENTS:
        c->clients_path = optarg;
        break;
    case O_FRAMES:
        st = pt_frames_parse("--frames", optarg, &c->frames, err);
        break;
    case O_TASKTIME:
        st = pt_opt_u32("--task-time", optarg, 1, 3600000, &c->task_ms, err);
        x->has_task_time = 1;
        break;
    case O_SAVE:
        st = pt_opt_seconds("--save-interval", optarg, 0, 86400, &c->save_interval, err);
        break;
    case O_LEASE:
        st = pt_opt_seconds("--lease-timeout", optarg, 0, 86400, &x->lease, err);
        break;
    case O_PORTFILE:
        c->port_file = optarg;
        break;
    case O_HANDSHAKE:
        st = pt_opt_seconds("--handshake-timeout", optarg, 0, 86400, &x->handshake, err);
        break;
    case O_VERIFY:
        st = pt_opt_double("--verify-fraction", optarg, 0.0, 1.0, &c->verify_fraction, err);
        break;
    case O_WBIN:
        c->worker_bin = optarg;
        break;
    case O_STATE:
        c->state_dir = optarg;
        break;
    case O_OUTDIR:
        c->output_dir = optarg;
        break;
    case O_MAXRES:
        st = pt_opt_u32("--max-res", optarg, 1, 65536, &c->caps.max_side, err);
        break;
    case O_MAXPIX:
        if ((st = pt_opt_u32("--max-pixels", optarg, 1, UINT32_MAX, &v, err)) == PT_OK)
            c->caps.max_pixels = v;
        break;
    case O_MAXSPP:
        st = pt_opt_u32("--max-spp", optarg, 1, 1u << 24, &c->caps.max_spp, err);
        break;
    case O_MAXSCENE:
        if ((st = pt_opt_u32("--max-scene-mb", optarg, 1, 2048, &v, err)) == PT_OK)
            c->caps.max_scene = (uint64_t)v << 20;
        break;
    case O_MAXQUEUED:
        st = pt_opt_u32("--max-queued", optarg, 1, 100000, &c->caps.max_queued, err);
        break;
    case O_MAXFILM:
        if ((st = pt_opt_u32("--max-film-mb", optarg, 1, 1u << 22, &v, err)) == PT_OK)
            c->caps.max_film = (uint64_t)v << 20;
        break;
    case O_MAXDENOISE:
        /* 32 MiB holds regions of 32 pixels of any frame (crops of 224). */
        if ((st = pt_opt_u32("--max-denoise-mb", optarg, 32, 1u << 22, &v, err)) == PT_OK)
            c->max_denoise = (uint64_t)v << 20;
        break;
    case O_DNWORKERS:
        c->denoise_share = 1;
        break;
    case O_DNREGION:
        if ((st = pt_opt_u32("--denoise-region", optarg, PT_DENOISE_TILE, PROTO_MAX_DENOISE_REGION,
                             &c->denoise_side, err)) == PT_OK &&
            c->denoise_side % PT_DENOISE_TILE != 0)
            st = pt_error_set(err, PT_ERR_ARG, "--denoise-region %u is not a multiple of %u",
                              c->denoise_side, PT_DENOISE_TILE);
        break;
    case O_MAXLOG:
        if ((st = pt_opt_u32("--max-log-mb", optarg, 1, 1u << 20, &v, err)) == PT_OK)
            c->max_log_mem = (uint64_t)v << 20;
        x->log_given = 1;
        break;
    case O_MAXINPUT:
        if ((st = pt_opt_u32("--max-input-mb", optarg, 3, 1u << 20, &v, err)) == PT_OK)
            c->limits.max_input_mem = (uint64_t)v << 20;
        break;
    case O_MAXHS:
        st = pt_opt_u32("--max-handshakes", optarg, 1, 512, &c->limits.max_handshakes, err);
        break;
    case O_MAXHSIP:
        st = pt_opt_u32("--max-handshakes-per-ip", optarg, 1, 512, &c->limits.max_handshakes_ip,
                        err);
        break;
    case O_GRACE:
        st = pt_opt_seconds("--frame-grace", optarg, 0.1, 3600, &x->grace, err);
        break;
    case O_LOCALSTOP:
        st = pt_opt_seconds("--local-stop-timeout", optarg, 0.1, 3600, &x->local_stop, err);
        break;
    case O_MINRATE:
        if ((st = pt_opt_u32("--min-rate", optarg, 1, 1u << 20, &v, err)) == PT_OK)
            c->limits.min_rate = v << 10;
        break;
    case O_HTTP:
        c->http = optarg;
        break;
    case O_HTTPPORT:
        c->http_port_file = optarg;
        break;
    case O_HTTPHOST:
        c->http_hosts = optarg;
        break;
    case 'q':
        c->quiet = 1;
        break;
    }
    return st;
}

/* The shared render options into the job (one-job mode) or the defaults
 * of submitted jobs (queue mode: tile, chunk, max depth). */
static void job_from_options(srv_config *c, const pt_render_opts *ro, parsed *x)
{
    c->job.spp = ro->spp;
    c->job.width = ro->width;
    c->job.height = ro->height;
    c->job.seed = ro->seed;
    c->job.max_depth = ro->max_depth;
    c->job.tile = ro->tile;
    c->job.chunk = ro->chunk;
    c->job.target_error = ro->target_error;
    c->job.min_gain = ro->min_gain;
    c->job.min_spp = ro->min_spp;
    x->has_chunk = (ro->given & PT_ROPT(PT_ROPT_CHUNK)) != 0;
    x->has_shutter = (ro->given & PT_ROPT(PT_ROPT_SHUTTER)) != 0;
    x->env_opts = (ro->given & (PT_ROPT(PT_ROPT_ENV_STRENGTH) | PT_ROPT(PT_ROPT_ENV_ROTATE))) != 0;
    x->placed = (ro->given & PT_ROPT(PT_ROPT_CAMERA_FROM)) != 0;
    x->shutter[0] = ro->shutter[0];
    x->shutter[1] = ro->shutter[1];
    if (ro->camera)
        snprintf(c->job.camera, sizeof c->job.camera, "%s", ro->camera);
    if (ro->variant)
        snprintf(c->job.variant, sizeof c->job.variant, "%s", ro->variant);
    c->animation = ro->animation;
    c->fps = (ro->given & PT_ROPT(PT_ROPT_FPS)) ? ro->fps : 0.0;
    c->env_path = ro->env_path;
    c->job.env.strength = (float)ro->env_strength;
    c->job.env.rotate_deg = (float)ro->env_rotate;
    if (ro->given & PT_ROPT(PT_ROPT_BACKGROUND)) {
        c->job.env.background = 1;
        for (int k = 0; k < 3; k++)
            c->job.env.rgb[k] = (float)ro->background[k];
    }
    if (ro->given & PT_ROPT(PT_ROPT_TRANSPARENT))
        c->job.film_flags |= PROTO_FILM_TRANSPARENT;
    c->job.film_flags |= proto_film_of_bdpt(ro->bdpt);
    c->job.film_flags |= proto_film_of_passes(ro->passes);
    if (ro->denoise)
        c->job.film_flags |= PROTO_FILM_DENOISE;
    if (ro->denoise_progressive)
        c->job.film_flags |= PROTO_FILM_DENOISE_PROGRESSIVE;
    c->job.clamp[0] = ro->clamp_direct;
    c->job.clamp[1] = ro->clamp_indirect;
    c->guiding = ro->guiding;
    c->view = ro->view;
}

/* The options that go together, for the mode they ask for (nargs: the
 * scenes named); the last conversions into c. 0, or an exit status after
 * saying why. */
static int check_options(srv_config *c, const pt_render_opts *ro, parsed *x, int nargs)
{
    if (c->state_dir) {
        if (nargs != 0 || c->out_path) {
            fprintf(stderr, "ptserve: --state-dir runs a queue: no SCENE or -o (submit jobs "
                            "with ptctl)\n");
            return 2;
        }
    } else if (nargs != 1 || !c->out_path) {
        fprintf(stderr, "ptserve: need -o OUT.exr and exactly one SCENE, or --state-dir DIR\n");
        usage(stderr);
        return 2;
    } else if (c->output_dir || x->log_given) {
        fprintf(stderr, "ptserve: %s is for queue mode (--state-dir)\n",
                c->output_dir ? "--output-dir" : "--max-log-mb");
        return 2;
    }
    if (c->state_dir && (c->env_path || c->job.env.background || x->env_opts)) {
        fprintf(stderr, "ptserve: --env, --env-strength, --env-rotate and --background are a "
                        "job's: in queue mode give them to ptctl submit\n");
        return 2;
    }
    if (c->clients_path && (!c->token_path || !c->state_dir)) {
        fprintf(stderr, "ptserve: --clients-file needs --token-file (the admin and worker token) "
                        "and --state-dir (clients use the queue)\n");
        return 2;
    }
    if (c->state_dir && x->has_shutter) {
        fprintf(stderr, "ptserve: --shutter is for one-job mode; a queued job asks for it "
                        "with ptctl submit --shutter\n");
        return 2;
    }
    if (c->state_dir && (c->frames.step || c->fps > 0 || c->animation)) {
        fprintf(stderr, "ptserve: --frames, --fps and --animation are for one-job mode; a queued "
                        "job asks for them with ptctl submit --frames\n");
        return 2;
    }
    if (!c->frames.step && c->animation) {
        fprintf(stderr, "ptserve: --animation poses the frames of --frames A-B[:STEP]; "
                        "give --frames\n");
        return 2;
    }
    if (!c->frames.step && !x->has_shutter && c->fps > 0) {
        fprintf(stderr, "ptserve: --fps is the frame rate of --frames A-B[:STEP] and --shutter; "
                        "give --frames or --shutter\n");
        return 2;
    }
    if (c->state_dir && x->placed) {
        fprintf(stderr, "ptserve: --camera-from and --camera-at are a job's: in queue mode give "
                        "them to ptctl submit\n");
        return 2;
    }
    if (c->out_path && pt_image_format_of(c->out_path) == PT_IMAGE_FORMAT_NONE) {
        fprintf(stderr, "ptserve: -o %s: " PT_IMAGE_FORMATS "\n", c->out_path);
        return 2;
    }
    if (c->frames.step && !pt_frames_has_pattern(c->out_path)) {
        fprintf(stderr,
                "ptserve: -o %s: a frame range needs a '#' run in the output name for "
                "the frame number (e.g. -o shot.####.exr: frame 7 is shot.0007.exr)\n",
                c->out_path);
        return 2;
    }
    /* One frame rate serves both: the shutter's fractions of a frame become seconds
     * after the frame's time (SHUTTER, protocol/msg.h) by the same R that times the
     * frames. c->fps stays 0 for a still so the job keeps a still's parameters. */
    double rate = c->fps > 0 ? c->fps : PT_FRAMES_DEFAULT_FPS;
    c->job.shutter[0] = x->shutter[0] / rate;
    c->job.shutter[1] = x->shutter[1] / rate;
    if (c->frames.step && c->fps == 0)
        c->fps = PT_FRAMES_DEFAULT_FPS;
    if (c->state_dir && c->job.variant[0]) {
        fprintf(stderr, "ptserve: --variant is for one-job mode; a queued job asks for it "
                        "with ptctl submit --variant\n");
        return 2;
    }
    if (c->state_dir && (c->job.film_flags & (PROTO_FILM_BDPT | PROTO_FILM_BDPT_OFF))) {
        fprintf(stderr, "ptserve: --bdpt is for one-job mode; a queued job asks for it with "
                        "ptctl submit --bdpt\n");
        return 2;
    }
    if (c->state_dir && (c->job.film_flags & PROTO_FILM_TRANSPARENT)) {
        fprintf(stderr, "ptserve: --transparent is for one-job mode; a queued job asks for it "
                        "with ptctl submit --transparent\n");
        return 2;
    }
    if (c->state_dir &&
        (ro->given & (PT_ROPT(PT_ROPT_CLAMP_DIRECT) | PT_ROPT(PT_ROPT_CLAMP_INDIRECT)))) {
        fprintf(stderr, "ptserve: --clamp-direct and --clamp-indirect are for one-job mode; a "
                        "queued job asks for them with ptctl submit --clamp-direct\n");
        return 2;
    }
    if (c->state_dir && (ro->given & PT_ROPT(PT_ROPT_GUIDING))) {
        fprintf(stderr, "ptserve: --guiding is for one-job mode; a queued job asks for it "
                        "with ptctl submit --guiding\n");
        return 2;
    }
    if (c->guiding) {
        /* Guided passes are learned from whole passes of every tile: no
         * adaptive stops, one pose. auto leaves guiding off there. */
        const char *why = c->job.target_error > 0.0 || c->job.min_gain > 0.0
                              ? "--target-error or --min-gain"
                          : c->frames.step                        ? "--frames"
                          : c->job.shutter[1] > c->job.shutter[0] ? "--shutter"
                                                                  : NULL;
        if (why && c->guiding == PT_GUIDING_ON) {
            fprintf(stderr, "ptserve: --guiding on does not combine with %s yet\n", why);
            return 2;
        }
        if (why)
            c->guiding = PT_GUIDING_OFF;
    }
    if (c->state_dir && ro->denoise) {
        const char *opt = ro->denoise_progressive ? "--denoise-progressive" : "--denoise";
        fprintf(stderr,
                "ptserve: %s is for one-job mode; a queued job asks for it with ptctl submit %s\n",
                opt, opt);
        return 2;
    }
    if (!c->state_dir && c->denoise_share) {
        /* One job's image is written once its loop is over: no worker is
         * served then. */
        fprintf(stderr, "ptserve: --denoise-on-workers is for a queue (--state-dir): one job's "
                        "finished image is denoised after its workers are gone\n");
        return 2;
    }
    if (c->state_dir && ro->passes) {
        fprintf(stderr, "ptserve: --passes is for one-job mode; a queued job asks for them "
                        "with ptctl submit --passes\n");
        return 2;
    }
    if (x->has_chunk && x->has_task_time) {
        fprintf(stderr, "ptserve: --chunk gives fixed tasks and --task-time sizes them by "
                        "time; give one\n");
        return 2;
    }
    if (x->has_chunk)
        c->task_ms = 0;
    if (c->job.chunk != pt_chunk_whole_blocks(c->job.chunk)) {
        /* A task that ends inside a block changes the image's last bits. */
        fprintf(stderr,
                "ptserve: --chunk %u rounded up to %u: samples are summed in blocks of %u\n",
                c->job.chunk, pt_chunk_whole_blocks(c->job.chunk), PT_SAMPLE_BLOCK);
        c->job.chunk = pt_chunk_whole_blocks(c->job.chunk);
    }
    if (x->lease < 0.1) {
        fprintf(stderr, "ptserve: --x->lease-timeout must be at least 0.1 s\n");
        return 2;
    }
    if (c->job.min_spp == 0)
        c->job.min_spp = c->job.chunk > 1 ? c->job.chunk : 2;
    c->lease_ms = (uint32_t)(x->lease * 1000.0);
    c->handshake_ms = (uint32_t)(x->handshake * 1000.0);
    c->limits.frame_grace_ms = (uint32_t)(x->grace * 1000.0);
    c->local_stop_ms = (uint32_t)(x->local_stop * 1000.0);
    return 0;
}

int main(int argc, char **argv)
{
    srv_config c;
    parsed x;
    config_defaults(&c, &x);
    /* Its own options, then every render option of the shared table
     * (common/render/options.h), then the end. */
    enum { NOWN = sizeof own / sizeof own[0] };
    struct option opts[NOWN + PT_ROPT_COUNT + 1];
    pt_render_getopt_table(own, NOWN, PT_ROPT_ALL, opts);
    _Static_assert(PT_ROPT_MAX_NAME == PROTO_MAX_NAME, "a job's names are the options'");
    pt_render_opts ro;
    pt_render_opts_init(&ro);
    pt_error err = {0};
    int ch;
    while ((ch = getopt_long(argc, argv, "o:qh", opts, NULL)) != -1) {
        pt_status st;
        if (ch == 'h') {
            usage(stdout);
            return 0;
        }
        if (ch == 'V')
            return pt_version_print("ptserve");
        if (pt_render_opt_is(ch)) {
            st = pt_render_opt_set(&ro, ch, optarg, &err);
        } else if (ch == '?' || ch == ':') {
            usage(stderr);
            return 2;
        } else {
            st = own_option(ch, &c, &x, &err);
        }
        if (st != PT_OK) {
            fprintf(stderr, "ptserve: %s\n", err.msg);
            return 2;
        }
    }
    if (pt_render_opts_finish(&ro, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        return 2;
    }
    job_from_options(&c, &ro, &x);
    int rc = check_options(&c, &ro, &x, argc - optind);
    if (rc)
        return rc;
    c.scene_path = c.state_dir ? NULL : argv[optind];
    return srv_serve(&c);
}
