#include "common/base/opt.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Plain decimal digits, at least one: strtoull alone would take blanks, '+'
 * and a '-' that wraps the value around. */
static int all_digits(const char *s)
{
    if (!*s)
        return 0;
    for (; *s; s++)
        if (*s < '0' || *s > '9')
            return 0;
    return 1;
}

/* Digits as a number; 0 when they fit in 64 bits. */
static int read_u64(const char *s, uint64_t *out)
{
    if (!all_digits(s))
        return -1;
    errno = 0;
    unsigned long long v = strtoull(s, NULL, 10);
    if (errno)
        return -1;
    *out = v;
    return 0;
}

pt_status pt_opt_u32(const char *opt, const char *text, uint32_t min, uint32_t max, uint32_t *out,
                     pt_error *err)
{
    uint64_t v;
    if (read_u64(text, &v) != 0 || v < min || v > max)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a whole number in [%lu, %lu]", opt,
                            text, (unsigned long)min, (unsigned long)max);
    *out = (uint32_t)v;
    return PT_OK;
}

pt_status pt_opt_u64(const char *opt, const char *text, uint64_t max, uint64_t *out, pt_error *err)
{
    uint64_t v;
    if (read_u64(text, &v) != 0 || v > max)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a whole number in [0, %llu]", opt,
                            text, (unsigned long long)max);
    *out = v;
    return PT_OK;
}

pt_status pt_opt_i32(const char *opt, const char *text, int32_t min, int32_t max, int32_t *out,
                     pt_error *err)
{
    int neg = text[0] == '-';
    uint64_t m;
    /* The magnitude is read as unsigned: |INT32_MIN| fits, overflow cannot. */
    int ok = read_u64(text + neg, &m) == 0 && m <= (uint64_t)INT32_MAX + 1;
    int64_t v = ok ? (neg ? -(int64_t)m : (int64_t)m) : 0;
    if (!ok || v < min || v > max)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a whole number in [%ld, %ld]", opt,
                            text, (long)min, (long)max);
    *out = (int32_t)v;
    return PT_OK;
}

/* text read in full by strtod as a finite number; 0, or -1. */
static int read_double(const char *text, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(text, &end);
    if (errno || end == text || *end || !isfinite(v))
        return -1;
    *out = v;
    return 0;
}

pt_status pt_opt_double(const char *opt, const char *text, double min, double max, double *out,
                        pt_error *err)
{
    double v;
    if (read_double(text, &v) == 0 && v >= min && v <= max) {
        *out = v;
        return PT_OK;
    }
    if (min <= -DBL_MAX && max >= DBL_MAX)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a finite number", opt, text);
    if (max >= DBL_MAX)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a number >= %g", opt, text, min);
    return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a number in [%g, %g]", opt, text, min,
                        max);
}

pt_status pt_opt_positive(const char *opt, const char *text, double max, double *out, pt_error *err)
{
    double v;
    if (read_double(text, &v) == 0 && v > 0.0 && v <= max) {
        *out = v;
        return PT_OK;
    }
    if (max >= DBL_MAX)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a positive number", opt, text);
    return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a positive number, at most %g", opt, text,
                        max);
}

pt_status pt_opt_seconds(const char *opt, const char *text, double min, double max, double *out,
                         pt_error *err)
{
    double v;
    if (read_double(text, &v) != 0 || !(v >= min) || !(v <= max))
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a number of seconds in [%g, %g]", opt,
                            text, min, max);
    *out = v;
    return PT_OK;
}

pt_status pt_opt_res(const char *opt, const char *text, uint32_t max_side, uint32_t *w, uint32_t *h,
                     pt_error *err)
{
    char side[32], name[64];
    const char *x = strchr(text, 'x');
    if (!x || (size_t)(x - text) >= sizeof side)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not WIDTHxHEIGHT", opt, text);
    memcpy(side, text, (size_t)(x - text));
    side[x - text] = '\0';
    uint32_t vw, vh;
    snprintf(name, sizeof name, "%s width", opt);
    pt_status st = pt_opt_u32(name, side, 1, max_side, &vw, err);
    if (st != PT_OK)
        return st;
    snprintf(name, sizeof name, "%s height", opt);
    st = pt_opt_u32(name, x + 1, 1, max_side, &vh, err);
    if (st != PT_OK)
        return st;
    *w = vw;
    *h = vh;
    return PT_OK;
}

/* text as three comma-separated finite numbers, each in [lo, hi], into v;
 * 0, or -1 (v then partly written). */
static int read_triple(const char *text, double lo, double hi, double v[3])
{
    char part[64];
    const char *p = text;
    for (int k = 0; k < 3; k++) {
        const char *end = k < 2 ? strchr(p, ',') : p + strlen(p);
        size_t n = end ? (size_t)(end - p) : 0;
        if (!end || n == 0 || n >= sizeof part)
            return -1;
        memcpy(part, p, n);
        part[n] = '\0';
        if (read_double(part, &v[k]) != 0 || !(v[k] >= lo && v[k] <= hi))
            return -1;
        p = end + 1;
    }
    return 0;
}

pt_status pt_opt_rgb(const char *opt, const char *text, double max, double out[3], pt_error *err)
{
    double v[3];
    if (read_triple(text, 0.0, max, v) != 0)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not R,G,B (three numbers in [0, %g])",
                            opt, text, max);
    memcpy(out, v, sizeof v);
    return PT_OK;
}

pt_status pt_opt_shutter(const char *opt, const char *text, double out[2], pt_error *err)
{
    char part[64];
    const char *comma = strchr(text, ',');
    double v[2];
    if (!comma || strchr(comma + 1, ','))
        goto bad;
    size_t n = (size_t)(comma - text);
    if (n == 0 || n >= sizeof part)
        goto bad;
    memcpy(part, text, n);
    part[n] = '\0';
    if (read_double(part, &v[0]) != 0 || read_double(comma + 1, &v[1]) != 0)
        goto bad;
    if (!(v[0] >= 0.0 && v[0] <= 1.0 && v[1] >= 0.0 && v[1] <= 1.0))
        return pt_error_set(err, PT_ERR_ARG,
                            "%s: '%s': the shutter opens and closes within the frame: both "
                            "fractions must be in [0, 1]",
                            opt, text);
    if (v[0] > v[1])
        return pt_error_set(err, PT_ERR_ARG,
                            "%s: '%s': the shutter opens (%g) after it closes (%g)", opt, text,
                            v[0], v[1]);
    out[0] = v[0];
    out[1] = v[1];
    return PT_OK;
bad:
    return pt_error_set(err, PT_ERR_ARG,
                        "%s: '%s' is not OPEN,CLOSE (two fractions of a frame, e.g. 0,0.5)", opt,
                        text);
}

pt_status pt_opt_point(const char *opt, const char *text, double max_abs, double out[3],
                       pt_error *err)
{
    double v[3];
    if (read_triple(text, -max_abs, max_abs, v) != 0)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not X,Y,Z (three numbers in [-%g, %g])",
                            opt, text, max_abs, max_abs);
    memcpy(out, v, sizeof v);
    return PT_OK;
}
