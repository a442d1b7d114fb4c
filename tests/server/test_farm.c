/*
 * test_farm.c - ptserve and ptworker as real processes over real sockets.
 *
 *  1. Bit identity: the standalone `ptworker --scene`, `ptserve --local 1`
 *     and `ptserve --local 3` give the same R, G, B and samples bits, with
 *     fixed chunks (--chunk) and with tasks sized by time (the default), also
 *     for workers of different speeds (2 threads and 1) and for adaptive
 *     sampling.
 *  2. Chaos: workers are killed with SIGKILL at random moments (at least ten
 *     times, each replaced) while tasks are sized by time; the job completes
 *     bit-identical (to the standalone render's chunks of 48) with exact sample
 *     counts, while a reader polling the output EXR always finds a valid file
 *     whose sample counts never decrease.
 *  3. Hostile peers during a render: garbage, a huge declared length, a bad
 *     CRC, a wrong token, another protocol version, another build id, a result
 *     for a task never leased, a slow-loris peer. Each is refused with a
 *     logged reason; the render completes bit-identical.
 *  4. SIGINT stops ptserve (and its local workers) with status 130 and
 *     leaves a valid progressive EXR.
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "common/base/net.h"
#include "common/image/exr.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "tests/check.h"

#include "tests/server/farm_util.h"

static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
#define COMMON "--res", "48x32", "--tile", "16", "--chunk", "8", "--seed", "3"
/* The same job with ptserve's default: tasks sized by time (decisions of
 * adaptive sampling every 16 samples, the standalone's --chunk 16). */
#define SIZED "--res", "48x32", "--tile", "16", "--seed", "3"
/* A standalone render of the same job in chunks of 48 samples: with exact
 * sums any cut at multiples of 16 samples gives the same bits. */
#define SOLO48 SIZED, "--chunk", "48"

/* ---- 1. bit identity ---------------------------------------------------------------- */

static void bit_identity(void)
{
    const char *standalone[] = {
        PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "32", "-o",
        path("ref.exr"),        "-q",      NULL};
    CHECK(run(standalone, "ref.log", 120) == 0);
    /* The loop adds every result itself here (--merge-threads 0); --local 3
     * hands the adds to the default 2 merge threads (server/sched/adder.h). */
    const char *local1[] = {
        PT_BIN_DIR "/ptserve", "--local", "1", "--merge-threads", "0", COMMON, "--spp", "32", "-o",
        path("l1.exr"),        SCENE,     NULL};
    CHECK(run(local1, "l1.log", 120) == 0);
    const char *local3[] = {
        PT_BIN_DIR "/ptserve", "--local", "3", "--worker-threads", "1", COMMON, "--spp", "32", "-o",
        path("l3.exr"),        SCENE,     NULL};
    CHECK(run(local3, "l3.log", 120) == 0);
    CHECKF(same_pixels("ref.exr", "l1.exr"), "--local 1 differs from the standalone render");
    CHECKF(same_pixels("ref.exr", "l3.exr"), "--local 3 differs from the standalone render");
    CHECK(all_samples("l3.exr", 32.0f));

    /* Punctual lights (five point lights, NEE choosing among them and the
     * emissive triangles): the farm's image is the standalone one's too. */
    struct stat sb;
    const char *lamp = PT_SHARED_SCENES "/LightsPunctualLamp/LightsPunctualLamp.gltf";
    if (stat(lamp, &sb) == 0) {
        const char *lamp_solo[] = {
            PT_BIN_DIR "/ptworker", "--scene", lamp, COMMON, "--spp", "32", "-o",
            path("lamp_ref.exr"),   "-q",      NULL};
        CHECK(run(lamp_solo, "lamp_ref.log", 120) == 0);
        const char *lamp_farm[] = {PT_BIN_DIR "/ptserve",
                                   "--local",
                                   "3",
                                   "--worker-threads",
                                   "1",
                                   COMMON,
                                   "--spp",
                                   "32",
                                   "-o",
                                   path("lamp3.exr"),
                                   lamp,
                                   NULL};
        CHECK(run(lamp_farm, "lamp3.log", 120) == 0);
        CHECKF(same_pixels("lamp_ref.exr", "lamp3.exr"),
               "punctual lights: --local 3 differs from the standalone render");
    } else {
        CHECK_SKIP("shared scenes not found; the punctual-light farm render");
        CHECK(!check_shared_required());
    }

    /* Adaptive sampling decides from the same sums in both: still identical. */
    const char *ad_solo[] = {PT_BIN_DIR "/ptworker",
                             "--scene",
                             SCENE,
                             COMMON,
                             "--spp",
                             "256",
                             "--target-error",
                             "0.05",
                             "-o",
                             path("ad_ref.exr"),
                             "-q",
                             NULL};
    CHECK(run(ad_solo, "ad_ref.log", 120) == 0);
    const char *ad_farm[] = {
        PT_BIN_DIR "/ptserve", "--local", "3",  "--worker-threads", "1",   COMMON, "--spp", "256",
        "--target-error",      "0.05",    "-o", path("ad3.exr"),    SCENE, NULL};
    CHECK(run(ad_farm, "ad3.log", 120) == 0);
    CHECKF(same_pixels("ad_ref.exr", "ad3.exr"), "adaptive --local 3 differs from standalone");
    pt_image *ad = load_exr("ad3.exr");
    int fewer = 0, full = 0;
    for (uint32_t i = 0; ad && i < ad->width * ad->height; i++) {
        fewer += ad->samples[i] < 256.0f;
        full += ad->samples[i] == 256.0f;
    }
    printf("adaptive: %d pixels stopped early, %d at the full count\n", fewer, full);
    CHECK(fewer > 0);
    pt_image_free(ad);

    /* The minimum-mean-error rule: the same, with counts spread over the tiles. */
    const char *mg_solo[] = {PT_BIN_DIR "/ptworker",
                             "--scene",
                             SCENE,
                             COMMON,
                             "--spp",
                             "256",
                             "--min-gain",
                             "1e-6",
                             "-o",
                             path("mg_ref.exr"),
                             "-q",
                             NULL};
    CHECK(run(mg_solo, "mg_ref.log", 120) == 0);
    const char *mg_farm[] = {
        PT_BIN_DIR "/ptserve", "--local", "3",  "--worker-threads", "1",   COMMON, "--spp", "256",
        "--min-gain",          "1e-6",    "-o", path("mg3.exr"),    SCENE, NULL};
    CHECK(run(mg_farm, "mg3.log", 120) == 0);
    CHECKF(same_pixels("mg_ref.exr", "mg3.exr"), "--min-gain --local 3 differs from standalone");
    CHECKF(!same_pixels("mg_ref.exr", "ad_ref.exr"), "--min-gain renders as --target-error");
    pt_image *mg = load_exr("mg3.exr");
    float counts[8];
    int ncounts = 0;
    full = 0;
    for (uint32_t i = 0; mg && i < mg->width * mg->height; i++) {
        full += mg->samples[i] == 256.0f;
        int seen = 0;
        for (int k = 0; k < ncounts; k++)
            seen |= counts[k] == mg->samples[i];
        if (!seen && ncounts < 8)
            counts[ncounts++] = mg->samples[i];
    }
    printf("min gain: %d distinct counts, %d pixels at the full count\n", ncounts, full);
    CHECK(ncounts >= 3 && full > 0 && full < (int)(48 * 32));
    pt_image_free(mg);

    /* Tasks sized by time (ptserve's default; a short task time so that
     * this small job's tasks grow past one block): the same bits as the
     * standalone render's chunks of 48, with one worker and with three. */
    const char *sized1[] = {
        PT_BIN_DIR "/ptserve", "--local", "1", SIZED, "--task-time", "50", "--spp", "256", "-o",
        path("s1.exr"),        SCENE,     NULL};
    CHECK(run(sized1, "s1.log", 300) == 0);
    const char *solo256[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, SOLO48, "--spp", "256", "-o",
                             path("ref256.exr"),     "-q",      NULL};
    CHECK(run(solo256, "ref256.log", 300) == 0);
    const char *sized3[] = {PT_BIN_DIR "/ptserve",
                            "--local",
                            "3",
                            "--worker-threads",
                            "1",
                            SIZED,
                            "--task-time",
                            "50",
                            "--spp",
                            "256",
                            "-o",
                            path("s3.exr"),
                            SCENE,
                            NULL};
    CHECK(run(sized3, "s3.log", 300) == 0);
    CHECKF(same_pixels("ref256.exr", "s1.exr"), "time-sized --local 1 differs from standalone");
    CHECKF(same_pixels("ref256.exr", "s3.exr"), "time-sized --local 3 differs from standalone");
    CHECK(all_samples("s3.exr", 256.0f));
    /* Adaptive sampling with time-sized tasks: decisions every 16 samples,
     * as the standalone render's with --chunk 16. */
    const char *ad16_solo[] = {PT_BIN_DIR "/ptworker",
                               "--scene",
                               SCENE,
                               SIZED,
                               "--chunk",
                               "16",
                               "--spp",
                               "256",
                               "--target-error",
                               "0.05",
                               "-o",
                               path("ad16_ref.exr"),
                               "-q",
                               NULL};
    CHECK(run(ad16_solo, "ad16_ref.log", 120) == 0);
    const char *ad_sized[] = {PT_BIN_DIR "/ptserve",
                              "--local",
                              "2",
                              "--worker-threads",
                              "1",
                              SIZED,
                              "--task-time",
                              "50",
                              "--spp",
                              "256",
                              "--target-error",
                              "0.05",
                              "-o",
                              path("ad_sized.exr"),
                              SCENE,
                              NULL};
    CHECK(run(ad_sized, "ad_sized.log", 120) == 0);
    CHECKF(same_pixels("ad16_ref.exr", "ad_sized.exr"),
           "adaptive time-sized --local 2 differs from standalone");
}

/* ---- 2. chaos ----------------------------------------------------------------------- */

static pid_t start_worker(int port, const char *token, const char *name)
{
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *argv[] = {
        PT_BIN_DIR "/ptworker", "--server",    server,   "--threads", "1", "--token-file", token,
        "--cache-dir",          path("cache"), "--name", name,        NULL};
    return spawn(argv, "workers.log");
}

static void write_token(void)
{
    FILE *f = fopen(path("token"), "w");
    fputs("correct horse battery staple\n", f);
    fclose(f);
    chmod(path("token"), 0600);
}

/* One chaos run at spp samples per pixel; returns how many workers were
 * killed before the job ended, or -1 when the render failed. */
static int chaos_run(uint32_t spp)
{
    char spp_text[16];
    snprintf(spp_text, sizeof spp_text, "%u", spp);
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, SOLO48, "--spp", spp_text, "-o",
                         path("chaos_ref.exr"),  "-q",      NULL};
    CHECK(run(ref, "chaos_ref.log", 300) == 0);
    unlink(path("port"));
    unlink(path("chaos.exr")); /* a run before this one left its image */
    const char *serve[] = {PT_BIN_DIR "/ptserve",
                           "--listen",
                           "127.0.0.1:0",
                           "--port-file",
                           path("port"),
                           "--token-file",
                           path("token"),
                           SIZED,
                           "--task-time",
                           "100",
                           "--spp",
                           spp_text,
                           "--save-interval",
                           "0.1",
                           "--lease-timeout",
                           "5",
                           "-o",
                           path("chaos.exr"),
                           SCENE,
                           NULL};
    pid_t srv = spawn(serve, "chaos.log");
    int port = read_port();
    CHECK(port > 0);
    pid_t w[3];
    int started = 0;
    char name[32];
    for (int i = 0; i < 3; i++) {
        snprintf(name, sizeof name, "w%d", started++);
        w[i] = start_worker(port, path("token"), name);
    }
    srand(12345);
    int kills = 0, polls = 0, bad_reads = 0, decreases = 0, status = -1;
    float *last = NULL;
    double end = pt_now_s() + 600;
    while (pt_now_s() < end) {
        int st;
        if (waitpid(srv, &st, WNOHANG) == srv) {
            status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
            break;
        }
        /* Poll the progressive image: valid, and counts never go down. */
        struct stat sb;
        if (stat(path("chaos.exr"), &sb) == 0) {
            pt_image *img = load_exr("chaos.exr");
            polls++;
            if (!img) {
                bad_reads++;
            } else {
                size_t n = (size_t)img->width * img->height;
                if (last)
                    for (size_t i = 0; i < n; i++)
                        decreases += img->samples[i] < last[i];
                free(last);
                last = malloc(n * sizeof *last);
                memcpy(last, img->samples, n * sizeof *last);
                pt_image_free(img);
            }
        }
        sleep_ms(30 + rand() % 120);
        if (kills < 12) {
            int k = rand() % 3;
            kill(w[k], SIGKILL);
            waitpid(w[k], NULL, 0);
            kills++;
            snprintf(name, sizeof name, "w%d", started++);
            w[k] = start_worker(port, path("token"), name);
        }
    }
    for (int i = 0; i < 3; i++) {
        kill(w[i], SIGTERM);
        wait_exit(w[i], 10);
    }
    free(last);
    printf("chaos: %d kills, %d polls of the progressive EXR\n", kills, polls);
    CHECKF(status == 0, "ptserve exit status %d", status);
    CHECK(polls > 0 && bad_reads == 0 && decreases == 0);
    CHECKF(same_pixels("chaos_ref.exr", "chaos.exr"), "chaos changed the image");
    CHECK(all_samples("chaos.exr", (float)spp));
    return status == 0 ? kills : -1;
}

/* Workers of different speeds (2 threads and 1) with time-sized tasks:
 * each gets tasks sized for itself, and the image is still the standalone
 * render's bits. */
static void mixed_speeds(void)
{
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, SOLO48, "--spp", "512", "-o",
                         path("mixed_ref.exr"),  "-q",      NULL};
    CHECK(run(ref, "mixed_ref.log", 300) == 0);
    unlink(path("port"));
    const char *serve[] = {PT_BIN_DIR "/ptserve",
                           "--listen",
                           "127.0.0.1:0",
                           "--port-file",
                           path("port"),
                           "--token-file",
                           path("token"),
                           SIZED,
                           "--task-time",
                           "100",
                           "--spp",
                           "512",
                           "-o",
                           path("mixed.exr"),
                           SCENE,
                           NULL};
    pid_t srv = spawn(serve, "mixed.log");
    int port = read_port();
    CHECK(port > 0);
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *fast[] = {
        PT_BIN_DIR "/ptworker", "--server",    server,        "--threads", "2",    "--token-file",
        path("token"),          "--cache-dir", path("cache"), "--name",    "fast", NULL};
    const char *slow[] = {
        PT_BIN_DIR "/ptworker", "--server", server,         "--threads",   "1",
        "--prefetch",           "0",        "--token-file", path("token"), "--cache-dir",
        path("cache"),          "--name",   "slow",         NULL};
    pid_t w1 = spawn(fast, "mixed_fast.log"), w2 = spawn(slow, "mixed_slow.log");
    int st = wait_exit(srv, 300);
    kill(w1, SIGTERM);
    kill(w2, SIGTERM);
    wait_exit(w1, 10);
    wait_exit(w2, 10);
    CHECKF(st == 0, "ptserve exit status %d", st);
    CHECKF(same_pixels("mixed_ref.exr", "mixed.exr"), "workers of mixed speeds changed the image");
    CHECK(all_samples("mixed.exr", 512.0f));
}

/* The kills must land while the job runs. How long it runs depends on the
 * machine, not on the test: when it ended before ten kills, the same chaos
 * runs again on a job four times larger, so a fast machine is no failure. */
static void chaos(void)
{
    int kills = 0;
    for (uint32_t spp = 2048; spp <= 32768 && kills >= 0 && kills < 10; spp *= 4) {
        kills = chaos_run(spp);
        if (kills >= 0 && kills < 10 && spp < 32768)
            printf("chaos: the job ended after %d kills; again with %u spp\n", kills, spp * 4);
    }
    CHECKF(kills >= 10, "only %d kills before the job ended", kills);
}

/* ---- 3. hostile peers --------------------------------------------------------------- */

static void hostile(void)
{
    unlink(path("port"));
    const char *serve[] = {PT_BIN_DIR "/ptserve",
                           "--listen",
                           "127.0.0.1:0",
                           "--port-file",
                           path("port"),
                           "--token-file",
                           path("token"),
                           "--handshake-timeout",
                           "1",
                           COMMON,
                           "--spp",
                           "1024",
                           "-o",
                           path("hostile.exr"),
                           SCENE,
                           NULL};
    pid_t srv = spawn(serve, "hostile.log");
    int port = read_port();
    CHECK(port > 0);

    /* Slow loris: a valid HELLO frame dripped a byte at a time, too slowly
     * to finish the handshake in time. */
    {
        proto_hello h = {0};
        h.version = PROTO_VERSION;
        h.role = PROTO_ROLE_WORKER;
        snprintf(h.name, sizeof h.name, "slow");
        snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
        proto_writer p, w;
        proto_writer_init(&p, 4096);
        proto_writer_init(&w, 4096);
        proto_msg_encode_hello(&p, &h, NULL);
        proto_frame_encode(&w, PROTO_MSG_HELLO, p.buf, p.len, NULL);
        int fd = connect_to(port);
        int closed = 0;
        for (size_t i = 0; i + 1 < w.len && !closed; i++)
            closed = pt_net_write_all(fd, w.buf + i, 1, NULL) != PT_OK || closed_by_server(fd, 150);
        CHECK(closed);
        close(fd);
        proto_writer_fini(&p);
        proto_writer_fini(&w);
    }

    /* An honest worker renders while the hostile peers keep coming. */
    pid_t w1 = start_worker(port, path("token"), "good1");

    int fd = connect_to(port);
    CHECK(pt_net_write_all(fd, "GET / HTTP/1.1\r\nHost: x\r\n\r\n", 27, NULL) == PT_OK);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    uint8_t hdr[12] = {'P',  'T',  'F',  '1', (uint8_t)PROTO_VERSION, 0, PROTO_MSG_HELLO, 0,
                       0xff, 0xff, 0xff, 0xff};
    fd = connect_to(port);
    pt_net_write_all(fd, hdr, sizeof hdr, NULL);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    /* A valid HELLO frame with one bit of its CRC flipped. */
    {
        proto_hello h = {0};
        h.version = PROTO_VERSION;
        h.role = PROTO_ROLE_WORKER;
        snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
        proto_writer p, w;
        proto_writer_init(&p, 4096);
        proto_writer_init(&w, 4096);
        proto_msg_encode_hello(&p, &h, NULL);
        proto_frame_encode(&w, PROTO_MSG_HELLO, p.buf, p.len, NULL);
        w.buf[w.len - 1] ^= 0x10;
        fd = connect_to(port);
        pt_net_write_all(fd, w.buf, w.len, NULL);
        CHECK(closed_by_server(fd, 3000));
        close(fd);
        proto_writer_fini(&p);
        proto_writer_fini(&w);
    }

    fd = authenticate(port, "not the token", PROTO_ROLE_WORKER);
    CHECK(fd >= 0 && closed_by_server(fd, 3000));
    close(fd);

    fd = connect_to(port);
    send_hello(fd, 99, proto_build_id(), PROTO_ROLE_WORKER);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    fd = connect_to(port);
    send_hello(fd, PROTO_VERSION, "0000000000000000", PROTO_ROLE_WORKER);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    /* Authenticated, then a result for a task it was never leased: the job's
     * last task (6 tiles x 64 chunks: --chunk 8 rounds up to the 16-sample
     * block), leased last. Task 0 would race the honest worker: once it
     * has merged it, a result for it is a harmless duplicate, not an error. */
    fd = authenticate(port, "correct horse battery staple", PROTO_ROLE_WORKER);
    CHECK(fd >= 0);
    if (fd >= 0) {
        static pt_pixel_acc px[256];
        memset(px, 0, sizeof px);
        for (int i = 0; i < 256; i++) {
            px[i].fsum[0] = (pt_i128)1e6 << PT_FIXED_BITS;
            px[i].n = 8;
        }
        proto_result r = {0};
        r.job_id = 1;
        r.task_id = 6 * 64 - 1;
        r.tile = (pt_rect){0, 0, 16, 16};
        r.s0 = 0;
        r.s1 = 8;
        r.npixels = 256;
        r.pixels = px;
        proto_writer p;
        proto_writer_init(&p, 1 << 20);
        proto_msg_encode_result(&p, &r, NULL);
        send_frame(fd, PROTO_MSG_RESULT, &p);
        proto_writer_fini(&p);
        sleep_ms(300);
        close(fd);
    }

    pid_t w2 = start_worker(port, path("token"), "good2");
    int status = wait_exit(srv, 300);
    kill(w1, SIGTERM);
    kill(w2, SIGTERM);
    wait_exit(w1, 10);
    wait_exit(w2, 10);
    CHECKF(status == 0, "ptserve exit status %d", status);
    const char *ref[] = {PT_BIN_DIR "/ptworker",  "--scene", SCENE, COMMON, "--spp", "1024", "-o",
                         path("hostile_ref.exr"), "-q",      NULL};
    CHECK(run(ref, "hostile_ref.log", 120) == 0);
    CHECKF(same_pixels("hostile_ref.exr", "hostile.exr"), "hostile peers changed the image");
    const char *reasons[] = {"bad magic",
                             "over",
                             "CRC",
                             "authentication failed",
                             "protocol version 99",
                             "build 0000000000000000",
                             "does not hold",
                             "handshake not finished"};
    for (size_t i = 0; i < sizeof reasons / sizeof *reasons; i++)
        CHECKF(log_has("hostile.log", reasons[i]), "no logged reason containing '%s'", reasons[i]);
}

/* ---- 4. Ctrl-C --------------------------------------------------------------------- */

static void interrupt(void)
{
    const char *serve[] = {PT_BIN_DIR "/ptserve",
                           "--local",
                           "2",
                           "--worker-threads",
                           "1",
                           COMMON,
                           "--spp",
                           "100000",
                           "--save-interval",
                           "0.1",
                           "-o",
                           path("int.exr"),
                           SCENE,
                           NULL};
    pid_t srv = spawn(serve, "int.log");
    struct stat sb;
    for (int i = 0; i < 1000 && stat(path("int.exr"), &sb) != 0; i++)
        sleep_ms(20);
    sleep_ms(200);
    kill(srv, SIGINT);
    int status = wait_exit(srv, 30);
    CHECKF(status == 130, "interrupted ptserve exit status %d", status);
    CHECK(log_has("int.log", "interrupted"));
    pt_image *img = load_exr("int.exr");
    CHECK(img != NULL);
    if (img) {
        double n = 0;
        for (uint32_t i = 0; i < img->width * img->height; i++)
            n += img->samples[i];
        CHECK(n > 0 && n < 48.0 * 32.0 * 100000.0);
    }
    pt_image_free(img);
    /* The local workers are gone: no process is left holding the loopback port. */
    CHECK(log_has("int.log", "holds"));
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_farm_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    write_token();
    bit_identity();
    mixed_speeds();
    chaos();
    hostile();
    interrupt();
    return farm_test_end();
}
