/*
 * dnshare.h - a finished frame's denoising shared between its writer thread
 * and the farm's workers (ptserve --denoise-on-workers).
 *
 * The writer cuts the frame into regions (pt_denoise_regions' cut,
 * common/image/denoise.h) and opens a share; the loop leases regions to
 * workers that can denoise (HELLO's PROTO_CAP_DENOISE), serves each one's
 * crop (DENOISE_GET) and takes their pixels back (DENOISE_RESULT). The
 * writer meanwhile denoises regions itself: those nobody took, the workers'
 * results picked for verification, and those leased and out too long (a
 * race: the same bits either way). So a worker that dies or stalls costs
 * the frame a bounded wait, and no state needs to outlive the coordinator:
 * after a restart the frame is denoised again from its merged film.
 *
 * The writer races a leased region only once it has been out
 * STALL_FACTOR times as long as the writer's own last region took for a
 * crop that size, and at least the lease timeout: otherwise it waits for
 * the workers, so their regions are work it does not do.
 *
 * Verification: each worker connection's first region, and others with
 * probability --verify-fraction (splitmix64 of the job, the region and a
 * per-run seed), are denoised again by the writer; a region both computed
 * is compared as it arrives. Bits that differ: the writer's are kept, every
 * region that worker returned is redone, and the worker is named a liar
 * (srv_dnshare_take_liar), which the loop blocks as it blocks a worker
 * whose render differs.
 *
 * Threads: the writer's thread calls open, run and close; the loop's
 * thread the rest. A mutex guards the state; the frame's planes are read by
 * both (read-only) while the share is open.
 */
#ifndef PT_SERVER_SCHED_DNSHARE_H
#define PT_SERVER_SCHED_DNSHARE_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/image/denoise.h"
#include "protocol/msg.h"

/* The side of the regions a shared frame is cut into (--denoise-region). */
#define SRV_DNSHARE_SIDE 512u

typedef struct srv_dnshare srv_dnshare;

/* What one shared denoising did. */
typedef struct srv_dnshare_stats {
    uint32_t regions;    /* in the frame */
    uint32_t by_workers; /* taken from workers' results */
    uint32_t verified;   /* of those, also denoised here and found the same */
    uint32_t liars;      /* workers whose bits differed */
} srv_dnshare_stats;

pt_status srv_dnshare_new(uint64_t verify_seed, double verify_fraction, srv_dnshare **out,
                          pt_error *err);
void srv_dnshare_free(srv_dnshare *d);

/* Writer: shares the frame in (its planes alive until close) cut into
 * regions of side, whose pixels end in out; job_id names the frame on the
 * wire. Hashes each region's crop. PT_ERR_NOMEM. */
pt_status srv_dnshare_open(srv_dnshare *d, const pt_denoise_input *in, uint32_t side,
                           float *const out[3], uint64_t job_id, pt_error *err);
/* Writer: denoises regions on `threads` threads until every pixel of out
 * is the frame's (see above); in->progress rises with the regions done,
 * in->cancel stops it (PT_AGAIN). */
pt_status srv_dnshare_run(srv_dnshare *d, unsigned threads, srv_dnshare_stats *st, pt_error *err);
/* Writer: the share ends; the loop's calls see none. */
void srv_dnshare_close(srv_dnshare *d);

/* Loop: leases a free region to owner: 1 and *t filled (lease_ms as given),
 * else 0 (none open or free). */
int srv_dnshare_lease(srv_dnshare *d, uint64_t owner, uint32_t lease_ms, proto_denoise_task *t);
/* Loop: up to cap bytes of the crop named by hash from offset into buf;
 * 1 with *len and *total, 0 when no open region has that hash (*job_id
 * then the last share's job, 0 when none). */
int srv_dnshare_chunk(srv_dnshare *d, const uint8_t hash[32], uint64_t offset, uint8_t *buf,
                      size_t cap, size_t *len, uint64_t *total, uint64_t *job_id);
/* What srv_dnshare_result did with a result. */
enum { SRV_DNSHARE_INVALID = 0, SRV_DNSHARE_DROPPED = 1, SRV_DNSHARE_TAKEN = 2 };
/* Loop: a worker's DENOISE_RESULT; first: the worker's first region taken
 * on this connection, which the writer verifies. TAKEN; DROPPED (late, a
 * copy, not leased to owner); INVALID with *err when its region or pixels
 * are not the leased region's denoised image (the worker is then closed). */
int srv_dnshare_result(srv_dnshare *d, uint64_t owner, int first, const proto_denoise_result *r,
                       pt_error *err);
/* Loop: the owner's leases go (it left). */
void srv_dnshare_release(srv_dnshare *d, uint64_t owner);
/* Loop: regions owner holds now. */
uint32_t srv_dnshare_held(srv_dnshare *d, uint64_t owner);
/* Loop: a worker found lying, once each: 1 and *owner, else 0. */
int srv_dnshare_take_liar(srv_dnshare *d, uint64_t *owner);

#endif
