/*
 * light_tree.c - the light hierarchy of light_tree.h: build (binned SAOH),
 * importance, sampling and the pmf of a given light.
 *
 * Orientation bounds: a cone (axis, half-angle theta_o) holds every emitting
 * normal of a node; emission reaches theta_e = pi/2 beyond it. Two cones are
 * merged into the smallest cone around both found by rotating the wider one's
 * axis towards the other (the construction of Conty & Kulla 2018, sec. 4.1).
 * The cost of a cluster (their eq. 1-2) is power x surface area x M_Omega,
 * M_Omega = 2 pi (1 - cos theta_o)
 *         + pi/2 (2 theta_w sin theta_o - cos(theta_o - 2 theta_w)
 *                 - 2 theta_o sin theta_o + cos theta_o),
 * theta_w = min(theta_o + theta_e, pi), the measure of directions the cluster
 * emits into weighted by cosine; a split's cost is the two sides' sum times
 * K_r = (longest extent of the node) / (extent along the split axis), which
 * keeps clusters from growing thin.
 */
#include "common/render/light_tree.h"

#include <math.h>
#include <string.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "common/base/alloc.h"

#define BUCKETS 12
/* From this depth on a node is split in half by count: the leaves below it
 * are then at most log2(PT_LIGHT_TREE_MAX) = 26 deeper, within the 64
 * branch bits. */
#define FORCE_MEDIAN_DEPTH 36u
#define PI_D 3.14159265358979323846

/* A node whose normals lie within acos(COARSE_COS) of its axis and whose
 * bounding sphere is seen from p under less than asin(1 / COARSE_RATIO) is
 * "coarse" there: its lights would all get about the same importance per
 * unit of power, so the walk stops and chooses among them by power (a
 * binary search of the cumulative power over the leaves' order, where each
 * subtree's lights are contiguous). On a smooth emitter of thousands of
 * triangles this ends the walk many levels early. */
#define COARSE_COS 0.9f
#define COARSE_RATIO 8.0f

/* One node, 32 bytes, so that the pair of children the walk reads is one
 * cache line: the pairs start at even places of a 64-byte aligned array
 * (the root is node 0, node 1 is unused). The box is kept as its centre and
 * the sphere around it (radius r): a point inside the box is inside the
 * sphere. The cone's axis and cosine are quantized to 16 bits, the cone
 * widened by the rounding so that it still holds every emitting normal
 * (node_store): the bound stays conservative, only a little looser. The
 * lights of a node (its place in the leaves' order) are read only when the
 * walk stops at a coarse node, so they sit apart, in span. */
typedef struct lt_node {
    float center[3];
    float r; /* half its diagonal */
    float power;
    uint32_t next;   /* inner: the left child (the right one follows); leaf: the light;
                      * and LT_LEAF, LT_TWO_SIDED in the top bits */
    int16_t axis[3]; /* the cone's axis x 32767 (not quite unit: see node_store) */
    int16_t cos_o;   /* cosine of the cone's half-angle x 32767, rounded down */
} lt_node;
_Static_assert(sizeof(lt_node) == 32, "a pair of nodes is one cache line");
#define LT_LEAF 0x80000000u
#define LT_TWO_SIDED 0x40000000u
#define LT_INDEX 0x3fffffffu
#define Q16 32767.0f
/* The most the quantized axis's direction and length move cos theta_w
 * (node_store), as an angle the cone is widened by: the axis's direction
 * is within 3e-5 rad of the true one, its length within 5e-5 of 1. */
#define AXIS_SLACK 1e-3

/* A node's lights: order[first .. first + count). */
typedef struct lt_span {
    uint32_t first, count;
} lt_span;

struct pt_light_tree {
    uint32_t n, nodes_used, depth;
    lt_node *nodes; /* 2n, 64-byte aligned in nodes_mem */
    void *nodes_mem;
    lt_span *span;   /* per node */
    uint64_t *bits;  /* per light: its branch bits, root's first (1 = right) */
    uint8_t *levels; /* per light: its leaf's depth */
    uint32_t *order; /* the lights in leaf order */
    uint32_t *rank;  /* per light: its place in order */
    double *cdf;     /* n + 1: cumulative power over order */
    uint32_t ranked; /* while building */
};

/* A cluster while building: box, cone (in double), power. */
typedef struct cluster {
    double lo[3], hi[3];
    double axis[3];
    double theta_o; /* half-angle, [0, pi]; negative: empty cone */
    double power;
    int two_sided;
} cluster;

static void cluster_empty(cluster *c)
{
    for (int i = 0; i < 3; i++) {
        c->lo[i] = INFINITY;
        c->hi[i] = -INFINITY;
        c->axis[i] = 0.0;
    }
    c->axis[2] = 1.0;
    c->theta_o = -1.0;
    c->power = 0.0;
    c->two_sided = 0;
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* The smallest cone (by this construction) holding cones a and b, into a. */
static void cone_union(double a_axis[3], double *a_theta, const double b_axis[3], double b_theta)
{
    if (b_theta < 0.0)
        return;
    if (*a_theta < 0.0) {
        memcpy(a_axis, b_axis, 3 * sizeof *a_axis);
        *a_theta = b_theta;
        return;
    }
    double wa[3], wb[3], ta, tb;
    if (b_theta > *a_theta) { /* wa: the wider */
        memcpy(wa, b_axis, sizeof wa);
        memcpy(wb, a_axis, sizeof wb);
        ta = b_theta;
        tb = *a_theta;
    } else {
        memcpy(wa, a_axis, sizeof wa);
        memcpy(wb, b_axis, sizeof wb);
        ta = *a_theta;
        tb = b_theta;
    }
    double c = dot3(wa, wb);
    double td = acos(c < -1.0 ? -1.0 : c > 1.0 ? 1.0 : c);
    if (fmin(td + tb, PI_D) <= ta) {
        memcpy(a_axis, wa, sizeof wa);
        *a_theta = ta;
        return;
    }
    double to = 0.5 * (ta + td + tb);
    /* k x wa with k = wa x wb / |wa x wb|: (wb - wa cos td) / sin td, the
     * direction in the plane of both axes towards wb. */
    double t[3] = {wb[0] - wa[0] * c, wb[1] - wa[1] * c, wb[2] - wa[2] * c};
    double tl = sqrt(dot3(t, t));
    if (to >= PI_D || !(tl > 1e-12)) { /* all around, or opposite axes */
        memcpy(a_axis, wa, sizeof wa);
        *a_theta = PI_D;
        return;
    }
    double rot = to - ta, cr = cos(rot), sr = sin(rot);
    double ax[3];
    for (int i = 0; i < 3; i++)
        ax[i] = wa[i] * cr + t[i] / tl * sr;
    double al = sqrt(dot3(ax, ax));
    for (int i = 0; i < 3; i++)
        a_axis[i] = ax[i] / al;
    *a_theta = to;
}

static void cluster_add(cluster *c, const cluster *o)
{
    for (int i = 0; i < 3; i++) {
        c->lo[i] = fmin(c->lo[i], o->lo[i]);
        c->hi[i] = fmax(c->hi[i], o->hi[i]);
    }
    cone_union(c->axis, &c->theta_o, o->axis, o->theta_o);
    c->power += o->power;
    c->two_sided |= o->two_sided;
}

static void cluster_of(const pt_light_tree_item *it, cluster *c)
{
    c->lo[0] = it->lo.x;
    c->lo[1] = it->lo.y;
    c->lo[2] = it->lo.z;
    c->hi[0] = it->hi.x;
    c->hi[1] = it->hi.y;
    c->hi[2] = it->hi.z;
    c->axis[0] = it->axis.x;
    c->axis[1] = it->axis.y;
    c->axis[2] = it->axis.z;
    double co = it->cos_o < -1.0f ? -1.0 : it->cos_o > 1.0f ? 1.0 : (double)it->cos_o;
    c->theta_o = acos(co);
    c->power = it->power;
    c->two_sided = it->two_sided != 0;
}

/* M_Omega of the top of the file. */
static double orientation_measure(double theta_o)
{
    if (theta_o < 0.0)
        return 0.0;
    double tw = fmin(theta_o + 0.5 * PI_D, PI_D), so = sin(theta_o), co = cos(theta_o);
    return 2.0 * PI_D * (1.0 - co) +
           0.5 * PI_D * (2.0 * tw * so - cos(theta_o - 2.0 * tw) - 2.0 * theta_o * so + co);
}

static double surface_area(const cluster *c)
{
    double e[3];
    for (int i = 0; i < 3; i++)
        e[i] = c->hi[i] > c->lo[i] ? c->hi[i] - c->lo[i] : 0.0;
    return 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]);
}

static double cluster_cost(const cluster *c)
{
    if (c->power <= 0.0)
        return 0.0;
    return c->power * orientation_measure(c->theta_o) * surface_area(c);
}

typedef struct builder {
    const pt_light_tree_item *items;
    const cluster *leaf; /* per item */
    double (*centroid)[3];
    uint32_t *perm, *tmp;
    pt_light_tree *t;
} builder;

static void node_store(lt_node *nd, const cluster *c)
{
    double d2 = 0.0;
    for (int i = 0; i < 3; i++) {
        nd->center[i] = (float)(0.5 * (c->lo[i] + c->hi[i]));
        double e = c->hi[i] - c->lo[i];
        d2 += e * e;
    }
    /* The axis to 16 bits a component; the cone widened by the angle
     * between the stored axis and the true one, and by AXIS_SLACK for the
     * stored axis's length (up to 5e-5 from 1, which the walk does not
     * divide out: a change of cos theta_w of that much is an angle of at
     * most 1e-2 near theta_w = 0, where the bound is 1 anyway, and of 5e-5
     * near pi/2, where the importance drops to 0). */
    double q[3], ql = 0.0, qd = 0.0;
    for (int i = 0; i < 3; i++) {
        double a = c->axis[i] < -1.0 ? -1.0 : c->axis[i] > 1.0 ? 1.0 : c->axis[i];
        nd->axis[i] = (int16_t)lrint(a * (double)Q16);
        q[i] = (double)nd->axis[i] / (double)Q16;
        ql += q[i] * q[i];
        qd += q[i] * c->axis[i];
    }
    double cq = ql > 0.0 ? qd / sqrt(ql) : -1.0;
    double th = c->theta_o + acos(cq < -1.0 ? -1.0 : cq > 1.0 ? 1.0 : cq) + AXIS_SLACK;
    /* rounded down: the cone only grows */
    nd->cos_o = th >= PI_D ? (int16_t)-32767 : (int16_t)floor(cos(th) * (double)Q16);
    nd->power = (float)c->power;
    nd->r = (float)(0.5 * sqrt(d2));
    nd->next = c->two_sided ? LT_TWO_SIDED : 0;
}

/* Splits perm[b..e) (e - b >= 2) into [b, mid) and [mid, e), stably. */
static uint32_t split(builder *B, uint32_t b, uint32_t e, const cluster *node, uint32_t depth)
{
    uint32_t n = e - b;
    double clo[3] = {INFINITY, INFINITY, INFINITY}, chi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = b; i < e; i++) {
        const double *c = B->centroid[B->perm[i]];
        for (int a = 0; a < 3; a++) {
            clo[a] = fmin(clo[a], c[a]);
            chi[a] = fmax(chi[a], c[a]);
        }
    }
    double ext[3], emax = 0.0;
    for (int a = 0; a < 3; a++) {
        ext[a] = node->hi[a] - node->lo[a];
        emax = fmax(emax, ext[a]);
    }
    int best_axis = -1, best_split = 0;
    double best_cost = INFINITY;
    for (int a = 0; a < 3 && depth < FORCE_MEDIAN_DEPTH; a++) {
        double cext = chi[a] - clo[a];
        if (!(cext > 0.0))
            continue;
        cluster bk[BUCKETS];
        for (int k = 0; k < BUCKETS; k++)
            cluster_empty(&bk[k]);
        for (uint32_t i = b; i < e; i++) {
            uint32_t l = B->perm[i];
            int k = (int)((double)BUCKETS * (B->centroid[l][a] - clo[a]) / cext);
            k = k < 0 ? 0 : k >= BUCKETS ? BUCKETS - 1 : k;
            cluster_add(&bk[k], &B->leaf[l]);
        }
        double kr = ext[a] > 0.0 ? emax / ext[a] : 1.0;
        /* The costs of buckets [s, BUCKETS) by one sweep from the right,
         * then of [0, s) from the left. */
        double rcost[BUCKETS], rpower[BUCKETS];
        cluster acc;
        cluster_empty(&acc);
        for (int k = BUCKETS - 1; k >= 1; k--) {
            cluster_add(&acc, &bk[k]);
            rcost[k] = cluster_cost(&acc);
            rpower[k] = acc.power;
        }
        cluster_empty(&acc);
        for (int s = 1; s < BUCKETS; s++) {
            cluster_add(&acc, &bk[s - 1]);
            if (acc.power <= 0.0 || rpower[s] <= 0.0)
                continue;
            double cost = kr * (cluster_cost(&acc) + rcost[s]);
            if (cost < best_cost) {
                best_cost = cost;
                best_axis = a;
                best_split = s;
            }
        }
    }
    uint32_t mid = b;
    if (best_axis >= 0) {
        double cext = chi[best_axis] - clo[best_axis];
        uint32_t nl = 0, nr = 0;
        for (uint32_t i = b; i < e; i++) {
            uint32_t l = B->perm[i];
            int k = (int)((double)BUCKETS * (B->centroid[l][best_axis] - clo[best_axis]) / cext);
            k = k < 0 ? 0 : k >= BUCKETS ? BUCKETS - 1 : k;
            if (k < best_split)
                B->perm[b + nl++] = l;
            else
                B->tmp[nr++] = l;
        }
        memcpy(&B->perm[b + nl], B->tmp, nr * sizeof *B->tmp);
        mid = b + nl;
    }
    if (mid == b || mid == e)
        mid = b + n / 2; /* no useful split (equal centroids, or deep): by count */
    return mid;
}

/* Node id over perm[b..e), its children allocated as a pair. */
static void build(builder *B, uint32_t id, uint32_t b, uint32_t e, uint32_t depth, uint64_t bits)
{
    pt_light_tree *t = B->t;
    cluster c;
    cluster_empty(&c);
    for (uint32_t i = b; i < e; i++)
        cluster_add(&c, &B->leaf[B->perm[i]]);
    node_store(&t->nodes[id], &c);
    t->span[id].first = t->ranked;
    t->span[id].count = e - b;
    if (depth > t->depth)
        t->depth = depth;
    if (e - b == 1) {
        uint32_t l = B->perm[b];
        t->nodes[id].next |= LT_LEAF | l;
        t->bits[l] = bits;
        t->levels[l] = (uint8_t)depth;
        t->rank[l] = t->ranked;
        t->order[t->ranked++] = l;
        return;
    }
    uint32_t mid = split(B, b, e, &c, depth);
    uint32_t pair = t->nodes_used;
    t->nodes_used += 2;
    t->nodes[id].next |= pair;
    build(B, pair, b, mid, depth + 1, bits);
    build(B, pair + 1, mid, e, depth + 1, bits | (uint64_t)1 << depth);
}

static int item_ok(const pt_light_tree_item *it)
{
    const float f[] = {it->lo.x, it->lo.y,   it->lo.z,   it->hi.x,   it->hi.y,
                       it->hi.z, it->axis.x, it->axis.y, it->axis.z, it->cos_o};
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++)
        if (!isfinite(f[i]))
            return 0;
    return it->power > 0.0f && isfinite(it->power) && it->lo.x <= it->hi.x &&
           it->lo.y <= it->hi.y && it->lo.z <= it->hi.z;
}

pt_status pt_light_tree_new(const pt_light_tree_item *items, uint32_t n, pt_light_tree **out,
                            pt_error *err)
{
    _Static_assert(2 * (uint64_t)PT_LIGHT_TREE_MAX <= LT_INDEX, "node ids fit next");
    if (!items || !out || n < 2 || n > PT_LIGHT_TREE_MAX)
        return pt_error_set(err, PT_ERR_ARG, "light tree: %u lights (2 to %u)", n,
                            PT_LIGHT_TREE_MAX);
    for (uint32_t i = 0; i < n; i++)
        if (!item_ok(&items[i]))
            return pt_error_set(err, PT_ERR_ARG,
                                "light tree: light %u has no finite bounds, "
                                "cone or positive power",
                                i);
    builder B = {0};
    pt_light_tree *t = pt_calloc(1, sizeof *t);
    cluster *leaf = NULL;
    if (!t)
        goto nomem;
    t->n = n;
    /* 2n - 1 nodes from place 0, place 1 unused; two spare nodes' room to
     * align the array to a cache line */
    t->nodes_mem = pt_malloc_array(2 * (size_t)n + 2, sizeof *t->nodes);
    if (t->nodes_mem) {
        t->nodes = (lt_node *)(((uintptr_t)t->nodes_mem + 63) & ~(uintptr_t)63);
        memset(&t->nodes[1], 0, sizeof t->nodes[1]);
    }
    t->span = pt_malloc_array(2 * (size_t)n, sizeof *t->span);
    t->bits = pt_malloc_array(n, sizeof *t->bits);
    t->levels = pt_malloc_array(n, sizeof *t->levels);
    t->order = pt_malloc_array(n, sizeof *t->order);
    t->rank = pt_malloc_array(n, sizeof *t->rank);
    t->cdf = pt_malloc_array((size_t)n + 1, sizeof *t->cdf);
    leaf = pt_malloc_array(n, sizeof *leaf);
    B.centroid = pt_malloc_array(n, sizeof *B.centroid);
    B.perm = pt_malloc_array(n, sizeof *B.perm);
    B.tmp = pt_malloc_array(n, sizeof *B.tmp);
    if (!t->nodes || !t->span || !t->bits || !t->levels || !t->order || !t->rank || !t->cdf ||
        !leaf || !B.centroid || !B.perm || !B.tmp)
        goto nomem;
    for (uint32_t i = 0; i < n; i++) {
        cluster_of(&items[i], &leaf[i]);
        for (int a = 0; a < 3; a++)
            B.centroid[i][a] = 0.5 * (leaf[i].lo[a] + leaf[i].hi[a]);
        B.perm[i] = i;
    }
    B.items = items;
    B.leaf = leaf;
    B.t = t;
    t->nodes_used = 2;
    build(&B, 0, 0, n, 0, 0);
    t->cdf[0] = 0.0;
    for (uint32_t i = 0; i < n; i++)
        t->cdf[i + 1] = t->cdf[i] + (double)items[t->order[i]].power;
    pt_free(B.tmp);
    pt_free(B.perm);
    pt_free(B.centroid);
    pt_free(leaf);
    *out = t;
    return PT_OK;
nomem:
    pt_free(B.tmp);
    pt_free(B.perm);
    pt_free(B.centroid);
    pt_free(leaf);
    pt_light_tree_free(t);
    return pt_error_set(err, PT_ERR_NOMEM, "light tree: out of memory for %u lights", n);
}

void pt_light_tree_free(pt_light_tree *tree)
{
    if (!tree)
        return;
    pt_free(tree->nodes_mem);
    pt_free(tree->span);
    pt_free(tree->bits);
    pt_free(tree->levels);
    pt_free(tree->order);
    pt_free(tree->rank);
    pt_free(tree->cdf);
    pt_free(tree);
}

uint32_t pt_light_tree_nodes(const pt_light_tree *tree)
{
    return tree ? tree->nodes_used - 1 : 0; /* less the unused place 1 */
}

uint32_t pt_light_tree_depth(const pt_light_tree *tree)
{
    return tree ? tree->depth : 0;
}

/* Four floats, of which the walk uses the first two: a pair of children. */
typedef float v4f __attribute__((vector_size(16)));
typedef int32_t v4i __attribute__((vector_size(16)));

static inline v4f v4_sel(v4i m, v4f a, v4f b)
{
    return (v4f)(((v4i)a & m) | ((v4i)b & ~m));
}

static inline v4f v4_sqrt(v4f x)
{
#if defined(__SSE__)
    return (v4f)_mm_sqrt_ps((__m128)x);
#else
    for (int l = 0; l < 4; l++)
        x[l] = __builtin_sqrtf(x[l]);
    return x;
#endif
}

/* The importances of nodes g[0..3] seen from p (the top of light_tree.h)
 * into out[0..3], all four in one set of SIMD lanes: the walk is bound by
 * the square roots and divisions, four for four nodes here instead of
 * twenty. A node of zero power (the unused place 1) has importance 0. Angles are subtracted through
 * their cosines and sines: cos(a - b) = cos a cos b + sin a sin b, clamped to 1 where a <= b.
 * Inside a node's bounding sphere every direction is possible (theta' = 0) and the distance is the
 * sphere's radius. Every case is computed and the answer selected: which holds is as random as the
 * shading points. Sampling and the pmf both call this, so they see the same bits. */
static inline __attribute__((always_inline)) void importance4(const lt_node *const g[4], pt_vec3 p,
                                                              pt_vec3 n, float out[4])
{
#define LANES(f) {g[0]->f, g[1]->f, g[2]->f, g[3]->f}
#define LANES_F(f)                                                                                 \
    {                                                                                              \
        (float)g[0]->f, (float)g[1]->f, (float)g[2]->f, (float)g[3]->f                             \
    }
#define LANES_2(f)                                                                                 \
    {                                                                                              \
        (g[0]->next & LT_TWO_SIDED) ? -1 : 0, (g[1]->next & LT_TWO_SIDED) ? -1 : 0,                \
            (g[2]->next & LT_TWO_SIDED) ? -1 : 0, (g[3]->next & LT_TWO_SIDED) ? -1 : 0             \
    }
    v4f dx = p.x - (v4f)LANES(center[0]);
    v4f dy = p.y - (v4f)LANES(center[1]);
    v4f dz = p.z - (v4f)LANES(center[2]);
    v4f r = LANES(r), power = LANES(power);
    v4f d2 = dx * dx + dy * dy + dz * dz, r2 = r * r;
    v4i outside = d2 > r2; /* else inside the sphere (or NaN): every direction, distance r */
    v4f inv = 1.0f / v4_sqrt(v4_sel(outside, d2, (v4f){1.0f, 1.0f, 1.0f, 1.0f}));
    /* theta_w: between the cone's axis and the direction to p */
    v4f ax = LANES_F(axis[0]);
    v4f ay = LANES_F(axis[1]);
    v4f az = LANES_F(axis[2]);
    v4f cos_w = (ax * dx + ay * dy + az * dz) * (inv * (1.0f / Q16));
    v4i two = LANES_2(next);
    cos_w = v4_sel(two, (v4f)((v4i)cos_w & 0x7fffffff), cos_w);
    cos_w = v4_sel(cos_w > 1.0f, (v4f){1.0f, 1.0f, 1.0f, 1.0f}, cos_w);
    cos_w = v4_sel(cos_w < -1.0f, (v4f){-1.0f, -1.0f, -1.0f, -1.0f}, cos_w);
    /* theta_x = max(0, theta_w - theta_o) */
    v4f cos_o = (v4f)LANES_F(cos_o) * (1.0f / Q16);
    v4f sin_w = v4_sqrt(1.0f - cos_w * cos_w), sin_o = v4_sqrt(1.0f - cos_o * cos_o);
    v4i apart = cos_w < cos_o;
    v4f cos_x = v4_sel(apart, cos_w * cos_o + sin_w * sin_o, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    v4f sin_x = v4_sel(apart, sin_w * cos_o - cos_w * sin_o, (v4f){0.0f, 0.0f, 0.0f, 0.0f});
    /* theta' = max(0, theta_x - theta_b), sin theta_b = r / d < 1 outside */
    v4f sin_b = r * inv;
    sin_b = v4_sel(sin_b < 1.0f, sin_b, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    v4f cos_b = v4_sqrt(1.0f - sin_b * sin_b);
    v4f cos_p = v4_sel(cos_x < cos_b, cos_x * cos_b + sin_x * sin_b, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    /* The receiver (Conty & Kulla 2018, eq. 3): theta_i between n and the
     * direction from p to the centre, less theta_b; cos(max(0, theta_i -
     * theta_b)), and 0 where that is >= pi/2: the node's sphere lies wholly
     * below p's tangent plane, where nothing it holds can light p. A zero n
     * (a receiver that scatters to both sides) sets no bound: 1 (has_n).
     * One more square root for the four lanes. */
    v4f cos_i = -(n.x * dx + n.y * dy + n.z * dz) * inv;
    cos_i = v4_sel(cos_i > 1.0f, (v4f){1.0f, 1.0f, 1.0f, 1.0f}, cos_i);
    cos_i = v4_sel(cos_i < -1.0f, (v4f){-1.0f, -1.0f, -1.0f, -1.0f}, cos_i);
    v4f sin_i = v4_sqrt(1.0f - cos_i * cos_i);
    v4f cos_ip =
        v4_sel(cos_i < cos_b, cos_i * cos_b + sin_i * sin_b, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    v4i has_n = (v4i){0, 0, 0, 0} - (int32_t)(n.x != 0.0f || n.y != 0.0f || n.z != 0.0f);
    cos_ip = v4_sel(has_n, cos_ip, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    v4f imp_out = power * cos_p * (inv * inv) * cos_ip;
    /* theta' >= theta_e = pi/2, or theta_i' >= pi/2: 0 */
    imp_out = (v4f)((v4i)imp_out & (cos_p > 0.0f) & (cos_ip > 0.0f));
    v4i r_ok = r2 > 0.0f;
    v4f imp_in = power / v4_sel(r_ok, r2, (v4f){1.0f, 1.0f, 1.0f, 1.0f});
    imp_in = (v4f)((v4i)imp_in & r_ok);
    v4f imp = v4_sel(outside, imp_out, imp_in);
    imp = (v4f)((v4i)imp & (imp < 3.4e38f)); /* not finite: 0 */
    memcpy(out, &imp, sizeof imp);
#undef LANES
#undef LANES_F
#undef LANES_2
}

/* Whether the walk stops at node nd seen from p (COARSE_COS above). */
static inline int coarse(const lt_node *nd, pt_vec3 p)
{
    if ((float)nd->cos_o * (1.0f / Q16) < COARSE_COS)
        return 0;
    float d[3] = {p.x - nd->center[0], p.y - nd->center[1], p.z - nd->center[2]};
    float rr = COARSE_RATIO * nd->r;
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > rr * rr;
}

/* The share of the light at place i of the order among node id's lights. */
static inline double power_share(const pt_light_tree *t, uint32_t id, uint32_t i)
{
    const lt_span *sp = &t->span[id];
    return (t->cdf[i + 1] - t->cdf[i]) / (t->cdf[sp->first + sp->count] - t->cdf[sp->first]);
}

/* The walk steps two levels at a time: from a node, it chooses among its
 * grandchildren at once (a child that is a leaf takes its own place, its
 * second place empty), each in proportion to its importance. This is the
 * 4-wide tree whose nodes are the binary tree's even levels: half the
 * steps, each one set of four SIMD lanes (importance4), and the same
 * function of the tree for the sampler and the pmf. The four places of
 * node id's step, and the node each stands for, into g and to: */
static inline __attribute__((always_inline)) void step_places(const pt_light_tree *t, uint32_t id,
                                                              const lt_node *g[4], uint32_t to[4])
{
    const lt_node *nodes = t->nodes;
    uint32_t c = nodes[id].next & LT_INDEX;
    for (uint32_t j = 0; j < 2; j++) {
        uint32_t nx = nodes[c + j].next;
        uint32_t gc = nx & LT_INDEX;
        int leaf = (nx & LT_LEAF) != 0;
        to[2 * j] = leaf ? c + j : gc;
        to[2 * j + 1] = leaf ? 1u : gc + 1; /* 1: the unused place, power 0 */
        g[2 * j] = &nodes[to[2 * j]];
        g[2 * j + 1] = &nodes[to[2 * j + 1]];
    }
}

/* The walk's next reads asked for before the current ones are used: the
 * children of the four places (one of them is read next), so that a
 * step's cache miss overlaps the one before it. A leaf's next names a
 * light, not a node: masked into the array, read for nothing. */
static inline void prefetch_below(const pt_light_tree *t, const lt_node *const g[4])
{
    uint32_t mask = t->nodes_used - 1; /* x & mask <= mask < nodes_used */
    for (int k = 0; k < 4; k++)
        __builtin_prefetch(&t->nodes[(g[k]->next & LT_INDEX) & mask]);
}

/* The functions that walk the tree are compiled at -O2 under GCC: at -O3
 * (the Release build's) the batched walk took 1.45x the time a choice
 * (16,704 lights on a sphere, 200,000 points: 265 ns against 182 ns),
 * and the one-at-a-time walk 1.07x; no single -O3 flag alone accounts for
 * it. Other compilers take the build's level. */
#if defined(__GNUC__) && !defined(__clang__)
#define LT_WALK_OPT __attribute__((optimize("O2")))
#else
#define LT_WALK_OPT
#endif

/* One walk of pt_light_tree_sample: u stays; the interval [base, base +
 * width) of it that leads to node id shrinks (a product, not a division, in
 * the walk's chain), q is the probability of reaching id. */
typedef struct lt_walk {
    double q, base, width;
    uint32_t id;
} lt_walk;

/* The walk w one step down from p and u; 1 while it goes on, 0 once it has
 * chosen: the light in *light (UINT32_MAX for none) and its pmf in *pmf.
 * pt_light_tree_sample and pt_light_tree_sample_n both walk by it, so that
 * their choices are the same bits. */
static inline __attribute__((always_inline)) int walk_step(const pt_light_tree *tree, lt_walk *w,
                                                           pt_vec3 p, pt_vec3 n, double u,
                                                           uint32_t *light, double *pmf)
{
    const lt_node *nodes = tree->nodes;
    uint32_t id = w->id;
    if (nodes[id].next & LT_LEAF) {
        *pmf = w->q;
        *light = nodes[id].next & LT_INDEX;
        return 0;
    }
    if (coarse(&nodes[id], p)) {
        /* the first place i of the node's lights with target < cdf[i + 1] */
        const lt_span *sp = &tree->span[id];
        uint32_t lo = sp->first, hi = sp->first + sp->count - 1;
        double c0 = tree->cdf[lo], v = (u - w->base) / w->width;
        v = v < 0.0 ? 0.0 : v < 0x1.fffffffffffffp-1 ? v : 0x1.fffffffffffffp-1;
        double target = c0 + v * (tree->cdf[hi + 1] - c0);
        while (lo < hi) {
            uint32_t mid = lo + (hi - lo) / 2;
            if (target < tree->cdf[mid + 1])
                hi = mid;
            else
                lo = mid + 1;
        }
        double share = power_share(tree, id, lo);
        if (!(share > 0.0)) { /* a rounded search found no light */
            *pmf = 0.0;
            *light = UINT32_MAX;
            return 0;
        }
        *pmf = w->q * share;
        *light = tree->order[lo];
        return 0;
    }
    const lt_node *g[4];
    uint32_t to[4];
    step_places(tree, id, g, to);
    prefetch_below(tree, g);
    float imp[4];
    importance4(g, p, n, imp);
    double sum = ((double)imp[0] + (double)imp[1]) + ((double)imp[2] + (double)imp[3]);
    if (!(sum > 0.0)) {
        *pmf = 0.0;
        *light = UINT32_MAX;
        return 0;
    }
    /* place k takes [cut_k, cut_k + width p_k); selects, not branches:
     * the place is random. An empty place's interval is empty. */
    double pk[4], cut[4], acc = 0.0;
    uint32_t k = 0;
    for (int j = 0; j < 4; j++) {
        pk[j] = (double)imp[j] / sum;
        cut[j] = w->base + acc * w->width;
        k = u < cut[j] ? k : (uint32_t)j;
        acc += pk[j];
    }
    /* rounding can leave u past the last non-empty place: then an empty
     * one, never chosen with a weight */
    if (!(pk[k] > 0.0)) {
        *pmf = 0.0;
        *light = UINT32_MAX;
        return 0;
    }
    w->base = cut[k];
    w->width *= pk[k];
    w->q *= pk[k];
    w->id = to[k];
    return 1;
}

LT_WALK_OPT
uint32_t pt_light_tree_sample(const pt_light_tree *tree, pt_vec3 p, pt_vec3 n, double u,
                              double *pmf)
{
    lt_walk w = {1.0, 0.0, 1.0, 0};
    uint32_t light;
    while (walk_step(tree, &w, p, n, u, &light, pmf))
        ;
    return light;
}

/* The walks in flight at once in pt_light_tree_sample_n: enough for their
 * cache misses to overlap, few enough for their state to stay in L1. */
#define WALKS 16u

LT_WALK_OPT
void pt_light_tree_sample_n(const pt_light_tree *tree, uint32_t n, const pt_vec3 *p,
                            const pt_vec3 *nrm, const double *u, uint32_t *light, double *pmf)
{
    lt_walk w[WALKS];
    uint32_t who[WALKS]; /* the point each slot walks for */
    uint32_t next = 0, live = 0;
    /* Slots refill as walks end, so that WALKS are in flight until the
     * points run out; each walk's steps are walk_step's, whatever the
     * interleaving. */
    while (live > 0 || next < n) {
        while (live < WALKS && next < n) {
            w[live] = (lt_walk){1.0, 0.0, 1.0, 0};
            who[live++] = next++;
        }
        for (uint32_t k = 0; k < live;) {
            uint32_t i = who[k];
            if (walk_step(tree, &w[k], p[i], nrm[i], u[i], &light[i], &pmf[i])) {
                k++;
                continue;
            }
            live--; /* the last slot takes this one's place */
            w[k] = w[live];
            who[k] = who[live];
        }
    }
}

LT_WALK_OPT
double pt_light_tree_pmf(const pt_light_tree *tree, pt_vec3 p, pt_vec3 n, uint32_t light)
{
    if (!tree || light >= tree->n)
        return 0.0;
    const lt_node *nodes = tree->nodes;
    uint64_t bits = tree->bits[light];
    uint32_t id = 0, levels = tree->levels[light];
    double q = 1.0;
    for (uint32_t k = 0; k < levels;) {
        if (coarse(&nodes[id], p))
            return q * power_share(tree, id, tree->rank[light]);
        const lt_node *g[4];
        uint32_t to[4];
        step_places(tree, id, g, to);
        /* the place on the light's path: its child's side, then, when that
         * child is not the leaf, the grandchild's */
        uint32_t b0 = (uint32_t)(bits >> k) & 1u, slot = 2 * b0;
        if (k + 1 < levels)
            slot += (uint32_t)(bits >> (k + 1)) & 1u;
        k += k + 1 < levels ? 2 : 1;
        float imp[4];
        importance4(g, p, n, imp);
        double sum = ((double)imp[0] + (double)imp[1]) + ((double)imp[2] + (double)imp[3]);
        if (!(sum > 0.0))
            return 0.0;
        q *= (double)imp[slot] / sum;
        id = to[slot];
    }
    return q;
}
