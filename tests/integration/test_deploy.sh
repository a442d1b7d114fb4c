#!/usr/bin/env bash
# The deployment recipes in deploy/, checked as far as this machine can:
#
#   1. CMake's install rules put ptserve and ptworker in PREFIX/bin, where the
#      recipes expect them (/usr/local/bin).
#   2. systemd: `systemd-analyze verify` of ptserve.service and an instance of
#      ptworker@.service, against a scratch root holding the installed
#      programs; any diagnostic fails (verify exits 0 on unknown keys and bad
#      values, so its output is what counts). Skipped, saying so, where
#      systemd-analyze is missing. Every option the ExecStart lines pass must
#      be one the program's --help lists.
#   3. Kubernetes: every YAML document under deploy/k8s parses (python3-yaml);
#      the kinds are there (Secret, PersistentVolumeClaim, Service, a
#      Deployment or StatefulSet running ptserve with --state-dir on the
#      claim, a Deployment running ptworker); the Service selects the
#      coordinator on 7878 with tcpSocket readiness and liveness probes; the
#      workers name that Service and read the token from the Secret; every
#      option passed is one the program's --help lists.
#   4. Slurm: `bash -n`, then a real run of deploy/slurm/ptfarm.sbatch on two
#      "nodes" of this machine through a stand-in srun; the image must be
#      bit-identical to a standalone render, and no worker may be left over.
#   5. Container: both stages of deploy/container/Containerfile are Debian 12,
#      the runtime stage installs deploy/setup.sh --runtime and copies the
#      installed programs from the build stage; every shared library the
#      programs load comes from a package of that runtime list or one of its
#      dependencies (checked with dpkg where it exists).
#
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail

: "${PT_BIN:?PT_BIN must name the bin folder of the build}"
: "${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}"
deploy=$PT_SOURCE_DIR/deploy
build=$(cd "$PT_BIN/.." && pwd)

fail() {
  echo "FAIL: $*" >&2
  exit 1
}
say() { printf '[%3ds] %s\n' "$SECONDS" "$*"; }

T=$(mktemp -d "${TMPDIR:-/tmp}/ptdeploy.XXXXXX")
bg_pids=()
# shellcheck disable=SC2317  # shellcheck 0.9 takes this EXIT trap for dead code
cleanup() {
  local st=$? pid
  trap - EXIT
  for pid in "${bg_pids[@]}"; do
    kill -TERM "$pid" 2>/dev/null
  done
  rm -rf -- "$T"
  exit "$st"
}
trap cleanup EXIT

for prog in ptserve ptworker ptexr-diff; do
  [[ -x "$PT_BIN/$prog" ]] || fail "$PT_BIN/$prog missing"
done
"$PT_BIN/ptserve" --help >"$T/ptserve.help"
"$PT_BIN/ptworker" --help >"$T/ptworker.help"

# Fails unless every --option in the words given is in the program's --help.
check_options() {
  local prog=$1 where=$2 word
  shift 2
  for word in "$@"; do
    [[ "$word" == --* ]] || continue
    grep -qE -- "(^|[[:space:],])${word%%=*}([[:space:]=,]|$)" "$T/$prog.help" ||
      fail "$where: $prog has no option $word (not in $prog --help)"
  done
}

# A Python 3 that has PyYAML: Debian's (python3-yaml) first, then PATH's.
py=""
for p in /usr/bin/python3 python3; do
  if command -v "$p" >/dev/null && "$p" -c 'import yaml' 2>/dev/null; then
    py=$p
    break
  fi
done

# 1. Install rules.
root=$T/root
cmake --install "$build" --prefix "$root/usr/local" >"$T/install.log" 2>&1 ||
  fail "cmake --install $build failed: $(tail -n 3 "$T/install.log")"
for prog in ptserve ptworker; do
  [[ -x "$root/usr/local/bin/$prog" ]] || fail "cmake --install put no $prog in PREFIX/bin"
done
say "install rules: ptserve and ptworker land in PREFIX/bin"

# 2. systemd units.
units=("$deploy/systemd/ptserve.service" "$deploy/systemd/ptworker@.service")
for u in "${units[@]}"; do
  [[ -f "$u" ]] || fail "$u missing"
done
exec_words() { # the ExecStart command of a unit, one word a line
  sed -n 's/^ExecStart=//p' "$1" | tr ' ' '\n' | grep -v '^$'
}
# Whether word $1 is among the rest. In bash, not `printf | grep -q`: grep
# quits at the first match, printf can then die of SIGPIPE, and pipefail
# fails a check that held.
has_word() {
  local w=$1 x
  shift
  for x in "$@"; do [[ $x == "$w" ]] && return 0; done
  return 1
}
mapfile -t words < <(exec_words "$deploy/systemd/ptserve.service")
[[ "${words[0]}" == /usr/local/bin/ptserve ]] || fail "ptserve.service does not start /usr/local/bin/ptserve"
has_word --state-dir "${words[@]}" || fail "ptserve.service: no --state-dir"
has_word --token-file "${words[@]}" || fail "ptserve.service: no --token-file"
check_options ptserve ptserve.service "${words[@]}"
mapfile -t words < <(exec_words "$deploy/systemd/ptworker@.service")
[[ "${words[0]}" == /usr/local/bin/ptworker ]] ||
  fail "ptworker@.service does not start /usr/local/bin/ptworker"
has_word --token-file "${words[@]}" || fail "ptworker@.service: no --token-file"
check_options ptworker ptworker@.service "${words[@]}"
for u in "${units[@]}"; do
  for key in DynamicUser=yes NoNewPrivileges=yes ProtectSystem=strict Restart=on-failure; do
    grep -qx "$key" "$u" || fail "${u##*/}: no $key"
  done
done
if command -v systemd-analyze >/dev/null; then
  # The scratch root: the installed programs, systemd's own units (for the
  # targets every service depends on), and the units under test.
  mkdir -p "$root/etc/systemd/system" "$root/usr/lib/systemd"
  for d in /usr/lib/systemd/system /lib/systemd/system; do
    if [[ -d "$d" ]]; then
      cp -r "$d" "$root/usr/lib/systemd/"
      break
    fi
  done
  cp "$deploy/systemd/ptserve.service" "$root/etc/systemd/system/"
  cp "$deploy/systemd/ptworker@.service" "$root/etc/systemd/system/ptworker@check.service"
  st=0
  systemd-analyze verify --man=no --root="$root" /etc/systemd/system/ptserve.service \
    /etc/systemd/system/ptworker@check.service >"$T/verify.log" 2>&1 || st=$?
  if ((st != 0)) || [[ -s "$T/verify.log" ]]; then
    cat "$T/verify.log" >&2
    fail "systemd-analyze verify: status $st, diagnostics above"
  fi
  say "systemd: both units verify cleanly"
else
  say "systemd: skipping systemd-analyze verify (systemd-analyze not installed)"
  skipped=1
fi

# 3. Kubernetes manifests.
[[ -n "$py" ]] || fail "no python3 with PyYAML (Debian: python3-yaml; deploy/setup.sh installs it)"
"$py" - "$deploy/k8s" "$T/ptserve.help" "$T/ptworker.help" <<'EOF' || fail "deploy/k8s: see above"
import glob, os, re, sys
import yaml

k8s_dir, help_files = sys.argv[1], {"ptserve": sys.argv[2], "ptworker": sys.argv[3]}
errors = []
def err(msg):
    errors.append(msg)

docs = []
files = sorted(glob.glob(os.path.join(k8s_dir, "*.yaml")) + glob.glob(os.path.join(k8s_dir, "*.yml")))
if not files:
    sys.exit("FAIL: no YAML files in " + k8s_dir)
for f in files:
    try:
        for d in yaml.safe_load_all(open(f)):
            if d is None:
                continue
            if not isinstance(d, dict) or "kind" not in d or "apiVersion" not in d:
                err(f"{f}: a document without kind and apiVersion")
                continue
            d["_file"] = os.path.basename(f)
            docs.append(d)
    except yaml.YAMLError as e:
        err(f"{f}: {e}")
if errors:
    sys.exit("\n".join("FAIL: " + e for e in errors))

def of_kind(*kinds):
    return [d for d in docs if d["kind"] in kinds]
def name(d):
    return d.get("metadata", {}).get("name", "?")

namespaces = {d.get("metadata", {}).get("namespace") for d in docs if d["kind"] != "Namespace"}
if len(namespaces) != 1:
    err(f"the objects name several namespaces: {sorted(map(str, namespaces))}")

def pod_spec(d):
    return d.get("spec", {}).get("template", {}).get("spec", {})
def containers_running(prog):
    out = []
    for d in of_kind("Deployment", "StatefulSet"):
        for c in pod_spec(d).get("containers", []):
            cmd = list(c.get("command", [])) + list(c.get("args", []))
            if cmd and os.path.basename(str(cmd[0])) == prog:
                out.append((d, c, [str(w) for w in cmd]))
    return out
def flag(cmd, opt):
    return cmd[cmd.index(opt) + 1] if opt in cmd[:-1] else None
def check_options(prog, where, cmd):
    text = open(help_files[prog]).read()
    for w in cmd:
        if w.startswith("--") and not re.search(r"(^|[\s,])" + re.escape(w) + r"([\s=,]|$)", text):
            err(f"{where}: {prog} has no option {w}")
def mount_for(c, path):
    """The volume mounted at the folder holding path, or None."""
    best = None
    for m in c.get("volumeMounts", []):
        mp = m["mountPath"].rstrip("/")
        if path.startswith(mp + "/") and (best is None or len(mp) > len(best["mountPath"])):
            best = m
    return best
def volume(spec, vname):
    for v in spec.get("volumes", []):
        if v["name"] == vname:
            return v
    return None

secrets = {name(d) for d in of_kind("Secret")}
pvcs = {name(d) for d in of_kind("PersistentVolumeClaim")}
services = of_kind("Service")
if not secrets:
    err("no Secret")
if not pvcs:
    err("no PersistentVolumeClaim")
if not services:
    err("no Service")

def token_from_secret(d, c, cmd, prog):
    """The token file must come from the Secret: mounted from it, or copied
    from it by an init container into a volume the container mounts."""
    spec = pod_spec(d)
    tok = flag(cmd, "--token-file")
    if not tok:
        err(f"{prog}: no --token-file")
        return
    m = mount_for(c, tok)
    if not m:
        err(f"{prog}: --token-file {tok} is on no mounted volume")
        return
    v = volume(spec, m["name"])
    if v and "secret" in v:
        ok = v["secret"].get("secretName") in secrets
    else:
        ok = False
        for ic in spec.get("initContainers", []):
            writes = any(im["name"] == m["name"] for im in ic.get("volumeMounts", []))
            reads = [volume(spec, im["name"]) for im in ic.get("volumeMounts", [])]
            if writes and any(r and "secret" in r and r["secret"].get("secretName") in secrets
                              for r in reads):
                ok = True
    if not ok:
        err(f"{prog}: --token-file {tok} does not come from the Secret ({sorted(secrets)})")

# The coordinator.
coord = containers_running("ptserve")
if len(coord) != 1:
    err(f"want one Deployment/StatefulSet container running ptserve, found {len(coord)}")
else:
    d, c, cmd = coord[0]
    where = f"{d['_file']}: {d['kind']} {name(d)}"
    if d.get("spec", {}).get("replicas", 1) != 1:
        err(f"{where}: the coordinator must have 1 replica")
    check_options("ptserve", where, cmd)
    state = flag(cmd, "--state-dir")
    if not state:
        err(f"{where}: ptserve without --state-dir")
    else:
        m = mount_for(c, state.rstrip("/") + "/x")
        v = volume(pod_spec(d), m["name"]) if m else None
        claims = [t["metadata"]["name"] for t in d.get("spec", {}).get("volumeClaimTemplates", [])]
        if not (v and v.get("persistentVolumeClaim", {}).get("claimName") in pvcs) and \
                not (m and m["name"] in claims):
            err(f"{where}: --state-dir {state} is not on the PersistentVolumeClaim")
    token_from_secret(d, c, cmd, "ptserve")
    ports = {p.get("name"): p["containerPort"] for p in c.get("ports", [])}
    if 7878 not in ports.values():
        err(f"{where}: no containerPort 7878")
    listen = flag(cmd, "--listen") or ""
    if not listen.endswith(":7878"):
        err(f"{where}: ptserve --listen {listen!r}, want port 7878")
    for probe in ("readinessProbe", "livenessProbe"):
        port = c.get(probe, {}).get("tcpSocket", {}).get("port")
        if ports.get(port, port) != 7878:
            err(f"{where}: {probe} is not a tcpSocket probe of port 7878")
    if "requests" not in c.get("resources", {}):
        err(f"{where}: no resource requests")
    labels = d["spec"]["template"]["metadata"].get("labels", {})
    coord_svcs = [s for s in services
                  if s["spec"].get("selector") and
                  all(labels.get(k) == v for k, v in s["spec"]["selector"].items())]
    if not coord_svcs:
        err(f"{where}: no Service selects the coordinator's pods")
    elif not any(p["port"] == 7878 for s in coord_svcs for p in s["spec"].get("ports", [])):
        err("the coordinator's Service has no port 7878")

# The workers.
workers = [w for w in containers_running("ptworker") if w[0]["kind"] == "Deployment"]
if len(workers) != 1:
    err(f"want one Deployment container running ptworker, found {len(workers)}")
else:
    d, c, cmd = workers[0]
    where = f"{d['_file']}: Deployment {name(d)}"
    check_options("ptworker", where, cmd)
    server = flag(cmd, "--server") or ""
    host, _, port = server.rpartition(":")
    svc_names = {name(s) for s in services}
    if port != "7878" or host.split(".")[0] not in svc_names:
        err(f"{where}: --server {server!r} is not a Service's port 7878 ({sorted(svc_names)})")
    token_from_secret(d, c, cmd, "ptworker")
    if "limits" not in c.get("resources", {}):
        err(f"{where}: no resource limits")

if errors:
    sys.exit("\n".join("FAIL: " + e for e in errors))
print(f"[   k8s] {len(docs)} documents in {len(files)} files: " +
      ", ".join(sorted(d["kind"] + " " + name(d) for d in docs)))
EOF
say "kubernetes: manifests parse and fit together"

# 4. Slurm.
sbatch=$deploy/slurm/ptfarm.sbatch
[[ -f "$sbatch" ]] || fail "$sbatch missing"
bash -n "$sbatch" || fail "bash -n $sbatch"
grep -q '^#SBATCH --nodes' "$sbatch" || fail "$sbatch has no #SBATCH --nodes"
grep -qE '^[[:space:]]*srun .*' "$sbatch" || fail "$sbatch does not start workers with srun"
# A stand-in srun: runs the command once per "node" here, with the variables
# Slurm sets in each task, and passes TERM on to them as srun does.
mkdir -p "$T/fake-slurm"
cat >"$T/fake-slurm/srun" <<'EOF'
#!/usr/bin/env bash
nodes=1
while [[ "$1" == -* ]]; do
  case "$1" in --nodes=*) nodes=${1#--nodes=} ;; esac
  shift
done
pids=() signals=0
trap 'signals=$((signals + 1)); kill -TERM "${pids[@]}" 2>/dev/null' TERM INT
for ((n = 0; n < nodes; n++)); do
  SLURM_NODEID=$n SLURM_CPUS_ON_NODE=1 "$@" &
  pids+=($!)
done
# A trapped signal interrupts wait (> 128) with the task's status still to
# collect: wait again; a second wait after a collected status answers 127.
st=0
for p in "${pids[@]}"; do
  t=0
  while :; do
    n=$signals
    wait "$p" && s=0 || s=$?
    ((s == 127 && n != 0)) || t=$s
    ((signals != n && s > 128)) || break
  done
  ((t == 0)) || st=$t
done
echo "$st" >"$SRUN_STATUS_FILE"
exit "$st"
EOF
chmod +x "$T/fake-slurm/srun"
scene=$PT_SOURCE_DIR/scenes/cornell_box.gltf
job=(--res 48x32 --spp 256 --tile 16 --chunk 8 --seed 5)
"$PT_BIN/ptworker" --scene "$scene" "${job[@]}" -q -o "$T/slurm-ref.exr" >"$T/slurm-ref.log" 2>&1 ||
  fail "the standalone reference render failed"
mkdir "$T/submit"
st=0
(cd "$T/submit" &&
  PATH=$T/fake-slurm:$PATH SLURM_JOB_ID=4242 SLURM_JOB_NUM_NODES=2 SLURM_SUBMIT_DIR=$T/submit \
    SRUN_STATUS_FILE=$T/srun.status PTFARM_BIN=$PT_BIN PTFARM_PORT=0 PTFARM_HOST=127.0.0.1 \
    PTFARM_CACHE_DIR=$T/slurm-cache PTFARM_WORKER_OPTS="--link-timeout 5" \
    timeout 120 bash "$sbatch" "$scene" "$T/slurm.exr" "${job[@]}" -q) >"$T/slurm.log" 2>&1 || st=$?
if ((st != 0)); then
  cat "$T/slurm.log" >&2
  fail "ptfarm.sbatch exited with status $st"
fi
grep -q "workers on 2 node" "$T/slurm.log" || { cat "$T/slurm.log" >&2; fail "ptfarm.sbatch did not start 2 nodes"; }
# One worker per node was started; whether the second one connects before a
# job this small is done depends on the machine's speed, so at least one must.
(($(grep -c "ptworker: farm worker " "$T/slurm.log") == 2)) ||
  { cat "$T/slurm.log" >&2; fail "want a worker started on each of the 2 nodes"; }
grep -q "ptworker: connected to 127.0.0.1:" "$T/slurm.log" ||
  { cat "$T/slurm.log" >&2; fail "no worker connected"; }
[[ "$(cat "$T/srun.status" 2>/dev/null)" == 0 ]] ||
  { cat "$T/slurm.log" >&2; fail "the workers did not stop with status 0"; }
[[ ! -e "$T/submit/.ptfarm-4242" ]] || fail "ptfarm.sbatch left its job folder behind"
"$PT_BIN/ptexr-diff" "$T/slurm-ref.exr" "$T/slurm.exr" >"$T/slurm-diff.log" 2>&1 ||
  { cat "$T/slurm-diff.log" >&2; fail "the Slurm farm's image differs from the standalone render"; }
say "slurm: ptfarm.sbatch rendered on 2 nodes (stand-in srun), bit-identical, cleaned up"

# 5. Container recipe.
cf=$deploy/container/Containerfile
[[ -f "$cf" ]] || fail "$cf missing"
mapfile -t froms < <(grep -E '^FROM[[:space:]]' "$cf")
((${#froms[@]} >= 2)) || fail "$cf: want a multi-stage build (2 FROM lines), found ${#froms[@]}"
for f in "${froms[@]}"; do
  base=$(awk '{print $2}' <<<"$f")
  [[ "$base" =~ ^(docker\.io/(library/)?)?debian:(12|bookworm)(-slim)?(@.*)?$ ]] ||
    fail "$cf: stage '$f' is not Debian 12 (bookworm)"
done
grep -qE '^FROM .* AS build' "$cf" || fail "$cf: no stage named build"
grep -qE 'setup\.sh --build' "$cf" || fail "$cf: the build stage does not run deploy/setup.sh --build"
grep -qE 'setup\.sh --runtime' "$cf" || fail "$cf: the runtime stage does not run deploy/setup.sh --runtime"
grep -qE '^COPY --from=build ' "$cf" || fail "$cf: the runtime stage copies nothing from the build stage"
grep -qE '^USER ' "$cf" || fail "$cf: the image runs as root (no USER)"
if command -v dpkg-query >/dev/null && command -v ldd >/dev/null; then
  # The runtime list of deploy/setup.sh, then its closure over installed Depends.
  runtime=$(sed -n 's/^runtime_pkgs=(\(.*\))$/\1/p' "$deploy/setup.sh")
  [[ -n "$runtime" ]] || fail "deploy/setup.sh: no runtime_pkgs=(...) line"
  dpkg-query -W -f='${Package}\t${Depends}, ${Pre-Depends}\n' >"$T/dpkg.tsv"
  # The package that owns each library file (merged /usr: every spelling,
  # asked of dpkg in one call, which reads its database once: one call per
  # spelling took 7 s). A sanitizer build loads its runtimes (libasan,
  # libubsan), which a release image never has: those are left out. dpkg
  # prints "pkg[:arch][, pkg2]: path", and exits 1 for the spellings no
  # package owns.
  owners=$(ldd "$PT_BIN/ptserve" "$PT_BIN/ptworker" | awk '/=> \// {print $3}' |
    grep -vE '/lib(a|ub|t|l)san\.so' | sort -u |
    while read -r lib; do
      r=$(readlink -f "$lib")
      printf '%s\n' "$lib" "$r" "${r#/usr}" "/usr$r"
    done | sort -u | { xargs dpkg -S 2>/dev/null || true; } | grep -v '^diversion ' |
    sed 's/[:,].*//' | sort -u)
  [[ -n "$owners" ]] || fail "dpkg knows no package of the programs' libraries"
  "$py" - "$T/dpkg.tsv" "$runtime" "$owners" <<'EOF' || fail "runtime libraries: see above"
import re, sys
deps = {}
for line in open(sys.argv[1]):
    pkg, _, rest = line.rstrip("\n").partition("\t")
    deps[pkg] = [re.split(r"[\s(:]", alt.strip())[0] for alt in re.split(r"[,|]", rest) if alt.strip()]
# What every Debian 12 image has: the essential set (libc6, libgcc-s1, ...).
base = {"libc6", "libgcc-s1", "zlib1g", "libstdc++6"}
todo, seen = sys.argv[2].split(), set()
while todo:
    p = todo.pop()
    if p not in seen:
        seen.add(p)
        todo.extend(deps.get(p, []))
missing = [o for o in sys.argv[3].split() if o not in seen | base]
if missing:
    sys.exit("FAIL: the programs load libraries from " + ", ".join(missing) +
             ", which deploy/setup.sh --runtime does not bring in")
EOF
  say "container: two Debian 12 stages; the runtime packages cover every library loaded"
else
  say "container: two Debian 12 stages (no dpkg here: runtime libraries not checked)"
  skipped=1
fi

say "PASS: deploy recipes"
# 77: ctest counts the test as skipped, not passed, when a part could not run.
[[ ${skipped:-0} == 1 ]] && exit 77
exit 0
