# shellcheck shell=bash
# lib_build.sh - what a test may ask of the build it runs against.
#
#   sanitized   true in an ASan + UBSan or ThreadSanitizer build (PT_BIN's
#               CMakeCache.txt), where a test may render less: the
#               sanitizers check the same code on a smaller job (they run
#               it three to ten times slower), the release build the
#               full-size one
sanitized() {
  grep -qE '^PT_(SANITIZE|TSAN):BOOL=ON$' "${PT_BIN:?}/../CMakeCache.txt" 2>/dev/null
}
