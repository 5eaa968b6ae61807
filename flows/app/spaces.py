"""The service's motion spaces (KG04 §4): stored spaces listed, their sampled parameters for
drawing, and motions synthesized for a target or blended from weights, kept loaded in memory.

A space is read from the store once (its examples rebuilt from the clips of its generation,
:func:`motionweb.flows.space.load_space`; started in the background when its cloud is asked
for) and kept (LRU of :data:`KEEP_SPACES`); a lock per space serializes its syntheses. Ids are digests (hex); a request names a space by its id or a unique
prefix, never by a path. Cost: loading a space reads and registers its N examples once; a
synthesis is a k-nearest-sample lookup plus one blend per refinement round (``tasks/parameterize``)
and the blend of the chosen weights; drawing it is forward kinematics of its frames.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from motionweb.flows.app.engine import NotFound
from motionweb.flows.config import Config
from motionweb.flows.query import indexed_config
from motionweb.flows.space import StoredSpace, list_spaces, load_space, space_info, weight_vector
from motionweb.store.bvh import format_bvh
from motionweb.store.generations import load_generation
from motionweb.store.motion import Motion
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.features import joint_positions_m

#: bounds (design §12): spaces kept loaded, samples sent for drawing, |target| in metres
KEEP_SPACES = 8
MAX_DRAW_SAMPLES = 4000
MAX_TARGET_M = 100.0
SPACE_ID = re.compile(r"^[0-9a-f]{1,64}$")
log = logging.getLogger("motionweb.app")


@dataclass
class Loaded:
    space: StoredSpace
    up: str
    lock: threading.Lock = field(default_factory=threading.Lock)


def check_id(space_id: str) -> None:
    if not SPACE_ID.match(space_id):
        raise NotFound(f"motion space {space_id!r} is not stored: ids are hexadecimal digests")


def check_target(param: str, dim: int, target: list[float]) -> np.ndarray:
    """The target as (d,) metres: as many finite values as the parameter has, each bounded."""
    if len(target) != dim:
        raise ValueError(f"--target has {len(target)} values; space parameter {param} has {dim}")
    if not all(math.isfinite(v) and abs(v) <= MAX_TARGET_M for v in target):
        raise ValueError(f"--target values must be finite and within ±{MAX_TARGET_M:g} m, got {target}")
    return np.asarray(target, np.float64)


class Spaces:
    """The motion spaces of one store (see the module docstring)."""

    def __init__(self, cfg: Config, on_query: Callable[[str, dict, dict], None] | None = None):
        self.cfg, self.on_query = cfg, on_query
        self._loaded: dict[str, Loaded] = {}
        self._order: list[str] = []
        self._loading: dict[str, threading.Lock] = {}
        self._lock = threading.Lock()

    def summaries(self) -> list[dict[str, Any]]:
        return list_spaces(self.cfg)

    def info(self, space_id: str) -> tuple[str, dict[str, Any], dict[str, np.ndarray]]:
        """(digest, attributes, arrays) without loading clips; :class:`NotFound`."""
        check_id(space_id)
        try:
            return space_info(self.cfg, space_id)
        except KeyError as exc:
            raise NotFound(str(exc).strip("'\"")) from None

    def detail(self, space_id: str) -> dict[str, Any]:
        """A space's parameter, examples and sampled parameters (at most
        :data:`MAX_DRAW_SAMPLES`, evenly chosen, the examples' always first) for drawing."""
        digest, attrs, arrays = self.info(space_id)
        self.prefetch(digest)
        params = np.asarray(arrays["params"], np.float64)
        ex = np.asarray(arrays["example_params"], np.float64)
        keep = params
        if len(params) > MAX_DRAW_SAMPLES:
            keep = params[np.unique(np.linspace(0, len(params) - 1, MAX_DRAW_SAMPLES).round().astype(int))]
        return {"id": digest, "param": attrs["param"], "dim": int(attrs["dim"]), "names": list(attrs["names"]),
                "generation": attrs["generation"], "query": attrs.get("request"), "epsilon": attrs.get("epsilon"),
                "samples_total": int(len(params)), "samples": np.round(keep, 4).tolist(),
                "example_params": np.round(ex, 4).tolist(),
                "lo": np.round(params.min(axis=0), 4).tolist(), "hi": np.round(params.max(axis=0), 4).tolist()}

    def load(self, space_id: str) -> Loaded:
        """The space loaded (once, however many requests ask at the same time; LRU)."""
        digest, attrs, _ = self.info(space_id)
        with self._lock:
            once = self._loading.setdefault(digest, threading.Lock())
        with once:
            with self._lock:
                hit = self._loaded.get(digest)
                if hit is not None:
                    self._order.remove(digest)
                    self._order.append(digest)
                    return hit
            space = load_space(self.cfg, digest)
            gen = load_generation(MotionStore(self.cfg.store.path, read_only=True), attrs["generation"], lean=True)
            loaded = Loaded(space, indexed_config(gen).corpus.up_axis)
            with self._lock:
                self._loaded[digest] = loaded
                self._order.append(digest)
                while len(self._order) > KEEP_SPACES:
                    self._loaded.pop(self._order.pop(0), None)
            return loaded

    def prefetch(self, digest: str) -> None:
        """Load the space in the background and make one motion from it (compiling the blend's
        kernels): the page asks for its cloud first, then for motions."""
        with self._lock:
            if digest in self._loaded or digest in self._loading:
                return  # loaded, or on its way
            self._loading[digest] = threading.Lock()

        def run() -> None:
            try:
                loaded = self.load(digest)
                with loaded.lock:
                    loaded.space.synthesize(loaded.space.samples[0])
            except Exception:  # noqa: BLE001 - the next request for it reports the problem
                log.exception("loading motion space %s", digest[:12])

        threading.Thread(target=run, name=f"space-{digest[:12]}", daemon=True).start()

    def synthesize(self, space_id: str, target: list[float]) -> tuple[Loaded, Motion, dict[str, Any]]:
        """A motion for ``target`` (KG04 §4.3; projected when outside) and how close it came."""
        _, attrs, _ = self.info(space_id)
        t = check_target(attrs["param"], int(attrs["dim"]), target)
        loaded = self.load(space_id)
        with loaded.lock:
            motion, syn = loaded.space.synthesize(t)
        extra = {
            "target": syn.target.tolist(), "achieved": syn.achieved.tolist(), "error": float(syn.error),
            "nearest": float(syn.nearest), "outside": bool(syn.outside),
            "weights": {n: float(w) for n, w in zip(loaded.space.clips, syn.weights, strict=True) if w != 0}}
        self._record("synthesize", {"space": space_id, "target": t.tolist()}, extra)
        return loaded, motion, extra

    def blend(self, space_id: str, weights: dict[str, float]) -> tuple[Loaded, Motion, dict[str, Any]]:
        """A motion from explicit weights by example (corpus path or stem; they sum to 1)."""
        if not all(math.isfinite(v) for v in weights.values()):
            raise ValueError("weights must be finite numbers")
        _, attrs, _ = self.info(space_id)
        w = weight_vector(list(attrs["names"]), weights)  # names and sum (the CLI's messages), before loading
        loaded = self.load(space_id)
        with loaded.lock:
            motion = loaded.space.motion(w)
        extra = {"weights": {n: float(v) for n, v in zip(loaded.space.clips, w, strict=True) if v}}
        self._record("blend", {"space": space_id, "weights": weights}, {"frames": motion.n_frames})
        return loaded, motion, extra

    def _record(self, kind: str, parameters: dict[str, Any], outcome: dict[str, Any]) -> None:
        """Hand an answered synthesis or blend to the recorder (a Prefect flow run, as searches)."""
        if self.on_query:
            self.on_query(kind, parameters, outcome)

    @staticmethod
    def answer(loaded: Loaded, motion: Motion, extra: dict[str, Any], pose: bool, bvh: bool,
               max_frames: int) -> dict[str, Any]:
        """The JSON answer: ``extra``, the motion's frames and fps, its joint positions for drawing
        (metres, y up, at most ``max_frames``) and its BVH text when asked."""
        out = {"space": loaded.space.id, **extra, "frames": int(motion.n_frames), "fps": float(motion.fps)}
        if pose:
            idx = np.arange(motion.n_frames)
            if len(idx) > max_frames:
                idx = np.unique(np.linspace(0, len(idx) - 1, max_frames).round().astype(int))
            pos = joint_positions_m(motion, loaded.up)[idx]
            rate = float(motion.fps) * (len(idx) - 1) / max(1, motion.n_frames - 1) if len(idx) > 1 else motion.fps
            out["pose"] = {"rate": float(rate), "frames": int(len(idx)), "joints": list(motion.skeleton.names),
                           "parents": [int(p) for p in motion.skeleton.parents],
                           "positions": np.round(pos.reshape(-1), 3).tolist()}
        if bvh:
            out["bvh"] = format_bvh(motion)
        return out
