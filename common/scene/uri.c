#include "common/scene/uri.h"

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
