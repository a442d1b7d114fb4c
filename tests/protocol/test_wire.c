/*
 * test_wire.c - byte order, float bit patterns, the capped writer and the
 * checked reader of protocol/wire.h.
 */
#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "protocol/wire.h"
#include "tests/check.h"

static void test_codecs(void)
{
    uint8_t b[8];
    proto_put_u16(b, 0x0102);
    CHECK(b[0] == 0x02 && b[1] == 0x01);
    CHECK(proto_get_u16(b) == 0x0102);
    proto_put_u32(b, 0x01020304u);
    CHECK(b[0] == 4 && b[1] == 3 && b[2] == 2 && b[3] == 1);
    CHECK(proto_get_u32(b) == 0x01020304u);
    proto_put_u64(b, 0x0102030405060708ull);
    for (int i = 0; i < 8; i++)
        CHECK(b[i] == 8 - i);
    CHECK(proto_get_u64(b) == 0x0102030405060708ull);
    proto_put_u64(b, UINT64_MAX);
    CHECK(proto_get_u64(b) == UINT64_MAX);
    proto_put_u32(b, 0xFFFFFFFFu);
    CHECK(proto_get_u32(b) == 0xFFFFFFFFu);
    proto_put_u8(b, 0xAB);
    CHECK(proto_get_u8(b) == 0xAB);

    /* IEEE 754 bit patterns, little-endian. */
    proto_put_f64(b, 1.0);
    CHECK(proto_get_u64(b) == 0x3FF0000000000000ull);
    CHECK(b[7] == 0x3F && b[6] == 0xF0 && b[0] == 0);
    proto_put_f32(b, -2.0f);
    CHECK(proto_get_u32(b) == 0xC0000000u);
    CHECK(proto_get_f32(b) == -2.0f);
    proto_put_f64(b, -0.0);
    CHECK(proto_get_u64(b) == 0x8000000000000000ull);
    CHECK(signbit(proto_get_f64(b)));
    /* A NaN's payload survives the trip. */
    uint64_t nan_bits = 0x7FF8000000000123ull;
    proto_put_f64(b, proto_bits_f64(nan_bits));
    CHECK(proto_get_u64(b) == nan_bits);
    CHECK(isnan(proto_get_f64(b)));
    proto_put_f64(b, INFINITY);
    CHECK(proto_get_f64(b) == INFINITY);
    proto_put_f64(b, 4.9406564584124654e-324); /* the smallest subnormal */
    CHECK(proto_get_u64(b) == 1);
}

static void test_writer(void)
{
    proto_writer w;
    proto_writer_init(&w, 15);
    CHECK(w.buf == NULL && w.len == 0);
    proto_w_u8(&w, 1);
    proto_w_u16(&w, 0x0203);
    proto_w_u32(&w, 0x04050607u);
    proto_w_u64(&w, 0x08090A0B0C0D0E0Full);
    CHECK(proto_writer_status(&w) == PT_OK);
    CHECK(w.len == 15);
    static const uint8_t want[15] = {1, 3, 2, 7, 6, 5, 4, 0xF, 0xE, 0xD, 0xC, 0xB, 0xA, 9, 8};
    CHECK(memcmp(w.buf, want, 15) == 0);
    CHECK(w.cap <= w.max);
    /* One byte past the max: PT_ERR_LIMIT, sticky, content kept. */
    proto_w_u8(&w, 9);
    CHECK(proto_writer_status(&w) == PT_ERR_LIMIT);
    CHECK(w.len == 15);
    proto_w_bytes(&w, "", 0);
    CHECK(proto_writer_status(&w) == PT_ERR_LIMIT);
    CHECK(proto_w_reserve(&w, 0) == NULL);
    proto_writer_reset(&w);
    CHECK(proto_writer_status(&w) == PT_OK && w.len == 0);
    proto_w_f32(&w, 1.0f);
    proto_w_f64(&w, 1.0);
    CHECK(w.len == 12 && proto_get_u32(w.buf) == 0x3F800000u);
    CHECK(proto_get_u64(w.buf + 4) == 0x3FF0000000000000ull);
    proto_writer_fini(&w);
    proto_writer_fini(NULL);

    /* A multi-byte write that would straddle the max writes nothing. */
    proto_writer_init(&w, 3);
    proto_w_u16(&w, 1);
    proto_w_u16(&w, 2);
    CHECK(proto_writer_status(&w) == PT_ERR_LIMIT && w.len == 2);
    proto_writer_fini(&w);

    /* Growth across many reallocations keeps every byte. */
    proto_writer_init(&w, 1u << 20);
    for (uint32_t i = 0; i < 100000; i++)
        proto_w_u32(&w, i * 2654435761u);
    CHECK(proto_writer_status(&w) == PT_OK && w.len == 400000);
    int same = 1;
    for (uint32_t i = 0; i < 100000; i++)
        same &= proto_get_u32(w.buf + 4 * (size_t)i) == i * 2654435761u;
    CHECK(same);
    /* Exactly the max fits. */
    proto_w_reserve(&w, (1u << 20) - w.len);
    CHECK(proto_writer_status(&w) == PT_OK && w.len == 1u << 20 && w.cap == 1u << 20);
    proto_writer_fini(&w);

    /* Allocation failure: PT_ERR_NOMEM, sticky, nothing leaked. */
    int64_t live = pt_alloc_live();
    for (uint64_t k = 1; k < 20; k++) {
        pt_alloc_fail_at(k);
        proto_writer_init(&w, 1u << 16);
        for (int i = 0; i < 4000; i++)
            proto_w_u64(&w, (uint64_t)i);
        pt_status st = proto_writer_status(&w);
        pt_alloc_fail_at(0);
        CHECK(st == PT_OK || st == PT_ERR_NOMEM);
        if (st == PT_OK)
            CHECK(w.len == 32000);
        proto_writer_fini(&w);
        CHECK(pt_alloc_live() == live);
    }
}

static void test_reader(void)
{
    static const uint8_t buf[] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11};
    proto_reader r = proto_reader_make(buf, sizeof buf);
    CHECK(proto_r_u8(&r, "a") == 1);
    CHECK(proto_r_u16(&r, "b") == 0x0302);
    CHECK(proto_r_u32(&r, "c") == 0x07060504u);
    CHECK(proto_r_left(&r) == 4);
    CHECK(proto_r_u64(&r, "d") == 0); /* 4 bytes left: truncated, reads nothing */
    CHECK(r.status == PT_ERR_PROTO && strcmp(r.field, "d") == 0);
    CHECK(r.p == r.end);
    /* Sticky: a later read that would fit still fails and keeps the first field. */
    CHECK(proto_r_u8(&r, "e") == 0);
    CHECK(strcmp(r.field, "d") == 0);
    pt_error err = {0};
    CHECK(proto_r_finish(&r, "MSG", &err) == PT_ERR_PROTO);
    CHECK(strcmp(err.msg, "MSG: truncated d") == 0);

    r = proto_reader_make(buf, sizeof buf);
    CHECK(proto_r_bytes(&r, 11, "all") == buf);
    CHECK(proto_r_bytes(&r, 0, "none") == buf + 11);
    CHECK(proto_r_finish(&r, "MSG", &err) == PT_OK);

    /* A huge n cannot wrap the pointer check. */
    r = proto_reader_make(buf, sizeof buf);
    CHECK(proto_r_bytes(&r, SIZE_MAX, "huge") == NULL);
    CHECK(r.status == PT_ERR_PROTO);

    r = proto_reader_make(buf, sizeof buf);
    proto_r_u64(&r, "x");
    CHECK(proto_r_finish(&r, "MSG", &err) == PT_ERR_PROTO);
    CHECK(strstr(err.msg, "3 trailing bytes") != NULL);

    r = proto_reader_make(buf, 8);
    CHECK(proto_r_f64(&r, "f") == proto_bits_f64(0x0807060504030201ull));
    r = proto_reader_make(buf, 3);
    CHECK(proto_r_f32(&r, "f") == 0.0f && r.status == PT_ERR_PROTO);

    /* Every length short of a u64, including the empty buffer. */
    for (size_t n = 0; n < 8; n++) {
        r = proto_reader_make(n ? buf : NULL, n);
        proto_r_u64(&r, "v");
        CHECK(r.status == PT_ERR_PROTO);
    }
}

int main(void)
{
    test_codecs();
    test_writer();
    test_reader();
    return check_report();
}
