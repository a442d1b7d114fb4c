/*
 * closure_of.h - the tests' closures of one parameter set
 * (common/render/closure.h), built for wo and evaluated or sampled at once:
 * the glTF base alone (cl_bsdf_*), clearcoat and sheen over their base
 * (cl_layers_*), glass (cl_glass_*). Each builds the closure exactly as the
 * integrator does for that material.
 */
#ifndef PT_TESTS_COMMON_RENDER_CLOSURE_OF_H
#define PT_TESTS_COMMON_RENDER_CLOSURE_OF_H

#include "common/render/closure.h"

static inline pt_closure cl_of_bsdf(const pt_bsdf *b, pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, b);
    return c;
}

static inline pt_closure cl_of_layers(const pt_layers *l, pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &l->base);
    pt_closure_add_layers(&c, l);
    return c;
}

static inline pt_closure cl_of_glass(const pt_glass *g, pt_vec3 wo)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, g);
    return c;
}

static inline pt_vec3 cl_bsdf_eval(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    pt_closure c = cl_of_bsdf(b, wo);
    return pt_closure_eval(&c, wi, pdf);
}

static inline float cl_bsdf_pdf(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi)
{
    pt_closure c = cl_of_bsdf(b, wo);
    return pt_closure_pdf(&c, wi);
}

static inline pt_vec3 cl_bsdf_sample(const pt_bsdf *b, pt_vec3 wo, const float u[3], pt_vec3 *wi,
                                     float *pdf)
{
    pt_closure c = cl_of_bsdf(b, wo);
    return pt_closure_sample(&c, u, wi, pdf, NULL);
}

static inline pt_vec3 cl_layers_eval(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    pt_closure c = cl_of_layers(l, wo);
    return pt_closure_eval(&c, wi, pdf);
}

static inline float cl_layers_pdf(const pt_layers *l, pt_vec3 wo, pt_vec3 wi)
{
    pt_closure c = cl_of_layers(l, wo);
    return pt_closure_pdf(&c, wi);
}

static inline pt_vec3 cl_layers_sample(const pt_layers *l, pt_vec3 wo, const float u[3],
                                       pt_vec3 *wi, float *pdf)
{
    pt_closure c = cl_of_layers(l, wo);
    return pt_closure_sample(&c, u, wi, pdf, NULL);
}

static inline pt_vec3 cl_glass_eval(const pt_glass *g, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    pt_closure c = cl_of_glass(g, wo);
    return pt_closure_eval(&c, wi, pdf);
}

static inline pt_vec3 cl_glass_sample(const pt_glass *g, pt_vec3 wo, const float u[3], pt_vec3 *wi,
                                      float *pdf, int *delta)
{
    pt_closure c = cl_of_glass(g, wo);
    return pt_closure_sample(&c, u, wi, pdf, delta);
}

#endif
