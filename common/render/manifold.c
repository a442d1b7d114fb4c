/*
 * manifold.c - Newton's method on chains of smooth refractions (manifold.h).
 */
#include "common/render/manifold.h"

#include <math.h>
#include <string.h>

#define MF_N (2u * PT_MF_MAX) /* unknowns at most */
/* Central differences' step in barycentrics and in radians: the
 * constraint is smooth at that scale, and its rounding (1e-16) over the
 * step stays far below PT_MF_TOL. */
#define MF_DB 1e-6
#define MF_DW 1e-6
/* A step moves a vertex by at most this share of its distance to the
 * previous one (the extrapolated plane is only a guess far away). */
#define MF_STEP_MAX 0.5

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

/* The constraint at vertex i with the barycentrics bs[] of all vertices. */
static void constraint_at(const double x[3], const pt_mf_chain *c, const double bs[][2],
                          const double wl[3], uint32_t i, double out[2])
{
    const pt_mf_vert *v = &c->v[i];
    double p[3], prev[3], wa[3], wb[3], n[3];
    pt_mf_point(v, bs[i], p);
    if (i == 0)
        memcpy(prev, x, sizeof prev);
    else
        pt_mf_point(&c->v[i - 1], bs[i - 1], prev);
    for (int j = 0; j < 3; j++)
        wa[j] = prev[j] - p[j];
    if (i + 1 < c->k) {
        double next[3];
        pt_mf_point(&c->v[i + 1], bs[i + 1], next);
        for (int j = 0; j < 3; j++)
            wb[j] = next[j] - p[j];
    } else {
        memcpy(wb, wl, sizeof wb);
    }
    norm3(wa);
    norm3(wb);
    double ea = dot3(wa, v->ng) > 0.0 ? 1.0 : v->ior;
    double eb = dot3(wb, v->ng) > 0.0 ? 1.0 : v->ior;
    double h[3];
    for (int j = 0; j < 3; j++)
        h[j] = ea * wa[j] + eb * wb[j];
    if (!(norm3(h) > 0.0) || !pt_mf_normal(v, bs[i], n)) {
        out[0] = out[1] = 1.0;
        return;
    }
    /* The tangents of the normal's frame, made smooth in b by taking them
     * from the triangle's first edge rather than the normal's signs. */
    double t1[3], t2[3];
    memcpy(t1, v->e1, sizeof t1);
    double en = dot3(t1, n);
    for (int j = 0; j < 3; j++)
        t1[j] -= en * n[j];
    if (!(norm3(t1) > 0.0))
        tangents(n, t1, t2);
    else
        cross3(n, t1, t2);
    out[0] = dot3(h, t1);
    out[1] = dot3(h, t2);
}

static void constraint_b(const double x[3], const pt_mf_chain *c, const double bs[][2],
                         const double wl[3], double C[])
{
    for (uint32_t i = 0; i < c->k; i++)
        constraint_at(x, c, bs, wl, i, &C[2 * i]);
}

void pt_mf_constraint(const double x[3], const pt_mf_chain *c, const double wl[3], double C[])
{
    double bs[PT_MF_MAX][2];
    for (uint32_t i = 0; i < c->k; i++)
        memcpy(bs[i], c->v[i].b, sizeof bs[i]);
    constraint_b(x, c, bs, wl, C);
}

/* dC/db: J[r * n + col], n = 2k, by central differences (central) or
 * forward ones from C0, the constraint at c (Newton's steps: a rougher
 * Jacobian only slows their convergence near the root, which the
 * tolerance still decides; the chain's own Jacobian takes central ones). */
static void jacobian_b(const double x[3], const pt_mf_chain *c, const double wl[3], int central,
                       const double *C0, double *J)
{
    uint32_t n = 2u * c->k;
    double bs[PT_MF_MAX][2];
    for (uint32_t i = 0; i < c->k; i++)
        memcpy(bs[i], c->v[i].b, sizeof bs[i]);
    for (uint32_t col = 0; col < n; col++) {
        double cp[MF_N], cm[MF_N];
        double keep = bs[col / 2][col % 2];
        bs[col / 2][col % 2] = keep + MF_DB;
        constraint_b(x, c, bs, wl, cp);
        if (central) {
            bs[col / 2][col % 2] = keep - MF_DB;
            constraint_b(x, c, bs, wl, cm);
        } else {
            memcpy(cm, C0, n * sizeof *cm);
        }
        bs[col / 2][col % 2] = keep;
        for (uint32_t r = 0; r < n; r++)
            J[r * n + col] = (cp[r] - cm[r]) / ((central ? 2.0 : 1.0) * MF_DB);
    }
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

int pt_mf_solve(const double x[3], pt_mf_chain *c, const double wl[3], pt_mf_project_fn project,
                void *user)
{
    if (c->k == 0 || c->k > PT_MF_MAX)
        return 0;
    uint32_t n = 2u * c->k;
    for (int it = 0; it < PT_MF_ITERS; it++) {
        double C[MF_N] = {0}, J[MF_N * MF_N];
        pt_mf_constraint(x, c, wl, C);
        if (!(max_abs(C, n) >= PT_MF_TOL))
            return max_abs(C, n) < PT_MF_TOL; /* converged (NaN: not) */
        jacobian_b(x, c, wl, 0, C, J);
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
        for (uint32_t i = 0; i < c->k; i++) {
            pt_mf_vert *v = &c->v[i];
            double nb[2] = {v->b[0] + scale * C[2 * i], v->b[1] + scale * C[2 * i + 1]};
            if (!(isfinite(nb[0]) && isfinite(nb[1])))
                return 0;
            if (inside(nb)) {
                v->b[0] = nb[0];
                v->b[1] = nb[1];
                continue;
            }
            /* Off its triangle: back onto the glass, along the ray from
             * the vertex before it through the point on the plane. */
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
    }
    return 0;
}

double pt_mf_jacobian(const double x[3], const pt_mf_chain *c, const double wl[3])
{
    if (c->k == 0 || c->k > PT_MF_MAX)
        return 0.0;
    uint32_t n = 2u * c->k;
    double J[MF_N * MF_N], K[MF_N * 2];
    jacobian_b(x, c, wl, 1, NULL, J);
    /* dC/dtheta: wl turned by theta along its two tangents. */
    double s1[3], s2[3];
    tangents(wl, s1, s2);
    const double *s[2] = {s1, s2};
    for (int col = 0; col < 2; col++) {
        double wp[3], wm[3], cp[MF_N], cm[MF_N];
        for (int j = 0; j < 3; j++) {
            wp[j] = wl[j] + MF_DW * s[col][j];
            wm[j] = wl[j] - MF_DW * s[col][j];
        }
        norm3(wp);
        norm3(wm);
        pt_mf_constraint(x, c, wp, cp);
        pt_mf_constraint(x, c, wm, cm);
        for (uint32_t r = 0; r < n; r++)
            K[r * 2 + col] = -(cp[r] - cm[r]) / (2.0 * MF_DW);
    }
    /* db/dtheta = -J^-1 dC/dtheta (K holds its negation). */
    if (!solve_linear(J, K, n, 2))
        return 0.0;
    const pt_mf_vert *v = &c->v[0];
    double y[3], w[3];
    pt_mf_point(v, v->b, y);
    for (int j = 0; j < 3; j++)
        w[j] = y[j] - x[j];
    double dist = norm3(w);
    if (!(dist > 0.0))
        return 0.0;
    double u1[3], u2[3];
    tangents(w, u1, u2);
    double M[2][2];
    for (int col = 0; col < 2; col++) {
        double dy[3];
        for (int j = 0; j < 3; j++)
            dy[j] = v->e1[j] * K[0 * 2 + col] + v->e2[j] * K[1 * 2 + col];
        /* d(omega) = (I - omega omega^T) dy / dist, read in u1, u2. */
        M[0][col] = dot3(u1, dy) / dist;
        M[1][col] = dot3(u2, dy) / dist;
    }
    double det = fabs(M[0][0] * M[1][1] - M[0][1] * M[1][0]);
    return isfinite(det) ? det : 0.0;
}
