/* Tests for common/base/alloc.c: pt_grow_array's doubling, its keeping the
 * elements, and its refusals (out of memory, a count past 32 bits) that
 * leave the array and its capacity as they were. */
#include "common/base/alloc.h"

#include <stdint.h>

#include "tests/check.h"

static void test_grow(void)
{
    uint32_t cap = 0, n = 0;
    int *a = NULL;
    for (int i = 0; i < 1000; i++) {
        if (n == cap) {
            int *g = pt_grow_array(a, &cap, sizeof *g, 16);
            CHECK(g != NULL);
            if (!g)
                break;
            a = g;
        }
        a[n++] = i;
    }
    /* 16, 32, ... 1024: doubled from the first size. */
    CHECKF(cap == 1024, "capacity %u", cap);
    int same = 1;
    for (uint32_t i = 0; i < n; i++)
        same &= a[i] == (int)i;
    CHECK(same);

    /* Out of memory: NULL, the array and its capacity unchanged. */
    pt_alloc_fail_at(1);
    uint32_t before = cap;
    CHECK(pt_grow_array(a, &cap, sizeof *a, 16) == NULL);
    pt_alloc_fail_at(0);
    CHECK(cap == before && a[999] == 999);

    /* A count that would pass 32 bits is refused before any allocation. */
    uint32_t huge = 0x80000000u;
    CHECK(pt_grow_array(a, &huge, sizeof *a, 16) == NULL && huge == 0x80000000u);
    pt_free(a);
    CHECK(pt_alloc_live() == 0);
}

int main(void)
{
    test_grow();
    return check_report();
}
