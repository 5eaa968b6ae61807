"""Benchmark: each command's CLI wall time next to the time its work takes in-process (issue 23).

On the demo corpus (``store.demo.corpus.write_demo_corpus`` with the packaged demo config, indexed
once by ``motionweb index`` before anything is timed), one table, one row per command:

* ``CLI cold``: a new ``motionweb`` process, no Prefect server configured (``PREFECT_API_URL``
  removed from the environment, nothing answering at 127.0.0.1:4200, checked first) and no
  ``motionweb app`` running (``MOTIONWEB_APP_DIR`` an empty folder of the run's own); the first
  run and the median of the repeats (numba's and Python's on-disk caches warm by then);
* ``work``: the same work called in-process in this process through the plain functions the
  flows call, median of the repeats after one warm-up call (imports and compiled kernels
  loaded): what a user waits for at least;
* ``overhead``: CLI (repeat median) minus work.

A command that exits non-zero stops the benchmark with its output (exit 1).

    .venv/bin/python -m bench.cli [--keep DIR] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")

MOTIONWEB = [sys.executable, "-c", "from motionweb.flows.cli import main; main()"]
CLIP = "jump/jump_00.bvh"


def cold_env(app_dir: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API_URL")}
    env["MOTIONWEB_APP_DIR"] = str(app_dir)
    return env


def server_answering(url: str = "http://127.0.0.1:4200/api") -> bool:
    try:
        with urllib.request.urlopen(url + "/health", timeout=1.0) as r:
            return r.status == 200
    except OSError:
        return False


def run_cli(args: list[str], env: dict[str, str], cwd: Path) -> float:
    t = time.perf_counter()
    proc = subprocess.run([*MOTIONWEB, *args], check=False, env=env, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        sys.exit(f"FAILED (exit {proc.returncode}): motionweb {' '.join(args)}\n{proc.stdout}\n{proc.stderr}")
    return wall


def setup(work: Path, env: dict[str, str]) -> Path:
    """The demo corpus and config in ``work`` (paths as `motionweb demo` writes them), indexed once."""
    import yaml
    from motionweb.flows.config import load_config, packaged_config
    from motionweb.store.demo.corpus import write_demo_corpus

    cfg_path = work / "config.yaml"
    if not cfg_path.exists():
        base = load_config(packaged_config("demo.yaml"))
        data = base.model_dump(mode="json")
        data["corpus"]["path"], data["store"]["path"], data["output"] = "corpus", "store", "out"
        cfg_path.write_text(yaml.safe_dump(data, sort_keys=False))
        paths = write_demo_corpus(work / "corpus", seed=base.demo.seed,
                                  variants_per_category=base.demo.variants_per_category, fps=base.demo.fps,
                                  variants=base.demo.variants)
        from motionweb.store.catalog import scan_corpus

        from bench.corpus import check_corpus  # stops unless every clip written loads, in its category

        check_corpus(work / "corpus", scan_corpus(work / "corpus", base.corpus),
                     {p.relative_to(work / "corpus").as_posix(): p.parent.name for p in paths}, 0)
    print(f"indexing {work} once (not timed) ...", flush=True)
    run_cli(["index", str(cfg_path), "--no-progress"], env, work)
    return cfg_path


# ------------------------------------------------------------------- the work, in-process
def work_functions(cfg_path: Path, work: Path) -> dict[str, Callable[[], object]]:
    """Each command's work through the plain functions its flow calls (the same arguments as
    the CLI rows below)."""
    from motionweb.flows.config import load_config

    cfg = load_config(cfg_path)
    clip = str(Path(cfg.corpus.path) / CLIP)
    inproc = work / "inproc"

    def retime() -> object:
        import motionweb.flows.retime as rt

        if hasattr(rt, "run_retime"):
            return rt.run_retime(clip, cfg, str(inproc / "retimed.bvh"), duration=2.5)
        import json as _json

        import numpy as np  # noqa: F401
        from motionweb.store.bvh import write_bvh
        from motionweb.tasks.retime import prepare, report, retime_plan

        motion, humanoid = rt.load_clip(clip, cfg)
        plan = prepare(motion, cfg.retime, up_axis=cfg.corpus.up_axis, gravity=None, mass={}, humanoid=humanoid,
                       contact_intervals=cfg.retime.contact_intervals.get(motion.name) or None, weight_factors={})
        retimed, res = retime_plan(plan, 2.5, [], cfg.retime)
        out = inproc / "retimed.bvh"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_bvh(retimed, out)
        rep = report(plan, res)
        out.with_suffix(".json").write_text(_json.dumps(rep, indent=1))
        return rep

    def warp() -> object:
        from motionweb.flows.warp import WarpRequest, run_warp

        return run_warp(cfg, WarpRequest(input=clip, out=str(inproc / "warped.bvh"), duration=2.5))

    def search() -> object:
        from motionweb.flows.query import QueryRequest, prepare_query, search_task, write_outputs

        request = QueryRequest(clip="walk_00", start=1.0, end=2.5, out=str(inproc / "search"))
        t0 = time.perf_counter()
        q = prepare_query(cfg, request)
        graph, eps = search_task.fn(q, cfg, request)
        return write_outputs(cfg, request, q, graph, eps, Path(request.out), None, t0)

    def index() -> object:
        import motionweb.flows.index as idx

        if hasattr(idx, "plan_index"):
            return idx.plan_index(cfg)
        # the original code: the flow's catalog and plan tasks as plain functions
        from motionweb.store.generations import check_current, load_generation
        from motionweb.store.zarr_store import MotionStore

        idx.get_run_logger = lambda: logging.getLogger("bench")
        store = MotionStore(cfg.store.path)
        prev = load_generation(store, check_current(store))
        cat = idx.catalog_task.fn(cfg)
        return idx.plan_task.fn(idx.plan_chunks(cat.entries, cfg.index.chunk_by), cfg, prev)

    def catalog() -> object:
        from motionweb.store.catalog import scan_corpus

        return scan_corpus(cfg.corpus.path, cfg.corpus)

    def verify() -> object:
        from motionweb.store.generations import check_current, load_generation, verify_generation
        from motionweb.store.zarr_store import MotionStore

        store = MotionStore(cfg.store.path)
        return verify_generation(store, load_generation(store, check_current(store)))

    return {"retime": retime, "warp": warp, "search": search, "index": index, "catalog": catalog, "verify": verify}


def cli_rows(cfg_path: Path, work: Path) -> dict[str, tuple[str, list[str]]]:
    clip = str(work / "corpus" / CLIP)
    c = str(cfg_path)
    return {
        "retime": ("retime jump_00.bvh --duration 2.5", ["retime", clip, "--duration", "2.5", "--out",
                                                         str(work / "cli" / "retimed.bvh"), "--config", c]),
        "warp": ("warp jump_00.bvh --duration 2.5", ["warp", clip, "--duration", "2.5", "--out",
                                                     str(work / "cli" / "warped.bvh"), "--config", c]),
        "search": ("search walk_00 1-2.5 s (no app)", ["search", c, "--clip", "walk_00", "--start", "1.0", "--end",
                                                       "2.5", "--out", str(work / "cli" / "search")]),
        "index": ("index, nothing changed", ["index", c, "--no-progress"]),
        "catalog": ("catalog", ["catalog", str(work / "corpus"), "--config", c]),
        "verify": ("verify", ["verify", c]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, help="Work folder kept between runs (default: a temporary one).")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    if server_answering():
        sys.exit("a Prefect server answers at 127.0.0.1:4200: stop it first (this measures the cold case)")
    work = args.keep.resolve() if args.keep else Path(tempfile.mkdtemp(prefix="bench-cli-"))
    work.mkdir(parents=True, exist_ok=True)
    app_dir = Path(tempfile.mkdtemp(prefix="bench-cli-app-"))
    env = cold_env(app_dir)
    try:
        cfg_path = setup(work, env)
        works = work_functions(cfg_path, work)
        rows = []
        for name, (label, argv) in cli_rows(cfg_path, work).items():
            walls = [run_cli(argv, env, work) for _ in range(args.repeat + 1)]
            fn = works[name]
            fn()  # warm-up: imports, compiled kernels
            times = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t)
            first, rep, w = walls[0], statistics.median(walls[1:]), statistics.median(times)
            rows.append((label, first, rep, w, rep - w))
            print(f"  {label}: CLI {first:.2f} s first, {rep:.2f} s repeat; work {w:.3f} s", flush=True)
    finally:
        shutil.rmtree(app_dir, ignore_errors=True)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    head = ("command", "CLI cold, first (s)", "CLI cold, repeat (s)", "work in-process (s)", "overhead (s)")
    body = [(r[0], f"{r[1]:.2f}", f"{r[2]:.2f}", f"{r[3]:.3f}", f"{r[4]:.2f}") for r in rows]
    print(f"\n{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; no Prefect server, no app; "
          f"median of {args.repeat}")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for r in body:
        print("| " + " | ".join(r) + " |")
    print(json.dumps({r[0]: {"cli_first_s": r[1], "cli_s": r[2], "work_s": r[3]} for r in rows}))


if __name__ == "__main__":
    main()
