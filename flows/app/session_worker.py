"""The retime sessions' work in a child process, so a crash in it cannot take the service down.

MPS06 §3 splits a retiming into what depends on the clip and its physics — path dynamics (§3.1),
contacts (§3.2), the feasible polygons (§3.3-3.4) and the baked objective (§3.5) — and the timing
optimised for one duration and keytimes (§3.6); the polygons are "reused for all subsequent
retimings". This worker keeps the first part, a :class:`~motionweb.tasks.retime.RetimePlan` per
(clip, physics), in a :class:`PlanCache` bounded by count and bytes (``AppParams.session_plans``,
``session_bytes``; least recently used first out), and answers each timing edit from it with
:func:`~motionweb.tasks.retime.retime_plan` and the CLI's :func:`~motionweb.tasks.retime.report`
(the same functions ``motionweb retime`` runs, flows/retime.py). Warp sessions (HDP07 §3) are
kept the same way: the clip, its reference and the local scores of its triples (n, s, s) per
working input, reused by every warp of another length or keytimes (``motionweb warp``'s
``plan_motions`` and ``solve``, flows/warp.py).

It runs as :class:`~motionweb.flows.app.worker.Worker` runs the search worker (a socket pair, one
request at a time), with its own loop: ``("prepare", PrepareJob)`` → ``{"key", "nbytes",
"polygons", ...}``;
``("edit", EditJob)`` → ``(retimed motion, report, CPU seconds)``, or ``None`` when the plan is no longer kept
(evicted, or the worker restarted: the service prepares it again); ``("warp_prepare",
WarpPrepareJob)``, ``("warp_edit", WarpEditJob)`` likewise; ``("info", None)``; ``("ping", None)``. A crash
(the compiled kernels: Pinocchio, numba, HiGHS) costs the request that ran it
(:class:`~motionweb.flows.app.worker.WorkerCrashed`); the next request starts a fresh worker and
prepares its plan again.

Run as ``python -m motionweb.flows.app.session_worker FD STORE_URL`` by :class:`SessionWorker` only.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from motionweb.flows.app.worker import Worker

log = logging.getLogger("motionweb.app")
#: test hook (off by default): a worker that prepares a clip named NAME sends itself SIGSEGV
CRASH_ENV = "MOTIONWEB_TEST_CRASH_RETIME"


@dataclass(frozen=True)
class PrepareJob:
    """Prepare one (clip, physics): the clip's motion, the retime section (``RetimeParams`` as a
    dict), the up axis, gravity (3,) m/s² or None (the default), per-joint mass and weight factors
    (MPS06 §3.2, Fig. 11) and, for a DeepMimic clip, its file (read by the service from the
    generation's record, never named by a request) for the URDF humanoid."""

    key: str
    #: the clip's key without the physics: plans of one clip share its path dynamics and contacts
    clip_key: str
    motion: Any  # motionweb.store.motion.Motion
    opts: dict[str, Any]
    up_axis: str
    gravity: tuple[float, float, float] | None
    mass: dict[str, float]
    weight_factors: dict[str, float]
    deepmimic_path: str | None = None


@dataclass(frozen=True)
class EditJob:
    """One timing of a prepared plan: output duration (s) and keytimes [(source s, output s)]."""

    key: str
    duration: float
    keytimes: tuple[tuple[float, float], ...]
    opts: dict[str, Any]


@dataclass(frozen=True)
class WarpPrepareJob:
    """A warp session's clip and reference (HDP07 §3; None: the clip itself, §4.1) with the
    service's config (its warp section; its retime section tells flight phases, MPS06 §3.2)."""

    key: str
    motion: Any  # Motion
    reference: Any  # Motion | None
    config: Any  # motionweb.flows.config.Config


@dataclass(frozen=True)
class WarpEditJob:
    """One warp of a prepared session: output duration (s), keytimes [(input s, output s)], and
    whether to use the §3.3 heuristic (``fast``)."""

    key: str
    duration: float
    keytimes: tuple[tuple[float, float], ...]
    fast: bool


@dataclass(frozen=True)
class UploadJob:
    """An uploaded clip to parse with the hardened readers (store/bvh.py, store/asfamc.py): BVH
    text, or ASF and AMC texts; the length unit (BVH declares none) and the AMC's frame rate."""

    name: str
    sha256: str
    bvh: str | None = None
    asf: str | None = None
    amc: str | None = None
    unit: str | None = None
    scale_to_m: float | None = None
    fps: float | None = None


def parse_upload(job: UploadJob) -> Any:
    """The :class:`~motionweb.store.motion.Motion` of an upload (MotionFormatError, a ValueError,
    naming the line of what the reader refuses). Run in this worker: a crash in the readers'
    compiled kernel costs the request, not the service."""
    if job.bvh is not None:
        from motionweb.store.bvh import parse_bvh

        return parse_bvh(job.bvh, f"{job.name}.bvh", unit=job.unit, scale_to_m=job.scale_to_m, name=job.name,
                         content_hash=job.sha256)
    from dataclasses import replace as _replace

    from motionweb.store.asfamc import CMU_FPS, parse_amc, parse_asf

    asf = parse_asf(job.asf or "", f"{job.name}.asf", **({"length_unit": job.unit} if job.unit else {}))
    m = parse_amc(job.amc or "", asf, f"{job.name}.amc", fps=job.fps or CMU_FPS, name=job.name,
                  content_hash=job.sha256)
    return _replace(m, scale_to_m=job.scale_to_m) if job.scale_to_m else m


def nbytes(obj: Any, seen: set[int] | None = None) -> int:
    """Bytes held by the numpy arrays reachable from ``obj`` (dataclasses, dicts, lists, tuples),
    each array counted once: what a plan costs in memory, but for small Python objects and the
    Pinocchio model (kilobytes)."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        base = obj if obj.base is None else obj.base
        if base is not obj and id(base) in seen:
            return 0
        seen.add(id(base))
        return int(base.nbytes) if isinstance(base, np.ndarray) else int(obj.nbytes)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(nbytes(getattr(obj, f.name), seen) for f in dataclasses.fields(obj))
    if isinstance(obj, dict):
        return sum(nbytes(v, seen) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(nbytes(v, seen) for v in obj)
    return 0


class PlanCache:
    """Prepared plans by key, at most ``max_plans`` of them and ``max_bytes`` in all (:func:`nbytes`);
    the least recently used are dropped first (the newest is kept even alone over the bound).

    Beside them, per clip (``clip_key``) its :func:`~motionweb.tasks.retime.pipeline.clip_physics`
    (body model, glitches, path dynamics, contacts: physics-independent, MPS06 §3.1-3.2), kept while
    a plan of the clip is: a physics change reuses it. Its arrays are the plans' own but for the
    contacts' force basis before the root column, O(F · 6 · nλ); :attr:`total` counts each array
    once."""

    def __init__(self, max_plans: int, max_bytes: int):
        self.max_plans, self.max_bytes = max_plans, max_bytes
        self.items: OrderedDict[str, tuple[Any, int]] = OrderedDict()
        self.clips: dict[str, str] = {}  # plan key -> clip key
        self.physics: dict[str, Any] = {}  # clip key -> clip_physics(...)
        self.evicted = 0

    @property
    def total(self) -> int:
        """Bytes of every array the cache holds, each counted once (plans of one clip share its
        path dynamics; the clips' kept ``clip_physics`` counted too)."""
        seen: set[int] = set()
        return sum(nbytes(p, seen) for p, _ in self.items.values()) + sum(nbytes(v, seen) for v in self.physics.values())

    def get(self, key: str) -> Any:
        if key not in self.items:
            return None
        self.items.move_to_end(key)
        return self.items[key][0]

    def put(self, key: str, plan: Any, clip_key: str | None = None, physics: Any = None) -> int:
        size = nbytes(plan)
        self.items[key] = (plan, size)
        self.items.move_to_end(key)
        if clip_key is not None:
            self.clips[key] = clip_key
            if physics is not None:
                self.physics[clip_key] = physics
        while len(self.items) > 1 and (len(self.items) > self.max_plans or self.total > self.max_bytes):
            old, _ = self.items.popitem(last=False)
            self.clips.pop(old, None)
            self.evicted += 1
        live = set(self.clips.values())
        for k in [k for k in self.physics if k not in live]:
            del self.physics[k]
        return size


class _State:
    def __init__(self, max_plans: int, max_bytes: int):
        self.plans = PlanCache(max_plans, max_bytes)
        #: warp sessions' motions and their local scores by working input (HDP07 §3.2), same bounds
        self.warps = PlanCache(max_plans, max_bytes)

    def warp_prepare(self, job: WarpPrepareJob) -> dict[str, Any]:
        from motionweb.tasks.guided_warp import check_compatible

        if job.reference is not None:
            check_compatible(job.motion, job.reference)
        size = self.warps.put(job.key, {"job": job, "scores": {}})
        return {"key": job.key, "nbytes": size}

    def warp_edit(self, job: WarpEditJob) -> tuple[Any, dict[str, Any]] | None:
        """(warped motion, summary) as ``motionweb warp`` computes them (flows/warp.py's
        ``plan_motions`` and ``solve``), the local scores reused; None when no longer kept."""
        from motionweb.flows.commands.requests import WarpRequest
        from motionweb.flows.warp import flight_phases, plan_motions, solve
        from motionweb.tasks.guided_warp import linear_warp

        entry = self.warps.get(job.key)
        if entry is None:
            return None
        prep = entry["job"]
        cpu = time.process_time()
        request = WarpRequest(input=prep.motion.name, out="", duration=job.duration, keytimes=job.keytimes,
                              fast=job.fast)
        plan = plan_motions(prep.config, request, prep.motion, prep.reference)
        result = solve(plan, job.fast, False, scores=entry["scores"])
        self.warps.items[job.key] = (entry, nbytes(entry))  # the scores it now holds
        fps = plan.motion.fps
        linear = linear_warp(plan.motion, result.n_out, plan.keytimes, resample_motion=False).times
        return result.motion, {
            "input_frames": plan.motion.n_frames, "output_frames": result.n_out, "fps": fps,
            "input_s": plan.motion.duration, "output_s": (result.n_out - 1) / fps, "cost": result.cost,
            "upsample": result.upsample, "heuristic": result.heuristic,
            "keytimes_s": [(i / fps, o / fps) for i, o in result.keytimes],
            # the warp curve (HDP07 Fig. 2): input seconds per output frame, the discrete path, linear
            "times_s": np.round(result.times / fps, 5).tolist(), "raw_s": np.round(result.raw_times / fps, 5).tolist(),
            "linear_s": np.round(linear / fps, 5).tolist(),
            "flights": flight_phases(plan.motion, result, plan.contact_params, plan.up_axis),
            "timings": result.timings, "cpu_s": time.process_time() - cpu}

    def prepare(self, job: PrepareJob) -> dict[str, Any]:
        from motionweb.flows.retime import clip_humanoid
        from motionweb.tasks.retime import RetimeParams, prepare
        from motionweb.tasks.retime.pipeline import clip_physics

        if job.motion.name and job.motion.name in os.environ.get(CRASH_ENV, "").split(","):
            os.kill(os.getpid(), signal.SIGSEGV)
        cpu = time.process_time()
        opts = RetimeParams.model_validate(job.opts)
        humanoid = clip_humanoid(job.deepmimic_path) if job.deepmimic_path else None
        intervals = opts.contacts.intervals.get(job.motion.name) or None
        physics, tm = self.plans.physics.get(job.clip_key), {}
        if physics is None:  # what prepare() computes first, kept for the clip's other physics
            physics = clip_physics(job.motion, opts, up="xyz".index(job.up_axis), humanoid=humanoid,
                                   contact_intervals=intervals, timings=tm)
        plan = prepare(job.motion, opts, up_axis=job.up_axis,
                       gravity=None if job.gravity is None else np.asarray(job.gravity, float), mass=dict(job.mass),
                       humanoid=humanoid, contact_intervals=intervals, weight_factors=dict(job.weight_factors),
                       physics=physics)
        size = self.plans.put(job.key, plan, job.clip_key, physics)
        return {"key": job.key, "nbytes": size, "timings": {**plan.timings, **tm}, "reused_dynamics": not tm,
                "polygons": plot_polygons(plan), "cpu_s": time.process_time() - cpu, **self.info()}

    def edit(self, job: EditJob) -> tuple[Any, dict[str, Any], float] | None:
        from motionweb.tasks.retime import RetimeParams, report, retime_plan

        plan = self.plans.get(job.key)
        if plan is None:
            return None
        cpu = time.process_time()
        opts = RetimeParams.model_validate(job.opts)
        retimed, res = retime_plan(plan, job.duration, [tuple(k) for k in job.keytimes], opts)
        return retimed, report(plan, res), time.process_time() - cpu

    def info(self) -> dict[str, Any]:
        return {"plans": len(self.plans.items), "plan_bytes": self.plans.total, "evicted": self.plans.evicted}


def plot_polygons(plan: Any) -> list[list[list[float]]]:
    """Per source frame its feasible polygon (K, 2) in (p̈, ṗ²) (MPS06 §3.4), 4 digits: what the
    page draws around an output frame's (p̈, ṗ²)."""
    return [np.round(v, 4).tolist() for v in plan.polygons.vertices]


def child_main(fd: int, max_plans: int, max_bytes: int) -> None:
    """The session worker's loop (see the module docstring) through :func:`~motionweb.flows.app.worker.serve`."""
    from motionweb.flows.app.worker import serve
    from motionweb.tasks.retime import prepare  # noqa: F401  (the heavy stack imported before "ready")

    state = _State(max_plans, max_bytes)
    serve(fd, "session worker", {"prepare": state.prepare, "edit": state.edit, "warp_prepare": state.warp_prepare,
                                 "warp_edit": state.warp_edit, "parse": parse_upload, "info": lambda _: state.info()})


class SessionWorker(Worker):
    """The session worker process (a :class:`~motionweb.flows.app.worker.Worker` running
    :func:`child_main`, with the plan cache's bounds)."""

    def __init__(self, max_plans: int, max_bytes: int):
        super().__init__(str(max_plans), str(max_bytes), module="motionweb.flows.app.session_worker")


if __name__ == "__main__":
    child_main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
