#define _GNU_SOURCE /* open_memstream */
#include "server/api/http_impl.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <microhttpd.h>
#include <openssl/crypto.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/net.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "protocol/auth.h"
#include "protocol/jobjson.h"
#include "server/api/http_assets.h"
#include "server/net/authlimit.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

void http_snap_unref_locked(snap *p)
{
    if (p && --p->refs == 0) {
        pt_free(p->jobs);
        pt_free(p->workers);
        pt_free(p->blocked);
        pt_free(p);
    }
}

snap *http_snap_get(srv_http *h)
{
    pthread_mutex_lock(&h->mu);
    snap *p = h->cur;
    if (p)
        p->refs++;
    pthread_mutex_unlock(&h->mu);
    return p;
}

void http_snap_put(srv_http *h, snap *p)
{
    pthread_mutex_lock(&h->mu);
    http_snap_unref_locked(p);
    pthread_mutex_unlock(&h->mu);
}

const snap_job *http_snap_find(const snap *p, uint64_t id)
{
    for (uint32_t i = 0; p && i < p->njobs; i++)
        if (p->jobs[i].info.job_id == id)
            return &p->jobs[i];
    return NULL;
}

/* ---- the loop's side ---- */

/* What a viewer would see change at once: jobs and their states and
 * priorities, peers. Progress alone waits for the next second, since each
 * snapshot computes every running job's error estimate over its film. */
uint64_t http_loop_signature(const srv_server *s)
{
    uint64_t sig = (uint64_t)s->nconns * 1000003u + s->njobs + (uint64_t)s->nblocked * 7919u;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        sig = sig * 1099511628211ull + j->rec.id * 31u + j->rec.state * 17u +
              (uint64_t)(uint32_t)j->rec.priority;
    return sig;
}

/* ---- requests ---- */

/* Queues r with status, its type and no-store, and lets it go. */
enum MHD_Result http_send_response(struct MHD_Connection *conn, unsigned status,
                                   struct MHD_Response *r, const char *type)
{
    MHD_add_response_header(r, "Content-Type", type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    enum MHD_Result ret = MHD_queue_response(conn, status, r);
    MHD_destroy_response(r);
    return ret;
}

enum MHD_Result http_respond(struct MHD_Connection *conn, unsigned status, const char *type,
                             void *data, size_t len, enum MHD_ResponseMemoryMode mode)
{
    struct MHD_Response *r = MHD_create_response_from_buffer(len, data, mode);
    if (!r) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(data);
        return MHD_NO;
    }
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    MHD_add_response_header(r, "X-Frame-Options", "DENY");
    MHD_add_response_header(r, "Content-Security-Policy",
                            "default-src 'self'; img-src 'self' blob:; frame-ancestors 'none'");
    return http_send_response(conn, status, r, type);
}

enum MHD_Result http_respond_text(struct MHD_Connection *conn, unsigned status, const char *type,
                                  const char *text)
{
    return http_respond(conn, status, type, (void *)text, strlen(text), MHD_RESPMEM_MUST_COPY);
}

/* {"error": TEXT} with status. */
enum MHD_Result http_respond_error(struct MHD_Connection *conn, unsigned status, const char *text)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f)
        return MHD_NO;
    fputs("{\"error\": ", f);
    proto_json_string(f, text);
    fputs("}\n", f);
    fclose(f);
    return http_respond(conn, status, "application/json", buf, len, MHD_RESPMEM_MUST_FREE);
}

/* Closes f, an open_memstream over *buf and *len (both set only then), and
 * sends what it holds. */
enum MHD_Result http_respond_stream(struct MHD_Connection *conn, FILE *f, char **buf, size_t *len,
                                    const char *type)
{
    if (fclose(f) != 0) {
        free(*buf);
        return http_respond_error(conn, 500, "out of memory");
    }
    return http_respond(conn, 200, type, *buf, *len, MHD_RESPMEM_MUST_FREE);
}

/* Hands an action to the loop and waits for its outcome. */
enum MHD_Result http_do_action(srv_http *h, struct MHD_Connection *conn, const who *w, int kind,
                               uint64_t id, int32_t priority)
{
    pthread_mutex_lock(&h->mu);
    action *a = NULL;
    for (unsigned i = 0; i < SRV_HTTP_ACTIONS && !a; i++)
        if (h->acts[i].state == ACT_FREE)
            a = &h->acts[i];
    if (!a) {
        pthread_mutex_unlock(&h->mu);
        return http_respond_error(conn, 503, "too many actions waiting; try again");
    }
    memset(a, 0, sizeof *a);
    a->state = ACT_PENDING;
    a->kind = kind;
    a->job = id;
    a->priority = priority;
    a->admin = w->admin;
    snprintf(a->who, sizeof a->who, "%s", w->name);
    char one = 1;
    if (write(h->wake_fd, &one, 1) < 0) {
        /* A full pipe already wakes the loop. */
    }
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += SRV_HTTP_ACTION_WAIT_MS / 1000;
    while (a->state != ACT_DONE && !h->stopping)
        if (pthread_cond_timedwait(&h->cv, &h->mu, &until) == ETIMEDOUT)
            break;
    if (a->state != ACT_DONE) {
        if (a->state == ACT_PENDING)
            a->state = ACT_FREE;
        else
            a->state = ACT_ABANDONED;
        pthread_mutex_unlock(&h->mu);
        return http_respond_error(conn, 503, "the coordinator did not answer in time");
    }
    unsigned status = a->status;
    char text[sizeof a->text];
    snprintf(text, sizeof text, "%s", a->text);
    a->state = ACT_FREE;
    pthread_mutex_unlock(&h->mu);
    if (status != 200)
        return http_respond_error(conn, status, text);
    snap *p = http_snap_get(h);
    const snap_job *j = http_snap_find(p, id);
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f) {
        http_snap_put(h, p);
        return MHD_NO;
    }
    if (j)
        proto_json_job(f, &j->info);
    else
        fputs("null", f);
    fputc('\n', f);
    http_snap_put(h, p);
    return http_respond_stream(conn, f, &buf, &len, "application/json");
}
