"""Benchmark: how the index by category grows with the library, fitted and extrapolated to a
million frames (issue 25, part 3: "A million frames").

For each size (frames at 60 Hz) a corpus is built in a temp folder (never in the repository):
  * the shared real data with their skeletons, linked, not copied (store.datasets.mocap_root: the
    CMU ASF/AMC trials beside their subject's ASF in ``cmu-<manifest category>/``, the DeepMimic
    clips in ``dm-<name>/``; bench/corpus.py's helpers), in path order until the size is reached;
    where the real data is absent it says so and uses takes only,
  * long demo takes for the rest (store.demo.takes.write_take_corpus: 10-60 s continuous sessions
    of several actions, each in the folder of its dominant action), written once for the largest
    size and linked: the take plan of a smaller size is a prefix of the larger one's.
The benchmark stops (``bench.corpus.CorpusError``, exit 1) unless the scan finds every clip
linked, each loading, in the categories asked for, with at least the frames asked for. Each size
is indexed by category (KG04 §3: webs within a category chunk) with the index flow exactly as
bench/corpus.py's ``run_index`` does (Prefect + a local Dask cluster, 2 single-threaded worker
processes) into a fresh store, and stops unless every clip was indexed, none broken, and the
generation's webs are the pairs expected (per category and skeleton, m(m + 1)/2 for m distinct
clips: KG04's all pairs of a chunk, self pairs included).

Printed per size: frames, clips, categories, pairs, cells (sum over pairs of frames_a · frames_b
at the working rate, 60 Hz: the full grids), wall seconds, the arithmetic floor (those cells ×
10·P flops per cell, P points per frame, at the float64 GEMM rate of one core measured in this
run, over the 2 workers: the time of every full grid as one matrix product; the index evaluates
only a band at fine rates, KG04 §3.2 Fig. 8, so it can run below this floor), peak memory of the
process tree (PeakRSS, Prefect's server excluded) and of the largest worker, store bytes and
object (file) count. Then each figure is fitted against frames (power law, least squares in
log-log, at least 4 sizes) and extrapolated to 1,000,000 frames (beside the issue's target: ≤ 30
min and ≤ 8 GB on this 2-core machine) and to 10^7 frames on N workers (N = 2, 8, 32, 128):
compute time ÷ (N/2), assuming pairs are independent (they are: each web needs only its two
clips' features) and the commit is streamed (not the serial tail it is now); memory per worker:
the fitted largest worker, unchanged by N.

    .venv/bin/python -m bench.scale --sizes 20000 40000 80000 150000 [--million] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW", "ignore")
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")

import numpy as np
import psutil
from motionweb.flows.config import Config
from motionweb.store.catalog import scan_corpus
from motionweb.store.datasets import mocap_root
from motionweb.store.demo.rig import humanoid_skeleton
from motionweb.store.demo.takes import write_take_corpus
from motionweb.store.generations import load_generation
from motionweb.store.zarr_store import MotionStore

from bench.corpus import (
    RATE,
    CorpusError,
    PeakRSS,
    check_corpus,
    frames60,
    link_clip,
    link_urdf,
    rates_for,
    real_placement,
    run_index,
)

SEED = 7
WORKERS = 2
MIN_FIT = 4
TARGET_FRAMES = 1_000_000
TARGET_WALL_S, TARGET_PEAK_GB = 30 * 60.0, 8.0
CLUSTER_FRAMES = 10_000_000
CLUSTER_WORKERS = (2, 8, 32, 128)


# ------------------------------------------------------------------------------------ corpus
def real_clips(cfg: Config) -> tuple[Path | None, list[tuple]]:
    """(mocap root, [(entry, corpus path, category)]) of the shared real data in path order;
    (None, []) with a message when it is absent."""
    root = mocap_root()
    if not root.is_dir():
        print(f"no real motion capture at {root} (set $MOTIONWEB_MOCAP): the corpora are long takes only")
        return None, []
    real = scan_corpus(root, cfg.corpus)
    if real.errors:
        raise CorpusError(f"{len(real.errors)} clips of {root} do not load: "
                          + "; ".join(f"{e.path}: {e.reason}" for e in real.errors[:5]))
    return root, sorted(real_placement(root, real.entries), key=lambda r: r[1])


def build_sized_corpus(out: Path, frames: int, root: Path | None, real: list[tuple], pool: Path,
                       pool_paths: list[Path], cfg: Config) -> dict:
    """Link real clips (path order) and then takes of ``pool`` (plan order) into ``out`` until it
    holds ``frames`` frames at 60 Hz; check it (:func:`check_scale_corpus`). O(clips)."""
    expected: dict[str, str] = {}
    total = n_real = n_takes = 0
    if root is not None:
        link_urdf(root, out)
    for e, rel, cat in real:
        if total >= frames:
            break
        link_clip(Path(e.abs_path), out / rel)
        expected[rel] = cat
        total += frames60(e.duration)
        n_real += 1
    for p in pool_paths:
        if total >= frames:
            break
        rel = p.relative_to(pool).as_posix()
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).symlink_to(p.resolve())
        (out / rel).with_suffix(".json").symlink_to(p.with_suffix(".json").resolve())  # truth + unit
        expected[rel] = p.parent.name
        total += _bvh_frames(p)  # a take is written at 60 Hz
        n_takes += 1
    if total < frames:
        raise CorpusError(f"the take pool {pool} holds too few frames for a corpus of {frames}")
    cat = scan_corpus(out, cfg.corpus)
    got = check_scale_corpus(out, cat, expected, frames)
    return {"frames": got, "clips": len(cat.entries), "categories": len(cat.by_category()), "real": n_real,
            "takes": n_takes, "entries": cat.entries}


def _bvh_frames(path: Path) -> int:
    with path.open() as f:
        for line in f:
            if line.startswith("Frames:"):
                return int(line.split()[1])
    raise CorpusError(f"{path}: no Frames line")


def check_scale_corpus(out: Path, cat, expected: dict[str, str], frames: int) -> int:
    """bench.corpus.check_corpus (every clip written found and loading, in its category, at least
    ``frames`` frames) and the categories asked for: exactly those of ``expected``."""
    total = check_corpus(out, cat, expected, frames)
    want, got = set(expected.values()), set(cat.by_category())
    if want != got:
        raise CorpusError(f"the corpus in {out} has categories {sorted(got)}, {sorted(want)} were asked for")
    return total


def expected_pairs(entries, rate: float) -> tuple[int, float]:
    """(pairs, cells) an index by category must build: per category and skeleton, every pair of
    distinct clips (by content) and each clip with itself, m(m + 1)/2 for m clips; cells are
    frames_a · frames_b at ``rate``. Independent of the flow's planner; O(clips²) for the cells."""
    groups: dict[tuple[str, str], dict[str, int]] = {}
    for e in entries:
        groups.setdefault((e.category, e.skeleton), {})[e.sha256] = math.floor(e.duration * rate + 1e-9) + 1
    pairs, cells = 0, 0.0
    for clips in groups.values():
        f = np.array(list(clips.values()), dtype=np.float64)
        pairs += len(f) * (len(f) + 1) // 2
        cells += (f.sum() ** 2 + (f ** 2).sum()) / 2
    return pairs, cells


# ------------------------------------------------------------------------------------ measures
class WorkerPeak(PeakRSS):
    """Largest RSS of any one child process of this one (the Dask workers; Prefect's server
    excluded), sampled every 50 ms while the block runs."""

    def _sample(self) -> int:
        return max(self._children(self.root or psutil.Process()), default=0)


def store_objects(store: Path) -> int:
    """Files under the store's folder (what an object store would hold as objects)."""
    return sum(len(files) for _, _, files in os.walk(store))


def points_per_frame(cfg: Config) -> int:
    """P: the points of a frame's cloud (every joint of the demo skeleton over the window)."""
    return humanoid_skeleton().n_joints * cfg.features.window


def gemm_rate(k: int, n: int = 2000, repeats: int = 5) -> float:
    """Float64 GEMM rate of one core (flop/s): (n, k) @ (k, n), best of ``repeats``, BLAS pinned
    to one thread as the index workers are."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, k)), rng.standard_normal((k, n))
    best = math.inf
    with threadpool_limits(1):
        a @ b
        for _ in range(repeats):
            t = time.perf_counter()
            a @ b
            best = min(best, time.perf_counter() - t)
    return 2.0 * n * n * k / best


# ------------------------------------------------------------------------------------ fits
def fit_power(x: list[float], y: list[float]) -> tuple[float, float]:
    """(exponent p, coefficient c) of y = c · x^p by least squares in log-log; refuses fewer than
    4 sizes or a non-positive value (a power law is not fitted to too little data)."""
    if len(x) != len(y):
        raise ValueError(f"{len(x)} sizes and {len(y)} values")
    if len(set(x)) < MIN_FIT:
        raise ValueError(f"a power law needs at least {MIN_FIT} distinct sizes, got {len(set(x))}")
    if min(x) <= 0 or min(y) <= 0:
        raise ValueError("a power law fits positive values only")
    p, logc = np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)
    return float(p), float(math.exp(logc))


def fit_work(cells: list[float], wall: list[float]) -> tuple[float, float]:
    """(a seconds, b seconds per cell) of wall = a + b · cells by least squares: a fixed cost (start,
    catalog, commit) plus the grids' work. The power law in frames cannot see that the work grows
    as the cells (frames² within a category) once the fixed costs stop dominating: over the small
    sizes it bends low. A negative intercept is refitted through the origin. Refuses fewer than 2
    distinct sizes or a negative value."""
    if len(cells) != len(wall):
        raise ValueError(f"{len(cells)} sizes and {len(wall)} values")
    if len(set(cells)) < 2:
        raise ValueError(f"a line needs at least 2 distinct sizes, got {len(set(cells))}")
    if min(cells) < 0 or min(wall) < 0:
        raise ValueError("cells and seconds are never negative")
    x, y = np.asarray(cells, float), np.asarray(wall, float)
    b, a = np.polyfit(x, y, 1)
    if a < 0:
        a, b = 0.0, float(x @ y / (x @ x))
    return float(a), float(b)


def predict(fit: tuple[float, float], x: float) -> float:
    p, c = fit
    return c * x ** p


# ------------------------------------------------------------------------------------ main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000, 40000, 80000, 150000],
                    help="corpus sizes, frames at 60 Hz")
    ap.add_argument("--million", action="store_true", help="add a 1,000,000-frame size")
    ap.add_argument("--keep", help="work folder kept (corpora, take pool, stores) instead of a temp one")
    args = ap.parse_args()
    sizes = sorted(set(args.sizes) | ({TARGET_FRAMES} if args.million else set()))

    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    cfg = Config.model_validate({"corpus": {"length_unit": "m"}, "features": {"rates": rates_for(RATE)}})
    root, real = real_clips(cfg)
    real_frames = sum(frames60(e.duration) for e, _, _ in real)
    pool = work / "takes"
    t = time.perf_counter()
    pool_paths = write_take_corpus(pool, max(0, max(sizes) - real_frames) + 4000, seed=SEED, fps=RATE)
    p_pts = points_per_frame(cfg)
    rate = gemm_rate(2 * p_pts)
    flops_cell = 10 * p_pts
    print(f"real data: {len(real)} clips, {real_frames} frames at 60 Hz ({root or 'absent'}); take pool: "
          f"{len(pool_paths)} takes written in {time.perf_counter() - t:.1f} s; {os.cpu_count()} cores, "
          f"{WORKERS} Dask workers x 1 thread; load {os.getloadavg()[0]:.1f}")
    print(f"GEMM float64, one core: {rate / 1e9:.2f} GFLOP/s on (2000, {2 * p_pts}) @ ({2 * p_pts}, 2000); "
          f"a cell = 10·P = {flops_cell} flops (P = {p_pts} points per frame); floor = cells x 10·P / "
          f"(GEMM rate x {WORKERS} workers)")
    print()
    head = (f"{'frames':>8} {'clips':>6} {'cats':>4} {'real':>4} {'takes':>5} {'pairs':>7} {'cells':>9} "
            f"{'wall s':>7} {'floor s':>7} {'peak GB':>7} {'wkr GB':>6} {'store MB':>8} {'objects':>7}  load")
    print(head, flush=True)
    rows = []
    with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        # warm-up, not measured: the first flow run pays the compiled kernels' loads and Prefect's start
        warm = work / "warm-up"
        shutil.rmtree(warm, ignore_errors=True)
        link_corpus = build_sized_corpus(warm / "corpus", 1, None, [], pool, pool_paths[:1], cfg)
        run_index(warm / "corpus", warm / "store", RATE, "category", WORKERS, link_corpus["clips"])
        shutil.rmtree(warm, ignore_errors=True)
        for size in sizes:
            corpus, store = work / f"corpus-{size}", work / f"store-{size}"
            shutil.rmtree(corpus, ignore_errors=True)
            shutil.rmtree(store, ignore_errors=True)
            info = build_sized_corpus(corpus, size, root, real, pool, pool_paths, cfg)
            pairs_exp, cells = expected_pairs(info["entries"], RATE)
            load = os.getloadavg()[0]
            with WorkerPeak() as wp:
                s = run_index(corpus, store, RATE, "category", WORKERS, info["clips"])
            gen = load_generation(MotionStore(str(store), read_only=True))
            webs = len({w["key"] for w in gen.webs})
            if len(gen.clips) != info["clips"] or s["pairs"] != pairs_exp or webs != pairs_exp:
                raise CorpusError(f"size {size}: {len(gen.clips)} clips indexed of {info['clips']}, "
                                  f"{s['pairs']} pairs and {webs} webs, {pairs_exp} pairs expected")
            row = {"frames": info["frames"], "clips": info["clips"], "categories": info["categories"],
                   "pairs": s["pairs"], "cells": cells, "wall_s": s["wall_s"],
                   "floor_s": cells * flops_cell / (rate * WORKERS), "peak_gb": s["peak_gb"],
                   "worker_gb": wp.peak / 1e9, "store_bytes": s["store_bytes"], "objects": store_objects(store)}
            rows.append(row)
            print(f"{row['frames']:8d} {row['clips']:6d} {row['categories']:4d} {info['real']:4d} {info['takes']:5d} "
                  f"{row['pairs']:7d} {cells:9.3g} {row['wall_s']:7.1f} {row['floor_s']:7.1f} {row['peak_gb']:7.2f} "
                  f"{row['worker_gb']:6.2f} {row['store_bytes'] / 1e6:8.1f} {row['objects']:7d}  "
                  f"{load:.1f}-{os.getloadavg()[0]:.1f}", flush=True)
            if not args.keep:
                shutil.rmtree(corpus, ignore_errors=True)
                shutil.rmtree(store, ignore_errors=True)
    report(rows)
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


def report(rows: list[dict]) -> None:
    """The fits and extrapolations of the module notes."""
    print()
    if len(rows) < MIN_FIT:
        print(f"fits: not made ({len(rows)} sizes; a power law needs at least {MIN_FIT})")
        return
    x = [r["frames"] for r in rows]
    if len(set(x)) < MIN_FIT:
        print(f"fits: not made ({len(set(x))} distinct sizes; a power law needs at least {MIN_FIT})")
        return
    figures = [("wall_s", "wall s", 1.0, TARGET_WALL_S), ("floor_s", "floor s", 1.0, None),
               ("peak_gb", "peak GB", 1.0, TARGET_PEAK_GB), ("worker_gb", "worker GB", 1.0, None),
               ("store_bytes", "store GB", 1e-9, None), ("objects", "objects", 1.0, None),
               ("pairs", "pairs", 1.0, None), ("cells", "cells", 1.0, None)]
    print(f"fits y = c·frames^p over {len(rows)} sizes ({min(x)}-{max(x)} frames), and predictions")
    print(f"{'figure':>10} {'p':>6} {'at 1e6 frames':>14}  target (2 cores)")
    fits = {}
    for key, label, k, target in figures:
        fit = fit_power(x, [r[key] for r in rows])
        fits[key] = fit
        at = predict(fit, TARGET_FRAMES) * k
        verdict = "" if target is None else f"<= {target:g} ({'met' if at <= target else 'NOT met'})"
        if key == "wall_s":
            verdict = f"<= 1800 s = 30 min ({'met' if at <= TARGET_WALL_S else 'NOT met'}: {at / 60:.1f} min)"
        print(f"{label:>10} {fit[0]:6.2f} {at:14.4g}  {verdict}")
    # the work model, fitted on the sizes below a million frames: measured against the 1e6 run when made
    big = [r for r in rows if r["frames"] >= 0.9 * TARGET_FRAMES]
    small = [r for r in rows if r not in big]
    base = small if len({r["cells"] for r in small}) >= 2 else rows
    a, b = fit_work([r["cells"] for r in base], [r["wall_s"] for r in base])
    cells6 = big[0]["cells"] if big else predict(fits["cells"], TARGET_FRAMES)
    at6 = a + b * cells6
    print(f"\nwall by the work, wall = a + b·cells over {len(base)} sizes ({min(r['frames'] for r in base)}-"
          f"{max(r['frames'] for r in base)} frames): a = {a:.1f} s, b = {b * 1e9:.1f} ns per cell; at "
          f"{cells6:.3g} cells ({'the 1e6-frame corpus built' if big else 'the cells fit at 1e6 frames'}): "
          f"{at6:.0f} s = {at6 / 60:.1f} min ({'met' if at6 <= TARGET_WALL_S else 'NOT met'})"
          + (f"; measured {big[0]['wall_s']:.0f} s = {big[0]['wall_s'] / 60:.1f} min" if big else ""))
    wall7, floor7 = predict(fits["wall_s"], CLUSTER_FRAMES), predict(fits["floor_s"], CLUSTER_FRAMES)
    cells7 = predict(fits["cells"], CLUSTER_FRAMES)
    mem7 = predict(fits["worker_gb"], CLUSTER_FRAMES)
    print()
    print("at 1e7 frames on N workers (time = the 2-worker fit / (N/2): pairs are independent, each web "
          "needs only its two clips' features, and the commit is assumed streamed, not a serial tail; "
          "memory per worker = the largest worker's fit, unchanged by N); 'work h' = a + b·cells / (N/2) "
          "at the cells fit's 1e7 frames")
    print(f"{'N':>5} {'wall h':>9} {'work h':>9} {'floor h':>9} {'GB/worker':>9}")
    for n in CLUSTER_WORKERS:
        print(f"{n:5d} {wall7 / (n / 2) / 3600:9.2f} {(a + b * cells7 / (n / 2)) / 3600:9.2f} "
              f"{floor7 / (n / 2) / 3600:9.2f} {mem7:9.2f}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
