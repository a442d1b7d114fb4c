#include "common/render/crypto.h"

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"

static uint32_t rotl32(uint32_t x, int r)
{
    return (x << r) | (x >> (32 - r));
}

/* MurmurHash3_x86_32 (Appleby, 2011, public domain): 4-byte blocks read
 * little-endian, mixed with c1, c2 and rotations; the tail likewise; then
 * the length and the 32-bit finaliser (fmix32). */
uint32_t pt_murmur3_32(const void *key, size_t len, uint32_t seed)
{
    const uint8_t *p = key;
    const uint32_t c1 = 0xcc9e2d51u, c2 = 0x1b873593u;
    uint32_t h = seed;
    size_t nblocks = len / 4;
    for (size_t i = 0; i < nblocks; i++) {
        const uint8_t *b = p + 4 * i;
        uint32_t k =
            (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
        k *= c1;
        k = rotl32(k, 15);
        k *= c2;
        h ^= k;
        h = rotl32(h, 13);
        h = h * 5u + 0xe6546b64u;
    }
    const uint8_t *tail = p + 4 * nblocks;
    uint32_t k = 0;
    switch (len & 3u) {
    case 3:
        k ^= (uint32_t)tail[2] << 16;
        /* fall through */
    case 2:
        k ^= (uint32_t)tail[1] << 8;
        /* fall through */
    case 1:
        k ^= tail[0];
        k *= c1;
        k = rotl32(k, 15);
        k *= c2;
        h ^= k;
    }
    h ^= (uint32_t)len;
    h ^= h >> 16;
    h *= 0x85ebca6bu;
    h ^= h >> 13;
    h *= 0xc2b2ae35u;
    h ^= h >> 16;
    return h;
}

uint32_t pt_crypto_id(const char *name)
{
    return pt_murmur3_32(name, strlen(name), 0);
}

/* The float's bits: the id's with the exponent clamped to [1, 254]. */
static uint32_t float_bits(uint32_t id)
{
    uint32_t e = (id >> 23) & 0xffu;
    e = e < 1 ? 1 : e > 254 ? 254 : e;
    return (id & 0x807fffffu) | e << 23;
}

float pt_crypto_float(uint32_t id)
{
    uint32_t b = float_bits(id);
    float f;
    memcpy(&f, &b, sizeof f);
    return f;
}

const char *pt_crypto_type(int kind)
{
    return kind == PT_CRYPTO_OBJECT ? "CryptoObject" : "CryptoMaterial";
}

void pt_crypto_key(int kind, char out[8])
{
    char hex[9];
    snprintf(hex, sizeof hex, "%08x", (unsigned)pt_crypto_id(pt_crypto_type(kind)));
    memcpy(out, hex, 7);
    out[7] = '\0';
}

pt_status pt_crypto_add_planes(pt_image *img, pt_crypto_planes *pl, pt_error *err)
{
    static const char *const rgba[4] = {"R", "G", "B", "A"};
    char name[PT_IMAGE_PLANE_NAME];
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        for (int l = 0; l < PT_CRYPTO_LAYERS; l++)
            for (int c = 0; c < 4; c++) {
                snprintf(name, sizeof name, "%s%02d.%s", pt_crypto_type(k), l, rgba[c]);
                pt_status st = pt_image_add_plane(img, name, &pl->ch[k][l][c], err);
                if (st != PT_OK)
                    return st;
            }
    return PT_OK;
}

void pt_crypto_resolve(const pt_pass_acc *p, uint32_t n, const pt_crypto_planes *pl, size_t i)
{
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        /* Rank by count, the larger first, ties by the smaller id (the list
         * is in ascending ids, so a stable insertion sort keeps that). */
        int order[PT_CRYPTO_KEEP], m = 0;
        for (int j = 0; j < PT_CRYPTO_KEEP && p->ccnt[k][j]; j++) {
            int at = m++;
            while (at > 0 && p->ccnt[k][order[at - 1]] < p->ccnt[k][j]) {
                order[at] = order[at - 1];
                at--;
            }
            order[at] = j;
        }
        for (int r = 0; r < PT_CRYPTO_KEEP; r++) {
            float id = 0.0f, cov = 0.0f;
            if (r < m && n > 0) {
                id = pt_crypto_float(p->cid[k][order[r]]);
                cov = (float)((double)p->ccnt[k][order[r]] / n);
            }
            pl->ch[k][r / 2][2 * (r % 2)][i] = id;
            pl->ch[k][r / 2][2 * (r % 2) + 1][i] = cov;
        }
    }
}

/* Appends s to b (a pt_malloc'd buffer of *cap, *len used); 0 on no memory. */
static int put(char **b, size_t *len, size_t *cap, const char *s, size_t n)
{
    if (*len + n + 1 > *cap) {
        size_t c = *cap ? *cap : 256;
        while (c < *len + n + 1)
            c *= 2;
        char *nb = pt_malloc(c);
        if (!nb)
            return 0;
        if (*b)
            memcpy(nb, *b, *len);
        pt_free(*b);
        *b = nb;
        *cap = c;
    }
    memcpy(*b + *len, s, n);
    *len += n;
    (*b)[*len] = '\0';
    return 1;
}

pt_status pt_crypto_manifest(const char *const *names, uint32_t count, char **out, pt_error *err)
{
    char *b = NULL;
    size_t len = 0, cap = 0;
    int ok = put(&b, &len, &cap, "{", 1);
    int first = 1;
    for (uint32_t i = 0; ok && i < count; i++) {
        int dup = 0;
        for (uint32_t j = 0; j < i && !dup; j++)
            dup = !strcmp(names[i], names[j]);
        if (dup)
            continue;
        ok = put(&b, &len, &cap, first ? "\"" : ",\"", first ? 1 : 2);
        first = 0;
        /* A JSON string: quote and backslash escaped, control bytes as \u00XX. */
        for (const unsigned char *c = (const unsigned char *)names[i]; ok && *c; c++) {
            char e[8];
            if (*c == '"' || *c == '\\')
                snprintf(e, sizeof e, "\\%c", *c);
            else if (*c < 0x20)
                snprintf(e, sizeof e, "\\u%04x", *c);
            else
                snprintf(e, sizeof e, "%c", *c);
            ok = put(&b, &len, &cap, e, strlen(e));
        }
        char hex[16];
        snprintf(hex, sizeof hex, "\":\"%08x\"", (unsigned)float_bits(pt_crypto_id(names[i])));
        ok = ok && put(&b, &len, &cap, hex, strlen(hex));
    }
    ok = ok && put(&b, &len, &cap, "}", 1);
    if (!ok) {
        pt_free(b);
        return pt_error_set(err, PT_ERR_NOMEM, "Cryptomatte manifest: out of memory");
    }
    *out = b;
    return PT_OK;
}

/* A JSON string at *p (after its opening quote) into out (n bytes, cut);
 * *p past the closing quote. 0 when malformed. */
static int json_string(const char **p, char *out, size_t n)
{
    size_t k = 0;
    for (const char *s = *p; *s; s++) {
        char c = *s;
        if (c == '"') {
            if (n)
                out[k < n ? k : n - 1] = '\0';
            *p = s + 1;
            return 1;
        }
        if (c == '\\') {
            s++;
            if (*s == 'u') {
                unsigned v = 0;
                for (int d = 1; d <= 4; d++) {
                    char h = s[d];
                    if (!((h >= '0' && h <= '9') || (h >= 'a' && h <= 'f') ||
                          (h >= 'A' && h <= 'F')))
                        return 0;
                    v = v * 16 + (unsigned)(h <= '9' ? h - '0' : (h | 0x20) - 'a' + 10);
                }
                c = (char)(v < 0x80 ? v : '?');
                s += 4;
            } else if (*s == '"' || *s == '\\' || *s == '/') {
                c = *s;
            } else if (*s == 'n') {
                c = '\n';
            } else if (*s == 't') {
                c = '\t';
            } else {
                return 0;
            }
        }
        if (k + 1 < n)
            out[k] = c;
        k++;
    }
    return 0;
}

static const char *skip_ws(const char *p)
{
    while (*p == ' ' || *p == '\n' || *p == '\t' || *p == '\r')
        p++;
    return p;
}

int pt_crypto_manifest_find(const char *manifest, uint32_t id, char *name, size_t n)
{
    char key[256], val[32];
    const char *p = skip_ws(manifest);
    if (*p++ != '{')
        return -1;
    p = skip_ws(p);
    if (*p == '}')
        return 0;
    int found = 0;
    for (;;) {
        if (*p++ != '"' || !json_string(&p, key, sizeof key))
            return -1;
        p = skip_ws(p);
        if (*p++ != ':')
            return -1;
        p = skip_ws(p);
        if (*p++ != '"' || !json_string(&p, val, sizeof val) || strlen(val) != 8)
            return -1;
        unsigned v = 0;
        if (sscanf(val, "%8x", &v) != 1)
            return -1;
        if (!found && v == float_bits(id)) {
            snprintf(name, n, "%s", key);
            found = 1;
        }
        p = skip_ws(p);
        if (*p == '}')
            return found;
        if (*p++ != ',')
            return -1;
        p = skip_ws(p);
    }
}

/* The attributes of m's manifests (set). */
static void meta_attrs(pt_crypto_meta *m)
{
    static const char *const what[4] = {"name", "hash", "conversion", "manifest"};
    m->nattrs = 0;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        char key[8];
        pt_crypto_key(k, key);
        const char *value[4] = {pt_crypto_type(k), "MurmurHash3_32", "uint32_to_float32",
                                m->manifest[k]};
        for (int a = 0; a < 4; a++) {
            snprintf(m->key[k][a], sizeof m->key[k][a], "cryptomatte/%s/%s", key, what[a]);
            m->attrs[m->nattrs++] = (pt_exr_attr){m->key[k][a], value[a]};
        }
    }
}

pt_status pt_crypto_meta_text(const pt_crypto_meta *m, char **out, pt_error *err)
{
    size_t a = strlen(m->manifest[0]), b = strlen(m->manifest[1]);
    char *t = pt_malloc(a + b + 2);
    if (!t)
        return pt_error_set(err, PT_ERR_NOMEM, "Cryptomatte manifests: out of memory");
    memcpy(t, m->manifest[0], a);
    t[a] = '\n';
    memcpy(t + a + 1, m->manifest[1], b + 1);
    *out = t;
    return PT_OK;
}

pt_status pt_crypto_meta_from_text(pt_crypto_meta *m, const char *text, pt_error *err)
{
    memset(m, 0, sizeof *m);
    const char *nl = strchr(text, '\n');
    if (!nl || strchr(nl + 1, '\n'))
        return pt_error_set(err, PT_ERR_FORMAT, "Cryptomatte manifests: not two lines");
    size_t a = (size_t)(nl - text), b = strlen(nl + 1);
    m->manifest[0] = pt_malloc(a + 1);
    m->manifest[1] = pt_malloc(b + 1);
    if (!m->manifest[0] || !m->manifest[1]) {
        pt_crypto_meta_fini(m);
        return pt_error_set(err, PT_ERR_NOMEM, "Cryptomatte manifests: out of memory");
    }
    memcpy(m->manifest[0], text, a);
    m->manifest[0][a] = '\0';
    memcpy(m->manifest[1], nl + 1, b + 1);
    char name[8];
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        if (pt_crypto_manifest_find(m->manifest[k], 0, name, sizeof name) < 0) {
            pt_crypto_meta_fini(m);
            return pt_error_set(err, PT_ERR_FORMAT, "Cryptomatte manifests: line %d is not one",
                                k + 1);
        }
    meta_attrs(m);
    return PT_OK;
}

pt_status pt_crypto_meta_init(pt_crypto_meta *m, const pt_scene *s, pt_error *err)
{
    memset(m, 0, sizeof *m);
    uint32_t most = s->num_objects > s->num_materials ? s->num_objects : s->num_materials;
    const char **names = pt_malloc_array(most ? most : 1, sizeof *names);
    if (!names)
        return pt_error_set(err, PT_ERR_NOMEM, "Cryptomatte manifest: out of memory");
    pt_status st = PT_OK;
    for (int k = 0; k < PT_CRYPTO_KINDS && st == PT_OK; k++) {
        uint32_t n = k == PT_CRYPTO_OBJECT ? s->num_objects : s->num_materials;
        for (uint32_t i = 0; i < n; i++)
            names[i] = k == PT_CRYPTO_OBJECT ? s->object_names[i].s : s->materials[i].name;
        if ((st = pt_crypto_manifest(names, n, &m->manifest[k], err)) != PT_OK)
            break;
    }
    pt_free(names);
    if (st != PT_OK)
        pt_crypto_meta_fini(m);
    else
        meta_attrs(m);
    return st;
}

void pt_crypto_meta_fini(pt_crypto_meta *m)
{
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        pt_free(m->manifest[k]);
        m->manifest[k] = NULL;
    }
    m->nattrs = 0;
}
