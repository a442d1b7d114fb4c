/*
 * job_guide.c - path guiding learned by the farm, for one job (job_impl.h):
 * passes at the fixed sample boundaries of common/render/guide_sched.h, the
 * statistics of each pass's accepted results merged exactly (integers,
 * saturating: any order gives the same sums), the next pass's distribution
 * built once every tile is merged to the pass's end, and each distribution
 * kept only packed (proto_guide_pack: what GUIDE_CHUNK sends), named by the
 * hash of its GUIDE bytes as TASK names it; a build unpacks and decodes the
 * pass's distribution on its own thread and drops it once the next one is
 * packed, so a 1080p job holds 8 MB of distribution instead of about 120.
 * A pass's distribution is then a pure
 * function of the samples before it, as in ptworker --guiding on, so the
 * image is the standalone one bit for bit however the work was split.
 */
#include "server/sched/job_impl.h"

#include <pthread.h>
#include <stdatomic.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/hash.h"
#include "common/render/guide_sched.h"
#include "server/log.h"

/* The largest fixed-point value one record adds (pt_guide_stats_record). */
#define RECORD_CAP ((uint64_t)(PT_GUIDE_MAX_RECORD * (double)(1u << PT_GUIDE_FIXED_BITS) + 0.5))

/* A distribution as the job keeps it: the SHA-256 and length of its GUIDE
 * bytes, and those bytes packed. */
typedef struct sealed {
    uint8_t hash[32];
    size_t len;
    uint8_t *pack;
    size_t plen;
} sealed;

/* GUIDE bytes raw[0, n) sealed into *out. */
static pt_status seal_bytes(const uint8_t *raw, size_t n, sealed *out, pt_error *err)
{
    pt_sha256(raw, n, out->hash);
    out->len = n;
    return proto_guide_pack(raw, n, &out->pack, &out->plen, err);
}

/* g encoded and sealed into *out; the GUIDE bytes are not kept. */
static pt_status seal(const pt_guide *g, sealed *out, pt_error *err)
{
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_GUIDE_BYTES);
    pt_status st = proto_guide_encode(&w, g, err);
    if (st == PT_OK)
        st = seal_bytes(w.buf, w.len, out, err);
    proto_writer_fini(&w);
    return st;
}

/* *out = the guide that pack[0, plen) holds, checked for sampling. */
static pt_status unseal(const uint8_t *pack, size_t plen, pt_guide **out, pt_error *err)
{
    uint8_t *raw = NULL;
    size_t n = 0;
    pt_status st = proto_guide_unpack(pack, plen, &raw, &n, err);
    if (st == PT_OK)
        st = proto_guide_decode(raw, n, out, err);
    pt_free(raw);
    if (st == PT_OK && (st = pt_guide_check(*out, err)) != PT_OK) {
        pt_guide_free(*out);
        *out = NULL;
    }
    return st;
}

/* Makes s pass k's distribution (the job takes its packed bytes). */
static void keep(srv_job *j, uint32_t k, sealed *s)
{
    pt_free(j->gpack[k]);
    j->gpack[k] = s->pack;
    j->gplen[k] = s->plen;
    j->glen[k] = s->len;
    memcpy(j->ghash[k], s->hash, 32);
    s->pack = NULL;
}

/* Guides of more directional nodes than this are built off the loop (a
 * 1080p job's second pass: 7.4 million nodes, 1.4 s); smaller ones at once. */
#define BUILD_ON_THREAD_NODES (1u << 16)

/* A build: from the pass's packed distribution and its statistics (read
 * only while it runs: the pass's results are all accepted) to the next
 * distribution, sealed, and empty statistics for it. */
struct job_guide_build {
    pthread_t thread;
    atomic_int done;
    const uint8_t *from; /* the pass's packed distribution */
    size_t from_len;
    const pt_guide_stats *stats;
    uint32_t pass; /* the pass it builds for */
    uint64_t split, t0;
    uint32_t nsnode, nqnode; /* the new distribution's nodes */
    pt_guide_stats *nstats;
    sealed out;
    uint64_t pack_ms; /* the time encoding, hashing and packing took */
    pt_status st;
    pt_error err;
};

static void build_run(struct job_guide_build *b)
{
    pt_guide *from = NULL, *g = NULL;
    b->st = unseal(b->from, b->from_len, &from, &b->err);
    if (b->st == PT_OK)
        b->st = pt_guide_build(from, b->stats, b->split, &g, &b->err);
    pt_guide_free(from);
    if (b->st == PT_OK)
        b->st = pt_guide_stats_new(g, &b->nstats, &b->err);
    if (b->st == PT_OK) {
        b->nsnode = g->nsnode;
        b->nqnode = g->nqnode;
        uint64_t t = pt_now_ms();
        b->st = seal(g, &b->out, &b->err);
        b->pack_ms = pt_now_ms() - t;
    }
    pt_guide_free(g);
}

static void *build_thread(void *arg)
{
    struct job_guide_build *b = arg;
    build_run(b);
    atomic_store(&b->done, 1);
    return NULL;
}

static void build_free(struct job_guide_build *b)
{
    if (!b)
        return;
    pt_guide_stats_free(b->nstats);
    pt_free(b->out.pack);
    pt_free(b);
}

pt_status job_guide_init(srv_job *j, pt_error *err)
{
    if (!j->p.guiding)
        return PT_OK;
    if (j->adaptive)
        return pt_error_set(err, PT_ERR_ARG,
                            "job: guiding does not combine with adaptive sampling");
    const float *b = j->p.guide_box;
    pt_guide *g = NULL;
    sealed s = {0};
    pt_status st = pt_guide_new_uniform(pt_v3(b[0], b[1], b[2]), pt_v3(b[3], b[4], b[5]), &g, err);
    if (st == PT_OK)
        st = pt_guide_stats_new(g, &j->gstats, err);
    if (st == PT_OK)
        st = seal(g, &s, err);
    if (st == PT_OK)
        keep(j, 0, &s);
    pt_free(s.pack);
    pt_guide_free(g);
    return st;
}

void job_guide_free(srv_job *j)
{
    if (j->gbuild) {
        pthread_join(j->gbuild->thread, NULL);
        build_free(j->gbuild);
        j->gbuild = NULL;
    }
    pt_guide_stats_free(j->gstats);
    for (uint32_t k = 0; k <= PROTO_MAX_GUIDE_PASS; k++)
        pt_free(j->gpack[k]);
}

uint32_t job_guide_end(const srv_job *j, uint32_t s0)
{
    if (!j->p.guiding)
        return j->p.spp;
    return pt_guide_pass_end(pt_guide_pass_of(s0, j->p.spp), j->p.spp);
}

int job_guide_gated(const srv_job *j, uint32_t frontier)
{
    return j->p.guiding && frontier >= pt_guide_pass_end(j->gpass, j->p.spp);
}

int job_guide_fill(const srv_job *j, uint32_t s0, proto_task *t)
{
    t->guided = 0;
    t->guide_pass = 0;
    memset(t->guide_hash, 0, sizeof t->guide_hash);
    if (!j->p.guiding)
        return 1;
    uint32_t k = pt_guide_pass_of(s0, j->p.spp);
    if (k > PROTO_MAX_GUIDE_PASS || !j->gpack[k])
        return 0;
    /* No distribution is built from the last pass's statistics: its tasks
     * record none (as the standalone render's last pass). */
    t->guided = pt_guide_pass_last(k, j->p.spp) ? PROTO_GUIDE_LAST : PROTO_GUIDE_RECORD;
    t->guide_pass = k;
    memcpy(t->guide_hash, j->ghash[k], 32);
    return 1;
}

int job_guide_result_ok(const srv_job *j, const proto_result *r, pt_error *err)
{
    if (!j->p.guiding) {
        if (!r->guide)
            return 1;
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu carries guiding statistics; the job is not guided",
                     (unsigned long long)r->task_id);
        return 0;
    }
    /* Its task said whether to record (job_guide_fill): statistics exactly
     * when the pass is not the last. */
    uint32_t k = pt_guide_pass_of(r->s0, j->p.spp);
    if (pt_guide_pass_last(k, j->p.spp)) {
        if (!r->guide)
            return 1;
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu carries guiding statistics; pass %u is the job's "
                     "last and records none",
                     (unsigned long long)r->task_id, k);
        return 0;
    }
    if (!r->guide) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu lacks the guiding statistics",
                     (unsigned long long)r->task_id);
        return 0;
    }
    /* A first copy is of the pass being learned; a verification copy's
     * statistics are compared, not merged, but must be of its pass too. */
    if (k == j->gpass && (r->g_nsnode != j->gstats->nsnode || r->g_nqnode != j->gstats->nqnode)) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: guiding statistics for %u+%u nodes, pass %u's "
                     "distribution has %u+%u",
                     (unsigned long long)r->task_id, r->g_nsnode, r->g_nqnode, k, j->gstats->nsnode,
                     j->gstats->nqnode);
        return 0;
    }
    /* At most one record per scattering event of each sample, each at most
     * RECORD_CAP (pt_guide_stats_record's clamp). */
    pt_u128 records = 0, sum = 0;
    for (uint32_t i = 0; i < r->gcount; i++)
        records += r->guide[i].value;
    for (uint32_t i = r->gcount; i < r->gcount + r->gsum; i++)
        sum += r->guide[i].value;
    pt_u128 most = (pt_u128)r->npixels * (r->s1 - r->s0) * ((pt_u128)j->p.max_depth + 1);
    if (records > most || sum > records * RECORD_CAP) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: guiding statistics of %.3g records and %.3g in sums "
                     "are not a plausible render of %u pixels x %u samples",
                     (unsigned long long)r->task_id, (double)records, (double)sum, r->npixels,
                     r->s1 - r->s0);
        return 0;
    }
    return 1;
}

void job_guide_logged_last(const srv_job *j, proto_result *r)
{
    if (!j->p.guiding || !r->guide ||
        !pt_guide_pass_last(pt_guide_pass_of(r->s0, j->p.spp), j->p.spp))
        return;
    if (r->owns_guide)
        pt_free(r->guide);
    r->guide = NULL;
    r->owns_guide = 0;
    r->g_nsnode = r->g_nqnode = r->gcount = r->gsum = 0;
}

void job_guide_accept(srv_job *j, const proto_result *r)
{
    if (!j->p.guiding || !r->guide)
        return;
    uint32_t k = pt_guide_pass_of(r->s0, j->p.spp);
    /* No task of the next pass is leased before its distribution exists, but
     * after a restart the results log can replay one while that
     * distribution is still being built off the loop (the checkpoint was
     * taken during the build): wait for it, so that the result's statistics
     * count in its own pass and are not dropped. */
    if (k == j->gpass + 1 && j->gbuild)
        job_guide_settle(j);
    if (k != j->gpass)
        return;
    pt_error err = {0};
    if (r->gcount + r->gsum > j->gmost)
        j->gmost = r->gcount + r->gsum;
    /* Checked by job_guide_result_ok: the sizes are the pass's. */
    if (proto_guide_stats_add(j->gstats, r, &err) != PT_OK)
        srv_log("job %llu: %s", (unsigned long long)j->id, err.msg);
}

/* Installs a finished build (joined) as pass b->pass's distribution. */
static void install(srv_job *j, struct job_guide_build *b, int threaded)
{
    j->gbuild = NULL;
    if (b->st != PT_OK) {
        srv_log("job %llu: guiding pass %u's distribution: %s (tried again at the next lease)",
                (unsigned long long)j->id, b->pass, b->err.msg);
        build_free(b);
        return;
    }
    pt_guide_stats_free(j->gstats);
    j->gstats = b->nstats;
    b->nstats = NULL;
    keep(j, b->pass, &b->out);
    j->gpass = b->pass;
    srv_log("job %llu: guiding pass %u: a distribution of %zu bytes, %zu packed (%u spatial, %u "
            "directional nodes) built in %llu ms%s (packed in %llu ms); pass %u's results carried "
            "at most %u statistics entries",
            (unsigned long long)j->id, j->gpass, j->glen[j->gpass], j->gplen[j->gpass], b->nsnode,
            b->nqnode, (unsigned long long)(pt_now_ms() - b->t0), threaded ? " off the loop" : "",
            (unsigned long long)b->pack_ms, j->gpass - 1, j->gmost);
    build_free(b);
    j->gmost = 0;
    uint32_t end = pt_guide_pass_end(j->gpass, j->p.spp);
    j->gtiles = 0;
    for (uint32_t t = 0; t < j->ntiles; t++)
        j->gtiles += j->tiles[t].merged >= end;
}

void job_guide_settle(srv_job *j)
{
    struct job_guide_build *b = j->gbuild;
    if (!b)
        return;
    pthread_join(b->thread, NULL);
    install(j, b, 1);
}

void job_guide_advance(srv_job *j)
{
    if (j->gbuild) {
        if (atomic_load(&j->gbuild->done))
            job_guide_settle(j);
        return;
    }
    uint32_t end = pt_guide_pass_end(j->gpass, j->p.spp);
    if (!j->p.guiding || j->gtiles < j->ntiles || end >= j->p.spp ||
        j->gpass >= PROTO_MAX_GUIDE_PASS)
        return;
    struct job_guide_build *b = pt_calloc(1, sizeof *b);
    if (!b) {
        srv_log("job %llu: out of memory for guiding pass %u's build (tried again at the next "
                "lease)",
                (unsigned long long)j->id, j->gpass + 1);
        return;
    }
    b->from = j->gpack[j->gpass];
    b->from_len = j->gplen[j->gpass];
    b->stats = j->gstats;
    b->pass = j->gpass + 1;
    b->split = pt_guide_split_count(j->gpass);
    b->t0 = pt_now_ms();
    atomic_init(&b->done, 0);
    j->gbuild = b;
    /* The result is the same bits on either path: a pure function of the
     * guide and the statistics. */
    if (j->gstats->nqnode > BUILD_ON_THREAD_NODES &&
        pthread_create(&b->thread, NULL, build_thread, b) == 0)
        return;
    build_run(b);
    install(j, b, 0);
}

void job_guide_tile_moved(srv_job *j, uint32_t from, uint32_t to)
{
    if (!j->p.guiding)
        return;
    uint32_t end = pt_guide_pass_end(j->gpass, j->p.spp);
    if (from < end && to >= end) {
        j->gtiles++;
        job_guide_advance(j);
    }
}

/* The checkpoint's guiding section: u32 the pass, u32 n and n bytes of its
 * distribution (packed from format 10 on, GUIDE bytes before), then its
 * statistics: u32 counts listed, u32 sums listed, then (u32 node, u64
 * value) each, ascending (RESULT's form). */
void job_guide_save(const srv_job *j, proto_writer *w)
{
    if (!j->p.guiding)
        return;
    uint32_t k = j->gpass;
    proto_w_u32(w, k);
    proto_w_u32(w, (uint32_t)j->gplen[k]);
    proto_w_bytes(w, j->gpack[k], j->gplen[k]);
    const pt_guide_stats *s = j->gstats;
    uint32_t nc = 0, ns = 0;
    for (uint32_t i = 0; i < s->nsnode; i++)
        nc += s->count[i] != 0;
    for (uint32_t i = 0; i < s->nqnode; i++)
        ns += s->sum[i] != 0;
    proto_w_u32(w, nc);
    proto_w_u32(w, ns);
    for (uint32_t i = 0; i < s->nsnode; i++)
        if (s->count[i]) {
            proto_w_u32(w, i);
            proto_w_u64(w, s->count[i]);
        }
    for (uint32_t i = 0; i < s->nqnode; i++)
        if (s->sum[i]) {
            proto_w_u32(w, i);
            proto_w_u64(w, s->sum[i]);
        }
}

/* The distribution of a checkpoint's n bytes at p (packed, or its GUIDE
 * bytes when !packed) sealed into *out, and *g decoded and checked. */
static pt_status load_distribution(const uint8_t *p, size_t n, int packed, sealed *out,
                                   pt_guide **g, pt_error *err)
{
    uint8_t *raw = NULL;
    size_t len = n;
    pt_status st = packed ? proto_guide_unpack(p, n, &raw, &len, err) : PT_OK;
    const uint8_t *bytes = packed ? raw : p;
    if (st == PT_OK)
        st = proto_guide_decode(bytes, len, g, err);
    if (st == PT_OK && (st = pt_guide_check(*g, err)) != PT_OK) {
        pt_guide_free(*g);
        *g = NULL;
    }
    if (st == PT_OK && packed) {
        /* The packed bytes as they are; the hash is of the GUIDE bytes. */
        pt_sha256(raw, len, out->hash);
        out->len = len;
        out->plen = n;
        if (!(out->pack = pt_malloc(n)))
            st = pt_error_set(err, PT_ERR_NOMEM, "checkpoint: guide of %zu bytes", n);
        else
            memcpy(out->pack, p, n);
    } else if (st == PT_OK) {
        st = seal_bytes(p, n, out, err);
    }
    pt_free(raw);
    return st;
}

pt_status job_guide_load(srv_job *j, proto_reader *r, int packed, pt_error *err)
{
    if (!j->p.guiding)
        return PT_OK;
    uint32_t k = proto_r_u32(r, "guiding pass");
    uint32_t len = proto_r_u32(r, "guide bytes");
    if (r->status != PT_OK)
        return proto_r_finish(r, "checkpoint", err);
    if (k > PROTO_MAX_GUIDE_PASS || pt_guide_pass_start(k, j->p.spp) >= j->p.spp ||
        len > PROTO_MAX_GUIDE_BYTES || proto_r_left(r) < len)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: guiding pass %u of %u bytes", k, len);
    const uint8_t *blob = proto_r_bytes(r, len, "guide");
    pt_guide *g = NULL;
    pt_guide_stats *s = NULL;
    sealed sl = {0};
    pt_status st = load_distribution(blob, len, packed, &sl, &g, err);
    if (st == PT_OK)
        st = pt_guide_stats_new(g, &s, err);
    uint32_t nc = proto_r_u32(r, "guiding counts"), ns = proto_r_u32(r, "guiding sums");
    if (st == PT_OK && (r->status != PT_OK || nc > g->nsnode || ns > g->nqnode ||
                        proto_r_left(r) < ((size_t)nc + ns) * 12))
        st = pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %u+%u guiding entries", nc, ns);
    for (uint32_t i = 0; st == PT_OK && i < nc + ns; i++) {
        uint32_t node = proto_r_u32(r, "guide node");
        uint64_t v = proto_r_u64(r, "guide value");
        if (node >= (i < nc ? g->nsnode : g->nqnode) || v == 0)
            st = pt_error_set(err, PT_ERR_FORMAT, "checkpoint: guiding entry %u", i);
        else
            (i < nc ? s->count : s->sum)[node] = v;
    }
    pt_guide_free(g);
    if (st != PT_OK) {
        pt_free(sl.pack);
        pt_guide_stats_free(s);
        return st;
    }
    pt_guide_stats_free(j->gstats);
    for (uint32_t i = 0; i <= PROTO_MAX_GUIDE_PASS; i++) {
        pt_free(j->gpack[i]);
        j->gpack[i] = NULL;
        j->glen[i] = j->gplen[i] = 0;
    }
    j->gstats = s;
    j->gpass = k;
    keep(j, k, &sl);
    return PT_OK;
}

int job_guide_copy(srv_job *c, const srv_job *j)
{
    if (!j->p.guiding)
        return 0;
    uint32_t k = j->gpass;
    c->gpass = k;
    c->glen[k] = j->glen[k];
    c->gplen[k] = j->gplen[k];
    memcpy(c->ghash[k], j->ghash[k], 32);
    c->gpack[k] = pt_malloc(j->gplen[k]);
    /* Statistics of the same sizes: pt_guide_stats_new reads a guide's node
     * counts only. */
    pt_guide shape = {0};
    shape.nsnode = j->gstats->nsnode;
    shape.nqnode = j->gstats->nqnode;
    if (pt_guide_stats_new(&shape, &c->gstats, NULL) != PT_OK || !c->gpack[k])
        return -1;
    memcpy(c->gpack[k], j->gpack[k], j->gplen[k]);
    pt_guide_stats_merge(c->gstats, j->gstats, NULL);
    return 0;
}

int srv_job_guide_bytes(const srv_job *j, const uint8_t hash[32], const uint8_t **data, size_t *len)
{
    for (uint32_t k = 0; j->p.guiding && k <= j->gpass && k <= PROTO_MAX_GUIDE_PASS; k++)
        if (j->gpack[k] && memcmp(j->ghash[k], hash, 32) == 0) {
            *data = j->gpack[k];
            *len = j->gplen[k];
            return 1;
        }
    return 0;
}

uint32_t srv_job_guide_pass(const srv_job *j)
{
    return j->p.guiding ? j->gpass : 0;
}
