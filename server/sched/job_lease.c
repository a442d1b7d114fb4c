#include "server/sched/job_impl.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/render.h"

/* ---- leases ---- */

static int grow_leases(srv_job *j)
{
    if (j->lease_free != NONE)
        return 0;
    uint32_t cap = j->lease_slots ? 2 * j->lease_slots : 64;
    lease *n = pt_realloc(j->leases, (size_t)cap * sizeof *n);
    if (!n)
        return -1;
    j->leases = n;
    for (uint32_t i = cap; i-- > j->lease_slots;) {
        n[i].live = 0;
        n[i].tnext = j->lease_free;
        j->lease_free = i;
    }
    j->lease_slots = cap;
    return 0;
}

/* Live first or backup copies of task t (verification copies aside). */
uint32_t job_task_copies(const srv_job *j, uint32_t t)
{
    uint32_t n = 0;
    for (uint32_t i = j->tasks[t].leases; i != NONE; i = j->leases[i].tnext)
        n += j->leases[i].kind != L_VERIFY;
    return n;
}

/* Owner's lease of task t: its slot, or -1. Walks the task's few copies. */
int job_find_lease(const srv_job *j, uint32_t t, uint64_t owner)
{
    for (uint32_t i = j->tasks[t].leases; i != NONE; i = j->leases[i].tnext)
        if (j->leases[i].owner == owner)
            return (int)i;
    return -1;
}

/* Adds a lease (a slot is free: grow_leases). */
static uint32_t add_lease(srv_job *j, owner_stat *o, uint32_t t, uint8_t kind, uint32_t ci,
                          uint64_t now_ms, uint32_t lease_ms)
{
    uint32_t s = j->lease_free;
    lease *l = &j->leases[s];
    j->lease_free = l->tnext;
    double v = job_expected_ms_ps(j, o);
    uint32_t gen = l->gen + 1 ? l->gen + 1 : 1;
    *l = (lease){.owner = o->owner,
                 .start = now_ms,
                 .deadline = now_ms + lease_ms,
                 .rate = v > 0.0 ? 1.0 / v : 0.0,
                 .task = t,
                 .check = ci,
                 .tnext = j->tasks[t].leases,
                 .oprev = NONE,
                 .onext = o->leases,
                 .owner_ix = (uint32_t)(o - j->owners),
                 .kind = kind,
                 .live = 1,
                 .gen = gen};
    j->tasks[t].leases = s;
    if (o->leases != NONE)
        j->leases[o->leases].oprev = s;
    o->leases = s;
    o->nleases++;
    j->nleases++;
    j->farm_rate += l->rate;
    return s;
}

/* Removes the lease in slot s from its task's and owner's lists. */
void job_remove_lease(srv_job *j, uint32_t s)
{
    lease *l = &j->leases[s];
    uint32_t *p = &j->tasks[l->task].leases;
    while (*p != s)
        p = &j->leases[*p].tnext;
    *p = l->tnext;
    owner_stat *o = &j->owners[l->owner_ix];
    if (l->oprev != NONE)
        j->leases[l->oprev].onext = l->onext;
    else
        o->leases = l->onext;
    if (l->onext != NONE)
        j->leases[l->onext].oprev = l->oprev;
    o->nleases--;
    j->nleases--;
    j->farm_rate -= l->rate;
    if (j->nleases == 0 || j->farm_rate < 0.0)
        j->farm_rate = 0.0; /* no drift left over from the sums */
    l->live = 0;
    l->tnext = j->lease_free;
    j->lease_free = s;
}

/* Drops the lease in slot s. A task's copy makes the task pending again
 * (requeued) when it was its last copy; a verification copy gives its check
 * back to the waiting ones. */
void job_requeue_lease(srv_job *j, uint32_t s)
{
    lease l = j->leases[s];
    job_remove_lease(j, s);
    if (l.kind == L_VERIFY) {
        check *c = &j->checks[l.check];
        if (c->stage == C_LEASED_B || c->stage == C_LEASED_C)
            c->stage--;
        return;
    }
    if (j->tasks[l.task].state != T_LEASED || job_task_copies(j, l.task) > 0)
        return;
    j->tasks[l.task].state = T_PENDING;
    job_requeue_push(j, l.task);
}

/* Drops every first or backup copy of task t (its result was accepted, or
 * adaptive sampling skipped it). */
void job_drop_copies(srv_job *j, uint32_t t)
{
    for (uint32_t i = j->tasks[t].leases; i != NONE;) {
        uint32_t next = j->leases[i].tnext;
        if (j->leases[i].kind != L_VERIFY)
            job_remove_lease(j, i);
        i = next;
    }
}

void srv_job_set_policy(srv_job *j, const srv_lease_policy *pol)
{
    j->pol = *pol;
}

/* How long after its start lease l may run, in ms; UINT64_MAX for no limit. */
static uint64_t allowance(const srv_job *j, const lease *l)
{
    if (!j->pol.floor_ms)
        return UINT64_MAX;
    if (j->t_high <= 0.0)
        return j->pol.first_ms > j->pol.floor_ms ? j->pol.first_ms : j->pol.floor_ms;
    double a = j->pol.factor * j->t_high * job_task_work(j, l->task);
    if (!(a < 1e15))
        a = 1e15;
    return a > (double)j->pol.floor_ms ? (uint64_t)a : j->pol.floor_ms;
}

/* A check owner may answer: the first waiting one whose results so far are
 * not owner's (only the first CHECK_SCAN are looked at, so a long list of
 * checks that only one worker could take costs little). -1 when none. */
static int verify_pick(const srv_job *j, uint64_t owner)
{
    uint32_t seen = 0;
    for (uint32_t i = 0; i < j->nchecks && seen < CHECK_SCAN; i++) {
        const check *c = &j->checks[i];
        if (c->stage != C_WANT_B && c->stage != C_WANT_C)
            continue;
        seen++;
        if (c->owner[0] == owner || (c->stage == C_WANT_C && c->owner[1] == owner))
            continue;
        return (int)i;
    }
    return -1;
}

/* The straggler owner should get a backup copy of: the oldest first copy,
 * not owner's, older than backup_factor x the median time for its size,
 * that has no backup yet. NONE when none (or nothing was observed). Scans
 * the leases, but only once nothing else is left to hand out. */
static uint32_t backup_pick(const srv_job *j, uint64_t owner, uint64_t now_ms)
{
    if (j->pol.backup_factor <= 0.0 || j->t_mid <= 0.0)
        return NONE;
    uint32_t best = NONE;
    uint64_t best_start = UINT64_MAX;
    for (uint32_t i = 0; i < j->lease_slots; i++) {
        const lease *l = &j->leases[i];
        if (!l->live || l->kind != L_TASK || l->answered || l->owner == owner ||
            l->start >= best_start)
            continue;
        double age = (double)(now_ms - l->start);
        if (now_ms < l->start || age < j->pol.backup_factor * j->t_mid * job_task_work(j, l->task))
            continue;
        if (job_task_copies(j, l->task) != 1)
            continue;
        best = l->task;
        best_start = l->start;
    }
    return best;
}

int srv_job_lease(srv_job *j, uint64_t owner, uint64_t now_ms, uint32_t lease_ms,
                  proto_task *task_out)
{
    uint32_t t = NONE, check_ix = 0;
    uint8_t kind = L_TASK;
    owner_stat *o = job_owner_entry(j, owner);
    if (!o || grow_leases(j) != 0)
        return 0;
    while (j->rq_len > 0) {
        uint32_t c = j->requeue[j->rq_head];
        j->rq_head = (j->rq_head + 1) % j->tasks_cap;
        j->rq_len--;
        if (j->tasks[c].state == T_PENDING) {
            t = c;
            break;
        }
    }
    int ci;
    if (t == NONE && (ci = verify_pick(j, owner)) >= 0) {
        t = j->checks[ci].task;
        kind = L_VERIFY;
        check_ix = (uint32_t)ci;
        j->checks[ci].stage++;
    }
    if (t == NONE)
        t = job_cut_next(j, o);
    if (t == NONE) {
        if ((t = backup_pick(j, owner, now_ms)) == NONE)
            return 0;
        kind = L_BACKUP;
        j->vs.backups++;
    }
    if (kind != L_VERIFY)
        j->tasks[t].state = T_LEASED;
    uint32_t s = add_lease(j, o, t, kind, check_ix, now_ms, lease_ms);
    if (kind == L_VERIFY)
        j->checks[check_ix].lease = s;

    const task *k = &j->tasks[t];
    memset(task_out, 0, sizeof *task_out);
    task_out->job_id = j->id;
    task_out->task_id = t;
    task_out->tile = job_tile_rect(j, k->tile);
    task_out->s0 = k->s0;
    task_out->s1 = k->s1;
    task_out->width = j->p.width;
    task_out->height = j->p.height;
    task_out->seed = j->p.seed;
    task_out->max_depth = (uint16_t)j->p.max_depth;
    task_out->rr_depth = (uint16_t)j->p.rr_depth;
    memcpy(task_out->scene_hash, j->hash, 32);
    task_out->lease_ms = lease_ms;
    snprintf(task_out->camera, sizeof task_out->camera, "%s", j->p.camera);
    task_out->env = j->p.env;
    task_out->film_flags = j->p.film_flags;
    snprintf(task_out->variant, sizeof task_out->variant, "%s", j->p.variant);
    task_out->shutter[0] = j->p.shutter[0];
    task_out->shutter[1] = j->p.shutter[1];
    task_out->clamp[0] = j->p.clamp[0];
    task_out->clamp[1] = j->p.clamp[1];
    job_guide_fill(j, k->s0, task_out);
    return 1;
}

void srv_job_heartbeat(srv_job *j, uint64_t owner, uint64_t task_id, uint64_t now_ms,
                       uint32_t lease_ms)
{
    if (task_id >= j->ntasks)
        return;
    int i = job_find_lease(j, (uint32_t)task_id, owner);
    if (i >= 0)
        j->leases[i].deadline = now_ms + lease_ms;
}

uint32_t srv_job_release_owner(srv_job *j, uint64_t owner)
{
    owner_stat *o = job_owner_find(j, owner);
    uint32_t n = 0;
    while (o && o->leases != NONE) {
        job_requeue_lease(j, o->leases);
        n++;
    }
    return n;
}

uint32_t srv_job_expire(srv_job *j, uint64_t now_ms, uint64_t *next_deadline, srv_miss_fn missed,
                        void *ctx)
{
    uint32_t n = 0;
    uint64_t next = UINT64_MAX;
    for (uint32_t i = 0; i < j->lease_slots; i++) {
        lease *l = &j->leases[i];
        if (!l->live)
            continue;
        uint64_t a = allowance(j, l);
        uint64_t hard = a > UINT64_MAX - l->start ? UINT64_MAX : l->start + a;
        uint64_t d = l->deadline < hard ? l->deadline : hard;
        if (d <= now_ms) {
            uint64_t owner = l->owner, t = l->task;
            /* Before the job's first result a slow start (a big scene to
             * fetch and load) cannot be told from hoarding: no miss then,
             * unless the owner stopped heartbeating. */
            int miss = l->deadline <= now_ms || j->t_high > 0.0;
            job_requeue_lease(j, i);
            n++;
            j->vs.expired++;
            if (missed && miss)
                missed(ctx, owner, t);
        } else if (d < next) {
            next = d;
        }
    }
    if (next_deadline)
        *next_deadline = next;
    return n;
}
