# shellcheck shell=bash
# lib_shared.sh - for the tests that render ../shared's sample assets.
#
#   need_shared FILE...   returns when every FILE exists; else exits 77
#                         (ctest's "skipped": ../shared is not there), or
#                         fails (exit 1) when CI is set, where it always is
need_shared() {
  local f
  for f in "$@"; do
    [ -f "$f" ] && continue
    case "${CI:-}" in true | 1 | yes) echo "FAIL: $f is missing" >&2; exit 1 ;; esac
    echo "skipped: $f is missing"
    exit 77
  done
}

#   sanitized             true in an ASan + UBSan or ThreadSanitizer build
#                         (PT_BIN's CMakeCache.txt), where a test may render
#                         less: the sanitizers check the same code on a
#                         smaller image, the release build the full-size one
sanitized() {
  grep -qE '^PT_(SANITIZE|TSAN):BOOL=ON$' "${PT_BIN:?}/../CMakeCache.txt" 2>/dev/null
}
