#include "server/sched/job_impl.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/guide_sched.h"
#include "common/render/render.h"

/* ---- checkpoints ---- */

#define CKPT_MAGIC 0x434a5450u /* "PTJC" */
#define CKPT_VERSION 10u
#define CKPT_OLDEST_VERSION 2u   /* no min gain: read as 0 */
#define CKPT_MIN_GAIN_VERSION 3u /* the first with the min gain */
/* The first with the environment (older: none), and the first with the film
 * flags, the depth-cap count and each pixel's camera hits; older pixels read
 * as fully covered (their jobs are never transparent, so the count is not
 * shown). One format version brought both: srv_job_params_read takes one flag. */
#define CKPT_ENV_VERSION 4u
#define CKPT_FILM_VERSION CKPT_ENV_VERSION
/* The first with fixed-point sums (tile.h); older double sums are converted
 * as they are read (get_acc). */
#define CKPT_FIXED_VERSION 5u
/* The first with motion blur's shutter in the params (older: none). */
#define CKPT_SHUTTER_VERSION 7u
/* The first whose jobs may have render passes (film flags; older: none):
 * each pixel's sums, held or in the film, are then followed by its pass
 * sums (put_pass). */
#define CKPT_PASSES_VERSION 8u
#define CKPT_PASS_SIZE 404u /* bytes of one pixel's pass sums */
/* The first with sample clamping in the params (older: none). */
#define CKPT_CLAMP_VERSION 9u
/* The first with the contributions clamped (older: 0), and with a guided
 * job's distribution packed (older: its GUIDE bytes). */
#define CKPT_CLAMPED_VERSION 10u
#define CKPT_PACKED_GUIDE_VERSION CKPT_CLAMPED_VERSION

/* A pixel as the checkpoint stores it: each sum as two u64, low half first
 * (RESULT's wide layout, msg.h), then n and hits. */
static void put_acc(proto_writer *w, const pt_pixel_acc *a)
{
    for (int c = 0; c < 3; c++) {
        proto_w_u64(w, (uint64_t)a->fsum[c]);
        proto_w_u64(w, (uint64_t)(a->fsum[c] >> 64));
    }
    proto_w_u64(w, (uint64_t)a->fsum_sq);
    proto_w_u64(w, (uint64_t)(a->fsum_sq >> 64));
    proto_w_u32(w, a->n);
    proto_w_u32(w, a->hits);
}

/* A pixel's pass sums as the checkpoint stores them: each sum as two u64,
 * low half first (RESULT's wide pass layout, msg.h), then n_even. */
static void put_pass(proto_writer *w, const pt_pass_acc *a)
{
    for (int k = 0; k < PT_PASS_SUMS; k++) {
        proto_w_u64(w, (uint64_t)a->s[k]);
        proto_w_u64(w, (uint64_t)(a->s[k] >> 64));
    }
    for (int k = 0; k < PT_PASS_SQS; k++) {
        proto_w_u64(w, (uint64_t)a->sq[k]);
        proto_w_u64(w, (uint64_t)(a->sq[k] >> 64));
    }
    proto_w_u32(w, a->n_even);
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        for (int j = 0; j < PT_CRYPTO_KEEP; j++)
            proto_w_u32(w, a->cid[k][j]);
        for (int j = 0; j < PT_CRYPTO_KEEP; j++)
            proto_w_u32(w, a->ccnt[k][j]);
    }
}

/* A pixel's pass sums are consistent with its n (as the RESULT decoder
 * checks them). */
static int pass_sane(const pt_pass_acc *a, uint32_t n)
{
    if (a->n_even > n)
        return 0;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        if (!pt_crypto_canonical(a->cid[k], a->ccnt[k], n))
            return 0;
    return 1;
}

static void get_pass(proto_reader *r, pt_pass_acc *a)
{
    for (int k = 0; k < PT_PASS_SUMS; k++) {
        uint64_t lo = proto_r_u64(r, "pass sum");
        a->s[k] = (pt_i128)(((pt_u128)proto_r_u64(r, "pass sum") << 64) | lo);
    }
    for (int k = 0; k < PT_PASS_SQS; k++) {
        uint64_t lo = proto_r_u64(r, "pass sum of squares");
        a->sq[k] = ((pt_u128)proto_r_u64(r, "pass sum of squares") << 64) | lo;
    }
    a->n_even = proto_r_u32(r, "pass even samples");
    a->pad = 0;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        for (int j = 0; j < PT_CRYPTO_KEEP; j++)
            a->cid[k][j] = proto_r_u32(r, "Cryptomatte id");
        for (int j = 0; j < PT_CRYPTO_KEEP; j++)
            a->ccnt[k][j] = proto_r_u32(r, "Cryptomatte count");
    }
}

/* A double sum of a checkpoint before CKPT_FIXED_VERSION in fixed point, by
 * the same rounding as a block's (pt_fixed_of): deterministic, so a job
 * resumed from an older checkpoint loses no work and every coordinator that
 * loads it gets the same bits. A value that is not finite or not within the
 * cap for n samples (which no render gives) becomes -1, for acc_sane to
 * refuse. */
static pt_i128 fixed_of_old(double d, uint32_t n)
{
    if (!(d >= 0.0 && d <= PT_MAX_SAMPLE_RADIANCE * n))
        return -1;
    return pt_fixed_of(d);
}

static void get_acc(proto_reader *r, pt_pixel_acc *a, uint32_t version)
{
    if (version >= CKPT_FIXED_VERSION) {
        for (int c = 0; c < 3; c++) {
            uint64_t lo = proto_r_u64(r, "pixel sum");
            a->fsum[c] = (pt_i128)(((pt_u128)proto_r_u64(r, "pixel sum") << 64) | lo);
        }
        uint64_t lo = proto_r_u64(r, "pixel sum of squares");
        a->fsum_sq = ((pt_u128)proto_r_u64(r, "pixel sum of squares") << 64) | lo;
        a->n = proto_r_u32(r, "pixel samples");
        a->hits = proto_r_u32(r, "pixel camera hits");
        return;
    }
    double sum[3], sum_sq;
    for (int c = 0; c < 3; c++)
        sum[c] = proto_r_f64(r, "pixel sum");
    sum_sq = proto_r_f64(r, "pixel sum of squares");
    a->n = proto_r_u32(r, "pixel samples");
    a->hits = version >= CKPT_FILM_VERSION ? proto_r_u32(r, "pixel camera hits") : a->n;
    for (int c = 0; c < 3; c++)
        a->fsum[c] = fixed_of_old(sum[c], a->n);
    a->fsum_sq = isfinite(sum_sq) ? pt_ufixed_of(sum_sq) : 0;
    if (!isfinite(sum_sq) || sum_sq < 0.0)
        a->fsum[0] = -1;
}

/* The first that records each tile's merged samples and each held result's
 * range (older: chunks merged per tile and held task ids, chunk x tiles +
 * tile, of fixed chunks). */
#define CKPT_RANGE_VERSION 6u

pt_status srv_job_save(const srv_job *j, proto_writer *w, pt_error *err)
{
    job_settle(j);
    proto_w_u32(w, CKPT_MAGIC);
    proto_w_u32(w, CKPT_VERSION);
    proto_w_u64(w, j->id);
    proto_w_bytes(w, j->hash, 32);
    srv_job_params_write(w, &j->p);
    proto_w_u64(w, j->capped);
    proto_w_u64(w, j->clamped);
    proto_w_u32(w, j->ntiles);
    proto_w_u32(w, j->npasses);
    for (uint32_t t = 0; t < j->ntiles; t++) {
        proto_w_u32(w, j->tiles[t].merged);
        proto_w_u8(w, j->tiles[t].stopped);
    }
    job_guide_save(j, w); /* a guided job's (format 9 on) */
    proto_w_u32(w, j->nheld);
    for (uint32_t i = 0; i < j->nheld; i++) {
        const task *k = &j->tasks[j->held[i].task];
        proto_w_u32(w, k->tile);
        proto_w_u32(w, k->s0);
        proto_w_u32(w, k->s1);
        uint32_t npx = job_tile_pixels(j, k->tile);
        const pt_pixel_acc *px = j->held[i].px;
        for (uint32_t p = 0; p < npx; p++) {
            put_acc(w, &px[p]);
            if (j->film->pass) /* a held block: the pixels, then their passes */
                put_pass(w, &((const pt_pass_acc *)(px + npx))[p]);
        }
    }
    size_t npx = (size_t)j->p.width * j->p.height;
    for (size_t k = 0; k < npx; k++) {
        put_acc(w, &j->film->px[k]);
        if (j->film->pass)
            put_pass(w, &j->film->pass[k]);
    }
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w),
                            "checkpoint of job %llu: cannot "
                            "serialise (%zu pixels)",
                            (unsigned long long)j->id, npx);
    return PT_OK;
}

/* Reads the checkpoint's tiles (their samples merged, stopped or not) into j. */
static pt_status load_tiles(srv_job *j, proto_reader *r, uint32_t ntiles, uint32_t nchunks,
                            int ranges, pt_error *err)
{
    for (uint32_t t = 0; t < ntiles; t++) {
        uint32_t m = proto_r_u32(r, ranges ? "tile samples merged" : "tile chunks merged");
        uint8_t stopped = proto_r_u8(r, "tile stopped");
        if (r->status != PT_OK)
            return proto_r_finish(r, "checkpoint", err);
        uint32_t most = ranges ? j->p.spp : nchunks;
        if (m > most || stopped > 1 || (stopped && m == most))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: tile %u has %u %s merged of %u (stopped %u)", t, m,
                                ranges ? "samples" : "chunks", most, stopped);
        if (!ranges) {
            uint64_t s = (uint64_t)m * j->p.chunk;
            j->merged += m;
            m = s < j->p.spp ? (uint32_t)s : j->p.spp;
        } else {
            j->merged += (m + j->p.chunk - 1) / j->p.chunk; /* as many fixed chunks */
        }
        tile_state *ts = &j->tiles[t];
        ts->merged = ts->frontier = m;
        j->uncut -= (uint64_t)job_tile_pixels(j, t) * m;
        if (m == j->p.spp)
            j->tiles_done++;
        if (stopped) {
            j->uncut -= (uint64_t)job_tile_pixels(j, t) * (j->p.spp - m);
            ts->frontier = j->p.spp;
            ts->stopped = 1;
            j->stopped++;
            j->tiles_done++;
        }
    }
    return PT_OK;
}

/* Reads the checkpoint's nheld held results into j's held tasks. A read
 * past the end leaves r's status for the caller's proto_r_finish. */
static pt_status load_held(srv_job *j, proto_reader *r, uint32_t nheld, uint32_t ntiles,
                           uint32_t nchunks, int ranges, uint32_t version, size_t acc_size,
                           pt_error *err)
{
    for (uint32_t i = 0; i < nheld && r->status == PT_OK; i++) {
        uint32_t tile, s0, s1;
        if (ranges) {
            tile = proto_r_u32(r, "held tile");
            s0 = proto_r_u32(r, "held samples start");
            s1 = proto_r_u32(r, "held samples end");
        } else {
            uint64_t t = proto_r_u64(r, "held task");
            tile = (uint32_t)(t % ntiles);
            uint64_t c = t / ntiles, e = (c + 1) * j->p.chunk;
            s0 = c < nchunks ? (uint32_t)(c * j->p.chunk) : j->p.spp;
            s1 = e < j->p.spp ? (uint32_t)e : j->p.spp;
        }
        if (r->status != PT_OK)
            return PT_OK;
        uint32_t t;
        pt_error e2 = {0};
        if (tile >= ntiles || job_locate(j, tile, s0, s1, &t, &e2) != SRV_MERGED ||
            j->tasks[t].state != T_PENDING)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: held samples %u to %u of tile %u are not ones that "
                                "can be held",
                                s0, s1, tile);
        uint32_t npx = job_tile_pixels(j, tile);
        if (proto_r_left(r) < (size_t)npx * acc_size)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: truncated held samples %u to %u of tile %u", s0, s1,
                                tile);
        if (j->nheld == j->held_cap) {
            held *n = pt_grow_array(j->held, &j->held_cap, sizeof *n, 32);
            if (!n)
                return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
            j->held = n;
        }
        pt_pixel_acc *px = pt_malloc(job_px_bytes(j, npx));
        if (!px)
            return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
        pt_pass_acc *pass = j->film->pass ? (pt_pass_acc *)(px + npx) : NULL;
        uint64_t samples = 0;
        for (uint32_t k = 0; k < npx; k++) {
            get_acc(r, &px[k], version);
            if (pass)
                get_pass(r, &pass[k]);
            samples += px[k].n;
        }
        j->held[j->nheld] = (held){t, 0, px, samples};
        j->tasks[t].held = j->nheld++;
        j->tasks[t].state = T_HELD;
        for (uint32_t k = 0; k < npx; k++)
            if (!job_acc_sane(&px[k], s1 - s0) || (pass && !pass_sane(&pass[k], px[k].n)))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "checkpoint: held samples %u to %u of tile %u, pixel %u, "
                                    "are not finite or have too many samples",
                                    s0, s1, tile, k);
    }
    return PT_OK;
}

pt_status srv_job_load(srv_job *j, const uint8_t *data, size_t len, pt_error *err)
{
    if (j->merged || j->nleases || j->nheld || j->ntasks)
        return pt_error_set(err, PT_ERR_ARG, "checkpoint: job %llu is not fresh",
                            (unsigned long long)j->id);
    proto_reader r = proto_reader_make(data, len);
    uint32_t magic = proto_r_u32(&r, "magic"), version = proto_r_u32(&r, "version");
    if (magic != CKPT_MAGIC || version < CKPT_OLDEST_VERSION || version > CKPT_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT, "not a version %u to %u job checkpoint",
                            CKPT_OLDEST_VERSION, CKPT_VERSION);
    uint64_t id = proto_r_u64(&r, "job id");
    const uint8_t *hash = proto_r_bytes(&r, 32, "scene hash");
    srv_job_params p;
    int film = version >= CKPT_FILM_VERSION, ranges = version >= CKPT_RANGE_VERSION;
    /* Per pixel: 4 sums of 16 bytes (fixed point) or 8 (double, before
     * CKPT_FIXED_VERSION), n, and hits (from CKPT_FILM_VERSION on). */
    size_t acc_size = version >= CKPT_FIXED_VERSION ? 72 : film ? 40 : 36;
    srv_job_params_read(&r, &p, version >= CKPT_MIN_GAIN_VERSION, version >= CKPT_ENV_VERSION,
                        version >= CKPT_SHUTTER_VERSION, version >= CKPT_CLAMP_VERSION);
    uint64_t capped = film ? proto_r_u64(&r, "paths capped") : 0;
    uint64_t clamped =
        version >= CKPT_CLAMPED_VERSION ? proto_r_u64(&r, "contributions clamped") : 0;
    uint32_t ntiles = proto_r_u32(&r, "tiles"), nchunks = proto_r_u32(&r, "chunks");
    if (r.status != PT_OK)
        return proto_r_finish(&r, "checkpoint", err);
    if (proto_film_passes(p.film_flags) && version < CKPT_PASSES_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "checkpoint: version %u cannot hold the render passes its job asks for",
                            version);
    if (proto_film_passes(p.film_flags))
        acc_size += CKPT_PASS_SIZE;
    if (id != j->id || memcmp(hash, j->hash, 32) != 0 || p.width != j->p.width ||
        p.height != j->p.height || p.spp != j->p.spp || p.tile != j->p.tile ||
        p.chunk != j->p.chunk || p.seed != j->p.seed || p.max_depth != j->p.max_depth ||
        p.rr_depth != j->p.rr_depth || p.min_spp != j->p.min_spp ||
        memcmp(&p.target_error, &j->p.target_error, sizeof p.target_error) != 0 ||
        memcmp(&p.min_gain, &j->p.min_gain, sizeof p.min_gain) != 0 ||
        strcmp(p.camera, j->p.camera) != 0 || !proto_env_same(&p.env, &j->p.env) ||
        p.film_flags != j->p.film_flags || strcmp(p.variant, j->p.variant) != 0 ||
        memcmp(p.shutter, j->p.shutter, sizeof p.shutter) != 0 ||
        memcmp(p.clamp, j->p.clamp, sizeof p.clamp) != 0 || p.guiding != j->p.guiding ||
        memcmp(p.guide_box, j->p.guide_box, sizeof p.guide_box) != 0 || ntiles != j->ntiles ||
        nchunks != j->npasses)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "checkpoint is of another job or other settings "
                            "(job %llu, %ux%u, %u spp)",
                            (unsigned long long)id, p.width, p.height, p.spp);
    pt_status st = load_tiles(j, &r, ntiles, nchunks, ranges, err);
    if (st != PT_OK)
        return st;
    if ((st = job_guide_load(j, &r, version >= CKPT_PACKED_GUIDE_VERSION, err)) != PT_OK)
        return st;
    j->heap_dirty = 1;
    uint32_t nheld = proto_r_u32(&r, "held results");
    if (r.status == PT_OK && nheld > (uint64_t)ntiles * nchunks)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %u held results", nheld);
    if ((st = load_held(j, &r, nheld, ntiles, nchunks, ranges, version, acc_size, err)) != PT_OK)
        return st;
    size_t npx = (size_t)j->p.width * j->p.height;
    if (r.status == PT_OK && proto_r_left(&r) != npx * acc_size)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %zu bytes of film, expected %zu",
                            proto_r_left(&r), npx * acc_size);
    for (size_t k = 0; k < npx && r.status == PT_OK; k++) {
        get_acc(&r, &j->film->px[k], version);
        if (j->film->pass) {
            get_pass(&r, &j->film->pass[k]);
            if (r.status == PT_OK && !pass_sane(&j->film->pass[k], j->film->px[k].n))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "checkpoint: pixel %zu's pass sums do not fit its samples", k);
        }
        if (r.status == PT_OK && !job_acc_sane(&j->film->px[k], j->p.spp))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: pixel %zu is not finite or has "
                                "too many samples",
                                k);
    }
    if ((st = proto_r_finish(&r, "checkpoint", err)) != PT_OK)
        return st;
    j->samples = pt_film_total_samples(j->film);
    j->capped = capped;
    j->clamped = clamped;
    job_passes_recount(j);
    j->gtiles = 0;
    for (uint32_t t = 0; j->p.guiding && t < j->ntiles; t++)
        j->gtiles += j->tiles[t].merged >= pt_guide_pass_end(j->gpass, j->p.spp);
    return PT_OK;
}

srv_job *srv_job_snapshot(const srv_job *j)
{
    job_settle(j);
    /* What srv_job_save reads, and nothing else: the sizes, the tiles' merged
     * samples, the held results (each with a copy of its task, numbered as
     * its place in held[], for its tile and range) and the film. */
    srv_job *c = pt_calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->id = j->id;
    c->p = j->p;
    memcpy(c->hash, j->hash, sizeof c->hash);
    c->tiles_x = j->tiles_x;
    c->tiles_y = j->tiles_y;
    c->ntiles = j->ntiles;
    c->npasses = j->npasses;
    c->capped = j->capped;
    c->clamped = j->clamped;
    c->tiles = pt_malloc_array(j->ntiles ? j->ntiles : 1, sizeof *c->tiles);
    c->tasks = pt_malloc_array(j->nheld ? j->nheld : 1, sizeof *c->tasks);
    c->held = pt_malloc_array(j->nheld ? j->nheld : 1, sizeof *c->held);
    if (!c->tiles || !c->tasks || !c->held ||
        pt_film_new(j->film->width, j->film->height, &c->film, NULL) != PT_OK ||
        (j->film->pass && pt_film_enable_passes(c->film, j->film->passes, NULL) != PT_OK)) {
        srv_job_free(c);
        return NULL;
    }
    memcpy(c->tiles, j->tiles, (size_t)j->ntiles * sizeof *c->tiles);
    if (job_guide_copy(c, j) != 0) {
        srv_job_free(c);
        return NULL;
    }
    memcpy(c->film->px, j->film->px,
           (size_t)j->film->width * j->film->height * sizeof *c->film->px);
    if (j->film->pass)
        memcpy(c->film->pass, j->film->pass,
               (size_t)j->film->width * j->film->height * sizeof *c->film->pass);
    for (uint32_t i = 0; i < j->nheld; i++) {
        const task *k = &j->tasks[j->held[i].task];
        size_t npx = job_tile_pixels(j, k->tile);
        pt_pixel_acc *px = pt_malloc(job_px_bytes(j, npx));
        if (!px) {
            srv_job_free(c);
            return NULL;
        }
        memcpy(px, j->held[i].px, job_px_bytes(j, npx));
        c->tasks[i] = (task){k->tile, k->s0, k->s1, NONE, NONE, i, T_HELD};
        c->ntasks = c->tasks_cap = i + 1;
        c->held[c->nheld++] = (held){i, j->held[i].owner, px, j->held[i].samples};
    }
    return c;
}

/* srv_job_replay as the state folder's codec asks it: a duplicate is no
 * fault, anything else that is not merged is one. */
static pt_status codec_replay(srv_job *job, proto_result *r, int *merged, pt_error *err)
{
    srv_outcome o = srv_job_replay(job, r, err);
    *merged = o == SRV_MERGED;
    if (o == SRV_MERGED || o == SRV_DUPLICATE)
        return PT_OK;
    return err && err->code != PT_OK ? err->code : PT_ERR_FORMAT;
}

const srv_job_codec srv_job_state_codec = {srv_job_id, srv_job_save, srv_job_load, codec_replay,
                                           srv_job_free};
