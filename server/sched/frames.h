/*
 * frames.h - frame-range jobs: one job of the queue whose units are
 * (frame, tile, chunk).
 *
 * The job a client submits and sees (its srv_entry, "the range") holds no
 * srv_job of its own. Each frame it renders is a srv_entry of the queue's
 * list too, its parent set (server/sched/queue.h): a still of its own with its
 * film, tasks, merge, progressive image, results log and checkpoint, under
 * its own job id (srv_frame_job_id), so the machinery of a still (leases,
 * merges, verification, pauses, checkpoints, the state folder's files under
 * jobs/FRAME-ID/) serves each frame unchanged. Frame entries are not in the
 * queue file, LIST or the dashboard: the range's record is, with the frames
 * done (server/store/state.h).
 *
 * At most srv_frames_in_flight frames render at once (SRV_FRAMES_AHEAD, fewer
 * for large frames: no more pixels than --max-pixels and no more film than
 * --max-film-mb, so a range holds no more film than the largest still could): the first frame not
 * done and the ones after it (never one that many or more past it). A free worker slot gets a task
 * of the earliest of them that has one to hand out, so early frames finish first and the farm moves
 * on to later ones only when earlier ones have nothing left to hand out (their last pass). Each
 * task carries its frame's pose (TASK: animate, time = frame / fps, animation).
 *
 * A frame that is done has its image written, then its index recorded in
 * the range's record and the queue file written, and only then are its
 * files removed: after a crash at any point a done frame is either recorded
 * done or restored complete from its files, never rendered again.
 *
 * Threads: the event-loop thread only.
 */
#ifndef PT_SERVER_FRAMES_H
#define PT_SERVER_FRAMES_H

#include <stddef.h>
#include <stdint.h>

#include "protocol/msg.h"
#include "server/core.h"
#include "server/sched/queue.h"

/* Frame ids: far above any job id a queue gives (those count from 1), and
 * readable: 10^18 + job x 10^6 + frame number. */
#define SRV_FRAME_ID_BASE 1000000000000000000ull
#define SRV_FRAME_MAX_JOB 1000000000000ull /* job ids a frame-range job may have */

/* The range's part of the queue's entries (srv_range_ops, installed by
 * srv_serve as s->ranges): the functions below. */
extern const srv_range_ops srv_frames_ops;

/* The wire and state-folder id of frame number of job. */
uint64_t srv_frame_job_id(uint64_t job, uint32_t number);

/* Makes the range p ready: its frames rendering, each restored from its
 * files when there is a state folder. Returns 0 when it cannot be (p is then
 * ended FAILED). */
int srv_frames_ready(srv_server *s, srv_entry *p);

/* The frames of p rendering now, earliest first (NULL past the last). */
srv_entry *srv_frames_at(const srv_entry *p, uint32_t i);

/* Fills the pose of frame f into a task of it. */
void srv_frames_pose(const srv_entry *f, proto_task *t);

/* Frame f is done: records it in its range's record (the caller writes the
 * queue file next, then removes f's files). */
void srv_frames_note_done(srv_entry *f);

/* Removes the state folders of range p's frames its record says are done: a
 * kill -9 between the queue file saying so and the folder's removal leaves
 * one behind (called once, as the queue is loaded). */
void srv_frames_forget_done(srv_server *s, const srv_entry *p);

/* The range p ends early (cancelled, failed): ends its frames so. */
void srv_frames_end(srv_server *s, srv_entry *p, uint8_t state, const char *message);

/* Once per round after the leases: frees the frames that ended, starts the
 * next ones, fails a range whose frame failed and ends DONE a range whose
 * every frame is done. Returns 1 when a range ended. */
int srv_frames_round(srv_server *s);

/* The range's fields of JOB_INFO (and its totals over the frames). */
void srv_frames_info(const srv_server *s, const srv_entry *p, proto_job_info *m);

/* The file of frame number of p, by its output pattern. PT_ERR_ARG when p
 * does not render that frame. */
pt_status srv_frames_path(const srv_entry *p, uint32_t number, char *out, size_t cap,
                          pt_error *err);

/* The image a viewer of p should see now: the earliest frame rendering, or
 * the last one done; "" when none. */
void srv_frames_latest(const srv_entry *p, char *out, size_t cap);

/* How many frames of width x height pixels with film_flags' passes a range
 * renders at once: as many as fit in caps->max_pixels and whose films fit in
 * caps->max_film (0: no such cap), at least 1, at most SRV_FRAMES_AHEAD. */
uint32_t srv_frames_in_flight(const srv_caps *caps, uint32_t width, uint32_t height,
                              uint32_t film_flags);

#endif
