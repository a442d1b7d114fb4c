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

void *pt_malloc(size_t size);
void *pt_calloc(size_t n, size_t size);
void *pt_realloc(void *p, size_t size);
void *pt_malloc_array(size_t n, size_t size); /* NULL on overflow */
void pt_free(void *p);
char *pt_strdup(const char *s);

/* Test hooks. pt_alloc_fail_at(n): allocation number n (1-based, counted
 * from this call) and every later one fail; 0 turns injection off. */
void pt_alloc_fail_at(uint64_t n);
/* Number of allocations made since the last pt_alloc_fail_at call. */
uint64_t pt_alloc_count(void);
/* Blocks allocated and not yet freed (pt_free(NULL) does not count). */
int64_t pt_alloc_live(void);

#endif
