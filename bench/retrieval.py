"""Benchmark: retrieving the query's category on real data, motionweb vs subsequence DTW.

    .venv/bin/python -m bench.retrieval [--queries-per 16] [--seed 0] [--cache DIR]

Library: CMU subject 16 (all 58 trials: walks, runs, jumps) plus the kicks and punches of the
other shared subjects (``cmu/manifest.csv`` gives the categories), one unsplit index: webs between
every pair of clips with the same skeleton, self pairs included (KG04 §3.1-3.2; built in-process
with the package's stages, cached under ``--cache`` by file hash and parameters).

Queries: a fixed-seed draw of 1 s and 2 s segments of walk, run and jump trials of subject 16 and
of the kick trials. Relevant trials: the other trials of the query's category (the query's own
trial is left out of every ranking).

* motionweb: the default trial ranking (``tasks.ranking.rank_trials``: per query window the
  nearest matches, ε = 2 × the nearest, a match graph of ``window_tiers`` tiers through each
  tier's ``window_nodes`` nearest clips with bottleneck distances, trials by their mean log
  distance ratio weighted by each window's information, found = mean ≤ log 2), one tier and tiered; with ``--quantiles`` also KG04's
  tiered search with ε as a quantile of the query's webs (slow).
* baseline: ``dtaidistance.subsequence.dtw.subsequence_alignment`` (C, ``use_c=True``) of the
  query's joint positions in the root heading frame (metres, 30 Hz) against every trial, trials
  ranked by ``best_match().value``; no index, no threshold.

Prints mean average precision (AP) per category and overall, precision and recall of the set a
method returns (motionweb: the trials it finds; DTW returns a ranking only, so its figures are at
the top R, R = number of relevant trials), time per query (warm), and what the tiers add to the
found set per query (same category vs others, with the manifest's descriptions).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.store.motion import Motion
from motionweb.store.web import MatchWeb, transpose
from motionweb.tasks.distance import ClipOperands
from motionweb.tasks.features import FeatureParams, clip_features, joint_positions_m, point_weights
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.matchweb.build import build_web_operands
from motionweb.tasks.matchweb.params import MatchWebParams
from motionweb.tasks.ranking import rank_trials
from motionweb.tasks.search import MatchSearch, SearchParams

RATE = 30.0
CATEGORIES = ("walk", "run", "jump", "kick")


@dataclass
class Library:
    clips: list[str]
    category: dict[str, str]
    frames: dict[str, int]
    dtw_series: dict[str, np.ndarray]  # (F, 3·J) joint positions, root heading frame, 30 Hz
    webs: dict[str, list[tuple[str, MatchWeb]]]


def library_files(root: Path) -> dict[str, str]:
    """{relative path: category}: subject 16 and every kick / punch trial of the manifest."""
    out = {}
    with open(root / "manifest.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            p = row["path"]
            if p.startswith("asf_amc/") and (p.startswith("asf_amc/16/") or row["category"] in ("kick", "punch")):
                out[p] = row["category"]
    return out


def heading_frame_positions(motion: Motion) -> np.ndarray:
    """(F, 3·J) joint positions in metres at 30 Hz, relative to the root and turned so the hips'
    heading (the horizontal normal of the hip line) is +z at every frame."""
    from motionweb.store.kinematics import resample

    m = resample(motion, RATE)
    pos = joint_positions_m(m)
    names = m.skeleton.names
    lh, rh = names.index("lhipjoint"), names.index("rhipjoint")
    hip = pos[:, lh] - pos[:, rh]
    yaw = np.arctan2(hip[:, 0], hip[:, 2]) - np.pi / 2  # heading = hip line turned by -90° about y
    c, s = np.cos(-yaw), np.sin(-yaw)
    rel = pos - pos[:, :1] * np.array([1.0, 0.0, 1.0])
    x, z = rel[..., 0], rel[..., 2]
    out = np.stack([c[:, None] * x + s[:, None] * z, rel[..., 1], -s[:, None] * x + c[:, None] * z], axis=-1)
    return np.ascontiguousarray(out.reshape(len(out), -1), dtype=np.float64)


def _digest(obj: object) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def load_library(root: Path, cache: Path, fcfg: FeatureParams, wcfg: MatchWebParams,
                 files: dict[str, str] | None = None) -> Library:
    """The webs of ``files`` ({path under ``root``: category}; default :func:`library_files`),
    every pair of clips with the same skeleton, self pairs included, as one unsplit index."""
    files = library_files(root) if files is None else files
    motions = {p: read_motion(root / p) for p in files}
    ops, frames, dtw = {}, {}, {}
    for p, m in motions.items():
        w = point_weights(m.skeleton, fcfg)
        ops[p] = {float(r): ClipOperands.of(clip_features(m, r, fcfg), w, np.float32) for r in fcfg.rates}
        frames[p] = ops[p][RATE].n_frames if hasattr(ops[p][RATE], "n_frames") else None
        dtw[p] = heading_frame_positions(m)
    params = _digest({"f": fcfg.model_dump(mode="json"), "w": wcfg.model_dump(mode="json")})
    cache.mkdir(parents=True, exist_ok=True)
    webs: dict[str, list[tuple[str, MatchWeb]]] = {p: [] for p in files}
    clips = sorted(files)
    t = time.perf_counter()
    built = 0
    for i, a in enumerate(clips):
        for b in clips[i:]:
            if motions[a].skeleton.signature() != motions[b].skeleton.signature():
                continue
            key = _digest([motions[a].content_hash, motions[b].content_hash, params])
            f = cache / f"{key}.npz"
            if f.exists():
                with np.load(f) as z:
                    web = MatchWeb.from_arrays(dict(z))
            else:
                web = build_web_operands(ops[a], ops[b], wcfg, a == b)
                np.savez(f, **web.to_arrays())
                built += 1
            webs[a].append((b, web))
            if a != b:
                webs[b].append((a, transpose(web)))
    print(f"library: {len(clips)} clips, {sum(len(v) for v in webs.values())} directed webs "
          f"({built} built in {time.perf_counter() - t:.1f} s, the rest from {cache})")
    frames = {p: webs[p][0][1].shape[0] for p in clips}
    return Library(clips, files, frames, dtw, webs)


def draw_queries(lib: Library, per: int, seed: int) -> list[Segment]:
    """``per`` queries per category (half 1 s, half 2 s), from trials long enough, fixed seed."""
    rng = np.random.default_rng(seed)
    out = []
    for cat in CATEGORIES:
        trials = [c for c in lib.clips if lib.category[c] == cat]
        for k in range(per):
            n = int(RATE * (1 + k % 2)) + 1
            ok = [c for c in trials if lib.frames[c] >= n]
            if not ok:
                continue
            c = ok[rng.integers(len(ok))]
            a = int(rng.integers(0, lib.frames[c] - n + 1))
            out.append(Segment(c, a, a + n - 1))
    return out


def average_precision(ranking: list[str], relevant: set[str]) -> float:
    hits, s = 0, 0.0
    for k, c in enumerate(ranking, 1):
        if c in relevant:
            hits += 1
            s += hits / k
    return s / len(relevant) if relevant else float("nan")


def full_ranking(found: list[str], lib: Library, own: str) -> list[str]:
    """Found trials first (in order), then the rest (in path order): every trial but ``own``."""
    rest = [c for c in lib.clips if c != own and c not in found]
    return [c for c in found if c != own] + rest


def dtw_rank(q: Segment, lib: Library) -> list[str]:
    from dtaidistance.subsequence.dtw import subsequence_alignment

    query = lib.dtw_series[q.clip][q.start:q.end + 1]
    score = {}
    for c in lib.clips:
        if c == q.clip:
            continue
        score[c] = subsequence_alignment(query, lib.dtw_series[c], use_c=True).best_match().value
    return sorted(score, key=score.get)


def evaluate(name: str, fn: Callable[[Segment], tuple[list[str], list[str] | None]], queries: list[Segment],
             lib: Library) -> dict:
    """Run ``fn`` (query -> (ranking of trials, returned set or None)) on every query, warm."""
    fn(queries[0])
    aps: dict[str, list[float]] = {}
    prec, rec, times, cpu = [], [], [], []
    for q in queries:
        t, c = time.perf_counter(), time.process_time()
        ranking, returned = fn(q)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        cat = lib.category[q.clip]
        relevant = {c for c in lib.clips if lib.category[c] == cat and c != q.clip}
        full = full_ranking(ranking, lib, q.clip)
        aps.setdefault(cat, []).append(average_precision(full, relevant))
        got = set(returned) - {q.clip} if returned is not None else set(full[:len(relevant)])
        prec.append(len(got & relevant) / len(got) if got else 0.0)
        rec.append(len(got & relevant) / len(relevant))
    row = {"name": name, "ap": {c: float(np.mean(v)) for c, v in aps.items()},
           "all": float(np.mean([x for v in aps.values() for x in v])), "precision": float(np.mean(prec)),
           "recall": float(np.mean(rec)), "ms": 1e3 * float(np.mean(times)), "ms_max": 1e3 * float(np.max(times)),
           "ms_p90": 1e3 * float(np.quantile(times, 0.9)), "cpu": 1e3 * float(np.mean(cpu)),
           "cpu_p90": 1e3 * float(np.quantile(cpu, 0.9)), "cpu_max": 1e3 * float(np.max(cpu))}
    return row


def print_rows(rows: list[dict], queries: list[Segment], lib: Library) -> None:
    counts = {c: sum(lib.category[q.clip] == c for q in queries) for c in CATEGORIES}
    head = " ".join(f"{c}({counts[c]})".rjust(9) for c in CATEGORIES)
    print(f"{'method':34s} {head} {'all':>6s} {'P@set':>6s} {'R@set':>6s} {'ms/q':>8s} {'max':>7s}")
    for r in rows:
        aps = " ".join(f"{r['ap'].get(c, float('nan')):9.3f}" for c in CATEGORIES)
        print(f"{r['name']:34s} {aps} {r['all']:6.3f} {r['precision']:6.3f} {r['recall']:6.3f} "
              f"{r['ms']:8.1f} {r['ms_max']:7.1f}")
    print(f"\ntime per query, ms (wall; CPU of this process, the machine being shared): "
          f"mean / p90 / max, load {os.getloadavg()[0]:.1f}")
    for r in rows:
        print(f"  {r['name']:34s} wall {r['ms']:7.1f} / {r['ms_p90']:7.1f} / {r['ms_max']:7.1f}   "
              f"CPU {r['cpu']:7.1f} / {r['cpu_p90']:7.1f} / {r['cpu_max']:7.1f}")


def kernel_cost(queries: list[Segment], ms: MatchSearch) -> None:
    """CPU per call of the nearest-match kernel over the queries' windows (one tier's work)."""
    from motionweb.tasks.matchweb.params import min_chain_extent
    from motionweb.tasks.ranking import query_windows
    from motionweb.tasks.search import nearest_by_clip

    calls = []
    for q in queries:
        g = ms.graph(q.clip)
        need = min_chain_extent(ms.web_cfg, g.rate)
        slots = np.array([-1 if o == q.clip else 0 for o in g.others], np.int64)
        wins = query_windows(q, max(need + 1, round(ms.cfg.window_s * g.rate) + 1))
        for w in wins:
            nearest_by_clip(g, w.start, w.end, slots, 1, need, ms.web_cfg.slope_k)  # warm
            c = time.process_time()
            for _ in range(5):
                nearest_by_clip(g, w.start, w.end, slots, 1, need, ms.web_cfg.slope_k)
            calls.append((time.process_time() - c) / 5)
    print(f"nearest-match kernel (nearest_by_clip) per query window: {1e3 * np.mean(calls):.3f} ms CPU mean, "
          f"{1e3 * np.quantile(calls, 0.9):.3f} p90, {1e3 * np.max(calls):.3f} max over {len(calls)} windows "
          f"({len(calls) / len(queries):.1f} per query)")


def manifest_descriptions(root: Path) -> dict[str, str]:
    """{relative path: the manifest's description} (e.g. "forward jump", "high jump")."""
    with open(root / "manifest.csv", newline="") as fh:
        return {row["path"]: row["description"] for row in csv.DictReader(fh)}


def tier_examples(queries: list[Segment], lib: Library, ms: MatchSearch, described: dict[str, str]) -> None:
    """Per query, the trials found with tiers and not at one tier, split into the query's category
    and the others; a table per category, then the queries with gains (those gaining only their own
    category first)."""
    tiers = ms.cfg.window_tiers
    print(f"\ntiers vs one tier: trials found with {tiers} tiers and not with one (found = weighted geometric "
          "mean over the query's windows of distance / the window's nearest match ≤ eps_nearest_ratio)")
    rows: dict[str, list[int]] = {c: [0, 0, 0, 0] for c in CATEGORIES}  # queries, clean, same, other
    clean, mixed = [], []
    for q in queries:
        one = set(rank_trials(ms, q, tiers=1).found)
        extra = [c for c in rank_trials(ms, q).found if c not in one and c != q.clip]
        cat = lib.category[q.clip]
        same = [c for c in extra if lib.category[c] == cat]
        other = [c for c in extra if lib.category[c] != cat]
        row = rows[cat]
        row[0] += 1
        row[1] += bool(same) and not other
        row[2] += len(same)
        row[3] += len(other)
        if not extra:
            continue
        name = f"{Path(q.clip).stem}[{q.start}..{q.end}] {cat} ({described.get(q.clip, '')})"
        gained = f"+{len(same)} {cat}: " + (", ".join(f"{Path(c).stem} ({described.get(c, '')})" for c in same) or "-")
        if other:
            kinds: dict[str, int] = {}
            for c in other:
                kinds[lib.category[c]] = kinds.get(lib.category[c], 0) + 1
            gained += f"; +{len(other)} other: " + ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
            mixed.append(f"    {name}: {gained}")
        else:
            clean.append(f"    {name}: {gained}")
    print(f"  {'category':9s} {'queries':>7s} {'same only':>9s} {'same gained':>11s} {'other gained':>12s}")
    for c, (n, ok, same, other) in rows.items():
        print(f"  {c:9s} {n:7d} {ok:9d} {same:11d} {other:12d}")
    print(f"  {'all':9s} {sum(r[0] for r in rows.values()):7d} {sum(r[1] for r in rows.values()):9d} "
          f"{sum(r[2] for r in rows.values()):11d} {sum(r[3] for r in rows.values()):12d}")
    print("  queries whose tier gains are all of their own category:")
    print("\n".join(clean) or "    none")
    print("  queries whose tier gains include other categories:")
    print("\n".join(mixed) or "    none")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries-per", type=int, default=16, help="queries per category (half 1 s, half 2 s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "motionweb-bench-retrieval")
    ap.add_argument("--quantiles", type=float, nargs="*", default=[],
                    help="also KG04's tiered search with ε = these quantiles of the query's webs (seconds per query)")
    args = ap.parse_args()
    root = mocap_root() / "cmu"
    fcfg, wcfg, scfg = FeatureParams(), MatchWebParams(), SearchParams()
    lib = load_library(root, args.cache, fcfg, wcfg)
    queries = draw_queries(lib, args.queries_per, args.seed)
    print(f"{len(queries)} queries (seed {args.seed}), load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    ms = MatchSearch(lib.webs, scfg, wcfg)
    t = time.perf_counter()
    states = sum(ms.graph(c).n_states for c in lib.clips)  # warm: every clip's webs packed once, as a service would
    print(f"packed {len(lib.clips)} walk graphs ({states:,} states) in {time.perf_counter() - t:.1f} s")
    rows = []

    def mw(tiers: int | None) -> Callable:
        def run(q: Segment) -> tuple[list[str], list[str]]:
            r = rank_trials(ms, q, tiers=tiers)
            return r.ranking, r.found
        return run

    rows.append(evaluate("motionweb default, one tier", mw(1), queries, lib))
    rows.append(evaluate(f"motionweb default, {scfg.window_tiers} tiers", mw(None), queries, lib))
    for qv in args.quantiles:
        def run_q(q: Segment, qv: float = qv) -> tuple[list[str], list[str]]:
            from motionweb.tasks.search import epsilon_from_quantile

            eps = epsilon_from_quantile([w for _, w in lib.webs[q.clip]], qv)
            g = ms.search(q, eps)
            best: dict[str, float] = {}
            for n in g.nodes[1:]:
                best.setdefault(n.segment.clip, n.distance)
            found = sorted(best, key=best.get)
            return found, found
        rows.append(evaluate(f"KG04 tiered, eps=quantile {qv:g}", run_q, queries, lib))
    rows.append(evaluate("subsequence DTW (dtaidistance, C)", lambda q: (dtw_rank(q, lib), None), queries, lib))
    print()
    print_rows(rows, queries, lib)
    kernel_cost(queries, ms)
    tier_examples(queries, lib, ms, manifest_descriptions(root))


if __name__ == "__main__":
    main()
