"""Benchmark: `motionweb app` on a store of any size — open, memory and warm search latency, this
checkout against a previous revision in the same run (issue 25, part 5).

The store: ``--store DIR`` (an indexed store, e.g. bench/app.py's ``--keep DIR`` ``store-category-30``,
with ``--corpus`` its corpus), or the demo corpus grown to ``--variants`` clips per category
(``store.demo.corpus.write_demo_corpus`` at 60 Hz, 9 categories: 60 gives the issue's
127,012 frames, 180 its 381,399) indexed by category at 30 Hz with the default config and a local
cluster of 2 workers, built in ``--keep`` when absent (the corpus is checked to hold the clips and
categories asked for; bench.corpus.CorpusError otherwise).

Then for each code — the previous revision ``--base`` (default: where this branch left ``main``; ``git archive`` of it
into the work folder, put first on PYTHONPATH, so its ``motionweb app`` and search workers run
the old code with this checkout's environment) and this checkout — the service is started on the
store (``--no-record``: no Prefect) and measured:
  * open: from starting ``motionweb app`` to the first search answered (the service answers during
    its warm-up), and to ``/api/status`` saying warm with its standby ready (target ≤ 10 s);
  * warm search: ``--queries`` random 1.5 s queries of bench/app.py (ε the 0.05 quantile of the
    scope's web values, 3 tiers) asked once each, then asked again and timed: median, p90, max
    (bench/app.py's "warm" figure; target on 381k frames: median ≤ 100 ms), p90, p99 and max;
  * first asked: each query's latency the first time (the first query excepted), median and p99;
    the service's file cache of packed graphs (``app.graph_files_gb``, ``MOTIONWEB_CACHE_DIR``) is
    empty at each code's start, then a third service ("restart") is measured on the files the run
    of this checkout left (``--no-restart``: not);
  * memory: peak RSS of the service and its search workers, sampled every 50 ms (target ≤ 2 GB),
    each process's RSS at the end, and the worker's cache then (this checkout only).
    The RSS counts the pages of mapped graph files a process holds (the page cache's, reclaimable).
A code that is not ready within ``--timeout`` s is reported so and stopped.

    .venv/bin/python -m bench.app_scale [--variants 60] [--keep DIR] [--base REV] [--queries 40] [--cache-mb MB]
        [--graph-files-gb GB]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")

import numpy as np
import psutil
import yaml
from motionweb.store.catalog import scan_corpus
from motionweb.store.demo.corpus import CATEGORIES, write_demo_corpus
from motionweb.store.generations import load_generation
from motionweb.store.zarr_store import MotionStore

from bench.app import Api, pct, random_queries
from bench.corpus import CorpusError, PeakRSS, frames60, run_index

REPO = Path(__file__).resolve().parent.parent


def build_store(work: Path, variants: int) -> tuple[Path, Path]:
    """(corpus, store) of the demo corpus grown to ``variants`` clips per category, indexed by
    category at 30 Hz; reused when ``work`` holds them."""
    corpus, store = work / f"demo-{variants}", work / f"store-demo-{variants}"
    if load_generation(MotionStore(str(store))) is not None:
        return corpus, store
    shutil.rmtree(corpus, ignore_errors=True)
    t = time.perf_counter()
    write_demo_corpus(corpus, seed=7, variants_per_category=variants, fps=60.0)
    cat = scan_corpus(corpus)
    if cat.errors or len(cat.entries) != variants * len(CATEGORIES) or len(cat.by_category()) != len(CATEGORIES):
        raise CorpusError(f"the grown demo corpus in {corpus} holds {len(cat.entries)} clips in "
                          f"{len(cat.by_category())} categories ({len(cat.errors)} unreadable); "
                          f"{variants * len(CATEGORIES)} in {len(CATEGORIES)} were asked for")
    frames = sum(frames60(e.duration) for e in cat.entries)
    print(f"corpus: {len(cat.entries)} clips, {frames} frames at 60 Hz, written in {time.perf_counter() - t:.0f} s")
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        s = run_index(corpus, store, 30.0, "category", 2, len(cat.entries))
    print(f"index: {s['pairs']} webs in {s['wall_s']:.0f} s (load {os.getloadavg()[0]:.1f}), "
          f"store {s['store_bytes'] / 1e6:.0f} MB")
    return corpus, store


def previous_revision() -> str:
    """Where this branch left ``main`` (``git merge-base HEAD main``): the code before this work,
    with this checkout's dependencies (``main`` itself may have moved on to others)."""
    return subprocess.run(["git", "-C", str(REPO), "merge-base", "HEAD", "main"], capture_output=True, text=True,
                          check=True).stdout.strip()


def base_code(work: Path, rev: str | None = None) -> Path:
    """A PYTHONPATH entry whose ``motionweb.{store,tasks,flows,configs}`` are revision ``rev``
    (default :func:`previous_revision`)."""
    sha = subprocess.run(["git", "-C", str(REPO), "rev-parse", rev or previous_revision()], capture_output=True,
                         text=True, check=True).stdout.strip()
    src, pkg = work / f"code-{sha[:10]}", work / f"pkg-{sha[:10]}"
    if not src.is_dir():
        src.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(REPO), "archive", sha], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    (pkg / "motionweb").mkdir(parents=True, exist_ok=True)
    for d in ("store", "tasks", "flows", "configs"):
        link = pkg / "motionweb" / d
        if not link.exists():
            link.symlink_to(src / d)
    return pkg


def within(seconds: float, call: Callable[[], object]) -> object:
    """``call()``'s result (its exception raised here), or TimeoutError after ``seconds``: the
    socket's own timeout does not end a request the service is still working on (a search on
    the 1e6 store ran 24 min past a 1,200 s one). The call goes on in its thread until the
    service is stopped."""
    box: list = []

    def run() -> None:
        try:
            box.append((True, call()))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box.append((False, exc))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(max(0.0, seconds))
    if not box:
        raise TimeoutError(f"no answer within {seconds:.0f} s")
    ok, value = box[0]
    if not ok:
        raise value
    return value


def measure(cfg_path: Path, queries: list[dict], env: dict, timeout: float) -> dict:
    """Start the service on ``cfg_path`` with ``env`` and measure it (see the module docstring)."""
    exe = Path(sys.executable).parent / "motionweb"
    out: dict = {"load": os.getloadavg()[0]}
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(exe), "app", str(cfg_path), "--port", "0", "--no-record"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True)
    mem = PeakRSS(root=psutil.Process(proc.pid))
    try:
        with mem:
            line = proc.stdout.readline()
            if "motionweb app:" not in line:
                raise RuntimeError(f"the service did not start: {line}{proc.stdout.read()}")
            url = line.split("motionweb app:")[1].split()[0].rstrip("/")
            out["listening_s"] = time.perf_counter() - t0
            api = Api(url)
            api.conn.timeout = timeout
            try:
                within(t0 + timeout - time.perf_counter(), lambda: api.json("POST", "/api/search", queries[0]))
                out["first_search_s"] = time.perf_counter() - t0
                deadline = t0 + timeout
                while time.perf_counter() < deadline:
                    s = api.json("GET", "/api/status")
                    if s.get("warm") and s.get("worker", {}).get("standby", True):
                        out["warm_s"] = time.perf_counter() - t0
                        break
                    time.sleep(0.25)
                else:
                    out["error"] = f"not warm after {timeout:.0f} s"
                    return out
            except (TimeoutError, OSError) as exc:
                out["error"] = f"no answer within {timeout:.0f} s ({type(exc).__name__})"
                return out
            first = []
            for i, q in enumerate(queries):  # each query once: the webs it reaches read (or their graphs' files), its scope's ε
                t = time.perf_counter()
                api.json("POST", "/api/search", q)
                first.append(time.perf_counter() - t)
                if first[-1] >= 1.0:  # a long run is readable while it goes (the row comes at the end)
                    print(f"  first-time query {i} ({q['clip']}): {first[-1]:.1f} s", file=sys.stderr, flush=True)
            out["first_median_ms"], out["first_p99_ms"] = pct(first[1:], 50), pct(first[1:], 99)
            times = []
            for q in queries:
                t = time.perf_counter()
                api.json("POST", "/api/search", q)
                times.append(time.perf_counter() - t)
            out["median_ms"], out["p90_ms"], out["p99_ms"] = pct(times, 50), pct(times, 90), pct(times, 99)
            out["max_ms"] = max(times) * 1000
            out["cache"] = api.json("GET", "/api/status").get("cache")
            try:  # resident memory now: the service, then its search workers (primary, standby)
                root = psutil.Process(proc.pid)
                out["rss_gb"] = [root.memory_info().rss / 1e9] + [c.memory_info().rss / 1e9 for c in root.children(recursive=True)]
            except psutil.Error:
                pass
    finally:
        out["peak_gb"] = mem.peak / 1e9  # also when it was not ready in time
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return out


def row(name: str, r: dict) -> str:
    def f(key: str, fmt: str) -> str:
        return format(r[key], fmt) if key in r else "-"

    cache = r.get("cache") or {}
    files = cache.get("graph_files") or {}
    extra = (f"  cache {cache['bytes'] / 2**20:.0f}/{cache['max_bytes'] / 2**20:.0f} MiB, {cache['entries']} entries, "
             f"{cache['webs_read']} webs read" + (f", graph files {files['hits']} read {files['writes']} written"
                                                  if files else "")) if cache else ""
    return (f"{name:>8} {f('load', '5.1f')} {f('listening_s', '9.1f')} {f('first_search_s', '9.1f')} "
            f"{f('warm_s', '8.1f')} {f('first_median_ms', '8.1f')} {f('first_p99_ms', '8.1f')} "
            f"{f('median_ms', '8.1f')} {f('p90_ms', '8.1f')} {f('p99_ms', '8.1f')} {f('max_ms', '8.1f')} "
            f"{f('peak_gb', '7.2f')}{extra}{'  ' + r['error'] if 'error' in r else ''}"
            + (f"  RSS GB now: service {r['rss_gb'][0]:.2f}, children {', '.join(f'{x:.2f}' for x in r['rss_gb'][1:])}"
               if r.get("rss_gb") else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=60, help="demo clips per category (60: ~127k frames)")
    ap.add_argument("--store", help="an indexed store to serve instead of the grown demo")
    ap.add_argument("--corpus", help="the corpus of --store")
    ap.add_argument("--keep", help="work folder (corpus, store, the base code), reused when present")
    ap.add_argument("--base", default=None, help="the previous revision measured in the same run "
                                                 "(default: where this branch left main)")
    ap.add_argument("--queries", type=int, default=40)
    ap.add_argument("--only-this", action="store_true", help="measure this checkout only (no previous code)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds a code may take to be ready")
    ap.add_argument("--cache-mb", type=float, default=None,
                    help="app.cache_mb of the service (each search worker's bound; default: the config's default)")
    ap.add_argument("--no-restart", action="store_true", help="do not measure a restart on the kept graph files")
    ap.add_argument("--graph-files-gb", type=float, default=None,
                    help="app.graph_files_gb of the service (its file cache of packed graphs; default: the config's)")
    args = ap.parse_args()

    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-app-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.store:
        corpus, store = Path(args.corpus or "."), Path(args.store)
    else:
        corpus, store = build_store(work, args.variants)
    gen = load_generation(MotionStore(str(store), read_only=True))
    if gen is None:
        raise CorpusError(f"{store} was never indexed")
    cfg_path = work / "app-scale.yaml"
    cfg = {"corpus": {"path": str(corpus), "length_unit": "m"}, "store": {"path": str(store)},
           "output": str(work / "out")}
    app = {"cache_mb": args.cache_mb, "graph_files_gb": args.graph_files_gb}
    if any(v is not None for v in app.values()):
        cfg["app"] = {k: v for k, v in app.items() if v is not None}
    cfg_path.write_text(yaml.safe_dump(cfg))
    queries = random_queries(gen, args.queries, np.random.default_rng(3))
    frames = sum(c["frames"] for c in gen.clips)
    print(f"store {store}: {len(gen.clips)} clips, {frames} frames (native rates), {len(gen.webs)} webs; "
          f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f} (shared machine: times are upper bounds)")
    base = args.base or previous_revision()[:10]
    codes = {} if args.only_this else {base[:10]: base_code(work, base)}
    codes["this"] = None
    if not args.no_restart:
        codes["restart"] = None  # this code again, on the graph files the run before wrote
    print(f"{'code':>8} {'load':>5} {'listen s':>9} {'1st srch s':>9} {'warm s':>8} {'1: med':>8} {'1: p99':>8} "
          f"{'med ms':>8} {'p90 ms':>8} {'p99 ms':>8} {'max ms':>8} {'peak GB':>7}")
    for name, pkg in codes.items():
        files = work / "graph-files"  # the service's file cache of graphs: empty for each code but "restart"
        if name != "restart":
            shutil.rmtree(files, ignore_errors=True)
        env = {**os.environ, "MOTIONWEB_APP_DIR": str(work / f"discovery-{name}"), "MOTIONWEB_CACHE_DIR": str(files)}
        env.pop("PYTHONPATH", None)
        if pkg is not None:
            env["PYTHONPATH"] = str(pkg)
        print(row(name, measure(cfg_path, queries, env, args.timeout)), flush=True)
    print("1: med / 1: p99: each query's first time (the first excepted: it opens the service); med, p90, p99, "
          "max: the queries asked again. restart: a new service on the graph files the run before kept.")
    print("targets: open (first search, warm) <= 10 s; warm median <= 100 ms (381k frames), p99 <= 500 ms; "
          f"service memory <= 2 GB. load at the end {os.getloadavg()[0]:.1f}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
