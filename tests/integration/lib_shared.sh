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

# and, from lib_build.sh, sanitized.
# shellcheck source=tests/integration/lib_build.sh
. "$(dirname "${BASH_SOURCE[0]}")/lib_build.sh"
