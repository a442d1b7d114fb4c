#include "common/base/frames.h"

#include <stdio.h>
#include <string.h>

/* Plain decimal digits into *v, at most 9 of them; returns the characters
 * read (0: none or too many). */
static size_t digits(const char *s, uint32_t *v)
{
    size_t n = 0;
    uint32_t x = 0;
    while (s[n] >= '0' && s[n] <= '9') {
        if (n == 9)
            return 0;
        x = x * 10u + (uint32_t)(s[n] - '0');
        n++;
    }
    *v = x;
    return n;
}

pt_status pt_frames_check(const pt_frames *f, pt_error *err)
{
    if (f->step == 0) {
        if (f->first || f->last)
            return pt_error_set(err, PT_ERR_ARG, "frame range %u-%u has STEP 0", f->first, f->last);
        return PT_OK;
    }
    if (f->last < f->first)
        return pt_error_set(err, PT_ERR_ARG, "frame range %u-%u ends before it starts", f->first,
                            f->last);
    if (f->last > PT_FRAMES_MAX_NUMBER)
        return pt_error_set(err, PT_ERR_ARG, "frame %u is over the highest frame number, %u",
                            f->last, PT_FRAMES_MAX_NUMBER);
    if (pt_frames_count(f) > PT_FRAMES_MAX_COUNT)
        return pt_error_set(err, PT_ERR_ARG,
                            "frame range %u-%u:%u has %u frames, over the cap of %u", f->first,
                            f->last, f->step, pt_frames_count(f), PT_FRAMES_MAX_COUNT);
    return PT_OK;
}

pt_status pt_frames_parse(const char *opt, const char *text, pt_frames *out, pt_error *err)
{
    pt_frames f = {0, 0, 1};
    const char *p = text;
    size_t n = digits(p, &f.first);
    if (n == 0)
        goto bad;
    p += n;
    f.last = f.first;
    if (*p == '-') {
        p++;
        if ((n = digits(p, &f.last)) == 0)
            goto bad;
        p += n;
        if (*p == ':') {
            p++;
            if ((n = digits(p, &f.step)) == 0)
                goto bad;
            p += n;
        }
    }
    if (*p != '\0')
        goto bad;
    if (f.step == 0)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s' has STEP 0 (a step is at least 1)", opt,
                            text);
    pt_error e2 = {0};
    if (pt_frames_check(&f, &e2) != PT_OK)
        return pt_error_set(err, PT_ERR_ARG, "%s: '%s': %s", opt, text, e2.msg);
    *out = f;
    return PT_OK;
bad:
    return pt_error_set(err, PT_ERR_ARG,
                        "%s: '%s' is not a frame range A-B[:STEP] (whole numbers "
                        "in [0, %u])",
                        opt, text, PT_FRAMES_MAX_NUMBER);
}

uint32_t pt_frames_count(const pt_frames *f)
{
    if (f->step == 0 || f->last < f->first)
        return 0;
    return (f->last - f->first) / f->step + 1;
}

uint32_t pt_frames_number(const pt_frames *f, uint32_t i)
{
    return f->first + i * f->step;
}

int64_t pt_frames_index(const pt_frames *f, uint32_t number)
{
    if (f->step == 0 || number < f->first || number > f->last || (number - f->first) % f->step)
        return -1;
    return (int64_t)((number - f->first) / f->step);
}

double pt_frames_time(uint32_t number, double fps)
{
    return (double)number / fps;
}

int pt_frames_has_pattern(const char *pattern)
{
    return strchr(pattern, '#') != NULL;
}

pt_status pt_frames_name(const char *pattern, uint32_t number, char *out, size_t cap, pt_error *err)
{
    const char *end = strrchr(pattern, '#');
    if (!end)
        return pt_error_set(err, PT_ERR_ARG,
                            "output '%s' has no '#' for the frame number (e.g. shot.####.exr)",
                            pattern);
    const char *start = end;
    while (start > pattern && start[-1] == '#')
        start--;
    int width = (int)(end - start) + 1;
    int n =
        snprintf(out, cap, "%.*s%0*u%s", (int)(start - pattern), pattern, width, number, end + 1);
    if (n < 0 || (size_t)n >= cap)
        return pt_error_set(err, PT_ERR_LIMIT, "output '%s': the name of frame %u is too long",
                            pattern, number);
    return PT_OK;
}
