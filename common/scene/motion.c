/*
 * motion.c - the time steps of moving meshes and of the camera (motion.h).
 *
 * The builder (scene.c) adds a moving mesh's step 0 as an ordinary mesh and
 * hands the mesh's steps here; at finish they go through the same scale,
 * translation and rebasing as step 0 (in double, rounded to float after the
 * shift, so step 0 here is bit for bit the scene's own position), and the
 * meshes that really move become the scene's pt_motion.
 */
#include "common/scene/motion.h"

#include <math.h>
#include <string.h>

#include <openssl/evp.h>

#include "common/base/alloc.h"

typedef struct motion_mesh {
    uint32_t v0, nv, t0, nt;
    float *pos;    /* steps x nv x 3, world space */
    float *nrm;    /* steps x nv x 3, or NULL: computed per step */
    uint32_t *idx; /* 3 x nt, into the mesh's own vertices */
} motion_mesh;

struct pt_motion_build {
    uint32_t steps;
    motion_mesh *meshes;
    uint32_t n, cap;
};

void pt_motion_free(pt_motion *m)
{
    if (!m)
        return;
    pt_free(m->positions);
    pt_free(m->normals);
    pt_free(m->tri);
    pt_free(m->indices);
    pt_free(m->moving);
    pt_free(m->static_tri);
    pt_free(m->cameras);
    pt_free(m);
}

void pt_motion_build_free(pt_motion_build *b)
{
    if (!b)
        return;
    for (uint32_t i = 0; i < b->n; i++) {
        pt_free(b->meshes[i].pos);
        pt_free(b->meshes[i].nrm);
        pt_free(b->meshes[i].idx);
    }
    pt_free(b->meshes);
    pt_free(b);
}

static int finite_under(const float *p, size_t n, float cap)
{
    for (size_t i = 0; i < n; i++)
        if (!(fabsf(p[i]) <= cap))
            return 0; /* NaN too */
    return 1;
}

pt_status pt_motion_build_add(pt_motion_build **bp, const char *what, uint32_t v0, uint32_t nv,
                              uint32_t t0, uint32_t nt, const uint32_t *indices, uint32_t steps,
                              const float *const *positions, const float *const *normals,
                              pt_error *err)
{
    if (steps < 2 || steps > PT_MOTION_MAX_STEPS)
        return pt_error_set(err, PT_ERR_ARG, "%s: %u time steps, not 2 to %u", what, steps,
                            PT_MOTION_MAX_STEPS);
    if (*bp && (*bp)->steps != steps)
        return pt_error_set(err, PT_ERR_ARG,
                            "%s: %u time steps where the scene's moving meshes have %u", what,
                            steps, (*bp)->steps);
    size_t per = (size_t)nv * 3;
    for (uint32_t k = 0; k < steps; k++) {
        if (!positions[k] || !finite_under(positions[k], per, PT_SCENE_MAX_COORD))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "%s: step %u: a position is missing, not finite or over %g", what,
                                k, (double)PT_SCENE_MAX_COORD);
        if (normals && (!normals[k] || !finite_under(normals[k], per, 3.4e38f)))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "%s: step %u: a normal is missing or not finite", what, k);
    }
    if (!*bp && !(*bp = pt_calloc(1, sizeof **bp)))
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", what);
    pt_motion_build *b = *bp;
    b->steps = steps;
    if (b->n == b->cap) {
        uint32_t cap = b->cap ? 2 * b->cap : 8;
        motion_mesh *q = pt_malloc_array(cap, sizeof *q);
        if (!q)
            return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", what);
        if (b->n)
            memcpy(q, b->meshes, b->n * sizeof *q);
        pt_free(b->meshes);
        b->meshes = q;
        b->cap = cap;
    }
    motion_mesh m = {v0, nv, t0, nt, NULL, NULL, NULL};
    m.pos = pt_malloc_array(per * steps, sizeof(float));
    m.nrm = normals ? pt_malloc_array(per * steps, sizeof(float)) : NULL;
    m.idx = pt_malloc_array((size_t)nt * 3, sizeof(uint32_t));
    if (!m.pos || (normals && !m.nrm) || !m.idx) {
        pt_free(m.pos);
        pt_free(m.nrm);
        pt_free(m.idx);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", what);
    }
    for (uint32_t k = 0; k < steps; k++) {
        memcpy(m.pos + per * k, positions[k], per * sizeof(float));
        if (normals)
            memcpy(m.nrm + per * k, normals[k], per * sizeof(float));
    }
    for (size_t i = 0; i < (size_t)nt * 3; i++)
        m.idx[i] = indices ? indices[i] : (uint32_t)i; /* checked by the builder */
    b->meshes[b->n++] = m;
    return PT_OK;
}

/* Whether any step of m differs from its step 0. */
static int mesh_moves(const motion_mesh *m, uint32_t steps)
{
    size_t per = (size_t)m->nv * 3 * sizeof(float);
    for (uint32_t k = 1; k < steps; k++) {
        if (memcmp(m->pos, m->pos + (size_t)m->nv * 3 * k, per) != 0)
            return 1;
        if (m->nrm && memcmp(m->nrm, m->nrm + (size_t)m->nv * 3 * k, per) != 0)
            return 1;
    }
    return 0;
}

/* The unit normals of one step of m into out (3 per vertex): the given
 * ones normalised, or area-weighted sums of the faces' cross products (in
 * double, as the builder computes a mesh's normals). Returns 0 when out of
 * memory. */
static int step_normals(const motion_mesh *m, uint32_t k, float *out)
{
    size_t per = (size_t)m->nv * 3;
    double *acc = pt_calloc(per ? per : 1, sizeof(double));
    if (!acc)
        return 0;
    if (m->nrm) {
        for (size_t i = 0; i < per; i++)
            acc[i] = m->nrm[per * k + i];
    } else {
        const float *p = m->pos + per * k;
        for (uint32_t t = 0; t < m->nt; t++) {
            const uint32_t *i = m->idx + 3 * (size_t)t;
            const float *p0 = p + 3 * (size_t)i[0], *p1 = p + 3 * (size_t)i[1],
                        *p2 = p + 3 * (size_t)i[2];
            double e1[3] = {(double)p1[0] - p0[0], (double)p1[1] - p0[1], (double)p1[2] - p0[2]};
            double e2[3] = {(double)p2[0] - p0[0], (double)p2[1] - p0[1], (double)p2[2] - p0[2]};
            double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                           e1[0] * e2[1] - e1[1] * e2[0]};
            for (int c = 0; c < 3; c++)
                for (int r = 0; r < 3; r++)
                    acc[3 * (size_t)i[c] + r] += g[r];
        }
    }
    for (uint32_t v = 0; v < m->nv; v++) {
        double x = acc[3 * v], y = acc[3 * v + 1], z = acc[3 * v + 2];
        double len = sqrt(x * x + y * y + z * z);
        if (!(len > 0.0) || !isfinite(len)) {
            x = 0.0;
            y = 0.0;
            z = 1.0;
            len = 1.0;
        }
        out[3 * v] = (float)(x / len);
        out[3 * v + 1] = (float)(y / len);
        out[3 * v + 2] = (float)(z / len);
    }
    pt_free(acc);
    return 1;
}

/* A new pt_motion for scene s with nothing moving yet (every triangle
 * still). */
static pt_motion *motion_new(const pt_scene *s)
{
    pt_motion *m = pt_calloc(1, sizeof *m);
    if (!m)
        return NULL;
    m->moving = pt_malloc_array(s->num_triangles, sizeof(uint32_t));
    m->static_tri = pt_malloc_array(s->num_triangles, sizeof(uint32_t));
    if (!m->moving || !m->static_tri) {
        pt_motion_free(m);
        return NULL;
    }
    for (uint32_t t = 0; t < s->num_triangles; t++) {
        m->moving[t] = UINT32_MAX;
        m->static_tri[t] = t;
    }
    m->num_static = s->num_triangles;
    return m;
}

pt_status pt_motion_build_finish(pt_motion_build *b, pt_scene *s, double sc, const double tr[3],
                                 pt_error *err)
{
    if (!b)
        return PT_OK;
    uint32_t K = b->steps, nvm = 0, ntm = 0;
    for (uint32_t i = 0; i < b->n; i++) {
        if (!mesh_moves(&b->meshes[i], K)) {
            b->meshes[i].nt = 0; /* still: it stays a single-step mesh */
            continue;
        }
        nvm += b->meshes[i].nv;
        ntm += b->meshes[i].nt;
    }
    if (ntm == 0)
        return PT_OK;
    pt_motion *m = motion_new(s);
    if (!m)
        return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
    m->steps = K;
    m->num_vertices = nvm;
    m->num_triangles = ntm;
    m->positions = pt_malloc_array((size_t)nvm * 3 * K, sizeof(float));
    m->normals = pt_malloc_array((size_t)nvm * 3 * K, sizeof(float));
    m->tri = pt_malloc_array(ntm, sizeof(uint32_t));
    m->indices = pt_malloc_array((size_t)ntm * 3, sizeof(uint32_t));
    if (!m->positions || !m->normals || !m->tri || !m->indices) {
        pt_motion_free(m);
        return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
    }
    pt_vec3 lo = s->bounds_min, hi = s->bounds_max;
    uint32_t vb = 0, tb = 0;
    for (uint32_t i = 0; i < b->n; i++) {
        const motion_mesh *mm = &b->meshes[i];
        if (mm->nt == 0)
            continue;
        for (uint32_t k = 0; k < K; k++) {
            const float *p = mm->pos + (size_t)mm->nv * 3 * k;
            float *q = m->positions + 3 * ((size_t)k * nvm + vb);
            for (uint32_t v = 0; v < mm->nv; v++) {
                /* The builder's arithmetic for step 0: the same bits. */
                for (int r = 0; r < 3; r++)
                    q[3 * v + r] = (float)(((double)p[3 * v + r] * sc + tr[r]) - s->origin[r]);
                if (!(fabsf(q[3 * v]) <= 3.4e38f && fabsf(q[3 * v + 1]) <= 3.4e38f &&
                      fabsf(q[3 * v + 2]) <= 3.4e38f)) {
                    pt_motion_free(m);
                    return pt_error_set(err, PT_ERR_ARG,
                                        "motion: step %u vertex %u is not finite after scaling", k,
                                        v);
                }
                pt_vec3 x = pt_v3(q[3 * v], q[3 * v + 1], q[3 * v + 2]);
                lo = pt_v3(fminf(lo.x, x.x), fminf(lo.y, x.y), fminf(lo.z, x.z));
                hi = pt_v3(fmaxf(hi.x, x.x), fmaxf(hi.y, x.y), fmaxf(hi.z, x.z));
            }
            if (!step_normals(mm, k, m->normals + 3 * ((size_t)k * nvm + vb))) {
                pt_motion_free(m);
                return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
            }
        }
        for (uint32_t t = 0; t < mm->nt; t++) {
            m->tri[tb + t] = mm->t0 + t;
            m->moving[mm->t0 + t] = tb + t;
            for (int c = 0; c < 3; c++)
                m->indices[3 * (size_t)(tb + t) + c] = vb + mm->idx[3 * (size_t)t + c];
        }
        vb += mm->nv;
        tb += mm->nt;
    }
    uint32_t ns = 0;
    for (uint32_t t = 0; t < s->num_triangles; t++)
        if (m->moving[t] == UINT32_MAX)
            m->static_tri[ns++] = t;
    m->num_static = ns;
    s->bounds_min = lo;
    s->bounds_max = hi;
    s->motion = m;
    s->features |= PT_FEAT_MOTION;
    return PT_OK;
}

void pt_motion_hash(const pt_motion *m, void *evp_md_ctx)
{
    EVP_MD_CTX *ctx = evp_md_ctx;
    uint32_t h[4] = {m->steps, m->num_vertices, m->num_triangles, m->camera_steps};
    EVP_DigestUpdate(ctx, h, sizeof h);
    size_t n = (size_t)m->steps * m->num_vertices * 3 * sizeof(float);
    if (m->num_triangles > 0) {
        EVP_DigestUpdate(ctx, m->positions, n);
        EVP_DigestUpdate(ctx, m->normals, n);
        EVP_DigestUpdate(ctx, m->tri, m->num_triangles * sizeof(uint32_t));
        EVP_DigestUpdate(ctx, m->indices, 3 * (size_t)m->num_triangles * sizeof(uint32_t));
    }
    for (uint32_t k = 0; k < m->camera_steps; k++) {
        const pt_camera *c = &m->cameras[k];
        float f[12] = {c->position.x, c->position.y, c->position.z, c->right.x,
                       c->right.y,    c->right.z,    c->up.x,       c->up.y,
                       c->up.z,       c->forward.x,  c->forward.y,  c->forward.z};
        EVP_DigestUpdate(ctx, f, sizeof f);
    }
}

pt_status pt_scene_set_motion(pt_scene *s, uint32_t steps, const float *const *positions,
                              const float *const *normals, pt_error *err)
{
    if (steps < 2 || steps > PT_MOTION_MAX_STEPS)
        return pt_error_set(err, PT_ERR_ARG, "motion: %u time steps, not 2 to %u", steps,
                            PT_MOTION_MAX_STEPS);
    uint32_t nv = s->num_vertices, nt = s->num_triangles;
    size_t per = (size_t)nv * 3;
    for (uint32_t k = 0; k < steps; k++)
        if (!positions[k] || !normals[k] || !finite_under(positions[k], per, 3.4e38f))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "motion: step %u: a position is missing or not finite", k);
    /* local[v]: the vertex's index among the moving ones, UINT32_MAX if none. */
    uint32_t *local = pt_malloc_array(nv ? nv : 1, sizeof(uint32_t));
    if (!local)
        return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
    for (uint32_t v = 0; v < nv; v++) {
        local[v] = UINT32_MAX;
        for (uint32_t k = 1; k < steps && local[v] == UINT32_MAX; k++)
            if (memcmp(positions[k] + 3 * (size_t)v, positions[0] + 3 * (size_t)v,
                       3 * sizeof(float)) != 0 ||
                memcmp(normals[k] + 3 * (size_t)v, normals[0] + 3 * (size_t)v, 3 * sizeof(float)) !=
                    0)
                local[v] = 0; /* moves */
    }
    /* tmove[t]: some vertex of triangle t moves; keep[v]: v is a vertex of
     * a moving triangle, so it gets steps (numbered in order). */
    uint8_t *tmove = pt_calloc(nt ? nt : 1, 1), *keep = pt_calloc(nv ? nv : 1, 1);
    if (!tmove || !keep) {
        pt_free(tmove);
        pt_free(keep);
        pt_free(local);
        return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
    }
    uint32_t ntm = 0;
    for (uint32_t t = 0; t < nt; t++) {
        const uint32_t *i = &s->indices[3 * (size_t)t];
        tmove[t] =
            local[i[0]] != UINT32_MAX || local[i[1]] != UINT32_MAX || local[i[2]] != UINT32_MAX;
        if (tmove[t])
            keep[i[0]] = keep[i[1]] = keep[i[2]] = 1;
        ntm += tmove[t];
    }
    uint32_t nvm = 0;
    for (uint32_t v = 0; v < nv; v++)
        local[v] = keep[v] ? nvm++ : UINT32_MAX;
    pt_free(keep);
    if (ntm == 0) {
        pt_free(tmove);
        pt_free(local);
        return PT_OK;
    }
    pt_motion *m = s->motion ? s->motion : motion_new(s);
    pt_status st = PT_OK;
    if (!m) {
        st = pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
        goto done;
    }
    /* A second call replaces the meshes' steps (the camera's stay). */
    pt_free(m->positions);
    pt_free(m->normals);
    pt_free(m->tri);
    pt_free(m->indices);
    m->positions = pt_malloc_array((size_t)nvm * 3 * steps, sizeof(float));
    m->normals = pt_malloc_array((size_t)nvm * 3 * steps, sizeof(float));
    m->tri = pt_malloc_array(ntm, sizeof(uint32_t));
    m->indices = pt_malloc_array((size_t)ntm * 3, sizeof(uint32_t));
    if (!m->positions || !m->normals || !m->tri || !m->indices) {
        if (m != s->motion)
            pt_motion_free(m);
        else { /* the camera's motion stays; the meshes' is dropped */
            pt_free(m->positions);
            pt_free(m->normals);
            pt_free(m->tri);
            pt_free(m->indices);
            m->positions = m->normals = NULL;
            m->tri = m->indices = NULL;
        }
        st = pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory");
        goto done;
    }
    m->steps = steps;
    m->num_vertices = nvm;
    m->num_triangles = ntm;
    pt_vec3 lo = s->bounds_min, hi = s->bounds_max;
    for (uint32_t k = 0; k < steps; k++) {
        for (uint32_t v = 0; v < nv; v++) {
            if (local[v] == UINT32_MAX)
                continue;
            float *q = m->positions + 3 * ((size_t)k * nvm + local[v]);
            float *n = m->normals + 3 * ((size_t)k * nvm + local[v]);
            memcpy(q, positions[k] + 3 * (size_t)v, 3 * sizeof(float));
            memcpy(n, normals[k] + 3 * (size_t)v, 3 * sizeof(float));
            lo = pt_v3(fminf(lo.x, q[0]), fminf(lo.y, q[1]), fminf(lo.z, q[2]));
            hi = pt_v3(fmaxf(hi.x, q[0]), fmaxf(hi.y, q[1]), fmaxf(hi.z, q[2]));
        }
    }
    uint32_t tb = 0, ns = 0;
    for (uint32_t t = 0; t < nt; t++) {
        const uint32_t *i = &s->indices[3 * (size_t)t];
        if (!tmove[t]) {
            m->moving[t] = UINT32_MAX;
            m->static_tri[ns++] = t;
            continue;
        }
        m->moving[t] = tb;
        m->tri[tb] = t;
        for (int c = 0; c < 3; c++)
            m->indices[3 * (size_t)tb + c] = local[i[c]];
        tb++;
    }
    m->num_static = ns;
    s->bounds_min = lo;
    s->bounds_max = hi;
    s->motion = m;
    s->features |= PT_FEAT_MOTION;
done:
    pt_free(tmove);
    pt_free(local);
    return st;
}

pt_camera pt_motion_camera(const pt_motion *m, float t)
{
    uint32_t i;
    float f;
    pt_motion_segment(m->camera_steps, t, &i, &f);
    const pt_camera *a = &m->cameras[i], *b = &m->cameras[i + 1];
    pt_camera c = *a;
    c.position = pt_v3_lerp(a->position, b->position, f);
    pt_vec3 fw = pt_v3_norm(pt_v3_lerp(a->forward, b->forward, f));
    pt_vec3 rt = pt_v3_lerp(a->right, b->right, f);
    rt = pt_v3_norm(pt_v3_sub(rt, pt_v3_scale(fw, pt_v3_dot(rt, fw))));
    c.forward = fw;
    c.right = rt;
    c.up = pt_v3_cross(rt, fw);
    return c;
}

static int unit(pt_vec3 v)
{
    float l = pt_v3_len(v);
    return pt_isfinite3(v) && fabsf(l - 1.0f) < 1e-3f;
}

/* The camera's poses, each position less shift (the origin for world-space
 * poses, 0 for scene-space ones). */
static pt_status set_camera_motion(pt_scene *s, uint32_t steps, const pt_camera *poses,
                                   const double shift[3], pt_error *err)
{
    if (steps < 2 || steps > PT_MOTION_MAX_STEPS)
        return pt_error_set(err, PT_ERR_ARG, "camera motion: %u time steps, not 2 to %u", steps,
                            PT_MOTION_MAX_STEPS);
    for (uint32_t k = 0; k < steps; k++) {
        const pt_camera *c = &poses[k];
        if (!pt_isfinite3(c->position) || !unit(c->right) || !unit(c->up) || !unit(c->forward))
            return pt_error_set(err, PT_ERR_ARG,
                                "camera motion: pose %u is not finite or its axes not unit", k);
    }
    pt_camera *cams = pt_malloc_array(steps, sizeof *cams);
    if (!cams)
        return pt_error_set(err, PT_ERR_NOMEM, "camera motion: out of memory");
    int moves = 0;
    for (uint32_t k = 0; k < steps; k++) {
        cams[k] = poses[k];
        const pt_vec3 p = poses[k].position;
        cams[k].position = pt_v3((float)((double)p.x - shift[0]), (float)((double)p.y - shift[1]),
                                 (float)((double)p.z - shift[2]));
        if (k > 0 && (memcmp(&cams[k].position, &cams[0].position, sizeof(pt_vec3)) != 0 ||
                      memcmp(&cams[k].right, &cams[0].right, sizeof(pt_vec3)) != 0 ||
                      memcmp(&cams[k].up, &cams[0].up, sizeof(pt_vec3)) != 0 ||
                      memcmp(&cams[k].forward, &cams[0].forward, sizeof(pt_vec3)) != 0))
            moves = 1;
    }
    s->camera = cams[0];
    if (!moves) {
        pt_free(cams);
        return PT_OK;
    }
    if (!s->motion && !(s->motion = motion_new(s))) {
        pt_free(cams);
        return pt_error_set(err, PT_ERR_NOMEM, "camera motion: out of memory");
    }
    pt_free(s->motion->cameras);
    s->motion->cameras = cams;
    s->motion->camera_steps = steps;
    s->features |= PT_FEAT_MOTION;
    return PT_OK;
}

pt_status pt_scene_set_camera_motion(pt_scene *s, uint32_t steps, const pt_camera *poses,
                                     pt_error *err)
{
    return set_camera_motion(s, steps, poses, s->origin, err);
}

pt_status pt_scene_set_camera_motion_scene(pt_scene *s, uint32_t steps, const pt_camera *poses,
                                           pt_error *err)
{
    static const double none[3] = {0.0, 0.0, 0.0};
    return set_camera_motion(s, steps, poses, none, err);
}
