#!/usr/bin/env bash
# ptserve --http against a real queue with a real worker, over real HTTP
# (curl): the JSON API has ptctl --json's shapes, actions reach the loop,
# and the rules on who may ask hold: 401 without a token, a bearer token or
# a login cookie (HttpOnly, SameSite=Strict), 403 for another client's job,
# 404 for URLs that name files, 413 for big bodies; without --token-file the
# dashboard stays on loopback. Hostile requests (a 100 KB header, bad cookies,
# slow clients holding connections) get clear codes while a job renders on,
# and a job rendered through them is bit-identical to a standalone render.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
command -v curl > /dev/null || { echo "SKIP: no curl"; exit 77; }
tmp=$(mktemp -d /tmp/pt_http_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

umask 077
head -c 32 /dev/urandom | base64 > "$tmp/admin.token"
head -c 32 /dev/urandom | base64 > "$tmp/alice.token"
head -c 32 /dev/urandom | base64 > "$tmp/bob.token"
printf 'alice %s\nbob %s\n' "$(cat "$tmp/alice.token")" "$(cat "$tmp/bob.token")" > "$tmp/clients"
"$bin/ptserve" --state-dir "$tmp/state" --listen 127.0.0.1:0 --port-file "$tmp/port" \
  --token-file "$tmp/admin.token" --clients-file "$tmp/clients" \
  --http 127.0.0.1:0 --http-port-file "$tmp/hport" --http-host farm.example \
  --local 1 --worker-threads 1 --tile 16 --chunk 8 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 200); do [ -s "$tmp/hport" ] && [ -s "$tmp/port" ] && break; sleep 0.05; done
[ -s "$tmp/hport" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
web=http://127.0.0.1:$(cat "$tmp/hport")
as() { # as WHO curl-args...: a request with WHO's bearer token
  local who=$1; shift
  curl -sS -H "Authorization: Bearer $(cat "$tmp/$who.token")" "$@"
}
code() { curl -sS -o /dev/null -w '%{http_code}' "$@"; }
# held_by PID LOG: waits (up to 60 s) until the client PID, which holds its
# connections until killed, has said on its first line of LOG how many.
held_by() {
  for _ in $(seq 600); do
    [ -s "$2" ] && return 0
    kill -0 "$1" 2> /dev/null || fail "the client holding connections exited: $(cat "$2")"
    sleep 0.1
  done
  fail "the client holding connections never said how many: $(cat "$2")"
}

# Alice submits a long job and a short one; bob one of his own.
long=$(PTFARM_TOKEN_FILE=$tmp/alice.token "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" \
  --res 32x24 --spp 65536 --name "alice long")
short=$(PTFARM_TOKEN_FILE=$tmp/alice.token "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" \
  --res 32x24 --spp 16 --name "alice short" --priority 9)
bobs=$(PTFARM_TOKEN_FILE=$tmp/bob.token "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" \
  --res 32x24 --spp 65536 --name "bob's")

# Without a token: 401 everywhere but the login page and its style.
for u in /api/jobs "/api/jobs/$long" /api/workers / /job /workers /app.js /metrics; do
  [ "$(code "$web$u")" = 401 ] || fail "$u without a token: not 401"
done
[ "$(code -H 'Authorization: Bearer not-the-token-at-all' "$web/api/jobs")" = 401 ] ||
  fail "a wrong bearer token is not 401"
[ "$(code "$web/login")" = 200 ] || fail "/login"
[ "$(code "$web/style.css")" = 200 ] || fail "/style.css"

# The short job ends; its JSON over HTTP is ptctl's, field for field (the
# snapshot follows within about a second).
PTFARM_TOKEN_FILE=$tmp/alice.token "$bin/ptctl" watch "$short" 2> /dev/null || fail "watch"
PTFARM_TOKEN_FILE=$tmp/alice.token "$bin/ptctl" status "$short" --json > "$tmp/ctl.json"
for _ in $(seq 100); do
  as alice "$web/api/jobs/$short" > "$tmp/http.json"
  cmp -s "$tmp/ctl.json" "$tmp/http.json" && break
  sleep 0.1
done
cmp "$tmp/ctl.json" "$tmp/http.json" || fail "/api/jobs/$short differs from ptctl status --json"
PTFARM_TOKEN_FILE=$tmp/admin.token "$bin/ptctl" list --json > "$tmp/ctl_list.json"
same_list() {
  python3 - "$tmp/ctl_list.json" "$tmp/http_list.json" <<'PY'
import json, sys
a, b = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
assert [j["id"] for j in a] == [j["id"] for j in b], (a, b)
assert all(set(x) == set(y) for x, y in zip(a, b))
PY
}
for _ in $(seq 100); do # the snapshot follows the loop within a second
  as admin "$web/api/jobs" > "$tmp/http_list.json"
  same_list 2> /dev/null && break
  sleep 0.1
done
same_list || fail "/api/jobs shape"
as admin "$web/api/workers" > "$tmp/workers.json"
[ "$(json "$tmp/workers.json" 'len(d) == 1 and d[0]["name"] == "local-1" and d[0]["threads"] == 1')" = True ] ||
  fail "workers: $(cat "$tmp/workers.json")"
[ "$(code -H "Authorization: Bearer $(cat "$tmp/bob.token")" "$web/api/jobs/999")" = 404 ] ||
  fail "no such job: not 404"

# Actions: bob may not touch alice's job (403), alice may; the admin may
# touch anyone's. Priority reorders the queue.
[ "$(code -X POST -H "Authorization: Bearer $(cat "$tmp/bob.token")" "$web/api/jobs/$long/cancel")" = 403 ] ||
  fail "bob cancelling alice's job: not 403"
[ "$(code -X POST -H "Authorization: Bearer $(cat "$tmp/bob.token")" -d priority=3 \
  "$web/api/jobs/$long/priority")" = 403 ] || fail "bob's priority on alice's job: not 403"
[ "$(code -X GET -H "Authorization: Bearer $(cat "$tmp/alice.token")" "$web/api/jobs/$long/cancel")" = 405 ] ||
  fail "GET cancel: not 405"
[ "$(code -X POST -H "Authorization: Bearer $(cat "$tmp/alice.token")" -d priority=high \
  "$web/api/jobs/$long/priority")" = 400 ] || fail "a bad priority: not 400"
as alice -X POST -d priority=7 "$web/api/jobs/$long/priority" > "$tmp/prio.json"
[ "$(json "$tmp/prio.json" 'd["priority"]')" = 7 ] || fail "priority: $(cat "$tmp/prio.json")"
PTFARM_TOKEN_FILE=$tmp/alice.token "$bin/ptctl" status "$long" --json > "$tmp/long.json"
[ "$(json "$tmp/long.json" 'd["priority"]')" = 7 ] || fail "priority not in the queue"
as alice -X POST "$web/api/jobs/$long/cancel" > "$tmp/cancel.json"
[ "$(json "$tmp/cancel.json" 'd["state"]')" = cancelled ] || fail "cancel: $(cat "$tmp/cancel.json")"
as admin -X POST "$web/api/jobs/$bobs/cancel" > "$tmp/cancel2.json"
[ "$(json "$tmp/cancel2.json" 'd["state"]')" = cancelled ] || fail "admin cancel: $(cat "$tmp/cancel2.json")"
grep -q "job $long cancelled: cancelled by alice (web)" "$tmp/serve.log" || fail "cancel not logged"

# The login form: a wrong token is refused; a right one sets a session
# cookie (HttpOnly, SameSite=Strict) that then opens the pages and the API.
[ "$(code -X POST --data-urlencode "token=wrong token" "$web/login")" = 401 ] ||
  fail "a wrong login: not 401"
curl -sS -D "$tmp/login.h" -o /dev/null -c "$tmp/jar" -X POST \
  --data-urlencode "token=$(cat "$tmp/bob.token")" "$web/login"
grep -qi '^HTTP/1.1 303' "$tmp/login.h" || fail "login: $(cat "$tmp/login.h")"
grep -i '^set-cookie:' "$tmp/login.h" | grep -i httponly | grep -qi 'samesite=strict' ||
  fail "cookie flags: $(cat "$tmp/login.h")"
[ "$(code -b "$tmp/jar" "$web/api/jobs")" = 200 ] || fail "the session cookie is not accepted"
[ "$(code -b "$tmp/jar" "$web/")" = 200 ] || fail "the queue page with a session"
[ "$(code -b "$tmp/jar" -H "Origin: $web" -X POST "$web/api/jobs/$short/cancel")" = 403 ] ||
  fail "bob's session on alice's job: not 403"
[ "$(code -b 'ptfarm_session=0000000000000000000000000000000000000000000000000000000000000000' \
  "$web/api/jobs")" = 401 ] || fail "a made-up session: not 401"

# Browsers. A Host that is not an IP address, localhost or a --http-host
# name (DNS rebinding) is refused; a state-changing request from another
# origin is refused whatever it carries, and one by session cookie must say
# where it comes from.
hp=$(cat "$tmp/hport")
[ "$(code -H "Host: evil.example:$hp" -H "Authorization: Bearer $(cat "$tmp/admin.token")" \
  "$web/api/jobs")" = 421 ] || fail "a foreign Host: not 421"
[ "$(code -H "Host: evil.example" "$web/login")" = 421 ] || fail "a foreign Host on /login"
for h in "localhost:$hp" "127.0.0.1:$hp" "farm.example:$hp" "[::1]:$hp"; do
  [ "$(code -H "Host: $h" -H "Authorization: Bearer $(cat "$tmp/admin.token")" "$web/api/jobs")" = 200 ] ||
    fail "Host $h: not 200"
done
bob2=$(PTFARM_TOKEN_FILE=$tmp/bob.token "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" \
  --res 32x24 --spp 65536 --name "bob again" --priority -5)
prio() { code -X POST -d priority="$1" "${@:2}" "$web/api/jobs/$bob2/priority"; }
[ "$(prio 5 -b "$tmp/jar" -H "Origin: http://evil.example")" = 403 ] || fail "CSRF by Origin"
[ "$(prio 5 -b "$tmp/jar" -H "Origin: http://127.0.0.1:1")" = 403 ] || fail "CSRF from another port"
[ "$(prio 5 -b "$tmp/jar" -H "Sec-Fetch-Site: same-site")" = 403 ] || fail "CSRF by Sec-Fetch-Site"
[ "$(prio 5 -b "$tmp/jar")" = 403 ] || fail "a cookie POST that does not say where it is from"
[ "$(prio 5 -H "Authorization: Bearer $(cat "$tmp/bob.token")" -H "Origin: http://evil.example")" = 403 ] ||
  fail "a bearer POST from another origin"
PTFARM_TOKEN_FILE=$tmp/bob.token "$bin/ptctl" status "$bob2" --json > "$tmp/bob2.json"
[ "$(json "$tmp/bob2.json" 'd["priority"]')" = -5 ] || fail "a refused request changed the priority"
[ "$(prio 6 -b "$tmp/jar" -H "Origin: $web" -H "Sec-Fetch-Site: same-origin")" = 200 ] ||
  fail "the dashboard's own POST"
[ "$(prio 7 -H "Authorization: Bearer $(cat "$tmp/bob.token")")" = 200 ] || fail "a script's POST"
# Logins: an identity holds 8; its 9th replaces its oldest, and no one
# else's is touched.
for i in $(seq 9); do
  curl -sS -o /dev/null -c "$tmp/ajar$i" -X POST --data-urlencode "token=$(cat "$tmp/alice.token")" \
    "$web/login"
done
[ "$(code -b "$tmp/ajar1" "$web/api/jobs")" = 401 ] || fail "alice's 9th login kept her first"
[ "$(code -b "$tmp/ajar2" "$web/api/jobs")" = 200 ] || fail "alice's second login was lost"
[ "$(code -b "$tmp/jar" "$web/api/jobs")" = 200 ] || fail "alice's logins pushed out bob's"
# Guessing: wrong tokens from one address (here 127.0.0.3) are backed off
# as on the worker port (the 5th in a row blocks it), answered 429 with
# Retry-After, and logged; other addresses are served.
for i in $(seq 5); do
  code --interface 127.0.0.3 -H "Authorization: Bearer guess-$i-of-many-guesses" "$web/api/jobs" > /dev/null
done
curl -sS -D "$tmp/blocked.h" -o /dev/null --interface 127.0.0.3 \
  -H "Authorization: Bearer $(cat "$tmp/admin.token")" "$web/api/jobs"
grep -q '^HTTP/1.1 429' "$tmp/blocked.h" || fail "a blocked address: $(cat "$tmp/blocked.h")"
grep -qi '^retry-after: [0-9]' "$tmp/blocked.h" || fail "no Retry-After: $(cat "$tmp/blocked.h")"
[ "$(code --interface 127.0.0.3 -X POST --data-urlencode "token=$(cat "$tmp/admin.token")" \
  "$web/login")" = 429 ] || fail "a login from a blocked address"
grep -q "peer 127.0.0.3.*failed authentications in a row" "$tmp/serve.log" ||
  fail "the block is not logged"
[ "$(code -H "Authorization: Bearer $(cat "$tmp/admin.token")" "$web/api/jobs")" = 200 ] ||
  fail "another address was blocked too"
as admin -X POST "$web/api/jobs/$bob2/cancel" > /dev/null

# URLs never reach files; bodies are small.
for u in /../../etc/passwd /index.html /web/app.js /api/jobs/1/../../etc/passwd; do
  c=$(as admin -o /dev/null -w '%{http_code}' --path-as-is "$web$u")
  [ "$c" = 404 ] || fail "$u: $c, not 404"
done
head -c 200000 /dev/zero | tr '\0' a > "$tmp/big"
c=$(as admin -o /dev/null -w '%{http_code}' -X POST --data-binary "priority=@$tmp/big" \
  "$web/api/jobs/$long/priority" || true)
[ "$c" = 413 ] || [ "$c" = 000 ] || fail "a big body: $c"

# A job that renders while the hostile requests below arrive.
fire=$(PTFARM_TOKEN_FILE=$tmp/admin.token "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" \
  --res 32x24 --spp 65536 --name "under fire")
# Hostile HTTP: an oversized header, a malformed and an oversized cookie,
# and slow clients that open connections and never finish a request (from
# another loopback address, so the per-address cap they hit is theirs).
c=$(as admin -o /dev/null -w '%{http_code}' -H "X-Big: $(head -c 100000 /dev/zero | tr '\0' a)" \
  "$web/api/jobs" || true)
case $c in 4* | 000) ;; *) fail "a 100 KB header: $c" ;; esac
for cookie in 'ptfarm_session=%00%0a../../x; ptfarm_session=' \
  "ptfarm_session=$(head -c 8000 /dev/zero | tr '\0' f)"; do
  # From an address of their own: failed authentications count per address.
  c=$(code --interface 127.0.0.4 -b "$cookie" "$web/api/jobs" || true)
  case $c in 400 | 401 | 413 | 431 | 000) ;; *) fail "a bad cookie: $c" ;; esac
done
python3 - "$(cat "$tmp/hport")" > "$tmp/slow.log" 2>&1 <<'PY' &
import socket, sys, time
held = []
for _ in range(48):
    try:
        s = socket.socket()
        s.bind(("127.0.0.2", 0))
        s.connect(("127.0.0.1", int(sys.argv[1])))
        s.sendall(b"GET /api/jobs HTTP/1.1\r\nHost: x\r\n")  # never ends the request
        held.append(s)
    except OSError:
        pass
print(len(held), flush=True)
time.sleep(120)  # held until killed
PY
slow_pid=$!
held_by "$slow_pid" "$tmp/slow.log"
for _ in 1 2 3; do
  [ "$(code -H "Authorization: Bearer $(cat "$tmp/admin.token")" --max-time 10 "$web/api/jobs")" = 200 ] ||
    fail "a request while slow clients hold connections"
done
kill "$slow_pid"
wait "$slow_pid" || true
# One network holds at most 16 connections: slow clients from four
# addresses of 127.0.9.0/24 keep 16 of their 32 open, and the rest of the
# farm is served.
python3 - "$(cat "$tmp/hport")" > "$tmp/net.log" 2>&1 <<'PY' &
import select, socket, sys, time
held = []
for a in range(2, 6):
    for _ in range(8):
        try:
            s = socket.socket()
            s.bind(("127.0.9.%d" % a, 0))
            s.connect(("127.0.0.1", int(sys.argv[1])))
            s.sendall(b"GET /api/jobs HTTP/1.1\r\nHost: x\r\n")  # never ends the request
            held.append(s)
        except OSError:
            pass
    time.sleep(0.2)
time.sleep(1.0)
open_ = 0
for s in held:
    r, _, _ = select.select([s], [], [], 0)
    if not r:
        open_ += 1
    else:
        try:
            open_ += s.recv(1, socket.MSG_PEEK) != b""
        except OSError:
            pass
print(open_, flush=True)
time.sleep(120)  # held until killed
PY
net_pid=$!
held_by "$net_pid" "$tmp/net.log"
[ "$(head -n 1 "$tmp/net.log")" = 16 ] || fail "one network held $(cat "$tmp/net.log") connections"
[ "$(code -H "Authorization: Bearer $(cat "$tmp/admin.token")" --max-time 10 "$web/api/jobs")" = 200 ] ||
  fail "a request while one network holds its share"
kill "$net_pid"
wait "$net_pid" || true
# A client that sends its headers a byte a second is closed once it has
# not finished them in 10 s (it would otherwise hold its connection for as
# long as it keeps sending).
python3 - "$(cat "$tmp/hport")" > "$tmp/drip.log" 2>&1 <<'PY'
import socket, sys, time
s = socket.socket()
s.bind(("127.0.0.6", 0))
s.connect(("127.0.0.1", int(sys.argv[1])))
s.settimeout(0.2)
head = b"GET /api/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 100
t0 = time.time()
for b in head:
    try:
        s.send(bytes([b]))
        if s.recv(1) == b"":
            break
    except socket.timeout:
        pass
    except OSError:
        break
    time.sleep(0.8)
print("%.0f" % (time.time() - t0), flush=True)
PY
t=$(head -n 1 "$tmp/drip.log")
if [ -z "$t" ] || [ "$t" -lt 9 ] || [ "$t" -gt 20 ]; then
  fail "a dripping client lasted $(cat "$tmp/drip.log") s"
fi
# The render went on through all of it: the job still gains samples.
s0=$(as admin "$web/api/jobs/$fire" | python3 -c 'import json,sys; print(json.load(sys.stdin)["samples_done"])')
for _ in $(seq 200); do
  s1=$(as admin "$web/api/jobs/$fire" | python3 -c 'import json,sys; print(json.load(sys.stdin)["samples_done"])')
  [ "$s1" -gt "$s0" ] && break
  sleep 0.1
done
[ "$s1" -gt "$s0" ] || fail "the job stopped gaining samples ($s0)"
as admin -X POST "$web/api/jobs/$fire/cancel" > /dev/null

# The image views and the EXR download.
for v in rgb standard filmic agx samples error; do
  as alice -o "$tmp/$v.png" "$web/api/jobs/$short/image.png?view=$v&exposure=1"
  [ "$(head -c 8 "$tmp/$v.png" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ] || fail "$v: not a PNG"
done
# The view transforms are the previews' own: rgb is standard, agx is not.
cmp -s "$tmp/rgb.png" "$tmp/standard.png" || fail "view=rgb and view=standard differ"
if cmp -s "$tmp/rgb.png" "$tmp/agx.png"; then fail "view=agx is the standard image"; fi
[ "$(code -H "Authorization: Bearer $(cat "$tmp/alice.token")" "$web/api/jobs/$short/image.png?view=aces")" = 400 ] ||
  fail "view=aces is not refused with 400"
as alice -o "$tmp/dl.exr" "$web/api/jobs/$short/image.exr"
cmp "$tmp/dl.exr" "$tmp/state/output/$short-alice_short.exr" || fail "EXR download differs"
# The worker's row counts what it rendered: tasks, samples, its last result.
ok=
for _ in $(seq 50); do
  as admin "$web/api/workers" > "$tmp/workers2.json"
  ok=$(json "$tmp/workers2.json" '(d[0]["state"] == "connected" and d[0]["tasks_done"] > 0 and
    d[0]["samples_done"] >= 16 * 32 * 24 and d[0]["samples_per_second"] > 0 and
    d[0]["last_result_seconds_ago"] is not None)')
  [ "$ok" = True ] && break
  sleep 0.1
done
[ "$ok" = True ] || fail "the worker's counts: $(cat "$tmp/workers2.json")"
# The short job, rendered through all of the above, is bit-identical to a
# standalone render of the same job (the same chunks: 8 splits the 16-sample
# block, which is exact only when both sides split it alike).
"$bin/ptworker" --scene "$src/scenes/cornell_box.gltf" --res 32x24 --spp 16 --chunk 8 --threads 1 -q \
  -o "$tmp/ref.exr" 2> "$tmp/ref.log" || fail "standalone: $(cat "$tmp/ref.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/dl.exr" > "$tmp/diff.log" 2>&1 ||
  fail "the farm's image differs from a standalone render: $(cat "$tmp/diff.log")"
# The server still serves (nothing above broke it).
[ "$(code -H "Authorization: Bearer $(cat "$tmp/admin.token")" "$web/api/jobs")" = 200 ] ||
  fail "after the bad requests"
kill "$srv_pid"; wait "$srv_pid" || true; srv_pid=

# Without a token the dashboard stays on loopback, whatever --http says.
"$bin/ptserve" --state-dir "$tmp/state2" --listen 127.0.0.1:0 --http 0.0.0.0:0 \
  --http-port-file "$tmp/hport2" 2> "$tmp/serve2.log" &
srv_pid=$!
for _ in $(seq 200); do [ -s "$tmp/hport2" ] && break; sleep 0.05; done
grep -q "dashboard listens on loopback only" "$tmp/serve2.log" || fail "$(cat "$tmp/serve2.log")"
grep -q "dashboard on http://127.0.0.1:" "$tmp/serve2.log" || fail "$(cat "$tmp/serve2.log")"
[ "$(code "http://127.0.0.1:$(cat "$tmp/hport2")/api/jobs")" = 200 ] || fail "loopback, no token"
failed=0
echo "PASS"
