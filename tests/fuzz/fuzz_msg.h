/*
 * fuzz_msg.h - decodes one message payload with the decoder its type names,
 * and checks that what decodes re-encodes to the very same bytes (the
 * encoding is canonical, so any difference is a decoder bug).
 * Shared by fuzz_msg.c (type from the first input byte) and fuzz_frame.c
 * (type from each decoded frame). Aborts on a broken invariant.
 */
#ifndef PT_TESTS_FUZZ_MSG_H
#define PT_TESTS_FUZZ_MSG_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "protocol/frame.h"
#include "protocol/msg.h"

#define FUZZ_CHECK(cond)                                                                           \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "%s:%d: fuzz invariant broken: %s\n", __FILE__, __LINE__, #cond);      \
            abort();                                                                               \
        }                                                                                          \
    } while (0)

/* Re-encodes with enc and compares with the input payload. */
#define FUZZ_REENCODE(enc, msgp)                                                                   \
    do {                                                                                           \
        proto_writer w_;                                                                           \
        proto_writer_init(&w_, PROTO_MAX_PAYLOAD);                                                 \
        FUZZ_CHECK(enc(&w_, (msgp), NULL) == PT_OK);                                               \
        FUZZ_CHECK(w_.len == len && (len == 0 || memcmp(w_.buf, p, len) == 0));                    \
        proto_writer_fini(&w_);                                                                    \
    } while (0)

/* Decodes payload p[0, len) as type; use_buf picks the caller-buffer path of
 * RESULT. Returns the decoder's status. */
static inline pt_status fuzz_decode(uint32_t type, const uint8_t *p, size_t len, int use_buf)
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
    } u;
    static pt_pixel_acc pixels[64];
    pt_error err = {0}; /* a decoder that fails must fill it */
    pt_status st = PT_ERR_ARG;
    int64_t live = pt_alloc_live();
    switch (type) {
    case PROTO_MSG_HELLO:
        st = proto_msg_decode_hello(p, len, &u.hello, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_hello, &u.hello);
        break;
    case PROTO_MSG_CHALLENGE:
        st = proto_msg_decode_challenge(p, len, &u.challenge, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_challenge, &u.challenge);
        break;
    case PROTO_MSG_AUTH:
        st = proto_msg_decode_auth(p, len, &u.auth, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_auth, &u.auth);
        break;
    case PROTO_MSG_WELCOME:
        st = proto_msg_decode_welcome(p, len, &u.welcome, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_welcome, &u.welcome);
        break;
    case PROTO_MSG_ERROR:
        st = proto_msg_decode_error(p, len, &u.error, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_error, &u.error);
        break;
    case PROTO_MSG_WORK_REQUEST:
        st = proto_msg_decode_work_request(p, len, &u.work, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_work_request, &u.work);
        break;
    case PROTO_MSG_TASK:
        st = proto_msg_decode_task(p, len, &u.task, &err);
        if (st == PT_OK) {
            FUZZ_CHECK(u.task.tile.x0 < u.task.tile.x1 && u.task.tile.y1 <= u.task.height);
            FUZZ_REENCODE(proto_msg_encode_task, &u.task);
        }
        break;
    case PROTO_MSG_SCENE_GET:
    case PROTO_MSG_GUIDE_GET:
    case PROTO_MSG_DENOISE_GET:
        st = proto_msg_decode_scene_get(p, len, &u.get, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_scene_get, &u.get);
        break;
    case PROTO_MSG_SCENE_CHUNK:
    case PROTO_MSG_GUIDE_CHUNK:
    case PROTO_MSG_DENOISE_CHUNK:
    case PROTO_MSG_UPLOAD:
    case PROTO_MSG_IMAGE:
        st = proto_msg_decode_scene_chunk(p, len, &u.chunk, &err);
        if (st == PT_OK) {
            FUZZ_CHECK(u.chunk.data >= p && u.chunk.data + u.chunk.len <= p + len);
            FUZZ_REENCODE(proto_msg_encode_scene_chunk, &u.chunk);
        }
        break;
    case PROTO_MSG_RESULT:
        st = proto_msg_decode_result(p, len, use_buf ? pixels : NULL,
                                     use_buf ? sizeof pixels / sizeof pixels[0] : 0, &u.result,
                                     &err);
        if (st == PT_OK) {
            FUZZ_CHECK(u.result.npixels <= PROTO_MAX_TILE_PIXELS);
            /* With passes, always a block of its own: the pixels, then them. */
            FUZZ_CHECK(u.result.owns_pixels == (!use_buf || u.result.pass != NULL));
            FUZZ_CHECK(!u.result.pass ||
                       u.result.pass == (pt_pass_acc *)(u.result.pixels + u.result.npixels));
            FUZZ_REENCODE(proto_msg_encode_result, &u.result);
            proto_result_fini(&u.result);
        }
        break;
    case PROTO_MSG_DENOISE_TASK:
        st = proto_msg_decode_denoise_task(p, len, &u.denoise_task, &err);
        if (st == PT_OK) {
            FUZZ_CHECK((u.denoise_task.task_id & PROTO_DENOISE_TASK_BIT) &&
                       u.denoise_task.region.x1 <= u.denoise_task.crop_w &&
                       u.denoise_task.region.y1 <= u.denoise_task.crop_h);
            FUZZ_REENCODE(proto_msg_encode_denoise_task, &u.denoise_task);
        }
        break;
    case PROTO_MSG_DENOISE_RESULT:
        st = proto_msg_decode_denoise_result(p, len, &u.denoise_result, &err);
        if (st == PT_OK) {
            /* Borrowed: the pixels are the payload's last 12N bytes. */
            FUZZ_CHECK(u.denoise_result.data >= p &&
                       u.denoise_result.data + (size_t)u.denoise_result.npixels * 12 == p + len);
            FUZZ_REENCODE(proto_msg_encode_denoise_result, &u.denoise_result);
        }
        break;
    case PROTO_MSG_HEARTBEAT:
        st = proto_msg_decode_heartbeat(p, len, &u.hb, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_heartbeat, &u.hb);
        break;
    case PROTO_MSG_STATUS:
    case PROTO_MSG_WATCH:
    case PROTO_MSG_CANCEL:
    case PROTO_MSG_FETCH:
    case PROTO_MSG_SUBMITTED:
    case PROTO_MSG_JOB_END:
        st = proto_msg_decode_job_ref(p, len, &u.ref, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_job_ref, &u.ref);
        break;
    case PROTO_MSG_FETCH_FRAME:
        st = proto_msg_decode_fetch_frame(p, len, &u.fetch_frame, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_fetch_frame, &u.fetch_frame);
        break;
    case PROTO_MSG_SUBMIT:
        st = proto_msg_decode_submit(p, len, &u.submit, &err);
        if (st == PT_OK) {
            FUZZ_CHECK(u.submit.spp > 0 && u.submit.bundle_size > 0);
            FUZZ_CHECK((u.submit.width == 0) == (u.submit.height == 0));
            FUZZ_REENCODE(proto_msg_encode_submit, &u.submit);
        }
        break;
    case PROTO_MSG_JOB_INFO:
        st = proto_msg_decode_job_info(p, len, &u.info, &err);
        if (st == PT_OK)
            FUZZ_REENCODE(proto_msg_encode_job_info, &u.info);
        break;
    case PROTO_MSG_JOB_LIST:
        st = proto_msg_decode_job_list(p, len, &u.list, &err);
        if (st == PT_OK) {
            FUZZ_CHECK(u.list.count <= PROTO_MAX_JOBS && (u.list.count == 0) == !u.list.jobs);
            proto_writer w_;
            proto_writer_init(&w_, PROTO_MAX_PAYLOAD);
            FUZZ_CHECK(proto_msg_encode_job_list(&w_, u.list.jobs, u.list.count, NULL) == PT_OK);
            FUZZ_CHECK(w_.len == len && memcmp(w_.buf, p, len) == 0);
            proto_writer_fini(&w_);
            pt_free(u.list.jobs);
        }
        break;
    default:
        return PT_ERR_ARG;
    }
    /* A failure names its cause, and nothing is left allocated either way. */
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0] != '\0'));
    FUZZ_CHECK(pt_alloc_live() == live);
    return st;
}

/* The decodable types, indexed by the fuzz_msg selector byte, in the order
 * of the samples of tests/protocol/samples.h (gen_corpus writes selector =
 * sample index). One type per decoder: the other JOB_REF types, UPLOAD,
 * IMAGE and the GUIDE_ and DENOISE_ GET and CHUNK share a decoder with one
 * listed here. */
static const uint16_t fuzz_types[] = {
    PROTO_MSG_HELLO,         PROTO_MSG_CHALLENGE,    PROTO_MSG_AUTH,      PROTO_MSG_WELCOME,
    PROTO_MSG_ERROR,         PROTO_MSG_WORK_REQUEST, PROTO_MSG_TASK,      PROTO_MSG_SCENE_GET,
    PROTO_MSG_SCENE_CHUNK,   PROTO_MSG_RESULT,       PROTO_MSG_HEARTBEAT, PROTO_MSG_WATCH,
    PROTO_MSG_SUBMIT,        PROTO_MSG_JOB_INFO,     PROTO_MSG_JOB_LIST,  PROTO_MSG_DENOISE_TASK,
    PROTO_MSG_DENOISE_RESULT};
#define FUZZ_NTYPES (sizeof fuzz_types / sizeof fuzz_types[0])

#endif
