// anim_rig.hpp - the rig of anim.h as the importer (gltf_import.cpp) reads
// it and the poser (anim.cpp) uses it. Internal to common/scene.
//
// Everything here has been checked by the importer: node, skin, sampler and
// joint indices are in range, times are finite and strictly increasing,
// keys are finite, counts agree (outputs per key, weights per target), the
// parent links form a forest and `order` lists every node after its parent.
#ifndef PT_COMMON_SCENE_ANIM_RIG_HPP
#define PT_COMMON_SCENE_ANIM_RIG_HPP

#include <cstdint>
#include <vector>

extern "C" {
#include "common/scene/anim.h"
}

namespace pt_rig
{

// A node's local matrix, column-major into m[16]: T * R * S with R from the
// quaternion (x, y, z, w) normalised first (glTF 3.5.3). The importer builds
// a still's node matrices with it and the rig its posed ones, so an
// unanimated node gets the same bits either way.
void trs_matrix(const double t[3], const double q[4], const double s[3], double *m);

enum path_kind { PATH_T = 0, PATH_R = 1, PATH_S = 2, PATH_W = 3 };
enum interp_kind { INTERP_STEP = 0, INTERP_LINEAR = 1, INTERP_CUBIC = 2 };

struct node {
    int parent = -1;
    bool has_matrix = false;
    double matrix[16];                                              // column-major, when has_matrix
    double t[3] = {0, 0, 0}, r[4] = {0, 0, 0, 1}, s[3] = {1, 1, 1}; // TRS otherwise
    std::vector<double> weights; // morph weights (node's, else its mesh's), empty without targets
};

struct sampler {
    int interp = INTERP_LINEAR;
    int comps = 0;         // numbers per value (3, 4, or the number of morph targets)
    std::vector<float> in; // key times, strictly increasing, finite
    std::vector<float>
        out; // comps per value; CUBICSPLINE: (in-tangent, value, out-tangent) per key
};

struct channel {
    int node = 0;
    int path = PATH_T;
    int sampler = 0; // index into pt_anim::samplers
};

struct skin {
    std::vector<int> joints; // node indices
    std::vector<double> ibm; // 16 per joint, column-major
};

// One mesh primitive instance of the scene: vertices [v0, v0 + nv) and
// triangles [t0, t0 + nt) of the built scene.
struct prim {
    int node = 0, mesh = 0, index = 0;
    int skin = -1;
    bool dynamic = false; // skinned, morphed or under an animated node: posed; else kept
    uint32_t v0 = 0, nv = 0, t0 = 0, nt = 0;
    std::vector<float> pos;       // 3 per vertex, mesh space
    std::vector<float> nrm;       // 3 per vertex, or empty: normals from the posed positions
    std::vector<float> tan;       // 4 per vertex (w = +-1), or empty: generated when needed
    int influences = 0;           // 0, 4 or 8 joints per vertex
    std::vector<uint32_t> joints; // influences per vertex, each < the skin's joints
    std::vector<float> weights;   // influences per vertex
    std::vector<std::vector<float>> dpos, dnrm, dtan; // per target: 3 per vertex, or empty
    bool has_inst = false; // EXT_mesh_gpu_instancing: global(node) * inst places it
    double inst[16] = {0};
};

struct placed {
    int node = 0;
    uint32_t index = 0;   // into scene->cameras or scene->punctual
    bool dynamic = false; // under an animated node: posed; else kept
};

} // namespace pt_rig

struct pt_anim {
    std::vector<pt_rig::node> nodes;
    std::vector<int> order; // every node after its parent
    std::vector<pt_rig::sampler> samplers;
    std::vector<pt_rig::channel> channels; // of the chosen animation(s), in file order
    std::vector<pt_rig::skin> skins;
    std::vector<pt_rig::prim> prims;
    std::vector<pt_rig::placed> cameras, lights;
    int camera = -1; // scene->camera is cameras[camera] of the scene; -1: framed
    double scale = 1.0, translate[3] = {0, 0, 0};
    double start = 0.0, end = 0.0;
    bool moves = false;
};

#endif
