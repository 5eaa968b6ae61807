"""The on-demand query flow: search the committed index, optionally register and export (design §5-6).

``query(config, request)`` reads only the store's committed generation, so a query never sees a
half-written index (an index run may be writing its next generation meanwhile). The corpus,
feature and web parameters come from that generation's recorded config; the request's config
gives the search parameters and the output folder. Outputs (in ``request.out`` or
``config.output``): ``matches.json``, ``graph.json``, ``graph.png``; with registration
``warps.csv``, ``warps.png`` and ``registered/*.bvh``; with ``export`` every match as BVH.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.flows.app.params import graph_files
from motionweb.flows.commands.requests import QueryRequest
from motionweb.flows.config import Config, load_config
from motionweb.flows.runtime.lazy_prefect import call, flow, run_logger, task
from motionweb.store.filecache import FileCache
from motionweb.store.formats import read_motion, write_motion
from motionweb.store.generations import Generation, current_generation, package_versions
from motionweb.store.kinematics import sample_motion
from motionweb.store.motion import Motion
from motionweb.store.webs import StoreWebs, WebSource
from motionweb.store.zarr_store import MotionStore, StoreError
from motionweb.tasks.matchgraph import MatchGraph, Segment
from motionweb.tasks.query_clip import WithQueryClip, clip_operands, query_clip_webs
from motionweb.tasks.ranking import NO_MATCH, search_query
from motionweb.tasks.register import Registration, register
from motionweb.tasks.search import MatchSearch


@dataclass
class QueryResult:
    """What the flow returns (and the CLI prints)."""

    out: str
    generation: str
    query: dict[str, Any]
    epsilon: float | None
    matches: list[dict[str, Any]]
    files: list[str]
    timings: dict[str, float]
    #: why there are no matches when the query matches nothing at any threshold (else empty)
    message: str = ""


def committed_generation(store_url: str) -> tuple[MotionStore, Generation]:
    """The store's committed generation (ValueError when it was never indexed)."""
    store = MotionStore(store_url, read_only=True)
    gen = current_generation(store, lean=True)  # webs as columns: a search reads few
    if gen is None:
        raise ValueError(f"store {store_url} was never indexed: run `motionweb index CONFIG` first")
    return store, gen


def indexed_config(gen: Generation) -> Config:
    """The corpus, feature and web parameters the generation was indexed with (other sections
    of its recorded config are ignored, so a store outlives changes to them)."""
    try:
        return Config.model_validate({k: gen.config.get(k, {}) for k in ("corpus", "features", "matchweb")})
    except ValueError as exc:
        raise ValueError(f"generation {gen.id} records parameters this version cannot read ({exc}); "
                         "re-index with `motionweb index CONFIG`") from None


def resolve_clip(gen: Generation, name: str) -> dict[str, Any]:
    """The clip record of a corpus path or unique stem (ValueError listing candidates)."""
    by_path = {c["path"]: c for c in gen.clips}
    if name in by_path:
        return by_path[name]
    hits = [c for c in gen.clips if Path(c["path"]).stem == name or Path(c["path"]).name == name]
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise ValueError(f"clip name {name!r} is ambiguous: {', '.join(c['path'] for c in hits)}")
    near = sorted(c["path"] for c in gen.clips if name.lower() in c["path"].lower())[:8]
    hint = f"; similar: {', '.join(near)}" if near else f"; the index holds {len(gen.clips)} clips"
    raise ValueError(f"unknown clip {name!r} in generation {gen.id}{hint}")


def query_segment(rec: dict[str, Any], start: float, end: float, rate: float) -> Segment:
    """Seconds to frames at the web rate, checked against the clip's duration (the error names the
    field that is out of range: ``start`` or ``end``). An end inside the clip that rounds past its
    last frame at the web rate (a clip whose length is not a whole number of web frames) ends on
    that last frame."""
    a, b = round(start * rate), round(end * rate)
    last = int(np.floor(rec["duration"] * rate + 1e-9))
    if b > last and end <= rec["duration"] + 1e-9:
        b = last
    if start < 0 or b > last:
        raise ValueError(f"{'start' if start < 0 else 'end'}: query {start:g} s .. {end:g} s is outside clip "
                         f"{rec['path']!r} (0 .. {rec['duration']:.3f} s)")
    return Segment(rec["path"], a, b)


def load_indexed_clip(gen_cfg: Config, rec: dict[str, Any]) -> Motion:
    """Read a clip of the generation, refusing a file that changed since it was indexed."""
    path = Path(gen_cfg.corpus.path) / rec["path"]
    motion = read_motion(path, unit=gen_cfg.corpus.length_unit, scale_to_m=gen_cfg.corpus.scale_to_m)
    if motion.content_hash != rec["sha256"]:
        raise ValueError(f"{path} changed since generation was indexed; run `motionweb index` again")
    return motion


def segment_motion(motion: Motion, frames: np.ndarray, rate: float) -> Motion:
    """The motion at (fractional) frames counted at ``rate`` Hz, played back at ``rate``."""
    return replace(sample_motion(motion, np.asarray(frames, np.float64) * motion.fps / rate), fps=float(rate))


@dataclass
class PreparedQuery:
    """A request resolved against the committed generation: its clip record, the query segment
    at the web rate and the webs it searches; ``motion`` is the query clip when it is a file from
    outside the index (``--query-file``), whose webs were built on demand."""

    store: MotionStore
    gen: Generation
    gen_cfg: Config
    record: dict[str, Any]
    segment: Segment
    webs: WebSource
    motion: Motion | None = None


#: the web-source name of a query clip from outside the index (never an indexed corpus path)
FILE_PREFIX = "file:"
#: a query file's record holds its features (by rate, point weights) under this key (never written out)
FILE_FEATURES = "_features"


def prepare_query(cfg: Config, request: QueryRequest, query_motion: Motion | None = None) -> PreparedQuery:
    """Resolve ``request`` on the store's committed generation (ValueError for a store never
    indexed, an unknown clip, a range outside it). With ``query_motion`` (``search --query-file``)
    the query is that clip, from outside the index: :func:`prepare_file_query`."""
    store, gen = committed_generation(cfg.store.path)
    gen_cfg = indexed_config(gen)
    rate = max(float(r) for r in gen_cfg.features.rates)
    all_cats = cfg.search.all_categories if request.all_categories is None else request.all_categories
    if query_motion is not None:
        rec = indexed_twin(gen, query_motion.content_hash)
        if rec is None:
            return prepare_file_query(store, gen, gen_cfg, rate, request, query_motion)
    else:
        rec = resolve_clip(gen, request.clip)
    seg = query_segment(rec, request.start, request.end, rate)
    return PreparedQuery(store, gen, gen_cfg, rec, seg, StoreWebs.for_query(store, seg.clip, all_cats, generation=gen))


def indexed_twin(gen: Generation, sha256: str) -> dict[str, Any] | None:
    """The record of the indexed clip whose file has the SHA-256 ``sha256`` (None: none): a query
    file with the same bytes is that clip (content-addressed), searched as the index's."""
    return next((c for c in gen.clips if c["sha256"] == sha256), None)


def file_record(motion: Motion, key: str) -> dict[str, Any]:
    """The clip record of a query clip from outside the index, under the web-source name ``key``."""
    return {"path": key, "category": "", "sha256": motion.content_hash, "duration": motion.duration,
            "frames": motion.n_frames, "fps": motion.fps, "skeleton": motion.skeleton.signature()}


def prepare_file_query(store: MotionStore, gen: Generation, gen_cfg: Config, rate: float, request: QueryRequest,
                       motion: Motion) -> PreparedQuery:
    """A query on a clip from outside the index (issue 24): its features and its webs against
    every indexed clip with its skeleton, built on demand as the index would
    (``tasks/query_clip.py``), added to the webs of every category (the file has none). Cost: one
    web per compatible indexed clip."""
    rec = file_record(motion, FILE_PREFIX + request.clip)
    others = {c["path"]: c["sha256"] for c in gen.clips if c.get("skeleton") == rec["skeleton"]}
    if not others:
        raise ValueError(f"{request.clip}: no indexed clip has its skeleton ({motion.skeleton.n_joints} joints: "
                         f"{', '.join(motion.skeleton.names[:6])}, ...); its frames cannot be compared")
    key = rec["path"]
    seg = query_segment(rec, request.start, request.end, rate)
    fdig = gen.params["features"]
    by_rate, weights, mine = clip_operands(motion, gen_cfg.features, gen_cfg.corpus.up_axis)
    rec[FILE_FEATURES] = (by_rate, weights)  # for the registration (never written out)
    webs = query_clip_webs(motion, mine, others, lambda name: store.read_features(others[name], fdig),
                           gen_cfg.matchweb)
    return PreparedQuery(store, gen, gen_cfg, rec, seg, WithQueryClip(StoreWebs(store, gen, None), key, webs), motion)


def plan_query(cfg: Config, request: QueryRequest, query_motion: Motion | None = None) -> PreparedQuery:
    """Every check of a request that needs no search (also: the range is long enough), so the
    CLI can refuse a bad request before the search; the prepared query, for the run to reuse."""
    q = prepare_query(cfg, request, query_motion)
    MatchSearch(q.webs, cfg.search, q.gen_cfg.matchweb).check(q.segment)
    return q


# ------------------------------------------------------------------------------------ outputs
def match_rows(graph: MatchGraph, clips: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per node, sorted by graph distance (the query first)."""
    rows = []
    for k, n in enumerate(graph.nodes):
        s, rec = n.segment, clips[n.segment.clip]
        rows.append({
            "rank": k, "clip": s.clip, "category": rec.get("category", ""),
            "start_frame": s.start, "end_frame": s.end, "rate": graph.rate,
            "start_s": round(s.start / graph.rate, 4), "end_s": round(s.end / graph.rate, 4),
            "cost": float(n.cost), "tier": n.tier, "distance": float(n.distance),
        })
    return rows


def graph_dict(graph: MatchGraph) -> dict[str, Any]:
    return {
        "rate": graph.rate,
        "nodes": [{**asdict(n.segment), "tier": n.tier, "cost": n.cost, "distance": n.distance} for n in graph.nodes],
        "edges": [{"u": e.u, "v": e.v, "cost": e.cost, "cells": e.cells.tolist()} for e in graph.edges],
    }


def plot_graph(graph: MatchGraph, rows: list[dict[str, Any]], out: Path) -> None:
    """Nodes placed by graph distance (x) and tier (y), coloured by category; edges in grey.
    Drawn with matplotlib's object API and fixed margins (no pyplot, no layout pass): a warm
    service draws it in a fraction of the time, and from any thread."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 5))
    fig.subplots_adjust(left=0.06, right=0.985, bottom=0.1, top=0.93)
    ax = fig.add_subplot()
    tiers = np.array([n.tier for n in graph.nodes], float)
    x = np.array([n.distance for n in graph.nodes])
    y = tiers + 0.25 * np.sin(np.arange(len(tiers)) * 2.3) * (tiers > 0)
    if graph.edges:
        ends = np.array([[e.u, e.v] for e in graph.edges])
        segs = np.stack([x[ends], y[ends]], axis=-1)  # (E, 2, 2)
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(segs, colors="0.8", linewidths=0.7, zorder=1))
    cats = sorted({r["category"] for r in rows})
    tab10 = colormaps["tab10"]
    for c, cat in enumerate(cats):
        k = [i for i, r in enumerate(rows) if r["category"] == cat]
        ax.scatter(x[k], y[k], color=tab10(c % 10), s=40, zorder=2, label=cat or "(none)")
    for k, n in enumerate(graph.nodes[:40]):
        ax.annotate(f"{Path(n.segment.clip).stem}[{n.segment.start}:{n.segment.end}]", (x[k], y[k]),
                    fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.scatter(x[:1], y[:1], s=140, facecolors="none", edgecolors="red", zorder=3, label="query")
    ax.set_yticks(range(int(tiers.max()) + 1))
    ax.set_xlabel("graph distance to the query (shortest-path cost)")
    ax.set_ylabel("tier")
    ax.set_title(f"match graph: {len(graph.nodes)} nodes, {len(graph.edges)} edges (KG04 §3.3)")
    ax.legend(loc="lower right", fontsize=7)
    fig.savefig(out, dpi=120)


def write_warps(reg: Registration, rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """``warps.csv`` (query frame u, then every node's frame s_i(u)) and ``warps.png`` (drawn
    like :func:`plot_graph`: object API, fixed margins)."""
    from matplotlib.figure import Figure

    names = [f"{rows[c]['rank']}:{Path(s.clip).stem}" for c, s in zip(reg.nodes, reg.segments, strict=True)]
    csv_path = out / "warps.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["u", *names])
        for u, row in zip(reg.u, reg.frames, strict=True):
            w.writerow([f"{u:g}", *(f"{v:.4f}" for v in row)])
    fig = Figure(figsize=(7, 5))
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.1, top=0.93)
    ax = fig.add_subplot()
    for c, name in enumerate(names):
        seg = reg.segments[c]
        ax.plot(reg.u - reg.u[0], (reg.frames[:, c] - seg.start) / reg.rate, lw=1, label=name if c < 12 else None)
    ax.set_xlabel("query frame (from the query's start)")
    ax.set_ylabel("example time from its segment start (s)")
    ax.set_title("registration: time-warp curves s(u) (KG04 §4.1)")
    ax.legend(fontsize=6)
    png = out / "warps.png"
    fig.savefig(png, dpi=120)
    return [csv_path, png]


# ----------------------------------------------------------------------------------- the flow
@task(name="search", no_cache=True)
def search_task(q: PreparedQuery, cfg: Config, request: QueryRequest) -> tuple[MatchGraph, float | None]:
    """Choose ε and run the tiered search on the committed generation; (graph, ε). With the
    default rule and no nearest match ε is None and the graph holds the query alone
    (``tasks.ranking.NO_MATCH`` says why)."""
    scfg = cfg.search if request.tiers is None else cfg.search.model_copy(update={"max_tiers": request.tiers})
    files = graph_files(cfg.app)  # the service's file cache of packed graphs: a later search reads them back
    ms = MatchSearch(q.webs, scfg, q.gen_cfg.matchweb, files=FileCache(*files) if files else None)
    return search_query(ms, q.segment, request.threshold, request.quantile)


def register_graph(store: MotionStore, gen: Generation, gen_cfg: Config, graph: MatchGraph,
                   clips: dict[str, dict[str, Any]]) -> Registration:
    """Load the nodes' features at the web rate and register every node to the query."""
    fdig = gen.params["features"]
    feats, weights = {}, {}
    for clip in sorted({n.segment.clip for n in graph.nodes}):  # a fixed order, whatever the set's
        if FILE_FEATURES in clips[clip]:  # a query file's, computed for this query
            by_rate, weights[clip] = clips[clip][FILE_FEATURES]
            feats[clip] = by_rate[graph.rate]
            continue
        try:
            by_rate, weights[clip] = store.read_features(clips[clip]["sha256"], fdig, [graph.rate])
        except StoreError as exc:
            raise StoreError(store.url, exc.key, f"(features of {clip}) {exc.reason}; "
                             "run motionweb index to recompute them") from None
        feats[clip] = by_rate[graph.rate]
    # the query clip's point weights: every registered clip is compared with the query's skeleton
    return register(graph, feats, weights[graph.nodes[0].segment.clip], gen_cfg.matchweb)


@task(name="register", no_cache=True)
def register_task(store: MotionStore, gen: Generation, gen_cfg: Config, graph: MatchGraph,
                  clips: dict[str, dict[str, Any]]) -> Registration:
    """:func:`register_graph` as a task of the query flow."""
    return register_graph(store, gen, gen_cfg, graph, clips)


@flow(name="query")
def query(config: str | Config, request: QueryRequest, prepared: PreparedQuery | None = None) -> dict[str, Any]:
    """Search the committed index for ``request`` (KG04 §3.3), optionally register (§4.1) and
    export; writes the outputs listed in the module docstring and returns a :class:`QueryResult`
    as a dict. Cost: one tier reads the webs of the query's chunk once and walks them in
    O(cells of the paths and bridges touching rows a..b); tiers repeat that per new node.
    ``prepared``: the request already resolved by :func:`plan_query` (not resolved twice)."""
    cfg = config if isinstance(config, Config) else load_config(config)
    logger = run_logger()
    t0 = time.perf_counter()
    q = prepared if prepared is not None else prepare_query(cfg, request)
    graph, eps = call(search_task, q, cfg, request)
    logger.info("query %s [%d, %d]: ε = %s, %d matches", q.segment.clip, q.segment.start, q.segment.end,
                "none" if eps is None else f"{eps:.4g}", len(graph.nodes) - 1)
    return write_outputs(cfg, request, q, graph, eps, Path(request.out or cfg.output),
                         Path(request.export) if request.export else None, t0,
                         lambda *a: call(register_task, *a))


def write_outputs(cfg: Config, request: QueryRequest, q: PreparedQuery, graph: MatchGraph, eps: float | None, out: Path,
                  export: Path | None, t0: float, register_fn: Callable[..., Registration] = register_graph
                  ) -> dict[str, Any]:
    """Write a searched query's outputs (the module docstring's list) into ``out`` (and the
    exported matches into ``export``), registering with ``register_fn`` when the request asks;
    the :class:`QueryResult` as a dict. ``request`` is only recorded: its ``out`` and ``export``
    are not read here (the running service writes into its own folders, see flows/app)."""
    store, gen, gen_cfg = q.store, q.gen, q.gen_cfg
    timings = {"search_s": time.perf_counter() - t0}
    clips = {c["path"]: c for c in gen.clips}
    if q.motion is not None:  # a query file: its record, with its features
        clips[q.record["path"]] = q.record
    rows = match_rows(graph, clips)
    out.mkdir(parents=True, exist_ok=True)
    message = NO_MATCH if eps is None else ""
    meta = {"generation": gen.id, "store": cfg.store.path, "epsilon": eps, "message": message, "request": request.wire(),
            "config_digest": cfg.digest(), "versions": package_versions()}
    files = [out / "matches.json", out / "graph.json", out / "graph.png"]
    files[0].write_text(json.dumps({**meta, "matches": rows}, indent=1))
    files[1].write_text(json.dumps({**meta, **graph_dict(graph)}))
    plot_graph(graph, rows, files[2])

    motions: dict[str, Motion] = {}

    if q.motion is not None:
        motions[q.record["path"]] = q.motion

    def motion_of(clip: str) -> Motion:
        if clip not in motions:
            motions[clip] = load_indexed_clip(gen_cfg, clips[clip])
        return motions[clip]

    if export is not None:
        export.mkdir(parents=True, exist_ok=True)
        for row, node in zip(rows, graph.nodes, strict=True):
            s = node.segment
            p = export / f"{row['rank']:03d}_{Path(s.clip).stem}_{s.start}-{s.end}.{request.format}"
            write_motion(segment_motion(motion_of(s.clip), np.arange(s.start, s.end + 1), graph.rate), p,
                         up=gen_cfg.corpus.up_axis)
            files.append(p)
    if request.register_ and len(graph.nodes) > 1:
        t = time.perf_counter()
        reg = register_fn(store, gen, gen_cfg, graph, clips)
        timings["register_s"] = time.perf_counter() - t
        files += write_warps(reg, rows, out)
        common = reg.resample()
        regdir = out / "registered"
        regdir.mkdir(exist_ok=True)
        for c, s in enumerate(reg.segments):
            p = regdir / f"{rows[reg.nodes[c]]['rank']:03d}_{Path(s.clip).stem}.{request.format}"
            write_motion(segment_motion(motion_of(s.clip), common[:, c], graph.rate), p, up=gen_cfg.corpus.up_axis)
            files.append(p)
    timings["total_s"] = time.perf_counter() - t0
    return asdict(QueryResult(out=str(out), generation=gen.id, query=rows[0], epsilon=eps, matches=rows[1:],
                              files=[str(f) for f in files], timings=timings, message=message))
