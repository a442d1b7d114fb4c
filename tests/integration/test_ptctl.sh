#!/usr/bin/env bash
# ptctl's behaviour that needs no server:
#
# - `--help` of ptctl and of every command exits 0, prints on stdout, names
#   every option of the command and the exit statuses scripts rely on;
# - bad usage exits 2 with a reason and a pointer to --help (unknown command,
#   unknown option, missing or extra argument, malformed numbers, job ids,
#   --res, --timeout, --server, an over-long --name, fetch without -o);
# - a scene that cannot be packed exits 1 before any connection is tried;
# - a closed port exits 1 and says which address refused; a token file that
#   cannot be read exits 1 and names it.
# The end-to-end queue tests (submit, watch, fetch against ptserve) are in
# test_queue. Environment (set by ctest): PT_BIN (the build's bin folder),
# PT_SOURCE_DIR.
set -euo pipefail

ptctl=${PT_BIN:?PT_BIN must name the build\'s bin folder}/ptctl
src=${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
unset PTFARM_SERVER PTFARM_TOKEN_FILE

failures=0
fail() {
  echo "FAIL: $*" >&2
  failures=$((failures + 1))
}

# run EXPECTED_STATUS ARGS...: runs ptctl, keeps stdout and stderr in $tmp.
run() {
  local want=$1
  shift
  local rc=0
  "$ptctl" "$@" >"$tmp/out" 2>"$tmp/err" || rc=$?
  if [[ $rc != "$want" ]]; then
    fail "ptctl $* exited $rc, wanted $want; stderr: $(head -c 400 "$tmp/err")"
    return 1
  fi
}

has() { # has FILE TEXT...: every TEXT is in FILE
  local f=$1
  shift
  for t in "$@"; do
    grep -qF -- "$t" "$f" || fail "'$t' not in $(basename "$f") of the last run: $(head -c 300 "$f")"
  done
}

# ---- help ----
globals=(--server --token-file --timeout --help)
statuses=("0  success" "1  error" "2  bad usage" "3  no such job" "4  watch")
for args in "--help" "-h" "help"; do
  # shellcheck disable=SC2086
  run 0 $args && has "$tmp/out" submit list status watch cancel fetch "${globals[@]}" "${statuses[@]}"
done
run 0 submit --help &&
  has "$tmp/out" "ptctl submit SCENE" --spp --res --seed --priority --name --max-depth \
    --target-error --min-gain --min-spp --env --env-strength --env-rotate --background \
    --transparent --watch "${globals[@]}" "${statuses[@]}"
run 0 list --help && has "$tmp/out" "ptctl list" --json "${globals[@]}" "${statuses[@]}"
run 0 status --help && has "$tmp/out" "ptctl status JOB" --json "${globals[@]}" "${statuses[@]}"
run 0 watch --help && has "$tmp/out" "ptctl watch JOB" "${globals[@]}" "${statuses[@]}"
run 0 cancel --help && has "$tmp/out" "ptctl cancel JOB" "${globals[@]}" "${statuses[@]}"
run 0 fetch --help && has "$tmp/out" "ptctl fetch JOB [--frame F] -o OUT.exr" --output --frame "${globals[@]}" "${statuses[@]}"
# Help wins over what else is on the line, and needs no server.
run 0 --server 127.0.0.1:1 fetch 7 --help && has "$tmp/out" "ptctl fetch"
[[ -s "$tmp/err" ]] && fail "help wrote to stderr: $(cat "$tmp/err")"

# ---- bad usage: status 2, a reason, a pointer to --help ----
usage_case() { # usage_case TEXT ARGS...: exits 2, TEXT in stderr, nothing on stdout
  local text=$1
  shift
  if run 2 "$@"; then
    has "$tmp/err" "$text" "--help"
    [[ -s "$tmp/out" ]] && fail "ptctl $* wrote to stdout: $(cat "$tmp/out")"
  fi
  return 0
}
run 2 || true
has "$tmp/err" "usage: ptctl"
usage_case "unknown command 'frobnicate'" frobnicate
usage_case "unknown option '--bogus'" --bogus list
usage_case "unknown option '--bogus'" list --bogus
usage_case "unknown option '-x'" status -x 3
usage_case "unknown option '--json'" watch 3 --json
usage_case "needs a value" --server
usage_case "needs a value" submit scene.gltf --spp
usage_case "which job?" status
usage_case "which job?" watch
usage_case "which job?" cancel
usage_case "which job?" fetch -o x.exr
usage_case "not a job id" status abc
usage_case "not a job id" cancel -- -3
usage_case "not a job id" status 18446744073709551616
usage_case "unexpected argument '4'" status 3 4
usage_case "unexpected argument 'extra'" list extra
usage_case "-o OUT.exr is required" fetch 3
usage_case "which scene?" submit
usage_case "is extra" submit a.gltf b.gltf
usage_case "--spp" submit a.gltf --spp 0
usage_case "--spp" submit a.gltf --spp 12x
usage_case "--spp" submit a.gltf --spp 4294967296
usage_case "--res" submit a.gltf --res 640
usage_case "--res" submit a.gltf --res 0x480
usage_case "--res" submit a.gltf --res 640x
usage_case "--seed" submit a.gltf --seed -1
usage_case "--priority" submit a.gltf --priority 2147483648
usage_case "--priority" submit a.gltf --priority high
usage_case "--max-depth" submit a.gltf --max-depth 70000
# The same limit as ptworker and ptserve: 1025 passed ptctl and failed at the server.
usage_case "in [0, 1024]" submit a.gltf --max-depth 1025 # the limits of every program (options.h)
usage_case "cap is 1 or more" submit a.gltf --max-depth 0
usage_case "--target-error" submit a.gltf --target-error -0.1
usage_case "--target-error" submit a.gltf --target-error nan
usage_case "--min-gain" submit a.gltf --min-gain -1e-6
usage_case "--min-gain" submit a.gltf --min-gain inf
usage_case "--min-gain" submit a.gltf --min-gain 1e-6x
usage_case "two adaptive rules" submit a.gltf --target-error 0.05 --min-gain 1e-6
usage_case "--min-spp" submit a.gltf --min-spp x
usage_case "two environments" submit a.gltf --env a.hdr --background 1,1,1
usage_case "--background" submit a.gltf --background 1,2
usage_case "--background" submit a.gltf --background 1,1,nan
usage_case "--env-strength" submit a.gltf --env-strength -1
usage_case "--env-rotate" submit a.gltf --env-rotate inf
usage_case "needs a value" submit a.gltf --env
usage_case "--name" submit a.gltf --name "$(printf 'n%.0s' {1..65})"
usage_case "--timeout" --timeout 0 list
usage_case "--timeout" --timeout abc list
usage_case "--timeout" list --timeout -5
usage_case "--server" --server nocolon list
usage_case "--server" --server 127.0.0.1:99999 status 1
PTFARM_SERVER=nocolon usage_case "--server" list

# ---- errors: status 1 with a clear reason ----
# A scene that cannot be packed fails before any connection is tried.
run 1 --server 127.0.0.1:1 submit "$tmp/missing.gltf" && has "$tmp/err" "missing.gltf"
grep -q "connect" "$tmp/err" && fail "submit of a missing scene tried to connect"

# A port where nothing listens: find one, then every command reports it. Below
# 1024, so no test running beside this one can be given it as an ephemeral port
# between the check and the commands.
port=""
for p in $(seq 1 1023); do
  if ! (exec 3<>"/dev/tcp/127.0.0.1/$p") 2>/dev/null; then
    port=$p
    break
  fi
done
if [[ -z $port ]]; then
  fail "no closed port found in 1..1023"
else
  for args in "list" "status 1" "watch 1" "cancel 1" "fetch 1 -o $tmp/o.exr" \
    "submit $src/scenes/cornell_box.gltf"; do
    # shellcheck disable=SC2086
    if run 1 --server "127.0.0.1:$port" --timeout 5 $args; then
      has "$tmp/err" "ptctl: cannot connect to 127.0.0.1:$port" "refused"
      [[ -s "$tmp/out" ]] && fail "ptctl $args wrote to stdout on a refused connection"
    fi
  done
  [[ -e "$tmp/o.exr" ]] && fail "fetch created its output without a server"
  # The same from the environment.
  PTFARM_SERVER="127.0.0.1:$port" run 1 list && has "$tmp/err" "127.0.0.1:$port"
fi

# A token file that cannot be read is named; nothing is sent.
run 1 --token-file "$tmp/no-token" --server 127.0.0.1:1 list && has "$tmp/err" "no-token"
: >"$tmp/empty-token"
chmod 600 "$tmp/empty-token"
PTFARM_TOKEN_FILE="$tmp/empty-token" run 1 --server 127.0.0.1:1 list &&
  has "$tmp/err" "empty-token"

if ((failures)); then
  echo "test_ptctl: $failures failures" >&2
  exit 1
fi
echo "test_ptctl: ok"
