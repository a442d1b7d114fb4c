#include "common/scene/uri.h"

#include <string.h>

#include "common/base/hash.h"

size_t pt_uri_decode(const char *uri, size_t n, char *out)
{
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {
        int hi = uri[i] == '%' && i + 2 < n ? pt_hex_digit(uri[i + 1]) : -1;
        int lo = hi >= 0 ? pt_hex_digit(uri[i + 2]) : -1;
        if (lo >= 0) {
            out[k++] = (char)(hi * 16 + lo);
            i += 2;
        } else {
            out[k++] = uri[i];
        }
    }
    return k;
}

const char *pt_uri_path_refusal(const char *name, size_t n)
{
    if (n == 0)
        return "is empty";
    if (name[0] == '/')
        return "is an absolute path";
    size_t start = 0;
    for (size_t i = 0; i <= n; i++) {
        if (i < n && name[i] == '\0')
            return "holds a NUL byte";
        if (i < n && name[i] == '\\')
            return "holds a backslash";
        if (i == n || name[i] == '/') {
            if (i - start == 2 && name[start] == '.' && name[start + 1] == '.')
                return "leads out of the scene's folder ('..')";
            start = i + 1;
        }
    }
    return NULL;
}

size_t pt_uri_path_clean(char *name, size_t n)
{
    size_t out = 0, start = 0;
    for (size_t i = 0; i <= n; i++) {
        if (i < n && name[i] != '/')
            continue;
        size_t len = i - start;
        if (len > 0 && !(len == 1 && name[start] == '.')) {
            if (out > 0)
                name[out++] = '/';
            memmove(name + out, name + start, len);
            out += len;
        }
        start = i + 1;
    }
    return out;
}
