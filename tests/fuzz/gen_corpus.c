/*
 * gen_corpus.c - writes or checks the seed corpus of the fuzz targets.
 *
 *   gen_corpus write DIR   writes the files of DIR/fuzz_frame and DIR/fuzz_msg
 *   gen_corpus check DIR   fails unless every generated file is in DIR with
 *                          the same bytes (other files, such as crash inputs
 *                          added by hand, are allowed)
 *
 * The seeds are the sample messages of tests/protocol/samples.h: for
 * fuzz_msg a selector byte (see fuzz_msg.c) and a payload; for fuzz_frame a
 * mode byte (see fuzz_frame.c) and frames, alone, in one stream, and a few
 * broken ones. ctest runs "check", so a change to the wire format that
 * forgets the corpus fails the suite; rerun "write" to refresh it.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "protocol/frame.h"
#include "protocol/msg.h"
#include "tests/protocol/samples.h"

static int write_mode;
static int failures;

static void emit(const char *dir, const char *target, const char *name, const uint8_t *data,
                 size_t len)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s/%s", dir, target, name);
    if (write_mode) {
        FILE *f = fopen(path, "wb");
        if (!f || fwrite(data, 1, len, f) != len || fclose(f) != 0) {
            fprintf(stderr, "cannot write %s\n", path);
            failures++;
        }
        return;
    }
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "missing %s (run gen_corpus write)\n", path);
        failures++;
        return;
    }
    uint8_t *have = malloc(len + 1);
    size_t got = have ? fread(have, 1, len + 1, f) : 0;
    fclose(f);
    if (!have || got != len || memcmp(have, data, len) != 0) {
        fprintf(stderr, "stale %s (run gen_corpus write)\n", path);
        failures++;
    }
    free(have);
}

/* Appends a mode byte then frames to w. */
static void frames(proto_writer *w, uint8_t mode, int variant_mask)
{
    proto_w_u8(w, mode);
    for (int v = 0; v < 2; v++)
        if (variant_mask & (1 << v))
            for (int s = 0; s < SAMPLE_COUNT; s++)
                if (!sample_frame(s, v, w))
                    failures++;
}

int main(int argc, char **argv)
{
    if (argc != 3 || (strcmp(argv[1], "write") && strcmp(argv[1], "check"))) {
        fprintf(stderr, "usage: %s write|check DIR\n", argv[0]);
        return 2;
    }
    write_mode = strcmp(argv[1], "write") == 0;
    const char *dir = argv[2];
    if (write_mode) {
        char path[4096];
        mkdir(dir, 0755);
        snprintf(path, sizeof path, "%s/fuzz_frame", dir);
        mkdir(path, 0755);
        snprintf(path, sizeof path, "%s/fuzz_msg", dir);
        mkdir(path, 0755);
    }
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    char name[64];

    for (int s = 0; s < SAMPLE_COUNT; s++) {
        for (int v = 0; v < 2; v++) {
            /* fuzz_msg: selector then payload; RESULT also through the caller's buffer. */
            for (int path = 0; path < (s == 9 ? 2 : 1); path++) {
                proto_writer_reset(&w);
                proto_w_u8(&w, (uint8_t)(s + path * SAMPLE_COUNT));
                uint16_t type = sample_payload(s, v, &w);
                if (!type || proto_writer_status(&w) != PT_OK) {
                    failures++;
                    continue;
                }
                snprintf(name, sizeof name, "%s_%d%s", proto_msg_type_name(type), v,
                         path ? "_buf" : "");
                emit(dir, "fuzz_msg", name, w.buf, w.len);
            }
            /* fuzz_frame: one frame, whole and byte by byte. */
            proto_writer_reset(&w);
            proto_w_u8(&w, (uint8_t)(v ? 0x01 : 0x00));
            uint16_t type = sample_frame(s, v, &w);
            if (!type) {
                failures++;
                continue;
            }
            snprintf(name, sizeof name, "%s_%d", proto_msg_type_name(type), v);
            emit(dir, "fuzz_frame", name, w.buf, w.len);
        }
    }

    /* Streams: every sample in pieces of 4 (pre-auth cap) and of 16. */
    proto_writer_reset(&w);
    frames(&w, 0x07, 3);
    emit(dir, "fuzz_frame", "stream_all_preauth", w.buf, w.len);
    proto_writer_reset(&w);
    frames(&w, 0x1E, 1);
    emit(dir, "fuzz_frame", "stream_v0", w.buf, w.len);
    /* A stream that turns to garbage, and one cut short. */
    proto_writer_reset(&w);
    frames(&w, 0x02, 2);
    proto_w_bytes(&w, "GET / HTTP/1.1\r\n", 16);
    emit(dir, "fuzz_frame", "stream_then_garbage", w.buf, w.len);
    proto_writer_reset(&w);
    frames(&w, 0x04, 2);
    w.len -= 5;
    emit(dir, "fuzz_frame", "stream_cut", w.buf, w.len);
    /* Empty frames of the client types (LIST is empty by design; the
     * others' decoders refuse them). */
    proto_writer_reset(&w);
    proto_w_u8(&w, 0);
    for (uint16_t t = PROTO_MSG_SUBMIT; t <= PROTO_MSG_IMAGE; t++)
        if (proto_msg_type_known(t) && proto_frame_encode(&w, t, NULL, 0, NULL) != PT_OK)
            failures++;
    emit(dir, "fuzz_frame", "client_empty", w.buf, w.len);
    /* A client session: SUBMIT, UPLOAD (SCENE_CHUNK layout), the JOB_REF
     * requests, then the server's answers (IMAGE in the SCENE_CHUNK layout). */
    {
        static const uint16_t session[][2] = {
            {12, PROTO_MSG_SUBMIT},   {8, PROTO_MSG_UPLOAD},    {11, PROTO_MSG_SUBMITTED},
            {11, PROTO_MSG_STATUS},   {11, PROTO_MSG_CANCEL},   {11, PROTO_MSG_FETCH},
            {13, PROTO_MSG_JOB_INFO}, {14, PROTO_MSG_JOB_LIST}, {8, PROTO_MSG_IMAGE},
        };
        proto_writer pw;
        proto_writer_init(&pw, PROTO_MAX_PAYLOAD);
        proto_writer_reset(&w);
        proto_w_u8(&w, 0x0C);
        for (size_t i = 0; i < sizeof session / sizeof session[0]; i++) {
            proto_writer_reset(&pw);
            if (!sample_payload(session[i][0], 1, &pw) ||
                proto_frame_encode(&w, session[i][1], pw.buf, pw.len, NULL) != PT_OK)
                failures++;
        }
        proto_frame_encode(&w, PROTO_MSG_LIST, NULL, 0, NULL);
        proto_writer_fini(&pw);
        emit(dir, "fuzz_frame", "client_session", w.buf, w.len);
    }
    /* A header declaring a payload over the pre-auth cap. */
    uint8_t h[13] = {1, 'P', 'T', 'F', '1'};
    proto_put_u16(h + 5, PROTO_VERSION);
    proto_put_u16(h + 7, PROTO_MSG_HELLO);
    proto_put_u32(h + 9, PROTO_MAX_PAYLOAD_PREAUTH + 1);
    emit(dir, "fuzz_frame", "over_cap_preauth", h, sizeof h);
    /* A bad CRC. */
    proto_writer_reset(&w);
    proto_w_u8(&w, 0);
    sample_frame(5, 0, &w);
    w.buf[w.len - 1] ^= 0x80;
    emit(dir, "fuzz_frame", "bad_crc", w.buf, w.len);

    proto_writer_fini(&w);
    if (failures)
        fprintf(stderr, "%d corpus problems\n", failures);
    else
        printf("corpus %s: ok\n", write_mode ? "written" : "current");
    return failures ? 1 : 0;
}
