"""Clips of the user's own in ``motionweb app``: uploaded BVH or ASF+AMC text, parsed by the
hardened readers (store/bvh.py, store/asfamc.py) in the session worker (a crash in a reader's
compiled kernel costs the request), kept in memory only — never written anywhere, and never under a
name the request gives (the name is a label, reduced to ``[A-Za-z0-9_.-]``) — content-addressed
(the id is the SHA-256 of the texts, so the same upload twice is one clip) in a cache bounded by
count and lifetime (``AppParams.uploads``, ``upload_ttl_s``); the request itself is bounded by
``AppParams.upload_bytes`` (the API's guard). An uploaded clip is named by its id (``up-`` and 16
hex digits) wherever the retime and warp sessions take a clip of the index, and as the query of a
search (KG04 §3.3): its features and its webs against the indexed clips are built on demand by the
search worker (``tasks/query_clip.py``, the code path of ``motionweb search --query-file``) and kept
here with the clip, per generation (:meth:`Uploads.query_webs`).

Memory: the cache is bounded by count (``app.uploads``), lifetime (``app.upload_ttl_s``) and bytes
(``app.upload_mb``, every kept motion, features and web counted), least recently used out first.
Cost: parsing is O(file size); a kept clip holds its motion, O(F · J) (about 40 kB per 100 frames
of a 31-joint skeleton); a searched one also its webs, one per indexed clip of its skeleton (O(F ·
Fb) cells each at most, usually a small fraction along the web's chains).
"""

from __future__ import annotations

import hashlib
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from motionweb.flows.app.engine import UPLOAD_PREFIX, NotFound
from motionweb.flows.app.params import AppParams
from motionweb.flows.app.session_worker import UploadJob, nbytes
from motionweb.flows.query import FILE_PREFIX
from motionweb.store.motion import UNIT_SCALES
from pydantic import BaseModel, ConfigDict, Field

PREFIX = UPLOAD_PREFIX


class UploadBody(BaseModel):
    """An upload: a display name and either ``bvh`` text or ``asf`` and ``amc`` texts; the length
    unit (``unit`` m/cm/mm/in/ft, or ``scale_to_m``; a BVH declares none: the config's corpus unit
    otherwise) and, for an AMC, its frame rate (CMU's 120 Hz by default)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=200)
    bvh: str | None = None
    asf: str | None = None
    amc: str | None = None
    unit: str | None = None
    scale_to_m: float | None = Field(default=None, gt=0, le=1000)
    fps: float | None = Field(default=None, gt=0, le=1000)

    def check(self) -> None:
        pair = self.asf is not None or self.amc is not None
        if (self.bvh is not None) == pair or (pair and (self.asf is None or self.amc is None)):
            raise ValueError("give either bvh (the file's text) or both asf and amc")
        if self.unit is not None and self.unit not in UNIT_SCALES:
            raise ValueError(f"unknown unit {self.unit!r}; expected one of {', '.join(UNIT_SCALES)}")


def label(name: str) -> str:
    """A display name reduced to ``[A-Za-z0-9_.-]`` (at most 64 characters, no leading dot): a
    label only, never a path."""
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name.rsplit("/", 1)[-1].rsplit("\\", 1)[-1])
    safe = re.sub(r"\.(bvh|amc|asf)$", "", safe, flags=re.IGNORECASE).lstrip(".")[:64]
    return safe or "upload"


@dataclass
class Upload:
    id: str
    name: str
    motion: Any
    kind: str
    added: float
    #: SHA-256 of the clip's file as uploaded (the BVH's, or the AMC's, UTF-8): the content address
    #: an index gives the same file, so an upload of an indexed file is searched as that clip
    file_sha256: str = ""
    #: per generation id, the query record (with its features) and webs built for a search
    webs: dict[str, tuple[dict[str, Any], dict[str, Any]]] = field(default_factory=dict)
    nbytes: int = 0

    def query_name(self) -> str:
        """The clip's name as a query file (``--query-file``'s is the file name): id and label."""
        return f"{self.id}/{self.name}.{self.kind}"

    def key(self) -> str:
        """The clip's web-source name as a query from outside the index (``flows/query.FILE_PREFIX``)."""
        return FILE_PREFIX + self.query_name()

    def record(self) -> dict[str, Any]:
        """The clip record the sessions take (as a generation's, its path a label under upload/)."""
        m = self.motion
        return {"path": f"upload/{self.name}.{self.kind}", "sha256": m.content_hash, "category": "upload",
                "frames": m.n_frames, "fps": m.fps, "duration": m.duration, "n_joints": m.skeleton.n_joints,
                "upload": self.id}


class Uploads:
    """The uploaded clips (see the module docstring); ``parse(job)`` runs a reader (the session
    worker's)."""

    def __init__(self, params: AppParams, parse):
        self.params, self.parse = params, parse
        self.items: OrderedDict[str, Upload] = OrderedDict()
        self.lock = threading.Lock()

    def _expire(self) -> None:
        now = time.monotonic()
        for k in [k for k, u in self.items.items() if now - u.added > self.params.upload_ttl_s]:
            del self.items[k]

    def _bound(self) -> None:
        """Drop the least recently used uploads over ``app.uploads`` or ``app.upload_mb`` (the
        newest stays, even alone over the bytes)."""
        limit = self.params.upload_mb * 2**20
        while len(self.items) > self.params.uploads or (len(self.items) > 1 and self.total() > limit):
            self.items.popitem(last=False)

    def total(self) -> int:
        """Bytes held by the kept uploads (motions, features, webs)."""
        return sum(u.nbytes for u in self.items.values())

    def add(self, body: UploadBody, default_unit: str | None, default_scale: float | None) -> dict[str, Any]:
        body.check()
        texts = [body.bvh] if body.bvh is not None else [body.asf, body.amc]
        h = hashlib.sha256()
        for t in texts:
            h.update(t.encode("utf-8", "surrogatepass"))
            h.update(b"\0")
        sha = h.hexdigest()
        uid = PREFIX + sha[:16]
        name = label(body.name)
        with self.lock:
            self._expire()
            known = self.items.get(uid)
        if known is None:
            unit = body.unit if body.unit or body.scale_to_m else default_unit
            scale = body.scale_to_m if body.unit or body.scale_to_m else default_scale
            if body.asf is not None and not (body.unit or body.scale_to_m):
                unit, scale = None, None  # the ASF declares its own (CMU: inches / 0.45)
            motion = self.parse(UploadJob(name, sha, body.bvh, body.asf, body.amc, unit, scale, body.fps))
            check_motion(motion, self.params)
            main = body.bvh if body.bvh is not None else body.amc
            known = Upload(uid, name, motion, "bvh" if body.bvh is not None else "amc", time.monotonic(),
                           hashlib.sha256(main.encode("utf-8", "surrogatepass")).hexdigest(), nbytes=nbytes(motion))
        with self.lock:
            self.items[uid] = known
            self.items.move_to_end(uid)
            self._bound()
        return self.summary(known)

    def query_webs(self, uid: str, gen_id: str, build: Callable[[Upload], tuple[dict[str, Any], dict[str, Any]]]
                   ) -> tuple[dict[str, Any], dict[str, Any]]:
        """The upload's query record (with its features) and webs on generation ``gen_id``: kept
        ones, else ``build(upload)`` (the search worker's, ``tasks/query_clip.py``), then kept with
        the upload within the cache's bounds. Two searches of a new upload may both build (the
        second's copy is kept): the lock is not held while building."""
        u = self.get(uid)
        with self.lock:
            got = u.webs.get(gen_id)
        if got is not None:
            return got
        got = build(u)
        with self.lock:
            u.webs = {gen_id: got}  # an older generation's are of no more use
            u.nbytes = nbytes(u.motion) + nbytes(list(got))
            if uid in self.items:
                self.items.move_to_end(uid)
                self._bound()
        return got

    def get(self, uid: str) -> Upload:
        with self.lock:
            self._expire()
            u = self.items.get(uid)
            if u is None:
                raise NotFound(f"unknown or expired upload {uid!r}: upload the clip again")
            self.items.move_to_end(uid)
            return u

    def summary(self, u: Upload) -> dict[str, Any]:
        m = u.motion
        return {"id": u.id, "name": u.name, "path": u.record()["path"], "frames": m.n_frames, "fps": m.fps,
                "duration": m.duration, "joints": list(m.skeleton.names), "unit": m.unit, "scale_to_m": m.scale_to_m,
                "bytes": u.nbytes}

    def stats(self) -> dict[str, Any]:
        """The cache's uploads, their bytes and its bounds."""
        with self.lock:
            return {"uploads": len(self.items), "bytes": self.total(), "max_bytes": int(self.params.upload_mb * 2**20),
                    "max_uploads": self.params.uploads}


def check_motion(motion: Any, params: AppParams) -> None:
    """ValueError for a clip the sessions cannot take: no frames, too long, no length unit, or
    numbers that are not finite (the readers refuse most such files already)."""
    if motion.n_frames < 2:
        raise ValueError("the clip has fewer than 2 frames")
    if motion.duration > params.session_max_clip_s:
        raise ValueError(f"the clip lasts {motion.duration:g} s; uploads are at most {params.session_max_clip_s:g} s "
                         "(app.session_max_clip_s)")
    if motion.scale_to_m is None:
        raise ValueError("a BVH declares no length unit: give unit (m, cm, mm, in, ft) or scale_to_m")
    if not (np.isfinite(motion.root_positions).all() and np.isfinite(motion.rotations).all()):
        raise ValueError("the clip holds numbers that are not finite")
