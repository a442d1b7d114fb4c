#!/usr/bin/env bash
# Installs the Debian 12 packages ptfarm needs to build, test and run.
# Idempotent: when everything is present it installs nothing and says so.
# Run as root, or as a user with sudo.
#
#   deploy/setup.sh           build + test dependencies
#   deploy/setup.sh --build   only what building the programs needs (container images)
#   deploy/setup.sh --runtime only what the binaries need at run time
set -euo pipefail

build_pkgs=(
  gcc g++ make cmake pkg-config        # toolchain
  libembree-dev                        # ray queries (Embree 3)
  libopenexr-dev                       # OpenEXR output (OpenEXRCore C API)
  libtinygltf-dev nlohmann-json3-dev   # glTF 2.0 import
  libstb-dev                           # image decoding for glTF, PNG previews
  libssl-dev                           # SHA-256 scene hashes, HMAC authentication
  libmicrohttpd-dev                    # ptserve --http: the dashboard, API, /metrics
  libdraco-dev                         # KHR_draco_mesh_compression meshes in glTF
  libwebp-dev                          # EXT_texture_webp images in glTF
  libmeshoptimizer-dev                 # EXT_meshopt_compression buffers in glTF
  zlib1g-dev                           # the guiding distribution, deflated on the wire
)
test_pkgs=(
  clang libclang-rt-14-dev             # libFuzzer targets, sanitizer runtime
  ninja-build                          # tests/run.sh: its four builds, a quarter faster than make
  lld                                  # tests/run.sh: links the builds' programs faster than ld
  python3                              # scene generator and test helpers
  iproute2                             # test_multihost: network namespaces, veth (ip, ss)
  python3-yaml                         # test_deploy: parses the Kubernetes manifests
  systemd                              # test_deploy: systemd-analyze verify of the units
  clang-format                         # tests/check_format.sh: C and C++ formatting
  shellcheck                           # tests/check_shell.sh: the shell scripts
  curl prometheus                      # test_http*: the dashboard's API, promtool check metrics
  chromium                             # test_http_browser: the job page in a headless browser
  blender python3-numpy                # tests/blender: the add-on (numpy: Blender's glTF exporter)
  xvfb                                 # tests/blender: the panel's screenshot under a virtual display
)
# One line: test_deploy reads it to check the release image's libraries.
runtime_pkgs=(libembree3-3 libopenexr-3-1-30 libstb0 libssl3 libmicrohttpd12 libdraco7 libwebp7 libmeshoptimizer2d zlib1g)

case "${1:-}" in
"") pkgs=("${build_pkgs[@]}" "${test_pkgs[@]}") ;;
--build) pkgs=("${build_pkgs[@]}") ;;
--runtime) pkgs=("${runtime_pkgs[@]}") ;;
*)
  echo "usage: deploy/setup.sh [--build|--runtime]" >&2
  exit 2
  ;;
esac

missing=()
for p in "${pkgs[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [[ ${#missing[@]} -eq 0 ]]; then
  echo "setup: all ${#pkgs[@]} packages present; nothing to install"
  exit 0
fi

as_root=()
if [[ $(id -u) -ne 0 ]]; then
  if command -v sudo >/dev/null; then
    as_root=(sudo)
  else
    echo "setup: missing packages (${missing[*]}) and not root; run as root" >&2
    exit 1
  fi
fi
echo "setup: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" apt-get update -qq
"${as_root[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "setup: done"
