"""Benchmark and crash sweep: every window of every clip of the shared CMU set as a query (issue 22).

    python -m bench.sweep [--tiers 1 3 20] [--windows 0.5 1 2] [--step 0.25] [--clips N] [--cache DIR]

Library: every ASF/AMC trial of ``cmu/manifest.csv`` (the real data under ``$MOTIONWEB_MOCAP``),
one unsplit index (all categories): webs between every pair of clips with the same skeleton, self
pairs included, built in-process with the package's stages (``bench.retrieval.load_library``,
cached under ``--cache``). The cgspeed BVH files declare no length unit and are left out, as the
index leaves them out.

Queries: every clip, windows of 0.5, 1 and 2 s starting every 0.25 s and at the last possible
start (the window ending on the clip's last frame), at the web rate; the default ε rule
(``tasks.ranking.default_epsilon``; a query with no nearest match gets the query alone); tiers 1,
3 and the service's maximum (``flows.app.engine.MAX_TIERS``). Each query runs the nearest-match
pass and the tiered search, the two compiled walks of a search.

The sweep runs with numba's bounds checking on: it re-executes itself with ``NUMBA_BOUNDSCHECK=1``
and a cache folder of its own unless they are set, so an out-of-bounds access is an IndexError,
counted and listed, not a silent write. Prints the number of queries, crashes (exceptions), empty
results and the time per query; exits 1 when any query raised. ``tests/tasks/test_search_sweep.py``
runs :func:`sweep` on a subset in CI.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from motionweb.store.web import MatchWeb
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.matchweb.params import MatchWebParams, min_chain_extent
from motionweb.tasks.ranking import default_epsilon, nearest_costs
from motionweb.tasks.search import MatchSearch, SearchParams


def windows(n_frames: int, rate: float, lengths_s: Sequence[float], step_s: float) -> Iterator[tuple[int, int]]:
    """Rows (a, b) of every window of ``lengths_s`` seconds starting every ``step_s`` seconds and
    at the last possible start, inside a clip of ``n_frames`` rows at ``rate`` Hz."""
    step = max(1, round(step_s * rate))
    for length_s in lengths_s:
        span = round(length_s * rate)
        if span > n_frames - 1:
            continue
        last = n_frames - 1 - span
        for a in sorted({*range(0, last + 1, step), last}):
            yield a, a + span


@dataclass
class SweepResult:
    queries: int = 0
    searches: int = 0
    empty: int = 0
    seconds: float = 0.0
    failures: list[str] = field(default_factory=list)


def sweep(webs: Mapping[str, Sequence[tuple[str, MatchWeb]]], tiers: Sequence[int], lengths_s: Sequence[float],
          step_s: float, web_cfg: MatchWebParams | None = None, clips: Sequence[str] | None = None,
          progress: bool = False) -> SweepResult:
    """Every window of every clip of ``webs`` (:func:`windows`) searched with the default ε rule at
    each number of tiers; an exception is a failure (query, tiers, the error's last frames). With
    ``progress`` a line per clip (so a long sweep's partial figures are on screen)."""
    web_cfg = web_cfg or MatchWebParams()
    out = SweepResult()
    t0 = time.perf_counter()
    todo = list(clips if clips is not None else sorted(webs))
    for k, clip in enumerate(todo):
        if progress:
            print(f"  [{k + 1}/{len(todo)}] {clip}: {out.searches} searches so far, {len(out.failures)} failures, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
        ms = MatchSearch(webs, SearchParams(), web_cfg)
        g = ms.graph(clip)
        need = min_chain_extent(web_cfg, g.rate)
        for a, b in windows(g.n_frames, g.rate, lengths_s, step_s):
            if b - a < need:
                continue
            q = Segment(clip, a, b)
            out.queries += 1
            for t in tiers:
                ms.cfg = SearchParams(max_tiers=t)  # the packed graphs stay (as the service does)
                out.searches += 1
                try:
                    eps = default_epsilon(nearest_costs(ms, q), ms.cfg.eps_nearest_ratio)
                    graph = ms.query_only(q) if eps is None else ms.search(q, eps)
                    out.empty += len(graph.nodes) == 1
                except Exception as exc:  # noqa: BLE001 - every exception is what the sweep counts
                    tb = "".join(traceback.format_exception(exc)[-3:]).strip().replace("\n", " | ")
                    out.failures.append(f"{clip} rows {a}..{b} tiers {t}: {tb}")
    out.seconds = time.perf_counter() - t0
    return out


def _bounds_checked() -> None:
    """Re-execute with numba's bounds checking on (and a cache of its own) unless it already is."""
    if os.environ.get("NUMBA_BOUNDSCHECK") == "1":
        return
    env = {**os.environ, "NUMBA_BOUNDSCHECK": "1",
           "NUMBA_CACHE_DIR": os.environ.get("MOTIONWEB_BOUNDSCHECK_CACHE",
                                             str(Path(tempfile.gettempdir()) / "motionweb-numba-boundscheck"))}
    os.execve(sys.executable, [sys.executable, "-m", "bench.sweep", *sys.argv[1:]], env)


def main() -> None:
    from motionweb.flows.app.engine import MAX_TIERS
    from motionweb.store.datasets import mocap_root
    from motionweb.tasks.features import FeatureParams

    from bench.retrieval import load_library

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tiers", type=int, nargs="+", default=[1, 3, MAX_TIERS])
    ap.add_argument("--windows", type=float, nargs="+", default=[0.5, 1.0, 2.0], help="window lengths (s)")
    ap.add_argument("--step", type=float, default=0.25, help="seconds between window starts")
    ap.add_argument("--clips", type=int, default=0, help="only the first N clips as queries (0: all)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "motionweb-bench-retrieval")
    args = ap.parse_args()
    _bounds_checked()
    import csv

    root = mocap_root() / "cmu"
    if not (root / "manifest.csv").is_file():
        sys.exit(f"bench.sweep: the CMU set is not at {root} (set MOTIONWEB_MOCAP)")
    with open(root / "manifest.csv", newline="") as fh:
        files = {r["path"]: r["category"] for r in csv.DictReader(fh) if r["path"].startswith("asf_amc/")}
    fcfg, wcfg = FeatureParams(), MatchWebParams()
    lib = load_library(root, args.cache, fcfg, wcfg, files)
    if len(lib.clips) != len(files) or any(not lib.webs[c] for c in lib.clips):
        sys.exit(f"bench.sweep: built {len(lib.clips)} clips of {len(files)}, or a clip without webs")
    cats = sorted(set(files.values()))
    print(f"library: {len(lib.clips)} clips ({', '.join(cats)}), {sum(lib.frames.values())} frames at "
          f"{max(fcfg.rates):g} Hz, one unsplit index; NUMBA_BOUNDSCHECK={os.environ.get('NUMBA_BOUNDSCHECK')}")
    clips = lib.clips[:args.clips] if args.clips else lib.clips
    res = sweep(lib.webs, args.tiers, args.windows, args.step, wcfg, clips, progress=True)
    if res.queries == 0:
        sys.exit("bench.sweep: no query was built")
    print(f"queries: {res.queries} windows x tiers {args.tiers} = {res.searches} searches "
          f"({res.empty} with no match: the query alone) over {len(clips)} clips")
    print(f"time: {res.seconds:.1f} s, {1e3 * res.seconds / res.searches:.1f} ms per search (bounds-checked)")
    print(f"crashes / exceptions: {len(res.failures)}")
    for f in res.failures[:20]:
        print("  " + f)
    sys.exit(1 if res.failures else 0)


if __name__ == "__main__":
    main()
