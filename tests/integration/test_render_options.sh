#!/usr/bin/env bash
# One table of render options (common/render/options.h): ptworker --scene,
# ptserve (one job) and ptctl submit refuse the same bad values with the
# same words after their own name, and exit 2, before loading anything.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scene=$src/scenes/cornell_box.gltf
tmp=$(mktemp -d /tmp/pt_render_options_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

# $@: one bad option (and its value); each program's message without its
# name must be the same line.
same_refusal() {
  local rc want='' got prog
  for prog in worker serve ctl; do
    rc=0
    case $prog in
      worker) "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" "$@" 2> "$tmp/$prog.err" || rc=$? ;;
      serve) "$bin/ptserve" --local 1 -o "$tmp/x.exr" "$@" "$scene" 2> "$tmp/$prog.err" || rc=$? ;;
      ctl) "$bin/ptctl" submit "$scene" "$@" --server 127.0.0.1:1 2> "$tmp/$prog.err" || rc=$? ;;
    esac
    [ "$rc" = 2 ] || fail "pt$prog $*: exit $rc: $(cat "$tmp/$prog.err")"
    got=$(head -n 1 "$tmp/$prog.err" | sed -E 's/^pt(worker|serve|ctl)( submit)?: //')
    if [ -z "$want" ]; then want=$got; fi
    [ "$got" = "$want" ] || fail "$*: pt$prog says '$got', another '$want'"
  done
  if ls "$tmp"/x.* > /dev/null 2>&1; then fail "$*: a refused render wrote a file"; fi
}
same_refusal --spp 0
same_refusal --spp 16777217
same_refusal --res 64x
same_refusal --res 20000x10
same_refusal --seed -1
same_refusal --max-depth 1025
same_refusal --min-spp 1
same_refusal --target-error 0
same_refusal --min-gain nan
same_refusal --env-strength -1
same_refusal --background 1,2
same_refusal --shutter 0.6,0.4
same_refusal --fps 0
same_refusal --fov 30
same_refusal --camera-from 1,1,1 --camera-at 1,1,1
same_refusal --camera-from 0,0,1 --camera-at 0,0,0 --camera Camera
same_refusal --env a.hdr --background 1,1,1
same_refusal --target-error 0.1 --min-gain 1e-6
same_refusal --camera "$(printf 'c%.0s' $(seq 65))"
failed=0
echo "ok"
