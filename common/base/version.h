/*
 * version.h - the release version and the renderer build id of a program.
 *
 * The version is the project's (CMake's PROJECT_VERSION). The build id is 16
 * lower-case hex digits that change whenever the renderer's code or the
 * compiler and flags it is built with change: a coordinator refuses workers
 * of another build, whose pixels could differ and break bit-identical
 * merging (protocol/msg.h, proto_build_id). `--version` of every program
 * prints both on one line, so that people and deployment scripts can tell
 * which build runs where. Constant data: any thread may call these.
 */
#ifndef PT_COMMON_BASE_VERSION_H
#define PT_COMMON_BASE_VERSION_H

/* The renderer build id: 16 lower-case hex digits, static storage. */
const char *pt_build_id(void);

/* Prints "PROG VERSION (build ID)" and a newline on stdout, the answer to
 * --version. Returns the exit status for main: 0, or 1 when stdout cannot be
 * written (a full disk, a closed pipe), with the reason on stderr. */
int pt_version_print(const char *prog);

#endif
