"""Retime sessions of ``motionweb app``: a clip of the index prepared once per physics, then
retimed interactively (MPS06 §3: "an interactive method for creating optimal motion retimings";
the polygons are computed once and reused for every timing, design §8).

``POST /api/retime/sessions`` names a clip (index id, corpus path or stem) and its physics —
gravity (3,) m/s², per-joint mass factors (inertia and weight, MPS06 §3.2) and weight factors
(weight alone, MPS06 Fig. 11) — and the session worker (:mod:`.session_worker`, a supervised
child process: a crash in the compiled kernels costs the request, never the service) prepares its
:class:`~motionweb.tasks.retime.RetimePlan` once per (clip, physics, retime section), kept in a
cache bounded by count and bytes (``AppParams``, the config's ``app`` section). Each
``POST .../edit`` {duration, keytimes} is one :func:`~motionweb.tasks.retime.retime_plan` on it
plus the CLI's :func:`~motionweb.tasks.retime.report` (flows/retime.py runs the same two), and
answers the retimed motion's joint positions with the data of the plots the CLI draws: p(t)
against linear timing, every source frame's polygon with the output frames' (p̈, ṗ²), torques
against their limits, contact phases and flights with their ratios, and the shortest reachable
duration with the output frames outside their polygons. The session keeps its last result:
``GET .../bvh`` and ``GET .../report`` (the CLI's JSON report but its ``output`` and ``plots``).

A physics change is a new session (the page creates one and replays its timing on it); sessions
are kept in an LRU of ``AppParams.sessions`` (clip, physics, last result: the retimed motion and
its report, O(frames · dofs)). A plan evicted from the worker, or lost with a crashed worker, is
prepared again on the next edit.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
import uuid
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.flows.app.engine import LRU, Engine, NotFound, QueryCrashed, pose_payload
from motionweb.flows.app.params import AppParams
from motionweb.flows.app.session_worker import EditJob, PrepareJob, SessionWorker
from motionweb.flows.app.uploads import PREFIX, Uploads
from motionweb.flows.app.worker import WorkerCrashed
from motionweb.store.bvh import format_bvh
from pydantic import BaseModel, ConfigDict, Field

#: largest |gravity| (m/s²) and per-limb factor a session accepts
MAX_GRAVITY = 100.0
MAX_FACTOR = 1000.0
#: what each job of the session worker is called in an error
WORK = {"prepare": "preparation", "edit": "timing edit", "warp_prepare": "warp's preparation", "warp_edit": "warp",
        "parse": "upload's parsing", "info": "status"}
#: joints whose torque curves an edit returns (the most loaded, by peak |τ| / limit)
TORQUE_JOINTS = 6


#: joint positions for the players are sent at most at this rate (Hz; the downloads keep the clip's)
MAX_POSE_RATE = 60.0


def draw_pose(snap: Any, motion: Any) -> dict[str, Any]:
    """A motion's joint positions for a player (engine.pose_payload) at its own rate, or at
    :data:`MAX_POSE_RATE` when faster (a 120 Hz clip: half the frames, every other one)."""
    rate = min(float(motion.fps), MAX_POSE_RATE)
    n = int(np.floor((motion.n_frames - 1) * rate / motion.fps + 1e-9)) + 1
    return pose_payload(snap, motion, np.arange(n, dtype=float), rate)


class SessionBody(BaseModel):
    """A retime session: the clip (index id, corpus path or stem) and its physics (MPS06 §3.2)."""

    model_config = ConfigDict(extra="forbid")
    clip: str = Field(min_length=1, max_length=300)
    #: (3,) m/s² in the clip's axes; None: the default (9.81 down the up axis)
    gravity: list[float] | None = Field(default=None, min_length=3, max_length=3)
    #: {joint: factor} of a body's mass (inertia and weight) / of its weight alone (the CLI's --mass / --weight)
    mass: dict[str, float] = Field(default_factory=dict)
    weight: dict[str, float] = Field(default_factory=dict)

    def check(self, params: AppParams) -> None:
        """ValueError for a non-finite or too large gravity or factor, or too many factors."""
        if self.gravity is not None and (not all(math.isfinite(v) for v in self.gravity)
                                         or math.hypot(*self.gravity) > MAX_GRAVITY):
            raise ValueError(f"gravity must be 3 finite values of magnitude at most {MAX_GRAVITY:g} m/s²")
        for name, factors in (("mass", self.mass), ("weight", self.weight)):
            if len(factors) > params.session_max_factors:
                raise ValueError(f"{name}: at most {params.session_max_factors} factors")
            for joint, k in factors.items():
                if len(joint) > 100 or not (math.isfinite(k) and 0 < k <= MAX_FACTOR):
                    raise ValueError(f"{name}.{joint[:100]}: a factor must be > 0 and ≤ {MAX_FACTOR:g}, got {k}")


class EditBody(BaseModel):
    """A timing: output duration (s; None: the clip's own) and keytimes [[source s, output s], ...]
    (MPS06 §3.6: p(t) passes through them)."""

    model_config = ConfigDict(extra="forbid")
    duration: float | None = None
    keytimes: list[tuple[float, float]] = Field(default_factory=list)
    pose: bool = True

    def check(self, params: AppParams) -> None:
        if self.duration is not None and not (math.isfinite(self.duration)
                                              and 0 < self.duration <= params.session_max_duration_s):
            raise ValueError(f"duration must be > 0 and ≤ {params.session_max_duration_s:g} s, got {self.duration}")
        if len(self.keytimes) > params.session_max_keytimes:
            raise ValueError(f"keytimes: at most {params.session_max_keytimes}")
        if not all(math.isfinite(v) for k in self.keytimes for v in k):
            raise ValueError("keytimes must be finite numbers (source s, output s)")


class SessionCrashed(QueryCrashed):
    """The session's work crashed its worker process (HTTP 500 with the session's request)."""

    def __init__(self, query: dict[str, Any], how: str, work: str):
        self.query, self.how = query, how
        RuntimeError.__init__(self, f"the {work} of the session request ({query}) crashed its worker process "
                                    f"({how}); the service goes on, but this request cannot be answered: "
                                    "please report it")


@dataclass
class Session:
    """One session: the clip on the snapshot it was opened on, its physics, the plan's key, and
    its last timing (the retimed motion and the report)."""

    id: str
    snap: Any  # engine.Snapshot
    rec: dict[str, Any]
    body: SessionBody
    job: PrepareJob
    prepared: dict[str, Any]
    last: tuple[Any, dict[str, Any], dict[str, Any]] | None = None  # (motion, report, request)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def request(self) -> dict[str, Any]:
        return {"session": self.id, "clip": self.rec["path"], **self.body.model_dump(exclude={"clip"})}


def digest(data: Any) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:24]


def clip_key(rec: dict[str, Any], gen_cfg: Any, opts: dict[str, Any]) -> str:
    """The clip's key in the plan cache: its content, the settings it is read with and the retime
    section (canonical JSON, SHA-256): what its path dynamics and contacts depend on."""
    return digest({"sha256": rec["sha256"], "path": rec["path"],
                   "corpus": gen_cfg.corpus.model_dump(mode="json", exclude={"path", "manifest"}), "retime": opts})


def plan_key(clip: str, body: SessionBody) -> str:
    """The plan's key: the clip's (:func:`clip_key`) and the physics."""
    return digest({"clip": clip, "gravity": body.gravity, "mass": sorted(body.mass.items()),
                   "weight": sorted(body.weight.items())})


def torque_plot(rep: dict[str, Any], joints: list[str]) -> dict[str, Any]:
    """Torques against their limits (MPS06 Eqn. 12) from a report: per output frame the largest
    |τ| / limit over all joints, and the curves of the :data:`TORQUE_JOINTS` most loaded joints.

    ``rep["frames"][k]["torques"]`` holds the joint dofs after the root's (nv − 6,);
    ``rep["torque_limits"]`` one limit per joint (the same for each of its dofs, limits.py)."""
    tau = np.abs(np.array([f["torques"] for f in rep["frames"]], float))  # (T, nv - 6)
    names = [n for n in joints[1:] if n in rep["torque_limits"]]
    dofs = tau.shape[1] // max(len(names), 1)
    per = np.zeros((tau.shape[0], len(names)))
    for j, n in enumerate(names):  # every joint of the body model has 3 rotational dofs
        per[:, j] = tau[:, j * dofs:(j + 1) * dofs].max(axis=1) / max(rep["torque_limits"][n]["limit"], 1e-9)
    peak = per.max(axis=0) if len(per) else np.zeros(len(names))
    top = np.argsort(-peak)[:TORQUE_JOINTS]
    return {"max_ratio": np.round(per.max(axis=1), 4).tolist() if per.size else [],
            "joints": [{"name": names[j], "peak": round(float(peak[j]), 4), "ratio": np.round(per[:, j], 4).tolist()}
                       for j in top]}


def edit_answer(s: Session, retimed: Any, rep: dict[str, Any], pose: bool, seconds: float) -> dict[str, Any]:
    """What the page draws after a timing edit (see the module docstring)."""
    frames = rep["frames"]
    t = [f["t"] for f in frames]
    total = rep["duration_out"] or 1.0
    out = {
        "session": s.id, "clip": s.rec["path"], "duration_in": rep["duration_in"], "duration_out": rep["duration_out"],
        "fps": rep["fps"], "timing": rep["timing"], "timing_note": rep["timing_note"], "objective": rep["objective"],
        "converged": rep["converged"],
        # p(t) against linear timing (the CLI's timing.png)
        "t": t, "p": [f["source_time"] for f in frames], "linear": [x * rep["duration_in"] / total for x in t],
        # each output frame's source frame and (p̈, ṗ²), drawn in that frame's polygon (the
        # session's "polygons", polygons.png)
        "source_frame": [f["source_frame"] for f in frames],
        "pdd": [f["accel"] for f in frames], "pd2": [round(f["speed"] ** 2, 6) for f in frames],
        "feasible": [f["feasible"] for f in frames],
        "torques": torque_plot(rep, s.prepared["joints"]),
        "contacts": rep["contacts"], "flights": rep["flights"], "phase_seconds": rep["phase_seconds"],
        "shortest_feasible_duration": rep["shortest_feasible_duration"], "reachable": rep["reachable"],
        "infeasible_output_frames": rep["infeasible_output_frames"],
        "infeasible_source_frames": rep["infeasible_source_frames"],
        "free_fall": rep["free_fall"], "edit_s": round(seconds, 4),
    }
    if pose:
        out["pose"] = draw_pose(s.snap, retimed)
    return out


class RetimeSessions:
    """The service's retime sessions over an :class:`~motionweb.flows.app.engine.Engine` (see the
    module docstring). One job at a time runs in the session worker; :meth:`close` ends it."""

    def __init__(self, engine: Engine, params: AppParams | None = None):
        self.engine = engine
        self.params = params or getattr(engine.cfg, "app", None) or AppParams()
        self.sessions = LRU(self.params.sessions)
        self._call = threading.Lock()
        self._worker: SessionWorker | None = None
        self.crashes = 0
        #: clips of the user's own, parsed in the session worker (uploads.py)
        self.uploads = Uploads(self.params, lambda job: self._run("parse", job, {"upload": job.name}))
        self._slot: list[SessionWorker | None] = [None]  # the worker, for the finalizer
        self._finalize = weakref.finalize(self, RetimeSessions._close_worker, self._slot)

    @staticmethod
    def _close_worker(slot: list) -> None:
        if slot[0] is not None:
            slot[0].close()

    def close(self) -> None:
        """End the session worker."""
        with self._call:
            self._finalize()
            self._worker = None

    def _run(self, kind: str, payload: Any, query: dict[str, Any]) -> Any:
        with self._call:
            if self._worker is None or not self._worker.alive():
                self._worker = SessionWorker(self.params.session_plans, self.params.session_bytes)
                self._slot[0] = self._worker
            w = self._worker
            try:
                return w.call(kind, payload)
            except WorkerCrashed as exc:
                self.crashes += 1
                self._worker = self._slot[0] = None
                raise SessionCrashed(query, exc.how, WORK.get(kind, kind)) from None

    def worker_info(self) -> dict[str, Any]:
        w = self._worker
        info = {"pid": w.pid if w is not None and w.alive() else None, "crashes": self.crashes}
        if w is not None and w.alive():
            info.update(self._run("info", None, {}))
        return info

    def clip(self, snap: Any, key: str) -> tuple[dict[str, Any], Any]:
        """(record, motion) of a clip of the index (id, corpus path or stem) or of an upload (its
        ``up-`` id); ValueError for one longer than ``app.session_max_clip_s``."""
        if key.startswith(PREFIX):
            u = self.uploads.get(key)
            return u.record(), u.motion
        rec = snap.clip(key)
        if rec["duration"] > self.params.session_max_clip_s:
            raise ValueError(f"{rec['path']} lasts {rec['duration']:g} s; a session takes at most "
                             f"{self.params.session_max_clip_s:g} s (app.session_max_clip_s)")
        return rec, snap.motion(rec)

    # -------------------------------------------------------------- requests
    def create(self, body: SessionBody) -> dict[str, Any]:
        """Open a session: the clip's plan prepared in the worker (a physics change of a clip the
        worker holds reuses its path dynamics and contacts); every source frame's polygon; the
        original clip's joint positions for the player beside the retimed one."""
        body.check(self.params)
        t0 = time.perf_counter()
        snap = self.engine.current()
        rec, motion = self.clip(snap, body.clip)
        opts = self.engine.cfg.retime.model_dump(mode="json")
        path = rec["path"]
        ck = clip_key(rec, snap.gen_cfg, opts)
        job = PrepareJob(plan_key(ck, body), ck, motion, opts, snap.gen_cfg.corpus.up_axis,
                         None if body.gravity is None else tuple(body.gravity), dict(body.mass), dict(body.weight),
                         str(Path(snap.gen_cfg.corpus.path) / path) if path.lower().endswith(".txt") else None)
        s = Session(uuid.uuid4().hex[:12], snap, rec, body, job, {})
        prepared = self._run("prepare", job, s.request())
        polygons = prepared.pop("polygons")
        s.prepared = {**prepared, "joints": list(motion.skeleton.names), "prepare_s": time.perf_counter() - t0}
        self.sessions.put(s.id, s)
        if self.engine.on_query:
            self.engine.on_query("retime-session", s.request(), {"session": s.id, **prepared["timings"]})
        return {"session": s.id, **snap.clip_row(rec), "generation": snap.gen.id,
                "joints": s.prepared["joints"], "prepare_s": round(s.prepared["prepare_s"], 4),
                "plan_bytes": prepared["nbytes"], "plans": prepared["plans"], "cache_bytes": prepared["plan_bytes"],
                "cpu_s": round(prepared["cpu_s"], 4),
                "timings": prepared["timings"], "reused_dynamics": prepared["reused_dynamics"],
                "physics": body.model_dump(exclude={"clip"}),
                # per source frame its feasible polygon (K, 2) in (p̈, ṗ²) (MPS06 §3.4; polygons.png)
                "polygons": polygons,
                "original": draw_pose(snap, motion)}

    def session(self, sid: str) -> Session:
        s = self.sessions.get(sid)
        if s is None:
            raise NotFound(f"unknown or expired retime session {sid!r}: open it again")
        return s

    def edit(self, sid: str, body: EditBody) -> dict[str, Any]:
        """Retime the session's clip to ``body``'s duration and keytimes (MPS06 §3.6)."""
        body.check(self.params)
        s = self.session(sid)
        t0 = time.perf_counter()
        duration = float(body.duration) if body.duration is not None else float(s.rec["duration"])
        job = EditJob(s.job.key, duration, tuple((float(a), float(b)) for a, b in body.keytimes), s.job.opts)
        query = {**s.request(), "duration": duration, "keytimes": [list(k) for k in job.keytimes]}
        out = self._run("edit", job, query)
        if out is None:  # the plan was evicted, or the worker restarted: prepare it again
            self._run("prepare", s.job, query)
            out = self._run("edit", job, query)
            if out is None:
                raise RuntimeError("the session worker dropped the plan it just prepared")
        retimed, rep, cpu = out
        with s.lock:
            s.last = (retimed, rep, {"duration": duration, "keytimes": [list(k) for k in job.keytimes]})
        return {**edit_answer(s, retimed, rep, body.pose, time.perf_counter() - t0), "cpu_s": round(cpu, 4)}

    def last(self, sid: str) -> tuple[Session, Any, dict[str, Any]]:
        s = self.session(sid)
        with s.lock:
            if s.last is None:
                raise NotFound(f"retime session {sid} has no timing yet: POST .../edit first")
            retimed, rep, _ = s.last
        return s, retimed, rep

    def bvh(self, sid: str) -> tuple[str, str]:
        """(file name, BVH text) of the session's last retimed motion (as ``motionweb retime`` writes it)."""
        s, retimed, _ = self.last(sid)
        return f"{Path(s.rec['path']).stem}_retimed.bvh", format_bvh(retimed)

    def report(self, sid: str) -> dict[str, Any]:
        """The last timing's report (:func:`~motionweb.tasks.retime.report`, the CLI's JSON but
        ``output`` and ``plots``), with the session's request."""
        s, _, rep = self.last(sid)
        return {**rep, "session": s.request(), "request": s.last[2]}


# ------------------------------------------------------------------ warp sessions (HDP07)
class WarpSessionBody(BaseModel):
    """A warp session (HDP07 §3): the clip, and the reference whose timing it takes (an index id,
    corpus path or stem; None: the clip itself, HDP07 §4.1)."""

    model_config = ConfigDict(extra="forbid")
    clip: str = Field(min_length=1, max_length=300)
    reference: str | None = Field(default=None, min_length=1, max_length=300)


class WarpEditBody(BaseModel):
    """A warp: output duration (s), keytimes [[input s, output s], ...] the warp passes through,
    ``fast``: the §3.3 heuristic (the CLI's ``--fast``)."""

    model_config = ConfigDict(extra="forbid")
    duration: float
    keytimes: list[tuple[float, float]] = Field(default_factory=list)
    fast: bool = False
    pose: bool = True

    def check(self, params: AppParams) -> None:
        EditBody(duration=self.duration, keytimes=self.keytimes).check(params)


@dataclass
class WarpSession:
    id: str
    snap: Any
    rec: dict[str, Any]
    ref: dict[str, Any] | None
    job: Any  # WarpPrepareJob
    last: tuple[Any, dict[str, Any]] | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def request(self) -> dict[str, Any]:
        return {"session": self.id, "clip": self.rec["path"], "reference": self.ref["path"] if self.ref else None}


class WarpSessions:
    """Warp sessions (HDP07 §3) in the retime sessions' worker (:class:`RetimeSessions`): the clip
    and its reference are kept there with the local scores of the clip's triples, computed once
    per working input (HDP07 §3.2) and reused by every edit of the length or the keytimes, which
    then costs the shortest path (§3.3) and the postprocessing (§3.4)."""

    def __init__(self, retime: RetimeSessions):
        self.retime = retime
        self.sessions = LRU(retime.params.sessions)

    def create(self, body: WarpSessionBody) -> dict[str, Any]:
        from motionweb.flows.app.session_worker import WarpPrepareJob

        snap = self.retime.engine.current()
        rec, motion = self.retime.clip(snap, body.clip)
        ref, reference = self.retime.clip(snap, body.reference) if body.reference else (None, None)
        cfg = self.retime.engine.cfg
        key = digest({"warp": [rec["sha256"], rec["path"], ref and ref["sha256"], ref and ref["path"]],
                      "corpus": snap.gen_cfg.corpus.model_dump(mode="json", exclude={"path", "manifest"}),
                      "warp_params": cfg.warp.model_dump(mode="json"), "retime": cfg.retime.model_dump(mode="json")})
        job = WarpPrepareJob(key, motion, reference, cfg.model_copy(update={"corpus": snap.gen_cfg.corpus}))
        s = WarpSession(uuid.uuid4().hex[:12], snap, rec, ref, job)
        prepared = self.retime._run("warp_prepare", job, s.request())
        self.sessions.put(s.id, s)
        return {"session": s.id, **snap.clip_row(rec), "generation": snap.gen.id,
                "reference": snap.clip_row(ref) if ref is not None else None, "nbytes": prepared["nbytes"],
                "original": draw_pose(snap, motion),
                # the reference's poses, for the player beside the warped one (HDP07 §3: the warp follows it)
                "reference_pose": draw_pose(snap, reference) if reference is not None else None}

    def session(self, sid: str) -> WarpSession:
        s = self.sessions.get(sid)
        if s is None:
            raise NotFound(f"unknown or expired warp session {sid!r}: open it again")
        return s

    def edit(self, sid: str, body: WarpEditBody) -> dict[str, Any]:
        """Warp the session's clip to ``body``'s duration and keytimes (HDP07 §3)."""
        from motionweb.flows.app.session_worker import WarpEditJob

        body.check(self.retime.params)
        s = self.session(sid)
        t0 = time.perf_counter()
        job = WarpEditJob(s.job.key, float(body.duration), tuple((float(a), float(b)) for a, b in body.keytimes),
                          body.fast)
        query = {**s.request(), "duration": job.duration, "keytimes": [list(k) for k in job.keytimes]}
        out = self.retime._run("warp_edit", job, query)
        if out is None:  # evicted, or the worker restarted
            self.retime._run("warp_prepare", s.job, query)
            out = self.retime._run("warp_edit", job, query)
        warped, summary = out
        with s.lock:
            s.last = (warped, summary)
        ans = {"session": s.id, **summary, "edit_s": round(time.perf_counter() - t0, 4)}
        if body.pose:
            ans["pose"] = draw_pose(s.snap, warped)
        return ans

    def bvh(self, sid: str) -> tuple[str, str]:
        """(file name, BVH text) of the last warp (as ``motionweb warp`` writes it)."""
        s = self.session(sid)
        with s.lock:
            if s.last is None:
                raise NotFound(f"warp session {sid} has no warp yet: POST .../edit first")
            warped = s.last[0]
        return f"{Path(s.rec['path']).stem}_warped.bvh", format_bvh(warped)
