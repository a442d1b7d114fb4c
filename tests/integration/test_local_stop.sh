#!/usr/bin/env bash
# ptserve --local stops its workers when it stops, even one that ignores
# SIGTERM: after --local-stop-timeout (10 s by default, 1 s here) such a
# worker is killed, the log names it, and ptserve exits 0 instead of
# waiting for it forever. The worker here is a stand-in (--worker-bin) that
# ignores SIGTERM and never connects; the bound on ptserve's exit (90 s) is
# far above the timeout, so load cannot fail the test, only a hang.
# Environment (set by ctest): PT_BIN, PT_SOURCE_DIR.
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
source "$(dirname "$0")/lib_farm.sh"
farm_init local_stop

cat > "$tmp/stubborn" << 'SH'
#!/usr/bin/env bash
trap '' TERM
echo $$ > "${0%/*}/stubborn.pid"
while :; do sleep 0.2; done
SH
chmod +x "$tmp/stubborn"

"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --local 1 --worker-bin "$tmp/stubborn" --local-stop-timeout 1 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 400); do [ -s "$tmp/stubborn.pid" ] && break; sleep 0.05; done
[ -s "$tmp/stubborn.pid" ] || fail "the local worker did not start: $(cat "$tmp/serve.log")"
child=$(cat "$tmp/stubborn.pid")

kill -TERM "$srv_pid"
for _ in $(seq 900); do kill -0 "$srv_pid" 2> /dev/null || break; sleep 0.1; done
if kill -0 "$srv_pid" 2> /dev/null; then
  kill -9 "$child" # so that the cleanup's wait for ptserve ends
  fail "ptserve still running 90 s after SIGTERM, waiting for a worker that ignores it"
fi
rc=0
wait "$srv_pid" || rc=$?
srv_pid=
[ "$rc" = 0 ] || fail "ptserve exited $rc: $(tail -n 5 "$tmp/serve.log")"
grep -q "local worker 1 did not stop within 1 s of SIGTERM; killed" "$tmp/serve.log" ||
  fail "the log does not say the worker was killed: $(tail -n 5 "$tmp/serve.log")"
! kill -0 "$child" 2> /dev/null || fail "the local worker ($child) is still running"
failed=0
echo "test_local_stop: ok"
