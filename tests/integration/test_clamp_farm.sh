#!/usr/bin/env bash
# Sample clamping on the farm: ptctl submit --clamp-direct/--clamp-indirect
# (a queue, 2 local workers) and ptserve --local 2 with the same options
# give the image ptworker --scene ... --clamp-direct/--clamp-indirect gives,
# bit for bit, and that image is not the unclamped one (so a farm that
# dropped the clamps would fail). A negative, NaN, infinite or absurd limit
# is refused by all three with exit 2 and the option's name before anything
# runs, and queue mode refuses ptserve's own clamps (a queued job asks with
# ptctl submit).
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init clamp_farm

view=(--res 48x32 --spp 32 --seed 3)
clamp=(--clamp-direct 0.75 --clamp-indirect 0.05)
"$bin/ptworker" --scene "$scene" "${view[@]}" "${clamp[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> "$tmp/ref.log" || fail "ptworker --clamp-*: $(cat "$tmp/ref.log")"
count=$(sed -n 's/^ptworker: \([0-9]*\) contributions clamped.*/\1/p' "$tmp/ref.log")
if [ -z "$count" ] || [ "$count" -eq 0 ]; then
  fail "ptworker counted no clamped sample: $(cat "$tmp/ref.log")"
fi
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/plain.exr" 2> "$tmp/plain.log" || fail "ptworker: $(cat "$tmp/plain.log")"
if "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/plain.exr" > /dev/null 2>&1; then
  fail "the clamps change nothing here: the test could not tell them from none"
fi

# Refusals: each names the option and exits 2, before anything runs.
expect_refusal() { # WHAT LOG PATTERN CMD...
  local what=$1 log=$2 pattern=$3
  shift 3
  set +e
  "$@" 2> "$log"
  local rc=$?
  set -e
  if [ $rc != 2 ] || ! grep -q -- "$pattern" "$log"; then
    fail "$what: rc $rc: $(cat "$log")"
  fi
}
for opt in --clamp-direct --clamp-indirect; do
  for bad in -1 nan NaN inf -inf 1e31 x ""; do
    expect_refusal "ptworker $opt '$bad'" "$tmp/w.log" "$opt" \
      "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" "$opt=$bad"
    expect_refusal "ptserve $opt '$bad'" "$tmp/s.log" "$opt" \
      "$bin/ptserve" --local 1 -o "$tmp/x.exr" "$opt=$bad" "$scene"
    expect_refusal "ptctl submit $opt '$bad'" "$tmp/c.log" "$opt" \
      "$bin/ptctl" --server 127.0.0.1:1 submit "$scene" "$opt=$bad"
  done
done
[ ! -e "$tmp/x.exr" ] || fail "a refused render wrote its output"
expect_refusal "ptserve --state-dir --clamp-direct" "$tmp/q.log" "one-job mode" \
  "$bin/ptserve" --state-dir "$tmp/qstate" --listen 127.0.0.1:0 --clamp-direct 1

serve serve.log
workers 2
job=$("$bin/ptctl" submit "$scene" "${view[@]}" "${clamp[@]}")
"$bin/ptctl" watch "$job" 2> /dev/null || fail "watch exited $?"
"$bin/ptctl" fetch "$job" -o "$tmp/queued.exr"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/queued.exr" || fail "ptctl submit --clamp-* image differs"
"$bin/ptctl" status "$job" > "$tmp/status.txt"
grep -q "^clamped  *$count contributions" "$tmp/status.txt" ||
  fail "ptctl status does not give ptworker's $count clamped: $(cat "$tmp/status.txt")"
"$bin/ptctl" status --json "$job" | grep -q "\"contributions_clamped\": $count," ||
  fail "ptctl status --json does not give $count clamped"
# The finished job's count is in the queue file: a restarted coordinator shows it.
restart_server serve.log
"$bin/ptctl" status "$job" > "$tmp/status2.txt"
grep -q "^clamped  *$count contributions" "$tmp/status2.txt" ||
  fail "after a restart, ptctl status lost the clamped count: $(cat "$tmp/status2.txt")"

"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" "${clamp[@]}" --tile 16 --task-time 50 \
  -o "$tmp/local.exr" "$scene" 2> "$tmp/local.log" ||
  fail "ptserve --local --clamp-*: $(cat "$tmp/local.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/local.exr" || fail "ptserve --clamp-* image differs"
grep -q "^ptserve: $count contributions clamped" "$tmp/local.log" ||
  fail "ptserve --local does not report ptworker's $count clamped: $(cat "$tmp/local.log")"
failed=0
echo "ok"
