"""Benchmark: distance grids (design §3) and match webs (design §4). Prints figures; not a test.

    .venv/bin/python bench/grid.py [--frames 2000 4000 8000] [--full-max 4000] [--points 155]

1. cells/s of the GEMM grid vs the slow reference (explicit alignment per pair) and vs a bare
   matmul of the same shapes (the ceiling the closed form can reach);
2. coarse-to-fine ``build_web`` (10 → 20 → 30 Hz) vs ``build_web_full`` (full 30 Hz grid) on
   synthetic clip pairs (a clip against a time-warped copy of itself) of the given 30 Hz lengths.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from motionweb.store.kinematics import quat_from_euler, sample_motion
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.distance import distance_grid, prepare_pair, rigid_align_2d
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.matchweb.build import build_web, build_web_full
from motionweb.tasks.matchweb.params import MatchWebParams

from bench.timing import best_of

ROT = ("Zrotation", "Xrotation", "Yrotation")


def bench_grid(n: int, points: int) -> None:
    rng = np.random.default_rng(0)
    fa = rng.normal(size=(n, points, 3)).astype(np.float32)
    fb = rng.normal(size=(n, points, 3)).astype(np.float32)
    w = np.full(points, 1.0 / points)
    distance_grid(fa[:64], fb[:64], w)  # compile / warm up
    t_gemm, _ = best_of(lambda: distance_grid(fa, fb, w))
    pa, pb = prepare_pair(fa, fb, w)
    rb = np.concatenate([pb.right, pb.right_rot], axis=0)

    def bare() -> None:
        np.matmul(pa.left, rb.T)
        np.matmul(pa.left_y, pb.right_y.T)

    t_bare, _ = best_of(bare)
    m = 300
    t0 = time.perf_counter()
    for k in range(m):
        rigid_align_2d(fa[k % n], fb[(7 * k) % n], w)
    t_slow = (time.perf_counter() - t0) / m
    cells = n * n
    flops = 10.0 * cells * points
    print(f"grid {n}x{n}, P={points}:")
    print(f"  GEMM form   {t_gemm * 1e3:8.1f} ms  {cells / t_gemm / 1e6:8.1f} Mcells/s  {flops / t_gemm / 1e9:6.1f} GFLOP/s")
    print(f"  bare matmul {t_bare * 1e3:8.1f} ms  {cells / t_bare / 1e6:8.1f} Mcells/s  {flops / t_bare / 1e9:6.1f} GFLOP/s")
    print(f"  slow ref    {t_slow * 1e6:8.1f} us/cell {1 / t_slow / 1e6:8.4f} Mcells/s")
    print(f"  GEMM vs slow: {t_slow * cells / t_gemm:,.0f}x   GEMM / bare-matmul ceiling: {t_bare / t_gemm:.0%}")


def skeleton(n_joints: int = 22) -> Skeleton:
    rng = np.random.default_rng(1)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n_joints)])
    offs = rng.normal(0, 0.15, (n_joints, 3))
    offs[0] = 0
    ch = (("Xposition", "Yposition", "Zposition", *ROT),) + (ROT,) * (n_joints - 1)
    return Skeleton(tuple(f"j{k}" for k in range(n_joints)), parents, offs, ch)


def clip(n: int, fps: float, seed: int) -> Motion:
    """Random smooth joint rotations (several incommensurate sines per channel), wandering root."""
    rng = np.random.default_rng(seed)
    sk = skeleton()
    t = np.arange(n) / fps
    ang = np.zeros((n, sk.n_joints, 3))
    for j in range(sk.n_joints):
        for a in range(3):
            for _ in range(3):
                ang[:, j, a] += rng.uniform(2, 13) * np.sin(2 * np.pi * rng.uniform(0.1, 1.2) * t + rng.uniform(0, 6))
    yaw = np.cumsum(rng.normal(0, 0.3, n)) / fps * 20
    ang[:, 0, 2] += yaw
    root = np.stack([np.cumsum(np.sin(np.deg2rad(yaw))) / fps, np.full(n, 0.95),
                     np.cumsum(np.cos(np.deg2rad(yaw))) / fps], axis=1)
    return Motion(sk, fps, root, quat_from_euler(ang, "ZXY"), unit="m")


def warp(n_out: int, n_in: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, n_out)
    speed = np.ones(n_out)
    for _ in range(3):
        speed += rng.uniform(-0.3, 0.3) * np.sin(2 * np.pi * rng.uniform(0.5, 3) * x + rng.uniform(0, 6))
    c = np.concatenate([[0], np.cumsum(np.clip(speed, 0.6, 1.6)[:-1])])
    return c / c[-1] * (n_in - 1)


def bench_webs(frames: list[int], full_max: int) -> None:
    fc, cfg = FeatureParams(), MatchWebParams()
    print("\nmatch webs, clip vs time-warped copy (frames at the 30 Hz working rate):")
    print(f"{'frames':>7} {'features':>9} {'c2f':>8} {'paths':>6} {'bridges':>7} | {'grid30':>8} "
          f"{'web30':>8} {'full':>8} {'paths':>6} {'bridges':>7} | {'full/c2f':>8}")
    # warm up the compiled kernels on a small pair
    small = {r: clip_features(clip(200, 30.0, 0), r, fc) for r in fc.rates}
    w = point_weights(skeleton(), fc)
    build_web(small, small, w, cfg, self_pair=True)
    build_web_full(distance_grid(small[30.0], small[30.0], w), 30.0, cfg, self_pair=True)
    for n in frames:
        a = clip(n, 30.0, n)
        b = replace(sample_motion(a, warp(int(n * 0.9), n, n + 1)))
        t = time.perf_counter()
        fa = {r: clip_features(a, r, fc) for r in fc.rates}
        fb = {r: clip_features(b, r, fc) for r in fc.rates}
        t_feat = time.perf_counter() - t
        t = time.perf_counter()
        web = build_web(fa, fb, w, cfg, self_pair=False)
        t_c2f = time.perf_counter() - t
        row = (f"{n:>7} {t_feat:>8.2f}s {t_c2f:>7.2f}s {web.n_paths:>6} {web.n_bridges:>7} |")
        if n <= full_max:
            t = time.perf_counter()
            g = distance_grid(fa[30.0], fb[30.0], w)
            t_grid = time.perf_counter() - t
            t = time.perf_counter()
            full = build_web_full(g, 30.0, cfg, self_pair=False)
            t_web = time.perf_counter() - t
            del g
            tot = t_grid + t_web
            row += (f" {t_grid:>7.2f}s {t_web:>7.2f}s {tot:>7.2f}s {full.n_paths:>6} {full.n_bridges:>7} |"
                    f" {tot / t_c2f:>7.1f}x")
        else:
            row += f" {'(skipped: --full-max)':>47} |"
        print(row, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[2000, 4000, 8000])
    ap.add_argument("--full-max", type=int, default=8000, help="largest pair also built at full resolution")
    ap.add_argument("--points", type=int, default=155, help="points per cloud for the grid benchmark (5 x 31)")
    ap.add_argument("--grid", type=int, default=4000, help="frames per side of the grid benchmark")
    args = ap.parse_args()
    bench_grid(args.grid, args.points)
    bench_webs(args.frames, args.full_max)


if __name__ == "__main__":
    main()
