/*
 * samples.h - one valid message of every implemented type, for the protocol
 * tests and the fuzz corpus generator.
 *
 * sample_payload(i, v, w) appends the payload of sample i (0..SAMPLE_COUNT-1)
 * in variant v (0 or 1: different sizes, strings and counts) to w and returns
 * its frame type, or 0 on failure. RESULT samples use a static pixel array.
 * The bytes never change with the build (the fuzz corpus is generated from them).
 */
#ifndef PT_TESTS_PROTOCOL_SAMPLES_H
#define PT_TESTS_PROTOCOL_SAMPLES_H

#include <string.h>

#include "protocol/frame.h"
#include "protocol/msg.h"

#define SAMPLE_COUNT 11

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
    return m;
}

static inline proto_result sample_result(int v)
{
    proto_result m;
    memset(&m, 0, sizeof m);
    for (unsigned i = 0; i < 12; i++) {
        sample_pixels[i].sum[0] = 0.25 * i;
        sample_pixels[i].sum[1] = -1.5e300 / (i + 1);
        sample_pixels[i].sum[2] = i == 5 ? proto_bits_f64(0x7FF8000000000123ull) : 1e-310;
        sample_pixels[i].sum_sq = i * 3.0;
        sample_pixels[i].n = i % 9;
        sample_pixels[i].pad = 0;
    }
    m.job_id = 3;
    m.task_id = v ? 99 : 17;
    m.tile = v ? (pt_rect){10, 20, 11, 21} : (pt_rect){100, 200, 104, 203};
    m.s0 = 8;
    m.s1 = 16;
    m.rejected = v ? 0 : 5;
    m.rays = v ? 1 : 123456789012ull;
    m.npixels = v ? 1 : 12;
    m.pixels = sample_pixels;
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
        type = PROTO_MSG_AUTH;
        st = proto_msg_encode_auth(w, &m, NULL);
        break;
    }
    case 3: {
        proto_welcome m;
        memset(&m, 0, sizeof m);
        m.session_id = v ? 0 : 0x8877665544332211ull;
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
