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
``--cpu`` given (``NUMBA_CPU_NAME``, each with a fresh ``NUMBA_CACHE_DIR``), and once more with
OpenBLAS told another core type (``OPENBLAS_CORETYPE``, each of ``--blas``). Printed: how many
values differ from this CPU's, and by how much at most. Exits 1 unless each variant computed
the sizes asked for.

    .venv/bin/python -m bench.cpu_bytes [--frames 300] [--cpu haswell sandybridge] [--blas Haswell Sandybridge]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

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


def run(name: str, env: dict[str, str], frames: int, work: Path) -> dict[str, np.ndarray]:
    out = work / f"{name}.npz"
    r = subprocess.run([sys.executable, "-c", CHILD, str(frames), str(out)], env=env, capture_output=True,
                       text=True, check=False)
    if r.returncode != 0:
        raise SystemExit(f"{name}: {r.stderr[-1500:]}")
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
    args = ap.parse_args()
    if args.frames < 21:
        raise SystemExit("--frames must be at least 21")
    work = Path(tempfile.mkdtemp(prefix="motionweb-bench-cpu-bytes-"))
    base_env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    host = run("host", {**base_env, "NUMBA_CACHE_DIR": str(work / "cache-host")}, args.frames, work)
    print(f"one pair of {args.frames} x {args.frames - 20} frames, P = 110; compared with this CPU's values "
          f"(numba for {os.environ.get('NUMBA_CPU_NAME', 'the host')}, "
          f"OpenBLAS core type {os.environ.get('OPENBLAS_CORETYPE', 'detected')})")
    variants = [(f"numba for {c}", {**base_env, "NUMBA_CPU_NAME": c, "NUMBA_CACHE_DIR": str(work / f"cache-{c}")})
                for c in args.cpu]
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


if __name__ == "__main__":
    main()
