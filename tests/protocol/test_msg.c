/*
 * test_msg.c - every message of protocol/msg.c: round trips, and every way a
 * payload can be refused.
 *
 * - Each sample message (tests/protocol/samples.h, two variants) encodes,
 *   decodes back to the same fields (floats bit for bit), and its layout size
 *   matches the table in msg.h.
 * - Every proper prefix of every payload, and the payload plus one byte, is
 *   PT_ERR_PROTO, with the output left untouched.
 * - Caps and shapes: strings at and over their caps, NUL in a string, unknown
 *   role, tile order / area / image bounds, sample range, RESULT pixel count
 *   against the area, counts over their caps (refused before the bytes they
 *   announce are looked for), SCENE_CHUNK past the end of the scene.
 * - DENOISE_TASK and DENOISE_RESULT: the task bit, crop and region bounds,
 *   despeckle, the input's size, the pixel count against the region's area
 *   and the bytes against the count, each refused by the decoder and the
 *   encoder alike.
 * - RESULT into a caller's buffer and a decoder-allocated one; the allocation
 *   failure loop without leaks; no allocation for a payload refused early.
 */
#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/denoise.h"
#include "common/render/render.h"
#include "protocol/frame.h"
#include "protocol/guide.h"
#include "protocol/msg.h"
#include "tests/check.h"
#include "tests/protocol/samples.h"

/* Decodes payload as type into a scratch struct, and turns a failure that
 * touched the output into PT_OK so that the caller's check fails. */
static pt_status decode_any(uint16_t type, const uint8_t *p, size_t len, pt_error *err)
{
    static union {
        proto_hello hello;
        proto_challenge challenge;
        proto_auth auth;
        proto_welcome welcome;
        proto_error_msg error;
        proto_work_request work;
        proto_task task;
        proto_scene_get get;
        proto_scene_chunk chunk;
        proto_result result;
        proto_heartbeat hb;
        proto_job_ref ref;
        proto_fetch_frame fetch_frame;
        proto_submit submit;
        proto_job_info info;
        proto_job_list list;
        proto_denoise_task denoise_task;
        proto_denoise_result denoise_result;
    } u, before;
    memset(&u, 0xCD, sizeof u);
    before = u;
    pt_status st = PT_ERR_ARG;
    switch (type) {
    case PROTO_MSG_HELLO:
        st = proto_msg_decode_hello(p, len, &u.hello, err);
        break;
    case PROTO_MSG_CHALLENGE:
        st = proto_msg_decode_challenge(p, len, &u.challenge, err);
        break;
    case PROTO_MSG_AUTH:
        st = proto_msg_decode_auth(p, len, &u.auth, err);
        break;
    case PROTO_MSG_WELCOME:
        st = proto_msg_decode_welcome(p, len, &u.welcome, err);
        break;
    case PROTO_MSG_ERROR:
        st = proto_msg_decode_error(p, len, &u.error, err);
        break;
    case PROTO_MSG_WORK_REQUEST:
        st = proto_msg_decode_work_request(p, len, &u.work, err);
        break;
    case PROTO_MSG_TASK:
        st = proto_msg_decode_task(p, len, &u.task, err);
        break;
    case PROTO_MSG_SCENE_GET:
    case PROTO_MSG_DENOISE_GET:
        st = proto_msg_decode_scene_get(p, len, &u.get, err);
        break;
    case PROTO_MSG_SCENE_CHUNK:
    case PROTO_MSG_DENOISE_CHUNK:
        st = proto_msg_decode_scene_chunk(p, len, &u.chunk, err);
        break;
    case PROTO_MSG_DENOISE_TASK:
        st = proto_msg_decode_denoise_task(p, len, &u.denoise_task, err);
        break;
    case PROTO_MSG_DENOISE_RESULT:
        st = proto_msg_decode_denoise_result(p, len, &u.denoise_result, err);
        break;
    case PROTO_MSG_RESULT:
        st = proto_msg_decode_result(p, len, NULL, 0, &u.result, err);
        if (st == PT_OK)
            proto_result_fini(&u.result);
        break;
    case PROTO_MSG_HEARTBEAT:
        st = proto_msg_decode_heartbeat(p, len, &u.hb, err);
        break;
    case PROTO_MSG_STATUS:
    case PROTO_MSG_WATCH:
    case PROTO_MSG_CANCEL:
    case PROTO_MSG_FETCH:
    case PROTO_MSG_SUBMITTED:
    case PROTO_MSG_JOB_END:
        st = proto_msg_decode_job_ref(p, len, &u.ref, err);
        break;
    case PROTO_MSG_FETCH_FRAME:
        st = proto_msg_decode_fetch_frame(p, len, &u.fetch_frame, err);
        break;
    case PROTO_MSG_UPLOAD:
    case PROTO_MSG_IMAGE:
        st = proto_msg_decode_scene_chunk(p, len, &u.chunk, err);
        break;
    case PROTO_MSG_SUBMIT:
        st = proto_msg_decode_submit(p, len, &u.submit, err);
        break;
    case PROTO_MSG_JOB_INFO:
        st = proto_msg_decode_job_info(p, len, &u.info, err);
        break;
    case PROTO_MSG_JOB_LIST:
        st = proto_msg_decode_job_list(p, len, &u.list, err);
        if (st == PT_OK)
            pt_free(u.list.jobs);
        break;
    }
    if (st != PT_OK && memcmp(&u, &before, sizeof u) != 0) {
        fprintf(stderr, "type %u: output touched on failure\n", (unsigned)type);
        return PT_OK; /* makes the caller's CHECK fail */
    }
    return st;
}

static int acc_same(const pt_pixel_acc *a, const pt_pixel_acc *b)
{
    for (int c = 0; c < 3; c++)
        if (a->fsum[c] != b->fsum[c])
            return 0;
    return a->fsum_sq == b->fsum_sq && a->n == b->n && a->hits == b->hits;
}

static int shown_same(const proto_job_info *a, const proto_job_info *b)
{
    for (uint32_t i = 0; i < a->nshown && i < PROTO_MAX_FRAMES_SHOWN; i++)
        if (a->shown[i].frame != b->shown[i].frame ||
            a->shown[i].samples_done != b->shown[i].samples_done ||
            a->shown[i].samples_total != b->shown[i].samples_total)
            return 0;
    return 1;
}

static int job_info_same(const proto_job_info *a, const proto_job_info *b)
{
    return a->job_id == b->job_id && a->state == b->state && a->priority == b->priority &&
           strcmp(a->name, b->name) == 0 && strcmp(a->owner, b->owner) == 0 &&
           strcmp(a->scene, b->scene) == 0 && strcmp(a->output, b->output) == 0 &&
           a->width == b->width && a->height == b->height && a->spp == b->spp &&
           a->samples_done == b->samples_done && a->samples_total == b->samples_total &&
           a->passes_done == b->passes_done && a->passes == b->passes &&
           a->tiles_stopped == b->tiles_stopped && a->tiles == b->tiles &&
           a->workers == b->workers && proto_f64_bits(a->seconds) == proto_f64_bits(b->seconds) &&
           proto_f64_bits(a->rate) == proto_f64_bits(b->rate) &&
           proto_f64_bits(a->error) == proto_f64_bits(b->error) && a->submitted == b->submitted &&
           a->queue_pos == b->queue_pos && strcmp(a->message, b->message) == 0 &&
           a->capped == b->capped && a->rejected == b->rejected &&
           a->frame_first == b->frame_first && a->frame_last == b->frame_last &&
           a->frame_step == b->frame_step && a->frames_done == b->frames_done &&
           a->frames_rendering == b->frames_rendering && a->nshown == b->nshown &&
           shown_same(a, b) && a->guided == b->guided && a->guide_pass == b->guide_pass &&
           a->guide_spp == b->guide_spp && a->clamped == b->clamped && a->bdpt == b->bdpt;
}

static size_t job_info_size(const proto_job_info *m)
{
    return 162 + strlen(m->name) + strlen(m->owner) + strlen(m->scene) + strlen(m->output) +
           strlen(m->message) + 20u * m->nshown;
}

static void check_round_trip(int s, int v, const uint8_t *p, size_t len)
{
    pt_error err = {0};
    switch (s) {
    case 0: {
        proto_hello a = sample_hello(v), b;
        CHECK(proto_msg_decode_hello(p, len, &b, &err) == PT_OK);
        CHECK(len == 13 + strlen(a.name) + strlen(a.build_id));
        CHECK(a.version == b.version && a.role == b.role && a.threads == b.threads);
        CHECK(strcmp(a.name, b.name) == 0 && strcmp(a.build_id, b.build_id) == 0);
        CHECK(a.caps == b.caps);
        break;
    }
    case 1: {
        proto_challenge b;
        CHECK(len == 32 && proto_msg_decode_challenge(p, len, &b, &err) == PT_OK);
        CHECK(memcmp(b.nonce, p, 32) == 0);
        break;
    }
    case 2: {
        proto_auth b;
        CHECK(len == 64 && proto_msg_decode_auth(p, len, &b, &err) == PT_OK);
        CHECK(memcmp(b.mac, p, 32) == 0 && memcmp(b.nonce, p + 32, 32) == 0);
        break;
    }
    case 3: {
        proto_welcome b;
        CHECK(proto_msg_decode_welcome(p, len, &b, &err) == PT_OK);
        CHECK(len == 42 + strlen(b.build_id));
        CHECK(memcmp(b.proof, p + 8, 32) == 0);
        CHECK(b.session_id == (v ? 0 : 0x8877665544332211ull));
        CHECK(strcmp(b.build_id, v ? "x" : "fedcba9876543210") == 0);
        break;
    }
    case 4: {
        proto_error_msg b;
        CHECK(proto_msg_decode_error(p, len, &b, &err) == PT_OK);
        CHECK(len == 4 + strlen(b.text));
        CHECK(b.code == (v ? 999 : PROTO_E_AUTH));
        CHECK(strcmp(b.text, v ? "" : "wrong response to the challenge") == 0);
        break;
    }
    case 5: {
        proto_work_request b;
        CHECK(len == 2 && proto_msg_decode_work_request(p, len, &b, &err) == PT_OK);
        CHECK(b.slots == (v ? PROTO_MAX_SLOTS : 9));
        break;
    }
    case 6: {
        proto_task a = sample_task(v), b;
        CHECK(len == 195 + strlen(a.camera) + strlen(a.env.name) + strlen(a.variant) +
                         strlen(a.animation) &&
              proto_msg_decode_task(p, len, &b, &err) == PT_OK);
        CHECK(a.animate == b.animate && proto_f64_bits(a.time) == proto_f64_bits(b.time) &&
              strcmp(a.animation, b.animation) == 0);
        CHECK(strcmp(a.camera, b.camera) == 0 && a.film_flags == b.film_flags);
        CHECK(memcmp(a.shutter, b.shutter, sizeof a.shutter) == 0);
        CHECK(memcmp(a.clamp, b.clamp, sizeof a.clamp) == 0);
        CHECK(strcmp(a.variant, b.variant) == 0);
        CHECK(proto_env_same(&a.env, &b.env));
        CHECK(a.job_id == b.job_id && a.task_id == b.task_id);
        CHECK(memcmp(&a.tile, &b.tile, sizeof a.tile) == 0);
        CHECK(a.s0 == b.s0 && a.s1 == b.s1 && a.width == b.width && a.height == b.height);
        CHECK(a.seed == b.seed && a.max_depth == b.max_depth && a.rr_depth == b.rr_depth);
        CHECK(memcmp(a.scene_hash, b.scene_hash, 32) == 0 && a.lease_ms == b.lease_ms);
        break;
    }
    case 7: {
        proto_scene_get b;
        CHECK(len == 40 && proto_msg_decode_scene_get(p, len, &b, &err) == PT_OK);
        CHECK(b.offset == (v ? 1u << 20 : 0) && b.hash[1] == (uint8_t)(37 + 5 + v));
        break;
    }
    case 8: {
        proto_scene_chunk b;
        CHECK(proto_msg_decode_scene_chunk(p, len, &b, &err) == PT_OK);
        CHECK(len == 52 + b.len);
        CHECK(b.offset == (v ? 1000u : 0) && b.total == (v ? 1000u : 4096u));
        CHECK(b.len == (v ? 0 : sizeof sample_scene_bytes));
        CHECK(b.data == p + 52 && memcmp(b.data, sample_scene_bytes, b.len) == 0);
        break;
    }
    case 9: {
        proto_result a = sample_result(v), b;
        CHECK(proto_msg_decode_result(p, len, NULL, 0, &b, &err) == PT_OK);
        /* v = 1: narrow, 40 bytes a pixel; v = 0: wide, 72. */
        CHECK(len == 69 + (v ? 40 : 72) * (size_t)a.npixels);
        CHECK(p[68] == (v ? 0 : 3));
        CHECK(a.job_id == b.job_id && a.task_id == b.task_id && a.s0 == b.s0 && a.s1 == b.s1);
        CHECK(memcmp(&a.tile, &b.tile, sizeof a.tile) == 0);
        CHECK(a.rejected == b.rejected && a.rays == b.rays && a.npixels == b.npixels);
        CHECK(a.capped == b.capped);
        CHECK(b.owns_pixels == 1);
        int same = 1;
        for (uint32_t i = 0; i < a.npixels; i++)
            same &= acc_same(&a.pixels[i], &b.pixels[i]);
        CHECK(same);
        proto_result_fini(&b);
        CHECK(b.pixels == NULL);
        proto_result_fini(&b);
        proto_result_fini(NULL);
        /* Into the caller's buffer: exact fit works, one short is PT_ERR_LIMIT. */
        pt_pixel_acc buf[12];
        CHECK(proto_msg_decode_result(p, len, buf, a.npixels, &b, &err) == PT_OK);
        CHECK(b.pixels == buf && b.owns_pixels == 0 && acc_same(&buf[0], &a.pixels[0]));
        proto_result_fini(&b);
        CHECK(proto_msg_decode_result(p, len, buf, a.npixels - 1, &b, &err) == PT_ERR_LIMIT);
        pt_error_clear(&err);
        break;
    }
    case 10: {
        proto_heartbeat *a = sample_heartbeat(v);
        static proto_heartbeat b;
        CHECK(len == 2 + 8 * (size_t)a->count);
        CHECK(proto_msg_decode_heartbeat(p, len, &b, &err) == PT_OK);
        CHECK(b.count == a->count);
        CHECK(memcmp(a->task_ids, b.task_ids, 8 * (size_t)a->count) == 0);
        break;
    }
    case 11: {
        proto_job_ref b;
        CHECK(len == 8 && proto_msg_decode_job_ref(p, len, &b, &err) == PT_OK);
        CHECK(b.job_id == (v ? UINT64_MAX : 42));
        break;
    }
    case 12: {
        proto_submit a = sample_submit(v), b;
        CHECK(proto_msg_decode_submit(p, len, &b, &err) == PT_OK);
        CHECK(len == 162 + strlen(a.name) + strlen(a.camera) + strlen(a.env.name) +
                         strlen(a.variant) + strlen(a.animation));
        CHECK(a.frame_first == b.frame_first && a.frame_last == b.frame_last &&
              a.frame_step == b.frame_step && proto_f64_bits(a.fps) == proto_f64_bits(b.fps) &&
              strcmp(a.animation, b.animation) == 0);
        CHECK(strcmp(a.camera, b.camera) == 0 && a.film_flags == b.film_flags);
        CHECK(memcmp(a.shutter, b.shutter, sizeof a.shutter) == 0);
        CHECK(memcmp(a.clamp, b.clamp, sizeof a.clamp) == 0);
        CHECK(strcmp(a.variant, b.variant) == 0);
        CHECK(proto_env_same(&a.env, &b.env));
        CHECK(strcmp(a.name, b.name) == 0 && a.width == b.width && a.height == b.height);
        CHECK(a.spp == b.spp && a.seed == b.seed && a.priority == b.priority);
        CHECK(a.max_depth == b.max_depth && a.min_spp == b.min_spp);
        CHECK(proto_f64_bits(a.target_error) == proto_f64_bits(b.target_error));
        CHECK(proto_f64_bits(a.min_gain) == proto_f64_bits(b.min_gain));
        CHECK(a.bundle_size == b.bundle_size && memcmp(a.bundle_hash, b.bundle_hash, 32) == 0);
        break;
    }
    case 13: {
        proto_job_info a = sample_job_info(v), b;
        CHECK(proto_msg_decode_job_info(p, len, &b, &err) == PT_OK);
        CHECK(len == job_info_size(&a));
        CHECK(job_info_same(&a, &b));
        break;
    }
    case 14: {
        proto_job_list b;
        CHECK(proto_msg_decode_job_list(p, len, &b, &err) == PT_OK);
        CHECK(b.count == (v ? 0u : 3u));
        size_t want = 4;
        for (uint32_t k = 0; k < b.count; k++) {
            proto_job_info a = sample_job_info((int)k);
            want += job_info_size(&a);
            CHECKF(job_info_same(&a, &b.jobs[k]), "JOB_LIST entry %u", (unsigned)k);
        }
        CHECK(len == want);
        CHECK(v == 0 || b.jobs == NULL);
        pt_free(b.jobs);
        break;
    }
    case 15: {
        proto_denoise_task a = sample_denoise_task(v), b;
        CHECK(len == 88 && proto_msg_decode_denoise_task(p, len, &b, &err) == PT_OK);
        CHECK(a.job_id == b.job_id && a.task_id == b.task_id && a.crop_w == b.crop_w &&
              a.crop_h == b.crop_h);
        CHECK(memcmp(&a.region, &b.region, sizeof a.region) == 0);
        CHECK(proto_f32_bits(a.despeckle) == proto_f32_bits(b.despeckle));
        CHECK(a.lease_ms == b.lease_ms && memcmp(a.hash, b.hash, 32) == 0 && a.size == b.size);
        /* The fields at the table's offsets. */
        CHECK(proto_get_u32(p + 16) == a.crop_w && proto_get_u32(p + 36) == a.region.y1);
        CHECK(proto_get_f32(p + 40) == a.despeckle && proto_get_u32(p + 44) == a.lease_ms);
        CHECK(p[48 + 1] == a.hash[1] && proto_get_u64(p + 80) == a.size);
        break;
    }
    case 16: {
        proto_denoise_result a = sample_denoise_result(v), b;
        CHECK(proto_msg_decode_denoise_result(p, len, &b, &err) == PT_OK);
        CHECK(len == 36 + 12 * (size_t)a.npixels);
        CHECK(a.job_id == b.job_id && a.task_id == b.task_id && a.npixels == b.npixels);
        CHECK(memcmp(&a.region, &b.region, sizeof a.region) == 0);
        /* Borrowed from the payload, the bytes verbatim (NaN's payload too). */
        CHECK(b.data == p + 36 && memcmp(b.data, a.data, 12 * (size_t)a.npixels) == 0);
        CHECK(proto_get_u32(p + 32) == a.npixels);
        break;
    }
    }
    CHECKF(err.code == PT_OK, "sample %d: %s", s, err.msg);
}

static void test_samples(void)
{
    for (int s = 0; s < SAMPLE_COUNT; s++) {
        for (int v = 0; v < 2; v++) {
            proto_writer w;
            proto_writer_init(&w, PROTO_MAX_PAYLOAD);
            uint16_t type = sample_payload(s, v, &w);
            CHECKF(type != 0, "sample %d variant %d does not encode", s, v);
            if (!type) {
                proto_writer_fini(&w);
                continue;
            }
            check_round_trip(s, v, w.buf, w.len);
            /* Every proper prefix is refused, as PT_ERR_PROTO, untouched output. */
            int bad = 0;
            pt_error err = {0};
            for (size_t k = 0; k < w.len; k++) {
                /* A copy of exactly k bytes, so ASan sees any read past them. */
                uint8_t *c = pt_malloc(k);
                memcpy(c, w.buf, k);
                bad += decode_any(type, c, k, &err) != PT_ERR_PROTO;
                pt_free(c);
            }
            CHECKF(bad == 0, "sample %d variant %d: %d prefixes not refused", s, v, bad);
            CHECK(decode_any(type, w.buf, w.len, &err) == PT_OK);
            proto_w_u8(&w, 0);
            CHECK(decode_any(type, w.buf, w.len, &err) == PT_ERR_PROTO);
            CHECK(strstr(err.msg, "trailing") != NULL);
            proto_writer_fini(&w);
        }
    }
}

/* ---- hand-made payloads ---- */

static void w_str(proto_writer *w, size_t n, char fill)
{
    proto_w_u16(w, (uint16_t)n);
    for (size_t i = 0; i < n; i++)
        proto_w_u8(w, (uint8_t)fill);
}

static pt_status hello_raw(uint8_t role, size_t name_len, char name_fill, size_t build_len,
                           pt_error *err)
{
    proto_writer w;
    proto_writer_init(&w, 1u << 20);
    proto_w_u16(&w, PROTO_VERSION);
    proto_w_u8(&w, role);
    w_str(&w, name_len, name_fill);
    proto_w_u16(&w, 4);
    w_str(&w, build_len, 'b');
    proto_w_u32(&w, 0);
    pt_status st = decode_any(PROTO_MSG_HELLO, w.buf, w.len, err);
    proto_writer_fini(&w);
    return st;
}

static void test_strings(void)
{
    pt_error err = {0};
    CHECK(hello_raw(PROTO_ROLE_WORKER, 64, 'n', 64, &err) == PT_OK);
    CHECK(hello_raw(PROTO_ROLE_WORKER, 0, 'n', 0, &err) == PT_OK);
    CHECK(hello_raw(PROTO_ROLE_WORKER, 65, 'n', 10, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "name") != NULL);
    CHECK(hello_raw(PROTO_ROLE_WORKER, 10, 'n', 65, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "build id") != NULL);
    CHECK(hello_raw(PROTO_ROLE_WORKER, 65535, 'n', 10, &err) == PT_ERR_PROTO);
    CHECK(hello_raw(PROTO_ROLE_WORKER, 5, '\0', 10, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "NUL") != NULL);
    CHECK(hello_raw(PROTO_ROLE_CLIENT, 5, 'n', 10, &err) == PT_OK);
    CHECK(hello_raw(0, 5, 'n', 10, &err) == PT_ERR_PROTO);
    CHECK(hello_raw(3, 5, 'n', 10, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "role") != NULL);

    /* A string length over the cap is refused before its bytes are looked for. */
    uint8_t head[5] = {1, 0, 1, 65, 0};
    CHECK(decode_any(PROTO_MSG_HELLO, head, sizeof head, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "cap") != NULL);

    /* ERROR text: 1024 bytes fit, 1025 do not. */
    for (size_t n = 1023; n <= 1026; n++) {
        proto_writer w;
        proto_writer_init(&w, 4096);
        proto_w_u16(&w, PROTO_E_LIMIT);
        w_str(&w, n, 'e');
        pt_status st = decode_any(PROTO_MSG_ERROR, w.buf, w.len, &err);
        CHECKF(st == (n <= PROTO_MAX_ERROR_TEXT ? PT_OK : PT_ERR_PROTO), "text of %zu", n);
        proto_writer_fini(&w);
    }

    /* Encoders refuse what decoders would. */
    proto_writer w;
    proto_writer_init(&w, 1u << 16);
    proto_hello h = sample_hello(0);
    memset(h.name, 'n', sizeof h.name); /* 65 bytes, no terminator inside the cap */
    CHECK(proto_msg_encode_hello(&w, &h, &err) == PT_ERR_ARG);
    h = sample_hello(0);
    memset(h.build_id, 'b', sizeof h.build_id);
    CHECK(proto_msg_encode_hello(&w, &h, &err) == PT_ERR_ARG);
    CHECK(w.len == 0); /* refused before a byte is written */
    h = sample_hello(0);
    h.role = 7;
    CHECK(proto_msg_encode_hello(&w, &h, &err) == PT_ERR_ARG);
    proto_welcome wm;
    wm.session_id = 1;
    memset(wm.build_id, 'b', sizeof wm.build_id);
    CHECK(proto_msg_encode_welcome(&w, &wm, &err) == PT_ERR_ARG);
    static proto_error_msg em;
    em.code = 1;
    memset(em.text, 't', sizeof em.text);
    CHECK(proto_msg_encode_error(&w, &em, &err) == PT_ERR_ARG);
    em.text[PROTO_MAX_ERROR_TEXT] = '\0';
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_error(&w, &em, &err) == PT_OK);
    CHECK(w.len == 4 + PROTO_MAX_ERROR_TEXT);
    /* The longest ERROR fits under the pre-authentication cap. */
    CHECK(w.len <= PROTO_MAX_PAYLOAD_PREAUTH);
    proto_writer_fini(&w);
}

/* An ENV block by hand: no environment. */
static void w_env_none(proto_writer *w)
{
    proto_w_u16(w, 0);
    proto_w_f32(w, 1.0f);
    proto_w_f32(w, 0.0f);
    proto_w_u8(w, 0);
    for (int k = 0; k < 3; k++)
        proto_w_f32(w, 0.0f);
}

static proto_writer task_raw(pt_rect t, uint32_t s0, uint32_t s1, uint32_t width, uint32_t height)
{
    proto_writer w;
    proto_writer_init(&w, 1024);
    proto_w_u64(&w, 1);
    proto_w_u64(&w, 2);
    proto_w_u32(&w, t.x0);
    proto_w_u32(&w, t.y0);
    proto_w_u32(&w, t.x1);
    proto_w_u32(&w, t.y1);
    proto_w_u32(&w, s0);
    proto_w_u32(&w, s1);
    proto_w_u32(&w, width);
    proto_w_u32(&w, height);
    proto_w_u32(&w, 5);
    proto_w_u16(&w, 16);
    proto_w_u16(&w, 3);
    for (int i = 0; i < 32; i++)
        proto_w_u8(&w, (uint8_t)i);
    proto_w_u32(&w, 1000);
    proto_w_u16(&w, 0); /* camera: "" */
    w_env_none(&w);
    proto_w_u32(&w, 0); /* film flags */
    proto_w_u16(&w, 0); /* variant: "" */
    proto_w_u8(&w, 0);  /* animate: a still */
    proto_w_f64(&w, 0.0);
    proto_w_u16(&w, 0);   /* animation: "" */
    proto_w_f64(&w, 0.0); /* shutter: off */
    proto_w_f64(&w, 0.0);
    proto_w_f32(&w, 0.0f); /* clamps: off */
    proto_w_f32(&w, 0.0f);
    proto_w_u8(&w, 0); /* not guided: pass 0, no hash */
    proto_w_u32(&w, 0);
    for (int i = 0; i < 32; i++)
        proto_w_u8(&w, 0);
    return w;
}

/* Bytes of a TASK's pose, its last fields: animate, time, animation. */
#define POSE_TAIL(t) (1 + 8 + 2 + strlen((t).animation))

static pt_status task_check(pt_rect t, uint32_t s0, uint32_t s1, uint32_t width, uint32_t height,
                            const char *want, pt_error *err)
{
    proto_writer w = task_raw(t, s0, s1, width, height);
    pt_status st = decode_any(PROTO_MSG_TASK, w.buf, w.len, err);
    proto_writer_fini(&w);
    if (st != PT_OK && want && !strstr(err->msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err->msg);
        return PT_OK;
    }
    /* The encoder agrees with the decoder. */
    proto_task m = sample_task(0);
    m.tile = t;
    m.s0 = s0;
    m.s1 = s1;
    m.width = width;
    m.height = height;
    proto_writer e;
    proto_writer_init(&e, 1024);
    pt_status est = proto_msg_encode_task(&e, &m, NULL);
    proto_writer_fini(&e);
    if ((st == PT_OK) != (est == PT_OK)) {
        fprintf(stderr, "encoder and decoder disagree\n");
        return PT_ERR_ARG;
    }
    return st;
}

static void test_task(void)
{
    pt_error err = {0};
    CHECK(task_check((pt_rect){0, 0, 64, 64}, 0, 16, 64, 64, NULL, &err) == PT_OK);
    CHECK(task_check((pt_rect){0, 0, 256, 256}, 0, 1, 256, 256, NULL, &err) == PT_OK);
    CHECK(task_check((pt_rect){5, 0, 5, 8}, 0, 16, 64, 64, "x0", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){6, 0, 5, 8}, 0, 16, 64, 64, "x0", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 8, 5, 8}, 0, 16, 64, 64, "y0", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 257, 256}, 0, 16, 512, 512, "area", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, UINT32_MAX, UINT32_MAX}, 0, 16, UINT32_MAX, UINT32_MAX, "area",
                     &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 65, 64}, 0, 16, 64, 64, "outside", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 64, 65}, 0, 16, 64, 64, "outside", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 8, 8}, 16, 16, 64, 64, "s0", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 8, 8}, 17, 16, 64, 64, "s0", &err) == PT_ERR_PROTO);
    CHECK(task_check((pt_rect){0, 0, 8, 8}, 0, UINT32_MAX, 64, 64, NULL, &err) == PT_OK);

    /* The environment: a bad field refused by the decoder and the encoder. */
    for (int k = 0; k < 4; k++) {
        proto_task e = sample_task(k & 1);
        if (k == 0)
            e.env.rgb[2] = NAN;
        else if (k == 1)
            e.env.strength = INFINITY;
        else if (k == 2)
            e.env.background = 3;
        else
            e.env.background = 1; /* and the map it names: two environments */
        proto_writer ew;
        proto_writer_init(&ew, 1024);
        CHECKF(proto_msg_encode_task(&ew, &e, &err) == PT_ERR_ARG && ew.len == 0, "env case %d", k);
        proto_task good = sample_task(k & 1);
        CHECK(proto_msg_encode_task(&ew, &good, &err) == PT_OK);
        /* Patch the bad value into the good bytes: the ENV block, then the
         * film flags, the variant, the pose, the shutter and the clamps end
         * the message. */
        uint8_t *env_at = ew.buf + ew.len - 37 - 8 - 16 - POSE_TAIL(good) - 2 -
                          strlen(good.variant) - 4 - 23 - strlen(good.env.name);
        if (k == 0)
            proto_put_u32(env_at + 19, 0x7FC00000u); /* rgb[2], the name empty */
        else if (k == 1)
            proto_put_u32(env_at + 2 + strlen(good.env.name), 0x7F800000u);
        else if (k == 2)
            env_at[2 + strlen(good.env.name) + 8] = 3;
        if (k < 3)
            CHECKF(decode_any(PROTO_MSG_TASK, ew.buf, ew.len, &err) == PT_ERR_PROTO &&
                       strstr(err.msg, "TASK") != NULL,
                   "env case %d: %s", k, err.msg);
        proto_writer_fini(&ew);
    }

    /* The camera name: at its cap, one over it (refused both ways). */
    proto_task t = sample_task(0);
    memset(t.camera, 'c', PROTO_MAX_NAME);
    t.camera[PROTO_MAX_NAME] = '\0';
    proto_writer w;
    proto_writer_init(&w, 1024);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    proto_task back;
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          strcmp(back.camera, t.camera) == 0);
    proto_writer_reset(&w);
    proto_writer raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
    raw.len -= 2 + 23 + 4 + 2 + 11 + 16 + 8 + 37; /* the empty camera, ENV, film flags, variant,
                                                pose, shutter, clamps */
    proto_w_u16(&raw, PROTO_MAX_NAME + 1);
    for (uint32_t i = 0; i <= PROTO_MAX_NAME; i++)
        proto_w_u8(&raw, 'c');
    proto_w_u32(&raw, 0);
    proto_w_u16(&raw, 0);
    proto_w_f64(&raw, 0.0);
    proto_w_f64(&raw, 0.0);
    CHECK(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
          strstr(err.msg, "camera"));
    proto_writer_fini(&raw);

    /* Film flags: the transparent bit travels; an unknown bit is refused both ways. */
    t = sample_task(1);
    CHECK(t.film_flags == PROTO_FILM_TRANSPARENT);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          back.film_flags == PROTO_FILM_TRANSPARENT);
    t.film_flags = PROTO_FILM_DENOISE | proto_film_of_passes(PT_PASS_ALBEDO);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          back.film_flags == t.film_flags);
    t.film_flags = PROTO_FILM_KNOWN + 1u; /* the lowest bit not defined */
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0);
    raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
    proto_put_u32(raw.buf + raw.len - 37 - 8 - 16 - 11 - 6, 0x80000000u);
    CHECK(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
          strstr(err.msg, "film flags"));
    proto_writer_fini(&raw);

    /* The variant name travels at the end: at its cap it round-trips, one
     * over is refused both ways, and the protocol-3 layout before it (no
     * variant field) is a truncated TASK. */
    t = sample_task(0);
    CHECK(strcmp(t.variant, "Peacock Velvet") == 0);
    memset(t.variant, 'v', PROTO_MAX_NAME);
    t.variant[PROTO_MAX_NAME] = '\0';
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          strcmp(back.variant, t.variant) == 0);
    raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
    raw.len -= 2 + 11 + 16 + 8 + 37; /* the empty variant, the pose, shutter, clamps, guide */
    proto_w_u16(&raw, PROTO_MAX_NAME + 1);
    for (uint32_t i = 0; i <= PROTO_MAX_NAME; i++)
        proto_w_u8(&raw, 'v');
    CHECK(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
          strstr(err.msg, "variant"));
    raw.len -= 2 + PROTO_MAX_NAME + 1;
    CHECK(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO);
    proto_writer_fini(&raw);
    memset(t.variant, 'w', sizeof t.variant);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0);

    /* The shutter comes before the clamps: it round-trips; open after close,
     * negative, NaN or over the cap is refused both ways. */
    t = sample_task(0);
    CHECK(t.shutter[1] > t.shutter[0]);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          memcmp(back.shutter, t.shutter, sizeof t.shutter) == 0);
    const double bad_shutters[][2] = {{0.5, 0.25}, {-1.0, 0.0},     {0.0, NAN},
                                      {NAN, 0.0},  {0.0, INFINITY}, {0.0, 3601.0}};
    for (size_t k = 0; k < sizeof bad_shutters / sizeof *bad_shutters; k++) {
        t.shutter[0] = bad_shutters[k][0];
        t.shutter[1] = bad_shutters[k][1];
        proto_writer_reset(&w);
        CHECKF(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0, "shutter %zu", k);
        raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
        proto_put_f64(raw.buf + raw.len - 37 - 8 - 16, bad_shutters[k][0]);
        proto_put_f64(raw.buf + raw.len - 37 - 8 - 8, bad_shutters[k][1]);
        CHECKF(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
                   strstr(err.msg, "shutter"),
               "shutter %zu: %s", k, err.msg);
        proto_writer_fini(&raw);
    }

    /* The clamps end the message: they round-trip bit for bit; negative,
     * NaN, infinite or over the cap is refused both ways, naming the limit;
     * the protocol-7 layout without them is a truncated TASK. */
    t = sample_task(0);
    CHECK(t.clamp[1] == 10.0f);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
          memcmp(back.clamp, t.clamp, sizeof t.clamp) == 0);
    const float bad_clamps[] = {-1.0f, -1e-30f, NAN, -NAN, INFINITY, 2e30f};
    for (size_t k = 0; k < sizeof bad_clamps / sizeof *bad_clamps; k++) {
        for (int c = 0; c < 2; c++) {
            t = sample_task(1);
            t.clamp[c] = bad_clamps[k];
            proto_writer_reset(&w);
            CHECKF(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0, "clamp %zu", k);
            raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
            proto_put_u32(raw.buf + raw.len - 37 - 8 + 4 * c, proto_f32_bits(bad_clamps[k]));
            CHECKF(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
                       strstr(err.msg, c ? "clamp indirect" : "clamp direct"),
                   "clamp %zu: %s", k, err.msg);
            proto_writer_fini(&raw);
        }
    }
    raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
    raw.len -= 8 + 37;
    CHECK(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
          strstr(err.msg, "truncated"));
    proto_writer_fini(&raw);

    /* GUIDE ends the message: the flag (not guided, guided and recording,
     * guided in the last pass without recording), the pass and the hash
     * round-trip; a flag over 2, a pass over 31, and a pass or a hash
     * without guiding are refused both ways. */
    const uint8_t flags[] = {PROTO_GUIDE_NONE, PROTO_GUIDE_RECORD, PROTO_GUIDE_LAST};
    for (size_t k = 0; k < sizeof flags; k++) {
        t = sample_task((int)k & 1);
        t.guided = flags[k];
        t.guide_pass = flags[k] ? 31u - (uint32_t)k : 0;
        for (int i = 0; i < 32; i++)
            t.guide_hash[i] = flags[k] ? (uint8_t)(i * 7 + k) : 0;
        proto_writer_reset(&w);
        CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK && w.buf[w.len - 37] == flags[k]);
        memset(&back, 0xAB, sizeof back);
        CHECKF(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK &&
                   back.guided == flags[k] && back.guide_pass == t.guide_pass &&
                   memcmp(back.guide_hash, t.guide_hash, 32) == 0,
               "guide flag %u: %s", flags[k], err.msg);
    }
    for (int k = 0; k < 4; k++) {
        t = sample_task(0);
        t.guided = k == 0 ? 3 : k == 1 ? PROTO_GUIDE_LAST : PROTO_GUIDE_NONE;
        t.guide_pass = k == 1 ? 32 : k == 2 ? 1 : 0;
        t.guide_hash[5] = k == 3;
        proto_writer_reset(&w);
        CHECKF(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0, "guide case %d", k);
        raw = task_raw((pt_rect){0, 0, 8, 8}, 0, 16, 64, 64);
        raw.buf[raw.len - 37] = t.guided;
        proto_put_u32(raw.buf + raw.len - 36, t.guide_pass);
        raw.buf[raw.len - 32 + 5] = t.guide_hash[5];
        CHECKF(decode_any(PROTO_MSG_TASK, raw.buf, raw.len, &err) == PT_ERR_PROTO &&
                   strstr(err.msg, "guid"),
               "guide case %d: %s", k, err.msg);
        proto_writer_fini(&raw);
    }
    proto_writer_fini(&w);
}

static void test_counts(void)
{
    pt_error err = {0};
    uint8_t b[2];
    proto_put_u16(b, PROTO_MAX_SLOTS);
    CHECK(decode_any(PROTO_MSG_WORK_REQUEST, b, 2, &err) == PT_OK);
    proto_put_u16(b, PROTO_MAX_SLOTS + 1);
    CHECK(decode_any(PROTO_MSG_WORK_REQUEST, b, 2, &err) == PT_ERR_PROTO);
    proto_work_request wr = {PROTO_MAX_SLOTS + 1};
    proto_writer w;
    proto_writer_init(&w, 1u << 24);
    CHECK(proto_msg_encode_work_request(&w, &wr, &err) == PT_ERR_ARG);

    /* HEARTBEAT: the cap, one over it (refused on the count alone), and a
     * count that promises more ids than are present. */
    proto_writer_reset(&w);
    proto_w_u16(&w, PROTO_MAX_HEARTBEAT_TASKS);
    for (unsigned i = 0; i < PROTO_MAX_HEARTBEAT_TASKS; i++)
        proto_w_u64(&w, i);
    CHECK(decode_any(PROTO_MSG_HEARTBEAT, w.buf, w.len, &err) == PT_OK);
    proto_put_u16(b, PROTO_MAX_HEARTBEAT_TASKS + 1);
    CHECK(decode_any(PROTO_MSG_HEARTBEAT, b, 2, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "cap") != NULL);
    proto_put_u16(b, 0xFFFF);
    CHECK(decode_any(PROTO_MSG_HEARTBEAT, b, 2, &err) == PT_ERR_PROTO);
    proto_put_u16(w.buf, 3);
    CHECK(decode_any(PROTO_MSG_HEARTBEAT, w.buf, 2 + 8 * 3 - 1, &err) == PT_ERR_PROTO);
    static proto_heartbeat hb;
    hb.count = PROTO_MAX_HEARTBEAT_TASKS + 1;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_heartbeat(&w, &hb, &err) == PT_ERR_ARG);

    /* SCENE_CHUNK: 1 MiB fits; one more byte is refused on the length alone. */
    static uint8_t data[PROTO_MAX_SCENE_CHUNK + 1];
    proto_scene_chunk c;
    memset(&c, 0, sizeof c);
    c.len = PROTO_MAX_SCENE_CHUNK;
    c.total = PROTO_MAX_SCENE_CHUNK;
    c.data = data;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_scene_chunk(&w, &c, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_SCENE_CHUNK, w.buf, w.len, &err) == PT_OK);
    c.len++;
    c.total++;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_scene_chunk(&w, &c, &err) == PT_ERR_ARG);
    proto_writer_reset(&w);
    proto_w_bytes(&w, data, 32);
    proto_w_u64(&w, 0);
    proto_w_u64(&w, UINT64_MAX);
    proto_w_u32(&w, PROTO_MAX_SCENE_CHUNK + 1);
    CHECK(decode_any(PROTO_MSG_SCENE_CHUNK, w.buf, w.len, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "cap") != NULL);
    /* Chunks past the end of the scene, including offsets that would wrap. */
    static const uint64_t cases[][3] = {
        {0, 9, 10},
        {1, 10, 10},
        {11, 10, 0},
        {UINT64_MAX, UINT64_MAX, 2},
        {UINT64_MAX - 1, UINT64_MAX, 2},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        proto_writer_reset(&w);
        proto_w_bytes(&w, data, 32);
        proto_w_u64(&w, cases[i][0]);
        proto_w_u64(&w, cases[i][1]);
        proto_w_u32(&w, (uint32_t)cases[i][2]);
        proto_w_bytes(&w, data, (size_t)cases[i][2]);
        CHECKF(decode_any(PROTO_MSG_SCENE_CHUNK, w.buf, w.len, &err) == PT_ERR_PROTO, "case %zu",
               i);
        c.offset = cases[i][0];
        c.total = cases[i][1];
        c.len = (uint32_t)cases[i][2];
        proto_writer_reset(&w);
        CHECK(proto_msg_encode_scene_chunk(&w, &c, &err) == PT_ERR_ARG);
    }
    proto_writer_reset(&w);
    proto_w_bytes(&w, data, 32);
    proto_w_u64(&w, UINT64_MAX - 2);
    proto_w_u64(&w, UINT64_MAX);
    proto_w_u32(&w, 2);
    proto_w_u16(&w, 0);
    CHECK(decode_any(PROTO_MSG_SCENE_CHUNK, w.buf, w.len, &err) == PT_OK);
    proto_writer_fini(&w);
}

/* A RESULT header for tile t claiming n pixels, followed by `have` pixels
 * whose sample count is pixel_n. */
static proto_writer result_raw(pt_rect t, uint32_t s0, uint32_t s1, uint32_t n, uint32_t have,
                               uint32_t pixel_n, uint32_t pixel_hits)
{
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    proto_w_u64(&w, 1);
    proto_w_u64(&w, 2);
    proto_w_u32(&w, t.x0);
    proto_w_u32(&w, t.y0);
    proto_w_u32(&w, t.x1);
    proto_w_u32(&w, t.y1);
    proto_w_u32(&w, s0);
    proto_w_u32(&w, s1);
    proto_w_u64(&w, 0);
    proto_w_u64(&w, 0);
    proto_w_u64(&w, 0);
    proto_w_u32(&w, n);
    proto_w_u8(&w, 0); /* narrow */
    for (uint32_t i = 0; i < have; i++) {
        for (int k = 0; k < 4; k++)
            proto_w_u64(&w, 1ull << 32);
        proto_w_u32(&w, pixel_n);
        proto_w_u32(&w, pixel_hits);
    }
    return w;
}

static pt_status result_hits_check(pt_rect t, uint32_t s0, uint32_t s1, uint32_t n, uint32_t have,
                                   uint32_t pixel_n, uint32_t pixel_hits, const char *want,
                                   int *allocated)
{
    proto_writer w = result_raw(t, s0, s1, n, have, pixel_n, pixel_hits);
    pt_error err = {0};
    proto_result r;
    pt_alloc_fail_at(0); /* resets the allocation counter */
    pt_status st = proto_msg_decode_result(w.buf, w.len, NULL, 0, &r, &err);
    *allocated = (int)pt_alloc_count();
    if (st == PT_OK)
        proto_result_fini(&r);
    proto_writer_fini(&w);
    if (st != PT_OK && want && !strstr(err.msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err.msg);
        return PT_OK;
    }
    return st;
}

static pt_status result_check(pt_rect t, uint32_t s0, uint32_t s1, uint32_t n, uint32_t have,
                              uint32_t pixel_n, const char *want, int *allocated)
{
    return result_hits_check(t, s0, s1, n, have, pixel_n, 0, want, allocated);
}

static void test_result(void)
{
    int alloc = 0;
    int64_t live = pt_alloc_live();
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 8, 8, NULL, &alloc) == PT_OK);
    CHECK(alloc == 1);
    CHECK(result_check((pt_rect){0, 0, 256, 256}, 0, 8, 65536, 65536, 0, NULL, &alloc) == PT_OK);
    /* Refused before any allocation: */
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 7, 7, 1, "area", &alloc) == PT_ERR_PROTO);
    CHECK(alloc == 0);
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 9, 9, 1, "area", &alloc) == PT_ERR_PROTO);
    CHECK(alloc == 0);
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 7, 1, "truncated", &alloc) == PT_ERR_PROTO);
    CHECK(alloc == 0);
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 9, 1, "trailing", &alloc) == PT_ERR_PROTO);
    CHECK(alloc == 0);
    CHECK(result_check((pt_rect){0, 0, 257, 256}, 0, 8, 257 * 256, 0, 1, "cap", &alloc) ==
          PT_ERR_PROTO);
    CHECK(alloc == 0);
    /* An area that wraps 32 bits (65536 x 65536 = 2^32 -> 0) and a count of 0. */
    CHECK(result_check((pt_rect){0, 0, 65536, 65536}, 0, 8, 0, 0, 1, "cap", &alloc) ==
          PT_ERR_PROTO);
    CHECK(result_check((pt_rect){0, 0, UINT32_MAX, UINT32_MAX}, 0, 8, UINT32_MAX, 0, 1, "cap",
                       &alloc) == PT_ERR_PROTO);
    CHECK(alloc == 0);
    CHECK(result_check((pt_rect){4, 0, 4, 2}, 0, 8, 0, 0, 1, "x0", &alloc) == PT_ERR_PROTO);
    CHECK(result_check((pt_rect){0, 3, 4, 2}, 0, 8, 0, 0, 1, "y0", &alloc) == PT_ERR_PROTO);
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 8, 8, 8, 8, 0, "s0", &alloc) == PT_ERR_PROTO);
    CHECK(result_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 8, 9, "sample count", &alloc) ==
          PT_ERR_PROTO);
    CHECK(alloc == 0);
    /* Camera hits: up to the pixel's count, not one more. */
    CHECK(result_hits_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 8, 5, 5, NULL, &alloc) == PT_OK);
    CHECK(result_hits_check((pt_rect){0, 0, 4, 2}, 0, 8, 8, 8, 5, 6, "hits", &alloc) ==
          PT_ERR_PROTO);
    CHECK(alloc == 0);
    /* The pixel form: 0 narrow, 1 wide (72-byte pixels), nothing else. */
    {
        proto_writer raw = result_raw((pt_rect){0, 0, 4, 2}, 0, 8, 8, 8, 8, 0);
        proto_result r;
        pt_error e = {0};
        raw.buf[68] = 1; /* wide RGB, but 40-byte pixels: 8 x 64 bytes are not there */
        CHECK(proto_msg_decode_result(raw.buf, raw.len, NULL, 0, &r, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "truncated"));
        raw.buf[68] = 64;
        CHECK(proto_msg_decode_result(raw.buf, raw.len, NULL, 0, &r, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "pixel form"));
        raw.buf[68] = PROTO_RESULT_GUIDE; /* statistics announced, none there */
        CHECK(proto_msg_decode_result(raw.buf, raw.len, NULL, 0, &r, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "guiding"));
        raw.buf[68] = PROTO_RESULT_WIDE_PASSES; /* wide passes without passes */
        CHECK(proto_msg_decode_result(raw.buf, raw.len, NULL, 0, &r, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "pixel form"));
        proto_writer_fini(&raw);
    }
    /* Only the sums of squares wide (a bright pixel): 48-byte pixels, and
     * only the RGB sums: 64; both round trip. */
    for (int k = 0; k < 2; k++) {
        pt_pixel_acc px[2] = {pt_pixel_acc_of(1.0, 2.0, 3.0, 4.0, 8, 8),
                              pt_pixel_acc_of(0.5, 0.25, 0.125, 0.0625, 8, 3)};
        if (k == 0)
            px[1].fsum_sq = ((pt_u128)1 << 64) + 5;
        else
            px[1].fsum[2] = -((pt_i128)1 << 64) - 5;
        proto_result m = {1, 2, {0, 0, 2, 1}, 0, 8, 0, 0, 0, 2, px, 0, NULL, 0, 0,
                          0, 0, NULL,         0, 0},
                     b;
        proto_writer ww;
        proto_writer_init(&ww, 1 << 20);
        CHECK(proto_msg_encode_result(&ww, &m, NULL) == PT_OK);
        CHECK(ww.len == 69 + 2 * (size_t)(k ? 64 : 48) && ww.buf[68] == (k ? 1 : 2));
        CHECK(proto_msg_decode_result(ww.buf, ww.len, NULL, 0, &b, NULL) == PT_OK &&
              acc_same(&b.pixels[0], &px[0]) && acc_same(&b.pixels[1], &px[1]));
        proto_result_fini(&b);
        if (k == 0) {
            /* The same bytes with the one wide sum's high word 0: every sum
             * fits 64 bits, so the wide form is not the encoder's and is
             * refused (one encoding per message). */
            memset(ww.buf + 69 + 48 + 3 * 8 + 8, 0, 8);
            pt_error e = {0};
            CHECK(proto_msg_decode_result(ww.buf, ww.len, NULL, 0, &b, &e) == PT_ERR_PROTO &&
                  strstr(e.msg, "no pixel needs"));
        }
        proto_writer_fini(&ww);
    }
    /* Pass sums (PROTO_RESULT_PASSES): narrow, then one wide value; both
     * round trip into one block after the pixels, whatever buffer is given;
     * an even count over n is refused both ways; bytes cut short too. */
    for (int k = 0; k < 2; k++) {
        pt_pixel_acc px[2] = {pt_pixel_acc_of(1.0, 2.0, 3.0, 4.0, 8, 8),
                              pt_pixel_acc_of(0.5, 0.25, 0.125, 0.0625, 8, 3)};
        pt_pass_acc pa[2];
        memset(pa, 0, sizeof pa);
        for (int i = 0; i < PT_PASS_SUMS; i++)
            pa[0].s[i] = -(pt_i128)i * 77 - 1, pa[1].s[i] = (pt_i128)i << 40;
        for (int i = 0; i < PT_PASS_SQS; i++)
            pa[0].sq[i] = (pt_u128)i * 1000 + 1, pa[1].sq[i] = 3;
        pa[0].n_even = 4;
        pa[1].n_even = 8;
        /* Cryptomatte lists: pixel 0 three objects and one material. */
        pa[0].cid[0][0] = 0, pa[0].cid[0][1] = 77, pa[0].cid[0][2] = 0xfffffff0u;
        pa[0].ccnt[0][0] = 1, pa[0].ccnt[0][1] = 5, pa[0].ccnt[0][2] = 2;
        pa[0].cid[1][0] = 12345, pa[0].ccnt[1][0] = 8;
        if (k == 1)
            pa[1].sq[2] = ((pt_u128)7 << 64) + 1;
        proto_result m = {1, 2, {0, 0, 2, 1}, 0, 8, 0, 0, 0, 2, px, 0, pa, 0, 0, 0, 0, NULL, 0, 0},
                     b;
        proto_writer ww;
        proto_writer_init(&ww, 1 << 20);
        CHECK(proto_msg_encode_result(&ww, &m, NULL) == PT_OK);
        size_t q = k ? PROTO_RESULT_WIDE_PASS_SIZE : PROTO_RESULT_PASS_SIZE;
        CHECK(ww.len == 69 + 2 * (40 + q));
        CHECK(ww.buf[68] ==
              (k ? PROTO_RESULT_PASSES | PROTO_RESULT_WIDE_PASSES : PROTO_RESULT_PASSES));
        static pt_pixel_acc scratch[4];
        CHECK(proto_msg_decode_result(ww.buf, ww.len, scratch, 4, &b, NULL) == PT_OK);
        CHECK(b.owns_pixels && b.pass == (pt_pass_acc *)(b.pixels + 2));
        CHECK(acc_same(&b.pixels[1], &px[1]) && memcmp(b.pass, pa, sizeof pa) == 0);
        proto_result_fini(&b);
        pt_error e = {0};
        CHECK(proto_msg_decode_result(ww.buf, ww.len - 1, NULL, 0, &b, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "truncated"));
        /* n_even of pixel 1 (before its 128 bytes of Cryptomatte) over its n of 8. */
        ww.buf[ww.len - 128 - 4] = 9;
        CHECK(proto_msg_decode_result(ww.buf, ww.len, NULL, 0, &b, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "even count"));
        ww.buf[ww.len - 128 - 4] = 8;
        CHECK(proto_msg_decode_result(ww.buf, ww.len, NULL, 0, &b, &e) == PT_OK);
        proto_result_fini(&b);
        /* A count without its id's order: the second entry used, the first not. */
        ww.buf[ww.len - 128 + 4 * PT_CRYPTO_KEEP + 4] = 1;
        CHECK(proto_msg_decode_result(ww.buf, ww.len, NULL, 0, &b, &e) == PT_ERR_PROTO &&
              strstr(e.msg, "Cryptomatte"));
        proto_writer_fini(&ww);
        pa[1].n_even = 9;
        proto_writer_init(&ww, 1 << 20);
        CHECK(proto_msg_encode_result(&ww, &m, &e) == PT_ERR_ARG && strstr(e.msg, "even count"));
        proto_writer_fini(&ww);
    }
    CHECK(pt_alloc_live() == live);

    /* Encoder side of the same rules. */
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    proto_result m = sample_result(0);
    m.npixels = 11;
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_ERR_ARG);
    m = sample_result(0);
    m.s1 = m.s0;
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_ERR_ARG);
    m = sample_result(0);
    m.pixels[3].n = m.s1 - m.s0 + 1;
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_ERR_ARG);
    m = sample_result(0);
    m.pixels[4].hits = m.pixels[4].n + 1;
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_ERR_ARG && strstr(err.msg, "hits"));
    m.pixels[4].hits = m.pixels[4].n;
    CHECK(w.len == 0);
    /* Writer too small: PT_ERR_LIMIT, and no partial message left behind. */
    proto_writer_fini(&w);
    proto_writer_init(&w, 100);
    proto_w_u32(&w, 0xABCD);
    m = sample_result(0);
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_ERR_LIMIT);
    CHECK(w.len == 4 && proto_get_u32(w.buf) == 0xABCD);
    proto_writer_fini(&w);

    /* The allocation-failure loop: fail allocation k of a decode for every k
     * until one succeeds; each failure is PT_ERR_NOMEM, out untouched, no leak. */
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    m = sample_result(0);
    CHECK(proto_msg_encode_result(&w, &m, &err) == PT_OK);
    int64_t live_w = pt_alloc_live(); /* the writer holds a block */
    int done = 0;
    for (uint64_t k = 1; k < 50 && !done; k++) {
        proto_result r;
        memset(&r, 0xCD, sizeof r);
        proto_result before = r;
        pt_alloc_fail_at(k);
        pt_status st = proto_msg_decode_result(w.buf, w.len, NULL, 0, &r, &err);
        pt_alloc_fail_at(0);
        if (st == PT_OK) {
            CHECK(r.npixels == 12 && acc_same(&r.pixels[11], &m.pixels[11]));
            proto_result_fini(&r);
            done = 1;
        } else {
            CHECK(st == PT_ERR_NOMEM && memcmp(&r, &before, sizeof r) == 0);
        }
        CHECK(pt_alloc_live() == live_w);
    }
    CHECK(done);
    proto_writer_fini(&w);

    /* The same loop over encoding every sample into a fresh writer. */
    for (int s = 0; s < SAMPLE_COUNT; s++) {
        done = 0;
        for (uint64_t k = 1; k < 50 && !done; k++) {
            proto_writer ew;
            proto_writer_init(&ew, PROTO_MAX_PAYLOAD);
            pt_alloc_fail_at(k);
            uint16_t type = sample_frame(s, 1, &ew);
            pt_alloc_fail_at(0);
            done = type != 0;
            proto_writer_fini(&ew);
            CHECKF(pt_alloc_live() == live, "sample %d k %d", s, (int)k);
        }
        CHECKF(done, "sample %d", s);
    }
}

/* RESULT's clamped count: absent (no byte, no bit) when 0, so an unclamped
 * task's bytes are those of protocol 8; 8 bytes after the pixels and before
 * the guiding statistics otherwise, round-tripping to the same bytes; the
 * bit with a count of 0 is refused (one encoding per value). */
static void test_result_clamped(void)
{
    pt_error e = {0};
    pt_pixel_acc px[2] = {pt_pixel_acc_of(1.0, 2.0, 3.0, 4.0, 8, 8),
                          pt_pixel_acc_of(0.5, 0.25, 0.125, 0.0625, 8, 3)};
    proto_guide_entry ent[2] = {{1, 7}, {5, 9}};
    proto_result m = {1, 2, {0, 0, 2, 1}, 0, 8, 0, 0, 0, 2, px, 0, NULL, 4, 2046, 1, 1, ent, 0, 0};
    proto_writer w, w2;
    proto_writer_init(&w, 1 << 20);
    proto_writer_init(&w2, 1 << 20);
    CHECK(proto_msg_encode_result(&w, &m, &e) == PT_OK);
    size_t plain = w.len;
    CHECK(w.buf[68] == PROTO_RESULT_GUIDE);
    m.clamped = 0x123456789ull;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_result(&w, &m, &e) == PT_OK);
    CHECK(w.len == plain + 8 && w.buf[68] == (PROTO_RESULT_GUIDE | PROTO_RESULT_CLAMPED));
    const size_t at = PROTO_RESULT_HEADER_SIZE + 2 * PROTO_RESULT_PIXEL_SIZE;
    CHECK(proto_get_u64(w.buf + at) == 0x123456789ull);
    proto_result b;
    CHECK(proto_msg_decode_result(w.buf, w.len, NULL, 0, &b, &e) == PT_OK);
    CHECK(b.clamped == 0x123456789ull && b.guide && b.gcount == 1 && b.gsum == 1 &&
          b.guide[1].node == 5);
    CHECK(proto_msg_encode_result(&w2, &b, &e) == PT_OK && w2.len == w.len &&
          memcmp(w.buf, w2.buf, w.len) == 0);
    proto_result_fini(&b);
    proto_put_u64(w.buf + at, 0);
    CHECK(proto_msg_decode_result(w.buf, w.len, NULL, 0, &b, &e) == PT_ERR_PROTO &&
          strstr(e.msg, "clamped count of 0"));
    /* The bit on a RESULT without the count: its guiding statistics are
     * then read 8 bytes late and do not add up. */
    m.clamped = 0;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_result(&w, &m, &e) == PT_OK);
    w.buf[68] |= PROTO_RESULT_CLAMPED;
    CHECK(proto_msg_decode_result(w.buf, w.len, NULL, 0, &b, &e) == PT_ERR_PROTO);
    proto_writer_fini(&w);
    proto_writer_fini(&w2);
}

/* RESULT's guiding statistics: they round-trip to the same bytes; each
 * hostile shape (nodes out of range, not ascending, a zero value, more
 * entries than nodes, no nodes, a count that the bytes do not hold) is
 * refused by name, and the encoder refuses what the decoder would. */
static void test_result_guide(void)
{
    pt_error e = {0};
    pt_pixel_acc px[2] = {pt_pixel_acc_of(1.0, 2.0, 3.0, 4.0, 8, 8),
                          pt_pixel_acc_of(0.5, 0.25, 0.125, 0.0625, 8, 3)};
    proto_guide_entry ent[5] = {{0, 7}, {3, 1}, {6, 65536}, {9, 1ull << 40}, {2045, 3}};
    proto_result m = {1, 2, {0, 0, 2, 1}, 0, 8, 0, 0, 0, 2, px, 0, NULL, 4, 2046, 2, 3, ent, 0, 0};
    proto_writer w, w2;
    proto_writer_init(&w, 1 << 20);
    proto_writer_init(&w2, 1 << 20);
    CHECK(proto_msg_encode_result(&w, &m, &e) == PT_OK);
    CHECK(w.len == PROTO_RESULT_HEADER_SIZE + 2 * PROTO_RESULT_PIXEL_SIZE + 16 + 5 * 12);
    CHECK(w.buf[68] == PROTO_RESULT_GUIDE);
    proto_result b;
    CHECK(proto_msg_decode_result(w.buf, w.len, NULL, 0, &b, &e) == PT_OK);
    CHECK(b.guide && b.owns_guide && b.g_nsnode == 4 && b.g_nqnode == 2046 && b.gcount == 2 &&
          b.gsum == 3);
    for (int k = 0; b.guide && k < 5; k++)
        CHECK(b.guide[k].node == ent[k].node && b.guide[k].value == ent[k].value);
    CHECK(proto_msg_encode_result(&w2, &b, &e) == PT_OK && w2.len == w.len &&
          memcmp(w.buf, w2.buf, w.len) == 0);
    proto_result_fini(&b);
    CHECK(b.guide == NULL && !b.owns_guide);
    const size_t at = PROTO_RESULT_HEADER_SIZE + 2 * PROTO_RESULT_PIXEL_SIZE;
    struct {
        size_t off;
        uint32_t v;
        const char *why;
    } bad[] = {
        {at + 16, 4, "ascending"},               /* count node 0 -> 4: out of range */
        {at + 16 + 12, 0, "ascending"},          /* count nodes 0, 0 */
        {at + 16 + 24 + 24, 2046, "ascending"},  /* sum node 9 -> 2046 */
        {at + 16 + 12 + 4, 0, "ascending"},      /* count 1 -> 0 (low word) */
        {at + 8, 5, "more guiding entries"},     /* 5 counts of a guide of 4 nodes */
        {at, 0, "guide sizes"},                  /* a guide of no spatial node */
        {at + 4, (1u << 24) + 1, "guide sizes"}, /* over the cap */
        {at + 12, 4, "entries in"},              /* 4 sums listed, 3 there */
    };
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        proto_writer_reset(&w2);
        proto_w_bytes(&w2, w.buf, w.len);
        proto_put_u32(w2.buf + bad[k].off, bad[k].v);
        CHECKF(proto_msg_decode_result(w2.buf, w2.len, NULL, 0, &b, &e) == PT_ERR_PROTO &&
                   strstr(e.msg, bad[k].why),
               "case %zu: %s", k, e.msg);
    }
    proto_writer_reset(&w2);
    CHECK(proto_msg_decode_result(w.buf, w.len - 1, NULL, 0, &b, &e) == PT_ERR_PROTO);
    ent[1].node = 0; /* not ascending */
    CHECK(proto_msg_encode_result(&w2, &m, &e) == PT_ERR_ARG && w2.len == 0);
    proto_writer_fini(&w);
    proto_writer_fini(&w2);
}

/* GUIDE_CHUNK's packing (protocol/guide.h): a distribution's bytes come back
 * exactly, smaller when they repeat; every hostile shape is refused by name
 * with nothing left allocated, and a declared length is never exceeded
 * however much the stream would inflate to. */
static void test_guide_pack(void)
{
    pt_error e = {0};
    int64_t live = pt_alloc_live();
    /* GUIDE-like bytes: ascending child indices beside energies. */
    const size_t n = 1u << 20;
    uint8_t *raw = pt_malloc(n);
    CHECK(raw != NULL);
    if (!raw)
        return;
    uint32_t x = 12345;
    for (size_t i = 0; i + 8 <= n; i += 8) {
        x = x * 1664525u + 1013904223u;
        proto_put_u32(raw + i, (uint32_t)(i / 16));
        proto_put_f32(raw + i + 4, (float)(x >> 20) / 4096.0f);
    }
    uint8_t *pk = NULL, *un = NULL;
    size_t plen = 0, ulen = 0;
    CHECK(proto_guide_pack(raw, n, &pk, &plen, &e) == PT_OK);
    CHECK(pk && plen > PROTO_GUIDE_PACK_HEADER && plen < n / 2);
    CHECK(pk && proto_get_u32(pk) == PROTO_GUIDE_PACK_MAGIC && proto_get_u64(pk + 4) == n);
    CHECK(proto_guide_unpack(pk, plen, &un, &ulen, &e) == PT_OK && ulen == n && un &&
          memcmp(un, raw, n) == 0);
    pt_free(un);
    CHECK(proto_guide_pack(raw, PROTO_GUIDE_HEADER - 1, &un, &ulen, &e) == PT_ERR_ARG && !un);

    /* Hostile packs, each from the good one. */
    uint8_t *bad = pt_malloc(plen + 1);
    CHECK(bad != NULL);
    struct {
        int what; /* 0 set the u64 at 4, 1 flip a byte at off, 2 cut to off, 3 add a byte */
        size_t off;
        uint64_t v;
        const char *why;
    } cases[] = {
        {1, 0, 0, "bad magic"},
        {0, 0, (uint64_t)PROTO_MAX_GUIDE_BYTES + 1, "declared"},
        {0, 0, PROTO_GUIDE_HEADER - 1, "declared"},
        {0, 0, 1ull << 40, "declared"},
        {0, 0, n - 1, "more than"},
        {0, 0, n + 1, "unpacked"},
        {1, plen - 2, 0, "corrupt"}, /* the stream's Adler-32 */
        {1, PROTO_GUIDE_PACK_HEADER, 0, "corrupt"},
        {2, plen - 9, 0, "ends before"},
        {2, PROTO_GUIDE_PACK_HEADER - 1, 0, "header"},
        {3, 0, 0, "after its zlib data"},
    };
    for (size_t k = 0; bad && k < sizeof cases / sizeof *cases; k++) {
        memcpy(bad, pk, plen);
        size_t len = plen;
        if (cases[k].what == 0)
            proto_put_u64(bad + 4, cases[k].v);
        else if (cases[k].what == 1)
            bad[cases[k].off] ^= 0x55;
        else if (cases[k].what == 2)
            len = cases[k].off;
        else
            bad[len++] = 0;
        un = NULL;
        pt_status st = proto_guide_unpack(bad, len, &un, &ulen, &e);
        CHECKF(st == PT_ERR_FORMAT && !un && strstr(e.msg, cases[k].why), "case %zu: %s", k, e.msg);
        pt_free(un);
    }
    pt_free(bad);
    pt_free(pk);

    /* A bomb: 64 MiB of zeros deflate to a few hundred KiB; declared as 1 MiB it
     * is refused, inflating stopped at 1 MiB. Declared as its length but
     * with a stream too short for it, it is refused before any allocation. */
    const size_t big = 64u << 20;
    uint8_t *zeros = pt_calloc(big, 1);
    CHECK(zeros != NULL);
    if (zeros && proto_guide_pack(zeros, big, &pk, &plen, &e) == PT_OK) {
        CHECK(plen < big / 100);
        proto_put_u64(pk + 4, 1u << 20);
        CHECK(proto_guide_unpack(pk, plen, &un, &ulen, &e) == PT_ERR_FORMAT &&
              strstr(e.msg, "more than") && !un);
        uint8_t tiny[PROTO_GUIDE_PACK_HEADER + 8] = {0};
        proto_put_u32(tiny, PROTO_GUIDE_PACK_MAGIC);
        proto_put_u64(tiny + 4, PROTO_MAX_GUIDE_BYTES);
        CHECK(proto_guide_unpack(tiny, sizeof tiny, &un, &ulen, &e) == PT_ERR_FORMAT &&
              strstr(e.msg, "can hold") && !un);
        pt_free(pk);
    }
    pt_free(zeros);
    pt_free(raw);
    CHECK(pt_alloc_live() == live);
}

static void test_types(void)
{
    CHECK(proto_msg_type_known(PROTO_MSG_HELLO) && proto_msg_type_known(PROTO_MSG_FETCH));
    CHECK(!proto_msg_type_known(0) && !proto_msg_type_known(0x10001));
    CHECK(proto_msg_type_preauth(PROTO_MSG_HELLO) && proto_msg_type_preauth(PROTO_MSG_ERROR));
    CHECK(!proto_msg_type_preauth(PROTO_MSG_TASK) && !proto_msg_type_preauth(0));
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_RESULT), "RESULT") == 0);
    CHECK(strcmp(proto_msg_type_name(12345), "unknown") == 0);
    size_t n = strlen(proto_build_id());
    CHECK(n > 0 && n <= PROTO_MAX_BUILD_ID);
    /* Every handshake message fits the pre-authentication cap at its largest. */
    CHECK(13 + PROTO_MAX_NAME + PROTO_MAX_BUILD_ID <= PROTO_MAX_PAYLOAD_PREAUTH);
    CHECK(4 + PROTO_MAX_ERROR_TEXT <= PROTO_MAX_PAYLOAD_PREAUTH);
    /* A full RESULT fits the frame cap. */
    CHECK(PROTO_RESULT_HEADER_SIZE +
              (uint64_t)PROTO_RESULT_WIDE_PIXEL_SIZE * PROTO_MAX_TILE_PIXELS <=
          PROTO_MAX_PAYLOAD);
    CHECK(52 + (uint64_t)PROTO_MAX_SCENE_CHUNK <= PROTO_MAX_PAYLOAD);
}

/* ---- DENOISE_TASK, DENOISE_RESULT ---- */

/* msg.h restates the denoiser's constants that the layout depends on, and
 * the largest region's crop (its margin on both sides) fits the crop cap. */
_Static_assert(PROTO_DENOISE_PLANES == PT_DENOISE_PLANES, "DENOISE_TASK planes");
_Static_assert(PROTO_MAX_DENOISE_REGION + 2 * PT_DENOISE_MARGIN <= PROTO_MAX_DENOISE_CROP,
               "DENOISE_TASK crop cap");

/* Writes m by hand at the table's offsets and decodes it; the encoder must
 * agree (PT_ERR_ARG with nothing written when the decoder refuses). */
static pt_status denoise_task_check(const proto_denoise_task *m, const char *want)
{
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_w_u64(&w, m->job_id);
    proto_w_u64(&w, m->task_id);
    proto_w_u32(&w, m->crop_w);
    proto_w_u32(&w, m->crop_h);
    proto_w_u32(&w, m->region.x0);
    proto_w_u32(&w, m->region.y0);
    proto_w_u32(&w, m->region.x1);
    proto_w_u32(&w, m->region.y1);
    proto_w_u32(&w, proto_f32_bits(m->despeckle));
    proto_w_u32(&w, m->lease_ms);
    proto_w_bytes(&w, m->hash, 32);
    proto_w_u64(&w, m->size);
    pt_error err = {0};
    pt_status st = decode_any(PROTO_MSG_DENOISE_TASK, w.buf, w.len, &err);
    if (st != PT_OK && want && !strstr(err.msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err.msg);
        st = PT_ERR_ARG;
    }
    proto_writer_reset(&w);
    pt_status est = proto_msg_encode_denoise_task(&w, m, &err);
    if ((st == PT_OK) != (est == PT_OK) || (est != PT_OK && (est != PT_ERR_ARG || w.len != 0))) {
        fprintf(stderr, "DENOISE_TASK: encoder and decoder disagree\n");
        st = PT_ERR_ARG;
    }
    proto_writer_fini(&w);
    return st;
}

static void test_denoise_task(void)
{
    proto_denoise_task m = sample_denoise_task(0);
    CHECK(denoise_task_check(&m, NULL) == PT_OK);
    m = sample_denoise_task(1); /* the largest crop and region */
    CHECK(denoise_task_check(&m, NULL) == PT_OK);
    m.lease_ms = UINT32_MAX; /* any lease */
    CHECK(denoise_task_check(&m, NULL) == PT_OK);

    /* The task id's bit. */
    m = sample_denoise_task(0);
    m.task_id &= ~PROTO_DENOISE_TASK_BIT;
    CHECK(denoise_task_check(&m, "denoise bit") == PT_ERR_PROTO);
    m.task_id = 0;
    CHECK(denoise_task_check(&m, "denoise bit") == PT_ERR_PROTO);
    m.task_id = PROTO_DENOISE_TASK_BIT; /* region 0 */
    CHECK(denoise_task_check(&m, NULL) == PT_OK);

    /* The crop: 1 x 1 up to the cap on each side; 0 or one over refused. */
    m = sample_denoise_task(0);
    m.crop_w = m.crop_h = 1;
    m.region = (pt_rect){0, 0, 1, 1};
    m.size = PROTO_DENOISE_PLANES * 4;
    CHECK(denoise_task_check(&m, NULL) == PT_OK);
    for (int k = 0; k < 4; k++) {
        m = sample_denoise_task(k & 1);
        uint32_t c = k < 2 ? 0 : PROTO_MAX_DENOISE_CROP + 1;
        if (k & 1)
            m.crop_h = c;
        else
            m.crop_w = c;
        m.size = (uint64_t)m.crop_w * m.crop_h * PROTO_DENOISE_PLANES * 4;
        CHECKF(denoise_task_check(&m, "crop") == PT_ERR_PROTO, "crop case %d", k);
    }
    m = sample_denoise_task(0);
    m.crop_w = m.crop_h = UINT32_MAX; /* the size would be 2^70 */
    m.size = UINT64_MAX;
    CHECK(denoise_task_check(&m, "crop") == PT_ERR_PROTO);

    /* The region: empty, reversed, out of the crop (by one, and far), a
     * side over the cap within a crop that holds it. */
    static const struct {
        pt_rect r;
        const char *why;
    } regions[] = {
        {{32, 32, 32, 48}, "x0 >= x1"},
        {{33, 32, 32, 48}, "x0 >= x1"},
        {{32, 48, 64, 48}, "y0 >= y1"},
        {{32, 49, 64, 48}, "y0 >= y1"},
        {{32, 32, 97, 48}, "outside"},
        {{32, 32, 64, 81}, "outside"},
        {{UINT32_MAX - 1, 0, UINT32_MAX, 1}, "outside"},
        {{0, 0, 96, 80}, NULL}, /* the whole crop */
    };
    for (size_t k = 0; k < sizeof regions / sizeof *regions; k++) {
        m = sample_denoise_task(0);
        m.region = regions[k].r;
        CHECKF(denoise_task_check(&m, regions[k].why) == (regions[k].why ? PT_ERR_PROTO : PT_OK),
               "region %zu", k);
    }
    m = sample_denoise_task(1);
    m.region = (pt_rect){0, 0, PROTO_MAX_DENOISE_REGION + 1, 1};
    CHECK(denoise_task_check(&m, "side") == PT_ERR_PROTO);
    m.region = (pt_rect){255, 0, 1280, 1};
    CHECK(denoise_task_check(&m, "side") == PT_ERR_PROTO);
    m.region = (pt_rect){0, 0, 1, 1280};
    CHECK(denoise_task_check(&m, "side") == PT_ERR_PROTO);

    /* Despeckle: 0 (either sign) or [1, 1e6]; anything else, NaN
     * included, refused. */
    const float good[] = {0.0f, -0.0f, 1.0f, 2.0f, PROTO_MAX_DESPECKLE};
    for (size_t k = 0; k < sizeof good / sizeof *good; k++) {
        m = sample_denoise_task(0);
        m.despeckle = good[k];
        CHECKF(denoise_task_check(&m, NULL) == PT_OK, "despeckle %g", (double)good[k]);
    }
    const float bad_d[] = {NAN,   -NAN,   nextafterf(PROTO_MAX_DESPECKLE, INFINITY),
                           0.5f,  2e6f,   nextafterf(1.0f, 0.0f),
                           -1.0f, 1e-45f, INFINITY};
    for (size_t k = 0; k < sizeof bad_d / sizeof *bad_d; k++) {
        m = sample_denoise_task(0);
        m.despeckle = bad_d[k];
        CHECKF(denoise_task_check(&m, "despeckle") == PT_ERR_PROTO, "despeckle %zu", k);
    }
    CHECK(PROTO_MAX_DESPECKLE == PT_DENOISE_DESPECKLE_MAX);

    /* The input's size: exactly the crop's 20 planes of f32. */
    const int64_t dsize[] = {1, -1, -4, 4};
    for (size_t k = 0; k < sizeof dsize / sizeof *dsize; k++) {
        m = sample_denoise_task(0);
        m.size += (uint64_t)dsize[k];
        CHECKF(denoise_task_check(&m, "input size") == PT_ERR_PROTO, "size %zu", k);
    }
    m = sample_denoise_task(0);
    m.size = 0;
    CHECK(denoise_task_check(&m, "input size") == PT_ERR_PROTO);
    m.size = (uint64_t)m.crop_w * m.crop_h * 19 * 4;
    CHECK(denoise_task_check(&m, "input size") == PT_ERR_PROTO);

    /* A writer too small: PT_ERR_LIMIT, nothing of the message left. */
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, 100);
    proto_w_u32(&w, 0xABCD);
    m = sample_denoise_task(0);
    CHECK(proto_msg_encode_denoise_task(&w, &m, &err) == PT_OK && w.len == 4 + 88);
    CHECK(proto_msg_encode_denoise_task(&w, &m, &err) == PT_ERR_LIMIT && w.len == 4 + 88);
    proto_writer_fini(&w);
}

/* A DENOISE_RESULT by hand: its header claiming n pixels of region t, then
 * `have` bytes of pixels. The decoder's verdict, want in its message; the
 * encoder must agree when the bytes are the 12n it would write. */
static pt_status denoise_result_check(uint64_t task_id, pt_rect t, uint32_t n, size_t have,
                                      const char *want)
{
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    proto_w_u64(&w, 7);
    proto_w_u64(&w, task_id);
    proto_w_u32(&w, t.x0);
    proto_w_u32(&w, t.y0);
    proto_w_u32(&w, t.x1);
    proto_w_u32(&w, t.y1);
    proto_w_u32(&w, n);
    uint8_t *px = proto_w_reserve(&w, have);
    if (px)
        for (size_t i = 0; i < have; i++)
            px[i] = (uint8_t)(i * 7);
    pt_error err = {0};
    pt_status st = decode_any(PROTO_MSG_DENOISE_RESULT, w.buf, w.len, &err);
    if (st != PT_OK && want && !strstr(err.msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err.msg);
        st = PT_ERR_ARG;
    }
    if (have == 12 * (size_t)n) {
        proto_writer e;
        proto_writer_init(&e, PROTO_MAX_PAYLOAD);
        proto_denoise_result m = {7, task_id, t, n, w.buf + 36};
        pt_status est = proto_msg_encode_denoise_result(&e, &m, &err);
        if ((st == PT_OK) != (est == PT_OK) ||
            (est == PT_OK && (e.len != w.len || memcmp(e.buf, w.buf, w.len) != 0)) ||
            (est != PT_OK && (est != PT_ERR_ARG || e.len != 0))) {
            fprintf(stderr, "DENOISE_RESULT: encoder and decoder disagree\n");
            st = PT_ERR_ARG;
        }
        proto_writer_fini(&e);
    }
    proto_writer_fini(&w);
    return st;
}

static void test_denoise_result(void)
{
    const uint64_t id = PROTO_DENOISE_TASK_BIT | 3;
    const pt_rect r = {8, 16, 12, 19}; /* 4 x 3 */
    CHECK(denoise_result_check(id, r, 12, 144, NULL) == PT_OK);
    CHECK(denoise_result_check(id, (pt_rect){0, 0, 1, 1}, 1, 12, NULL) == PT_OK);
    /* The largest region, 12 MiB of pixels, fits the frame cap. */
    CHECK(denoise_result_check(PROTO_DENOISE_TASK_BIT, (pt_rect){0, 0, 1024, 1024}, 1u << 20,
                               12u << 20, NULL) == PT_OK);
    CHECK(36 + 12 * (uint64_t)PROTO_MAX_DENOISE_REGION * PROTO_MAX_DENOISE_REGION <=
          PROTO_MAX_PAYLOAD);

    /* The task id's bit. */
    CHECK(denoise_result_check(3, r, 12, 144, "denoise bit") == PT_ERR_PROTO);
    CHECK(denoise_result_check(UINT64_MAX >> 1, r, 12, 144, "denoise bit") == PT_ERR_PROTO);

    /* The region: empty, reversed, a side over the cap; an area that
     * would wrap 32 bits (65536^2 -> 0) with a count of 0 is refused on
     * its sides. */
    CHECK(denoise_result_check(id, (pt_rect){4, 0, 4, 2}, 0, 0, "x0 >= x1") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, (pt_rect){5, 0, 4, 2}, 0, 0, "x0 >= x1") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, (pt_rect){0, 2, 4, 2}, 0, 0, "y0 >= y1") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, (pt_rect){0, 0, 1025, 1}, 1025, 12 * 1025, "side") ==
          PT_ERR_PROTO);
    CHECK(denoise_result_check(id, (pt_rect){0, 0, 1, 1025}, 1025, 12 * 1025, "side") ==
          PT_ERR_PROTO);
    CHECK(denoise_result_check(id, (pt_rect){0, 0, 65536, 65536}, 0, 0, "side") == PT_ERR_PROTO);

    /* The count: the region's area, not one more or less, and a huge one is
     * refused before it is used as a length. */
    CHECK(denoise_result_check(id, r, 11, 132, "area") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 13, 156, "area") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 0, 0, "area") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, UINT32_MAX, 0, "area") == PT_ERR_PROTO);

    /* The bytes: exactly 12 a pixel. */
    CHECK(denoise_result_check(id, r, 12, 143, "truncated") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 12, 132, "truncated") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 12, 0, "truncated") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 12, 145, "trailing") == PT_ERR_PROTO);
    CHECK(denoise_result_check(id, r, 12, 156, "trailing") == PT_ERR_PROTO);

    /* A writer too small: PT_ERR_LIMIT, nothing of the message left. */
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, 200);
    proto_w_u32(&w, 0xABCD);
    proto_denoise_result m = sample_denoise_result(0);
    CHECK(proto_msg_encode_denoise_result(&w, &m, &err) == PT_OK && w.len == 4 + 36 + 144);
    proto_writer_reset(&w);
    proto_w_bytes(&w, "abcdefghijklmnopqrstuvwxyz", 26);
    CHECK(proto_msg_encode_denoise_result(&w, &m, &err) == PT_ERR_LIMIT && w.len == 26);
    proto_writer_fini(&w);
}

/* DENOISE_GET and DENOISE_CHUNK are SCENE_GET and SCENE_CHUNK; the four
 * types are known, named, and not for before authentication. */
static void test_denoise_types(void)
{
    static const struct {
        uint16_t type;
        const char *name;
    } types[] = {{PROTO_MSG_DENOISE_TASK, "DENOISE_TASK"},
                 {PROTO_MSG_DENOISE_GET, "DENOISE_GET"},
                 {PROTO_MSG_DENOISE_CHUNK, "DENOISE_CHUNK"},
                 {PROTO_MSG_DENOISE_RESULT, "DENOISE_RESULT"}};
    for (size_t i = 0; i < sizeof types / sizeof *types; i++) {
        CHECK(proto_msg_type_known(types[i].type) && !proto_msg_type_preauth(types[i].type));
        CHECK(strcmp(proto_msg_type_name(types[i].type), types[i].name) == 0);
    }
    CHECK(!proto_msg_type_known(PROTO_MSG_DENOISE_RESULT + 1) && !proto_msg_type_known(31));
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, 4096);
    CHECK(sample_payload(7, 1, &w) == PROTO_MSG_SCENE_GET);
    CHECK(decode_any(PROTO_MSG_DENOISE_GET, w.buf, w.len, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_DENOISE_GET, w.buf, w.len - 1, &err) == PT_ERR_PROTO);
    proto_writer_reset(&w);
    CHECK(sample_payload(8, 0, &w) == PROTO_MSG_SCENE_CHUNK);
    CHECK(decode_any(PROTO_MSG_DENOISE_CHUNK, w.buf, w.len, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_DENOISE_CHUNK, w.buf, w.len - 1, &err) == PT_ERR_PROTO);
    /* A HELLO's capability bit travels. */
    proto_writer_reset(&w);
    proto_hello h = sample_hello(0), hb;
    h.caps = PROTO_CAP_DENOISE;
    CHECK(proto_msg_encode_hello(&w, &h, &err) == PT_OK);
    CHECK(proto_msg_decode_hello(w.buf, w.len, &hb, &err) == PT_OK && hb.caps == PROTO_CAP_DENOISE);
    proto_writer_fini(&w);
}

/* ---- client messages ---- */

/* Encodes m with the SUBMIT encoder and checks that the decoder agrees on
 * a payload written by hand with the same fields. */
static pt_status submit_check(const proto_submit *m, const char *want)
{
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_w_u16(&w, (uint16_t)strlen(m->name));
    proto_w_bytes(&w, m->name, strlen(m->name));
    proto_w_u32(&w, m->width);
    proto_w_u32(&w, m->height);
    proto_w_u32(&w, m->spp);
    proto_w_u32(&w, m->seed);
    proto_w_u32(&w, (uint32_t)m->priority);
    proto_w_u16(&w, m->max_depth);
    proto_w_u32(&w, m->min_spp);
    proto_w_f64(&w, m->target_error);
    proto_w_u64(&w, m->bundle_size);
    proto_w_bytes(&w, m->bundle_hash, 32);
    proto_w_u16(&w, (uint16_t)strlen(m->camera));
    proto_w_bytes(&w, m->camera, strlen(m->camera));
    proto_w_f64(&w, m->min_gain);
    proto_w_u16(&w, (uint16_t)strlen(m->env.name));
    proto_w_bytes(&w, m->env.name, strlen(m->env.name));
    proto_w_f32(&w, m->env.strength);
    proto_w_f32(&w, m->env.rotate_deg);
    proto_w_u8(&w, m->env.background);
    for (int k = 0; k < 3; k++)
        proto_w_f32(&w, m->env.rgb[k]);
    proto_w_u32(&w, m->film_flags);
    proto_w_u16(&w, (uint16_t)strnlen(m->variant, sizeof m->variant));
    proto_w_bytes(&w, m->variant, strnlen(m->variant, sizeof m->variant));
    proto_w_u32(&w, m->frame_first);
    proto_w_u32(&w, m->frame_last);
    proto_w_u32(&w, m->frame_step);
    proto_w_f64(&w, m->fps);
    proto_w_u16(&w, (uint16_t)strnlen(m->animation, sizeof m->animation));
    proto_w_bytes(&w, m->animation, strnlen(m->animation, sizeof m->animation));
    proto_w_f64(&w, m->shutter[0]);
    proto_w_f64(&w, m->shutter[1]);
    proto_w_f32(&w, m->clamp[0]);
    proto_w_f32(&w, m->clamp[1]);
    proto_w_u8(&w, m->guiding);
    pt_error err = {0};
    pt_status st = decode_any(PROTO_MSG_SUBMIT, w.buf, w.len, &err);
    if (st != PT_OK && want && !strstr(err.msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err.msg);
        st = PT_ERR_ARG;
    }
    proto_writer_reset(&w);
    pt_status est = proto_msg_encode_submit(&w, m, &err);
    if ((st == PT_OK) != (est == PT_OK) || (est != PT_OK && (est != PT_ERR_ARG || w.len != 0))) {
        fprintf(stderr, "SUBMIT: encoder and decoder disagree\n");
        st = PT_ERR_ARG;
    }
    proto_writer_fini(&w);
    return st;
}

static void test_submit(void)
{
    proto_submit m = sample_submit(0);
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.width = 0;
    CHECK(submit_check(&m, "width") == PT_ERR_PROTO);
    m.height = 0;
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.width = 5;
    CHECK(submit_check(&m, "width") == PT_ERR_PROTO);
    m = sample_submit(0);
    m.spp = 0;
    CHECK(submit_check(&m, "samples") == PT_ERR_PROTO);
    m = sample_submit(0);
    m.bundle_size = 0;
    CHECK(submit_check(&m, "bundle size") == PT_ERR_PROTO);
    m = sample_submit(1);
    CHECK(m.film_flags == PROTO_FILM_TRANSPARENT && submit_check(&m, NULL) == PT_OK);
    m.film_flags = PROTO_FILM_TRANSPARENT | PROTO_FILM_DENOISE;
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.film_flags = PROTO_FILM_TRANSPARENT | (PROTO_FILM_KNOWN + 1u);
    CHECK(submit_check(&m, "film flags") == PT_ERR_PROTO);
    /* The variant: at its cap accepted, one over refused both ways. */
    m = sample_submit(0);
    CHECK(strcmp(m.variant, "Mango Velvet") == 0 && submit_check(&m, NULL) == PT_OK);
    memset(m.variant, 'v', PROTO_MAX_NAME);
    m.variant[PROTO_MAX_NAME] = '\0';
    CHECK(submit_check(&m, NULL) == PT_OK);
    memset(m.variant, 'v', sizeof m.variant);
    CHECK(submit_check(&m, "variant") == PT_ERR_PROTO);
    /* The shutter: a quarter to three quarters of a frame at 30 per second
     * travels; open after close, negative or NaN is refused both ways. */
    m = sample_submit(1);
    CHECK(m.shutter[1] > m.shutter[0] && submit_check(&m, NULL) == PT_OK);
    m.shutter[0] = m.shutter[1] + 1.0;
    CHECK(submit_check(&m, "shutter") == PT_ERR_PROTO);
    m.shutter[0] = -0.5;
    CHECK(submit_check(&m, "shutter") == PT_ERR_PROTO);
    m.shutter[0] = NAN;
    CHECK(submit_check(&m, "shutter") == PT_ERR_PROTO);
    /* The clamps: 0 (off) to 1e30 travel; negative, NaN or infinite is
     * refused both ways. */
    m = sample_submit(1);
    CHECK(m.clamp[1] == PROTO_MAX_CLAMP && submit_check(&m, NULL) == PT_OK);
    m.clamp[0] = -2.0f;
    CHECK(submit_check(&m, "clamp direct") == PT_ERR_PROTO);
    m = sample_submit(0);
    m.clamp[1] = NAN;
    CHECK(submit_check(&m, "clamp indirect") == PT_ERR_PROTO);
    m.clamp[1] = INFINITY;
    CHECK(submit_check(&m, "clamp indirect") == PT_ERR_PROTO);
    static const uint64_t bad_errors[] = {
        0x7FF8000000000000ull, /* NaN */
        0xFFF8000000000000ull, /* -NaN */
        0x7FF0000000000000ull, /* +Inf */
        0xFFF0000000000000ull, /* -Inf */
        0xBFF0000000000000ull, /* -1 */
        0x8000000000000001ull, /* the smallest negative subnormal */
    };
    for (size_t i = 0; i < sizeof bad_errors / sizeof bad_errors[0]; i++) {
        m = sample_submit(0);
        m.target_error = proto_bits_f64(bad_errors[i]);
        CHECKF(submit_check(&m, "target error") == PT_ERR_PROTO, "error bits %016llx",
               (unsigned long long)bad_errors[i]);
    }
    for (size_t i = 0; i < sizeof bad_errors / sizeof bad_errors[0]; i++) {
        m = sample_submit(1);
        m.min_gain = proto_bits_f64(bad_errors[i]);
        CHECKF(submit_check(&m, "min gain") == PT_ERR_PROTO, "gain bits %016llx",
               (unsigned long long)bad_errors[i]);
    }
    m = sample_submit(1);
    m.min_gain = 1e308;
    CHECK(submit_check(&m, NULL) == PT_OK);
    m = sample_submit(0);
    m.target_error = -0.0; /* compares equal to 0: off */
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.target_error = 1e308;
    CHECK(submit_check(&m, NULL) == PT_OK);
    /* Name at its cap, and over it (encoder: no terminator within the cap). */
    m = sample_submit(0);
    memset(m.name, 'n', PROTO_MAX_NAME);
    m.name[PROTO_MAX_NAME] = '\0';
    CHECK(submit_check(&m, NULL) == PT_OK);
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, 4096);
    memset(m.name, 'n', sizeof m.name);
    CHECK(proto_msg_encode_submit(&w, &m, &err) == PT_ERR_ARG && w.len == 0);
    proto_w_u16(&w, PROTO_MAX_NAME + 1);
    CHECK(decode_any(PROTO_MSG_SUBMIT, w.buf, w.len, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "cap") != NULL);
    /* The environment: each field's bad values refused both ways, by name. */
    static const uint32_t bad_floats[] = {0x7FC00000u, 0xFFC00000u, 0x7F800000u, 0xFF800000u};
    for (size_t i = 0; i < sizeof bad_floats / sizeof bad_floats[0]; i++) {
        m = sample_submit(0);
        m.env.strength = proto_bits_f32(bad_floats[i]);
        CHECK(submit_check(&m, "environment strength") == PT_ERR_PROTO);
        m = sample_submit(0);
        m.env.rotate_deg = proto_bits_f32(bad_floats[i]);
        CHECK(submit_check(&m, "environment rotation") == PT_ERR_PROTO);
        m = sample_submit(1);
        m.env.background = 1;
        m.env.rgb[i % 3] = proto_bits_f32(bad_floats[i]);
        CHECK(submit_check(&m, "background colour") == PT_ERR_PROTO);
    }
    m = sample_submit(0);
    m.env.strength = -1.0f;
    CHECK(submit_check(&m, "environment strength") == PT_ERR_PROTO);
    m.env.strength = 0.0f; /* black, but well formed */
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.env.rotate_deg = -1e30f;
    CHECK(submit_check(&m, NULL) == PT_OK);
    m = sample_submit(1);
    m.env.background = 2;
    CHECK(submit_check(&m, "background flag") == PT_ERR_PROTO);
    m.env.background = 1;
    m.env.rgb[1] = -0.5f;
    CHECK(submit_check(&m, "background colour") == PT_ERR_PROTO);
    m.env.rgb[1] = 0.5f;
    CHECK(submit_check(&m, NULL) == PT_OK);
    strcpy(m.env.name, ".ptfarm/environment");
    CHECK(submit_check(&m, "two environments") == PT_ERR_PROTO);
    /* The map's name at its cap, and over it. */
    m = sample_submit(0);
    memset(m.env.name, 'e', PROTO_MAX_PATH);
    m.env.name[PROTO_MAX_PATH] = '\0';
    CHECK(submit_check(&m, NULL) == PT_OK);
    memset(m.env.name, 'e', sizeof m.env.name);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_submit(&w, &m, &err) == PT_ERR_ARG && w.len == 0);
    /* Cut inside the ENV block: refused as truncated. */
    m = sample_submit(0);
    CHECK(proto_msg_encode_submit(&w, &m, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_SUBMIT, w.buf,
                     w.len - 1 - 8 - 16 - 22 - strlen(m.animation) - 2 - strlen(m.variant) - 4 - 1,
                     &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "background colour") != NULL);
    proto_writer_reset(&w);
    /* A NUL in the name. */
    proto_writer_reset(&w);
    m = sample_submit(0);
    CHECK(proto_msg_encode_submit(&w, &m, &err) == PT_OK);
    w.buf[3] = 0;
    CHECK(decode_any(PROTO_MSG_SUBMIT, w.buf, w.len, &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "NUL") != NULL);
    proto_writer_fini(&w);
}

/* A JOB_INFO by hand: string field f (0 name, 1 owner, 2 scene, 3 output,
 * 4 message) n bytes long, the others empty, every number 0. */
static void job_info_raw(proto_writer *w, int f, size_t n)
{
    proto_w_u64(w, 1);
    proto_w_u8(w, PROTO_JOB_DONE);
    proto_w_u32(w, 0);
    for (int k = 0; k < 4; k++)
        w_str(w, k == f ? n : 0, 'q');
    /* width .. queue position: 84 bytes */
    for (int k = 0; k < 21; k++)
        proto_w_u32(w, 0);
    w_str(w, f == 4 ? n : 0, 'q');
    proto_w_u64(w, 0); /* paths capped */
    proto_w_u64(w, 0); /* samples rejected */
    for (int k = 0; k < 5; k++)
        proto_w_u32(w, 0); /* a still: no frame range, no frames */
    proto_w_u8(w, 0);      /* no frames listed */
    proto_w_u8(w, 0);      /* not guided */
    proto_w_u32(w, 0);
    proto_w_u32(w, 0);
    proto_w_u64(w, 0); /* contributions clamped */
    proto_w_u8(w, 0);  /* not bidirectional */
}

static void test_job_info(void)
{
    pt_error err = {0};
    proto_writer w;
    proto_writer_init(&w, 1u << 16);
    /* Every string at its cap round-trips; one byte over is refused by both sides. */
    proto_job_info m = sample_job_info(2);
    CHECK(proto_msg_encode_job_info(&w, &m, &err) == PT_OK);
    CHECK(w.len == 162 + 2 * PROTO_MAX_NAME + 2 * PROTO_MAX_PATH + PROTO_MAX_ERROR_TEXT);
    static proto_job_info b;
    CHECK(proto_msg_decode_job_info(w.buf, w.len, &b, &err) == PT_OK);
    CHECK(job_info_same(&m, &b));
    /* The string fields in payload order, with their caps. */
    size_t caps[5] = {PROTO_MAX_NAME, PROTO_MAX_NAME, PROTO_MAX_PATH, PROTO_MAX_PATH,
                      PROTO_MAX_ERROR_TEXT};
    const char *names[5] = {"name", "owner", "scene", "output", "message"};
    for (int f = 0; f < 5; f++) {
        m = sample_job_info(2);
        char *field[5] = {m.name, m.owner, m.scene, m.output, m.message};
        field[f][caps[f]] = 'z'; /* no terminator within the cap */
        proto_writer_reset(&w);
        CHECKF(proto_msg_encode_job_info(&w, &m, &err) == PT_ERR_ARG && w.len == 0, "%s", names[f]);
        CHECK(strstr(err.msg, names[f]) != NULL);
        CHECK(proto_msg_encode_job_list(&w, &m, 1, &err) == PT_ERR_ARG && w.len == 0);
        /* By hand: string f one byte over its cap, the others empty. */
        proto_writer_reset(&w);
        job_info_raw(&w, f, caps[f] + 1);
        CHECKF(decode_any(PROTO_MSG_JOB_INFO, w.buf, w.len, &err) == PT_ERR_PROTO, "%s", names[f]);
        CHECKF(strstr(err.msg, names[f]) && strstr(err.msg, "cap"), "%s: %s", names[f], err.msg);
    }
    for (int f = 0; f < 5; f++) {
        proto_writer_reset(&w);
        job_info_raw(&w, f, caps[f]);
        CHECKF(decode_any(PROTO_MSG_JOB_INFO, w.buf, w.len, &err) == PT_OK, "%s at its cap",
               names[f]);
    }
    /* Guiding: a flag of 0 or 1, and no pass for an unguided job. */
    for (int k = 0; k < 3; k++) {
        proto_writer_reset(&w);
        job_info_raw(&w, 0, 0);
        if (k == 0)
            w.buf[w.len - 18] = 2; /* guided 2 */
        else
            proto_put_u32(w.buf + w.len - (k == 1 ? 17 : 13), 16); /* a pass, unguided */
        CHECKF(decode_any(PROTO_MSG_JOB_INFO, w.buf, w.len, &err) == PT_ERR_PROTO &&
                   strstr(err.msg, "guiding"),
               "case %d: %s", k, err.msg);
        m = sample_job_info(1);
        m.guided = k == 0 ? 2 : 0;
        m.guide_pass = k == 1;
        m.guide_spp = k == 2;
        proto_writer_reset(&w);
        CHECKF(proto_msg_encode_job_info(&w, &m, &err) == PT_ERR_ARG && w.len == 0, "case %d", k);
    }
    /* The bidirectional flag: 0 or 1. */
    proto_writer_reset(&w);
    job_info_raw(&w, 0, 0);
    w.buf[w.len - 1] = 2;
    CHECKF(decode_any(PROTO_MSG_JOB_INFO, w.buf, w.len, &err) == PT_ERR_PROTO &&
               strstr(err.msg, "bidirectional"),
           "%s", err.msg);
    m = sample_job_info(1);
    m.bdpt = 2;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_job_info(&w, &m, &err) == PT_ERR_ARG && w.len == 0);
    /* Any state value decodes; names for the known ones. */
    m = sample_job_info(0);
    m.state = 200;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_job_info(&w, &m, &err) == PT_OK);
    CHECK(proto_msg_decode_job_info(w.buf, w.len, &b, &err) == PT_OK && b.state == 200);
    CHECK(strcmp(proto_job_state_name(PROTO_JOB_QUEUED), "queued") == 0);
    CHECK(strcmp(proto_job_state_name(PROTO_JOB_RUNNING), "running") == 0);
    CHECK(strcmp(proto_job_state_name(PROTO_JOB_DONE), "done") == 0);
    CHECK(strcmp(proto_job_state_name(PROTO_JOB_CANCELLED), "cancelled") == 0);
    CHECK(strcmp(proto_job_state_name(PROTO_JOB_FAILED), "failed") == 0);
    CHECK(strcmp(proto_job_state_name(0), "unknown") == 0);
    CHECK(strcmp(proto_job_state_name(6), "unknown") == 0);
    /* Writer too small: PT_ERR_LIMIT and the writer as it was. */
    proto_writer_fini(&w);
    proto_writer_init(&w, 120);
    proto_w_u32(&w, 0xABCD);
    m = sample_job_info(0);
    CHECK(proto_msg_encode_job_info(&w, &m, &err) == PT_ERR_LIMIT);
    CHECK(w.len == 4 && proto_get_u32(w.buf) == 0xABCD);
    CHECK(proto_msg_encode_job_list(&w, &m, 1, &err) == PT_ERR_LIMIT && w.len == 4);
    proto_writer_fini(&w);
}

/* Decodes a JOB_LIST and reports how many allocations it made. */
static pt_status job_list_check(const uint8_t *p, size_t len, const char *want, int *allocated)
{
    pt_error err = {0};
    pt_alloc_fail_at(0);
    pt_status st = decode_any(PROTO_MSG_JOB_LIST, p, len, &err);
    *allocated = (int)pt_alloc_count();
    if (st != PT_OK && want && !strstr(err.msg, want)) {
        fprintf(stderr, "wanted \"%s\" in \"%s\"\n", want, err.msg);
        return PT_ERR_ARG;
    }
    return st;
}

static void test_job_list(void)
{
    pt_error err = {0};
    int alloc = 0;
    int64_t live = pt_alloc_live();
    static proto_job_info jobs[PROTO_MAX_JOBS + 1];
    for (unsigned i = 0; i <= PROTO_MAX_JOBS; i++)
        jobs[i] = sample_job_info(2); /* the largest entry */
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    /* The largest list fits a frame, and decodes. */
    CHECK(proto_msg_encode_job_list(&w, jobs, PROTO_MAX_JOBS, &err) == PT_OK);
    CHECK(w.len <= PROTO_MAX_PAYLOAD);
    CHECK(job_list_check(w.buf, w.len, NULL, &alloc) == PT_OK && alloc == 1);
    /* One over the cap: refused by the encoder, and by the decoder from the count alone. */
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_job_list(&w, jobs, PROTO_MAX_JOBS + 1, &err) == PT_ERR_ARG);
    CHECK(w.len == 0);
    uint8_t head[4];
    proto_put_u32(head, PROTO_MAX_JOBS + 1);
    CHECK(job_list_check(head, 4, "cap", &alloc) == PT_ERR_PROTO && alloc == 0);
    proto_put_u32(head, UINT32_MAX);
    CHECK(job_list_check(head, 4, "cap", &alloc) == PT_ERR_PROTO && alloc == 0);
    /* A count that the bytes present cannot hold: refused before allocating. */
    proto_writer_reset(&w);
    jobs[0] = sample_job_info(1); /* the smallest entry: 162 bytes */
    CHECK(proto_msg_encode_job_list(&w, jobs, 1, &err) == PT_OK && w.len == 4 + 162);
    CHECK(job_list_check(w.buf, w.len, NULL, &alloc) == PT_OK && alloc == 1);
    proto_put_u32(w.buf, 2);
    CHECK(job_list_check(w.buf, w.len, "bytes", &alloc) == PT_ERR_PROTO && alloc == 0);
    proto_put_u32(w.buf, PROTO_MAX_JOBS);
    CHECK(job_list_check(w.buf, w.len, "bytes", &alloc) == PT_ERR_PROTO && alloc == 0);
    /* A count the bytes could hold, with entries that do not add up: refused
     * after allocating, nothing leaked. */
    proto_writer_reset(&w);
    jobs[0] = sample_job_info(2);
    CHECK(proto_msg_encode_job_list(&w, jobs, 1, &err) == PT_OK);
    proto_put_u32(w.buf, 3);
    CHECK(job_list_check(w.buf, w.len, "truncated", &alloc) == PT_ERR_PROTO && alloc == 1);
    proto_put_u32(w.buf, 0);
    CHECK(job_list_check(w.buf, w.len, "trailing", &alloc) == PT_ERR_PROTO && alloc == 0);
    CHECK(pt_alloc_live() == live + 1); /* the writer's block */
    /* An entry refused inside a list (string over its cap). */
    proto_writer_reset(&w);
    proto_w_u32(&w, 1);
    proto_w_u64(&w, 1);
    proto_w_u8(&w, 1);
    proto_w_u32(&w, 0);
    w_str(&w, PROTO_MAX_NAME + 1, 'n');
    for (int k = 0; k < 40; k++)
        proto_w_u32(&w, 0);
    CHECK(job_list_check(w.buf, w.len, "name", &alloc) == PT_ERR_PROTO);
    CHECK(pt_alloc_live() == live + 1);

    /* The allocation-failure loop over a decode. */
    proto_writer_reset(&w);
    for (int k = 0; k < 3; k++)
        jobs[k] = sample_job_info(k);
    CHECK(proto_msg_encode_job_list(&w, jobs, 3, &err) == PT_OK);
    int done = 0;
    for (uint64_t k = 1; k < 50 && !done; k++) {
        proto_job_list r;
        memset(&r, 0xCD, sizeof r);
        proto_job_list before = r;
        pt_alloc_fail_at(k);
        pt_status st = proto_msg_decode_job_list(w.buf, w.len, &r, &err);
        pt_alloc_fail_at(0);
        if (st == PT_OK) {
            CHECK(r.count == 3 && job_info_same(&r.jobs[2], &jobs[2]));
            pt_free(r.jobs);
            done = 1;
        } else {
            CHECK(st == PT_ERR_NOMEM && memcmp(&r, &before, sizeof r) == 0);
        }
        CHECK(pt_alloc_live() == live + 1);
    }
    CHECK(done);
    proto_writer_fini(&w);
}

static void test_client_types(void)
{
    static const uint16_t client[] = {PROTO_MSG_SUBMIT,   PROTO_MSG_LIST,      PROTO_MSG_STATUS,
                                      PROTO_MSG_WATCH,    PROTO_MSG_CANCEL,    PROTO_MSG_FETCH,
                                      PROTO_MSG_UPLOAD,   PROTO_MSG_SUBMITTED, PROTO_MSG_JOB_LIST,
                                      PROTO_MSG_JOB_INFO, PROTO_MSG_IMAGE};
    for (size_t i = 0; i < sizeof client / sizeof client[0]; i++) {
        CHECK(proto_msg_type_known(client[i]));
        CHECK(!proto_msg_type_preauth(client[i]));
    }
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_UPLOAD), "UPLOAD") == 0);
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_SUBMITTED), "SUBMITTED") == 0);
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_JOB_LIST), "JOB_LIST") == 0);
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_JOB_INFO), "JOB_INFO") == 0);
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_IMAGE), "IMAGE") == 0);
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_JOB_END), "JOB_END") == 0);
    CHECK(proto_msg_type_known(PROTO_MSG_JOB_END) && !proto_msg_type_preauth(PROTO_MSG_JOB_END));
    CHECK(strcmp(proto_msg_type_name(PROTO_MSG_FETCH_FRAME), "FETCH_FRAME") == 0);
    CHECK(!proto_msg_type_known(40) && !proto_msg_type_known(47) && !proto_msg_type_known(52));
    /* UPLOAD and IMAGE go through the SCENE_CHUNK decoder; JOB_REF types share one. */
    proto_writer w;
    pt_error err = {0};
    proto_writer_init(&w, 4096);
    CHECK(sample_payload(8, 0, &w) == PROTO_MSG_SCENE_CHUNK);
    CHECK(decode_any(PROTO_MSG_UPLOAD, w.buf, w.len, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_IMAGE, w.buf, w.len - 1, &err) == PT_ERR_PROTO);
    proto_writer_reset(&w);
    proto_job_ref ref = {7};
    CHECK(proto_msg_encode_job_ref(&w, &ref, &err) == PT_OK && w.len == 8);
    CHECK(decode_any(PROTO_MSG_CANCEL, w.buf, w.len, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_FETCH, w.buf, 7, &err) == PT_ERR_PROTO);
    proto_writer_fini(&w);
}

/* Protocol 4's frame ranges: SUBMIT's range and pose, TASK's pose,
 * FETCH_FRAME; each malformed value refused by both sides. */
static void test_frames(void)
{
    proto_submit m = sample_submit(0);
    CHECK(m.frame_step == 2 && submit_check(&m, NULL) == PT_OK);
    m.frame_last = 0; /* reversed */
    CHECK(submit_check(&m, "frame range") == PT_ERR_PROTO);
    m = sample_submit(0);
    m.frame_step = 0; /* a still with a range's other fields */
    CHECK(submit_check(&m, "frame range") == PT_ERR_PROTO);
    m = sample_submit(0);
    m.frame_first = 0;
    m.frame_last = 100000; /* 100001 frames */
    m.frame_step = 1;
    CHECK(submit_check(&m, "frame range") == PT_ERR_PROTO);
    m.frame_last = 99999;
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.fps = 0.0;
    CHECK(submit_check(&m, "frames per second") == PT_ERR_PROTO);
    m.fps = NAN;
    CHECK(submit_check(&m, "frames per second") == PT_ERR_PROTO);
    m.fps = INFINITY;
    CHECK(submit_check(&m, "frames per second") == PT_ERR_PROTO);
    m = sample_submit(1); /* a still: no rate, no animation */
    CHECK(submit_check(&m, NULL) == PT_OK);
    m.fps = 24.0;
    CHECK(submit_check(&m, "frames per second") == PT_ERR_PROTO);
    m.fps = 0.0;
    strcpy(m.animation, "Walk");
    CHECK(submit_check(&m, "animation") == PT_ERR_PROTO);

    pt_error err = {0};
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_task t = sample_task(1), back;
    CHECK(t.animate == 1);
    for (int k = 0; k < 4; k++) {
        t = sample_task(k < 2);
        if (k == 0)
            t.animate = 2;
        else if (k == 1)
            t.time = NAN;
        else if (k == 2)
            t.time = 1.0; /* a time without animate */
        else
            t.time = -0.0 - 1.0;
        proto_writer_reset(&w);
        CHECKF(proto_msg_encode_task(&w, &t, &err) == PT_ERR_ARG && w.len == 0, "pose %d", k);
        /* By hand: the good bytes with the bad pose patched in. */
        proto_task good = sample_task(k < 2);
        CHECK(proto_msg_encode_task(&w, &good, &err) == PT_OK);
        uint8_t *pose = w.buf + w.len - 37 - 8 - 16 - POSE_TAIL(good); /* shutter... after */
        pose[0] = t.animate;
        proto_put_u64(pose + 1, proto_f64_bits(t.time));
        CHECKF(decode_any(PROTO_MSG_TASK, w.buf, w.len, &err) == PT_ERR_PROTO &&
                   (strstr(err.msg, "animate") || strstr(err.msg, "time")),
               "pose %d: %s", k, err.msg);
    }
    /* The protocol-3 layout (no pose) is a truncated TASK now. */
    t = sample_task(0);
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_task(&w, &t, &err) == PT_OK);
    CHECK(decode_any(PROTO_MSG_TASK, w.buf, w.len - 37 - 8 - 16 - POSE_TAIL(t), &err) ==
          PT_ERR_PROTO);
    CHECK(proto_msg_decode_task(w.buf, w.len, &back, &err) == PT_OK && back.animate == 0 &&
          back.time == 0.0);

    proto_fetch_frame ff = {UINT64_MAX, 999999}, fb;
    proto_writer_reset(&w);
    CHECK(proto_msg_encode_fetch_frame(&w, &ff, &err) == PT_OK && w.len == 12);
    CHECK(proto_msg_decode_fetch_frame(w.buf, w.len, &fb, &err) == PT_OK &&
          fb.job_id == UINT64_MAX && fb.frame == 999999);
    CHECK(decode_any(PROTO_MSG_FETCH_FRAME, w.buf, 11, &err) == PT_ERR_PROTO);
    proto_w_u8(&w, 0);
    CHECK(decode_any(PROTO_MSG_FETCH_FRAME, w.buf, w.len, &err) == PT_ERR_PROTO);
    proto_writer_fini(&w);
}

int main(void)
{
    test_types();
    test_frames();
    test_samples();
    test_strings();
    test_task();
    test_counts();
    test_result();
    test_result_clamped();
    test_result_guide();
    test_guide_pack();
    test_denoise_task();
    test_denoise_result();
    test_denoise_types();
    test_submit();
    test_job_info();
    test_job_list();
    test_client_types();
    return check_report();
}
