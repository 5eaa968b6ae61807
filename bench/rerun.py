"""Benchmark: a nightly ``motionweb index`` over a large store with nothing changed, this checkout
against a previous revision in the same run (issue 25: the run's serial steps).

A rerun with nothing changed computes nothing but still scans the corpus, verifies every web and
feature object it reuses (each read whole and checked against its checksum), builds the
generation and compares it with the current one. On the 381k-frame demo store (146,610 webs) its
planning step verified the webs one by one through zarr, ~1.5 ms each. This runs
``motionweb index CONFIG --no-progress`` (by category at ``--rate`` Hz: 30, the config
bench/app_scale.py and bench/corpus.py index with, or 60, bench/scale.py's; a local cluster of 2
workers) on ``--store`` / ``--corpus``: ``--runs`` times with the previous revision ``--base``
(``git archive`` of it put first on PYTHONPATH, as in bench/app_scale.py), then ``--runs`` times
with this checkout, and prints each run's wall time and
the peak RSS of its process tree, with a floor measured in the same run: reading the webs' files
once (a verification reads them all, then decompresses and hashes them).
This checkout's last rerun must commit nothing (checked); the first run of a code whose web
records differ from the current manifest's (the shard each web is in) commits one generation.

    .venv/bin/python -m bench.rerun --store DIR --corpus DIR [--base REV] [--keep DIR] [--rate 30]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import yaml
from motionweb.store.generations import load_generation
from motionweb.store.zarr_store import MotionStore

from bench.app_scale import base_code
from bench.corpus import CorpusError, PeakRSS, rates_for


def disk_read_s(store: Path) -> tuple[int, float]:
    """(bytes, seconds) of reading every file under ``webs/`` once (the OS's page cache as the
    runs find it: a floor for a verification that reads them all)."""
    total, t = 0, time.perf_counter()
    for root, _, files in os.walk(store / "webs"):
        for f in files:
            with open(os.path.join(root, f), "rb") as fh:
                while chunk := fh.read(1 << 22):
                    total += len(chunk)
    return total, time.perf_counter() - t


def rerun(cfg_path: Path, env: dict) -> tuple[float, float]:
    """(wall seconds, peak GB of the process tree) of one ``motionweb index`` run."""
    exe = Path(sys.executable).parent / "motionweb"
    t = time.perf_counter()
    proc = subprocess.Popen([str(exe), "index", str(cfg_path), "--no-progress"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)
    with PeakRSS(root=psutil.Process(proc.pid)) as mem:
        out, _ = proc.communicate()
    if proc.returncode != 0:
        raise CorpusError(f"motionweb index exited {proc.returncode}: {out[-2000:]}")
    return time.perf_counter() - t, mem.peak / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", required=True, help="an indexed store (e.g. bench/app_scale.py's store-demo-180)")
    ap.add_argument("--corpus", required=True, help="the corpus it indexes")
    ap.add_argument("--base", default="d6fdd3e", help="the previous revision measured in the same run")
    ap.add_argument("--keep", help="work folder (the base code), reused when present")
    ap.add_argument("--runs", type=int, default=2, help="reruns per code")
    ap.add_argument("--rate", type=float, default=30.0,
                    help="the store's working rate (30: bench/app_scale.py's stores; 60: bench/scale.py's)")
    args = ap.parse_args()
    store, work = Path(args.store), Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-rerun-"))
    work.mkdir(parents=True, exist_ok=True)
    before = load_generation(MotionStore(str(store), read_only=True))
    if before is None:
        raise CorpusError(f"{store} was never indexed")
    cfg_path = work / "rerun.yaml"
    cfg_path.write_text(yaml.safe_dump({
        "corpus": {"path": str(Path(args.corpus).resolve()), "length_unit": "m"},
        "features": {"rates": rates_for(args.rate)}, "store": {"path": str(store.resolve())},
        "dask": {"n_workers": 2, "processes": True}, "index": {"chunk_by": "category"},
        "output": str(work / "out")}))
    nbytes, read_s = disk_read_s(store)
    print(f"store {store}: {len(before.clips)} clips, {len(before.webs)} webs, {nbytes / 1e6:.0f} MB of webs read "
          f"in {read_s:.1f} s (the floor of a verification); {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    print(f"{'code':>10} {'run':>3} {'wall s':>7} {'peak GB':>7}  committed")
    codes = {args.base[:10]: base_code(work, args.base), "this": None}
    for name, pkg in codes.items():
        env = {**os.environ, "PREFECT_LOGGING_LEVEL": "WARNING"}
        env.pop("PYTHONPATH", None)
        if pkg is not None:
            env["PYTHONPATH"] = str(pkg)
        for i in range(args.runs):
            cur = load_generation(MotionStore(str(store), read_only=True)).id
            wall, peak = rerun(cfg_path, env)
            gen = load_generation(MotionStore(str(store), read_only=True)).id
            print(f"{name:>10} {i + 1:>3} {wall:7.1f} {peak:7.2f}  {'yes: ' + gen if gen != cur else 'no'}", flush=True)
    if gen != cur:
        raise CorpusError(f"this code's last rerun with nothing changed committed generation {gen} (was {cur}): "
                          "the store changed under the benchmark, or a rerun is not idempotent")
    print("committed: a run commits a generation when its records differ from the current one's (a "
          "code that records each web's shard over a manifest without them, or the reverse), once")
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
