/*
 * test_farm_guide.c - hostile guiding statistics on the farm, with real
 * ptserve and ptworker processes over real sockets.
 *
 * ptserve renders the NVIDIA Cornell box (../shared/scenes) with --guiding
 * on. Authenticated workers of our own each take a TASK of the guided job
 * (it names pass 0 and its distribution's hash, which GUIDE_GET hands out
 * whole) and answer with a RESULT of plausible pixels whose statistics are
 * hostile: none at all, made for a guide of other sizes, more records than
 * one per bounce of every sample, a sum over the records' cap. Each is
 * answered with ERROR and the connection closed, the reason logged, and
 * nothing of it merged: honest workers finish the job and its image is
 * ptworker --guiding on's, bit for bit.
 */
#include <math.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/image/image.h"
#include "common/render/render.h"
#include "protocol/guide.h"
#include "tests/check.h"
#include "tests/server/farm_util.h"

static const char *SCENE = PT_SHARED_SCENES "/CornellBox/cornellBox.gltf";
#define COMMON "--res", "48x32", "--tile", "16", "--chunk", "16", "--seed", "9", "--guiding", "on"
#define TOKEN "correct horse battery staple"

/* Takes one task as a worker and answers it with statistics of kind k;
 * returns 1 when the coordinator answered ERROR and closed. */
static int hostile_result(int port, int k)
{
    int fd = authenticate(port, TOKEN, PROTO_ROLE_WORKER);
    if (fd < 0)
        return 0;
    static uint8_t buf[1 << 20];
    proto_frame f;
    if (read_frame(fd, buf, sizeof buf, &f) != PROTO_MSG_WELCOME) {
        close(fd);
        return 0;
    }
    proto_writer p;
    proto_writer_init(&p, 1 << 20);
    proto_work_request wr = {1};
    proto_msg_encode_work_request(&p, &wr, NULL);
    send_frame(fd, PROTO_MSG_WORK_REQUEST, &p);
    proto_task t;
    int got = read_frame(fd, buf, sizeof buf, &f) == PROTO_MSG_TASK &&
              proto_msg_decode_task(f.payload, f.len, &t, NULL) == PT_OK;
    CHECK(got && t.guided && t.guide_pass == 0);
    if (!got) {
        proto_writer_fini(&p);
        close(fd);
        return 0;
    }
    /* The distribution it names is handed out, and hashes to its name. */
    proto_scene_get g;
    memcpy(g.hash, t.guide_hash, 32);
    g.offset = 0;
    proto_writer_reset(&p);
    proto_msg_encode_scene_get(&p, &g, NULL);
    send_frame(fd, PROTO_MSG_GUIDE_GET, &p);
    proto_scene_chunk ch;
    got = read_frame(fd, buf, sizeof buf, &f) == PROTO_MSG_GUIDE_CHUNK &&
          proto_msg_decode_scene_chunk(f.payload, f.len, &ch, NULL) == PT_OK;
    CHECK(got && ch.offset == 0 && ch.len == ch.total);
    uint32_t nsn = 0, nqn = 0;
    if (got) {
        /* Packed on the wire; the hash is of the unpacked bytes. */
        uint8_t h[32], *raw = NULL;
        size_t rawlen = 0;
        CHECK(proto_guide_unpack(ch.data, ch.len, &raw, &rawlen, NULL) == PT_OK && rawlen > ch.len);
        pt_sha256(raw, rawlen, h);
        CHECK(memcmp(h, t.guide_hash, 32) == 0);
        pt_guide *gd = NULL;
        CHECK(proto_guide_decode(raw, rawlen, &gd, NULL) == PT_OK);
        pt_free(raw);
        if (gd) {
            nsn = gd->nsnode;
            nqn = gd->nqnode;
        }
        pt_guide_free(gd);
    }
    uint32_t npx = (t.tile.x1 - t.tile.x0) * (t.tile.y1 - t.tile.y0), n = t.s1 - t.s0;
    static pt_pixel_acc px[PROTO_MAX_TILE_PIXELS];
    for (uint32_t i = 0; i < npx; i++)
        px[i] = pt_pixel_acc_of(0.5, 0.5, 0.5, 0.25, n, n);
    proto_guide_entry e[2] = {{0, 100}, {7, 1000}};
    proto_result r = {0};
    r.job_id = t.job_id;
    r.task_id = t.task_id;
    r.tile = t.tile;
    r.s0 = t.s0;
    r.s1 = t.s1;
    r.npixels = npx;
    r.pixels = px;
    r.g_nsnode = nsn;
    r.g_nqnode = nqn;
    r.gcount = 1;
    r.gsum = 1;
    r.guide = e;
    if (k == 0) {
        r.guide = NULL; /* none */
    } else if (k == 1) {
        r.g_nqnode = nqn + 4; /* another guide's size */
    } else if (k == 2) {
        e[0].value = (uint64_t)npx * n * 2000; /* records: far over one per bounce */
    } else {
        e[1].value = UINT64_MAX / 2; /* a sum no 100 records can make */
    }
    proto_writer_reset(&p);
    CHECK(proto_msg_encode_result(&p, &r, NULL) == PT_OK);
    send_frame(fd, PROTO_MSG_RESULT, &p);
    proto_writer_fini(&p);
    int error = read_frame(fd, buf, sizeof buf, &f) == PROTO_MSG_ERROR;
    int closed = closed_by_server(fd, 3000);
    close(fd);
    return error && closed;
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_farm_guide_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    struct stat sb;
    if (stat(SCENE, &sb) != 0) {
        CHECK_SKIP("shared scenes not found (%s)", SCENE);
        CHECK(!check_shared_required());
        int rc = check_report();
        pt_remove_tree(tmp);
        return rc;
    }
    FILE *tf = fopen(path("token"), "w");
    CHECK(tf != NULL);
    if (tf) {
        fputs(TOKEN "\n", tf);
        fclose(tf);
    }
    chmod(path("token"), 0600);
    const char *serve[] = {PT_BIN_DIR "/ptserve",
                           "--listen",
                           "127.0.0.1:0",
                           "--port-file",
                           path("port"),
                           "--token-file",
                           path("token"),
                           COMMON,
                           "--spp",
                           "64",
                           "-o",
                           path("farm.exr"),
                           "--verify-fraction",
                           "0",
                           SCENE,
                           NULL};
    pid_t srv = spawn(serve, "serve.log");
    int port = read_port();
    CHECK(port > 0);
    for (int k = 0; port > 0 && k < 4; k++)
        CHECKF(hostile_result(port, k), "hostile statistics %d were not refused", k);
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *worker[] = {PT_BIN_DIR "/ptworker", "--server",    server,   "--threads", "2",
                            "--token-file",         path("token"), "--name", "honest",    NULL};
    pid_t w = spawn(worker, "worker.log");
    int status = wait_exit(srv, 300);
    kill(w, SIGTERM);
    wait_exit(w, 10);
    CHECKF(status == 0, "ptserve exit status %d", status);
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "64", "-o",
                         path("ref.exr"),        "-q",      NULL};
    CHECK(run(ref, "ref.log", 120) == 0);
    CHECKF(same_pixels("ref.exr", "farm.exr"), "hostile statistics changed the image");
    const char *reasons[] = {"lacks the guiding statistics", "guiding statistics for",
                             "not a plausible render"};
    for (size_t i = 0; i < sizeof reasons / sizeof *reasons; i++)
        CHECKF(log_has("serve.log", reasons[i]), "no logged reason containing '%s'", reasons[i]);
    return farm_test_end();
}
