/* madvise and MADV_HUGEPAGE (Linux) are outside POSIX. */
#define _DEFAULT_SOURCE
#include "common/base/alloc.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

static atomic_uint_fast64_t alloc_count;
static atomic_uint_fast64_t fail_at;
static atomic_int_fast64_t live;

static int should_fail(void)
{
    uint64_t n = atomic_fetch_add(&alloc_count, 1) + 1;
    uint64_t f = atomic_load(&fail_at);
    return f != 0 && n >= f;
}

/* A block of at least PT_ALLOC_HUGE_MIN bytes asks the kernel for
 * transparent huge pages over the 2 MiB-aligned part of it (Linux's
 * MADV_HUGEPAGE; THP's default mode there is "madvise", where nothing else
 * gets them). The large blocks are a scene's textures, vertex arrays and
 * environment map, read at random while rendering: one TLB entry then maps
 * 2 MiB instead of 4 KiB, and filling one takes one page fault instead of
 * 512. Where the kernel has no THP the call fails and nothing changes. */
static void advise_huge(void *p, size_t size)
{
#ifdef MADV_HUGEPAGE
    if (size < PT_ALLOC_HUGE_MIN)
        return;
    const uintptr_t huge = (uintptr_t)2 << 20;
    uintptr_t lo = ((uintptr_t)p + huge - 1) & ~(huge - 1);
    uintptr_t hi = ((uintptr_t)p + size) & ~(huge - 1);
    if (hi > lo)
        (void)madvise((void *)lo, hi - lo, MADV_HUGEPAGE);
#else
    (void)p;
    (void)size;
#endif
}

void *pt_malloc(size_t size)
{
    if (should_fail())
        return NULL;
    void *p = malloc(size ? size : 1);
    if (p) {
        atomic_fetch_add(&live, 1);
        advise_huge(p, size);
    }
    return p;
}

void *pt_calloc(size_t n, size_t size)
{
    if (should_fail())
        return NULL;
    void *p = calloc(n ? n : 1, size ? size : 1);
    if (p) {
        atomic_fetch_add(&live, 1);
        advise_huge(p, n * size); /* calloc checked n * size */
    }
    return p;
}

void *pt_malloc_array(size_t n, size_t size)
{
    size_t total;
    if (__builtin_mul_overflow(n, size, &total))
        return NULL;
    return pt_malloc(total);
}

void *pt_realloc(void *p, size_t size)
{
    if (!p)
        return pt_malloc(size);
    if (should_fail())
        return NULL;
    void *q = realloc(p, size ? size : 1);
    if (q)
        advise_huge(q, size);
    return q;
}

void pt_free(void *p)
{
    if (p) {
        atomic_fetch_sub(&live, 1);
        free(p);
    }
}

void *pt_grow_array(void *arr, uint32_t *cap, size_t size, uint32_t first)
{
    uint64_t want = *cap ? 2 * (uint64_t)*cap : first;
    if (want > UINT32_MAX || size == 0 || want > SIZE_MAX / size)
        return NULL;
    void *n = pt_realloc(arr, (size_t)want * size);
    if (n)
        *cap = (uint32_t)want;
    return n;
}

char *pt_strdup(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = pt_malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

void pt_alloc_fail_at(uint64_t n)
{
    atomic_store(&alloc_count, 0);
    atomic_store(&fail_at, n);
}

uint64_t pt_alloc_count(void)
{
    return atomic_load(&alloc_count);
}

int64_t pt_alloc_live(void)
{
    return atomic_load(&live);
}
