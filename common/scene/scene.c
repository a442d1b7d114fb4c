/*
 * scene.c - the scene builder (shared by the glTF importer and procedural
 * scenes), texture lookup, default camera and material.
 *
 * Every mesh goes through pt_scene_builder_add_mesh, so the validation
 * (finite coordinates under PT_SCENE_MAX_COORD, indices in range, caps) is the
 * same whatever the source. Normals are transformed by the inverse transpose
 * of the upper 3x3 (computed as the cofactor matrix times sign(det), which has
 * the same direction); a transform with a negative determinant mirrors space,
 * so the triangle winding is flipped to keep the geometric normal on the side
 * the shading normals point to.
 *
 * Rebasing: world-space positions (node transform, then opts' scale and
 * translation) are kept in double until pt_scene_builder_finish, which moves
 * the scene next to the origin before rounding to float. A float's ULP at 1e5
 * is 8 mm, so georeferenced data stored as world-space floats would lose its
 * detail and push the ray offsets (Waechter & Binder, 256 ULPs) to metres;
 * stored relative to a nearby origin, positions keep float's full relative
 * precision whatever the translation, and rendering is translation invariant,
 * so nothing downstream needs to know (world = stored + scene->origin).
 */
#include "common/scene/scene.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <openssl/evp.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/base/opt.h"
#include "common/scene/gltf_import.h"
#include "common/scene/motion.h"
#include "common/scene/tangent.h"

struct pt_scene_builder {
    double *pos; /* world space, before opts' scale/translate; float only at finish */
    float *nrm, *uv;
    uint32_t nv, cap_pos, cap_nrm, cap_uv;
    int has_uv;
    /* The optional attributes (pt_mesh_extra): NULL until a mesh has one,
     * then kept for every vertex, with defaults for meshes without it. */
    float *uv1, *tan, *col;
    uint32_t cap_uv1, cap_tan, cap_col;
    uint32_t *idx, *tmat, *tobj;
    uint32_t nt, cap_idx, cap_tmat, cap_tobj;
    pt_scene_name *objs; /* distinct object names */
    uint32_t nobj, cap_obj;
    int32_t cur_obj; /* pt_scene_builder_set_object's, or -1: each mesh's `what` */
    pt_material *mats;
    uint32_t nmat, cap_mat;
    pt_texture *texs;
    uint32_t ntex, cap_tex;
    uint64_t texels; /* width * height summed over texs (PT_SCENE_MAX_TEXELS) */
    pt_camera *cams;
    double *cam_pos; /* 3 per camera: the world-space position in double */
    uint32_t ncam, cap_cam, cap_cam_pos;
    pt_punctual *puns;
    double *pun_pos; /* 3 per light: the world-space position in double */
    uint32_t npun, cap_pun, cap_pun_pos;
    double *portals; /* 9 per portal triangle: its world-space corners */
    uint32_t nportal, cap_portal;
    int hash_set;
    char hash[65];
    pt_motion_build *motion; /* moving meshes' time steps, or NULL (motion.h) */
    /* Instancing: the prototypes (their triangles and vertices at the end
     * of the arrays), whether one is being added, and each instance's
     * world matrix (16 doubles, column-major) and prototype. */
    pt_prototype *protos;
    uint32_t nproto, cap_proto;
    int in_proto;
    double *inst_xf;
    uint32_t *inst_proto;
    uint32_t *inst_obj; /* the object at add_instance, or UINT32_MAX: the prototype's */
    uint32_t ninst, cap_inst_xf, cap_inst_proto, cap_inst_obj;
};

/* Grows *p (elements of `elem` bytes, `per` per item) to hold `need` items. */
static int reserve(void **p, uint32_t *cap, uint32_t need, size_t elem, size_t per)
{
    if (need <= *cap)
        return 1;
    uint64_t n = (uint64_t)*cap * 2;
    if (n < need)
        n = need;
    if (n < 16)
        n = 16;
    if (n > UINT32_MAX)
        n = UINT32_MAX;
    size_t bytes;
    if (__builtin_mul_overflow((size_t)n, elem * per, &bytes))
        return 0;
    void *q = pt_realloc(*p, bytes);
    if (!q)
        return 0;
    *p = q;
    *cap = (uint32_t)n;
    return 1;
}

pt_material pt_material_default(void)
{
    pt_material m;
    memset(&m, 0, sizeof m);
    for (int i = 0; i < 4; i++)
        m.base_color[i] = 1.0f;
    m.base_color_tex = -1;
    m.metallic = 1.0f;
    m.roughness = 1.0f;
    m.metal_rough_tex = -1;
    m.emissive_tex = -1;
    m.specular = 1.0f;
    for (int i = 0; i < 3; i++)
        m.specular_color[i] = 1.0f;
    m.transmission_tex = -1;
    m.ior = 1.5f;
    for (int i = 0; i < 3; i++)
        m.attenuation_color[i] = 1.0f;
    m.double_sided = 0;
    m.alpha_mode = PT_ALPHA_OPAQUE;
    m.alpha_cutoff = 0.5f;
    m.normal_tex = -1;
    m.normal_scale = 1.0f;
    m.clearcoat_normal_tex = -1;
    m.clearcoat_normal_scale = 1.0f;
    m.clearcoat_tex = m.clearcoat_rough_tex = m.sheen_color_tex = m.sheen_rough_tex = -1;
    m.specular_tex = m.specular_color_tex = m.sg_tex = -1;
    for (int i = 0; i < 3; i++)
        m.sg_specular[i] = 1.0f;
    m.sg_glossiness = 1.0f;
    m.iridescence_tex = m.irid_thickness_tex = m.anisotropy_tex = -1;
    m.diffuse_transmission_tex = m.diffuse_transmission_color_tex = -1;
    for (int i = 0; i < 3; i++)
        m.diffuse_transmission_color[i] = 1.0f;
    m.iridescence_ior = 1.3f;
    m.irid_thickness_min = 100.0f;
    m.irid_thickness_max = 400.0f;
    for (int i = 0; i < PT_SLOT_COUNT; i++)
        m.tex_xf[i] = pt_tex_xform_identity();
    snprintf(m.name, sizeof m.name, "default");
    return m;
}

pt_status pt_scene_builder_new(pt_scene_builder **out, pt_error *err)
{
    pt_scene_builder *b = pt_calloc(1, sizeof *b);
    if (!b)
        return pt_error_set(err, PT_ERR_NOMEM, "scene builder: out of memory");
    b->cur_obj = -1;
    *out = b;
    return PT_OK;
}

static void free_textures(pt_texture *t, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++)
        if (t[i].member == 0) /* the others' texels are in the block of a member 0 */
            pt_free(t[i].rgba);
    pt_free(t);
}

void pt_scene_builder_free(pt_scene_builder *b)
{
    if (!b)
        return;
    pt_free(b->pos);
    pt_free(b->nrm);
    pt_free(b->uv);
    pt_free(b->uv1);
    pt_free(b->tan);
    pt_free(b->col);
    pt_free(b->idx);
    pt_free(b->tmat);
    pt_free(b->tobj);
    pt_free(b->objs);
    pt_free(b->mats);
    free_textures(b->texs, b->ntex);
    pt_free(b->cams);
    pt_free(b->cam_pos);
    pt_free(b->puns);
    pt_free(b->pun_pos);
    pt_free(b->portals);
    pt_motion_build_free(b->motion);
    pt_free(b->protos);
    pt_free(b->inst_xf);
    pt_free(b->inst_proto);
    pt_free(b->inst_obj);
    pt_free(b);
}

void pt_scene_builder_set_hash(pt_scene_builder *b, const char *hex)
{
    snprintf(b->hash, sizeof b->hash, "%s", hex);
    b->hash_set = 1;
}

uint32_t pt_scene_builder_num_materials(const pt_scene_builder *b)
{
    return b->nmat;
}

/* The index of the object named `name` (cut to 63 bytes), added when new. */
static pt_status object_of(pt_scene_builder *b, const char *name, uint32_t *out, pt_error *err)
{
    pt_scene_name n;
    snprintf(n.s, sizeof n.s, "%s", name);
    /* From the last: a node's primitives come one after another. */
    for (uint32_t i = b->nobj; i-- > 0;)
        if (!strcmp(b->objs[i].s, n.s)) {
            *out = i;
            return PT_OK;
        }
    if (!reserve((void **)&b->objs, &b->cap_obj, b->nobj + 1, sizeof n, 1))
        return pt_error_set(err, PT_ERR_NOMEM, "object %s: out of memory", n.s);
    b->objs[b->nobj] = n;
    *out = b->nobj++;
    return PT_OK;
}

pt_status pt_scene_builder_set_object(pt_scene_builder *b, const char *name, pt_error *err)
{
    uint32_t i = 0;
    pt_status st = object_of(b, name, &i, err);
    if (st == PT_OK)
        b->cur_obj = (int32_t)i;
    return st;
}

void pt_scene_builder_counts(const pt_scene_builder *b, uint32_t counts[4])
{
    counts[0] = b->nv;
    counts[1] = b->nt;
    counts[2] = b->ncam;
    counts[3] = b->npun;
}

static int finite_n(const float *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

/* The transmission and volume fields, checked only when the material
 * transmits (a zero-filled material stays valid). KHR_materials_ior allows
 * ior 0 (F0 = 1) as well as >= 1. */
static pt_status check_transmission(const pt_scene_builder *b, const pt_material *m,
                                    const char *name, pt_error *err)
{
    if (!(m->transmission >= 0.0f && m->transmission <= 1.0f))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': transmissionFactor %g is outside [0, 1]", name,
                            (double)m->transmission);
    /* A diffuse transmitter's volume is checked too (its medium). */
    if (m->transmission == 0.0f && !(m->diffuse_transmission > 0.0f))
        return PT_OK;
    if (m->transmission > 0.0f && !(m->ior == 0.0f || (m->ior >= 1.0f && isfinite(m->ior))))
        return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': ior %g is not 0 or >= 1", name,
                            (double)m->ior);
    if (!(m->thickness >= 0.0f && isfinite(m->thickness)))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': thicknessFactor %g is negative or not finite", name,
                            (double)m->thickness);
    if (!(m->attenuation_distance >= 0.0f))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': attenuationDistance %g is not positive", name,
                            (double)m->attenuation_distance);
    for (int i = 0; i < 3; i++)
        if (!(m->attenuation_color[i] >= 0.0f && m->attenuation_color[i] <= 1.0f))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "material '%.64s': attenuationColor[%d] %g is outside [0, 1]", name,
                                i, (double)m->attenuation_color[i]);
    if (m->transmission_tex < -1 ||
        (m->transmission_tex >= 0 && (uint32_t)m->transmission_tex >= b->ntex))
        return pt_error_set(err, PT_ERR_ARG, "material '%.64s': texture %d out of range", name,
                            (int)m->transmission_tex);
    return PT_OK;
}

/* The clearcoat, sheen, specular and specular-glossiness texture indices,
 * and the specular-glossiness factors (in [0, 1], as the extension bounds
 * them). */
static pt_status check_layers(const pt_scene_builder *b, const pt_material *m, const char *name,
                              pt_error *err)
{
    const int32_t t[13] = {m->diffuse_transmission_tex,
                           m->diffuse_transmission_color_tex,
                           m->clearcoat_tex,
                           m->clearcoat_rough_tex,
                           m->sheen_color_tex,
                           m->sheen_rough_tex,
                           m->clearcoat_normal_tex,
                           m->specular_tex,
                           m->specular_color_tex,
                           m->sg_tex,
                           m->iridescence_tex,
                           m->irid_thickness_tex,
                           m->anisotropy_tex};
    if (!isfinite(m->clearcoat_normal_scale))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': clearcoat normal scale is not finite", name);
    const float sg[4] = {m->sg_specular[0], m->sg_specular[1], m->sg_specular[2], m->sg_glossiness};
    for (int i = 0; i < 4; i++)
        if (!(sg[i] >= 0.0f && sg[i] <= 1.0f))
            return pt_error_set(
                err, PT_ERR_FORMAT, "material '%.64s': %s %g is outside [0, 1]", name,
                i < 3 ? "specularGlossiness specularFactor" : "glossinessFactor", (double)sg[i]);
    if (!(m->iridescence >= 0.0f && m->iridescence <= 1.0f))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': iridescenceFactor %g is outside [0, 1]", name,
                            (double)m->iridescence);
    if (!(m->iridescence_ior >= 1.0f && isfinite(m->iridescence_ior)))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': iridescenceIor %g is not a finite number >= 1", name,
                            (double)m->iridescence_ior);
    /* Films past 1 mm are no longer thin (and a float's OPD then loses the
     * phase): refused. */
    const float th[2] = {m->irid_thickness_min, m->irid_thickness_max};
    for (int i = 0; i < 2; i++)
        if (!(th[i] >= 0.0f && th[i] <= 1e6f))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "material '%.64s': iridescenceThickness%s %g nm is outside "
                                "[0, 1e6]",
                                name, i ? "Maximum" : "Minimum", (double)th[i]);
    if (!(m->anisotropy >= 0.0f && m->anisotropy <= 1.0f) || !isfinite(m->anisotropy_rotation))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': anisotropyStrength %g is outside [0, 1] or "
                            "anisotropyRotation %g is not finite",
                            name, (double)m->anisotropy, (double)m->anisotropy_rotation);
    if (!(m->dispersion >= 0.0f && isfinite(m->dispersion)))
        return pt_error_set(err, PT_ERR_FORMAT,
                            "material '%.64s': dispersion %g is negative or not finite", name,
                            (double)m->dispersion);
    const float dt[4] = {m->diffuse_transmission, m->diffuse_transmission_color[0],
                         m->diffuse_transmission_color[1], m->diffuse_transmission_color[2]};
    for (int i = 0; i < 4; i++)
        if (!(dt[i] >= 0.0f && dt[i] <= 1.0f))
            return pt_error_set(
                err, PT_ERR_FORMAT, "material '%.64s': %s %g is outside [0, 1]", name,
                i ? "diffuseTransmissionColorFactor" : "diffuseTransmissionFactor", (double)dt[i]);
    for (int i = 0; i < 13; i++)
        if (t[i] < -1 || (t[i] >= 0 && (uint32_t)t[i] >= b->ntex))
            return pt_error_set(err, PT_ERR_ARG, "material '%.64s': texture %d out of range", name,
                                (int)t[i]);
    return PT_OK;
}

pt_status pt_scene_builder_add_material(pt_scene_builder *b, const pt_material *m, uint32_t *index,
                                        pt_error *err)
{
    const char *name = m->name[0] ? m->name : "(unnamed)";
    if (!finite_n(m->base_color, 4) || !isfinite(m->metallic) || !isfinite(m->roughness) ||
        !finite_n(m->emissive, 3) || !isfinite(m->specular) || !finite_n(m->specular_color, 3))
        return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': factor is NaN or infinite",
                            name);
    if (m->emissive[0] < 0 || m->emissive[1] < 0 || m->emissive[2] < 0)
        return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': negative emission", name);
    /* glTF 2.0 (5.22, 5.23) bounds these factors to [0, 1]; outside it the
     * BSDF gains energy or its roughness mapping breaks, so a file that says
     * otherwise is rejected rather than silently clamped. */
    const struct {
        const char *field;
        float v;
    } unit[] = {{"baseColorFactor[0]", m->base_color[0]}, {"baseColorFactor[1]", m->base_color[1]},
                {"baseColorFactor[2]", m->base_color[2]}, {"baseColorFactor[3]", m->base_color[3]},
                {"metallicFactor", m->metallic},          {"roughnessFactor", m->roughness},
                {"specularFactor", m->specular}};
    for (size_t i = 0; i < sizeof unit / sizeof unit[0]; i++)
        if (!(unit[i].v >= 0.0f && unit[i].v <= 1.0f))
            return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': %s %g is outside [0, 1]",
                                name, unit[i].field, (double)unit[i].v);
    for (int i = 0; i < 3; i++)
        if (m->specular_color[i] < 0.0f)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "material '%.64s': specularColorFactor[%d] %g is negative", name, i,
                                (double)m->specular_color[i]);
    if (m->alpha_mode != PT_ALPHA_OPAQUE && m->alpha_mode != PT_ALPHA_MASK &&
        m->alpha_mode != PT_ALPHA_BLEND)
        return pt_error_set(err, PT_ERR_ARG, "material '%.64s': alpha mode %d is unknown", name,
                            m->alpha_mode);
    /* glTF 2.0 (5.19): alphaCutoff has minimum 0 and no maximum (above 1 a
     * MASK material is nowhere present). */
    if (!(m->alpha_cutoff >= 0.0f) || !isfinite(m->alpha_cutoff))
        return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': alphaCutoff %g is not >= 0",
                            name, (double)m->alpha_cutoff);
    pt_status st = check_transmission(b, m, name, err);
    if (st == PT_OK)
        st = check_layers(b, m, name, err);
    if (st != PT_OK)
        return st;
    if (!isfinite(m->normal_scale))
        return pt_error_set(err, PT_ERR_FORMAT, "material '%.64s': normal scale is not finite",
                            name);
    for (int i = 0; i < PT_SLOT_COUNT; i++)
        if (!finite_n(m->tex_xf[i].m, 6) || m->tex_xf[i].texcoord < 0 || m->tex_xf[i].texcoord > 1)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "material '%.64s': texture transform %d is not finite or its "
                                "texCoord is not 0 or 1",
                                name, i);
    const int32_t tex[4] = {m->base_color_tex, m->metal_rough_tex, m->emissive_tex, m->normal_tex};
    for (int i = 0; i < 4; i++)
        if (tex[i] < -1 || (tex[i] >= 0 && (uint32_t)tex[i] >= b->ntex))
            return pt_error_set(err, PT_ERR_ARG, "material '%.64s': texture %d out of range", name,
                                (int)tex[i]);
    if (!reserve((void **)&b->mats, &b->cap_mat, b->nmat + 1, sizeof(pt_material), 1))
        return pt_error_set(err, PT_ERR_NOMEM, "material '%.64s': out of memory", name);
    pt_material *d = &b->mats[b->nmat];
    *d = *m;
    if (d->unlit) {
        d->unlit = 1;
        d->emissive[0] = d->emissive[1] = d->emissive[2] = 0.0f;
    }
    d->spec_gloss = d->spec_gloss != 0;
    d->ext = d->unlit ? PT_MATX_UNLIT : 0;
    if (d->spec_gloss)
        d->ext |= PT_MATX_SPEC_GLOSS;
    else if (d->specular > 0.0f && (d->specular_tex >= 0 || d->specular_color_tex >= 0))
        d->ext |= PT_MATX_SPECULAR_TEX;
    if (d->iridescence > 0.0f)
        d->ext |= PT_MATX_IRIDESCENCE;
    if (d->anisotropy > 0.0f && !(d->transmission > 0.0f))
        d->ext |= PT_MATX_ANISOTROPY;
    if (d->diffuse_transmission > 0.0f && !(d->transmission > 0.0f))
        d->ext |= PT_MATX_DIFFUSE_TRANSMISSION;
    /* Zero the bytes after the name's end so the scene hash sees only the name. */
    size_t len = strnlen(m->name, sizeof m->name - 1);
    memset(d->name + len, 0, sizeof d->name - len);
    *index = b->nmat++;
    return PT_OK;
}

pt_status pt_scene_builder_add_texture(pt_scene_builder *b, const pt_texture *tex, uint32_t *index,
                                       pt_error *err)
{
    pt_status st;
    if (!tex->rgba) {
        return pt_error_set(err, PT_ERR_ARG, "texture %u: no pixels", b->ntex);
    }
    if (tex->width == 0 || tex->height == 0 || tex->width > PT_SCENE_MAX_TEXTURE_DIM ||
        tex->height > PT_SCENE_MAX_TEXTURE_DIM) {
        st = pt_error_set(err, PT_ERR_LIMIT, "texture %u: %ux%u pixels (at most %u a side)",
                          b->ntex, tex->width, tex->height, PT_SCENE_MAX_TEXTURE_DIM);
        goto fail;
    }
    uint64_t texels = (uint64_t)tex->width * tex->height;
    if (texels > PT_SCENE_MAX_IMAGE_TEXELS || texels > PT_SCENE_MAX_TEXELS - b->texels) {
        st = pt_error_set(
            err, PT_ERR_LIMIT,
            "texture %u: %ux%u pixels make %llu texels in the scene (at most %llu "
            "an image, %llu a scene)",
            b->ntex, tex->width, tex->height, (unsigned long long)(b->texels + texels),
            (unsigned long long)PT_SCENE_MAX_IMAGE_TEXELS, (unsigned long long)PT_SCENE_MAX_TEXELS);
        goto fail;
    }
    if (tex->wrap_s < PT_WRAP_REPEAT || tex->wrap_s > PT_WRAP_MIRROR ||
        tex->wrap_t < PT_WRAP_REPEAT || tex->wrap_t > PT_WRAP_MIRROR) {
        st = pt_error_set(err, PT_ERR_ARG, "texture %u: bad wrap mode", b->ntex);
        goto fail;
    }
    if (b->ntex >= INT32_MAX) {
        st = pt_error_set(err, PT_ERR_LIMIT, "too many textures");
        goto fail;
    }
    if (!reserve((void **)&b->texs, &b->cap_tex, b->ntex + 1, sizeof(pt_texture), 1)) {
        st = pt_error_set(err, PT_ERR_NOMEM, "texture %u: out of memory", b->ntex);
        goto fail;
    }
    b->texs[b->ntex] = *tex;
    b->texs[b->ntex].srgb = tex->srgb ? 1 : 0;
    b->texels += texels;
    *index = b->ntex++;
    return PT_OK;
fail:
    pt_free(tex->rgba);
    return st;
}

pt_status pt_scene_builder_add_camera_at(pt_scene_builder *b, const pt_camera *cam,
                                         const double position[3], pt_error *err)
{
    const char *name = cam->name[0] ? cam->name : "(unnamed)";
    const char *bad = NULL;
    if (!isfinite(position[0]) || !isfinite(position[1]) || !isfinite(position[2]) ||
        fabs(position[0]) > (double)PT_SCENE_MAX_COORD ||
        fabs(position[1]) > (double)PT_SCENE_MAX_COORD ||
        fabs(position[2]) > (double)PT_SCENE_MAX_COORD)
        bad = "position is not finite or too large";
    else if (!pt_isfinite3(cam->right) || !pt_isfinite3(cam->up) || !pt_isfinite3(cam->forward))
        bad = "orientation is not finite";
    else if (!cam->ortho && !(cam->yfov > 0.0f && cam->yfov < PT_PI))
        bad = "yfov is not in (0, pi)";
    else if (cam->ortho && !(cam->xmag > 0.0f && cam->xmag <= PT_SCENE_MAX_COORD &&
                             cam->ymag > 0.0f && cam->ymag <= PT_SCENE_MAX_COORD))
        bad = "xmag and ymag are not in (0, 1e15]";
    else if (!(cam->aspect >= 0.0f && cam->aspect < 1e6f))
        bad = "aspectRatio is not in [0, 1e6)";
    else if (!(cam->znear >= 0.0f) || !isfinite(cam->znear))
        bad = "znear is negative or not finite";
    if (bad)
        return pt_error_set(err, PT_ERR_FORMAT, "camera '%.64s': %s", name, bad);
    if (b->ncam >= 65536)
        return pt_error_set(err, PT_ERR_LIMIT, "camera '%.64s': too many cameras", name);
    if (!reserve((void **)&b->cams, &b->cap_cam, b->ncam + 1, sizeof(pt_camera), 1) ||
        !reserve((void **)&b->cam_pos, &b->cap_cam_pos, b->ncam + 1, sizeof(double), 3))
        return pt_error_set(err, PT_ERR_NOMEM, "camera '%.64s': out of memory", name);
    memcpy(&b->cam_pos[3 * (size_t)b->ncam], position, 3 * sizeof(double));
    pt_camera *d = &b->cams[b->ncam++];
    *d = *cam;
    size_t len = strnlen(cam->name, sizeof cam->name - 1);
    memset(d->name + len, 0, sizeof d->name - len);
    return PT_OK;
}

pt_status pt_scene_builder_add_punctual(pt_scene_builder *b, const pt_punctual *p,
                                        const double position[3], pt_error *err)
{
    const char *name = p->name[0] ? p->name : "(unnamed)";
    const char *bad = NULL;
    float dlen = pt_v3_len(p->direction);
    if (!isfinite(position[0]) || !isfinite(position[1]) || !isfinite(position[2]) ||
        fabs(position[0]) > (double)PT_SCENE_MAX_COORD ||
        fabs(position[1]) > (double)PT_SCENE_MAX_COORD ||
        fabs(position[2]) > (double)PT_SCENE_MAX_COORD)
        bad = "position is not finite or too large";
    else if (p->type < PT_PUNCTUAL_POINT || p->type > PT_PUNCTUAL_DIRECTIONAL)
        bad = "type is not point, spot or directional";
    else if (!pt_isfinite3(p->direction) || !(fabsf(dlen - 1.0f) < 1e-3f))
        bad = "direction is not a unit vector";
    else if (!pt_isfinite3(p->intensity) || !(p->intensity.x >= 0.0f) ||
             !(p->intensity.y >= 0.0f) || !(p->intensity.z >= 0.0f) ||
             !(pt_luminance(p->intensity) < 1e30f))
        bad = "colour x intensity is negative, not finite or over 1e30";
    else if (!(p->range >= 0.0f) || !isfinite(p->range))
        bad = "range is negative or not finite";
    else if (p->type == PT_PUNCTUAL_SPOT &&
             !(p->cos_outer >= -1e-6f && p->cos_inner > p->cos_outer && p->cos_inner <= 1.0f))
        bad = "spot cone angles are not 0 <= inner < outer <= pi/2";
    if (bad)
        return pt_error_set(err, PT_ERR_FORMAT, "light '%.64s': %s", name, bad);
    if (b->npun >= 65536)
        return pt_error_set(err, PT_ERR_LIMIT, "light '%.64s': more than 65536 lights", name);
    if (!reserve((void **)&b->puns, &b->cap_pun, b->npun + 1, sizeof(pt_punctual), 1) ||
        !reserve((void **)&b->pun_pos, &b->cap_pun_pos, b->npun + 1, sizeof(double), 3))
        return pt_error_set(err, PT_ERR_NOMEM, "light '%.64s': out of memory", name);
    memcpy(&b->pun_pos[3 * (size_t)b->npun], position, 3 * sizeof(double));
    pt_punctual *d = &b->puns[b->npun++];
    *d = *p;
    d->direction = pt_v3_scale(p->direction, 1.0f / dlen);
    size_t len = strnlen(p->name, sizeof p->name - 1);
    memset(d->name + len, 0, sizeof d->name - len);
    return PT_OK;
}

/* The cross product of a portal triangle's edges (corners v, double): its
 * front's normal, unnormalised. */
static void portal_cross(const double v[9], double c[3])
{
    double e1[3], e2[3];
    for (int r = 0; r < 3; r++) {
        e1[r] = v[3 + r] - v[r];
        e2[r] = v[6 + r] - v[r];
    }
    c[0] = e1[1] * e2[2] - e1[2] * e2[1];
    c[1] = e1[2] * e2[0] - e1[0] * e2[2];
    c[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

pt_status pt_scene_builder_add_portal(pt_scene_builder *b, const double v[9], const char *what,
                                      pt_error *err)
{
    for (int i = 0; i < 9; i++)
        if (!isfinite(v[i]) || fabs(v[i]) > (double)PT_SCENE_MAX_COORD)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "portal '%.64s': a corner is not finite or over %g", what,
                                (double)PT_SCENE_MAX_COORD);
    double c[3];
    portal_cross(v, c);
    if (!(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] > 0.0))
        return PT_OK; /* no area: no light comes through it */
    if (b->nportal >= PT_SCENE_MAX_PORTALS)
        return pt_error_set(err, PT_ERR_LIMIT, "portal '%.64s': more than %u portal triangles",
                            what, PT_SCENE_MAX_PORTALS);
    if (!reserve((void **)&b->portals, &b->cap_portal, b->nportal + 1, sizeof(double), 9))
        return pt_error_set(err, PT_ERR_NOMEM, "portal '%.64s': out of memory", what);
    memcpy(&b->portals[9 * (size_t)b->nportal++], v, 9 * sizeof(double));
    return PT_OK;
}

pt_status pt_scene_builder_add_camera(pt_scene_builder *b, const pt_camera *cam, pt_error *err)
{
    const double p[3] = {cam->position.x, cam->position.y, cam->position.z};
    return pt_scene_builder_add_camera_at(b, cam, p, err);
}

double pt_normal_matrix(const double *m, double c[3][3])
{
    double a[3][3]; /* a[row][col] */
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++)
            a[r][k] = m ? m[k * 4 + r] : (r == k);
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 3; k++) {
            int r1 = (r + 1) % 3, r2 = (r + 2) % 3, k1 = (k + 1) % 3, k2 = (k + 2) % 3;
            c[r][k] = a[r1][k1] * a[r2][k2] - a[r1][k2] * a[r2][k1];
        }
    }
    return a[0][0] * c[0][0] + a[0][1] * c[0][1] + a[0][2] * c[0][2];
}

pt_status pt_scene_builder_add_mesh(pt_scene_builder *b, const char *what, const float *positions,
                                    const float *normals, const float *uvs, uint32_t nv,
                                    const uint32_t *indices, uint32_t nt, const float xform[16],
                                    uint32_t material, pt_error *err)
{
    double xd[16];
    if (xform)
        for (int i = 0; i < 16; i++)
            xd[i] = xform[i];
    return pt_scene_builder_add_mesh_dxform(b, what, positions, normals, uvs, nv, indices, nt,
                                            xform ? xd : NULL, material, err);
}

pt_status pt_scene_builder_add_mesh_motion(pt_scene_builder *b, const char *what, uint32_t steps,
                                           const float *const *positions,
                                           const float *const *normals, const float *uvs,
                                           uint32_t nv, const uint32_t *indices, uint32_t nt,
                                           uint32_t material, pt_error *err)
{
    if (!what)
        what = "mesh";
    if (!positions || steps < 2 || steps > PT_MOTION_MAX_STEPS)
        return pt_error_set(err, PT_ERR_ARG, "%s: %u time steps, not 2 to %u", what, steps,
                            PT_MOTION_MAX_STEPS);
    if (b->nproto > 0)
        return pt_error_set(err, PT_ERR_ARG, "%s: a moving mesh in a scene with instances", what);
    uint32_t v0 = b->nv, t0 = b->nt;
    pt_status st =
        pt_scene_builder_add_mesh_extra(b, what, positions[0], normals ? normals[0] : NULL, uvs,
                                        NULL, nv, indices, nt, NULL, material, err);
    if (st != PT_OK || b->nt == t0)
        return st;
    st = pt_motion_build_add(&b->motion, what, v0, nv, t0, nt, indices, steps, positions, normals,
                             err);
    if (st != PT_OK) { /* the mesh goes too: a failed add leaves the builder as it was */
        b->nv = v0;
        b->nt = t0;
    }
    return st;
}

pt_status pt_scene_builder_add_mesh_dxform(pt_scene_builder *b, const char *what,
                                           const float *positions, const float *normals,
                                           const float *uvs, uint32_t nv, const uint32_t *indices,
                                           uint32_t nt, const double xform[16], uint32_t material,
                                           pt_error *err)
{
    return pt_scene_builder_add_mesh_extra(b, what, positions, normals, uvs, NULL, nv, indices, nt,
                                           xform, material, err);
}

static pt_status add_vertex_extra(pt_scene_builder *b, const char *what, const pt_mesh_extra *x,
                                  uint32_t v, const double xform[16], double nsign, pt_error *err);

/* Makes room in an optional attribute array (per floats a vertex) for
 * nv_all vertices when this mesh has it or an earlier one had: allocated on
 * first use with dflt for the vertices before this mesh. Returns 0 when out
 * of memory. */
static int extra_reserve(float **arr, uint32_t *cap, uint32_t nv_old, uint32_t nv_all, int per,
                         const float *given, const float *dflt)
{
    if (!given && !*arr)
        return 1;
    int fresh = *arr == NULL;
    if (!reserve((void **)arr, cap, nv_all, sizeof(float), (size_t)per))
        return 0;
    if (fresh)
        for (uint32_t v = 0; v < nv_old; v++)
            memcpy(*arr + (size_t)per * v, dflt, sizeof(float) * (size_t)per);
    return 1;
}

pt_status pt_scene_builder_begin_prototype(pt_scene_builder *b, uint32_t *proto, pt_error *err)
{
    if (b->in_proto)
        return pt_error_set(err, PT_ERR_ARG, "prototype %u is not ended", b->nproto - 1);
    if (b->motion)
        return pt_error_set(err, PT_ERR_ARG, "an instanced prototype in a scene with motion");
    if (!reserve((void **)&b->protos, &b->cap_proto, b->nproto + 1, sizeof(pt_prototype), 1))
        return pt_error_set(err, PT_ERR_NOMEM, "prototype: out of memory");
    pt_prototype *p = &b->protos[b->nproto];
    p->first_tri = b->nt;
    p->first_vertex = b->nv;
    p->num_tris = p->num_vertices = 0;
    b->in_proto = 1;
    *proto = b->nproto++;
    return PT_OK;
}

pt_status pt_scene_builder_end_prototype(pt_scene_builder *b, pt_error *err)
{
    if (!b->in_proto)
        return pt_error_set(err, PT_ERR_ARG, "no prototype to end");
    pt_prototype *p = &b->protos[b->nproto - 1];
    p->num_tris = b->nt - p->first_tri;
    p->num_vertices = b->nv - p->first_vertex;
    b->in_proto = 0;
    return PT_OK;
}

pt_status pt_scene_builder_add_instance(pt_scene_builder *b, uint32_t proto, const double xform[16],
                                        pt_error *err)
{
    if (proto >= b->nproto || (b->in_proto && proto == b->nproto - 1) || !xform)
        return pt_error_set(err, PT_ERR_ARG, "instance of prototype %u: no such ended prototype",
                            proto);
    for (int i = 0; i < 16; i++)
        if (!isfinite(xform[i]) || fabs(xform[i]) > (double)PT_SCENE_MAX_COORD)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "instance %u of prototype %u: its matrix is not finite or over %g",
                                b->ninst, proto, (double)PT_SCENE_MAX_COORD);
    if (xform[3] != 0.0 || xform[7] != 0.0 || xform[11] != 0.0 || xform[15] != 1.0)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "instance %u of prototype %u: its matrix is not affine", b->ninst,
                            proto);
    double c[3][3];
    double det = pt_normal_matrix(xform, c);
    if (!(fabs(det) > 0.0) || !isfinite(det))
        return PT_OK; /* no area: nothing to see */
    if (b->ninst >= PT_SCENE_MAX_INSTANCES)
        return pt_error_set(err, PT_ERR_LIMIT, "instance %u: over the cap of %u instances a scene",
                            b->ninst, PT_SCENE_MAX_INSTANCES);
    if (!reserve((void **)&b->inst_xf, &b->cap_inst_xf, b->ninst + 1, sizeof(double), 16) ||
        !reserve((void **)&b->inst_proto, &b->cap_inst_proto, b->ninst + 1, sizeof(uint32_t), 1) ||
        !reserve((void **)&b->inst_obj, &b->cap_inst_obj, b->ninst + 1, sizeof(uint32_t), 1))
        return pt_error_set(err, PT_ERR_NOMEM, "instance: out of memory");
    memcpy(b->inst_xf + 16 * (size_t)b->ninst, xform, 16 * sizeof(double));
    b->inst_obj[b->ninst] = b->cur_obj >= 0 ? (uint32_t)b->cur_obj : UINT32_MAX;
    b->inst_proto[b->ninst++] = proto;
    return PT_OK;
}

/* Whether material m reads tangents, and from which UV set (0 or 1): the
 * rule finish_extra applies, one tangent per vertex from the base normal
 * map's set, else the coat normal map's, else the anisotropy texture's. */
static int material_tangent_set(const pt_material *m, int *set)
{
    int coat = m->clearcoat > 0.0f && m->clearcoat_normal_tex >= 0;
    int slot = m->normal_tex >= 0 ? PT_SLOT_NORMAL
                                  : (coat ? PT_SLOT_CLEARCOAT_NORMAL : PT_SLOT_ANISOTROPY);
    *set = m->tex_xf[slot].texcoord;
    return m->normal_tex >= 0 || coat || (m->ext & PT_MATX_ANISOTROPY);
}

/*
 * Tangents generated for a mesh without TANGENT, in the mesh's own space, into
 * tan (4 per vertex, zeroed here): the builder then takes them to world space
 * as it takes a given TANGENT (through the 3x3, the handedness flipped by a
 * mirror). glTF 2.0 (3.7.2.1) asks for MikkTSpace over the mesh's vertex
 * positions, and viewers generate them on the mesh and transform them with
 * the node, so a node's non-uniform scale bends the tangents as it bends a
 * given TANGENT; generated from world-space positions they would differ.
 * It also makes an EXT_mesh_gpu_instancing instance, whose prototype is
 * the mesh in its own space, shade as its copy does. The normals are the
 * mesh-space ones the builder gives a mesh placed without a matrix (each
 * normalised in double, or area-weighted from the positions where none is
 * usable), so a copy and a prototype generate from the same numbers. A
 * vertex whose tangent is not finite (a hostile position, refused later)
 * is left zero with w = 1, which the builder leaves to finish.
 */
static pt_status mesh_space_tangents(const float *positions, const float *normals, const float *uv,
                                     uint32_t nv, const uint32_t *indices, uint32_t nt, float *tan,
                                     pt_error *err)
{
    float *n = pt_malloc((size_t)nv * 3 * sizeof(float));
    double *acc = pt_calloc((size_t)nv * 3, sizeof(double));
    float *flat = uv ? NULL : pt_calloc((size_t)nv * 2, sizeof(float));
    uint32_t *idx = indices ? NULL : pt_malloc((size_t)nt * 3 * sizeof(uint32_t));
    pt_status st = PT_OK;
    if (!n || !acc || (!uv && !flat) || (!indices && !idx)) {
        st = pt_error_set(err, PT_ERR_NOMEM, "tangents: out of memory for %u vertices", nv);
        goto fail;
    }
    if (!indices)
        for (uint32_t i = 0; i < 3 * nt; i++)
            idx[i] = i;
    const uint32_t *I = indices ? indices : idx;
    for (uint32_t t = 0; t < nt; t++) {
        const float *p0 = positions + 3 * (size_t)I[3 * t],
                    *p1 = positions + 3 * (size_t)I[3 * t + 1],
                    *p2 = positions + 3 * (size_t)I[3 * t + 2];
        double e1[3] = {(double)p1[0] - p0[0], (double)p1[1] - p0[1], (double)p1[2] - p0[2]};
        double e2[3] = {(double)p2[0] - p0[0], (double)p2[1] - p0[1], (double)p2[2] - p0[2]};
        double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        if (!isfinite(g[0]) || !isfinite(g[1]) || !isfinite(g[2]))
            continue;
        for (int k = 0; k < 3; k++)
            for (int r = 0; r < 3; r++)
                acc[3 * (size_t)I[3 * t + k] + r] += g[r];
    }
    for (uint32_t v = 0; v < nv; v++) {
        const double *a = acc + 3 * (size_t)v;
        double m[3] = {a[0], a[1], a[2]};
        if (normals) {
            const float *g = normals + 3 * (size_t)v;
            double l2 = (double)g[0] * g[0] + (double)g[1] * g[1] + (double)g[2] * g[2];
            if (l2 > 0.0 && isfinite(l2))
                m[0] = g[0], m[1] = g[1], m[2] = g[2];
        }
        double len = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        for (int r = 0; r < 3; r++)
            n[3 * (size_t)v + r] = len > 0.0 && isfinite(len) ? (float)(m[r] / len) : (r == 2);
    }
    memset(tan, 0, (size_t)nv * 4 * sizeof(float));
    st = pt_tangents_generate(positions, n, uv ? uv : flat, I, nt, NULL, nv, tan, err);
    for (uint32_t v = 0; st == PT_OK && v < nv; v++) {
        float *d = tan + 4 * (size_t)v;
        if (!finite_n(d, 4)) {
            d[0] = d[1] = d[2] = 0.0f;
            d[3] = 1.0f;
        } else if (d[3] == 0.0f) { /* no triangle reached it: left to finish */
            d[3] = 1.0f;
        }
    }
fail:
    pt_free(n);
    pt_free(acc);
    pt_free(flat);
    pt_free(idx);
    return st;
}

pt_status pt_scene_builder_mesh_tangents(const pt_scene_builder *b, uint32_t material,
                                         const float *positions, const float *normals,
                                         const float *uvs, const float *uvs1, uint32_t nv,
                                         const uint32_t *indices, uint32_t nt, float *tan,
                                         int *made, pt_error *err)
{
    int set = 0;
    *made = 0;
    if (material >= b->nmat || !material_tangent_set(&b->mats[material], &set))
        return PT_OK;
    pt_status st =
        mesh_space_tangents(positions, normals, set ? uvs1 : uvs, nv, indices, nt, tan, err);
    *made = st == PT_OK;
    return st;
}

pt_status pt_scene_builder_add_mesh_extra(pt_scene_builder *b, const char *what,
                                          const float *positions, const float *normals,
                                          const float *uvs, const pt_mesh_extra *extra, uint32_t nv,
                                          const uint32_t *indices, uint32_t nt,
                                          const double xform[16], uint32_t material, pt_error *err)
{
    static const pt_mesh_extra none = {NULL, NULL, NULL};
    static const float zero4[4] = {0, 0, 0, 0}, one4[4] = {1, 1, 1, 1};
    if (!extra)
        extra = &none;
    double *acc = NULL;
    pt_status st = PT_OK;
    if (!what)
        what = "mesh";
    if (material >= b->nmat)
        return pt_error_set(err, PT_ERR_ARG, "%s: material %u out of range", what, material);
    if (nt == 0)
        return PT_OK;
    if (!positions)
        return pt_error_set(err, PT_ERR_ARG, "%s: no positions", what);
    float *gen_tan = NULL; /* tangents generated in the mesh's space */
    pt_mesh_extra with_tan;
    if (b->nproto > 0 && !b->in_proto)
        return pt_error_set(err, PT_ERR_ARG,
                            "%s: a mesh in scene space after an instanced prototype (flat meshes "
                            "come first)",
                            what);
    if (!indices && (uint64_t)nv != 3 * (uint64_t)nt)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: non-indexed mesh with %u vertices for %u triangles", what, nv, nt);
    if (nt > PT_SCENE_MAX_TRIANGLES - b->nt)
        return pt_error_set(err, PT_ERR_LIMIT,
                            "%s: %llu triangles in the scene, over the cap of %u (every "
                            "instance counted)",
                            what, (unsigned long long)b->nt + nt, PT_SCENE_MAX_TRIANGLES);
    if (nv > PT_SCENE_MAX_VERTICES - b->nv)
        return pt_error_set(err, PT_ERR_LIMIT,
                            "%s: %llu vertices in the scene, over the cap of %u (every "
                            "instance counted)",
                            what, (unsigned long long)b->nv + nv, PT_SCENE_MAX_VERTICES);
    if (indices) {
        for (uint64_t i = 0; i < 3 * (uint64_t)nt; i++)
            if (indices[i] >= nv)
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "%s: index %u of triangle %u out of range (%u vertices)", what,
                                    indices[i], (uint32_t)(i / 3), nv);
    }
    int tan_set = 0;
    if (!extra->tangents && material_tangent_set(&b->mats[material], &tan_set)) {
        int made = 0;
        gen_tan = pt_malloc((size_t)nv * 4 * sizeof(float));
        if (!gen_tan)
            return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory for tangents", what);
        if ((st = pt_scene_builder_mesh_tangents(b, material, positions, normals, uvs, extra->uvs1,
                                                 nv, indices, nt, gen_tan, &made, err)) != PT_OK)
            goto fail;
        with_tan = *extra;
        with_tan.tangents = gen_tan;
        extra = &with_tan;
    }
    uint32_t nv_all = b->nv + nv, nt_all = b->nt + nt;
    if (!reserve((void **)&b->pos, &b->cap_pos, nv_all, sizeof(double), 3) ||
        !reserve((void **)&b->nrm, &b->cap_nrm, nv_all, sizeof(float), 3) ||
        !reserve((void **)&b->uv, &b->cap_uv, nv_all, sizeof(float), 2) ||
        !reserve((void **)&b->idx, &b->cap_idx, nt_all, sizeof(uint32_t), 3) ||
        !reserve((void **)&b->tmat, &b->cap_tmat, nt_all, sizeof(uint32_t), 1) ||
        !reserve((void **)&b->tobj, &b->cap_tobj, nt_all, sizeof(uint32_t), 1) ||
        !extra_reserve(&b->uv1, &b->cap_uv1, b->nv, nv_all, 2, extra->uvs1, zero4) ||
        !extra_reserve(&b->tan, &b->cap_tan, b->nv, nv_all, 4, extra->tangents, zero4) ||
        !extra_reserve(&b->col, &b->cap_col, b->nv, nv_all, 4, extra->colors, one4)) {
        st = pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", what);
        goto fail;
    }

    double c[3][3];
    double det = pt_normal_matrix(xform, c);
    double nsign = det < 0 ? -1.0 : 1.0;
    double *P = b->pos + 3 * (size_t)b->nv;
    float *N = b->nrm + 3 * (size_t)b->nv;
    float *UV = b->uv + 2 * (size_t)b->nv;
    int need_geo = normals == NULL;
    for (uint32_t v = 0; v < nv; v++) {
        const float *p = positions + 3 * (size_t)v;
        double q[3];
        for (int r = 0; r < 3; r++) {
            q[r] = xform
                       ? xform[r] * p[0] + xform[4 + r] * p[1] + xform[8 + r] * p[2] + xform[12 + r]
                       : (double)p[r];
            if (!isfinite(q[r]) || fabs(q[r]) > (double)PT_SCENE_MAX_COORD) {
                st = pt_error_set(err, PT_ERR_FORMAT,
                                  "%s: vertex %u position (%g, %g, %g) is not finite or over "
                                  "%g in world space",
                                  what, v, (double)p[0], (double)p[1], (double)p[2],
                                  (double)PT_SCENE_MAX_COORD);
                goto fail;
            }
            P[3 * v + r] = q[r];
        }
        if (normals) {
            const float *n = normals + 3 * (size_t)v;
            if (!finite_n(n, 3)) {
                st =
                    pt_error_set(err, PT_ERR_FORMAT, "%s: vertex %u normal is not finite", what, v);
                goto fail;
            }
            double m[3], len2 = 0;
            for (int r = 0; r < 3; r++) {
                m[r] = nsign * (c[r][0] * n[0] + c[r][1] * n[1] + c[r][2] * n[2]);
                len2 += m[r] * m[r];
            }
            double len = sqrt(len2);
            if (len > 0 && isfinite(len)) {
                for (int r = 0; r < 3; r++)
                    N[3 * v + r] = (float)(m[r] / len);
            } else {
                N[3 * v] = N[3 * v + 1] = N[3 * v + 2] = 0.0f; /* marks a fallback */
                need_geo = 1;
            }
        }
        if (uvs) {
            const float *t = uvs + 2 * (size_t)v;
            if (!finite_n(t, 2)) {
                st = pt_error_set(err, PT_ERR_FORMAT, "%s: vertex %u TEXCOORD is not finite", what,
                                  v);
                goto fail;
            }
            UV[2 * v] = t[0];
            UV[2 * v + 1] = t[1];
        } else {
            UV[2 * v] = UV[2 * v + 1] = 0.0f;
        }
        if ((st = add_vertex_extra(b, what, extra, v, xform, nsign, err)) != PT_OK)
            goto fail;
    }
    uint32_t obj = 0;
    if (b->cur_obj >= 0)
        obj = (uint32_t)b->cur_obj;
    else if ((st = object_of(b, what, &obj, err)) != PT_OK)
        goto fail;
    uint32_t *I = b->idx + 3 * (size_t)b->nt;
    for (uint32_t t = 0; t < nt; t++) {
        b->tobj[b->nt + t] = obj;
        uint32_t i0 = indices ? indices[3 * t] : 3 * t;
        uint32_t i1 = indices ? indices[3 * t + 1] : 3 * t + 1;
        uint32_t i2 = indices ? indices[3 * t + 2] : 3 * t + 2;
        if (det < 0) {
            uint32_t s = i1;
            i1 = i2;
            i2 = s;
        }
        I[3 * t] = b->nv + i0;
        I[3 * t + 1] = b->nv + i1;
        I[3 * t + 2] = b->nv + i2;
        b->tmat[b->nt + t] = material;
    }
    if (need_geo) {
        /* Area-weighted vertex normals: the cross product's length is twice
         * the triangle's area, so summing unnormalised cross products weights
         * each face by its area. Degenerate faces add nothing. In double, from
         * the double world-space positions: edges of a mesh far from the
         * origin keep their precision, so a translation does not change the
         * normals. */
        acc = pt_calloc((size_t)nv * 3, sizeof(double));
        if (!acc) {
            st = pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", what);
            goto fail;
        }
        for (uint32_t t = 0; t < nt; t++) {
            uint32_t i[3] = {I[3 * t] - b->nv, I[3 * t + 1] - b->nv, I[3 * t + 2] - b->nv};
            const double *p0 = P + 3 * (size_t)i[0], *p1 = P + 3 * (size_t)i[1],
                         *p2 = P + 3 * (size_t)i[2];
            double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
            double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
            double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                           e1[0] * e2[1] - e1[1] * e2[0]};
            if (!isfinite(g[0]) || !isfinite(g[1]) || !isfinite(g[2]))
                continue;
            for (int k = 0; k < 3; k++)
                for (int r = 0; r < 3; r++)
                    acc[3 * (size_t)i[k] + r] += g[r];
        }
        for (uint32_t v = 0; v < nv; v++) {
            float *n = N + 3 * (size_t)v;
            if (normals && (n[0] != 0.0f || n[1] != 0.0f || n[2] != 0.0f))
                continue;
            const double *a = acc + 3 * (size_t)v;
            /* Coordinates are capped at PT_SCENE_MAX_COORD (1e15), so a face's
             * cross product is under ~1e31 and the squared sum cannot overflow. */
            double len = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
            if (len > 0.0 && isfinite(len)) {
                n[0] = (float)(a[0] / len);
                n[1] = (float)(a[1] / len);
                n[2] = (float)(a[2] / len);
            } else {
                n[0] = 0.0f;
                n[1] = 0.0f;
                n[2] = 1.0f;
            }
        }
    }
    if (uvs)
        b->has_uv = 1;
    b->nv = nv_all;
    b->nt = nt_all;
fail:
    pt_free(acc);
    pt_free(gen_tan);
    return st;
}

/* Vertex v of the mesh being added (stored at b->nv + v): its optional
 * attributes from extra, or their defaults where the builder keeps the array.
 * A tangent is a direction on the surface, so it goes through the upper 3x3
 * of xform itself (not the normal matrix); a mirroring transform (nsign -1)
 * reverses the handedness, since M(n x t) = det(M) M^-T (n x t). A zero
 * tangent means "generate" (pt_scene_builder_finish). */
static pt_status add_vertex_extra(pt_scene_builder *b, const char *what, const pt_mesh_extra *x,
                                  uint32_t v, const double xform[16], double nsign, pt_error *err)
{
    size_t o = (size_t)b->nv + v;
    if (b->uv1) {
        float *d = b->uv1 + 2 * o;
        d[0] = d[1] = 0.0f;
        if (x->uvs1) {
            const float *t = x->uvs1 + 2 * (size_t)v;
            if (!finite_n(t, 2))
                return pt_error_set(err, PT_ERR_FORMAT, "%s: vertex %u TEXCOORD_1 is not finite",
                                    what, v);
            d[0] = t[0];
            d[1] = t[1];
        }
    }
    if (b->col) {
        float *d = b->col + 4 * o;
        d[0] = d[1] = d[2] = d[3] = 1.0f;
        if (x->colors) {
            const float *c = x->colors + 4 * (size_t)v;
            if (!finite_n(c, 4))
                return pt_error_set(err, PT_ERR_FORMAT, "%s: vertex %u COLOR_0 is not finite", what,
                                    v);
            memcpy(d, c, 4 * sizeof(float));
        }
    }
    if (b->tan) {
        float *d = b->tan + 4 * o;
        d[0] = d[1] = d[2] = d[3] = 0.0f;
        if (x->tangents) {
            const float *t = x->tangents + 4 * (size_t)v;
            if (!finite_n(t, 4) || !(t[3] == 1.0f || t[3] == -1.0f))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "%s: vertex %u TANGENT is not finite or its w is not +-1", what,
                                    v);
            double m[3], len2 = 0.0;
            for (int r = 0; r < 3; r++) {
                m[r] = xform ? xform[r] * t[0] + xform[4 + r] * t[1] + xform[8 + r] * t[2]
                             : (double)t[r];
                len2 += m[r] * m[r];
            }
            double len = sqrt(len2);
            /* A zero tangent stays zero: generated at finish. */
            if (len > 0.0 && isfinite(len)) {
                for (int r = 0; r < 3; r++)
                    d[r] = (float)(m[r] / len);
                d[3] = (float)(t[3] * nsign);
            }
        }
    }
    return PT_OK;
}

/* The slots whose textures interleave_textures puts side by side, and
 * pt_scene_prefetch_hits asks for: those every hit on a material reads
 * (the others depend on extensions that few materials have). */
static const struct {
    size_t tex; /* offset of the texture index in pt_material */
    int slot;
} core_slots[] = {
    {offsetof(pt_material, base_color_tex), PT_SLOT_BASE},
    {offsetof(pt_material, metal_rough_tex), PT_SLOT_METAL_ROUGH},
    {offsetof(pt_material, normal_tex), PT_SLOT_NORMAL},
    {offsetof(pt_material, emissive_tex), PT_SLOT_EMISSIVE},
    {offsetof(pt_material, transmission_tex), PT_SLOT_TRANSMISSION},
    {offsetof(pt_material, clearcoat_tex), PT_SLOT_CLEARCOAT},
    {offsetof(pt_material, clearcoat_rough_tex), PT_SLOT_CLEARCOAT_ROUGH},
    {offsetof(pt_material, clearcoat_normal_tex), PT_SLOT_CLEARCOAT_NORMAL},
    {offsetof(pt_material, sheen_color_tex), PT_SLOT_SHEEN_COLOR},
    {offsetof(pt_material, sheen_rough_tex), PT_SLOT_SHEEN_ROUGH},
};
#define NUM_CORE_SLOTS (sizeof core_slots / sizeof core_slots[0])

static int32_t slot_texture(const pt_material *m, size_t k)
{
    int32_t ti;
    memcpy(&ti, (const char *)m + core_slots[k].tex, sizeof ti);
    return ti;
}

static int same_xform(const pt_tex_xform *a, const pt_tex_xform *b)
{
    if (a->texcoord != b->texcoord || a->active != b->active)
        return 0;
    return !a->active || memcmp(a->m, b->m, sizeof a->m) == 0;
}

/* Puts side by side, texel by texel, the textures that a material reads at
 * the same coordinates (pt_texture): for each material in order, its core
 * slots' textures not yet placed that have the first one's size and read
 * through the same coordinate set and transform. Each texture joins at most
 * one block; the texels' values do not change, nor does any lookup's
 * result. A block holds at most PT_SCENE_MAX_IMAGE_TEXELS texels in all
 * (256 MiB), so the copy adds at most that to the load's peak, less than
 * the decoding of one image at that cap holds. Where memory runs out for a
 * block, its textures stay as they are: the layout is only faster. */
static void interleave_textures(pt_scene *s)
{
    for (uint32_t mi = 0; mi < s->num_materials; mi++) {
        const pt_material *m = &s->materials[mi];
        uint32_t group[NUM_CORE_SLOTS];
        uint32_t n = 0;
        const pt_tex_xform *xf = NULL;
        for (size_t k = 0; k < NUM_CORE_SLOTS; k++) {
            int32_t ti = slot_texture(m, k);
            if (ti < 0 || (uint32_t)ti >= s->num_textures)
                continue;
            const pt_texture *t = &s->textures[ti];
            if ((t->step != 0 && t->step != 4) || !t->rgba)
                continue; /* already in a block */
            const pt_tex_xform *x = &m->tex_xf[core_slots[k].slot];
            if (n > 0) {
                const pt_texture *t0 = &s->textures[group[0]];
                int dup = 0;
                for (uint32_t j = 0; j < n; j++)
                    dup |= group[j] == (uint32_t)ti;
                if (dup || t->width != t0->width || t->height != t0->height || !same_xform(x, xf))
                    continue;
                if ((uint64_t)(n + 1) * t->width * t->height > PT_SCENE_MAX_IMAGE_TEXELS)
                    continue; /* the block at most one largest image's bytes */
            } else {
                xf = x;
            }
            group[n++] = (uint32_t)ti;
        }
        if (n < 2)
            continue;
        size_t texels = (size_t)s->textures[group[0]].width * s->textures[group[0]].height;
        uint8_t *block = pt_malloc_array(texels, 4 * (size_t)n);
        if (!block)
            continue;
        for (uint32_t j = 0; j < n; j++) {
            pt_texture *t = &s->textures[group[j]];
            const uint8_t *from = t->rgba;
            uint8_t *to = block + 4 * (size_t)j;
            for (size_t i = 0; i < texels; i++, from += 4, to += 4 * (size_t)n)
                memcpy(to, from, 4);
            pt_free(t->rgba);
            t->rgba = block + 4 * j;
            t->step = 4 * n;
            t->member = j;
        }
    }
}

/* SHA-256 (FIPS 180-4) of the built data, for scenes made by code. */
static pt_status hash_scene(const pt_scene *s, char out[65], pt_error *err)
{
    EVP_MD_CTX *ctx = EVP_MD_CTX_new();
    if (!ctx || EVP_DigestInit_ex(ctx, EVP_sha256(), NULL) != 1) {
        EVP_MD_CTX_free(ctx);
        return pt_error_set(err, PT_ERR_NOMEM, "scene hash: cannot start SHA-256");
    }
    uint32_t counts[5] = {s->num_vertices, s->num_triangles, s->num_materials, s->num_textures,
                          s->num_cameras};
    EVP_DigestUpdate(ctx, counts, sizeof counts);
    EVP_DigestUpdate(ctx, s->positions, 3 * sizeof(float) * s->num_vertices);
    EVP_DigestUpdate(ctx, s->origin, sizeof s->origin);
    EVP_DigestUpdate(ctx, s->normals, 3 * sizeof(float) * s->num_vertices);
    if (s->uvs)
        EVP_DigestUpdate(ctx, s->uvs, 2 * sizeof(float) * s->num_vertices);
    /* The optional attributes only when present: other scenes keep their hash. */
    if (s->uvs1)
        EVP_DigestUpdate(ctx, s->uvs1, 2 * sizeof(float) * s->num_vertices);
    if (s->tangents)
        EVP_DigestUpdate(ctx, s->tangents, 4 * sizeof(float) * s->num_vertices);
    if (s->colors)
        EVP_DigestUpdate(ctx, s->colors, 4 * sizeof(float) * s->num_vertices);
    EVP_DigestUpdate(ctx, s->indices, 3 * sizeof(uint32_t) * s->num_triangles);
    EVP_DigestUpdate(ctx, s->tri_material, sizeof(uint32_t) * s->num_triangles);
    EVP_DigestUpdate(ctx, s->materials, sizeof(pt_material) * s->num_materials);
    if (s->motion) /* only then: a still scene keeps its hash */
        pt_motion_hash(s->motion, ctx);
    if (s->num_instances > 0) { /* likewise */
        EVP_DigestUpdate(ctx, s->prototypes, sizeof(pt_prototype) * s->num_prototypes);
        EVP_DigestUpdate(ctx, s->instances, sizeof(pt_instance) * s->num_instances);
    }
    for (uint32_t i = 0; i < s->num_textures; i++) {
        const pt_texture *t = &s->textures[i];
        int32_t h[5] = {(int32_t)t->width, (int32_t)t->height, t->srgb, t->wrap_s, t->wrap_t};
        EVP_DigestUpdate(ctx, h, sizeof h);
        if (t->nearest)
            EVP_DigestUpdate(ctx, &t->nearest, sizeof t->nearest);
        /* Each texture's own block yet: interleave_textures runs after. */
        EVP_DigestUpdate(ctx, t->rgba, (size_t)t->width * t->height * 4);
    }
    for (uint32_t i = 0; i < s->num_cameras; i++) {
        const pt_camera *c = &s->cameras[i];
        float f[15] = {c->position.x, c->position.y, c->position.z, c->right.x, c->right.y,
                       c->right.z,    c->up.x,       c->up.y,       c->up.z,    c->forward.x,
                       c->forward.y,  c->forward.z,  c->yfov,       c->aspect,  c->znear};
        EVP_DigestUpdate(ctx, f, sizeof f);
        EVP_DigestUpdate(ctx, c->name, sizeof c->name);
        if (c->ortho) { /* only then: a perspective camera keeps its hash */
            float o[2] = {c->xmag, c->ymag};
            EVP_DigestUpdate(ctx, o, sizeof o);
        }
    }
    /* Lights only when there are any: a scene without keeps its hash. */
    if (s->num_punctual > 0)
        EVP_DigestUpdate(ctx, &s->num_punctual, sizeof s->num_punctual);
    for (uint32_t i = 0; i < s->num_punctual; i++) {
        const pt_punctual *l = &s->punctual[i];
        float f[13] = {l->position.x,  l->position.y,  l->position.z,  l->direction.x,
                       l->direction.y, l->direction.z, l->intensity.x, l->intensity.y,
                       l->intensity.z, l->range,       l->cos_inner,   l->cos_outer,
                       (float)l->type};
        EVP_DigestUpdate(ctx, f, sizeof f);
        EVP_DigestUpdate(ctx, l->name, sizeof l->name);
    }
    /* Portals only when there are any, likewise. */
    if (s->num_portals > 0) {
        EVP_DigestUpdate(ctx, "portals", 7);
        EVP_DigestUpdate(ctx, &s->num_portals, sizeof s->num_portals);
        EVP_DigestUpdate(ctx, s->portals, 9 * (size_t)s->num_portals * sizeof(float));
    }
    /* Zeroed first: a failed digest reads as 64 zeros, as pt_sha256_hex's does. */
    unsigned char md[EVP_MAX_MD_SIZE] = {0};
    EVP_DigestFinal_ex(ctx, md, NULL);
    EVP_MD_CTX_free(ctx);
    pt_hash_hex(md, out);
    return PT_OK;
}

uint32_t pt_camera_height(float aspect, uint32_t width, uint32_t max_height)
{
    float a = aspect > 0.0f ? aspect : 1.0f; /* NaN too */
    float h = (float)width / a + 0.5f;
    /* Compared before the cast: a float past UINT32_MAX does not convert. */
    uint32_t n = h < (float)max_height ? (uint32_t)h : max_height;
    return n > 0 ? n : 1;
}

void pt_camera_frame(pt_vec3 lo, pt_vec3 hi, float aspect, pt_camera *out)
{
    pt_camera c;
    memset(&c, 0, sizeof c);
    pt_vec3 centre = pt_v3_scale(pt_v3_add(lo, hi), 0.5f);
    pt_vec3 ext = pt_v3_sub(hi, lo);
    float radius = 0.5f * pt_v3_len(ext);
    int box = radius > 0.0f && isfinite(radius);
    if (!box)
        radius = 1.0f;
    c.yfov = 40.0f * PT_PI / 180.0f;
    c.aspect = aspect > 0.0f && isfinite(aspect) ? aspect : 0.0f;
    float a = c.aspect > 0.0f ? c.aspect : 1.0f;
    /* From +Z, a little above, so the top of the scene shows. */
    pt_vec3 dir = pt_v3_norm(pt_v3(0.0f, 0.25f, 1.0f));
    c.forward = pt_v3_neg(dir);
    c.right = pt_v3_norm(pt_v3_cross(c.forward, pt_v3(0.0f, 1.0f, 0.0f)));
    c.up = pt_v3_cross(c.right, c.forward);
    /* The box's projection fitted to the image: the camera sits at distance
     * d from the centre, on dir; a corner v (from the centre) at depth
     * d + v.forward is inside the view when |v.right| <= (d + v.forward)
     * tan(xfov/2) and |v.up| <= (d + v.forward) tan(yfov/2), so d is the
     * largest of |v.right| / tx - v.forward and |v.up| / ty - v.forward over
     * the 8 corners, with 5 % of margin in the tangents. A flat board then
     * fills the frame, where the bounding sphere left it half of it. */
    float ty = tanf(0.5f * c.yfov) / 1.05f, tx = ty * a;
    float dist = radius / sinf(atanf(a < 1.0f ? tx : ty)); /* the sphere's: no box */
    if (box) {
        dist = 0.0f;
        float deepest = 0.0f;
        for (int k = 0; k < 8; k++) {
            pt_vec3 v =
                pt_v3(0.5f * ext.x * (k & 1 ? 1.0f : -1.0f), 0.5f * ext.y * (k & 2 ? 1.0f : -1.0f),
                      0.5f * ext.z * (k & 4 ? 1.0f : -1.0f));
            float x = fabsf(pt_v3_dot(v, c.right)), y = fabsf(pt_v3_dot(v, c.up));
            float z = pt_v3_dot(v, c.forward);
            float need = fmaxf(x / tx, y / ty) - z;
            dist = fmaxf(dist, need);
            deepest = fmaxf(deepest, -z);
        }
        /* Never inside the box: in front of its nearest corner by 1 % of its size. */
        dist = fmaxf(dist, deepest + 0.01f * radius);
    }
    c.position = pt_v3_add(centre, pt_v3_scale(dir, dist));
    c.znear = dist * 1e-4f;
    c.framed = 1;
    snprintf(c.name, sizeof c.name, "(framed)");
    *out = c;
}

void pt_scene_frame_camera(pt_scene *scene, float aspect)
{
    pt_camera_frame(scene->bounds_min, scene->bounds_max, aspect, &scene->camera);
}

void pt_scene_free(pt_scene *s)
{
    if (!s)
        return;
    pt_free(s->positions);
    pt_free(s->normals);
    pt_free(s->uvs);
    pt_free(s->uvs1);
    pt_free(s->tangents);
    pt_free(s->colors);
    pt_free(s->indices);
    pt_free(s->tri_material);
    pt_free(s->tri_object);
    pt_free(s->object_names);
    pt_free(s->materials);
    free_textures(s->textures, s->num_textures);
    pt_free(s->cameras);
    pt_free(s->punctual);
    pt_free(s->portals);
    pt_free(s->portal_fronts);
    pt_motion_free(s->motion);
    pt_free(s->prototypes);
    pt_free(s->instances);
    pt_free(s);
}

int pt_scene_find_camera(const pt_scene *s, const char *name)
{
    if (!name)
        return s->num_cameras > 0 ? 0 : -1;
    for (uint32_t i = 0; i < s->num_cameras; i++)
        if (strcmp(s->cameras[i].name, name) == 0)
            return (int)i;
    for (uint32_t i = 0; i < s->num_cameras; i++)
        if (s->cameras[i].node[0] && strcmp(s->cameras[i].node, name) == 0)
            return (int)i;
    /* A decimal index, plain digits, as --list numbers them. */
    size_t n = strlen(name);
    if (n == 0 || n > 9 || strspn(name, "0123456789") != n)
        return -1;
    unsigned long k = strtoul(name, NULL, 10);
    return k < s->num_cameras ? (int)k : -1;
}

/* The placement's text with `digits` significant digits into buf; its length. */
static int look_format(const double from[3], const double at[3], double fov_deg, double ortho_width,
                       int digits, char *buf, size_t cap)
{
    int n =
        snprintf(buf, cap, PT_CAMERA_LOOK_PREFIX "%.*g,%.*g,%.*g:%.*g,%.*g,%.*g", digits, from[0],
                 digits, from[1], digits, from[2], digits, at[0], digits, at[1], digits, at[2]);
    if (ortho_width > 0.0)
        n += snprintf(buf + n, cap - (size_t)n, ":ortho=%.*g", digits, ortho_width);
    else if (fov_deg > 0.0)
        n += snprintf(buf + n, cap - (size_t)n, ":fov=%.*g", digits, fov_deg);
    return n;
}

pt_status pt_camera_look_text_fit(const double from[3], const double at[3], double fov_deg,
                                  double ortho_width, char *out, size_t cap, pt_error *err)
{
    char buf[256];
    for (int digits = 9; digits >= 4; digits--) {
        if ((size_t)look_format(from, at, fov_deg, ortho_width, digits, buf, sizeof buf) >= cap)
            continue;
        pt_camera c;
        pt_status st = pt_camera_look_parse(buf, &c, err);
        if (st == PT_OK)
            memcpy(out, buf, strlen(buf) + 1);
        return st;
    }
    return pt_error_set(err, PT_ERR_ARG,
                        "the camera placement '%s' is over %zu bytes as text even with 4 digits",
                        buf, cap - 1);
}

pt_status pt_camera_look_text(const double from[3], const double at[3], double fov_deg,
                              double ortho_width, char *out, size_t cap, pt_error *err)
{
    char buf[256];
    int n = look_format(from, at, fov_deg, ortho_width, 9, buf, sizeof buf);
    if ((size_t)n >= cap)
        return pt_error_set(err, PT_ERR_ARG,
                            "the camera placement '%s' is %d bytes as text, over %zu: give the "
                            "numbers with fewer digits",
                            buf, n, cap - 1);
    pt_camera c;
    pt_status st = pt_camera_look_parse(buf, &c, err);
    if (st != PT_OK)
        return st;
    memcpy(out, buf, (size_t)n + 1);
    return PT_OK;
}

/* "X,Y,Z" at *p, up to its end or a ':': three finite numbers within the
 * coordinate cap; p moves past them. */
static int read_point(const char **p, double v[3])
{
    for (int k = 0; k < 3; k++) {
        char *end;
        v[k] = strtod(*p, &end);
        if (end == *p || !isfinite(v[k]) || fabs(v[k]) > PT_SCENE_MAX_COORD)
            return -1;
        if (k < 2 && *end != ',')
            return -1;
        *p = end + (k < 2);
    }
    return 0;
}

/* The placement text as a camera whose position is from * sc + t - origin
 * (in double: a scene far from zero keeps it). */
static pt_status look_build(const char *text, double sc, const double t[3], const double origin[3],
                            pt_camera *out, pt_error *err)
{
    const char *p = text;
    double from[3], at[3], fov = 40.0, width = 0.0;
    size_t pre = strlen(PT_CAMERA_LOOK_PREFIX);
    if (strncmp(p, PT_CAMERA_LOOK_PREFIX, pre) != 0)
        goto bad;
    p += pre;
    if (read_point(&p, from) != 0 || *p++ != ':' || read_point(&p, at) != 0)
        goto bad;
    if (*p) {
        char *end;
        if (strncmp(p, ":fov=", 5) == 0) {
            fov = strtod(p + 5, &end);
            if (end == p + 5 || *end || !(fov > 0.0 && fov < 180.0))
                return pt_error_set(err, PT_ERR_ARG,
                                    "camera '%.64s': the field of view must be in (0, 180) "
                                    "degrees",
                                    text);
        } else if (strncmp(p, ":ortho=", 7) == 0) {
            width = strtod(p + 7, &end);
            if (end == p + 7 || *end || !(width > 0.0 && width <= PT_SCENE_MAX_COORD))
                return pt_error_set(err, PT_ERR_ARG,
                                    "camera '%.64s': the orthographic width must be > 0", text);
        } else {
            goto bad;
        }
    }
    pt_camera c;
    memset(&c, 0, sizeof c);
    pt_vec3 d = pt_v3((float)(at[0] - from[0]), (float)(at[1] - from[1]), (float)(at[2] - from[2]));
    float len = pt_v3_len(d);
    if (!(len > 0.0f) || !isfinite(len))
        return pt_error_set(err, PT_ERR_ARG,
                            "camera '%.64s': the camera is where it looks (or too far from it)",
                            text);
    c.forward = pt_v3_scale(d, 1.0f / len);
    /* Up is +Y, glTF's; looking straight up or down, -Z is the image's up. */
    pt_vec3 up = fabsf(c.forward.y) > 0.9999f ? pt_v3(0.0f, 0.0f, c.forward.y > 0 ? 1.0f : -1.0f)
                                              : pt_v3(0.0f, 1.0f, 0.0f);
    c.right = pt_v3_norm(pt_v3_cross(c.forward, up));
    c.up = pt_v3_cross(c.right, c.forward);
    c.position =
        pt_v3((float)(from[0] * sc + t[0] - origin[0]), (float)(from[1] * sc + t[1] - origin[1]),
              (float)(from[2] * sc + t[2] - origin[2]));
    if (!pt_isfinite3(c.position))
        return pt_error_set(err, PT_ERR_ARG, "camera '%.64s' is not finite after scaling", text);
    if (width > 0.0) {
        c.ortho = 1;
        c.xmag = (float)(0.5 * width * sc);
        c.ymag = 0.0f; /* the image's aspect gives it (pt_renderer_new) */
    } else {
        c.yfov = (float)(fov * PT_PI / 180.0);
    }
    /* A width or an angle too small for a float (5e-56) would be 0 here. */
    if (!(c.ortho ? c.xmag > 0.0f && isfinite(c.xmag) : c.yfov > 0.0f))
        return pt_error_set(err, PT_ERR_ARG, "camera '%.64s': the %s is too small to render", text,
                            c.ortho ? "orthographic width" : "field of view");
    c.znear = (float)(1e-4 * len * sc);
    snprintf(c.name, sizeof c.name, "%s", text);
    *out = c;
    return PT_OK;
bad:
    return pt_error_set(
        err, PT_ERR_ARG,
        "camera '%.64s' is not " PT_CAMERA_LOOK_PREFIX "X,Y,Z:X,Y,Z[:fov=DEG|:ortho=WIDTH]", text);
}

pt_status pt_camera_look_parse(const char *text, pt_camera *out, pt_error *err)
{
    const double zero[3] = {0.0, 0.0, 0.0};
    return look_build(text, 1.0, zero, zero, out, err);
}

pt_status pt_camera_look_option(pt_camera_look_opts *l, const char *opt, const char *text,
                                pt_error *err)
{
    pt_status st;
    if (strcmp(opt, "--camera-from") == 0) {
        st = pt_opt_point(opt, text, PT_SCENE_MAX_COORD, l->from, err);
        l->has_from = st == PT_OK;
    } else if (strcmp(opt, "--camera-at") == 0) {
        st = pt_opt_point(opt, text, PT_SCENE_MAX_COORD, l->at, err);
        l->has_at = st == PT_OK;
    } else if (strcmp(opt, "--fov") == 0) {
        st = pt_opt_double(opt, text, 0.0, 180.0, &l->fov, err);
        if (st == PT_OK && !(l->fov > 0.0 && l->fov < 180.0))
            st = pt_error_set(err, PT_ERR_ARG, "--fov: '%s' is not in (0, 180) degrees", text);
    } else {
        st = pt_opt_positive(opt, text, PT_SCENE_MAX_COORD, &l->ortho, err);
    }
    return st;
}

pt_status pt_camera_look_finish(const pt_camera_look_opts *l, const char *camera_name, char *out,
                                size_t cap, int *given, pt_error *err)
{
    *given = 0;
    if (!l->has_from && !l->has_at && l->fov == 0.0 && l->ortho == 0.0)
        return PT_OK;
    if (!l->has_from || !l->has_at)
        return pt_error_set(err, PT_ERR_ARG,
                            "%s: a camera is placed by --camera-from X,Y,Z and --camera-at X,Y,Z "
                            "together",
                            l->has_from  ? "--camera-from"
                            : l->has_at  ? "--camera-at"
                            : l->fov > 0 ? "--fov"
                                         : "--ortho");
    if (l->fov > 0.0 && l->ortho > 0.0)
        return pt_error_set(err, PT_ERR_ARG,
                            "--fov and --ortho are two projections; give one (or neither)");
    if (camera_name)
        return pt_error_set(err, PT_ERR_ARG,
                            "--camera picks the file's camera, --camera-from places one; give one");
    pt_status st = pt_camera_look_text(l->from, l->at, l->fov, l->ortho, out, cap, err);
    if (st == PT_OK)
        *given = 1;
    return st;
}

/* A placement (PT_CAMERA_LOOK_PREFIX) in world space, through the build's
 * scale and translation, to scene space. */
static pt_status look_camera(pt_scene *s, const char *text, double sc, const double t[3],
                             pt_error *err)
{
    pt_camera c;
    pt_status st = look_build(text, sc, t, s->origin, &c, err);
    if (st == PT_OK)
        s->camera = c;
    return st;
}

static pt_status choose_camera(pt_scene *s, const char *name, pt_error *err)
{
    if (name) {
        int k = pt_scene_find_camera(s, name);
        if (k >= 0) {
            s->camera = s->cameras[k];
            return PT_OK;
        }
        char list[400];
        size_t n = 0;
        list[0] = 0;
        for (uint32_t i = 0; i < s->num_cameras && n + 1 < sizeof list; i++) {
            int w = snprintf(list + n, sizeof list - n, "%s%u '%s'", i ? ", " : "", i,
                             s->cameras[i].name);
            if (w < 0)
                break;
            n += (size_t)w;
        }
        if (n >= sizeof list)
            snprintf(list + sizeof list - 5, 5, "...");
        if (s->num_cameras == 0)
            return pt_error_set(err, PT_ERR_ARG,
                                "no camera named '%.64s': the scene has no cameras", name);
        return pt_error_set(err, PT_ERR_ARG, "no camera named '%.64s'; cameras: %s", name, list);
    }
    if (s->num_cameras > 0)
        s->camera = s->cameras[0];
    else
        pt_scene_frame_camera(s, 0.0f);
    return PT_OK;
}

static uint32_t scene_features(const pt_scene *s, int has_uv, pt_error *err, pt_status *st)
{
    uint8_t *used = pt_calloc(s->num_materials, 1);
    uint32_t f = has_uv ? PT_FEAT_UVS : 0;
    if (!used) {
        *st = pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory");
        return 0;
    }
    for (uint32_t t = 0; t < s->num_triangles; t++)
        used[s->tri_material[t]] = 1;
    for (uint32_t i = 0; i < s->num_materials; i++) {
        const pt_material *m = &s->materials[i];
        if (!used[i])
            continue;
        if (m->unlit) {
            /* Only its base colour (and its alpha) is read. */
            f |= PT_FEAT_UNLIT;
            if (m->base_color_tex >= 0)
                f |= PT_FEAT_TEXTURES;
            if (m->alpha_mode != PT_ALPHA_OPAQUE)
                f |= PT_FEAT_ALPHA;
            continue;
        }
        if (m->spec_gloss) {
            /* Its own inputs: always a GGX lobe (F0 = specular, F90 = 1). */
            f |= PT_FEAT_SPEC_GLOSS | PT_FEAT_GLOSSY;
            if (m->sg_tex >= 0)
                f |= PT_FEAT_TEXTURES;
        }
        if (m->ext & PT_MATX_SPECULAR_TEX)
            f |= PT_FEAT_SPECULAR_TEX | PT_FEAT_TEXTURES;
        if (m->ext & PT_MATX_DIFFUSE_TRANSMISSION) {
            f |= PT_FEAT_DIFFUSE_TRANSMISSION | PT_FEAT_GLOSSY;
            if (m->diffuse_transmission_tex >= 0 || m->diffuse_transmission_color_tex >= 0)
                f |= PT_FEAT_TEXTURES;
        }
        if (m->ext & PT_MATX_ANISOTROPY) {
            f |= PT_FEAT_ANISOTROPY | PT_FEAT_GLOSSY;
            if (m->anisotropy_tex >= 0)
                f |= PT_FEAT_TEXTURES;
        }
        if (m->ext & PT_MATX_IRIDESCENCE) {
            f |= PT_FEAT_IRIDESCENCE | PT_FEAT_GLOSSY;
            if (m->iridescence_tex >= 0 || m->irid_thickness_tex >= 0)
                f |= PT_FEAT_TEXTURES;
        }
        if (m->base_color_tex >= 0 || m->metal_rough_tex >= 0)
            f |= PT_FEAT_TEXTURES;
        /* Pure Lambert only without any GGX lobe: not metallic (factor and
         * texture) and no dielectric specular (KHR_materials_specular = 0). */
        if (!(m->metallic == 0.0f && m->metal_rough_tex < 0 && m->specular == 0.0f))
            f |= PT_FEAT_GLOSSY;
        if (m->emissive[0] > 0.0f || m->emissive[1] > 0.0f || m->emissive[2] > 0.0f) {
            f |= PT_FEAT_EMITTERS;
            if (m->emissive_tex >= 0)
                f |= PT_FEAT_EMISSIVE_TEX;
        }
        if (!m->double_sided)
            f |= PT_FEAT_SINGLE_SIDED;
        if (m->alpha_mode != PT_ALPHA_OPAQUE)
            f |= PT_FEAT_ALPHA;
        if (m->transmission > 0.0f) {
            /* The glass BSDF has GGX lobes: the Lambert paths must not run. */
            f |= PT_FEAT_TRANSMISSION | PT_FEAT_GLOSSY;
            if (m->transmission_tex >= 0)
                f |= PT_FEAT_TEXTURES;
            if (pt_material_absorbs(m))
                f |= PT_FEAT_VOLUME;
            if (m->dispersion > 0.0f && m->thickness > 0.0f)
                f |= PT_FEAT_DISPERSION;
        }
        if (m->diffuse_transmission > 0.0f && !(m->transmission > 0.0f) && pt_material_absorbs(m))
            f |= PT_FEAT_VOLUME; /* a diffuse transmitter's volume */
        if (m->normal_tex >= 0)
            f |= PT_FEAT_NORMAL_MAP;
        /* Layers have GGX-like lobes: the Lambert paths must not run. */
        if (m->clearcoat > 0.0f) {
            f |= PT_FEAT_CLEARCOAT | PT_FEAT_GLOSSY;
            if (m->clearcoat_tex >= 0 || m->clearcoat_rough_tex >= 0)
                f |= PT_FEAT_TEXTURES;
            /* The coat's normal map needs the tangents (and the UVs). */
            if (m->clearcoat_normal_tex >= 0)
                f |= PT_FEAT_NORMAL_MAP | PT_FEAT_TEXTURES;
        }
        if (m->sheen_color[0] > 0.0f || m->sheen_color[1] > 0.0f || m->sheen_color[2] > 0.0f) {
            f |= PT_FEAT_SHEEN | PT_FEAT_GLOSSY;
            if (m->sheen_color_tex >= 0 || m->sheen_rough_tex >= 0)
                f |= PT_FEAT_TEXTURES;
        }
    }
    pt_free(used);
    *st = PT_OK;
    return f;
}

/* The origin positions are stored relative to: the centre of the bounds,
 * rounded to a multiple of g, the smallest power of two above 4x the largest
 * extent. Stored coordinates then stay within about 4.5 extents of zero (at
 * most ~3 bits of float precision from perfectly centred), the origin has a
 * short mantissa, and a scene whose centre is within two extents of the world
 * origin keeps origin 0 and its world-space coordinates unchanged. */
static double rebase_origin(double lo, double hi, double extent)
{
    double c = 0.5 * lo + 0.5 * hi;
    if (!(extent > 0.0))
        return c; /* every vertex at one coordinate: store zeros */
    int e;
    frexp(4.0 * extent, &e);
    double g = ldexp(1.0, e);
    return nearbyint(c / g) * g;
}

/* The optional attributes go to the scene where something reads them:
 * TEXCOORD_1 and COLOR_0 when some mesh had them, tangents when some
 * material has a normal texture, a clear coat with its own normal texture or
 * anisotropy (then generated where missing, from the normal texture's
 * coordinate set, else the coat normal texture's, else the anisotropy
 * texture's). Sets PT_FEAT_NORMAL_MAP and
 * PT_FEAT_VERTEX_COLOR. */
static pt_status finish_extra(pt_scene_builder *b, pt_scene *s, pt_error *err)
{
    s->uvs1 = b->uv1;
    b->uv1 = NULL;
    if (b->col) {
        s->colors = b->col;
        b->col = NULL;
        s->features |= PT_FEAT_VERTEX_COLOR;
    }
    if (!(s->features & (PT_FEAT_NORMAL_MAP | PT_FEAT_ANISOTROPY)))
        return PT_OK;
    if (!b->tan) {
        b->tan = pt_calloc((size_t)s->num_vertices * 4, sizeof(float));
        if (!b->tan)
            return pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory for tangents");
    }
    s->tangents = b->tan;
    b->tan = NULL;
    uint8_t *use = pt_malloc(s->num_triangles);
    if (!use)
        return pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory for tangents");
    pt_status st = PT_OK;
    for (int set = 0; set < 2 && st == PT_OK; set++) {
        const float *uv = set ? s->uvs1 : s->uvs;
        int any = 0;
        for (uint32_t t = 0; t < s->num_triangles; t++) {
            const pt_material *m = &s->materials[s->tri_material[t]];
            /* One tangent per vertex: a triangle with both maps gets it
             * from the base normal map's coordinate set. */
            int coat = m->clearcoat > 0.0f && m->clearcoat_normal_tex >= 0;
            int slot = m->normal_tex >= 0 ? PT_SLOT_NORMAL
                                          : (coat ? PT_SLOT_CLEARCOAT_NORMAL : PT_SLOT_ANISOTROPY);
            int mapped = m->normal_tex >= 0 || coat || (m->ext & PT_MATX_ANISOTROPY);
            use[t] = mapped && m->tex_xf[slot].texcoord == set;
            any |= use[t];
        }
        /* Without that UV set every vertex gets a frame from its normal. */
        if (any && uv)
            st = pt_tangents_generate(s->positions, s->normals, uv, s->indices, s->num_triangles,
                                      use, s->num_vertices, s->tangents, err);
        else if (any) {
            float *flat = pt_calloc((size_t)s->num_vertices * 2, sizeof(float));
            if (!flat) {
                st = pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory for tangents");
                break;
            }
            st = pt_tangents_generate(s->positions, s->normals, flat, s->indices, s->num_triangles,
                                      use, s->num_vertices, s->tangents, err);
            pt_free(flat);
        }
    }
    pt_free(use);
    return st;
}

/* World matrix x (column-major 4x4) after opts' scale sc and translation
 * t: y = sc x + t, as the 3x4 of its rows. */
static void instance_world(const double *x, double sc, const double t[3], double m[3][4])
{
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 4; k++)
            m[r][k] = sc * x[4 * k + r];
        m[r][3] += t[r];
    }
}

/* The box of the 8 corners of [plo, phi] under m, into [lo, hi]. */
static void box_under(const double m[3][4], const double plo[3], const double phi[3], double lo[3],
                      double hi[3])
{
    for (int c = 0; c < 8; c++) {
        double p[3] = {c & 1 ? phi[0] : plo[0], c & 2 ? phi[1] : plo[1], c & 4 ? phi[2] : plo[2]};
        for (int r = 0; r < 3; r++) {
            double y = m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3];
            lo[r] = fmin(lo[r], y);
            hi[r] = fmax(hi[r], y);
        }
    }
}

/* Whether the bounds take every instance's every vertex (then they are
 * the copies' bounds, bit for bit, and so is a framed camera), or, past
 * 64 Mi vertex maps (a second or so), each prototype's box under each
 * instance (a larger box that holds them). */
static int tight_bounds(const pt_scene_builder *b, const pt_scene *s)
{
    uint64_t work = 0;
    for (uint32_t i = 0; i < b->ninst; i++)
        work += s->prototypes[b->inst_proto[i]].num_vertices;
    return work <= (64u << 20);
}

/* The box of prototype p's vertices (double, pos) under m, less origin
 * (NULL: 0), into [lo, hi]: the values a copy's builder computes. */
static void vertices_under(const double m[3][4], const double *pos, const pt_prototype *p,
                           const double *origin, double lo[3], double hi[3])
{
    for (uint32_t v = p->first_vertex; v < p->first_vertex + p->num_vertices; v++) {
        const double *q = pos + 3 * (size_t)v;
        for (int r = 0; r < 3; r++) {
            double y = m[r][0] * q[0] + m[r][1] * q[1] + m[r][2] * q[2] + m[r][3];
            if (origin)
                y -= origin[r];
            lo[r] = fmin(lo[r], y);
            hi[r] = fmax(hi[r], y);
        }
    }
}

/* The prototypes' own boxes (double, 6 per prototype, from b->pos) and the
 * scene's instances (their records filled but for the origin, which the
 * caller subtracts in place_instances); the world boxes of the instances
 * widen [lo, hi]. */
static pt_status finish_instances(pt_scene_builder *b, pt_scene *s, double sc, const double t[3],
                                  double lo[3], double hi[3], pt_error *err)
{
    if (b->nproto == 0)
        return PT_OK;
    s->prototypes = b->protos;
    s->num_prototypes = b->nproto;
    b->protos = NULL;
    b->nproto = 0;
    if (b->ninst == 0)
        return PT_OK;
    double *box = pt_malloc_array((size_t)s->num_prototypes * 6, sizeof(double));
    s->instances = pt_malloc_array(b->ninst, sizeof(pt_instance));
    if (!box || !s->instances) {
        pt_free(box);
        return pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory for instances");
    }
    s->num_instances = b->ninst;
    const int tight = tight_bounds(b, s);
    for (uint32_t i = 0; i < s->num_prototypes; i++) {
        const pt_prototype *p = &s->prototypes[i];
        double *bx = box + 6 * (size_t)i;
        bx[0] = bx[1] = bx[2] = INFINITY;
        bx[3] = bx[4] = bx[5] = -INFINITY;
        for (uint32_t v = p->first_vertex; v < p->first_vertex + p->num_vertices; v++)
            for (int r = 0; r < 3; r++) {
                bx[r] = fmin(bx[r], b->pos[3 * (size_t)v + r]);
                bx[3 + r] = fmax(bx[3 + r], b->pos[3 * (size_t)v + r]);
            }
    }
    for (uint32_t i = 0; i < b->ninst; i++) {
        const double *x = b->inst_xf + 16 * (size_t)i;
        pt_instance *in = &s->instances[i];
        double m[3][4], c[3][3];
        instance_world(x, sc, t, m);
        double det = pt_normal_matrix(x, c);
        in->proto = b->inst_proto[i];
        in->object = b->inst_obj[i];
        if (in->object == UINT32_MAX) {
            const pt_prototype *pp = &s->prototypes[in->proto];
            in->object = pp->num_tris > 0 ? s->tri_object[pp->first_tri] : 0;
        }
        in->tan_sign = det < 0.0 ? -1.0f : 1.0f;
        for (int r = 0; r < 3; r++)
            for (int k = 0; k < 3; k++)
                in->nm[3 * k + r] = (float)(c[r][k] / det); /* inverse transpose */
        const double *bx = box + 6 * (size_t)in->proto;
        const pt_prototype *p = &s->prototypes[in->proto];
        if (p->num_tris > 0 && tight)
            vertices_under(m, b->pos, p, NULL, lo, hi);
        else if (p->num_tris > 0)
            box_under(m, bx, bx + 3, lo, hi);
        for (int r = 0; r < 3; r++) {
            if (!(fabs(m[r][3]) <= (double)PT_SCENE_MAX_COORD)) {
                pt_free(box);
                return pt_error_set(err, PT_ERR_ARG, "instance %u is over %g after scaling by %g",
                                    i, (double)PT_SCENE_MAX_COORD, sc);
            }
        }
    }
    pt_free(box);
    return PT_OK;
}

/* The instances' 3x4 maps into scene space (the origin subtracted), and
 * their corners in the float bounds. */
static void place_instances(const pt_scene_builder *b, pt_scene *s, double sc, const double t[3],
                            pt_vec3 *flo, pt_vec3 *fhi)
{
    const int tight = s->num_instances > 0 && tight_bounds(b, s);
    for (uint32_t i = 0; i < s->num_instances; i++) {
        pt_instance *in = &s->instances[i];
        double m[3][4];
        instance_world(b->inst_xf + 16 * (size_t)i, sc, t, m);
        for (int r = 0; r < 3; r++) {
            m[r][3] -= s->origin[r];
            for (int k = 0; k < 4; k++)
                in->xf[3 * k + r] = (float)m[r][k];
        }
        const pt_prototype *p = &s->prototypes[in->proto];
        if (p->num_tris == 0)
            continue;
        if (tight) {
            /* As a copy's stored vertices: float(world - origin). */
            double lo[3] = {INFINITY, INFINITY, INFINITY},
                   hi[3] = {-INFINITY, -INFINITY, -INFINITY};
            double w[3][4];
            instance_world(b->inst_xf + 16 * (size_t)i, sc, t, w);
            vertices_under(w, b->pos, p, s->origin, lo, hi);
            *flo = pt_v3(fminf(flo->x, (float)lo[0]), fminf(flo->y, (float)lo[1]),
                         fminf(flo->z, (float)lo[2]));
            *fhi = pt_v3(fmaxf(fhi->x, (float)hi[0]), fmaxf(fhi->y, (float)hi[1]),
                         fmaxf(fhi->z, (float)hi[2]));
            continue;
        }
        /* The float corners of the map of the prototype's float box. */
        double plo[3] = {INFINITY, INFINITY, INFINITY}, phi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (uint32_t v = p->first_vertex; v < p->first_vertex + p->num_vertices; v++)
            for (int r = 0; r < 3; r++) {
                plo[r] = fmin(plo[r], s->positions[3 * (size_t)v + r]);
                phi[r] = fmax(phi[r], s->positions[3 * (size_t)v + r]);
            }
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        box_under(m, plo, phi, lo, hi);
        /* Outward by a float's rounding, so that the box holds the points
         * shading computes in float. */
        *flo = pt_v3(fminf(flo->x, nextafterf((float)lo[0], -INFINITY)),
                     fminf(flo->y, nextafterf((float)lo[1], -INFINITY)),
                     fminf(flo->z, nextafterf((float)lo[2], -INFINITY)));
        *fhi = pt_v3(fmaxf(fhi->x, nextafterf((float)hi[0], INFINITY)),
                     fmaxf(fhi->y, nextafterf((float)hi[1], INFINITY)),
                     fmaxf(fhi->z, nextafterf((float)hi[2], INFINITY)));
    }
}

pt_status pt_scene_builder_finish(pt_scene_builder *b, const pt_scene_opts *opts, pt_scene **out,
                                  pt_error *err)
{
    pt_status st;
    pt_scene *s = NULL;
    float scale = opts && opts->scale != 0.0f ? opts->scale : 1.0f;
    pt_vec3 tr = opts ? opts->translate : pt_v3(0, 0, 0);
    /* Flat triangles and vertices first, then the prototypes'. */
    const uint32_t nvf = b->nproto ? b->protos[0].first_vertex : b->nv;
    const uint32_t ntf = b->nproto ? b->protos[0].first_tri : b->nt;
    uint32_t placed = 0; /* instances of a prototype with triangles */
    for (uint32_t i = 0; i < b->ninst; i++)
        placed += b->protos[b->inst_proto[i]].num_tris > 0;
    if (ntf == 0 && placed == 0) {
        st = pt_error_set(err, PT_ERR_FORMAT, "no triangles");
        goto fail;
    }
    if (b->in_proto) {
        st = pt_error_set(err, PT_ERR_ARG, "prototype %u is not ended", b->nproto - 1);
        goto fail;
    }
    for (uint32_t i = ntf; i < b->nt; i++) {
        const pt_material *m = &b->mats[b->tmat[i]];
        if (m->emissive[0] > 0.0f || m->emissive[1] > 0.0f || m->emissive[2] > 0.0f) {
            st = pt_error_set(err, PT_ERR_ARG,
                              "material '%.64s' of an instanced prototype is emissive (lights "
                              "need their copies)",
                              m->name);
            goto fail;
        }
    }
    if (!(scale > 0.0f) || !isfinite(scale) || !pt_isfinite3(tr)) {
        st = pt_error_set(err, PT_ERR_ARG, "scale %g / translation is invalid", (double)scale);
        goto fail;
    }
    s = pt_calloc(1, sizeof *s);
    if (!s) {
        st = pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory");
        goto fail;
    }
    s->positions = pt_malloc_array((size_t)b->nv * 3, sizeof(float));
    if (!s->positions) {
        st = pt_error_set(err, PT_ERR_NOMEM, "scene: out of memory");
        goto fail;
    }
    /* Hand the other arrays over; the builder no longer owns them. */
    s->num_vertices = b->nv;
    s->num_triangles = b->nt;
    s->normals = b->nrm;
    s->indices = b->idx;
    s->tri_material = b->tmat;
    s->tri_object = b->tobj;
    s->num_objects = b->nobj;
    s->object_names = b->objs;
    b->tobj = NULL;
    b->objs = NULL;
    b->nobj = 0;
    s->materials = b->mats;
    s->num_materials = b->nmat;
    s->textures = b->texs;
    s->num_textures = b->ntex;
    s->cameras = b->cams;
    s->num_cameras = b->ncam;
    s->punctual = b->puns;
    s->num_punctual = b->npun;
    b->puns = NULL;
    b->nrm = NULL;
    b->idx = b->tmat = NULL;
    b->mats = NULL;
    b->texs = NULL;
    b->ntex = 0;
    b->cams = NULL;
    if (b->has_uv) {
        s->uvs = b->uv;
        b->uv = NULL;
    }

    /* opts' scale and translation in double, in place, with the double bounds. */
    const double sc = scale, t[3] = {tr.x, tr.y, tr.z};
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    s->num_flat_triangles = ntf;
    s->num_flat_vertices = nvf;
    if ((st = finish_instances(b, s, sc, t, lo, hi, err)) != PT_OK)
        goto fail;
    for (uint32_t v = 0; v < nvf; v++) {
        double *p = b->pos + 3 * (size_t)v;
        for (int r = 0; r < 3; r++) {
            p[r] = p[r] * sc + t[r];
            lo[r] = fmin(lo[r], p[r]);
            hi[r] = fmax(hi[r], p[r]);
        }
        if (!(fabs(p[0]) <= (double)PT_SCENE_MAX_COORD &&
              fabs(p[1]) <= (double)PT_SCENE_MAX_COORD &&
              fabs(p[2]) <= (double)PT_SCENE_MAX_COORD)) {
            st = pt_error_set(err, PT_ERR_ARG, "vertex %u is over %g after scaling by %g", v,
                              (double)PT_SCENE_MAX_COORD, (double)scale);
            goto fail;
        }
    }
    double extent = fmax(hi[0] - lo[0], fmax(hi[1] - lo[1], hi[2] - lo[2]));
    for (int r = 0; r < 3; r++)
        s->origin[r] = rebase_origin(lo[r], hi[r], extent);

    /* Stored = float(world - origin); the float bounds are taken from the
     * stored values so they contain every vertex exactly. */
    pt_vec3 flo = pt_v3(INFINITY, INFINITY, INFINITY), fhi = pt_v3(-INFINITY, -INFINITY, -INFINITY);
    for (uint32_t v = 0; v < b->nv; v++) {
        const double *p = b->pos + 3 * (size_t)v;
        float *q = s->positions + 3 * (size_t)v;
        if (v >= nvf) { /* a prototype's: its own space, and instance_bounds' */
            for (int r = 0; r < 3; r++)
                q[r] = (float)p[r];
            continue;
        }
        for (int r = 0; r < 3; r++)
            q[r] = (float)(p[r] - s->origin[r]);
        if (!finite_n(q, 3)) {
            st = pt_error_set(err, PT_ERR_ARG, "vertex %u is not finite after scaling", v);
            goto fail;
        }
        flo = pt_v3(fminf(flo.x, q[0]), fminf(flo.y, q[1]), fminf(flo.z, q[2]));
        fhi = pt_v3(fmaxf(fhi.x, q[0]), fmaxf(fhi.y, q[1]), fmaxf(fhi.z, q[2]));
    }
    place_instances(b, s, sc, t, &flo, &fhi);
    s->bounds_min = flo;
    s->bounds_max = fhi;
    pt_free(b->pos);
    b->pos = NULL;
    for (uint32_t i = 0; i < s->num_cameras; i++) {
        pt_camera *c = &s->cameras[i];
        const double *p = b->cam_pos + 3 * (size_t)i;
        c->position = pt_v3((float)(p[0] * sc + t[0] - s->origin[0]),
                            (float)(p[1] * sc + t[1] - s->origin[1]),
                            (float)(p[2] * sc + t[2] - s->origin[2]));
        c->znear *= scale;
        c->xmag *= scale;
        c->ymag *= scale;
        if (!pt_isfinite3(c->position) || !isfinite(c->znear)) {
            st = pt_error_set(err, PT_ERR_ARG, "camera '%.64s' is not finite after scaling",
                              c->name);
            goto fail;
        }
    }
    for (uint32_t i = 0; i < s->num_punctual; i++) {
        pt_punctual *l = &s->punctual[i];
        const double *p = b->pun_pos + 3 * (size_t)i;
        l->position = pt_v3((float)(p[0] * sc + t[0] - s->origin[0]),
                            (float)(p[1] * sc + t[1] - s->origin[1]),
                            (float)(p[2] * sc + t[2] - s->origin[2]));
        if (l->type != PT_PUNCTUAL_DIRECTIONAL)
            l->intensity = pt_v3_scale(l->intensity, (float)(sc * sc));
        l->range *= scale;
        if (!pt_isfinite3(l->position) || !pt_isfinite3(l->intensity) || !isfinite(l->range)) {
            st =
                pt_error_set(err, PT_ERR_ARG, "light '%.64s' is not finite after scaling", l->name);
            goto fail;
        }
    }
    if (b->nportal > 0) {
        s->portals = pt_malloc_array(9 * (size_t)b->nportal, sizeof(float));
        s->portal_fronts = pt_malloc_array(3 * (size_t)b->nportal, sizeof(float));
        if (!s->portals || !s->portal_fronts) {
            st = pt_error_set(err, PT_ERR_NOMEM, "portals: out of memory");
            goto fail;
        }
        s->num_portals = b->nportal;
        for (size_t i = 0; i < 9 * (size_t)b->nportal; i++)
            s->portals[i] = (float)(b->portals[i] * sc + t[i % 3] - s->origin[i % 3]);
        for (uint32_t i = 0; i < b->nportal; i++) {
            double c[3]; /* the edges scale by sc, their cross product by sc^2 */
            portal_cross(b->portals + 9 * (size_t)i, c);
            double len = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
            for (int r = 0; r < 3; r++)
                s->portal_fronts[3 * (size_t)i + r] = (float)(c[r] / len);
        }
        if (!finite_n(s->portals, (int)(9 * b->nportal))) {
            st = pt_error_set(err, PT_ERR_ARG, "a portal is not finite after scaling");
            goto fail;
        }
    }
    s->features = scene_features(s, b->has_uv, err, &st);
    if (st != PT_OK)
        goto fail;
    if (s->num_punctual > 0)
        s->features |= PT_FEAT_PUNCTUAL;
    if (s->num_portals > 0)
        s->features |= PT_FEAT_PORTAL;
    if (s->num_instances > 0)
        s->features |= PT_FEAT_INSTANCES;
    if ((st = finish_extra(b, s, err)) != PT_OK)
        goto fail;
    if ((st = pt_motion_build_finish(b->motion, s, sc, t, err)) != PT_OK)
        goto fail;
    if (b->hash_set) {
        memcpy(s->hash, b->hash, sizeof s->hash);
    } else if ((st = hash_scene(s, s->hash, err)) != PT_OK) {
        goto fail;
    }
    interleave_textures(s); /* after the hash, which reads each texture's own block */
    if (opts && opts->camera_name &&
        strncmp(opts->camera_name, PT_CAMERA_LOOK_PREFIX, strlen(PT_CAMERA_LOOK_PREFIX)) == 0 &&
        pt_scene_find_camera(s, opts->camera_name) < 0) {
        if ((st = look_camera(s, opts->camera_name, sc, t, err)) != PT_OK)
            goto fail;
    } else if ((st = choose_camera(s, opts ? opts->camera_name : NULL, err)) != PT_OK) {
        goto fail;
    }
    pt_scene_builder_free(b);
    *out = s;
    return PT_OK;
fail:
    pt_scene_free(s);
    pt_scene_builder_free(b);
    return st;
}

/* ---- textures ------------------------------------------------------------------------ */

/*
 * A texel byte's value, decoded: texel_lut[0] is the unorm byte / 255 as
 * (float)b * (1.0f / 255.0f) computes it, texel_lut[1] the IEC 61966-2-1 sRGB
 * transfer function (decoding direction) computed in double and rounded to
 * float. Both are the bits those formulas give (test_texture recomputes every
 * entry); a table in the binary instead of one built on the first lookup
 * needs no once-guard on every call and no branch per channel.
 */
static const float texel_lut[2][256] = {
    {
        0x0p+0,        0x1.010102p-8, 0x1.010102p-7, 0x1.818184p-7, 0x1.010102p-6, 0x1.414142p-6,
        0x1.818184p-6, 0x1.c1c1c4p-6, 0x1.010102p-5, 0x1.212122p-5, 0x1.414142p-5, 0x1.616162p-5,
        0x1.818184p-5, 0x1.a1a1a4p-5, 0x1.c1c1c4p-5, 0x1.e1e1e4p-5, 0x1.010102p-4, 0x1.111112p-4,
        0x1.212122p-4, 0x1.313132p-4, 0x1.414142p-4, 0x1.515152p-4, 0x1.616162p-4, 0x1.717172p-4,
        0x1.818184p-4, 0x1.919194p-4, 0x1.a1a1a4p-4, 0x1.b1b1b4p-4, 0x1.c1c1c4p-4, 0x1.d1d1d4p-4,
        0x1.e1e1e4p-4, 0x1.f1f1f4p-4, 0x1.010102p-3, 0x1.09090ap-3, 0x1.111112p-3, 0x1.19191ap-3,
        0x1.212122p-3, 0x1.29292ap-3, 0x1.313132p-3, 0x1.39393ap-3, 0x1.414142p-3, 0x1.49494ap-3,
        0x1.515152p-3, 0x1.59595ap-3, 0x1.616162p-3, 0x1.69696ap-3, 0x1.717172p-3, 0x1.79797ap-3,
        0x1.818184p-3, 0x1.89898cp-3, 0x1.919194p-3, 0x1.99999cp-3, 0x1.a1a1a4p-3, 0x1.a9a9acp-3,
        0x1.b1b1b4p-3, 0x1.b9b9bcp-3, 0x1.c1c1c4p-3, 0x1.c9c9ccp-3, 0x1.d1d1d4p-3, 0x1.d9d9dcp-3,
        0x1.e1e1e4p-3, 0x1.e9e9ecp-3, 0x1.f1f1f4p-3, 0x1.f9f9fcp-3, 0x1.010102p-2, 0x1.050506p-2,
        0x1.09090ap-2, 0x1.0d0d0ep-2, 0x1.111112p-2, 0x1.151516p-2, 0x1.19191ap-2, 0x1.1d1d1ep-2,
        0x1.212122p-2, 0x1.252526p-2, 0x1.29292ap-2, 0x1.2d2d2ep-2, 0x1.313132p-2, 0x1.353536p-2,
        0x1.39393ap-2, 0x1.3d3d3ep-2, 0x1.414142p-2, 0x1.454546p-2, 0x1.49494ap-2, 0x1.4d4d4ep-2,
        0x1.515152p-2, 0x1.555556p-2, 0x1.59595ap-2, 0x1.5d5d5ep-2, 0x1.616162p-2, 0x1.656566p-2,
        0x1.69696ap-2, 0x1.6d6d6ep-2, 0x1.717172p-2, 0x1.757576p-2, 0x1.79797ap-2, 0x1.7d7d7ep-2,
        0x1.818184p-2, 0x1.858588p-2, 0x1.89898cp-2, 0x1.8d8d9p-2,  0x1.919194p-2, 0x1.959598p-2,
        0x1.99999cp-2, 0x1.9d9dap-2,  0x1.a1a1a4p-2, 0x1.a5a5a8p-2, 0x1.a9a9acp-2, 0x1.adadbp-2,
        0x1.b1b1b4p-2, 0x1.b5b5b8p-2, 0x1.b9b9bcp-2, 0x1.bdbdcp-2,  0x1.c1c1c4p-2, 0x1.c5c5c8p-2,
        0x1.c9c9ccp-2, 0x1.cdcddp-2,  0x1.d1d1d4p-2, 0x1.d5d5d8p-2, 0x1.d9d9dcp-2, 0x1.ddddep-2,
        0x1.e1e1e4p-2, 0x1.e5e5e8p-2, 0x1.e9e9ecp-2, 0x1.ededfp-2,  0x1.f1f1f4p-2, 0x1.f5f5f8p-2,
        0x1.f9f9fcp-2, 0x1.fdfep-2,   0x1.010102p-1, 0x1.030304p-1, 0x1.050506p-1, 0x1.070708p-1,
        0x1.09090ap-1, 0x1.0b0b0cp-1, 0x1.0d0d0ep-1, 0x1.0f0f1p-1,  0x1.111112p-1, 0x1.131314p-1,
        0x1.151516p-1, 0x1.171718p-1, 0x1.19191ap-1, 0x1.1b1b1cp-1, 0x1.1d1d1ep-1, 0x1.1f1f2p-1,
        0x1.212122p-1, 0x1.232324p-1, 0x1.252526p-1, 0x1.272728p-1, 0x1.29292ap-1, 0x1.2b2b2cp-1,
        0x1.2d2d2ep-1, 0x1.2f2f3p-1,  0x1.313132p-1, 0x1.333334p-1, 0x1.353536p-1, 0x1.373738p-1,
        0x1.39393ap-1, 0x1.3b3b3cp-1, 0x1.3d3d3ep-1, 0x1.3f3f4p-1,  0x1.414142p-1, 0x1.434344p-1,
        0x1.454546p-1, 0x1.474748p-1, 0x1.49494ap-1, 0x1.4b4b4cp-1, 0x1.4d4d4ep-1, 0x1.4f4f5p-1,
        0x1.515152p-1, 0x1.535354p-1, 0x1.555556p-1, 0x1.575758p-1, 0x1.59595ap-1, 0x1.5b5b5cp-1,
        0x1.5d5d5ep-1, 0x1.5f5f6p-1,  0x1.616162p-1, 0x1.636364p-1, 0x1.656566p-1, 0x1.676768p-1,
        0x1.69696ap-1, 0x1.6b6b6cp-1, 0x1.6d6d6ep-1, 0x1.6f6f7p-1,  0x1.717172p-1, 0x1.737374p-1,
        0x1.757576p-1, 0x1.777778p-1, 0x1.79797ap-1, 0x1.7b7b7cp-1, 0x1.7d7d7ep-1, 0x1.7f7f8p-1,
        0x1.818184p-1, 0x1.838386p-1, 0x1.858588p-1, 0x1.87878ap-1, 0x1.89898cp-1, 0x1.8b8b8ep-1,
        0x1.8d8d9p-1,  0x1.8f8f92p-1, 0x1.919194p-1, 0x1.939396p-1, 0x1.959598p-1, 0x1.97979ap-1,
        0x1.99999cp-1, 0x1.9b9b9ep-1, 0x1.9d9dap-1,  0x1.9f9fa2p-1, 0x1.a1a1a4p-1, 0x1.a3a3a6p-1,
        0x1.a5a5a8p-1, 0x1.a7a7aap-1, 0x1.a9a9acp-1, 0x1.ababaep-1, 0x1.adadbp-1,  0x1.afafb2p-1,
        0x1.b1b1b4p-1, 0x1.b3b3b6p-1, 0x1.b5b5b8p-1, 0x1.b7b7bap-1, 0x1.b9b9bcp-1, 0x1.bbbbbep-1,
        0x1.bdbdcp-1,  0x1.bfbfc2p-1, 0x1.c1c1c4p-1, 0x1.c3c3c6p-1, 0x1.c5c5c8p-1, 0x1.c7c7cap-1,
        0x1.c9c9ccp-1, 0x1.cbcbcep-1, 0x1.cdcddp-1,  0x1.cfcfd2p-1, 0x1.d1d1d4p-1, 0x1.d3d3d6p-1,
        0x1.d5d5d8p-1, 0x1.d7d7dap-1, 0x1.d9d9dcp-1, 0x1.dbdbdep-1, 0x1.ddddep-1,  0x1.dfdfe2p-1,
        0x1.e1e1e4p-1, 0x1.e3e3e6p-1, 0x1.e5e5e8p-1, 0x1.e7e7eap-1, 0x1.e9e9ecp-1, 0x1.ebebeep-1,
        0x1.ededfp-1,  0x1.efeff2p-1, 0x1.f1f1f4p-1, 0x1.f3f3f6p-1, 0x1.f5f5f8p-1, 0x1.f7f7fap-1,
        0x1.f9f9fcp-1, 0x1.fbfbfep-1, 0x1.fdfep-1,   0x1p+0,
    },
    {
        0x0p+0,         0x1.3e4568p-12, 0x1.3e4568p-11, 0x1.dd681cp-11, 0x1.3e4568p-10,
        0x1.8dd6c2p-10, 0x1.dd681cp-10, 0x1.167cbap-9,  0x1.3e4568p-9,  0x1.660e14p-9,
        0x1.8dd6c2p-9,  0x1.b6a31cp-9,  0x1.e1e31ep-9,  0x1.07c38cp-8,  0x1.1fcc2cp-8,
        0x1.390ffap-8,  0x1.53936cp-8,  0x1.6f5adep-8,  0x1.8c6a94p-8,  0x1.aac6cp-8,
        0x1.ca7382p-8,  0x1.eb74e2p-8,  0x1.06e76cp-7,  0x1.18c2a6p-7,  0x1.2b4e0ap-7,
        0x1.3e8b7cp-7,  0x1.527cd6p-7,  0x1.6723eep-7,  0x1.7c8292p-7,  0x1.929a88p-7,
        0x1.a96d92p-7,  0x1.c0fd68p-7,  0x1.d94bbep-7,  0x1.f25a44p-7,  0x1.061552p-6,
        0x1.135f3ep-6,  0x1.210bb8p-6,  0x1.2f1b8cp-6,  0x1.3d8f84p-6,  0x1.4c6866p-6,
        0x1.5ba6fap-6,  0x1.6b4c04p-6,  0x1.7b5842p-6,  0x1.8bcc74p-6,  0x1.9ca958p-6,
        0x1.adefaap-6,  0x1.bfa02p-6,   0x1.d1bb74p-6,  0x1.e4425ap-6,  0x1.f73586p-6,
        0x1.054ad4p-5,  0x1.0f31bap-5,  0x1.194fccp-5,  0x1.23a55ep-5,  0x1.2e32c8p-5,
        0x1.38f86p-5,   0x1.43f678p-5,  0x1.4f2d64p-5,  0x1.5a9d76p-5,  0x1.664702p-5,
        0x1.722a56p-5,  0x1.7e47c8p-5,  0x1.8a9fa4p-5,  0x1.97323ap-5,  0x1.a3ffd8p-5,
        0x1.b108dp-5,   0x1.be4d6cp-5,  0x1.cbcdfap-5,  0x1.d98ac6p-5,  0x1.e7841cp-5,
        0x1.f5ba48p-5,  0x1.0216cap-4,  0x1.096f26p-4,  0x1.10e65cp-4,  0x1.187c9p-4,
        0x1.2031e8p-4,  0x1.280688p-4,  0x1.2ffa92p-4,  0x1.380e2ap-4,  0x1.404174p-4,
        0x1.489494p-4,  0x1.5107acp-4,  0x1.599adep-4,  0x1.624e4ep-4,  0x1.6b221ep-4,
        0x1.74167p-4,   0x1.7d2b66p-4,  0x1.86612p-4,   0x1.8fb7cp-4,   0x1.992f68p-4,
        0x1.a2c83ap-4,  0x1.ac8256p-4,  0x1.b65ddcp-4,  0x1.c05aecp-4,  0x1.ca79a8p-4,
        0x1.d4ba3p-4,   0x1.df1ca2p-4,  0x1.e9a12p-4,   0x1.f447cap-4,  0x1.ff10bcp-4,
        0x1.04fe0cp-3,  0x1.0a84fep-3,  0x1.101d44p-3,  0x1.15c6eep-3,  0x1.1b8208p-3,
        0x1.214ea6p-3,  0x1.272cd4p-3,  0x1.2d1ca2p-3,  0x1.331e1ep-3,  0x1.393158p-3,
        0x1.3f566p-3,   0x1.458d42p-3,  0x1.4bd60ep-3,  0x1.5230d4p-3,  0x1.589dap-3,
        0x1.5f1c84p-3,  0x1.65ad8ap-3,  0x1.6c50c4p-3,  0x1.73063ep-3,  0x1.79ce06p-3,
        0x1.80a82ep-3,  0x1.8794cp-3,   0x1.8e93ccp-3,  0x1.95a55ep-3,  0x1.9cc986p-3,
        0x1.a40052p-3,  0x1.ab49cep-3,  0x1.b2a60ap-3,  0x1.ba1512p-3,  0x1.c196f4p-3,
        0x1.c92bbep-3,  0x1.d0d37cp-3,  0x1.d88e3ep-3,  0x1.e05c0ep-3,  0x1.e83cfcp-3,
        0x1.f03116p-3,  0x1.f83866p-3,  0x1.00297ep-2,  0x1.044072p-2,  0x1.086116p-2,
        0x1.0c8b7p-2,   0x1.10bf86p-2,  0x1.14fd6p-2,   0x1.194502p-2,  0x1.1d9676p-2,
        0x1.21f1bep-2,  0x1.2656e4p-2,  0x1.2ac5ecp-2,  0x1.2f3edep-2,  0x1.33c1cp-2,
        0x1.384e98p-2,  0x1.3ce56cp-2,  0x1.418642p-2,  0x1.46312p-2,   0x1.4ae60ep-2,
        0x1.4fa51p-2,   0x1.546e2cp-2,  0x1.59416cp-2,  0x1.5e1edp-2,   0x1.630664p-2,
        0x1.67f82ap-2,  0x1.6cf428p-2,  0x1.71fa68p-2,  0x1.770aecp-2,  0x1.7c25bcp-2,
        0x1.814adcp-2,  0x1.867a54p-2,  0x1.8bb428p-2,  0x1.90f86p-2,   0x1.9647p-2,
        0x1.9ba01p-2,   0x1.a10394p-2,  0x1.a67192p-2,  0x1.abea1p-2,   0x1.b16d14p-2,
        0x1.b6faa4p-2,  0x1.bc92c6p-2,  0x1.c2357ep-2,  0x1.c7e2d2p-2,  0x1.cd9acap-2,
        0x1.d35d6ap-2,  0x1.d92ab6p-2,  0x1.df02b8p-2,  0x1.e4e57p-2,   0x1.ead2e8p-2,
        0x1.f0cb26p-2,  0x1.f6ce2cp-2,  0x1.fcdcp-2,    0x1.017a56p-1,  0x1.048c18p-1,
        0x1.07a34ap-1,  0x1.0abfeep-1,  0x1.0de208p-1,  0x1.11099ap-1,  0x1.1436a8p-1,
        0x1.176932p-1,  0x1.1aa13ep-1,  0x1.1ddecap-1,  0x1.2121dep-1,  0x1.246a7ap-1,
        0x1.27b8ap-1,   0x1.2b0c54p-1,  0x1.2e6598p-1,  0x1.31c46ep-1,  0x1.3528dcp-1,
        0x1.3892ep-1,   0x1.3c028p-1,   0x1.3f77bcp-1,  0x1.42f29ap-1,  0x1.467318p-1,
        0x1.49f93ep-1,  0x1.4d850ap-1,  0x1.511682p-1,  0x1.54ada4p-1,  0x1.584a78p-1,
        0x1.5becfep-1,  0x1.5f9538p-1,  0x1.634328p-1,  0x1.66f6d4p-1,  0x1.6ab03ap-1,
        0x1.6e6f6p-1,   0x1.723448p-1,  0x1.75fef4p-1,  0x1.79cf64p-1,  0x1.7da59ep-1,
        0x1.8181a4p-1,  0x1.856378p-1,  0x1.894b1cp-1,  0x1.8d3892p-1,  0x1.912bdep-1,
        0x1.9525p-1,    0x1.9923fep-1,  0x1.9d28d8p-1,  0x1.a13392p-1,  0x1.a5442cp-1,
        0x1.a95aacp-1,  0x1.ad771p-1,   0x1.b1995ep-1,  0x1.b5c198p-1,  0x1.b9efbep-1,
        0x1.be23d4p-1,  0x1.c25ddep-1,  0x1.c69ddcp-1,  0x1.cae3d2p-1,  0x1.cf2fcp-1,
        0x1.d381aap-1,  0x1.d7d994p-1,  0x1.dc377ep-1,  0x1.e09b6ap-1,  0x1.e5055cp-1,
        0x1.e97556p-1,  0x1.edeb5cp-1,  0x1.f2676cp-1,  0x1.f6e98cp-1,  0x1.fb71bcp-1,
        0x1p+0,
    },
};

/* The index of texel i in a row (or column) of n under the wrap mode: for
 * REPEAT i mod n, for MIRROR i mod 2n reflected into [0, n). Coordinates
 * reach here reduced (reduce_coord), so i lies within a period of the range
 * and one add or subtract replaces the integer division; the division stays
 * for any other i, with the same result. */
static inline int wrap_index(int i, int n, int mode)
{
    switch (mode) {
    case PT_WRAP_CLAMP:
        return i < 0 ? 0 : (i >= n ? n - 1 : i);
    case PT_WRAP_MIRROR: {
        int n2 = 2 * n;
        int p = i < 0 ? i + n2 : (i >= n2 ? i - n2 : i);
        if ((unsigned)p >= (unsigned)n2) {
            p = i % n2;
            p = p < 0 ? p + n2 : p;
        }
        return p < n ? p : n2 - 1 - p;
    }
    default: {
        int p = i < 0 ? i + n : (i >= n ? i - n : i);
        if ((unsigned)p >= (unsigned)n) {
            p = i % n;
            p = p < 0 ? p + n : p;
        }
        return p;
    }
    }
}

/* Brings u into a small range before it meets an int, so huge or NaN
 * coordinates cannot overflow the conversion. */
static inline float reduce_coord(float u, int mode)
{
    if (!isfinite(u))
        return 0.0f;
    switch (mode) {
    case PT_WRAP_CLAMP:
        return fminf(fmaxf(u, -1.0f), 2.0f);
    case PT_WRAP_MIRROR:
        return u - 2.0f * floorf(0.5f * u);
    default:
        return u - floorf(u);
    }
}

/* Bytes from a texel to the next (pt_texture.step; 0 means 4). */
static inline size_t texel_step(const pt_texture *tex)
{
    return tex->step ? tex->step : 4;
}

void pt_texture_texel(const pt_texture *tex, uint32_t x, uint32_t y, uint8_t out[4])
{
    memcpy(out, tex->rgba + texel_step(tex) * ((size_t)y * tex->width + x), 4);
}

void pt_texture_sample(const pt_texture *tex, float u, float v, float out[4])
{
    const float *lut = texel_lut[tex->srgb != 0], *unorm = texel_lut[0];
    int w = (int)tex->width, h = (int)tex->height;
    const size_t step = texel_step(tex);
    if (tex->nearest) {
        /* The texel whose square holds (u, v): index floor(u w), wrapped. */
        int xi = wrap_index((int)floorf(reduce_coord(u, tex->wrap_s) * (float)w), w, tex->wrap_s);
        int yi = wrap_index((int)floorf(reduce_coord(v, tex->wrap_t) * (float)h), h, tex->wrap_t);
        const uint8_t *px = tex->rgba + step * ((size_t)yi * (size_t)w + (size_t)xi);
        for (int c = 0; c < 3; c++)
            out[c] = lut[px[c]];
        out[3] = unorm[px[3]];
        return;
    }
    /* Texel centres at (i + 0.5) / w; v = 0 is the top row (glTF UVs). */
    float x = reduce_coord(u, tex->wrap_s) * (float)w - 0.5f;
    float y = reduce_coord(v, tex->wrap_t) * (float)h - 0.5f;
    float fx0 = floorf(x), fy0 = floorf(y);
    float fx = x - fx0, fy = y - fy0;
    int x0 = (int)fx0, y0 = (int)fy0;
    size_t xs[2] = {(size_t)wrap_index(x0, w, tex->wrap_s),
                    (size_t)wrap_index(x0 + 1, w, tex->wrap_s)};
    size_t ys[2] = {(size_t)wrap_index(y0, h, tex->wrap_t) * (size_t)w,
                    (size_t)wrap_index(y0 + 1, h, tex->wrap_t) * (size_t)w};
    const float wt[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
    const uint8_t *px[4] = {tex->rgba + step * (ys[0] + xs[0]), tex->rgba + step * (ys[0] + xs[1]),
                            tex->rgba + step * (ys[1] + xs[0]), tex->rgba + step * (ys[1] + xs[1])};
    /* The sum in the order k = 0..3 from +0: each term is >= +0, so starting
     * from the first term gives the bits that 0 + term gives. */
    for (int c = 0; c < 3; c++) {
        float a = wt[0] * lut[px[0][c]];
        for (int k = 1; k < 4; k++)
            a += wt[k] * lut[px[k][c]];
        out[c] = a;
    }
    /* Alpha as (weight x byte) / 255, in that order. */
    float a = wt[0] * (float)px[0][3] * (1.0f / 255.0f);
    for (int k = 1; k < 4; k++)
        a += wt[k] * (float)px[k][3] * (1.0f / 255.0f);
    out[3] = a;
}

/* The two texel rows (one address each) around (u, v): the fractional
 * part for any wrap mode (exact for REPEAT and for UVs in [0, 1), which is
 * what the prefetch needs to be useful), clamped into the image. Inlined
 * by force: GCC 12's IPA finds a function whose only effect is a prefetch
 * const and deletes the calls to it. */
static inline __attribute__((always_inline)) void texture_prefetch(const pt_texture *tex, float u,
                                                                   float v)
{
    float fu = u - floorf(u), fv = v - floorf(v);
    fu = fu >= 0.0f && fu < 1.0f ? fu : 0.0f; /* NaN and inf give NaN */
    fv = fv >= 0.0f && fv < 1.0f ? fv : 0.0f;
    uint32_t w = tex->width, h = tex->height;
    uint32_t x = (uint32_t)(fu * (float)w), y = (uint32_t)(fv * (float)h);
    x = x < w ? x : w - 1;
    y = y < h ? y : h - 1;
    /* The second row of the bilinear footprint: below the texel's centre
     * the row above, else the row below. */
    uint32_t y2 =
        fv * (float)h - (float)y < 0.5f ? (y > 0 ? y - 1 : h - 1) : (y + 1 < h ? y + 1 : 0);
    size_t step = texel_step(tex);
    const uint8_t *p = tex->rgba + step * ((size_t)y * w + x);
    const uint8_t *p2 = tex->rgba + step * ((size_t)y2 * w + x);
    __builtin_prefetch(p);
    __builtin_prefetch(p2);
    if (step > 4) {
        /* In a shared block a row's two texels span 2 step bytes, often two
         * lines: the column after too (the one before is the other case
         * of the footprint, not asked for). */
        __builtin_prefetch(p + 2 * step - 1);
        __builtin_prefetch(p2 + 2 * step - 1);
    }
}

void pt_texture_prefetch(const pt_texture *tex, float u, float v)
{
    texture_prefetch(tex, u, v);
}

/* The texels of the core slots of tri's material at (b1, b2): once for
 * the textures that share a block (pt_texture) and a transform. */
static inline __attribute__((always_inline)) void prefetch_texels(const pt_scene *s, uint32_t tri,
                                                                  float b1, float b2)
{
    if (!s->uvs || tri >= s->num_triangles)
        return;
    uint32_t mi = s->tri_material[tri];
    if (mi >= s->num_materials)
        return;
    const pt_material *m = &s->materials[mi];
    const uint32_t *i = &s->indices[3 * (size_t)tri];
    if (i[0] >= s->num_vertices || i[1] >= s->num_vertices || i[2] >= s->num_vertices)
        return;
    float b0 = 1.0f - b1 - b2;
    float uv[2][2] = {{0.0f, 0.0f}, {0.0f, 0.0f}};
    for (int set = 0; set < 2; set++) {
        const float *t = set ? s->uvs1 : s->uvs;
        if (!t)
            continue;
        uv[set][0] = b0 * t[2 * i[0]] + b1 * t[2 * i[1]] + b2 * t[2 * i[2]];
        uv[set][1] = b0 * t[2 * i[0] + 1] + b1 * t[2 * i[1] + 1] + b2 * t[2 * i[2] + 1];
    }
    const uint8_t *done = NULL; /* the shared block asked for, at done_xf */
    const pt_tex_xform *done_xf = NULL;
    for (size_t k = 0; k < NUM_CORE_SLOTS; k++) {
        int32_t ti = slot_texture(m, k);
        if (ti < 0 || (uint32_t)ti >= s->num_textures)
            continue;
        const pt_texture *tex = &s->textures[ti];
        const pt_tex_xform *x = &m->tex_xf[core_slots[k].slot];
        if (tex->step > 4) {
            const uint8_t *block = tex->rgba - 4 * (size_t)tex->member;
            if (block == done && same_xform(x, done_xf))
                continue;
            done = block;
            done_xf = x;
        }
        float t[2];
        pt_tex_xform_apply(x, uv[x->texcoord ? 1 : 0], t);
        texture_prefetch(tex, t[0], t[1]);
    }
}

void pt_scene_prefetch_hits(const pt_scene *s, uint32_t n, const uint32_t *tri, const float *b1,
                            const float *b2)
{
    for (uint32_t j = 0; j < n; j++) {
        if (tri[j] >= s->num_triangles)
            continue;
        __builtin_prefetch(&s->indices[3 * (size_t)tri[j]]);
        __builtin_prefetch(&s->tri_material[tri[j]]);
    }
    /* Per corner: the line its attribute starts in (an attribute that
     * straddles two lines brings the second on its own use). */
    for (uint32_t j = 0; j < n; j++) {
        if (tri[j] >= s->num_triangles)
            continue;
        const uint32_t *i = &s->indices[3 * (size_t)tri[j]];
        for (int c = 0; c < 3; c++) {
            size_t v = i[c];
            if (v >= s->num_vertices)
                continue;
            if (s->normals)
                __builtin_prefetch(&s->normals[3 * v]);
            if (s->uvs)
                __builtin_prefetch(&s->uvs[2 * v]);
            if (s->uvs1)
                __builtin_prefetch(&s->uvs1[2 * v]);
            if (s->tangents)
                __builtin_prefetch(&s->tangents[4 * v]);
        }
    }
    for (uint32_t j = 0; j < n; j++)
        prefetch_texels(s, tri[j], b1[j], b2[j]);
}

pt_tex_xform pt_tex_xform_identity(void)
{
    pt_tex_xform x;
    memset(&x, 0, sizeof x);
    x.m[0] = x.m[4] = 1.0f;
    return x;
}

pt_tex_xform pt_tex_xform_make(const float offset[2], float rotation, const float scale[2],
                               int32_t texcoord)
{
    /* KHR_texture_transform's README: T * R * S, with R = [cos sin; -sin cos]
     * (rows) so that a positive rotation turns the image counter-clockwise
     * as displayed (v points down): uv' = (cos sx u + sin sy v + ox,
     * -sin sx u + cos sy v + oy), in double and rounded once. The sample
     * asset TextureTransformTest confirms the sense (its arrows point at the
     * green markers; the other sense points at the red one). */
    double c = cos((double)rotation), sn = sin((double)rotation);
    pt_tex_xform x;
    memset(&x, 0, sizeof x);
    x.m[0] = (float)(c * scale[0]);
    x.m[1] = (float)(sn * scale[1]);
    x.m[2] = offset[0];
    x.m[3] = (float)(-sn * scale[0]);
    x.m[4] = (float)(c * scale[1]);
    x.m[5] = offset[1];
    x.texcoord = texcoord;
    x.active = !(x.m[0] == 1.0f && x.m[1] == 0.0f && x.m[2] == 0.0f && x.m[3] == 0.0f &&
                 x.m[4] == 1.0f && x.m[5] == 0.0f);
    return x;
}

void pt_scene_slot_uv(const pt_scene *s, const pt_material *m, int slot, uint32_t tri, float b1,
                      float b2, float out[2])
{
    const pt_tex_xform *x = &m->tex_xf[slot];
    const float *uv = x->texcoord ? s->uvs1 : s->uvs;
    float t[2] = {0.0f, 0.0f};
    if (uv) {
        const uint32_t *i = &s->indices[3 * (size_t)tri];
        float b0 = 1.0f - b1 - b2;
        t[0] = b0 * uv[2 * i[0]] + b1 * uv[2 * i[1]] + b2 * uv[2 * i[2]];
        t[1] = b0 * uv[2 * i[0] + 1] + b1 * uv[2 * i[1] + 1] + b2 * uv[2 * i[2] + 1];
    }
    pt_tex_xform_apply(x, t, out);
}
