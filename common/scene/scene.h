/*
 * scene.h - the renderer's scene: world-space triangles, materials, textures,
 * cameras, and the feature mask that lets the integrator skip what a scene
 * does not need.
 *
 * A pt_scene is immutable after it is built and may be shared by any number of
 * render threads. It owns all of its memory (freed by pt_scene_free).
 * Geometry is flattened: every mesh instance of the glTF default scene is
 * transformed to world space, but for EXT_mesh_gpu_instancing's, kept once
 * in the mesh's own space as a prototype placed by its instances
 * (PT_FEAT_INSTANCES, pt_instance). Per-vertex arrays are shared by all
 * triangles; tri_material[i] is an index into materials[] for triangle i.
 *
 * Coordinate spaces: positions, camera positions and bounds are stored in the
 * "scene space" of world space translated by -origin (world = stored + origin),
 * so a scene far from the world origin (georeferenced data at 1e5 and beyond)
 * keeps float's relative precision: the builder keeps world positions in
 * double and rounds to float only after the shift. origin is 0 for a scene
 * whose centre is within two extents of the world origin, so ordinary scenes
 * are stored in world space unchanged. Rendering is translation invariant, so
 * the accelerator, lights and integrator work in scene space throughout.
 * Directions (normals, camera axes) are the same in both spaces.
 *
 * Scenes come from glTF 2.0 files (pt_scene_load, backed by tinygltf in
 * gltf_import.cpp) or are built by code (pt_scene_builder, used by the
 * importer itself and by tests for procedural scenes).
 * Colours are linear Rec.709. Textures are kept as RGBA8, those a material
 * reads at the same coordinates side by side (pt_texture); sRGB ones are
 * decoded to linear at lookup (pt_texture_sample).
 */
#ifndef PT_COMMON_SCENE_SCENE_H
#define PT_COMMON_SCENE_SCENE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "common/base/error.h"
#include "common/math/vec.h"

/* Feature mask bits: what a scene needs from the integrator. */
enum {
    PT_FEAT_TEXTURES = 1u << 0,     /* some material reads a base-colour or metal-rough texture */
    PT_FEAT_GLOSSY = 1u << 1,       /* some material has a non-zero specular (GGX) lobe */
    PT_FEAT_EMITTERS = 1u << 2,     /* there is at least one emissive triangle */
    PT_FEAT_EMISSIVE_TEX = 1u << 3, /* some emissive material has an emissive texture */
    PT_FEAT_SINGLE_SIDED = 1u << 4, /* some material is not doubleSided */
    PT_FEAT_UVS = 1u << 5,          /* the scene has texture coordinates */
    PT_FEAT_PUNCTUAL = 1u << 6,     /* there is at least one punctual light */
    PT_FEAT_ENV = 1u << 7,          /* an environment light (set by the renderer, not the file) */
    PT_FEAT_ALPHA = 1u << 10,       /* some material's alphaMode is MASK or BLEND */
    PT_FEAT_NORMAL_MAP = 1u << 8,   /* some material has a normal texture (tangents exist) */
    PT_FEAT_VERTEX_COLOR = 1u << 9, /* the scene has COLOR_0 vertex colours */
};
/* Glass: some material transmits (KHR_materials_transmission; it sets
 * PT_FEAT_GLOSSY too), and some transmitting material absorbs inside its
 * closed mesh (KHR_materials_volume, pt_material_absorbs). */
enum { PT_FEAT_TRANSMISSION = 1u << 11, PT_FEAT_VOLUME = 1u << 12 };
/* Layers over the base (common/render/layers.h): some material has a
 * clearcoat > 0 (KHR_materials_clearcoat) or a sheen colour > 0
 * (KHR_materials_sheen). Both set PT_FEAT_GLOSSY too. */
enum { PT_FEAT_CLEARCOAT = 1u << 13, PT_FEAT_SHEEN = 1u << 14 };
/* Motion blur (common/scene/motion.h): something moves while the shutter is
 * open (scene->motion is not NULL). */
enum { PT_FEAT_MOTION = 1u << 15 };
/* KHR_materials_unlit: some material shows its base colour whatever the
 * lighting (pt_material.unlit). */
enum { PT_FEAT_UNLIT = 1u << 16 };
/* KHR_materials_pbrSpecularGlossiness: some material is specular-glossiness
 * (pt_material.spec_gloss); KHR_materials_specular: some material reads a
 * specular or specular colour texture. Both set PT_FEAT_GLOSSY too. */
enum { PT_FEAT_SPEC_GLOSS = 1u << 17, PT_FEAT_SPECULAR_TEX = 1u << 18 };
/* KHR_materials_iridescence: some material has an iridescenceFactor > 0
 * (common/render/thinfilm.h; over glass, dielectric.h). Sets PT_FEAT_GLOSSY
 * too. */
enum { PT_FEAT_IRIDESCENCE = 1u << 19 };
/* KHR_materials_anisotropy: some opaque material has an anisotropyStrength
 * > 0 (common/render/aniso.h); the scene then has tangents. Sets
 * PT_FEAT_GLOSSY too. */
enum { PT_FEAT_ANISOTROPY = 1u << 20 };
/* KHR_materials_diffuse_transmission: some opaque material transmits
 * diffusely (thin-walled: a Lambertian lobe on the far side). Sets
 * PT_FEAT_GLOSSY too. */
enum { PT_FEAT_DIFFUSE_TRANSMISSION = 1u << 21 };
/* KHR_materials_dispersion: some transmitting, not thin-walled material has
 * a dispersion > 0 (common/render/dielectric.h). */
enum { PT_FEAT_DISPERSION = 1u << 22 };
/* EXT_mesh_gpu_instancing kept as instances (pt_scene.instances): a hit
 * may come through an instance, whose transform shading applies. */
enum { PT_FEAT_INSTANCES = 1u << 23 };
/* Thin smooth glass: some thin-walled transmitting material (no
 * KHR_materials_volume thickness) may be smooth, so that its transmission
 * is a delta lobe straight through, which shadow rays cross with its
 * transmittance (common/render/render.c, trace_shadow). Set by the renderer
 * (pt_renderer_new), not the file: a render may turn it off. */
enum { PT_FEAT_THIN_GLASS = 1u << 24 };
/* Manifold next-event estimation: light of the environment reaches rough
 * surfaces through smooth thick glass by chains of refractions solved for
 * (common/render/manifold.h). Set by the renderer (pt_renderer_new), not
 * the file: the scene has such glass, an environment and nothing that
 * moves or is cut out by alpha. */
enum { PT_FEAT_MANIFOLD = 1u << 25 };
/* Environment portals: the scene names openings (a window, a door) through
 * which the environment lights it (pt_scene.portals), and next-event
 * estimation of the environment samples directions through them as well
 * as from the map (common/render/light.c, after Bitterli et al. 2015). */
enum { PT_FEAT_PORTAL = 1u << 26 };

/* pt_material.ext: what the BSDF of a material reads past the core
 * metallic-roughness inputs, set by the builder from the material's fields,
 * so that the renderer tests one word to keep the core path. */
enum {
    PT_MATX_SPEC_GLOSS = 1u << 0,
    PT_MATX_SPECULAR_TEX = 1u << 1,
    PT_MATX_IRIDESCENCE = 1u << 2,
    PT_MATX_ANISOTROPY = 1u << 3,
    PT_MATX_DIFFUSE_TRANSMISSION = 1u << 4,
    PT_MATX_UNLIT = 1u << 5
};

/* glTF alphaMode (common/scene/alpha.h). OPAQUE is 0, so a material
 * initialised with zeros is opaque. */
enum { PT_ALPHA_OPAQUE = 0, PT_ALPHA_MASK = 1, PT_ALPHA_BLEND = 2 };

enum { PT_WRAP_REPEAT = 0, PT_WRAP_CLAMP = 1, PT_WRAP_MIRROR = 2 };

/* Texels are RGBA8, row 0 at the top (v = 0): texel (x, y) is the 4 bytes
 * at rgba + step (y width + x). A texture has its block to itself (step 4,
 * or 0 meaning 4, as decoders and the builder make it), or shares one with
 * the other textures that a material reads at the same texture coordinates
 * (pt_scene_builder_finish), texel by texel: n textures of one size in one
 * block of 4 n bytes a texel, step 4 n, texture `member` at byte 4 member
 * of each. Every lookup of such a material at a point then reads the same
 * few cache lines, where separate textures each cost their own (the misses
 * are what textured scenes wait for: docs/bench/throughput.md, seventh
 * round). The member 0 owns (frees) the block. */
typedef struct pt_texture {
    uint32_t width, height;
    uint8_t *rgba;      /* texel (0, 0); see above */
    int srgb;           /* 1: colour data in sRGB, decoded to linear at lookup */
    int wrap_s, wrap_t; /* PT_WRAP_* */
    int nearest;        /* 1: the sampler's magFilter is NEAREST (see pt_texture_sample) */
    uint32_t step;      /* bytes from a texel to the next: 0 or 4 alone, 4 n in a block of n */
    uint32_t member;    /* its place in a shared block (0: first, or alone) */
} pt_texture;

/* A material's texture slots, each with its KHR_texture_transform and its
 * texture coordinate set (glTF textureInfo.texCoord: 0 or 1). */
enum {
    PT_SLOT_BASE = 0,
    PT_SLOT_METAL_ROUGH,
    PT_SLOT_EMISSIVE,
    PT_SLOT_NORMAL,
    PT_SLOT_TRANSMISSION,
    PT_SLOT_CLEARCOAT,
    PT_SLOT_CLEARCOAT_ROUGH,
    PT_SLOT_SHEEN_COLOR,
    PT_SLOT_SHEEN_ROUGH,
    PT_SLOT_CLEARCOAT_NORMAL,
    PT_SLOT_SPECULAR,
    PT_SLOT_SPECULAR_COLOR,
    PT_SLOT_SPEC_GLOSS,
    PT_SLOT_IRIDESCENCE,
    PT_SLOT_IRID_THICKNESS,
    PT_SLOT_ANISOTROPY,
    PT_SLOT_DIFFUSE_TRANSMISSION,
    PT_SLOT_DIFFUSE_TRANSMISSION_COLOR,
    PT_SLOT_COUNT
};

/* uv' = (m[0] u + m[1] v + m[2], m[3] u + m[4] v + m[5]): the extension's
 * T * R * S (offset, rotation, scale) as the top two rows of its 3x3 matrix.
 * active: 0 for the identity (m is then not read), so that lookups skip it
 * and give the same bits as before the extension, and a zeroed pt_tex_xform
 * is the identity on TEXCOORD_0. */
typedef struct pt_tex_xform {
    float m[6];
    int32_t texcoord; /* 0: TEXCOORD_0, 1: TEXCOORD_1 */
    int32_t active;
} pt_tex_xform;

typedef struct pt_material {
    float base_color[4];    /* linear RGBA factor */
    int32_t base_color_tex; /* texture index or -1 */
    /* PT_MATX_*: what the material reads past the core metallic-roughness
     * inputs, set by the builder from the fields below (any value given is
     * replaced); beside the base colour, so that the renderer's test of it
     * reads the cache line it reads anyway. */
    uint32_t ext;
    float metallic, roughness;
    int32_t metal_rough_tex; /* G = roughness, B = metallic (linear), or -1 */
    float emissive[3];       /* linear radiance: emissiveFactor x KHR_materials_emissive_strength */
    int32_t emissive_tex;    /* sRGB texture or -1 */
    float specular;          /* KHR_materials_specular specularFactor (default 1) */
    float specular_color[3]; /* KHR_materials_specular specularColorFactor (default 1,1,1) */
    /* KHR_materials_transmission, _ior, _volume (all ignored while
     * transmission is 0: the texture only scales the factor). */
    float transmission;         /* transmissionFactor in [0, 1] (default 0) */
    int32_t transmission_tex;   /* R = transmission (linear), or -1 */
    float ior;                  /* index of refraction, >= 1 (default 1.5), or 0: F0 = 1 */
    float thickness;            /* thicknessFactor >= 0: 0 is thin-walled (the default), else the
                                   mesh is a closed volume (glass's, or a diffuse transmitter's);
                                   its value is not otherwise used */
    float attenuation_color[3]; /* in [0, 1] (default 1,1,1) */
    float attenuation_distance; /* > 0; 0 (or +inf in glTF) means no absorption */
    int double_sided;
    int alpha_mode;                     /* PT_ALPHA_* (default OPAQUE) */
    float alpha_cutoff;                 /* MASK: covered where alpha >= this (glTF default 0.5) */
    int32_t normal_tex;                 /* linear tangent-space normal texture or -1 */
    float normal_scale;                 /* normalTexture.scale: scales the map's x and y */
    pt_tex_xform tex_xf[PT_SLOT_COUNT]; /* per slot (PT_SLOT_*) */
    /* KHR_materials_clearcoat and KHR_materials_sheen factors (all 0 by
     * default: no layer) and textures (-1: none; each multiplies its
     * factor, so a texture under a factor of 0 is unused). */
    float clearcoat;             /* clearcoatFactor in [0, 1] */
    float clearcoat_roughness;   /* clearcoatRoughnessFactor in [0, 1] */
    float sheen_color[3];        /* sheenColorFactor, linear, in [0, 1] */
    float sheen_roughness;       /* sheenRoughnessFactor in [0, 1] */
    int32_t clearcoat_tex;       /* R = clearcoat (linear), or -1 */
    int32_t clearcoat_rough_tex; /* G = clearcoat roughness (linear), or -1 */
    int32_t sheen_color_tex;     /* RGB = sheen colour (sRGB), or -1 */
    int32_t sheen_rough_tex;     /* A = sheen roughness (linear), or -1 */
    /* clearcoatNormalTexture: the coat's own tangent-space normal (linear),
     * or -1 (the coat then uses the base's shading normal); it reads the
     * same tangents as normal_tex, so it sets PT_FEAT_NORMAL_MAP too. */
    int32_t clearcoat_normal_tex;
    float clearcoat_normal_scale; /* its scale: scales the map's x and y */
    /* KHR_materials_unlit: 1, every ray that meets the surface sees its base
     * colour (factor x texture x COLOR_0) and the path ends there: it
     * neither scatters nor is a light (the builder zeroes its emission, as
     * the extension ignores it); alpha and doubleSided still apply. */
    int32_t unlit;
    /* KHR_materials_specular textures (-1: none), each times its factor:
     * specular x A of specular_tex (linear), specular_color x RGB of
     * specular_color_tex (sRGB). */
    int32_t specular_tex;
    int32_t specular_color_tex;
    /* KHR_materials_pbrSpecularGlossiness (spec_gloss 1): the diffuse is
     * base_color and base_color_tex (diffuseFactor, diffuseTexture), and
     * the BSDF inputs are those of the extension, c_diff = diffuse x (1 -
     * max(specular)), F0 = specular, alpha = (1 - glossiness)^2; metallic,
     * roughness, specular and their textures are not read. */
    int32_t spec_gloss;
    float sg_specular[3]; /* specularFactor, linear, in [0, 1] (default 1) */
    float sg_glossiness;  /* glossinessFactor in [0, 1] (default 1) */
    int32_t sg_tex;       /* specularGlossinessTexture: RGB specular (sRGB), A glossiness
                             (linear), or -1 */
    /* KHR_materials_iridescence: a thin film over the opaque base, or over
     * glass's interface from outside. iridescence 0: none. */
    float iridescence;          /* iridescenceFactor in [0, 1] (default 0) */
    int32_t iridescence_tex;    /* R x iridescence (linear), or -1 */
    float iridescence_ior;      /* the film's index, >= 1 (default 1.3) */
    float irid_thickness_min;   /* nm, >= 0 (default 100): the thickness texture's 0 */
    float irid_thickness_max;   /* nm, >= 0 (default 400): its 1, and the thickness without it */
    int32_t irid_thickness_tex; /* G picks the thickness (linear), or -1 */
    /* KHR_materials_anisotropy over the opaque base's GGX lobe (a
     * transmitting material ignores it); strength 0: none. */
    float anisotropy;          /* anisotropyStrength in [0, 1] (default 0) */
    float anisotropy_rotation; /* radians, counter-clockwise from the tangent (default 0) */
    int32_t anisotropy_tex;    /* RG direction in [-1, 1] (tangent space), B x strength
                                  (linear), or -1 */
    /* KHR_materials_diffuse_transmission: the share dt of the dielectric's
     * diffuse that is transmitted to the far side, as a thin wall, tinted
     * by the colour (a transmitting material ignores it); 0: none. */
    float diffuse_transmission;             /* diffuseTransmissionFactor in [0, 1] (default 0) */
    int32_t diffuse_transmission_tex;       /* A x the factor (linear), or -1 */
    float diffuse_transmission_color[3];    /* diffuseTransmissionColorFactor (default 1, 1, 1) */
    int32_t diffuse_transmission_color_tex; /* RGB x the colour (sRGB), or -1 */
    /* KHR_materials_dispersion: 20 / V_d (the Abbe number), >= 0 (default
     * 0: none); read by transmitting, not thin-walled materials only. */
    float dispersion;
    char name[64];
} pt_material;

/* A name as the scene keeps it: NUL-terminated, cut to 63 bytes. */
typedef struct pt_scene_name {
    char s[64];
} pt_scene_name;

typedef struct pt_camera {
    pt_vec3 position;
    pt_vec3 right, up, forward; /* world-space orthonormal basis; looks along +forward (glTF -Z) */
    float yfov;                 /* radians; 0 for an orthographic camera */
    int ortho;                  /* 1: orthographic: parallel rays along forward */
    float xmag, ymag;           /* orthographic: half the view's width and height */
    float aspect;               /* width/height from the file, 0 when the image decides */
    float znear;
    int framed;    /* 1: no camera of the file's: the renderer frames the scene's bounds
                      (pt_camera_frame) for the image's aspect, as posed */
    char name[64]; /* the camera's name, else its node's, else "camera N" */
    char node[64]; /* its node's name ("" when unnamed) */
} pt_camera;

/* A punctual light (KHR_lights_punctual): a point, a spot or a directional
 * light, placed by its node (it shines down the node's local -Z).
 *
 * Units: the file's number is used as the radiometric value on the scale of
 * emission, with no photometric factor: a point or spot light of intensity I
 * (colour x intensity) gives irradiance I / d^2 at distance d, facing it, as
 * an emitter of radiance L and area A seen head-on from afar gives L A / d^2;
 * a directional light of intensity E gives irradiance E. The extension names
 * candela and lux, but an emissive factor has no unit in glTF, so converting
 * only the lights (by 683 lm/W, or 4 pi) would light a scene's lamps and its
 * emissive surfaces on different scales. */
enum { PT_PUNCTUAL_POINT = 0, PT_PUNCTUAL_SPOT = 1, PT_PUNCTUAL_DIRECTIONAL = 2 };

typedef struct pt_punctual {
    int type;          /* PT_PUNCTUAL_* */
    pt_vec3 position;  /* scene space (point, spot) */
    pt_vec3 direction; /* unit: where the light travels (the node's -Z) */
    pt_vec3 intensity; /* linear colour x intensity (see above) */
    float range;       /* 0: infinite; else the distance where it reaches zero */
    float cos_inner;   /* spot: cosines of innerConeAngle and outerConeAngle */
    float cos_outer;
    char name[64];
} pt_punctual;

typedef struct pt_motion pt_motion; /* common/scene/motion.h */

/* A mesh kept once for its instances (EXT_mesh_gpu_instancing): its
 * triangles and vertices, contiguous at the end of the scene's arrays
 * (after every flat one), are in the mesh's own space. */
typedef struct pt_prototype {
    uint32_t first_tri, num_tris;
    uint32_t first_vertex, num_vertices;
} pt_prototype;

/* One instance of a prototype: the affine map from the prototype's space
 * to scene space (opts' scale and translation and the origin included). A
 * point p goes to xf[0..2] p.x + xf[3..5] p.y + xf[6..8] p.z + xf[9..11]
 * (column-major 3x4, Embree's RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR); a normal
 * to nm (the inverse transpose of the 3x3, column-major too), then
 * normalised; a tangent to the 3x3, with its handedness w times tan_sign
 * (-1 where the map mirrors), as the builder transforms a copy's. */
typedef struct pt_instance {
    float xf[12];
    float nm[9];
    float tan_sign;
    uint32_t proto;  /* index into pt_scene.prototypes */
    uint32_t object; /* its object, an index into object_names (Cryptomatte) */
} pt_instance;

/* The most instances a scene may have (PT_FEAT_INSTANCES): each costs
 * about 330 bytes, its record and Embree's (OPERATIONS.md). */
#define PT_SCENE_MAX_INSTANCES (4u * 1024u * 1024u)

typedef struct pt_scene {
    uint32_t num_vertices;
    uint32_t num_triangles;
    float *positions;       /* 3 per vertex, scene space (world = stored + origin) */
    float *normals;         /* 3 per vertex, world space (= scene space), unit length */
    float *uvs;             /* 2 per vertex, or NULL when no primitive has TEXCOORD_0 */
    float *uvs1;            /* 2 per vertex (TEXCOORD_1), or NULL when no primitive has it */
    float *tangents;        /* 4 per vertex, or NULL when no material has a normal texture:
                               xyz unit, world space, w = +-1 the handedness (bitangent =
                               w cross(normal, xyz)); given by TANGENT or generated */
    float *colors;          /* 4 per vertex (COLOR_0, linear RGBA), or NULL when no primitive
                               has it; (1,1,1,1) for vertices of a primitive without it */
    uint32_t *indices;      /* 3 per triangle */
    uint32_t *tri_material; /* 1 per triangle */
    uint32_t *tri_object;   /* 1 per triangle: its object, an index into object_names */
    uint32_t num_objects;
    pt_scene_name *object_names; /* the objects' names (a glTF node's name, else
                                    "node N"; a built mesh's `what` unless
                                    pt_scene_builder_set_object), for Cryptomatte */

    uint32_t num_materials;
    pt_material *materials;
    uint32_t num_textures;
    pt_texture *textures;

    uint32_t num_cameras;
    pt_camera *cameras; /* from the file; may be 0 */
    pt_camera camera;   /* the one to render: chosen, or framed from the bounds;
                           positions in scene space */

    uint32_t num_punctual;
    pt_punctual *punctual; /* positions in scene space; may be 0 */

    /* Environment portals (PT_FEAT_PORTAL): triangles that are not
     * geometry (no ray meets them) but openings the environment's light
     * comes through: a mesh node whose extras hold "ptfarm_portal": true.
     * 9 floats a triangle (its corners, scene space); NULL and 0 without.
     * portal_fronts: 3 floats a triangle, the unit normal of its front (its
     * counter-clockwise side, which faces into the room), derived from the
     * corners in double before they are rounded. */
    uint32_t num_portals;
    float *portals;
    float *portal_fronts;

    pt_vec3 bounds_min, bounds_max; /* scene space: they contain every stored position */
    uint32_t features;              /* PT_FEAT_* */
    char hash[65];                  /* SHA-256 (hex) of the scene's files, or of the built data
                                       (origin included) */
    double origin[3];               /* world position of scene space's zero: world = stored +
                                       origin; a multiple of a power of two near the centre
                                       of the bounds, or 0 (see above) */
    pt_motion *motion;              /* what moves within the shutter, or NULL (motion.h) */
    /* Instancing (PT_FEAT_INSTANCES; 0 and NULL without): triangles
     * [0, num_flat_triangles) and vertices [0, num_flat_vertices) are in
     * scene space; the rest are the prototypes', each in its own space,
     * seen only through the instances. Without instances the counts are
     * num_triangles and num_vertices. */
    uint32_t num_flat_triangles, num_flat_vertices;
    uint32_t num_prototypes;
    pt_prototype *prototypes;
    uint32_t num_instances;
    pt_instance *instances;
} pt_scene;

typedef void (*pt_warn_fn)(void *user, const char *message);

typedef struct pt_scene_opts {
    const char *camera_name; /* NULL: the first camera, else frame the bounds; else a
                                camera's name, node name or index (pt_scene_find_camera) */
    float scale;             /* uniform scale applied to world space (0 means 1), in double */
    pt_vec3 translate;       /* added to world space after scaling, in double, before
                                the scene is rebased (so it moves origin, not stored
                                positions, when it is large) */
    pt_warn_fn warn;         /* each unsupported feature reported once; NULL: stderr */
    void *warn_user;
    const char *variant; /* KHR_materials_variants name: mapped primitives use its material;
                            NULL: every primitive its own. Unknown: PT_ERR_ARG listing them */
    /* glTF animation (common/scene/anim.h). animate 0: every node keeps its own
     * transform (and morph weights), as in a still of the file. animate 1: the
     * scene is posed at time seconds of animation: NULL or "" plays the
     * first animation (said once through warn when the file has several),
     * "all" every channel of every animation (a later channel on the same
     * property wins); else an animation's name or its decimal index
     * (unknown: PT_ERR_ARG listing them). A name wins over "all" or an index. */
    int animate;
    double time;
    const char *animation;
    /* Motion blur (common/scene/motion.h): with animate 1 and shutter_close >
     * shutter_open (seconds of animation), the scene is posed at time steps
     * over [shutter_open, shutter_close] and what moves there blurs; its
     * still pose is then the one at shutter_open. Otherwise both are
     * ignored (0, 0 when zeroed: no motion blur). */
    double shutter_open, shutter_close;
    /* A lower cap on the scene's triangles (and 3 vertices each, and an
     * animated load's morph deltas in proportion) than PT_SCENE_MAX_TRIANGLES,
     * for a caller that wants less (the fuzzers, whose every input must load
     * in well under a second); 0: the caps. */
    uint32_t max_triangles;
} pt_scene_opts;

/* Hard caps on what a file may ask for, so that the memory a worker (and the
 * coordinator's scene check) needs for an accepted scene is bounded: see
 * docs/OPERATIONS.md, "Limits", for the bytes each one costs.
 *
 * Triangles are counted once flattened, every instance of a mesh counted
 * (a 100k-triangle mesh under 80 nodes is 8 M), before anything is built:
 * 16 Mi is 16 times the largest test asset (1.04 M, itself 98 instances)
 * and holds the large public test scenes (San Miguel, 10 M). A worker needs
 * about 170 bytes a triangle for indexed meshes and up to 500 for a soup
 * with every attribute, its BVH included (measured: OPERATIONS.md).
 * Texels are those decoded (RGBA8, 4 bytes each), summed over the scene's
 * textures (an image used both as sRGB and linear data counts twice), and
 * are checked from the image's header before anything is decoded: 256 Mi
 * (1 GiB) is 64 textures of 2048^2 or 16 of 4096^2; one image may have at
 * most 64 Mi texels (8192^2, or 16384 x 4096), which also bounds what the
 * decoder holds while it works (up to 20 bytes a texel for a Radiance
 * .hdr, 8 for a PNG). */
#define PT_SCENE_MAX_TRIANGLES (16u * 1024u * 1024u)
/* Vertices are not capped by the triangles alone: unreferenced vertices
 * still cost memory. Three per triangle is the most a sane mesh needs. */
#define PT_SCENE_MAX_VERTICES (3u * PT_SCENE_MAX_TRIANGLES)
#define PT_SCENE_MAX_TEXTURE_DIM 16384u
#define PT_SCENE_MAX_IMAGE_TEXELS (64ull * 1024u * 1024u)
#define PT_SCENE_MAX_TEXELS (256ull * 1024u * 1024u)
#define PT_SCENE_MAX_COORD 1e15f

/* Loads a .gltf or .glb. Returns PT_ERR_IO, PT_ERR_FORMAT (message names the
 * file and the element: "scene.gltf: accessor 3: index 912 out of range"),
 * PT_ERR_LIMIT or PT_ERR_NOMEM. opts may be NULL. On success *out is a new
 * scene; on failure it is untouched and nothing leaks. External buffers and
 * images are read only from below the folder of path: a URI that is absolute
 * or has a ".." component, a symbolic link on the way, or a file that is not
 * regular is PT_ERR_FORMAT, and messages name such a file by its URI only. */
pt_status pt_scene_load(const char *path, const pt_scene_opts *opts, pt_scene **out, pt_error *err);

/* Frees the scene and all it owns. Accepts NULL. */
void pt_scene_free(pt_scene *scene);

/* The four bytes (RGBA8, as decoded) of texel (x, y), x < width and
 * y < height, wherever the texture keeps them. */
void pt_texture_texel(const pt_texture *tex, uint32_t x, uint32_t y, uint8_t out[4]);

/* Lookup with the texture's wrap modes (per axis) and filter: bilinear, or
 * the nearest texel when tex->nearest. Without ray footprints the renderer
 * cannot tell magnification from minification, so the magFilter decides
 * (a pixel-art texture asks for NEAREST there) and minification is left to
 * the pixel's own supersampling. Returns linear RGBA (sRGB decoded). */
void pt_texture_sample(const pt_texture *tex, float u, float v, float out[4]);

/* Starts fetching, without waiting for them, the texels that
 * pt_texture_sample(tex, u, v) reads (a hint that changes no value; the
 * address is clamped into the image and approximate at the wrap edges).
 * Thread-safe. */
void pt_texture_prefetch(const pt_texture *tex, float u, float v);

/* What shading n hits (triangle tri[j] at (b1[j], b2[j])) reads, asked for
 * in three passes over them: each triangle's indices and material; its
 * corners' texture coordinates, normals and tangents; then the texels of
 * its material's core slots (base colour, metal-rough, normal, emissive,
 * transmission, clearcoat's three, sheen's two) at each slot's UV. A pass's
 * addresses come from what the pass before fetched, so each pass's cache
 * misses overlap across the hits instead of following one another within a
 * hit. A hint: it changes no value and reads nothing out of bounds (a bad
 * index is skipped). Thread-safe. */
void pt_scene_prefetch_hits(const pt_scene *s, uint32_t n, const uint32_t *tri, const float *b1,
                            const float *b2);

/* The identity transform on TEXCOORD_0. */
pt_tex_xform pt_tex_xform_identity(void);

/* The transform of KHR_texture_transform: offset, then rotation (radians,
 * counter-clockwise in UV space as the extension defines), then scale. */
pt_tex_xform pt_tex_xform_make(const float offset[2], float rotation, const float scale[2],
                               int32_t texcoord);

/* Applies x to uv (!x->active: uv unchanged, bit for bit). */
static inline void pt_tex_xform_apply(const pt_tex_xform *x, const float uv[2], float out[2])
{
    if (!x->active) {
        out[0] = uv[0];
        out[1] = uv[1];
        return;
    }
    out[0] = x->m[0] * uv[0] + x->m[1] * uv[1] + x->m[2];
    out[1] = x->m[3] * uv[0] + x->m[4] * uv[1] + x->m[5];
}

/* The UV at which material m's texture in `slot` is read on triangle tri at
 * barycentrics (b1, b2): its coordinate set interpolated, then transformed.
 * (0, 0) when the scene lacks that set. */
void pt_scene_slot_uv(const pt_scene *s, const pt_material *m, int slot, uint32_t tri, float b1,
                      float b2, float out[2]);

/* The index in s->cameras of the camera `name` picks: a camera's name,
 * else a camera's node name, else a decimal index; NULL picks the first.
 * -1 when none does. Pure: any thread may call it. */
int pt_scene_find_camera(const pt_scene *s, const char *name);

/* A camera placed by its position and the point it looks at, as text that
 * travels where a camera name does (pt_scene_opts.camera_name, a farm
 * job's camera): "look:FX,FY,FZ:AX,AY,AZ[:fov=DEG|:ortho=WIDTH]", world
 * coordinates; +Y is up (-Z when looking straight up or down); a 40-degree
 * vertical field of view unless fov (0 < DEG < 180) or an orthographic view
 * WIDTH wide (its height from the image) is given. A file's camera of that
 * very name wins. Both sides of the farm read the same text, so the view is
 * the same bits. */
#define PT_CAMERA_LOOK_PREFIX "look:"

/* The text of a placement into out (cap bytes with the NUL; the numbers as
 * %.9g): PT_ERR_ARG when it does not fit, or when pt_camera_look_parse would
 * refuse it (from == at, a field of view outside (0, 180)). fov_deg 0:
 * the default; ortho_width > 0: orthographic. */
pt_status pt_camera_look_text(const double from[3], const double at[3], double fov_deg,
                              double ortho_width, char *out, size_t cap, pt_error *err);

/* pt_camera_look_text with as many significant digits, 9 down to 4, as fit
 * in cap: for a placement computed rather than typed, whose text must fit a
 * job's camera name (a 1e-4 relative shift of a view is a small fraction of
 * a pixel in a 512-pixel image of the scene). */
pt_status pt_camera_look_text_fit(const double from[3], const double at[3], double fov_deg,
                                  double ortho_width, char *out, size_t cap, pt_error *err);

/* text (PT_CAMERA_LOOK_PREFIX...) as a camera in world space into *out
 * (name: the text). PT_ERR_ARG naming what is wrong. */
pt_status pt_camera_look_parse(const char *text, pt_camera *out, pt_error *err);

/* The command-line options that place a camera, as every program takes
 * them: --camera-from X,Y,Z, --camera-at X,Y,Z, --fov DEG, --ortho WIDTH.
 * Zero it, hand it each option with pt_camera_look_option, then
 * pt_camera_look_finish. */
typedef struct pt_camera_look_opts {
    int has_from, has_at;
    double from[3], at[3];
    double fov, ortho; /* 0: not given */
} pt_camera_look_opts;

/* opt ("--camera-from", "--camera-at", "--fov", "--ortho") with its text
 * into l. PT_ERR_ARG naming the option when the value is bad. */
pt_status pt_camera_look_option(pt_camera_look_opts *l, const char *opt, const char *text,
                                pt_error *err);

/* *given = 0 when no option of l was given (out untouched); else the
 * placement's text (pt_camera_look_text) into out. PT_ERR_ARG when only
 * one of --camera-from and --camera-at is given, when --fov or --ortho
 * comes without them or with each other, or with camera_name (--camera)
 * not NULL. */
pt_status pt_camera_look_finish(const pt_camera_look_opts *l, const char *camera_name, char *out,
                                size_t cap, int *given, pt_error *err);

/* Prints what path holds that a render's options choose among, for
 * ptworker --list: its size; its cameras in --camera's numbering (name,
 * node, projection); its punctual lights; whether it has emissive
 * triangles; its animations (channels, time range), KHR_materials_variants
 * variants and the extensions it uses and requires. Loads it as a still
 * first, with every check of pt_scene_load (its errors). more (or NULL)
 * is called with the loaded still and ctx right after its portals are
 * listed, for what layers above the scene print of it (a portal wound the
 * wrong way). */
typedef void pt_scene_list_more(const pt_scene *scene, FILE *out, void *ctx);
pt_status pt_scene_list(const char *path, FILE *out, pt_scene_list_more *more, void *ctx,
                        pt_error *err);

/* A default view of the box [lo, hi] for an image of `aspect` (width/height;
 * 0: square) into *out: a 40-degree camera looking down -Z from a little
 * above, at the distance where the 8 corners' projections fit the image
 * with 5 % to spare, so the box fills the frame along one axis. Degenerate
 * bounds (empty, infinite) get a unit sphere's view. framed is set. */
void pt_camera_frame(pt_vec3 lo, pt_vec3 hi, float aspect, pt_camera *out);

/* The 3x3 cofactor matrix of the column-major 4x4 m's upper-left block (m
 * NULL: the identity), as rows c[r][k] so that a normal goes to c * n, and
 * the block's determinant. cof(A) = det(A) inv(A)^T: normals stay
 * perpendicular to transformed surfaces without an inverse. */
double pt_normal_matrix(const double *m, double c[3][3]);

/* Sets scene->camera to pt_camera_frame of its bounds for `aspect`. The
 * renderer frames such a camera again for its image's aspect from the
 * bounds as they are then (posed at the requested time). */
void pt_scene_frame_camera(pt_scene *scene, float aspect);

/* The image height for an image `width` pixels wide seen through a camera of
 * `aspect` (pt_camera.aspect, width/height): width / aspect rounded to
 * nearest, in float as every program has computed it, so that a default size
 * is the same everywhere. An aspect of 0 (the image decides), negative or NaN
 * gives a square image. The result is clamped to [1, max_height], so
 * a near-zero aspect cannot overflow. Pure: any thread may call it. */
uint32_t pt_camera_height(float aspect, uint32_t width, uint32_t max_height);

/* Whether m absorbs inside its volume (Beer-Lambert): it transmits (glass,
 * or KHR_materials_diffuse_transmission: the transmitted light enters the
 * volume), is not thin-walled, and has a finite attenuation distance with a
 * colour below 1. */
static inline int pt_material_absorbs(const pt_material *m)
{
    return (m->transmission > 0.0f || m->diffuse_transmission > 0.0f) && m->thickness > 0.0f &&
           m->attenuation_distance > 0.0f && m->attenuation_distance < 3.4e38f &&
           (m->attenuation_color[0] < 1.0f || m->attenuation_color[1] < 1.0f ||
            m->attenuation_color[2] < 1.0f);
}

/* A default material: white base colour, metallic 1, roughness 1 (glTF defaults),
 * specular 1, single-sided, OPAQUE with alpha cutoff 0.5. */
pt_material pt_material_default(void);

/* ---- building scenes by code ---------------------------------------------------------- */

typedef struct pt_scene_builder pt_scene_builder;

pt_status pt_scene_builder_new(pt_scene_builder **out, pt_error *err);
void pt_scene_builder_free(pt_scene_builder *b); /* accepts NULL */

/* Adds a material (copied); its index goes to *index. Rejects (PT_ERR_FORMAT,
 * naming the material and the field) NaN/Inf factors, negative emission,
 * base colour, metallic, roughness or specular factors outside [0, 1] (glTF's
 * range: rejected, not clamped), a negative specular colour, an unknown
 * alpha mode and a negative or non-finite alpha cutoff. */
pt_status pt_scene_builder_add_material(pt_scene_builder *b, const pt_material *m, uint32_t *index,
                                        pt_error *err);
/* Adds a texture; the builder takes ownership of tex->rgba (pt_malloc'd)
 * even on failure. */
pt_status pt_scene_builder_add_texture(pt_scene_builder *b, const pt_texture *tex, uint32_t *index,
                                       pt_error *err);
/* Vertex attributes beyond position, normal and TEXCOORD_0; any may be NULL.
 * uvs1: 2 per vertex (TEXCOORD_1). tangents: 4 per vertex in the mesh's
 * space (glTF TANGENT: xyz, w = +-1), transformed with the mesh (a
 * mirroring transform flips w). Without tangents, when the mesh's material
 * needs them (a normal map, a coat normal map, anisotropy), they are
 * generated (tangent.h) in the mesh's own space from its positions, its
 * normals and the map's UV set, then transformed as given ones are, so a
 * node's matrix, non-uniform scale included, maps them as viewers do and an
 * instance's prototype gets the same; a given tangent of zero length is
 * generated at finish, in world space. colors: 4 per vertex
 * (COLOR_0, linear RGBA; a VEC3 is given with alpha 1). */
typedef struct pt_mesh_extra {
    const float *uvs1;
    const float *tangents;
    const float *colors;
} pt_mesh_extra;

/* The tangents pt_scene_builder_add_mesh_extra generates for a mesh without
 * them, in the mesh's own space (4 per vertex into tan; *made 1), when
 * material needs them; else *made 0 and tan untouched. The arguments are
 * add_mesh_extra's (uvs1: extra's TEXCOORD_1). For a rig that poses the
 * mesh and must map the load's tangents. PT_ERR_NOMEM. */
pt_status pt_scene_builder_mesh_tangents(const pt_scene_builder *b, uint32_t material,
                                         const float *positions, const float *normals,
                                         const float *uvs, const float *uvs1, uint32_t nv,
                                         const uint32_t *indices, uint32_t nt, float *tan,
                                         int *made, pt_error *err);

/* Adds a triangle mesh. positions: 3*nv floats; normals: 3*nv or NULL (then
 * computed, area-weighted); uvs: 2*nv or NULL; indices: 3*nt, or NULL for
 * non-indexed (nv must then be 3*nt). xform: column-major 4x4 world matrix or
 * NULL for identity. Checks indices against nv, coordinates for NaN/Inf and
 * |x| <= PT_SCENE_MAX_COORD; `what` names the mesh in error messages. */
pt_status pt_scene_builder_add_mesh(pt_scene_builder *b, const char *what, const float *positions,
                                    const float *normals, const float *uvs, uint32_t nv,
                                    const uint32_t *indices, uint32_t nt, const float xform[16],
                                    uint32_t material, pt_error *err);
/* The same with a double-precision world matrix, so that a large translation
 * (a georeferenced node at 1e5 or more) is not rounded to float before the
 * scene is rebased. */
pt_status pt_scene_builder_add_mesh_dxform(pt_scene_builder *b, const char *what,
                                           const float *positions, const float *normals,
                                           const float *uvs, uint32_t nv, const uint32_t *indices,
                                           uint32_t nt, const double xform[16], uint32_t material,
                                           pt_error *err);
/* The same with the attributes of `extra` (may be NULL). Rejects non-finite
 * values in them (PT_ERR_FORMAT) and a tangent w that is not +-1. */
pt_status pt_scene_builder_add_mesh_extra(pt_scene_builder *b, const char *what,
                                          const float *positions, const float *normals,
                                          const float *uvs, const pt_mesh_extra *extra, uint32_t nv,
                                          const uint32_t *indices, uint32_t nt,
                                          const double xform[16], uint32_t material, pt_error *err);
/* Adds a mesh that moves while the shutter is open: as
 * pt_scene_builder_add_mesh without a transform, posed at `steps` times
 * evenly spaced over the shutter (common/scene/motion.h): positions[k] (3*nv
 * floats, world space) and normals[k] (or normals NULL: computed per step)
 * for k < steps; step 0 is also the mesh's still pose. steps must be in
 * [2, PT_MOTION_MAX_STEPS] and the same for every moving mesh of the scene
 * (PT_ERR_ARG). A mesh whose steps are all equal does not move (no
 * PT_FEAT_MOTION). */
pt_status pt_scene_builder_add_mesh_motion(pt_scene_builder *b, const char *what, uint32_t steps,
                                           const float *const *positions,
                                           const float *const *normals, const float *uvs,
                                           uint32_t nv, const uint32_t *indices, uint32_t nt,
                                           uint32_t material, pt_error *err);
/* Instancing: the meshes added between begin and end make prototype
 * *proto, kept in their own space (their xform is the mesh's place within
 * the prototype, normally NULL); pt_scene_builder_add_instance then places
 * it. Every flat mesh must come before the first prototype (PT_ERR_ARG
 * otherwise), and a scene with prototypes cannot have moving meshes or
 * emissive prototype triangles (PT_ERR_ARG): lights and motion need every
 * copy in scene space. */
pt_status pt_scene_builder_begin_prototype(pt_scene_builder *b, uint32_t *proto, pt_error *err);
pt_status pt_scene_builder_end_prototype(pt_scene_builder *b, pt_error *err);
/* Places prototype `proto` by the column-major 4x4 world matrix xform
 * (before opts' scale and translation, as a mesh's). PT_ERR_FORMAT for a
 * non-finite matrix or one whose last row is not (0, 0, 0, 1), PT_ERR_LIMIT
 * past PT_SCENE_MAX_INSTANCES. A singular matrix (a scale of 0, which
 * hides an instance) places nothing. The instance belongs to the object of
 * the last pt_scene_builder_set_object (else to its prototype's first
 * triangle's), whatever object the prototype's triangles have: each node
 * that instances a shared mesh keeps its own Cryptomatte name. */
pt_status pt_scene_builder_add_instance(pt_scene_builder *b, uint32_t proto, const double xform[16],
                                        pt_error *err);
/* Adds a camera (copied) in world space. Rejects (PT_ERR_FORMAT) non-finite
 * vectors, a position over PT_SCENE_MAX_COORD, yfov outside (0, pi), aspect
 * outside [0, 1e6), a negative or non-finite znear. */
pt_status pt_scene_builder_add_camera(pt_scene_builder *b, const pt_camera *cam, pt_error *err);
/* The object the meshes added next belong to (its name, cut to 63 bytes;
 * one object per distinct name). Until it is called a mesh is an object
 * named by its `what`. PT_ERR_NOMEM. */
pt_status pt_scene_builder_set_object(pt_scene_builder *b, const char *name, pt_error *err);
/* The same with the world-space position in double (cam->position ignored). */
pt_status pt_scene_builder_add_camera_at(pt_scene_builder *b, const pt_camera *cam,
                                         const double position[3], pt_error *err);
/* Adds a punctual light (copied) with its world-space position in double
 * (p->position ignored). Rejects (PT_ERR_FORMAT, naming the light) a
 * non-finite or too large position, a direction that is not unit length, a
 * negative or non-finite intensity or range, and spot cones outside
 * 0 <= inner < outer <= pi/2 (given as cosines). */
pt_status pt_scene_builder_add_punctual(pt_scene_builder *b, const pt_punctual *p,
                                        const double position[3], pt_error *err);
/* The most portal triangles a scene may have: each light sample of the
 * environment measures every one's solid angle. */
#define PT_SCENE_MAX_PORTALS 64u
/* Adds a portal triangle (PT_FEAT_PORTAL) by its world-space corners in
 * double (v[0..2], v[3..5], v[6..8]); `what` names it in errors. A
 * triangle without area is dropped (it lets no light through). Rejects
 * (PT_ERR_FORMAT) a corner that is not finite or over PT_SCENE_MAX_COORD,
 * and past PT_SCENE_MAX_PORTALS (PT_ERR_LIMIT). */
pt_status pt_scene_builder_add_portal(pt_scene_builder *b, const double v[9], const char *what,
                                      pt_error *err);
/* Finishes: applies opts' scale/translate (in double), computes the bounds,
 * rebases the scene (origin, above) and rounds positions to float (a
 * point or spot light's intensity is scaled by scale^2 and its range by
 * scale, so the irradiance it gives a scaled scene is unchanged), then
 * features, hash, and chooses the camera. Fails with PT_ERR_FORMAT on zero
 * triangles, PT_ERR_ARG when a scaled coordinate is not finite in float. The
 * builder is consumed (freed) whether or not it succeeds. While building,
 * positions take 24 bytes a vertex (double); the float copy is made here. */
pt_status pt_scene_builder_finish(pt_scene_builder *b, const pt_scene_opts *opts, pt_scene **out,
                                  pt_error *err);

#endif
