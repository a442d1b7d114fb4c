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

#   sanitized_spp N
#               prints N, or half of N in a sanitizer build: the samples of
#               a farm job that only needs to outlast kills or saves (as
#               CHECK_JOB_SPP in tests/check.h)
sanitized_spp() {
  if sanitized; then echo $(($1 / 2)); else echo "$1"; fi
}
