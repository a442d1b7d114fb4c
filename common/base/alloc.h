/*
 * alloc.h - the one allocation hook of the project.
 *
 * Every allocation of project code goes through pt_malloc / pt_calloc /
 * pt_realloc / pt_free, so a test can make the Nth allocation fail
 * (pt_alloc_fail_at) and prove that loaders and decoders survive it without
 * leaking (pt_alloc_live counts the blocks not yet freed).
 * Sizes are overflow-checked: pt_malloc_array(n, size) fails on n*size overflow.
 * Thread-safety: the counters are atomic; fail injection is meant for
 * single-threaded tests.
 */
#ifndef PT_COMMON_BASE_ALLOC_H
#define PT_COMMON_BASE_ALLOC_H

#include <stddef.h>
#include <stdint.h>

/* Blocks of this many bytes or more are backed by transparent huge pages
 * where the kernel has them (alloc.c). */
#define PT_ALLOC_HUGE_MIN ((size_t)4 << 20)

void *pt_malloc(size_t size);
void *pt_calloc(size_t n, size_t size);
void *pt_realloc(void *p, size_t size);
void *pt_malloc_array(size_t n, size_t size); /* NULL on overflow */
void pt_free(void *p);
char *pt_strdup(const char *s);
/* The block arr (*cap elements of size bytes, full) reallocated to twice as
 * many (first when *cap is 0), *cap updated; NULL (arr and *cap untouched)
 * when memory or the element count runs out. For arrays grown one element
 * at a time: if (n == cap) { p = pt_grow_array(a, &cap, sizeof *a, 16); ... } */
void *pt_grow_array(void *arr, uint32_t *cap, size_t size, uint32_t first);

/* Test hooks. pt_alloc_fail_at(n): allocation number n (1-based, counted
 * from this call) and every later one fail; 0 turns injection off. */
void pt_alloc_fail_at(uint64_t n);
/* Number of allocations made since the last pt_alloc_fail_at call. */
uint64_t pt_alloc_count(void);
/* Blocks allocated and not yet freed (pt_free(NULL) does not count). */
int64_t pt_alloc_live(void);

#endif
