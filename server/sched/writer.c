#include "server/sched/writer.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/image/denoise.h"
#include "common/render/denoise_frame.h"
#include "server/log.h"
#include "server/sched/dnshare.h"

struct srv_writer {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    pthread_t thread;
    char exr[4096], png[4096]; /* exr "": a .png output, the PNG alone */
    char gate[4096];           /* test hook: wait for this file before each write */
    int hold_progressive;      /* test hook: a progressive denoise waits for a final */
    const pt_film *film;
    int has_alpha;
    pt_view view;            /* the preview's */
    pt_image *img;           /* the thread's, made at the first write and kept */
    int pending;             /* a request not yet taken */
    int final;               /* the pending request is the finished image's */
    int denoise;             /* SRV_WRITER_DENOISE_*, 0 (srv_writer_set_denoise) */
    uint64_t denoise_max;    /* the denoiser's working memory at most; 0: no limit */
    uint32_t said_side;      /* the regions last logged (0: none) */
    atomic_int dn_final;     /* 1 while the finished image is denoised (srv_writer_denoising) */
    atomic_uint dn_progress; /* ... its work done, thousandths */
    char dn_gate[4096];      /* test hook: that denoising waits for this file first */
    int busy_progressive;    /* the thread denoises a progressive write */
    atomic_int cancel;       /* set by a final submit: stop that denoising */
    srv_dnshare *share;      /* NULL, or the finished image's regions shared with workers */
    uint32_t share_side;     /* ... cut this wide */
    uint64_t share_job;      /* ... the frame's id on the wire */
    int denoised;            /* img holds denoised planes, of denoised_samples samples */
    uint64_t denoised_samples;
    pt_exr_meta meta;
    int busy, stop;
    unsigned long written, failures;
    double error; /* pt_film_resolve_measured's at the last resolve; -1 before any */
    pt_status last;
    pt_error last_err;
};

/* pt_denoise_frame_opts.denoise of a final image whose regions are shared
 * with the workers (srv_writer_share_denoise): the writer denoises those no
 * worker returns first. */
static pt_status share_regions(void *ctx, const pt_denoise_input *in, float *const out[3],
                               uint32_t *side, pt_error *err)
{
    srv_writer *w = ctx;
    uint32_t cut = w->share_side;
    uint32_t fits =
        w->denoise_max ? pt_denoise_region_side(in->width, in->height, w->denoise_max) : 0;
    if (fits && fits < cut)
        cut = fits; /* --max-denoise-mb holds regions of PT_DENOISE_TILE (ptserve checks) */
    *side = cut;
    pt_status st = srv_dnshare_open(w->share, in, cut, out, w->share_job, err);
    if (st != PT_OK)
        return st;
    /* Test hook (tests/integration/test_denoise_share.sh): the writer's own
     * denoising waits for a file while the workers take regions. Unset in
     * production. */
    pt_wait_for_file(w->dn_gate);
    srv_dnshare_stats ds;
    st = srv_dnshare_run(w->share, pt_denoise_default_threads(), &ds, err);
    srv_dnshare_close(w->share);
    if (st == PT_OK)
        srv_log("%s: denoised in %u regions of %u pixels: %u from workers (%u of them verified), "
                "%u by the coordinator; lying workers: %u",
                w->exr[0] ? w->exr : w->png, ds.regions, cut, ds.by_workers, ds.verified,
                ds.regions - ds.by_workers, ds.liars);
    return st;
}

/* The image denoised (once for a count of samples): its layer
 * denoised.R/G/B added to w->img, and *shown the image the preview shows.
 * PT_AGAIN when w->cancel stopped it. */
static pt_status denoise_image(srv_writer *w, uint64_t samples, int final, pt_image *shown,
                               pt_error *err)
{
    if (!w->denoised || w->denoised_samples != samples) {
        w->denoised = 0;
        if (w->hold_progressive && w->busy_progressive) {
            /* Test hook (tests/integration/test_denoise_farm.sh): this
             * progressive denoise starts only once a final write was asked
             * for (or after 60 s), so the final comes while it runs. */
            struct timespec ts = {0, 10 * 1000 * 1000};
            fprintf(stderr,
                    "ptserve: test hook: a progressive denoise waits for the final write\n");
            for (int i = 0; i < 6000 && !atomic_load(&w->cancel); i++)
                nanosleep(&ts, NULL);
        }
        uint32_t side = 0;
        pt_denoise_frame_opts o = {.despeckle = PT_DENOISE_DESPECKLE,
                                   .max_bytes = w->denoise_max,
                                   .cancel = &w->cancel,
                                   .progress = &w->dn_progress};
        if (final && w->share) {
            o.denoise = share_regions;
            o.ctx = w;
        }
        if (final) {
            atomic_store(&w->dn_progress, 0);
            atomic_store(&w->dn_final, 1);
            /* Test hook (tests/integration/test_denoise_farm.sh): the
             * finished image's denoising, shown in the job's status, waits
             * for a file. Unset in production. */
            if (!w->share)
                pt_wait_for_file(w->dn_gate); /* shared: once the regions are open */
        }
        pt_status st =
            pt_denoise_frame_until(w->img, pt_denoise_default_threads(), &o, NULL, &side, err);
        atomic_store(&w->dn_final, 0);
        if (st != PT_OK)
            return st;
        if (side && side != w->said_side && !o.denoise)
            srv_log("%s: denoised in regions of %u pixels, within --max-denoise-mb %llu",
                    w->exr[0] ? w->exr : w->png, side, (unsigned long long)(w->denoise_max >> 20));
        w->said_side = side;
        w->denoised = 1;
        w->denoised_samples = samples;
    }
    shown->r = pt_image_find_plane(w->img, "denoised.R");
    shown->g = pt_image_find_plane(w->img, "denoised.G");
    shown->b = pt_image_find_plane(w->img, "denoised.B");
    return PT_OK;
}

static void *writer_main(void *p)
{
    srv_writer *w = p;
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (!w->pending && !w->stop)
            pthread_cond_wait(&w->cv, &w->mu);
        if (!w->pending && w->stop)
            break;
        pt_exr_meta meta = w->meta;
        int final = w->final;
        int denoise = w->denoise == SRV_WRITER_DENOISE_ALL ||
                      (final && w->denoise == SRV_WRITER_DENOISE_FINAL);
        w->pending = 0;
        w->busy = 1;
        w->busy_progressive = denoise && !final;
        atomic_store(&w->cancel, 0);
        pthread_mutex_unlock(&w->mu);

        pt_error err = {0};
        pt_status st = PT_OK;
        double e = -1.0;
        if (!w->img)
            st = pt_image_new(w->film->width, w->film->height, &w->img, &err);
        pt_wait_for_file(w->gate);
        pt_image shown;
        if (st == PT_OK) {
            meta.total_samples = pt_film_resolve_measured(w->film, w->img, &e);
            w->img->has_alpha = w->has_alpha;
            shown = *w->img;
            if (denoise)
                st = denoise_image(w, meta.total_samples, final, &shown, &err);
        }
        if (st == PT_AGAIN) {
            /* a final write came while this progressive one was denoised:
             * dropped, not a failure; the final one is pending */
            pthread_mutex_lock(&w->mu);
            w->busy = w->busy_progressive = 0;
            w->error = e;
            pthread_cond_broadcast(&w->cv);
            continue;
        }
        if (st == PT_OK && w->exr[0])
            st = pt_exr_write(w->exr, w->img, &meta, &err);
        if (st == PT_OK)
            st = pt_png_write_preview(w->png, &shown, &w->view, &err);

        pthread_mutex_lock(&w->mu);
        w->busy = w->busy_progressive = 0;
        if (e != -1.0)
            w->error = e;
        w->last = st;
        w->last_err = err;
        if (st == PT_OK) {
            w->written++;
            w->failures = 0;
        } else {
            w->failures++;
        }
        pthread_cond_broadcast(&w->cv);
    }
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

pt_status srv_writer_new(const char *exr_path, const pt_film *film, int has_alpha,
                         const pt_view *view, srv_writer **out, pt_error *err)
{
    srv_writer *w = pt_calloc(1, sizeof *w);
    if (!w)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    w->film = film;
    w->has_alpha = has_alpha;
    if (view)
        w->view = *view;
    w->error = -1.0;
    atomic_init(&w->cancel, 0);
    if (pt_image_format_of(exr_path) == PT_IMAGE_FORMAT_PNG) {
        /* A .png output is the PNG alone: no EXR is written. */
        snprintf(w->png, sizeof w->png, "%s", exr_path);
    } else {
        snprintf(w->exr, sizeof w->exr, "%s", exr_path);
        pt_png_preview_path(exr_path, w->png, sizeof w->png);
    }
    /* Test hook (tests/integration/test_queue_ctl.sh): hold every write
     * until a file exists. Unset in production. */
    const char *gate = getenv("PTSERVE_TEST_WRITE_GATE");
    if (gate)
        snprintf(w->gate, sizeof w->gate, "%s", gate);
    /* Test hook (tests/integration/test_denoise_farm.sh): a progressive
     * denoise held until a final write stops it. Unset in production. */
    w->hold_progressive = getenv("PTSERVE_TEST_DENOISE_HOLD") != NULL;
    const char *dn_gate = getenv("PTSERVE_TEST_DENOISE_GATE");
    if (dn_gate)
        snprintf(w->dn_gate, sizeof w->dn_gate, "%s", dn_gate);
    atomic_init(&w->dn_final, 0);
    atomic_init(&w->dn_progress, 0);
    pthread_mutex_init(&w->mu, NULL);
    pthread_cond_init(&w->cv, NULL);
    if (pthread_create(&w->thread, NULL, writer_main, w) != 0) {
        pthread_mutex_destroy(&w->mu);
        pthread_cond_destroy(&w->cv);
        pt_free(w);
        return pt_error_set(err, PT_ERR_IO, "cannot start the EXR writer thread");
    }
    *out = w;
    return PT_OK;
}

void srv_writer_set_denoise(srv_writer *w, int mode, uint64_t max_bytes)
{
    pthread_mutex_lock(&w->mu);
    w->denoise = mode;
    w->denoise_max = max_bytes;
    pthread_mutex_unlock(&w->mu);
}

pt_status srv_writer_share_denoise(srv_writer *w, uint32_t side, uint64_t job_id,
                                   uint64_t verify_seed, double verify_fraction, pt_error *err)
{
    srv_dnshare *d = NULL;
    pt_status st = srv_dnshare_new(verify_seed, verify_fraction, &d, err);
    if (st != PT_OK)
        return st;
    pthread_mutex_lock(&w->mu);
    srv_dnshare *old = w->share;
    w->share = d;
    w->share_side = side;
    w->share_job = job_id;
    pthread_mutex_unlock(&w->mu);
    srv_dnshare_free(old); /* set before the first write: never in use */
    return PT_OK;
}

srv_dnshare *srv_writer_share(srv_writer *w)
{
    return w->share;
}

void srv_writer_submit(srv_writer *w, const pt_exr_meta *meta, int final)
{
    pthread_mutex_lock(&w->mu);
    w->pending = 1;
    w->final = final;
    w->meta = *meta;
    if (final && w->busy_progressive)
        atomic_store(&w->cancel, 1);
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

pt_status srv_writer_flush(srv_writer *w, pt_error *err)
{
    pthread_mutex_lock(&w->mu);
    while (w->pending || w->busy)
        pthread_cond_wait(&w->cv, &w->mu);
    pt_status st = w->last;
    if (st != PT_OK && err)
        *err = w->last_err;
    pthread_mutex_unlock(&w->mu);
    return st;
}

int srv_writer_denoising(srv_writer *w)
{
    return atomic_load(&w->dn_final) ? (int)atomic_load(&w->dn_progress) : -1;
}

int srv_writer_idle(srv_writer *w)
{
    pthread_mutex_lock(&w->mu);
    int idle = !w->pending && !w->busy;
    pthread_mutex_unlock(&w->mu);
    return idle;
}

pt_status srv_writer_last(srv_writer *w, unsigned long *failures, pt_error *err)
{
    pthread_mutex_lock(&w->mu);
    pt_status st = w->last;
    if (st != PT_OK && err)
        *err = w->last_err;
    if (failures)
        *failures = w->failures;
    pthread_mutex_unlock(&w->mu);
    return st;
}

double srv_writer_error(srv_writer *w)
{
    pthread_mutex_lock(&w->mu);
    double e = w->error;
    pthread_mutex_unlock(&w->mu);
    return e;
}

unsigned long srv_writer_count(srv_writer *w)
{
    pthread_mutex_lock(&w->mu);
    unsigned long n = w->written;
    pthread_mutex_unlock(&w->mu);
    return n;
}

void srv_writer_free(srv_writer *w)
{
    if (!w)
        return;
    pthread_mutex_lock(&w->mu);
    w->stop = 1;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
    pthread_join(w->thread, NULL);
    pt_image_free(w->img);
    srv_dnshare_free(w->share);
    pthread_mutex_destroy(&w->mu);
    pthread_cond_destroy(&w->cv);
    pt_free(w);
}
