/* Tests for common/base/alloc.c: pt_grow_array's doubling, its keeping the
 * elements, and its refusals (out of memory, a count past 32 bits) that
 * leave the array and its capacity as they were; a large block asks for
 * transparent huge pages (its mapping's VmFlags in /proc/self/smaps hold
 * "hg", MADV_HUGEPAGE) and a small one does not. */
#include "common/base/alloc.h"

#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

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

/* 1 when the mapping that holds address a has MADV_HUGEPAGE (VmFlags "hg"),
 * 0 when not, -1 when /proc/self/smaps does not say. */
static int advised_huge(const void *a)
{
    FILE *f = fopen("/proc/self/smaps", "r");
    if (!f)
        return -1;
    char line[512];
    int in = 0, found = -1;
    uintptr_t x = (uintptr_t)a;
    while (fgets(line, sizeof line, f)) {
        unsigned long lo, hi;
        if (sscanf(line, "%lx-%lx ", &lo, &hi) == 2) {
            in = x >= lo && x < hi;
        } else if (in && strncmp(line, "VmFlags:", 8) == 0) {
            found = strstr(line, " hg") != NULL;
            break;
        }
    }
    fclose(f);
    return found;
}

static void test_huge_pages(void)
{
    if (access("/sys/kernel/mm/transparent_hugepage/enabled", R_OK) != 0) {
        CHECK_SKIP("huge pages: this kernel has no transparent huge pages");
        return;
    }
    size_t big = 4 * PT_ALLOC_HUGE_MIN;
    unsigned char *p = pt_malloc(big), *q = pt_calloc(big / 8, 8), *s = pt_malloc(4096);
    CHECK(p && q && s);
    if (p && q && s) {
        /* The middle of a large block is inside its 2 MiB-aligned part. */
        CHECKF(advised_huge(p + big / 2) == 1, "pt_malloc'd block of %zu bytes not advised", big);
        CHECKF(advised_huge(q + big / 2) == 1, "pt_calloc'd block of %zu bytes not advised", big);
        CHECKF(advised_huge(s) == 0, "a small block advised");
        unsigned char *r = pt_realloc(s, big);
        CHECK(r != NULL);
        if (r) {
            s = r;
            CHECKF(advised_huge(r + big / 2) == 1, "pt_realloc'd block not advised");
        }
    }
    pt_free(p);
    pt_free(q);
    pt_free(s);
}

int main(void)
{
    test_grow();
    test_huge_pages();
    return check_report();
}
