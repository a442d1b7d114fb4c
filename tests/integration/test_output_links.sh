#!/usr/bin/env bash
# Links planted in the output folder are never followed: not at the image's
# and the preview's names, not at the names temporaries used to have
# (NAME.tmp.PID.N); a fetch does not read an image through a link planted
# there, by ptctl fetch or by the dashboard; ptctl fetch into a folder with
# a link at the destination replaces the link and leaves its target alone; a
# FIFO at an image's name blocks neither a restart nor the dashboard, and
# ptserve still stops on SIGTERM.
set -euo pipefail
command -v curl > /dev/null || { echo "SKIP: no curl"; exit 77; }
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_output_links_XXXXXX)
srv_pid='' wrk_pid=''
cleanup() {
  for p in $srv_pid $wrk_pid; do
    if kill -9 "$p" 2>/dev/null; then wait "$p" 2>/dev/null || true; fi
  done
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() {
  echo "FAIL: $*" >&2
  tail -n 20 "$tmp/serve.log" >&2 || true
  exit 1
}

mkdir -p "$tmp/out" "$tmp/dl"
for v in victim_exr victim_png victim_tmp victim_fetch secret; do echo "precious $v" > "$tmp/$v"; done
"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --local 1 --worker-threads 1 --tile 16 --chunk 8 --save-interval 0 \
  --http 127.0.0.1:0 --http-port-file "$tmp/hport" -q 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 200); do [ -s "$tmp/port" ] && [ -s "$tmp/hport" ] && break; sleep 0.05; done
[ -s "$tmp/port" ] || fail "ptserve did not start"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
web=http://127.0.0.1:$(cat "$tmp/hport")

# The first job's names are known in advance: 1-links.exr and 1-links.png,
# and the temporaries used to be NAME.tmp.PID.N with N counting from 0.
ln -s "$tmp/victim_exr" "$tmp/out/1-links.exr"
ln -s "$tmp/victim_png" "$tmp/out/1-links.png"
for n in $(seq 0 199); do
  ln -s "$tmp/victim_tmp" "$tmp/out/1-links.exr.tmp.$srv_pid.$n"
  ln -s "$tmp/victim_tmp" "$tmp/out/1-links.png.tmp.$srv_pid.$n"
done
id=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" --res 32x32 --spp 64 --name links)
[ "$id" = 1 ] || fail "job id $id"
"$bin/ptctl" watch "$id" 2> /dev/null || fail "watch exited $?"
for v in victim_exr victim_png victim_tmp; do
  [ "$(cat "$tmp/$v")" = "precious $v" ] || fail "ptserve wrote through a link into $v"
done
for f in 1-links.exr 1-links.png; do
  if [ ! -f "$tmp/out/$f" ] || [ -L "$tmp/out/$f" ]; then fail "$f is not a regular file"; fi
done

# ptctl submit reads what a scene names below its folder with no link on
# the way: a link there is refused before anything is sent, and a FIFO is
# refused at once, not read for ever.
mkdir -p "$tmp/scene"
sed 's|"uri": *"data:[^"]*"|"uri": "data.bin"|' "$src/scenes/cornell_box.gltf" > "$tmp/scene/s.gltf"
ln -s "$tmp/secret" "$tmp/scene/data.bin"
set +e
"$bin/ptctl" submit "$tmp/scene/s.gltf" --res 32x32 --spp 16 --name leak 2> "$tmp/submit.err"
rc=$?
set -e
[ "$rc" != 0 ] || fail "ptctl submitted a scene through a link"
grep -q "data.bin: a symbolic link" "$tmp/submit.err" || fail "refusal: $(cat "$tmp/submit.err")"
rm "$tmp/scene/data.bin"
mkfifo "$tmp/scene/data.bin"
set +e
timeout 20 "$bin/ptctl" submit "$tmp/scene/s.gltf" --res 32x32 --spp 16 --name fifo 2> "$tmp/submit.err"
rc=$?
set -e
if [ "$rc" = 0 ] || [ "$rc" = 124 ]; then fail "ptctl submit with a FIFO in the folder: rc $rc"; fi
grep -q "not a regular file" "$tmp/submit.err" || fail "refusal: $(cat "$tmp/submit.err")"
[ "$("$bin/ptctl" list | grep -c -e leak -e fifo || true)" = 0 ] || fail "a refused scene was queued"

# ptctl fetch: a link at the destination is replaced, its target untouched.
ln -s "$tmp/victim_fetch" "$tmp/dl/img.exr"
"$bin/ptctl" fetch "$id" -o "$tmp/dl/img.exr" || fail "fetch exited $?"
[ "$(cat "$tmp/victim_fetch")" = "precious victim_fetch" ] || fail "fetch wrote through a link"
if [ ! -f "$tmp/dl/img.exr" ] || [ -L "$tmp/dl/img.exr" ]; then fail "the fetched image is a link"; fi
cmp -s "$tmp/dl/img.exr" "$tmp/out/1-links.exr" || fail "the fetched image differs"

# The server does not read an image through a link planted in the output
# folder: the fetch is refused and nothing of the link's target is sent.
rm "$tmp/out/1-links.exr"
ln -s "$tmp/secret" "$tmp/out/1-links.exr"
set +e
"$bin/ptctl" fetch "$id" -o "$tmp/dl/leak.exr" 2> "$tmp/fetch.err"
rc=$?
set -e
[ "$rc" != 0 ] || fail "a fetch through a link succeeded"
[ ! -e "$tmp/dl/leak.exr" ] || fail "a fetch through a link wrote $(cat "$tmp/dl/leak.exr")"
grep -q "not a regular file" "$tmp/fetch.err" || fail "refusal: $(cat "$tmp/fetch.err")"
grep -q "$tmp/out" "$tmp/fetch.err" && fail "the refusal names a server path: $(cat "$tmp/fetch.err")"
"$bin/ptctl" status "$id" > /dev/null || fail "the server stopped serving"
# Nor does the dashboard: the EXR download and the PNG view answer 404 and
# send nothing of the link's target.
# (The dashboard's snapshot follows the loop within about a second.)
for _ in $(seq 100); do
  [ "$(curl -sS -o /dev/null -w '%{http_code}' "$web/api/jobs/$id")" = 200 ] && break
  sleep 0.1
done
[ "$(curl -sS -o /dev/null -w '%{http_code}' "$web/api/jobs/$id")" = 200 ] || fail "/api/jobs/$id"
for u in image.exr image.png; do
  code=$(curl -sS -o "$tmp/dl/leak.$u" -w '%{http_code}' "$web/api/jobs/$id/$u")
  [ "$code" = 404 ] || fail "the dashboard's $u through a link: $code"
  if grep -q "precious secret" "$tmp/dl/leak.$u"; then fail "the dashboard sent the link's target"; fi
done

# A restart does not open what is planted at a running job's image name: a
# FIFO there would block the coordinator before it serves anyone.
kill "$srv_pid"
wait "$srv_pid" 2>/dev/null || true
srv_pid=''
serve2() {
  rm -f "$tmp/port" "$tmp/hport"
  "$bin/ptserve" --state-dir "$tmp/state2" --output-dir "$tmp/out2" --listen 127.0.0.1:0 \
    --port-file "$tmp/port" --tile 16 --chunk 8 --save-interval 0 \
    --http 127.0.0.1:0 --http-port-file "$tmp/hport" -q 2>> "$tmp/serve2.log" &
  srv_pid=$!
  for _ in $(seq 200); do [ -s "$tmp/port" ] && [ -s "$tmp/hport" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start"
  PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
  web=http://127.0.0.1:$(cat "$tmp/hport")
}
serve2
id=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" --res 32x32 --spp 65536 --name fifo)
"$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --cache-dir "$tmp/cache" 2> /dev/null &
wrk_pid=$!
for _ in $(seq 600); do [ -f "$tmp/out2/$id-fifo.exr" ] && break; sleep 0.05; done
[ -f "$tmp/out2/$id-fifo.exr" ] || fail "no progressive image"
kill -9 "$srv_pid" "$wrk_pid"
wait "$srv_pid" "$wrk_pid" 2>/dev/null || true
srv_pid=''
rm "$tmp/out2/$id-fifo.exr"
mkfifo "$tmp/out2/$id-fifo.exr"
serve2
timeout 20 "$bin/ptctl" status "$id" > /dev/null || fail "a FIFO at the image's name blocked the restart"
# The dashboard neither blocks on the FIFO nor runs out of image slots: each
# of more requests than it renders at once is answered 404 at once.
for _ in $(seq 100); do
  [ "$(curl -sS -m 10 -o /dev/null -w '%{http_code}' "$web/api/jobs/$id")" = 200 ] && break
  sleep 0.1
done
for u in image.exr image.png image.png image.png image.png image.png image.png; do
  code=$(curl -sS -m 10 -o /dev/null -w '%{http_code}' "$web/api/jobs/$id/$u" || true)
  [ "$code" = 404 ] || fail "the dashboard's $u with a FIFO at the image's name: $code"
done
# And SIGTERM still stops it.
kill -TERM "$srv_pid"
for _ in $(seq 200); do kill -0 "$srv_pid" 2>/dev/null || break; sleep 0.05; done
if kill -0 "$srv_pid" 2>/dev/null; then fail "ptserve did not stop on SIGTERM"; fi
wait "$srv_pid" 2>/dev/null || true
srv_pid=''
failed=0
echo "PASS"
