/*
 * guide.h - path guiding's learned distribution of incident light: a
 * spatial binary tree over the scene's bounds whose leaves each hold a
 * directional quadtree (Mueller, Gross & Novak 2017, "Practical Path
 * Guiding for Efficient Light-Transport Simulation", the SD-tree), and the
 * statistics a pass of rendering collects to build the next one.
 *
 * A spatial leaf holds PT_GUIDE_FACES quadtrees, one per face of the cube
 * that a surface's normal points to (+x, -x, +y, -y, +z, -z): the light a
 * floor receives and the light a wall beside it receives are learned apart,
 * so a floor's distribution stays above the floor. A cell is a leaf and a
 * face (pt_guide_cell); sampling, pdfs and records name cells.
 *
 * Directions map to the unit square by the cylindrical equal-area map
 * (u, v) = ((z + 1) / 2, atan2(y, x) / (2 pi) wrapped to [0, 1)), so a
 * density over the square is the solid-angle density times 4 pi. A quadtree
 * node covers a square of side 2^-depth; a leaf's share of its tree is
 * spread uniformly over its square. Sampling descends from the root, each
 * step picking a child in proportion to its energy, one number rescaled at
 * every level; the pdf of a direction is the product, level by level, of
 * the probability of the child it lies in (its energy over its siblings'
 * sum: the sampler's column choice times its row choice) divided by the
 * leaf's area, so it is the sampler's density whatever the stored
 * energies are (a node's own energy is not assumed to be its children's sum).
 *
 * Learning runs in passes. A pass renders with a distribution G and records
 * into statistics made for G: each record is a spatial leaf, a direction and
 * an estimate of incident radiance over its pdf (Mueller's L / p), summed in
 * fixed point (PT_GUIDE_FIXED_BITS fractional bits, each record clamped to
 * PT_GUIDE_MAX_RECORD) into the quadtree leaf it falls in, with a count per
 * spatial leaf (render.c's caustic photons record too, in those units).
 * Integer sums merge exactly in any order, so the statistics
 * of a pass - and the distribution pt_guide_build makes from them - do not
 * depend on how the pass was split into threads, tasks or workers. Building
 * splits a spatial leaf at its midpoints while a part's share of its records
 * (half at each level) exceeds the split threshold, the parts inheriting its
 * directions, and rebuilds each quadtree from its energies: a
 * node is subdivided while its share of the tree is above
 * PT_GUIDE_SUBDIV_SHARE (down to PT_GUIDE_MAX_DEPTH), a leaf new to the tree
 * takes a quarter of its parent's energy. A tree with no energy is uniform.
 *
 * A pt_guide is immutable once built: any number of render threads may
 * sample it. Statistics belong to one thread at a time; merge them after.
 */
#ifndef PT_COMMON_RENDER_GUIDE_H
#define PT_COMMON_RENDER_GUIDE_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"

#define PT_GUIDE_FACES 6u              /* quadtrees a spatial leaf holds, by normal */
#define PT_GUIDE_INIT_DEPTH 4u         /* a new guide's trees: complete to this depth */
#define PT_GUIDE_FIXED_BITS 16         /* fractional bits of a record's fixed point */
#define PT_GUIDE_MAX_RECORD 1.0e9      /* a record above this is clamped to it */
#define PT_GUIDE_SUBDIV_SHARE 0.01     /* a quadtree node above this share is split */
#define PT_GUIDE_MAX_DEPTH 16u         /* quadtree levels at most */
#define PT_GUIDE_MAX_SPATIAL_DEPTH 48u /* spatial tree levels at most */
#define PT_GUIDE_MAX_NODES (1u << 24)  /* spatial or directional nodes at most */
#define PT_GUIDE_MAX_SPLIT_LEVELS 12u  /* levels one build adds under a leaf at most */

/* A spatial node: a leaf when child is 0, else its children are child and
 * child + 1, split at the midpoint of axis (a leaf's: the axis its next
 * split takes). */
typedef struct pt_guide_snode {
    uint32_t child;
    uint32_t axis; /* 0, 1, 2 */
    uint32_t tree; /* a leaf's quadtrees: their PT_GUIDE_FACES roots from this index on */
} pt_guide_snode;

/* A directional node: a leaf when child is 0, else its children are child
 * .. child + 3 (quadrants (0,0), (1,0), (0,1), (1,1) of its square). A
 * root's energy is 1 when its tree was learned, 0 when not. */
typedef struct pt_guide_qnode {
    uint32_t child;
    float energy; /* >= 0, finite */
} pt_guide_qnode;

typedef struct pt_guide {
    pt_vec3 lo, hi; /* the spatial tree's bounds; points outside are clamped */
    uint32_t nsnode, nqnode;
    pt_guide_snode *snode; /* [0] the root */
    pt_guide_qnode *qnode;
} pt_guide;

typedef struct pt_guide_stats {
    uint32_t nsnode, nqnode; /* the guide's they were made for */
    uint64_t *count;         /* per spatial node (leaves): records */
    uint64_t *sum;           /* per directional node (leaves): fixed-point L / p */
} pt_guide_stats;

/* A guide of one spatial leaf over [lo, hi] whose quadtrees are uniform and
 * complete to PT_GUIDE_INIT_DEPTH, so that a first pass records directions
 * at that resolution; none is learned yet. */
pt_status pt_guide_new_uniform(pt_vec3 lo, pt_vec3 hi, pt_guide **out, pt_error *err);
void pt_guide_free(pt_guide *g); /* accepts NULL */

/* The spatial leaf holding p (clamped into the bounds). */
uint32_t pt_guide_leaf(const pt_guide *g, pt_vec3 p);
/* The same leaf, with its depth in the tree and its extent (for tools that
 * read what a guide learned). */
uint32_t pt_guide_leaf_box(const pt_guide *g, pt_vec3 p, uint32_t *depth, pt_vec3 *extent);
/* The cell of a surface point p with normal n: its leaf and n's face. */
uint32_t pt_guide_cell(const pt_guide *g, pt_vec3 p, pt_vec3 n);

/* 1 when cell's quadtree was learned from records (its root's energy is 1);
 * 0: it is the uniform tree it started as (root energy 0), and sampling it
 * would waste directions. Sampling reads only children's energies. */
int pt_guide_learned(const pt_guide *g, uint32_t cell);
/* Starts fetching cell's quadtree root, which pt_guide_learned and the
 * lookups read first: a caller with other work to do before them hides
 * the fetch behind it. */
void pt_guide_prefetch(const pt_guide *g, uint32_t cell);

/* A direction from cell's quadtree for u (2 numbers in [0,1)), and its
 * solid-angle pdf (> 0). */
pt_vec3 pt_guide_sample(const pt_guide *g, uint32_t cell, const float u[2], float *pdf);
/* The solid-angle pdf pt_guide_sample gives dir (unit) at cell. */
float pt_guide_pdf(const pt_guide *g, uint32_t cell, pt_vec3 dir);
/* The same, and the quadtree leaf dir falls in (*qleaf), which
 * pt_guide_stats_add takes: a record along dir then costs no second
 * lookup. */
float pt_guide_pdf_leaf(const pt_guide *g, uint32_t cell, pt_vec3 dir, uint32_t *qleaf);

/* The quadtree leaf dir (unit) falls in at cell: the one
 * pt_guide_pdf_leaf gives, found without the pdf's divisions. A direction
 * just sampled from cell finds it in the lines its sampling fetched; its
 * record (pt_guide_stats_add) then walks no tree at the path's end. Its
 * depth in the tree into *depth unless depth is NULL (for tools that read
 * what a guide learned). */
uint32_t pt_guide_qleaf(const pt_guide *g, uint32_t cell, pt_vec3 dir, uint32_t *depth);

/* Direction <-> the unit square (the equal-area map above). */
void pt_guide_dir_to_square(pt_vec3 dir, float *u, float *v);
pt_vec3 pt_guide_square_to_dir(float u, float v);

/* Empty statistics for g. */
pt_status pt_guide_stats_new(const pt_guide *g, pt_guide_stats **out, pt_error *err);
void pt_guide_stats_free(pt_guide_stats *s); /* accepts NULL */
/* Records value (incident radiance over the pdf that chose dir) at cell
 * along dir: counted at the cell's leaf, and added to its direction's cell when
 * above 0 (clamped to PT_GUIDE_MAX_RECORD); a value that is negative or not
 * finite is dropped. */
void pt_guide_stats_record(pt_guide_stats *s, const pt_guide *g, uint32_t cell, pt_vec3 dir,
                           float value);
/* pt_guide_stats_record for a direction whose quadtree leaf qleaf the
 * guide the statistics were made for gave (pt_guide_pdf_leaf or
 * pt_guide_qleaf at cell): the same sums. */
void pt_guide_stats_add(pt_guide_stats *s, uint32_t cell, uint32_t qleaf, float value);
/* into += from (saturating); PT_ERR_ARG when they were made for different
 * guides' shapes. */
pt_status pt_guide_stats_merge(pt_guide_stats *into, const pt_guide_stats *from, pt_error *err);

/* The next pass's guide from g and the statistics s of a pass rendered with
 * it: a spatial leaf is split until a part holds about split_count records
 * or fewer (at most PT_GUIDE_MAX_SPLIT_LEVELS levels a build). */
pt_status pt_guide_build(const pt_guide *g, const pt_guide_stats *s, uint64_t split_count,
                         pt_guide **out, pt_error *err);

/* The end (exclusive, in samples per pixel) of guided pass k of a render
 * of spp samples: training passes of 16, 32, 64... spp, each learning
 * from the one before (Mueller et al. 2017 double them); a pass after
 * which fewer samples are left than the next pass would take runs to spp,
 * so the last guide renders a full pass rather than a stub. The standalone
 * worker and the farm cut passes here alike. */
uint32_t pt_guide_pass_end(uint32_t k, uint32_t spp);

/* 1 when guided pass k is the last of a render of spp samples: it runs to
 * spp, so nothing is built from its statistics and neither the standalone
 * render nor a farm worker records them. */
int pt_guide_pass_last(uint32_t k, uint32_t spp);

/* --guiding auto: 1 when scene has glass or a diffuse transmitter (its
 * feature mask), whose light path tracing with NEE finds by chance and
 * where guiding pays or came closest (docs/bench/guiding.md: 1.46x the
 * time to equal relMSE on a glass ball; TransmissionTest and ToyCar,
 * whose references are too noisy to rank, 0.59x and 0.70x); 0 otherwise
 * (the NVIDIA Cornell box 0.77x, DamagedHelmet 0.88x, StainedGlassLamp
 * 0.80x), so those scenes keep their unguided variant and pay nothing. A
 * pure function of the scene: ptworker, ptserve and the farm's workers
 * decide alike. */
typedef struct pt_scene pt_scene;
int pt_guide_auto(const pt_scene *scene);

/* 1 when a render asked for guiding mode (PT_GUIDING_*, options.h) of scene
 * is guided: on wherever a material is glossy (the guided integrator variant
 * samples glossy closures only, so an all-Lambert scene is not), auto where
 * pt_guide_auto says, off never. The one rule of every program: ptworker,
 * the coordinator and its upload check decide alike. */
int pt_guide_enabled(uint32_t mode, const pt_scene *scene);

/* PT_OK when g's trees are well formed (children in range, after their
 * parent and referenced once, leaves' trees in range, energies finite and
 * >= 0, depths within the caps); else PT_ERR_FORMAT naming the fault. For a
 * guide that came from elsewhere (a decoder) before it is sampled. */
pt_status pt_guide_check(const pt_guide *g, pt_error *err);

#endif
