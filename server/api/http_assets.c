#include "server/api/http_assets.h"

#include <string.h>

/* Generated from server/api/web/ (server/CMakeLists.txt). */
extern const char srv_web_index_html[], srv_web_job_html[], srv_web_workers_html[],
    srv_web_style_css[], srv_web_app_js[];
extern const size_t srv_web_index_html_len, srv_web_job_html_len, srv_web_workers_html_len,
    srv_web_style_css_len, srv_web_app_js_len;

#define HTML "text/html; charset=utf-8"

static const srv_http_asset assets[] = {
    {"/", HTML, srv_web_index_html, &srv_web_index_html_len, 0},
    {"/job", HTML, srv_web_job_html, &srv_web_job_html_len, 0},
    {"/workers", HTML, srv_web_workers_html, &srv_web_workers_html_len, 0},
    {"/style.css", "text/css; charset=utf-8", srv_web_style_css, &srv_web_style_css_len, 1},
    {"/app.js", "text/javascript; charset=utf-8", srv_web_app_js, &srv_web_app_js_len, 0},
};

const srv_http_asset *srv_http_asset_find(const char *path)
{
    for (size_t i = 0; i < sizeof assets / sizeof assets[0]; i++)
        if (strcmp(assets[i].path, path) == 0)
            return &assets[i];
    return NULL;
}

#define LOGIN(MSG)                                                                                 \
    "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>ptfarm: log "         \
    "in</title>\n<link rel=\"stylesheet\" "                                                        \
    "href=\"/style.css\"></head>\n<body><h1>ptfarm</h1>\n" MSG                                     \
    "<form method=\"post\" action=\"/login\"><label>token <input type=\"password\" "               \
    "name=\"token\" autofocus></label> <button>log in</button></form>\n</body></html>\n"

const char *srv_http_login_page(int failed)
{
    return failed ? LOGIN("<p class=\"err\">That token is not known here.</p>\n")
                  : LOGIN("<p>This coordinator needs a token (the shared one, or a client's "
                          "from --clients-file).</p>\n");
}
