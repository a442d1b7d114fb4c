/*
 * jobjson.h - a job (proto_job_info) as JSON: the one formatter behind
 * `ptctl status --json` / `ptctl list --json` and ptserve's HTTP API
 * (/api/jobs, server/api/http.h), so a script reads the same fields from both.
 *
 * Strings from peers are never trusted: they are escaped and bytes that are
 * not well-formed UTF-8 become U+FFFD. Numbers JSON cannot carry (NaN,
 * infinities) are written as null.
 * Threads: pure functions over their arguments; any thread may call them.
 */
#ifndef PT_PROTOCOL_JOBJSON_H
#define PT_PROTOCOL_JOBJSON_H

#include <stdio.h>

#include "protocol/msg.h"

/* Fraction of the job done, 0..1 (1 once DONE; adaptive jobs end early). */
double proto_job_fraction(const proto_job_info *j);

/* s as a JSON string, quotes included: '"', '\\' and control characters
 * escaped, bytes that are not well-formed UTF-8 replaced by U+FFFD. */
void proto_json_string(FILE *f, const char *s);

/* A JSON number (the shortest of 15 or 17 significant digits that reads
 * back as v), or null when v is not finite. */
void proto_json_double(FILE *f, double v);

/* One job as a JSON object (no trailing newline). */
void proto_json_job(FILE *f, const proto_job_info *j);

#endif
