#!/usr/bin/env bash
# Compressed and quantized variants of two sample assets with normal maps
# and UVs (DamagedHelmet, a GLB; ToyCar, a .gltf with clearcoat, sheen and
# glass), written by ptgltf-pack (tests/tools/gltf_pack.cpp, as gltfpack
# would), rendered with ptworker against the original (64x48, 4 spp, seed 7,
# a constant background: no environment fireflies to dominate the rms):
# - EXT_meshopt_compression, lossless, indices in mode INDICES (their
#   order kept): bit-identical to the original;
# - the same with indices in mode TRIANGLES (gltfpack's choice): the codec
#   may rotate a triangle's corners, so the hit points differ by float
#   rounding: within the paired z-test (ptexr-diff --z 4) and the noise
#   ratio below;
# - KHR_mesh_quantization (int16 positions dequantized by a node matrix,
#   int8 normals, uint16 UVs): the floats change, so the test is ptexr-diff
#   --noise 0.3 against a render of the original with another seed: the
#   rms of (variant - original) over the rms of (seed 8 - seed 7). The
#   variant shares the original's random numbers, so the ratio's square is
#   about the share of samples whose path the quantization turned aside
#   (each then as far off as an independent sample). Positions move by at
#   most sqrt(3)/2 x 1/65534 of the mesh's extent (0.002 pixel here),
#   normals by at most sqrt(3)/2 x 1/127 = 0.0068 rad, so only rays that
#   graze an edge or a sampling decision turn aside: measured 0.07-0.11;
#   0.3 allows 9 % of the samples;
# - both, as gltfpack writes by default (the quantized views coded by
#   meshopt, indices in mode INDICES): bit-identical to the quantized one;
#   and with the normals through meshopt's 8-bit OCTAHEDRAL filter (as
#   gltfpack -cc), which moves a normal by up to about 1.5 / 127 rad (two
#   coordinates rounded, the octahedron's stretch at most about 2): within
#   the same noise ratio (measured 0.10-0.15);
# - the test fails when the decoding is broken: a dequantization scale off
#   by 0.5 % (--scale-error 1.005, a geometric error 300 times the
#   quantization step) measured 0.54-0.73 and must exceed 0.3; a meshopt
#   stream with one bit flipped must be refused or render differently.
# - every other sample asset in ../shared, coded by meshopt (INDICES),
#   renders bit-identical to itself at 32x24, 1 spp (skins and morph
#   targets included; the sparse and the Draco files are left out, which
#   ptgltf-pack refuses; the two assets above are not rendered again). Not
#   in a sanitizer build: there the two assets above take the decoder
#   through its modes and filters (and fuzz_meshopt takes it further), and
#   its 50 more scene loads were 43 % of this test's CPU time under ASan
#   (65 s of CPU with them, 37 s without).
# Needs ../shared (skipped without it, a failure when CI=true).
set -euo pipefail
bin=${PT_BIN:?}
scenes=${PT_SHARED_SCENES:?}
helmet=$scenes/DamagedHelmet/DamagedHelmet.glb
car=$scenes/ToyCar/ToyCar.gltf
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$helmet" "$car"
tmp=$(mktemp -d /tmp/pt_gltf_pack_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

# ToyCar's images are files beside it, which the variants name too (the
# importer refuses symbolic links).
cp "$scenes"/ToyCar/*.png "$tmp/"

render() { # NAME FILE SEED [camera options]
  local name=$1 file=$2 seed=$3
  shift 3
  "$bin/ptworker" --scene "$file" --res 64x48 --spp 4 --seed "$seed" --background "0.6,0.7,0.8" \
    "$@" -q -o "$tmp/$name.exr" 2> "$tmp/$name.log"
}

for asset in helmet car; do
  if [ $asset = helmet ]; then
    src=$helmet
    cam=(--camera-from "0,0.3,3" --camera-at "0,0,0" --fov 45) # fixed: no framing by the bounds
  else
    src=$car
    cam=() # the file's camera
  fi
  pack() { # MODE NAME [options]
    local mode=$1 name=$2
    shift 2
    "$bin/ptgltf-pack" "$mode" "$src" "$tmp/$name.glb" "$@" ||
      fail "ptgltf-pack $mode $asset $*"
  }
  pack meshopt ${asset}_seq --sequence
  pack meshopt ${asset}_tri
  pack meshopt ${asset}_flip --sequence --corrupt
  pack quantize ${asset}_q
  pack quantize ${asset}_qbad --scale-error 1.005
  pack quantize+meshopt ${asset}_qm --sequence
  pack quantize+meshopt ${asset}_qf --sequence --filter
  grep -q '"filter":"OCTAHEDRAL"' "$tmp/${asset}_qf.glb" || fail "$asset: no filtered view"
  grep -q '"extensionsRequired":\["EXT_meshopt_compression"\]' "$tmp/${asset}_seq.glb" ||
    fail "$asset: the meshopt variant does not require EXT_meshopt_compression"
  grep -q '"mode":"TRIANGLES"' "$tmp/${asset}_tri.glb" || fail "$asset: no TRIANGLES view"
  grep -q 'KHR_mesh_quantization' "$tmp/${asset}_q.glb" || fail "$asset: not quantized"

  render ${asset}_a "$src" 7 "${cam[@]}" || fail "$asset: $(cat "$tmp/${asset}_a.log")"
  render ${asset}_c "$src" 8 "${cam[@]}" || fail "$asset seed 8: $(cat "$tmp/${asset}_c.log")"
  for v in seq tri q qbad qm qf; do
    render ${asset}_$v "$tmp/${asset}_$v.glb" 7 "${cam[@]}" ||
      fail "$asset $v: $(cat "$tmp/${asset}_$v.log")"
    if grep -q "warning" "$tmp/${asset}_$v.log"; then
      # Only the original's own warnings (occlusion textures) may appear.
      if grep "warning" "$tmp/${asset}_$v.log" | grep -qv "occlusion textures are ignored"; then
        fail "$asset $v: $(cat "$tmp/${asset}_$v.log")"
      fi
    fi
  done
  a=$tmp/${asset}_a.exr
  c=$tmp/${asset}_c.exr
  "$bin/ptexr-diff" "$a" "$tmp/${asset}_seq.exr" > "$tmp/${asset}_seq.diff" ||
    fail "$asset: the lossless meshopt variant is not bit-identical: $(cat "$tmp/${asset}_seq.diff")"
  "$bin/ptexr-diff" --z 4 "$a" "$tmp/${asset}_tri.exr" > "$tmp/${asset}_tri.diff" ||
    fail "$asset: meshopt TRIANGLES: $(cat "$tmp/${asset}_tri.diff")"
  "$bin/ptexr-diff" --noise 0.3 "$a" "$tmp/${asset}_tri.exr" "$c" >> "$tmp/${asset}_tri.diff" ||
    fail "$asset: meshopt TRIANGLES: $(cat "$tmp/${asset}_tri.diff")"
  "$bin/ptexr-diff" --noise 0.3 "$a" "$tmp/${asset}_q.exr" "$c" > "$tmp/${asset}_q.diff" ||
    fail "$asset: the quantized variant is too far from the original: $(cat "$tmp/${asset}_q.diff")"
  echo "$asset quantized: $(tr '\n' ' ' < "$tmp/${asset}_q.diff")"
  "$bin/ptexr-diff" "$tmp/${asset}_q.exr" "$tmp/${asset}_qm.exr" > "$tmp/${asset}_qm.diff" ||
    fail "$asset: quantized and meshopt-coded differs from quantized: $(cat "$tmp/${asset}_qm.diff")"
  "$bin/ptexr-diff" --noise 0.3 "$a" "$tmp/${asset}_qf.exr" "$c" > "$tmp/${asset}_qf.diff" ||
    fail "$asset: octahedral normals too far from the original: $(cat "$tmp/${asset}_qf.diff")"
  if "$bin/ptexr-diff" --noise 0.3 "$a" "$tmp/${asset}_qbad.exr" "$c" > "$tmp/${asset}_qbad.diff"; then
    fail "$asset: a dequantization scale off by 0.5 % passes: $(cat "$tmp/${asset}_qbad.diff")"
  fi
  if render ${asset}_flip "$tmp/${asset}_flip.glb" 7 "${cam[@]}"; then
    if "$bin/ptexr-diff" "$a" "$tmp/${asset}_flip.exr" > /dev/null; then
      fail "$asset: a meshopt stream with a bit flipped renders as the original"
    fi
  else
    grep -q "EXT_meshopt_compression" "$tmp/${asset}_flip.log" ||
      fail "$asset: the flipped stream's error does not name the extension: $(cat "$tmp/${asset}_flip.log")"
  fi
done

# Every sample asset, coded by meshopt. The two above are: their meshopt
# (INDICES) variants were just found bit-identical at a larger size.
coded="the other sample assets are not coded (sanitizer build)"
if ! sanitized; then
  mkdir "$tmp/all"
  n=2
  while IFS= read -r f; do
    if [ "$f" = "$helmet" ] || [ "$f" = "$car" ]; then continue; fi
    rm -f "$tmp"/all/*
    for img in "$(dirname "$f")"/*.png "$(dirname "$f")"/*.jpg "$(dirname "$f")"/*.jpeg; do
      if [ -f "$img" ]; then cp "$img" "$tmp/all/"; fi
    done
    if ! "$bin/ptgltf-pack" meshopt "$f" "$tmp/all/x.glb" --sequence 2> "$tmp/all.log"; then
      grep -q "sparse accessors\|Draco primitives" "$tmp/all.log" || fail "$f: $(cat "$tmp/all.log")"
      continue
    fi
    for v in a x; do
      file=$f
      if [ $v = x ]; then file=$tmp/all/x.glb; fi
      "$bin/ptworker" --scene "$file" --res 32x24 --spp 1 --threads 1 --seed 3 \
        --background "0.5,0.5,0.5" -q -o "$tmp/all/$v.exr" 2> "$tmp/all.log" ||
        fail "$f ($v): $(cat "$tmp/all.log")"
    done
    "$bin/ptexr-diff" "$tmp/all/a.exr" "$tmp/all/x.exr" > "$tmp/all.log" ||
      fail "$f: its meshopt variant differs: $(cat "$tmp/all.log")"
    n=$((n + 1))
  done < <(find "$scenes" \( -name '*.gltf' -o -name '*.glb' \) | sort)
  [ $n -ge 20 ] || fail "only $n sample assets coded by meshopt"
  coded="$n sample assets coded by meshopt render bit-identical"
fi

failed=0
echo "ok: meshopt variants bit-identical (INDICES) or within rounding (TRIANGLES), quantized"
echo "    variants within their noise ratio and equal to their meshopt coding, a wrong scale"
echo "    and a flipped bit caught; $coded"
