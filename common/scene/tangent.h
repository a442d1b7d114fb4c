/*
 * tangent.h - per-vertex tangents for normal maps, generated from the UV
 * parametrisation when a glTF primitive has no TANGENT attribute.
 *
 * glTF 2.0 (3.7.2.1) asks for MikkTSpace tangents (Mikkelsen 2008, "Simulation
 * of Wrinkled Surfaces Revisited") when TANGENT is absent. This follows its
 * arithmetic where a shared-vertex mesh allows it: per triangle the tangent
 * and bitangent are the derivatives of position by u and by v (Lengyel's
 * solution of the 2x2 UV system), each corner projects them into the plane of
 * its vertex normal, normalises and weighs them by the corner's angle, and
 * the handedness w is the sign of the triangle's UV area. Unlike MikkTSpace it
 * does not split a vertex whose triangles disagree on handedness or whose
 * tangents diverge sharply (that would add vertices): such a vertex gets the
 * weighted mean and the majority's sign. Texture space has v pointing down
 * (glTF puts v = 0 at the top of an image), so v is negated, as the glTF
 * exporters do before calling MikkTSpace: the bitangent points to the image's
 * top, where a normal map's green channel points.
 *
 * Pure functions over caller-owned arrays; any thread.
 */
#ifndef PT_COMMON_SCENE_TANGENT_H
#define PT_COMMON_SCENE_TANGENT_H

#include <stdint.h>

#include "common/base/error.h"

/* Fills tan[4 v .. 4 v + 3] (xyz unit, w = +-1) for every vertex v whose
 * tangent is all zero on entry and that some triangle t with use[t] != 0
 * (use NULL: every triangle) references; other vertices keep theirs. pos: 3
 * per vertex; nrm: 3 per vertex, unit; uv: 2 per vertex; idx: 3 per
 * triangle, each < nv. A vertex whose triangles have degenerate UVs gets a
 * tangent perpendicular to its normal and w = 1. Returns PT_ERR_NOMEM (24
 * bytes a vertex of scratch). */
pt_status pt_tangents_generate(const float *pos, const float *nrm, const float *uv,
                               const uint32_t *idx, uint32_t nt, const uint8_t *use, uint32_t nv,
                               float *tan, pt_error *err);

#endif
