/*
 * sphtri.c - Arvo 1995's sampling of a spherical triangle (sphtri.h).
 *
 * With A, B, C the unit directions to the vertices, alpha the inner angle at
 * A (between the planes of the arcs AB and AC) and c the arc AB, Arvo's
 * sec. 2 gives, for the sub-triangle of area A' = u1 Omega:
 *     s = sin(A' - alpha), t = cos(A' - alpha),
 *     u = t - cos alpha, v = s + sin alpha cos c,
 *     q = ((v t - u s) cos alpha - v) / ((v s + u t) sin alpha),
 *     C' = q A + sqrt(1 - q^2) unit(C - (C.A) A)   (on the arc AC),
 *     z = 1 - u2 (1 - C'.B),
 *     P = z B + sqrt(1 - z^2) unit(C' - (C'.B) B)   (on the arc BC').
 */
#include "common/render/sphtri.h"

#include <math.h>

#define PI_D 3.14159265358979323846

typedef struct d3 {
    double x, y, z;
} d3;

static d3 d3_of(pt_vec3 v, pt_vec3 p)
{
    return (d3){(double)v.x - (double)p.x, (double)v.y - (double)p.y, (double)v.z - (double)p.z};
}

static double dot(d3 a, d3 b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

static d3 cross(d3 a, d3 b)
{
    return (d3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

static d3 axpy(double s, d3 a, d3 b) /* s a + b */
{
    return (d3){s * a.x + b.x, s * a.y + b.y, s * a.z + b.z};
}

/* a / |a| into *out; 0 when a has no length. */
static int unit(d3 a, d3 *out)
{
    double l = sqrt(dot(a, a));
    if (!(l > 0.0) || !isfinite(l))
        return 0;
    *out = (d3){a.x / l, a.y / l, a.z / l};
    return 1;
}

static double angle(d3 n1, d3 n2)
{
    double c = dot(n1, n2);
    return acos(c < -1.0 ? -1.0 : c > 1.0 ? 1.0 : c);
}

/* Unit directions and inner angles; the solid angle, 0 when degenerate. */
static double setup(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c, d3 v[3], double ang[3])
{
    if (!unit(d3_of(a, p), &v[0]) || !unit(d3_of(b, p), &v[1]) || !unit(d3_of(c, p), &v[2]))
        return 0.0;
    d3 ab, ac, bc, ba, ca, cb;
    if (!unit(cross(v[0], v[1]), &ab) || !unit(cross(v[0], v[2]), &ac) ||
        !unit(cross(v[1], v[2]), &bc) || !unit(cross(v[1], v[0]), &ba) ||
        !unit(cross(v[2], v[0]), &ca) || !unit(cross(v[2], v[1]), &cb))
        return 0.0;
    ang[0] = angle(ab, ac);
    ang[1] = angle(bc, ba);
    ang[2] = angle(ca, cb);
    double omega = ang[0] + ang[1] + ang[2] - PI_D;
    return omega > 0.0 && isfinite(omega) ? omega : 0.0;
}

/* Van Oosterom & Strackee 1983 ("The Solid Angle of a Plane Triangle",
 * IEEE TBME 30(2)): tan(Omega / 2) = |a.(b x c)| / (|a||b||c| + (a.b)|c| +
 * (a.c)|b| + (b.c)|a|) for the vectors from p: one atan2 where the inner
 * angles take three acos. It agrees with them to rounding (test_sphtri). */
double pt_sphtri_solid_angle(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c)
{
    d3 A = d3_of(a, p), B = d3_of(b, p), C = d3_of(c, p);
    double la = sqrt(dot(A, A)), lb = sqrt(dot(B, B)), lc = sqrt(dot(C, C));
    double num = fabs(dot(A, cross(B, C)));
    double den = la * lb * lc + dot(A, B) * lc + dot(A, C) * lb + dot(B, C) * la;
    double o = 2.0 * atan2(num, den);
    return o > 0.0 && isfinite(o) && num > 0.0 ? o : 0.0;
}

/* Arvo's map for unit directions A, B, C, the inner angle alpha at A and
 * the area: the direction for u1, u2 into *wi. */
static int arvo_map(d3 A, d3 B, d3 C, double alpha, double area, float u1, float u2, pt_vec3 *wi)
{
    double ca = cos(alpha), sa = sin(alpha);
    double sub = (double)u1 * area;
    double s = sin(sub - alpha), t = cos(sub - alpha);
    double u = t - ca, w = s + sa * dot(A, B);
    double q = ((w * t - u * s) * ca - w) / ((w * s + u * t) * sa);
    q = q < -1.0 ? -1.0 : q > 1.0 ? 1.0 : q;
    d3 e;
    if (!unit(axpy(-dot(C, A), A, C), &e))
        return 0;
    d3 cp =
        axpy(q, A, (d3){sqrt(1.0 - q * q) * e.x, sqrt(1.0 - q * q) * e.y, sqrt(1.0 - q * q) * e.z});
    double z = 1.0 - (double)u2 * (1.0 - dot(cp, B));
    z = z < -1.0 ? -1.0 : z > 1.0 ? 1.0 : z;
    d3 out = B;
    if (unit(axpy(-dot(cp, B), B, cp), &e))
        out = axpy(z, B,
                   (d3){sqrt(1.0 - z * z) * e.x, sqrt(1.0 - z * z) * e.y, sqrt(1.0 - z * z) * e.z});
    if (!unit(out, &out))
        return 0;
    *wi = pt_v3((float)out.x, (float)out.y, (float)out.z);
    return 1;
}

int pt_sphtri_sample(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c, float u1, float u2, pt_vec3 *wi,
                     double *omega)
{
    d3 v[3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    double ang[3] = {0, 0, 0};
    double area = setup(p, a, b, c, v, ang);
    *omega = area;
    if (!(area > 0.0))
        return 0;
    return arvo_map(v[0], v[1], v[2], ang[0], area, u1, u2, wi);
}

int pt_sphtri_sample_omega(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c, double omega, float u1,
                           float u2, pt_vec3 *wi)
{
    d3 A, B, C, ab, ac;
    if (!(omega > 0.0) || !unit(d3_of(a, p), &A) || !unit(d3_of(b, p), &B) ||
        !unit(d3_of(c, p), &C) || !unit(cross(A, B), &ab) || !unit(cross(A, C), &ac))
        return 0;
    return arvo_map(A, B, C, angle(ab, ac), omega, u1, u2, wi);
}
