#!/usr/bin/env bash
# The dashboard's job page in a real browser (headless Chromium) against a
# real ptserve and worker: the page gets the job's progress over
# Server-Sent Events and asks for a newer image as passes merge (read from
# the DOM Chromium dumps), the image it asks for changes between dumps, and
# the queue and workers pages render their tables from the API. A page of
# another origin (another port of this host, which SameSite cookies do not
# tell apart) that posts a cancel and a priority to the dashboard, by a form
# and by fetch, changes nothing.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
browser=$(command -v chromium || command -v chromium-browser || true)
[ -n "$browser" ] || { echo "SKIP: no chromium"; exit 77; }
command -v curl > /dev/null || { echo "SKIP: no curl"; exit 77; }
tmp=$(mktemp -d /tmp/pt_http_browser_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
# The DOM after the page's load event (--timeout ends pages that stream);
# with a second argument, after that much virtual time (pages that poll).
dom() {
  local wait=(--timeout=3000)
  [ -z "${2:-}" ] || wait=(--virtual-time-budget="$2")
  HOME=$tmp timeout 60 "$browser" --headless --no-sandbox --disable-gpu --no-first-run \
    --user-data-dir="$tmp/profile" "${wait[@]}" --dump-dom "$1" 2>> "$tmp/browser.log"
}

"$bin/ptserve" --state-dir "$tmp/state" --listen 127.0.0.1:0 --port-file "$tmp/port" \
  --http 127.0.0.1:0 --http-port-file "$tmp/hport" --save-interval 0.2 \
  --local 1 --worker-threads 1 --tile 16 --chunk 4 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 200); do [ -s "$tmp/hport" ] && [ -s "$tmp/port" ] && break; sleep 0.05; done
[ -s "$tmp/hport" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
web=http://127.0.0.1:$(cat "$tmp/hport")
id=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" --res 64x48 --spp 65536 --name "in the browser")

# Dumps of the job page until two show the page asking for different
# images (the n= of its image URL counts images written and samples merged)
# while the job runs.
first='' second=''
for _ in $(seq 60); do
  dom "$web/job?id=$id" > "$tmp/job.html" || true
  src_url=$(grep -o 'id="image"[^>]*src="[^"]*"' "$tmp/job.html" | sed 's/.*src="//; s/"$//; s/&amp;/\&/g' || true)
  samples=$(grep -o 'data-samples="[0-9]*"' "$tmp/job.html" | tr -dc 0-9 || true)
  if [ -n "$src_url" ] && [ -n "$samples" ] && [ "$samples" -gt 0 ]; then
    if [ -z "$first" ]; then
      first=$src_url
      curl -sS -o "$tmp/first.png" "$web$first"
    elif [ "$src_url" != "$first" ]; then
      second=$src_url
      curl -sS -o "$tmp/second.png" "$web$second"
      break
    fi
  fi
  sleep 0.3
done
[ -n "$first" ] || fail "the job page never showed progress: $(cat "$tmp/job.html")"
[ -n "$second" ] || fail "the job page never asked for a newer image (stayed at $first)"
grep -q '<h1 id="title">Job '"$id"': in the browser</h1>' "$tmp/job.html" || fail "job title"
grep -q 'running, ' "$tmp/job.html" || fail "no running summary: $(grep summary "$tmp/job.html")"
[ "$(head -c 8 "$tmp/second.png" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ] || fail "not a PNG"
! cmp -s "$tmp/first.png" "$tmp/second.png" || fail "the image did not change between dumps"

# A screenshot renders the page with its image (not only the DOM). With
# PT_SCREENSHOT_OUT set, it is kept there at a readable size (the README's).
size=500,400
[ -z "${PT_SCREENSHOT_OUT:-}" ] || size=960,720
(cd "$tmp" && HOME=$tmp timeout 60 "$browser" --headless --no-sandbox --disable-gpu --no-first-run \
  --user-data-dir="$tmp/profile" --timeout=3000 --window-size=$size \
  --screenshot="$tmp/job.png" "$web/job?id=$id" 2>> "$tmp/browser.log") || true
[ -s "$tmp/job.png" ] || fail "no screenshot"
[ -z "${PT_SCREENSHOT_OUT:-}" ] || cp "$tmp/job.png" "$PT_SCREENSHOT_OUT"

# The queue and workers pages fill their tables from the API.
dom "$web/" 3000 > "$tmp/queue.html" || true
grep -q "href=\"/job?id=$id\">in the browser</a>" "$tmp/queue.html" || fail "queue page: $(cat "$tmp/queue.html")"
grep -q "data-cancel=\"$id\"" "$tmp/queue.html" || fail "queue page has no cancel button"
dom "$web/workers" 3000 > "$tmp/workers.html" || true
grep -q '<td>local-1</td>' "$tmp/workers.html" || fail "workers page: $(cat "$tmp/workers.html")"

# Cross-site request forgery, from a page served on another port.
mkdir -p "$tmp/evil"
cat > "$tmp/evil/index.html" <<HTML
<!doctype html><html><body>
<form id="f" method="POST" action="$web/api/jobs/$id/cancel"></form>
<iframe name="sink" style="display:none"></iframe>
<script>
fetch("$web/api/jobs/$id/priority", {method: "POST", mode: "no-cors",
  body: new URLSearchParams("priority=42")}).finally(function () {
  document.getElementById("f").target = "sink";
  document.getElementById("f").submit();
});
</script><p id="done">sent</p></body></html>
HTML
python3 -m http.server --bind 127.0.0.1 --directory "$tmp/evil" 0 > "$tmp/evil.log" 2>&1 &
evil_pid=$!
for _ in $(seq 100); do grep -q "port [0-9]" "$tmp/evil.log" && break; sleep 0.05; done
eport=$(grep -o "port [0-9]*" "$tmp/evil.log" | head -1 | tr -dc 0-9)
[ -n "$eport" ] || fail "no page server: $(cat "$tmp/evil.log")"
dom "http://127.0.0.1:$eport/" 3000 > "$tmp/evil.html" || true
kill "$evil_pid" 2> /dev/null || true
grep -q 'id="done"' "$tmp/evil.html" || fail "the other origin's page did not run"
"$bin/ptctl" status "$id" --json > "$tmp/after.json"
python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); sys.exit(not (d["state"] == "running" and d["priority"] == 0))' "$tmp/after.json" ||
  fail "a page of another origin changed the job: $(cat "$tmp/after.json")"
if grep -q "cancelled" "$tmp/serve.log"; then fail "the job was cancelled from another origin"; fi

"$bin/ptctl" cancel "$id" > /dev/null
failed=0
echo "PASS"
