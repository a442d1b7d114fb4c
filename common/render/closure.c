/*
 * closure.c - the material closure (closure.h): the builder, and eval and
 * sample over the groups of lobes.
 *
 * The sums and products are written in the order the model states them
 * (closure.h): a group's pdf adds its lobes' shares in order, then the
 * inner group's, then the shares of lobes on their own normal; the value
 * folds from the innermost lobe outwards. u[0] is compared with the running
 * sum of the probabilities and rescaled by subtracting them one by one, so a
 * pick is the same whichever lobes a material lacks.
 */
#include "common/render/closure.h"

#include <assert.h>
#include <math.h>

#include "common/render/path_trace.h"

void pt_closure_init(pt_closure *c, pt_vec3 wo)
{
    c->wo = wo;
    c->n_lobes = 0;
    c->n_groups = 0;
    c->dead = !(wo.z > 0.0f);
    c->coat_mirror = 0;
}

/* Nothing scatters at this wo. */
static void closure_kill(pt_closure *c)
{
    c->dead = 1;
    c->n_lobes = 0;
    c->n_groups = 0;
}

/* A new outermost group; below is the probability of the group inside. */
static pt_closure_group *open_group(pt_closure *c, float below)
{
    assert(c->n_groups < PT_CLOSURE_MAX_GROUPS);
    pt_closure_group *g = &c->group[c->n_groups];
    g->first = c->n_lobes;
    g->n = 0;
    g->below = c->n_groups > 0 ? below : 0.0f;
    c->n_groups++;
    return g;
}

static pt_lobe *add_lobe(pt_closure *c, pt_closure_group *g, uint32_t kind, float prob)
{
    assert(c->n_lobes < PT_CLOSURE_MAX_LOBES);
    pt_lobe *l = &c->lobe[c->n_lobes++];
    g->n++;
    l->kind = kind;
    l->own = 0;
    l->prob = prob;
    return l;
}

void pt_closure_add_base(pt_closure *c, const pt_bsdf *b)
{
    if (c->dead)
        return;
    float ps = pt_bsdf_spec_prob(b, c->wo.z);
    pt_closure_group *g = open_group(c, 0.0f);
    if (ps > 0.0f)
        add_lobe(c, g, PT_LOBE_SPECULAR, ps)->p.specular = pt_bsdf_specular(b);
    if (ps < 1.0f)
        add_lobe(c, g, PT_LOBE_DIFFUSE, 1.0f - ps)->p.diffuse = pt_bsdf_diffuse(b);
}

/* The base under a film, its GGX lobe anisotropic when aniso. */
static void add_base_irid(pt_closure *c, const pt_bsdf *b, const pt_irid *film, int aniso,
                          float strength, float dc, float ds)
{
    if (c->dead)
        return;
    float ps = pt_bsdf_spec_prob(b, c->wo.z);
    pt_closure_group *g = open_group(c, 0.0f);
    if (ps > 0.0f && aniso) {
        pt_irid_aniso_lobe *l = &add_lobe(c, g, PT_LOBE_SPECULAR_ANISO_IRID, ps)->p.irid_aniso;
        l->a = pt_aniso_setup(b, strength, dc, ds);
        l->film = *film;
    } else if (ps > 0.0f) {
        pt_irid_specular_lobe *l = &add_lobe(c, g, PT_LOBE_SPECULAR_IRID, ps)->p.irid_specular;
        l->s = pt_bsdf_specular(b);
        l->film = *film;
    }
    if (ps < 1.0f) {
        pt_irid_diffuse_lobe *l = &add_lobe(c, g, PT_LOBE_DIFFUSE_IRID, 1.0f - ps)->p.irid_diffuse;
        l->d = pt_bsdf_diffuse(b);
        l->f0 = b->f0;
        l->film = *film;
    }
}

void pt_closure_add_base_irid(pt_closure *c, const pt_bsdf *b, const pt_irid *film)
{
    add_base_irid(c, b, film, 0, 0.0f, 1.0f, 0.0f);
}

void pt_closure_add_base_irid_aniso(pt_closure *c, const pt_bsdf *b, const pt_irid *film,
                                    float strength, float dc, float ds)
{
    add_base_irid(c, b, film, 1, strength, dc, ds);
}

void pt_closure_add_base_aniso(pt_closure *c, const pt_bsdf *b, float strength, float dc, float ds)
{
    if (c->dead)
        return;
    float ps = pt_bsdf_spec_prob(b, c->wo.z);
    pt_closure_group *g = open_group(c, 0.0f);
    if (ps > 0.0f)
        add_lobe(c, g, PT_LOBE_SPECULAR_ANISO, ps)->p.aniso = pt_aniso_setup(b, strength, dc, ds);
    if (ps < 1.0f)
        add_lobe(c, g, PT_LOBE_DIFFUSE, 1.0f - ps)->p.diffuse = pt_bsdf_diffuse(b);
}

/* pt_closure_add_base_dt with the specular lobe anisotropic when aniso
 * (strength, dc, ds as pt_closure_add_base_aniso's), every lobe under
 * the film when film is not NULL. */
static void add_base_dt(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through, int aniso,
                        float strength, float dc, float ds, const pt_irid *film)
{
    if (c->dead)
        return;
    /* The specular lobe's share from both diffuse albedos together; the
     * rest split between them by their luminances. */
    pt_bsdf both = *b;
    pt_vec3 refl = pt_v3_scale(b->diffuse, 1.0f - dt);
    both.diffuse = pt_v3_add(refl, through);
    float ps = pt_bsdf_spec_prob(&both, c->wo.z);
    float lr = pt_luminance(refl), lt = pt_luminance(through);
    float pr = lr + lt > 0.0f ? lr / (lr + lt) : 0.5f;
    pt_closure_group *g = open_group(c, 0.0f);
    if (ps > 0.0f && film && aniso) {
        pt_irid_aniso_lobe *l = &add_lobe(c, g, PT_LOBE_SPECULAR_ANISO_IRID, ps)->p.irid_aniso;
        l->a = pt_aniso_setup(b, strength, dc, ds);
        l->film = *film;
    } else if (ps > 0.0f && film) {
        pt_irid_specular_lobe *l = &add_lobe(c, g, PT_LOBE_SPECULAR_IRID, ps)->p.irid_specular;
        l->s = pt_bsdf_specular(b);
        l->film = *film;
    } else if (ps > 0.0f && aniso) {
        add_lobe(c, g, PT_LOBE_SPECULAR_ANISO, ps)->p.aniso = pt_aniso_setup(b, strength, dc, ds);
    } else if (ps > 0.0f) {
        add_lobe(c, g, PT_LOBE_SPECULAR, ps)->p.specular = pt_bsdf_specular(b);
    }
    if (ps < 1.0f && pr > 0.0f) {
        pt_diffuse_lobe d = {refl, b->dielectric_f0, b->dielectric_f90};
        float p = (1.0f - ps) * pr;
        if (film) {
            pt_irid_diffuse_lobe *l = &add_lobe(c, g, PT_LOBE_DIFFUSE_IRID, p)->p.irid_diffuse;
            l->d = d;
            l->f0 = b->f0;
            l->film = *film;
        } else {
            add_lobe(c, g, PT_LOBE_DIFFUSE, p)->p.diffuse = d;
        }
    }
    if (ps < 1.0f && pr < 1.0f) {
        pt_diffuse_lobe d = {through, b->dielectric_f0, b->dielectric_f90};
        float p = (1.0f - ps) * (1.0f - pr);
        if (film) {
            pt_irid_diffuse_lobe *l =
                &add_lobe(c, g, PT_LOBE_DIFFUSE_TRANSMIT_IRID, p)->p.irid_diffuse;
            l->d = d;
            l->f0 = b->f0;
            l->film = *film;
        } else {
            add_lobe(c, g, PT_LOBE_DIFFUSE_TRANSMIT, p)->p.diffuse = d;
        }
    }
}

void pt_closure_add_base_dt(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through)
{
    add_base_dt(c, b, dt, through, 0, 0.0f, 1.0f, 0.0f, NULL);
}

void pt_closure_add_base_dt_aniso(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through,
                                  float strength, float dc, float ds)
{
    add_base_dt(c, b, dt, through, 1, strength, dc, ds, NULL);
}

void pt_closure_add_base_dt_irid(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through,
                                 const pt_irid *film, int aniso, float strength, float dc, float ds)
{
    add_base_dt(c, b, dt, through, aniso, strength, dc, ds, film);
}

void pt_closure_add_glass(pt_closure *c, const pt_glass *gl)
{
    if (c->dead)
        return;
    /* The opaque share, when sampling can pick it; the interface beside it. */
    if (gl->pick < 1.0f)
        pt_closure_add_base(c, &gl->base);
    if (gl->pick > 0.0f) {
        pt_closure_group *g = open_group(c, 1.0f - gl->pick);
        add_lobe(c, g, PT_LOBE_DIELECTRIC, gl->pick)->p.dielectric = pt_glass_interface(gl);
    }
}

void pt_closure_add_layers(pt_closure *c, const pt_layers *l)
{
    if (c->dead)
        return;
    pt_coat_lobe coat;
    pt_sheen_lobe sheen;
    float pc, ps, pb;
    if (!pt_layers_lobes(l, c->wo, &coat, &sheen, &pc, &ps, &pb)) {
        closure_kill(c);
        return;
    }
    pt_closure_group *g = open_group(c, pb);
    if (l->clearcoat > 0.0f) {
        pt_lobe *lc = add_lobe(c, g, PT_LOBE_COAT, pc);
        lc->p.coat = coat;
        lc->own = (uint32_t)coat.own;
    }
    if (l->sheen_max > 0.0f)
        add_lobe(c, g, PT_LOBE_SHEEN, ps)->p.sheen = sheen;
}

void pt_closure_coat_mirror(pt_closure *c)
{
    c->coat_mirror = 1;
}

/* One lobe's f cos, pdf share and factor on the lobes under it. */
static inline __attribute__((always_inline)) pt_vec3
lobe_eval(const pt_lobe *l, pt_vec3 wo, pt_vec3 wi, float *share, float *below)
{
    *below = 1.0f;
    switch (l->kind) {
    case PT_LOBE_DIFFUSE:
        return pt_diffuse_eval(&l->p.diffuse, wo, wi, l->prob, share);
    case PT_LOBE_SPECULAR:
        return pt_specular_eval(&l->p.specular, wo, wi, l->prob, share);
    case PT_LOBE_DIELECTRIC:
        return pt_dielectric_eval(&l->p.dielectric, wo, wi, l->prob, share);
    case PT_LOBE_SHEEN:
        return pt_sheen_eval(&l->p.sheen, wo, wi, l->prob, share, below);
    case PT_LOBE_COAT:
        return pt_coat_eval(&l->p.coat, wo, wi, l->prob, share, below);
    case PT_LOBE_SPECULAR_IRID:
        return pt_irid_specular_eval(&l->p.irid_specular, wo, wi, l->prob, share);
    case PT_LOBE_DIFFUSE_IRID:
        return pt_irid_diffuse_eval(&l->p.irid_diffuse, wo, wi, l->prob, share);
    case PT_LOBE_SPECULAR_ANISO:
        return pt_aniso_eval(&l->p.aniso, wo, wi, l->prob, share);
    case PT_LOBE_DIFFUSE_TRANSMIT:
        return pt_diffuse_transmit_eval(&l->p.diffuse, wo, wi, l->prob, share);
    case PT_LOBE_SPECULAR_ANISO_IRID:
        return pt_irid_aniso_eval(&l->p.irid_aniso, wo, wi, l->prob, share);
    case PT_LOBE_DIFFUSE_TRANSMIT_IRID:
        return pt_irid_transmit_eval(&l->p.irid_diffuse, wo, wi, l->prob, share);
    }
    *share = 0.0f;
    return pt_v3(0.0f, 0.0f, 0.0f);
}

/* f cos at wi, and each group's pdf in gpdf (the outermost's is the
 * closure's). */
static inline __attribute__((always_inline)) pt_vec3 eval_groups(const pt_closure *c, pt_vec3 wi,
                                                                 float gpdf[PT_CLOSURE_MAX_GROUPS])
{
    pt_vec3 f = pt_v3(0.0f, 0.0f, 0.0f);
    float inner = 0.0f;
    for (uint32_t g = 0; g < c->n_groups; g++) {
        const pt_closure_group *gr = &c->group[g];
        float share[PT_CLOSURE_MAX_LOBES];
        /* Innermost lobe first: f = f_lobe + below_lobe x f. */
        for (uint32_t i = gr->n; i-- > 0;) {
            float below;
            pt_vec3 fl = lobe_eval(&c->lobe[gr->first + i], c->wo, wi, &share[i], &below);
            if (below != 1.0f)
                f = pt_v3_scale(f, below);
            f = pt_v3_add(fl, f);
        }
        float p = 0.0f;
        for (uint32_t i = 0; i < gr->n; i++)
            if (!c->lobe[gr->first + i].own)
                p += share[i];
        if (g > 0)
            p += gr->below * inner;
        for (uint32_t i = 0; i < gr->n; i++)
            if (c->lobe[gr->first + i].own)
                p += share[i];
        gpdf[g] = p;
        inner = p;
    }
    return f;
}

pt_vec3 pt_closure_eval(const pt_closure *c, pt_vec3 wi, float *pdf)
{
    if (c->n_groups == 0) {
        *pdf = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float gpdf[PT_CLOSURE_MAX_GROUPS];
    pt_vec3 f = eval_groups(c, wi, gpdf);
    *pdf = gpdf[c->n_groups - 1];
    return f;
}

float pt_closure_pdf(const pt_closure *c, pt_vec3 wi)
{
    float pdf;
    pt_closure_eval(c, wi, &pdf);
    return pdf;
}

pt_vec3 pt_closure_sample(const pt_closure *c, const float u[3], pt_vec3 *wi, float *pdf,
                          int *delta)
{
    const float below1 = 0x1.fffffep-1f;
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    if (delta)
        *delta = 0;
    *wi = pt_v3(0.0f, 0.0f, 1.0f);
    if (c->n_groups == 0)
        return zero;

    /* Pick a lobe, outermost group first: u0 against the running sum of the
     * group's probabilities, else the group inside (the innermost group's
     * last lobe takes what is left); u0 rescaled to what it picked. */
    float u0 = u[0];
    uint32_t g = c->n_groups - 1;
    const pt_lobe *pick = NULL;
    for (;;) {
        const pt_closure_group *gr = &c->group[g];
        float cum = 0.0f;
        uint32_t i;
        for (i = 0; i < gr->n; i++) {
            const pt_lobe *l = &c->lobe[gr->first + i];
            if (g == 0 && i + 1 == gr->n) {
                pick = l;
                break;
            }
            cum += l->prob;
            if (u0 < cum) {
                pick = l;
                break;
            }
        }
        for (uint32_t j = 0; j < i; j++)
            u0 -= c->lobe[gr->first + j].prob;
        u0 = pt_fminf(u0 / (pick ? pick->prob : gr->below), below1);
        if (!(u0 >= 0.0f))
            u0 = 0.0f;
        if (pick)
            break;
        if (g == 0)
            return zero; /* an innermost group without lobes */
        g--;
    }

    PT_TRACE_LOBE(pick->kind);
    const float ul[3] = {u0, u[1], u[2]};
    int ok = 0;
    switch (pick->kind) {
    case PT_LOBE_DIFFUSE:
    case PT_LOBE_DIFFUSE_IRID:
        ok = pt_diffuse_sample(ul, wi);
        break;
    case PT_LOBE_SPECULAR_IRID:
        ok = pt_specular_sample(&pick->p.irid_specular.s, c->wo, ul, wi);
        break;
    case PT_LOBE_SPECULAR_ANISO:
        ok = pt_aniso_sample(&pick->p.aniso, c->wo, ul, wi);
        break;
    case PT_LOBE_SPECULAR_ANISO_IRID:
        ok = pt_aniso_sample(&pick->p.irid_aniso.a, c->wo, ul, wi);
        break;
    case PT_LOBE_DIFFUSE_TRANSMIT:
    case PT_LOBE_DIFFUSE_TRANSMIT_IRID:
        ok = pt_diffuse_transmit_sample(ul, wi);
        break;
    case PT_LOBE_SPECULAR:
        ok = pt_specular_sample(&pick->p.specular, c->wo, ul, wi);
        break;
    case PT_LOBE_SHEEN:
        ok = pt_sheen_sample(ul, wi);
        break;
    case PT_LOBE_COAT:
        ok = pt_coat_sample(&pick->p.coat, c->wo, ul, wi);
        break;
    case PT_LOBE_DIELECTRIC: {
        pt_vec3 w;
        float p;
        int r = pt_dielectric_sample(&pick->p.dielectric, c->wo, ul, pick->prob, wi, &w, &p);
        if (r == PT_DIELECTRIC_DELTA) {
            /* The groups around it: the lobes there add no delta, they only
             * pass on below(wo, wi) of it, and picking it took each
             * group's below probability. */
            for (uint32_t k = g + 1; k < c->n_groups; k++) {
                const pt_closure_group *gr = &c->group[k];
                for (uint32_t i = gr->n; i-- > 0;) {
                    float sh, below;
                    lobe_eval(&c->lobe[gr->first + i], c->wo, *wi, &sh, &below);
                    w = pt_v3_scale(w, below);
                }
                w = pt_v3_scale(w, 1.0f / gr->below);
                p *= gr->below;
            }
            if (!(p > 0.0f))
                return zero;
            *pdf = p;
            if (delta)
                *delta = 1;
            return w;
        }
        ok = r == PT_DIELECTRIC_DIR;
        break;
    }
    }
    if (!ok)
        return zero;

    /* The closure's f cos / pdf, not the lobe's, so that sampling agrees
     * with pt_closure_eval for MIS. */
    float gpdf[PT_CLOSURE_MAX_GROUPS];
    pt_vec3 f = eval_groups(c, *wi, gpdf);
    for (uint32_t k = g; k < c->n_groups; k++)
        if (!(gpdf[k] > 0.0f))
            return zero;
    *pdf = gpdf[c->n_groups - 1];
    return pt_v3_scale(f, 1.0f / *pdf);
}

/* The delta event `reflect` or not of the closure's one smooth dielectric
 * lobe (pt_closure_refracted, pt_closure_reflected). */
static pt_vec3 closure_delta(const pt_closure *c, int reflect, pt_vec3 *wi, float *take)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *take = 0.0f;
    if (c->dead || c->n_groups != 1)
        return zero;
    const pt_closure_group *gr = &c->group[0];
    for (uint32_t i = 0; i < gr->n; i++) {
        const pt_lobe *l = &c->lobe[gr->first + i];
        if (l->kind != PT_LOBE_DIELECTRIC)
            continue;
        if (!(l->prob > 0.0f))
            return zero;
        /* As pt_closure_sample weighs the delta: picking the lobe (prob)
         * cancels against the weight's 1 / prob. */
        float t;
        pt_vec3 w = reflect ? pt_dielectric_reflected(&l->p.dielectric, c->wo, wi, &t)
                            : pt_dielectric_refracted(&l->p.dielectric, c->wo, wi, &t);
        *take = l->prob * t;
        return w;
    }
    return zero;
}

pt_vec3 pt_closure_refracted(const pt_closure *c, pt_vec3 *wi, float *take)
{
    return closure_delta(c, 0, wi, take);
}

pt_vec3 pt_closure_reflected(const pt_closure *c, pt_vec3 *wi, float *take)
{
    return closure_delta(c, 1, wi, take);
}

/* 1 when l is the base's GGX lobe, or a coat on the base's normal, at
 * PT_BSDF_MIN_ALPHA: glTF's roughness up to about 0.03, a mirror in all
 * but the last tenth of a degree. Under c->coat_mirror, the coat on the
 * surface's normal alone. */
static inline int lobe_mirror(const pt_closure *c, const pt_lobe *l)
{
    return (l->kind == PT_LOBE_SPECULAR && !c->coat_mirror &&
            !(l->p.specular.alpha > PT_BSDF_MIN_ALPHA)) ||
           (l->kind == PT_LOBE_COAT && (c->coat_mirror || !l->p.coat.own) &&
            !(l->p.coat.alpha > PT_BSDF_MIN_ALPHA));
}

/* wo mirrored about the mirror lobes' normal: the shading frame's, or
 * under c->coat_mirror the coat's own. */
static pt_vec3 mirror_dir(const pt_closure *c)
{
    if (c->coat_mirror)
        for (uint32_t i = 0; i < c->n_lobes; i++) {
            const pt_lobe *l = &c->lobe[i];
            if (l->kind == PT_LOBE_COAT && l->p.coat.own) {
                pt_vec3 v = l->p.coat.wo;
                return pt_frame_to_world(&l->p.coat.fr, pt_v3(-v.x, -v.y, v.z));
            }
        }
    return pt_v3(-c->wo.x, -c->wo.y, c->wo.z);
}

pt_vec3 pt_closure_mirrored(const pt_closure *c, pt_vec3 *wi, float *take)
{
    pt_vec3 w = pt_v3(0.0f, 0.0f, 0.0f);
    *take = 0.0f;
    *wi = mirror_dir(c);
    if (c->dead)
        return w;
    /* Outermost group first: what the lobes met so far pass on (their below
     * factors at wi), and the probability of sampling inside them. */
    float pass = 1.0f, pick = 1.0f;
    for (uint32_t g = c->n_groups; g-- > 0;) {
        const pt_closure_group *gr = &c->group[g];
        for (uint32_t i = 0; i < gr->n; i++) {
            const pt_lobe *l = &c->lobe[gr->first + i];
            float share, below;
            lobe_eval(l, c->wo, *wi, &share, &below);
            if (lobe_mirror(c, l) && l->prob > 0.0f) {
                /* GGX's f cos integrated over wi as alpha goes to 0: D's
                 * mass at the mirror direction, G2 1, the Fresnel at wo.h
                 * = wo.z (the coat's, Fc(wo), is its weight). */
                pt_vec3 f =
                    l->kind == PT_LOBE_COAT
                        ? pt_v3(l->p.coat.fc, l->p.coat.fc, l->p.coat.fc)
                        : pt_bsdf_spec_fresnel(l->p.specular.f0, l->p.specular.f90, c->wo.z);
                w = pt_v3_add(w, pt_v3_scale(f, pass));
                *take += pick * l->prob;
            }
            pass *= below;
        }
        pick *= gr->below;
    }
    return w;
}

pt_vec3 pt_closure_eval_mirror(const pt_closure *c, pt_vec3 wi, pt_vec3 *f)
{
    pt_vec3 fm = pt_v3(0.0f, 0.0f, 0.0f), fa = fm;
    for (uint32_t g = 0; g < c->n_groups; g++) {
        const pt_closure_group *gr = &c->group[g];
        /* eval_groups' fold, twice: every lobe, and the mirrors alone under
         * the same below factors. */
        for (uint32_t i = gr->n; i-- > 0;) {
            const pt_lobe *l = &c->lobe[gr->first + i];
            float share, below;
            pt_vec3 fl = lobe_eval(l, c->wo, wi, &share, &below);
            if (below != 1.0f) {
                fa = pt_v3_scale(fa, below);
                fm = pt_v3_scale(fm, below);
            }
            fa = pt_v3_add(fl, fa);
            if (lobe_mirror(c, l))
                fm = pt_v3_add(fl, fm);
        }
    }
    if (f)
        *f = fa;
    return fm;
}

int pt_closure_has_mirror(const pt_closure *c)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < c->n_lobes; i++)
        n += (uint32_t)lobe_mirror(c, &c->lobe[i]);
    return n == 0 ? 0 : n == c->n_lobes ? 2 : 1;
}

pt_vec3 pt_closure_straight(const pt_closure *c, int *smooth)
{
    pt_vec3 w = pt_v3(0.0f, 0.0f, 0.0f);
    if (smooth)
        *smooth = 0;
    if (c->dead)
        return w;
    for (uint32_t g = 0; g < c->n_groups; g++) {
        const pt_closure_group *gr = &c->group[g];
        for (uint32_t i = 0; i < gr->n; i++) {
            const pt_lobe *l = &c->lobe[gr->first + i];
            if (l->kind != PT_LOBE_DIELECTRIC)
                continue;
            const pt_dielectric_lobe *d = &l->p.dielectric;
            if (!d->thin || d->alpha != 0.0f || d->disp)
                return w;
            if (smooth)
                *smooth = 1;
            /* A lobe that sampling never picks passes nothing: the BSDF
             * strategy could not cross where NEE did. */
            if (!(l->prob > 0.0f))
                return w;
            for (uint32_t k = g + 1; k < c->n_groups; k++)
                if (!(c->group[k].below > 0.0f))
                    return w;
            /* As pt_closure_sample weighs the delta: picking the lobe (its
             * prob and each outer group's below) cancels against the
             * weight's 1 / prob, leaving the outer lobes' below factors. */
            w = pt_dielectric_straight(d, c->wo);
            pt_vec3 wi = pt_v3_neg(c->wo);
            for (uint32_t k = g + 1; k < c->n_groups; k++) {
                const pt_closure_group *go = &c->group[k];
                for (uint32_t j = go->n; j-- > 0;) {
                    float sh, below;
                    lobe_eval(&c->lobe[go->first + j], c->wo, wi, &sh, &below);
                    w = pt_v3_scale(w, below);
                }
            }
            return w;
        }
    }
    return w;
}

int pt_closure_albedo(const pt_closure *c, pt_vec3 *albedo)
{
    pt_vec3 a = pt_v3(0.0f, 0.0f, 0.0f);
    float reach = 1.0f, rough = 0.0f, all = 0.0f;
    const float ra = PT_CLOSURE_ROUGH_ALPHA;
    /* Sampling picks a lobe of the outermost group with its prob, or the
     * group inside with the group's below: a lobe's chance is its prob times
     * the below of every group around it. */
    for (uint32_t g = c->n_groups; g-- > 0;) {
        const pt_closure_group *gr = &c->group[g];
        for (uint32_t i = 0; i < gr->n; i++) {
            const pt_lobe *l = &c->lobe[gr->first + i];
            pt_vec3 col = pt_v3(0.0f, 0.0f, 0.0f);
            int is_rough = 1;
            switch (l->kind) {
            case PT_LOBE_DIFFUSE:
            case PT_LOBE_DIFFUSE_TRANSMIT:
                col = l->p.diffuse.albedo;
                break;
            case PT_LOBE_DIFFUSE_IRID:
            case PT_LOBE_DIFFUSE_TRANSMIT_IRID:
                col = l->p.irid_diffuse.d.albedo;
                break;
            case PT_LOBE_SPECULAR:
                col = l->p.specular.f0;
                is_rough = l->p.specular.alpha > ra;
                break;
            case PT_LOBE_SPECULAR_IRID:
                col = l->p.irid_specular.s.f0;
                is_rough = l->p.irid_specular.s.alpha > ra;
                break;
            case PT_LOBE_SPECULAR_ANISO:
                col = l->p.aniso.f0;
                is_rough = l->p.aniso.ax * l->p.aniso.ay > ra * ra;
                break;
            case PT_LOBE_SPECULAR_ANISO_IRID:
                col = l->p.irid_aniso.a.f0;
                is_rough = l->p.irid_aniso.a.ax * l->p.irid_aniso.a.ay > ra * ra;
                break;
            case PT_LOBE_DIELECTRIC:
                col = pt_v3_scale(l->p.dielectric.tint, l->p.dielectric.weight);
                is_rough = l->p.dielectric.alpha > ra;
                break;
            case PT_LOBE_SHEEN:
                col = l->p.sheen.color;
                break;
            case PT_LOBE_COAT:
                is_rough = l->p.coat.alpha > ra;
                break;
            }
            float p = reach * l->prob;
            a = pt_v3_add(a, col);
            all += p;
            if (is_rough)
                rough += p;
        }
        reach *= gr->below;
    }
    *albedo = a;
    return all > 0.0f && 4.0f * rough > all;
}
