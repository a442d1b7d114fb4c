/*
 * params.h - a job's render parameters: what ptserve's options (the one job,
 * the queue's defaults) and a client's SUBMIT set, what a job renders with
 * (server/sched/job.h) and what the state folder keeps of it.
 *
 * Under every layer of server/: it includes nothing of server/. Plain data:
 * any thread may read it.
 */
#ifndef PT_SERVER_PARAMS_H
#define PT_SERVER_PARAMS_H

#include <stdint.h>

#include "protocol/msg.h"

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
} srv_job_params;

#endif
