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
#include "common/image/view.h"
#include "protocol/auth.h"
#include "protocol/jobjson.h"
#include "server/api/http_assets.h"
#include "server/net/authlimit.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

static void json_jobs(FILE *f, const snap *p)
{
    fputc('[', f);
    for (uint32_t i = 0; p && i < p->njobs; i++) {
        fputs(i ? ",\n " : "", f);
        proto_json_job(f, &p->jobs[i].info);
    }
    fputs("]\n", f);
}

static void json_workers(FILE *f, const snap *p)
{
    fputc('[', f);
    for (uint32_t i = 0; p && i < p->nworkers; i++) {
        const snap_worker *w = &p->workers[i];
        fprintf(f, "%s{\"id\": %llu, \"name\": ", i ? ",\n " : "", (unsigned long long)w->id);
        proto_json_string(f, w->name);
        fputs(", \"address\": ", f);
        proto_json_string(f, w->peer);
        fprintf(f, ", \"threads\": %u, \"slots_wanted\": %u, \"deadline_misses\": %u, ", w->threads,
                w->want, w->misses);
        fputs("\"connected_seconds\": ", f);
        proto_json_double(f, w->connected_s);
        fprintf(f, ", \"tasks_done\": %llu, \"samples_done\": %llu, \"samples_per_second\": ",
                (unsigned long long)w->tasks_done, (unsigned long long)w->samples_done);
        proto_json_double(f, w->connected_s > 0.0 ? (double)w->samples_done / w->connected_s : 0.0);
        fputs(", \"last_result_seconds_ago\": ", f);
        if (w->last_result_s >= 0.0)
            proto_json_double(f, w->last_result_s);
        else
            fputs("null", f);
        fputs(", \"state\": \"connected\", \"reason\": \"\"}", f);
    }
    /* Blocked workers are closed and refused at HELLO: listed by name, with
     * the address refused with them ("" for loopback) and why. */
    for (uint32_t i = 0; p && i < p->nblocked; i++) {
        const srv_blocked *b = &p->blocked[i];
        fprintf(f, "%s{\"id\": null, \"name\": ", (i || p->nworkers) ? ",\n " : "");
        proto_json_string(f, b->name);
        fputs(", \"address\": ", f);
        proto_json_string(f, b->addr);
        fputs(", \"state\": \"blocked\", \"reason\": ", f);
        proto_json_string(f, b->why);
        fputc('}', f);
    }
    fputs("]\n", f);
}

/* "/api/jobs/123/rest": 123 and "/rest" ("" when none); 0 when not a job id. */
static uint64_t parse_job_path(const char *p, const char **rest)
{
    uint64_t id = 0;
    int digits = 0;
    while (*p >= '0' && *p <= '9' && digits < 19) {
        id = id * 10 + (uint64_t)(*p++ - '0');
        digits++;
    }
    if (!digits || (*p && *p != '/'))
        return 0;
    *rest = p;
    return id;
}

enum MHD_Result http_post_field(void *cls, enum MHD_ValueKind kind, const char *key,
                                const char *filename, const char *type, const char *enc,
                                const char *data, uint64_t off, size_t size)
{
    (void)kind, (void)filename, (void)type, (void)enc;
    req *r = cls;
    char *dst = NULL;
    size_t cap = 0, *have = NULL, pr_len = strlen(r->priority);
    if (strcmp(key, "token") == 0) {
        dst = r->token;
        cap = sizeof r->token - 1;
        have = &r->token_len;
    } else if (strcmp(key, "priority") == 0) {
        dst = r->priority;
        cap = sizeof r->priority - 1;
        have = &pr_len;
    } else {
        return MHD_YES;
    }
    if (off != *have || size > cap - *have) {
        r->too_big = 1;
        return MHD_NO;
    }
    memcpy(dst + *have, data, size);
    *have += size;
    dst[*have] = '\0';
    return MHD_YES;
}

static int parse_priority(const char *v, int32_t *out)
{
    if (!v || !*v)
        return 0;
    char *end;
    errno = 0;
    long x = strtol(v, &end, 10);
    if (*end || errno || x < -1000000 || x > 1000000)
        return 0;
    *out = (int32_t)x;
    return 1;
}

static double arg_double(struct MHD_Connection *conn, const char *key, double def, double lo,
                         double hi)
{
    const char *v = MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, key);
    if (!v)
        return def;
    char *end;
    double x = strtod(v, &end);
    if (*end || !(x >= lo && x <= hi))
        return def;
    return x;
}

/* A colour ramp for heat maps: black, blue, red, yellow, white over 0..1. */
static void heat(double t, uint8_t *px)
{
    static const double stops[5][3] = {
        {0, 0, 0}, {0.1, 0.1, 0.7}, {0.85, 0.1, 0.1}, {1, 0.85, 0}, {1, 1, 1}};
    if (!(t > 0.0))
        t = 0.0;
    if (t > 1.0)
        t = 1.0;
    double x = t * 4.0;
    int i = x >= 4.0 ? 3 : (int)x;
    double u = x - i;
    for (int c = 0; c < 3; c++)
        px[c] = (uint8_t)(255.0 * (stops[i][c] * (1 - u) + stops[i + 1][c] * u) + 0.5);
}

/* The job's current image as a PNG: view "rgb" or "standard", "filmic" or
 * "agx" (the previews' view transforms, common/image/view.h, after exposure
 * in stops), "samples" (samples per pixel over the most any pixel has) or
 * "error" (the relative standard error of each pixel, 0 to 20 %). */
static enum MHD_Result make_png(struct MHD_Connection *conn, const snap_job *j)
{
    const char *view = MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "view");
    if (!view)
        view = "rgb";
    pt_view tv = {PT_VIEW_STANDARD, 0.0f};
    int image = !strcmp(view, "rgb") || pt_view_parse("view", view, &tv.kind, NULL) == PT_OK;
    if (!image && strcmp(view, "samples") && strcmp(view, "error"))
        return http_respond_error(conn, 400, "view: rgb, standard, filmic, agx, samples or error");
    tv.exposure = (float)arg_double(conn, "exposure", 0.0, -PT_VIEW_MAX_EV, PT_VIEW_MAX_EV);
    pt_image *img = NULL;
    pt_error err = {0};
    if (!j->exr[0] || pt_exr_read_nofollow(j->exr, &img, NULL, &err) != PT_OK)
        return http_respond_error(conn, 404, "no image yet");
    size_t n = (size_t)img->width * img->height;
    uint8_t *rgb = pt_malloc_array(n, 3);
    if (!rgb) {
        pt_image_free(img);
        return http_respond_error(conn, 500, "out of memory");
    }
    float smax = 0.0f;
    for (size_t i = 0; i < n; i++)
        smax = img->samples[i] > smax ? img->samples[i] : smax;
    for (size_t i = 0; i < n; i++) {
        uint8_t *px = rgb + 3 * i;
        if (image) {
            const float c[3] = {img->r[i], img->g[i], img->b[i]};
            pt_view_pixel(&tv, c, px);
        } else if (view[0] == 's') {
            heat(smax > 0.0f ? img->samples[i] / smax : 0.0, px);
        } else {
            double lum = 0.2126 * img->r[i] + 0.7152 * img->g[i] + 0.0722 * img->b[i];
            double e = img->samples[i] > 0.0f && lum > 1e-6 ? sqrt(img->variance[i]) / lum
                                                            : (img->samples[i] > 0 ? 0.0 : 1.0);
            heat(e / 0.2, px);
        }
    }
    uint8_t *png = NULL;
    size_t len = 0;
    pt_status st = pt_png_encode_rgb8(rgb, img->width, img->height, &png, &len, &err);
    pt_image_free(img);
    pt_free(rgb);
    if (st != PT_OK)
        return http_respond_error(conn, 500, err.msg);
    /* MHD frees with free(); the buffer is pt_malloc'd, so copy it. */
    enum MHD_Result ret = http_respond(conn, 200, "image/png", png, len, MHD_RESPMEM_MUST_COPY);
    pt_free(png);
    return ret;
}

/* make_png holds a whole float image: only SRV_HTTP_RENDERS at a time. */
static enum MHD_Result serve_png(srv_http *h, struct MHD_Connection *conn, const snap_job *j)
{
    pthread_mutex_lock(&h->mu);
    int ok = h->rendering < (int)SRV_HTTP_RENDERS;
    h->rendering += ok;
    pthread_mutex_unlock(&h->mu);
    if (!ok)
        return http_respond_error(conn, 503, "busy making other images; try again");
    enum MHD_Result ret = make_png(conn, j);
    pthread_mutex_lock(&h->mu);
    h->rendering--;
    pthread_mutex_unlock(&h->mu);
    return ret;
}

static enum MHD_Result serve_exr(struct MHD_Connection *conn, const snap_job *j)
{
    /* Sent from the open file: a rename by the writer meanwhile leaves this
     * copy whole, and no image is held in memory. Opened as FETCH opens it:
     * a link or a FIFO planted at the image's name is refused, not followed
     * or waited on. */
    int fd = -1;
    struct stat st;
    if (!j->exr[0] || pt_open_regular(j->exr, 0, &fd, NULL) != PT_OK)
        return http_respond_error(conn, 404, "no image yet");
    if (fstat(fd, &st) != 0) {
        close(fd);
        return http_respond_error(conn, 404, "no image yet");
    }
    struct MHD_Response *r = MHD_create_response_from_fd((uint64_t)st.st_size, fd);
    if (!r) {
        close(fd);
        return MHD_NO;
    }
    char disp[128];
    snprintf(disp, sizeof disp, "attachment; filename=\"job%llu.exr\"",
             (unsigned long long)j->info.job_id);
    MHD_add_response_header(r, "Content-Disposition", disp);
    return http_send_response(conn, 200, r, "image/x-exr");
}

/* Server-Sent Events of one job: its JSON each time a snapshot changes it,
 * a comment every 15 s otherwise; the stream ends when the job does. */
typedef struct sse {
    srv_http *h;
    uint64_t job, seen;
    char last[4096];
    int ended;
} sse;

static ssize_t sse_read(void *cls, uint64_t pos, char *out, size_t max)
{
    (void)pos;
    sse *e = cls;
    srv_http *h = e->h;
    if (e->ended)
        return MHD_CONTENT_READER_END_OF_STREAM;
    pthread_mutex_lock(&h->mu);
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += 15;
    while (h->version == e->seen && !h->stopping)
        if (pthread_cond_timedwait(&h->cv, &h->mu, &until) == ETIMEDOUT)
            break;
    int fresh = h->version != e->seen;
    if (h->stopping) {
        pthread_mutex_unlock(&h->mu);
        return MHD_CONTENT_READER_END_OF_STREAM;
    }
    e->seen = h->version;
    pthread_mutex_unlock(&h->mu);
    if (!fresh)
        return snprintf(out, max, ": ping\n\n");
    snap *p = http_snap_get(h);
    const snap_job *j = http_snap_find(p, e->job);
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f) {
        http_snap_put(h, p);
        return MHD_CONTENT_READER_END_WITH_ERROR;
    }
    if (j) {
        fputs("{\"job\": ", f);
        proto_json_job(f, &j->info);
        fprintf(f, ", \"images\": %lu}", j->images);
    } else {
        fputs("null", f);
    }
    fclose(f);
    if (!j || (j->info.state != PROTO_JOB_QUEUED && j->info.state != PROTO_JOB_RUNNING))
        e->ended = 1;
    http_snap_put(h, p);
    ssize_t n = 0;
    if (len + 16 <= max && strcmp(buf, e->last) != 0) {
        n = snprintf(out, max, "data: %s\n\n", buf);
        snprintf(e->last, sizeof e->last, "%s", buf);
    } else {
        n = snprintf(out, max, ": same\n\n");
    }
    free(buf);
    return n;
}

static enum MHD_Result serve_events(srv_http *h, struct MHD_Connection *conn, uint64_t id)
{
    sse *e = calloc(1, sizeof *e);
    if (!e)
        return MHD_NO;
    e->h = h;
    e->job = id;
    struct MHD_Response *r =
        MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 8192, sse_read, e, free);
    if (!r) {
        free(e);
        return MHD_NO;
    }
    return http_send_response(conn, 200, r, "text/event-stream");
}

enum MHD_Result http_serve_api(srv_http *h, struct MHD_Connection *conn, const who *w,
                               const char *method, const char *url, req *r)
{
    int get = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    int post = strcmp(method, "POST") == 0;
    char *buf = NULL;
    size_t len = 0;
    if (strcmp(url, "/api/jobs") == 0 || strcmp(url, "/api/workers") == 0) {
        if (!get)
            return http_respond_error(conn, 405, "GET only");
        snap *p = http_snap_get(h);
        FILE *f = open_memstream(&buf, &len);
        if (!f) {
            http_snap_put(h, p);
            return MHD_NO;
        }
        if (url[5] == 'j')
            json_jobs(f, p);
        else
            json_workers(f, p);
        http_snap_put(h, p);
        return http_respond_stream(conn, f, &buf, &len, "application/json");
    }
    if (strncmp(url, "/api/jobs/", 10) != 0)
        return http_respond_error(conn, 404, "no such API");
    const char *rest = "";
    uint64_t id = parse_job_path(url + 10, &rest);
    if (id == 0)
        return http_respond_error(conn, 404, "not a job id");
    if (strcmp(rest, "/cancel") == 0 || strcmp(rest, "/priority") == 0) {
        if (!post)
            return http_respond_error(conn, 405, "POST only");
        int32_t prio = 0;
        if (rest[1] == 'p') {
            const char *v =
                r->priority[0]
                    ? r->priority
                    : MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "priority");
            if (!parse_priority(v, &prio))
                return http_respond_error(conn, 400, "priority: an integer, -1000000..1000000");
        }
        return http_do_action(h, conn, w, rest[1] == 'c' ? ACT_CANCEL : ACT_PRIORITY, id, prio);
    }
    if (!get)
        return http_respond_error(conn, 405, "GET only");
    if (strcmp(rest, "/events") == 0)
        return serve_events(h, conn, id);
    snap *p = http_snap_get(h);
    const snap_job *j = http_snap_find(p, id);
    enum MHD_Result ret;
    if (!j) {
        char text[64];
        snprintf(text, sizeof text, "no job %llu", (unsigned long long)id);
        ret = http_respond_error(conn, 404, text);
    } else if (rest[0] == '\0') {
        FILE *f = open_memstream(&buf, &len);
        if (!f) {
            ret = MHD_NO;
        } else {
            proto_json_job(f, &j->info);
            fputc('\n', f);
            ret = http_respond_stream(conn, f, &buf, &len, "application/json");
        }
    } else if (strcmp(rest, "/image.png") == 0) {
        ret = serve_png(h, conn, j);
    } else if (strcmp(rest, "/image.exr") == 0) {
        ret = serve_exr(conn, j);
    } else {
        ret = http_respond_error(conn, 404, "no such API");
    }
    http_snap_put(h, p);
    return ret;
}

/* ---- /metrics: the Prometheus text format (version 0.0.4) ---- */

static void metric_head(FILE *f, const char *name, const char *type, const char *help)
{
    fprintf(f, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void metric_counter(FILE *f, const char *name, const char *help, uint64_t v)
{
    metric_head(f, name, "counter", help);
    fprintf(f, "%s %llu\n", name, (unsigned long long)v);
}

static void metric_gauge(FILE *f, const char *name, const char *help, double v)
{
    metric_head(f, name, "gauge", help);
    fprintf(f, "%s %.17g\n", name, v);
}

static void metric_histogram(FILE *f, const char *name, const char *help, const srv_histogram *h)
{
    metric_head(f, name, "histogram", help);
    double bound = SRV_HIST_FIRST;
    for (int i = 0; i < SRV_HIST_BUCKETS; i++, bound *= SRV_HIST_FACTOR)
        fprintf(f, "%s_bucket{le=\"%g\"} %llu\n", name, bound, (unsigned long long)h->buckets[i]);
    fprintf(f, "%s_bucket{le=\"+Inf\"} %llu\n%s_sum %.17g\n%s_count %llu\n", name,
            (unsigned long long)h->count, name, h->sum, name, (unsigned long long)h->count);
}

void http_metrics_text(FILE *f, const snap *p)
{
    static const srv_counters none;
    const srv_counters *c = p ? &p->counters : &none;
    uint32_t by_state[6] = {0}, threads = 0;
    for (uint32_t i = 0; p && i < p->njobs; i++)
        if (p->jobs[i].info.state < 6)
            by_state[p->jobs[i].info.state]++;
    for (uint32_t i = 0; p && i < p->nworkers; i++)
        threads += p->workers[i].threads;
    metric_head(f, "ptfarm_jobs", "gauge", "Jobs the coordinator knows, by state.");
    for (uint32_t st = PROTO_JOB_QUEUED; st <= PROTO_JOB_FAILED; st++)
        fprintf(f, "ptfarm_jobs{state=\"%s\"} %u\n", proto_job_state_name(st), by_state[st]);
    metric_counter(f, "ptfarm_samples_merged_total", "Samples merged into job images.",
                   c->samples_merged);
    metric_counter(f, "ptfarm_tasks_leased_total", "Tasks leased to workers.", c->tasks_leased);
    metric_counter(f, "ptfarm_tasks_requeued_total",
                   "Leased tasks put back because their worker left or their job paused.",
                   c->tasks_requeued);
    metric_counter(f, "ptfarm_tasks_expired_total", "Leases past their deadline, requeued.",
                   c->tasks_expired);
    metric_counter(f, "ptfarm_results_rejected_total",
                   "Results refused as invalid or not leased to their sender.",
                   c->results_rejected);
    metric_counter(f, "ptfarm_samples_rejected_total",
                   "Samples merged as rejected: NaN or Inf, or results that held no sample.",
                   c->samples_rejected);
    metric_counter(f, "ptfarm_state_write_errors_total",
                   "Failed writes to the state folder (queue file, results logs, checkpoints).",
                   c->state_write_errors);
    metric_counter(f, "ptfarm_results_log_holds_total",
                   "Times workers were not read because the results log was over --max-log-mb "
                   "waiting for the disk.",
                   c->log_holds);
    metric_gauge(f, "ptfarm_results_log_unsynced_bytes",
                 "Bytes of results not yet durable: their log records and decoded pixels.",
                 (double)c->log_unsynced);
    metric_gauge(f, "ptfarm_workers_connected", "Authenticated workers connected.",
                 p ? p->nworkers : 0);
    metric_gauge(f, "ptfarm_worker_threads", "Render threads of the connected workers.", threads);
    metric_gauge(f, "ptfarm_clients_connected", "Authenticated clients (ptctl) connected.",
                 p ? p->nclients : 0);
    metric_counter(f, "ptfarm_received_bytes_total", "Bytes received from workers and clients.",
                   p ? p->bytes_in : 0);
    metric_counter(f, "ptfarm_sent_bytes_total", "Bytes sent to workers and clients.",
                   p ? p->bytes_out : 0);
    metric_histogram(f, "ptfarm_merge_seconds", "Event-loop time merging one result.", &c->merge);
    metric_histogram(f, "ptfarm_image_save_seconds",
                     "Event-loop time resolving a progressive image for its writer.", &c->save);
    metric_histogram(f, "ptfarm_checkpoint_seconds", "Time writing one job checkpoint.",
                     &c->checkpoint);
    metric_gauge(f, "ptfarm_uptime_seconds", "Seconds since the coordinator started.",
                 p ? p->uptime_s : 0.0);
}
