/* pt_json_too_deep: the bound at its edge, brackets in strings and escapes,
 * unbalanced text, and a long text in one pass. */
#include "common/base/json.h"

#include <string.h>

#include "common/base/alloc.h"
#include "tests/check.h"

/* depth opening brackets (alternating [ and {"k":), then their closings. */
static char *nest(unsigned depth, size_t *n)
{
    char *s = pt_malloc((size_t)depth * 6 + 1);
    size_t k = 0;
    for (unsigned i = 0; i < depth; i++) {
        if (i % 2) {
            memcpy(s + k, "{\"k\":", 5);
            k += 5;
        } else {
            s[k++] = '[';
        }
    }
    for (unsigned i = depth; i-- > 0;)
        s[k++] = i % 2 ? '}' : ']';
    s[k] = '\0';
    *n = k;
    return s;
}

static void test_edge(void)
{
    size_t n, at = 12345;
    char *s = nest(PT_JSON_MAX_DEPTH, &n);
    CHECK(pt_json_too_deep(s, n, PT_JSON_MAX_DEPTH, &at) == 0 && at == 12345);
    CHECK(pt_json_too_deep(s, n, PT_JSON_MAX_DEPTH - 1, &at) == 1);
    /* The bracket that went over: the last opening one. */
    CHECK(s[at] == ((PT_JSON_MAX_DEPTH - 1) % 2 ? '{' : '['));
    pt_free(s);
    s = nest(PT_JSON_MAX_DEPTH + 1, &n);
    CHECK(pt_json_too_deep(s, n, PT_JSON_MAX_DEPTH, NULL) == 1);
    pt_free(s);
    /* Siblings do not add up: many shallow arrays are fine. */
    const char *flat = "[[1],[2],[3],{\"a\":[4]},[[5]]]";
    CHECK(pt_json_too_deep(flat, strlen(flat), 3, NULL) == 0);
    CHECK(pt_json_too_deep(flat, strlen(flat), 2, &at) == 1 && at == 18);
    CHECK(pt_json_too_deep("", 0, 0, NULL) == 0);
    CHECK(pt_json_too_deep("1", 1, 0, NULL) == 0);
    CHECK(pt_json_too_deep("[]", 2, 0, NULL) == 1);
}

static void test_strings(void)
{
    /* Brackets in strings are not markup, escaped quotes do not end them,
     * an escaped backslash does not escape the quote after it. */
    const char *a = "{\"s\":\"[[[[{{{{\"}";
    CHECK(pt_json_too_deep(a, strlen(a), 1, NULL) == 0);
    const char *b = "{\"s\":\"\\\"[[[[\"}";
    CHECK(pt_json_too_deep(b, strlen(b), 1, NULL) == 0);
    const char *c = "{\"s\":\"\\\\\",\"t\":[[]]}";
    CHECK(pt_json_too_deep(c, strlen(c), 2, NULL) == 1);
    CHECK(pt_json_too_deep(c, strlen(c), 3, NULL) == 0);
    /* Unbalanced closings neither underflow nor hide a later depth. */
    const char *d = "]]]]}}[[[";
    CHECK(pt_json_too_deep(d, strlen(d), 3, NULL) == 0);
    CHECK(pt_json_too_deep(d, strlen(d), 2, NULL) == 1);
    /* An escape at the very end reads no byte past the text. */
    const char *e = "[\"\\";
    CHECK(pt_json_too_deep(e, strlen(e), 1, NULL) == 0);
    /* NUL bytes are ordinary bytes. */
    const char f[] = {'[', '\0', '[', ']', ']'};
    CHECK(pt_json_too_deep(f, sizeof f, 1, NULL) == 1);
}

/* The hostile file of the size: 30,000 deep in 60 KB, refused at
 * the first bracket past the bound. */
static void test_deep(void)
{
    size_t n, at = 0;
    char *s = nest(30000, &n);
    CHECK(pt_json_too_deep(s, n, PT_JSON_MAX_DEPTH, &at) == 1 && at < 6 * PT_JSON_MAX_DEPTH);
    pt_free(s);
}

int main(void)
{
    test_edge();
    test_strings();
    test_deep();
    return check_report();
}
