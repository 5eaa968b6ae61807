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
* ``work, new process``: the same work function run once in a new Python process (``bench.cli
  --only NAME``): Python's start, the imports and compiled-kernel loads the work needs, and the
  work; the floor any cold command pays;
* ``CLI, Prefect server running``: the same CLI runs with a Prefect server of the run's own
  configured (``PREFECT_API_URL``): each run is recorded as a flow run after its answer (the
  benchmark checks the server holds them all);
* ``overhead``: CLI (repeat median) minus work; ``over the floor``: CLI minus the new-process work,
  what the CLI itself adds (its option parsing, config, plan, record check, guard and watchdog).

A command that exits non-zero stops the benchmark with its output (exit 1).

    .venv/bin/python -m bench.cli [--keep DIR] [--repeat 3]
"""

from __future__ import annotations

import argparse
import contextlib
import json
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

MOTIONWEB = [sys.executable, "-c", "from motionweb.flows.commands.cli import main; main()"]
CLIP = "jump/jump_00.bvh"
#: the query of the space synthesize and blend use (KG04 §4: a walk's final root position)
SPACE_QUERY = ["--clip", "walk_00", "--start", "1.0", "--end", "2.5", "--param", "final_root", "--quantile", "0.8",
               "--samples", "200"]


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
    space_file = work / "space.txt"
    if not space_file.exists():
        print("a motion space for synthesize and blend (not timed) ...", flush=True)
        proc = subprocess.run([*MOTIONWEB, "parameterize", str(cfg_path), *SPACE_QUERY], check=False, env=env,
                              cwd=work, capture_output=True, text=True)
        if proc.returncode != 0 or not proc.stdout.startswith("space "):
            sys.exit(f"FAILED: motionweb parameterize\n{proc.stdout}\n{proc.stderr}")
        space_file.write_text(proc.stdout.split()[1].rstrip(":"))
    return cfg_path


def space_args(cfg_path: Path, work: Path) -> tuple[str, list[float], dict[str, float]]:
    """The bench's space: its id, a target (its first example's parameter) and equal weights of
    its first two examples."""
    from motionweb.flows.config import load_config
    from motionweb.flows.space import space_info

    sid = (work / "space.txt").read_text().strip()
    _, info, arrays = space_info(load_config(cfg_path), sid)
    names = info["names"]
    if len(names) < 2:
        sys.exit(f"bench: space {sid} has {len(names)} examples; blend needs two")
    target = [round(float(v), 4) for v in arrays["example_params"][0]] if "example_params" in arrays else None
    if target is None:
        sys.exit(f"bench: space {sid} records no example parameters ({sorted(arrays)})")
    return sid, target, {names[0]: 0.5, names[1]: 0.5}


# ------------------------------------------------------------------- the work, in-process
def work_functions(cfg_path: Path, work: Path) -> dict[str, Callable[[], object]]:
    """Each command's work through the plain functions its flow calls (the same arguments as
    the CLI rows below)."""
    from motionweb.flows.config import load_config

    cfg = load_config(cfg_path)
    clip = str(Path(cfg.corpus.path) / CLIP)
    inproc = work / "inproc"

    def retime() -> object:
        from motionweb.flows.retime import retime_flow

        return retime_flow.fn(clip, cfg, str(inproc / "retimed.bvh"), duration=2.5)

    def warp() -> object:
        from motionweb.flows.commands.requests import WarpRequest
        from motionweb.flows.warp import run_warp

        return run_warp(cfg, WarpRequest(input=clip, out=str(inproc / "warped.bvh"), duration=2.5))

    def search() -> object:
        from motionweb.flows.commands.requests import QueryRequest
        from motionweb.flows.query import prepare_query, search_task, write_outputs

        request = QueryRequest(clip="walk_00", start=1.0, end=2.5, out=str(inproc / "search"))
        t0 = time.perf_counter()
        q = prepare_query(cfg, request)
        graph, eps = search_task.fn(q, cfg, request)
        return write_outputs(cfg, request, q, graph, eps, Path(request.out), None, t0)

    def index() -> object:
        from motionweb.flows.index import unchanged_summary

        summary = unchanged_summary(cfg)
        if summary is None:
            raise SystemExit("bench: the index has work to do; this row measures an index with nothing changed")
        return summary

    def catalog() -> object:
        from motionweb.store.catalog import scan_corpus

        return scan_corpus(cfg.corpus.path, cfg.corpus)

    def verify() -> object:
        from motionweb.store.generations import check_current, load_generation, verify_generation
        from motionweb.store.zarr_store import MotionStore

        store = MotionStore(cfg.store.path)
        return verify_generation(store, load_generation(store, check_current(store)))

    def synthesize() -> object:
        import numpy as np
        from motionweb.flows.space import load_space
        from motionweb.store.formats import write_motion

        sid, target, _ = space_args(cfg_path, work)
        motion, _ = load_space(cfg, sid).synthesize(np.array(target))
        return write_motion(motion, inproc / "synth.bvh")

    def blend() -> object:
        from motionweb.flows.space import load_space
        from motionweb.store.formats import write_motion

        sid, _, weights = space_args(cfg_path, work)
        return write_motion(load_space(cfg, sid).blend(weights), inproc / "blend.bvh")

    def preview() -> object:
        from motionweb.flows.preview import render_gif
        from motionweb.store.formats import read_motion

        return render_gif(read_motion(clip), inproc / "preview.gif", max_frames=60, fps=15.0, up="y")

    return {"retime": retime, "warp": warp, "search": search, "index": index, "catalog": catalog, "verify": verify,
            "synthesize": synthesize, "blend": blend, "preview": preview}


def cli_rows(cfg_path: Path, work: Path) -> dict[str, tuple[str, list[str]]]:
    clip = str(work / "corpus" / CLIP)
    c = str(cfg_path)
    sid, target, weights = space_args(cfg_path, work)
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
        "synthesize": ("synthesize (no app)", ["synthesize", sid, "--target", ",".join(map(str, target)), "--out",
                                               str(work / "cli" / "synth.bvh"), "--config", c]),
        "blend": ("blend (no app)", ["blend", sid, *[x for k, v in weights.items() for x in ("--weights", f"{k}={v}")],
                                     "--out", str(work / "cli" / "blend.bvh"), "--config", c]),
        "preview": ("preview jump_00.bvh (60 frames)", ["preview", clip, "--out", str(work / "cli" / "p.gif"),
                                                        "--max-frames", "60"]),
    }


@contextlib.contextmanager
def prefect_server():
    """A Prefect API server of this run's own (Prefect's local server process, in a temporary
    ``PREFECT_HOME``): its API URL."""
    home = tempfile.mkdtemp(prefix="bench-cli-prefect-")
    os.environ["PREFECT_HOME"] = home
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()
    server.start()
    try:
        yield server.api_url
    finally:
        server.stop()
        shutil.rmtree(home, ignore_errors=True)


def flow_runs(url: str) -> int:
    """How many flow runs the server at ``url`` holds."""
    req = urllib.request.Request(url + "/flow_runs/count", data=b"{}", headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as r:
        return int(json.loads(r.read()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, help="Work folder kept between runs (default: a temporary one).")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", help=argparse.SUPPRESS)  # one work function, in this new process
    args = ap.parse_args()
    if args.only:
        work_functions(args.keep / "config.yaml", args.keep)[args.only]()
        return
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
            fresh = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "bench.cli", "--keep", str(work), "--only", name], check=True,
                               env=env, capture_output=True)
                fresh.append(time.perf_counter() - t)
            first, rep, w, f = walls[0], statistics.median(walls[1:]), statistics.median(times), statistics.median(fresh)
            rows.append([label, first, rep, w, f, rep - w, rep - f, float("nan")])
            print(f"  {label}: CLI {first:.2f} s first, {rep:.2f} s repeat; work {w:.3f} s, "
                  f"in a new process {f:.2f} s", flush=True)
        with prefect_server() as url:  # the same commands, each run recorded in Prefect after its answer
            served = {**env, "PREFECT_API_URL": url}
            for row, (_, argv) in zip(rows, cli_rows(cfg_path, work).values(), strict=True):
                row[7] = statistics.median(run_cli(argv, served, work) for _ in range(args.repeat))
                print(f"  {row[0]}: CLI with a Prefect server {row[7]:.2f} s", flush=True)
            recorded = flow_runs(url)
        if recorded < len(rows) * args.repeat:
            sys.exit(f"bench: the Prefect server holds {recorded} flow runs, fewer than the "
                     f"{len(rows) * args.repeat} commands run against it")
    finally:
        shutil.rmtree(app_dir, ignore_errors=True)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    head = ("command", "CLI cold, first (s)", "CLI cold, repeat (s)", "work in-process (s)",
            "work, new process (s)", "overhead (s)", "over the floor (s)", "CLI, Prefect server running (s)")
    body = [(r[0], f"{r[1]:.2f}", f"{r[2]:.2f}", f"{r[3]:.3f}", f"{r[4]:.2f}", f"{r[5]:.2f}", f"{r[6]:.2f}",
             f"{r[7]:.2f}") for r in rows]
    print(f"\n{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; no app; cold: no Prefect server; "
          f"last column: a Prefect server running, each run recorded ({recorded} flow runs); median of {args.repeat}")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for r in body:
        print("| " + " | ".join(r) + " |")
    print(json.dumps({r[0]: {"cli_first_s": r[1], "cli_s": r[2], "work_s": r[3], "work_new_process_s": r[4]}
                      for r in rows}))


if __name__ == "__main__":
    main()
