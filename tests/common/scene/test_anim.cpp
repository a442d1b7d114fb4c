// test_anim.cpp - glTF animation (anim.h) against references computed here,
// independently of the importer: the test reads the files with tinygltf
// itself (its declarations only; the implementation is the one compiled into
// ptcore) and evaluates the glTF 2.0 formulas by hand.
//
// - Interpolation: InterpolationTest's nine cubes (STEP, LINEAR and
//   CUBICSPLINE on translation, rotation and scale) at times before the
//   first key, on the first key, between keys, on a key, on the last key and
//   after it: every vertex equals the node's hand-computed T * R * S applied
//   to the mesh's POSITION.
// - Skinning: the Fox's "Walk" at 0.3 s: every vertex equals
//   sum w_i * global(joint_i) * inverseBind_i * v from the accessors.
// - Re-posing: a rig posed at t1 then t2 is bit for bit a fresh load at t2
//   (positions, normals, bounds, cameras), for the three animated assets.
// - Hostile input: hand-written files (mismatched sampler counts, times out
//   of order, NaN times and keys, joints out of range, a skin whose joints
//   form a cycle, weights that do not match the targets) fail with
//   PT_ERR_FORMAT naming the element, and load as stills without animate.
// - Options: an unknown animation is PT_ERR_ARG listing the file's, a
//   negative or NaN time PT_ERR_ARG; an index chooses as the name does.
// - A file with nothing to animate loads animated as its still, bit for bit,
//   and so do the static parts of animated ones.
// - Stills: a skinned mesh's still is its skin posed with no animation
//   (bit for bit the animated load of a file without animations; the fox's
//   is its bind pose), and a morphed mesh's is at its default weights.
// - Morph weights animated (LINEAR) add the weighted target deltas; a
//   camera and a point light under an animated node follow it; a skin with
//   JOINTS_1/WEIGHTS_1 blends both sets, ignores the mesh node's transform
//   and turns normals by the inverse transpose.
// The same configuration as the importer's (gltf_import.cpp).
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <cmath>
#include <cstring>
#include <string>
#include <unistd.h>
#include <vector>

extern "C" {
#include "common/scene/anim.h"
#include "common/scene/motion.h"
}
#include "tests/check.h"
#include "tests/common/scene/gltf_writer.hpp"

namespace
{

std::string shared(const char *rel)
{
    return std::string(PT_SHARED_SCENES) + "/" + rel;
}

bool exists(const std::string &p)
{
    FILE *f = fopen(p.c_str(), "rb");
    if (f)
        fclose(f);
    return f != nullptr;
}

bool load_model(const std::string &path, tinygltf::Model &m)
{
    tinygltf::TinyGLTF loader;
    std::string err, warn;
    return loader.LoadBinaryFromFile(&m, &err, &warn, path);
}

// Accessor element i, component c, as a double (float, u8, u16).
double acc_get(const tinygltf::Model &m, int ai, size_t i, int c)
{
    const tinygltf::Accessor &a = m.accessors[size_t(ai)];
    const tinygltf::BufferView &v = m.bufferViews[size_t(a.bufferView)];
    int cs = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
    int nc = tinygltf::GetNumComponentsInType(uint32_t(a.type));
    size_t stride = v.byteStride ? v.byteStride : size_t(cs * nc);
    const unsigned char *p = m.buffers[size_t(v.buffer)].data.data() + v.byteOffset + a.byteOffset +
                             i * stride + size_t(c * cs);
    switch (a.componentType) {
    case TINYGLTF_COMPONENT_TYPE_FLOAT: {
        float f;
        memcpy(&f, p, 4);
        return f;
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
        return double(p[0] | p[1] << 8);
    default:
        return double(p[0]);
    }
}

typedef std::vector<double> mat; // 16, column-major

mat mul(const mat &a, const mat &b)
{
    mat r(16, 0.0);
    for (int c = 0; c < 4; c++)
        for (int rr = 0; rr < 4; rr++)
            for (int k = 0; k < 4; k++)
                r[size_t(c * 4 + rr)] += a[size_t(k * 4 + rr)] * b[size_t(c * 4 + k)];
    return r;
}

// The spec's T * R * S (glTF 2.0, 3.5.3), the quaternion normalised.
mat trs(const double t[3], const double q0[4], const double s[3])
{
    double l = std::sqrt(q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3]);
    double x = q0[0] / l, y = q0[1] / l, z = q0[2] / l, w = q0[3] / l;
    mat m(16, 0.0);
    // Rotation matrix columns.
    double R[3][3] = {{1 - 2 * y * y - 2 * z * z, 2 * x * y + 2 * z * w, 2 * x * z - 2 * y * w},
                      {2 * x * y - 2 * z * w, 1 - 2 * x * x - 2 * z * z, 2 * y * z + 2 * x * w},
                      {2 * x * z + 2 * y * w, 2 * y * z - 2 * x * w, 1 - 2 * x * x - 2 * y * y}};
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++)
            m[size_t(c * 4 + r)] = R[c][r] * s[c];
    m[12] = t[0];
    m[13] = t[1];
    m[14] = t[2];
    m[15] = 1.0;
    return m;
}

// A channel's value at time t, by the formulas of the spec's Appendix C.
std::vector<double> sample(const tinygltf::Model &m, const tinygltf::Animation &an,
                           const tinygltf::AnimationChannel &ch, double t)
{
    const tinygltf::AnimationSampler &s = an.samplers[size_t(ch.sampler)];
    size_t n = m.accessors[size_t(s.input)].count;
    int nc = ch.target_path == "rotation" ? 4 : 3;
    bool cubic = s.interpolation == "CUBICSPLINE";
    auto key = [&](size_t k) { return acc_get(m, s.input, k, 0); };
    // CUBICSPLINE elements: a_k (in-tangent), v_k, b_k (out-tangent).
    auto val = [&](size_t k, int part) {
        std::vector<double> v(static_cast<size_t>(nc));
        size_t e = cubic ? 3 * k + size_t(part) : k;
        for (int c = 0; c < nc; c++)
            v[size_t(c)] = acc_get(m, s.output, e, c);
        return v;
    };
    auto unit = [&](std::vector<double> v) {
        if (nc == 4) {
            double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]);
            for (double &x : v)
                x /= l;
        }
        return v;
    };
    if (t <= key(0))
        return unit(val(0, 1));
    if (t >= key(n - 1))
        return unit(val(n - 1, 1));
    size_t k = 0;
    while (!(key(k) <= t && t < key(k + 1)))
        k++;
    double tk = key(k), td = key(k + 1) - tk, u = (t - tk) / td;
    std::vector<double> out(static_cast<size_t>(nc));
    if (s.interpolation == "STEP")
        return val(k, 1);
    if (!cubic && nc == 4) {
        std::vector<double> a = val(k, 1), b = val(k + 1, 1);
        double d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
        if (d < 0) { // the shorter way round
            for (double &x : b)
                x = -x;
            d = -d;
        }
        double th = std::acos(std::fmin(d, 1.0));
        for (int c = 0; c < 4; c++)
            out[size_t(c)] =
                th < 1e-6
                    ? (1 - u) * a[size_t(c)] + u * b[size_t(c)]
                    : (std::sin((1 - u) * th) * a[size_t(c)] + std::sin(u * th) * b[size_t(c)]) /
                          std::sin(th);
        return unit(out);
    }
    if (!cubic) {
        std::vector<double> a = val(k, 1), b = val(k + 1, 1);
        for (int c = 0; c < nc; c++)
            out[size_t(c)] = a[size_t(c)] + u * (b[size_t(c)] - a[size_t(c)]);
        return out;
    }
    std::vector<double> p0 = val(k, 1), m0 = val(k, 2), p1 = val(k + 1, 1), m1 = val(k + 1, 0);
    for (int c = 0; c < nc; c++) {
        size_t i = size_t(c);
        out[i] = (2 * u * u * u - 3 * u * u + 1) * p0[i] +
                 (u * u * u - 2 * u * u + u) * td * m0[i] + (-2 * u * u * u + 3 * u * u) * p1[i] +
                 (u * u * u - u * u) * td * m1[i];
    }
    return unit(out);
}

// Global matrices of every node at time t with the channels of animation
// `which` (-1: all).
std::vector<mat> globals(const tinygltf::Model &m, int which, double t)
{
    size_t nn = m.nodes.size();
    std::vector<std::vector<double>> T(nn), R(nn), S(nn);
    for (size_t i = 0; i < nn; i++) {
        const tinygltf::Node &n = m.nodes[i];
        T[i] = n.translation.empty() ? std::vector<double>{0, 0, 0} : n.translation;
        R[i] = n.rotation.empty() ? std::vector<double>{0, 0, 0, 1} : n.rotation;
        S[i] = n.scale.empty() ? std::vector<double>{1, 1, 1} : n.scale;
    }
    for (size_t a = 0; a < m.animations.size(); a++) {
        if (which >= 0 && size_t(which) != a)
            continue;
        for (const auto &ch : m.animations[a].channels) {
            std::vector<double> v = sample(m, m.animations[a], ch, t);
            size_t ni = size_t(ch.target_node);
            (ch.target_path == "translation" ? T[ni]
             : ch.target_path == "rotation"  ? R[ni]
                                             : S[ni]) = v;
        }
    }
    std::vector<int> parent(nn, -1);
    for (size_t i = 0; i < nn; i++)
        for (int c : m.nodes[i].children)
            parent[size_t(c)] = int(i);
    std::vector<mat> g(nn);
    for (size_t i = 0; i < nn; i++) {
        mat w = trs(T[i].data(), R[i].data(), S[i].data());
        for (int p = parent[i]; p >= 0; p = parent[size_t(p)]) {
            size_t pi = size_t(p);
            w = mul(trs(T[pi].data(), R[pi].data(), S[pi].data()), w);
        }
        g[i] = w;
    }
    return g;
}

// The scene's vertex offset of each (node, primitive) in the order the
// importer visits the default scene (depth first, triangle primitives).
void offsets(const tinygltf::Model &m, int ni, std::vector<std::pair<int, size_t>> &out, size_t &nv)
{
    const tinygltf::Node &n = m.nodes[size_t(ni)];
    if (n.mesh >= 0)
        for (size_t p = 0; p < m.meshes[size_t(n.mesh)].primitives.size(); p++) {
            out.push_back({ni, nv});
            nv += m.accessors[size_t(
                                  m.meshes[size_t(n.mesh)].primitives[p].attributes.at("POSITION"))]
                      .count;
        }
    for (int c : n.children)
        offsets(m, c, out, nv);
}

pt_scene *load_at(const char *path, const char *animation, double t, pt_status *st, pt_error *err)
{
    pt_scene_opts o{};
    o.animate = 1;
    o.time = t;
    o.animation = animation;
    pt_scene *s = nullptr;
    *st = pt_scene_load(path, &o, &s, err);
    return s;
}

void test_interpolation()
{
    std::string path = shared("InterpolationTest/InterpolationTest.glb");
    tinygltf::Model m;
    if (!exists(path) || !load_model(path, m)) {
        if (check_shared_required())
            CHECKF(0, "%s is missing", path.c_str());
        else
            CHECK_SKIP("%s is missing", path.c_str());
        return;
    }
    std::vector<std::pair<int, size_t>> inst;
    size_t nv = 0;
    for (int ni : m.scenes[0].nodes)
        offsets(m, ni, inst, nv);
    // The times: before the first key of the samplers starting at 1/24 s,
    // the keys themselves (first, inner, last), between keys, after.
    std::vector<double> times = {0.0, 0.02, 0.25, 0.5, 0.9, 1.3, 1.69, 1.75, 3.0};
    for (const auto &an : m.animations)
        for (const auto &ch : an.channels) {
            const tinygltf::AnimationSampler &s = an.samplers[size_t(ch.sampler)];
            size_t n = m.accessors[size_t(s.input)].count;
            for (size_t k = 0; k < n; k++)
                times.push_back(acc_get(m, s.input, k, 0));
        }
    int checked_interp[3] = {0, 0, 0};
    for (const auto &an : m.animations) {
        const std::string &ip = an.samplers[0].interpolation;
        checked_interp[ip == "STEP" ? 0 : ip == "LINEAR" ? 1 : 2]++;
    }
    CHECKF(checked_interp[0] == 3 && checked_interp[1] == 3 && checked_interp[2] == 3,
           "InterpolationTest has 3 STEP, 3 LINEAR and 3 CUBICSPLINE animations");
    int worst_node = -1;
    double worst = 0.0, worst_t = 0.0;
    size_t compared = 0;
    for (double t : times) {
        pt_error err{};
        pt_status st;
        pt_scene *s = load_at(path.c_str(), "all", t, &st, &err);
        CHECKF(st == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        CHECK(s->num_vertices == nv);
        std::vector<mat> g = globals(m, -1, t);
        for (const auto &in : inst) {
            const tinygltf::Node &n = m.nodes[size_t(in.first)];
            int pa = m.meshes[size_t(n.mesh)].primitives[0].attributes.at("POSITION");
            size_t cnt = m.accessors[size_t(pa)].count;
            const mat &w = g[size_t(in.first)];
            for (size_t v = 0; v < cnt && in.second + v < s->num_vertices; v++) {
                double p[3] = {acc_get(m, pa, v, 0), acc_get(m, pa, v, 1), acc_get(m, pa, v, 2)};
                for (int r = 0; r < 3; r++) {
                    double want = w[size_t(r)] * p[0] + w[size_t(4 + r)] * p[1] +
                                  w[size_t(8 + r)] * p[2] + w[size_t(12 + r)] - s->origin[r];
                    double got = s->positions[3 * (in.second + v) + size_t(r)];
                    double d = std::fabs(got - want) / std::fmax(1.0, std::fabs(want));
                    if (d > worst) {
                        worst = d;
                        worst_node = in.first;
                        worst_t = t;
                    }
                    compared++;
                }
            }
        }
        pt_scene_free(s);
    }
    CHECKF(worst < 2e-6, "node %d at %g s is off by %g (relative)", worst_node, worst_t, worst);
    CHECK(compared > 1000);
}

void test_fox_skinning()
{
    std::string path = shared("Fox/Fox.glb");
    tinygltf::Model m;
    if (!exists(path) || !load_model(path, m)) {
        if (check_shared_required())
            CHECKF(0, "%s is missing", path.c_str());
        else
            CHECK_SKIP("%s is missing", path.c_str());
        return;
    }
    int walk = -1;
    for (size_t a = 0; a < m.animations.size(); a++)
        if (m.animations[a].name == "Walk")
            walk = int(a);
    CHECK(walk >= 0);
    const double t = 0.3;
    const tinygltf::Skin &sk = m.skins[0];
    // Joint matrices global(joint) * inverseBind with animation `which` at
    // t (which past the animations: none, every node at its own TRS).
    auto joints = [&](int which, double at) {
        std::vector<mat> g = globals(m, which, at);
        std::vector<mat> jm;
        for (size_t j = 0; j < sk.joints.size(); j++) {
            mat ibm(16);
            for (int e = 0; e < 16; e++)
                ibm[size_t(e)] = acc_get(m, sk.inverseBindMatrices, j, e);
            jm.push_back(mul(g[size_t(sk.joints[j])], ibm));
        }
        return jm;
    };
    std::vector<mat> jm = joints(walk, t), rest = joints(int(m.animations.size()), 0.0);
    const tinygltf::Primitive &p = m.meshes[0].primitives[0];
    int pa = p.attributes.at("POSITION"), ja = p.attributes.at("JOINTS_0"),
        wa = p.attributes.at("WEIGHTS_0");
    pt_error err{};
    pt_status st;
    pt_scene *s = load_at(path.c_str(), "Walk", t, &st, &err);
    CHECKF(st == PT_OK, "%s", err.msg);
    pt_scene_opts still{};
    pt_scene *s0 = nullptr;
    CHECK(pt_scene_load(path.c_str(), &still, &s0, &err) == PT_OK);
    if (!s || !s0) {
        pt_scene_free(s);
        pt_scene_free(s0);
        return;
    }
    size_t nv = m.accessors[size_t(pa)].count;
    CHECK(s->num_vertices == nv && s0->num_vertices == nv);
    // The still is the skin posed with no animation (each joint at its own
    // TRS, as viewers show it), which for the fox is its bind pose: every
    // joint matrix the identity, every vertex its POSITION.
    double worst = 0.0, moved = 0.0, worst_still = 0.0, worst_bind = 0.0;
    for (size_t v = 0; v < nv && v < s->num_vertices && v < s0->num_vertices; v++) {
        double q[3] = {acc_get(m, pa, v, 0), acc_get(m, pa, v, 1), acc_get(m, pa, v, 2)};
        double want[3] = {0, 0, 0}, want0[3] = {0, 0, 0};
        for (int i = 0; i < 4; i++) {
            double wi = acc_get(m, wa, v, i);
            const mat &J = jm[size_t(acc_get(m, ja, v, i))];
            const mat &J0 = rest[size_t(acc_get(m, ja, v, i))];
            for (int r = 0; r < 3; r++) {
                want[r] += wi * (J[size_t(r)] * q[0] + J[size_t(4 + r)] * q[1] +
                                 J[size_t(8 + r)] * q[2] + J[size_t(12 + r)]);
                want0[r] += wi * (J0[size_t(r)] * q[0] + J0[size_t(4 + r)] * q[1] +
                                  J0[size_t(8 + r)] * q[2] + J0[size_t(12 + r)]);
            }
        }
        for (int r = 0; r < 3; r++) {
            double got = s->positions[3 * v + size_t(r)] + s->origin[r];
            double got0 = s0->positions[3 * v + size_t(r)] + s0->origin[r];
            worst = std::fmax(worst, std::fabs(got - want[r]));
            worst_still = std::fmax(worst_still, std::fabs(got0 - want0[r]));
            worst_bind = std::fmax(worst_bind, std::fabs(got0 - q[r]));
            moved = std::fmax(moved, std::fabs(got - got0));
        }
    }
    CHECKF(worst_still < 1e-3, "the still's skinned vertices are off by up to %g", worst_still);
    CHECKF(worst_bind < 1e-3, "the still is off the bind pose by up to %g", worst_bind);
    // The fox is ~170 units long: float rounding is under 1e-4 of it.
    CHECKF(worst < 1e-3, "skinned vertices are off by up to %g", worst);
    CHECKF(moved > 1.0, "the walk moves vertices from the still by %g only", moved);
    // Normals are unit length and finite.
    int bad = 0;
    for (size_t v = 0; v < s->num_vertices; v++) {
        const float *n = s->normals + 3 * v;
        double l = std::sqrt(double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2]);
        bad += !(std::fabs(l - 1.0) < 1e-5);
    }
    CHECK(bad == 0);
    pt_scene_free(s);
    pt_scene_free(s0);
}

bool same_scene(const pt_scene *a, const pt_scene *b)
{
    size_t nv = a->num_vertices;
    bool ok =
        a->num_vertices == b->num_vertices && memcmp(a->positions, b->positions, 12 * nv) == 0 &&
        memcmp(a->normals, b->normals, 12 * nv) == 0 && (!a->tangents) == (!b->tangents) &&
        (!a->tangents || memcmp(a->tangents, b->tangents, 16 * nv) == 0) &&
        memcmp(&a->bounds_min, &b->bounds_min, sizeof a->bounds_min) == 0 &&
        memcmp(&a->bounds_max, &b->bounds_max, sizeof a->bounds_max) == 0 &&
        memcmp(&a->camera, &b->camera, sizeof a->camera) == 0 && a->num_cameras == b->num_cameras &&
        a->num_punctual == b->num_punctual && memcmp(a->origin, b->origin, sizeof a->origin) == 0;
    for (uint32_t i = 0; ok && i < a->num_cameras; i++)
        ok = memcmp(&a->cameras[i], &b->cameras[i], sizeof(pt_camera)) == 0;
    for (uint32_t i = 0; ok && i < a->num_punctual; i++)
        ok = memcmp(&a->punctual[i], &b->punctual[i], sizeof(pt_punctual)) == 0;
    return ok;
}

void test_repose()
{
    const char *files[3] = {"Fox/Fox.glb", "BoxAnimated/BoxAnimated.glb",
                            "InterpolationTest/InterpolationTest.glb"};
    for (const char *f : files) {
        std::string path = shared(f);
        if (!exists(path)) {
            if (check_shared_required())
                CHECKF(0, "%s is missing", path.c_str());
            else
                CHECK_SKIP("%s is missing", path.c_str());
            continue;
        }
        pt_scene_opts o{};
        o.animate = 1;
        o.time = 0.0;
        o.animation = "all"; // every node moves
        pt_scene *s = nullptr;
        pt_anim *a = nullptr;
        pt_error err{};
        CHECKF(pt_anim_load(path.c_str(), &o, &s, &a, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        CHECK(pt_anim_moves(a));
        double t0 = -1, t1 = -1;
        pt_anim_range(a, &t0, &t1);
        CHECK(t0 >= 0.0 && t1 > t0);
        const double times[3] = {1.3, 0.45, 0.8125};
        for (double t : times) {
            CHECKF(pt_anim_pose(a, t, s, &err) == PT_OK, "%s", err.msg);
            pt_status st;
            pt_scene *fresh = load_at(path.c_str(), "all", t, &st, &err);
            CHECKF(st == PT_OK, "%s", err.msg);
            if (fresh) {
                CHECKF(same_scene(s, fresh), "%s at %g s: re-posed differs from a fresh load", f,
                       t);
                // Into separate arrays: the same bits.
                std::vector<float> P(3 * size_t(s->num_vertices)), N(P.size());
                pt_anim_pose_out out{};
                out.positions = P.data();
                out.normals = N.data();
                CHECK(pt_anim_pose_into(a, t, fresh, &out, &err) == PT_OK);
                CHECK(memcmp(P.data(), fresh->positions, P.size() * 4) == 0);
                CHECK(memcmp(N.data(), fresh->normals, N.size() * 4) == 0);
            }
            pt_scene_free(fresh);
        }
        // The pose differs from another time's (the test would pass
        // vacuously on a rig that did not move).
        pt_status st;
        pt_scene *early = load_at(path.c_str(), "all", 0.6, &st, &err);
        if (early)
            CHECKF(!same_scene(s, early), "%s: poses at 0.6 s and 0.8125 s are the same", f);
        pt_scene_free(early);
        // Another file's scene, smaller than the rig's: refused, not read.
        pt_scene *other =
            load_at(shared("BoxAnimated/BoxAnimated.glb").c_str(), nullptr, 0.0, &st, &err);
        if (other && other->num_vertices < s->num_vertices)
            CHECK(pt_anim_pose(a, 0.5, other, &err) == PT_ERR_ARG);
        pt_scene_free(other);
        CHECK(pt_anim_pose(a, -1.0, s, &err) == PT_ERR_ARG);
        CHECK(pt_anim_pose(a, NAN, s, &err) == PT_ERR_ARG);
        pt_anim_free(a);
        pt_scene_free(s);
    }
}

// The static instances of an animated scene keep the still's bits at any
// time (BoxAnimated's base, node 3; InterpolationTest's plane, node 11,
// rotated, scaled and moved), while the animated ones move.
void test_static_parts(const char *rel, int static_node)
{
    std::string path = shared(rel);
    tinygltf::Model m;
    if (!exists(path) || !load_model(path, m)) {
        if (check_shared_required())
            CHECKF(0, "%s is missing", path.c_str());
        else
            CHECK_SKIP("%s is missing", path.c_str());
        return;
    }
    std::vector<std::pair<int, size_t>> inst;
    size_t nv = 0;
    for (int ni : m.scenes[0].nodes)
        offsets(m, ni, inst, nv);
    pt_scene_opts o{};
    pt_scene *still = nullptr;
    pt_error err{};
    pt_status st;
    CHECK(pt_scene_load(path.c_str(), &o, &still, &err) == PT_OK);
    pt_scene *s = load_at(path.c_str(), "all", 0.75, &st, &err);
    CHECKF(st == PT_OK, "%s", err.msg);
    int seen = 0;
    if (s && still && s->num_vertices == nv) {
        for (size_t i = 0; i < inst.size(); i++) {
            size_t v0 = inst[i].second, v1 = i + 1 < inst.size() ? inst[i + 1].second : nv;
            bool same =
                memcmp(s->positions + 3 * v0, still->positions + 3 * v0, 12 * (v1 - v0)) == 0 &&
                memcmp(s->normals + 3 * v0, still->normals + 3 * v0, 12 * (v1 - v0)) == 0;
            if (inst[i].first == static_node) {
                CHECKF(same, "%s: static node %d moved", rel, static_node);
                seen++;
            } else {
                CHECKF(!same, "%s: node %d did not move", rel, inst[i].first);
            }
        }
    }
    CHECKF(seen == 1, "%s: node %d not found", rel, static_node);
    pt_scene_free(s);
    pt_scene_free(still);
}

// ---- hand-written files ----------------------------------------------------------------

using pt_test::gltf;

const std::vector<float> k_tri = {0, 0, 0, 1, 0, 0, 0, 1, 0};

std::string write_tmp(const std::string &text, const char *name)
{
    std::string p =
        std::string("/tmp/pt_test_anim_") + std::to_string(getpid()) + "_" + name + ".gltf";
    FILE *f = fopen(p.c_str(), "wb");
    if (f) {
        fwrite(text.data(), 1, text.size(), f);
        fclose(f);
    }
    return p;
}

// The file fails with animate (PT_ERR_FORMAT, message containing `want`).
// Without animate, a fault in an animation leaves the still as it is (a
// still reads no animation); one in a skin or in morph weights fails it too,
// with the same message (a still poses its skins and default weights).
void hostile(const char *name, const std::string &text, const char *want, bool still_fails)
{
    std::string p = write_tmp(text, name);
    pt_error err{};
    pt_status st;
    pt_scene *s = load_at(p.c_str(), nullptr, 0.5, &st, &err);
    CHECKF(st == PT_ERR_FORMAT && !s, "%s: status %d, '%s'", name, int(st), err.msg);
    CHECKF(strstr(err.msg, want) != nullptr, "%s: message '%s' lacks '%s'", name, err.msg, want);
    pt_scene_free(s);
    pt_scene_opts still{};
    still.warn = [](void *, const char *) {};
    s = nullptr;
    st = pt_scene_load(p.c_str(), &still, &s, &err);
    if (still_fails) {
        CHECKF(st == PT_ERR_FORMAT && !s, "%s as a still: status %d", name, int(st));
        CHECKF(strstr(err.msg, want) != nullptr, "%s as a still: '%s' lacks '%s'", name, err.msg,
               want);
    } else {
        CHECKF(st == PT_OK, "%s as a still: %s", name, err.msg);
    }
    pt_scene_free(s);
    unlink(p.c_str());
}

// An animation of node 0's translation with the given times, values and
// interpolation.
std::string anim_file(const std::vector<float> &times, const std::vector<float> &values,
                      const char *interp)
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int in = g.floats(times, "SCALAR", 1), out = g.floats(values, "VEC3", 3);
    char a[300];
    snprintf(a, sizeof a,
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
             "\"POSITION\":0}}]}],\"animations\":[{\"name\":\"Move\",\"channels\":[{\"sampler\":0,"
             "\"target\":{\"node\":0,\"path\":\"translation\"}}],\"samplers\":[{\"input\":%d,"
             "\"output\":%d,\"interpolation\":\"%s\"}]}]",
             in, out, interp);
    return g.json(a);
}

// What the loader says through opts->warn, gathered.
void gather(void *user, const char *msg)
{
    static_cast<std::string *>(user)->append(msg).append("\n");
}

// A file with two animations of node 0's translation, "Move" along x and
// "Lift" along y: a pose with none named plays the first and says so once;
// "all" plays both (the later channel wins: Lift); an index or a name picks one.
void test_default_first()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int in = g.floats({0, 1}, "SCALAR", 1);
    int mx = g.floats({0, 0, 0, 2, 0, 0}, "VEC3", 3), my = g.floats({0, 0, 0, 0, 2, 0}, "VEC3", 3);
    char a[700];
    snprintf(a, sizeof a,
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
             "\"POSITION\":0}}]}],\"animations\":["
             "{\"name\":\"Move\",\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,\"path\":"
             "\"translation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]},"
             "{\"name\":\"Lift\",\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,\"path\":"
             "\"translation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
             in, mx, in, my);
    std::string p = write_tmp(g.json(a), "two");
    struct pick {
        const char *animation;
        double x, y;
        bool said;
    } picks[] = {{nullptr, 1, 0, true}, {"", 1, 0, true},      {"all", 0, 1, false},
                 {"1", 0, 1, false},    {"Move", 1, 0, false}, {"0", 1, 0, false}};
    for (const pick &k : picks) {
        std::string said;
        pt_scene_opts o{};
        o.animate = 1;
        o.time = 0.5;
        o.animation = k.animation;
        o.warn = gather;
        o.warn_user = &said;
        pt_scene *s = nullptr;
        pt_error err{};
        CHECKF(pt_scene_load(p.c_str(), &o, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        double x = s->positions[0] + s->origin[0], y = s->positions[1] + s->origin[1];
        const char *name = k.animation ? k.animation : "(none)";
        CHECKF(std::fabs(x - k.x) < 1e-6 && std::fabs(y - k.y) < 1e-6, "%s: at (%g, %g)", name, x,
               y);
        bool first = said.find("2 animations; playing the first, 0 'Move'") != std::string::npos;
        CHECKF(first == k.said, "%s: said '%s'", name, said.c_str());
        CHECKF(said.find("playing the first") == said.rfind("playing the first"),
               "%s: said it twice", name);
        pt_scene_free(s);
    }
    unlink(p.c_str());
    // One animation: nothing to say.
    std::string one = write_tmp(anim_file({0, 1}, {0, 0, 0, 2, 0, 0}, "LINEAR"), "one");
    std::string said;
    pt_scene_opts o{};
    o.animate = 1;
    o.time = 0.5;
    o.warn = gather;
    o.warn_user = &said;
    pt_scene *s = nullptr;
    pt_error err{};
    CHECK(pt_scene_load(one.c_str(), &o, &s, &err) == PT_OK && said.empty());
    pt_scene_free(s);
    unlink(one.c_str());
}

void test_hostile()
{
    // A well-formed one first: it loads and moves.
    {
        std::string p = write_tmp(anim_file({0, 1}, {0, 0, 0, 2, 0, 0}, "LINEAR"), "good");
        pt_error err{};
        pt_status st;
        pt_scene *s = load_at(p.c_str(), nullptr, 0.5, &st, &err);
        CHECKF(st == PT_OK, "%s", err.msg);
        if (s)
            CHECKF(std::fabs(s->positions[0] + s->origin[0] - 1.0) < 1e-6, "x %g",
                   double(s->positions[0]));
        pt_scene_free(s);
        // Unknown animation: PT_ERR_ARG listing the file's; by index and name.
        s = load_at(p.c_str(), "Walk", 0.5, &st, &err);
        CHECK(st == PT_ERR_ARG && !s);
        CHECKF(strstr(err.msg, "0 'Move'") != nullptr, "%s", err.msg);
        s = load_at(p.c_str(), "1", 0.5, &st, &err);
        CHECK(st == PT_ERR_ARG);
        s = load_at(p.c_str(), "0", 0.5, &st, &err);
        CHECK(st == PT_OK);
        pt_scene_free(s);
        s = load_at(p.c_str(), "Move", 0.5, &st, &err);
        CHECK(st == PT_OK);
        pt_scene_free(s);
        s = load_at(p.c_str(), nullptr, -0.5, &st, &err);
        CHECK(st == PT_ERR_ARG && !s);
        s = load_at(p.c_str(), nullptr, NAN, &st, &err);
        CHECK(st == PT_ERR_ARG && !s);
        unlink(p.c_str());
    }
    hostile("count", anim_file({0, 1}, {0, 0, 0, 1, 0, 0, 2, 0, 0}, "LINEAR"),
            "animation 0 ('Move') sampler 0: 9 output numbers for 2 keys", false);
    hostile("cubic-count", anim_file({0, 1}, {0, 0, 0, 1, 0, 0}, "CUBICSPLINE"),
            "6 output numbers for 2 keys", false);
    hostile("order", anim_file({0, 1, 0.5f}, {0, 0, 0, 1, 0, 0, 2, 0, 0}, "LINEAR"),
            "input times are not increasing at key 2", false);
    hostile("nan-time", anim_file({0, NAN}, {0, 0, 0, 1, 0, 0}, "STEP"),
            "input of animation 0 ('Move') sampler 0): element 1 is not finite", false);
    hostile("nan-key", anim_file({0, 1}, {0, 0, 0, 1, NAN, 0}, "LINEAR"),
            "output of animation 0 ('Move') sampler 0): element 1 is not finite", false);
    // Skins: node 0 is the skinned mesh, joints node 1 (and node 2).
    auto skin_file = [](uint16_t joint, bool cycle) {
        gltf g;
        g.floats(k_tri, "VEC3", 3);
        uint16_t j[12] = {0, 0, 0, 0, joint, 0, 0, 0, 0, 0, 0, 0};
        int ja = g.add(j, sizeof j, 5123, "VEC4", 3);
        int wa = g.floats({1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0}, "VEC4", 4);
        // The cycle: node 1 under node 2 and node 2 under node 1, out of
        // the scene; else both joints under the mesh's node.
        const char *nodes = cycle ? "{\"mesh\":0,\"skin\":0},{\"children\":[2]},{\"children\":[1]}"
                                  : "{\"mesh\":0,\"skin\":0,\"children\":[1,2]},{},{}";
        char a[400];
        snprintf(a, sizeof a,
                 "\"nodes\":[%s],\"skins\":[{\"joints\":[1,2]}],\"meshes\":[{\"primitives\":[{"
                 "\"attributes\":{\"POSITION\":0,\"JOINTS_0\":%d,\"WEIGHTS_0\":%d}}]}]",
                 nodes, ja, wa);
        return g.json(a);
    };
    hostile("joint", skin_file(7, false), "vertex 1 names joint 7, but skin 0 has 2 joints", true);
    hostile("cycle", skin_file(0, true), "skin 0: joint node 1: the node hierarchy has a cycle",
            true);
    // Morph weights: two targets, one weight.
    {
        gltf g;
        g.floats(k_tri, "VEC3", 3);
        int d0 = g.floats({0, 0, 1, 0, 0, 1, 0, 0, 1}, "VEC3", 3);
        int d1 = g.floats({0, 1, 0, 0, 1, 0, 0, 1, 0}, "VEC3", 3);
        char a[300];
        snprintf(a, sizeof a,
                 "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"weights\":[0.5],\"primitives\":[{"
                 "\"attributes\":{\"POSITION\":0},\"targets\":[{\"POSITION\":%d},{\"POSITION\":%"
                 "d}]}]}]",
                 d0, d1);
        hostile("weights", g.json(a), "mesh 0: 1 weights for 2 morph targets", true);
    }
    // Morph targets that are well-formed: weights animated, LINEAR.
    {
        gltf g;
        g.floats(k_tri, "VEC3", 3);
        int d0 = g.floats({0, 0, 1, 0, 0, 1, 0, 0, 1}, "VEC3", 3);
        int d1 = g.floats({0, 1, 0, 0, 1, 0, 0, 1, 0}, "VEC3", 3);
        int in = g.floats({0, 2}, "SCALAR", 1);
        int out = g.floats({0, 1, 1, 0}, "SCALAR", 1); // key 0: (0, 1); key 1: (1, 0)
        char a[600];
        snprintf(a, sizeof a,
                 "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"weights\":[0.25,0.5],\"primitives\":[{"
                 "\"attributes\":{\"POSITION\":0},\"targets\":[{\"POSITION\":%d},{\"POSITION\":%"
                 "d}]}]}],\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,"
                 "\"path\":\"weights\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
                 d0, d1, in, out);
        std::string p = write_tmp(g.json(a), "morph");
        pt_error err{};
        pt_status st;
        pt_scene *s = load_at(p.c_str(), nullptr, 0.5, &st, &err);
        CHECKF(st == PT_OK, "%s", err.msg);
        if (s) {
            // Weights (0.25, 0.75) at 0.5 s: vertex 1 = (1, 0, 0) + 0.25 z + 0.75 y.
            const float *v = s->positions + 3;
            CHECKF(std::fabs(v[0] + s->origin[0] - 1.0) < 1e-6 &&
                       std::fabs(v[1] + s->origin[1] - 0.75) < 1e-6 &&
                       std::fabs(v[2] + s->origin[2] - 0.25) < 1e-6,
                   "morphed vertex (%g, %g, %g)", double(v[0]), double(v[1]), double(v[2]));
        }
        pt_scene_free(s);
        // Without animate: the still, at the mesh's default weights (0.25,
        // 0.5): vertex 1 = (1, 0, 0) + 0.25 z + 0.5 y, as viewers show it.
        pt_scene_opts still{};
        still.warn = [](void *, const char *) {};
        s = nullptr;
        CHECK(pt_scene_load(p.c_str(), &still, &s, &err) == PT_OK);
        if (s) {
            const float *v = s->positions + 3;
            CHECKF(std::fabs(v[0] + s->origin[0] - 1.0) < 1e-6 &&
                       std::fabs(v[1] + s->origin[1] - 0.5) < 1e-6 &&
                       std::fabs(v[2] + s->origin[2] - 0.25) < 1e-6,
                   "still vertex (%g, %g, %g)", double(v[0]), double(v[1]), double(v[2]));
        }
        pt_scene_free(s);
        unlink(p.c_str());
    }
}

// A camera and a point light under an animated node move with it, and the
// rendered camera (the file's first) with them.
void test_follow()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int in = g.floats({0, 1}, "SCALAR", 1), out = g.floats({0, 0, 0, 2, 0, 0}, "VEC3", 3);
    char a[900];
    snprintf(
        a, sizeof a,
        "\"extensionsUsed\":[\"KHR_lights_punctual\"],\"extensions\":{\"KHR_lights_punctual\":"
        "{\"lights\":[{\"type\":\"point\",\"intensity\":2}]}},"
        "\"nodes\":[{\"mesh\":0,\"children\":[1,2]},{\"camera\":0,\"translation\":[0,0,5]},"
        "{\"translation\":[0,3,0],\"extensions\":{\"KHR_lights_punctual\":{\"light\":0}}}],"
        "\"cameras\":[{\"type\":\"perspective\",\"perspective\":{\"yfov\":0.7,\"znear\":0.1}}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,\"path\":"
        "\"translation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
        in, out);
    std::string p = write_tmp(g.json(a), "follow");
    pt_error err{};
    pt_status st;
    pt_scene *s = load_at(p.c_str(), nullptr, 0.5, &st, &err);
    CHECKF(st == PT_OK, "%s", err.msg);
    if (s) {
        CHECK(s->num_cameras == 1 && s->num_punctual == 1);
        pt_vec3 c = s->cameras[0].position, r = s->camera.position, l = s->punctual[0].position;
        const double *o = s->origin;
        CHECKF(std::fabs(c.x + o[0] - 1) < 1e-6 && std::fabs(c.y + o[1]) < 1e-6 &&
                   std::fabs(c.z + o[2] - 5) < 1e-6,
               "camera at (%g, %g, %g)", double(c.x), double(c.y), double(c.z));
        CHECK(memcmp(&r, &c, sizeof r) == 0);
        CHECK(std::fabs(s->camera.forward.z + 1.0f) < 1e-6f);
        CHECKF(std::fabs(l.x + o[0] - 1) < 1e-6 && std::fabs(l.y + o[1] - 3) < 1e-6 &&
                   std::fabs(l.z + o[2]) < 1e-6,
               "light at (%g, %g, %g)", double(l.x), double(l.y), double(l.z));
    }
    pt_scene_free(s);
    unlink(p.c_str());
}

// JOINTS_1/WEIGHTS_1 and normals by the inverse transpose: each vertex half
// on joint 0 (scale (2, 1, 1)) by its first set and half on joint 1
// (translation (0, 0, 1)) by its second, so the blended matrix is
// diag(1.5, 1, 1) with translation (0, 0, 0.5); a normal (1, 1, 0)/sqrt 2
// becomes normalize(1/1.5, 1, 0). No animation: a rig with a skin only.
void test_skin_sets()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    const float h = 0.70710678f;
    int na = g.floats({h, h, 0, h, h, 0, h, h, 0}, "VEC3", 3);
    uint16_t j0[12] = {0}, j1[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};
    int j0a = g.add(j0, sizeof j0, 5123, "VEC4", 3), j1a = g.add(j1, sizeof j1, 5123, "VEC4", 3);
    int w0a = g.floats({0.5f, 0, 0, 0, 0.5f, 0, 0, 0, 0.5f, 0, 0, 0}, "VEC4", 4);
    int w1a = g.floats({0.5f, 0, 0, 0, 0.5f, 0, 0, 0, 0.5f, 0, 0, 0}, "VEC4", 4);
    char a[600];
    snprintf(a, sizeof a,
             "\"nodes\":[{\"mesh\":0,\"skin\":0,\"translation\":[9,9,9],\"children\":[1,2]},"
             "{\"scale\":[2,1,1]},{\"translation\":[0,0,1]}],\"skins\":[{\"joints\":[1,2]}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"NORMAL\":%d,"
             "\"JOINTS_0\":%d,\"WEIGHTS_0\":%d,\"JOINTS_1\":%d,\"WEIGHTS_1\":%d}}]}]",
             na, j0a, w0a, j1a, w1a);
    std::string p = write_tmp(g.json(a), "skinsets");
    pt_error err{};
    pt_status st;
    pt_scene *s = load_at(p.c_str(), nullptr, 0.0, &st, &err);
    CHECKF(st == PT_OK, "%s", err.msg);
    if (s) {
        // The joints hang under the mesh node (translation 9, 9, 9): their
        // globals include it, the mesh node's own transform is not applied
        // on top.
        for (int v = 0; v < 3; v++) {
            double want[3] = {1.5 * k_tri[size_t(3 * v)] + 9, k_tri[size_t(3 * v + 1)] + 9,
                              k_tri[size_t(3 * v + 2)] + 9.5};
            for (int r = 0; r < 3; r++)
                CHECKF(std::fabs(s->positions[3 * v + r] + s->origin[r] - want[r]) < 1e-5,
                       "vertex %d axis %d: %g, want %g", v, r,
                       s->positions[3 * v + r] + s->origin[r], want[r]);
            double n[3] = {1 / 1.5, 1, 0}, l = std::sqrt(n[0] * n[0] + n[1] * n[1]);
            for (int r = 0; r < 3; r++)
                CHECKF(std::fabs(s->normals[3 * v + r] - n[r] / l) < 1e-6, "normal %d axis %d: %g",
                       v, r, double(s->normals[3 * v + r]));
        }
    }
    // A still poses the skin as that load does (no animation: every joint
    // at its own TRS), bit for bit: the vertices checked just above, not the
    // mesh node's (9, 9, 9) translation of the unskinned positions.
    pt_scene_opts still{};
    pt_scene *s0 = nullptr;
    CHECKF(pt_scene_load(p.c_str(), &still, &s0, &err) == PT_OK, "%s", err.msg);
    if (s && s0)
        CHECK(same_scene(s, s0));
    pt_scene_free(s0);
    pt_scene_free(s);
    unlink(p.c_str());
}

// A file with nothing to animate (the Cornell box) loads with animate 1 as
// its still, bit for bit, and its rig does not move; naming an animation
// there is an error.
void test_static()
{
    std::string path = std::string(PT_SOURCE_DIR) + "/scenes/cornell_box.gltf";
    pt_scene_opts o{};
    o.warn = [](void *, const char *) {};
    pt_scene *still = nullptr, *s = nullptr;
    pt_anim *a = nullptr;
    pt_error err{};
    CHECKF(pt_scene_load(path.c_str(), &o, &still, &err) == PT_OK, "%s", err.msg);
    o.animate = 1;
    o.time = 2.5;
    CHECKF(pt_anim_load(path.c_str(), &o, &s, &a, &err) == PT_OK, "%s", err.msg);
    if (still && s) {
        CHECK(!pt_anim_moves(a));
        CHECK(same_scene(s, still));
        CHECK(pt_anim_pose(a, 7.0, s, &err) == PT_OK);
        CHECK(same_scene(s, still));
        std::vector<float> P(3 * size_t(s->num_vertices));
        pt_anim_pose_out out{};
        out.positions = P.data();
        CHECK(pt_anim_pose_into(a, 1.0, s, &out, &err) == PT_OK);
        CHECK(memcmp(P.data(), still->positions, P.size() * 4) == 0);
    }
    pt_anim_free(a);
    pt_scene_free(s);
    pt_scene_free(still);
    o.animation = "Walk";
    s = nullptr;
    CHECK(pt_scene_load(path.c_str(), &o, &s, &err) == PT_ERR_ARG && !s);
    CHECKF(strstr(err.msg, "the scene has no animations") != nullptr, "%s", err.msg);
}

// A static instance far from the origin (the still rounds its node matrix
// to float, as the importer always has) keeps the still's bits beside an
// animated one.
void test_static_far()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int in = g.floats({0, 1}, "SCALAR", 1), out = g.floats({0, 0, 0, 2, 0, 0}, "VEC3", 3);
    char a[600];
    snprintf(a, sizeof a,
             "\"nodes\":[{\"children\":[1,2]},{\"mesh\":0,\"translation\":[123456.789,0.1,0.3]},"
             "{\"mesh\":0,\"translation\":[123450.5,0,0]}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
             "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":2,\"path\":"
             "\"translation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
             in, out);
    std::string p = write_tmp(g.json(a), "far");
    pt_scene_opts o{};
    pt_scene *still = nullptr;
    pt_error err{};
    pt_status st;
    CHECK(pt_scene_load(p.c_str(), &o, &still, &err) == PT_OK);
    pt_scene *s = load_at(p.c_str(), nullptr, 0.5, &st, &err);
    CHECKF(st == PT_OK, "%s", err.msg);
    if (s && still) {
        CHECK(memcmp(s->origin, still->origin, sizeof s->origin) == 0);
        CHECKF(memcmp(s->positions, still->positions, 36) == 0, "static x %.9g, still %.9g",
               double(s->positions[0]), double(still->positions[0]));
        CHECK(memcmp(s->positions + 9, still->positions + 9, 36) != 0);
    }
    pt_scene_free(s);
    pt_scene_free(still);
    unlink(p.c_str());
}

// Motion blur's steps double while the motion curves, up to 17 for a half
// turn, and stop before the scene's triangles times the steps pass the cap:
// 3 steps under a cap of 3 a triangle, and 2 (linear) always.
void test_motion_cap()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    const float h = float(std::sqrt(0.5));
    int in = g.floats({0, 0.5f, 1}, "SCALAR", 1);
    int out = g.floats({0, 0, 0, 1, 0, h, 0, h, 0, 1, 0, 0}, "VEC4", 4);
    char a[600];
    snprintf(a, sizeof a,
             "\"nodes\":[{\"mesh\":0,\"translation\":[0.5,0,0]}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
             "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,\"path\":"
             "\"rotation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
             in, out);
    std::string p = write_tmp(g.json(a), "motioncap");
    pt_scene_opts o{};
    o.animate = 1;
    pt_scene *s = nullptr;
    pt_anim *rig = nullptr;
    pt_error err{};
    CHECKF(pt_anim_load(p.c_str(), &o, &s, &rig, &err) == PT_OK, "%s", err.msg);
    if (s && rig) {
        CHECKF(pt_motion_from_anim(s, rig, 0.0, 1.0, &err) == PT_OK, "%s", err.msg);
        CHECKF(s->motion && s->motion->steps == 17, "steps %u", s->motion ? s->motion->steps : 0u);
        CHECKF(pt_motion_from_anim_cap(s, rig, 0.0, 1.0, 3ull * s->num_triangles, &err) == PT_OK,
               "%s", err.msg);
        CHECKF(s->motion && s->motion->steps == 3, "steps %u", s->motion ? s->motion->steps : 0u);
        CHECKF(pt_motion_from_anim_cap(s, rig, 0.0, 1.0, 0, &err) == PT_OK, "%s", err.msg);
        CHECKF(s->motion && s->motion->steps == 2, "steps %u", s->motion ? s->motion->steps : 0u);
    }
    pt_anim_free(rig);
    pt_scene_free(s);
    unlink(p.c_str());
}

// Morph target deltas are counted with every instance before the rig keeps
// a copy of them for each: a triangle with 1,024 targets (one accessor of
// deltas for all) under 15 levels of shared nodes is 2^15 x 3 x 1024
// deltas, refused for an animated load; a still, whose default weights are
// all 0, needs no rig and loads.
void test_morph_cap()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int d = g.floats({0.1f, 0, 0, 0.1f, 0, 0, 0.1f, 0, 0}, "VEC3", 3);
    std::string m = "\"nodes\":[";
    for (int i = 0; i < 15; i++)
        m += "{\"children\":[" + std::to_string(i + 1) + "," + std::to_string(i + 1) + "]},";
    m += "{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},"
         "\"targets\":[";
    for (int k = 0; k < 1024; k++)
        m += (k ? ",{\"POSITION\":" : "{\"POSITION\":") + std::to_string(d) + "}";
    m += "]}]}]";
    std::string p = write_tmp(g.json(m), "morphcap");
    pt_scene_opts o{};
    o.warn = [](void *, const char *) {};
    pt_scene *s = nullptr;
    pt_anim *rig = nullptr;
    pt_error err{};
    CHECK(pt_anim_load(p.c_str(), &o, &s, &rig, &err) == PT_ERR_LIMIT && !s && !rig);
    CHECKF(strstr(err.msg,
                  "100663296 morph target deltas (vertices x targets) once every "
                  "instance of its meshes is counted, over the cap of 67108864") != nullptr,
           "%s", err.msg);
    CHECKF(pt_scene_load(p.c_str(), &o, &s, &err) == PT_OK && s && s->num_triangles == 32768, "%s",
           err.msg);
    pt_scene_free(s);
    unlink(p.c_str());
}

} // namespace

// The largest of |x| / tan(xfov/2) and |y| / tan(yfov/2) over the corners of
// [lo, hi] (scene space) seen by c (scene space) in an image of aspect a,
// or 1e9 when a corner is behind it: <= 1 when the box is in the frame.
double box_reach(const pt_camera &c, pt_vec3 lo, pt_vec3 hi, double a)
{
    double ty = std::tan(0.5 * double(c.yfov)), tx = ty * a, reach = 0.0;
    for (int k = 0; k < 8; k++) {
        double v[3] = {double(k & 1 ? hi.x : lo.x) - double(c.position.x),
                       double(k & 2 ? hi.y : lo.y) - double(c.position.y),
                       double(k & 4 ? hi.z : lo.z) - double(c.position.z)};
        double z = v[0] * c.forward.x + v[1] * c.forward.y + v[2] * c.forward.z;
        double x = v[0] * c.right.x + v[1] * c.right.y + v[2] * c.right.z;
        double y = v[0] * c.up.x + v[1] * c.up.y + v[2] * c.up.z;
        if (!(z > 0.0))
            return 1e9;
        reach = std::max(reach, std::max(std::fabs(x) / (z * tx), std::fabs(y) / (z * ty)));
    }
    return reach;
}

// A frame range of a file without a camera is seen from one place
// (pt_anim_range_view): every frame's posed bounds are in the frame, one
// of them within 10 % of its edge (the view is fitted, with 5 % to spare),
// while the view framed at the first frame alone loses a later frame's lid
// (so the union is what holds them). A file's camera or a scene that does
// not move gives no placement (each frame's own framing is that view).
void test_range_view()
{
    std::string path = shared("BoxAnimated/BoxAnimated.glb");
    if (!exists(path)) {
        if (check_shared_required())
            CHECKF(0, "%s is missing", path.c_str());
        else
            CHECK_SKIP("%s is missing", path.c_str());
        return;
    }
    pt_scene_opts o{};
    o.animate = 1;
    pt_scene *s = nullptr;
    pt_anim *a = nullptr;
    pt_error err{};
    CHECK(pt_anim_load(path.c_str(), &o, &s, &a, &err) == PT_OK);
    if (!s)
        return;
    const pt_frames fr = {0, 88, 4};
    const double fps = 24.0, aspect = 1.5;
    char look[65];
    CHECK(pt_anim_range_view(a, s, &o, &fr, fps, float(aspect), look, sizeof look, &err) == PT_OK);
    CHECKF(strncmp(look, PT_CAMERA_LOOK_PREFIX, strlen(PT_CAMERA_LOOK_PREFIX)) == 0,
           "no placement: '%s'", look);
    pt_camera c{};
    CHECK(pt_camera_look_parse(look, &c, &err) == PT_OK);
    for (int k = 0; k < 3; k++)
        (&c.position.x)[k] -= float(s->origin[k]);
    pt_camera first;
    pt_camera_frame(s->bounds_min, s->bounds_max, float(aspect), &first);
    double widest = 0.0, first_widest = 0.0;
    for (uint32_t i = 0; i < pt_frames_count(&fr); i++) {
        pt_anim_pose_out po{};
        double t = pt_frames_time(pt_frames_number(&fr, i), fps);
        CHECK(pt_anim_pose_into(a, t, s, &po, &err) == PT_OK);
        double r = box_reach(c, po.bounds_min, po.bounds_max, aspect);
        CHECKF(r <= 1.0, "frame %u: the posed bounds reach %g of the half-frame", i, r);
        widest = std::max(widest, r);
        first_widest =
            std::max(first_widest, box_reach(first, po.bounds_min, po.bounds_max, aspect));
    }
    CHECKF(widest > 0.9, "the view is loose: the widest frame reaches %g of the half-frame",
           widest);
    CHECKF(first_widest > 1.0, "the first frame's own view holds every frame (%g): no test",
           first_widest);
    // A camera given: nothing to place.
    pt_scene_opts oc = o;
    oc.camera_name = "look:0,1,5:0,0,0";
    pt_scene *sc = nullptr;
    pt_anim *ac = nullptr;
    CHECK(pt_anim_load(path.c_str(), &oc, &sc, &ac, &err) == PT_OK);
    if (sc) {
        CHECK(pt_anim_range_view(ac, sc, &oc, &fr, fps, 1.0f, look, sizeof look, &err) == PT_OK);
        CHECKF(look[0] == 0, "a given camera was replaced by '%s'", look);
    }
    pt_anim_free(ac);
    pt_scene_free(sc);
    // A file that does not move: the same.
    std::string still = shared("MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.glb");
    pt_scene *ss = nullptr;
    pt_anim *as = nullptr;
    if (exists(still) && pt_anim_load(still.c_str(), &o, &ss, &as, &err) == PT_OK) {
        CHECK(pt_anim_range_view(as, ss, &o, &fr, fps, 1.0f, look, sizeof look, &err) == PT_OK);
        CHECKF(look[0] == 0, "a still scene got '%s'", look);
    } else {
        CHECKF(!check_shared_required(), "%s: %s", still.c_str(), err.msg);
    }
    pt_anim_free(as);
    pt_scene_free(ss);
    pt_anim_free(a);
    pt_scene_free(s);
}

int main(void)
{
    test_interpolation();
    test_fox_skinning();
    test_repose();
    test_static_parts("BoxAnimated/BoxAnimated.glb", 3);
    test_static_parts("InterpolationTest/InterpolationTest.glb", 11);
    test_hostile();
    test_default_first();
    test_follow();
    test_skin_sets();
    test_static();
    test_static_far();
    test_motion_cap();
    test_morph_cap();
    test_range_view();
    return check_report();
}
