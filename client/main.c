/*
 * ptctl_main.c - ptctl, the command-line client of the ptserve render queue.
 *
 *   ptctl [--server HOST:PORT] [--token-file PATH] [--timeout SEC] COMMAND [ARGS]
 *
 * Commands: submit, list, status, watch, cancel, fetch (usage() and each
 * command's --help say what they do). One connection per run; the wire work
 * is in client/ctl.c. Exit status, relied on by scripts: 0 success, 1 error
 * (connection, refusal, I/O; the reason on stderr), 2 bad usage, 3 no such
 * job, 4 a watched job ended cancelled or failed. Only results go to stdout
 * (a job id, a state, a table or JSON); progress and errors go to stderr.
 */
#include <errno.h>
#include <float.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "client/ctl.h"
#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/frames.h"
#include "common/base/fsutil.h"
#include "common/base/opt.h"
#include "common/base/text.h"
#include "common/base/version.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/view.h"
#include "common/render/options.h"
#include "common/render/tile.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "protocol/auth.h"

enum { EXIT_ERROR = 1, EXIT_USAGE = 2, EXIT_NO_JOB = 3, EXIT_JOB_FAILED = 4 };

/* Big transfers show progress on a terminal. */
#define PROGRESS_MIN_BYTES ((uint64_t)4 << 20)
/* Without a terminal, watch prints a line at most this often. */
#define WATCH_LOG_INTERVAL_S 5.0

static const char GLOBAL_HELP[] =
    "options (before or after the command):\n"
    "  --server HOST:PORT  the coordinator ([V6]:PORT for IPv6; default $PTFARM_SERVER,\n"
    "                      else " CTL_DEFAULT_SERVER ")\n"
    "  --token-file PATH   your token: the farm's shared (admin) token, or your own\n"
    "                      from the coordinator's --clients-file (default\n"
    "                      $PTFARM_TOKEN_FILE, else none: for a coordinator that\n"
    "                      requires no token); at least 16 bytes, mode 0600, made with\n"
    "                      " PROTO_TOKEN_HOWTO "\n"
    "  --timeout SEC       for connecting and for each reply (default 30)\n"
    "  -h, --help          help\n";

static const char EXIT_HELP[] =
    "exit status:\n"
    "  0  success\n"
    "  1  error: connection, refused by the server, I/O (the reason is on stderr)\n"
    "  2  bad usage\n"
    "  3  no such job\n"
    "  4  watch (or submit --watch) saw the job end cancelled or failed\n";

static void usage(FILE *f)
{
    fprintf(f,
            "usage: ptctl [--server HOST:PORT] [--token-file PATH] [--timeout SEC] COMMAND [ARGS]\n"
            "\n"
            "Client of the ptserve render queue: submits scenes, follows and cancels\n"
            "jobs, fetches their images.\n"
            "\n"
            "examples:\n"
            "  export PTFARM_SERVER=farm:7878 PTFARM_TOKEN_FILE=farm.token\n"
            "  id=$(ptctl submit scene.gltf --spp 1024 --res 1920x1080)\n"
            "  ptctl watch $id && ptctl fetch $id -o final.exr\n"
            "  ptctl list\n"
            "\n"
            "commands:\n"
            "  submit SCENE [options]  queue a render of SCENE; prints the job id\n"
            "  list [--json]           the jobs the server knows\n"
            "  status JOB [--json]     everything about one job\n"
            "  watch JOB               follow a job's progress until it ends\n"
            "  cancel JOB              cancel a job; prints the state it ends in\n"
            "  fetch JOB [--frame F] -o OUT.exr\n"
            "                          download a job's image (or one frame's)\n"
            "'ptctl COMMAND --help' describes each one; 'ptctl --version' prints the\n"
            "version and renderer build id.\n"
            "\n"
            "%s\n%s",
            GLOBAL_HELP, EXIT_HELP);
}

/* ---- options ---- */

typedef struct globals {
    const char *server;
    const char *token_file;
    int timeout_ms;
} globals;

enum {
    O_SERVER = 1000,
    O_FRAMES,
    O_FPS,
    O_ANIMATION,
    O_FRAME,
    O_TOKEN,
    O_TIMEOUT,
    O_JSON,
    O_SPP,
    O_RES,
    O_SEED,
    O_PRIORITY,
    O_NAME,
    O_DEPTH,
    O_TARGET,
    O_MINGAIN,
    O_MINSPP,
    O_WATCH,
    O_CAMERA,
    O_VARIANT,
    O_ENV,
    O_ENVSTRENGTH,
    O_ENVROTATE,
    O_BACKGROUND,
    O_TRANSPARENT,
    O_SHUTTER,
    O_LOOK,
    O_EXPOSURE,
    O_VIEW
};

static int bad_usage(const char *cmd, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static int bad_usage(const char *cmd, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("ptctl: ", stderr);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fprintf(stderr, "\ntry 'ptctl %s%s--help'\n", cmd ? cmd : "", cmd ? " " : "");
    return EXIT_USAGE;
}

/* After getopt_long returned '?': optopt is the short option at fault, or 0
 * for a long one, which is then the argument just passed. */
static int unknown_option(const char *cmd, char **argv)
{
    if (optopt)
        return bad_usage(cmd, "unknown option '-%c'", optopt);
    return bad_usage(cmd, "unknown option '%s'", argv[optind - 1]);
}

/* An option's value through common/base/opt.h: 0, or the bad-usage exit status. */
static int bad_value(const char *cmd, pt_status st, const pt_error *err)
{
    return st == PT_OK ? 0 : bad_usage(cmd, "%s", err->msg);
}

static int parse_job(const char *cmd, const char *s, uint64_t *out)
{
    if (pt_opt_u64("job", s, UINT64_MAX, out, NULL) != PT_OK)
        return bad_usage(cmd, "'%s' is not a job id (a whole number)", s);
    return 0;
}

static int parse_global(const char *cmd, int c, const char *arg, globals *g)
{
    switch (c) {
    case O_SERVER:
        g->server = arg;
        return 0;
    case O_TOKEN:
        g->token_file = arg;
        return 0;
    case O_TIMEOUT: {
        pt_error err = {0};
        double v = 0;
        int rc = bad_value(cmd, pt_opt_seconds("--timeout", arg, 0.001, 86400.0, &v, &err), &err);
        if (!rc)
            g->timeout_ms = (int)(v * 1000.0 + 0.5);
        return rc;
    }
    }
    return bad_usage(cmd, "unknown option");
}

/* ---- connecting, and what failures exit with ---- */

static int fail(const ctl_conn *c, const pt_error *e)
{
    uint16_t code = ctl_server_code(c);
    if (code) {
        char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
        fprintf(stderr, "ptctl: server: %s\n",
                pt_text_shown(ctl_server_text(c), text, sizeof text));
        return code == PROTO_E_NOT_FOUND ? EXIT_NO_JOB : EXIT_ERROR;
    }
    fprintf(stderr, "ptctl: %s\n", e->msg[0] ? e->msg : pt_status_str(e->code));
    return EXIT_ERROR;
}

/* fail() for a request on c, which is then closed. */
static int fail_close(ctl_conn *c, const pt_error *e)
{
    int rc = fail(c, e);
    ctl_close(c);
    return rc;
}

/* Connects and authenticates; 0 with *out set, or the exit status. */
static int connect_server(const globals *g, ctl_conn **out)
{
    static uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len = 0;
    pt_error err = {0};
    if (g->token_file &&
        proto_token_load(g->token_file, token, sizeof token, &token_len, &err) != PT_OK) {
        fprintf(stderr, "ptctl: %s\n", err.msg);
        return EXIT_ERROR;
    }
    char name[PROTO_MAX_NAME + 1];
    ctl_default_name(name);
    ctl_opts o = {g->server, token, token_len, g->timeout_ms, name};
    ctl_conn *c = NULL;
    pt_status st = ctl_connect(&o, &c, &err);
    if (st == PT_ERR_ARG)
        return bad_usage(NULL, "--server: %s", err.msg);
    if (st != PT_OK)
        return fail_close(c, &err);
    *out = c;
    return 0;
}

/* ---- progress ---- */

typedef struct transfer {
    const char *verb;
    int shown;
} transfer;

static void show_transfer(uint64_t done, uint64_t total, void *arg)
{
    transfer *t = arg;
    fprintf(stderr, "\rptctl: %s %.1f of %.1f MiB (%3.0f%%)", t->verb, done / 1048576.0,
            total / 1048576.0, total ? 100.0 * (double)done / (double)total : 100.0);
    t->shown = 1;
}

/* Follows job id on c until a JOB_INFO with a terminal state; the exit status. */
static int watch_job(ctl_conn *c, uint64_t id)
{
    pt_error err = {0};
    if (ctl_watch_begin(c, id, &err) != PT_OK)
        return fail(c, &err);
    int tty = isatty(STDERR_FILENO);
    double last = -1e9;
    size_t prev = 0;
    static proto_job_info j;
    for (;;) {
        if (ctl_watch_next(c, &j, &err) != PT_OK) {
            if (tty && prev)
                fputc('\n', stderr);
            return fail(c, &err);
        }
        if (j.job_id != id) {
            if (tty && prev)
                fputc('\n', stderr);
            fprintf(stderr, "ptctl: the server sent job %llu while job %llu was watched\n",
                    (unsigned long long)j.job_id, (unsigned long long)id);
            return EXIT_ERROR;
        }
        char line[256];
        ctl_progress_line(&j, line, sizeof line);
        int ended = ctl_job_ended(j.state);
        if (tty) {
            size_t n = strlen(line);
            /* Blanks over the rest of a longer previous line. */
            fprintf(stderr, "\r%s%*s", line, prev > n ? (int)(prev - n) : 0, "");
            prev = n;
            if (ended)
                fputc('\n', stderr);
        } else if (ended || pt_now_s() - last >= WATCH_LOG_INTERVAL_S) {
            fprintf(stderr, "%s\n", line);
            last = pt_now_s();
        }
        fflush(stderr);
        if (!ended)
            continue;
        if (j.state == PROTO_JOB_DONE)
            return 0;
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        ctl_printable(j.message, msg, sizeof msg);
        fprintf(stderr, "ptctl: job %llu %s%s%s\n", (unsigned long long)id,
                proto_job_state_name(j.state), msg[0] ? ": " : "", msg);
        return EXIT_JOB_FAILED;
    }
}

/* ---- commands ---- */

typedef int (*command_fn)(int argc, char **argv, globals *g);

static const char SUBMIT_HELP[] =
    "usage: ptctl submit SCENE [options]\n"
    "\n"
    "Queues a render of SCENE (.gltf or .glb): the scene and every file it references\n"
    "are packed into one bundle and uploaded. Prints the new job's id alone on\n"
    "stdout. Upload progress goes to stderr when it is a terminal; what the\n"
    "coordinator's check of the scene says of the job (a portal wound the wrong\n"
    "way), which ptctl status shows as its message, goes to stderr always.\n"
    "\n"
    "options:\n"
    "  --spp N            samples per pixel (default 64)\n"
    "  --res WxH          image size (default: 512 wide, height from the camera)\n"
    "  --seed S           random seed (default 0); same seed, same image\n"
    "  --camera NAME      the camera to render: its name, its node's name or its index\n"
    "                     (default: the scene's first; none: a view framing the scene)\n"
    "  --camera-from X,Y,Z  a camera of your own at X,Y,Z (world coordinates, +Y up)\n"
    "  --camera-at X,Y,Z    looking at this point; 40 degrees high unless --fov DEG\n"
    "  --fov DEG            (0 to 180) or --ortho WIDTH (orthographic, WIDTH wide);\n"
    "  --ortho WIDTH        the same image as ptworker's; not with --camera\n"
    "  --priority P       higher runs first, ties in submission order (default 0;\n"
    "                     may be negative)\n"
    "  --name NAME        the job's name (default: the scene's file name without\n"
    "                     extension; at most 64 bytes)\n"
    "  --max-depth D      maximum bounces (default: the server's)\n"
    "  --target-error E   adaptive sampling: a tile stops once the RMS relative error\n"
    "                     of its pixel means is <= E (e.g. 0.01); off by default\n"
    "  --min-gain G       adaptive sampling for the lowest mean error: a tile stops\n"
    "                     once one more sample per pixel would lower the mean squared\n"
    "                     error of its pixels (R, G, B, absolute) by <= G; a tile\n"
    "                     then gets samples in proportion to its noise (e.g. 1e-6;\n"
    "                     smaller is longer); judged from the second chunk on, a\n"
    "                     tile of black samples only from the first; off by\n"
    "                     default; not with --target-error\n"
    "  --min-spp N        adaptive sampling: samples before a tile may stop\n"
    "                     (default: one chunk)\n"
    "  --env PATH         environment light: an equirectangular map (Radiance .hdr\n"
    "                     or OpenEXR, row 0 straight up, the middle column -Z); rays\n"
    "                     leaving the scene see it. Uploaded inside the scene's\n"
    "                     bundle; the server decodes it before queueing the job and\n"
    "                     refuses a file that is not a map or holds NaN, Inf or\n"
    "                     absurd values\n"
    "  --env-strength S   the map's factor (default 1)\n"
    "  --env-rotate DEG   turn the map about +Y (default 0)\n"
    "  --background R,G,B a uniform environment of this radiance instead\n"
    "                     (a scene with no emitter, no KHR_lights_punctual light and\n"
    "                     neither of these is refused: it would render black)\n"
    "  --variant NAME     the KHR_materials_variants variant: mapped primitives take\n"
    "                     its material (an unknown name is refused at submit)\n"
    "  --transparent      camera rays that leave the scene add nothing, and the EXR\n"
    "                     gets an A channel (coverage; RGB premultiplied by it)\n"
    "  --passes LIST      render passes written as EXR layers: a comma-separated\n"
    "                     list of albedo, normal, depth, emission, halves,\n"
    "                     cryptomatte, or all\n"
    "                     (see ptworker --help); merged exactly like the beauty\n"
    "  --denoise          the coordinator denoises the finished image (NFOR) into\n"
    "                     the layer denoised.R/G/B; the passes it needs are added\n"
    "  --denoise-progressive  --denoise, and the coordinator's progressive saves\n"
    "                     denoised too (the newest save while one is denoised)\n"
    "  --frames A-B[:STEP] one job of the frames A, A+STEP, ... B of the scene's\n"
    "                     animation (at most 100000, numbers 0 to 999999), each\n"
    "                     written as ID-NAME.####.exr with its zero-padded number;\n"
    "                     early frames finish first ('ptctl fetch JOB --frame F')\n"
    "  --animation NAME|INDEX|all  the animation played (default: the first; all:\n"
    "                     every one at once); an\n"
    "                     unknown one (or a scene without animations) is refused\n"
    "  --shutter O,C      motion blur: the shutter opens and closes at these\n"
    "                     fractions of a frame (0,0.5: 180 degrees; default off);\n"
    "                     what the scene's animation moves then blurs\n"
    "  --fps R            frames per second of --frames and --shutter: frame F is\n"
    "                     at F / R seconds (default 24)\n"
    "  --guiding on|off|auto  path guiding learned by the farm (default off; as\n"
    "                     ptworker --guiding, whose image it gives bit for bit)\n"
    "  --bdpt[=auto|on|off]  bidirectional path tracing, as ptworker --bdpt (the\n"
    "                     same bits); a scene on cannot render is refused at\n"
    "                     submission; auto (the default) is decided there, once\n"
    "  --clamp-direct X   clamp each sample's light that reaches the camera or the\n"
    "                     first surface it sees to R+G+B <= X, as Cycles' Clamp\n"
    "                     Direct (biased; default 0, off)\n"
    "  --clamp-indirect X the same for light after more bounces (Cycles' Clamp\n"
    "                     Indirect); the image is ptworker --clamp-* 's, bit for bit\n"
    "  --watch            then follow the job as 'ptctl watch' does (exit status 4\n"
    "                     when it ends cancelled or failed)\n";

/* The default job name: the scene's file name without its extension, cut to
 * the cap on a UTF-8 character boundary, made plain for the server (no
 * leading '.', no "..", no '\\' or control characters). */
static void default_job_name(const char *scene, char out[PROTO_MAX_NAME + 1])
{
    const char *base = strrchr(scene, '/');
    base = base ? base + 1 : scene;
    size_t n = strlen(base);
    const char *dot = strrchr(base, '.');
    if (dot && dot != base)
        n = (size_t)(dot - base);
    if (n > PROTO_MAX_NAME) {
        n = PROTO_MAX_NAME;
        while (n > 0 && ((unsigned char)base[n] & 0xC0) == 0x80)
            n--;
    }
    while (n > 0 && *base == '.') {
        base++;
        n--;
    }
    for (size_t i = 0; i < n; i++) {
        unsigned char ch = (unsigned char)base[i];
        int dots = ch == '.' && i + 1 < n && base[i + 1] == '.';
        out[i] = ch < 0x20 || ch == 0x7F || ch == '\\' || dots ? '_' : (char)ch;
    }
    out[n] = '\0';
    if (n == 0)
        snprintf(out, PROTO_MAX_NAME + 1, "scene");
}

static int cmd_submit(int argc, char **argv, globals *g)
{
    static const struct option own[] = {/* the global options, accepted after the command too */
                                        {"server", required_argument, NULL, O_SERVER},
                                        {"token-file", required_argument, NULL, O_TOKEN},
                                        {"timeout", required_argument, NULL, O_TIMEOUT},
                                        {"help", no_argument, NULL, 'h'},
                                        {"priority", required_argument, NULL, O_PRIORITY},
                                        {"name", required_argument, NULL, O_NAME},
                                        {"watch", no_argument, NULL, O_WATCH},
                                        {"frames", required_argument, NULL, O_FRAMES}};
    /* The render options of the shared table (common/render/options.h) but
     * tiles, chunks and the preview's, which are the coordinator's. */
    const uint32_t mine = PT_ROPT_ALL & ~(PT_ROPT(PT_ROPT_TILE) | PT_ROPT(PT_ROPT_CHUNK) |
                                          PT_ROPT(PT_ROPT_EXPOSURE) | PT_ROPT(PT_ROPT_VIEW));
    enum { NOWN = sizeof own / sizeof own[0] };
    struct option opts[NOWN + PT_ROPT_COUNT + 1];
    pt_render_getopt_table(own, NOWN, mine, opts);
    _Static_assert(PT_ROPT_MAX_NAME == PROTO_MAX_NAME, "a job's names are the options'");
    proto_submit m;
    memset(&m, 0, sizeof m);
    pt_render_opts ro;
    pt_render_opts_init(&ro);
    const char *name = NULL;
    int watch = 0;
    int c;
    optind = 0;
    while ((c = getopt_long(argc, argv, ":h", opts, NULL)) != -1) {
        int rc = 0;
        pt_status st = PT_OK;
        pt_error err = {0};
        switch (c) {
        case 'h':
            fputs(SUBMIT_HELP, stdout);
            printf("\n%s\n%s", GLOBAL_HELP, EXIT_HELP);
            return 0;
        case O_PRIORITY:
            st = pt_opt_i32("--priority", optarg, INT32_MIN, INT32_MAX, &m.priority, &err);
            break;
        case O_NAME:
            name = optarg;
            if (strlen(name) > PROTO_MAX_NAME)
                rc = bad_usage("submit", "--name: longer than %u bytes", PROTO_MAX_NAME);
            break;
        case O_FRAMES: {
            pt_frames fr;
            if ((st = pt_frames_parse("--frames", optarg, &fr, &err)) == PT_OK) {
                m.frame_first = fr.first;
                m.frame_last = fr.last;
                m.frame_step = fr.step;
            }
            break;
        }
        case O_WATCH:
            watch = 1;
            break;
        case ':':
            return bad_usage("submit", "%s needs a value", argv[optind - 1]);
        case '?':
            return unknown_option("submit", argv);
        default:
            if (pt_render_opt_is(c))
                st = pt_render_opt_set(&ro, c, optarg, &err);
            else
                rc = parse_global("submit", c, optarg, g);
        }
        if (!rc)
            rc = bad_value("submit", st, &err);
        if (rc)
            return rc;
    }
    {
        pt_error err = {0};
        if (pt_render_opts_finish(&ro, &err) != PT_OK)
            return bad_usage("submit", "%s", err.msg);
    }
    if ((ro.given & PT_ROPT(PT_ROPT_MAX_DEPTH)) && ro.max_depth == 0)
        return bad_usage("submit", "--max-depth 0: a job's cap is 1 or more (0 in a job asks the "
                                   "coordinator's default)");
    /* The shared options into the job. */
    m.spp = ro.spp;
    m.width = ro.width;
    m.height = ro.height;
    m.seed = ro.seed;
    m.max_depth = (ro.given & PT_ROPT(PT_ROPT_MAX_DEPTH)) ? (uint16_t)ro.max_depth : 0;
    m.target_error = ro.target_error;
    m.min_gain = ro.min_gain;
    m.min_spp = ro.min_spp;
    if (ro.given & PT_ROPT(PT_ROPT_TRANSPARENT))
        m.film_flags |= PROTO_FILM_TRANSPARENT;
    m.film_flags |= proto_film_of_passes(ro.passes);
    if (ro.denoise)
        m.film_flags |= PROTO_FILM_DENOISE;
    if (ro.denoise_progressive)
        m.film_flags |= PROTO_FILM_DENOISE_PROGRESSIVE;
    m.film_flags |= proto_film_of_bdpt(ro.bdpt);
    m.clamp[0] = ro.clamp_direct;
    m.clamp[1] = ro.clamp_indirect;
    m.guiding = (uint8_t)ro.guiding;
    if (m.guiding == PT_GUIDING_ON && (m.target_error > 0.0 || m.min_gain > 0.0 || m.frame_step ||
                                       (ro.given & PT_ROPT(PT_ROPT_SHUTTER))))
        return bad_usage("submit", "--guiding on does not combine with --target-error, "
                                   "--min-gain, --frames or --shutter yet");
    if (ro.camera)
        snprintf(m.camera, sizeof m.camera, "%s", ro.camera);
    if (ro.variant)
        snprintf(m.variant, sizeof m.variant, "%s", ro.variant);
    if (ro.animation)
        snprintf(m.animation, sizeof m.animation, "%s", ro.animation);
    proto_env_none(&m.env);
    const char *env_path = ro.env_path;
    m.env.strength = (float)ro.env_strength;
    m.env.rotate_deg = (float)ro.env_rotate;
    if (ro.given & PT_ROPT(PT_ROPT_BACKGROUND)) {
        m.env.background = 1;
        for (int k = 0; k < 3; k++)
            m.env.rgb[k] = (float)ro.background[k];
    }
    int has_shutter = (ro.given & PT_ROPT(PT_ROPT_SHUTTER)) != 0;
    double shutter[2] = {ro.shutter[0], ro.shutter[1]};
    m.fps = (ro.given & PT_ROPT(PT_ROPT_FPS)) ? ro.fps : 0.0;
    if (optind >= argc)
        return bad_usage("submit", "which scene?");
    if (argc - optind > 1)
        return bad_usage("submit", "one scene at a time ('%s' is extra)", argv[optind + 1]);
    if (!m.frame_step && m.animation[0])
        return bad_usage("submit", "--animation poses the frames of --frames A-B[:STEP]; give "
                                   "--frames");
    if (!m.frame_step && !has_shutter && m.fps > 0.0)
        return bad_usage("submit", "--fps is the frame rate of --frames A-B[:STEP] and --shutter; "
                                   "give --frames or --shutter");
    /* One frame rate serves both: SUBMIT carries the shutter in seconds after the
     * frame's time (SHUTTER, protocol/msg.h), and a still's SUBMIT has fps 0. */
    double rate = m.fps > 0.0 ? m.fps : PT_FRAMES_DEFAULT_FPS;
    m.shutter[0] = shutter[0] / rate;
    m.shutter[1] = shutter[1] / rate;
    m.fps = m.frame_step ? rate : 0.0;
    if (env_path)
        snprintf(m.env.name, sizeof m.env.name, "%s", PT_BUNDLE_ENV_NAME);
    const char *scene = argv[optind];
    if (name)
        snprintf(m.name, sizeof m.name, "%s", name);
    else
        default_job_name(scene, m.name);

    pt_error err = {0};
    pt_bundle *b = NULL;
    if (pt_bundle_pack_env(scene, env_path, &b, &err) != PT_OK) {
        fprintf(stderr, "ptctl: %s\n", err.msg);
        return EXIT_ERROR;
    }
    m.bundle_size = b->size;
    if (ctl_hex_to_hash(b->hash, m.bundle_hash) != 0) {
        fprintf(stderr, "ptctl: %s: bad bundle hash\n", scene);
        pt_bundle_free(b);
        return EXIT_ERROR;
    }
    ctl_conn *conn = NULL;
    int rc = connect_server(g, &conn);
    if (rc) {
        pt_bundle_free(b);
        return rc;
    }
    transfer t = {"uploading", 0};
    int show = isatty(STDERR_FILENO) && b->size >= PROGRESS_MIN_BYTES;
    uint64_t id = 0;
    pt_status st = ctl_submit(conn, &m, b, show ? show_transfer : NULL, &t, &id, &err);
    if (t.shown)
        fputc('\n', stderr);
    pt_bundle_free(b);
    if (st != PT_OK)
        return fail_close(conn, &err);
    printf("%llu\n", (unsigned long long)id);
    fflush(stdout);
    /* What the coordinator's check of the scene said of the job (a portal
     * wound the wrong way): its message, on stderr, before any work. */
    static proto_job_info j;
    if (ctl_status(conn, id, &j, &err) == PT_OK && j.message[0]) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        ctl_printable(j.message, msg, sizeof msg);
        fprintf(stderr, "ptctl: job %llu: %s\n", (unsigned long long)id, msg);
    }
    if (watch)
        rc = watch_job(conn, id);
    ctl_close(conn);
    return rc;
}

/* The shared parser of the commands that take JOB and maybe --json / -o. */
typedef struct job_args {
    uint64_t id;
    int json;
    const char *output;
    int has_frame; /* --frame F */
    uint32_t frame;
    pt_view view; /* --exposure, --view: a .png output's */
    int has_view;
} job_args;

enum { TAKES_JOB = 1, TAKES_JSON = 2, TAKES_OUTPUT = 4, TAKES_FRAME = 8 };

/* Parses the command's arguments, then connects: 0 with *conn set, or the
 * exit status with *conn NULL (0 too after --help). */
static int open_job_command(const char *cmd, const char *help, int flags, int argc, char **argv,
                            globals *g, job_args *a, ctl_conn **conn)
{
    static const struct option opts[] = {/* the global options, accepted after the command too */
                                         {"server", required_argument, NULL, O_SERVER},
                                         {"token-file", required_argument, NULL, O_TOKEN},
                                         {"timeout", required_argument, NULL, O_TIMEOUT},
                                         {"help", no_argument, NULL, 'h'},
                                         {"json", no_argument, NULL, O_JSON},
                                         {"output", required_argument, NULL, 'o'},
                                         {"frame", required_argument, NULL, O_FRAME},
                                         {"exposure", required_argument, NULL, O_EXPOSURE},
                                         {"view", required_argument, NULL, O_VIEW},
                                         {NULL, 0, NULL, 0}};
    int c;
    *conn = NULL;
    optind = 0;
    while ((c = getopt_long(argc, argv, ":ho:", opts, NULL)) != -1) {
        int rc = 0;
        switch (c) {
        case 'h':
            fputs(help, stdout);
            printf("\n%s\n%s", GLOBAL_HELP, EXIT_HELP);
            return 0;
        case O_JSON:
            if (!(flags & TAKES_JSON))
                return bad_usage(cmd, "unknown option '--json'");
            a->json = 1;
            break;
        case 'o':
            if (!(flags & TAKES_OUTPUT))
                return bad_usage(cmd, "unknown option '%s'", argv[optind - 1]);
            a->output = optarg;
            break;
        case O_FRAME: {
            pt_error err = {0};
            if (!(flags & TAKES_FRAME))
                return bad_usage(cmd, "unknown option '--frame'");
            pt_status st = pt_opt_u32("--frame", optarg, 0, PT_FRAMES_MAX_NUMBER, &a->frame, &err);
            if ((rc = bad_value(cmd, st, &err)) != 0)
                return rc;
            a->has_frame = 1;
            break;
        }
        case O_EXPOSURE:
        case O_VIEW: {
            /* The PNG's, as ptworker's and ptserve's previews. */
            pt_error err = {0};
            double ev = 0.0;
            if (!(flags & TAKES_OUTPUT))
                return bad_usage(cmd, "unknown option '%s'", c == O_VIEW ? "--view" : "--exposure");
            pt_status st = c == O_VIEW ? pt_view_parse("--view", optarg, &a->view.kind, &err)
                                       : pt_opt_double("--exposure", optarg, -PT_VIEW_MAX_EV,
                                                       PT_VIEW_MAX_EV, &ev, &err);
            if ((rc = bad_value(cmd, st, &err)) != 0)
                return rc;
            if (c == O_EXPOSURE)
                a->view.exposure = (float)ev;
            a->has_view = 1;
            break;
        }
        case ':':
            return bad_usage(cmd, "%s needs a value", argv[optind - 1]);
        case '?':
            return unknown_option(cmd, argv);
        default:
            rc = parse_global(cmd, c, optarg, g);
        }
        if (rc)
            return rc;
    }
    int want = (flags & TAKES_JOB) ? 1 : 0;
    if (argc - optind < want)
        return bad_usage(cmd, "which job?");
    if (argc - optind > want)
        return bad_usage(cmd, "unexpected argument '%s'", argv[optind + want]);
    if (want && parse_job(cmd, argv[optind], &a->id))
        return EXIT_USAGE;
    if ((flags & TAKES_OUTPUT) && (!a->output || !*a->output))
        return bad_usage(cmd, "-o OUT.exr is required");
    if (flags & TAKES_OUTPUT) {
        /* The output's format follows its name, and its folder is checked
         * before anything is downloaded. */
        pt_image_format f = pt_image_format_of(a->output);
        if (f == PT_IMAGE_FORMAT_NONE)
            return bad_usage(cmd, "-o %s: " PT_IMAGE_FORMATS, a->output);
        if (f == PT_IMAGE_FORMAT_EXR && a->has_view)
            return bad_usage(cmd, "--exposure and --view make a PNG: give -o NAME.png (the EXR "
                                  "is linear)");
        pt_temp probe;
        pt_error err = {0};
        if (pt_temp_open(a->output, 0644, &probe, &err) != PT_OK) {
            fprintf(stderr, "ptctl: -o %s: cannot be written: %s\n", a->output, err.msg);
            return EXIT_ERROR;
        }
        pt_temp_abort(&probe);
    }
    return connect_server(g, conn);
}

static const char LIST_HELP[] =
    "usage: ptctl list [--json]\n"
    "\n"
    "The jobs the server knows, queued, running and ended: id, state, priority,\n"
    "name, owner, progress (samples per pixel done of those asked, percent) and\n"
    "position in the queue.\n"
    "\n"
    "options:\n"
    "  --json             a JSON array of job objects instead of a table (the\n"
    "                     fields of 'ptctl status --json')\n";

static int cmd_list(int argc, char **argv, globals *g)
{
    job_args a = {0};
    ctl_conn *c;
    int rc = open_job_command("list", LIST_HELP, TAKES_JSON, argc, argv, g, &a, &c);
    if (!c)
        return rc;
    pt_error err = {0};
    proto_job_list l;
    if (ctl_list(c, &l, &err) != PT_OK)
        return fail_close(c, &err);
    ctl_close(c);
    if (a.json) {
        fputc('[', stdout);
        for (uint32_t i = 0; i < l.count; i++) {
            fputs(i ? ",\n " : "", stdout);
            ctl_json_job(stdout, &l.jobs[i]);
        }
        fputs("]\n", stdout);
    } else {
        /* Name and owner columns as wide as their longest entry, within reason. */
        int wn = 4, wo = 5;
        for (uint32_t i = 0; i < l.count; i++) {
            int n = (int)strlen(l.jobs[i].name), o = (int)strlen(l.jobs[i].owner);
            wn = n > wn ? n : wn;
            wo = o > wo ? o : wo;
        }
        wn = wn > 32 ? 32 : wn;
        wo = wo > 32 ? 32 : wo;
        printf("%-8s %-9s %5s  %-*s  %-*s  %-21s %s\n", "ID", "STATE", "PRI", wn, "NAME", wo,
               "OWNER", "PROGRESS", "QUEUE");
        for (uint32_t i = 0; i < l.count; i++) {
            const proto_job_info *j = &l.jobs[i];
            char name[PROTO_MAX_NAME + 1], owner[PROTO_MAX_NAME + 1], prog[48], queue[16];
            ctl_printable(j->name, name, sizeof name);
            ctl_printable(j->owner, owner, sizeof owner);
            uint64_t px = (uint64_t)j->width * j->height;
            if (j->frame_step) /* a frame range: frames done of its frames */
                snprintf(prog, sizeof prog, "%lu/%lu frames %5.1f%%", (unsigned long)j->frames_done,
                         (unsigned long)((j->frame_last - j->frame_first) / j->frame_step + 1),
                         100.0 * ctl_job_fraction(j));
            else
                snprintf(prog, sizeof prog, "%llu/%lu spp %5.1f%%",
                         (unsigned long long)(px ? j->samples_done / px : 0), (unsigned long)j->spp,
                         100.0 * ctl_job_fraction(j));
            if (j->queue_pos)
                snprintf(queue, sizeof queue, "%lu", (unsigned long)j->queue_pos);
            else
                snprintf(queue, sizeof queue, "-");
            printf("%-8llu %-9s %5ld  %-*.*s  %-*.*s  %-21s %s\n", (unsigned long long)j->job_id,
                   proto_job_state_name(j->state), (long)j->priority, wn, wn, name, wo, wo, owner,
                   prog, queue);
        }
    }
    pt_free(l.jobs);
    if (fflush(stdout) != 0) {
        fprintf(stderr, "ptctl: cannot write the list: %s\n", strerror(errno));
        return EXIT_ERROR;
    }
    return 0;
}

static void print_status(const proto_job_info *j)
{
    char s[PROTO_MAX_ERROR_TEXT + 1], d[32];
    printf("job        %llu\n", (unsigned long long)j->job_id);
    ctl_printable(j->name, s, sizeof s);
    printf("name       %s\n", s);
    printf("state      %s\n", proto_job_state_name(j->state));
    if (j->queue_pos)
        printf("queue      position %lu\n", (unsigned long)j->queue_pos);
    printf("priority   %ld\n", (long)j->priority);
    ctl_printable(j->owner, s, sizeof s);
    printf("owner      %s\n", s);
    ctl_printable(j->scene, s, sizeof s);
    printf("scene      %s\n", s);
    ctl_printable(j->output, s, sizeof s);
    printf("output     %s\n", s);
    printf("size       %lux%lu\n", (unsigned long)j->width, (unsigned long)j->height);
    uint64_t px = (uint64_t)j->width * j->height;
    printf("spp        %.1f of %lu\n", px ? (double)j->samples_done / (double)px : 0.0,
           (unsigned long)j->spp);
    printf("samples    %llu of %llu (%.1f%%)\n", (unsigned long long)j->samples_done,
           (unsigned long long)j->samples_total, 100.0 * ctl_job_fraction(j));
    printf("passes     %lu of %lu\n", (unsigned long)j->passes_done, (unsigned long)j->passes);
    printf("tiles      %lu (%lu stopped by adaptive sampling)\n", (unsigned long)j->tiles,
           (unsigned long)j->tiles_stopped);
    printf("workers    %lu\n", (unsigned long)j->workers);
    printf("integrator %s\n", j->bdpt ? "bidirectional (--bdpt)" : "path tracing");
    if (j->guided && j->state != PROTO_JOB_RUNNING)
        printf("guiding    on\n");
    else if (j->guided && j->guide_pass > 0)
        printf("guiding    pass %lu, its distribution learned from %lu spp\n",
               (unsigned long)j->guide_pass, (unsigned long)j->guide_spp);
    else if (j->guided)
        printf("guiding    pass 0, learning (a uniform distribution)\n");
    if (j->capped > 0)
        printf("depth cap  %llu paths reached it; raise --max-depth if this matters\n",
               (unsigned long long)j->capped);
    if (j->clamped > 0)
        printf("clamped    %llu contributions scaled down by --clamp-direct/--clamp-indirect "
               "(biased)\n",
               (unsigned long long)j->clamped);
    if (j->rejected > 0)
        printf("rejected   %llu samples (%.2f%% of those merged): NaN or Inf, or results that "
               "held no sample\n",
               (unsigned long long)j->rejected,
               100.0 * (double)j->rejected / (double)(j->samples_done + j->rejected));
    ctl_format_duration(j->seconds, d, sizeof d);
    printf("time       %s\n", d);
    if (j->rate > 0.0 && isfinite(j->rate))
        printf("rate       %.0f samples/s\n", j->rate);
    else
        printf("rate       -\n");
    if (j->error >= 0.0 && isfinite(j->error))
        printf("error      %.3g%% (estimated relative)\n", 100.0 * j->error);
    else
        printf("error      unknown\n");
    time_t t = (time_t)j->submitted;
    struct tm tm;
    char when[64] = "-";
    if (j->submitted <= (uint64_t)INT64_MAX && localtime_r(&t, &tm))
        strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S %z", &tm);
    printf("submitted  %s\n", when);
    if (j->message[0]) {
        ctl_printable(j->message, s, sizeof s);
        printf("message    %s\n", s);
    }
    if (j->frame_step) {
        pt_frames fr = {j->frame_first, j->frame_last, j->frame_step};
        uint32_t count = pt_frames_count(&fr);
        uint32_t queued = count - j->frames_done - j->frames_rendering;
        printf("frames     %lu-%lu:%lu, %lu done, %lu rendering, %lu queued\n",
               (unsigned long)j->frame_first, (unsigned long)j->frame_last,
               (unsigned long)j->frame_step, (unsigned long)j->frames_done,
               (unsigned long)j->frames_rendering, (unsigned long)(queued <= count ? queued : 0));
        for (uint32_t i = 0; i < j->nshown && i < PROTO_MAX_FRAMES_SHOWN; i++) {
            double tot = (double)j->shown[i].samples_total;
            printf("frame      %lu: %.1f%%\n", (unsigned long)j->shown[i].frame,
                   tot > 0 ? 100.0 * (double)j->shown[i].samples_done / tot : 0.0);
        }
    }
}

static const char STATUS_HELP[] =
    "usage: ptctl status JOB [--json]\n"
    "\n"
    "Everything the server reports about job JOB: state, queue position, priority,\n"
    "owner, scene, output file, size, samples done and asked, passes, tiles stopped\n"
    "by adaptive sampling, workers, render time, samples/s, estimated error,\n"
    "submission time and message; for a frame range, the frames done, rendering and\n"
    "queued, and each rendering frame's percentage.\n"
    "\n"
    "options:\n"
    "  --json             one JSON object instead (error: null when unknown)\n";

static int cmd_status(int argc, char **argv, globals *g)
{
    job_args a = {0};
    ctl_conn *c;
    int rc = open_job_command("status", STATUS_HELP, TAKES_JOB | TAKES_JSON, argc, argv, g, &a, &c);
    if (!c)
        return rc;
    pt_error err = {0};
    static proto_job_info j;
    if (ctl_status(c, a.id, &j, &err) != PT_OK)
        return fail_close(c, &err);
    ctl_close(c);
    if (a.json) {
        ctl_json_job(stdout, &j);
        fputc('\n', stdout);
    } else {
        print_status(&j);
    }
    return fflush(stdout) == 0 ? 0 : EXIT_ERROR;
}

static const char WATCH_HELP[] =
    "usage: ptctl watch JOB\n"
    "\n"
    "Follows job JOB until it ends: a progress line on stderr (bar, samples per\n"
    "pixel done of those asked, percent, samples/s, workers, ETA, estimated error),\n"
    "redrawn in place on a terminal, else printed at most every 5 s. Exit status 0\n"
    "when the job is done, 4 when it was cancelled or failed.\n";

static int cmd_watch(int argc, char **argv, globals *g)
{
    job_args a = {0};
    ctl_conn *c;
    int rc = open_job_command("watch", WATCH_HELP, TAKES_JOB, argc, argv, g, &a, &c);
    if (!c)
        return rc;
    rc = watch_job(c, a.id);
    ctl_close(c);
    return rc;
}

static const char CANCEL_HELP[] =
    "usage: ptctl cancel JOB\n"
    "\n"
    "Cancels job JOB, queued or running, and prints the state it ends in on stdout:\n"
    "'cancelled', or the state it had already ended in ('done', 'failed').\n";

static int cmd_cancel(int argc, char **argv, globals *g)
{
    job_args a = {0};
    ctl_conn *c;
    int rc = open_job_command("cancel", CANCEL_HELP, TAKES_JOB, argc, argv, g, &a, &c);
    if (!c)
        return rc;
    pt_error err = {0};
    static proto_job_info j;
    if (ctl_cancel(c, a.id, &j, &err) != PT_OK)
        return fail_close(c, &err);
    ctl_close(c);
    printf("%s\n", proto_job_state_name(j.state));
    return fflush(stdout) == 0 ? 0 : EXIT_ERROR;
}

static const char FETCH_HELP[] =
    "usage: ptctl fetch JOB [--frame F] -o OUT.exr\n"
    "       ptctl fetch JOB [--frame F] [--exposure EV] [--view V] -o OUT.png\n"
    "\n"
    "Downloads job JOB's image (the EXR the server wrote last) and writes it to\n"
    "OUT.exr atomically: a temporary file in the same folder, synced, renamed\n"
    "over OUT.exr. The SHA-256 of the bytes received is checked against the\n"
    "server's. Download progress goes to stderr when it is a terminal. The\n"
    "output's format follows its name: OUT.png is the image as an 8-bit PNG\n"
    "through the previews' exposure and view transform; any other name is\n"
    "refused, and the output's folder is checked, before anything is downloaded.\n"
    "\n"
    "options:\n"
    "  -o, --output PATH  the file to write (required): NAME.exr or NAME.png\n"
    "  --exposure EV      the PNG's exposure in stops (default 0)\n"
    "  --view V           the PNG's view transform: standard (default), filmic, agx\n"
    "  --frame F          frame F of a frame-range job (its latest image); without\n"
    "                     it, such a job's earliest frame rendering, or else the\n"
    "                     last frame done\n";

/* The EXR bytes received, as a PNG through view at path: read back from a
 * temporary beside path (the EXR reader reads files), which is removed. */
static pt_status write_png(const char *path, const uint8_t *exr, size_t size, const pt_view *view,
                           pt_error *err)
{
    pt_temp t;
    pt_status st = pt_temp_open(path, 0600, &t, err);
    if (st != PT_OK)
        return st;
    pt_image *img = NULL;
    if (pt_write_all(t.fd, exr, size) != 0)
        st = pt_error_set(err, PT_ERR_IO, "%s: cannot write a temporary", path);
    if (st == PT_OK)
        st = pt_exr_read(t.path, &img, NULL, err);
    pt_temp_abort(&t);
    if (st == PT_OK)
        st = pt_png_write_preview(path, img, view, err);
    pt_image_free(img);
    return st;
}

static int cmd_fetch(int argc, char **argv, globals *g)
{
    job_args a = {0};
    ctl_conn *c;
    int rc = open_job_command("fetch", FETCH_HELP, TAKES_JOB | TAKES_OUTPUT | TAKES_FRAME, argc,
                              argv, g, &a, &c);
    if (!c)
        return rc;
    pt_error err = {0};
    uint8_t *data = NULL;
    size_t size = 0;
    transfer t = {"downloading", 0};
    int tty = isatty(STDERR_FILENO);
    pt_status st =
        a.has_frame
            ? ctl_fetch_frame(c, a.id, a.frame, tty ? show_transfer : NULL, &t, &data, &size, &err)
            : ctl_fetch(c, a.id, tty ? show_transfer : NULL, &t, &data, &size, &err);
    if (t.shown)
        fputc('\n', stderr);
    if (st != PT_OK)
        return fail_close(c, &err);
    ctl_close(c);
    if (pt_image_format_of(a.output) == PT_IMAGE_FORMAT_PNG)
        st = write_png(a.output, data, size, &a.view, &err);
    else
        st = ctl_write_atomic(a.output, data, size, &err);
    pt_free(data);
    if (st != PT_OK) {
        fprintf(stderr, "ptctl: %s\n", err.msg);
        return EXIT_ERROR;
    }
    return 0;
}

static const struct {
    const char *name;
    command_fn fn;
} commands[] = {
    {"submit", cmd_submit}, {"list", cmd_list},     {"status", cmd_status},
    {"watch", cmd_watch},   {"cancel", cmd_cancel}, {"fetch", cmd_fetch},
};

int main(int argc, char **argv)
{
    globals g = {0};
    g.server = getenv("PTFARM_SERVER");
    if (!g.server || !*g.server)
        g.server = CTL_DEFAULT_SERVER;
    g.token_file = getenv("PTFARM_TOKEN_FILE");
    if (g.token_file && !*g.token_file)
        g.token_file = NULL;
    g.timeout_ms = CTL_DEFAULT_TIMEOUT_MS;

    static const struct option opts[] = {/* before the command */
                                         {"server", required_argument, NULL, O_SERVER},
                                         {"token-file", required_argument, NULL, O_TOKEN},
                                         {"timeout", required_argument, NULL, O_TIMEOUT},
                                         {"help", no_argument, NULL, 'h'},
                                         {"version", no_argument, NULL, 'V'},
                                         {NULL, 0, NULL, 0}};
    int c;
    /* '+': stop at the command; what follows is the command's. */
    while ((c = getopt_long(argc, argv, "+:h", opts, NULL)) != -1) {
        int rc = 0;
        switch (c) {
        case 'h':
            usage(stdout);
            return 0;
        case 'V':
            return pt_version_print("ptctl");
        case ':':
            return bad_usage(NULL, "%s needs a value", argv[optind - 1]);
        case '?':
            return unknown_option(NULL, argv);
        default:
            rc = parse_global(NULL, c, optarg, &g);
        }
        if (rc)
            return rc;
    }
    if (optind >= argc) {
        usage(stderr);
        return EXIT_USAGE;
    }
    const char *cmd = argv[optind];
    if (strcmp(cmd, "help") == 0) {
        usage(stdout);
        return 0;
    }
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(cmd, commands[i].name) == 0)
            return commands[i].fn(argc - optind, argv + optind, &g);
    return bad_usage(NULL, "unknown command '%s'", cmd);
}
