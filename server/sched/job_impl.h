/*
 * job_impl.h - the inside of one job (server/sched/job.h), shared by the
 * files it is cut into by concern: job.c (the job, its tiles and the cutting
 * of tasks, its owners), job_lease.c (leases, deadlines, backups and the
 * policy), job_merge.c (validation, merge order, verification, replay) and
 * job_ckpt.c (the checkpoint codec and snapshots). No other file includes it.
 *
 * Threads: as job.h: one thread at a time per job.
 */
#ifndef PT_SERVER_SCHED_JOB_IMPL_H
#define PT_SERVER_SCHED_JOB_IMPL_H

#include <stdint.h>

#include "common/render/guide.h"
#include "protocol/guide.h"
#include "server/sched/job.h"

enum { T_PENDING = 0, T_LEASED = 1, T_HELD = 2, T_MERGED = 3, T_SKIPPED = 4 };

/* A lease's kind: the task's first copy, a backup copy of a straggler, or a
 * verification copy of a task already merged. */
enum { L_TASK = 0, L_BACKUP = 1, L_VERIFY = 2 };

#define NONE UINT32_MAX

/* A task: samples [s0, s1) of one tile. Its id is its index in the job's
 * task table; records are never removed (a check names a merged task). */
typedef struct task {
    uint32_t tile, s0, s1;
    uint32_t next;   /* the tile's next unmerged task in sample order, NONE at the end */
    uint32_t leases; /* its live leases: the first one's slot, NONE when none */
    uint32_t held;   /* T_HELD: its index in held[] */
    uint8_t state;   /* T_* */
} task;

/* A lease lives in a slot of a pool; slots are stable while it lives, so
 * tasks and owners keep lists of them (by slot) and nothing is looked up by
 * scanning. */
typedef struct lease {
    uint64_t owner;
    uint64_t start;    /* when it was handed out (ms) */
    uint64_t deadline; /* heartbeat deadline: start or last heartbeat + lease_ms */
    double rate;       /* what it adds to the farm's rate (pixel-samples per ms) */
    uint32_t task;
    uint32_t check;        /* L_VERIFY: its check's index */
    uint32_t tnext;        /* the task's next lease; in a free slot, the next free slot */
    uint32_t oprev, onext; /* the owner's lease list */
    uint32_t owner_ix;     /* the owner's index in owners[] */
    uint8_t kind;          /* L_* */
    uint8_t live;
    uint8_t answered; /* its result arrived and waits for its log record to be
                         durable before it is merged: not a straggler */
    uint32_t gen;     /* bumped each time the slot is given, never 0: a ticket's
                         (srv_job_answered) proof that it is still this lease */
} lease;

typedef struct held {
    uint32_t task;
    uint64_t owner;
    pt_pixel_acc *px;
    uint64_t samples; /* the sum of px's n */
} held;

/* A verification in progress: the task's first result (owner[0], hash[0]),
 * a second worker's (stage 1 on), a third's when those two differ. */
enum { C_WANT_B = 0, C_LEASED_B, C_WANT_C, C_LEASED_C };

typedef struct check {
    uint32_t task;
    uint32_t lease; /* C_LEASED_*: the copy's slot */
    uint64_t owner[2];
    uint8_t hash[2][32];
    uint8_t stage; /* C_* */
} check;

/* Per worker connection (owner), what it delivered to this job, its leases
 * and its measured speed. */
typedef struct owner_stat {
    uint64_t owner, merged, verified, samples;
    double ms_ps;    /* ms per pixel-sample of one of its tasks (moving average); 0 unknown */
    uint32_t leases; /* its first lease's slot, NONE when none */
    uint32_t nleases;
} owner_stat;

/* Per tile: samples [0, merged) are in the film, [merged, frontier) are cut
 * into tasks (the list head..tail in sample order), [frontier, spp) are not
 * cut yet. */
typedef struct tile_state {
    uint32_t merged, frontier;
    uint32_t head, tail;
    uint8_t stopped; /* adaptive sampling stopped it: nothing more is rendered */
} tile_state;

#define TIMES 256 /* observed task times kept (a ring) for the deadline quantile */
#define CHECK_SCAN 64
/* Near the end a task takes at most the time the farm needs for the work not
 * yet cut, divided by this: the last tasks end within a fraction of one
 * another, and no core idles long on the tail. */
#define TAIL_SHARE 2.0
/* After the first pass a task takes a tile to at most this many times the
 * samples it had cut: 16, 128, 1024... so a 1,024-spp tile is three results
 * (doubling made it seven, and the coordinator's cost is per result), while
 * a task is still bounded by the task time and the image still improves
 * pass by pass, fewest samples first. */
#define GROWTH 8
/* Weight of a new measurement in an owner's moving average of its speed. */
#define SPEED_WEIGHT 0.5

struct srv_job {
    uint64_t id;
    srv_job_params p;
    uint8_t hash[32];
    uint32_t tiles_x, tiles_y, ntiles, npasses;
    int adaptive;        /* adaptive sampling is on: decisions at multiples of chunk */
    uint32_t first_stop; /* the first decision point (a multiple of chunk >= min_spp) */
    uint32_t least;      /* the fewest samples of a time-sized task: a block, or more
                          * where a job's blocks would pass half of SRV_MAX_TASKS */
    tile_state *tiles;
    uint32_t *heap; /* tiles not fully cut, by (frontier, tile) */
    uint32_t nheap;
    int heap_dirty; /* a frontier moved in the heap (a replay): rebuild it */
    task *tasks;
    uint32_t ntasks, tasks_cap;
    uint32_t *requeue; /* FIFO ring of task ids, as large as the task table */
    uint32_t rq_head, rq_len;
    lease *leases;
    uint32_t nleases, lease_slots, lease_free;
    held *held;
    uint32_t nheld, held_cap;
    uint64_t merged; /* tasks merged or skipped */
    uint64_t samples;
    uint64_t capped;  /* paths ended by the depth cap, over the results accepted */
    uint64_t clamped; /* contributions clamped (--clamp-*), likewise */
    uint32_t stopped, tiles_done;
    uint32_t passes_done, at_level; /* tiles with merged >= the next pass's samples */
    uint64_t uncut;                 /* pixel-samples of every tile's [frontier, spp) */
    double farm_rate;               /* sum of the live leases' rates */
    pt_film *film;
    srv_adder *adder; /* srv_job_set_adder: film adds go to its threads */
    srv_adds adds;    /* those in flight */
    /* deadlines, backups, verification and sizing (srv_job_set_policy) */
    srv_lease_policy pol;
    double times[TIMES];  /* ms per pixel-sample of merged results, in arrival order */
    double sorted[TIMES]; /* the same ntimes values, ascending */
    uint32_t ntimes, times_at;
    double t_high, t_mid; /* the quantile and the median of times, 0 before any */
    check *checks;
    uint32_t nchecks, checks_cap;
    owner_stat *owners;
    uint32_t nowners, owners_cap;
    uint32_t *owner_map; /* open addressing: owner index + 1, 0 empty */
    uint32_t owner_map_cap;
    srv_verify_stats vs;
    /* Path guiding (p.guiding, job_guide.c): tasks of pass gpass are leased
     * (pt_guide_pass_end: none of a later pass before its distribution
     * exists); guide is its distribution, gstats the statistics of its
     * results accepted so far; gtiles the tiles merged to its end. Each
     * pass's distribution is kept only packed for the wire (gpack[k],
     * proto_guide_pack: what GUIDE_GET hands out; NULL for passes before a
     * resume: only verification copies ask for an older one), with the
     * length (glen) and SHA-256 (ghash, what TASK names) of its GUIDE
     * bytes; a build unpacks the pass's (job_guide.c). */
    uint32_t gpass, gtiles;
    uint32_t gmost; /* the most statistics entries one result of the pass carried */
    /* A large build runs on a thread of its own (job_guide.c); the loop
     * installs what it made at the next lease or result after gdone. */
    struct job_guide_build *gbuild;
    pt_guide_stats *gstats;
    size_t glen[PROTO_MAX_GUIDE_PASS + 1];
    uint8_t ghash[PROTO_MAX_GUIDE_PASS + 1][32];
    uint8_t *gpack[PROTO_MAX_GUIDE_PASS + 1];
    size_t gplen[PROTO_MAX_GUIDE_PASS + 1];
};

pt_rect job_tile_rect(const srv_job *j, uint32_t tile);

/* Pixel-samples of task t: what its time is measured against. */
double job_task_work(const srv_job *j, uint32_t t);

void job_requeue_push(srv_job *j, uint32_t t);

/* Owner's entry of the per-owner table (made when missing); NULL without memory. */
owner_stat *job_owner_entry(srv_job *j, uint64_t owner);

uint32_t job_tile_pixels(const srv_job *j, uint32_t tile);

/* Waits for the job's adds in flight: the film's pixels are then the
 * merged tasks' sums (every read of them on the loop comes after this). */
void job_settle(const srv_job *j);

owner_stat *job_owner_find(const srv_job *j, uint64_t owner);

/* Drops every first or backup copy of task t (its result was accepted, or
 * adaptive sampling skipped it). */
void job_drop_copies(srv_job *j, uint32_t t);

/* Cuts the next task from the tile with the fewest samples cut, for owner o
 * (its speed sizes it). NONE when every tile is cut to its end. */
uint32_t job_cut_next(srv_job *j, const owner_stat *o);

/* Live first or backup copies of task t (verification copies aside). */
uint32_t job_task_copies(const srv_job *j, uint32_t t);

/* A new pending task [s0, s1) of tile, linked after `after` in the tile's
 * list (NONE: at its tail). NONE without memory. The requeue ring grows with
 * the table, so a task can always be put back (each is in it at most once). */
uint32_t job_task_add(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t after);

/* Drops the lease in slot s. A task's copy makes the task pending again
 * (requeued) when it was its last copy; a verification copy gives its check
 * back to the waiting ones. */
void job_requeue_lease(srv_job *j, uint32_t s);

/* Removes the lease in slot s from its task's and owner's lists. */
void job_remove_lease(srv_job *j, uint32_t s);

/* Counts passes done from scratch, from the tiles' samples (one pass of the
 * tiles per pass done, so a few per job). */
void job_passes_recount(srv_job *j);

/* The furthest a task starting at s0 may end: spp, and for an adaptive job
 * never past a decision point. With the min-gain rule, which judges the
 * chunk before the point against the samples before it (pt_tile_gain), only
 * a task of exactly that chunk may end at one; the error rule reads the sums
 * alone. */
uint32_t job_max_end(const srv_job *j, uint32_t s0);

/* The task of tile that samples [s0, s1) are, for a result without a lease
 * (a replay, a checkpoint's held result): the task cut so, else one made by
 * cutting a pending task or the tile's uncut samples (the rest pending).
 * SRV_MERGED with *out, or SRV_DUPLICATE (merged already), or SRV_INVALID
 * (the range does not fit what is cut; err says why). */
srv_outcome job_locate(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t *out,
                       pt_error *err);

/* With the min gain, a task that starts a decision point's chunk must end at
 * the point: the end it must have, or 0 when it is free. */
uint32_t job_forced_end(const srv_job *j, uint32_t s0);

/* Owner's lease of task t: its slot, or -1. Walks the task's few copies. */
int job_find_lease(const srv_job *j, uint32_t t, uint64_t owner);

/* ms per pixel-sample expected of owner o's next task: its own average, else
 * the job's median, 0 when nothing was measured. */
double job_expected_ms_ps(const srv_job *j, const owner_stat *o);

/* 1 when adaptive sampling decides after sample count s (s a multiple of the
 * chunk, at least min spp, short of spp). */
int job_decision_point(const srv_job *j, uint32_t s);

/* Sums non-negative and within the cap for n samples (radiance is never
 * negative: emission, base colour and textures are bounded and non-negative,
 * see common/scene/scene.c), a pixel with no samples all zero, counts
 * consistent. The sum of squares is unsigned and saturates (tile.h): any
 * value is possible but 0 is the only one for no samples. */
int job_acc_sane(const pt_pixel_acc *a, uint32_t max_n);

/* ---- path guiding (job_guide.c) ---- */

/* The first distribution (uniform over p.guide_box), its bytes and empty
 * statistics, for a guided job. PT_ERR_NOMEM, PT_ERR_ARG. */
pt_status job_guide_init(srv_job *j, pt_error *err);
void job_guide_free(srv_job *j);
/* The end of the pass that a task starting at s0 is in (spp when not guided). */
uint32_t job_guide_end(const srv_job *j, uint32_t s0);
/* 1 when a tile cut to frontier waits for the next pass's distribution. */
int job_guide_gated(const srv_job *j, uint32_t frontier);
/* TASK's GUIDE block for task samples from s0. 0 when the distribution of
 * its pass is not held (a verification copy of a pass before a resume). */
int job_guide_fill(const srv_job *j, uint32_t s0, proto_task *t);
/* 1 when r's statistics fit the job: present exactly when it is guided and
 * its pass is not the last (pt_guide_pass_last), made for its pass's
 * distribution, counts and sums plausible for its samples; else 0 with err. */
int job_guide_result_ok(const srv_job *j, const proto_result *r, pt_error *err);
/* Drops the statistics of r, a result replayed from the results log, when
 * they are of the job's last pass: a coordinator before PROTO_GUIDE_LAST had
 * its last pass's tasks record, and logged them with their statistics, from
 * which nothing is built. */
void job_guide_logged_last(const srv_job *j, proto_result *r);
/* Adds the statistics of r (accepted, job_guide_result_ok) to the pass's;
 * nothing for a result without any (the last pass's). */
void job_guide_accept(srv_job *j, const proto_result *r);
/* A tile's merged samples went from `from` to `to`: counts the tiles at the
 * pass's end and builds the next distribution when all are. */
void job_guide_tile_moved(srv_job *j, uint32_t from, uint32_t to);
/* Builds the next pass's distribution when every tile is merged to the
 * current pass's end (a retry after a failed build): at once when the
 * pass's guide is small, else on a thread whose distribution a later call
 * installs. */
void job_guide_advance(srv_job *j);
/* Waits for a build in flight and installs it (a replay, which must see
 * the next pass's distribution before that pass's results). */
void job_guide_settle(srv_job *j);
/* The checkpoint's guiding section (after the tiles' count): gpass, the
 * pass's distribution (packed; GUIDE bytes in a checkpoint before format 10,
 * !packed), its statistics. */
void job_guide_save(const srv_job *j, proto_writer *w);
pt_status job_guide_load(srv_job *j, proto_reader *r, int packed, pt_error *err);
/* Copies what job_guide_save reads into c (a snapshot). -1 without memory. */
int job_guide_copy(srv_job *c, const srv_job *j);
/* The bytes of npx pixels' sums as the job keeps a tile's (held, posted to
 * the adder): the pixels, then their pass sums when the job has passes. */
size_t job_px_bytes(const srv_job *j, size_t npx);

#endif
