#!/usr/bin/env bash
# The denoiser on real renders: ptworker --passes albedo,normal,depth,halves
# on the Cornell box, then ptdenoise. Against a 1,024-spp reference of
# another seed, the denoised image has a lower relMSE than the raw one at
# 16 and at 64 spp, its error falls from 16 to 64 spp, and its mean stays
# within 1 % of the raw image's; the denoised layer is the same bytes for 1
# and 3 threads; the beauty and every pass are kept bit for bit; a
# transparent render's preview is RGBA.
# Skipped (77) while ptworker writes no passes (before the render passes
# are in the build).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_denoise_render_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "files kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

# The help text whole, then matched (grep -q would close the pipe early).
help=$("$bin/ptworker" --help 2>&1 || true)
if [[ $help != *--passes* ]]; then
  echo "skipped: this ptworker has no --passes"
  failed=0
  exit 77
fi
box=$src/scenes/cornell_box.gltf
view=(--scene "$box" --res 64x64 --threads 2 -q)
"$bin/ptworker" "${view[@]}" --spp 1024 --seed 2 -o "$tmp/ref.exr" 2> /dev/null
metric() { # NAME IMAGE [--layer L]: the value of ptbench error's line NAME
  local name=$1 img=$2
  shift 2
  "$bin/ptbench" error "$img" "$tmp/ref.exr" "$@" | awk -v n="$name" '$1 == n { print $2 }'
}
prev=
for spp in 16 64; do
  "$bin/ptworker" "${view[@]}" --spp $spp --seed 1 --passes albedo,normal,depth,halves \
    -o "$tmp/low$spp.exr" 2> /dev/null
  "$bin/ptdenoise" "$tmp/low$spp.exr" -o "$tmp/dn$spp.exr" --threads 1 --no-preview 2> /dev/null ||
    fail "ptdenoise at $spp spp: exit $?"
  raw=$(metric relMSE "$tmp/dn$spp.exr")
  dn=$(metric relMSE "$tmp/dn$spp.exr" --layer denoised)
  echo "$spp spp: relMSE raw $raw, denoised $dn"
  awk -v a="$dn" -v b="$raw" 'BEGIN { exit !(a < b) }' || fail "$spp spp: denoised $dn >= raw $raw"
  if [ -n "$prev" ]; then
    awk -v a="$dn" -v b="$prev" 'BEGIN { exit !(a < b) }' ||
      fail "$spp spp: denoised $dn did not fall from $prev"
  fi
  prev=$dn
  m_raw=$("$bin/ptbench" error "$tmp/dn$spp.exr" --constant 0 | awk '$1 == "mean" { print $2 + $3 + $4 }')
  m_dn=$("$bin/ptbench" error "$tmp/dn$spp.exr" --constant 0 --layer denoised |
    awk '$1 == "mean" { print $2 + $3 + $4 }')
  awk -v a="$m_dn" -v b="$m_raw" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d <= 0.01 * b) }' ||
    fail "$spp spp: mean $m_dn vs raw $m_raw"
done
"$bin/ptexr-diff" --base "$tmp/low64.exr" "$tmp/dn64.exr" > /dev/null || fail "the beauty changed"
"$bin/ptdenoise" "$tmp/low64.exr" -o "$tmp/dn64t3.exr" --threads 3 --no-preview 2> /dev/null
cmp -s "$tmp/dn64.exr" "$tmp/dn64t3.exr" || fail "3 threads wrote another file than 1"
# A transparent render: its preview is RGBA (PNG colour type 6, byte 25).
"$bin/ptworker" "${view[@]}" --spp 16 --seed 1 --transparent \
  --passes albedo,normal,depth,halves -o "$tmp/alpha.exr" 2> /dev/null
"$bin/ptdenoise" "$tmp/alpha.exr" -o "$tmp/alpha_dn.exr" 2> /dev/null || fail "transparent: exit $?"
[ "$(od -An -tu1 -j25 -N1 "$tmp/alpha_dn.png" | tr -d ' ')" = 6 ] ||
  fail "the transparent render's preview is not RGBA"
failed=0
echo ok
