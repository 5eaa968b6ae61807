"""The index flow: catalog → category chunks → features → pair plan → match webs → commit (design §1, §10).

Prefect tasks are chunk-level and thin; inside a chunk Dask computes batches of clip pairs
balanced by grid cells (KG04 §3: one distance grid and web per pair of motions). Tasks pass
store URLs and keys, never arrays: Dask workers read features from the Zarr store and write
webs to it (design §9). The pure pieces — chunking, skeleton compatibility, pair plan, batch
balancing, generation manifest, summary — are plain functions tested without Prefect.

Incremental rules follow from content addressing: a pair whose web key (both clip hashes +
parameter digest) is complete in the store is *cached*; only the others are computed. A new
generation lists exactly the pairs of the current catalog, so removed clips drop out.

Skeleton compatibility: point-cloud distances (design §3) need the same joints in both clips. In
each chunk the majority skeleton signature is reported; every clip is paired only with clips of
the same signature, so a clip with a minority skeleton is indexed against the (possibly empty)
set of compatible clips and listed under ``skeleton`` in the generation record.
"""

from __future__ import annotations

import heapq
import logging
import math
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any

from motionweb.flows.config import Config, DaskConfig
from motionweb.flows.runtime.lazy_prefect import run_logger, task
from motionweb.store.catalog import Catalog, ClipEntry, scan_corpus
from motionweb.store.generations import (
    Generation,
    PointerError,
    commit,
    current_generation,
    gc,
    package_versions,
    same_content,
)
from motionweb.store.keys import (
    feature_digest,
    feature_key,
    feature_params,
    rate_tag,
    web_digest,
    web_key,
    web_params,
)
from motionweb.store.zarr_store import MotionStore, StoreError, new_id, now_iso

log = logging.getLogger(__name__)

#: below this many working-rate cells to compute, a local cluster uses threads (no process start)
SMALL_RUN_CELLS = 4e7
#: a batch holds about this many cells at most (progress granularity; KG04 grids are O(n²))
BATCH_CELLS = 5e7
#: per-pair fixed cost in cell units when balancing (loading, coarse levels, writing)
PAIR_OVERHEAD_CELLS = 2e4

#: optional progress callback ``(stage, done, total)``, set by the CLI for a counter
PROGRESS: Callable[[str, int, int], None] | None = None
#: the objects an :func:`unchanged_summary` that found a commit to make (a config, a catalog
#: change) verified, set by the CLI for the flow it then runs, like :data:`PROGRESS`:
#: ``{"store": url, "generation": id, "objects": {key: problem or None}}``. The flow's plan takes
#: the answers for the same store and current generation instead of reading every reused object
#: a second time (32.6 GB of webs at 10^6 frames: about a minute)
VERIFIED: dict[str, Any] | None = None


# ------------------------------------------------------------------------------ pure planning
@dataclass(frozen=True)
class Chunk:
    """A set of clips indexed against each other (a category, or the whole corpus)."""

    name: str
    clips: tuple[ClipEntry, ...]

    @property
    def frames(self) -> int:
        return sum(c.frames for c in self.clips)


@dataclass(frozen=True)
class PairJob:
    """One web to compute: rows ``a``, columns ``b`` (``a.sha256 <= b.sha256``)."""

    chunk: str
    a: ClipEntry
    b: ClipEntry
    key: str
    cells: int
    self_pair: bool

    def record(self) -> dict[str, Any]:
        return {"chunk": self.chunk, "a": self.a.path, "b": self.b.path, "a_sha": self.a.sha256,
                "b_sha": self.b.sha256, "key": self.key, "cells": self.cells, "self": self.self_pair}


@dataclass
class SkeletonReport:
    """Per chunk: the majority skeleton and the clips only indexed against compatible clips."""

    chunk: str
    majority: str
    groups: dict[str, list[str]]
    minority: list[str]


def working_rate(cfg: Config) -> float:
    """The finest rate of the coarse-to-fine ladder (KG04 §3.2; the last of ``features.rates``)."""
    return float(max(cfg.features.rates))


def frames_at(entry: ClipEntry, rate: float) -> int:
    """Frames of a clip resampled to ``rate`` (an estimate used for balancing and reporting)."""
    return math.floor(entry.duration * rate + 1e-9) + 1


def plan_chunks(entries: list[ClipEntry], chunk_by: str) -> list[Chunk]:
    """Category chunks (design §1), or one chunk ``all`` when ``chunk_by == "none"``."""
    ordered = sorted(entries, key=lambda e: e.path)
    if chunk_by == "none":
        return [Chunk("all", tuple(ordered))] if ordered else []
    groups: dict[str, list[ClipEntry]] = {}
    for e in ordered:
        groups.setdefault(e.category, []).append(e)
    return [Chunk(name, tuple(clips)) for name, clips in sorted(groups.items())]


def skeleton_groups(chunk: Chunk) -> SkeletonReport:
    """Group a chunk's clips by skeleton signature; the majority (most frames on ties) first."""
    groups: dict[str, list[ClipEntry]] = {}
    for c in chunk.clips:
        groups.setdefault(c.skeleton, []).append(c)
    if not groups:
        return SkeletonReport(chunk.name, "", {}, [])
    majority = max(groups, key=lambda s: (len(groups[s]), sum(c.frames for c in groups[s]), s))
    minority = [c.path for s, cs in groups.items() if s != majority for c in cs]
    return SkeletonReport(chunk.name, majority, {s: [c.path for c in cs] for s, cs in groups.items()}, minority)


def plan_pairs(chunk: Chunk, wdigest: str, rate: float, self_pairs: bool = True) -> list[PairJob]:
    """Every unordered pair of skeleton-compatible clips of a chunk (and each clip with itself).

    The rows clip is the one with the smaller hash, so a pair's key does not depend on paths or
    order; two files with identical bytes share one key (and are treated as a self pair).
    """
    by_sig: dict[str, list[ClipEntry]] = {}
    for c in chunk.clips:
        by_sig.setdefault(c.skeleton, []).append(c)
    jobs: list[PairJob] = []
    for clips in by_sig.values():
        for i, ci in enumerate(clips):
            for cj in clips[i if self_pairs else i + 1:]:
                a, b = (ci, cj) if (ci.sha256, ci.path) <= (cj.sha256, cj.path) else (cj, ci)
                jobs.append(PairJob(
                    chunk=chunk.name, a=a, b=b, key=web_key(a.sha256, b.sha256, wdigest),
                    cells=frames_at(a, rate) * frames_at(b, rate), self_pair=a.sha256 == b.sha256,
                ))
    return jobs


def unique_jobs(jobs: list[PairJob]) -> list[PairJob]:
    """One job per web key (identical files give identical keys)."""
    seen: dict[str, PairJob] = {}
    for j in jobs:
        seen.setdefault(j.key, j)
    return list(seen.values())


def balance_batches(jobs: list[PairJob], n_batches: int) -> list[list[PairJob]]:
    """Split jobs into ``n_batches`` batches of nearly equal cell counts (greedy LPT).

    Largest jobs first, each to the currently lightest batch: the makespan is within 4/3 of the
    optimum, which keeps Dask workers busy to the end. Empty batches are dropped.
    """
    n_batches = max(1, min(n_batches, len(jobs)))
    heap = [(0.0, i) for i in range(n_batches)]
    batches: list[list[PairJob]] = [[] for _ in range(n_batches)]
    for job in sorted(jobs, key=lambda j: (-j.cells, j.key)):
        load, i = heapq.heappop(heap)
        batches[i].append(job)
        heapq.heappush(heap, (load + job.cells + PAIR_OVERHEAD_CELLS, i))
    # pairs sharing a rows clip run back to back (the worker's feature cache hits)
    return [sorted(b, key=lambda j: (j.a.sha256, j.b.sha256)) for b in batches if b]


def batch_count(jobs: list[PairJob], n_workers: int) -> int:
    """About four batches per worker, more when a chunk is large (bounded batch size)."""
    cells = sum(j.cells for j in jobs)
    return min(len(jobs), max(4 * max(1, n_workers), math.ceil(cells / BATCH_CELLS)))


def balance_clips(clips: list[ClipEntry], n_batches: int) -> list[list[ClipEntry]]:
    """Feature batches balanced by frame count (LPT), one clip per hash."""
    uniq = list({c.sha256: c for c in clips}.values())
    n_batches = max(1, min(n_batches, len(uniq)))
    heap = [(0, i) for i in range(n_batches)]
    out: list[list[ClipEntry]] = [[] for _ in range(n_batches)]
    for c in sorted(uniq, key=lambda c: (-c.frames, c.path)):
        load, i = heapq.heappop(heap)
        out[i].append(c)
        heapq.heappush(heap, (load + c.frames, i))
    return [b for b in out if b]


@dataclass
class ChunkPlan:
    """What one chunk needs: feature clips to compute, web jobs to compute, cached pairs."""

    chunk: Chunk
    skeleton: SkeletonReport
    pairs: list[PairJob]
    features_todo: list[ClipEntry]
    todo: list[PairJob]
    cached: list[PairJob]


def plan_chunk(chunk: Chunk, cfg: Config, has: Callable[[str], bool],
               has_features: Callable[[str], bool], keep: set[tuple[str, str]] | None = None,
               features: bool = True, pairs: list[PairJob] | None = None) -> ChunkPlan:
    """Pair plan of one chunk split into cached and to-compute using the store predicates.

    ``keep``: the shortlisted pairs of the chunk (``(a.sha256, b.sha256)`` with ``a <= b``, see
    :func:`shortlist_chunk`); only those are planned. None: every pair. ``features=False`` asks
    nothing about features (``features_todo`` empty: a shortlist run planned them before).
    ``pairs``: the chunk's :func:`plan_pairs`, when the caller has them already."""
    if pairs is None:
        pairs = plan_pairs(chunk, web_digest(cfg), working_rate(cfg))
    if keep is not None:
        pairs = [j for j in pairs if (j.a.sha256, j.b.sha256) in keep]
    uniq = unique_jobs(pairs)
    todo = [j for j in uniq if not has(j.key)]
    todo_keys = {j.key for j in todo}
    cached = [j for j in pairs if j.key not in todo_keys]
    feats = ([c for c in {c.sha256: c for c in chunk.clips}.values() if not has_features(c.sha256)]
             if features else [])
    return ChunkPlan(chunk, skeleton_groups(chunk), pairs, feats, todo, cached)


def plan_features(chunk: Chunk, has_features: Callable[[str], bool]) -> ChunkPlan:
    """The first plan of a shortlist run: the clips of a chunk lacking features, no pairs yet (the
    shortlist reads every clip's features)."""
    feats = [c for c in {c.sha256: c for c in chunk.clips}.values() if not has_features(c.sha256)]
    return ChunkPlan(chunk, skeleton_groups(chunk), [], feats, [], [])


@dataclass
class ShortlistReport:
    """A chunk's shortlist: its kept pairs and what they were chosen from."""

    chunk: str
    #: (a.sha256, b.sha256) with a <= b, self pairs included
    keep: set[tuple[str, str]]
    #: pairs the exact index would plan (every skeleton-compatible pair, self pairs included)
    candidates: int
    windows: int
    seconds: float
    #: digest of what the shortlist is a function of (:func:`shortlist_inputs`)
    inputs: str = ""
    #: taken from the previous generation (same inputs), not recomputed
    reused: bool = False

    def record(self) -> dict[str, Any]:
        return {"chunk": self.chunk, "pairs": len(self.keep), "candidates": self.candidates,
                "windows": self.windows, "seconds": round(self.seconds, 3), "inputs": self.inputs,
                "reused": self.reused}


def shortlist_inputs(chunk: Chunk, cfg: Config, bad_sha: set[str] = frozenset()) -> str:
    """Digest of everything a chunk's shortlist depends on: its clips' contents by skeleton, the
    feature parameters and the lowest rate, the shortlist parameters, the faiss version."""
    import hashlib
    import json
    from importlib.metadata import version

    groups = {s: sorted({c.sha256 for c in chunk.clips if c.skeleton == s} - set(bad_sha))
              for s in sorted({c.skeleton for c in chunk.clips})}
    data = {"groups": groups, "features": feature_digest(cfg), "lowest": min(float(r) for r in cfg.features.rates),
            "shortlist": cfg.index.shortlist.model_dump(mode="json", exclude={"enabled"}),
            "faiss": version("faiss-cpu")}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def reused_shortlist(chunk: Chunk, prev: Generation | None, inputs: str) -> ShortlistReport | None:
    """The chunk's shortlist as the previous generation recorded it, when its inputs digest is
    ``inputs`` (the shortlist is a deterministic function of them): the pairs of its webs and of
    its broken pairs in this chunk. None otherwise."""
    rec = next((c.get("shortlist") for c in (prev.chunks if prev else []) if c["name"] == chunk.name), None)
    if not rec or rec.get("inputs") != inputs:
        return None
    sha = {c["path"]: c["sha256"] for c in prev.clips}
    keep = {(w["a_sha"], w["b_sha"]) for w in prev.webs if w.get("chunk") == chunk.name}
    for b in prev.broken:
        a_path, _, b_path = b["path"].partition(" x ")
        if a_path in sha and b_path in sha:
            keep.add((min(sha[a_path], sha[b_path]), max(sha[a_path], sha[b_path])))
    if len(keep) != rec["pairs"]:
        return None
    return ShortlistReport(chunk.name, keep, rec["candidates"], rec["windows"], 0.0, inputs, reused=True)


def shortlist_chunk(chunk: Chunk, cfg: Config, lowest: Callable[[str], tuple[Any, Any]],
                    bad_sha: set[str] = frozenset(), prev: Generation | None = None) -> ShortlistReport:
    """The pairs of ``chunk`` worth a web (:func:`motionweb.tasks.shortlist.shortlist_pairs` with
    ``index.shortlist``), per skeleton group (only compatible clips are paired), one entry per
    file content. ``lowest(sha)``: the clip's features at the lowest rate and its point weights.
    Clips in ``bad_sha`` (features failed) are left out. A pure function of the chunk's contents
    and the parameters: an unchanged corpus gets the same pairs on every run; when a clip changes,
    the whole chunk's shortlist is recomputed (its new windows may also be, or stop being, the
    neighbours of other clips' windows). Cost: :mod:`motionweb.tasks.shortlist`'s, about
    O(W log W) for W windows, plus one read of every clip's lowest-rate features; none when
    ``prev`` recorded the shortlist of the same inputs (:func:`reused_shortlist`)."""
    from motionweb.tasks.shortlist import shortlist_pairs

    inputs = shortlist_inputs(chunk, cfg, bad_sha)
    if (again := reused_shortlist(chunk, prev, inputs)) is not None:
        return again
    t = time.perf_counter()
    keep: set[tuple[str, str]] = set()
    candidates = windows = 0
    for shas in {s: sorted({c.sha256 for c in chunk.clips if c.skeleton == s} - bad_sha)
                 for s in sorted({c.skeleton for c in chunk.clips})}.values():
        sl = shortlist_pairs({sha: lowest(sha) for sha in shas}, cfg.index.shortlist)
        keep.update(sl.pairs)
        candidates += sl.candidates
        windows += sl.windows
    return ShortlistReport(chunk.name, keep, candidates, windows, time.perf_counter() - t, inputs)


def build_generation(
    cfg: Config, catalog: Catalog, plans: list[ChunkPlan], results: dict[str, dict[str, Any]],
    failed_clips: dict[str, str], parent: str | None, timings: dict[str, float], gen_id: str | None = None,
    cached_meta: dict[str, dict[str, Any]] | None = None, shortlists: list[ShortlistReport] | None = None,
) -> Generation:
    """The manifest of a run: clips, feature keys, web records, broken files, config, versions.

    ``results`` maps computed web keys to their record (counts, seconds, or ``error``);
    ``cached_meta`` the stored attributes of cached webs. Pairs that failed, or that involve a
    clip that failed to load, are left out and listed under ``broken``. ``shortlists`` (a
    shortlist run): each chunk's, recorded under ``stats["shortlist"]`` and in the chunk records;
    the webs listed are those of the shortlisted pairs, so a reader (``store.webs.StoreWebs``)
    finds no web, and the search no match, for a pair left out.
    """
    fdig = feature_digest(cfg)
    rates = sorted(float(r) for r in cfg.features.rates)
    cached_meta = cached_meta or {}
    broken = [{"path": e.path, "reason": e.reason} for e in catalog.errors]
    bad_sha = set()
    for e in catalog.entries:
        if e.sha256 in failed_clips:
            bad_sha.add(e.sha256)
            broken.append({"path": e.path, "reason": failed_clips[e.sha256]})
    webs: list[dict[str, Any]] = []
    for plan in plans:
        for job in plan.pairs:
            if job.a.sha256 in bad_sha or job.b.sha256 in bad_sha:
                continue
            res = results.get(job.key)
            if res is not None and "error" in res:
                broken.append({"path": f"{job.a.path} x {job.b.path}", "reason": res["error"]})
                continue
            meta = res if res is not None else cached_meta.get(job.key, {})
            rec = job.record()
            rec["computed"] = res is not None
            rec.update({k: meta[k] for k in ("n_chains", "n_bridges", "rate", "shape", "shard") if k in meta})
            webs.append(rec)
    clips = [asdict(e) | {"chunk": p.chunk.name} for p in plans for e in p.chunk.clips
             if e.sha256 not in bad_sha]
    for c in clips:
        c.pop("abs_path", None)
    features = {c["sha256"]: {rate_tag(r): feature_key(c["sha256"], fdig) for r in rates} for c in clips}
    computed = {w["key"] for w in webs if w["computed"]}
    stats = {
        "chunks": len(plans),
        "clips": len(clips),
        "frames": sum(c["frames"] for c in clips),
        "pairs": len(webs),
        "pairs_computed": len(computed),
        "pairs_cached": len(webs) - sum(1 for w in webs if w["computed"]),
        "features_computed": sum(len(p.features_todo) for p in plans),
        "chains": sum(int(w.get("n_chains", 0)) for w in webs),
        "bridges": sum(int(w.get("n_bridges", 0)) for w in webs),
        "broken": len(broken),
        "skeleton_minority": sum(len(p.skeleton.minority) for p in plans),
    }
    by_chunk = {r.chunk: r for r in shortlists or []}
    if shortlists is not None:
        stats["shortlist"] = {"pairs": sum(len(r.keep) for r in shortlists),
                              "candidates": sum(r.candidates for r in shortlists),
                              "windows": sum(r.windows for r in shortlists),
                              "seconds": round(sum(r.seconds for r in shortlists), 3),
                              "reused": sum(r.reused for r in shortlists)}
    return Generation(
        id=gen_id or new_id(),
        created=now_iso(),
        parent=parent,
        params={"features": fdig, "webs": web_digest(cfg),
                "features_params": feature_params(cfg), "web_params": web_params(cfg)},
        config=cfg.model_dump(mode="json"),
        clips=clips,
        features=features,
        webs=webs,
        chunks=[{"name": p.chunk.name, "clips": len(p.chunk.clips), "frames": p.chunk.frames,
                 "pairs": len(p.pairs), "computed": len(p.todo), "features_computed": len(p.features_todo)}
                | ({"shortlist": by_chunk[p.chunk.name].record()} if p.chunk.name in by_chunk else {})
                for p in plans],
        broken=broken,
        skeleton=[asdict(p.skeleton) for p in plans if len(p.skeleton.groups) > 1],
        versions=package_versions(),
        timings=dict(timings),
        stats=stats,
    )


@dataclass
class IndexSummary:
    """What ``motionweb index`` prints."""

    generation: str
    store: str
    params: dict[str, str]
    chunks: int
    clips: int
    frames: int
    pairs: int
    pairs_computed: int
    pairs_cached: int
    features_computed: int
    chains: int
    bridges: int
    wall_s: float
    store_bytes: int
    broken: list[dict[str, str]] = field(default_factory=list)
    skeleton_minority: list[str] = field(default_factory=list)
    params_changed: bool = False
    #: what the run found damaged in the pointer or current manifest and how it repaired it
    repaired: str = ""
    #: a shortlist run (``index.shortlist.enabled``): pairs kept, candidates, windows, seconds
    shortlist: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def format_summary(s: IndexSummary | dict[str, Any]) -> str:
    """Human-readable run summary (chunks, clips, frames, pairs computed/cached, chains, bridges...)."""
    d = s.to_dict() if isinstance(s, IndexSummary) else s
    lines = [
        f"generation {d['generation']} in {d['store']}",
        f"  chunks {d['chunks']}, clips {d['clips']}, frames {d['frames']}",
        (f"  pairs {d['pairs']}: computed {d['pairs_computed']}, cached {d['pairs_cached']} "
         f"(features computed for {d['features_computed']} clips)"),
        f"  chains {d['chains']}, bridges {d['bridges']}",
        *([(f"  shortlist: {sl['pairs']} of {sl['candidates']} pairs kept ({sl['windows']} pose windows, "
            f"{sl['seconds']:.1f} s)")] if (sl := d.get("shortlist")) else []),
        f"  wall time {d['wall_s']:.1f} s, store size {d['store_bytes'] / 1e6:.2f} MB",
        f"  parameters: features {d['params']['features']}, webs {d['params']['webs']}"
        + (" (new parameter hash: results are not mixed with the previous generation's)"
           if d.get("params_changed") else ""),
    ]
    if d.get("repaired"):
        lines.append(f"  repaired: {d['repaired']}")
    if d["skeleton_minority"]:
        lines.append(f"  {len(d['skeleton_minority'])} clips with a minority skeleton, indexed only "
                     f"against compatible clips: {', '.join(d['skeleton_minority'])}")
    if d["broken"]:
        lines.append(f"  {len(d['broken'])} broken files skipped:")
        lines += [f"    {b['path']}: {b['reason']}" for b in d["broken"]]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- Dask plumbing
@contextmanager
def dask_scheduler(dcfg: DaskConfig, small: bool) -> Iterator[str]:
    """Address of the scheduler to use: ``dask.address``, or a local cluster for this run.

    The scheduler's HTTP endpoint (health and metrics; no dashboard) binds a free port on loopback,
    never Dask's default 8787 on every interface: no "port in use" warning, nothing exposed.
    The local default is sized to the machine (one single-threaded worker per core, at most 2
    unless ``n_workers`` says otherwise); small runs use threads, which start in ~1 s. It closes
    client first, then the cluster; a worker whose last heartbeat meets the closing scheduler
    would still print a traceback, so its ``distributed.worker`` log drops that one message from
    then on (:func:`~motionweb.flows.runtime.workers.quiet_heartbeat`, in the workers and in this process
    until the cluster is gone).
    """
    if dcfg.address:
        with _client_for(dcfg.address):
            yield dcfg.address
        return
    from distributed import LocalCluster
    from motionweb.flows.runtime.workers import (
        quiet_heartbeat,  # the stages' kernels: loaded when work is done
    )

    n = dcfg.n_workers or max(1, min(2, os.cpu_count() or 1))
    processes = dcfg.processes if dcfg.processes is not None else not small
    kwargs: dict[str, Any] = {"host": "127.0.0.1"} if processes else {}
    try:
        with LocalCluster(n_workers=n, threads_per_worker=dcfg.threads_per_worker, processes=processes,
                          dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                          **kwargs) as cluster, _client_for(cluster.scheduler_address) as client:
            try:
                yield cluster.scheduler_address
            finally:
                quiet_heartbeat()
                try:
                    client.run(quiet_heartbeat)  # process workers: their own logs
                except Exception as exc:  # noqa: BLE001 - a worker already gone needs no filter
                    log.debug("quiet_heartbeat on the workers: %s", exc)
    finally:
        quiet_heartbeat(on=False)


#: one Dask client per scheduler address while a run uses it, shared by the chunk tasks' threads
#: (a client per task cost a connection, a config scatter and a close each: ~50 chunk tasks)
_CLIENTS: dict[str, Any] = {}


@contextmanager
def _client_for(address: str) -> Iterator[Any]:
    from distributed import Client

    client = _CLIENTS[address] = Client(address, set_as_default=False)
    try:
        yield client
    finally:
        _CLIENTS.pop(address, None)
        client.close()


def _client(address: str) -> Any:
    """The run's shared client for ``address`` (see :func:`dask_scheduler`)."""
    return _CLIENTS[address]


def _run_on_dask(address: str, fn: Callable, batches: list[list], cfg: Config, store_url: str,
                 stage: str, logger: Any) -> list[dict[str, Any]]:
    """Submit one Dask task per batch, gather records as they finish and report progress."""
    from distributed import as_completed

    out: list[dict[str, Any]] = []
    total = sum(len(b) for b in batches)
    client = _client(address)
    cfg_f = client.scatter(cfg, broadcast=True)
    futures = [client.submit(fn, b, cfg_f, store_url, pure=False, key=f"{stage}-{i}-{os.urandom(4).hex()}")
               for i, b in enumerate(batches)]
    step = max(1, total // 10)
    last = 0
    for fut in as_completed(futures, loop=client.loop):
        out.extend(fut.result())
        if PROGRESS is not None:
            PROGRESS(stage, len(out), total)
        if len(out) - last >= step or len(out) == total:
            logger.info("%s: %d/%d", stage, len(out), total)
            last = len(out)
    return out


def _workers(address: str) -> int:
    return max(1, len(_client(address).scheduler_info().get("workers", {})))


# ---------------------------------------------------------------------------- Prefect tasks
def known_clips(prev: Generation | None, cfg: Config) -> dict[str, dict[str, Any]]:
    """The clip records of generation ``prev`` by corpus path, for the scan to describe unchanged
    BVH files from (``store.catalog.scan_corpus`` ``known``); {} when there is none, or when it
    was scanned with other corpus settings or another version of this package (a description
    could then differ)."""
    if prev is None or not isinstance(prev.config, dict):
        return {}
    if (prev.config.get("corpus") != cfg.corpus.model_dump(mode="json")
            or prev.versions.get("motionweb") != package_versions().get("motionweb")):
        return {}
    return {c["path"]: c for c in prev.clips if isinstance(c, dict) and isinstance(c.get("path"), str)}


@task(name="catalog", no_cache=True)
def catalog_task(cfg: Config, known: dict[str, dict[str, Any]] | None = None) -> Catalog:
    """Scan the corpus (hash, label, describe every clip; broken files listed, not fatal;
    ``known``: see :func:`known_clips`)."""
    cat = scan_corpus(cfg.corpus.path, cfg.corpus, known=known)
    run_logger().info("catalog: %d clips, %d unreadable", len(cat.entries), len(cat.errors))
    return cat


@task(name="plan", no_cache=True)
def plan_task(chunks: list[Chunk], cfg: Config, prev: Generation | None,
              keep: dict[str, ShortlistReport] | None = None, stage: str = "all",
              verified: dict[str, str | None] | None = None, store: MotionStore | None = None) -> list[ChunkPlan]:
    """Pair plan of every chunk, split into cached and to-compute by the store.

    Every object reused is verified first (read whole, checksum against the one recorded with
    it and in the current manifest): a missing or damaged one is recomputed, never committed
    again. The webs are verified in one pass in the store's order (``MotionStore.verify_webs``).
    Cost: one read of every reused object, O(store bytes used by this generation).
    A shortlist run plans twice: ``stage="features"`` the clips lacking features (no pairs),
    then ``stage="pairs"`` the pairs of each chunk's shortlist (``keep``, by chunk name).
    ``verified``: the answers by object key, filled here (and those already in it taken: a
    plan of the same store and generation, see :data:`VERIFIED`). ``store``: the run's instance of
    the store, whose index of the web shards :func:`finish` and the commit then reuse (else one of
    its own): an instance that has taken in a web's shard does not look for a newer shard holding
    it, so :func:`finish` lists the shards again and takes in those the workers wrote since (their
    headers alone: names sort by time, so a recomputed web's new shard is taken in last and serves
    it, as in a store opened afresh).
    """
    store = store if store is not None else MotionStore(cfg.store.path)
    fdig = feature_digest(cfg)
    rates = [float(r) for r in cfg.features.rates]
    expected = prev.checksums if prev else {}
    stored = store.web_keys(web_digest(cfg))  # one listing of the web shards, not a lookup per pair
    logger = run_logger()

    if verified is None:  # the objects verified: the stored webs of the chunks' pairs in one pass
        verified = {}
        if VERIFIED and VERIFIED.get("store") == store.url and VERIFIED.get("generation") == (prev.id if prev else None):
            verified.update(VERIFIED["objects"])
    one_pass = [any(k.startswith("webs/") for k in verified)]  # the webs' pass done (or handed over)

    def sound(key: str) -> bool:
        if key not in verified:
            verified[key] = store.verify(key, expected.get(key))
        problem = verified[key]
        if problem is not None and (key in stored or key in expected):
            logger.warning("store object %s %s: recomputing it", key, problem)
        return problem is None

    wdig, rate = web_digest(cfg), working_rate(cfg)
    pairs = {c.name: plan_pairs(c, wdig, rate) for c in chunks} if stage != "features" else {}

    def web_ok(key: str) -> bool:
        if key in stored and not one_pass[0]:
            one_pass[0] = True
            verified.update(store.verify_webs(sorted({j.key for ps in pairs.values() for j in ps} & stored), expected))
        return key in stored and sound(key)

    def features_ok(sha: str) -> bool:
        return store.has_features(sha, fdig, rates) and sound(feature_key(sha, fdig))

    if stage == "features":
        plans = [plan_features(c, features_ok) for c in chunks]
        for p in plans:
            logger.info("chunk %s: %d clips, %d need features (pairs planned after the shortlist)",
                        p.chunk.name, len(p.chunk.clips), len(p.features_todo))
        return plans
    plans = [plan_chunk(c, cfg, web_ok, features_ok, None if keep is None else keep[c.name].keep,
                        features=stage != "pairs", pairs=pairs[c.name]) for c in chunks]
    for p in plans:
        logger.info("chunk %s: %d clips, %d pairs (%d to compute, %d cached), %d clips need features",
                    p.chunk.name, len(p.chunk.clips), len(p.pairs), len(p.todo), len(p.cached),
                    len(p.features_todo))
    return plans


@task(name="shortlist", no_cache=True)
def shortlist_task(chunks: list[Chunk], cfg: Config, bad_sha: set[str],
                   prev: Generation | None = None) -> dict[str, ShortlistReport]:
    """Each chunk's shortlist (:func:`shortlist_chunk`) from the stored features at the lowest
    rate, in this process (seconds, against the webs it saves; see ``bench/shortlist.py``), or
    from ``prev`` when its inputs are unchanged."""
    store = MotionStore(cfg.store.path)
    fdig = feature_digest(cfg)
    low = min(float(r) for r in cfg.features.rates)

    def lowest(sha: str) -> tuple[Any, Any]:
        by_rate, weights = store.read_features(sha, fdig, [low])
        return by_rate[low], weights

    out = {c.name: shortlist_chunk(c, cfg, lowest, bad_sha, prev) for c in chunks}
    for r in out.values():
        run_logger().info("chunk %s: shortlist of %d of %d pairs from %d pose windows %s", r.chunk,
                          len(r.keep), r.candidates, r.windows,
                          "as the previous generation's" if r.reused else f"in {r.seconds:.1f} s")
    return out


@task(name="features", no_cache=True, retries=1)
def features_task(plan: ChunkPlan, cfg: Config, address: str) -> list[dict[str, Any]]:
    """Features for the chunk's clips that lack them, on Dask."""
    if not plan.features_todo:
        return []
    batches = balance_clips(plan.features_todo, 4 * _workers(address))
    from motionweb.flows.runtime.workers import compute_features_batch

    return _run_on_dask(address, compute_features_batch, batches, cfg, cfg.store.path,
                        f"features[{plan.chunk.name}]", run_logger())


@task(name="webs", no_cache=True, retries=1)
def webs_task(plan: ChunkPlan, cfg: Config, address: str, bad_sha: set[str]) -> list[dict[str, Any]]:
    """Webs of the chunk's uncached pairs, batches balanced by cell count, on Dask."""
    jobs = [j for j in plan.todo if j.a.sha256 not in bad_sha and j.b.sha256 not in bad_sha]
    if not jobs:
        return []
    batches = [[(j.key, j.a.sha256, j.b.sha256, j.self_pair) for j in b]
               for b in balance_batches(jobs, batch_count(jobs, _workers(address)))]
    from motionweb.flows.runtime.workers import compute_web_batch

    return _run_on_dask(address, compute_web_batch, batches, cfg, cfg.store.path,
                        f"webs[{plan.chunk.name}]", run_logger())


@task(name="commit", no_cache=True)
def commit_task(gen: Generation, store_url: str, store: MotionStore | None = None) -> str:
    """Write the manifest and switch the ``current`` pointer (design §9). ``store``: the run's
    instance of the store at ``store_url`` that took in the web shards after the webs were written
    (:func:`finish`'s checksums), whose index of them the commit's check of every object then
    reuses instead of reading every shard's header again (~2 s at 146,610 webs)."""
    return commit(store if store is not None else MotionStore(store_url), gen)


# ------------------------------------------------------------------------------------ flow
def repair_note(damage: PointerError) -> str:
    """One line saying what was damaged and what the run does about it (see
    :func:`motionweb.store.generations.repair_current`)."""
    what = f"{damage.key} {damage.reason}"
    if damage.manifest_damaged:
        base = (f"current now names generation {damage.fallback} (the newest intact one)" if damage.fallback
                else "no generation manifest is intact")
        return f"{what}: {base}; this run commits a fresh generation"
    if damage.fallback:
        return f"{what}: rewritten to name generation {damage.fallback} (the newest intact one)"
    return f"{what}, and no generation manifest is intact: this run commits a fresh generation"


def __getattr__(name: str) -> Any:
    """``index_library``, the Prefect flow, from :mod:`motionweb.flows.index_flow` on first use:
    this module imports no Prefect, so an index run with nothing to do answers without it."""
    if name == "index_library":
        from motionweb.flows.index_flow import index_library

        return index_library
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Changed(Exception):
    """Raised by :func:`unchanged_summary`'s commit: the run would commit a new generation."""


def finish(cfg: Config, store: MotionStore, catalog: Catalog, plans: list[ChunkPlan], results: dict[str, dict[str, Any]],
           failed: dict[str, str], parent: str | None, prev: Generation | None, damage: PointerError | None,
           timings: dict[str, float], t0: float, commit_fn: Callable[[Generation], Any],
           shortlists: dict[str, ShortlistReport] | None = None) -> dict[str, Any]:
    """The end of an index run: the generation of the plans and results, committed with
    ``commit_fn`` unless it lists the current one's content, gc, and the run summary."""
    logger = run_logger()
    repaired = "" if damage is None else repair_note(damage)
    store.web_keys(web_digest(cfg))  # the shards written since the plan, taken in (see plan_task)
    cached_keys = {j.key for p in plans for j in p.cached}
    cached_meta = {w["key"]: w for w in (prev.webs if prev else []) if w["key"] in cached_keys}
    for key in cached_keys - set(cached_meta):
        cached_meta[key] = store.web_attrs(key)
    for key, meta in cached_meta.items():  # where each web is (a manifest written before recorded none)
        if "shard" not in meta and (shard := store.web_shard(key)) is not None:
            cached_meta[key] = {**meta, "shard": shard}
    gen = build_generation(cfg, catalog, plans, results, failed, parent, timings, cached_meta=cached_meta,
                           shortlists=None if shortlists is None else list(shortlists.values()))
    keys = [w["key"] for w in gen.webs] + sorted({k for rs in gen.features.values() for k in rs.values()})
    gen.checksums = {k: c for k in keys if (c := store.recorded_checksum(k)) is not None}
    gen.timings["before_commit_s"] = time.perf_counter() - t0
    # a manifest written before records named each web's shard is written again once, with them
    unplaced = prev is not None and any("shard" not in w for w in prev.webs) and all("shard" in w for w in gen.webs)
    if prev is not None and same_content(prev, gen) and not unplaced and not (damage and damage.manifest_damaged):
        logger.info("nothing changed: generation %s stays current", prev.id)
        gen.id = prev.id  # no manifest repeating the current one
    else:
        commit_fn(gen)
    removed = gc(store, cfg.index.keep_generations)
    if removed:
        logger.info("gc: removed %d objects and files no kept generation needs", len(removed))
    wall = time.perf_counter() - t0
    summary = IndexSummary(
        generation=gen.id, store=cfg.store.path,
        params={"features": gen.params["features"], "webs": gen.params["webs"]},
        chunks=gen.stats["chunks"], clips=gen.stats["clips"], frames=gen.stats["frames"],
        pairs=gen.stats["pairs"], pairs_computed=gen.stats["pairs_computed"],
        pairs_cached=gen.stats["pairs_cached"], features_computed=gen.stats["features_computed"],
        chains=gen.stats["chains"], bridges=gen.stats["bridges"], wall_s=wall,
        store_bytes=store.size_bytes(), broken=gen.broken,
        skeleton_minority=[m for p in plans for m in p.skeleton.minority],
        params_changed=prev is not None and prev.params.get("webs") != gen.params["webs"],
        repaired=repaired, shortlist=gen.stats.get("shortlist", {}),
    )
    logger.info("generation %s: %d clips, %d pairs (%d computed, %d cached), %d broken files, %.1f s",
                gen.id, summary.clips, summary.pairs, summary.pairs_computed, summary.pairs_cached,
                len(summary.broken), wall)
    return summary.to_dict()


def unchanged_summary(cfg: Config, handover: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """The summary of an index run that has nothing to do, found without Prefect or Dask (the CLI
    asks first when no Prefect server is there: the flow run's server start costs 10 s and more):
    the pointer and the manifest it names are intact (:func:`check_current`), every clip's
    features and every pair's web are stored and sound (the plan task's checks, checksums
    included) and the generation they make lists the current one's content. None otherwise:
    anything to compute, to commit or to repair is the flow's to do (``index_library``). Like the
    flow, it removes what no kept generation needs (:func:`gc`). ``handover``: filled, when None
    is returned after the objects were verified, with what :data:`VERIFIED` holds for the flow."""
    t0 = time.perf_counter()
    store = MotionStore(cfg.store.path)
    try:
        prev = current_generation(store, strict=True)
        parent = prev.id if prev is not None else None
    except StoreError:  # PointerError included: the flow repairs it
        return None
    if prev is None:
        return None
    timings: dict[str, float] = {}
    plain = logging.getLogger("motionweb.flows")
    level, plain.level = plain.level, logging.ERROR  # what the plan finds damaged, the flow's run reports
    try:
        catalog = catalog_task.fn(cfg, known_clips(prev, cfg))
        if not catalog.entries:
            return None
        timings["catalog_s"] = time.perf_counter() - t0
        t = time.perf_counter()
        chunks = plan_chunks(catalog.entries, cfg.index.chunk_by)
        shortlists = None
        if cfg.index.shortlist.enabled:
            if any(p.features_todo for p in plan_task.fn(chunks, cfg, prev, stage="features")):
                return None
            shortlists = shortlist_task.fn(chunks, cfg, set(), prev)
            timings["shortlist_s"] = time.perf_counter() - t
        verified: dict[str, str | None] = {}
        plans = plan_task.fn(chunks, cfg, prev, shortlists, stage="pairs" if shortlists else "all", verified=verified,
                             store=store)
        if handover is not None:
            handover.update({"store": store.url, "generation": prev.id, "objects": verified})
        timings["plan_s"] = time.perf_counter() - t
    finally:
        plain.setLevel(level)
    if any(p.todo or p.features_todo for p in plans):
        return None
    timings["compute_s"] = 0.0

    def changed(gen: Generation) -> None:
        raise _Changed

    try:
        return finish(cfg, store, catalog, plans, {}, {}, parent, prev, None, timings, t0, changed, shortlists)
    except _Changed:
        return None
