"""The service's in-memory side: one committed generation opened, queries on it.

A :class:`Snapshot` is one committed generation of the store opened once: its clip records (each
with an opaque id, the first 12 hex digits of the SHA-256 of its corpus path, so no request names
a path). The searches run in a supervised worker process (:mod:`motionweb.flows.app.worker`) that
reads the webs a search reaches from the store and keeps them packed (KG04 §3.3: the web is
searched in memory) in a cache bounded by ``app.cache_mb``, so a crash in a search's compiled kernels costs that one request (HTTP
500 naming the query, :class:`QueryCrashed`), never the service. :class:`Engine` holds the current
snapshot and, between requests, notices a newly committed generation (the store's pointer moved),
opens it (in the background), then swaps it in: a request works on the snapshot it started with from first to
last, so it never mixes two generations (design §9), and a killed index run, which never moves the
pointer, changes nothing. Results keep their snapshot, so registering or exporting an older result
reads its own generation.

Cost: opening a generation reads its manifest, O(clips + webs), and reads no web, whatever the
size of the library; a search that first reaches a clip reads its webs and packs them into its
walk graph, O(cells of those webs), kept while the cache's bound allows; a warm search costs what
:meth:`MatchSearch.search` costs (linear in the cells of the webs it walks, per tier). Memory: the
manifest, plus per search worker at most ``app.cache_mb`` of webs and graphs (design §5).
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import tempfile
import threading
import time
import uuid
import weakref
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.flows.app.params import graph_files
from motionweb.flows.app.worker import SearchJob, SearchWorkers, WorkerCrashed
from motionweb.flows.commands.requests import QueryRequest, SearchQuery, parse
from motionweb.flows.config import Config
from motionweb.flows.query import (
    PreparedQuery,
    file_record,
    graph_dict,
    indexed_config,
    indexed_twin,
    load_indexed_clip,
    match_rows,
    plot_graph,
    query_segment,
    resolve_clip,
    segment_motion,
    write_outputs,
)
from motionweb.store.bvh import format_bvh
from motionweb.store.cache import LRU
from motionweb.store.generations import Generation, current_generation, load_generation, pointer_signature
from motionweb.store.gltf import glb_bytes
from motionweb.store.motion import Motion
from motionweb.store.webs import StoreWebs
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.features import joint_positions_m
from motionweb.tasks.matchgraph import MatchEdge, MatchGraph, MatchNode, Segment
from motionweb.tasks.ranking import NO_MATCH
from motionweb.tasks.register import Registration
from motionweb.tasks.search import SearchParams
from pydantic import ValidationError

#: bounds on what one request may ask for (design §12: requests are bounded)
MAX_QUERY_S = 60.0
MAX_TIERS = 20
MAX_DRAW_FRAMES = 6000
KEEP_RESULTS = 128
KEEP_MOTIONS = 64
#: an upload's id begins so (flows/app/uploads.py): a search of it builds its webs on demand
UPLOAD_PREFIX = "up-"


class NotFound(KeyError):
    """An unknown clip or result id (the API answers 404)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "not found"


class NotIndexed(ValueError):
    """The store has no committed generation yet (the API answers 409)."""


class QueryCrashed(RuntimeError):
    """A search crashed the worker that ran it (the API answers 500 with the message and the
    query); the service goes on with the standby worker."""

    def __init__(self, query: dict[str, Any], how: str, work: str = "search"):
        self.query, self.how = query, how
        what = f"clip {query['clip']!r}, start {query['start']:g} s, end {query['end']:g} s"
        extra = ", ".join(f"{k} {query[k]}" for k in ("threshold", "quantile", "tiers", "all_categories")
                          if query.get(k) is not None)
        super().__init__(f"the {work} of the query ({what}{', ' + extra if extra else ''}) crashed its worker "
                         f"process ({how}); the service goes on, but this query cannot be answered: please report it")


def clip_id(path: str) -> str:
    """The opaque id of a clip: the first 12 hex digits of the SHA-256 of its corpus path."""
    return hashlib.sha256(path.encode()).hexdigest()[:12]


class Snapshot:
    """One committed generation, opened once (see the module docstring)."""

    def __init__(self, store_url: str, gen: Generation):
        self.url, self.gen = store_url, gen
        self.gen_cfg = indexed_config(gen)
        self.rate = max(float(r) for r in self.gen_cfg.features.rates)
        self.by_path = {c["path"]: c for c in gen.clips}
        self.by_id = {clip_id(c["path"]): c for c in gen.clips}
        self.categories = sorted({c.get("category", "") for c in gen.clips})
        self.motions = LRU(max_items=KEEP_MOTIONS)
        self.warmed = threading.Event()

    def clip(self, key: str) -> dict[str, Any]:
        """A clip record by id, corpus path or unique stem (only looked up in the generation's
        list, never opened as a path)."""
        rec = self.by_id.get(key)
        if rec is not None:
            return rec
        try:
            return resolve_clip(self.gen, key)
        except ValueError as exc:
            raise NotFound(str(exc)) from None

    def warm(self, workers: SearchWorkers) -> None:
        """Have the search workers open every category's scope (reading no web: searches read
        the webs they reach)."""
        try:
            workers.prepare(self.gen.id, list(self.categories))
        finally:
            self.warmed.set()

    def motion(self, rec: dict[str, Any]) -> Motion:
        """The clip's motion (read once, LRU), refused when the file changed since indexing."""
        m = self.motions.get(rec["path"])
        if m is None:
            m = load_indexed_clip(self.gen_cfg, rec)
            self.motions.put(rec["path"], m)
        return m

    def positions(self, motion: Motion) -> np.ndarray:
        """(F, J, 3) joint positions in metres, vertical axis in column 1."""
        return joint_positions_m(motion, self.gen_cfg.corpus.up_axis)

    def clip_row(self, rec: dict[str, Any]) -> dict[str, Any]:
        return {"id": clip_id(rec["path"]), "path": rec["path"], "category": rec.get("category", ""),
                "frames": rec.get("frames"), "fps": rec.get("fps"), "duration": rec["duration"],
                "joints": rec.get("n_joints", rec.get("joints"))}


@dataclass
class Result:
    """A search answered on ``snap``: the graph, its rows, ε and, once asked, the registration."""

    id: str
    snap: Snapshot
    request: SearchQuery
    params: SearchParams
    graph: MatchGraph
    epsilon: float | None  # None: the query matches nothing at any threshold (tasks.ranking.NO_MATCH)
    rows: list[dict[str, Any]]
    timings: dict[str, float]
    lock: threading.Lock = field(default_factory=threading.Lock)
    registration: Registration | None = None
    #: a query clip from outside the index (an upload): its id, record (with its features) and motion
    upload: tuple[str, dict[str, Any], Motion] | None = None

    def clip(self, path: str) -> tuple[dict[str, Any], Motion]:
        """(record, motion) of a node's clip: the query upload's, or the snapshot's."""
        if self.upload is not None and path == self.upload[1]["path"]:
            return self.upload[1], self.upload[2]
        rec = self.snap.by_path[path]
        return rec, self.snap.motion(rec)

    def clip_row(self, rec: dict[str, Any]) -> dict[str, Any]:
        row = self.snap.clip_row(rec)
        if self.upload is not None and rec["path"] == self.upload[1]["path"]:
            row["id"] = self.upload[0]
        return row

    def summary(self) -> dict[str, Any]:
        g = graph_dict(self.graph)
        for e in g["edges"]:
            e.pop("cells")  # the page draws the graph, not the paths (they can be long)
        up = self.upload
        rows = [{**r, "id": up[0] if up is not None and r["clip"] == up[1]["path"] else clip_id(r["clip"])}
                for r in self.rows]
        return {"result": self.id, "generation": self.snap.gen.id, "epsilon": self.epsilon,
                "message": NO_MATCH if self.epsilon is None else "", "query": rows[0],
                "matches": rows[1:], "graph": g, "timings": self.timings, "request": self.request.wire()}


def query_fields(request: SearchQuery) -> dict[str, Any]:
    """A request's fields but a CLI's local folders (what an error names)."""
    return request.search_query().wire() if isinstance(request, QueryRequest) else request.wire()


def draw_frames(frames: np.ndarray) -> np.ndarray:
    """At most :data:`MAX_DRAW_FRAMES` of ``frames`` (evenly subsampled, last kept)."""
    if len(frames) <= MAX_DRAW_FRAMES:
        return frames
    return frames[np.unique(np.linspace(0, len(frames) - 1, MAX_DRAW_FRAMES).round().astype(int))]


def pose_payload(snap: Snapshot, motion: Motion, frames: np.ndarray, rate: float) -> dict[str, Any]:
    """Joint positions for drawing: ``frames`` (at ``rate`` Hz, fractional allowed) as a flat
    list of metres (F·J·3, millimetre precision), with the bones."""
    m = segment_motion(motion, draw_frames(np.asarray(frames, np.float64)), rate)
    pos = snap.positions(m)
    return {"rate": rate, "frames": int(pos.shape[0]), "joints": list(motion.skeleton.names),
            "parents": [int(p) for p in motion.skeleton.parents],
            "positions": np.round(pos.reshape(-1), 3).tolist()}


def prime_plots() -> None:
    """Draw one small match graph into memory, so the first query's ``graph.png`` does not pay
    for loading matplotlib and its fonts (seconds on a busy machine)."""
    graph = MatchGraph(30.0, [MatchNode(Segment("a/query.bvh", 0, 30)), MatchNode(Segment("b/m.bvh", 5, 35), 1, 0.1, 0.1)],
                       [MatchEdge(0, 1, 0.1)])
    rows = [{"category": "a"}, {"category": "b"}]
    plot_graph(graph, rows, io.BytesIO())


class Engine:
    """The current snapshot of one store and the queries on it (see the module docstring).

    ``on_query(kind, parameters, summary)`` is called after every answered query (the recorder
    makes a Prefect flow run of it); ``warm`` opens a generation's scopes in the search worker
    before it is swapped in and keeps a warm standby search worker (each worker keeps at most
    ``cfg.app.cache_mb`` of webs and graphs). :meth:`close` ends the search workers (also done
    when the engine is garbage-collected, and at exit).
    """

    def __init__(self, cfg: Config, on_query: Callable[[str, dict, dict], None] | None = None, warm: bool = True):
        self.cfg, self.on_query, self.warm = cfg, on_query, warm
        self.url = cfg.store.path
        self._snap: Snapshot | None = None
        self._pointer: tuple[tuple | None, str | None] = (None, None)  # (pointer_signature, its generation)
        #: the generation the last strict check parsed, until :meth:`_open` takes it (parsed once)
        self._parsed: Generation | None = None
        self._lock = threading.Lock()
        self._loading: threading.Thread | None = None
        self.results = LRU(max_items=KEEP_RESULTS)
        #: the user's uploaded clips (:class:`~motionweb.flows.app.uploads.Uploads`, set by the API):
        #: a search names one by its id, its webs are kept there
        self.uploads: Any = None
        self._plot_lock = threading.Lock()  # one figure drawn at a time (they share font caches)
        self.switches = 0
        self.workers = SearchWorkers(self.url, standby=warm, cache_bytes=int(cfg.app.cache_mb * 2**20),
                                     files=graph_files(cfg.app))
        self._finalize = weakref.finalize(self, self.workers.close)
        if warm:
            threading.Thread(target=prime_plots, name="prime-plots", daemon=True).start()
            # the primary search worker opens the current generation meanwhile (its manifest parsed
            # on the other core while this process parses its own)
            threading.Thread(target=self.workers.start, name="search-start", daemon=True).start()

    def close(self) -> None:
        """End the search workers."""
        self._finalize()

    # ------------------------------------------------------------------ generations
    def pointer(self) -> str | None:
        """The current generation's id (``current_generation``: the strict check, which reads the
        whole manifest, O(webs), runs only when the pointer or its manifest changed since the last
        request: :func:`~motionweb.store.generations.pointer_signature`; the generation it parsed
        is kept for :meth:`_open`)."""
        store = MotionStore(self.url, read_only=True)
        sig = pointer_signature(store)
        if sig is not None and sig == self._pointer[0]:
            return self._pointer[1]
        gen = current_generation(store, lean=True)
        gen_id = gen.id if gen is not None else None
        with self._lock:
            self._pointer = (sig, gen_id)
            self._parsed = gen
        return gen_id

    def _open(self, gen_id: str) -> Snapshot:
        """A snapshot of ``gen_id``, from the manifest the pointer check parsed when it is that one
        (called with ``_lock`` held)."""
        gen, self._parsed = self._parsed, None
        if gen is None or gen.id != gen_id:
            gen = load_generation(MotionStore(self.url, read_only=True), gen_id, lean=True)
        return Snapshot(self.url, gen)

    def _swap_after_warm(self, snap: Snapshot) -> None:
        try:
            if self.warm:
                snap.warm(self.workers)
        finally:
            with self._lock:
                if self._snap is None or snap.gen.id > self._snap.gen.id:
                    self._snap = snap
                    self.switches += 1
                self._loading = None

    def current(self, wait: bool = False) -> Snapshot:
        """The snapshot requests use now. A newly committed generation is opened and warmed in a
        background thread while the previous one keeps serving (``wait``: block until it is in).
        Raises :class:`NotIndexed` while the store has no generation."""
        gen_id = self.pointer()
        with self._lock:
            snap, loading = self._snap, self._loading
            if snap is not None and snap.gen.id == gen_id:
                self._parsed = None  # the one served: no second copy kept
            if gen_id is not None and (snap is None or snap.gen.id != gen_id) and loading is None:
                new = self._open(gen_id)
                if snap is None:  # nothing to serve meanwhile: serve it now, warm it behind
                    self._snap, snap = new, new
                    self.switches += 1
                    if self.warm:
                        threading.Thread(target=new.warm, args=(self.workers,), name="warm", daemon=True).start()
                else:
                    loading = self._loading = threading.Thread(target=self._swap_after_warm, args=(new,),
                                                               name="warm", daemon=True)
                    loading.start()
        if wait and loading is not None:
            loading.join()
            snap = self._snap
        if snap is None:
            raise NotIndexed(f"store {self.url} was never indexed: run `motionweb index CONFIG` first")
        return snap

    def status(self) -> dict[str, Any]:
        try:
            snap = self.current()
        except NotIndexed as exc:
            return {"generation": None, "message": str(exc)}
        cats: dict[str, int] = {}
        for c in snap.gen.clips:
            cats[c.get("category", "")] = cats.get(c.get("category", ""), 0) + 1
        return {"generation": snap.gen.id, "committed": snap.gen.completed, "clips": len(snap.gen.clips),
                "webs": len(snap.gen.webs), "rate": snap.rate, "categories": cats,
                "loading": self._loading is not None, "warm": snap.warmed.is_set(), "max_query_s": MAX_QUERY_S,
                "max_tiers": MAX_TIERS, "worker": self.workers.info(), "cache": self.workers.cache_stats(),
                "uploads": self.uploads.stats() if self.uploads is not None else None}

    # ------------------------------------------------------------------ catalog and clips
    def catalog(self, category: str | None = None, name: str | None = None, min_s: float | None = None,
                max_s: float | None = None, offset: int = 0, limit: int = 500) -> dict[str, Any]:
        """Clips filtered by category (exact), name (case-insensitive substring of the path) and
        duration (seconds), sorted by path; one page of them."""
        snap = self.current()
        rows = []
        for rec in sorted(snap.gen.clips, key=lambda c: c["path"]):
            if category is not None and rec.get("category", "") != category:
                continue
            if name and name.lower() not in rec["path"].lower():
                continue
            if (min_s is not None and rec["duration"] < min_s) or (max_s is not None and rec["duration"] > max_s):
                continue
            rows.append(snap.clip_row(rec))
        return {"generation": snap.gen.id, "total": len(rows), "offset": offset,
                "clips": rows[offset:offset + limit]}

    def clip_pose(self, key: str, rate: float) -> dict[str, Any]:
        """A whole clip's joint positions at ``rate`` Hz for drawing."""
        snap = self.current()
        rec = snap.clip(key)
        m = snap.motion(rec)
        frames = np.arange(0.0, rec["duration"] * rate + 1e-9)
        return {**snap.clip_row(rec), "generation": snap.gen.id, **pose_payload(snap, m, frames, rate)}

    def upload_pose(self, uid: str, rate: float) -> dict[str, Any]:
        """An uploaded clip's joint positions at ``rate`` Hz for drawing (the player shows it to
        choose the query's segment), with the upload's summary."""
        snap = self.current()
        u = self.uploads_get(uid)
        frames = np.arange(0.0, u.motion.duration * rate + 1e-9)
        summary = {k: v for k, v in self.uploads.summary(u).items() if k != "joints"}
        return {**summary, "category": "upload", "generation": snap.gen.id, "upload": True,
                **pose_payload(snap, u.motion, frames, rate)}

    def clip_bvh(self, key: str) -> tuple[str, str]:
        """(file name, BVH text) of a clip as indexed."""
        snap = self.current()
        rec = snap.clip(key)
        return Path(rec["path"]).name if rec["path"].endswith(".bvh") else Path(rec["path"]).stem + ".bvh", \
            format_bvh(snap.motion(rec))

    def clip_glb(self, key: str) -> tuple[str, bytes]:
        """(file name, GLB bytes) of a clip as indexed (store.gltf: metres, Y up)."""
        snap = self.current()
        rec = snap.clip(key)
        return Path(rec["path"]).stem + ".glb", glb_bytes(snap.motion(rec), snap.gen_cfg.corpus.up_axis)

    # ------------------------------------------------------------------ search
    @staticmethod
    def check_bounds(req: SearchQuery) -> None:
        """The service's bounds on a request the CLI would accept (after the CLI's own checks)."""
        if req.end - req.start > MAX_QUERY_S:
            raise ValueError(f"the query spans {req.end - req.start:g} s; the service searches at most "
                             f"{MAX_QUERY_S:g} s")
        if req.tiers is not None and req.tiers > MAX_TIERS:
            raise ValueError(f"tiers must be ≤ {MAX_TIERS}, got {req.tiers}")

    def search_params(self, search: dict[str, Any] | None) -> SearchParams:
        """The config's search section with ``search`` (the CLI's own) over it."""
        try:
            return SearchParams.model_validate({**self.cfg.search.model_dump(), **(search or {})})
        except ValidationError as exc:
            raise ValueError("; ".join(f"search.{'.'.join(str(p) for p in e['loc'])}: {e['msg']}"
                                       for e in exc.errors())) from None

    def search(self, request: SearchQuery | dict[str, Any], search: dict[str, Any] | None = None) -> Result:
        """Search the current snapshot (KG04 §3.3) for ``request`` (the model, or its fields),
        with ``search`` overriding the config's search section (the CLI sends its own).
        ValueError with the CLI's messages for bad requests."""
        t0 = time.perf_counter()
        if isinstance(request, QueryRequest):
            request = request.search_query()
        elif not isinstance(request, SearchQuery):
            request = parse(SearchQuery, **request)  # ValueError with the CLI's messages
        snap = self.current()
        upload, key = None, request.clip
        if self.uploads is not None and request.clip.startswith(UPLOAD_PREFIX):
            upload = self.uploads_get(request.clip)
            twin = indexed_twin(snap.gen, upload.file_sha256)
            if twin is not None:  # the upload is an indexed file: the query is that clip (content-addressed)
                upload, key = None, twin["path"]
        if upload is not None:
            rec = file_record(upload.motion, upload.key())
        else:
            rec = snap.clip(key)
        seg = query_segment(rec, request.start, request.end, snap.rate)
        self.check_bounds(request)
        params = self.search_params(search)
        if request.tiers is not None:
            params = params.model_copy(update={"max_tiers": request.tiers})
        all_cats = params.all_categories if request.all_categories is None else request.all_categories
        query = None
        if upload is not None:
            rec, webs = self.upload_webs(snap, upload, request)
            query, all_cats = (rec["path"], webs), True  # a file has no category: every category's webs
        # ε: the threshold, the quantile of the scope's webs, or else the query flow's default
        # rule (a multiple of the query's nearest match); all computed in the worker
        job = SearchJob(snap.gen.id, None if all_cats else rec.get("category", ""), seg, params.model_dump(),
                        request.threshold, request.quantile, query)
        try:
            graph, eps = self.workers.search(job)
        except WorkerCrashed as exc:
            raise QueryCrashed(query_fields(request), exc.how) from None
        clips = snap.by_path if upload is None else {**snap.by_path, rec["path"]: rec}
        res = Result(uuid.uuid4().hex[:12], snap, request, params, graph, None if eps is None else float(eps),
                     match_rows(graph, clips), {"search_s": time.perf_counter() - t0},
                     upload=None if upload is None else (upload.id, rec, upload.motion))
        self.results.put(res.id, res)
        if self.on_query:
            self.on_query("search", request.wire(), {"result": res.id, "generation": snap.gen.id, "epsilon": eps,
                                                      "matches": len(res.rows) - 1, **res.timings})
        return res

    def uploads_get(self, uid: str) -> Any:
        """An upload by id (:class:`NotFound` naming the field ``clip``)."""
        try:
            return self.uploads.get(uid)
        except NotFound as exc:
            raise NotFound(f"clip: {exc}") from None

    def upload_webs(self, snap: Snapshot, upload: Any, request: SearchQuery) -> tuple[dict[str, Any], dict[str, Any]]:
        """The upload's query record (with its features) and its webs against the snapshot's
        clips (KG04 §3.3): kept in the upload cache, else built by the search worker with
        ``search --query-file``'s code path (``flows/query.prepare_file_query``)."""
        def build(u: Any) -> tuple[dict[str, Any], dict[str, Any]]:
            t = time.perf_counter()
            try:
                # content-addressed by its file's SHA-256, as --query-file's clip (the hashes order
                # each pair's rows as the index does: the same file gives the same webs)
                motion = replace(u.motion, content_hash=u.file_sha256)
                got = self.workers.query_webs(snap.gen.id, u.query_name(), motion)
            except WorkerCrashed as exc:
                raise QueryCrashed(query_fields(request), exc.how, "webs") from None
            except ValueError as exc:  # e.g. no indexed clip has its skeleton
                raise ValueError(f"clip: {exc}") from None
            if self.on_query:
                self.on_query("query-webs", {"upload": u.id, "generation": snap.gen.id},
                              {"webs": len(got[1]), "webs_s": time.perf_counter() - t})
            return got

        return self.uploads.query_webs(upload.id, snap.gen.id, build)

    def registration(self, gen_id: str, graph: MatchGraph, request: SearchQuery,
                     extra: dict[str, Any] | None = None) -> Registration:
        """``graph``'s registration (KG04 §4.1), computed by the search worker (``extra``: the
        record of a query clip from outside the index)."""
        try:
            return self.workers.register(gen_id, graph, extra)
        except WorkerCrashed as exc:
            raise QueryCrashed(query_fields(request), exc.how, "registration") from None

    def result(self, rid: str) -> Result:
        res = self.results.get(rid)
        if res is None:
            raise NotFound(f"unknown or expired result {rid!r}: search again")
        return res

    def register(self, rid: str) -> dict[str, Any]:
        """The result's registration (KG04 §4.1): for each node (by rank) its frames s_i(u) at
        every query frame u, and its parent in the shortest-path tree."""
        res = self.result(rid)
        with res.lock:
            if res.registration is None and len(res.graph.nodes) > 1:
                t = time.perf_counter()
                snap = res.snap
                extra = None if res.upload is None else {res.upload[1]["path"]: res.upload[1]}
                res.registration = self.registration(snap.gen.id, res.graph, res.request, extra)
                res.timings["register_s"] = time.perf_counter() - t
                if self.on_query:
                    self.on_query("register", {"result": rid}, {"nodes": len(res.graph.nodes),
                                                                "register_s": res.timings["register_s"]})
        reg = res.registration
        q = res.graph.nodes[0].segment
        if reg is None:
            return {"result": rid, "rate": res.graph.rate, "u": [q.start, q.end], "nodes": [
                {"rank": 0, "parent": -1, "start": q.start, "end": q.end, "frames": [q.start, q.end]}]}
        u = reg.u
        nodes = [{"rank": int(reg.nodes[c]), "parent": int(reg.nodes[reg.parents[c]]) if reg.parents[c] >= 0 else -1,
                  "start": s.start, "end": s.end, "frames": np.round(reg.frames[:, c], 3).tolist()}
                 for c, s in enumerate(reg.segments)]
        nodes.sort(key=lambda n: n["rank"])
        return {"result": rid, "rate": reg.rate, "u": [float(u[0]), float(u[-1])], "nodes": nodes,
                "register_s": res.timings.get("register_s")}

    def node(self, rid: str, rank: int) -> tuple[Result, Segment]:
        res = self.result(rid)
        if not 0 <= rank < len(res.graph.nodes):
            raise NotFound(f"result {rid} has no rank {rank} (ranks 0..{len(res.graph.nodes) - 1})")
        return res, res.graph.nodes[rank].segment

    def node_frames(self, rid: str, rank: int, registered: bool) -> np.ndarray:
        """Frames (at the web rate) of a node: its segment, or registered to the query's timing
        (its s_i(u) at the query's frames, KG04 §4.1)."""
        res, seg = self.node(rid, rank)
        if not registered:
            return np.arange(seg.start, seg.end + 1, dtype=np.float64)
        self.register(rid)
        if res.registration is None:
            return np.arange(seg.start, seg.end + 1, dtype=np.float64)
        col = res.registration.nodes.index(rank)
        return res.registration.resample()[:, col]

    def node_pose(self, rid: str, rank: int, registered: bool) -> dict[str, Any]:
        res, seg = self.node(rid, rank)
        frames = self.node_frames(rid, rank, registered)
        rec, motion = res.clip(seg.clip)
        return {**res.clip_row(rec), "rank": rank, "start_frame": seg.start, "end_frame": seg.end,
                "registered": registered, **pose_payload(res.snap, motion, frames, res.graph.rate)}

    def node_bvh(self, rid: str, rank: int, registered: bool) -> tuple[str, str]:
        """(file name, BVH text) of a node's segment, as the query flow's export names it."""
        res, seg = self.node(rid, rank)
        frames = self.node_frames(rid, rank, registered)
        m = segment_motion(res.clip(seg.clip)[1], frames, res.graph.rate)
        tag = "registered" if registered else f"{seg.start}-{seg.end}"
        return f"{rank:03d}_{Path(seg.clip).stem}_{tag}.bvh", format_bvh(m)

    def node_glb(self, rid: str, rank: int, registered: bool) -> tuple[str, bytes]:
        """(file name, GLB bytes) of a node's segment: :meth:`node_bvh` as glTF binary."""
        res, seg = self.node(rid, rank)
        frames = self.node_frames(rid, rank, registered)
        m = segment_motion(res.clip(seg.clip)[1], frames, res.graph.rate)
        tag = "registered" if registered else f"{seg.start}-{seg.end}"
        return f"{rank:03d}_{Path(seg.clip).stem}_{tag}.glb", glb_bytes(m, res.snap.gen_cfg.corpus.up_axis)

    # ------------------------------------------------------------------ the CLI's query
    def query_bundle(self, request: QueryRequest, search: dict[str, Any] | None) -> bytes:
        """What ``motionweb search`` writes, made here: a zip of ``result.json`` (the query
        flow's result, file names relative to the zip: ``out/...``, ``export/...``) and those
        files. They are written into a folder of the service's own, never one a request names."""
        t0 = time.perf_counter()
        if request.clip.startswith(UPLOAD_PREFIX):
            raise ValueError("clip: an upload is searched with POST /api/search (the CLI searches a file of "
                             "its own with --query-file)")
        res = self.search(request, search)
        snap = res.snap
        export = request.export is not None
        # the config as the CLI's run records it: its search section, not the request's tiers
        cfg = self.cfg.model_copy(update={"search": self.search_params(search)})
        rec = snap.clip(request.clip)
        store = MotionStore(snap.url, read_only=True)
        q = PreparedQuery(store, snap.gen, snap.gen_cfg, rec, res.graph.nodes[0].segment,
                          StoreWebs(store, snap.gen, rec.get("category", "")))
        tmp = Path(tempfile.mkdtemp(prefix="motionweb-app-"))
        try:
            with self._plot_lock:
                out = write_outputs(cfg, request, q, res.graph, res.epsilon, tmp / "out",
                                    tmp / "export" if export else None, t0,
                                    lambda _store, gen, _cfg, graph, _clips: self.registration(gen.id, graph, request))
            out["files"] = [Path(f).relative_to(tmp).as_posix() for f in out["files"]]
            out["out"], out["result"] = "out", res.id
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
                z.writestr("result.json", json.dumps(out))
                for f in out["files"]:
                    z.write(tmp / f, f)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return buf.getvalue()
