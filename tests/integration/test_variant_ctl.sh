#!/usr/bin/env bash
# --variant on the farm: a copy of the Cornell box with KHR_materials_variants
# ("Red" maps the first primitive to a red material, "Plain" maps nothing).
# ptctl submit --variant Red and ptserve --variant Red (one-job mode, local
# workers) are bit-identical to ptworker --scene ... --variant Red, which
# differs from the default render; "Plain" renders as the default; an unknown
# variant is refused at submit, naming the file's variants, and the server
# keeps serving.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_variant_ctl_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

python3 - "$src/scenes/cornell_box.gltf" "$tmp/variants.gltf" <<'PY'
import copy, json, sys
d = json.load(open(sys.argv[1]))
red = copy.deepcopy(d["materials"][d["meshes"][0]["primitives"][0].get("material", 0)])
red["name"] = "red variant"
red.setdefault("pbrMetallicRoughness", {})["baseColorFactor"] = [0.9, 0.05, 0.05, 1]
red.pop("emissiveFactor", None)
d["materials"].append(red)
d.setdefault("extensionsUsed", []).append("KHR_materials_variants")
d.setdefault("extensions", {})["KHR_materials_variants"] = {
    "variants": [{"name": "Red"}, {"name": "Plain"}]}
prim = d["meshes"][0]["primitives"][0]
prim.setdefault("extensions", {})["KHR_materials_variants"] = {
    "mappings": [{"material": len(d["materials"]) - 1, "variants": [0]}]}
json.dump(d, open(sys.argv[2], "w"))
PY

view=(--res 48x32 --spp 16 --seed 3)
"$bin/ptworker" --scene "$tmp/variants.gltf" "${view[@]}" --variant Red --tile 16 --chunk 8 -q \
  -o "$tmp/red_ref.exr"
"$bin/ptworker" --scene "$tmp/variants.gltf" "${view[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/default_ref.exr"
! "$bin/ptexr-diff" "$tmp/red_ref.exr" "$tmp/default_ref.exr" > /dev/null ||
  fail "the Red variant renders as the default"

"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --local 2 --worker-threads 1 --tile 16 --chunk 8 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 100); do [ -s "$tmp/port" ] && break; sleep 0.05; done
[ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
ctl() { "$bin/ptctl" "$@"; }

set +e
ctl submit "$tmp/variants.gltf" "${view[@]}" --variant Blue 2> "$tmp/novariant.log"; rc=$?
set -e
if [ $rc != 1 ] || ! grep -q "no variant named 'Blue'; variants: 'Red', 'Plain'" "$tmp/novariant.log"; then
  fail "unknown variant: rc $rc: $(cat "$tmp/novariant.log")"
fi
red=$(ctl submit "$tmp/variants.gltf" "${view[@]}" --variant Red)
plain=$(ctl submit "$tmp/variants.gltf" "${view[@]}" --variant Plain)
ctl watch "$red" 2> /dev/null || fail "watch exited $?"
ctl watch "$plain" 2> /dev/null || fail "watch exited $?"
ctl fetch "$red" -o "$tmp/red.exr"
ctl fetch "$plain" -o "$tmp/plain.exr"
"$bin/ptexr-diff" "$tmp/red_ref.exr" "$tmp/red.exr" || fail "ptctl --variant image differs"
"$bin/ptexr-diff" "$tmp/default_ref.exr" "$tmp/plain.exr" ||
  fail "a variant that maps nothing differs from the default"

"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" --variant Red --tile 16 --chunk 8 -q \
  -o "$tmp/red_local.exr" "$tmp/variants.gltf" 2> "$tmp/red_local.log" ||
  fail "ptserve --local --variant: $(cat "$tmp/red_local.log")"
"$bin/ptexr-diff" "$tmp/red_ref.exr" "$tmp/red_local.exr" || fail "ptserve --variant image differs"
set +e
"$bin/ptserve" --local 1 "${view[@]}" --variant Blue -q -o "$tmp/x.exr" "$tmp/variants.gltf" \
  2> "$tmp/local_blue.log"; rc=$?
set -e
if [ $rc != 1 ] || ! grep -q "no variant named 'Blue'" "$tmp/local_blue.log"; then
  fail "ptserve --variant Blue: rc $rc: $(cat "$tmp/local_blue.log")"
fi
grep -q "Sanitizer\|runtime error:" "$tmp/serve.log" && fail "sanitizer report"
failed=0
echo "ok: --variant through ptctl submit, ptserve one-job mode and ptworker"
