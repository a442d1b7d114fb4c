#!/usr/bin/env bash
# The light tree is built by every worker from the scene alone: a farm's image
# of a scene with many emitters is the standalone render's, bit for bit, with
# 1 and 3 local workers (EmissiveStrengthTest: 60 emissive triangles, so NEE
# chooses through the tree). Needs ../shared (skipped without it, unless
# CI=true).
set -euo pipefail
bin=${PT_BIN:?}
shared=${PT_SHARED_SCENES:?}
tmp=$(mktemp -d /tmp/pt_light_tree_farm_XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
scene=$shared/EmissiveStrengthTest/EmissiveStrengthTest.glb
if [[ ! -f $scene ]]; then
    if [[ ${CI:-} == true ]]; then
        fail "$scene is missing (CI=true)"
    fi
    echo "SKIP: $scene is missing"
    exit 77
fi
common=(--res 48x32 --spp 32 --tile 16 -q)

"$bin/ptworker" --scene "$scene" "${common[@]}" --threads 2 -o "$tmp/ref.exr"
for n in 1 3; do
    "$bin/ptserve" --local "$n" --worker-threads 1 "${common[@]}" -o "$tmp/farm$n.exr" \
        "$scene" 2> "$tmp/serve$n.log" || fail "ptserve --local $n: $(cat "$tmp/serve$n.log")"
    "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/farm$n.exr" > "$tmp/diff$n" ||
        fail "the farm with $n workers: $(cat "$tmp/diff$n")"
done
echo "PASS"
