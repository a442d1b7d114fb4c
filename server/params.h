/*
 * params.h - a job's render parameters: what ptserve's options (the one job,
 * the queue's defaults) and a client's SUBMIT set, what a job renders with
 * (server/sched/job.h) and what the state folder keeps of it.
 *
 * Under every layer of server/: it includes nothing of server/. Plain data
 * and its codec, which the job's checkpoint (server/sched/) and the state
 * folder's queue file (server/store/) both write: any thread may call them.
 */
#ifndef PT_SERVER_PARAMS_H
#define PT_SERVER_PARAMS_H

#include <stdint.h>

#include "protocol/msg.h"
#include "protocol/wire.h"

typedef struct srv_job_params {
    uint32_t width, height;
    uint32_t spp;
    uint32_t tile, chunk;
    uint32_t seed;
    uint32_t max_depth, rr_depth;
    double target_error;             /* adaptive sampling: 0 = off, else pt_tile_rel_error target */
    uint32_t min_spp;                /* adaptive sampling: no tile stops before this many samples */
    double min_gain;                 /* adaptive sampling: 0 = off, else pt_tile_gain threshold */
    char camera[PROTO_MAX_NAME + 1]; /* the camera's name; "" the scene's default view */
    proto_env env;       /* the environment light; its map is a file of the job's bundle */
    uint32_t film_flags; /* PROTO_FILM_* (transparent: the EXR gets A) */
    char variant[PROTO_MAX_NAME + 1]; /* KHR_materials_variants name; "" the default materials */
    double shutter[2]; /* motion blur's shutter, seconds after the frame's time (SHUTTER in
                          protocol/msg.h); 0, 0 off */
    float clamp[2];    /* sample clamping, direct and indirect (CLAMP in protocol/msg.h); 0 off */
    /* Path guiding, learned by the farm (server/sched/job.h): 1 when the job
     * is guided (--guiding on or auto, resolved against the scene: glossy
     * surfaces), with the bounds of its first, uniform distribution: the
     * scene's, grown as ptworker --guiding grows them. */
    uint32_t guiding;
    float guide_box[6]; /* lo x, y, z, hi x, y, z; zeros when not guided */
} srv_job_params;

/* The params block as the checkpoint and the state folder's queue file both
 * store it: nine u32 (width, height, spp, tile, chunk, seed, max depth, rr
 * depth, min spp), f64 target error, f64 min gain (in the formats that have
 * it; read as 0 from older ones), str camera, then (in the formats that have
 * them: no environment and no film flags from older ones) the environment: str
 * map name, f32 strength, f32 rotation, u8 background flag, f32 x3 colour; and
 * u32 film flags (an unknown bit is a format error), str material variant
 * (formats 4 on; "" from older ones), then f64 x2 motion blur's shutter (open,
 * close; refused unless proto_shutter_problem passes; formats 5 on, 0, 0 from
 * older ones), then f32 x2 sample clamping (direct, indirect; refused unless
 * proto_clamp_problem passes) and path guiding: u8 guided (0 or 1), f32 x6 its
 * first distribution's bounds (finite, ordered; zeros when not guided) (format
 * 9 brought both; off from older ones). srv_job_params_read reads a block with
 * or without the min gain, with or without both the environment and the film
 * flags (one format version brought both), with or without the shutter and
 * with or without the clamps and guiding, as its file's format version says; a
 * failure is left in r's status. */
void srv_job_params_write(proto_writer *w, const srv_job_params *p);
void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain, int has_env_film,
                         int has_shutter, int has_clamp_guide);

#endif
