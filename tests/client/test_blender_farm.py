"""client/blender/ptfarm_blender/farm.py without Blender: FarmJob against
a scripted stand-in for ptctl, for what a small real queue rarely shows.

- A frame range whose frames end out of order (frame 12 done while frame
  11 still renders): a frame is fetched only once no frame before it is
  rendering, never while the farm still holds a partial image of it, and
  every frame is fetched once, in range order.
- The coordinator's message of a running job is shown beside its
  progress.
- ptctl's failures become the sentences the add-on shows: a refused token,
  no coordinator, a refused job, a job that failed on the farm, a status
  that is not JSON; never a traceback.

The stand-in reads its answers from a JSON file (a list of status objects,
one per 'status' call; the last repeats) and logs every call. Run by
ctest with python3; needs nothing but the source tree.
"""
import json
import os
import shutil
import stat
import sys
import tempfile

SRC = os.environ.get("PT_SOURCE_DIR") or os.path.join(os.path.dirname(__file__), "..", "..")
sys.path.insert(0, os.path.join(SRC, "client", "blender", "ptfarm_blender"))
import farm  # noqa: E402

farm.POLL_SECONDS = 0.0

FAKE = r'''#!/usr/bin/env python3
import json, os, sys
here = os.path.dirname(os.path.abspath(__file__))
args = sys.argv[1:]
with open(os.path.join(here, "calls.log"), "a") as f:
    f.write(" ".join(args) + "\n")
plan = json.load(open(os.path.join(here, "plan.json")))
cmd = [a for a in args if not a.startswith("--")]
words = args[args.index("--timeout") + 2:] if "--timeout" in args else args
if plan.get("fail"):
    sys.stderr.write(plan["fail"] + "\n")
    sys.exit(plan.get("rc", 1))
if words[0] == "submit":
    print(7)
elif words[0] == "status":
    n = int(open(os.path.join(here, "n")).read()) if os.path.exists(
        os.path.join(here, "n")) else 0
    open(os.path.join(here, "n"), "w").write(str(n + 1))
    answers = plan["status"]
    a = answers[min(n, len(answers) - 1)]
    print(a if isinstance(a, str) else json.dumps(a))
elif words[0] == "fetch":
    out = words[words.index("-o") + 1]
    frame = words[words.index("--frame") + 1] if "--frame" in words else "-"
    # What the farm holds of that frame now: the fetch records it.
    with open(out, "w") as f:
        f.write(frame)
elif words[0] == "cancel":
    print("cancelled")
'''

failures = 0
scratch = []


def check(cond, what):
    global failures
    print(("ok " if cond else "FAIL ") + what, flush=True)
    if not cond:
        failures += 1


def setup(plan):
    d = tempfile.mkdtemp(prefix="pt_blender_farm_")
    scratch.append(d)
    path = os.path.join(d, "ptctl")
    with open(path, "w") as f:
        f.write(FAKE)
    os.chmod(path, stat.S_IRWXU)
    with open(os.path.join(d, "plan.json"), "w") as f:
        json.dump(plan, f)
    return d, path


def calls(d):
    with open(os.path.join(d, "calls.log")) as f:
        return [ln.split() for ln in f.read().splitlines()]


def job_for(d, ptctl, frames):
    def out(frame):
        return os.path.join(d, "out.%s.exr" % ("still" if frame is None else frame))
    return farm.FarmJob(ptctl, "127.0.0.1:7878", "", os.path.join(d, "s.glb"), ["--spp", "8"],
                        frames, out)


def status(state, done, rendering):
    return {"id": 7, "state": state, "progress": done / 3.0, "workers": 2,
            "frame_range": {"first": 10, "last": 12, "step": 1}, "frames_done": done,
            "frames_rendering": len(rendering),
            "frames": [{"frame": f, "samples_done": 1, "samples_total": 2} for f in rendering]}


# Frames 10, 11, 12: 10 ends, then 12 ends while 11 still renders.
plan = {"status": [status("running", 0, [10, 11]), status("running", 1, [11, 12]),
                   status("running", 2, [11]), status("done", 3, [])]}
d, ptctl = setup(plan)
job = job_for(d, ptctl, [10, 11, 12])
job.run()
snap = job.snapshot()
check(snap["error"] is None and snap["done"], "the range ends without error (%s)" % snap["error"])
order = [(w[0], w[w.index("--frame") + 1] if "--frame" in w else None)
         for w in (c[c.index("--timeout") + 2:] for c in calls(d))]
fetches = [(i, f) for i, (cmd, f) in enumerate(order) if cmd == "fetch"]
statuses = [i for i, (cmd, _) in enumerate(order) if cmd == "status"]
check([f for _, f in fetches] == ["10", "11", "12"], "each frame fetched once, in order: %s" %
      [f for _, f in fetches])
# Frame 10 is fetched after the second status (frames_done 1, 11 and 12
# rendering), 11 and 12 only after the last (done): at the third status
# frame 12 is done but 11 still renders before it.
check(statuses[1] < fetches[0][0] < statuses[2], "frame 10 is fetched once it is done")
check(fetches[1][0] > statuses[3] and fetches[2][0] > statuses[3],
      "frames 11 and 12 wait until no frame before them renders")
check([f for f, _ in snap["fetched"]] == [10, 11, 12], "the fetched list is in range order")

# A still: fetched once, when done.
d, ptctl = setup({"status": [{"id": 7, "state": "queued", "queue_position": 2},
                             {"id": 7, "state": "running", "progress": 0.5, "workers": 1},
                             {"id": 7, "state": "done", "progress": 1.0}]})
job = job_for(d, ptctl, None)
job.run()
snap = job.snapshot()
check(snap["error"] is None and [f for f, _ in snap["fetched"]] == [None] and
      open(snap["fetched"][0][1]).read() == "-", "a still is fetched once when done")

# What the coordinator says of a running job (its message) is shown beside
# the progress: a scene check's warning, the denoiser's progress.
d, ptctl = setup({"status": [{"id": 7, "state": "done", "progress": 1.0}]})
job = job_for(d, ptctl, None)
for st, want in [({"id": 7, "state": "running", "progress": 0.5, "workers": 1,
                   "message": "warning: 2 of 2 portal triangles look wound the wrong way"},
                  "job 7 running 50%, 1 worker: warning: 2 of 2 portal triangles look wound "
                  "the wrong way"),
                 ({"id": 7, "state": "running", "progress": 1.0, "workers": 1,
                   "message": "denoising the image: 40 %"},
                  "job 7 running 100%, 1 worker: denoising the image: 40 %"),
                 ({"id": 7, "state": "running", "progress": 0.5, "workers": 1},
                  "job 7 running 50%, 1 worker")]:
    job._follow(7, st)
    shown = job.snapshot()["message"]
    check(shown == want, "the job's message is shown: '%s'" % shown)

# Failures: one sentence, no traceback.
cases = [
    ({"fail": "ptctl: server: authentication failed (wrong token)"}, "refused the token"),
    ({"fail": "ptctl: cannot connect to 127.0.0.1:7878: Connection refused"},
     "no coordinator answers at 127.0.0.1:7878"),
    ({"fail": "ptctl: server: 60000 samples per pixel is over this server's limit of 4096"},
     "refused: 60000 samples per pixel"),
    ({"status": [{"id": 7, "state": "failed", "message": "scene refused: no triangles"}]},
     "job 7 failed: scene refused: no triangles"),
    ({"status": ["not json at all"]}, "unexpected JSONDecodeError"),
]
for plan, words in cases:
    d, ptctl = setup(plan)
    job = job_for(d, ptctl, None)
    job.run()
    err = job.snapshot()["error"] or ""
    check(words in err and "Traceback" not in err, "failure told as: '%s'" % err)
try:
    farm.find_ptctl("/nonexistent/ptctl")
    check(False, "a missing ptctl is refused")
except farm.FarmError as e:
    check("ptctl not found at '/nonexistent/ptctl'" in str(e), "a missing ptctl: '%s'" % e)

if not failures:
    for d in scratch:
        shutil.rmtree(d)
sys.exit(1 if failures else 0)
