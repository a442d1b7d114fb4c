/*
 * frames.h - frame ranges and the file names of their frames.
 *
 * A range is "A-B" or "A-B:STEP" (or a single "A"): the frames A, A+STEP,
 * ... up to B (B itself only when STEP reaches it), numbers in
 * [0, PT_FRAMES_MAX_NUMBER], at most PT_FRAMES_MAX_COUNT frames. Frame F is
 * posed at F / fps seconds of the scene's animation (glTF time 0 is frame 0),
 * the one definition the farm and a standalone --frame render share, so the
 * two give the same bits.
 *
 * A frame's file name comes from a pattern whose last run of '#' is
 * replaced by the frame number, zero-padded to the run's length
 * ("shot.####.exr", frame 7: "shot.0007.exr"; a number wider than the run is
 * written whole). A multi-frame job needs a '#' in its output name: without
 * one every frame would overwrite the last, so it is refused.
 *
 * Pure functions: any thread may call them.
 */
#ifndef PT_COMMON_BASE_FRAMES_H
#define PT_COMMON_BASE_FRAMES_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#define PT_FRAMES_MAX_NUMBER 999999u /* the highest frame number */
#define PT_FRAMES_MAX_COUNT 100000u  /* frames in one range */
#define PT_FRAMES_DEFAULT_FPS 24.0
/* The frame rates every program accepts (ptworker, ptserve and ptctl --fps,
 * and a SUBMIT's): at the slowest, frame PT_FRAMES_MAX_NUMBER is at 1e9 s,
 * a finite time that every TASK can carry. */
#define PT_FRAMES_MIN_FPS 1e-3
#define PT_FRAMES_MAX_FPS 1e6

/* A range; step 0: none (a still). */
typedef struct pt_frames {
    uint32_t first, last, step;
} pt_frames;

/* text ("A-B[:STEP]" or "A") into *out. PT_ERR_ARG with the reason
 * ("--frames: '9-3' ends before it starts", "STEP 0", "over 100000 frames",
 * ...); *out untouched on failure. opt names the option in the message. */
pt_status pt_frames_parse(const char *opt, const char *text, pt_frames *out, pt_error *err);

/* PT_OK when f is a range pt_frames_parse could have made, or none (all
 * zero); PT_ERR_ARG naming what is wrong otherwise (for ranges off the wire). */
pt_status pt_frames_check(const pt_frames *f, pt_error *err);

/* Frames in f (0 for none). */
uint32_t pt_frames_count(const pt_frames *f);

/* The number of the i-th frame of f (i < pt_frames_count). */
uint32_t pt_frames_number(const pt_frames *f, uint32_t i);

/* The index of frame number in f, or -1 when f does not render it. */
int64_t pt_frames_index(const pt_frames *f, uint32_t number);

/* Seconds into the animation of frame number at fps frames per second. */
double pt_frames_time(uint32_t number, double fps);

/* 1 when pattern has a '#'. */
int pt_frames_has_pattern(const char *pattern);

/* pattern with its last run of '#' replaced by number (see above) into out.
 * PT_ERR_ARG when pattern has no '#', PT_ERR_LIMIT when out is too small. */
pt_status pt_frames_name(const char *pattern, uint32_t number, char *out, size_t cap,
                         pt_error *err);

#endif
