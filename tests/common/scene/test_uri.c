/* Tests for common/scene/uri.c: the percent-decoding that the bundle packer
 * and the glTF importer share, fed the strings where decoders differ, and the
 * rule that keeps a decoded name inside the scene's folder. */
#include "common/scene/uri.h"

#include <string.h>

#include "tests/check.h"

/* Decodes text (NUL-terminated) and compares with want[0, want_len). */
static void decodes_to(const char *text, const char *want, size_t want_len)
{
    char out[64];
    memset(out, '#', sizeof out);
    size_t n = strlen(text);
    size_t k = pt_uri_decode(text, n, out);
    CHECKF(k == want_len && memcmp(out, want, k) == 0, "'%s': %zu bytes '%.*s'", text, k, (int)k,
           out);
    CHECKF(k == sizeof out || out[k] == '#', "'%s': wrote past its result", text);
}

int main(void)
{
    decodes_to("", "", 0);
    decodes_to("plain.bin", "plain.bin", 9);
    decodes_to("a%20b.png", "a b.png", 7);
    decodes_to("dir%2Ffile.bin", "dir/file.bin", 12); /* an encoded '/' is a '/' */
    decodes_to("dir%2ffile.bin", "dir/file.bin", 12); /* either case */
    decodes_to("%zz.bin", "%zz.bin", 7);              /* not hex: kept */
    decodes_to("%4z.bin", "%4z.bin", 7);
    decodes_to("%z4", "%z4", 3);
    decodes_to("a%", "a%", 2);   /* trailing '%' */
    decodes_to("a%4", "a%4", 3); /* one digit before the end */
    decodes_to("%41", "A", 1);   /* two digits exactly at the end */
    decodes_to("x%00y", "x\0y", 3);
    decodes_to("a+b.bin", "a+b.bin", 7); /* '+' is not a space in a path */
    decodes_to("%2541", "%41", 3);       /* decoded once, not twice */
    decodes_to("%%41", "%A", 2);
    decodes_to("%C3%A9.png", "\xC3\xA9.png", 6);
    decodes_to("%FF", "\xFF", 1);
    /* Only n bytes are read: a "%41" cut after its '%' stays a '%'. */
    char out[8];
    CHECK(pt_uri_decode("a%41", 2, out) == 2 && memcmp(out, "a%", 2) == 0);

    /* The rule both readers apply to a decoded name. */
    const char *ok[] = {"a.bin", "sub/tex.png", "./a.png", "a//b", "a/./b", "..a", "a..", "a/..b"};
    for (size_t i = 0; i < sizeof ok / sizeof *ok; i++)
        CHECKF(pt_uri_path_refusal(ok[i], strlen(ok[i])) == NULL, "'%s' refused", ok[i]);
    const char *bad[] = {"",       "..",       "../x",  "a/../../x", "a/..", "/etc/passwd",
                         "/a.bin", "a\\..\\x", "..\\x", "./../x"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++)
        CHECKF(pt_uri_path_refusal(bad[i], strlen(bad[i])) != NULL, "'%s' accepted", bad[i]);
    CHECK(pt_uri_path_refusal("a\0/etc", 6) != NULL); /* from "a%00/etc" */
    char dec[16];
    size_t k = pt_uri_decode("%2e%2e/x", 8, dec); /* decoded first, then judged */
    CHECK(pt_uri_path_refusal(dec, k) != NULL);

    /* The name a bundle stores: "." and empty components gone. */
    const char *clean[][2] = {
        {"./a.png", "a.png"}, {"a//b", "a/b"},    {"a/./b", "a/b"}, {".//./sub/x", "sub/x"},
        {"sub/", "sub"},      {"a.bin", "a.bin"}, {"./.", ""},      {"..a/./.b", "..a/.b"}};
    for (size_t i = 0; i < sizeof clean / sizeof *clean; i++) {
        char name[32];
        size_t n = strlen(clean[i][0]);
        memcpy(name, clean[i][0], n);
        size_t m = pt_uri_path_clean(name, n);
        CHECKF(m == strlen(clean[i][1]) && memcmp(name, clean[i][1], m) == 0, "'%s': '%.*s'",
               clean[i][0], (int)m, name);
    }
    return check_report();
}
