/*
 * null_render.c - the renderer of ptworker-null, the benchmark build of the
 * worker (tests/bench/CMakeLists.txt): the worker's own sources compiled
 * with pt_render_tile and pt_render_tile_passes defined to the fills
 * below, so everything but the rendering is the shipped worker's code
 * (protocol, authentication, scene fetch and cache, render threads, RESULT
 * frames of the real size).
 * Never installed: its images are not renders.
 *
 * The fill is one that the coordinator accepts as it would a render: every
 * pixel gets the task's sample count, every camera ray a hit, and zero sums
 * (black, whatever the sums' type), so a tile's merge does the same
 * arithmetic on as many bytes as a real one.
 *
 * Pacing: with PTWORKER_NULL_RATE set to R > 0 (samples per second), the
 * calling thread sleeps as long as a render thread of that speed would take
 * over the task's pixel-samples; it burns no processor time meanwhile, so a
 * shared machine can emulate many cores, and a coordinator that sizes tasks
 * from the rates it observes sees a real core's rate. Unset or 0: no sleep.
 *
 * Threads: any (it reads the environment once, under a pthread_once).
 */
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "common/render/render.h"

void ptbench_null_render_tile(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                              pt_pixel_acc *out, pt_render_stats *stats);
void ptbench_null_render_tile_passes(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                                     pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,
                                     const pt_render_guiding *gd);

static pthread_once_t rate_once = PTHREAD_ONCE_INIT;
static double rate; /* samples per second per thread; 0: as fast as it can */

static void read_rate(void)
{
    const char *v = getenv("PTWORKER_NULL_RATE");
    char *end;
    double x = v ? strtod(v, &end) : 0.0;
    rate = v && end != v && x > 0.0 && x < 1e15 ? x : 0.0;
}

void ptbench_null_render_tile(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                              pt_pixel_acc *out, pt_render_stats *stats)
{
    (void)r;
    uint32_t n = s1 - s0;
    size_t npx = (size_t)(tile.x1 - tile.x0) * (size_t)(tile.y1 - tile.y0);
    memset(out, 0, npx * sizeof *out);
    for (size_t i = 0; i < npx; i++) {
        out[i].n = n;
        out[i].hits = n;
    }
    uint64_t samples = (uint64_t)npx * n;
    if (stats) {
        stats->samples += samples;
        stats->rays += 2 * samples;
    }
    pthread_once(&rate_once, read_rate);
    if (rate > 0.0) {
        double sec = (double)samples / rate;
        struct timespec ts = {(time_t)sec, (long)((sec - (double)(time_t)sec) * 1e9)};
        while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
        }
    }
}

/* The farm worker renders through pt_render_tile_passes: the same fill, with
 * any pass sums zeroed as a renderer without passes writes them. */
void ptbench_null_render_tile_passes(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                                     pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,
                                     const pt_render_guiding *gd)
{
    (void)gd;
    if (pout)
        memset(pout, 0, (size_t)(tile.x1 - tile.x0) * (size_t)(tile.y1 - tile.y0) * sizeof *pout);
    ptbench_null_render_tile(r, tile, s0, s1, out, stats);
}
