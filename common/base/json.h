/*
 * json.h - a bound on JSON nesting, checked before any parser sees the text.
 *
 * The JSON parsers the project uses build their values recursively: tinygltf
 * converts nlohmann's document into its own Value tree one call per level
 * (and frees it the same way), so a 60 KB glTF whose "extras" nest 30,000
 * deep overflows the stack of whatever thread loads it. pt_json_depth scans
 * the text once, in linear time and constant space, counting the open
 * objects and arrays outside strings, and stops at the first that goes over
 * the bound. It validates nothing else: the parser still judges the syntax.
 * Pure function: any thread may call it.
 */
#ifndef PT_COMMON_BASE_JSON_H
#define PT_COMMON_BASE_JSON_H

#include <stddef.h>

/* The deepest nesting of objects and arrays any JSON the project reads may
 * have. A glTF's own structure needs 7 (root, "nodes", a node, its
 * "extensions", an extension, an object, an array); the rest is room for
 * "extras" and extensions' data. 128 levels take well under 1 MiB of stack in
 * tinygltf's recursion. */
#define PT_JSON_MAX_DEPTH 128u

/* 0 when no object or array in text[0..n) is nested more than max_depth
 * deep; else 1, with *at (when not NULL) the offset of the bracket that
 * went over. Brackets inside strings (escapes honoured) do not count; an
 * unbalanced text is the parser's to refuse. */
int pt_json_too_deep(const char *text, size_t n, unsigned max_depth, size_t *at);

#endif
