/*
 * portal.h - environment portals: the openings (windows, doors) through
 * which the environment lights an interior, sampled by solid angle.
 *
 * A scene names them (pt_scene.portals: triangles no ray meets, from mesh
 * nodes marked "ptfarm_portal", scene.h). Seen from a receiver at p, the
 * directions through them are most of the directions along which the map
 * can light p at all; the map's own distribution (env.h) spreads its
 * samples over the whole sphere, and inside a room nearly all of them end
 * on a wall. Bitterli, Novak and Jarosz 2015 ("Portal-Masked Environment
 * Map Sampling", EGSR) sample the map masked by the portal; here, as in
 * Cycles' portal lights, the directions through the portals are sampled
 * uniformly in the solid angle they subtend (a triangle chosen by its solid
 * angle, then Arvo's map within it: sphtri.h) and the environment light
 * mixes that with the map's distribution (light.c), which keeps a sun in
 * a window found by the map's samples.
 *
 * A portal's front (its counter-clockwise side, the glTF front face)
 * faces into the room. A triangle counts for a receiver on its front side
 * when some corner lies strictly above the receiver's tangent plane
 * (normal n; a zero n: no bound), so a wall facing away from the window
 * sends no sample there, and neither does a point outside the room (the
 * ground seen through the window), whose samples through the window would
 * end in the room. The density of a direction
 * is k / Omega, Omega the counted triangles' solid angles summed and k how
 * many of them the ray from p crosses (1 but where two overlap from p).
 * Pure functions of their arguments; any thread.
 */
#ifndef PT_COMMON_RENDER_PORTAL_H
#define PT_COMMON_RENDER_PORTAL_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"
#include "common/scene/scene.h"

/* The portals as a receiver at p with normal nrm sees them: which
 * triangles count (bit i of `counted`; PT_SCENE_MAX_PORTALS is 64), and,
 * once measured (pt_portal_measure, which the functions below call when
 * they need it), each one's solid angle from p (0 where it does not count)
 * and their sum Omega. Most light samples of the map from inside a room
 * cross no portal, and their density needs no solid angle. */
typedef struct pt_portal_view {
    const float *tris;   /* 9 floats a triangle */
    const float *fronts; /* 3 floats a triangle: its front's unit normal */
    uint32_t n;
    pt_vec3 p;
    uint64_t counted;
    int measured;
    double om[PT_SCENE_MAX_PORTALS];
    double sum;
} pt_portal_view;

/* The view of the n portal triangles tris with their fronts (a scene's
 * portals and portal_fronts; n at most PT_SCENE_MAX_PORTALS, the rest are
 * ignored) from p with normal nrm. */
void pt_portal_view_init(pt_portal_view *v, const float *tris, const float *fronts, uint32_t n,
                         pt_vec3 p, pt_vec3 nrm);

/* Measures the counted triangles' solid angles (once). */
void pt_portal_measure(pt_portal_view *v);

/* A direction from p through the portals for u0, u1, u2 in [0,1) (u0 the
 * triangle, by its solid angle; u1, u2 the direction within it) into *wi,
 * with its density (per steradian, above) into *pdf: pt_portal_pdf's,
 * with the chosen triangle counted as crossed even where rounding puts the
 * direction just past its edge. Returns 0 when no triangle counts or the
 * sample is impossible. */
int pt_portal_sample(pt_portal_view *v, float u0, float u1, float u2, pt_vec3 *wi, double *pdf);

/* The density pt_portal_sample gives direction dir (unit) from p: k /
 * Omega (above); 0 when dir crosses no counted triangle (then nothing is
 * measured). */
double pt_portal_pdf(pt_portal_view *v, pt_vec3 dir);

/* ---- which way a portal faces, checked before a render ------------------ */

/* A portal wound the wrong way faces out of its room: no point in the room
 * is on its front, so it is never sampled, and the render is the one
 * without it, silently. Seen from its centroid, a portal in an opening
 * has the room's walls in front and the outdoors behind; one wound the
 * wrong way, the reverse. pt_portal_openness measures it: for each portal
 * triangle i, the share of PT_PORTAL_PROBES directions, cosine-distributed
 * about its front (open[2 i]) and about its back (open[2 i + 1]), that
 * leave the scene without meeting a surface, glass excepted (a material
 * that transmits: a window's pane is not a wall; in a scene of instances
 * every surface counts). Fixed directions: a function of the scene. open
 * holds 2 x scene->num_portals floats. PT_OK, or an error building the ray
 * queries. */
#define PT_PORTAL_PROBES 64u
pt_status pt_portal_openness(const pt_scene *scene, float *open, pt_error *err);

/* How many of scene's portal triangles look wound the wrong way (their
 * front more open than their back by PT_PORTAL_REVERSED_GAP or more: a
 * window's back sees at least the sky's half above a ground plane, its
 * front a closed room) into *n, and the first one's front into *front.
 * *n is 0 for a scene without portals (and nothing is traced). */
#define PT_PORTAL_REVERSED_GAP 0.25f
pt_status pt_portal_reversed(const pt_scene *scene, uint32_t *n, pt_vec3 *front, pt_error *err);

/* What every program says of scene's portals before a render, into out
 * (cap bytes): the warning of those pt_portal_reversed names (returns 1),
 * or that the check could not run, and why (returns -1: a check, never a
 * condition of the render); returns 0 with out "" when there is nothing to
 * say, as for a scene without portals. */
int pt_portal_check_text(const pt_scene *scene, char *out, size_t cap);

#endif
