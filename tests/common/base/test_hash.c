/* Tests for common/base/hash.c: SHA-256 text and hex in both directions. */
#include "common/base/hash.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "tests/check.h"

/* pt_sha256_fd reads a file in pieces: across piece boundaries, empty, and
 * from a descriptor whose offset is elsewhere, it gives pt_sha256's bytes. */
static void test_sha256_fd(void)
{
    const size_t sizes[] = {0, 1, (1u << 20) - 1, 1u << 20, 3u * (1u << 20) + 17};
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        size_t n = sizes[k];
        uint8_t *data = malloc(n ? n : 1), want[32], got[32];
        for (size_t i = 0; i < n; i++)
            data[i] = (uint8_t)(i * 131u + (i >> 9));
        FILE *f = tmpfile();
        CHECK(f && fwrite(data, 1, n, f) == n && fflush(f) == 0);
        int fd = f ? fileno(f) : -1;
        lseek(fd, (off_t)(n / 2), SEEK_SET);
        pt_error err = {0};
        pt_sha256(data, n, want);
        CHECKF(pt_sha256_fd(fd, got, &err) == PT_OK && memcmp(got, want, 32) == 0, "%zu bytes: %s",
               n, err.msg);
        CHECK(lseek(fd, 0, SEEK_CUR) == (off_t)(n / 2));
        if (f)
            fclose(f);
        free(data);
    }
    uint8_t out[32] = {7};
    pt_error err = {0};
    CHECK(pt_sha256_fd(-1, out, &err) == PT_ERR_IO && out[0] == 7);
}

static void test_sha256(void)
{
    char out[PT_HASH_HEX];
    /* FIPS 180-2, appendix B.1: SHA-256("abc"). */
    pt_sha256_hex((const uint8_t *)"abc", 3, out);
    CHECK(!strcmp(out, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"));
    uint8_t raw[PT_HASH_SIZE], back[PT_HASH_SIZE];
    pt_sha256((const uint8_t *)"abc", 3, raw);
    CHECK(pt_hex_decode(out, back, sizeof back) == 0 && !memcmp(raw, back, sizeof raw));
    pt_sha256_hex(NULL, 0, out);
    CHECK(!strcmp(out, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"));
}

static void test_hex_round_trip(void)
{
    uint8_t h[PT_HASH_SIZE], back[PT_HASH_SIZE];
    for (unsigned i = 0; i < PT_HASH_SIZE; i++)
        h[i] = (uint8_t)(i * 37 + 5);
    char text[PT_HASH_HEX];
    pt_hash_hex(h, text);
    CHECK(strlen(text) == 64);
    CHECK(pt_hex_decode(text, back, sizeof back) == 0 && !memcmp(h, back, sizeof h));
}

static void test_hex_decode_rejects(void)
{
    uint8_t b[2] = {0xaa, 0xbb};
    CHECK(pt_hex_decode("00fF", b, 2) == 0 && b[0] == 0x00 && b[1] == 0xff);
    b[0] = 0xaa;
    CHECK(pt_hex_decode("00f", b, 2) == -1 && b[0] == 0xaa);   /* short */
    CHECK(pt_hex_decode("00ff0", b, 2) == -1 && b[0] == 0xaa); /* long */
    CHECK(pt_hex_decode("0g11", b, 2) == -1 && b[0] == 0xaa);  /* not hex, untouched */
    CHECK(pt_hex_decode("", b, 0) == 0);
}

static void test_hex_digit(void)
{
    const char *digits = "0123456789abcdef", *upper = "ABCDEF";
    for (int i = 0; i < 16; i++)
        CHECK(pt_hex_digit(digits[i]) == i);
    for (int i = 0; i < 6; i++)
        CHECK(pt_hex_digit(upper[i]) == 10 + i);
    int others = 0;
    for (int c = -128; c < 128; c++)
        others += pt_hex_digit((char)c) < 0;
    CHECK(others == 256 - 22);
    CHECK(pt_hex_digit('g') == -1 && pt_hex_digit('/') == -1 && pt_hex_digit(':') == -1 &&
          pt_hex_digit('@') == -1 && pt_hex_digit('G') == -1 && pt_hex_digit('`') == -1 &&
          pt_hex_digit('\0') == -1);
}

int main(void)
{
    test_hex_digit();
    test_sha256();
    test_sha256_fd();
    test_hex_round_trip();
    test_hex_decode_rejects();
    return check_report();
}
