/*
 * jobjson.c - a job's JSON object, shared by ptctl (--json) and ptserve's
 * HTTP API (server/api/http.h) so that both print the same fields.
 */
#include "protocol/jobjson.h"

#include <math.h>
#include <stdlib.h>

double proto_job_fraction(const proto_job_info *j)
{
    if (j->state == PROTO_JOB_DONE)
        return 1.0;
    if (j->samples_total == 0)
        return 0.0;
    double f = (double)j->samples_done / (double)j->samples_total;
    return f < 0.0 ? 0.0 : f > 1.0 ? 1.0 : f;
}

/* Length of the well-formed UTF-8 sequence at s (1..4), or 0 when the bytes
 * there are not one (RFC 3629: no overlong forms, surrogates or values past
 * U+10FFFF). s is NUL-terminated, so a cut sequence stops at the NUL. */
static size_t utf8_len(const unsigned char *s)
{
    unsigned char c = s[0];
    if (c < 0x80)
        return 1;
    size_t n;
    unsigned lo = 0x80, hi = 0xBF; /* range of the second byte */
    if (c >= 0xC2 && c <= 0xDF)
        n = 2;
    else if (c >= 0xE0 && c <= 0xEF) {
        n = 3;
        if (c == 0xE0)
            lo = 0xA0;
        else if (c == 0xED)
            hi = 0x9F;
    } else if (c >= 0xF0 && c <= 0xF4) {
        n = 4;
        if (c == 0xF0)
            lo = 0x90;
        else if (c == 0xF4)
            hi = 0x8F;
    } else
        return 0;
    if (s[1] < lo || s[1] > hi)
        return 0;
    for (size_t i = 2; i < n; i++)
        if (s[i] < 0x80 || s[i] > 0xBF)
            return 0;
    return n;
}

void proto_json_string(FILE *f, const char *s)
{
    const unsigned char *p = (const unsigned char *)s;
    fputc('"', f);
    while (*p) {
        unsigned char c = *p;
        if (c == '"' || c == '\\') {
            fputc('\\', f);
            fputc(c, f);
            p++;
        } else if (c < 0x20) {
            switch (c) {
            case '\n':
                fputs("\\n", f);
                break;
            case '\r':
                fputs("\\r", f);
                break;
            case '\t':
                fputs("\\t", f);
                break;
            case '\b':
                fputs("\\b", f);
                break;
            case '\f':
                fputs("\\f", f);
                break;
            default:
                fprintf(f, "\\u%04x", c);
            }
            p++;
        } else {
            size_t n = utf8_len(p);
            if (n == 0) {
                fputs("\\ufffd", f);
                p++;
            } else {
                fwrite(p, 1, n, f);
                p += n;
            }
        }
    }
    fputc('"', f);
}

/* A JSON number, or null for what JSON cannot carry (NaN, infinities): the
 * shortest of 15 or 17 significant digits that reads back as the same double. */
void proto_json_double(FILE *f, double v)
{
    if (!isfinite(v)) {
        fputs("null", f);
        return;
    }
    char buf[40];
    snprintf(buf, sizeof buf, "%.15g", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, sizeof buf, "%.17g", v);
    fputs(buf, f);
}

void proto_json_job(FILE *f, const proto_job_info *j)
{
    fprintf(f, "{\"id\": %llu, \"state\": ", (unsigned long long)j->job_id);
    proto_json_string(f, proto_job_state_name(j->state));
    fprintf(f, ", \"state_code\": %u, \"priority\": %ld, \"name\": ", (unsigned)j->state,
            (long)j->priority);
    proto_json_string(f, j->name);
    fputs(", \"owner\": ", f);
    proto_json_string(f, j->owner);
    fputs(", \"scene\": ", f);
    proto_json_string(f, j->scene);
    fputs(", \"output\": ", f);
    proto_json_string(f, j->output);
    fprintf(f,
            ", \"width\": %lu, \"height\": %lu, \"spp\": %lu, \"samples_done\": %llu, "
            "\"samples_total\": %llu, \"progress\": ",
            (unsigned long)j->width, (unsigned long)j->height, (unsigned long)j->spp,
            (unsigned long long)j->samples_done, (unsigned long long)j->samples_total);
    proto_json_double(f, proto_job_fraction(j));
    fprintf(f,
            ", \"passes_done\": %lu, \"passes\": %lu, \"tiles_stopped\": %lu, \"tiles\": %lu, "
            "\"workers\": %lu, \"seconds\": ",
            (unsigned long)j->passes_done, (unsigned long)j->passes,
            (unsigned long)j->tiles_stopped, (unsigned long)j->tiles, (unsigned long)j->workers);
    proto_json_double(f, j->seconds);
    fputs(", \"samples_per_second\": ", f);
    proto_json_double(f, j->rate);
    fputs(", \"error\": ", f);
    if (j->error >= 0.0)
        proto_json_double(f, j->error);
    else
        fputs("null", f);
    fprintf(f,
            ", \"paths_capped\": %llu, \"contributions_clamped\": %llu, \"samples_rejected\": "
            "%llu, \"submitted\": %llu, \"queue_position\": %lu, \"guiding\": ",
            (unsigned long long)j->capped, (unsigned long long)j->clamped,
            (unsigned long long)j->rejected, (unsigned long long)j->submitted,
            (unsigned long)j->queue_pos);
    if (j->guided)
        fprintf(f, "{\"pass\": %lu, \"learned_spp\": %lu}", (unsigned long)j->guide_pass,
                (unsigned long)j->guide_spp);
    else
        fputs("null", f);
    fprintf(f, ", \"integrator\": \"%s\"", j->bdpt ? "bidirectional" : "path");
    fputs(", \"message\": ", f);
    proto_json_string(f, j->message);
    if (j->frame_step) {
        /* A frame-range job: its range, and its frames rendering. */
        fprintf(f,
                ", \"frame_range\": {\"first\": %lu, \"last\": %lu, \"step\": %lu}, "
                "\"frames_done\": %lu, \"frames_rendering\": %lu, \"frames\": [",
                (unsigned long)j->frame_first, (unsigned long)j->frame_last,
                (unsigned long)j->frame_step, (unsigned long)j->frames_done,
                (unsigned long)j->frames_rendering);
        for (uint32_t i = 0; i < j->nshown && i < PROTO_MAX_FRAMES_SHOWN; i++) {
            double total = (double)j->shown[i].samples_total;
            fprintf(f,
                    "%s{\"frame\": %lu, \"samples_done\": %llu, \"samples_total\": %llu, "
                    "\"progress\": ",
                    i ? ", " : "", (unsigned long)j->shown[i].frame,
                    (unsigned long long)j->shown[i].samples_done,
                    (unsigned long long)j->shown[i].samples_total);
            proto_json_double(f, total > 0 ? (double)j->shown[i].samples_done / total : 0.0);
            fputc('}', f);
        }
        fputc(']', f);
    }
    fputc('}', f);
}
