/*
 * writer.h - progressive EXR writes off the event loop.
 *
 * The loop resolves the film into an image snapshot and hands it over with
 * srv_writer_submit; a thread writes it (pt_exr_write: temp file, fsync,
 * rename) and a PNG preview beside it. Only the newest snapshot waiting is
 * kept: an older one not yet written is dropped, so a slow disk never makes
 * the loop wait or memory grow, and the files on disk only move forward.
 * srv_writer_flush waits until everything submitted has been written. A write
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

typedef struct srv_writer srv_writer;

pt_status srv_writer_new(const char *exr_path, srv_writer **out, pt_error *err);
/* Takes ownership of img (freed after writing or when replaced). */
void srv_writer_submit(srv_writer *w, pt_image *img, const pt_exr_meta *meta);
/* Waits until the last submitted snapshot is on disk; returns the status of
 * the last write (its error in err). */
pt_status srv_writer_flush(srv_writer *w, pt_error *err);
/* Without waiting: the status of the last write that finished (PT_OK before
 * any), its error in err; *failures (may be NULL) receives the number of
 * writes that failed in a row up to it (0 after a success). */
pt_status srv_writer_last(srv_writer *w, unsigned long *failures, pt_error *err);
/* Number of snapshots written so far. */
unsigned long srv_writer_count(srv_writer *w);
void srv_writer_free(srv_writer *w); /* flushes first; accepts NULL */

#endif
