"""Motion spaces: search → registration → sampling as a Prefect flow, stored in the Zarr store
(KG04 §4; design §6), and the small API that makes motions from a stored space.

``parameterize(config, request)`` searches the committed index for the request's query, registers
the matches (KG04 §4.1), samples the parameter space (§4.2) and writes the space — the examples'
clips (corpus paths and SHA-256), their registration frames, the samples' parameters and sparse
weights, the parameter function, the generation and config digests — under
``spaces/<digest>`` of the store, the digest taken over everything that determines it, plus a
KG04 Fig. 14-style plot of the examples' and the samples' parameters.

API (for the CLI and the browser app)::

    space = load_space(cfg, space_id)        # a stored space (id or unique prefix)
    space.samples, space.example_params     # (M, d), (N, d) parameters
    motion, syn = space.synthesize([x, y, z])   # a BVH-ready Motion and how close it got
    motion = space.blend({"walk/walk_01.bvh": 0.6, "walk/walk_02.bvh": 0.4})
    list_spaces(cfg)                          # ids and summaries of the stored spaces

A ``custom:package.module.function`` parameter imports and runs that code: a config or request
naming one runs it with the caller's rights.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.flows.commands.requests import SpaceRequest
from motionweb.flows.config import Config, load_config
from motionweb.flows.query import (
    PreparedQuery,
    committed_generation,
    indexed_config,
    load_indexed_clip,
    plan_query,
    prepare_query,
    register_graph,
    search_task,
)
from motionweb.flows.runtime.lazy_prefect import call, flow, run_logger, task
from motionweb.store.generations import load_generation, package_versions
from motionweb.store.motion import Motion
from motionweb.store.zarr_store import MotionStore, now_iso
from motionweb.tasks.blend import BlendParams, blend, registered_examples, to_file_unit
from motionweb.tasks.flights import FlightExamples, flight_registration, query_flight
from motionweb.tasks.matchgraph import MatchGraph, Segment
from motionweb.tasks.parameterize import (
    JointPosition,
    MotionSpace,
    ParameterizeParams,
    Synthesis,
    check_param,
    parse_param,
)
from motionweb.tasks.register import Registration


def plan_space(cfg: Config, request: SpaceRequest) -> int:
    """Every check before a flow starts, each failing with one clear line (ValueError): the query
    (store, clip, range), the parameter spec, the sample count, then the parameter function
    evaluated on the query alone (an unknown joint, a time outside the query, a custom
    function's output, the feet of ``blend.feet``; this also gives its dimension d), and last the
    search itself with the examples it yields (fewer than d + 1 cannot span a d-D space). Returns
    the number of examples. Costs one search, which the flow repeats (seconds at most; the flow
    records it as its own task)."""
    fn = parse_param(request.param)
    plan_query(cfg, request.query())
    q = prepare_query(cfg, request.query())
    query = load_indexed_clip(q.gen_cfg, q.record)
    rate = float(max(q.gen_cfg.features.rates))
    if isinstance(fn, JointPosition) and not 0.0 <= fn.seconds <= request.end - request.start:
        raise ValueError(f"time {fn.seconds:g} s is outside the query (0 .. {request.end - request.start:g} s "
                         "from its start)")
    alone = Registration(rate, [0], [q.segment], [-1], np.zeros(1),
                         np.arange(q.segment.start, q.segment.end + 1, dtype=np.float64)[:, None], [])
    try:
        check_param(fn, registered_examples([query], alone, [q.record["path"]], cfg.blend))
    except ValueError as exc:
        raise ValueError(f"{q.record['path']}: {exc}") from None
    mode = registration_mode(cfg.parameterize.registration, query, q.segment, rate)
    graph, _ = search_task.fn(q, cfg, request.query())
    n = len(graph.nodes)
    if mode == "flight":
        n = len(flight_examples(q, graph).kept)
    check_count(n, fn.dim, mode)
    return n


def registration_mode(setting: str, query: Motion, segment: Segment, rate: float) -> str:
    """``web`` or ``flight`` for ``ParameterizeParams.registration`` (``auto``: flight when the query holds
    exactly one flight phase)."""
    has_flight = query_flight(query, segment, rate) is not None
    if setting == "flight" and not has_flight:
        raise ValueError(f"parameterize.registration = flight, but the query {segment.clip} {segment.start / rate:g}-"
                         f"{segment.end / rate:g} s holds no single flight phase")
    return setting if setting != "auto" else ("flight" if has_flight else "web")


def check_count(n: int, dim: int, mode: str) -> None:
    """ValueError unless ``n`` examples (the query included) can span a ``dim``-D space."""
    if n < dim + 1:
        what = "motions with a flight phase" if mode == "flight" else "motions"
        raise ValueError(f"the search found {n} {what} (the query included); a {dim}-D parameter needs at least "
                         f"{dim + 1}: raise --threshold / --quantile")


def flight_examples(q: PreparedQuery, graph: MatchGraph) -> FlightExamples:
    """The search's matches as flight-keyed examples (``tasks/flights.py``)."""
    clips = {c["path"]: c for c in q.gen.clips}
    names = sorted({n.segment.clip for n in graph.nodes})
    motions = {c: load_indexed_clip(q.gen_cfg, clips[c]) for c in names}
    return flight_registration(motions, [n.segment for n in graph.nodes], [n.distance for n in graph.nodes],
                               graph.rate)


@task(name="register-examples", no_cache=True)
def examples_task(q: PreparedQuery, graph: MatchGraph, mode: str) -> Registration:
    """The matches registered to the query: along the match graph (KG04 §4.1) or by flights."""
    if mode == "flight":
        fx = flight_examples(q, graph)
        run_logger().info("flight-keyed examples: %d of %d matches kept; dropped: %s", len(fx.kept),
                              len(graph.nodes), fx.dropped)
        return fx.registration
    clips = {c["path"]: c for c in q.gen.clips}
    return register_graph(q.store, q.gen, q.gen_cfg, graph, clips)


def space_digest(gen_id: str, reg: Registration, shas: list[str], spec: str, pcfg: ParameterizeParams,
                 bcfg: BlendParams) -> str:
    """SHA-256 over everything that determines a space (generation, examples, registration,
    parameter function, sampling and blending parameters)."""
    h = hashlib.sha256()
    h.update(json.dumps({"generation": gen_id, "clips": shas, "segments": [[s.start, s.end] for s in reg.segments],
                         "rate": reg.rate, "param": spec, "parameterize": pcfg.model_dump(mode="json"),
                         "blend": bcfg.model_dump(mode="json")}, sort_keys=True).encode())
    h.update(np.ascontiguousarray(reg.frames, np.float64).tobytes())
    return h.hexdigest()


@task(name="sample-space", no_cache=True)
def sample_task(ex, spec: str, pcfg: ParameterizeParams) -> MotionSpace:
    """KG04 §4.2 sampling of the registered examples."""
    from motionweb.tasks.parameterize import build_space

    fn = parse_param(spec)
    check_param(fn, ex)
    return build_space(fn, ex, pcfg)


@flow(name="parameterize")
def parameterize(config: str | Config, request: SpaceRequest) -> dict[str, Any]:
    """Search → register → sample → store a motion space (KG04 §4); returns a summary dict (id,
    examples, samples, timings, files). Cost: the query's search and registration, then the
    sampling (O(n·(d + 1)·C_f), see ``tasks/parameterize.py``)."""
    cfg = config if isinstance(config, Config) else load_config(config)
    logger = run_logger()
    t0 = time.perf_counter()
    q = prepare_query(cfg, request.query())
    graph, eps = call(search_task, q, cfg, request.query())
    clips = {c["path"]: c for c in q.gen.clips}
    fn = parse_param(request.param)
    query = load_indexed_clip(q.gen_cfg, q.record)
    mode = registration_mode(cfg.parameterize.registration, query, q.segment, graph.rate)
    timings = {"search_s": time.perf_counter() - t0}
    t = time.perf_counter()
    reg = call(examples_task, q, graph, mode)
    timings["register_s"] = time.perf_counter() - t
    motions = [load_indexed_clip(q.gen_cfg, clips[s.clip]) for s in reg.segments]
    names = example_names(reg.segments)
    ex = registered_examples(motions, reg, names, cfg.blend)
    pcfg = cfg.parameterize if request.samples is None else cfg.parameterize.model_copy(
        update={"samples": request.samples})
    t = time.perf_counter()
    check_param(fn, ex)
    check_count(ex.n, fn.dim, mode)  # plan_space checked it; the index cannot change under a generation
    space = call(sample_task, ex, request.param, pcfg)
    timings["sample_s"] = time.perf_counter() - t
    shas = [clips[s.clip]["sha256"] for s in reg.segments]
    digest = space_digest(q.gen.id, reg, shas, fn.spec, pcfg, cfg.blend)
    attrs = {
        "kind": "motion-space", "param": fn.spec, "dim": space.dim, "rate": reg.rate,
        "clips": [s.clip for s in reg.segments], "names": names, "sha256": shas, "segments": [[s.start, s.end] for s in reg.segments],
        "nodes": reg.nodes, "parents": reg.parents, "generation": q.gen.id, "store": cfg.store.path,
        "config_digest": cfg.digest(), "parameterize": pcfg.model_dump(mode="json"), "registration": mode,
        "blend": cfg.blend.model_dump(mode="json"), "epsilon": eps, "request": request.wire(),
        "versions": package_versions(), "created": now_iso(),
    }
    arrays = {"frames": reg.frames, "params": space.params, "indices": space.indices.astype(np.int64),
              "weights": space.weights, "example_params": space.example_params,
              "distances": np.asarray(reg.distances, np.float64)}
    store = MotionStore(cfg.store.path)
    store.write_space(digest, arrays, attrs)
    out = Path(request.out or cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    png = out / f"space-{digest[:12]}.png"
    plot_space(space.example_params, space.params, fn.spec, png)
    timings["total_s"] = time.perf_counter() - t0
    logger.info("space %s: %d examples, %d samples (%s)", digest[:12], ex.n, len(space.params), fn.spec)
    return {"id": digest, "param": fn.spec, "examples": names, "samples": len(space.params), "epsilon": eps,
            "example_params": space.example_params.tolist(), "files": [str(png)], "timings": timings}


def plot_space(example_params: np.ndarray, samples: np.ndarray, spec: str, out: Path) -> None:
    """KG04 Fig. 14: the examples' parameters (large red) and the sampled ones (small grey); 3-D
    parameters in a 3-D view, 2-D as a plane, 1-D along a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = samples.shape[1]
    fig = plt.figure(figsize=(6, 5))
    if d >= 3:
        ax = fig.add_subplot(projection="3d")
        ax.scatter(samples[:, 0], samples[:, 2], samples[:, 1], s=3, c="0.6", label="samples")
        ax.scatter(example_params[:, 0], example_params[:, 2], example_params[:, 1], s=60, c="red", marker="s",
                   label="examples")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z (m)")
        ax.set_zlabel("y (m)")
    else:
        ax = fig.add_subplot()
        ys = samples[:, 1] if d == 2 else np.zeros(len(samples))
        ye = example_params[:, 1] if d == 2 else np.zeros(len(example_params))
        ax.scatter(samples[:, 0], ys, s=3, c="0.6", label="samples")
        ax.scatter(example_params[:, 0], ye, s=60, c="red", marker="s", label="examples")
        ax.set_xlabel("x (m)" if d == 2 else spec)
        if d == 2:
            ax.set_ylabel("z (m)")
            ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{spec}: {len(example_params)} examples, {len(samples)} samples (KG04 Fig. 14)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------------- stored spaces
@dataclass
class StoredSpace:
    """A motion space loaded from the store: ``space`` (examples rebuilt from the indexed clips),
    ``info`` (the stored attributes), ``id`` its digest."""

    id: str
    info: dict[str, Any]
    space: MotionSpace
    fps: float

    @property
    def samples(self) -> np.ndarray:
        """(M, d) sampled parameters (the examples' first)."""
        return self.space.params

    @property
    def example_params(self) -> np.ndarray:
        return self.space.example_params

    @property
    def clips(self) -> list[str]:
        """The examples' names: corpus paths, ``path@start`` where a clip gives several."""
        return list(self.info["names"])

    def motion(self, weights: np.ndarray, hold_feet: bool = True) -> Motion:
        """The blend of ``weights`` (N,) at the query clip's fps, in the examples' file unit."""
        ex = self.space.examples
        r = blend(ex, weights, fps=self.fps, cfg=BlendParams.model_validate(self.info["blend"]), hold_feet=hold_feet,
                  measure=False)
        m = to_file_unit(r.motion, ex.scale_to_m, ex.unit)
        return Motion(skeleton=m.skeleton, fps=m.fps, root_positions=m.root_positions, rotations=m.rotations,
                      name=f"space_{self.id[:12]}", unit=m.unit, scale_to_m=m.scale_to_m)

    def synthesize(self, target: np.ndarray) -> tuple[Motion, Synthesis]:
        """A motion for a target parameter (KG04 §4.3) and how close it came (projected when outside)."""
        syn = self.space.synthesize(target)
        return self.motion(syn.weights), syn

    def blend(self, weights: dict[str, float]) -> Motion:
        """A motion from explicit weights by clip (corpus path or stem; unnamed examples get 0)."""
        return self.motion(self.weight_vector(weights))

    def weight_vector(self, weights: dict[str, float]) -> np.ndarray:
        return weight_vector(self.clips, weights)


def example_names(segments: list[Segment]) -> list[str]:
    """Each example's corpus path, or ``path@start`` (frame at the registration rate) where one
    clip gives several examples."""
    count: dict[str, int] = {}
    for s in segments:
        count[s.clip] = count.get(s.clip, 0) + 1
    return [s.clip if count[s.clip] == 1 else f"{s.clip}@{s.start}" for s in segments]


def weight_vector(clips: list[str], weights: dict[str, float]) -> np.ndarray:
    """(N,) weights from {clip or stem: weight}; ValueError for an unknown or ambiguous clip or a
    sum other than 1."""
    w = np.zeros(len(clips))
    for name, value in weights.items():
        hits = [i for i, c in enumerate(clips) if c == name] or [i for i, c in enumerate(clips) if Path(c).stem == name]
        if len(hits) != 1:
            raise ValueError(f"clip {name!r} is {'ambiguous' if hits else 'not an example'} of this space; "
                             f"examples: {', '.join(clips)}")
        w[hits[0]] = value
    if abs(w.sum() - 1.0) > 1e-6:
        raise ValueError(f"weights must sum to 1, got {w.sum():.6g}")
    return w


def space_info(cfg: Config, space_id: str) -> tuple[str, dict[str, Any], dict[str, np.ndarray]]:
    """(digest, attributes, arrays) of a stored space without loading its clips."""
    store = MotionStore(cfg.store.path, read_only=True)
    arrays, attrs = store.read_space(space_id)
    digest = next(i for i in store.space_ids() if i.startswith(space_id))
    return digest, attrs, arrays


def load_space(cfg: Config, space_id: str) -> StoredSpace:
    """A stored motion space (by id or unique prefix), its examples rebuilt from the clips of
    its generation (each checked against its recorded SHA-256). KeyError / ValueError naming
    what is missing."""
    digest, attrs, arrays = space_info(cfg, space_id)
    store, _ = committed_generation(cfg.store.path)
    gen = load_generation(store, attrs["generation"])
    if gen is None:
        raise ValueError(f"space {digest[:12]}: its generation {attrs['generation']} is no longer in the store")
    gen_cfg = indexed_config(gen)
    recs = {c["path"]: c for c in gen.clips}
    motions = [load_indexed_clip(gen_cfg, recs[c]) for c in attrs["clips"]]
    segs = [Segment(c, int(a), int(b)) for c, (a, b) in zip(attrs["clips"], attrs["segments"], strict=True)]
    reg = Registration(float(attrs["rate"]), list(attrs["nodes"]), segs, list(attrs["parents"]),
                       arrays["distances"], arrays["frames"], [])
    bcfg = BlendParams.model_validate(attrs["blend"])
    ex = registered_examples(motions, reg, attrs["names"], bcfg)
    fn = parse_param(attrs["param"])
    check_param(fn, ex)
    space = MotionSpace(ex, fn, arrays["example_params"], arrays["params"], arrays["indices"], arrays["weights"],
                        ParameterizeParams.model_validate(attrs["parameterize"]))
    return StoredSpace(digest, attrs, space, float(motions[0].fps))


def list_spaces(cfg: Config) -> list[dict[str, Any]]:
    """Every stored space: id, parameter, examples, samples, query."""
    store = MotionStore(cfg.store.path, read_only=True)
    out = []
    for sid in store.space_ids():
        arrays, attrs = store.read_space(sid)
        out.append({"id": sid, "param": attrs["param"], "examples": len(attrs["clips"]),
                    "samples": int(arrays["params"].shape[0]), "query": attrs["request"]})
    return out
