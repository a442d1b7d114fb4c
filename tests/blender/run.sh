#!/usr/bin/env bash
# Runs one Blender test script (tests/blender/test_*.py) headless against a
# real ptserve queue on 127.0.0.1 with one local worker and a token file:
#   bash tests/blender/run.sh test_render_frame.py
# The script gets, after '--': the queue's HOST:PORT, the token file, a
# scratch folder, the bin folder and the source folder. Blender runs with
# --factory-startup and its own user folders under the scratch folder, so
# the add-on is installed as a user installs it and nothing of the user's
# is read or changed. A test_ui_*.py runs with Blender's window under Xvfb.
# Exit 77 (skipped) only where Blender is not
# installed (or Xvfb, for a window) and the test is not in CI
# (deploy/setup.sh installs both).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
script=$src/tests/blender/${1:?usage: run.sh TEST.py}
blender=${PT_BLENDER:-blender}
if ! command -v "$blender" > /dev/null; then
  if [ "${CI:-}" = true ]; then
    echo "FAIL: no '$blender' (deploy/setup.sh installs Blender)" >&2
    exit 1
  fi
  echo "skipped: no '$blender' (deploy/setup.sh installs Blender)"
  exit 77
fi
if [[ $1 == test_ui_* ]] && ! command -v xvfb-run > /dev/null; then
  if [ "${CI:-}" = true ]; then
    echo "FAIL: no xvfb-run (deploy/setup.sh installs xvfb)" >&2
    exit 1
  fi
  echo "skipped: no xvfb-run for Blender's window (deploy/setup.sh installs xvfb)"
  exit 77
fi
tmp=$(mktemp -d /tmp/pt_blender_XXXXXX)
srv_pid=
failed=1
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2> /dev/null; then wait "$srv_pid" 2> /dev/null || true; fi
  if [ "$failed" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT

head -c 32 /dev/urandom | base64 > "$tmp/farm.token"
chmod 600 "$tmp/farm.token"
# --tile 16 --chunk 8 as the tests' ptworker references use; --max-spp so a
# test can ask for a job the queue refuses.
"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --token-file "$tmp/farm.token" --local 1 --worker-threads 2 \
  --tile 16 --chunk 8 --max-spp 4096 2> "$tmp/ptserve.log" &
srv_pid=$!
for _ in $(seq 100); do [ -s "$tmp/port" ] && break; sleep 0.05; done
if ! [ -s "$tmp/port" ]; then
  echo "FAIL: ptserve did not start: $(cat "$tmp/ptserve.log")" >&2
  exit 1
fi

mkdir -p "$tmp/user/scripts" "$tmp/user/config"
export PYTHONDONTWRITEBYTECODE=1 PATH="$bin:$PATH" BLENDER_USER_SCRIPTS="$tmp/user/scripts"
export BLENDER_USER_CONFIG="$tmp/user/config"
args=("127.0.0.1:$(cat "$tmp/port")" "$tmp/farm.token" "$tmp" "$bin" "$src")
start=$(date +%s.%N)
set +e
if [[ $1 == test_ui_* ]]; then
  # With its window, under a virtual display: Blender opens a file given on
  # the command line without its splash screen.
  "$blender" -b --factory-startup --python-expr \
    "import bpy; bpy.ops.wm.save_as_mainfile(filepath='$tmp/start.blend')" > "$tmp/start.log" 2>&1
  timeout 300 xvfb-run -a -s "-screen 0 1280x800x24" "$blender" --factory-startup "$tmp/start.blend" \
    --python "$script" -- "${args[@]}" > "$tmp/blender.log" 2>&1
else
  "$blender" -b --factory-startup --python-exit-code 1 --python "$script" -- "${args[@]}" \
    > "$tmp/blender.log" 2>&1
fi
rc=$?
set -e
end=$(date +%s.%N)
grep -E '^(ok|FAIL|note)' "$tmp/blender.log" || true
if [ $rc != 0 ] || ! grep -q '^PASS' "$tmp/blender.log"; then
  echo "FAIL: $1 (blender exit $rc); its log:" >&2
  tail -40 "$tmp/blender.log" >&2
  exit 1
fi
printf '%s passed in %s s (Blender %s)\n' "$1" "$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.1f", b - a }')" \
  "$("$blender" --version 2> /dev/null | head -1 | sed 's/^Blender //')"
failed=0
