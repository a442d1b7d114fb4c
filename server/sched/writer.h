/*
 * writer.h - progressive EXR writes off the event loop.
 *
 * The loop asks for an image with srv_writer_submit; a thread resolves the
 * job's live film into its own image (pt_film_resolve, band by band under
 * the film's locks, while the loop goes on adding tiles), writes it
 * (pt_exr_write: temp file, fsync, rename) and a PNG preview beside it. So
 * the loop spends nothing per save but the request. The thread also measures
 * the image's estimated error in the same walk (pt_film_resolve_measured),
 * which the loop reads with srv_writer_error instead of computing it. Only
 * the newest request waiting is kept: one not yet taken is replaced, so a
 * slow disk never makes the loop wait or memory grow, and the files on disk
 * only move forward.
 * srv_writer_flush waits until everything asked for has been written;
 * srv_writer_idle tells, without waiting, whether it would wait. A write
 * that fails (a full output folder) leaves the last good image in place and
 * is reported by srv_writer_last; the caller submits again later.
 * Threads: one owner thread (the event loop's) calls every function; the
 * writer's own thread is internal.
 */
#ifndef PT_SERVER_WRITER_H
#define PT_SERVER_WRITER_H

#include "common/base/error.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/image/view.h"
#include "common/render/film.h"

typedef struct srv_writer srv_writer;

/* exr_path: the image, its format by its name (pt_image_format_of): an EXR
 * with its PNG preview beside it, or a .png alone.
 * film: what every image is resolved from; it must outlive the writer.
 * has_alpha: the images carry A (the film's coverage). view: the PNG
 * preview's exposure and transform (NULL: standard at 0 EV). */
pt_status srv_writer_new(const char *exr_path, const pt_film *film, int has_alpha,
                         const pt_view *view, srv_writer **out, pt_error *err);
/* Asks for the film as it is when the thread takes the request, written with
 * meta; meta's total_samples is replaced by the samples of the pixels
 * resolved, so the file says what its pixels hold. */
void srv_writer_submit(srv_writer *w, const pt_exr_meta *meta, int final);
/* --denoise (PROTO_FILM_DENOISE), SRV_WRITER_DENOISE_FINAL: a write
 * submitted as final (the image holds every sample the job will have) first
 * denoises the resolved image (pt_denoise_frame, on the processors online;
 * the same bits on any number), so the EXR gets the layer denoised.R/G/B and
 * the preview shows it; a write of the same samples again (a retry, a
 * second flush) reuses it. --denoise-progressive (with
 * PROTO_FILM_DENOISE_PROGRESSIVE), SRV_WRITER_DENOISE_ALL: progressive
 * writes are denoised too, on this thread, so saves asked for meanwhile
 * coalesce into the newest as any write does; a final write asked for
 * while a progressive one is denoised stops it (pt_denoise_frame_until):
 * that progressive image is dropped, never written, and the finished one
 * taken at once. 0: nothing is denoised. Call before the first submit. */
enum { SRV_WRITER_DENOISE_FINAL = 1, SRV_WRITER_DENOISE_ALL = 2 };
/* max_bytes: the denoiser's working memory at most (ptserve
 * --max-denoise-mb; 0: what the frame needs): a larger frame is denoised
 * in regions, the same bits (pt_denoise_frame_until). */
void srv_writer_set_denoise(srv_writer *w, int mode, uint64_t max_bytes);
/* ptserve --denoise-on-workers: the finished image's denoising is shared
 * with the workers (server/sched/dnshare.h) in regions of side (a multiple
 * of PT_DENOISE_TILE; smaller when max_bytes asks), the frame named job_id
 * on the wire, their results verified as verify_fraction says. Called
 * before the first write. The same bits as the writer alone. */
pt_status srv_writer_share_denoise(srv_writer *w, uint32_t side, uint64_t job_id,
                                   uint64_t verify_seed, double verify_fraction, pt_error *err);
/* NULL, or w's share, whose regions the loop leases (dnshare.h's loop calls). */
struct srv_dnshare *srv_writer_share(srv_writer *w);
/* Waits until the last submitted snapshot is on disk; returns the status of
 * the last write (its error in err). */
pt_status srv_writer_flush(srv_writer *w, pt_error *err);
/* Without waiting: 1 when everything submitted has been written (or has
 * failed), so that srv_writer_flush would return at once. */
int srv_writer_idle(srv_writer *w);
/* Without waiting: the work done of the finished image's denoising, in
 * thousandths, while it runs (the job's status: "denoising the image"); -1
 * when the writer is not denoising it. Any thread. */
int srv_writer_denoising(srv_writer *w);
/* Without waiting: the status of the last write that finished (PT_OK before
 * any), its error in err; *failures (may be NULL) receives the number of
 * writes that failed in a row up to it (0 after a success). */
pt_status srv_writer_last(srv_writer *w, unsigned long *failures, pt_error *err);
/* The estimated relative error (pt_film_resolve_measured's: infinite while a pixel
 * has fewer than 2 samples) of the film at the last resolve, written or not:
 * after srv_writer_flush, the film's as submitted. -1 before any. */
double srv_writer_error(srv_writer *w);
/* Number of snapshots written so far. */
unsigned long srv_writer_count(srv_writer *w);
void srv_writer_free(srv_writer *w); /* flushes first; accepts NULL */

#endif
