/*
 * tangent.c - MikkTSpace-like per-vertex tangents (see tangent.h).
 */
#include "common/scene/tangent.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* v minus its component along the unit n, normalised; 0 when nothing is left. */
static int project_unit(const double v[3], const float *n, double out[3])
{
    double nd[3] = {n[0], n[1], n[2]};
    double d = dot3(v, nd);
    for (int r = 0; r < 3; r++)
        out[r] = v[r] - nd[r] * d;
    double len = sqrt(dot3(out, out));
    if (!(len > 1e-30) || !isfinite(len))
        return 0;
    for (int r = 0; r < 3; r++)
        out[r] /= len;
    return 1;
}

/* The angle at corner p0 between the edges to p1 and p2. */
static double corner_angle(const float *p0, const float *p1, const float *p2)
{
    double a[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
    double b[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
    double la = sqrt(dot3(a, a)), lb = sqrt(dot3(b, b));
    if (!(la > 0.0) || !(lb > 0.0))
        return 0.0;
    double c = dot3(a, b) / (la * lb);
    return acos(c < -1.0 ? -1.0 : (c > 1.0 ? 1.0 : c));
}

pt_status pt_tangents_generate(const float *pos, const float *nrm, const float *uv,
                               const uint32_t *idx, uint32_t nt, const uint8_t *use, uint32_t nv,
                               float *tan, pt_error *err)
{
    /* Per vertex: the weighted tangent sum (3) and the handedness votes
     * (weights of w = +1 minus those of w = -1), and whether it is wanted. */
    double *acc = pt_calloc((size_t)nv * 4, sizeof(double));
    uint8_t *want = pt_calloc(nv ? nv : 1, 1);
    if (!acc || !want) {
        pt_free(acc);
        pt_free(want);
        return pt_error_set(err, PT_ERR_NOMEM, "tangents: out of memory for %u vertices", nv);
    }
    for (uint32_t t = 0; t < nt; t++) {
        if (use && !use[t])
            continue;
        const uint32_t *i = &idx[3 * (size_t)t];
        for (int k = 0; k < 3; k++) {
            const float *tv = &tan[4 * (size_t)i[k]];
            if (tv[0] == 0.0f && tv[1] == 0.0f && tv[2] == 0.0f && tv[3] == 0.0f)
                want[i[k]] = 1;
        }
    }
    for (uint32_t t = 0; t < nt; t++) {
        if (use && !use[t])
            continue;
        const uint32_t *i = &idx[3 * (size_t)t];
        /* A triangle none of whose corners is wanted adds to no sum that is
         * read: skipped (a scene whose tangents the builder made already). */
        if (!want[i[0]] && !want[i[1]] && !want[i[2]])
            continue;
        const float *p0 = &pos[3 * (size_t)i[0]], *p1 = &pos[3 * (size_t)i[1]],
                    *p2 = &pos[3 * (size_t)i[2]];
        const float *t0 = &uv[2 * (size_t)i[0]], *t1 = &uv[2 * (size_t)i[1]],
                    *t2 = &uv[2 * (size_t)i[2]];
        double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        /* v negated: texture space's y points to the image's top (tangent.h). */
        double du1 = (double)t1[0] - t0[0], dv1 = -((double)t1[1] - t0[1]);
        double du2 = (double)t2[0] - t0[0], dv2 = -((double)t2[1] - t0[1]);
        double area = du1 * dv2 - du2 * dv1; /* twice the signed UV area */
        if (area == 0.0 || !isfinite(area))
            continue;
        /* dP/du = (e1 dv2 - e2 dv1) / area; its direction is all that
         * matters, so scale by sign(area) instead of dividing. */
        double sg = area > 0.0 ? 1.0 : -1.0;
        double tu[3];
        for (int r = 0; r < 3; r++)
            tu[r] = sg * (e1[r] * dv2 - e2[r] * dv1);
        const float *ps[3] = {p0, p1, p2};
        for (int k = 0; k < 3; k++) {
            if (!want[i[k]])
                continue;
            double w = corner_angle(ps[k], ps[(k + 1) % 3], ps[(k + 2) % 3]);
            double tp[3];
            if (!(w > 0.0) || !project_unit(tu, &nrm[3 * (size_t)i[k]], tp))
                continue;
            double *a = &acc[4 * (size_t)i[k]];
            for (int r = 0; r < 3; r++)
                a[r] += w * tp[r];
            a[3] += w * sg;
        }
    }
    for (uint32_t v = 0; v < nv; v++) {
        if (!want[v])
            continue;
        const float *n = &nrm[3 * (size_t)v];
        float *out = &tan[4 * (size_t)v];
        double tp[3];
        if (!project_unit(&acc[4 * (size_t)v], n, tp)) {
            /* No usable UVs: any tangent perpendicular to n (Duff et al.
             * 2017's frame), so the normal map still reads as a rotation. */
            double s = n[2] >= 0.0f ? 1.0 : -1.0;
            double a = -1.0 / (s + n[2]);
            tp[0] = 1.0 + s * n[0] * n[0] * a;
            tp[1] = s * n[0] * n[1] * a;
            tp[2] = -s * n[0];
            acc[4 * (size_t)v + 3] = 1.0;
        }
        for (int r = 0; r < 3; r++)
            out[r] = (float)tp[r];
        out[3] = acc[4 * (size_t)v + 3] < 0.0 ? -1.0f : 1.0f;
    }
    pt_free(acc);
    pt_free(want);
    return PT_OK;
}
