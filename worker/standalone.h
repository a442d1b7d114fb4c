/*
 * standalone.h - `ptworker --scene`: render one image on this machine, no
 * coordinator. Tiles are handed to T render threads; each thread renders its
 * tile's sample chunks in order and adds them to the film in chunk order, the
 * same merge the coordinator does, so the image is bit-identical to a farm
 * render with the same seed, tile and chunk size.
 */
#ifndef PT_WORKER_STANDALONE_H
#define PT_WORKER_STANDALONE_H

#include <stdint.h>

#include "common/image/view.h"

typedef struct wrk_standalone_opts {
    const char *scene_path;
    const char *out_path; /* .exr; a .png preview is written beside it */
    const char *camera;   /* NULL: the scene's first camera */
    const char *variant;  /* KHR_materials_variants name; NULL: the default materials */
    /* glTF animation (pt_scene_opts): animate 0 renders the still of the
     * file; 1 poses it at time seconds, playing `animation` (NULL: all). */
    int animate;
    double time;
    const char *animation;
    uint32_t spp;
    uint32_t width, height; /* 0: from the camera's aspect, 512 wide */
    uint32_t seed;
    uint32_t threads; /* 0: all cores */
    uint32_t max_depth;
    uint32_t tile;        /* tile side in pixels */
    uint32_t chunk;       /* samples per chunk */
    double target_error;  /* adaptive sampling (0 = off): stop a tile at this error */
    double min_gain;      /* adaptive sampling (0 = off): pt_tile_stops' min_gain */
    uint32_t min_spp;     /* adaptive sampling: samples before a tile may stop */
    const char *env_path; /* environment map (.hdr, .exr) or NULL */
    float env_strength;   /* its factor (1 by default) */
    float env_rotate;     /* degrees about +Y */
    int has_background;   /* a uniform environment of background[] (not with env_path) */
    float background[3];
    int transparent;   /* escaped camera rays add nothing; the EXR gets A (coverage) */
    int has_shutter;   /* motion blur over [time + shutter[0] / fps, time + shutter[1] / fps] */
    double shutter[2]; /* fractions of a frame, 0 <= open <= close <= 1 (pt_opt_shutter) */
    double fps;        /* frames per second (24 by default; --fps) */
    pt_view view;      /* the PNG's exposure and view transform; the EXR stays linear */
    int guiding;       /* --guiding: PT_GUIDING_* (options.h); guided where pt_guide_enabled */
    int bdpt;          /* --bdpt: bidirectional path tracing (pt_render_params.bdpt) */
    float clamp_direct, clamp_indirect; /* sample clamping (pt_render_params; 0: off) */
    int denoise; /* --denoise: passes has PT_PASS_DENOISE; denoised.R/G/B added, PNG of it */
    uint64_t denoise_max; /* --max-denoise-mb: the denoiser's memory at most; 0: no limit */
    uint32_t passes;      /* PT_PASS_* render passes (passes.h) written as EXR layers; 0: none */
    int quiet;
} wrk_standalone_opts;

/* Renders and writes the image. Returns a process exit status (0 success). */
int wrk_standalone_run(const wrk_standalone_opts *o);

#endif
