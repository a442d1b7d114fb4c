/* Tests for common/base/text.c: control bytes escaped, truncation marked. */
#include "common/base/text.h"

#include <string.h>

#include "tests/check.h"

static int shown_is(const char *in, size_t len, size_t cap, const char *want)
{
    char out[256];
    memset(out, 'Z', sizeof out);
    char *r = pt_text_escape(in, len, out, cap);
    return r == out && !strcmp(out, want) && strlen(out) < cap;
}

static void test_escapes(void)
{
    CHECK(shown_is("plain name-1.exr", 16, 64, "plain name-1.exr"));
    CHECK(shown_is("a\nb", 3, 64, "a\\x0ab"));
    CHECK(shown_is("\x1b[31mred", 8, 64, "\\x1b[31mred"));
    CHECK(shown_is("a\0b", 3, 64, "a\\x00b"));
    CHECK(shown_is("back\\slash", 10, 64, "back\\\\slash"));
    CHECK(shown_is("\x7f\x01\x1f\x20~", 5, 64, "\\x7f\\x01\\x1f ~"));
    CHECK(shown_is("\xc3\xa9\x9b", 3, 64, "\\xc3\\xa9\\x9b"));
    CHECK(shown_is("\r\t", 2, 64, "\\x0d\\x09"));
    CHECK(shown_is(NULL, 0, 64, ""));
    char out[PT_TEXT_ESCAPED_SIZE(3)];
    CHECK(!strcmp(pt_text_escape("\n\n\n", 3, out, sizeof out), "\\x0a\\x0a\\x0a"));
    CHECK(!strcmp(pt_text_shown("x\ny", out, sizeof out), "x\\x0ay"));
    CHECK(!strcmp(pt_text_shown(NULL, out, sizeof out), ""));
}

static void test_truncation(void)
{
    /* "abcdef" needs 7 bytes: 7 fits exactly, 6 does not. */
    CHECK(shown_is("abcdef", 6, 7, "abcdef"));
    CHECK(shown_is("abcdef", 6, 6, "ab..."));
    CHECK(shown_is("abcdef", 6, 5, "a..."));
    CHECK(shown_is("abcdef", 6, 4, "..."));
    CHECK(shown_is("abcdef", 6, 3, ".."));
    CHECK(shown_is("abcdef", 6, 2, "."));
    CHECK(shown_is("abcdef", 6, 1, ""));
    /* An escape is never cut: "a\x0a" needs 6 bytes whole. */
    CHECK(shown_is("a\n", 2, 6, "a\\x0a"));
    CHECK(shown_is("a\nb", 3, 7, "a\\x0ab"));
    CHECK(shown_is("a\nb", 3, 6, "a..."));
    CHECK(shown_is("ab\n", 3, 6, "ab..."));
    CHECK(shown_is("\\\\", 2, 5, "\\\\\\\\"));
    CHECK(shown_is("\\\\", 2, 4, "..."));
    char out[4] = "abc";
    pt_text_escape("x", 1, out, 0);
    CHECK(!strcmp(out, "abc"));
}

int main(void)
{
    test_escapes();
    test_truncation();
    return check_report();
}
