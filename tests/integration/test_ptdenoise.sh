#!/usr/bin/env bash
# ptdenoise end to end on EXRs with the denoiser's passes (ptpasses-exr: a
# synthetic render whose truth is known): the output keeps every channel of
# the input bit for bit and adds denoised.R/G/B, closer to the truth than
# the beauty; a PNG preview beside it, or alone with -o X.png; the same
# bytes for 1 and 3 threads, and cut into regions by --max-memory. Refused with exit 1 and a message naming the
# cause: a render without the passes (a plain ptworker EXR), a missing
# pass, NaN, an absurd normal or a negative variance, a pixel with fewer than
# 2 samples, a file that is not an EXR; bad usage exits 2. No refusal leaves
# an output file.
set -euo pipefail
# shellcheck source=tests/integration/lib_build.sh
. "$(dirname "$0")/lib_build.sh"
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_denoise_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "files kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

"$bin/ptpasses-exr" "$tmp/in.exr" 96 80 0.1 7 "$tmp/truth.exr"
"$bin/ptdenoise" "$tmp/in.exr" -o "$tmp/out.exr" --threads 1 2> "$tmp/log" ||
  fail "denoise: exit $?: $(cat "$tmp/log")"
grep -q "96x80 denoised" "$tmp/log" || fail "no summary: $(cat "$tmp/log")"
[ -s "$tmp/out.png" ] || fail "no preview beside out.exr"
"$bin/ptexr-diff" --base "$tmp/in.exr" "$tmp/out.exr" > /dev/null || fail "the beauty changed"
"$bin/ptpasses-exr" --error "$tmp/out.exr" "$tmp/truth.exr" > "$tmp/mse" ||
  fail "denoised not closer to the truth: $(cat "$tmp/mse")"
cat "$tmp/mse"

# --despeckle 0 (pure NFOR) is another result, still closer to the truth.
"$bin/ptdenoise" "$tmp/in.exr" -o "$tmp/nfor.exr" --despeckle 0 --no-preview 2> /dev/null ||
  fail "--despeckle 0: exit $?"
"$bin/ptpasses-exr" --error "$tmp/nfor.exr" "$tmp/truth.exr" > /dev/null ||
  fail "--despeckle 0: not closer to the truth"

# Any thread count: the same file, byte for byte.
"$bin/ptdenoise" "$tmp/in.exr" -o "$tmp/out3.exr" --threads 3 --no-preview 2> /dev/null
cmp -s "$tmp/out.exr" "$tmp/out3.exr" || fail "3 threads wrote another file than 1"
[ ! -e "$tmp/out3.png" ] || fail "--no-preview wrote a preview"

# --max-memory: a frame whose denoising needs more is denoised in regions,
# the same file byte for byte (the release build only: test_denoise checks
# the regions' code under the sanitizers, which denoise ten times slower);
# one that fits is not cut; too little for any region is refused (below).
if ! sanitized; then
  "$bin/ptpasses-exr" "$tmp/wide.exr" 1024 64 0.1 7
  "$bin/ptdenoise" "$tmp/wide.exr" -o "$tmp/wide_dn.exr" --threads 2 --no-preview 2> /dev/null
  "$bin/ptdenoise" "$tmp/wide.exr" -o "$tmp/wide_rg.exr" --threads 2 --no-preview \
    --max-memory 25 2> "$tmp/log" || fail "--max-memory 25: exit $?: $(cat "$tmp/log")"
  grep -q "in regions of" "$tmp/log" || fail "--max-memory 25: no regions: $(cat "$tmp/log")"
  cmp -s "$tmp/wide_dn.exr" "$tmp/wide_rg.exr" || fail "regions wrote another file than the whole"
fi
"$bin/ptdenoise" "$tmp/in.exr" -o "$tmp/fits.exr" --no-preview --max-memory 64 2> "$tmp/log"
grep -q "96x80 denoised in" "$tmp/log" || fail "--max-memory 64 cut the frame: $(cat "$tmp/log")"

# -o X.png: the preview alone, through the view transform.
"$bin/ptdenoise" "$tmp/in.exr" -o "$tmp/only.png" --view agx --exposure 1 2> /dev/null ||
  fail "-o only.png: exit $?"
[ "$(head -c 8 "$tmp/only.png" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ] ||
  fail "only.png is not a PNG"
[ ! -e "$tmp/only.exr" ] || fail "-o only.png wrote an EXR"

refused() { # NAME EXPECTED_RC PATTERN ARGS...
  local name=$1 want=$2 pattern=$3 rc=0
  shift 3
  "$bin/ptdenoise" "$@" 2> "$tmp/err" || rc=$?
  [ "$rc" = "$want" ] || fail "$name: exit $rc, want $want: $(cat "$tmp/err")"
  grep -q -- "$pattern" "$tmp/err" || fail "$name: '$pattern' not in: $(cat "$tmp/err")"
  if [ -e "$tmp/bad.exr" ] || [ -e "$tmp/bad.png" ]; then fail "$name left an output"; fi
}

# A render without passes: the renderer's own EXR.
"$bin/ptworker" --scene "$src/scenes/cornell_box.gltf" --res 16x16 --spp 4 --threads 1 -q \
  -o "$tmp/plain.exr"
refused "no passes" 1 "missing halfA.R, halfA.G" "$tmp/plain.exr" -o "$tmp/bad.exr"
refused "no passes hint" 1 "render it with --denoise" "$tmp/plain.exr" -o "$tmp/bad.exr"

"$bin/ptpasses-exr" "$tmp/nodepth.exr" 16 16 0.1 1 --drop depth.variance
refused "a missing pass" 1 "missing depth.variance)" "$tmp/nodepth.exr" -o "$tmp/bad.exr"

"$bin/ptpasses-exr" "$tmp/nan.exr" 16 16 0.1 1 --nan albedo.G
refused "NaN albedo" 1 "albedo.G at (1, 2) is nan" "$tmp/nan.exr" -o "$tmp/bad.exr"
"$bin/ptpasses-exr" "$tmp/nanr.exr" 16 16 0.1 1 --nan R
refused "NaN beauty" 1 "R at (1, 2) is nan" "$tmp/nanr.exr" -o "$tmp/bad.exr"
"$bin/ptpasses-exr" "$tmp/normal.exr" 16 16 0.1 1 --set N.Y=40
refused "absurd normal" 1 "N.Y at (1, 2) is 40" "$tmp/normal.exr" -o "$tmp/bad.exr"
"$bin/ptpasses-exr" "$tmp/var.exr" 16 16 0.1 1 --set depth.variance=-1
refused "negative variance" 1 "depth.variance at (1, 2) is -1" "$tmp/var.exr" -o "$tmp/bad.png"
"$bin/ptpasses-exr" "$tmp/huge.exr" 16 16 0.1 1 --set halfB.G=1e30
refused "absurd half" 1 "halfB.G at (1, 2)" "$tmp/huge.exr" -o "$tmp/bad.exr"

"$bin/ptpasses-exr" "$tmp/one.exr" 16 16 0.1 1 --set samples=1
refused "one sample" 1 "pixel (1, 2) has 1 samples" "$tmp/one.exr" -o "$tmp/bad.exr"

printf 'not an exr\n' > "$tmp/junk.exr"
refused "not an EXR" 1 "not a readable OpenEXR file" "$tmp/junk.exr" -o "$tmp/bad.exr"
refused "a missing file" 1 "missing.exr" "$tmp/missing.exr" -o "$tmp/bad.exr"
head -c 3000 "$tmp/in.exr" > "$tmp/cut.exr"
refused "a truncated file" 1 "cut.exr" "$tmp/cut.exr" -o "$tmp/bad.exr"

refused "no -o" 2 "no -o OUT" "$tmp/in.exr"
refused "no input" 2 "no input EXR" -o "$tmp/bad.exr"
refused "a bad format" 2 "the output's format follows its name" "$tmp/in.exr" -o "$tmp/bad.tif"
refused "bad threads" 2 "threads" "$tmp/in.exr" -o "$tmp/bad.exr" --threads 0
refused "bad view" 2 "standard, filmic or agx" "$tmp/in.exr" -o "$tmp/bad.exr" --view aces
refused "bad despeckle" 2 "not 0 or at least 1" "$tmp/in.exr" -o "$tmp/bad.exr" --despeckle 0.5
refused "bad max-memory" 2 "max-memory" "$tmp/in.exr" -o "$tmp/bad.exr" --max-memory 0
refused "too little memory" 1 "is too little" "$tmp/in.exr" -o "$tmp/bad.exr" --max-memory 1
help=$("$bin/ptdenoise" --help)
[[ $help == "usage: ptdenoise"* ]] || fail "--help"
# Worked examples first, as the other programs' help: within its first lines.
head -12 <<< "$help" | grep -q "^examples:" || fail "--help does not open with examples"
"$bin/ptdenoise" --version | grep -q "^ptdenoise " || fail "--version"
failed=0
echo "ok"
