/*
 * test_farm_env.c - the environment light on the farm, with real ptserve,
 * ptworker and ptctl processes over real sockets.
 *
 *  1. One job: `ptserve --local 2 --background ...` and (with ../shared/envs)
 *     `--env MAP --env-strength --env-rotate` give the standalone render's
 *     R, G, B and sample bits; the map changes the image (it is not ignored).
 *     A scene with no light, and a bad map, are refused at start with the
 *     reason and exit 1.
 *  2. Queue: `ptctl submit --env ...` while a worker renders; maps that are
 *     cut short, not images, 0 x 0, 1e38 (RGBE), NaN and 1e38 (EXR) are
 *     refused at upload with the reason, as is a scene with no light, while
 *     the running job goes on; so is a SUBMIT naming any other file as its map
 *     or a map its bundle lacks; then the coordinator is killed with SIGKILL
 *     mid-job and restarted, and the environment job and a --background job
 *     queued behind it finish bit-identical to their standalone renders.
 */
#include <math.h>

#include "common/base/alloc.h"
#include "common/image/image.h"
#include "common/scene/bundle.h"
#include "tests/check.h"
#include "tests/server/farm_util.h"

static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
static const char *MAP = PT_SHARED_SCENES "/../envs/studio_small_03_1k.hdr";
#define COMMON "--res", "48x32", "--tile", "16", "--chunk", "8", "--seed", "3"
#define ENV_OPTS "--env-strength", "2", "--env-rotate", "30"
#define SKY "0.5,0.6,0.7"

static int have_map;
static char listen_addr[64];
static int g_port;

/* A triangle and nothing that emits: it would render black. */
static void write_dark_scene(void)
{
    FILE *f = fopen(path("dark.gltf"), "w");
    CHECK(f != NULL);
    if (!f)
        return;
    fputs("{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
          "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
          "{\"POSITION\":0}}]}],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,"
          "\"count\":3,\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,1,0]}],"
          "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36,"
          "\"uri\":\"data:application/octet-stream;base64,"
          "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA\"}]}",
          f);
    fclose(f);
}

static void write_bytes(const char *name, const void *d, size_t n)
{
    FILE *f = fopen(path(name), "wb");
    CHECK(f && fwrite(d, 1, n, f) == n);
    if (f)
        fclose(f);
}

/* A flat Radiance file of w x h texels, all (r, g, b, e). */
static size_t rgbe_file(uint8_t *buf, size_t cap, int w, int h, const uint8_t px[4])
{
    int n = snprintf((char *)buf, cap, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    size_t at = (size_t)n;
    for (int i = 0; i < w * h && at + 4 <= cap; i++, at += 4)
        memcpy(buf + at, px, 4);
    return at;
}

/* The bad maps a client might send, each with a word its refusal must hold. */
static const char *const BAD[][2] = {
    {"cut.hdr", "environment map refused"},
    {"text.hdr", "not an environment map"},
    {"empty.hdr", "environment map refused"},
    {"huge.hdr", "not a radiance in"},
    {"nan.exr", "pixel (5, 0)"},
    {"big.exr", "pixel (5, 0)"},
};

static void write_bad_maps(void)
{
    static uint8_t buf[1 << 16];
    const uint8_t grey[4] = {128, 128, 128, 129}, huge[4] = {255, 255, 255, 255};
    size_t n = rgbe_file(buf, sizeof buf, 8, 4, grey);
    write_bytes("cut.hdr", buf, n - 40);
    write_bytes("text.hdr", "hello, not an image\n", 20);
    n = rgbe_file(buf, sizeof buf, 0, 0, grey);
    write_bytes("empty.hdr", buf, n);
    n = rgbe_file(buf, sizeof buf, 8, 4, huge); /* about 1.7e38 per texel */
    write_bytes("huge.hdr", buf, n);
    pt_image *img = NULL;
    CHECK(pt_image_new(8, 4, &img, NULL) == PT_OK);
    const float bad[2] = {NAN, 1e38f};
    const char *names[2] = {"nan.exr", "big.exr"};
    for (int k = 0; k < 2 && img; k++) {
        pt_error err = {0};
        img->g[5] = bad[k];
        CHECK(pt_exr_write(path(names[k]), img, NULL, &err) == PT_OK);
    }
    pt_image_free(img);
}

/* Runs argv with stdout to out_name (in tmp) and stderr to log; the exit status. */
static int run_out(const char *const *argv, const char *out_name, const char *log, double timeout)
{
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, path(out_name), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, path(log), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = -1;
    if (posix_spawn(&pid, argv[0], &fa, NULL, (char *const *)argv, environ) != 0)
        pid = -1;
    posix_spawn_file_actions_destroy(&fa);
    return pid > 0 ? wait_exit(pid, timeout) : -1;
}

static char *slurp(const char *name)
{
    static char buf[1 << 16];
    FILE *f = fopen(path(name), "r");
    size_t n = f ? fread(buf, 1, sizeof buf - 1, f) : 0;
    if (f)
        fclose(f);
    buf[n] = '\0';
    return buf;
}

/* ---- 1. one job ------------------------------------------------------------------- */

static void one_job(void)
{
    const char *solo_bg[] = {
        PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "32", "--background", SKY, "-o",
        path("bg_ref.exr"),     "-q",      NULL};
    CHECK(run(solo_bg, "bg_ref.log", 300) == 0);
    const char *farm_bg[] = {
        PT_BIN_DIR "/ptserve", "--local", "2",  "--worker-threads", "1",   COMMON, "--spp", "32",
        "--background",        SKY,       "-o", path("bg2.exr"),    SCENE, NULL};
    CHECK(run(farm_bg, "bg2.log", 300) == 0);
    CHECKF(same_pixels("bg_ref.exr", "bg2.exr"), "--background: the farm differs from standalone");

    if (have_map) {
        const char *solo[] = {PT_BIN_DIR "/ptworker",
                              "--scene",
                              SCENE,
                              COMMON,
                              "--spp",
                              "32",
                              "--env",
                              MAP,
                              ENV_OPTS,
                              "-o",
                              path("env_ref.exr"),
                              "-q",
                              NULL};
        CHECK(run(solo, "env_ref.log", 300) == 0);
        const char *farm[] = {PT_BIN_DIR "/ptserve",
                              "--local",
                              "2",
                              "--worker-threads",
                              "1",
                              COMMON,
                              "--spp",
                              "32",
                              "--env",
                              MAP,
                              ENV_OPTS,
                              "-o",
                              path("env2.exr"),
                              SCENE,
                              NULL};
        CHECK(run(farm, "env2.log", 300) == 0);
        CHECKF(same_pixels("env_ref.exr", "env2.exr"), "--env: the farm differs from standalone");
        /* The map is used, and turned: neither the box alone nor the map unturned. */
        const char *plain[] = {PT_BIN_DIR "/ptworker",
                               "--scene",
                               SCENE,
                               COMMON,
                               "--spp",
                               "32",
                               "--env",
                               MAP,
                               "--env-strength",
                               "2",
                               "-o",
                               path("env_unturned.exr"),
                               "-q",
                               NULL};
        CHECK(run(plain, "env_unturned.log", 300) == 0);
        CHECK(!same_pixels("env_ref.exr", "env_unturned.exr"));
        CHECK(!same_pixels("env_ref.exr", "bg_ref.exr"));
    }

    /* No light: refused at start with the way to light it. */
    const char *dark[] = {
        PT_BIN_DIR "/ptserve", "--local",         "1", "--res", "8x8", "--spp", "1", "-o",
        path("dark.exr"),      path("dark.gltf"), NULL};
    CHECK(run(dark, "dark.log", 120) == 1);
    CHECK(log_has("dark.log", "has no light") && log_has("dark.log", "--env") &&
          log_has("dark.log", "--background"));
    const char *dark_lit[] = {PT_BIN_DIR "/ptserve",
                              "--local",
                              "1",
                              "--res",
                              "8x8",
                              "--spp",
                              "1",
                              "--background",
                              "1,1,1",
                              "-o",
                              path("dark.exr"),
                              path("dark.gltf"),
                              NULL};
    CHECK(run(dark_lit, "dark_lit.log", 120) == 0);
    /* A bad map: refused at start, before any worker. */
    const char *bad[] = {PT_BIN_DIR "/ptserve",
                         "--local",
                         "1",
                         "--res",
                         "8x8",
                         "--spp",
                         "1",
                         "--env",
                         path("text.hdr"),
                         "-o",
                         path("bad.exr"),
                         SCENE,
                         NULL};
    CHECK(run(bad, "bad_one.log", 120) == 1);
    CHECK(log_has("bad_one.log", "not an environment map"));
    const char *both[] = {PT_BIN_DIR "/ptserve", "--env", path("text.hdr"),
                          "--background",        "1,1,1", "-o",
                          path("bad.exr"),       SCENE,   NULL};
    CHECK(run(both, "both.log", 60) == 2 && log_has("both.log", "give one"));
    const char *queue_env[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("nostate"),
                               "--background",        "1,1,1",       NULL};
    CHECK(run(queue_env, "queue_env.log", 60) == 2 && log_has("queue_env.log", "ptctl submit"));
}

/* A raw SUBMIT of bundle b naming env_name as its map (and the upload when
 * SUBMIT is accepted); the text of the ERROR it gets, or "" for none. */
static const char *raw_submit(const pt_bundle *b, const char *env_name)
{
    static char text[PROTO_MAX_ERROR_TEXT + 1];
    static uint8_t buf[1 << 16];
    text[0] = '\0';
    int fd = authenticate(g_port, "", PROTO_ROLE_CLIENT);
    proto_frame f;
    if (fd < 0 || read_frame(fd, buf, sizeof buf, &f) != PROTO_MSG_WELCOME) {
        if (fd >= 0)
            close(fd);
        return "no WELCOME";
    }
    proto_submit m;
    memset(&m, 0, sizeof m);
    snprintf(m.name, sizeof m.name, "raw");
    m.width = m.height = 8;
    m.spp = 1;
    m.bundle_size = b->size;
    for (int i = 0; i < 32; i++) {
        unsigned v = 0;
        sscanf(b->hash + 2 * i, "%2x", &v);
        m.bundle_hash[i] = (uint8_t)v;
    }
    proto_env_none(&m.env);
    snprintf(m.env.name, sizeof m.env.name, "%s", env_name);
    proto_writer w;
    proto_writer_init(&w, 1 << 21);
    CHECK(proto_msg_encode_submit(&w, &m, NULL) == PT_OK);
    send_frame(fd, PROTO_MSG_SUBMIT, &w);
    proto_writer_reset(&w);
    proto_scene_chunk ch = {{0}, 0, b->size, (uint32_t)b->size, b->data};
    memcpy(ch.hash, m.bundle_hash, 32);
    CHECK(proto_msg_encode_scene_chunk(&w, &ch, NULL) == PT_OK);
    send_frame(fd, PROTO_MSG_UPLOAD, &w);
    proto_writer_fini(&w);
    if (read_frame(fd, buf, sizeof buf, &f) == PROTO_MSG_ERROR) {
        proto_error_msg e;
        if (proto_msg_decode_error(f.payload, f.len, &e, NULL) == PT_OK)
            snprintf(text, sizeof text, "%s", e.text);
    }
    close(fd);
    return text;
}

/* ---- 2. queue ----------------------------------------------------------------------- */

static pid_t g_srv = -1;

static void start_server(void)
{
    unlink(path("port"));
    const char *argv[] = {PT_BIN_DIR "/ptserve",
                          "--state-dir",
                          path("state"),
                          "--listen",
                          listen_addr,
                          "--port-file",
                          path("port"),
                          "--tile",
                          "16",
                          "--chunk",
                          "8",
                          "--save-interval",
                          "0.2",
                          "--quiet",
                          NULL};
    g_srv = spawn(argv, "serve.log");
    int port = read_port();
    CHECK(port > 0);
    g_port = port;
    snprintf(listen_addr, sizeof listen_addr, "127.0.0.1:%d", port);
}

/* ptctl ARGS... with --server; stdout to out, stderr to log; the exit status. */
static int ctl(const char *out, const char *log, const char *const *args)
{
    const char *argv[32] = {PT_BIN_DIR "/ptctl", "--server", listen_addr};
    int n = 3;
    for (int i = 0; args[i] && n < 31; i++)
        argv[n++] = args[i];
    argv[n] = NULL;
    return run_out(argv, out, log, 120);
}

/* Submits; the job id, 0 when refused. */
static uint64_t submit(const char *log, const char *const *args)
{
    if (ctl("submit.out", log, args) != 0)
        return 0;
    return strtoull(slurp("submit.out"), NULL, 10);
}

/* The job's JSON status, or "" */
static const char *status_json(uint64_t id)
{
    char ids[32];
    snprintf(ids, sizeof ids, "%llu", (unsigned long long)id);
    const char *args[] = {"status", ids, "--json", NULL};
    if (ctl("status.out", "status.log", args) != 0)
        return "";
    return slurp("status.out");
}

static uint64_t json_u64(const char *json, const char *field)
{
    char key[64];
    snprintf(key, sizeof key, "\"%s\": ", field);
    const char *p = strstr(json, key);
    return p ? strtoull(p + strlen(key), NULL, 10) : 0;
}

static int json_state_is(const char *json, const char *state)
{
    char want[64];
    snprintf(want, sizeof want, "\"state\": \"%s\"", state);
    return strstr(json, want) != NULL;
}

static void queue(void)
{
    /* The environment job (a uniform one when the shared maps are absent) and
     * a --background job queued behind it; references rendered standalone. */
    /* The worker is held (SIGSTOP) from the job's first samples until after
     * the kill below, so the job still runs then however long the
     * submissions in between take: 768 tasks of 8 passes, of which a few
     * are done when it is held. */
    const char *spp = "1024";
    const char *env_solo[] = {PT_BIN_DIR "/ptworker",
                              "--scene",
                              SCENE,
                              "--res",
                              "48x32",
                              "--tile",
                              "16",
                              "--chunk",
                              "8",
                              "--seed",
                              "5",
                              "--spp",
                              spp,
                              have_map ? "--env" : "--background",
                              have_map ? MAP : "0.3,0.3,0.3",
                              ENV_OPTS,
                              "-o",
                              path("qenv_ref.exr"),
                              "-q",
                              NULL};
    CHECK(run(env_solo, "qenv_ref.log", 600) == 0);
    const char *bg_solo[] = {PT_BIN_DIR "/ptworker",
                             "--scene",
                             SCENE,
                             "--res",
                             "48x32",
                             "--tile",
                             "16",
                             "--chunk",
                             "8",
                             "--seed",
                             "5",
                             "--spp",
                             "64",
                             "--background",
                             SKY,
                             "-o",
                             path("qbg_ref.exr"),
                             "-q",
                             NULL};
    CHECK(run(bg_solo, "qbg_ref.log", 300) == 0);

    snprintf(listen_addr, sizeof listen_addr, "127.0.0.1:0");
    start_server();
    const char *env_args[] = {"submit",
                              SCENE,
                              "--res",
                              "48x32",
                              "--seed",
                              "5",
                              "--spp",
                              spp,
                              have_map ? "--env" : "--background",
                              have_map ? MAP : "0.3,0.3,0.3",
                              ENV_OPTS,
                              NULL};
    uint64_t a = submit("submit_env.log", env_args);
    CHECKF(a > 0, "environment job refused: %s", slurp("submit_env.log"));
    const char *wargv[] = {PT_BIN_DIR "/ptworker", "--server",    listen_addr, "--threads", "1",
                           "--cache-dir",          path("cache"), "--name",    "w1",        NULL};
    pid_t w1 = spawn(wargv, "workers.log");

    /* Wait until it renders. */
    double end = pt_now_s() + 120;
    while (pt_now_s() < end && json_u64(status_json(a), "samples_done") == 0)
        sleep_ms(50);
    CHECK(json_u64(status_json(a), "samples_done") > 0);
    kill(w1, SIGSTOP);

    /* Bad maps and a dark scene, refused at upload while the job runs. */
    for (size_t i = 0; i < sizeof BAD / sizeof BAD[0]; i++) {
        const char *args[] = {"submit", SCENE,   "--res",         "16x16", "--spp",
                              "8",      "--env", path(BAD[i][0]), NULL};
        CHECKF(submit("submit_bad.log", args) == 0, "%s was accepted", BAD[i][0]);
        CHECKF(strstr(slurp("submit_bad.log"), BAD[i][1]) != NULL, "%s: refusal lacks '%s': %s",
               BAD[i][0], BAD[i][1], slurp("submit_bad.log"));
        /* Named by the bundle's name, never the server's folders. */
        CHECKF(strstr(slurp("submit_bad.log"), "/state/") == NULL, "%s: %s", BAD[i][0],
               slurp("submit_bad.log"));
    }
    /* A map named outside the bundle's own place, and one the bundle lacks:
     * refused, nothing opened. */
    pt_bundle *plain = NULL;
    CHECK(pt_bundle_pack(SCENE, &plain, NULL) == PT_OK);
    if (plain) {
        const char *t = raw_submit(plain, "../../etc/passwd");
        CHECKF(strstr(t, "must be the bundle's") != NULL, "outside name: '%s'", t);
        t = raw_submit(plain, "scene.bin");
        CHECKF(strstr(t, "must be the bundle's") != NULL, "other file: '%s'", t);
        t = raw_submit(plain, PT_BUNDLE_ENV_NAME);
        CHECKF(strstr(t, "holds no") != NULL, "absent map: '%s'", t);
    }
    pt_bundle_free(plain);
    const char *missing[] = {"submit", SCENE, "--env", path("missing.hdr"), NULL};
    CHECK(submit("submit_missing.log", missing) == 0);
    CHECK(strstr(slurp("submit_missing.log"), "missing.hdr") != NULL);
    const char *dark[] = {"submit", path("dark.gltf"), "--res", "8x8", "--spp", "1", NULL};
    CHECK(submit("submit_dark.log", dark) == 0);
    CHECKF(strstr(slurp("submit_dark.log"), "has no light") != NULL &&
               strstr(slurp("submit_dark.log"), "--background") != NULL,
           "%s", slurp("submit_dark.log"));
    const char *dark_lit[] = {"submit",       path("dark.gltf"), "--res",      "8x8", "--spp", "1",
                              "--background", "1,1,1",           "--priority", "-1",  NULL};
    uint64_t d = submit("submit_dark_lit.log", dark_lit);
    CHECKF(d > 0, "%s", slurp("submit_dark_lit.log"));

    const char *bg_args[] = {"submit", SCENE, "--res",        "48x32", "--seed", "5",
                             "--spp",  "64",  "--background", SKY,     NULL};
    uint64_t b = submit("submit_bg.log", bg_args);
    CHECK(b > 0);

    /* The environment job still runs, its tasks leased to the held worker;
     * now a kill -9 mid-job, and a restart on the same state folder and
     * port. */
    const char *js = status_json(a);
    CHECKF(json_state_is(js, "running"), "before the kill: %s", js);
    uint64_t before = json_u64(js, "samples_done");
    kill(g_srv, SIGKILL);
    waitpid(g_srv, NULL, 0);
    start_server();
    js = status_json(a);
    CHECKF(json_u64(js, "samples_done") >= before, "after the restart: %s", js);
    kill(w1, SIGCONT); /* it finds its coordinator gone and joins the new one */

    end = pt_now_s() + 600;
    while (pt_now_s() < end && !json_state_is(status_json(d), "done"))
        sleep_ms(100);
    CHECK(json_state_is(status_json(a), "done"));
    CHECK(json_state_is(status_json(b), "done"));
    CHECK(json_state_is(status_json(d), "done"));
    char ids[32];
    snprintf(ids, sizeof ids, "%llu", (unsigned long long)a);
    const char *fa[] = {"fetch", ids, "-o", path("qenv.exr"), NULL};
    CHECK(ctl("fetch.out", "fetch.log", fa) == 0);
    snprintf(ids, sizeof ids, "%llu", (unsigned long long)b);
    const char *fb[] = {"fetch", ids, "-o", path("qbg.exr"), NULL};
    CHECK(ctl("fetch.out", "fetch.log", fb) == 0);
    CHECKF(same_pixels("qenv_ref.exr", "qenv.exr"),
           "the environment job differs from standalone after a restart");
    CHECK(all_samples("qenv.exr", (float)atoi(spp)));
    CHECKF(same_pixels("qbg_ref.exr", "qbg.exr"), "the --background job differs from standalone");
    CHECK(log_has("serve.log", "resumed"));

    kill(w1, SIGTERM);
    wait_exit(w1, 60);
    kill(g_srv, SIGTERM);
    wait_exit(g_srv, 60);
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_farm_env_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    struct stat sb;
    have_map = stat(MAP, &sb) == 0;
    if (!have_map) {
        CHECK_SKIP("shared maps not found (%s); the --env renders use a uniform sky", MAP);
        CHECK(!check_shared_required());
    }
    write_dark_scene();
    write_bad_maps();
    one_job();
    queue();
    int rc = check_report();
    if (rc == 0)
        pt_remove_tree(tmp);
    return rc;
}
