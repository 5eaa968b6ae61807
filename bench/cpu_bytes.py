"""Benchmark (a check, not a timing): do the index's distance values depend on the CPU that
computes them? (the brief: "the same inputs give the same bytes whatever the worker kind").

A Dask cluster may mix machines. numba compiles the kernels for the CPU it runs on (``fastmath``
lets LLVM reorder sums and fuse multiply-adds to suit it) and OpenBLAS picks its GEMM kernel by
CPU, so the same features could give other bits on another machine. This computes, in child
processes, for one random pair of clips (``--frames`` each, P = 110 points, float32 operands as
the index uses): the whole grid by the GEMM path (three GEMMs and the fused ``_combine``,
``tasks.distance.distance_grid_prepared``: the coarse level of webs before ``store.keys.WEB_VALUES``
2, and ``keep_grids``), the per-cell values (float64, ``tasks.distance.cell_distance``: the fine
levels), and the whole grid cell by cell (``distance_grid_cells``: the coarse level of webs now), once compiled for this CPU and once for each
``--cpu`` given (``NUMBA_CPU_NAME`` and that CPU's ``NUMBA_CPU_FEATURES``, :data:`CPU_FEATURES`,
each with a fresh ``NUMBA_CACHE_DIR``), and once more with
OpenBLAS told another core type (``OPENBLAS_CORETYPE``, each of ``--blas``). Printed: how many
values differ from this CPU's, and by how much at most. Exits 1 unless each variant computed
the sizes asked for.

With ``--store DIR --corpus DIR`` (an indexed store and its corpus, e.g. bench/scale.py's long
takes) it also builds ``--pairs`` webs of a category (``--category``, default the one of most
pairs; the config of the store's current generation) in each variant, as the index workers do
(``tasks.matchweb.build.build_web_operands``), and counts the webs whose arrays differ; with
``--base REV`` the same for that revision's code (``git archive`` of it first on PYTHONPATH).

    .venv/bin/python -m bench.cpu_bytes [--frames 300] [--cpu haswell sandybridge] [--blas Haswell Sandybridge]
        [--store DIR --corpus DIR [--category C] [--pairs 24] [--base REV]]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

#: LLVM target features of the CPUs compared. numba passes the host's own features unless
#: NUMBA_CPU_FEATURES is set, so NUMBA_CPU_NAME alone keeps this machine's AVX-512 and FMA and
#: compares little: each name comes with its CPU's feature set.
CPU_FEATURES = {
    "haswell": ("+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+f16c,+fma,+fsgsbase,+lzcnt,+movbe,+mmx,+pclmul,+popcnt,"
                "+rdrnd,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave,+xsaveopt,-avx512f,-avx512dq,-avx512bw,"
                "-avx512vl,-avx512cd"),
    "sandybridge": ("+64bit,+avx,+cmov,+cx16,+mmx,+pclmul,+popcnt,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave,"
                    "-avx2,-fma,-avx512f,-avx512dq,-avx512bw,-avx512vl,-avx512cd"),
}


def cpu_env(env: dict[str, str], cpu: str, cache: Path) -> dict[str, str]:
    """``env`` with numba compiling for ``cpu`` (its name and its features, :data:`CPU_FEATURES`)
    into a cache of its own."""
    if cpu not in CPU_FEATURES:
        raise SystemExit(f"--cpu {cpu}: no feature set known (known: {', '.join(sorted(CPU_FEATURES))})")
    return {**env, "NUMBA_CPU_NAME": cpu, "NUMBA_CPU_FEATURES": CPU_FEATURES[cpu], "NUMBA_CACHE_DIR": str(cache)}


CHILD = r"""
import sys
import numpy as np
from motionweb.tasks.distance import _cells_kernel, distance_grid_cells, distance_grid_prepared, prepare_pair
n, out = int(sys.argv[1]), sys.argv[2]
rng = np.random.default_rng(0)
fa = rng.normal(size=(n, 110, 3)).astype(np.float32)
fb = rng.normal(size=(n - 20, 110, 3)).astype(np.float32)
w = rng.uniform(0.5, 1.5, 110)
pa, pb = prepare_pair(fa, fb, w)
rows = np.repeat(np.arange(pa.n_frames), pb.n_frames).astype(np.int64)
cols = np.tile(np.arange(pb.n_frames), pa.n_frames).astype(np.int64)
cells = np.empty(len(rows))
_cells_kernel(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, rows, cols, cells)
np.savez(out, grid=distance_grid_prepared(pa, pb), cells=cells, grid_cells=distance_grid_cells(pa, pb))
"""


WEBS = r"""
import hashlib, json, random, sys
from pathlib import Path
import numpy as np
from bench.index_scale import store_category
from motionweb.flows.index import Chunk, plan_pairs, working_rate
from motionweb.flows.runtime.workers import clip_operands, pin_blas_threads
from motionweb.store.keys import feature_digest, web_digest
from motionweb.tasks.matchweb.build import build_web_operands
store, corpus, category, n, out = sys.argv[1], Path(sys.argv[2]), sys.argv[3] or None, int(sys.argv[4]), sys.argv[5]
cfg, category, entries, _ = store_category(Path(store), corpus, category)
pin_blas_threads()
jobs = plan_pairs(Chunk(category, tuple(entries)), web_digest(cfg), working_rate(cfg))
hashes = []
for j in random.Random(1).sample(jobs, min(n, len(jobs))):
    oa = clip_operands(store, j.a.sha256, feature_digest(cfg))
    ob = oa if j.self_pair else clip_operands(store, j.b.sha256, feature_digest(cfg))
    arrays = build_web_operands(oa, ob, cfg.matchweb, j.self_pair).to_arrays()
    h = hashlib.sha256()
    for k in sorted(arrays):
        h.update(k.encode() + np.ascontiguousarray(arrays[k]).tobytes())
    hashes.append(h.hexdigest())
json.dump({"category": category, "webs": hashes}, open(out, "w"))
"""


def child(code: str, args: list[str], env: dict[str, str], name: str) -> None:
    root = str(Path(__file__).resolve().parent.parent)  # bench/ is importable from the checkout
    env = {**env, "PYTHONPATH": os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)}
    r = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise SystemExit(f"{name}: {r.stderr[-1500:]}")


def webs(name: str, env: dict[str, str], args: argparse.Namespace, work: Path) -> dict:
    out = work / f"{name}-webs.json"
    child(WEBS, [args.store, args.corpus, args.category or "", str(args.pairs), str(out)], env, name)
    got = json.loads(out.read_text())
    if len(got["webs"]) != args.pairs:
        raise SystemExit(f"{name}: built {len(got['webs'])} webs of {got['category']}, {args.pairs} asked for")
    return got


def run(name: str, env: dict[str, str], frames: int, work: Path) -> dict[str, np.ndarray]:
    out = work / f"{name}.npz"
    child(CHILD, [str(frames), str(out)], env, name)
    got = dict(np.load(out))
    if (got["grid"].shape != (frames, frames - 20) or got["grid_cells"].shape != got["grid"].shape
            or got["cells"].shape != (frames * (frames - 20),)):
        raise SystemExit(f"{name}: computed {got['grid'].shape}, {got['grid_cells'].shape} and {got['cells'].shape}, "
                         "not the sizes asked for")
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--cpu", nargs="*", default=["haswell", "sandybridge"], help="NUMBA_CPU_NAME values")
    ap.add_argument("--blas", nargs="*", default=["Haswell", "Sandybridge"], help="OPENBLAS_CORETYPE values")
    ap.add_argument("--store", help="an indexed store: also compare webs of one of its categories")
    ap.add_argument("--corpus", help="with --store: the corpus it indexed")
    ap.add_argument("--category", help="with --store: the category (default: the one of most pairs)")
    ap.add_argument("--pairs", type=int, default=24, help="with --store: webs built per variant")
    ap.add_argument("--base", help="with --store: a previous revision whose webs are compared likewise")
    args = ap.parse_args()
    if args.store and not args.corpus:
        raise SystemExit("--store needs --corpus DIR")
    if args.frames < 21:
        raise SystemExit("--frames must be at least 21")
    work = Path(tempfile.mkdtemp(prefix="motionweb-bench-cpu-bytes-"))
    try:
        compare(args, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def compare(args: argparse.Namespace, work: Path) -> None:
    base_env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    host = run("host", {**base_env, "NUMBA_CACHE_DIR": str(work / "cache-host")}, args.frames, work)
    print(f"one pair of {args.frames} x {args.frames - 20} frames, P = 110; compared with this CPU's values "
          f"(numba for {os.environ.get('NUMBA_CPU_NAME', 'the host')}, "
          f"OpenBLAS core type {os.environ.get('OPENBLAS_CORETYPE', 'detected')})")
    variants = [(f"numba for {c}", cpu_env(base_env, c, work / f"cache-{c}")) for c in args.cpu]
    variants += [(f"OpenBLAS as {b}", {**base_env, "OPENBLAS_CORETYPE": b, "NUMBA_CACHE_DIR": str(work / "cache-host")})
                 for b in args.blas]
    print(f"{'variant':24s} {'GEMM grid (float32)':>30s} {'per-cell values (float64)':>30s} "
          f"{'grid by cells (float32)':>30s}")
    for name, env in variants:
        got = run(name.replace(" ", "-"), env, args.frames, work)
        figures = []
        for key in ("grid", "cells", "grid_cells"):
            d = got[key] != host[key]
            figures.append(f"{int(d.sum())} of {d.size} differ, max {float(np.abs(got[key] - host[key]).max()):.1e}")
        print(f"{name:24s} " + " ".join(f"{f:>30s}" for f in figures))
    if args.store:
        from bench.app_scale import base_code

        codes = [(args.base[:10], base_code(work, args.base))] if args.base else []
        print(f"webs of a category of {args.store} ({args.pairs} random pairs, built as the index workers build "
              f"them), compared with this CPU's, per code:")
        for code, pkg in [*codes, ("this", None)]:
            path = {"PYTHONPATH": str(pkg)} if pkg else {}
            ours = webs(f"{code}-host", {**base_env, **path, "NUMBA_CACHE_DIR": str(work / "cache-host") + f"-{code}"},
                        args, work)
            for name, env in variants:
                env = {**env, **path, "NUMBA_CACHE_DIR": env["NUMBA_CACHE_DIR"] + f"-{code}"}
                got = webs(f"{code}-{name.replace(' ', '-')}", env, args, work)
                n = sum(a != b for a, b in zip(ours["webs"], got["webs"], strict=True))
                print(f"  {code:>10s}  {ours['category']}  {name:24s} {n} of {args.pairs} webs differ")


if __name__ == "__main__":
    main()
