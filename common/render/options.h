/*
 * options.h - the render options every program takes, in one table.
 *
 * ptworker --scene, ptserve (one job) and ptctl submit describe the same
 * render: samples, size, seed, bounce cap, camera, variant, animation,
 * environment, film, shutter, adaptive sampling, tiles, the preview's
 * view, the render passes, sample clamping, path guiding and bidirectional
 * path tracing. Their names, their value syntax and
 * their limits are here once, so a job that one program accepts the others accept too, and "--spp
 * 0" or
 * "--res 64x" is refused with the same words everywhere. A program builds
 * its getopt table from its own options and pt_render_longopts (those of
 * the table it takes), hands every value whose id is PT_ROPT_BASE + k to
 * pt_render_opt_set, then checks the options that go together with
 * pt_render_opts_finish and copies the values into its own structures.
 *
 * Pure functions over the caller's pt_render_opts: any thread may call
 * them on its own.
 */
#ifndef PT_COMMON_RENDER_OPTIONS_H
#define PT_COMMON_RENDER_OPTIONS_H

#include <getopt.h>
#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/image/view.h"
#include "common/render/bdpt_auto.h"
#include "common/scene/scene.h"

/* The options, by id; getopt's value for one is PT_ROPT_BASE + id. */
typedef enum pt_ropt_id {
    PT_ROPT_SPP = 0,
    PT_ROPT_RES,
    PT_ROPT_SEED,
    PT_ROPT_MAX_DEPTH,
    PT_ROPT_CAMERA,
    PT_ROPT_CAMERA_FROM,
    PT_ROPT_CAMERA_AT,
    PT_ROPT_FOV,
    PT_ROPT_ORTHO,
    PT_ROPT_VARIANT,
    PT_ROPT_ANIMATION,
    PT_ROPT_ENV,
    PT_ROPT_ENV_STRENGTH,
    PT_ROPT_ENV_ROTATE,
    PT_ROPT_BACKGROUND,
    PT_ROPT_TRANSPARENT,
    PT_ROPT_SHUTTER,
    PT_ROPT_FPS,
    PT_ROPT_TARGET_ERROR,
    PT_ROPT_MIN_GAIN,
    PT_ROPT_MIN_SPP,
    PT_ROPT_TILE,
    PT_ROPT_CHUNK,
    PT_ROPT_EXPOSURE,
    PT_ROPT_VIEW,
    PT_ROPT_PASSES,
    PT_ROPT_DENOISE,
    PT_ROPT_DENOISE_PROGRESSIVE,
    PT_ROPT_CLAMP_DIRECT,
    PT_ROPT_CLAMP_INDIRECT,
    PT_ROPT_GUIDING,
    PT_ROPT_BDPT,
    PT_ROPT_COUNT
} pt_ropt_id;

#define PT_ROPT_BASE 0x4000
#define PT_ROPT(id) (1u << (id)) /* an option's bit in a mask */
/* The masks are 32 bits: the table holds 32 options at most (a 33rd
 * widens `given` and the masks to 64 bits). */
#define PT_ROPT_ALL ((uint32_t)((UINT64_C(1) << PT_ROPT_COUNT) - 1u))
_Static_assert(PT_ROPT_COUNT <= 32, "the render options' masks are 32 bits");

/* The limits, one set for every program. */
#define PT_ROPT_MAX_SPP (1u << 24)
#define PT_ROPT_MAX_NAME 64u   /* camera, variant, animation: a farm job's fields */
#define PT_ROPT_MAX_CLAMP 1e30 /* --clamp-direct, --clamp-indirect (CLAMP, protocol/msg.h) */

typedef struct pt_render_opts {
    uint32_t given;         /* PT_ROPT(id) for each option given */
    uint32_t spp;           /* 64 unless given */
    uint32_t width, height; /* 0, 0: from the camera, 512 wide */
    uint32_t seed;
    uint32_t max_depth; /* PT_RENDER_DEFAULT_MAX_DEPTH unless given */
    const char *camera; /* NULL: the scene's first; after finish, also a
                           --camera-from placement (camera_text) */
    pt_camera_look_opts look;
    char camera_text[PT_ROPT_MAX_NAME + 1];
    const char *variant, *animation, *env_path;
    double env_strength; /* 1 unless given */
    double env_rotate;   /* degrees about +Y */
    double background[3];
    double shutter[2]; /* fractions of a frame */
    double fps;        /* 24 unless given */
    double target_error, min_gain;
    uint32_t min_spp; /* 0 unless given */
    uint32_t tile;    /* 32 unless given */
    uint32_t chunk;   /* 16 unless given */
    pt_view view;
    uint32_t passes;         /* PT_PASS_* (tile.h), 0 unless given; with denoise,
                                PT_PASS_DENOISE's too after finish */
    int denoise;             /* --denoise: the finished image denoised (denoise_frame.h) */
    int denoise_progressive; /* --denoise-progressive: progressive saves too
                                (the coordinator's; denoise is set with it) */
    float clamp_direct, clamp_indirect; /* sample clamping (pt_render_params); 0: off */
    uint32_t guiding;                   /* PT_GUIDING_*; off unless given */
    int bdpt; /* --bdpt[=auto|on|off]: PT_BDPT_* (bdpt_auto.h), auto unless given */
} pt_render_opts;

/* --guiding: off, on, or auto (pt_guide_enabled, guide.h, says where each
 * guides). The values are SUBMIT's (PROTO_GUIDING_*, protocol/msg.h). */
enum { PT_GUIDING_OFF = 0, PT_GUIDING_ON = 1, PT_GUIDING_AUTO = 2 };

/* The defaults above, nothing given. */
void pt_render_opts_init(pt_render_opts *o);

/* The getopt entries of the options in mask (PT_ROPT bits) appended at
 * out[0..], at most cap; returns how many (not NUL-terminated). */
size_t pt_render_longopts(uint32_t mask, struct option *out, size_t cap);

/* A program's getopt table into out: its own nown entries, then those of
 * mask, then the terminating entry. out holds nown + PT_ROPT_COUNT + 1. */
void pt_render_getopt_table(const struct option *own, size_t nown, uint32_t mask,
                            struct option *out);

/* The option whose getopt value is c (PT_ROPT_BASE + id) with its text
 * into o. PT_ERR_ARG naming the option and its limits when the value is
 * bad ("--spp: '0' is not a whole number in [1, 16777216]"). */
pt_status pt_render_opt_set(pt_render_opts *o, int c, const char *text, pt_error *err);

/* 1 when c is a value pt_render_opt_set takes. */
int pt_render_opt_is(int c);

/* The options that go together: --env and --background, --target-error
 * and --min-gain, --camera and a placement (which becomes o->camera).
 * PT_ERR_ARG saying what to give. */
pt_status pt_render_opts_finish(pt_render_opts *o, pt_error *err);

#endif
