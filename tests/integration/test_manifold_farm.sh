#!/usr/bin/env bash
# Manifold NEE (common/render/manifold.h) solves each chain from the sample's
# own numbers and the scene: a farm's image of the glass ball with things
# inside under the studio map is the standalone render's, bit for bit, with 1
# and 3 local workers, and the standalone render did connect chains through
# the glass. Needs ../shared's map (skipped without it, unless CI=true).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
shared=${PT_SHARED_SCENES:?}
tmp=$(mktemp -d /tmp/pt_manifold_farm_XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
env_map=$shared/../envs/studio_small_03_1k.hdr
if [[ ! -f $env_map ]]; then
    if [[ ${CI:-} == true ]]; then
        fail "$env_map is missing (CI=true)"
    fi
    echo "SKIP: $env_map is missing"
    exit 77
fi
scene=$src/scenes/glass_things.gltf
common=(--res 48x32 --spp 16 --tile 16 --env "$env_map")

"$bin/ptworker" --scene "$scene" "${common[@]}" --threads 2 -o "$tmp/ref.exr" 2> "$tmp/ref.log" ||
    fail "ptworker: $(cat "$tmp/ref.log")"
grep -q 'light paths through thick glass connected' "$tmp/ref.log" ||
    fail "no chain through the glass was connected: $(cat "$tmp/ref.log")"
for n in 1 3; do
    "$bin/ptserve" --local "$n" --worker-threads 1 "${common[@]}" -q -o "$tmp/farm$n.exr" \
        "$scene" 2> "$tmp/serve$n.log" || fail "ptserve --local $n: $(cat "$tmp/serve$n.log")"
    "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/farm$n.exr" > "$tmp/diff$n" ||
        fail "the farm with $n workers: $(cat "$tmp/diff$n")"
done
echo "PASS"
