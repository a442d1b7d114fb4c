/*
 * crypto.h - Cryptomatte ids, names and layers (Psyop's Cryptomatte
 * specification 1.1.0, Friedman and Jones 2015).
 *
 * An id is MurmurHash3_x86_32 (Austin Appleby's public-domain hash; seed 0)
 * of a name: a glTF node's name for CryptoObject, a material's for
 * CryptoMaterial. A sample whose camera ray meets nothing has id 0, as the
 * specification asks. Pixels store ids as floats: the hash's bits with the
 * exponent clamped to [1, 254], so no id is a NaN, an infinity or a
 * denormal (pt_crypto_float). Each kind is written as layers {type}00,
 * {type}01, ... of R = id of rank 2k, G = its coverage, B = id of rank
 * 2k + 1, A = its coverage, the ranks by coverage (ties by the smaller id),
 * and described in the header by cryptomatte/<key>/name, hash, conversion
 * and manifest (a JSON object of name: 8 hex digits of the float's bits),
 * key the first 7 hex digits of the type name's hash.
 *
 * Coverage is counted per id in whole samples (tile.h: PT_CRYPTO_KEEP ids a
 * pixel, merged exactly in any order) and resolved as count / n.
 * Pure functions; any thread may call them.
 */
#ifndef PT_COMMON_RENDER_CRYPTO_H
#define PT_COMMON_RENDER_CRYPTO_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/render/tile.h"
#include "common/scene/scene.h"

/* The layers written per kind: PT_CRYPTO_KEEP ranks, two a layer. */
#define PT_CRYPTO_LAYERS (PT_CRYPTO_KEEP / 2)

/* MurmurHash3_x86_32 of len bytes at key with seed. */
uint32_t pt_murmur3_32(const void *key, size_t len, uint32_t seed);

/* The id of a name: pt_murmur3_32 of its bytes (no NUL), seed 0. */
uint32_t pt_crypto_id(const char *name);

/* An id as the float the pixels hold (the specification's uint32_to_float32). */
float pt_crypto_float(uint32_t id);

/* The type names of the kinds ("CryptoObject", "CryptoMaterial"). */
const char *pt_crypto_type(int kind);

/* The kind's metadata key: the first 7 hex digits of its type name's id. */
void pt_crypto_key(int kind, char out[8]);

/* The image planes of one kind's layers, resolved by pt_crypto_resolve. */
typedef struct pt_crypto_planes {
    float *ch[PT_CRYPTO_KINDS][PT_CRYPTO_LAYERS][4]; /* {type}NN.R, .G, .B, .A */
} pt_crypto_planes;

/* Adds both kinds' layers to img (zeroed) and points *pl at them. */
pt_status pt_crypto_add_planes(pt_image *img, pt_crypto_planes *pl, pt_error *err);

/* Pixel i's ranks from its pass sums over n samples into pl. */
void pt_crypto_resolve(const pt_pass_acc *p, uint32_t n, const pt_crypto_planes *pl, size_t i);

/* The manifest of names[0..count) (each NUL-terminated; duplicates once):
 * {"name":"hex",...}, names escaped as JSON strings. *out is pt_malloc'd. */
pt_status pt_crypto_manifest(const char *const *names, uint32_t count, char **out, pt_error *err);

/* Parses a manifest back into its name of id (the first match) into name
 * (n bytes): 1 when found, 0 when not, -1 when the text is not a manifest
 * (flat JSON object of string values of 8 hex digits). */
int pt_crypto_manifest_find(const char *manifest, uint32_t id, char *name, size_t n);

/* The header attributes of both kinds for a scene: cryptomatte/<key>/name,
 * hash ("MurmurHash3_32"), conversion ("uint32_to_float32") and manifest
 * (its objects' names, its materials'), for pt_exr_meta.attrs. */
typedef struct pt_crypto_meta {
    char key[PT_CRYPTO_KINDS][4][40];
    char *manifest[PT_CRYPTO_KINDS];
    pt_exr_attr attrs[PT_CRYPTO_KINDS * 4];
    uint32_t nattrs;
} pt_crypto_meta;
pt_status pt_crypto_meta_init(pt_crypto_meta *m, const pt_scene *s, pt_error *err);
/* Both manifests as one text, objects' then materials', a line each (a
 * manifest has no raw newline): *out pt_malloc'd. */
pt_status pt_crypto_meta_text(const pt_crypto_meta *m, char **out, pt_error *err);
/* The attributes of such a text; PT_ERR_FORMAT when it is not two
 * manifests. */
pt_status pt_crypto_meta_from_text(pt_crypto_meta *m, const char *text, pt_error *err);
void pt_crypto_meta_fini(pt_crypto_meta *m);

#endif
