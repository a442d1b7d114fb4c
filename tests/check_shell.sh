#!/usr/bin/env bash
# Runs shellcheck over every shell script under version control: the *.sh
# files and every file whose first line is a sh or bash #! line (.ci/run,
# deploy/slurm/ptfarm.sbatch). Exits 1 on any finding, of any severity; a
# finding that is wrong for a line is silenced there with a
# `# shellcheck disable=SCxxxx` comment that says why. Needs shellcheck
# (deploy/setup.sh installs it) and git; works from any folder.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v shellcheck >/dev/null; then
  echo "check_shell: shellcheck is not installed (Debian: shellcheck)" >&2
  exit 1
fi
scripts=()
shebang='^#!.*[/ ](ba)?sh( |$)'
while IFS= read -r -d '' f; do
  [[ -f $f ]] || continue
  # The first line read by bash itself: a head and a grep for each of the
  # tree's 700 files took 9 s.
  first=
  [[ $f == *.sh ]] || IFS= read -r -n 200 first < "$f" || true
  if [[ $f == *.sh || $first =~ $shebang ]]; then
    scripts+=("$f")
  fi
done < <(git ls-files -z)
if ((${#scripts[@]} == 0)); then
  echo "check_shell: no scripts found (not a git checkout?)" >&2
  exit 1
fi
# -x: follow `source` into the files the `# shellcheck source=` lines name
# (paths from the repository root, where this runs). Eight scripts a
# process, two processes a core; xargs exits non-zero when any of them did.
if ! printf '%s\0' "${scripts[@]}" | xargs -0 -n 8 -P "$((2 * $(nproc)))" shellcheck -x --; then
  echo "check_shell: shellcheck found problems in the scripts above" >&2
  exit 1
fi
echo "check_shell: ${#scripts[@]} scripts pass shellcheck"
