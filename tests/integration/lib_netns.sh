# shellcheck shell=bash
# lib_netns.sh - helpers for integration tests that run ptfarm processes on
# "hosts" made of Linux network namespaces joined by veth pairs.
#
# Source it from a bash test that runs with `set -euo pipefail`, then call
# netns_init PREFIX once: it registers netns_cleanup on EXIT (and turns INT,
# TERM and HUP into an exit), so every namespace, veth pair and process this
# library created goes away however the test ends, and so does the folder
# NETNS_TMP when the test sets it (after printing the end of each *.log in it
# when the test failed). Only namespaces created
# here are touched; every `ip` command names its namespace (`ip -n NS`), so no
# interface of the machine's own namespace is ever created, changed or deleted.
#
#   netns_require                 exit 77 (ctest: skipped) with "SKIP: ..." when namespaces cannot be
#                                 created (not root, no CAP_SYS_ADMIN, no iproute2);
#                                 with CI=true that is a failure instead
#   netns_add NAME                create namespace PREFIX-NAME with lo up; prints nothing
#   netns_name NAME               the real namespace name: PREFIX-NAME
#   netns_veth NS_A IF_A ADDR_A NS_B IF_B ADDR_B
#                                 a veth pair from NS_A to NS_B, addresses in CIDR form
#   netns_exec NS CMD...          run CMD in NS (foreground)
#   netns_spawn VAR LOG NS CMD... run CMD in NS in the background, stdout and stderr to
#                                 LOG; its pid goes to variable VAR and is killed at exit
#   netns_link_set NS IF up|down  bring one veth end up or down
#   wait_for_log LOG REGEX SECS [COUNT [PID]]
#                                 wait until LOG has COUNT (default 1) lines matching the
#                                 extended regex; 1 on timeout or when PID exits first
#   log_count LOG REGEX           number of matching lines (0 when LOG is missing)
#   wait_pid_timeout PID SECS VAR wait for a child to exit; its status goes to VAR
#                                 (124 on timeout, the process is then left running)
#   fail MSG...                   print "FAIL: MSG" and exit 1

NETNS_PREFIX=""
NETNS_CREATED=()
NETNS_PIDS=()

fail() {
  echo "FAIL: $*" >&2
  exit 1
}

netns_name() { printf '%s-%s' "$NETNS_PREFIX" "$1"; }

# Why namespaces cannot be used here, or nothing when they can.
_netns_unusable_reason() {
  if ! command -v ip >/dev/null 2>&1; then
    echo "iproute2's ip is not installed"
    return
  fi
  local probe="${NETNS_PREFIX}-probe" out
  if ! out=$(ip netns add "$probe" 2>&1); then
    echo "ip netns add: ${out:-failed} (uid $(id -u); needs root or CAP_SYS_ADMIN)"
    return
  fi
  if ! out=$(ip netns exec "$probe" ip link set lo up 2>&1); then
    ip netns del "$probe" >/dev/null 2>&1 || true
    echo "ip netns exec: ${out:-failed}"
    return
  fi
  ip netns del "$probe" >/dev/null 2>&1 || true
}

netns_require() {
  local why
  why=$(_netns_unusable_reason)
  [[ -z "$why" ]] && return 0
  if [[ "${CI:-}" == true ]]; then
    fail "cannot create network namespaces ($why); CI must run this test"
  fi
  echo "SKIP: cannot create network namespaces ($why)"
  exit 77
}

netns_init() {
  NETNS_PREFIX="$1"
  trap netns_cleanup EXIT
  trap 'exit 129' HUP
  trap 'exit 130' INT
  trap 'exit 143' TERM
}

netns_add() {
  local ns
  ns=$(netns_name "$1")
  ip netns add "$ns"
  NETNS_CREATED+=("$ns")
  ip -n "$ns" link set lo up
}

# The pair is created inside NS_A with its peer placed straight into NS_B:
# neither end ever exists in the machine's own namespace.
netns_veth() {
  local a b
  a=$(netns_name "$1")
  b=$(netns_name "$4")
  ip -n "$a" link add "$2" type veth peer name "$5" netns "$b"
  ip -n "$a" addr add "$3" dev "$2"
  ip -n "$b" addr add "$6" dev "$5"
  ip -n "$a" link set "$2" up
  ip -n "$b" link set "$5" up
}

netns_exec() {
  local ns
  ns=$(netns_name "$1")
  shift
  ip netns exec "$ns" "$@"
}

netns_spawn() {
  local _nss_ns
  _nss_ns=$(netns_name "$3")
  # `ip netns exec` execs the command, so $! is the program itself.
  ip netns exec "$_nss_ns" "${@:4}" >"$2" 2>&1 &
  NETNS_PIDS+=("$!")
  printf -v "$1" '%s' "$!"
}

netns_link_set() {
  ip -n "$(netns_name "$1")" link set "$2" "$3"
}

log_count() {
  [[ -f "$1" ]] || { echo 0; return; }
  grep -cE -- "$2" "$1" || true
}

wait_for_log() {
  local log=$1 re=$2 secs=$3 count=${4:-1} pid=${5:-}
  local deadline=$((SECONDS + secs))
  while ((SECONDS <= deadline)); do
    (($(log_count "$log" "$re") >= count)) && return 0
    if [[ -n "$pid" ]] && ! kill -0 "$pid" 2>/dev/null; then
      (($(log_count "$log" "$re") >= count)) && return 0
      return 1
    fi
    sleep 0.1
  done
  return 1
}

wait_pid_timeout() {
  local _wpt_pid=$1 _wpt_st=0
  local _wpt_deadline=$((SECONDS + $2))
  while kill -0 "$_wpt_pid" 2>/dev/null; do
    if ((SECONDS > _wpt_deadline)); then
      printf -v "$3" '%s' 124
      return 0
    fi
    sleep 0.1
  done
  wait "$_wpt_pid" || _wpt_st=$?
  printf -v "$3" '%s' "$_wpt_st"
}

# Processes first (TERM, then KILL after 3 s), then anything still running inside
# our namespaces, then the veth pairs (deleting either end deletes the pair) and
# the namespaces. Every step tolerates what is already gone.
netns_cleanup() {
  local st=$? pid ns i alive
  trap - EXIT HUP INT TERM
  set +e
  for pid in "${NETNS_PIDS[@]}"; do
    kill -TERM "$pid" 2>/dev/null
    kill -CONT "$pid" 2>/dev/null # a stopped process acts on TERM only once continued
  done
  for ((i = 0; i < 30; i++)); do
    alive=0
    for pid in "${NETNS_PIDS[@]}"; do
      kill -0 "$pid" 2>/dev/null && alive=1
    done
    ((alive)) || break
    sleep 0.1
  done
  for pid in "${NETNS_PIDS[@]}"; do
    kill -KILL "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
  done
  for ns in "${NETNS_CREATED[@]}"; do
    for pid in $(ip netns pids "$ns" 2>/dev/null); do
      kill -KILL "$pid" 2>/dev/null
    done
  done
  for ns in "${NETNS_CREATED[@]}"; do
    for i in $(ip -n "$ns" -o link show type veth 2>/dev/null | awk -F': ' '{print $2}' |
      cut -d@ -f1); do
      ip -n "$ns" link del "$i" 2>/dev/null
    done
  done
  for ns in "${NETNS_CREATED[@]}"; do
    ip netns del "$ns" 2>/dev/null
  done
  if [[ -n "${NETNS_TMP:-}" && -d "$NETNS_TMP" ]]; then
    if ((st != 0)); then
      for i in "$NETNS_TMP"/*.log; do
        [[ -f "$i" ]] || continue
        echo "--- last lines of ${i##*/} ---" >&2
        tail -n 25 "$i" | tr '\r' '\n' | grep -v '^$' | tail -n 25 >&2
      done
    fi
    rm -rf -- "$NETNS_TMP"
  fi
  exit "$st"
}
