"""Talking to a ptfarm coordinator through ptctl, without Blender.

A FarmJob submits an exported scene with `ptctl submit`, follows it with
`ptctl status JOB --json` (polled: ptctl watch prints for people, status
for programs), and fetches each finished frame with `ptctl fetch`. It runs
either in the caller's thread (run()) or in a thread of its own (start());
the Blender side reads snapshot() from its main thread, so every field a
thread writes is guarded by one lock.

Every failure ends as one sentence for a person (FarmError), built from
ptctl's own message on stderr and its exit status (ptctl --help: 1 error,
2 bad usage, 3 no such job, 4 the job ended cancelled or failed), never a
traceback.

Threads: a FarmJob's methods may be called from any thread; run() once.
"""

import json
import os
import shutil
import subprocess
import threading
import time

# ptctl's exit statuses (client/main.c, ptctl --help).
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_NO_JOB = 3
EXIT_ENDED_BADLY = 4

POLL_SECONDS = 0.5


class FarmError(Exception):
    """A failure told in one sentence; str() is what the user reads."""


def find_ptctl(configured=""):
    """The ptctl to run: the configured path, else ptctl on PATH. Raises
    FarmError naming what was looked for."""
    if configured:
        path = os.path.abspath(os.path.expanduser(configured))
        if os.path.isfile(path) and os.access(path, os.X_OK):
            return path
        raise FarmError("ptctl not found at '%s' (set its path in the ptfarm add-on's "
                        "preferences)" % configured)
    found = shutil.which("ptctl")
    if found:
        return found
    raise FarmError("ptctl is not on PATH: install ptfarm or set ptctl's path in the ptfarm "
                    "add-on's preferences")


def explain(stderr, rc, server):
    """One readable sentence from ptctl's stderr and exit status."""
    # A usage error ends with "try 'ptctl submit --help'" after the reason.
    lines = [ln.strip() for ln in (stderr or "").splitlines()
             if ln.strip() and not ln.strip().startswith("try 'ptctl")]
    # ptctl prints "ptctl: <reason>"; the last such line is the one that ended it.
    said = lines[-1] if lines else "exit status %d" % rc
    if said.startswith("ptctl: "):
        said = said[len("ptctl: "):]
    low = said.lower()
    if "connection refused" in low or "cannot connect" in low or "no route" in low \
            or "timed out" in low and "connect" in low:
        return "no coordinator answers at %s (%s): is ptserve running there?" % (server, said)
    if "authentication failed" in low or "does not know the token" in low:
        return "the coordinator at %s refused the token (%s): check the token file" % (
            server, said)
    if "token" in low:
        return "token file: %s" % said
    if said.startswith("server: "):
        return "the coordinator at %s refused: %s" % (server, said[len("server: "):])
    if rc == EXIT_ENDED_BADLY:
        return "the job ended without an image: %s" % said
    if rc == EXIT_NO_JOB:
        return "the coordinator no longer knows the job: %s" % said
    return said


class FarmJob:
    """One submitted render: a still (frames None) or a frame range.

    ptctl: the program; server: HOST:PORT; token_file: a path or "";
    scene: the exported .glb; args: ptctl submit's options after the scene;
    frames: None, or the frame numbers the range renders in order;
    out_path(frame): where a finished image goes (frame None for a still).
    """

    def __init__(self, ptctl, server, token_file, scene, args, frames, out_path,
                 timeout=30.0):
        self.ptctl = ptctl
        self.server = server
        self.token_file = token_file
        self.scene = scene
        self.args = list(args)
        self.frames = list(frames) if frames is not None else None
        self.out_path = out_path
        self.timeout = timeout
        self._lock = threading.Lock()
        self._thread = None
        self._cancel = False
        self._state = {"phase": "starting", "job": None, "progress": 0.0, "message": "",
                       "error": None, "fetched": [], "done": False, "status": None}

    # ---- state shared with the main thread -------------------------------
    def _set(self, **kw):
        with self._lock:
            self._state.update(kw)

    def snapshot(self):
        """A copy of the job's state: phase, job id, progress (0..1),
        message, error (None or a sentence), fetched [(frame, path)],
        done (True once run() has returned)."""
        with self._lock:
            s = dict(self._state)
            s["fetched"] = list(s["fetched"])
            return s

    def cancel(self):
        """Asks the farm to cancel the job, and stops following it."""
        with self._lock:
            self._cancel = True

    # ---- ptctl -------------------------------------------------------------
    def _ctl(self, *words):
        cmd = [self.ptctl, "--server", self.server, "--timeout", "%g" % self.timeout]
        if self.token_file:
            cmd += ["--token-file", self.token_file]
        cmd += list(words)
        try:
            p = subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True,
                               timeout=self.timeout * 4 + 60)
        except OSError as e:
            raise FarmError("cannot run %s: %s" % (self.ptctl, e.strerror or e))
        except subprocess.TimeoutExpired:
            raise FarmError("ptctl %s did not answer within %d s" % (
                words[0], self.timeout * 4 + 60))
        if p.returncode != 0:
            raise FarmError(explain(p.stderr, p.returncode, self.server))
        return p.stdout

    def submit_command(self):
        """The ptctl submit words (for the record the add-on writes)."""
        return ["submit", self.scene] + self.args

    # ---- the job -------------------------------------------------------------
    def start(self):
        """Runs the job in a daemon thread; follow it with snapshot()."""
        self._thread = threading.Thread(target=self.run, name="ptfarm-job", daemon=True)
        self._thread.start()

    def run(self):
        """Submits, follows and fetches; never raises: the outcome is in
        snapshot() (error None when every image came back)."""
        try:
            self._run()
        except FarmError as e:
            self._set(error=str(e), phase="failed")
        except Exception as e:  # a bug here must still reach the user as a sentence
            self._set(error="unexpected %s: %s" % (type(e).__name__, e), phase="failed")
        finally:
            self._set(done=True)

    def _run(self):
        self._set(phase="submitting", message="uploading %s" % os.path.basename(self.scene))
        out = self._ctl(*self.submit_command()).strip()
        if not out.isdigit():
            raise FarmError("ptctl submit printed '%s', not a job id" % out[:80])
        job = int(out)
        self._set(job=job, phase="queued", message="job %d queued" % job)
        pending = list(self.frames) if self.frames is not None else [None]
        while True:
            with self._lock:
                cancel = self._cancel
            if cancel:
                self._ctl("cancel", str(job))
                raise FarmError("job %d cancelled" % job)
            st = json.loads(self._ctl("status", str(job), "--json"))
            self._follow(job, st)
            state = st.get("state")
            if state in ("cancelled", "failed"):
                msg = st.get("message") or state
                raise FarmError("job %d %s: %s" % (job, state, msg))
            ready = len(pending) if state == "done" else self._frames_ready(st, pending)
            for _ in range(ready):
                self._fetch(job, pending.pop(0))
            if state == "done" and not pending:
                break
            time.sleep(POLL_SECONDS)
        self._set(phase="done", progress=1.0, message="job %d done" % job)

    def _frames_ready(self, st, pending):
        """How many of the pending frames (in range order) are finished while
        the job runs: the scheduler serves early frames first (ptctl submit
        --help), so a frame is done once it counts among frames_done and no
        frame rendering comes before it."""
        if self.frames is None or st.get("frames_done") is None:
            return 0
        done = int(st["frames_done"])
        rendering = [f.get("frame") for f in st.get("frames") or []]
        index = {f: i for i, f in enumerate(self.frames)}
        limit = min([done] + [index[f] for f in rendering if f in index])
        return sum(1 for f in pending if index[f] < limit)

    def _follow(self, job, st):
        state = st.get("state", "?")
        progress = float(st.get("progress") or 0.0)
        msg = "job %d %s" % (job, state)
        if state == "queued" and st.get("queue_position"):
            msg += ", %d ahead" % st["queue_position"]
        elif state == "done":
            msg += ", fetching the image%s" % ("s" if self.frames else "")
        elif state == "running":
            msg += " %d%%, %d worker%s" % (progress * 100, st.get("workers", 0),
                                           "" if st.get("workers") == 1 else "s")
            if self.frames is not None and st.get("frames_done") is not None:
                msg += ", frame %d of %d" % (min(st["frames_done"] + 1, len(self.frames)),
                                             len(self.frames))
        # What the coordinator says of the job besides (a warning from its
        # scene check, "denoising the image: 40 %", a paused output folder).
        if st.get("message"):
            msg += ": %s" % st["message"]
        self._set(phase=state, progress=progress, message=msg, status=st)

    def _fetch(self, job, frame):
        path = self.out_path(frame)
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        words = ["fetch", str(job), "-o", path]
        if frame is not None:
            words[2:2] = ["--frame", str(frame)]
        self._ctl(*words)
        with self._lock:
            self._state["fetched"].append((frame, path))
