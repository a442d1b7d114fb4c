#include "server/params.h"

#include <math.h>

void srv_job_params_write(proto_writer *w, const srv_job_params *p)
{
    proto_w_u32(w, p->width);
    proto_w_u32(w, p->height);
    proto_w_u32(w, p->spp);
    proto_w_u32(w, p->tile);
    proto_w_u32(w, p->chunk);
    proto_w_u32(w, p->seed);
    proto_w_u32(w, p->max_depth);
    proto_w_u32(w, p->rr_depth);
    proto_w_u32(w, p->min_spp);
    proto_w_f64(w, p->target_error);
    proto_w_f64(w, p->min_gain);
    proto_w_str(w, p->camera);
    proto_w_str(w, p->env.name);
    proto_w_f32(w, p->env.strength);
    proto_w_f32(w, p->env.rotate_deg);
    proto_w_u8(w, p->env.background);
    for (int k = 0; k < 3; k++)
        proto_w_f32(w, p->env.rgb[k]);
    proto_w_u32(w, p->film_flags);
    proto_w_str(w, p->variant);
    proto_w_f64(w, p->shutter[0]);
    proto_w_f64(w, p->shutter[1]);
    proto_w_f32(w, p->clamp[0]);
    proto_w_f32(w, p->clamp[1]);
    proto_w_u8(w, (uint8_t)p->guiding);
    for (int k = 0; k < 6; k++)
        proto_w_f32(w, p->guide_box[k]);
}

/* NULL when the guiding fields make sense: off with zero bounds, or on with
 * finite ordered ones. */
static const char *guide_problem(const srv_job_params *p)
{
    if (p->guiding > 1)
        return "guiding flag";
    for (int k = 0; k < 3; k++) {
        float lo = p->guide_box[k], hi = p->guide_box[3 + k];
        if (p->guiding ? !(lo <= hi) || !isfinite(lo) || !isfinite(hi) : lo != 0.0f || hi != 0.0f)
            return "guiding bounds";
    }
    return NULL;
}

void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain, int has_env_film,
                         int has_shutter, int has_clamp_guide)
{
    p->width = proto_r_u32(r, "width");
    p->height = proto_r_u32(r, "height");
    p->spp = proto_r_u32(r, "spp");
    p->tile = proto_r_u32(r, "tile");
    p->chunk = proto_r_u32(r, "chunk");
    p->seed = proto_r_u32(r, "seed");
    p->max_depth = proto_r_u32(r, "max depth");
    p->rr_depth = proto_r_u32(r, "rr depth");
    p->min_spp = proto_r_u32(r, "min spp");
    p->target_error = proto_r_f64(r, "target error");
    p->min_gain = has_min_gain ? proto_r_f64(r, "min gain") : 0.0;
    p->camera[0] = '\0';
    proto_r_str(r, p->camera, PROTO_MAX_NAME, "camera");
    proto_env_none(&p->env);
    p->film_flags = 0;
    p->variant[0] = '\0';
    p->shutter[0] = p->shutter[1] = 0.0;
    p->clamp[0] = p->clamp[1] = 0.0f;
    p->guiding = 0;
    for (int k = 0; k < 6; k++)
        p->guide_box[k] = 0.0f;
    if (!has_env_film)
        return;
    proto_r_str(r, p->env.name, PROTO_MAX_PATH, "environment map name");
    p->env.strength = proto_r_f32(r, "environment strength");
    p->env.rotate_deg = proto_r_f32(r, "environment rotation");
    p->env.background = proto_r_u8(r, "environment background flag");
    for (int k = 0; k < 3; k++)
        p->env.rgb[k] = proto_r_f32(r, "background colour");
    p->film_flags = proto_r_u32(r, "film flags");
    if (r->status == PT_OK && (p->film_flags & ~PROTO_FILM_KNOWN))
        proto_r_fail(r, PT_ERR_FORMAT, "unknown", "film flags");
    proto_r_str(r, p->variant, PROTO_MAX_NAME, "variant");
    if (!has_shutter)
        return;
    p->shutter[0] = proto_r_f64(r, "shutter open");
    p->shutter[1] = proto_r_f64(r, "shutter close");
    if (r->status == PT_OK && proto_shutter_problem(p->shutter))
        proto_r_fail(r, PT_ERR_FORMAT, "bad", "shutter");
    if (!has_clamp_guide)
        return;
    p->clamp[0] = proto_r_f32(r, "clamp direct");
    p->clamp[1] = proto_r_f32(r, "clamp indirect");
    if (r->status == PT_OK && proto_clamp_problem(p->clamp))
        proto_r_fail(r, PT_ERR_FORMAT, "bad", "clamp");
    p->guiding = proto_r_u8(r, "guiding");
    for (int k = 0; k < 6; k++)
        p->guide_box[k] = proto_r_f32(r, "guiding bounds");
    const char *why = r->status == PT_OK ? guide_problem(p) : NULL;
    if (why)
        proto_r_fail(r, PT_ERR_FORMAT, "bad", why);
}
