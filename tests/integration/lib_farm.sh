# shellcheck shell=bash
# lib_farm.sh - what the farm tests share (test_passes_farm.sh,
# test_denoise_farm.sh, test_clamp_farm.sh, test_transparent_ctl.sh, ...):
# a queue on loopback, workers,
# polling a job, and comparing its EXR with the standalone render's.
# Source it after `set -euo pipefail`; it reads PT_BIN, PT_SOURCE_DIR and
# makes $tmp (kept, with the logs, when the test fails).
#
#   farm_init NAME          bin, src, scene (the Cornell box), tmp, traps
#   fail MSG                says why on stderr, exits 1
#   json FILE EXPR          EXPR over the JSON in FILE (d), printed
#   serve LOG [VAR=VAL...]  a ptserve queue on $port (0: any; kept for a
#                           restart, so the workers reconnect), tiles of 16,
#                           chunks of 8, leases of 1 s, and the options in
#                           the array serve_args when set; sets srv_pid and
#                           exports PTFARM_SERVER
#   stop_server [-9]        stops it (SIGTERM, or SIGKILL with -9)
#   restart_server LOG      stops it (SIGTERM) and serves again on its port
#   workers N               N ptworker of one thread each (pids in wrk_pids)
#   stop_workers            stops them
#   kill_worker             SIGKILL to the first of them
#   hold_workers            SIGSTOP to them (around a coordinator's kill -9)
#   release_workers         SIGCONT to them
#   status ID               ptctl status ID --json into $tmp/status.json
#   until_status ID EXPR    polls (up to 120 s) until EXPR over the status holds
#   same NAME               $tmp/NAME.exr equals $tmp/ref.exr in every channel
#                           (ptexr-diff; its report in $tmp/NAME.diff); a test
#                           redefines it to check more (finish calls it)
#   finish ID NAME          waits for done, fetches $tmp/NAME.exr, same NAME
#   sanitized               (lib_build.sh) true in a sanitizer build
# shellcheck source=tests/integration/lib_build.sh
. "$(dirname "${BASH_SOURCE[0]}")/lib_build.sh"
# shellcheck disable=SC2034 # bin, src and scene are the sourcing test's

farm_init() {
  bin=${PT_BIN:?}
  src=${PT_SOURCE_DIR:?}
  scene=$src/scenes/cornell_box.gltf
  tmp=$(mktemp -d "/tmp/pt_$1_XXXXXX")
  srv_pid=
  wrk_pids=
  port=0
  failed=1
  trap farm_cleanup EXIT
}

farm_cleanup() {
  local p
  for p in $wrk_pids; do kill "$p" 2> /dev/null || true; done
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2> /dev/null; then wait "$srv_pid" 2> /dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}

fail() {
  echo "FAIL: $*" >&2
  exit 1
}

json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

serve() {
  local log=$1
  shift
  rm -f "$tmp/port"
  # shellcheck disable=SC2154 # serve_args: the sourcing test's, when it sets it
  env "$@" "$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" \
    --listen "127.0.0.1:$port" --port-file "$tmp/port" --tile 16 --chunk 8 --lease-timeout 1 \
    ${serve_args[@]+"${serve_args[@]}"} 2>> "$tmp/$log" &
  srv_pid=$!
  for _ in $(seq 400); do [ -s "$tmp/port" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/$log")"
  port=$(cat "$tmp/port")
  PTFARM_SERVER=127.0.0.1:$port
  export PTFARM_SERVER
}

# The workers held (SIGSTOP) and let go again: a coordinator killed while
# they are held cannot see its job end in between, however loaded the machine.
hold_workers() { for p in $wrk_pids; do kill -STOP "$p"; done; }
release_workers() { for p in $wrk_pids; do kill -CONT "$p"; done; }

stop_server() {
  if [ "${1:-}" = -9 ]; then
    kill -9 "$srv_pid"
  else
    kill "$srv_pid"
  fi
  wait "$srv_pid" 2> /dev/null || true
  srv_pid=
}

restart_server() {
  stop_server -15
  serve "$1"
}

workers() {
  local w
  for w in $(seq "$1"); do
    "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --prefetch 2 --name "w$w" \
      --cache-dir "$tmp/cache$w" 2>> "$tmp/worker.log" &
    wrk_pids="$wrk_pids $!"
  done
}

stop_workers() {
  local p
  for p in $wrk_pids; do kill "$p" 2> /dev/null || true; done
  wrk_pids=
}

kill_worker() {
  local victim
  read -r victim _ <<< "$wrk_pids"
  kill -9 "$victim"
  wait "$victim" 2> /dev/null || true
}

status() { "$bin/ptctl" --timeout 20 status "$1" --json > "$tmp/status.json"; }

until_status() {
  for _ in $(seq 1200); do
    status "$1" && [ "$(json "$tmp/status.json" "$2")" = True ] && return 0
    sleep 0.1
  done
  fail "job $1: never $2: $(cat "$tmp/status.json")"
}

same() {
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$1.exr" > "$tmp/$1.diff" || fail "$1: $(cat "$tmp/$1.diff")"
}

finish() {
  until_status "$1" 'd["state"] == "done"'
  "$bin/ptctl" fetch "$1" -o "$tmp/$2.exr"
  same "$2"
}
