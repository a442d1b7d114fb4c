/*
 * samples.h - one valid message of every implemented type, for the protocol
 * tests and the fuzz corpus generator.
 *
 * sample_payload(i, v, w) appends the payload of sample i (0..SAMPLE_COUNT-1)
 * in variant v (0 or 1: different sizes, strings and counts) to w and returns
 * its frame type, or 0 on failure. RESULT samples use a static pixel array,
 * DENOISE_RESULT ones a static byte array.
 * The bytes never change with the build (the fuzz corpus is generated from them).
 */
#ifndef PT_TESTS_PROTOCOL_SAMPLES_H
#define PT_TESTS_PROTOCOL_SAMPLES_H

#include <stdint.h>
#include <string.h>

#include "protocol/frame.h"
#include "protocol/msg.h"

/* The order is the fuzz_msg selector's (tests/fuzz/fuzz_msg.h, fuzz_types). */
#define SAMPLE_COUNT 17

static pt_pixel_acc sample_pixels[4 * 3];
static uint8_t sample_scene_bytes[300];

static inline void sample_hash(uint8_t h[PROTO_HASH_SIZE], unsigned salt)
{
    for (unsigned i = 0; i < PROTO_HASH_SIZE; i++)
        h[i] = (uint8_t)(i * 37u + salt);
}

static inline proto_hello sample_hello(int v)
{
    proto_hello m;
    memset(&m, 0, sizeof m);
    m.version = PROTO_VERSION;
    m.role = v ? PROTO_ROLE_CLIENT : PROTO_ROLE_WORKER;
    strcpy(m.name, v ? "" : "render-node-07");
    m.threads = v ? 0 : 64;
    strcpy(m.build_id, v ? "0123456789abcdef" : "fedcba9876543210");
    m.caps = v ? 0xA5A5A5A5u : 0;
    return m;
}

static inline proto_task sample_task(int v)
{
    proto_task m;
    memset(&m, 0, sizeof m);
    m.job_id = v ? 0xFFFFFFFFFFFFFFFFull : 3;
    m.task_id = v ? 0x0102030405060708ull : 17;
    m.tile = v ? (pt_rect){0, 0, 256, 256} : (pt_rect){32, 64, 64, 96};
    m.s0 = v ? 0 : 64;
    m.s1 = v ? 1 : 128;
    m.width = v ? 256 : 1920;
    m.height = v ? 256 : 1080;
    m.seed = v ? 0xDEADBEEFu : 7;
    m.max_depth = 16;
    m.rr_depth = 3;
    sample_hash(m.scene_hash, (unsigned)v);
    m.lease_ms = v ? 0 : 30000;
    strcpy(m.camera, v ? "" : "Camera.001");
    /* v 0: a uniform background; v 1: a map, strengthened and turned. */
    proto_env_none(&m.env);
    if (v) {
        strcpy(m.env.name, ".ptfarm/environment");
        m.env.strength = 2.5f;
        m.env.rotate_deg = -90.0f;
    } else {
        m.env.background = 1;
        m.env.rgb[0] = 0.5f;
        m.env.rgb[1] = 0.25f;
        m.env.rgb[2] = 1e-3f;
    }
    m.film_flags = v ? PROTO_FILM_TRANSPARENT : 0;
    strcpy(m.variant, v ? "" : "Peacock Velvet");
    /* v 1: a frame of an animation. */
    m.animate = v ? 1 : 0;
    m.time = v ? 41.0 / 24.0 : 0.0;
    strcpy(m.animation, v ? "Walk" : "");
    /* v 0: a 180-degree shutter at 24 frames per second; v 1: off. */
    m.shutter[0] = 0.0;
    m.shutter[1] = v ? 0.0 : 0.5 / 24.0;
    /* v 0: indirect light clamped at 10; v 1: direct at 0.5. */
    m.clamp[0] = v ? 0.5f : 0.0f;
    m.clamp[1] = v ? 0.0f : 10.0f;
    /* v 0: guided pass 2, recording; v 1: the last pass, at its largest
     * number, recording nothing. */
    m.guided = v ? PROTO_GUIDE_LAST : PROTO_GUIDE_RECORD;
    m.guide_pass = v ? PROTO_MAX_GUIDE_PASS : 2;
    sample_hash(m.guide_hash, 40u + (unsigned)v);
    return m;
}

static pt_pass_acc sample_passes[12];
static inline proto_result sample_result(int v)
{
    proto_result m;
    memset(&m, 0, sizeof m);
    for (unsigned i = 0; i < 12; i++) {
        /* Pixel 0 alone (v = 1) fits the narrow form, at its edges (the
         * least i64, the largest u64); the 12 (v = 0) need the wide one. */
        sample_pixels[i].fsum[0] = (pt_i128)i << 30;
        sample_pixels[i].fsum[1] = i ? -((pt_i128)1 << 100) - i : -7;
        sample_pixels[i].fsum[2] = i == 5 ? ((pt_i128)1 << 126) + 12345 : (pt_i128)INT64_MIN;
        sample_pixels[i].fsum_sq = i == 3 ? PT_U128_MAX : (pt_u128)UINT64_MAX - i;
        sample_pixels[i].n = i % 9;
        sample_pixels[i].hits = i % 9 - i % 9 % 2; /* <= n, some below */
    }
    m.job_id = 3;
    m.task_id = v ? 99 : 17;
    m.tile = v ? (pt_rect){10, 20, 11, 21} : (pt_rect){100, 200, 104, 203};
    m.s0 = 8;
    m.s1 = 16;
    m.rejected = v ? 0 : 5;
    m.rays = v ? 1 : 123456789012ull;
    m.capped = v ? 0 : 0x0102030405060708ull;
    m.npixels = v ? 1 : 12;
    m.pixels = sample_pixels;
    return m;
}

/* sample_result(v) with render passes' sums: narrow for pixel 0 alone (v =
 * 1), one wide value among the 12 (v = 0). */
static inline proto_result sample_result_passes(int v)
{
    proto_result m = sample_result(v);
    for (unsigned i = 0; i < 12; i++) {
        for (int k = 0; k < PT_PASS_SUMS; k++)
            sample_passes[i].s[k] = (pt_i128)(k + 1) * (i + 1) * (k % 2 ? -1 : 1);
        for (int k = 0; k < PT_PASS_SQS; k++)
            sample_passes[i].sq[k] = (pt_u128)k * 1000 + i;
        sample_passes[i].s[3] = i == 5 ? -((pt_i128)1 << 90) : sample_passes[i].s[3];
        sample_passes[i].n_even = sample_pixels[i].n / 2;
        memset(sample_passes[i].cid, 0, sizeof sample_passes[i].cid);
        memset(sample_passes[i].ccnt, 0, sizeof sample_passes[i].ccnt);
        if (sample_pixels[i].n > 1) { /* two ids a kind, counts summing to n */
            for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
                sample_passes[i].cid[k][0] = 3u + (unsigned)k;
                sample_passes[i].cid[k][1] = 0x80000000u + i;
                sample_passes[i].ccnt[k][0] = 1;
                sample_passes[i].ccnt[k][1] = sample_pixels[i].n - 1;
            }
        }
        sample_passes[i].pad = 0;
    }
    m.pass = sample_passes;
    return m;
}

static inline proto_heartbeat *sample_heartbeat(int v)
{
    static proto_heartbeat m;
    m.count = v ? 0 : 5;
    for (unsigned i = 0; i < m.count; i++)
        m.task_ids[i] = 1000u + i * i;
    return &m;
}

/* JOB_INFO: v 0 a running job with every string set, v 1 a queued one with
 * empty strings; v 2 a failed one with strings at their caps (JOB_LIST only). */
static inline proto_submit sample_submit(int v)
{
    proto_submit m;
    memset(&m, 0, sizeof m);
    strcpy(m.name, v ? "" : "cornell final");
    m.width = v ? 0 : 1920;
    m.height = v ? 0 : 1080;
    m.spp = v ? 1 : 1024;
    m.seed = v ? UINT32_MAX : 7;
    m.priority = v ? INT32_MIN : -3;
    m.max_depth = v ? 0 : 8;
    m.min_spp = v ? 0 : 64;
    m.target_error = v ? 0.0 : 0.01;
    m.bundle_size = v ? UINT64_MAX : 123456;
    sample_hash(m.bundle_hash, 3u + (unsigned)v);
    strcpy(m.camera, v ? "" : "close-up");
    m.min_gain = v ? 2.5e-7 : 0.0;
    /* v 0: a map; v 1: none. */
    proto_env_none(&m.env);
    if (!v) {
        strcpy(m.env.name, ".ptfarm/environment");
        m.env.strength = 0.75f;
        m.env.rotate_deg = 180.0f;
    }
    m.film_flags = v ? PROTO_FILM_TRANSPARENT : 0;
    strcpy(m.variant, v ? "" : "Mango Velvet");
    /* v 0: a frame range. */
    if (!v) {
        m.frame_first = 1;
        m.frame_last = 240;
        m.frame_step = 2;
        m.fps = 23.976;
        strcpy(m.animation, "Survey");
    }
    m.shutter[0] = v ? 0.25 / 30.0 : 0.0;
    m.shutter[1] = v ? 0.75 / 30.0 : 0.0;
    m.clamp[0] = v ? 0.0f : 3.0f;
    m.clamp[1] = v ? 1e30f : 0.25f;
    return m;
}

static inline proto_job_info sample_job_info(int v)
{
    proto_job_info m;
    memset(&m, 0, sizeof m);
    m.job_id = v == 1 ? 1 : 0x1122334455667788ull + (uint64_t)v;
    m.state = v == 0 ? PROTO_JOB_RUNNING : v == 1 ? PROTO_JOB_QUEUED : PROTO_JOB_FAILED;
    m.priority = v == 0 ? -5 : v == 1 ? INT32_MIN : INT32_MAX;
    if (v == 0) {
        strcpy(m.name, "cornell final");
        strcpy(m.owner, "alice@render-01");
        strcpy(m.scene, "cornell_box.gltf");
        strcpy(m.output, "job-12.exr");
        strcpy(m.message, "");
    } else if (v == 2) {
        memset(m.name, 'n', PROTO_MAX_NAME);
        memset(m.owner, 'o', PROTO_MAX_NAME);
        memset(m.scene, 's', PROTO_MAX_PATH);
        memset(m.output, 'x', PROTO_MAX_PATH);
        memset(m.message, 'm', PROTO_MAX_ERROR_TEXT);
    }
    m.width = v == 1 ? 0 : 1920;
    m.height = v == 1 ? 0 : 1080;
    m.spp = v == 1 ? 1 : 1024;
    m.samples_done = v == 0 ? 1234567890ull : 0;
    m.samples_total = v == 1 ? UINT64_MAX : 1920ull * 1080 * 1024;
    m.passes_done = v == 0 ? 3 : 0;
    m.passes = v == 0 ? 64 : 0;
    m.tiles_stopped = v == 0 ? 7 : 0;
    m.tiles = v == 0 ? 510 : 0;
    m.workers = v == 0 ? 4 : 0;
    m.seconds = v == 0 ? 123.25 : 0.0;
    m.rate = v == 0 ? 9.75e6 : -0.0;
    m.error = v == 0 ? 0.0125 : v == 1 ? -1.0 : proto_bits_f64(0x7FF8000000000001ull);
    m.submitted = v == 0 ? 1700000000u : UINT64_MAX;
    m.queue_pos = v == 1 ? 2 : 0;
    m.capped = v == 0 ? 12 : v == 2 ? UINT64_MAX : 0;
    m.rejected = v == 0 ? 34 : v == 2 ? UINT64_MAX : 0;
    m.clamped = v == 0 ? 56 : v == 2 ? UINT64_MAX : 0;
    m.guided = v != 1;
    m.guide_pass = v == 0 ? 2 : v == 2 ? UINT32_MAX : 0;
    m.guide_spp = v == 0 ? 48 : v == 2 ? UINT32_MAX : 0;
    m.bdpt = v == 2;
    if (v == 0) { /* a frame range, two frames rendering */
        m.frame_first = 1001;
        m.frame_last = 1100;
        m.frame_step = 1;
        m.frames_done = 12;
        m.frames_rendering = 2;
        m.nshown = 2;
        m.shown[0].frame = 1013;
        m.shown[0].samples_done = 5000;
        m.shown[0].samples_total = 8000;
        m.shown[1].frame = 1014;
        m.shown[1].samples_total = UINT64_MAX;
    }
    return m;
}

/* DENOISE_TASK: v 0 a region inside its crop, despeckled; v 1 the largest
 * region filling the largest crop, not despeckled. */
static inline proto_denoise_task sample_denoise_task(int v)
{
    proto_denoise_task m;
    memset(&m, 0, sizeof m);
    m.job_id = v ? UINT64_MAX : 3;
    m.task_id = PROTO_DENOISE_TASK_BIT | (v ? 0xFFFFFFFFull : 5);
    m.crop_w = v ? PROTO_MAX_DENOISE_CROP : 96;
    m.crop_h = v ? PROTO_MAX_DENOISE_CROP : 80;
    m.region = v ? (pt_rect){256, 0, 1280, 1024} : (pt_rect){32, 32, 64, 48};
    m.despeckle = v ? 0.0f : 2.0f;
    m.lease_ms = v ? 0 : 30000;
    sample_hash(m.hash, 50u + (unsigned)v);
    m.size = (uint64_t)m.crop_w * m.crop_h * PROTO_DENOISE_PLANES * 4;
    return m;
}

/* DENOISE_RESULT: v 0 a 4 x 3 region, v 1 one pixel; the planes' bytes
 * (12 a pixel) hold any floats, NaN and -0 among them. */
static uint8_t sample_denoise_bytes[12 * 12];
static inline proto_denoise_result sample_denoise_result(int v)
{
    static const uint32_t bits[4] = {0x3F800000u, 0x80000000u, 0x7FC00001u, 0x00000001u};
    for (unsigned i = 0; i < sizeof sample_denoise_bytes / 4; i++)
        proto_put_u32(sample_denoise_bytes + 4 * i, i < 4 ? bits[i] : 0x3E800000u + i);
    proto_denoise_result m;
    memset(&m, 0, sizeof m);
    m.job_id = v ? 0 : 3;
    m.task_id = PROTO_DENOISE_TASK_BIT | (v ? 0 : 5);
    m.region = v ? (pt_rect){0, 0, 1, 1} : (pt_rect){32, 32, 36, 35};
    m.npixels = v ? 1 : 12;
    m.data = sample_denoise_bytes;
    return m;
}

static inline uint16_t sample_payload(int i, int v, proto_writer *w)
{
    pt_status st = PT_ERR_ARG;
    uint16_t type = 0;
    switch (i) {
    case 0: {
        proto_hello m = sample_hello(v);
        type = PROTO_MSG_HELLO;
        st = proto_msg_encode_hello(w, &m, NULL);
        break;
    }
    case 1: {
        proto_challenge m;
        sample_hash(m.nonce, 11u + (unsigned)v);
        type = PROTO_MSG_CHALLENGE;
        st = proto_msg_encode_challenge(w, &m, NULL);
        break;
    }
    case 2: {
        proto_auth m;
        sample_hash(m.mac, 23u + (unsigned)v);
        sample_hash(m.nonce, 29u + (unsigned)v);
        type = PROTO_MSG_AUTH;
        st = proto_msg_encode_auth(w, &m, NULL);
        break;
    }
    case 3: {
        proto_welcome m;
        memset(&m, 0, sizeof m);
        m.session_id = v ? 0 : 0x8877665544332211ull;
        sample_hash(m.proof, 31u + (unsigned)v);
        strcpy(m.build_id, v ? "x" : "fedcba9876543210");
        type = PROTO_MSG_WELCOME;
        st = proto_msg_encode_welcome(w, &m, NULL);
        break;
    }
    case 4: {
        proto_error_msg m;
        memset(&m, 0, sizeof m);
        m.code = v ? 999 : PROTO_E_AUTH;
        strcpy(m.text, v ? "" : "wrong response to the challenge");
        type = PROTO_MSG_ERROR;
        st = proto_msg_encode_error(w, &m, NULL);
        break;
    }
    case 5: {
        proto_work_request m = {(uint16_t)(v ? PROTO_MAX_SLOTS : 9)};
        type = PROTO_MSG_WORK_REQUEST;
        st = proto_msg_encode_work_request(w, &m, NULL);
        break;
    }
    case 6: {
        proto_task m = sample_task(v);
        type = PROTO_MSG_TASK;
        st = proto_msg_encode_task(w, &m, NULL);
        break;
    }
    case 7: {
        proto_scene_get m;
        sample_hash(m.hash, 5u + (unsigned)v);
        m.offset = v ? 1u << 20 : 0;
        type = PROTO_MSG_SCENE_GET;
        st = proto_msg_encode_scene_get(w, &m, NULL);
        break;
    }
    case 8: {
        proto_scene_chunk m;
        for (unsigned k = 0; k < sizeof sample_scene_bytes; k++)
            sample_scene_bytes[k] = (uint8_t)(k ^ 0x5a);
        sample_hash(m.hash, 5u + (unsigned)v);
        m.offset = v ? 1000 : 0;
        m.len = v ? 0 : (uint32_t)sizeof sample_scene_bytes;
        m.total = v ? 1000 : 4096;
        m.data = sample_scene_bytes;
        type = PROTO_MSG_SCENE_CHUNK;
        st = proto_msg_encode_scene_chunk(w, &m, NULL);
        break;
    }
    case 9: {
        proto_result m = sample_result(v);
        type = PROTO_MSG_RESULT;
        st = proto_msg_encode_result(w, &m, NULL);
        break;
    }
    case 10: {
        type = PROTO_MSG_HEARTBEAT;
        st = proto_msg_encode_heartbeat(w, sample_heartbeat(v), NULL);
        break;
    }
    case 11: {
        proto_job_ref m = {v ? UINT64_MAX : 42};
        type = v ? PROTO_MSG_SUBMITTED : PROTO_MSG_WATCH;
        st = proto_msg_encode_job_ref(w, &m, NULL);
        break;
    }
    case 12: {
        proto_submit m = sample_submit(v);
        type = PROTO_MSG_SUBMIT;
        st = proto_msg_encode_submit(w, &m, NULL);
        break;
    }
    case 13: {
        proto_job_info m = sample_job_info(v);
        type = PROTO_MSG_JOB_INFO;
        st = proto_msg_encode_job_info(w, &m, NULL);
        break;
    }
    case 14: {
        static proto_job_info jobs[3];
        for (int k = 0; k < 3; k++)
            jobs[k] = sample_job_info(k);
        type = PROTO_MSG_JOB_LIST;
        st = proto_msg_encode_job_list(w, jobs, v ? 0 : 3, NULL);
        break;
    }
    case 15: {
        proto_denoise_task m = sample_denoise_task(v);
        type = PROTO_MSG_DENOISE_TASK;
        st = proto_msg_encode_denoise_task(w, &m, NULL);
        break;
    }
    case 16: {
        proto_denoise_result m = sample_denoise_result(v);
        type = PROTO_MSG_DENOISE_RESULT;
        st = proto_msg_encode_denoise_result(w, &m, NULL);
        break;
    }
    }
    return st == PT_OK ? type : 0;
}

/* Appends sample i, variant v, as a whole frame; returns its type or 0. */
static inline uint16_t sample_frame(int i, int v, proto_writer *w)
{
    proto_writer pw;
    proto_writer_init(&pw, PROTO_MAX_PAYLOAD);
    uint16_t type = sample_payload(i, v, &pw);
    if (type && proto_frame_encode(w, type, pw.buf, pw.len, NULL) != PT_OK)
        type = 0;
    proto_writer_fini(&pw);
    return type;
}

#endif
