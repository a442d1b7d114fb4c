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
 *
 * The honest ptworker talks to ptserve through a relay of ours that
 * forwards every byte and reads the frames: the tasks of the job's last
 * pass (it runs to spp; no distribution is built from it) say so
 * (PROTO_GUIDE_LAST), the earlier passes' PROTO_GUIDE_RECORD; the worker's
 * results carry statistics for the earlier passes and none for the last.
 * Once the last pass is leased, one more hostile worker answers a task of
 * it with plausible statistics of the right sizes: refused as well.
 */
#include <math.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/image/image.h"
#include "common/render/guide.h"
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
    if (k < 4)
        CHECK(got && t.guided == PROTO_GUIDE_RECORD && t.guide_pass == 0);
    else
        CHECKF(got && t.guided == PROTO_GUIDE_LAST && t.guide_pass == 1,
               "a task of the last pass: guided %u, pass %u", got ? t.guided : 0,
               got ? t.guide_pass : 0);
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
    } else if (k == 3) {
        e[1].value = UINT64_MAX / 2; /* a sum no 100 records can make */
    } /* else plausible statistics of the right sizes, but of the last pass */
    proto_writer_reset(&p);
    CHECK(proto_msg_encode_result(&p, &r, NULL) == PT_OK);
    send_frame(fd, PROTO_MSG_RESULT, &p);
    proto_writer_fini(&p);
    int error = read_frame(fd, buf, sizeof buf, &f) == PROTO_MSG_ERROR;
    int closed = closed_by_server(fd, 3000);
    close(fd);
    return error && closed;
}

/* ---- a relay that watches the honest worker ---- */

#define RELAY_CAP (4u << 20) /* a frame of a scene's or a guide's chunk fits */
#define MAX_SEEN 4096u
#define SPP 64u

/* What the relay saw: each TASK's guiding flag and whether its pass is the
 * job's last; each RESULT's statistics by its task's pass. */
typedef struct seen {
    uint64_t id[MAX_SEEN];
    uint8_t last[MAX_SEEN];
    uint32_t ntasks;
    uint32_t record_tasks, last_tasks, misflagged;
    uint32_t record_with, record_without, last_with, last_without, unknown;
    int hostile_due; /* a task of the last pass went by: time for hostile case 4 */
} seen;

static void watch_task(seen *sn, const proto_frame *f)
{
    proto_task t;
    if (proto_msg_decode_task(f->payload, f->len, &t, NULL) != PT_OK || sn->ntasks == MAX_SEEN) {
        sn->misflagged++;
        return;
    }
    int last = t.guided && pt_guide_pass_end(t.guide_pass, SPP) == SPP;
    sn->id[sn->ntasks] = t.task_id;
    sn->last[sn->ntasks++] = (uint8_t)last;
    sn->record_tasks += t.guided == PROTO_GUIDE_RECORD;
    sn->last_tasks += t.guided == PROTO_GUIDE_LAST;
    sn->misflagged += t.guided != (last ? PROTO_GUIDE_LAST : PROTO_GUIDE_RECORD);
    if (last && sn->hostile_due == 0)
        sn->hostile_due = 1;
}

static void watch_result(seen *sn, const proto_frame *f)
{
    proto_result r;
    if (proto_msg_decode_result(f->payload, f->len, NULL, 0, &r, NULL) != PT_OK) {
        sn->unknown++;
        return;
    }
    uint32_t i = 0;
    while (i < sn->ntasks && sn->id[i] != r.task_id)
        i++;
    if (i == sn->ntasks)
        sn->unknown++;
    else if (sn->last[i])
        ++*(r.guide ? &sn->last_with : &sn->last_without);
    else
        ++*(r.guide ? &sn->record_with : &sn->record_without);
    proto_result_fini(&r);
}

/* Relays bytes between the worker (wfd) and ptserve (sfd) until either
 * closes or timeout seconds pass, reading the frames as they go by; runs
 * hostile case 4 against port once a task of the last pass went by. */
static void relay(int wfd, int sfd, int port, seen *sn, double timeout)
{
    int fds[2] = {wfd, sfd};
    uint8_t *buf[2] = {malloc(RELAY_CAP), malloc(RELAY_CAP)};
    size_t len[2] = {0, 0};
    double end = pt_now_s() + timeout;
    int open = buf[0] && buf[1];
    CHECK(open);
    while (open && pt_now_s() < end) {
        struct pollfd p[2] = {{wfd, POLLIN, 0}, {sfd, POLLIN, 0}};
        if (poll(p, 2, 100) <= 0)
            continue;
        for (int i = 0; open && i < 2; i++) {
            if (!(p[i].revents & (POLLIN | POLLHUP | POLLERR)))
                continue;
            ssize_t n = recv(fds[i], buf[i] + len[i], RELAY_CAP - len[i], 0);
            if (n <= 0 || pt_net_write_all(fds[1 - i], buf[i] + len[i], (size_t)n, NULL) != PT_OK) {
                open = 0;
                break;
            }
            len[i] += (size_t)n;
            proto_frame f;
            size_t used;
            while (proto_frame_decode(buf[i], len[i], PROTO_MAX_PAYLOAD, &f, &used, NULL) ==
                   PT_OK) {
                if (i == 1 && f.type == PROTO_MSG_TASK)
                    watch_task(sn, &f);
                else if (i == 0 && f.type == PROTO_MSG_RESULT)
                    watch_result(sn, &f);
                memmove(buf[i], buf[i] + used, len[i] - used);
                len[i] -= used;
            }
            CHECKF(len[i] < RELAY_CAP, "the relay found no frame in %u bytes", RELAY_CAP);
            if (len[i] == RELAY_CAP)
                open = 0;
        }
        if (sn->hostile_due == 1) {
            sn->hostile_due = 2;
            CHECKF(hostile_result(port, 4), "statistics of the last pass were not refused");
        }
    }
    free(buf[0]);
    free(buf[1]);
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
                           "64", /* SPP */
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
    /* The honest worker, through the relay. */
    int lfd = -1;
    uint16_t rport = 0;
    pt_error err = {0};
    CHECKF(pt_net_listen("127.0.0.1", 0, &lfd, &rport, &err) == PT_OK, "%s", err.msg);
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%u", rport);
    const char *worker[] = {PT_BIN_DIR "/ptworker", "--server",    server,   "--threads", "2",
                            "--token-file",         path("token"), "--name", "honest",    NULL};
    pid_t w = spawn(worker, "worker.log");
    struct pollfd lp = {lfd, POLLIN, 0};
    int wfd = lfd >= 0 && poll(&lp, 1, 30000) == 1 ? accept(lfd, NULL, NULL) : -1;
    int sfd = wfd >= 0 && port > 0 ? connect_to(port) : -1;
    CHECK(wfd >= 0 && sfd >= 0);
    static seen sn;
    if (wfd >= 0 && sfd >= 0)
        relay(wfd, sfd, port, &sn, 300);
    int status = wait_exit(srv, 30);
    if (wfd >= 0)
        close(wfd);
    if (sfd >= 0)
        close(sfd);
    if (lfd >= 0)
        close(lfd);
    kill(w, SIGTERM);
    wait_exit(w, 10);
    CHECKF(sn.hostile_due == 2, "no task of the last pass went by");
    CHECKF(sn.record_tasks > 0 && sn.last_tasks > 0 && sn.misflagged == 0,
           "tasks: %u recording, %u of the last pass, %u flagged otherwise", sn.record_tasks,
           sn.last_tasks, sn.misflagged);
    CHECKF(sn.record_with > 0 && sn.record_without == 0 && sn.last_without > 0 &&
               sn.last_with == 0 && sn.unknown == 0,
           "results with and without statistics: %u and %u recording, %u and %u of the last "
           "pass, %u not of a task seen",
           sn.record_with, sn.record_without, sn.last_with, sn.last_without, sn.unknown);
    CHECKF(status == 0, "ptserve exit status %d", status);
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "64", "-o",
                         path("ref.exr"),        "-q",      NULL};
    CHECK(run(ref, "ref.log", 120) == 0);
    CHECKF(same_pixels("ref.exr", "farm.exr"), "hostile statistics changed the image");
    const char *reasons[] = {"lacks the guiding statistics", "guiding statistics for",
                             "not a plausible render", "is the job's last and records none"};
    for (size_t i = 0; i < sizeof reasons / sizeof *reasons; i++)
        CHECKF(log_has("serve.log", reasons[i]), "no logged reason containing '%s'", reasons[i]);
    return farm_test_end();
}
