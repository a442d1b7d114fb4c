#include "common/base/text.h"

#include <string.h>

/* The escaped form of byte c into piece (5 bytes); returns its length. */
static size_t escape_byte(unsigned char c, char piece[5])
{
    static const char hex[] = "0123456789abcdef";
    if (c == '\\') {
        piece[0] = piece[1] = '\\';
        return 2;
    }
    if (c >= 0x20 && c < 0x7f) {
        piece[0] = (char)c;
        return 1;
    }
    piece[0] = '\\';
    piece[1] = 'x';
    piece[2] = hex[c >> 4];
    piece[3] = hex[c & 15];
    return 4;
}

char *pt_text_escape(const char *in, size_t in_len, char *out, size_t cap)
{
    if (cap == 0)
        return out;
    char piece[5];
    size_t whole = 0;
    for (size_t i = 0; i < in_len; i++)
        whole += escape_byte((unsigned char)in[i], piece);
    /* Room for the text before the marker: all of it when it fits whole. */
    size_t marker = whole + 1 <= cap ? 0 : 3;
    size_t room = cap - 1 > marker ? cap - 1 - marker : 0;
    size_t n = 0;
    for (size_t i = 0; i < in_len; i++) {
        size_t k = escape_byte((unsigned char)in[i], piece);
        if (n + k > room)
            break;
        memcpy(out + n, piece, k);
        n += k;
    }
    for (size_t i = 0; i < marker && n + 1 < cap; i++)
        out[n++] = '.';
    out[n] = '\0';
    return out;
}

char *pt_text_shown(const char *s, char *out, size_t cap)
{
    return pt_text_escape(s, s ? strlen(s) : 0, out, cap);
}
