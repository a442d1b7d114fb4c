// anim.cpp - posing a rig (anim.h) at a time: sampler evaluation, node
// transforms, morph targets, skinning, and the scene-space write-out.
//
// All arithmetic is in double; the results are rounded to float once, as
// the scene builder rounds its positions, after opts' scale and translation
// and the shift by the scene's origin. The rig (anim_rig.hpp) is checked by
// the importer, so nothing here indexes out of range whatever the file said.
#include "common/scene/anim_rig.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <new>
#include <utility>

extern "C" {
#include "common/base/alloc.h"
#include "common/scene/tangent.h"
}

using namespace pt_rig;

void pt_rig::trs_matrix(const double t[3], const double q_in[4], const double s[3], double *m)
{
    double q[4] = {q_in[0], q_in[1], q_in[2], q_in[3]};
    double ql = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (ql > 0 && std::isfinite(ql))
        for (double &c : q)
            c /= ql;
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w),     2 * (x * z - y * w),
                   2 * (x * y - z * w),     1 - 2 * (x * x + z * z), 2 * (y * z + x * w),
                   2 * (x * z + y * w),     2 * (y * z - x * w),     1 - 2 * (x * x + y * y)};
    for (int c = 0; c < 3; c++) {
        for (int rr = 0; rr < 3; rr++)
            m[c * 4 + rr] = r[c * 3 + rr] * s[c];
        m[c * 4 + 3] = 0.0;
    }
    m[12] = t[0];
    m[13] = t[1];
    m[14] = t[2];
    m[15] = 1.0;
}

namespace
{

typedef double mat4[16]; // column-major

void mat_mul(const double *a, const double *b, double *r)
{
    double t[16];
    for (int c = 0; c < 4; c++)
        for (int rr = 0; rr < 4; rr++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += a[k * 4 + rr] * b[c * 4 + k];
            t[c * 4 + rr] = s;
        }
    memcpy(r, t, sizeof t);
}

// Spherical linear interpolation of unit quaternions along the shorter arc
// (glTF 2.0, Appendix C "Interpolation"), falling back to a normalised lerp
// where the two are too close for the sine ratio.
static void slerp(const float *a, const float *b_in, double u, double *out)
{
    double b[4] = {b_in[0], b_in[1], b_in[2], b_in[3]};
    double d =
        double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2] + double(a[3]) * b[3];
    if (d < 0.0) {
        d = -d;
        for (double &c : b)
            c = -c;
    }
    double s0, s1;
    if (d > 0.9995) {
        s0 = 1.0 - u;
        s1 = u;
    } else {
        double th0 = std::acos(d), th = u * th0, st0 = std::sin(th0);
        s0 = std::sin(th0 - th) / st0;
        s1 = std::sin(th) / st0;
    }
    double l = 0.0;
    for (int k = 0; k < 4; k++) {
        out[k] = s0 * a[k] + s1 * b[k];
        l += out[k] * out[k];
    }
    l = std::sqrt(l);
    if (l > 0.0)
        for (int k = 0; k < 4; k++)
            out[k] /= l;
}

// The sampler's value at t into out[0 .. comps). rotation: quaternion rules
// (slerp for LINEAR, normalised after CUBICSPLINE).
void evaluate(const sampler &s, double t, bool rotation, double *out)
{
    size_t n = s.in.size(), c = size_t(s.comps);
    bool cubic = s.interp == INTERP_CUBIC;
    // The value of key k: CUBICSPLINE stores (in-tangent, value, out-tangent).
    auto value = [&](size_t k) { return s.out.data() + (cubic ? (3 * k + 1) * c : k * c); };
    if (n == 1 || t <= double(s.in[0]) || t >= double(s.in[n - 1]) || !(t == t)) {
        const float *v = value(t >= double(s.in[n - 1]) ? n - 1 : 0);
        for (size_t i = 0; i < c; i++)
            out[i] = v[i];
        if (rotation && cubic) {
            double l =
                std::sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3]);
            if (l > 0.0)
                for (int i = 0; i < 4; i++)
                    out[i] /= l;
        }
        return;
    }
    // The last key at or before t: in[k] <= t < in[k + 1].
    size_t lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        size_t mid = lo + (hi - lo) / 2;
        if (double(s.in[mid]) <= t)
            lo = mid;
        else
            hi = mid;
    }
    size_t k = lo;
    double t0 = s.in[k], t1 = s.in[k + 1], td = t1 - t0;
    double u = (t - t0) / td;
    const float *v0 = value(k), *v1 = value(k + 1);
    if (s.interp == INTERP_STEP) {
        for (size_t i = 0; i < c; i++)
            out[i] = v0[i];
    } else if (!cubic) {
        if (rotation)
            slerp(v0, v1, u, out);
        else
            for (size_t i = 0; i < c; i++)
                out[i] = (1.0 - u) * v0[i] + u * v1[i];
    } else {
        // Hermite spline (Appendix C): tangents scaled by the key interval.
        const float *b0 = s.out.data() + (3 * k + 2) * c; // out-tangent of key k
        const float *a1 = s.out.data() + (3 * k + 3) * c; // in-tangent of key k + 1
        double u2 = u * u, u3 = u2 * u;
        double h00 = 2 * u3 - 3 * u2 + 1, h10 = u3 - 2 * u2 + u, h01 = -2 * u3 + 3 * u2,
               h11 = u3 - u2;
        for (size_t i = 0; i < c; i++)
            out[i] = h00 * v0[i] + h10 * td * b0[i] + h01 * v1[i] + h11 * td * a1[i];
        if (rotation) {
            double l =
                std::sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3]);
            if (l > 0.0)
                for (int i = 0; i < 4; i++)
                    out[i] /= l;
        }
    }
}

void normalise3(double *v)
{
    double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (l > 0.0 && std::isfinite(l)) {
        v[0] /= l;
        v[1] /= l;
        v[2] /= l;
    } else {
        v[0] = v[1] = v[2] = 0.0;
    }
}

struct pose_state {
    std::vector<double> global;               // 16 per node
    std::vector<std::vector<double>> weights; // per node
};

void pose_nodes(const pt_anim &a, double t, pose_state &ps)
{
    size_t nn = a.nodes.size();
    std::vector<double> T(3 * nn), R(4 * nn), S(3 * nn);
    ps.weights.resize(nn);
    for (size_t i = 0; i < nn; i++) {
        const node &n = a.nodes[i];
        memcpy(&T[3 * i], n.t, sizeof n.t);
        memcpy(&R[4 * i], n.r, sizeof n.r);
        memcpy(&S[3 * i], n.s, sizeof n.s);
        ps.weights[i] = n.weights;
    }
    std::vector<double> v;
    for (const channel &ch : a.channels) {
        const sampler &s = a.samplers[size_t(ch.sampler)];
        v.assign(size_t(s.comps), 0.0);
        evaluate(s, t, ch.path == PATH_R, v.data());
        size_t ni = size_t(ch.node);
        switch (ch.path) {
        case PATH_T:
            memcpy(&T[3 * ni], v.data(), 3 * sizeof(double));
            break;
        case PATH_R:
            memcpy(&R[4 * ni], v.data(), 4 * sizeof(double));
            break;
        case PATH_S:
            memcpy(&S[3 * ni], v.data(), 3 * sizeof(double));
            break;
        default:
            ps.weights[ni] = v;
            break;
        }
    }
    ps.global.assign(16 * nn, 0.0);
    for (int ni : a.order) {
        const node &n = a.nodes[size_t(ni)];
        double local[16];
        if (n.has_matrix)
            memcpy(local, n.matrix, sizeof local);
        else
            trs_matrix(&T[3 * size_t(ni)], &R[4 * size_t(ni)], &S[3 * size_t(ni)], local);
        double *g = &ps.global[16 * size_t(ni)];
        if (n.parent >= 0)
            mat_mul(&ps.global[16 * size_t(n.parent)], local, g);
        else
            memcpy(g, local, sizeof local);
    }
}

// A camera's placement from its node's global matrix, as the importer
// places it at load (add_camera). A matrix that degenerates during an
// animation (a scale through zero) keeps the camera's previous axes, which
// the load checked, rather than making NaN ones.
void place_camera(const double *w, const double *pos, pt_camera *c)
{
    c->position = pt_v3(float(pos[0]), float(pos[1]), float(pos[2]));
    pt_vec3 fwd = pt_v3(float(-w[8]), float(-w[9]), float(-w[10]));
    pt_vec3 up = pt_v3(float(w[4]), float(w[5]), float(w[6]));
    if (!pt_isfinite3(fwd) || !pt_isfinite3(up) || !(pt_v3_len(fwd) > 0.0f))
        return;
    pt_vec3 f = pt_v3_norm(fwd);
    pt_vec3 r = pt_v3_norm(pt_v3_cross(f, up));
    if (!(pt_v3_len(r) > 0.5f) || !pt_isfinite3(r))
        return;
    c->forward = f;
    c->right = r;
    c->up = pt_v3_cross(r, f);
}

pt_status pose(const pt_anim &a, double t, const pt_scene *s, pt_anim_pose_out *out, pt_error *err)
{
    if (!(t >= 0.0) || !std::isfinite(t))
        return pt_error_set(err, PT_ERR_ARG, "animation time %g is negative or not finite", t);
    // A scene other than the rig's would be read out of range: refuse it.
    for (const prim &p : a.prims)
        if (uint64_t(p.v0) + p.nv > s->num_vertices || uint64_t(p.t0) + p.nt > s->num_triangles)
            return pt_error_set(err, PT_ERR_ARG, "pt_anim_pose: the scene is not the rig's");
    for (const placed &pc : a.cameras)
        if (pc.index >= s->num_cameras)
            return pt_error_set(err, PT_ERR_ARG, "pt_anim_pose: the scene is not the rig's");
    for (const placed &pl : a.lights)
        if (pl.index >= s->num_punctual)
            return pt_error_set(err, PT_ERR_ARG, "pt_anim_pose: the scene is not the rig's");
    if (!a.moves) {
        // Every pose is the load's: the scene's own arrays, copied where the
        // output is elsewhere.
        size_t nv = s->num_vertices;
        if (out->positions && out->positions != s->positions)
            memcpy(out->positions, s->positions, 12 * nv);
        if (out->normals && out->normals != s->normals)
            memcpy(out->normals, s->normals, 12 * nv);
        if (out->tangents && s->tangents && out->tangents != s->tangents)
            memcpy(out->tangents, s->tangents, 16 * nv);
        if (out->cameras && out->cameras != s->cameras && s->num_cameras)
            memcpy(out->cameras, s->cameras, sizeof(pt_camera) * s->num_cameras);
        if (out->camera && out->camera != &s->camera)
            *out->camera = s->camera;
        if (out->punctual && out->punctual != s->punctual && s->num_punctual)
            memcpy(out->punctual, s->punctual, sizeof(pt_punctual) * s->num_punctual);
        out->bounds_min = s->bounds_min;
        out->bounds_max = s->bounds_max;
        return PT_OK;
    }
    pose_state ps;
    pose_nodes(a, t, ps);
    const double sc = a.scale;
    const double *org = s->origin;
    uint32_t nv_all = s->num_vertices;
    // Stored positions, normals and tangents start as the load's: a static
    // instance keeps them, bit for bit. World positions (double, scaled) of
    // the dynamic ones.
    std::vector<double> P(size_t(nv_all) * 3, 0.0);
    std::vector<float> F(s->positions, s->positions + size_t(nv_all) * 3);
    std::vector<float> N(s->normals, s->normals + size_t(nv_all) * 3);
    std::vector<float> TG;
    bool want_tan = s->tangents != nullptr;
    if (want_tan)
        TG.assign(s->tangents, s->tangents + size_t(nv_all) * 4);
    std::vector<uint8_t> dyn_tri(s->num_triangles, 0);
    std::vector<double> m, jm;
    for (const prim &p : a.prims) {
        if (!p.dynamic)
            continue;
        std::fill(N.begin() + 3 * long(p.v0), N.begin() + 3 * long(p.v0 + p.nv), 0.0f);
        if (want_tan)
            std::fill(TG.begin() + 4 * long(p.v0), TG.begin() + 4 * long(p.v0 + p.nv), 0.0f);
        std::fill(dyn_tri.begin() + long(p.t0), dyn_tri.begin() + long(p.t0 + p.nt), uint8_t(1));
        const node &nd = a.nodes[size_t(p.node)];
        const std::vector<double> &wts = ps.weights[size_t(p.node)];
        size_t ntg = p.dpos.size();
        const double *W = &ps.global[16 * size_t(p.node)];
        double Wi[16];
        if (p.has_inst) { // one instance of EXT_mesh_gpu_instancing
            mat_mul(W, p.inst, Wi);
            W = Wi;
        }
        double c[3][3];
        double det = 0.0;
        if (p.skin >= 0) {
            // Joint matrices: global(joint) * inverseBindMatrix.
            const skin &sk = a.skins[size_t(p.skin)];
            jm.resize(16 * sk.joints.size());
            for (size_t j = 0; j < sk.joints.size(); j++)
                mat_mul(&ps.global[16 * size_t(sk.joints[j])], &sk.ibm[16 * j], &jm[16 * j]);
        } else {
            det = pt_normal_matrix(W, c);
        }
        (void)nd;
        bool geo = p.nrm.empty();
        for (uint32_t v = 0; v < p.nv; v++) {
            double q[3], n[3] = {0, 0, 0}, tg[4] = {0, 0, 0, 1};
            for (int r = 0; r < 3; r++)
                q[r] = p.pos[3 * v + r];
            if (!p.nrm.empty())
                for (int r = 0; r < 3; r++)
                    n[r] = p.nrm[3 * v + r];
            if (!p.tan.empty())
                for (int r = 0; r < 4; r++)
                    tg[r] = p.tan[4 * v + r];
            for (size_t k = 0; k < ntg && k < wts.size(); k++) {
                double wk = wts[k];
                if (wk == 0.0)
                    continue;
                if (!p.dpos[k].empty())
                    for (int r = 0; r < 3; r++)
                        q[r] += wk * p.dpos[k][3 * v + r];
                if (!p.nrm.empty() && !p.dnrm[k].empty())
                    for (int r = 0; r < 3; r++)
                        n[r] += wk * p.dnrm[k][3 * v + r];
                if (!p.tan.empty() && !p.dtan[k].empty())
                    for (int r = 0; r < 3; r++)
                        tg[r] += wk * p.dtan[k][3 * v + r];
            }
            const double *M = W;
            double skinned[16];
            if (p.skin >= 0) {
                // sum_i w_i * jointMatrix_i, applied to the vertex.
                for (double &e : skinned)
                    e = 0.0;
                for (int i = 0; i < p.influences; i++) {
                    double wi = p.weights[size_t(v) * size_t(p.influences) + size_t(i)];
                    if (wi == 0.0)
                        continue;
                    const double *J =
                        &jm[16 * size_t(p.joints[size_t(v) * size_t(p.influences) + size_t(i)])];
                    for (int e = 0; e < 16; e++)
                        skinned[e] += wi * J[e];
                }
                M = skinned;
                det = pt_normal_matrix(M, c);
            }
            double *o = &P[3 * (size_t(p.v0) + v)];
            for (int r = 0; r < 3; r++)
                o[r] = (M[r] * q[0] + M[4 + r] * q[1] + M[8 + r] * q[2] + M[12 + r]) * sc +
                       a.translate[r];
            double nsign = det < 0 ? -1.0 : 1.0;
            if (!p.nrm.empty()) {
                double mn[3];
                for (int r = 0; r < 3; r++)
                    mn[r] = nsign * (c[r][0] * n[0] + c[r][1] * n[1] + c[r][2] * n[2]);
                normalise3(mn);
                if (mn[0] == 0.0 && mn[1] == 0.0 && mn[2] == 0.0)
                    geo = true;
                for (int r = 0; r < 3; r++)
                    N[3 * (size_t(p.v0) + v) + size_t(r)] = float(mn[r]);
            }
            if (want_tan && !p.tan.empty()) {
                double mt[3];
                for (int r = 0; r < 3; r++)
                    mt[r] = M[r] * tg[0] + M[4 + r] * tg[1] + M[8 + r] * tg[2];
                normalise3(mt);
                float *d = &TG[4 * (size_t(p.v0) + v)];
                if (mt[0] != 0.0 || mt[1] != 0.0 || mt[2] != 0.0) {
                    for (int r = 0; r < 3; r++)
                        d[r] = float(mt[r]);
                    d[3] = float(tg[3] * nsign);
                }
            }
        }
        if (geo) {
            // Area-weighted normals from the posed positions, for the
            // vertices without a usable one (as the builder does at load).
            std::vector<double> acc(size_t(p.nv) * 3, 0.0);
            for (uint32_t tri = p.t0; tri < p.t0 + p.nt; tri++) {
                const uint32_t *I = s->indices + 3 * size_t(tri);
                if (I[0] - p.v0 >= p.nv || I[1] - p.v0 >= p.nv || I[2] - p.v0 >= p.nv)
                    continue; // not this instance's (a scene other than the rig's)
                const double *p0 = &P[3 * size_t(I[0])], *p1 = &P[3 * size_t(I[1])],
                             *p2 = &P[3 * size_t(I[2])];
                double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
                double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
                double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                               e1[0] * e2[1] - e1[1] * e2[0]};
                if (!std::isfinite(g[0]) || !std::isfinite(g[1]) || !std::isfinite(g[2]))
                    continue;
                for (int k = 0; k < 3; k++)
                    for (int r = 0; r < 3; r++)
                        acc[3 * size_t(I[k] - p.v0) + size_t(r)] += g[r];
            }
            for (uint32_t v = 0; v < p.nv; v++) {
                float *n = &N[3 * (size_t(p.v0) + v)];
                if (n[0] != 0.0f || n[1] != 0.0f || n[2] != 0.0f)
                    continue;
                double g[3] = {acc[3 * v], acc[3 * v + 1], acc[3 * v + 2]};
                normalise3(g);
                if (g[0] == 0.0 && g[1] == 0.0 && g[2] == 0.0)
                    g[2] = 1.0;
                for (int r = 0; r < 3; r++)
                    n[r] = float(g[r]);
            }
        }
    }
    // Stored = float(world - origin) for the dynamic instances; bounds from
    // all the stored values.
    for (const prim &p : a.prims) {
        if (!p.dynamic)
            continue;
        for (size_t v = p.v0; v < size_t(p.v0) + p.nv; v++)
            for (int r = 0; r < 3; r++) {
                float q = float(P[3 * v + size_t(r)] - org[r]);
                if (!std::isfinite(q) ||
                    std::fabs(P[3 * v + size_t(r)]) > double(PT_SCENE_MAX_COORD))
                    return pt_error_set(err, PT_ERR_FORMAT,
                                        "animation at %g s: vertex %zu is not finite or over %g", t,
                                        v, double(PT_SCENE_MAX_COORD));
                F[3 * v + size_t(r)] = q;
            }
    }
    pt_vec3 lo = pt_v3(INFINITY, INFINITY, INFINITY), hi = pt_v3(-INFINITY, -INFINITY, -INFINITY);
    for (size_t v = 0; v < nv_all; v++) {
        const float *q = &F[3 * v];
        lo = pt_v3(fminf(lo.x, q[0]), fminf(lo.y, q[1]), fminf(lo.z, q[2]));
        hi = pt_v3(fmaxf(hi.x, q[0]), fmaxf(hi.y, q[1]), fmaxf(hi.z, q[2]));
    }
    if (want_tan) {
        // Regenerate what the load generated (scene.c, finish_extra): the
        // tangents of mapped triangles' vertices that the file does not give.
        std::vector<uint8_t> use(s->num_triangles);
        for (int set = 0; set < 2; set++) {
            const float *uv = set ? s->uvs1 : s->uvs;
            int any = 0;
            for (uint32_t tri = 0; tri < s->num_triangles; tri++) {
                const pt_material *mt = &s->materials[s->tri_material[tri]];
                int slot = mt->normal_tex >= 0 ? PT_SLOT_NORMAL : PT_SLOT_CLEARCOAT_NORMAL;
                int mapped =
                    mt->normal_tex >= 0 || (mt->clearcoat > 0.0f && mt->clearcoat_normal_tex >= 0);
                // Only the dynamic instances': the static keep the load's.
                use[tri] = dyn_tri[tri] && mapped && mt->tex_xf[slot].texcoord == set;
                any |= use[tri];
            }
            if (!any)
                continue;
            std::vector<float> flat;
            if (!uv) {
                flat.assign(size_t(nv_all) * 2, 0.0f);
                uv = flat.data();
            }
            pt_status st =
                pt_tangents_generate(F.data(), N.data(), uv, s->indices, s->num_triangles,
                                     use.data(), nv_all, TG.data(), err);
            if (st != PT_OK)
                return st;
        }
    }

    // Checked before anything is written, so that a failed pose leaves the
    // output as it was.
    std::vector<std::pair<uint32_t, pt_camera>> cams;
    std::vector<std::pair<uint32_t, pt_punctual>> lights;
    for (const placed &pc : a.cameras) {
        if (!pc.dynamic)
            continue;
        const double *w = &ps.global[16 * size_t(pc.node)];
        double pos[3];
        for (int r = 0; r < 3; r++)
            pos[r] = w[12 + r] * sc + a.translate[r] - org[r];
        pt_camera c = s->cameras[pc.index];
        place_camera(w, pos, &c);
        if (!pt_isfinite3(c.position))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "animation at %g s: camera '%.64s' is not finite", t, c.name);
        cams.push_back({pc.index, c});
    }
    for (const placed &pl : a.lights) {
        if (!pl.dynamic)
            continue;
        const double *w = &ps.global[16 * size_t(pl.node)];
        pt_punctual l = s->punctual[pl.index];
        double d[3] = {-w[8], -w[9], -w[10]};
        normalise3(d);
        if (d[0] != 0.0 || d[1] != 0.0 || d[2] != 0.0)
            l.direction = pt_v3(float(d[0]), float(d[1]), float(d[2]));
        l.position = pt_v3(float(w[12] * sc + a.translate[0] - org[0]),
                           float(w[13] * sc + a.translate[1] - org[1]),
                           float(w[14] * sc + a.translate[2] - org[2]));
        if (!pt_isfinite3(l.position))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "animation at %g s: light '%.64s' is not finite", t, l.name);
        lights.push_back({pl.index, l});
    }
    // Static cameras and lights keep the load's (copied where the output is
    // elsewhere), dynamic ones move.
    if (out->cameras && out->cameras != s->cameras && s->num_cameras)
        memcpy(out->cameras, s->cameras, sizeof(pt_camera) * s->num_cameras);
    if (out->camera && out->camera != &s->camera)
        *out->camera = s->camera;
    if (out->punctual && out->punctual != s->punctual && s->num_punctual)
        memcpy(out->punctual, s->punctual, sizeof(pt_punctual) * s->num_punctual);
    for (const auto &c : cams) {
        if (out->cameras)
            out->cameras[c.first] = c.second;
        if (out->camera && a.camera >= 0 && uint32_t(a.camera) == c.first)
            *out->camera = c.second;
    }
    for (const auto &l : lights)
        if (out->punctual)
            out->punctual[l.first] = l.second;
    if (out->positions)
        memcpy(out->positions, F.data(), F.size() * sizeof(float));
    if (out->normals)
        memcpy(out->normals, N.data(), N.size() * sizeof(float));
    if (out->tangents && want_tan)
        memcpy(out->tangents, TG.data(), TG.size() * sizeof(float));
    out->bounds_min = lo;
    out->bounds_max = hi;
    return PT_OK;
}

} // namespace

extern "C" pt_status pt_anim_pose_into(const pt_anim *anim, double t, const pt_scene *scene,
                                       pt_anim_pose_out *out, pt_error *err)
{
    if (!anim || !scene || !out)
        return pt_error_set(err, PT_ERR_ARG, "pt_anim_pose: no rig, scene or output");
    try {
        return pose(*anim, t, scene, out, err);
    } catch (const std::bad_alloc &) {
        return pt_error_set(err, PT_ERR_NOMEM, "animation: out of memory");
    }
}

extern "C" pt_status pt_anim_pose(const pt_anim *anim, double t, pt_scene *scene, pt_error *err)
{
    if (!scene)
        return pt_error_set(err, PT_ERR_ARG, "pt_anim_pose: no scene");
    pt_anim_pose_out o{};
    o.positions = scene->positions;
    o.normals = scene->normals;
    o.tangents = scene->tangents;
    o.cameras = scene->cameras;
    o.camera = &scene->camera;
    o.punctual = scene->punctual;
    pt_status st = pt_anim_pose_into(anim, t, scene, &o, err);
    if (st != PT_OK)
        return st;
    scene->bounds_min = o.bounds_min;
    scene->bounds_max = o.bounds_max;
    return PT_OK;
}

extern "C" void pt_anim_range(const pt_anim *anim, double *start, double *end)
{
    if (start)
        *start = anim ? anim->start : 0.0;
    if (end)
        *end = anim ? anim->end : 0.0;
}

extern "C" int pt_anim_moves(const pt_anim *anim)
{
    return anim && anim->moves;
}

extern "C" void pt_anim_free(pt_anim *anim)
{
    delete anim;
}

extern "C" pt_status pt_anim_range_view(const pt_anim *anim, const pt_scene *scene,
                                        const pt_scene_opts *opts, const pt_frames *frames,
                                        double fps, float aspect, char *out, size_t cap,
                                        pt_error *err)
{
    if (cap)
        out[0] = '\0';
    uint32_t n = pt_frames_count(frames);
    if (!scene->camera.framed || !pt_anim_moves(anim) || n < 2)
        return PT_OK;
    pt_vec3 lo = pt_v3(INFINITY, INFINITY, INFINITY), hi = pt_v3(-INFINITY, -INFINITY, -INFINITY);
    for (uint32_t i = 0; i < n; i++) {
        pt_anim_pose_out o{};
        pt_status st = pt_anim_pose_into(anim, pt_frames_time(pt_frames_number(frames, i), fps),
                                         scene, &o, err);
        if (st != PT_OK)
            return st;
        lo = pt_v3(fminf(lo.x, o.bounds_min.x), fminf(lo.y, o.bounds_min.y),
                   fminf(lo.z, o.bounds_min.z));
        hi = pt_v3(fmaxf(hi.x, o.bounds_max.x), fmaxf(hi.y, o.bounds_max.y),
                   fmaxf(hi.z, o.bounds_max.z));
    }
    if (!(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z))
        return PT_OK; /* nothing to frame: each frame's (a unit sphere's) view */
    pt_camera c;
    pt_camera_frame(lo, hi, aspect, &c);
    // Scene space back to the coordinates the options scale and move:
    // stored = world * sc + t - origin.
    double sc = opts && opts->scale != 0.0f ? double(opts->scale) : 1.0;
    double t[3] = {opts ? opts->translate.x : 0.0, opts ? opts->translate.y : 0.0,
                   opts ? opts->translate.z : 0.0};
    double from[3], at[3];
    const float p[3] = {c.position.x, c.position.y, c.position.z};
    const float m[3] = {0.5f * (lo.x + hi.x), 0.5f * (lo.y + hi.y), 0.5f * (lo.z + hi.z)};
    for (int k = 0; k < 3; k++) {
        from[k] = (double(p[k]) + scene->origin[k] - t[k]) / sc;
        at[k] = (double(m[k]) + scene->origin[k] - t[k]) / sc;
    }
    return pt_camera_look_text_fit(from, at, 0.0, 0.0, out, cap, err);
}
