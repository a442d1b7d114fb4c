#!/usr/bin/env bash
# ptserve --http's /metrics against a real queue with real workers: the
# Prometheus text format passes promtool, the counters agree with what the
# job reports (samples merged, tasks leased, jobs by state, workers), and a
# token guards it like the rest of the dashboard.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
command -v curl > /dev/null || { echo "SKIP: no curl"; exit 77; }
command -v promtool > /dev/null || { echo "SKIP: no promtool (Debian package prometheus)"; exit 77; }
tmp=$(mktemp -d /tmp/pt_http_metrics_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
metric() { awk -v n="$1" '$1 == n { print $2 }' "$2"; }

umask 077
head -c 32 /dev/urandom | base64 > "$tmp/token"
"$bin/ptserve" --state-dir "$tmp/state" --listen 127.0.0.1:0 --port-file "$tmp/port" \
  --token-file "$tmp/token" --http 127.0.0.1:0 --http-port-file "$tmp/hport" \
  --local 2 --worker-threads 1 --tile 16 --chunk 16 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 200); do [ -s "$tmp/hport" ] && [ -s "$tmp/port" ] && break; sleep 0.05; done
[ -s "$tmp/hport" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
PTFARM_TOKEN_FILE=$tmp/token
export PTFARM_SERVER PTFARM_TOKEN_FILE
url=http://127.0.0.1:$(cat "$tmp/hport")/metrics
auth=(-H "Authorization: Bearer $(cat "$tmp/token")")

[ "$(curl -sS -o /dev/null -w '%{http_code}' "$url")" = 401 ] || fail "/metrics without a token"

id=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" --res 48x32 --spp 64 --name metrics)
"$bin/ptctl" watch "$id" 2> /dev/null || fail "watch"
"$bin/ptctl" status "$id" --json > "$tmp/job.json"
samples=$(json "$tmp/job.json" 'd["samples_done"]')
# The snapshot follows the loop within about a second: poll for it.
for _ in $(seq 100); do
  curl -sS "${auth[@]}" -D "$tmp/headers" "$url" > "$tmp/metrics"
  [ "$(awk '$1 == "ptfarm_jobs{state=\"done\"}" { print $2 }' "$tmp/metrics")" = 1 ] &&
    [ "$(metric ptfarm_workers_connected "$tmp/metrics")" = 2 ] && break
  sleep 0.1
done
grep -qi '^content-type: text/plain; version=0.0.4' "$tmp/headers" || fail "$(cat "$tmp/headers")"
promtool check metrics < "$tmp/metrics" || fail "promtool check metrics"
[ "$(metric ptfarm_samples_merged_total "$tmp/metrics")" = "$samples" ] ||
  fail "samples merged $(metric ptfarm_samples_merged_total "$tmp/metrics"), the job has $samples"
# 48x32 in 16-pixel tiles, 64 spp in chunks of 16: 6 tiles x 4 chunks, plus
# any verification copies and backups.
leased=$(metric ptfarm_tasks_leased_total "$tmp/metrics")
[ "$leased" -ge 24 ] || fail "tasks leased $leased < 24"
[ "$(metric ptfarm_merge_seconds_count "$tmp/metrics")" -ge 24 ] || fail "merge histogram"
[ "$(metric ptfarm_worker_threads "$tmp/metrics")" = 2 ] || fail "worker threads"
[ "$(metric ptfarm_received_bytes_total "$tmp/metrics")" -gt 0 ] || fail "bytes in"
[ "$(metric ptfarm_state_write_errors_total "$tmp/metrics")" = 0 ] || fail "write errors"
for m in ptfarm_tasks_requeued_total ptfarm_tasks_expired_total ptfarm_results_rejected_total \
  ptfarm_sent_bytes_total ptfarm_image_save_seconds_count ptfarm_checkpoint_seconds_count \
  ptfarm_clients_connected ptfarm_uptime_seconds; do
  [ -n "$(metric "$m" "$tmp/metrics")" ] || fail "no $m"
done
grep -q '^# TYPE ptfarm_merge_seconds histogram$' "$tmp/metrics" || fail "merge histogram type"

# A worker killed mid-job: its leases come back (requeued) and are counted.
# An extra worker that asks for 8 tasks beyond its thread, so it holds
# some whenever it dies.
"$bin/ptworker" --server "$PTFARM_SERVER" --token-file "$tmp/token" --threads 1 --prefetch 8 \
  --name extra --cache-dir "$tmp/cache" 2> "$tmp/extra.log" &
extra=$!
long=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" --res 48x32 --spp 65536 --name long)
for _ in $(seq 200); do
  curl -sS "${auth[@]}" "$url" > "$tmp/metrics2"
  [ "$(metric ptfarm_workers_connected "$tmp/metrics2")" = 3 ] &&
    [ "$(metric ptfarm_tasks_leased_total "$tmp/metrics2")" -gt $((leased + 50)) ] && break
  sleep 0.05
done
[ "$(metric ptfarm_workers_connected "$tmp/metrics2")" = 3 ] || fail "the extra worker did not join"
kill -KILL "$extra"
wait "$extra" 2> /dev/null || true
for _ in $(seq 200); do
  curl -sS "${auth[@]}" "$url" > "$tmp/metrics2"
  [ "$(metric ptfarm_tasks_requeued_total "$tmp/metrics2")" -gt 0 ] && break
  sleep 0.05
done
[ "$(metric ptfarm_tasks_requeued_total "$tmp/metrics2")" -gt 0 ] || fail "no requeue counted"
promtool check metrics < "$tmp/metrics2" || fail "promtool check metrics (second)"
"$bin/ptctl" cancel "$long" > /dev/null
failed=0
echo "PASS"
