"""Benchmark: the candidate-pair shortlist (tasks/shortlist.py) against the exact all-pairs index
on an unsplit library (issue 25, part 4).

The corpus: the demo generator (``store.demo.corpus.write_demo_corpus``, seed 7, 60 Hz, 9
categories) with ``--variants`` clips per category (60: the issue's 540 clips, ~127k frames at
60 Hz); it stops (bench.corpus.CorpusError, exit 1) unless the scan finds exactly the clips and
categories asked for, all loading, and at least ``--min-frames`` frames. Both indexes are built by
the index flow (Prefect, a local Dask cluster of ``--workers`` worker processes), unsplit
(``index.chunk_by: none``), features at 10, 20 and ``--rate`` Hz:
  * exact: every pair of clips (KG04 §3);
  * shortlist: ``index.shortlist.enabled`` with the given k, stride, min_hits, headings, hub_ratio.
Each into its own fresh store (``--keep DIR`` reuses stores and corpus built there before, with the
run summary recorded beside each store; a reused index is checked to be of that corpus and config).

Then ``--queries`` tiered searches (KG04 §3.3; default search parameters, all clips searched: the
library has no categories) of random ``--query-s`` windows (seeded) on both indexes, each at the
ε the default rule gives on the exact index (``eps_nearest_ratio`` × the query's nearest match),
the same ε for both. Recall: the fraction of the exact index's returned matches (the query node
excluded) that the shortlist index also returns, a match counting as returned when a node of the
shortlist's result lies in the same clip with an overlapping interval; pooled over queries, and
the mean, median and least per query. Printed in a table with the pairs each index built and its
wall time. A query whose nearest match is far (nothing in the library is like it) gets an ε that
admits most of the library, and its tiers return thousands of matches, so a few queries decide the
pooled figure: the run prints the three with the most exact matches, their share of the pooled
figure, and the cross clip pairs their exact searches used (their edges' clips), beside the pairs
all the exact searches used.

Exact results are cached (``--keep`` only): each query's ε and exact matches (clip, start, end,
tier) with the edges between them go to ``DIR/exact-results/<generation>/<digest>.json``, the
digest of (the exact store's generation id, the search parameters, the query). A re-run or a run
with other ``--also`` variants reads them instead of redoing the exact search (minutes for a
"hub" query whose windows match hundreds of clips); a rebuilt exact store has a new generation id,
so nothing stale is read. A cached file whose recorded key differs from the one asked for stops
the run (CorpusError). ``--cache-gb`` bounds all the web and graph caches of the run together
(split evenly among them); the peak resident memory is printed at the end.

    nice -n 10 .venv/bin/python -m bench.shortlist [--variants 60] [--keep DIR] [--queries 100]
        [--k 24] [--stride 1] [--min-hits 1] [--headings 16] [--hub-ratio 8] [--tiers 3] [--also JSON ...]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW", "ignore")
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")  # a shared, loaded machine

import numpy as np
from motionweb.flows.config import Config
from motionweb.store.cache import LRU
from motionweb.store.catalog import scan_corpus
from motionweb.store.demo.corpus import CATEGORIES, write_demo_corpus
from motionweb.store.generations import Generation, load_generation
from motionweb.store.keys import web_digest
from motionweb.store.webs import StoreWebs
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.params.search import SearchParams
from motionweb.tasks.ranking import default_epsilon, nearest_costs
from motionweb.tasks.search import MatchSearch

from bench.corpus import CorpusError, frames60, rates_for
from bench.search import random_queries


def build_corpus(work: Path, variants: int, min_frames: int) -> tuple[Path, int, int]:
    """The demo corpus of ``variants`` clips per category at 60 Hz in ``work`` (reused when there);
    (folder, clips, frames at 60 Hz). CorpusError unless it is exactly what was asked for."""
    corpus = work / f"demo-{variants}"
    if not corpus.is_dir():
        t = time.perf_counter()
        write_demo_corpus(corpus, seed=7, variants_per_category=variants, fps=60.0)
        print(f"corpus written in {time.perf_counter() - t:.0f} s", flush=True)
    cat = scan_corpus(corpus)
    want = variants * len(CATEGORIES)
    frames = sum(frames60(e.duration) for e in cat.entries)
    if cat.errors or len(cat.entries) != want or sorted(cat.by_category()) != sorted(CATEGORIES):
        raise CorpusError(f"the demo corpus in {corpus} holds {len(cat.entries)} clips in {len(cat.by_category())} "
                          f"categories ({len(cat.errors)} unreadable); {want} in {len(CATEGORIES)} were asked for")
    if frames < min_frames:
        raise CorpusError(f"the demo corpus in {corpus} holds {frames} frames at 60 Hz, fewer than the "
                          f"{min_frames} asked for")
    return corpus, want, frames


def index_config(corpus: Path, store: Path, rate: float, workers: int, shortlist: dict | None) -> Config:
    index = {"chunk_by": "none"}
    if shortlist is not None:
        index["shortlist"] = {"enabled": True, **shortlist}
    return Config.model_validate({
        "corpus": {"path": str(corpus), "length_unit": "m"},
        "features": {"rates": rates_for(rate)},
        "store": {"path": str(store)},
        "dask": {"n_workers": workers, "processes": True},
        "index": index,
    })


def run_or_reuse(cfg: Config, clips: int, name: str) -> tuple[dict, Generation]:
    """The index of ``cfg`` (built now, or reused when its store holds a generation of ``clips``
    clips with this config's webs and index section and its recorded summary); (summary, generation)."""
    store = Path(cfg.store.path)
    record = store.parent / f"{store.name}.summary.json"
    gen = load_generation(MotionStore(str(store), read_only=True)) if store.is_dir() else None
    if gen is not None and record.is_file():
        s = json.loads(record.read_text())
        recorded = gen.config["index"].get("shortlist", {})
        wanted = cfg.index.shortlist.model_dump(mode="json")
        if (len(gen.clips) == clips and gen.params["webs"] == web_digest(cfg)
                and gen.config["index"]["chunk_by"] == "none"
                and (recorded == wanted if wanted["enabled"] else not recorded.get("enabled", False))):
            print(f"{name}: reusing {store} (built {s['wall_s']:.0f} s)", flush=True)
            return s, gen
    shutil.rmtree(store, ignore_errors=True)
    from motionweb.flows.index import index_library
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    t = time.perf_counter()
    with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        s = index_library(cfg)
    s["call_s"] = time.perf_counter() - t
    s["load_after"] = os.getloadavg()[0]
    if s["broken"] or s["clips"] != clips:
        raise CorpusError(f"{name}: indexed {s['clips']} clips of {clips}, {len(s['broken'])} broken: {s['broken'][:3]}")
    record.write_text(json.dumps(s))
    print(f"{name}: {s['pairs']} pairs in {s['wall_s']:.0f} s (load {s['load_after']:.1f})", flush=True)
    return s, load_generation(MotionStore(str(store), read_only=True))


def recalled(exact: list[Segment], short: list[Segment]) -> int:
    """Matches of ``exact`` with a match of ``short`` in the same clip overlapping it."""
    by_clip: dict[str, list[Segment]] = {}
    for s in short:
        by_clip.setdefault(s.clip, []).append(s)
    return sum(any(m.start <= s.end and s.start <= m.end for s in by_clip.get(m.clip, [])) for m in exact)


def pairs_used(query_clip: str, rec: dict) -> set[tuple[str, str]]:
    """The cross clip pairs (sorted clip paths) that the edges of one exact result join (node 0:
    the query): the webs a search needs to return those matches by the same routes."""
    clips = [query_clip] + [m[0] for m in rec["matches"]]
    out = set()
    for u, v, _ in rec.get("edges", []):
        a, b = clips[int(u)], clips[int(v)]
        if a != b:
            out.add((min(a, b), max(a, b)))
    return out


def exact_key(gen: Generation, sp: SearchParams, query: Segment) -> dict:
    """What an exact result depends on: the exact store's generation, the search parameters, the query."""
    return {"generation": gen.id, "search": sp.model_dump(mode="json"),
            "query": [query.clip, int(query.start), int(query.end)]}


def cache_path(work: Path, key: dict) -> Path:
    """``work/exact-results/<generation>/<sha256 of the key>.json``."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:24]
    return work / "exact-results" / key["generation"] / f"{digest}.json"


def read_exact(path: Path, key: dict) -> dict | None:
    """The cached exact result of ``key`` at ``path`` (None when absent); CorpusError when the
    file records another key (a digest collision or a hand-edited file: never read silently)."""
    if not path.is_file():
        return None
    rec = json.loads(path.read_text())
    if rec.get("key") != key:
        raise CorpusError(f"{path} records the exact result of {rec.get('key')}, not of {key}")
    return rec


def write_exact(path: Path, key: dict, eps: float | None, graph, seconds: float) -> dict:
    """Cache one exact result (written to a temporary file, then renamed: a stopped run leaves no
    half file): ε, the matches (the query node excluded) as (clip, start, end, tier), the edges
    (u, v, cost) between node numbers (0: the query) and the search's seconds."""
    rec = {"key": key, "eps": eps, "seconds": seconds,
           "matches": [] if graph is None else [[n.segment.clip, n.segment.start, n.segment.end, n.tier]
                                                for n in graph.nodes[1:]],
           "edges": [] if graph is None else [[e.u, e.v, e.cost] for e in graph.edges]}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(rec))
    tmp.replace(path)
    return rec


def restricted(store: MotionStore, gen: Generation, cfg: Config, params: dict, webs: LRU, cap: int,
               sp: SearchParams) -> dict:
    """A search over the exact index's webs restricted to the shortlist of ``params`` (computed
    here from the stored features), sharing the exact index's web cache."""
    from dataclasses import replace

    from motionweb.store.keys import feature_digest
    from motionweb.tasks.shortlist import ShortlistParams, shortlist_pairs

    low = min(float(r) for r in cfg.features.rates)
    fdig = feature_digest(cfg)
    feats = {}
    for c in gen.clips:
        by_rate, weights = store.read_features(c["sha256"], fdig, [low])
        feats[c["sha256"]] = (by_rate[low], weights)
    t = time.perf_counter()
    sl = shortlist_pairs(feats, ShortlistParams(enabled=True, **params))
    seconds = time.perf_counter() - t
    keep = set(sl.pairs)
    sub = replace(gen, webs=[w for w in gen.webs if (w["a_sha"], w["b_sha"]) in keep])
    name = ", ".join(f"{k}={v}" for k, v in sorted(params.items()))
    print(f"{name}: {len(sub.webs)} pairs, {sl.hub_windows} hub windows of {sl.windows}, shortlist in "
          f"{seconds:.0f} s", flush=True)
    return {"name": name, "pairs": len(sub.webs), "seconds": seconds, "hit": 0,
            "search": MatchSearch(StoreWebs(store, sub, None, webs), sp, graphs=LRU(max_bytes=cap)),
            "per_query": [], "search_s": 0.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=60, help="demo clips per category (60: 540 clips, ~127k frames)")
    ap.add_argument("--min-frames", type=int, default=None, help="least frames at 60 Hz (default: 2100 per clip)")
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--query-s", type=float, default=1.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--k", type=int, default=None)
    ap.add_argument("--stride", type=int, default=None)
    ap.add_argument("--min-hits", type=int, default=None)
    ap.add_argument("--headings", type=int, default=None)
    ap.add_argument("--hub-ratio", type=float, default=None, help="index.shortlist.hub_ratio (0: no hub rule)")
    ap.add_argument("--also", nargs="*", default=[], metavar="JSON",
                    help='more shortlist parameters (e.g. \'{"k": 48, "k_windows": 128}\'), measured without an '
                         'index run: the exact index\'s webs restricted to their shortlist (the webs a shortlist '
                         'index builds are the exact ones, tests/flows/test_index_flow.py)')
    ap.add_argument("--tiers", type=int, default=None, help="search.max_tiers (default: the search's own, 10)")
    ap.add_argument("--cache-gb", type=float, default=4.0,
                    help="bound of all the web and graph caches together (split evenly among them)")
    ap.add_argument("--keep", help="work folder (corpus, stores), reused when present")
    ap.add_argument("--per-query", help="write one JSON line per query (ε, exact matches and their clips and tiers, "
                                        "matches recalled by the shortlist index and by each variant) to this file")
    args = ap.parse_args()
    if args.queries < 1:
        raise SystemExit("--queries must be at least 1")
    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-shortlist-"))
    work.mkdir(parents=True, exist_ok=True)
    min_frames = args.min_frames if args.min_frames is not None else 210 * args.variants * len(CATEGORIES)
    corpus, clips, frames = build_corpus(work, args.variants, min_frames)
    print(f"corpus: {clips} clips, {frames} frames at 60 Hz, {len(CATEGORIES)} categories, unsplit; "
          f"webs at {args.rate:g} Hz; {os.cpu_count()} cores, {args.workers} Dask workers", flush=True)
    sl = {k: v for k, v in (("k", args.k), ("stride", args.stride), ("min_hits", args.min_hits),
                            ("headings", args.headings), ("hub_ratio", args.hub_ratio)) if v is not None}
    exact_cfg = index_config(corpus, work / f"store-exact-{args.rate:g}", args.rate, args.workers, None)
    tag = "-".join(f"{k}{v}" for k, v in sorted(sl.items())) or "default"
    short_cfg = index_config(corpus, work / f"store-shortlist-{args.rate:g}-{tag}", args.rate, args.workers, sl)
    se, ge = run_or_reuse(exact_cfg, clips, "exact")
    ss, gs = run_or_reuse(short_cfg, clips, "shortlist")

    queries = random_queries(ge, args.queries, args.rate, np.random.default_rng(args.seed), args.query_s)
    n_caches = 4 + len(args.also)  # exact webs (shared by the variants) and graphs, shortlist webs and
    cap = int(args.cache_gb * 1e9 / n_caches)  # graphs, one graph cache per variant
    exact_store = MotionStore(exact_cfg.store.path, read_only=True)
    exact_webs = LRU(max_bytes=cap)
    sp = SearchParams() if args.tiers is None else SearchParams(max_tiers=args.tiers)
    me = MatchSearch(StoreWebs(exact_store, ge, None, exact_webs), sp, graphs=LRU(max_bytes=cap))
    msh = MatchSearch(StoreWebs(MotionStore(short_cfg.store.path, read_only=True), gs, None, LRU(max_bytes=cap)),
                      sp, graphs=LRU(max_bytes=cap))
    variants = [restricted(exact_store, ge, exact_cfg, json.loads(a), exact_webs, cap, sp) for a in args.also]
    n_exact = n_hit = n_short = same_eps = cached = 0
    per_query, t_exact, t_short, per_query_lines = [], 0.0, 0.0, []
    heavy = []  # (exact matches, ε, recalled, clip pairs its exact search used, query) per query
    used: set[tuple[str, str]] = set()  # the cross clip pairs the exact searches' edges used
    t0 = time.perf_counter()
    for i, q in enumerate(queries):
        key = exact_key(ge, sp, q)
        path = cache_path(work, key)
        rec = read_exact(path, key) if args.keep else None
        if rec is None:
            t = time.perf_counter()
            eps = default_epsilon(nearest_costs(me, q), me.cfg.eps_nearest_ratio)
            graph = None if eps is None else me.search(q, eps)
            rec = {"eps": eps, "seconds": time.perf_counter() - t, "matches": [] if graph is None else
                   [[n.segment.clip, n.segment.start, n.segment.end, n.tier] for n in graph.nodes[1:]]}
            if args.keep:
                rec = write_exact(path, key, eps, graph, rec["seconds"])
        else:
            cached += 1
        t_exact += rec["seconds"]
        eps = rec["eps"]
        eps_s = default_epsilon(nearest_costs(msh, q), msh.cfg.eps_nearest_ratio)
        same_eps += eps == eps_s
        if eps is None:
            continue
        ex = [Segment(c, a, b) for c, a, b, _ in rec["matches"]]
        mine = pairs_used(q.clip, rec)
        used |= mine
        t = time.perf_counter()
        sh = [n.segment for n in msh.search(q, eps).nodes[1:]]
        t_short += time.perf_counter() - t
        hit = recalled(ex, sh)
        line = {"query": [q.clip, q.start, q.end], "eps": eps, "exact": len(ex),
                "clips": len({m.clip for m in ex}), "tiers": [int(m[3]) for m in rec["matches"]],
                "shortlist": hit, "variants": {}}
        for v in variants:
            t = time.perf_counter()
            got = recalled(ex, [n.segment for n in v["search"].search(q, eps).nodes[1:]])
            line["variants"][v["name"]] = got
            v["search_s"] += time.perf_counter() - t
            v["hit"] += got
            if ex:
                v["per_query"].append(got / len(ex))
        if args.per_query:
            per_query_lines.append(line)
        n_exact, n_hit, n_short = n_exact + len(ex), n_hit + hit, n_short + len(sh)
        if ex:
            per_query.append(hit / len(ex))
            heavy.append((len(ex), eps, hit, len(mine), q))
        if (i + 1) % 10 == 0:
            print(f"  {i + 1}/{len(queries)} queries ({cached} exact results cached), recall so far "
                  f"{n_hit / max(1, n_exact):.4f} pooled, "
                  f"{np.median(per_query) if per_query else float('nan'):.4f} median per query, "
                  f"{min(per_query, default=float('nan')):.4f} least"
                  + "".join(f"; {v['name']}: {v['hit'] / max(1, n_exact):.4f}" for v in variants)
                  + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.per_query:
        Path(args.per_query).write_text("".join(json.dumps(x) + "\n" for x in per_query_lines))
    recall = n_hit / n_exact if n_exact else float("nan")
    pq = np.array(per_query) if per_query else np.array([np.nan])
    sh_stats = ss.get("shortlist", {})
    print()
    print(f"shortlist parameters: {json.dumps(gs.config['index']['shortlist'])}; search tiers {sp.max_tiers}")
    print(f"{'index':>10} {'pairs built':>11} {'of all':>7} {'wall s':>8} {'shortlist s':>11} {'windows':>8} "
          f"{'matches':>8} {'search s':>8}")
    print(f"{'exact':>10} {se['pairs']:11d} {1.0:7.3f} {se['wall_s']:8.1f} {'-':>11} {'-':>8} {n_exact:8d} {t_exact:8.1f}")
    print(f"{'shortlist':>10} {ss['pairs']:11d} {ss['pairs'] / se['pairs']:7.3f} {ss['wall_s']:8.1f} "
          f"{sh_stats.get('seconds', float('nan')):11.1f} {sh_stats.get('windows', 0):8d} {n_short:8d} {t_short:8.1f}")
    for v in variants:
        vq = np.array(v["per_query"]) if v["per_query"] else np.array([np.nan])
        print(f"  {v['name']}: {v['pairs']} pairs ({v['pairs'] / se['pairs']:.3f} of all), shortlist "
              f"{v['seconds']:.1f} s, recall {v['hit'] / max(1, n_exact):.4f} pooled, per query mean "
              f"{vq.mean():.4f}, median {np.median(vq):.3f}, least {vq.min():.3f}, {np.mean(vq >= 0.95):.0%} ≥ 0.95; search "
              f"{v['search_s']:.1f} s (exact webs restricted, no index run)")
    print(f"saved: {se['pairs'] - ss['pairs']} pairs ({1 - ss['pairs'] / se['pairs']:.1%}), "
          f"{se['wall_s'] - ss['wall_s']:.0f} s of index wall time ({1 - ss['wall_s'] / se['wall_s']:.1%})")
    print(f"recall over {len(queries)} queries ({len(per_query)} with matches, {n_exact} exact matches): "
          f"{recall:.4f} pooled; per query mean {pq.mean():.4f}, median {np.median(pq):.3f}, least {pq.min():.3f}, "
          f"{np.mean(pq >= 0.95):.0%} of queries ≥ 0.95; the default ε equal on both indexes for "
          f"{same_eps}/{len(queries)} queries")
    cross = len(gs.clips) * (len(gs.clips) - 1) // 2
    print(f"the exact searches used {len(used)} cross pairs ({len(used) / max(1, cross):.1%} of {cross}); "
          f"the queries with the most exact matches (their share of the pooled figure):")
    for n, e, h, m, q in sorted(heavy, key=lambda x: -x[0])[:3]:
        print(f"  {q.clip} {q.start}-{q.end}: ε {e:.3g}, {n} matches ({n / max(1, n_exact):.0%} of all), "
              f"recall {h / n:.3f}, its search used {m} cross pairs ({m / max(1, cross):.1%})")
    print(f"exact results: {cached}/{len(queries)} read from the cache, search seconds above include the "
          f"cached runs' recorded seconds; peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.1f} GB; "
          f"web/graph caches {cap / 1e9:.2f} GB each × {n_caches}")
    print(f"target recall ≥ 0.95: pooled {'met' if recall >= 0.95 else 'NOT met'}, per query mean "
          f"{'met' if pq.mean() >= 0.95 else 'NOT met'}; load average {os.getloadavg()[0]:.1f}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
