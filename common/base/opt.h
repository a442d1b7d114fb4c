/*
 * opt.h - the values of command-line options: whole numbers, real numbers,
 * seconds and WIDTHxHEIGHT, each checked against the caller's bounds.
 *
 * Every program's getopt loop (ptserve, ptworker, ptctl, the benchmarks)
 * reads its option values here, so "--spp 1e3", "--seed -1" or "--res 64x"
 * is refused the same way everywhere. Whole numbers are plain decimal
 * digits only (an optional '-' for signed ones): no sign '+', no leading
 * blanks, no hex. Real numbers are what strtod reads in full, finite, with
 * no overflow. On failure err says "OPT: 'TEXT' is not ..." naming the
 * option (opt, e.g. "--spp") and the bounds, ready for "prog: %s\n"; the
 * out-parameters are untouched. Pure functions: any thread may call them.
 */
#ifndef PT_COMMON_BASE_OPT_H
#define PT_COMMON_BASE_OPT_H

#include <stdint.h>

#include "common/base/error.h"

/* text as a whole number in [min, max] into *out. PT_ERR_ARG otherwise:
 * "OPT: 'TEXT' is not a whole number in [MIN, MAX]". */
pt_status pt_opt_u32(const char *opt, const char *text, uint32_t min, uint32_t max, uint32_t *out,
                     pt_error *err);

/* text as a whole number in [0, max] into *out. PT_ERR_ARG as pt_opt_u32. */
pt_status pt_opt_u64(const char *opt, const char *text, uint64_t max, uint64_t *out, pt_error *err);

/* text as a whole number, '-' allowed, in [min, max] into *out. PT_ERR_ARG as pt_opt_u32. */
pt_status pt_opt_i32(const char *opt, const char *text, int32_t min, int32_t max, int32_t *out,
                     pt_error *err);

/* text as a finite real number in [min, max] into *out. PT_ERR_ARG otherwise:
 * "is not a number in [MIN, MAX]", "is not a number >= MIN" when max is
 * DBL_MAX, "is not a finite number" when the range is all of them. */
pt_status pt_opt_double(const char *opt, const char *text, double min, double max, double *out,
                        pt_error *err);

/* text as a real number in (0, max] into *out. PT_ERR_ARG otherwise:
 * "is not a positive number" (", at most MAX" when max is below DBL_MAX). */
pt_status pt_opt_positive(const char *opt, const char *text, double max, double *out,
                          pt_error *err);

/* text as seconds (fractions allowed) in [min, max] into *out. PT_ERR_ARG
 * otherwise: "is not a number of seconds in [MIN, MAX]". */
pt_status pt_opt_seconds(const char *opt, const char *text, double min, double max, double *out,
                         pt_error *err);

/* text as WIDTHxHEIGHT, each a whole number in [1, max_side], into *w and *h
 * (both or neither). PT_ERR_ARG otherwise: "OPT: 'TEXT' is not WIDTHxHEIGHT",
 * or pt_opt_u32's message for "OPT width" or "OPT height". */
pt_status pt_opt_res(const char *opt, const char *text, uint32_t max_side, uint32_t *w, uint32_t *h,
                     pt_error *err);

/* text as R,G,B, three real numbers in [0, max], into out. PT_ERR_ARG
 * otherwise: "OPT: 'TEXT' is not R,G,B (three numbers in [0, MAX])". */
pt_status pt_opt_rgb(const char *opt, const char *text, double max, double out[3], pt_error *err);

/* text as X,Y,Z, three real numbers in [-max_abs, max_abs], into out.
 * PT_ERR_ARG otherwise: "OPT: 'TEXT' is not X,Y,Z (...)". */
pt_status pt_opt_point(const char *opt, const char *text, double max_abs, double out[3],
                       pt_error *err);

/* text as OPEN,CLOSE: a camera shutter, two fractions of a frame with
 * 0 <= OPEN <= CLOSE <= 1 (0,0.5 is a 180-degree shutter), into out[0] and
 * out[1]. PT_ERR_ARG otherwise: "OPT: 'TEXT' is not OPEN,CLOSE (...)" for
 * anything but two numbers, and naming the rule broken for a value outside
 * [0, 1] or OPEN after CLOSE. */
pt_status pt_opt_shutter(const char *opt, const char *text, double out[2], pt_error *err);

#endif
