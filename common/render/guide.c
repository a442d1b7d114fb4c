/*
 * guide.c - the SD-tree of path guiding (guide.h): lookup, sampling and pdf,
 * statistics, and the build of the next pass's tree.
 */
#include "common/render/guide.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/options.h"
#include "common/scene/scene.h"

#define PI_F 3.14159265358979323846f
#define ONE_BELOW 0x1.fffffep-1f

void pt_guide_free(pt_guide *g)
{
    if (!g)
        return;
    pt_free(g->snode);
    pt_free(g->qnode);
    pt_free(g);
}

static pt_guide *guide_alloc(uint32_t nsnode, uint32_t nqnode)
{
    pt_guide *g = pt_calloc(1, sizeof *g);
    if (!g)
        return NULL;
    g->nsnode = nsnode;
    g->nqnode = nqnode;
    g->snode = pt_calloc(nsnode, sizeof *g->snode);
    g->qnode = pt_calloc(nqnode, sizeof *g->qnode);
    if (!g->snode || !g->qnode) {
        pt_guide_free(g);
        return NULL;
    }
    return g;
}

pt_status pt_guide_new_uniform(pt_vec3 lo, pt_vec3 hi, pt_guide **out, pt_error *err)
{
    if (!pt_isfinite3(lo) || !pt_isfinite3(hi) || !(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z))
        return pt_error_set(err, PT_ERR_ARG, "guide bounds are not finite and ordered");
    /* Each face's tree complete to PT_GUIDE_INIT_DEPTH, breadth first, so
     * the first pass records at that resolution; roots 0 (not learned). */
    uint32_t per = 0, level = 1;
    for (uint32_t d = 0; d <= PT_GUIDE_INIT_DEPTH; d++, level *= 4)
        per += level;
    pt_guide *g = guide_alloc(1, PT_GUIDE_FACES * per);
    if (!g)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a guide");
    g->lo = lo;
    g->hi = hi;
    uint32_t next = PT_GUIDE_FACES;
    for (uint32_t f = 0; f < PT_GUIDE_FACES; f++) {
        g->qnode[f].energy = 0.0f;
        /* The nodes of this tree in breadth-first order: node k's children
         * are the next four unassigned. */
        uint32_t lvl_start[PT_GUIDE_INIT_DEPTH + 1], lvl_n[PT_GUIDE_INIT_DEPTH + 1];
        lvl_start[0] = f;
        lvl_n[0] = 1;
        for (uint32_t d = 1; d <= PT_GUIDE_INIT_DEPTH; d++) {
            lvl_start[d] = next;
            lvl_n[d] = lvl_n[d - 1] * 4;
            for (uint32_t k = 0; k < lvl_n[d - 1]; k++) {
                uint32_t parent = d == 1 ? lvl_start[0] : lvl_start[d - 1] + k;
                g->qnode[parent].child = next;
                for (uint32_t c = 0; c < 4; c++)
                    g->qnode[next + c].energy = 1.0f;
                next += 4;
            }
        }
    }
    *out = g;
    return PT_OK;
}

static float clamp_below1(float x)
{
    return x >= 0.0f ? (x < 1.0f ? x : ONE_BELOW) : 0.0f;
}

void pt_guide_dir_to_square(pt_vec3 dir, float *u, float *v)
{
    float z = dir.z < -1.0f ? -1.0f : (dir.z > 1.0f ? 1.0f : dir.z);
    float phi = atan2f(dir.y, dir.x) * (0.5f / PI_F);
    if (phi < 0.0f)
        phi += 1.0f;
    *u = clamp_below1(0.5f * (z + 1.0f));
    *v = clamp_below1(phi);
}

pt_vec3 pt_guide_square_to_dir(float u, float v)
{
    float z = 2.0f * u - 1.0f;
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    float phi = 2.0f * PI_F * v;
    return pt_v3(r * cosf(phi), r * sinf(phi), z);
}

/* The face of the cube that n points to: 0..5 for +x, -x, +y, -y, +z, -z. */
static uint32_t face_of(pt_vec3 n)
{
    float ax = fabsf(n.x), ay = fabsf(n.y), az = fabsf(n.z);
    if (ax >= ay && ax >= az)
        return n.x >= 0.0f ? 0u : 1u;
    if (ay >= az)
        return n.y >= 0.0f ? 2u : 3u;
    return n.z >= 0.0f ? 4u : 5u;
}

uint32_t pt_guide_cell(const pt_guide *g, pt_vec3 p, pt_vec3 n)
{
    return pt_guide_leaf(g, p) * PT_GUIDE_FACES + face_of(n);
}

/* The root of cell's quadtree. */
static uint32_t cell_root(const pt_guide *g, uint32_t cell)
{
    return g->snode[cell / PT_GUIDE_FACES].tree + cell % PT_GUIDE_FACES;
}

void pt_guide_prefetch(const pt_guide *g, uint32_t cell)
{
    __builtin_prefetch(&g->qnode[cell_root(g, cell)]);
}

int pt_guide_learned(const pt_guide *g, uint32_t cell)
{
    return g->qnode[cell_root(g, cell)].energy > 0.0f;
}

/* The walk down to p's spatial leaf; inlined, what a caller drops of depth
 * and extent costs nothing. Branch-free: which side of a split a point lies
 * on is a coin toss to the branch predictor, and the bounds stay in
 * registers (selected by axis, not indexed), so each level is a few
 * dependent selects rather than a mispredicted branch and a store reloaded. */
static inline uint32_t leaf_walk(const pt_guide *g, pt_vec3 p, uint32_t *depth, pt_vec3 *extent)
{
    float lx = g->lo.x, ly = g->lo.y, lz = g->lo.z, hx = g->hi.x, hy = g->hi.y, hz = g->hi.z;
    uint32_t n = 0, d = 0;
    const pt_guide_snode *sn = g->snode;
    while (sn[n].child) {
        uint32_t a = sn[n].axis;
        float lo = a == 0 ? lx : (a == 1 ? ly : lz);
        float hi = a == 0 ? hx : (a == 1 ? hy : hz);
        float q = a == 0 ? p.x : (a == 1 ? p.y : p.z);
        float mid = 0.5f * (lo + hi);
        uint32_t right = !(q < mid);
        float nlo = right ? mid : lo, nhi = right ? hi : mid;
        lx = a == 0 ? nlo : lx;
        ly = a == 1 ? nlo : ly;
        lz = a == 2 ? nlo : lz;
        hx = a == 0 ? nhi : hx;
        hy = a == 1 ? nhi : hy;
        hz = a == 2 ? nhi : hz;
        n = sn[n].child + right;
        d++;
    }
    *depth = d;
    *extent = pt_v3(hx - lx, hy - ly, hz - lz);
    return n;
}

uint32_t pt_guide_leaf(const pt_guide *g, pt_vec3 p)
{
    uint32_t d;
    pt_vec3 e;
    return leaf_walk(g, p, &d, &e);
}

uint32_t pt_guide_leaf_box(const pt_guide *g, pt_vec3 p, uint32_t *depth, pt_vec3 *extent)
{
    return leaf_walk(g, p, depth, extent);
}

/* The probability the sampler picks quadrant q of a node with children
 * energies e: its column's, then its row's within the column, which is
 * e[q] over their sum (a node with none: 1/4). The sampler reports it and
 * the pdf computes it alike, one division a level. */
static float quadrant_prob(const float e[4], uint32_t q)
{
    float tot = (e[0] + e[2]) + (e[1] + e[3]);
    if (!(tot > 0.0f) || !isfinite(tot))
        return 0.25f;
    return e[q] / tot;
}

static void child_energies(const pt_guide *g, uint32_t c, float e[4])
{
    for (int i = 0; i < 4; i++)
        e[i] = g->qnode[c + (uint32_t)i].energy;
}

pt_vec3 pt_guide_sample(const pt_guide *g, uint32_t cell, const float u[2], float *pdf)
{
    uint32_t n = cell_root(g, cell);
    float ux = clamp_below1(u[0]), uy = clamp_below1(u[1]);
    float x0 = 0.0f, y0 = 0.0f, size = 1.0f, prob = 1.0f;
    while (g->qnode[n].child) {
        uint32_t c = g->qnode[n].child;
        float e[4];
        child_energies(g, c, e);
        /* The next level's nodes, whichever child is taken: their fetch
         * (a large guide's nodes are far apart) overlaps this level's
         * divisions instead of following them. */
        for (uint32_t i = 0; i < 4; i++)
            __builtin_prefetch(&g->qnode[g->qnode[c + i].child]);
        /* The column by its energy, then the row within the column taken
         * (a node whose children have no energy, or a column with none,
         * splits in halves); only the row split of that column is divided
         * out, the level's one dependent division. */
        float left = e[0] + e[2], right = e[1] + e[3], tot = left + right;
        int flat = !(tot > 0.0f) || !isfinite(tot);
        float px = flat ? 0.5f : left / tot;
        uint32_t qx, qy;
        if (ux < px) {
            qx = 0;
            ux = clamp_below1(ux / px);
        } else {
            qx = 1;
            ux = clamp_below1((ux - px) / (1.0f - px));
        }
        float col = qx ? right : left;
        float py = flat || !(col > 0.0f) ? 0.5f : e[qx] / col;
        if (uy < py) {
            qy = 0;
            uy = clamp_below1(uy / py);
        } else {
            qy = 1;
            uy = clamp_below1((uy - py) / (1.0f - py));
        }
        prob *= quadrant_prob(e, qx + 2 * qy);
        size *= 0.5f;
        x0 += (float)qx * size;
        y0 += (float)qy * size;
        n = c + qx + 2 * qy;
    }
    *pdf = prob / (size * size) * (0.25f / PI_F);
    return pt_guide_square_to_dir(x0 + ux * size, y0 + uy * size);
}

/* The quadtree leaf of g's tree rooted at n that holds (u, v). With prob,
 * also the probability the sampler reaches it with (*prob) and its square's
 * side (*size); without, a record's walk that reads no energies and
 * divides nothing. *depth its depth unless NULL. Inlined at each caller,
 * so the NULLs cost nothing. */
static inline uint32_t find_qleaf(const pt_guide *g, uint32_t n, float u, float v, float *prob,
                                  float *size, uint32_t *depth)
{
    float x0 = 0.0f, y0 = 0.0f, s = 1.0f, p = 1.0f;
    uint32_t d = 0;
    while (g->qnode[n].child) {
        uint32_t c = g->qnode[n].child;
        s *= 0.5f;
        uint32_t qx = u >= x0 + s, qy = v >= y0 + s;
        if (prob) {
            float e[4];
            child_energies(g, c, e);
            p *= quadrant_prob(e, qx + 2 * qy);
        }
        x0 += (float)qx * s;
        y0 += (float)qy * s;
        n = c + qx + 2 * qy;
        d++;
    }
    if (prob) {
        *prob = p;
        *size = s;
    }
    if (depth)
        *depth = d;
    return n;
}

uint32_t pt_guide_qleaf(const pt_guide *g, uint32_t cell, pt_vec3 dir, uint32_t *depth)
{
    float u, v;
    pt_guide_dir_to_square(dir, &u, &v);
    return find_qleaf(g, cell_root(g, cell), u, v, NULL, NULL, depth);
}

float pt_guide_pdf_leaf(const pt_guide *g, uint32_t cell, pt_vec3 dir, uint32_t *qleaf)
{
    float u, v, prob, size;
    pt_guide_dir_to_square(dir, &u, &v);
    *qleaf = find_qleaf(g, cell_root(g, cell), u, v, &prob, &size, NULL);
    return prob / (size * size) * (0.25f / PI_F);
}

float pt_guide_pdf(const pt_guide *g, uint32_t cell, pt_vec3 dir)
{
    uint32_t leaf;
    return pt_guide_pdf_leaf(g, cell, dir, &leaf);
}

/* ---- statistics ---------------------------------------------------------- */

pt_status pt_guide_stats_new(const pt_guide *g, pt_guide_stats **out, pt_error *err)
{
    pt_guide_stats *s = pt_calloc(1, sizeof *s);
    if (!s)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for guiding statistics");
    s->nsnode = g->nsnode;
    s->nqnode = g->nqnode;
    s->count = pt_calloc(g->nsnode, sizeof *s->count);
    s->sum = pt_calloc(g->nqnode, sizeof *s->sum);
    if (!s->count || !s->sum) {
        pt_guide_stats_free(s);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for guiding statistics");
    }
    *out = s;
    return PT_OK;
}

void pt_guide_stats_free(pt_guide_stats *s)
{
    if (!s)
        return;
    pt_free(s->count);
    pt_free(s->sum);
    pt_free(s);
}

static uint64_t sat_add(uint64_t a, uint64_t b)
{
    uint64_t r;
    return __builtin_add_overflow(a, b, &r) ? UINT64_MAX : r;
}

/* The fixed-point value of a record (value >= 0, finite). */
static uint64_t record_fixed(float value)
{
    double v = value < PT_GUIDE_MAX_RECORD ? (double)value : PT_GUIDE_MAX_RECORD;
    return (uint64_t)(v * (double)(1u << PT_GUIDE_FIXED_BITS) + 0.5);
}

void pt_guide_stats_record(pt_guide_stats *s, const pt_guide *g, uint32_t cell, pt_vec3 dir,
                           float value)
{
    uint32_t n = 0; /* read only for a value above 0 */
    if (value > 0.0f && isfinite(value))
        n = pt_guide_qleaf(g, cell, dir, NULL);
    pt_guide_stats_add(s, cell, n, value);
}

void pt_guide_stats_add(pt_guide_stats *s, uint32_t cell, uint32_t qleaf, float value)
{
    if (!(value >= 0.0f) || !isfinite(value))
        return;
    uint32_t leaf = cell / PT_GUIDE_FACES;
    s->count[leaf] = sat_add(s->count[leaf], 1);
    if (value > 0.0f)
        s->sum[qleaf] = sat_add(s->sum[qleaf], record_fixed(value));
}

pt_status pt_guide_stats_merge(pt_guide_stats *into, const pt_guide_stats *from, pt_error *err)
{
    if (into->nsnode != from->nsnode || into->nqnode != from->nqnode)
        return pt_error_set(err, PT_ERR_ARG,
                            "guiding statistics for %u+%u nodes cannot merge into %u+%u",
                            from->nsnode, from->nqnode, into->nsnode, into->nqnode);
    for (uint32_t i = 0; i < into->nsnode; i++)
        into->count[i] = sat_add(into->count[i], from->count[i]);
    for (uint32_t i = 0; i < into->nqnode; i++)
        into->sum[i] = sat_add(into->sum[i], from->sum[i]);
    return PT_OK;
}

/* ---- building ------------------------------------------------------------ */

typedef struct builder {
    pt_guide_snode *snode;
    pt_guide_qnode *qnode;
    uint32_t ns, nq, cap_s, cap_q;
    int nomem;
} builder;

static int grow(void **arr, uint32_t *cap, uint32_t need, size_t elem)
{
    if (need <= *cap)
        return 1;
    uint32_t nc = *cap ? *cap : 64;
    while (nc < need)
        nc = nc > PT_GUIDE_MAX_NODES / 2 ? PT_GUIDE_MAX_NODES : nc * 2;
    if (need > nc)
        return 0;
    void *p = pt_realloc(*arr, (size_t)nc * elem);
    if (!p)
        return 0;
    memset((char *)p + (size_t)*cap * elem, 0, (size_t)(nc - *cap) * elem);
    *arr = p;
    *cap = nc;
    return 1;
}

static uint32_t new_qnodes(builder *b, uint32_t k)
{
    if (b->nomem || !grow((void **)&b->qnode, &b->cap_q, b->nq + k, sizeof *b->qnode)) {
        b->nomem = 1;
        return 0;
    }
    uint32_t first = b->nq;
    b->nq += k;
    return first;
}

/* E(node) over the old tree rooted at n: the fixed-point sums of its leaves
 * (recursion at most PT_GUIDE_MAX_DEPTH deep). */
static double sum_energy(const pt_guide *g, const pt_guide_stats *s, uint32_t n, double *E,
                         int from_stats, uint32_t depth)
{
    double e;
    uint32_t c = g->qnode[n].child;
    if (!c || depth >= PT_GUIDE_MAX_DEPTH)
        e = from_stats ? (double)s->sum[n] : (double)g->qnode[n].energy;
    else
        e = sum_energy(g, s, c, E, from_stats, depth + 1) +
            sum_energy(g, s, c + 1, E, from_stats, depth + 1) +
            sum_energy(g, s, c + 2, E, from_stats, depth + 1) +
            sum_energy(g, s, c + 3, E, from_stats, depth + 1);
    E[n] = e;
    return e;
}

/* Builds the new node at index at for the square of old node n (divisor: a
 * square inside old leaf n at a finer depth has E(n) / divisor), depth
 * levels down; subdivides while its share of total is above the threshold. */
static void build_q(builder *b, const pt_guide *g, const double *E, uint32_t n, double divisor,
                    uint32_t at, uint32_t depth, double total)
{
    double e = E[n] / divisor;
    b->qnode[at].energy = (float)(total > 0.0 ? e / total : 0.0);
    b->qnode[at].child = 0;
    if (!(total > 0.0) || depth >= PT_GUIDE_MAX_DEPTH || !(e / total > PT_GUIDE_SUBDIV_SHARE))
        return;
    uint32_t c = new_qnodes(b, 4);
    if (b->nomem)
        return;
    b->qnode[at].child = c;
    uint32_t oc = g->qnode[n].child;
    for (uint32_t i = 0; i < 4; i++) {
        if (oc)
            build_q(b, g, E, oc + i, 1.0, c + i, depth + 1, total);
        else
            build_q(b, g, E, n, divisor * 4.0, c + i, depth + 1, total);
    }
}

/* Copies the new tree's subtree at src into node dst (allocated), its
 * descendants into new nodes. */
static void copy_q(builder *b, uint32_t src, uint32_t dst)
{
    b->qnode[dst] = b->qnode[src];
    uint32_t sc = b->qnode[src].child;
    if (!sc)
        return;
    uint32_t c = new_qnodes(b, 4);
    if (b->nomem)
        return;
    b->qnode[dst].child = c;
    for (uint32_t i = 0; i < 4 && !b->nomem; i++)
        copy_q(b, sc + i, c + i);
}

/* Makes new spatial node at a subtree `levels` deep split at the midpoints
 * (axes cycling from axis), whose leaves hold tree q (the first) and copies
 * of it (the others; first: q is not yet used). */
static void split_leaf(builder *b, uint32_t at, uint32_t axis, uint32_t levels, uint32_t q,
                       int first)
{
    if (levels == 0) {
        b->snode[at].child = 0;
        b->snode[at].axis = axis; /* the axis its next split takes */
        if (first) {
            b->snode[at].tree = q;
            return;
        }
        uint32_t t = new_qnodes(b, PT_GUIDE_FACES);
        for (uint32_t f = 0; f < PT_GUIDE_FACES && !b->nomem; f++)
            copy_q(b, q + f, t + f);
        b->snode[at].tree = t;
        return;
    }
    if (!grow((void **)&b->snode, &b->cap_s, b->ns + 2, sizeof *b->snode)) {
        b->nomem = 1;
        return;
    }
    uint32_t c = b->ns;
    b->ns += 2;
    b->snode[at].child = c;
    b->snode[at].axis = axis;
    b->snode[at].tree = 0;
    split_leaf(b, c, (axis + 1) % 3, levels - 1, q, first);
    if (!b->nomem)
        split_leaf(b, c + 1, (axis + 1) % 3, levels - 1, q, 0);
}

pt_status pt_guide_build(const pt_guide *g, const pt_guide_stats *s, uint64_t split_count,
                         pt_guide **out, pt_error *err)
{
    if (s->nsnode != g->nsnode || s->nqnode != g->nqnode)
        return pt_error_set(err, PT_ERR_ARG, "guiding statistics were made for another guide");
    builder b;
    memset(&b, 0, sizeof b);
    double *E = pt_malloc_array(g->nqnode, sizeof *E);
    uint32_t *depth = pt_calloc(g->nsnode, sizeof *depth);
    uint32_t *map = pt_calloc(g->nsnode, sizeof *map);
    pt_guide *ng = NULL;
    if (!E || !depth || !map)
        goto nomem;
    /* The spatial tree: old nodes in index order (children after parents),
     * each mapped to its new index; a leaf over the split count and above
     * the depth cap becomes a node with two leaves. */
    if (!grow((void **)&b.snode, &b.cap_s, 1, sizeof *b.snode))
        goto nomem;
    b.ns = 1;
    map[0] = 0;
    for (uint32_t i = 0; i < g->nsnode; i++) {
        uint32_t ni = map[i];
        const pt_guide_snode *o = &g->snode[i];
        if (o->child) {
            uint32_t c = b.ns;
            if (!grow((void **)&b.snode, &b.cap_s, b.ns + 2, sizeof *b.snode))
                goto nomem;
            b.ns += 2;
            b.snode[ni].child = c;
            b.snode[ni].axis = o->axis;
            map[o->child] = c;
            map[o->child + 1] = c + 1;
            depth[o->child] = depth[o->child + 1] = depth[i] + 1;
            continue;
        }
        /* A leaf: its rebuilt quadtree, from the pass's energies (or, with
         * none recorded, from the distribution it sampled). */
        uint32_t q = new_qnodes(&b, PT_GUIDE_FACES);
        if (b.nomem)
            goto nomem;
        for (uint32_t f = 0; f < PT_GUIDE_FACES; f++) {
            /* From the pass's records; a cell none reached keeps the
             * distribution it had, learned or not (root energy 0). */
            uint32_t root = g->snode[i].tree + f;
            double total = sum_energy(g, s, root, E, 1, 0);
            int learned = total > 0.0;
            if (!learned) {
                learned = g->qnode[root].energy > 0.0f;
                total = sum_energy(g, s, root, E, 0, 0);
            }
            build_q(&b, g, E, root, 1.0, q + f, 0, total);
            if (b.nomem)
                goto nomem;
            b.qnode[q + f].energy = learned ? 1.0f : 0.0f;
        }
        /* Split while a part's share of the records (halved each level,
         * as Mueller et al. assume) is over the split count. */
        uint32_t levels = 0;
        for (uint64_t c = s->count[i]; c > split_count && levels < PT_GUIDE_MAX_SPLIT_LEVELS &&
                                       depth[i] + levels < PT_GUIDE_MAX_SPATIAL_DEPTH;
             c /= 2)
            levels++;
        split_leaf(&b, ni, o->axis, levels, q, 1);
        if (b.nomem)
            goto nomem;
    }
    ng = guide_alloc(b.ns, b.nq);
    if (!ng)
        goto nomem;
    ng->lo = g->lo;
    ng->hi = g->hi;
    memcpy(ng->snode, b.snode, (size_t)b.ns * sizeof *b.snode);
    memcpy(ng->qnode, b.qnode, (size_t)b.nq * sizeof *b.qnode);
    pt_free(b.snode);
    pt_free(b.qnode);
    pt_free(E);
    pt_free(depth);
    pt_free(map);
    *out = ng;
    return PT_OK;
nomem:
    pt_free(b.snode);
    pt_free(b.qnode);
    pt_free(E);
    pt_free(depth);
    pt_free(map);
    return pt_error_set(err, PT_ERR_NOMEM, "out of memory (or past %u nodes) building a guide",
                        PT_GUIDE_MAX_NODES);
}

/* ---- passes and the auto rule --------------------------------------------- */

uint32_t pt_guide_pass_end(uint32_t k, uint32_t spp)
{
    if (k >= 26)
        return spp;
    uint64_t end = 16ull * ((1ull << (k + 1)) - 1), next = 16ull << (k + 1);
    if (end >= spp || (uint64_t)spp - end < next)
        return spp;
    return (uint32_t)end;
}

int pt_guide_pass_last(uint32_t k, uint32_t spp)
{
    return pt_guide_pass_end(k, spp) >= spp;
}

int pt_guide_auto(const pt_scene *scene)
{
    return (scene->features & (PT_FEAT_TRANSMISSION | PT_FEAT_DIFFUSE_TRANSMISSION)) != 0;
}

int pt_guide_enabled(uint32_t mode, const pt_scene *scene)
{
    if (mode == PT_GUIDING_ON)
        return (scene->features & PT_FEAT_GLOSSY) != 0;
    return mode == PT_GUIDING_AUTO && pt_guide_auto(scene);
}

/* ---- checking ------------------------------------------------------------ */

pt_status pt_guide_check(const pt_guide *g, pt_error *err)
{
    if (!g->nsnode || g->nqnode < PT_GUIDE_FACES || g->nsnode > PT_GUIDE_MAX_NODES ||
        g->nqnode > PT_GUIDE_MAX_NODES)
        return pt_error_set(err, PT_ERR_FORMAT, "guide has %u spatial and %u directional nodes",
                            g->nsnode, g->nqnode);
    if (!pt_isfinite3(g->lo) || !pt_isfinite3(g->hi) ||
        !(g->lo.x <= g->hi.x && g->lo.y <= g->hi.y && g->lo.z <= g->hi.z))
        return pt_error_set(err, PT_ERR_FORMAT, "guide bounds are not finite and ordered");
    pt_status st = PT_OK;
    uint8_t *seen_s = pt_calloc(g->nsnode, 1), *seen_q = pt_calloc(g->nqnode, 1);
    uint8_t *sdepth = pt_calloc(g->nsnode, 1), *qdepth = pt_calloc(g->nqnode, 1);
    if (!seen_s || !seen_q || !sdepth || !qdepth) {
        st = pt_error_set(err, PT_ERR_NOMEM, "out of memory checking a guide");
        goto done;
    }
    /* Children after their parent and referenced once: node 0 is the only
     * root, so every node is reached once, in index order. */
    seen_s[0] = 1;
    for (uint32_t i = 0; i < g->nsnode; i++) {
        const pt_guide_snode *n = &g->snode[i];
        if (!seen_s[i]) {
            st = pt_error_set(err, PT_ERR_FORMAT, "guide spatial node %u is not in the tree", i);
            goto done;
        }
        if (n->child) {
            if (n->child <= i || n->child >= g->nsnode - 1 || seen_s[n->child] ||
                seen_s[n->child + 1] || n->axis > 2 || sdepth[i] >= PT_GUIDE_MAX_SPATIAL_DEPTH) {
                st = pt_error_set(err, PT_ERR_FORMAT, "guide spatial node %u: bad children", i);
                goto done;
            }
            seen_s[n->child] = seen_s[n->child + 1] = 1;
            sdepth[n->child] = sdepth[n->child + 1] = (uint8_t)(sdepth[i] + 1);
        } else {
            int bad = n->tree > g->nqnode - PT_GUIDE_FACES;
            for (uint32_t f = 0; !bad && f < PT_GUIDE_FACES; f++)
                bad = seen_q[n->tree + f];
            if (bad) {
                st = pt_error_set(err, PT_ERR_FORMAT, "guide spatial leaf %u: bad trees at %u", i,
                                  n->tree);
                goto done;
            }
            for (uint32_t f = 0; f < PT_GUIDE_FACES; f++)
                seen_q[n->tree + f] = 1;
        }
    }
    for (uint32_t i = 0; i < g->nqnode; i++) {
        const pt_guide_qnode *n = &g->qnode[i];
        if (!seen_q[i]) {
            st = pt_error_set(err, PT_ERR_FORMAT, "guide directional node %u is not in a tree", i);
            goto done;
        }
        if (!(n->energy >= 0.0f) || !isfinite(n->energy)) {
            st = pt_error_set(err, PT_ERR_FORMAT, "guide directional node %u: energy %g", i,
                              (double)n->energy);
            goto done;
        }
        if (!n->child)
            continue;
        if (n->child <= i || n->child > g->nqnode - 4 || qdepth[i] >= PT_GUIDE_MAX_DEPTH) {
            st = pt_error_set(err, PT_ERR_FORMAT, "guide directional node %u: bad children", i);
            goto done;
        }
        for (uint32_t k = 0; k < 4; k++) {
            if (seen_q[n->child + k]) {
                st = pt_error_set(err, PT_ERR_FORMAT, "guide directional node %u: shared child", i);
                goto done;
            }
            seen_q[n->child + k] = 1;
            qdepth[n->child + k] = (uint8_t)(qdepth[i] + 1);
        }
    }
done:
    pt_free(seen_s);
    pt_free(seen_q);
    pt_free(sdepth);
    pt_free(qdepth);
    return st;
}
