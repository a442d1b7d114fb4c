/*
 * test_job.c - the coordinator's job model without sockets: pass order,
 * leases and their expiry, requeue on a lost worker, idempotent merging,
 * bit-identical films whatever order results arrive in, and time-sized
 * tasks (sizes by owner speed, the tail, fixed chunks, any cut merging to
 * the same film, with adaptive sampling and a resume too).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "protocol/guide.h"
#include "server/sched/job.h"
#include "tests/check.h"

static const uint8_t HASH[32] = {1, 2, 3};

/* Deterministic synthetic pixels for a task (same task, same bits). */
static void fake_result(const proto_task *t, pt_pixel_acc *px, proto_result *r)
{
    uint32_t n = (t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
    uint64_t h = t->task_id * 0x9E3779B97F4A7C15ull + 1;
    for (uint32_t i = 0; i < n; i++) {
        h ^= h >> 33;
        h *= 0xff51afd7ed558ccdull;
        double v = (double)(h >> 11) / 9007199254740992.0;
        px[i] = pt_pixel_acc_of(v, v * 0.5, v * 1e-7, v * v, t->s1 - t->s0, 0);
    }
    memset(r, 0, sizeof *r);
    r->job_id = t->job_id;
    r->task_id = t->task_id;
    r->tile = t->tile;
    r->s0 = t->s0;
    r->s1 = t->s1;
    r->npixels = n;
    r->pixels = px;
}

static srv_job *make(uint32_t w, uint32_t h, uint32_t spp, uint32_t tile, uint32_t chunk)
{
    srv_job_params p = {
        w, h,  spp,    tile,   chunk, 5,  16, 3, 0.0, 0, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0, "", {0, 0}, {0, 0}, 0,     {0}};
    srv_job *j = NULL;
    pt_error err = {0};
    CHECKF(srv_job_new(9, &p, HASH, &j, &err) == PT_OK, "%s", err.msg);
    return j;
}

static void pass_order(void)
{
    srv_job *j = make(70, 40, 40, 32, 16); /* 3x2 tiles, chunks 16,16,8 */
    CHECK(srv_job_passes(j) == 3);
    CHECK(srv_job_tasks_total(j) == 18);
    proto_task t;
    for (uint32_t i = 0; i < 18; i++) {
        CHECK(srv_job_lease(j, 1, 0, 1000, &t) == 1);
        CHECK(t.task_id == i);
        CHECK(t.s0 == 16 * (i / 6));
    }
    CHECK(t.s1 == 40 && t.tile.x1 == 70 && t.tile.y1 == 40 && t.tile.x0 == 64);
    CHECK(srv_job_lease(j, 1, 0, 1000, &t) == 0);
    CHECK(srv_job_tasks_total(j) == 18);
    CHECK(srv_job_tasks_merged(j) == 0);
    CHECK(memcmp(t.scene_hash, HASH, 32) == 0 && t.width == 70 && t.seed == 5);
    srv_job_free(j);
}

static void leases(void)
{
    srv_job *j = make(64, 64, 32, 32, 16);
    proto_task a, b, c;
    srv_job_lease(j, 1, 0, 100, &a);
    srv_job_lease(j, 2, 0, 100, &b);
    /* Heartbeat keeps owner 1's lease; owner 2's expires. */
    srv_job_heartbeat(j, 1, a.task_id, 90, 100);
    srv_job_heartbeat(j, 1, b.task_id, 90, 100); /* not its lease: ignored */
    CHECK(srv_job_expire(j, 150, NULL, NULL, NULL) == 1);
    CHECK(srv_job_leases(j) == 1);
    /* The requeued task is handed out before new ones. */
    CHECK(srv_job_lease(j, 3, 150, 100, &c) == 1 && c.task_id == b.task_id);
    /* A lost owner's tasks come back too. */
    CHECK(srv_job_release_owner(j, 3) == 1);
    CHECK(srv_job_lease(j, 4, 150, 100, &c) == 1 && c.task_id == b.task_id);

    pt_pixel_acc px[1024];
    proto_result r;
    pt_error err = {0};
    fake_result(&a, px, &r);
    CHECK(srv_job_result(j, 2, &r, &err) == SRV_NOT_LEASED); /* never leased to 2 */
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_DUPLICATE);
    fake_result(&c, px, &r);
    r.s1++;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_INVALID);
    r.s1--;
    px[3].fsum[1] = -1; /* negative */
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_INVALID && strstr(err.msg, "pixel 3"));
    fake_result(&c, px, &r);
    px[0].n = 17;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_INVALID);
    fake_result(&c, px, &r);
    r.npixels--;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_INVALID);
    r.npixels++;
    r.task_id = 1000;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_INVALID);
    r.task_id = c.task_id;
    r.job_id = 3;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_NOT_LEASED);
    r.job_id = c.job_id;
    CHECK(srv_job_result(j, 4, &r, &err) == SRV_MERGED);
    srv_job_free(j);
}

/* Completes a job with results arriving in an order given by a seed;
 * returns the film's pixels (caller frees). */
static pt_pixel_acc *complete(uint32_t seed, int owners)
{
    srv_job *j = make(50, 30, 64, 16, 16);
    uint64_t total = (uint64_t)srv_job_tiles(j) * srv_job_passes(j);
    proto_task *tasks = calloc(total, sizeof *tasks);
    uint64_t n = 0;
    int guard = 0;
    srand(seed);
    while (!srv_job_complete(j) && guard++ < 100000) {
        /* Lease a few, then return a random one of those outstanding. */
        for (int k = 0; k < 1 + rand() % 4; k++) {
            proto_task t;
            if (srv_job_lease(j, (uint64_t)(rand() % owners), 0, 1000, &t))
                tasks[n++] = t;
        }
        if (n == 0)
            continue;
        uint64_t pick = (uint64_t)rand() % n;
        proto_task t = tasks[pick];
        tasks[pick] = tasks[--n];
        if (rand() % 10 == 0) {
            /* Every worker vanished: their tasks come back and are leased again. */
            for (int o = 0; o < owners; o++)
                srv_job_release_owner(j, (uint64_t)o);
            n = 0;
            continue;
        }
        pt_pixel_acc px[256];
        proto_result r;
        fake_result(&t, px, &r);
        uint64_t owner_guess;
        srv_outcome o = SRV_NOT_LEASED;
        for (owner_guess = 0; owner_guess < (uint64_t)owners && o == SRV_NOT_LEASED; owner_guess++)
            o = srv_job_result(j, owner_guess, &r, NULL);
        CHECK(o == SRV_MERGED);
    }
    CHECK(srv_job_complete(j));
    CHECK(srv_job_passes_done(j) == srv_job_passes(j));
    CHECK(srv_job_samples_merged(j) == 50ull * 30 * 64);
    const pt_film *f = srv_job_film(j);
    pt_pixel_acc *out = malloc(50 * 30 * sizeof *out);
    memcpy(out, f->px, 50 * 30 * sizeof *out);
    free(tasks);
    srv_job_free(j);
    return out;
}

static void bit_identical(void)
{
    pt_pixel_acc *a = complete(1, 1);
    int same = 1;
    for (uint32_t s = 2; s < 8; s++) {
        pt_pixel_acc *b = complete(s, 1 + (int)s % 4);
        same &= memcmp(a, b, 50 * 30 * sizeof *a) == 0;
        free(b);
    }
    CHECKF(same, "arrival order changed the film");
    int exact = 1;
    for (uint32_t i = 0; i < 50 * 30; i++)
        exact &= a[i].n == 64;
    CHECK(exact);
    free(a);
}

/* Adaptive sampling: tiles whose pixels have no variance stop after min_spp;
 * a noisy tile goes on to the end; tasks of a stopped tile that were already
 * leased or held are dropped harmlessly. */
static void adaptive(void)
{
    srv_job_params p = {
        64, 32, 64,     32,     8, 1,  16, 3, 0.01, 16, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0,  "", {0, 0}, {0, 0}, 0, {0}};
    srv_job *j = NULL;
    CHECK(srv_job_new(2, &p, HASH, &j, NULL) == PT_OK);
    if (!j)
        return;
    /* Tile 0: constant pixels (error 0). Tile 1: alternating values (noisy). */
    pt_pixel_acc px[1024];
    proto_task t;
    proto_task leased[64];
    int n = 0;
    while (srv_job_lease(j, 1, 0, 1000, &t))
        leased[n++] = t;
    CHECK(n == 16);
    int dup = 0;
    for (int k = n - 1; k >= 0; k--) { /* arrival in reverse: everything is held first */
        t = leased[k];
        uint32_t np = 32 * 32, ns = t.s1 - t.s0;
        int tile = (int)(t.task_id % 2);
        for (uint32_t i = 0; i < np; i++) {
            double v = tile == 0 ? 0.5 : ((i + t.task_id) % 2 ? 1.0 : 0.0);
            /* ns samples of value v (tile 0), or half 0 and half 2v (tile 1). */
            double sum = tile == 0 ? v * ns : v * ns;
            double sq = tile == 0 ? ns * 0.25 : 2.0 * v * v * ns;
            px[i] = pt_pixel_acc_of(sum, sum, sum, sq, ns, 0);
        }
        proto_result r = {t.job_id, t.task_id, t.tile, t.s0, t.s1, 0, 0,    0, 32 * 32, px,
                          0,        NULL,      0,      0,    0,    0, NULL, 0, 0};
        srv_outcome o = srv_job_result(j, 1, &r, NULL);
        dup += o == SRV_DUPLICATE;
        CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
    }
    CHECK(srv_job_complete(j));
    CHECK(srv_job_tiles_stopped(j) == 1);
    CHECK(dup == 0); /* held chunks of the stopped tile were dropped before their turn */
    const pt_film *f = srv_job_film(j);
    CHECK(f->px[0].n == 16);  /* tile 0: stopped at min_spp */
    CHECK(f->px[32].n == 64); /* tile 1: all chunks */
    CHECK(srv_job_samples_merged(j) == 32ull * 32 * 16 + 32ull * 32 * 64);
    CHECK(srv_job_passes_done(j) == srv_job_passes(j));
    srv_job_free(j);
}

/* Pixels for the min-gain test: tile 0 constant (each chunk agrees with the
 * past: nothing to gain; black with black0), tile 1 alternating 1 and 0 chunk
 * by chunk (a chunk always differs from the past by about 0.5). */
static void gain_pixels_of(const proto_task *t, pt_pixel_acc *px, proto_result *r, int black0)
{
    uint32_t ns = t->s1 - t->s0, chunk = t->s0 / 8;
    for (uint32_t i = 0; i < 32 * 32; i++) {
        double v = t->tile.x0 == 0 ? (black0 ? 0.0 : 0.5) : (double)((chunk + 1) % 2);
        px[i] = pt_pixel_acc_of(v * ns, v * ns, v * ns, v * v * ns, ns, 0);
    }
    *r = (proto_result){t->job_id, t->task_id, t->tile, t->s0, t->s1, 0, 0,    0, 32 * 32, px,
                        0,         NULL,       0,       0,     0,     0, NULL, 0, 0};
}

/* A pixel of a version 5 checkpoint (72 bytes: sums as u64 pairs, low half
 * first, n, hits) as version 4 wrote it (40 bytes: f64 sums, n, hits). */
static void put_old_pixel(proto_writer *o, const uint8_t *q)
{
    for (int c = 0; c < 3; c++)
        proto_w_f64(o, pt_fixed_to_double((pt_i128)(((pt_u128)proto_get_u64(q + 16 * c + 8) << 64) |
                                                    proto_get_u64(q + 16 * c))));
    proto_w_f64(
        o, pt_ufixed_to_double(((pt_u128)proto_get_u64(q + 56) << 64) | proto_get_u64(q + 48)));
    proto_w_u32(o, proto_get_u32(q + 64));
    proto_w_u32(o, proto_get_u32(q + 68));
}

static void gain_pixels(const proto_task *t, pt_pixel_acc *px, proto_result *r)
{
    gain_pixels_of(t, px, r, 0);
}

/* The minimum-mean-error rule in the coordinator: the quiet tile stops at the
 * second chunk (the first the rule can judge, as it is not black), the noisy
 * one runs to the end; a checkpoint taken midway resumes to the same bits, and
 * refuses a job with another min gain. */
static void adaptive_min_gain(void)
{
    srv_job_params p = {
        64, 32, 64,     32,     8, 1,  16, 3, 0.0, 8, 1e-5, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0,  "", {0, 0}, {0, 0}, 0, {0}};
    srv_job *a = NULL, *b = NULL, *c = NULL, *d = NULL;
    CHECK(srv_job_new(3, &p, HASH, &a, NULL) == PT_OK);
    CHECK(srv_job_new(3, &p, HASH, &b, NULL) == PT_OK);
    if (!a || !b)
        goto done;
    static pt_pixel_acc px[32 * 32];
    proto_task t;
    proto_result r;
    while (srv_job_lease(a, 1, 0, 1000, &t)) {
        gain_pixels(&t, px, &r);
        CHECK(srv_job_result(a, 1, &r, NULL) == SRV_MERGED);
    }
    CHECK(srv_job_complete(a));
    CHECK(srv_job_tiles_stopped(a) == 1);
    const pt_film *f = srv_job_film(a);
    CHECK(f->px[0].n == 16 && f->px[32].n == 64);

    /* The same job, saved after 5 results and resumed in another. */
    proto_task tasks[16];
    int n = 0;
    while (n < 16 && srv_job_lease(b, 1, 0, 1000, &tasks[n]))
        n++;
    for (int k = 0; k < 5 && k < n; k++) { /* the 5th is of tile 0, stopped by then */
        gain_pixels(&tasks[k], px, &r);
        CHECK(srv_job_result(b, 1, &r, NULL) == (k < 4 ? SRV_MERGED : SRV_DUPLICATE));
    }
    proto_writer w;
    proto_writer_init(&w, 1u << 20);
    CHECK(srv_job_save(b, &w, NULL) == PT_OK);
    CHECK(srv_job_new(3, &p, HASH, &c, NULL) == PT_OK);
    CHECK(c && srv_job_load(c, w.buf, w.len, NULL) == PT_OK);
    for (int k = 5; c && k < n; k++) {
        gain_pixels(&tasks[k], px, &r);
        srv_outcome o = srv_job_replay(c, &r, NULL);
        CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
    }
    CHECK(c && srv_job_complete(c));
    const pt_film *g = c ? srv_job_film(c) : NULL;
    CHECK(g && memcmp(f->px, g->px, 64 * 32 * sizeof *f->px) == 0);
    srv_job_params q = p;
    q.min_gain = 2e-5;
    pt_error err = {0};
    CHECK(srv_job_new(3, &q, HASH, &d, NULL) == PT_OK);
    CHECK(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT);
    srv_job_free(d);
    d = NULL;
    /* Another environment is another job too: a map, or a turned one. */
    q = p;
    snprintf(q.env.name, sizeof q.env.name, ".ptfarm/environment");
    CHECK(srv_job_new(3, &q, HASH, &d, NULL) == PT_OK);
    CHECK(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT);
    srv_job_free(d);
    d = NULL;
    q = p;
    q.env.rotate_deg = 1.0f;
    CHECK(srv_job_new(3, &q, HASH, &d, NULL) == PT_OK);
    CHECK(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT);
    srv_job_free(d);
    d = NULL;
    /* So is another material variant; the same one resumes. */
    q = p;
    snprintf(q.variant, sizeof q.variant, "Peacock Velvet");
    CHECK(srv_job_new(3, &q, HASH, &d, NULL) == PT_OK);
    CHECKF(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT, "%s", err.msg);
    {
        srv_job *e = NULL;
        proto_writer wv;
        proto_writer_init(&wv, 1u << 20);
        CHECK(d && srv_job_save(d, &wv, NULL) == PT_OK);
        CHECK(srv_job_new(3, &q, HASH, &e, NULL) == PT_OK);
        CHECKF(e && srv_job_load(e, wv.buf, wv.len, &err) == PT_OK, "%s", err.msg);
        proto_task vt;
        CHECK(e && srv_job_lease(e, 1, 0, 1000, &vt) && strcmp(vt.variant, "Peacock Velvet") == 0);
        srv_job_free(e);
        proto_writer_fini(&wv);
    }
    srv_job_free(d);
    d = NULL;
    /* So are other clamps, and a clamped job's checkpoint resumes with its
     * clamps in every task. */
    q = p;
    q.clamp[1] = 10.0f;
    CHECK(srv_job_new(3, &q, HASH, &d, NULL) == PT_OK);
    CHECKF(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT, "%s", err.msg);
    {
        srv_job *e = NULL;
        proto_writer wc;
        proto_writer_init(&wc, 1u << 20);
        CHECK(d && srv_job_save(d, &wc, NULL) == PT_OK);
        CHECK(srv_job_new(3, &q, HASH, &e, NULL) == PT_OK);
        CHECKF(e && srv_job_load(e, wc.buf, wc.len, &err) == PT_OK, "%s", err.msg);
        proto_task ct;
        CHECK(e && srv_job_lease(e, 1, 0, 1000, &ct) && ct.clamp[0] == 0.0f &&
              ct.clamp[1] == 10.0f);
        srv_job_free(e);
        proto_writer_fini(&wc);
    }
    srv_job_free(d);
    d = NULL;
    /* The params end with the shutter (16 bytes), which formats before 7
     * lack, and the clamps and guiding (8 + 25), which formats before 9 lack. */
    const size_t pend = 4 + 4 + 8 + 32 + 9 * 4 + 2 * 8 + 2 + strlen(p.camera) + 23 + 4 + 2;
    const size_t head = pend + 49 + 8;
    /* Format 10 put the contributions clamped after the depth-cap count; the
     * older formats below are built from a version 9 checkpoint, the same
     * bytes without it, which loads to the same bits. */
    proto_writer w9;
    proto_writer_init(&w9, 1u << 20);
    proto_w_bytes(&w9, w.buf, head);
    proto_w_bytes(&w9, w.buf + head + 8, w.len - head - 8);
    proto_put_u32(w9.buf + 4, 9);
    {
        srv_job *e = NULL;
        CHECK(proto_writer_status(&w9) == PT_OK);
        CHECK(srv_job_new(3, &p, HASH, &e, NULL) == PT_OK);
        CHECKF(e && srv_job_load(e, w9.buf, w9.len, &err) == PT_OK, "%s", err.msg);
        CHECK(e && memcmp(srv_job_film(e)->px, srv_job_film(b)->px, 64 * 32 * sizeof *f->px) == 0);
        srv_job_free(e);
    }
    /* A version 6 checkpoint (time-sized tasks, no shutter: the same bytes
     * without it) loads to the same bits. */
    {
        proto_writer v6;
        proto_writer_init(&v6, 1u << 20);
        proto_w_bytes(&v6, w9.buf, pend);
        proto_w_bytes(&v6, w9.buf + pend + 49, w9.len - pend - 49);
        proto_put_u32(v6.buf + 4, 6);
        srv_job *e = NULL;
        CHECK(proto_writer_status(&v6) == PT_OK);
        CHECK(srv_job_new(3, &p, HASH, &e, NULL) == PT_OK);
        CHECKF(e && srv_job_load(e, v6.buf, v6.len, &err) == PT_OK, "%s", err.msg);
        CHECK(e && memcmp(srv_job_film(e)->px, srv_job_film(b)->px, 64 * 32 * sizeof *f->px) == 0);
        srv_job_free(e);
        proto_writer_fini(&v6);
    }
    /* A version 5 checkpoint (fixed-point sums, fixed chunks: each tile's
     * chunks merged, held results by task id; no shutter) loads to the same
     * bits and resumes to the same image: a state folder from before
     * time-sized tasks goes on. */
    {
        proto_writer v5;
        proto_writer_init(&v5, 1u << 20);
        uint32_t ntiles = proto_get_u32(w9.buf + head);
        size_t at = head + 8;
        proto_w_bytes(&v5, w9.buf, pend);
        proto_w_bytes(&v5, w9.buf + pend + 49, at - pend - 49);
        proto_put_u32(v5.buf + 4, 5);
        for (uint32_t ti = 0; ti < ntiles; ti++, at += 5) {
            proto_w_u32(&v5, proto_get_u32(w9.buf + at) / 8);
            proto_w_u8(&v5, w9.buf[at + 4]);
        }
        uint32_t nheld = proto_get_u32(w9.buf + at);
        proto_w_u32(&v5, nheld);
        at += 4;
        for (uint32_t i = 0; i < nheld; i++) {
            uint32_t tile = proto_get_u32(w9.buf + at), s0 = proto_get_u32(w9.buf + at + 4);
            proto_w_u64(&v5, (uint64_t)(s0 / 8) * ntiles + tile); /* task id */
            at += 12;
            proto_w_bytes(&v5, w9.buf + at, 32 * 32 * 72);
            at += 32 * 32 * 72;
        }
        proto_w_bytes(&v5, w9.buf + at, w9.len - at);
        srv_job *e = NULL;
        CHECK(proto_writer_status(&v5) == PT_OK);
        CHECK(srv_job_new(3, &p, HASH, &e, NULL) == PT_OK);
        CHECKF(e && srv_job_load(e, v5.buf, v5.len, &err) == PT_OK, "%s", err.msg);
        CHECK(e && memcmp(srv_job_film(e)->px, srv_job_film(b)->px, 64 * 32 * sizeof *f->px) == 0);
        for (int k = 5; e && k < n; k++) {
            gain_pixels(&tasks[k], px, &r);
            srv_outcome o = srv_job_replay(e, &r, NULL);
            CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
        }
        CHECK(e && srv_job_complete(e) &&
              memcmp(f->px, srv_job_film(e)->px, 64 * 32 * sizeof *f->px) == 0);
        srv_job_free(e);
        proto_writer_fini(&v5);
    }
    /* A version 4 checkpoint (before fixed-point sums and the shutter: the
     * same bytes without the shutter and with each pixel's four sums as f64) loads to the same
     * bits: sums of whole multiples of 2^-32 this small are exact in double, and the conversion
     * rounds to nearest. */
    proto_writer v4;
    proto_writer_init(&v4, 1u << 20);
    {
        /* Format 6 counts a tile's samples merged and names a held result by
         * its tile and samples; older ones count chunks (8 samples here) and
         * name the task, chunk x tiles + tile. */
        uint32_t ntiles = proto_get_u32(w9.buf + head);
        size_t at = head + 8;
        proto_w_bytes(&v4, w9.buf, pend); /* without the shutter and the clamps */
        proto_w_bytes(&v4, w9.buf + pend + 49, at - pend - 49);
        proto_put_u32(v4.buf + 4, 4);
        for (uint32_t ti = 0; ti < ntiles; ti++, at += 5) {
            proto_w_u32(&v4, proto_get_u32(w9.buf + at) / 8);
            proto_w_u8(&v4, w9.buf[at + 4]);
        }
        uint32_t nheld = proto_get_u32(w9.buf + at);
        proto_w_u32(&v4, nheld);
        at += 4;
        for (uint32_t i = 0; i <= nheld && at < w9.len; i++) {
            size_t npx = i < nheld ? 32 * 32 : 64 * 32; /* held tiles, then the film */
            if (i < nheld) {
                uint32_t tile = proto_get_u32(w9.buf + at), s0 = proto_get_u32(w9.buf + at + 4);
                proto_w_u64(&v4, (uint64_t)(s0 / 8) * ntiles + tile); /* task id */
                at += 12;
            }
            for (size_t k = 0; k < npx; k++, at += 72)
                put_old_pixel(&v4, w9.buf + at);
        }
        CHECK(at == w9.len && proto_writer_status(&v4) == PT_OK);
    }
    srv_job_free(d);
    d = NULL;
    CHECK(srv_job_new(3, &p, HASH, &d, NULL) == PT_OK);
    CHECKF(d && srv_job_load(d, v4.buf, v4.len, &err) == PT_OK, "%s", err.msg);
    const pt_film *fb = srv_job_film(b);
    CHECK(d && memcmp(srv_job_film(d)->px, fb->px, 64 * 32 * sizeof *fb->px) == 0);
    /* ... and resumes to the same image as the uninterrupted job. */
    for (int k = 5; d && k < n; k++) {
        gain_pixels(&tasks[k], px, &r);
        srv_outcome o = srv_job_replay(d, &r, NULL);
        CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
    }
    CHECK(d && srv_job_complete(d) &&
          memcmp(f->px, srv_job_film(d)->px, 64 * 32 * sizeof *f->px) == 0);
    /* A double sum that no render gives (negative) is refused. */
    {
        proto_writer bad;
        proto_writer_init(&bad, 1u << 20);
        proto_w_bytes(&bad, v4.buf, v4.len);
        proto_put_f64(bad.buf + bad.len - 40 * 3, -1.0); /* a film pixel's R */
        srv_job *e = NULL;
        CHECK(srv_job_new(3, &p, HASH, &e, NULL) == PT_OK);
        CHECK(e && srv_job_load(e, bad.buf, bad.len, &err) == PT_ERR_FORMAT);
        srv_job_free(e);
        proto_writer_fini(&bad);
    }
    srv_job_free(d);
    d = NULL;
    /* A version 3 checkpoint (before the environment and the film flags: the
     * same bytes less the ENV block, the film flags, the variant, the shutter
     * and the depth-cap count after the camera, and 36-byte pixels, without the camera hits) loads
     * as a job with no environment and an opaque film. */
    size_t at = 4 + 4 + 8 + 32 + 9 * 4 + 2 * 8 + 2 + strlen(p.camera);
    proto_writer v3;
    proto_writer_init(&v3, 1u << 20);
    proto_w_bytes(&v3, v4.buf, at);
    proto_put_u32(v3.buf + 4, 3);
    at += 23 + 4 + 2 + 8;
    uint32_t ntiles = proto_get_u32(v4.buf + at);
    proto_w_bytes(&v3, v4.buf + at, 8 + (size_t)ntiles * 5 + 4);
    at += 8 + (size_t)ntiles * 5;
    uint32_t nheld = proto_get_u32(v4.buf + at);
    at += 4;
    for (uint32_t i = 0; i <= nheld && at < v4.len; i++) {
        size_t npx = i < nheld ? 32 * 32 : 64 * 32; /* held tiles, then the film */
        if (i < nheld) {
            proto_w_bytes(&v3, v4.buf + at, 8); /* task id */
            at += 8;
        }
        for (size_t k = 0; k < npx; k++, at += 40)
            proto_w_bytes(&v3, v4.buf + at, 36);
    }
    CHECK(at == v4.len && proto_writer_status(&v3) == PT_OK);
    CHECK(srv_job_new(3, &p, HASH, &d, NULL) == PT_OK);
    CHECKF(d && srv_job_load(d, v3.buf, v3.len, &err) == PT_OK, "%s", err.msg);
    const pt_film *h = d ? srv_job_film(d) : NULL;
    CHECK(h && h->px[0].n > 0 && h->px[0].hits == h->px[0].n); /* read as fully covered */
    proto_writer_fini(&v3);
    proto_writer_fini(&v4);
    proto_writer_fini(&w9);
    proto_writer_fini(&w);
done:
    srv_job_free(a);
    srv_job_free(b);
    srv_job_free(c);
    srv_job_free(d);
}

/* A tile whose samples are all exactly 0 (black background) stops after its
 * first chunk when min_spp allows it (pt_tile_gain counts it 0 from the
 * first chunk); the noisy tile still runs to the end. */
static void adaptive_min_gain_black(void)
{
    srv_job_params p = {
        64, 32, 64,     32,     8, 1,  16, 3, 0.0, 8, 1e-5, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0,  "", {0, 0}, {0, 0}, 0, {0}};
    srv_job *j = NULL;
    CHECK(srv_job_new(3, &p, HASH, &j, NULL) == PT_OK);
    if (!j)
        return;
    static pt_pixel_acc px[32 * 32];
    proto_task t;
    proto_result r;
    while (srv_job_lease(j, 1, 0, 1000, &t)) {
        gain_pixels_of(&t, px, &r, 1);
        srv_outcome o = srv_job_result(j, 1, &r, NULL);
        CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
    }
    CHECK(srv_job_complete(j));
    CHECK(srv_job_tiles_stopped(j) == 1);
    const pt_film *f = srv_job_film(j);
    CHECK(f->px[0].n == 8 && f->px[32].n == 64);
    CHECK(f->px[0].fsum[0] == 0 && f->px[0].fsum_sq == 0);
    srv_job_free(j);
}

static void bad_params(void)
{
    srv_job_params p = {
        0, 10, 4,      16,     4, 0,  4, 3, 0.0, 0, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0, "", {0, 0}, {0, 0}, 0, {0}};
    srv_job *j = NULL;
    pt_error err = {0};
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_ARG);
    p.width = 10;
    p.tile = 1000;
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_ARG);
    p = (srv_job_params){
        16, 16, 4,      16,     4, 0,  4, 3, 0.0, 0, NAN, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0,  "", {0, 0}, {0, 0}, 0, {0}};
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_ARG);
    p.min_gain = -1e-6;
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_ARG);
    p.min_gain = INFINITY;
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_ARG);
    p = (srv_job_params){16384,
                         16384,
                         1u << 24,
                         16,
                         1,
                         0,
                         4,
                         3,
                         0.0,
                         0,
                         0.0,
                         "",
                         {"", 1.0f, 0.0f, 0, {0, 0, 0}},
                         0,
                         "",
                         {0, 0},
                         {0, 0},
                         0,
                         {0}};
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_ERR_LIMIT);
    CHECK(j == NULL);
}

/* ---- deadlines, backups, plausibility, verification ---- */

typedef struct misses {
    uint64_t owner[16];
    int n;
} misses;

static void on_miss(void *ctx, uint64_t owner, uint64_t task)
{
    misses *m = ctx;
    (void)task;
    if (m->n < 16)
        m->owner[m->n++] = owner;
}

/* Leases and answers a task of j for owner at t0, done at t1 (ms). */
static srv_outcome render(srv_job *j, uint64_t owner, uint64_t t0, uint64_t t1, proto_task *t)
{
    static pt_pixel_acc px[PROTO_MAX_TILE_PIXELS];
    proto_result r;
    CHECK(srv_job_lease(j, owner, t0, 100000, t) == 1);
    fake_result(t, px, &r);
    int li;
    pt_error err = {0};
    srv_outcome o = srv_job_validate(j, owner, &r, &li, &err);
    return o == SRV_MERGED ? srv_job_result_validated(j, li, &r, t1, &err) : o;
}

static void hard_deadlines(void)
{
    srv_job *j = make(64, 16, 64, 16, 8); /* 4 tiles x 8 chunks, 2048 samples a task */
    srv_lease_policy pol = {100, 1000, 8.0, 0.0, 0.0, 0, 0, 0, NULL};
    srv_job_set_policy(j, &pol);
    proto_task a, b, c;
    misses m = {{0}, 0};
    /* Before any result: the first allowance, heartbeats or not, and no
     * miss counted (a slow start is not hoarding); a silent owner's is. */
    CHECK(srv_job_lease(j, 1, 0, 100000, &a) == 1);
    srv_job_heartbeat(j, 1, a.task_id, 900, 100000);
    CHECK(srv_job_expire(j, 999, NULL, on_miss, &m) == 0 && m.n == 0);
    CHECK(srv_job_expire(j, 1000, NULL, on_miss, &m) == 1 && m.n == 0);
    CHECK(srv_job_lease(j, 1, 1000, 500, &a) == 1);
    CHECK(srv_job_expire(j, 1500, NULL, on_miss, &m) == 1 && m.n == 1 && m.owner[0] == 1);
    /* A result taking 20 ms: 8 x 20 ms = 160 ms beats the floor. */
    CHECK(render(j, 2, 1000, 1020, &b) == SRV_MERGED);
    CHECK(srv_job_lease(j, 3, 2000, 100000, &c) == 1);
    srv_job_heartbeat(j, 3, c.task_id, 2150, 100000);
    uint64_t next = 0;
    CHECK(srv_job_expire(j, 2159, &next, on_miss, &m) == 0 && next == 2160);
    CHECK(srv_job_expire(j, 2160, NULL, on_miss, &m) == 1 && m.n == 2 && m.owner[1] == 3);
    /* The floor holds when tasks are fast. */
    for (int i = 0; i < 20; i++)
        CHECK(render(j, 2, 3000, 3001, &b) == SRV_MERGED);
    CHECK(srv_job_lease(j, 3, 4000, 100000, &c) == 1);
    CHECK(srv_job_expire(j, 4099, NULL, NULL, NULL) == 0);
    CHECK(srv_job_expire(j, 4100, NULL, NULL, NULL) == 1);
    /* No policy: heartbeats alone, as before. */
    srv_lease_policy none = {0};
    srv_job_set_policy(j, &none);
    CHECK(srv_job_lease(j, 3, 5000, 1000, &c) == 1);
    CHECK(srv_job_expire(j, 5999, NULL, NULL, NULL) == 0);
    srv_job_heartbeat(j, 3, c.task_id, 5999, 1000);
    CHECK(srv_job_expire(j, 6500, NULL, NULL, NULL) == 0);
    srv_job_free(j);
}

static void backups(void)
{
    static pt_pixel_acc px[256];
    srv_job *j = make(16, 16, 16, 16, 8); /* two tasks */
    srv_lease_policy pol = {100000, 100000, 8.0, 3.0, 0.0, 0, 0, 0, NULL};
    srv_job_set_policy(j, &pol);
    proto_task a, b, c;
    CHECK(srv_job_lease(j, 1, 0, 100000, &a) == 1 && a.task_id == 0);
    CHECK(render(j, 2, 0, 10, &b) == SRV_MERGED && b.task_id == 1);
    CHECK(srv_job_lease(j, 2, 29, 100000, &c) == 0); /* 29 ms < 3 x 10 ms */
    CHECK(srv_job_lease(j, 1, 40, 100000, &c) == 0); /* never its own task */
    CHECK(srv_job_lease(j, 2, 40, 100000, &c) == 1 && c.task_id == 0);
    CHECK(srv_job_lease(j, 3, 40, 100000, &c) == 0); /* one backup a task */
    CHECK(srv_job_leases(j) == 2);
    /* The first copy expiring leaves the backup: the task stays leased. */
    srv_lease_policy tight = {50, 50, 8.0, 3.0, 0.0, 0, 0, 0, NULL};
    srv_job_set_policy(j, &tight);
    CHECK(srv_job_expire(j, 85, NULL, NULL, NULL) == 1 && srv_job_leases(j) == 1);
    CHECK(srv_job_lease(j, 4, 85, 100000, &c) == 0);
    srv_job_set_policy(j, &pol);
    /* The backup's result wins; the first copy's is a harmless duplicate. */
    proto_result r;
    fake_result(&a, px, &r);
    pt_error err = {0};
    CHECK(srv_job_result(j, 2, &r, &err) == SRV_MERGED);
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_DUPLICATE);
    CHECK(srv_job_leases(j) == 0 && srv_job_complete(j));
    CHECK(srv_job_verify_stats(j).backups == 1);
    srv_job_free(j);
}

#define ONE ((pt_i128)1 << PT_FIXED_BITS)
#define HALF (ONE / 2)

static void plausible(void)
{
    static pt_pixel_acc px[256];
    srv_job *j = make(16, 16, 16, 16, 8);
    proto_task t;
    proto_result r;
    pt_error err = {0};
    CHECK(srv_job_lease(j, 1, 0, 1000, &t) == 1);
    struct {
        pt_i128 sum;
        pt_u128 sum_sq;
        uint32_t n, rejected;
        srv_outcome want;
    } cases[] = {
        /* Sums in fixed point (units of 2^-32): far over the cap, negative. */
        {(pt_i128)1 << 120, 1, 8, 0, SRV_INVALID},
        {-1, 0, 8, 0, SRV_INVALID},
        {0, 0, 0, 0, SRV_INVALID},
        {HALF, HALF, 7, 0, SRV_INVALID},
        {HALF, HALF, 9, 0, SRV_INVALID},
        {ONE, 0, 0, 8, SRV_INVALID}, /* no samples, yet a sum */
        {0, 1, 0, 8, SRV_INVALID},   /* no samples, yet a sum of squares */
        /* Just over 8 samples at the per-sample cap. */
        {(pt_i128)(8.001 * PT_MAX_SAMPLE_RADIANCE * PT_FIXED_ONE), 0, 8, 0, SRV_INVALID},
        /* 7 samples at the cap, the sum of squares saturated: plausible. */
        {(pt_i128)(7.0 * PT_MAX_SAMPLE_RADIANCE * PT_FIXED_ONE), PT_U128_MAX, 7, 1, SRV_MERGED},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        fake_result(&t, px, &r);
        px[5].fsum[1] = cases[i].sum;
        px[5].fsum_sq = cases[i].sum_sq;
        px[5].n = cases[i].n;
        r.rejected = cases[i].rejected;
        srv_outcome o = srv_job_result(j, 1, &r, &err);
        CHECKF(o == cases[i].want, "case %zu: outcome %d (%s)", i, (int)o, err.msg);
    }
    CHECK(srv_job_samples_merged(j) == 256 * 8 - 1);
    srv_job_free(j);
}

static void verification(void)
{
    static pt_pixel_acc px[256];
    srv_job *j = make(16, 16, 16, 16, 8);
    srv_lease_policy pol = {0, 0, 0.0, 0.0, 1.0, 42, 0, 0, NULL};
    srv_job_set_policy(j, &pol);
    proto_task t, v;
    proto_result r;
    pt_error err = {0};
    srv_verdict verdict;
    int li;
    CHECK(srv_job_lease(j, 1, 0, 1000, &t) == 1 && t.task_id == 0);
    fake_result(&t, px, &r);
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    pt_pixel_acc film0 = srv_job_film(j)->px[3];
    /* Owner 1 never verifies itself; owner 2 gets task 1, then the copy. */
    CHECK(srv_job_lease(j, 1, 0, 1000, &v) == 1 && v.task_id == 1);
    CHECK(srv_job_lease(j, 2, 0, 1000, &v) == 1 && v.task_id == 0);
    fake_result(&v, px, &r);
    CHECK(srv_job_validate(j, 2, &r, &li, &err) == SRV_CHECK);
    srv_job_check(j, li, &r, &verdict);
    CHECK(verdict.kind == SRV_V_MATCH && verdict.honest == 1);
    CHECK(memcmp(&srv_job_film(j)->px[3], &film0, sizeof film0) == 0);
    CHECK(srv_job_result(j, 2, &r, &err) == SRV_DUPLICATE); /* the lease is gone */
    /* Owner 1 answers task 1 with 0.5 everywhere; 2 disagrees, 3 decides. */
    CHECK(srv_job_lease(j, 1, 0, 1000, &v) == 0);
    fake_result(&v, px, &r);
    r.task_id = 1;
    r.s0 = 8;
    r.s1 = 16;
    for (int i = 0; i < 256; i++)
        px[i] = pt_pixel_acc_of(0.5, 0.5, 0.5, 0.25, 8, 0);
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    CHECK(srv_job_complete(j));
    CHECK(srv_job_lease(j, 2, 0, 1000, &v) == 1 && v.task_id == 1);
    fake_result(&v, px, &r);
    CHECK(srv_job_validate(j, 2, &r, &li, &err) == SRV_CHECK);
    srv_job_check(j, li, &r, &verdict);
    CHECK(verdict.kind == SRV_V_MISMATCH);
    CHECK(!srv_job_complete(j));                  /* not until a third render decides */
    CHECK(srv_job_lease(j, 2, 0, 1000, &v) == 0); /* neither of the two decides */
    CHECK(srv_job_lease(j, 3, 0, 1000, &v) == 1 && v.task_id == 1);
    fake_result(&v, px, &r);
    CHECK(srv_job_validate(j, 3, &r, &li, &err) == SRV_CHECK);
    srv_job_check(j, li, &r, &verdict);
    CHECK(verdict.kind == SRV_V_LIAR && verdict.liar == 1 && verdict.honest == 2);
    CHECK(srv_job_complete(j));
    uint64_t merged = 0, samples = 0;
    srv_job_forget_owner(j, 1, &merged, &samples);
    CHECK(merged == 1 && samples == 2 * 256 * 8); /* task 0 verified, task 1 not */
    srv_verify_stats vs = srv_job_verify_stats(j);
    CHECK(vs.picked == 2 && vs.matched == 1 && vs.mismatched == 1 && vs.liars == 1);
    CHECK(vs.samples == 3 * 256 * 8);
    srv_job_free(j);

    /* A liar's held (not yet merged) results go back to pending. */
    j = make(16, 16, 24, 16, 8);
    proto_task t0, t1;
    CHECK(srv_job_lease(j, 1, 0, 1000, &t0) == 1 && srv_job_lease(j, 5, 0, 1000, &t1) == 1);
    fake_result(&t1, px, &r);
    CHECK(srv_job_result(j, 5, &r, &err) == SRV_MERGED); /* held: chunk 1 before 0 */
    srv_job_forget_owner(j, 5, NULL, NULL);
    fake_result(&t0, px, &r);
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    CHECK(srv_job_tasks_merged(j) == 1);
    CHECK(srv_job_lease(j, 1, 0, 1000, &t1) == 1 && t1.task_id == 1);
    srv_job_free(j);

    /* The pick is a function of the seed and the task: about the fraction. */
    j = make(512, 512, 64, 16, 8); /* 8192 tasks */
    srv_lease_policy f = {0, 0, 0.0, 0.0, 0.02, 7, 0, 0, NULL};
    srv_job_set_policy(j, &f);
    proto_task x;
    while (srv_job_lease(j, 1, 0, 1000, &x)) {
        fake_result(&x, px, &r);
        srv_job_result(j, 1, &r, &err);
    }
    uint64_t picked = srv_job_verify_stats(j).picked;
    /* Binomial(8192, 0.02): mean 164, sd 12.7; 5 sd either side (plus the
     * owner's first result, always picked). */
    CHECKF(picked > 100 && picked < 228, "%llu picked", (unsigned long long)picked);
    srv_job_free(j);

    /* Every owner's first result is picked: 64-task jobs at 0.02, whose
     * pick alone leaves about 27 % of them unchecked, each get one check per
     * owner at least, whatever the seed. */
    for (uint64_t seed = 1; seed <= 50; seed++) {
        j = make(128, 128, 16, 16, 16); /* 64 tiles, one chunk each */
        /* Seeds apart in their high bits: the pick hashes seed ^ task. */
        srv_lease_policy small = {0, 0, 0.0, 0.0, 0.02, seed * 0x9E3779B97F4A7C15ull, 0, 0, NULL};
        srv_job_set_policy(j, &small);
        for (uint64_t owner = 1; srv_job_lease(j, owner, 0, 1000, &x); owner = 3 - owner) {
            fake_result(&x, px, &r);
            srv_job_result(j, owner, &r, &err);
        }
        picked = srv_job_verify_stats(j).picked;
        CHECKF(picked >= 2, "seed %llu: %llu picked", (unsigned long long)seed,
               (unsigned long long)picked);
        srv_job_free(j);
    }
}

/* The film flags reach every task; the depth-cap counts of accepted results
 * are summed (a duplicate's not, an implausible one refused) and, with the
 * camera hits, kept by a checkpoint, which a job of other film flags refuses. */
static void film_and_cap(void)
{
    srv_job_params p = {32,
                        32,
                        16,
                        16,
                        8,
                        5,
                        2,
                        3,
                        0.0,
                        0,
                        0.0,
                        "",
                        {"", 1.0f, 0.0f, 0, {0, 0, 0}},
                        PROTO_FILM_TRANSPARENT,
                        "",
                        {0, 0},
                        {0, 0},
                        0,
                        {0}};
    srv_job *j = NULL, *k = NULL, *o = NULL;
    pt_error err = {0};
    CHECK(srv_job_new(4, &p, HASH, &j, &err) == PT_OK);
    if (!j)
        return;
    static pt_pixel_acc px[16 * 16];
    proto_task t;
    proto_result r;
    uint64_t want = 0;
    for (uint32_t i = 0; srv_job_lease(j, 1, 0, 1000, &t); i++) {
        CHECK(t.film_flags == PROTO_FILM_TRANSPARENT);
        fake_result(&t, px, &r);
        for (uint32_t q = 0; q < r.npixels; q++)
            px[q].hits = q % (px[q].n + 1);
        r.capped = (uint64_t)r.npixels * (t.s1 - t.s0) + 1; /* more than its paths */
        CHECK(srv_job_result(j, 1, &r, &err) == SRV_INVALID && strstr(err.msg, "depth cap"));
        r.capped = i + 1;
        CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
        want += i + 1;
        CHECK(srv_job_result(j, 1, &r, &err) == SRV_DUPLICATE);
        if (i == 2)
            break; /* the rest stay leased: the checkpoint has partial state */
    }
    CHECK(srv_job_paths_capped(j) == want);
    proto_writer w;
    proto_writer_init(&w, 1u << 24);
    CHECK(srv_job_save(j, &w, &err) == PT_OK);
    CHECK(srv_job_new(4, &p, HASH, &k, &err) == PT_OK);
    CHECKF(k && srv_job_load(k, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
    if (k) {
        CHECK(srv_job_paths_capped(k) == want);
        const pt_film *a = srv_job_film(j), *b = srv_job_film(k);
        CHECK(memcmp(a->px, b->px, 32 * 32 * sizeof *a->px) == 0);
    }
    p.film_flags = 0;
    CHECK(srv_job_new(4, &p, HASH, &o, &err) == PT_OK);
    CHECK(o && srv_job_load(o, w.buf, w.len, &err) == PT_ERR_FORMAT);
    proto_writer_fini(&w);
    srv_job_free(o);
    srv_job_free(k);
    srv_job_free(j);
}

/* ---- time-sized tasks ---- */

/* Pixels whose every sample is a multiple of 1/2 below 3: sums of any split
 * are exact in double, so films merged from different cuts compare bit for
 * bit, as exact sums make them in the renderer. Tile 0 is constant (adaptive
 * sampling stops it), the others vary by sample. */
static void exact_result(const proto_task *t, pt_pixel_acc *px, proto_result *r)
{
    uint32_t w = t->tile.x1 - t->tile.x0, n = w * (t->tile.y1 - t->tile.y0);
    for (uint32_t i = 0; i < n; i++) {
        uint32_t x = t->tile.x0 + i % w, y = t->tile.y0 + i / w;
        double sum = 0, sq = 0;
        for (uint32_t s = t->s0; s < t->s1; s++) {
            double v = x < 32 && y < 32 ? 0.5 : (double)((s * 7 + x + 3 * y) % 5) * 0.5;
            sum += v;
            sq += v * v;
        }
        px[i] = pt_pixel_acc_of(sum, sum, sum, sq, t->s1 - t->s0, t->s1 - t->s0);
    }
    *r = (proto_result){t->job_id, t->task_id, t->tile, t->s0, t->s1, 0, 0,    0, n, px,
                        0,         NULL,       0,       0,     0,     0, NULL, 0, 0};
}

typedef struct sim_owner {
    uint64_t id;
    double ms_ps; /* its true ms per pixel-sample */
    int busy;
    proto_task t;
    uint64_t done_at;
} sim_owner;

typedef struct sim_log {
    uint32_t ntasks;
    uint32_t s0[4096], s1[4096];
    uint64_t owner[4096], at[4096];
    uint32_t tile_px[4096];
} sim_log;

/* The merge threads simulate's jobs use when it is set (ptserve's). */
static srv_adder *sim_adder;

/* Runs job j to the end with owners of the given speeds, one task each at a
 * time (a result arrives when its owner's time for it has passed); logs
 * every lease. ckpt_at: after this many results the job is saved and
 * replaced by a loaded copy, the results outstanding replayed into it
 * (-1: never). Returns the job (perhaps the copy). With sim_adder each
 * result owns its pixels, as ptserve's do, so the job may hand their add to
 * the merge threads. */
static srv_job *simulate(srv_job *j, sim_owner *ow, int n, sim_log *log, int ckpt_at,
                         const srv_job_params *p)
{
    static pt_pixel_acc px[32 * 32];
    if (sim_adder)
        srv_job_set_adder(j, sim_adder);
    uint64_t now = 0;
    int results = 0, guard = 0;
    if (log)
        log->ntasks = 0;
    while (!srv_job_complete(j) && guard++ < 100000) {
        for (int k = 0; k < n; k++) {
            if (ow[k].busy || !srv_job_lease(j, ow[k].id, now, 100000, &ow[k].t))
                continue;
            ow[k].busy = 1;
            uint32_t w = ow[k].t.tile.x1 - ow[k].t.tile.x0, h = ow[k].t.tile.y1 - ow[k].t.tile.y0;
            double ms = ow[k].ms_ps * w * h * (ow[k].t.s1 - ow[k].t.s0);
            ow[k].done_at = now + (uint64_t)(ms < 1.0 ? 1.0 : ms);
            if (log && log->ntasks < 4096) {
                log->s0[log->ntasks] = ow[k].t.s0;
                log->s1[log->ntasks] = ow[k].t.s1;
                log->owner[log->ntasks] = ow[k].id;
                log->at[log->ntasks] = now;
                log->tile_px[log->ntasks] = w * h;
                log->ntasks++;
            }
        }
        int next = -1;
        for (int k = 0; k < n; k++)
            if (ow[k].busy && (next < 0 || ow[k].done_at < ow[next].done_at))
                next = k;
        if (next < 0)
            break;
        now = ow[next].done_at;
        ow[next].busy = 0;
        proto_result r;
        exact_result(&ow[next].t, px, &r);
        if (sim_adder) {
            r.pixels = pt_malloc_array(r.npixels, sizeof *r.pixels);
            CHECK(r.pixels != NULL);
            if (!r.pixels)
                break;
            memcpy(r.pixels, px, r.npixels * sizeof *px);
            r.owns_pixels = 1;
        }
        int li;
        pt_error err = {0};
        srv_outcome o = srv_job_validate(j, ow[next].id, &r, &li, &err);
        if (o == SRV_MERGED)
            o = srv_job_result_validated(j, li, &r, now, &err);
        CHECKF(o == SRV_MERGED || o == SRV_DUPLICATE, "outcome %d: %s", (int)o, err.msg);
        CHECK(o != SRV_MERGED || !r.owns_pixels); /* taken, held or posted */
        proto_result_fini(&r);
        if (++results == ckpt_at) {
            /* A coordinator killed here: the checkpoint, then what the log
             * holds (results outstanding are lost with their leases). */
            proto_writer w;
            proto_writer_init(&w, 1u << 24);
            srv_job *c = NULL;
            CHECK(srv_job_save(j, &w, &err) == PT_OK);
            CHECK(srv_job_new(srv_job_id(j), p, HASH, &c, &err) == PT_OK);
            CHECKF(c && srv_job_load(c, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
            proto_writer_fini(&w);
            if (c) {
                srv_lease_policy pol = {0};
                pol.task_ms = 1000;
                srv_job_set_policy(c, &pol);
                if (sim_adder)
                    srv_job_set_adder(c, sim_adder);
                srv_job_free(j);
                j = c;
                for (int k = 0; k < n; k++)
                    ow[k].busy = 0;
            }
        }
    }
    CHECK(srv_job_complete(j));
    return j;
}

static srv_job_params sized_params(uint32_t spp, double target_error)
{
    srv_job_params p = {64,
                        48,
                        spp,
                        32,
                        16,
                        1,
                        16,
                        3,
                        target_error,
                        32,
                        0.0,
                        "",
                        {"", 1.0f, 0.0f, 0, {0, 0, 0}},
                        0,
                        "",
                        {0.0, 0.0},
                        {0, 0},
                        0,
                        {0}};
    return p;
}

static srv_job *sized_job(const srv_job_params *p, uint32_t task_ms)
{
    srv_job *j = NULL;
    CHECK(srv_job_new(7, p, HASH, &j, NULL) == PT_OK);
    srv_lease_policy pol = {0};
    pol.task_ms = task_ms;
    if (j)
        srv_job_set_policy(j, &pol);
    return j;
}

/* Sizes follow the owner that asks: a fast one's grow from one block,
 * each taking its tile to at most 8 times its samples, up to its time's worth; a slow one's stay
 * one block; every task is a whole number of blocks within [0, spp); near the end they shrink
 * again. */
static void sizing(void)
{
    static sim_log log;
    srv_job_params p = sized_params(4096, 0.0);
    /* 4 tiles, 2 of 1024 pixels and 2 of 512 (the last row is 16 high).
     * One fast owner (1 us per pixel-sample: 1,000 ms is ~1 M pixel-samples,
     * ~1,000 samples of a whole tile) and one slow (20 ms per pixel-sample:
     * 16 samples of a tile take 330 s, more than the task time). */
    srv_job *j = sized_job(&p, 1000);
    sim_owner ow[2] = {{1, 0.001, 0, {0}, 0}, {2, 20.0, 0, {0}, 0}};
    j = simulate(j, ow, 2, &log, -1, &p);
    uint32_t most_fast = 0, most_slow = 0, blocks = 1, first = 1, px_ok = 1;
    for (uint32_t i = 0; i < log.ntasks; i++) {
        uint32_t n = log.s1[i] - log.s0[i];
        /* ~1,000 ms of the fast owner: 976 samples of 1024 pixels, 1952 of 512 */
        px_ok &= log.owner[i] != 1 || n * (log.tile_px[i]) <= 1000u * 1000u;
        blocks &= (n % 16 == 0 || log.s1[i] == p.spp) && log.s0[i] % 16 == 0 && log.s1[i] <= p.spp;
        if (log.owner[i] == 1 && n > most_fast)
            most_fast = n;
        if (log.owner[i] == 2 && n > most_slow)
            most_slow = n;
        /* The first pass is one block a tile, and no task takes its tile
         * past 8 times its samples (job.c: GROWTH). */
        first &= i >= 4 || (log.s0[i] == 0 && log.s1[i] == 16);
        first &= log.s0[i] == 0 ? n == 16 : n <= 7 * (log.s0[i] > 16 ? log.s0[i] : 16);
    }
    CHECK(blocks && first);
    CHECKF(most_fast == 1952, "fast owner's largest task: %u samples", most_fast);
    CHECK(px_ok);
    CHECKF(most_slow == 16, "slow owner's largest task: %u samples", most_slow);
    /* The last tasks of the fast owner are smaller than its largest. */
    uint32_t last_fast = 0;
    for (uint32_t i = 0; i < log.ntasks; i++)
        if (log.owner[i] == 1)
            last_fast = log.s1[i] - log.s0[i];
    CHECKF(last_fast < most_fast, "fast owner's last task %u, largest %u", last_fast, most_fast);
    CHECK(srv_job_samples_merged(j) == (64ull * 48) * p.spp);
    srv_job_free(j);

    /* Four equal owners near the end: once the work left is under what they
     * render in a few task times, each task takes at most a quarter of what
     * is left, so the last tasks end close together. */
    j = sized_job(&p, 1000);
    sim_owner eq[4] = {
        {1, 0.001, 0, {0}, 0}, {2, 0.001, 0, {0}, 0}, {3, 0.001, 0, {0}, 0}, {4, 0.001, 0, {0}, 0}};
    j = simulate(j, eq, 4, &log, -1, &p);
    uint64_t end = 0, last_start = 0;
    for (int k = 0; k < 4; k++)
        end = eq[k].done_at > end ? eq[k].done_at : end;
    for (uint32_t i = 0; i < log.ntasks; i++)
        last_start = log.at[i] > last_start ? log.at[i] : last_start;
    /* Total work 12.6 M pixel-samples: 3.1 s for the four. Without the
     * shrink the last 1,000 ms tasks would leave owners idle that long. */
    CHECKF(end - last_start < 300, "the last task started %llu ms before the end",
           (unsigned long long)(end - last_start));
    srv_job_free(j);
}

/* Fixed chunks (ptserve --chunk) whatever the owners' speeds: every task is
 * the next chunk, in pass order. */
static void fixed_chunks(void)
{
    static sim_log log;
    srv_job_params p = sized_params(100, 0.0);
    p.chunk = 24;
    srv_job *j = sized_job(&p, 0);
    sim_owner ow[2] = {{1, 0.0001, 0, {0}, 0}, {2, 1.0, 0, {0}, 0}};
    j = simulate(j, ow, 2, &log, -1, &p);
    CHECK(log.ntasks == 4 * 5);
    int fixed = 1;
    for (uint32_t i = 0; i < log.ntasks; i++) {
        uint32_t c = i / 4;
        fixed &= log.s0[i] == 24 * c && log.s1[i] == (c == 4 ? 100 : 24 * (c + 1));
    }
    CHECK(fixed);
    srv_job_free(j);
}

/* The film is the same bits however the samples were cut: fixed chunks,
 * time-sized tasks for owners of mixed speeds, and the same with the job
 * saved and resumed midway; with adaptive sampling too, by either rule
 * (decisions every 64 samples from 64 on: no task crosses one, with the min
 * gain one ends there only as the 64 before it, and the same tiles stop at
 * the same samples). */
static void same_film_any_cut(void)
{
    for (int mode = 0; mode < 3; mode++) {
        srv_job_params p = sized_params(512, mode == 1 ? 0.05 : 0.0);
        if (mode) {
            p.chunk = 64;
            p.min_spp = 64;
            p.min_gain = mode == 2 ? 1e-3 : 0.0;
        }
        srv_job *a = sized_job(&p, 0);
        sim_owner one[1] = {{1, 0.001, 0, {0}, 0}};
        a = simulate(a, one, 1, NULL, -1, &p);
        srv_job *b = sized_job(&p, 1000);
        sim_owner mixed[3] = {{1, 0.0002, 0, {0}, 0}, {2, 0.003, 0, {0}, 0}, {3, 0.05, 0, {0}, 0}};
        static sim_log log;
        b = simulate(b, mixed, 3, &log, -1, &p);
        int bigger = 0, crossed = 0;
        for (uint32_t i = 0; i < log.ntasks; i++) {
            uint32_t s0 = log.s0[i], s1 = log.s1[i];
            bigger |= s1 - s0 > 16;
            for (uint32_t d = 64; mode && d < 512; d += 64)
                crossed |= (s0 < d && d < s1) || (mode == 2 && s1 == d && s0 != d - 64);
        }
        CHECK(bigger);
        CHECKF(!crossed, "mode %d: a task crossed a decision point", mode);
        srv_job *c = sized_job(&p, 1000);
        sim_owner again[3] = {{1, 0.0002, 0, {0}, 0}, {2, 0.003, 0, {0}, 0}, {3, 0.05, 0, {0}, 0}};
        c = simulate(c, again, 3, NULL, 9, &p);
        /* The same, its adds made by merge threads (server/sched/adder.h), and
         * resumed after a checkpoint as well. */
        srv_adder *ad = NULL;
        CHECK(srv_adder_new(2, &ad, NULL) == PT_OK);
        if (!ad)
            return;
        srv_job *d = sized_job(&p, 1000), *e = sized_job(&p, 1000);
        sim_owner more[3] = {{1, 0.0002, 0, {0}, 0}, {2, 0.003, 0, {0}, 0}, {3, 0.05, 0, {0}, 0}};
        sim_owner last[3] = {{1, 0.0002, 0, {0}, 0}, {2, 0.003, 0, {0}, 0}, {3, 0.05, 0, {0}, 0}};
        sim_adder = ad;
        d = simulate(d, more, 3, NULL, -1, &p);
        e = simulate(e, last, 3, NULL, 9, &p);
        sim_adder = NULL;
        uint64_t threaded, inl;
        srv_adder_counts(ad, &threaded, &inl);
        /* With the min gain every task here ends where a tile is judged, so
         * its adds are made at once (the judgement reads the sums). */
        CHECKF(mode == 2 || threaded > 0, "mode %d: no add went to the merge threads", mode);
        const pt_film *fa = srv_job_film(a), *fb = srv_job_film(b), *fc = srv_job_film(c);
        const pt_film *fd = srv_job_film(d), *fe = srv_job_film(e);
        CHECKF(memcmp(fa->px, fb->px, 64 * 48 * sizeof *fa->px) == 0,
               "mode %d: time-sized tasks changed the film", mode);
        CHECKF(memcmp(fa->px, fc->px, 64 * 48 * sizeof *fa->px) == 0,
               "mode %d: a resumed job changed the film", mode);
        CHECKF(memcmp(fa->px, fd->px, 64 * 48 * sizeof *fa->px) == 0,
               "mode %d: merge threads changed the film", mode);
        CHECKF(memcmp(fa->px, fe->px, 64 * 48 * sizeof *fa->px) == 0,
               "mode %d: merge threads and a resume changed the film", mode);
        CHECK(srv_job_samples_merged(d) == srv_job_samples_merged(a));
        CHECK(srv_job_tiles_stopped(d) == srv_job_tiles_stopped(a));
        srv_job_free(d);
        srv_job_free(e);
        srv_adder_free(ad);
        CHECKF(mode == 0 ? srv_job_tiles_stopped(a) == 0 : srv_job_tiles_stopped(a) >= 1,
               "mode %d: %u tiles stopped", mode, srv_job_tiles_stopped(a));
        CHECK(srv_job_tiles_stopped(b) == srv_job_tiles_stopped(a));
        CHECK(srv_job_samples_merged(b) == srv_job_samples_merged(a));
        CHECK(srv_job_passes_done(b) == srv_job_passes(b));
        srv_job_free(a);
        srv_job_free(b);
        srv_job_free(c);
    }
}

/* An expired lease gives its exact range back; a replay finds its task by
 * tile and samples even when it was cut otherwise in this run. */
static void ranges_back(void)
{
    srv_job_params p = sized_params(256, 0.0);
    srv_job *j = sized_job(&p, 1000);
    static pt_pixel_acc px[32 * 32];
    proto_task t[8], u;
    proto_result r;
    for (int k = 0; k < 6; k++) /* the first pass, merged at 10 ms: ~1 us per pixel-sample */
        if (srv_job_lease(j, 1, 0, 100, &t[k])) {
            exact_result(&t[k], px, &r);
            int li;
            CHECK(srv_job_validate(j, 1, &r, &li, NULL) == SRV_MERGED);
            CHECK(srv_job_result_validated(j, li, &r, 10, NULL) == SRV_MERGED);
        }
    CHECK(srv_job_lease(j, 1, 10, 100, &t[6]) && t[6].s0 == 16 && t[6].s1 == 128);
    CHECK(srv_job_lease(j, 2, 10, 100, &t[7]) && t[7].s0 == 16);
    CHECK(srv_job_expire(j, 200, NULL, NULL, NULL) == 2);
    CHECK(srv_job_lease(j, 3, 200, 100, &u) && u.task_id == t[6].task_id && u.s0 == t[6].s0 &&
          u.s1 == t[6].s1 && memcmp(&u.tile, &t[6].tile, sizeof u.tile) == 0);
    /* A replay of t[7]'s samples of its tile, with another id. */
    proto_task v = t[7];
    v.task_id = 999;
    exact_result(&v, px, &r);
    CHECK(srv_job_replay(j, &r, NULL) == SRV_MERGED);
    CHECK(srv_job_replay(j, &r, NULL) == SRV_DUPLICATE);
    /* Samples that straddle the end of what is merged fit no task. */
    v.s0 = t[7].s1 - 8;
    v.s1 = t[7].s1 + 8;
    exact_result(&v, px, &r);
    pt_error err = {0};
    CHECK(srv_job_replay(j, &r, &err) == SRV_INVALID && strstr(err.msg, "do not fit"));
    srv_job_free(j);
}

/* Thousands of owners (the owner table and its hash grow, each owner lists
 * its own leases): a lost owner gives back exactly its leases, the others'
 * stay; heartbeats and results find their lease among all of them. */
static void many_owners(void)
{
    srv_job_params p = sized_params(64, 0.0);
    p.width = 1024;
    p.height = 1024; /* 1024 tiles */
    srv_job *j = sized_job(&p, 0);
    static proto_task t[3000];
    uint32_t n = 0;
    for (uint64_t o = 0; o < 3000; o++)
        n += (uint32_t)srv_job_lease(j, 100 + o, 0, 1000, &t[o]);
    CHECK(n == 3000 && srv_job_leases(j) == 3000);
    /* The first pass (1024 tasks), then the second. */
    CHECK(t[0].s0 == 0 && t[1023].s0 == 0 && t[1024].s0 == 16);
    uint32_t back = 0;
    for (uint64_t o = 0; o < 3000; o += 2)
        back += srv_job_release_owner(j, 100 + o);
    CHECK(back == 1500 && srv_job_leases(j) == 1500);
    int active = 1, idle = 1;
    for (uint64_t o = 0; o < 3000; o++) {
        srv_job_heartbeat(j, 100 + o, t[o].task_id, 900, 1000);
        if (o % 2)
            active &= srv_job_owner_active(j, 100 + o);
        else
            idle &= !srv_job_owner_active(j, 100 + o);
    }
    CHECK(active && idle);
    CHECK(srv_job_expire(j, 1500, NULL, NULL, NULL) == 0); /* the heartbeats held */
    /* The released tasks come back first, to the owners that ask. */
    proto_task u;
    CHECK(srv_job_lease(j, 99, 1500, 1000, &u) && u.task_id == t[0].task_id);
    static pt_pixel_acc px[32 * 32];
    proto_result r;
    int merged = 1;
    for (uint64_t o = 1; o < 3000; o += 2) {
        fake_result(&t[o], px, &r);
        merged &= srv_job_result(j, 100 + o, &r, NULL) == SRV_MERGED;
    }
    CHECK(merged && srv_job_leases(j) == 1);
    srv_job_free(j);
}

/* A lease whose result arrived and waits for its log record to be durable
 * (srv_job_answered) is no straggler: no backup copy of it is handed out
 * however long the commit takes, and the result then merges. */
static void answered_no_backup(void)
{
    static pt_pixel_acc px[256];
    srv_job *j = make(16, 16, 16, 16, 8); /* two tasks */
    srv_lease_policy pol = {100000, 100000, 8.0, 3.0, 0.0, 0, 0, 0, NULL};
    srv_job_set_policy(j, &pol);
    proto_task a, b, c;
    CHECK(srv_job_lease(j, 1, 0, 100000, &a) == 1 && a.task_id == 0);
    CHECK(render(j, 2, 0, 10, &b) == SRV_MERGED && b.task_id == 1);
    proto_result r;
    fake_result(&a, px, &r);
    pt_error err = {0};
    int li = -1;
    CHECK(srv_job_validate(j, 1, &r, &li, &err) == SRV_MERGED);
    srv_job_answered(j, li);
    CHECK(srv_job_lease(j, 2, 40, 100000, &c) == 0); /* 40 ms > 3 x 10 ms, but answered */
    CHECK(srv_job_lease(j, 2, 5000, 100000, &c) == 0);
    CHECK(srv_job_result_validated(j, li, &r, 5000, &err) == SRV_MERGED);
    CHECK(srv_job_complete(j) && srv_job_verify_stats(j).backups == 0);
    srv_job_free(j);
}

/* The ticket srv_job_answered gives names its lease while that lease lives,
 * and never a later lease in the same slot: a result logged before its
 * lease was released, and its task leased again (to the same owner, in the
 * same slot), must be judged anew rather than merged through the new lease. */
static void answered_ticket(void)
{
    static pt_pixel_acc px[256];
    srv_job *j = make(16, 16, 16, 16, 8); /* two tasks */
    proto_task a, b;
    CHECK(srv_job_lease(j, 1, 0, 100000, &a) == 1 && a.task_id == 0);
    proto_result r;
    fake_result(&a, px, &r);
    pt_error err = {0};
    int li = -1, li2 = -1;
    CHECK(srv_job_validate(j, 1, &r, &li, &err) == SRV_MERGED);
    uint64_t ticket = srv_job_answered(j, li);
    CHECK(ticket != 0 && srv_job_ticket_lease(j, ticket) == li);
    CHECK(srv_job_ticket_lease(j, 0) == -1);
    CHECK(srv_job_release_owner(j, 1) == 1);
    CHECK(srv_job_ticket_lease(j, ticket) == -1);
    /* The requeued task, to the same owner, in the slot just freed. */
    CHECK(srv_job_lease(j, 1, 10, 100000, &b) == 1 && b.task_id == 0);
    CHECK(srv_job_validate(j, 1, &r, &li2, &err) == SRV_MERGED && li2 == li);
    CHECK(srv_job_ticket_lease(j, ticket) == -1);
    uint64_t ticket2 = srv_job_answered(j, li2);
    CHECK(ticket2 != ticket && srv_job_ticket_lease(j, ticket2) == li2);
    CHECK(srv_job_result_validated(j, srv_job_ticket_lease(j, ticket2), &r, 20, &err) ==
          SRV_MERGED);
    CHECK(srv_job_ticket_lease(j, ticket2) == -1); /* merged: its lease went */
    srv_job_free(j);
}

/* A snapshot saves the same bytes as the job it was taken of (per tile
 * state, held results by tile and range, film), and keeps them while the job
 * goes on; its checkpoint resumes to the job's bits. */
static void snapshot_saves_the_same(void)
{
    static pt_pixel_acc px[16 * 16];
    srv_job *j = make(32, 32, 32, 16, 8), *k = NULL, *snap = NULL;
    if (!j)
        return;
    proto_task t[64];
    int n = 0;
    while (n < 64 && srv_job_lease(j, 1, 0, 100000, &t[n]))
        n++;
    CHECK(n >= 8);
    proto_result r;
    pt_error err = {0};
    int done = 0;
    for (int i = n - 1; i >= n / 2; i--, done++) { /* later samples first: held */
        fake_result(&t[i], px, &r);
        CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    }
    fake_result(&t[0], px, &r); /* one merged into the film */
    CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    proto_writer w, ws, w2;
    proto_writer_init(&w, 1u << 24);
    proto_writer_init(&ws, 1u << 24);
    proto_writer_init(&w2, 1u << 24);
    CHECK(srv_job_save(j, &w, &err) == PT_OK);
    snap = srv_job_snapshot(j);
    CHECK(snap && srv_job_save(snap, &ws, &err) == PT_OK);
    CHECK(w.len == ws.len && memcmp(w.buf, ws.buf, w.len) == 0);
    /* The job goes on to the end; the snapshot does not move. */
    for (int i = 1; i < n / 2; i++) {
        fake_result(&t[i], px, &r);
        CHECK(srv_job_result(j, 1, &r, &err) == SRV_MERGED);
    }
    CHECK(srv_job_complete(j));
    CHECK(snap && srv_job_save(snap, &w2, &err) == PT_OK);
    CHECK(w2.len == ws.len && memcmp(w2.buf, ws.buf, ws.len) == 0);
    /* Resumed from the snapshot's checkpoint, with the rest replayed. */
    CHECK(srv_job_new(9, srv_job_params_of(j), HASH, &k, &err) == PT_OK);
    CHECKF(k && srv_job_load(k, ws.buf, ws.len, &err) == PT_OK, "%s", err.msg);
    for (int i = 0; k && i < n; i++) {
        fake_result(&t[i], px, &r);
        srv_outcome o = srv_job_replay(k, &r, &err);
        CHECK(o == SRV_MERGED || o == SRV_DUPLICATE);
    }
    CHECK(k && srv_job_complete(k));
    if (k)
        CHECK(memcmp(srv_job_film(j)->px, srv_job_film(k)->px, 32 * 32 * sizeof(pt_pixel_acc)) ==
              0);
    proto_writer_fini(&w);
    proto_writer_fini(&ws);
    proto_writer_fini(&w2);
    srv_job_free(snap);
    srv_job_free(k);
    srv_job_free(j);
}

/* A guided result of task t (16 samples a pixel) with the statistics
 * entries e (nc counts, ns sums) made for a guide of nsn + nqn nodes. */
static proto_result guided_result(const proto_task *t, pt_pixel_acc *px, proto_guide_entry *e,
                                  uint32_t nc, uint32_t ns, uint32_t nsn, uint32_t nqn)
{
    uint32_t n = (t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
    for (uint32_t i = 0; i < n; i++)
        px[i] = pt_pixel_acc_of(0.5, 0.25, 0.125, 0.0625, t->s1 - t->s0, t->s1 - t->s0);
    proto_result r = {t->job_id, t->task_id, t->tile, t->s0, t->s1, 0,  0, 0, n, px,
                      0,         NULL,       nsn,     nqn,   nc,    ns, e, 0, 0};
    return r;
}

/* Path guiding (job_guide.c): tasks never cross a pass's end and those of
 * pass 1 wait for its distribution, named by the hash of bytes the job
 * hands out; a result without statistics, with a guide's of another size,
 * with more records than bounces or sums over the record cap is refused
 * and leaves the film as it was; the pass's statistics, once every tile is
 * merged, make the next distribution, which a checkpoint keeps. */
static void guided(void)
{
    pt_error err = {0};
    srv_job_params p = {64,
                        32,
                        64,
                        32,
                        16,
                        5,
                        8,
                        3,
                        0.0,
                        0,
                        0.0,
                        "",
                        {"", 1.0f, 0.0f, 0, {0, 0, 0}},
                        0,
                        "",
                        {0, 0},
                        {0, 0},
                        1,
                        {-1.0f, -1.0f, -1.0f, 1.0f, 1.0f, 1.0f}};
    srv_job *j = NULL;
    CHECK(srv_job_new(1, &p, HASH, &j, &err) == PT_OK);
    if (!j)
        return;
    proto_task t[3];
    CHECK(srv_job_lease(j, 7, 0, 1000, &t[0]) && srv_job_lease(j, 7, 0, 1000, &t[1]));
    CHECK(!srv_job_lease(j, 7, 0, 1000, &t[2])); /* pass 1 waits for its distribution */
    const uint8_t *blob = NULL;
    size_t len = 0;
    for (int k = 0; k < 2; k++) {
        CHECK(t[k].s0 == 0 && t[k].s1 == 16 && t[k].guided && t[k].guide_pass == 0);
        CHECK(srv_job_guide_bytes(j, t[k].guide_hash, &blob, &len) && len > 0);
    }
    /* The bytes handed out are packed; the hash names the unpacked ones. */
    uint8_t h[32], *raw = NULL;
    size_t rawlen = 0;
    CHECK(proto_guide_unpack(blob, len, &raw, &rawlen, &err) == PT_OK && rawlen > len);
    pt_sha256(raw, rawlen, h);
    pt_free(raw);
    CHECK(memcmp(h, t[0].guide_hash, 32) == 0);
    static pt_pixel_acc px[32 * 32];
    proto_guide_entry good[2] = {{0, 1000}, {100, 1000ull << 16}};
    proto_guide_entry absurd[1] = {{0, 32ull * 32 * 16 * 9 + 1}}; /* > a record per bounce */
    proto_guide_entry over[2] = {{0, 1},
                                 {5, (uint64_t)1e9 * 65536 + 2}}; /* a record over the cap */
    struct {
        proto_guide_entry *e;
        uint32_t nc, ns, nsn, nqn;
        const char *why;
    } bad[] = {{NULL, 0, 0, 0, 0, "lacks"},
               {good, 1, 1, 1, 2047, "nodes"},
               {good, 1, 1, 2, 2046, "nodes"},
               {absurd, 1, 0, 1, 2046, "plausible"},
               {over, 1, 1, 1, 2046, "plausible"}};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        proto_result r =
            guided_result(&t[0], px, bad[k].e, bad[k].nc, bad[k].ns, bad[k].nsn, bad[k].nqn);
        CHECKF(srv_job_result(j, 7, &r, &err) == SRV_INVALID && strstr(err.msg, bad[k].why),
               "case %zu: %s", k, err.msg);
    }
    CHECK(pt_film_total_samples(srv_job_film(j)) == 0); /* nothing merged */
    for (int k = 0; k < 2; k++) {
        proto_result r = guided_result(&t[k], px, good, 1, 1, 1, 2046);
        CHECKF(srv_job_result(j, 7, &r, &err) == SRV_MERGED, "%s", err.msg);
    }
    /* Both tiles at pass 0's end: pass 1's distribution exists, another.
     * Pass 0's tasks recorded; pass 1 runs to spp, the last: its tasks
     * record nothing, and a result of one with statistics is refused. */
    CHECK(srv_job_guide_pass(j) == 1);
    CHECK(srv_job_lease(j, 7, 0, 1000, &t[2]) && t[2].s0 == 16 && t[2].s1 <= 48 &&
          t[2].guided == PROTO_GUIDE_LAST && t[2].guide_pass == 1 &&
          memcmp(t[2].guide_hash, h, 32) != 0);
    CHECK(t[0].guided == PROTO_GUIDE_RECORD && t[1].guided == PROTO_GUIDE_RECORD);
    CHECK(srv_job_guide_bytes(j, t[2].guide_hash, &blob, &len));
    /* Statistics of pass 1's sizes, as a worker that recorded would send. */
    uint32_t nsn1 = 0, nqn1 = 0;
    {
        pt_guide *g1 = NULL;
        CHECK(proto_guide_unpack(blob, len, &raw, &rawlen, &err) == PT_OK &&
              proto_guide_decode(raw, rawlen, &g1, &err) == PT_OK);
        pt_free(raw);
        if (g1) {
            nsn1 = g1->nsnode;
            nqn1 = g1->nqnode;
        }
        pt_guide_free(g1);
    }
    CHECK(nqn1 > 100);
    uint64_t before = pt_film_total_samples(srv_job_film(j));
    {
        proto_result r = guided_result(&t[2], px, good, 1, 1, nsn1, nqn1);
        CHECKF(srv_job_result(j, 7, &r, &err) == SRV_INVALID && strstr(err.msg, "records none"),
               "%s", err.msg);
        CHECK(pt_film_total_samples(srv_job_film(j)) == before);
    }
    /* A checkpoint keeps pass 1's distribution and statistics. */
    proto_writer w;
    proto_writer_init(&w, 1u << 24);
    CHECK(srv_job_save(j, &w, &err) == PT_OK);
    srv_job *c = NULL;
    CHECK(srv_job_new(1, &p, HASH, &c, &err) == PT_OK);
    CHECKF(c && srv_job_load(c, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
    proto_task ct;
    CHECK(c && srv_job_guide_pass(c) == 1 && srv_job_lease(c, 8, 0, 1000, &ct) &&
          ct.guide_pass == 1 && memcmp(ct.guide_hash, t[2].guide_hash, 32) == 0);
    /* It holds the distribution packed (format 10), the bytes GUIDE_GET
     * hands out; after it, u32 counts and sums listed. */
    size_t at = 4 + 4 + 8 + 32; /* the params follow; find the packed guide's magic */
    while (at + 4 <= w.len && proto_get_u32(w.buf + at) != PROTO_GUIDE_PACK_MAGIC)
        at++;
    CHECK(at + 40 < w.len && proto_get_u32(w.buf + at - 4) == len &&
          memcmp(w.buf + at, blob, len) == 0);
    /* A version 9 checkpoint: no clamped count after the depth-cap count
     * (the params are this job's: no environment map, no variant) and the
     * distribution's GUIDE bytes; it loads to the same distribution. */
    uint8_t *raw1 = NULL;
    size_t raw1len = 0;
    CHECK(proto_guide_unpack(blob, len, &raw1, &raw1len, &err) == PT_OK);
    const size_t capped_at =
        4 + 4 + 8 + 32 + 9 * 4 + 2 * 8 + 2 + strlen(p.camera) + 23 + 4 + 2 + 49;
    proto_writer v9;
    proto_writer_init(&v9, 1u << 24);
    proto_w_bytes(&v9, w.buf, capped_at + 8);
    proto_w_bytes(&v9, w.buf + capped_at + 16, at - 4 - (capped_at + 16));
    proto_w_u32(&v9, (uint32_t)raw1len);
    proto_w_bytes(&v9, raw1, raw1len);
    proto_w_bytes(&v9, w.buf + at + len, w.len - at - len);
    proto_put_u32(v9.buf + 4, 9);
    srv_job *d = NULL;
    CHECK(srv_job_new(1, &p, HASH, &d, &err) == PT_OK);
    CHECKF(d && srv_job_load(d, v9.buf, v9.len, &err) == PT_OK, "%s", err.msg);
    const uint8_t *blob9 = NULL;
    size_t len9 = 0;
    CHECK(d && srv_job_guide_pass(d) == 1 && srv_job_lease(d, 8, 0, 1000, &ct) &&
          memcmp(ct.guide_hash, t[2].guide_hash, 32) == 0 &&
          srv_job_guide_bytes(d, ct.guide_hash, &blob9, &len9));
    srv_job_free(d);
    d = NULL;
    /* A damaged distribution is refused: GUIDE bytes that do not decode (a
     * version 9 checkpoint), a packed stream that does not unpack. */
    size_t g9 = v9.len - (w.len - at - len) - raw1len;
    CHECK(proto_get_u32(v9.buf + g9) == PROTO_GUIDE_MAGIC);
    proto_put_u32(v9.buf + g9 + 40, 99); /* the root's child */
    CHECK(srv_job_new(1, &p, HASH, &d, &err) == PT_OK);
    CHECK(d && srv_job_load(d, v9.buf, v9.len, &err) == PT_ERR_FORMAT);
    srv_job_free(d);
    d = NULL;
    w.buf[at + len / 2] ^= 0x5a;
    CHECK(srv_job_new(1, &p, HASH, &d, &err) == PT_OK);
    CHECK(d && srv_job_load(d, w.buf, w.len, &err) == PT_ERR_FORMAT);
    srv_job_free(d);
    pt_free(raw1);
    proto_writer_fini(&v9);
    /* The last pass's result without statistics merges; so does one that a
     * coordinator before PROTO_GUIDE_LAST logged with them, replayed (they
     * are dropped: nothing is built from them). */
    {
        proto_result r = guided_result(&t[2], px, NULL, 0, 0, 0, 0);
        CHECKF(srv_job_result(j, 7, &r, &err) == SRV_MERGED, "%s", err.msg);
        r = guided_result(&t[2], px, good, 1, 1, nsn1, nqn1);
        CHECKF(c && srv_job_replay(c, &r, &err) == SRV_MERGED, "%s", err.msg);
        CHECK(r.guide == NULL);
        uint64_t want = (uint64_t)(t[2].tile.x1 - t[2].tile.x0) * (t[2].tile.y1 - t[2].tile.y0) *
                        (t[2].s1 - t[2].s0);
        CHECK(pt_film_total_samples(srv_job_film(j)) == before + want);
        CHECK(c && pt_film_total_samples(srv_job_film(c)) == before + want);
    }
    srv_job_free(c);
    proto_writer_fini(&w);
    srv_job_free(j);
}

/* The test hook's hold (srv_lease_policy.hold_spp): no task starting at or
 * past it is cut while its gate file is missing, whatever is asked; a
 * requeued task below it still goes out; the file there, cutting goes on. */
static void lease_hold(void)
{
    char gate[64];
    snprintf(gate, sizeof gate, "/tmp/pt_test_job_gate_%ld", (long)getpid());
    unlink(gate);
    srv_job *j = make(64, 64, 64, 32, 16); /* 2x2 tiles, chunks of 16 */
    srv_lease_policy pol = {0};
    pol.hold_spp = 32;
    pol.hold_gate = gate;
    srv_job_set_policy(j, &pol);
    proto_task t;
    uint32_t n = 0, below = 1;
    while (n < 100 && srv_job_lease(j, 1, 0, 1000, &t)) {
        below &= t.s0 < 32;
        n++;
    }
    CHECKF(n == 8 && below, "%u tasks before the hold", n);
    CHECK(srv_job_lease(j, 2, 0, 1000, &t) == 0);
    CHECK(srv_job_release_owner(j, 1) == 8);
    CHECK(srv_job_lease(j, 2, 0, 1000, &t) == 1 && t.s0 < 32);
    FILE *f = fopen(gate, "w");
    CHECK(f != NULL);
    if (f)
        fclose(f);
    n = 0;
    while (srv_job_lease(j, 2, 0, 1000, &t))
        n++;
    CHECKF(n == 7 + 8, "%u tasks once the gate exists", n);
    unlink(gate);
    srv_job_free(j);
}

int main(void)
{
    int64_t live = pt_alloc_live();
    guided();
    pass_order();
    leases();
    bit_identical();
    adaptive();
    adaptive_min_gain();
    adaptive_min_gain_black();
    bad_params();
    hard_deadlines();
    backups();
    plausible();
    verification();
    film_and_cap();
    sizing();
    fixed_chunks();
    same_film_any_cut();
    ranges_back();
    many_owners();
    answered_no_backup();
    answered_ticket();
    snapshot_saves_the_same();
    lease_hold();
    CHECK(pt_alloc_live() == live);
    return check_report();
}
