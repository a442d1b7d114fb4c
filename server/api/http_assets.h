/*
 * http_assets.h - the dashboard's pages, style and script, compiled in.
 *
 * A fixed table from URL path to bytes: no request path ever reaches the
 * file system. The sources are server/api/web/ (plain HTML, CSS and JS, no
 * build step and nothing fetched from elsewhere); CMake turns each into a
 * C string at build time (server/CMakeLists.txt).
 * Threads: read-only data; any thread.
 */
#ifndef PT_SERVER_HTTP_ASSETS_H
#define PT_SERVER_HTTP_ASSETS_H

#include <stddef.h>

typedef struct srv_http_asset {
    const char *path; /* "/", "/job", "/app.js", ... */
    const char *type; /* its Content-Type */
    const char *data;
    const size_t *len; /* its size in bytes (the data has a NUL after) */
    int is_public;     /* served without a token (what the login page needs) */
} srv_http_asset;

/* The asset at exactly path, NULL when none. */
const srv_http_asset *srv_http_asset_find(const char *path);

/* The login form; failed: says the last token was wrong. */
const char *srv_http_login_page(int failed);

#endif
