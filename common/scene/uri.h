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
 * space in a path), is kept as it is.
 *
 * Both also apply one rule to the decoded name, pt_uri_path_refusal: a URI
 * names a file inside the scene's folder or nothing. The coordinator loads
 * scenes that clients send, so a name that leads out of the folder
 * ("../x", "/etc/passwd", "a/../../x", "%2e%2e/x") must never reach open().
 * Pure: any thread may call them.
 */
#ifndef PT_COMMON_SCENE_URI_H
#define PT_COMMON_SCENE_URI_H

#include <stddef.h>

/* Decodes the n bytes of uri into out, which has room for n bytes (decoding
 * never lengthens); returns the decoded length. The output may hold NUL
 * bytes (from "%00") and is not NUL-terminated: callers that need a C string
 * must refuse an embedded NUL. uri and out may not overlap. */
size_t pt_uri_decode(const char *uri, size_t n, char *out);

/* Why the n bytes of a decoded URI do not name a file below the scene's
 * folder, as a static phrase ("is an absolute path"), or NULL when they do.
 * Refused: an empty name, a NUL byte, a backslash (a separator elsewhere),
 * a leading '/', and any ".." component. "." and empty components are
 * harmless and allowed ("./a.png" is common). Symbolic links are not seen
 * here: the importer's reads refuse them (pt_read_file_beneath). */
const char *pt_uri_path_refusal(const char *name, size_t n);

/* The file a name that pt_uri_path_refusal allows stands for, written as
 * the bundle stores it: "." and empty components dropped, in place
 * ("./a.png" and "sub//b.bin" become "a.png" and "sub/b.bin"). Returns the
 * new length (at most n). Two URIs that name one file so get one bundle
 * entry, and the bundle's stricter name rule, which has no "." components,
 * holds for every scene the importer would load. */
size_t pt_uri_path_clean(char *name, size_t n);

#endif
