/*
 * manifold.c - Newton's method on chains of smooth refractions (manifold.h).
 */
#include "common/render/manifold.h"

#include <math.h>
#include <string.h>

#define MF_N (2u * PT_MF_MAX) /* unknowns at most */
/* A step moves a vertex by at most its distance to the previous one (the
 * extrapolated plane is only a guess far away; on the glass ball with
 * things inside, the two-refraction chains that the solver missed carried
 * 1.2, 1.0, 1.0 and 1.3 times as much squared light at 0.25, 0.5, 2 and no
 * limit, over three seeds). */
#define MF_STEP_MAX 1.0
/* A solve still this far from the root (the constraint's largest part, a
 * sine) after this many steps gives up: on the glass ball with things
 * inside (scenes/glass_things.gltf) the chains that converge are below
 * 0.25 there, those that do not (no chain from x reaches wl) wander at 0.5
 * to 0.9 until the last step. */
#define MF_BAIL_ITER 5
#define MF_BAIL_RES 0.4
/* Halvings of a step that leaves the glass before the solve gives up. */
#define MF_HALVINGS 4

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline double norm3(double a[3])
{
    double l = sqrt(dot3(a, a));
    if (!(l > 0.0))
        return 0.0;
    a[0] /= l;
    a[1] /= l;
    a[2] /= l;
    return l;
}

static inline void cross3(const double a[3], const double b[3], double out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

void pt_mf_point(const pt_mf_vert *v, const double b[2], double p[3])
{
    for (int i = 0; i < 3; i++)
        p[i] = v->p0[i] + b[0] * v->e1[i] + b[1] * v->e2[i];
}

int pt_mf_normal(const pt_mf_vert *v, const double b[2], double n[3])
{
    double b0 = 1.0 - b[0] - b[1];
    for (int i = 0; i < 3; i++)
        n[i] = b0 * v->n0[i] + b[0] * v->n1[i] + b[1] * v->n2[i];
    return norm3(n) > 0.0;
}

/* An orthonormal pair perpendicular to unit n (Duff et al. 2017's frame). */
static void tangents(const double n[3], double t1[3], double t2[3])
{
    double s = n[2] >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (s + n[2]), b = n[0] * n[1] * a;
    t1[0] = 1.0 + s * n[0] * n[0] * a;
    t1[1] = s * b;
    t1[2] = -s * n[0];
    t2[0] = b;
    t2[1] = s + n[1] * n[1] * a;
    t2[2] = -n[1];
}

/* v - w (w . v): v's part perpendicular to unit w. */
static inline void perp3(const double w[3], const double v[3], double out[3])
{
    double d = dot3(w, v);
    for (int j = 0; j < 3; j++)
        out[j] = v[j] - d * w[j];
}

/* The constraint at vertex i of c, into C[0..1], and where G is given its
 * derivatives by the barycentrics: G[r][0..1] by those of vertex i - 1,
 * [2..3] by vertex i's, [4..5] by vertex i + 1's (zero where there is no
 * such vertex); where K is given (the last vertex), by wl turned along its
 * unit tangents s[0], s[1]. The chain rule through the unit vectors
 * (d(v / |v|) = (I - u u^T) dv / |v|): w_a, w_b, h, the interpolated
 * normal n and the frame's tangent t1 = (e1 - n (n . e1)) / |...|, taken
 * from the triangle's first edge so that it is smooth in b, t2 = n x t1.
 * 0 where the vertex is degenerate (a zero h, normal or tangent). */
static int vertex_eval(const double x[3], const pt_mf_chain *c, const double wl[3], uint32_t i,
                       double C[2], double G[2][6], const double s[2][3], double K[2][2])
{
    const pt_mf_vert *v = &c->v[i];
    const int last = i + 1 == c->k;
    double p[3], prev[3], wa[3], wb[3], h[3], n[3], t1[3], t2[3];
    pt_mf_point(v, v->b, p);
    if (i == 0)
        memcpy(prev, x, sizeof prev);
    else
        pt_mf_point(&c->v[i - 1], c->v[i - 1].b, prev);
    for (int j = 0; j < 3; j++)
        wa[j] = prev[j] - p[j];
    double la = norm3(wa), lb = 1.0;
    /* towards a point: the next vertex, or the light's point (fixed) */
    const int towards = !last || c->at;
    if (towards) {
        double next[3];
        if (!last)
            pt_mf_point(&c->v[i + 1], c->v[i + 1].b, next);
        else
            memcpy(next, wl, sizeof next);
        for (int j = 0; j < 3; j++)
            wb[j] = next[j] - p[j];
        lb = norm3(wb);
    } else {
        memcpy(wb, wl, sizeof wb);
    }
    double ea = dot3(wa, v->ng) > 0.0 ? 1.0 : v->ior;
    double eb = dot3(wb, v->ng) > 0.0 ? 1.0 : v->ior;
    for (int j = 0; j < 3; j++)
        h[j] = ea * wa[j] + eb * wb[j];
    double lh = norm3(h), b0 = 1.0 - v->b[0] - v->b[1];
    for (int j = 0; j < 3; j++)
        n[j] = b0 * v->n0[j] + v->b[0] * v->n1[j] + v->b[1] * v->n2[j];
    double ln = norm3(n), ne = dot3(n, v->e1);
    for (int j = 0; j < 3; j++)
        t1[j] = v->e1[j] - ne * n[j];
    double lt = norm3(t1);
    if (!(la > 0.0 && lb > 0.0 && lh > 0.0 && ln > 0.0 && lt > 1e-12))
        return 0;
    cross3(n, t1, t2);
    C[0] = dot3(h, t1);
    C[1] = dot3(h, t2);
    for (int q = 0; G && q < 6; q++) {
        int who = (int)i + q / 2 - 1;
        G[0][q] = G[1][q] = 0.0;
        if (who < 0 || who >= (int)c->k)
            continue;
        const pt_mf_vert *u = &c->v[who];
        const double *e = q % 2 == 0 ? u->e1 : u->e2;
        double dprev[3] = {0, 0, 0}, dp[3] = {0, 0, 0}, dnext[3] = {0, 0, 0}, dnt[3] = {0, 0, 0};
        if (who + 1 == (int)i) {
            memcpy(dprev, e, sizeof dprev);
        } else if (who == (int)i) {
            memcpy(dp, e, sizeof dp);
            for (int j = 0; j < 3; j++)
                dnt[j] = (q % 2 == 0 ? v->n1[j] : v->n2[j]) - v->n0[j];
        } else {
            memcpy(dnext, e, sizeof dnext);
        }
        double d[3], dwa[3], dwb[3] = {0, 0, 0}, dh[3], dn[3], dt1[3], dt2[3], tmp[3];
        for (int j = 0; j < 3; j++)
            d[j] = (dprev[j] - dp[j]) / la;
        perp3(wa, d, dwa);
        if (towards) {
            for (int j = 0; j < 3; j++)
                d[j] = (dnext[j] - dp[j]) / lb;
            perp3(wb, d, dwb);
        }
        for (int j = 0; j < 3; j++)
            d[j] = (ea * dwa[j] + eb * dwb[j]) / lh;
        perp3(h, d, dh);
        if (who != (int)i) {
            /* A neighbour moves h alone: the frame stays. */
            G[0][q] = dot3(dh, t1);
            G[1][q] = dot3(dh, t2);
            continue;
        }
        for (int j = 0; j < 3; j++)
            d[j] = dnt[j] / ln;
        perp3(n, d, dn);
        double dne = dot3(dn, v->e1);
        for (int j = 0; j < 3; j++)
            d[j] = (-dn[j] * ne - n[j] * dne) / lt;
        perp3(t1, d, dt1);
        cross3(dn, t1, dt2);
        cross3(n, dt1, tmp);
        for (int j = 0; j < 3; j++)
            dt2[j] += tmp[j];
        G[0][q] = dot3(dh, t1) + dot3(h, dt1);
        G[1][q] = dot3(dh, t2) + dot3(h, dt2);
    }
    for (int q = 0; K && !c->at && last && q < 2; q++) {
        /* wl turned by theta along s[q]: d wl = s[q] (perpendicular to wl) */
        double d[3], dh[3];
        for (int j = 0; j < 3; j++)
            d[j] = eb * s[q][j] / lh;
        perp3(h, d, dh);
        K[0][q] = dot3(dh, t1);
        K[1][q] = dot3(dh, t2);
    }
    for (int q = 0; K && c->at && i == 0 && q < 2; q++) {
        /* x moved along s[q]: w_a turns by (I - w_a w_a^T) s[q] / |x - p| */
        double d[3], dwa[3], dh[3];
        for (int j = 0; j < 3; j++)
            d[j] = s[q][j] / la;
        perp3(wa, d, dwa);
        for (int j = 0; j < 3; j++)
            d[j] = ea * dwa[j] / lh;
        perp3(h, d, dh);
        K[0][q] = dot3(dh, t1);
        K[1][q] = dot3(dh, t2);
    }
    return 1;
}

/* The constraint C (2k values) and, where J is given, dC/db (J[r * n +
 * col], n = 2k), and where K is, dC/dtheta for wl's tangents s (K[r * 2 +
 * q]). 0 where a vertex is degenerate. */
static int chain_eval(const double x[3], const pt_mf_chain *c, const double wl[3], double *C,
                      double *J, const double s[2][3], double *K)
{
    uint32_t n = 2u * c->k;
    if (J)
        memset(J, 0, (size_t)n * n * sizeof *J);
    if (K)
        memset(K, 0, (size_t)n * 2 * sizeof *K);
    for (uint32_t i = 0; i < c->k; i++) {
        double G[2][6], Kv[2][2];
        if (!vertex_eval(x, c, wl, i, &C[2 * i], J ? G : NULL, s, K ? Kv : NULL))
            return 0;
        for (uint32_t r = 0; J && r < 2; r++)
            for (int q = 0; q < 6; q++) {
                int col = 2 * ((int)i + q / 2 - 1) + q % 2;
                if (col >= 0 && col < (int)n)
                    J[(2 * i + r) * n + (uint32_t)col] = G[r][q];
            }
        if (K && (c->at ? i == 0 : i + 1 == c->k))
            for (uint32_t r = 0; r < 2; r++) {
                K[(2 * i + r) * 2] = Kv[r][0];
                K[(2 * i + r) * 2 + 1] = Kv[r][1];
            }
    }
    return 1;
}

/* Solves A X = B in place (A n x n, B n x m, row-major) by Gaussian
 * elimination with partial pivoting; 0 when A is singular. */
static int solve_linear(double *A, double *B, uint32_t n, uint32_t m)
{
    for (uint32_t k = 0; k < n; k++) {
        uint32_t piv = k;
        for (uint32_t r = k + 1; r < n; r++)
            if (fabs(A[r * n + k]) > fabs(A[piv * n + k]))
                piv = r;
        if (!(fabs(A[piv * n + k]) > 1e-300))
            return 0;
        if (piv != k) {
            for (uint32_t j = 0; j < n; j++) {
                double t = A[k * n + j];
                A[k * n + j] = A[piv * n + j];
                A[piv * n + j] = t;
            }
            for (uint32_t j = 0; j < m; j++) {
                double t = B[k * m + j];
                B[k * m + j] = B[piv * m + j];
                B[piv * m + j] = t;
            }
        }
        for (uint32_t r = k + 1; r < n; r++) {
            double f = A[r * n + k] / A[k * n + k];
            for (uint32_t j = k; j < n; j++)
                A[r * n + j] -= f * A[k * n + j];
            for (uint32_t j = 0; j < m; j++)
                B[r * m + j] -= f * B[k * m + j];
        }
    }
    for (uint32_t k = n; k-- > 0;)
        for (uint32_t j = 0; j < m; j++) {
            double s = B[k * m + j];
            for (uint32_t c = k + 1; c < n; c++)
                s -= A[k * n + c] * B[c * m + j];
            B[k * m + j] = s / A[k * n + k];
        }
    return 1;
}

static double max_abs(const double *v, uint32_t n)
{
    double m = 0.0;
    for (uint32_t i = 0; i < n; i++)
        m = fmax(m, fabs(v[i]));
    return m;
}

static inline int inside(const double b[2])
{
    return b[0] >= 0.0 && b[1] >= 0.0 && b[0] + b[1] <= 1.0;
}

/* c's vertices moved by scale x the step D (in barycentrics): 1, or 0
 * when a point could not be put back on the glass, -1 on a NaN. */
static int apply_step(const double x[3], pt_mf_chain *c, const double *D, double scale,
                      pt_mf_project_fn project, void *user)
{
    for (uint32_t i = 0; i < c->k; i++) {
        pt_mf_vert *v = &c->v[i];
        double nb[2] = {v->b[0] + scale * D[2 * i], v->b[1] + scale * D[2 * i + 1]};
        if (!(isfinite(nb[0]) && isfinite(nb[1])))
            return -1;
        if (inside(nb)) {
            v->b[0] = nb[0];
            v->b[1] = nb[1];
            continue;
        }
        /* Off its triangle: back onto the glass, along the ray from the
         * vertex before it through the point on the plane. */
        double q[3], prev[3];
        pt_mf_point(v, nb, q);
        if (i == 0)
            memcpy(prev, x, sizeof prev);
        else
            pt_mf_point(&c->v[i - 1], c->v[i - 1].b, prev);
        pt_mf_vert moved;
        if (!project(user, i == 0 ? NULL : &c->v[i - 1], prev, q, &moved))
            return 0;
        *v = moved;
    }
    return 1;
}

int pt_mf_solve(const double x[3], pt_mf_chain *c, const double wl[3], pt_mf_project_fn project,
                void *user)
{
    if (c->k == 0 || c->k > PT_MF_MAX)
        return 0;
    uint32_t n = 2u * c->k;
    for (int it = 0; it < PT_MF_ITERS; it++) {
        double C[MF_N] = {0}, J[MF_N * MF_N];
        if (!chain_eval(x, c, wl, C, J, NULL, NULL))
            return 0;
        double res = max_abs(C, n);
        if (!(res >= PT_MF_TOL))
            return res < PT_MF_TOL; /* converged (NaN: not) */
        if (it == MF_BAIL_ITER && res > MF_BAIL_RES)
            return 0;
        for (uint32_t i = 0; i < n; i++)
            C[i] = -C[i];
        if (!solve_linear(J, C, n, 1))
            return 0;
        /* The step, shortened so that no vertex moves by more than
         * MF_STEP_MAX of its distance to the one before it. */
        double scale = 1.0;
        for (uint32_t i = 0; i < c->k; i++) {
            const pt_mf_vert *v = &c->v[i];
            double p[3], q[3], prev[3];
            double nb[2] = {v->b[0] + C[2 * i], v->b[1] + C[2 * i + 1]};
            pt_mf_point(v, v->b, p);
            pt_mf_point(v, nb, q);
            if (i == 0)
                memcpy(prev, x, sizeof prev);
            else
                pt_mf_point(&c->v[i - 1], c->v[i - 1].b, prev);
            double d[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
            double l[3] = {p[0] - prev[0], p[1] - prev[1], p[2] - prev[2]};
            double moved = sqrt(dot3(d, d)), reach = MF_STEP_MAX * sqrt(dot3(l, l));
            if (moved > reach)
                scale = fmin(scale, reach / moved);
        }
        /* A step whose point leaves the glass's outline (the ray back onto
         * it misses) is halved, up to MF_HALVINGS times. */
        int done = 0;
        for (int h = 0; h <= MF_HALVINGS && !done; h++, scale *= 0.5) {
            pt_mf_chain next = *c;
            done = apply_step(x, &next, C, scale, project, user);
            if (done < 0)
                return 0;
            if (done)
                *c = next;
        }
        if (!done)
            return 0;
    }
    return 0;
}

/* |det| of how the unit direction from `from` to vertex v turns per unit
 * of the two parameters whose derivatives of v's barycentrics are K's rows
 * r0, r0 + 1 (2 columns): d(omega) = (I - omega omega^T) dy / dist, read in
 * omega's tangents. 0 where v is at `from` or the product overflows. */
static double turn_det(const pt_mf_vert *v, const double *K, uint32_t r0, const double from[3])
{
    double y[3], w[3];
    pt_mf_point(v, v->b, y);
    for (int j = 0; j < 3; j++)
        w[j] = y[j] - from[j];
    double dist = norm3(w);
    if (!(dist > 0.0))
        return 0.0;
    double u1[3], u2[3];
    tangents(w, u1, u2);
    double M[2][2];
    for (int col = 0; col < 2; col++) {
        double dy[3];
        for (int j = 0; j < 3; j++)
            dy[j] = v->e1[j] * K[r0 * 2 + col] + v->e2[j] * K[(r0 + 1) * 2 + col];
        M[0][col] = dot3(u1, dy) / dist;
        M[1][col] = dot3(u2, dy) / dist;
    }
    double det = fabs(M[0][0] * M[1][1] - M[0][1] * M[1][0]);
    return isfinite(det) ? det : 0.0;
}

double pt_mf_jacobian(const double x[3], const pt_mf_chain *c, const double wl[3])
{
    if (c->k == 0 || c->k > PT_MF_MAX || c->at)
        return 0.0;
    uint32_t n = 2u * c->k;
    double J[MF_N * MF_N], K[MF_N * 2], C[MF_N];
    /* dC/dtheta: wl turned by theta along its two tangents. */
    double s[2][3];
    tangents(wl, s[0], s[1]);
    if (!chain_eval(x, c, wl, C, J, (const double(*)[3])s, K))
        return 0.0;
    for (uint32_t i = 0; i < 2 * n; i++)
        K[i] = -K[i];
    /* db/dtheta = -J^-1 dC/dtheta (K holds its negation). */
    if (!solve_linear(J, K, n, 2))
        return 0.0;
    return turn_det(&c->v[0], K, 0, x);
}

double pt_mf_point_jacobian(const double x[3], const pt_mf_chain *c, const double l[3])
{
    if (c->k == 0 || c->k > PT_MF_MAX || !c->at)
        return 0.0;
    uint32_t n = 2u * c->k;
    double J[MF_N * MF_N], K[MF_N * 2], C[MF_N];
    /* dC/dx: x moved along the two unit tangents of its segment's direction. */
    double y[3], w[3], s[2][3];
    pt_mf_point(&c->v[0], c->v[0].b, y);
    for (int j = 0; j < 3; j++)
        w[j] = y[j] - x[j];
    if (!(norm3(w) > 0.0))
        return 0.0;
    tangents(w, s[0], s[1]);
    if (!chain_eval(x, c, l, C, J, (const double(*)[3])s, K))
        return 0.0;
    for (uint32_t i = 0; i < 2 * n; i++)
        K[i] = -K[i];
    if (!solve_linear(J, K, n, 2))
        return 0.0;
    /* The last vertex's move turns omega_l = (y_k - l) / |y_k - l|. */
    return turn_det(&c->v[c->k - 1], K, 2 * (c->k - 1), l);
}
