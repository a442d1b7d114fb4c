/*
 * uri.h - the percent-decoding of the relative URIs a glTF names its
 * buffers and images by (glTF 2.0, 3.6.1 and 3.8.3; RFC 3986, 2.1).
 *
 * Two readers turn a URI into a file name: the bundle packer
 * (pt_gltf_dependencies, gltf_deps.cpp) chooses which files travel with a
 * scene, and the importer (gltf_import.cpp) opens them and hashes them. If
 * they decoded differently, a bundle would carry other files than those the
 * importer opens, so both call this one function. The rule: "%XY" with two
 * hex digits (either case) is the byte 0xXY, "%00" included; a '%' not
 * followed by two hex digits, and every other byte ('+' too: it is not a
 * space in a path), is kept as it is. Pure: any thread may call it.
 */
#ifndef PT_COMMON_SCENE_URI_H
#define PT_COMMON_SCENE_URI_H

#include <stddef.h>

/* Decodes the n bytes of uri into out, which has room for n bytes (decoding
 * never lengthens); returns the decoded length. The output may hold NUL
 * bytes (from "%00") and is not NUL-terminated: callers that need a C string
 * must refuse an embedded NUL. uri and out may not overlap. */
size_t pt_uri_decode(const char *uri, size_t n, char *out);

#endif
