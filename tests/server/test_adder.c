/*
 * test_adder.c - film adds on merge threads (server/sched/adder.h): the same film
 * as adding at once, whatever the threads and however full the queue; a
 * settle waits for every add of its group; freeing the adder makes the adds
 * still queued; the thread count is checked.
 */
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "server/sched/adder.h"
#include "tests/check.h"

#define W 96u
#define H 80u
#define T 16u /* tile side: 6 x 5 tiles */

/* Deterministic sums for add k of tile (tx, ty). */
static void fill(pt_pixel_acc *px, uint32_t k)
{
    uint64_t h = k * 0x9E3779B97F4A7C15ull + 7;
    for (uint32_t i = 0; i < T * T; i++) {
        h ^= h >> 31;
        h *= 0xBF58476D1CE4E5B9ull;
        double v = (double)(h >> 11) * 0x1.0p-53;
        px[i] = pt_pixel_acc_of(v * 16, v * 8, v, v * v * 16, 16, (uint32_t)(h % 17));
    }
}

static pt_rect tile_of(uint32_t k)
{
    uint32_t t = k % ((W / T) * (H / T));
    pt_rect r = {(t % (W / T)) * T, (t / (W / T)) * T, 0, 0};
    r.x1 = r.x0 + T;
    r.y1 = r.y0 + T;
    return r;
}

static pt_film *reference(uint32_t adds)
{
    pt_film *f = NULL;
    CHECK(pt_film_new(W, H, &f, NULL) == PT_OK);
    pt_pixel_acc px[T * T];
    for (uint32_t k = 0; f && k < adds; k++) {
        fill(px, k);
        pt_film_add_tile(f, tile_of(k), px);
    }
    return f;
}

/* Posts adds [0, adds) to film through a, in group g. */
static void post_all(srv_adder *a, srv_adds *g, pt_film *film, uint32_t adds)
{
    for (uint32_t k = 0; k < adds; k++) {
        pt_pixel_acc *px = pt_malloc_array(T * T, sizeof *px);
        CHECK(px != NULL);
        if (!px)
            return;
        fill(px, k);
        srv_adder_post(a, g, film, tile_of(k), px);
    }
}

static int same(const pt_film *a, const pt_film *b)
{
    return a && b && memcmp(a->px, b->px, (size_t)W * H * sizeof *a->px) == 0;
}

static void same_film(void)
{
    enum { ADDS = 3000 };
    pt_film *ref = reference(ADDS);
    for (uint32_t threads = 1; threads <= 3; threads++) {
        srv_adder *a = NULL;
        pt_film *f = NULL;
        CHECK(srv_adder_new(threads, &a, NULL) == PT_OK);
        CHECK(pt_film_new(W, H, &f, NULL) == PT_OK);
        if (!a || !f)
            return;
        srv_adds g = {0};
        post_all(a, &g, f, ADDS);
        srv_adder_settle(a, &g);
        CHECK(g.pending == 0);
        CHECKF(same(f, ref), "%u merge threads changed the film", threads);
        uint64_t threaded, inl;
        srv_adder_counts(a, &threaded, &inl);
        CHECKF(threaded + inl == ADDS && threaded > 0, "%u threads: %llu + %llu adds of %d",
               threads, (unsigned long long)threaded, (unsigned long long)inl, ADDS);
        srv_adder_settle(a, &g); /* nothing in flight: returns at once */
        srv_adder_free(a);
        pt_film_free(f);
    }
    pt_film_free(ref);
}

/* Two films, two groups: settling one leaves the film complete; freeing the
 * adder with adds still queued makes them. */
static void groups_and_free(void)
{
    enum { ADDS = 800 };
    pt_film *ref = reference(ADDS);
    srv_adder *a = NULL;
    pt_film *f1 = NULL, *f2 = NULL;
    CHECK(srv_adder_new(2, &a, NULL) == PT_OK);
    CHECK(pt_film_new(W, H, &f1, NULL) == PT_OK && pt_film_new(W, H, &f2, NULL) == PT_OK);
    if (!a || !f1 || !f2)
        return;
    srv_adds g1 = {0}, g2 = {0};
    post_all(a, &g1, f1, ADDS);
    post_all(a, &g2, f2, ADDS);
    srv_adder_settle(a, &g1);
    CHECK(same(f1, ref));
    srv_adder_free(a); /* g2's adds may still be queued */
    CHECK(g2.pending == 0);
    CHECKF(same(f2, ref), "freeing the adder dropped queued adds");
    pt_film_free(f1);
    pt_film_free(f2);
    pt_film_free(ref);
}

static void bad_threads(void)
{
    srv_adder *a = NULL;
    pt_error err = {0};
    CHECK(srv_adder_new(0, &a, &err) == PT_ERR_ARG && a == NULL && strstr(err.msg, "merge"));
    CHECK(srv_adder_new(SRV_ADDER_MAX_THREADS + 1, &a, &err) == PT_ERR_ARG && a == NULL);
    srv_adder_free(NULL);
}

int main(void)
{
    int64_t live = pt_alloc_live();
    same_film();
    groups_and_free();
    bad_threads();
    CHECK(pt_alloc_live() == live);
    return check_report();
}
