"""Benchmark: the band DP of match webs and registration (KG04 §3.1-3.2). Prints figures; not a test.

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE .venv/bin/python -m bench.band_dp [--frames 1500] [--widths 12 40]

``band_dp`` with slope_k = 3 (the default) runs an unrolled kernel (``_band_dp_run2``); the
baseline, measured in the same run on the same band, is the kernel with the states in loops
(``_band_dp_any``, which ran every slope_k before). Both are timed on a diagonal band of the given
width through a frame-distance grid of two smooth synthetic motions (the kind of values real webs
have: neighbours close, few ties) and through random values, with 2 % blocked and 2 % terminal
cells. The bench checks that both kernels wrote the same costs, lengths and predecessors on every
band cell, and stops with an error otherwise.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from motionweb.tasks.distance import distance_grid
from motionweb.tasks.matchweb.band import _band_dp_any, band_buffers, band_dp

from bench.timing import best_of


def smooth_grid(frames: int, points: int = 20, seed: int = 0) -> np.ndarray:
    """(frames, frames) distances between a smooth motion of ``points`` points and its reverse."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 30, frames)[:, None, None]
    a = np.sin(t * rng.uniform(1, 3, (1, points, 3)) + rng.uniform(0, 6, (1, points, 3))).astype(np.float32)
    return np.asarray(distance_grid(a, a[::-1].copy(), np.full(points, 1.0 / points)), np.float64)


def diagonal_band(frames: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, off) of a band ``width`` cells wide along the diagonal of a frames × frames grid."""
    lo = np.clip(np.arange(frames) - width // 2, 0, None).astype(np.int64)
    hi = np.minimum(frames - 1, lo + width - 1).astype(np.int64)
    off = np.concatenate([[0], np.cumsum(hi - lo + 1)]).astype(np.int64)
    return lo, hi, off


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--widths", type=int, nargs="+", default=[12, 40])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args(argv)
    grid = smooth_grid(args.frames)
    rng = np.random.default_rng(1)
    mrun = 2  # slope_k = 3
    print(f"{'band':>22} {'cells':>8} {'unrolled ns/cell':>17} {'loop kernel ns/cell':>20} {'speed-up':>9}")
    for width in args.widths:
        lo, hi, off = diagonal_band(args.frames, width)
        n = int(off[-1])
        smooth = np.concatenate([grid[i, lo[i]:hi[i] + 1] for i in range(args.frames)])
        for name, vals in (("smooth", smooth), ("random", rng.uniform(0, 1, n))):
            vals = vals.copy()
            vals[rng.integers(0, n, n // 50)] = np.inf
            flags = np.zeros(n, np.uint8)
            flags[rng.integers(0, n, n // 50)] = 2
            init = np.full(n, np.inf)
            init[:width // 2] = vals[:width // 2]
            new, old = band_buffers(n, mrun), band_buffers(n, mrun)
            t_new, _ = best_of(lambda: band_dp(lo, hi, off, vals, init, flags, mrun, *new), args.repeat)  # noqa: B023
            t_old, _ = best_of(lambda: _band_dp_any(lo, hi, off, vals, init, flags, mrun, *old), args.repeat)  # noqa: B023
            if n != (hi - lo + 1).sum() or not all(np.array_equal(a, b) for a, b in zip(new, old, strict=True)):
                sys.exit(f"band_dp bench: the kernels disagree on the {name} band of width {width} ({n} cells)")
            print(f"{name + ', width ' + str(width):>22} {n:>8} {t_new / n * 1e9:>17.1f} {t_old / n * 1e9:>20.1f} "
                  f"{t_old / t_new:>8.2f}×")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
