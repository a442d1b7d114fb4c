/*
 * fuzz_manifest.c - libFuzzer target for the Cryptomatte manifest reader
 * (pt_crypto_manifest_find, common/render/crypto.c): a JSON object of
 * names and 8-hex-digit ids, as an EXR header's cryptomatte/<key>/manifest
 * attribute holds it.
 *
 * Input: 4 bytes of an id (little-endian), then the text (cut at the first
 * NUL and at 64 KiB). Invariants: the answer is -1, 0 or 1 and the same
 * twice; a name found is NUL-terminated within its buffer; nothing is left
 * allocated; a manifest pt_crypto_manifest writes of the names found reads
 * back and finds each. Seeds (corpus/fuzz_manifest/): the specification's
 * example, an empty object, escapes, and refusals, committed as written.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/crypto.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 4)
        return 0;
    uint32_t id = (uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 |
                  (uint32_t)data[3] << 24;
    size_t n = size - 4 < 65536 ? size - 4 : 65536;
    char *text = malloc(n + 1);
    if (!text)
        return 0;
    memcpy(text, data + 4, n);
    text[n] = '\0';
    int64_t live = pt_alloc_live();
    char name[64], again[64];
    memset(name, 0x55, sizeof name);
    int r = pt_crypto_manifest_find(text, id, name, sizeof name);
    FUZZ_CHECK(r == -1 || r == 0 || r == 1);
    FUZZ_CHECK(pt_crypto_manifest_find(text, id, again, sizeof again) == r);
    if (r == 1) {
        FUZZ_CHECK(memchr(name, 0, sizeof name) != NULL && strcmp(name, again) == 0);
        /* The name written into a manifest of our own is found by its id. */
        const char *names[1] = {name};
        char *m = NULL;
        FUZZ_CHECK(pt_crypto_manifest(names, 1, &m, NULL) == PT_OK);
        char back[64];
        FUZZ_CHECK(pt_crypto_manifest_find(m, pt_crypto_id(name), back, sizeof back) == 1 &&
                   strcmp(back, name) == 0);
        pt_free(m);
    }
    FUZZ_CHECK(pt_alloc_live() == live);
    free(text);
    return 0;
}
