#include "common/render/options.h"

#include <float.h>
#include <string.h>

#include "common/base/frames.h"
#include "common/base/opt.h"
#include "common/render/denoise_frame.h"
#include "common/render/passes.h"
#include "common/render/render.h"
#include "common/render/tile.h"

static const struct {
    const char *name;
    int has_arg;
} table[PT_ROPT_COUNT] = {
    [PT_ROPT_SPP] = {"spp", required_argument},
    [PT_ROPT_RES] = {"res", required_argument},
    [PT_ROPT_SEED] = {"seed", required_argument},
    [PT_ROPT_MAX_DEPTH] = {"max-depth", required_argument},
    [PT_ROPT_CAMERA] = {"camera", required_argument},
    [PT_ROPT_CAMERA_FROM] = {"camera-from", required_argument},
    [PT_ROPT_CAMERA_AT] = {"camera-at", required_argument},
    [PT_ROPT_FOV] = {"fov", required_argument},
    [PT_ROPT_ORTHO] = {"ortho", required_argument},
    [PT_ROPT_VARIANT] = {"variant", required_argument},
    [PT_ROPT_ANIMATION] = {"animation", required_argument},
    [PT_ROPT_ENV] = {"env", required_argument},
    [PT_ROPT_ENV_STRENGTH] = {"env-strength", required_argument},
    [PT_ROPT_ENV_ROTATE] = {"env-rotate", required_argument},
    [PT_ROPT_BACKGROUND] = {"background", required_argument},
    [PT_ROPT_TRANSPARENT] = {"transparent", no_argument},
    [PT_ROPT_SHUTTER] = {"shutter", required_argument},
    [PT_ROPT_FPS] = {"fps", required_argument},
    [PT_ROPT_TARGET_ERROR] = {"target-error", required_argument},
    [PT_ROPT_MIN_GAIN] = {"min-gain", required_argument},
    [PT_ROPT_MIN_SPP] = {"min-spp", required_argument},
    [PT_ROPT_TILE] = {"tile", required_argument},
    [PT_ROPT_CHUNK] = {"chunk", required_argument},
    [PT_ROPT_EXPOSURE] = {"exposure", required_argument},
    [PT_ROPT_VIEW] = {"view", required_argument},
    [PT_ROPT_PASSES] = {"passes", required_argument},
    [PT_ROPT_DENOISE] = {"denoise", no_argument},
    [PT_ROPT_DENOISE_PROGRESSIVE] = {"denoise-progressive", no_argument},
    [PT_ROPT_CLAMP_DIRECT] = {"clamp-direct", required_argument},
    [PT_ROPT_CLAMP_INDIRECT] = {"clamp-indirect", required_argument},
    [PT_ROPT_GUIDING] = {"guiding", required_argument},
    [PT_ROPT_BDPT] = {"bdpt", optional_argument},
};

void pt_render_opts_init(pt_render_opts *o)
{
    memset(o, 0, sizeof *o);
    o->spp = 64;
    o->max_depth = PT_RENDER_DEFAULT_MAX_DEPTH;
    o->env_strength = 1.0;
    o->fps = PT_FRAMES_DEFAULT_FPS;
    o->tile = 32;
    o->chunk = 16;
}

size_t pt_render_longopts(uint32_t mask, struct option *out, size_t cap)
{
    size_t n = 0;
    for (int id = 0; id < PT_ROPT_COUNT && n < cap; id++)
        if (mask & PT_ROPT(id))
            out[n++] = (struct option){table[id].name, table[id].has_arg, NULL, PT_ROPT_BASE + id};
    return n;
}

void pt_render_getopt_table(const struct option *own, size_t nown, uint32_t mask,
                            struct option *out)
{
    memcpy(out, own, nown * sizeof *own);
    size_t n = nown + pt_render_longopts(mask, out + nown, PT_ROPT_COUNT);
    out[n] = (struct option){NULL, 0, NULL, 0};
}

int pt_render_opt_is(int c)
{
    return c >= PT_ROPT_BASE && c < PT_ROPT_BASE + PT_ROPT_COUNT;
}

/* off, on or auto into *out as values[0], [1] or [2]. */
static pt_status on_off_auto(const char *opt, const char *text, const int values[3], int *out,
                             pt_error *err)
{
    static const char *const names[3] = {"off", "on", "auto"};
    for (int k = 0; k < 3; k++)
        if (strcmp(text, names[k]) == 0) {
            *out = values[k];
            return PT_OK;
        }
    return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not on, off or auto", opt, text);
}

/* A name a farm job carries (camera, variant, animation): 1 to 64 bytes. */
static pt_status name_of(const char *opt, const char *text, const char **out, pt_error *err)
{
    if (!text[0] || strlen(text) > PT_ROPT_MAX_NAME)
        return pt_error_set(err, PT_ERR_ARG, "%s: a name of 1 to %u bytes", opt, PT_ROPT_MAX_NAME);
    *out = text;
    return PT_OK;
}

pt_status pt_render_opt_set(pt_render_opts *o, int c, const char *text, pt_error *err)
{
    if (!pt_render_opt_is(c))
        return pt_error_set(err, PT_ERR_ARG, "not a render option (%d)", c);
    int id = c - PT_ROPT_BASE;
    char opt[32];
    snprintf(opt, sizeof opt, "--%s", table[id].name);
    pt_status st = PT_OK;
    switch ((pt_ropt_id)id) {
    case PT_ROPT_SPP:
        st = pt_opt_u32(opt, text, 1, PT_ROPT_MAX_SPP, &o->spp, err);
        break;
    case PT_ROPT_RES:
        st = pt_opt_res(opt, text, PT_RENDER_MAX_SIDE, &o->width, &o->height, err);
        break;
    case PT_ROPT_SEED:
        st = pt_opt_u32(opt, text, 0, UINT32_MAX, &o->seed, err);
        break;
    case PT_ROPT_MAX_DEPTH:
        st = pt_opt_u32(opt, text, 0, PT_RENDER_MAX_DEPTH, &o->max_depth, err);
        break;
    case PT_ROPT_CAMERA:
        st = name_of(opt, text, &o->camera, err);
        break;
    case PT_ROPT_CAMERA_FROM:
    case PT_ROPT_CAMERA_AT:
    case PT_ROPT_FOV:
    case PT_ROPT_ORTHO:
        st = pt_camera_look_option(&o->look, opt, text, err);
        break;
    case PT_ROPT_VARIANT:
        st = name_of(opt, text, &o->variant, err);
        break;
    case PT_ROPT_ANIMATION:
        st = name_of(opt, text, &o->animation, err);
        break;
    case PT_ROPT_ENV:
        o->env_path = text;
        break;
    case PT_ROPT_ENV_STRENGTH:
        st = pt_opt_double(opt, text, 0.0, 1e20, &o->env_strength, err);
        break;
    case PT_ROPT_ENV_ROTATE:
        st = pt_opt_double(opt, text, -1e6, 1e6, &o->env_rotate, err);
        break;
    case PT_ROPT_BACKGROUND:
        st = pt_opt_rgb(opt, text, 1e20, o->background, err);
        break;
    case PT_ROPT_TRANSPARENT:
        break;
    case PT_ROPT_BDPT:
        /* --bdpt alone is on, as before auto was the default. */
        st = on_off_auto(opt, text ? text : "on",
                         (const int[3]){PT_BDPT_OFF, PT_BDPT_ON, PT_BDPT_AUTO}, &o->bdpt, err);
        break;
    case PT_ROPT_SHUTTER:
        st = pt_opt_shutter(opt, text, o->shutter, err);
        break;
    case PT_ROPT_FPS:
        st = pt_opt_double(opt, text, PT_FRAMES_MIN_FPS, PT_FRAMES_MAX_FPS, &o->fps, err);
        break;
    case PT_ROPT_TARGET_ERROR:
        st = pt_opt_positive(opt, text, 1e6, &o->target_error, err);
        break;
    case PT_ROPT_MIN_GAIN:
        st = pt_opt_positive(opt, text, DBL_MAX, &o->min_gain, err);
        break;
    case PT_ROPT_MIN_SPP:
        st = pt_opt_u32(opt, text, 2, PT_ROPT_MAX_SPP, &o->min_spp, err);
        break;
    case PT_ROPT_TILE:
        st = pt_opt_u32(opt, text, 1, PT_TILE_MAX, &o->tile, err);
        break;
    case PT_ROPT_CHUNK:
        st = pt_opt_u32(opt, text, 1, PT_ROPT_MAX_SPP, &o->chunk, err);
        break;
    case PT_ROPT_EXPOSURE: {
        double ev = 0.0;
        st = pt_opt_double(opt, text, -PT_VIEW_MAX_EV, PT_VIEW_MAX_EV, &ev, err);
        o->view.exposure = (float)ev;
        break;
    }
    case PT_ROPT_VIEW:
        st = pt_view_parse(opt, text, &o->view.kind, err);
        break;
    case PT_ROPT_PASSES:
        st = pt_passes_parse(opt, text, &o->passes, err);
        break;
    case PT_ROPT_DENOISE:
        o->denoise = 1;
        break;
    case PT_ROPT_DENOISE_PROGRESSIVE:
        o->denoise = 1;
        o->denoise_progressive = 1;
        break;
    case PT_ROPT_CLAMP_DIRECT:
    case PT_ROPT_CLAMP_INDIRECT: {
        /* A float on the wire and in the renderer: the limit is checked as
         * the double read (NaN, negative and infinite refused) and sent as
         * the float it rounds to, the same bits in every program. */
        double v = 0.0;
        st = pt_opt_double(opt, text, 0.0, PT_ROPT_MAX_CLAMP, &v, err);
        if (st == PT_OK)
            *(id == PT_ROPT_CLAMP_DIRECT ? &o->clamp_direct : &o->clamp_indirect) = (float)v;
        break;
    }
    case PT_ROPT_GUIDING: {
        int g = 0;
        st = on_off_auto(opt, text, (const int[3]){PT_GUIDING_OFF, PT_GUIDING_ON, PT_GUIDING_AUTO},
                         &g, err);
        o->guiding = (uint32_t)g;
        break;
    }
    case PT_ROPT_COUNT:
        break;
    }
    if (st == PT_OK)
        o->given |= PT_ROPT(id);
    return st;
}

pt_status pt_render_opts_finish(pt_render_opts *o, pt_error *err)
{
    if ((o->given & PT_ROPT(PT_ROPT_ENV)) && (o->given & PT_ROPT(PT_ROPT_BACKGROUND)))
        return pt_error_set(err, PT_ERR_ARG,
                            "--env and --background are two environments; give "
                            "one");
    if ((o->given & PT_ROPT(PT_ROPT_TARGET_ERROR)) && (o->given & PT_ROPT(PT_ROPT_MIN_GAIN)))
        return pt_error_set(err, PT_ERR_ARG,
                            "--target-error and --min-gain are two adaptive rules; give one");
    int placed = 0;
    pt_status st = pt_camera_look_finish(&o->look, o->camera, o->camera_text, sizeof o->camera_text,
                                         &placed, err);
    if (st != PT_OK)
        return st;
    if (placed)
        o->camera = o->camera_text;
    if (o->denoise) {
        /* The denoiser reads these passes, and both halves of every pixel. */
        o->passes |= PT_PASS_DENOISE;
        if (o->spp < 2 || ((o->given & PT_ROPT(PT_ROPT_MIN_SPP)) && o->min_spp < 2))
            return pt_error_set(err, PT_ERR_ARG,
                                "--denoise needs 2 samples a pixel or more (--spp%s): each "
                                "pixel's even and odd samples are its two halves",
                                (o->given & PT_ROPT(PT_ROPT_MIN_SPP)) ? ", --min-spp" : "");
    }
    return PT_OK;
}
