"""Benchmark: the index workers' cost per pair on a category of the size of the issue 25 corpora,
this checkout against a previous revision in the same run (issue 25, part 2).

The issue's corpora (the demo grown to 60 and 180 clips per category) cost 3.9 ms and 6.9 ms
per pair: the larger category pays more per pair. This measures where: one demo category grown to
``--clips`` clips (60 Hz; 180 is a category of the 381,399-frame corpus, checked), its features
computed in this process into a store, then the pair plan and batches the index flow makes for
2 workers (``flows.index.plan_pairs``, ``balance_batches``, ``batch_count``), of which the first
``--batches`` are computed by ``flows.runtime.workers.compute_web_batch`` (what a Dask worker runs) in one
child process per code: the previous revision ``--base`` (default: where this branch left
``main``; ``git archive`` of
it put first on PYTHONPATH) and this checkout, each into its own copy of the store. Printed per
code: seconds, ms per pair, and the clips' feature reads (a read and a preparation per miss of
the worker's operand cache; the floor is one per clip of the batch), with the load average.
Then every web computed is compared byte for byte between the two codes (arrays and
attributes): the webs must be identical.

With ``--breakdown N`` it measures where a pair's time goes instead, in this process on ``N``
random pairs of the category (the worker's own functions, stage by stage): preparing the pair's
operands, the coarse grid (GEMM) and web, and per finer level the refinement (the band cells'
values and the paths, chains and bridges: ``refine.refine_web``), then the write. It counts the
cells each level evaluates (``refine_web``'s own count: unique cells of the cropped bands) against
the full grid, and prints two arithmetic floors measured in the same run on the working-rate grids of
the sampled pairs: those cells at the row kernel's rate (``tasks.distance.distance_row``, whose
float64 sums, the bytes of ``tasks.distance.cell_distance``, the stored webs' values are, every
level's since ``store.keys.WEB_VALUES`` 2; the per-cell call's rate printed beside it),
and every level's whole grid by the GEMM path (float32 sums in BLAS's order: values that differ
in the last bits, and from CPU to CPU, bench/cpu_bytes.py).

With ``--store STORE --corpus DIR`` (an indexed store and its corpus, e.g. bench/scale.py's, whose
long takes have grids ~100x a demo clip's) the same comparison runs on a category of that store
(``--category``, default the one of most pairs) with the config of its current generation, each
code computing into a copy of the store's features; with ``--breakdown N`` as well, the breakdown
runs on that category instead.

With ``--commit-store STORE`` (an indexed store, e.g. bench/app_scale.py's 381k one) it measures
the index flow's serial tail instead: the commit task called inside a Prefect flow with that
store's generation (146,610 web records for the 381k corpus) as its argument, as the previous
code passes it and quoted (``prefect.utilities.annotations.quote``) as this checkout does; the
task's body is the same no-op in both, so the difference is Prefect's walk over the argument
(resolving futures, recording task inputs: O(objects in the argument), in Python).

    .venv/bin/python -m bench.index_scale [--clips 180] [--batches 1] [--keep DIR] [--base REV]
    .venv/bin/python -m bench.index_scale --breakdown 300 [--clips 180]
    .venv/bin/python -m bench.index_scale --store DIR --corpus DIR [--category C] [--batches 1] [--breakdown N]
    .venv/bin/python -m bench.index_scale --commit-store DIR
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")

import numpy as np
from motionweb.flows.config import Config
from motionweb.flows.index import Chunk, balance_batches, batch_count, plan_pairs, working_rate
from motionweb.flows.runtime.workers import compute_features_batch
from motionweb.store.catalog import scan_corpus
from motionweb.store.demo.corpus import write_demo_corpus
from motionweb.store.keys import web_digest
from motionweb.store.zarr_store import MotionStore

from bench.app_scale import base_code, previous_revision
from bench.corpus import CorpusError, frames60

CHILD = r"""
import json, sys, time
from motionweb.flows.runtime import workers as W
from motionweb.flows.config import Config
job = json.load(open(sys.argv[1]))
cfg = Config.model_validate(job["cfg"])
store = W.worker_store(job["store"])
reads = [0]
read = type(store).read_features
def counted(self, *a, **k):
    reads[0] += 1
    return read(self, *a, **k)
type(store).read_features = counted
W.compute_web_batch([tuple(p) for p in job["warm"]], cfg, job["store"])  # compiled kernels loaded
clear = getattr(W, "clear_operands", None) or W.clip_operands.cache_clear
clear()
reads[0] = 0
t = time.perf_counter()
n = 0
for b in job["batches"]:
    n += len(W.compute_web_batch([tuple(p) for p in b], cfg, job["store"]))
print(json.dumps({"seconds": time.perf_counter() - t, "pairs": n, "reads": reads[0]}))
"""


def build(work: Path, clips: int, cfg: Config) -> tuple[Path, list]:
    """A one-category demo corpus of ``clips`` walks at 60 Hz and a store with their features;
    (store, catalog entries)."""
    corpus, store = work / f"walks-{clips}", work / f"features-{clips}"
    if not corpus.is_dir():
        write_demo_corpus(corpus, seed=7, variants={c: (clips if c == "walk" else 0) for c in
                                                    ("walk", "run", "jump", "kick", "punch", "reach", "hop", "sit", "idle")},
                          fps=60.0)
    cat = scan_corpus(corpus, cfg.corpus)
    if cat.errors or len(cat.entries) != clips or list(cat.by_category()) != ["walk"]:
        raise CorpusError(f"{corpus}: {len(cat.entries)} clips in {sorted(cat.by_category())}, "
                          f"{len(cat.errors)} unreadable; {clips} walks were asked for")
    if not store.is_dir():
        recs = compute_features_batch(cat.entries, cfg, str(store))
        bad = [r for r in recs if "error" in r]
        if bad:
            raise CorpusError(f"features failed: {bad[:3]}")
    return store, cat.entries


def run_child(pkg: Path | None, store: Path, cfg: Config, batches: list, warm: list, work: Path, name: str) -> dict:
    job = work / f"job-{name}.json"
    conf = cfg.model_dump(mode="json")
    conf.pop("app", None)  # sections and keys the previous code may not know (defaults here)
    conf["index"].pop("operand_cache_mb", None)
    job.write_text(json.dumps({"cfg": conf, "store": str(store), "batches": batches,
                               "warm": warm}))
    env = {**os.environ}
    env.pop("PYTHONPATH", None)
    if pkg is not None:
        env["PYTHONPATH"] = str(pkg)
    load = os.getloadavg()[0]
    r = subprocess.run([sys.executable, "-c", CHILD, str(job)], capture_output=True, text=True, env=env,
                       cwd=str(work), check=False)
    if r.returncode != 0:
        raise RuntimeError(f"{name}: {r.stderr[-2000:]}")
    return {**json.loads(r.stdout.strip().splitlines()[-1]), "load": load, "load_after": os.getloadavg()[0]}


def same_webs(a: Path, b: Path, keys: list[str]) -> list[str]:
    """Keys whose web differs between stores ``a`` and ``b`` (arrays byte for byte, attributes)."""
    sa, sb = MotionStore(str(a), read_only=True), MotionStore(str(b), read_only=True)
    bad = []
    for k in keys:
        (xa, ta), (xb, tb) = sa.read_web_arrays(k), sb.read_web_arrays(k)
        if ta != tb or sorted(xa) != sorted(xb) or any(
                xa[n].dtype != xb[n].dtype or xa[n].shape != xb[n].shape or xa[n].tobytes() != xb[n].tobytes()
                for n in xa):
            bad.append(k)
    return bad


def commit_tail(store_dir: str) -> None:
    """The Prefect task call of the commit with a real generation, unquoted and quoted."""
    from motionweb.store.generations import load_generation
    from prefect import flow, task
    from prefect.cache_policies import NO_CACHE
    from prefect.utilities.annotations import quote

    gen = load_generation(MotionStore(store_dir, read_only=True))
    if gen is None:
        raise CorpusError(f"{store_dir} was never indexed")

    @task(name="commit", cache_policy=NO_CACHE)
    def commit_like(g, store_url: str) -> int:
        return len(g.webs)

    @flow(name="commit-tail")
    def tail() -> dict[str, float]:
        out = {}
        for name, arg in (("previous (unquoted)", gen), ("this (quoted)", quote(gen))):
            t = time.perf_counter()
            n = commit_like(arg, store_dir)
            out[name] = time.perf_counter() - t
            assert n == len(gen.webs)
        return out

    print(f"commit task on a generation of {len(gen.clips)} clips, {len(gen.webs)} webs, "
          f"{len(gen.checksums)} checksums; load {os.getloadavg()[0]:.1f}")
    for name, sec in tail().items():
        print(f"  {name:20s} {sec:7.2f} s  (the task's body: a no-op)")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


def breakdown(store: Path, entries: list, cfg: Config, n: int, scale_to: tuple[str, int] = ("the 381k corpus", 146_610)) -> None:
    """Per-pair cost by stage on ``n`` random pairs of the category (see the module notes);
    ``scale_to``: (what, pairs) the per-pair cost is multiplied out to at the end."""
    import math
    import random

    from motionweb.flows.runtime.workers import clip_operands, pin_blas_threads, web_counts
    from motionweb.store.keys import feature_digest
    from motionweb.store.zarr_store import checksum, pack_arrays
    from motionweb.tasks.distance import (
        _cells_kernel,
        distance_grid_cells,
        distance_grid_prepared,
        prepare_operands_pair,
    )
    from motionweb.tasks.matchweb import refine as R
    from motionweb.tasks.matchweb.build import build_web_full

    pin_blas_threads()
    rate = working_rate(cfg)
    jobs = plan_pairs(Chunk("walk", tuple(entries)), web_digest(cfg), rate)
    rnd = random.Random(1)
    sample = rnd.sample(jobs, min(n, len(jobs)))
    fd = feature_digest(cfg)
    t = time.perf_counter()
    ops = {}
    for j in sample:
        for sha in (j.a.sha256, j.b.sha256):
            if sha not in ops:
                ops[sha] = clip_operands(str(store), sha, fd)
    read_s = (time.perf_counter() - t) / len(ops)
    rates = sorted(ops[sample[0].a.sha256])
    mw = cfg.matchweb
    stages = ["prepare", "coarse grid", "coarse web"] + [f"{r:g} Hz refine" for r in rates[1:]] \
        + ["arrays, pack, checksum"]
    sec = dict.fromkeys(stages, 0.0)
    cells = {"full": dict.fromkeys(rates, 0), "evaluated": dict.fromkeys(rates, 0)}

    def one(j, count: bool) -> None:
        oa = ops[j.a.sha256]
        ob = oa if j.self_pair else ops[j.b.sha256]
        t0 = time.perf_counter()
        pairs = {r: prepare_operands_pair(oa[r], ob[r]) for r in rates}
        t1 = time.perf_counter()
        grid0 = distance_grid_cells(*pairs[rates[0]])  # as build_web_operands
        t2 = time.perf_counter()
        web = build_web_full(grid0, rates[0], mw, j.self_pair)
        t3 = time.perf_counter()
        sec["prepare"] += t1 - t0
        sec["coarse grid"] += t2 - t1
        sec["coarse web"] += t3 - t2
        if count:
            cells["full"][rates[0]] += grid0.size
            cells["evaluated"][rates[0]] += grid0.size
        for r in rates[1:]:
            pa, pb = pairs[r]
            counts: dict[str, int] = {}
            ta = time.perf_counter()
            web = R.refine_web(web, pa, pb, r, mw, j.self_pair, counts=counts)
            sec[f"{r:g} Hz refine"] += time.perf_counter() - ta
            if count:
                cells["full"][r] += pa.n_frames * pb.n_frames
                cells["evaluated"][r] += counts["evaluated"]
        t4 = time.perf_counter()
        arrays = web.to_arrays()
        parts, _, _ = pack_arrays(arrays)
        checksum(parts)
        web_counts(arrays)
        sec["arrays, pack, checksum"] += time.perf_counter() - t4

    for j in sample[:3]:
        one(j, False)  # compiled kernels loaded
    for k in sec:
        sec[k] = 0.0
    load = os.getloadavg()[0]
    for j in sample:
        one(j, True)
    m = len(sample)
    p = ops[sample[0].a.sha256][rates[0]].w.shape[0]
    flops_cell = 10 * p  # three products of K = 2P, 2P, P (2 flops each), then the fused combine
    fine = sum(cells["evaluated"][r] for r in rates[1:]) / m
    coarse = cells["evaluated"][rates[0]] / m
    # the per-cell kernel (the stored values) and the GEMM path (the coarsest level's) on the
    # working-rate grids of the first 20 pairs, each cell once
    per_cell = gemm_cell = row_cell = 0.0
    n_cells = 0
    for j in sample[:20]:
        oa = ops[j.a.sha256]
        ob = oa if j.self_pair else ops[j.b.sha256]
        pa0, pb0 = prepare_operands_pair(oa[rates[-1]], ob[rates[-1]])
        rows = np.repeat(np.arange(pa0.n_frames), pb0.n_frames).astype(np.int64)
        cols = np.tile(np.arange(pb0.n_frames), pa0.n_frames).astype(np.int64)
        out = np.empty(len(rows))
        _cells_kernel(pa0.left, pa0.left_y, pa0.norms, pb0.right, pb0.right_y, pb0.norms, rows, cols, out)
        distance_grid_prepared(pa0, pb0)
        grid = distance_grid_cells(pa0, pb0)
        if grid.reshape(-1).tobytes() != out.astype(grid.dtype).tobytes():
            raise SystemExit("the row kernel's grid differs from the per-cell kernel's values")
        t = time.perf_counter()
        _cells_kernel(pa0.left, pa0.left_y, pa0.norms, pb0.right, pb0.right_y, pb0.norms, rows, cols, out)
        t1 = time.perf_counter()
        distance_grid_prepared(pa0, pb0)
        t2 = time.perf_counter()
        distance_grid_cells(pa0, pb0)
        per_cell += t1 - t
        gemm_cell += t2 - t1
        row_cell += time.perf_counter() - t2
        n_cells += len(rows)
    per_cell /= n_cells
    gemm_cell /= n_cells
    row_cell /= n_cells
    total = sum(sec.values()) / m
    print(f"{m} random pairs of {len(jobs)}; P = {p} points per frame; load {load:.1f} "
          f"(at the end {os.getloadavg()[0]:.1f}); clip read + operands: {read_s * 1e3:.2f} ms per clip")
    print(f"{'stage':24s} {'ms/pair':>8s} {'share':>6s}")
    for k, v in sec.items():
        print(f"{k:24s} {v / m * 1e3:8.3f} {v / m / total:6.0%}")
    print(f"{'total':24s} {total * 1e3:8.3f}")
    for r in rates:
        print(f"cells at {r:g} Hz: {cells['evaluated'][r] / m:9.0f} evaluated of {cells['full'][r] / m:9.0f} "
              f"({cells['evaluated'][r] / max(1, cells['full'][r]):.0%})")
    print(f"a cell at the working rate: {per_cell * 1e9:.1f} ns by the per-cell kernel "
          f"(tasks.distance.cell_distance, {flops_cell / per_cell / 1e9:.1f} GFLOP/s), {row_cell * 1e9:.1f} ns "
          f"by the row kernel on whole rows (distance_row, the same bytes, {flops_cell / row_cell / 1e9:.1f} "
          f"GFLOP/s), {gemm_cell * 1e9:.1f} ns by the GEMM path on the whole grid (distance_grid_prepared, "
          f"{flops_cell / gemm_cell / 1e9:.1f} GFLOP/s)")
    floor_cells = (fine + coarse) * row_cell
    floor_gemm = sum(cells["full"][r] for r in rates) / m * gemm_cell
    print(f"floors per pair: the evaluated cells at the row kernel's rate (every level's values since "
          f"store.keys.WEB_VALUES 2) {floor_cells * 1e3:.3f} ms; every level's whole grid by the GEMM path "
          f"{floor_gemm * 1e3:.3f} ms; measured {total * 1e3:.3f} ms = {total / floor_cells:.1f}x / "
          f"{total / floor_gemm:.1f}x")
    what, n_pairs = scale_to
    print(f"for {what} ({n_pairs} pairs of such categories) on 2 workers: "
          f"{n_pairs * total / 2:.0f} s at this cost; floors {n_pairs * floor_cells / 2:.0f} s (per-cell values) "
          f"and {n_pairs * floor_gemm / 2:.0f} s (whole grids by GEMM)")
    if not math.isfinite(total) or m == 0:
        raise SystemExit("nothing measured")


def store_category(store: Path, corpus: Path, category: str | None) -> tuple[Config, str, list, int]:
    """(config of the store's current generation with ``corpus`` as its corpus, category, its
    catalog entries, the generation's webs); the category of most pairs by default. Stops unless every clip of the
    category has its features in the store."""
    from motionweb.store.generations import current_generation

    gen = current_generation(MotionStore(str(store), read_only=True))
    if gen is None:
        raise CorpusError(f"{store}: no current generation (index it first)")
    cfg = Config.model_validate({**gen.config, "corpus": {**gen.config["corpus"], "path": str(corpus)}})
    cat = scan_corpus(corpus, cfg.corpus)
    by_cat = cat.by_category()
    rate = working_rate(cfg)
    if category is None:
        category = max(by_cat, key=lambda c: (len(plan_pairs(Chunk(c, tuple(by_cat[c])), web_digest(cfg), rate)), c))
    if category not in by_cat:
        raise CorpusError(f"{corpus}: no category {category!r} (has {sorted(by_cat)})")
    entries = by_cat[category]
    indexed = {c["sha256"] for c in gen.clips}
    if missing := [e.path for e in entries if e.sha256 not in indexed]:
        raise CorpusError(f"{store} did not index {len(missing)} clips of {category}: {missing[:3]}")
    return cfg, category, entries, len(gen.webs)


def store_breakdown(store: Path, corpus: Path, category: str | None, n: int) -> None:
    """:func:`breakdown` on a category of an indexed store (e.g. bench/scale.py's long takes, whose
    grids are ~100x a demo clip's), with the config of its current generation."""
    cfg, category, entries, n_webs = store_category(store, corpus, category)
    frames = sum(frames60(e.duration) for e in entries)
    print(f"category {category}: {len(entries)} clips, {frames} frames at 60 Hz; rates {cfg.features.rates} "
          f"(store {store}, {n_webs} webs)")
    breakdown(store, entries, cfg, n, (f"the store's {n_webs} webs", n_webs))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", type=int, default=180, help="clips of the category (180: the 381k corpus's)")
    ap.add_argument("--batches", type=int, default=1, help="batches of the flow's plan computed per code")
    ap.add_argument("--keep", help="work folder (corpus, features, base code), reused when present")
    ap.add_argument("--commit-store", help="measure the commit task's Prefect overhead on this store instead")
    ap.add_argument("--breakdown", type=int, default=0, help="measure where the time of N random pairs goes instead")
    ap.add_argument("--store", help="with --breakdown: pairs of a category of this indexed store (its config) instead")
    ap.add_argument("--corpus", help="with --store: the corpus it indexed")
    ap.add_argument("--category", help="with --store: the category (default: the one of most pairs)")
    ap.add_argument("--base", default=None, help="the previous revision measured in the same run "
                                                 "(default: where this branch left main)")
    args = ap.parse_args()
    if args.commit_store:
        commit_tail(args.commit_store)
        return
    if args.store:
        if not args.corpus:
            raise SystemExit("--store needs --corpus DIR")
        store, corpus = Path(args.store), Path(args.corpus)
        if args.breakdown:
            store_breakdown(store, corpus, args.category, args.breakdown)
            return
        cfg, category, entries, _ = store_category(store, corpus, args.category)
        work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-index-scale-"))
        work.mkdir(parents=True, exist_ok=True)
        features = work / "features-of-store"  # the store's features alone: the codes write webs afresh
        if not features.is_dir():
            shutil.copytree(store, features, ignore=lambda d, names: [n for n in names if Path(d) == store
                                                                      and n in ("webs", "generations", "current")])
        compare(work, features, category, entries, cfg, args.batches, args.base, args.keep is None)
        return
    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-index-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    cfg = Config.model_validate({"corpus": {"path": str(work), "length_unit": "m"},
                                 "features": {"rates": [10.0, 20.0, 30.0]}})
    store, entries = build(work, args.clips, cfg)
    if args.breakdown:
        breakdown(store, entries, cfg, args.breakdown)
        return
    compare(work, store, "walk", entries, cfg, args.batches, args.base, args.keep is None)


def compare(work: Path, store: Path, category: str, entries: list, cfg: Config, n_batches: int, base: str | None,
            remove: bool) -> None:
    """The first ``n_batches`` batches of the flow's plan for the category, computed by the previous
    code and by this checkout (each into a copy of ``store``), then their webs compared byte for
    byte; exits 1 when any differs."""
    frames = sum(frames60(e.duration) for e in entries)
    rate = working_rate(cfg)
    jobs = plan_pairs(Chunk(category, tuple(entries)), web_digest(cfg), rate)
    batches = balance_batches(jobs, batch_count(jobs, 2))
    if len(batches) <= n_batches:
        raise CorpusError(f"{category}: {len(batches)} batches, {n_batches} asked for and one more kept for the warm-up")
    todo = [[(j.key, j.a.sha256, j.b.sha256, j.self_pair) for j in b] for b in batches[:n_batches]]
    # the warm-up (compiled kernels loaded): a self pair and another pair, outside the measured batches
    rest = [j for b in batches[n_batches:] for j in b]
    warm = [(j.key, j.a.sha256, j.b.sha256, j.self_pair) for flag in (True, False)
            for j in [next(j for j in rest if j.self_pair == flag)]]
    n = sum(len(b) for b in todo)
    clips_used = len({s for b in todo for _, a, b_, _ in b for s in (a, b_)})
    print(f"category {category}: {len(entries)} clips, {frames} frames at 60 Hz; rates {cfg.features.rates}; "
          f"{len(jobs)} pairs in {len(batches)} batches for 2 workers; measured: {n} pairs of "
          f"{len(todo)} batch(es) touching {clips_used} clips; {os.cpu_count()} cores")
    print(f"{'code':>8} {'load':>5} {'seconds':>8} {'ms/pair':>8} {'feature reads':>13}  (floor: {clips_used})")
    stores = {}
    base = base or previous_revision()[:10]
    for name, pkg in ((base[:10], base_code(work, base)), ("this", None)):
        dst = work / f"store-{name.replace('/', '-')}"
        shutil.rmtree(dst, ignore_errors=True)
        shutil.copytree(store, dst)
        r = run_child(pkg, dst, cfg, todo, warm, work, name.replace("/", "-"))
        stores[name] = dst
        print(f"{name:>8} {r['load']:5.1f} {r['seconds']:8.1f} {r['seconds'] / r['pairs'] * 1000:8.2f} {r['reads']:13d}",
              flush=True)
    keys = [k for b in todo for k, *_ in b]
    bad = same_webs(*stores.values(), keys)
    print(f"webs: {len(keys) - len(bad)} of {len(keys)} byte-identical between the two codes"
          + (f"; DIFFERENT: {bad[:5]}" if bad else ""))
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    if remove:
        shutil.rmtree(work, ignore_errors=True)
    if bad:
        raise SystemExit(1)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
